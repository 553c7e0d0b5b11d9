//! voxserve's GPU stages: WGSL compute shaders, the Rust pipelines that drive them,
//! and a CPU twin of every stage with the same name, written loop for loop like the
//! shader, which tests compare against the GPU.
//!
//! # Layout
//! - [`gpu`]: [`GpuContext`], adapter selection (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`,
//!   hardware before software), the device with the adapter's own limits, error
//!   scopes turned into [`GpuError`], waiting and readback.
//! - [`camera`]: [`Camera`], an orbit camera around the volume, and its matrices.
//! - [`frame`]: [`FrameRequest`] (what to draw) and [`Frame`] (RGBA8 pixels).
//! - [`volume_texture`]: how a [`blocks::Volume`] becomes a 3D texture (format and
//!   the texel value → transfer-function coordinate map), shared by GPU and CPU.
//! - [`raycast`]: the `raycast` stage: [`RaycastParams`] (mirrored in WGSL) and
//!   [`RaycastPipeline`].
//! - [`renderer`]: [`Renderer`], a volume resident on the GPU rendered frame by frame.
//! - [`cpu`]: the CPU twins (`cpu::raycast`) and [`cpu::render`].
//! - [`error`]: [`GpuError`], this crate's one error type.
//!
//! The WGSL sources are in `shaders/wgsl/`: one file per stage, shared structs and
//! helpers in `shaders/wgsl/shared/`, concatenated ahead of the stage by [`wgsl`].

pub mod camera;
pub mod cpu;
pub mod error;
pub mod frame;
pub mod gpu;
pub mod raycast;
pub mod renderer;
pub mod volume_texture;
pub mod wgsl;

/// The wgpu this crate is built on, for callers that name its types.
pub use wgpu;

pub use camera::Camera;
pub use error::GpuError;
pub use frame::{Frame, FrameRequest, Shading};
pub use gpu::GpuContext;
pub use raycast::{RaycastParams, RaycastPipeline};
pub use renderer::Renderer;
