//! DICOM series, read with the dicom-rs crates.
//!
//! A folder is read file by file, headers only (up to the pixel data), in
//! parallel. Files are grouped by SeriesInstanceUID, and each series is split
//! by geometry (orientation, rows × columns, pixel spacing) so images of
//! different shapes are never stacked. A folder with several series lists them
//! and asks for one (`--series`).
//!
//! An enhanced multi-frame image (CT, MR, legacy converted) is one slice per
//! frame: each frame's ImagePositionPatient, ImageOrientationPatient,
//! PixelSpacing, SliceThickness and rescale come from its item of the
//! PerFrameFunctionalGroupsSequence, else from the
//! SharedFunctionalGroupsSequence, else from the top level, so its frames
//! (and those of several instances of one series) are grouped, sorted and
//! checked as classic slices are. Its file is read whole once and kept while
//! the frames of a slab are decoded in parallel.
//!
//! Within a series, slices are sorted by the projection of ImagePositionPatient
//! on the slice normal (row × column direction) — never by InstanceNumber or file
//! name. The slice spacing comes from position differences and is checked:
//! duplicated positions, missing slices and uneven spacing beyond
//! [`SPACING_TOLERANCE`] are refused with the files named. A gantry tilt (slices
//! stacked along a direction that is not their normal) is kept as a sheared
//! affine: the third direction is the stacking direction, not the normal.
//!
//! Pixels: BitsStored and HighBit select the stored bits, sign-extended when
//! PixelRepresentation is 1; MONOCHROME1 is inverted so higher is brighter;
//! pixels equal to PixelPaddingValue (up to PixelPaddingRangeLimit) take the
//! lowest other value of the series. RescaleSlope/RescaleIntercept become the
//! value map when every slice shares them; otherwise each slice is rescaled to
//! physical values in `f32`. Compressed transfer syntaxes (RLE, JPEG lossless,
//! JPEG-LS, JPEG 2000) are decoded by dicom-pixeldata.
//!
//! Hostile files: every element length is checked against the file's size
//! before dicom-rs reads the file (`bounds`), and every header read and pixel
//! decode runs inside the panic boundary ([`crate::ingest::boundary`]).
//!
//! # Layout
//! - `bounds`: element lengths checked against the file before reading it.
//! - `slice_header`: what one file's header says, read up to the pixel data.
//! - `folder`: [`FolderScan`], the series of a folder grouped by UID and
//!   geometry, their [`SeriesSummary`] listing, [`open_folder`] and [`open_file`].
//! - `geometry`: placing a series in patient LPS: axes, slice sorting, spacing
//!   checks, gantry tilt.
//! - `pixels`: the series' one pixel format and decoding a slice to values.
//! - `series`: [`DicomSeries`], a checked series as a [`super::VolumeSource`].

mod bounds;
mod folder;
mod geometry;
mod pixels;
mod series;
mod slice_header;

pub use folder::{FolderScan, SeriesSummary, open_file, open_folder};
pub use geometry::SPACING_TOLERANCE;
pub use series::DicomSeries;
pub use slice_header::{InstanceUids, instance_uids, is_uid};
