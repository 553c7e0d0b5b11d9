//! Volume data for voxserve: what a volume is, where the built-in one comes from,
//! and how values are classified by a transfer function.
//!
//! # Layout
//! - [`ingest`]: reading raw, NRRD, NIfTI-1, MetaImage and DICOM series as a
//!   [`ingest::VolumeSource`] that delivers z-slabs in bounded memory.
//! - [`volume`]: [`Volume`], a voxel grid in memory with its physical geometry
//!   (dimensions, spacing, origin) and the map from stored values to physical ones
//!   (Hounsfield units for CT).
//! - [`phantom`]: the built-in dataset, a deterministic procedural CT head phantom
//!   (a 3D Shepp–Logan head with Hounsfield-like values).
//! - [`transfer_function`]: [`TransferFunction`] (control points in physical units),
//!   its named presets and the 1D RGBA table that the GPU stages sample.
//! - [`error`]: [`Error`], this crate's one error type.

pub mod error;
pub mod ingest;
pub mod phantom;
pub mod transfer_function;
pub mod volume;

pub use error::Error;
pub use ingest::{VolumeInfo, VolumeSource};
pub use transfer_function::{Preset, TfPoint, TransferFunction};
pub use volume::{ValueMap, Volume, Voxel, VoxelData, VoxelType};

// GPU uploads hand voxel memory to the device as little-endian bytes.
#[cfg(target_endian = "big")]
compile_error!("voxserve assumes a little-endian target");
