//! voxserve's GPU stages: WGSL compute shaders, the Rust pipelines that drive them,
//! and a CPU twin of every stage with the same name, written loop for loop like the
//! shader, which tests compare against the GPU.
//!
//! # Layout
//! - [`gpu`]: [`GpuContext`], adapter selection (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`,
//!   hardware before software), the device with the adapter's own limits, error
//!   scopes turned into [`GpuError`], waiting and readback.
//! - [`camera`]: [`Camera`], an orbit camera around the volume with a
//!   perspective or orthographic [`Projection`], and its matrices.
//! - [`settings`]: the view-settings schema: [`settings!`] declares each
//!   setting once (name, type, default, range, unit, group, doc); command
//!   line, query, view sessions and `GET /api/settings` derive from it;
//!   [`SettingError`] names a refused setting, its value and what was expected.
//! - [`frame`]: [`FrameRequest`] (what to draw: camera, classification,
//!   [`Shading`], [`ClipBox`], data reduction, the illumination modes'
//!   settings) and [`Frame`] (RGBA8 pixels).
//! - [`volume_texture`]: how voxels become texels (format and the texel value →
//!   transfer-function coordinate map), shared by the atlas, the reference
//!   texture and the CPU twins.
//! - [`raycast`]: the ray-marching stages `raycast` (packed blocks) and
//!   `reference` (one plain texture): [`RaycastParams`] (mirrored in WGSL) and
//!   [`MarchPipeline`].
//! - [`packed_volume`]: [`packed_volume::PackedVolume`], the uniform block
//!   every stage reading packed blocks shares (volume and atlas sizes, the
//!   texel → transfer-function map), and [`packed_volume::PackedLayout`].
//! - [`packed`]: the atlas and block index on the GPU ([`packed::GpuAtlas`]),
//!   uploaded in rows of slots and updated block by block.
//! - [`illumination`]: the illumination modes behind one interface
//!   ([`illumination::Mode`], [`illumination::Illumination`]): each mode's
//!   stages declared once, and the update policy they share.
//! - [`global_light`]: global light propagation (local piecewise integration,
//!   the shadow volume, direct light, first-order in-scattering) in packed
//!   block coordinates, one module per job (settings, uniforms, pipelines,
//!   resources, update policy).
//! - [`extinction`]: extinction-based illumination (a 3D summed-area table of
//!   extinction coefficients; ambient occlusion, colour bleeding and cone soft
//!   shadows from several lights in a light cache), laid out alike.
//! - [`pipeline`]: builders for compute stages and their bind group layouts.
//! - [`residency`]: [`residency::Residency`], the blocks a renderer keeps on
//!   the GPU at the levels the selection asks for as far as memory allows
//!   now: blocks not yet read are requested in the background and shown
//!   coarser meanwhile, so rendering never waits for storage.
//! - [`renderer`]: [`Renderer`] (a brick store rendered from its packed blocks,
//!   frame by frame) and [`ReferenceRenderer`] (tests and benchmarks).
//! - [`cpu`]: the CPU twins (`cpu::raycast`, `cpu::reference`,
//!   `cpu::global_light`, `cpu::extinction`), whole-frame CPU renders, and
//!   [`cpu::CpuRenderer`], the CPU backend: a brick store rendered frame by
//!   frame through the twins, as [`Renderer`] renders it on the GPU.
//! - [`backend`]: `--renderer auto|gpu|cpu` ([`RendererChoice`]), the
//!   [`Backend`] it picks (the CPU when the only adapter is a software one),
//!   and [`AnyRenderer`], either renderer behind the same calls.
//! - [`colour_difference`]: CIE ΔE*uv between a frame and its reference (mean,
//!   RMS, 99th percentile, ΔE₆; over the image or the object's pixels), for
//!   tests and benchmarks.
//! - [`error`]: [`GpuError`], this crate's one error type.
//!
//! The WGSL sources are in `shaders/wgsl/`: one file per stage, shared structs and
//! helpers in `shaders/wgsl/shared/`, concatenated ahead of the stage by [`wgsl`].

pub mod backend;
pub mod camera;
pub mod colour_difference;
pub mod cpu;
pub mod error;
pub mod extinction;
pub mod frame;
pub mod global_light;
pub mod gpu;
pub mod illumination;
#[cfg(test)]
mod layout;
pub mod packed;
pub mod packed_volume;
pub mod pipeline;
pub mod raycast;
pub mod renderer;
pub mod residency;
pub mod settings;
pub mod slice;
pub mod volume_texture;
pub mod wgsl;

/// The wgpu this crate is built on, for callers that name its types.
pub use wgpu;

pub use backend::{AnyRenderer, Backend, RendererChoice};
pub use camera::{Camera, Projection};
pub use error::GpuError;
pub use frame::{ClipBox, Compositing, Frame, FrameRequest, Rows, Shading, Window};
pub use global_light::{LightSettings, LightSource};
pub use gpu::GpuContext;
pub use raycast::{MarchPipeline, RaycastParams, Stage};
pub use renderer::{ReferenceRenderer, RenderStats, Renderer};
pub use settings::{Choice, SettingError, Settings};
