//! Volume data for voxserve: what a volume is, where the built-in one comes from,
//! and how values are classified by a transfer function.
//!
//! # Layout
//! - [`ingest`]: reading raw, NRRD, NIfTI-1, MetaImage and DICOM series as a
//!   [`ingest::VolumeSource`] that delivers z-slabs in bounded memory.
//! - [`geometry`]: [`Geometry`], where a voxel grid sits in patient space
//!   (dimensions, spacing, origin, direction), its invariants and what derives
//!   from it; every other crate's view of a volume's geometry is this type.
//! - [`volume`]: [`Volume`], a voxel grid in memory with its [`Geometry`] and the
//!   map from stored values to physical ones (Hounsfield units for CT).
//! - [`phantom`]: the built-in dataset, a deterministic procedural CT head phantom
//!   (skull with orbits, sinuses and foramen magnum, brain with ventricles,
//!   contrast-filled arteries, a lesion; Hounsfield-like values).
//! - [`store`]: the brick store: OME-Zarr 0.5 written with `zarrs`, 16³ blocks at
//!   five levels of detail, per-block statistics, crash-safe ingest.
//! - [`cache`]: [`cache::BlockCache`], decoded chunks under a byte budget.
//! - [`lod`]: transfer-function based level-of-detail selection under a budget.
//! - [`packing`]: the atlas layout by level and the block index, for the GPU.
//! - [`seams`]: aprons that meet neighbours of other levels without a step.
//! - [`transfer_function`]: [`TransferFunction`] (control points in physical units),
//!   its named presets and the 1D RGBA table that the GPU stages sample.
//! - [`error`]: [`Error`], this crate's one error type.

pub mod cache;
pub mod error;
pub mod geometry;
pub mod ingest;
pub mod lod;
pub mod packing;
pub mod phantom;
pub mod seams;
pub mod store;
pub mod transfer_function;
pub mod visibility;
pub mod volume;

pub use error::Error;
pub use geometry::Geometry;
pub use ingest::{VolumeInfo, VolumeSource};
pub use transfer_function::{Preset, TfPoint, TransferFunction};
pub use volume::{ValueMap, Volume, Voxel, VoxelData, VoxelType};

// GPU uploads hand voxel memory to the device as little-endian bytes.
#[cfg(target_endian = "big")]
compile_error!("voxserve assumes a little-endian target");
