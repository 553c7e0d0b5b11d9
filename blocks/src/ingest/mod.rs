//! Reading volumes from the files scanners and tools write: raw, NRRD, NIfTI-1,
//! MetaImage and DICOM series.
//!
//! Every reader is a [`VolumeSource`]: a [`VolumeInfo`] (a [`Geometry`] in
//! patient LPS, voxel type, value map, modality) and slab reads — a range of
//! z-slices at a time — so a volume far larger than memory flows through in
//! bounded memory. [`open`] picks the reader from the path.
//!
//! Geometry: every reader hands its [`Geometry`] through
//! [`Geometry::checked`], naming the header fields each part came from.
//! Formats that work in RAS (NIfTI, NRRD with a RAS space) are converted.
//!
//! Headers never decide an allocation on their own: dimensions are checked
//! against [`MAX_SLICE_BYTES`] and [`MAX_VOXELS`], and against the size of the
//! data they describe, before anything is read.
//!
//! Files a header names (NRRD's `data file`, MetaImage's `ElementDataFile`, a
//! NIfTI pair's `.img`) must be regular files inside the header's folder unless
//! [`OpenOptions::allow_data_outside`] says otherwise; every size derived from a
//! header is computed with checked arithmetic and compared with the file's real
//! size before anything is allocated or sought.
//!
//! Decoders voxserve does not own run inside [`boundary::guard`]: a panic in one
//! is an error naming the file, never a crash.
//!
//! # Layout
//! - [`boundary`]: the panic boundary around decoders.
//! - [`stream`]: voxels as a byte stream in a file (raw, gzip or zlib), shared by
//!   raw, NRRD, NIfTI and MetaImage.
//! - [`raw`], [`nrrd`], [`nifti`], [`metaimage`]: the header readers.
//! - [`dicom`]: DICOM series: grouping, sorting, spacing checks, pixel decoding.
//! - [`header`]: parsing helpers shared by the text headers.

pub mod boundary;
pub mod dicom;
pub mod header;
pub mod metaimage;
pub mod nifti;
pub mod nrrd;
pub mod raw;
pub mod stream;

use std::fmt;
use std::path::{Path, PathBuf};

use crate::{Error, Geometry, ValueMap, Volume, VoxelData, VoxelType};

/// The largest slice accepted, in bytes: a slab holds at least one slice, so this
/// bounds the memory a read can need.
pub const MAX_SLICE_BYTES: u64 = 1 << 30;
/// The largest volume accepted, in voxels (2⁴⁰: 4 TiB of 32-bit voxels).
pub const MAX_VOXELS: u64 = 1 << 40;
/// The most voxels along one axis.
pub const MAX_AXIS: u64 = u32::MAX as u64;
/// Slab size aimed at by [`slab_depth`].
pub const SLAB_BYTES: u64 = 64 << 20;

/// The file formats voxserve reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Format {
    /// Headerless voxels.
    Raw,
    /// NRRD, attached or detached header.
    Nrrd,
    /// NIfTI-1, single file or pair, optionally gzip-compressed.
    Nifti,
    /// MetaImage, `.mha` or `.mhd` + data file.
    MetaImage,
    /// A DICOM series (a folder) or a single DICOM file.
    Dicom,
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Format::Raw => "raw",
            Format::Nrrd => "NRRD",
            Format::Nifti => "NIfTI-1",
            Format::MetaImage => "MetaImage",
            Format::Dicom => "DICOM",
        })
    }
}

/// The most characters kept of each text of a [`Study`] (DICOM's long
/// strings hold 64).
pub const STUDY_TEXT_MAX: usize = 128;

/// Who and what was scanned, from DICOM headers: what a viewer shows in its
/// corners. Each text at most [`STUDY_TEXT_MAX`] characters; absent where the
/// source says nothing (files other than DICOM say nothing).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct Study {
    /// PatientName (0010,0010) as stored: family^given^middle^prefix^suffix.
    pub patient_name: Option<String>,
    /// PatientID (0010,0020).
    pub patient_id: Option<String>,
    /// PatientBirthDate (0010,0030), YYYYMMDD.
    pub patient_birth_date: Option<String>,
    /// StudyDate (0008,0020), YYYYMMDD.
    pub study_date: Option<String>,
    /// StudyDescription (0008,1030).
    pub study_description: Option<String>,
    /// SeriesDescription (0008,103E).
    pub series_description: Option<String>,
    /// SliceThickness (0018,0050), mm.
    pub slice_thickness_mm: Option<f64>,
}

impl Study {
    /// Whether nothing is known.
    pub fn is_empty(&self) -> bool {
        *self == Study::default()
    }

    /// `text` cut to [`STUDY_TEXT_MAX`] characters.
    pub fn text(text: &str) -> String {
        text.chars().take(STUDY_TEXT_MAX).collect()
    }
}

/// What a reader learnt about a volume from its headers.
#[derive(Debug, Clone, PartialEq)]
pub struct VolumeInfo {
    /// The file or folder read.
    pub path: PathBuf,
    /// The format.
    pub format: Format,
    /// Dimensions, spacing, origin and direction in LPS.
    pub geometry: Geometry,
    /// The type slabs are delivered in.
    pub voxel_type: VoxelType,
    /// Stored → physical values.
    pub value_map: ValueMap,
    /// The unit of physical values, when known (e.g. `HU`).
    pub unit: Option<String>,
    /// The imaging modality, when known (e.g. `CT`).
    pub modality: Option<String>,
    /// A description from the header, when there is one.
    pub description: Option<String>,
    /// Patient and study, from DICOM headers.
    pub study: Study,
    /// Things the reader assumed or corrected, for the user to see.
    pub notes: Vec<String>,
}

impl VolumeInfo {
    /// Bytes in one z-slice.
    pub fn slice_bytes(&self) -> u64 {
        self.geometry.slice_voxels() * self.voxel_type.size() as u64
    }

    /// Bytes in the whole volume.
    pub fn total_bytes(&self) -> u64 {
        self.geometry.voxel_count() * self.voxel_type.size() as u64
    }

    /// A short name for listings: the file or folder name.
    pub fn name(&self) -> String {
        self.path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.path.display().to_string())
    }
}

/// A volume that can be read a slab of z-slices at a time.
///
/// Reading slabs in increasing z is the fast path; compressed sources restart
/// their decoder when asked to go back.
pub trait VolumeSource: Send + fmt::Debug {
    /// What the headers say.
    fn info(&self) -> &VolumeInfo;

    /// Reads slices `z0 .. z0 + depth`, x fastest, in [`VolumeInfo::voxel_type`].
    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<VoxelData, Error>;
}

/// How to open an input where its headers leave choices.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OpenOptions {
    /// The DICOM series to read from a folder that holds several.
    pub series: Option<String>,
    /// Layout of a raw file (each field overrides what the file name says).
    pub raw: raw::RawOptions,
    /// Whether a detached header may name a data file outside its own folder
    /// (and a DICOM folder hold symbolic links to files outside it).
    pub allow_data_outside: bool,
}

/// Opens `path` with the reader its name or first bytes call for. Headers are
/// read, and slabs later decoded, inside the panic [`boundary`].
pub fn open(path: &Path, options: &OpenOptions) -> Result<Box<dyn VolumeSource>, Error> {
    let inner = boundary::guard(path, "volume header", || open_unguarded(path, options))?;
    Ok(Box::new(Guarded { inner }))
}

/// A source whose slab reads run inside the panic [`boundary`].
#[derive(Debug)]
struct Guarded {
    inner: Box<dyn VolumeSource>,
}

impl VolumeSource for Guarded {
    fn info(&self) -> &VolumeInfo {
        self.inner.info()
    }

    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<VoxelData, Error> {
        let path = self.inner.info().path.clone();
        let decoder = format!("{} voxel data", self.inner.info().format);
        boundary::guard(&path, &decoder, || self.inner.read_slab(z0, depth))
    }
}

/// [`open`] without the boundary.
fn open_unguarded(path: &Path, options: &OpenOptions) -> Result<Box<dyn VolumeSource>, Error> {
    let meta = std::fs::metadata(path).map_err(|source| Error::Io {
        path: path.to_owned(),
        source,
    })?;
    if !meta.is_dir() && !meta.is_file() {
        return Err(header::field(
            path,
            "input",
            "not a regular file (a device, pipe or socket): expected a volume file or a folder",
        ));
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let ext = |e: &str| name.ends_with(e);
    let headed = meta.is_dir()
        || [
            ".nrrd", ".nhdr", ".nii", ".nii.gz", ".hdr", ".mha", ".mhd", ".dcm",
        ]
        .iter()
        .any(|e| ext(e));
    let given = options.raw.given();
    if headed && !given.is_empty() {
        return Err(Error::Field {
            path: path.to_owned(),
            field: given.join(", "),
            message: "raw-file options, but this input has headers that say its layout and \
                      geometry: expected them only for headerless raw files"
                .into(),
        });
    }
    if meta.is_dir() {
        return Ok(Box::new(dicom::open_folder(
            path,
            options.series.as_deref(),
            options.allow_data_outside,
        )?));
    }
    if ext(".nrrd") || ext(".nhdr") {
        return Ok(Box::new(nrrd::open(path, options.allow_data_outside)?));
    }
    if ext(".nii") || ext(".nii.gz") || ext(".hdr") {
        return Ok(Box::new(nifti::open(path, options.allow_data_outside)?));
    }
    if ext(".mha") || ext(".mhd") {
        return Ok(Box::new(metaimage::open(path, options.allow_data_outside)?));
    }
    if ext(".dcm") {
        return Ok(Box::new(dicom::open_file(path)?));
    }
    if ext(".raw") || options.raw.is_given() {
        return Ok(Box::new(raw::open(path, &options.raw)?));
    }
    // No telling extension: look at the first bytes.
    let head = header::read_prefix(path, 352)?;
    if head.starts_with(b"NRRD") {
        Ok(Box::new(nrrd::open(path, options.allow_data_outside)?))
    } else if head.get(128..132) == Some(b"DICM") {
        Ok(Box::new(dicom::open_file(path)?))
    } else if head.get(344..347) == Some(b"n+1") || head.starts_with(&[0x1f, 0x8b]) {
        Ok(Box::new(nifti::open(path, options.allow_data_outside)?))
    } else if head.starts_with(b"ObjectType") || head.starts_with(b"NDims") {
        Ok(Box::new(metaimage::open(path, options.allow_data_outside)?))
    } else {
        Err(Error::UnknownFormat {
            path: path.to_owned(),
        })
    }
}

/// Checks that slices `z0 .. z0 + depth` are a non-empty range within the volume.
pub fn check_slab(info: &VolumeInfo, z0: u32, depth: u32) -> Result<(), Error> {
    let nz = info.geometry.dims[2];
    if depth == 0 || z0.checked_add(depth).is_none_or(|end| end > nz) {
        return Err(Error::Field {
            path: info.path.clone(),
            field: "slab".into(),
            message: format!(
                "slices {z0}..{}: expected a non-empty range within 0..{nz}",
                u64::from(z0) + u64::from(depth)
            ),
        });
    }
    Ok(())
}

/// Checks dimensions from a header before anything is allocated for them:
/// every axis at least 1, a slice at most [`MAX_SLICE_BYTES`], the volume at most
/// [`MAX_VOXELS`].
pub fn check_dims(
    path: &Path,
    field: &str,
    dims: [u64; 3],
    voxel_size: u64,
) -> Result<[u32; 3], Error> {
    let bad = |message: String| Error::Field {
        path: path.to_owned(),
        field: field.to_owned(),
        message,
    };
    if dims.contains(&0) {
        return Err(bad(format!(
            "{dims:?}: expected at least one voxel along every axis"
        )));
    }
    for (axis, d) in ["x", "y", "z"].into_iter().zip(dims) {
        if d > MAX_AXIS {
            return Err(bad(format!(
                "{} × {} × {}: {d} voxels along {axis} is out of range: expected 1 to {MAX_AXIS} \
                 voxels per axis, at most {MAX_SLICE_BYTES} bytes per slice and {MAX_VOXELS} \
                 voxels in all",
                dims[0], dims[1], dims[2]
            )));
        }
    }
    // Each axis is below 2³², so the product of two fits u64.
    let slice = (dims[0] * dims[1]).saturating_mul(voxel_size);
    if slice > MAX_SLICE_BYTES {
        return Err(bad(format!(
            "{} × {} × {}: one slice would be {slice} bytes; expected at most {MAX_SLICE_BYTES} \
             bytes per slice (are the dimensions right?)",
            dims[0], dims[1], dims[2]
        )));
    }
    let voxels = (dims[0] * dims[1]).saturating_mul(dims[2]);
    if voxels > MAX_VOXELS {
        return Err(bad(format!(
            "{} × {} × {} = {voxels} voxels: expected at most {MAX_VOXELS}",
            dims[0], dims[1], dims[2]
        )));
    }
    // Each axis fits u32 now: a slice is at most 2³⁰ bytes and the volume 2⁴⁰ voxels.
    let axis = |d: u64| {
        u32::try_from(d)
            .map_err(|_| bad(format!("axis of {d} voxels: expected at most {}", u32::MAX)))
    };
    Ok([axis(dims[0])?, axis(dims[1])?, axis(dims[2])?])
}

/// The largest physical value accepted, in magnitude: far inside `f32`'s range
/// (3.4·10³⁸), so that sums, differences and gradients of physical values stay
/// finite on the GPU.
pub const MAX_PHYSICAL: f64 = 1e30;

/// Checks a value map read from `field`: a finite, non-zero slope, a finite
/// intercept and, for integer types, every value `voxel_type` can store mapped
/// within ±[`MAX_PHYSICAL`] (float data is checked on its values by [`scan`]).
pub fn check_value_map(
    path: &Path,
    field: &str,
    map: ValueMap,
    voxel_type: VoxelType,
) -> Result<(), Error> {
    let bad = |message: String| Error::Field {
        path: path.to_owned(),
        field: field.to_owned(),
        message,
    };
    let (slope, intercept) = (f64::from(map.slope), f64::from(map.intercept));
    if !slope.is_finite() || slope == 0.0 || !intercept.is_finite() {
        return Err(bad(format!(
            "slope {slope}, intercept {intercept}: expected a finite, non-zero slope and a \
             finite intercept"
        )));
    }
    if let Some(max) = voxel_type.max_stored() {
        let max = f64::from(max);
        let min = if matches!(voxel_type, VoxelType::I8 | VoxelType::I16 | VoxelType::I32) {
            -max - 1.0
        } else {
            0.0
        };
        let ends = [map.physical(min), map.physical(max)];
        if !ends.iter().all(|v| within(*v, MAX_PHYSICAL)) {
            return Err(bad(format!(
                "slope {slope}, intercept {intercept} map {} values {min}..{max} to {}..{}: \
                 expected physical values within ±{MAX_PHYSICAL:e}",
                voxel_type.name(),
                ends[0],
                ends[1]
            )));
        }
    }
    Ok(())
}

/// Whether `|v| <= bound` (false for NaN).
fn within(v: f64, bound: f64) -> bool {
    v.abs() <= bound
}

/// Refuses stored values whose physical values lie beyond ±[`MAX_PHYSICAL`].
fn check_physical_range(info: &VolumeInfo, stored: [f64; 2]) -> Result<(), Error> {
    let ends = stored.map(|v| info.value_map.physical(v));
    if ends.iter().all(|v| v.abs() <= MAX_PHYSICAL) {
        return Ok(());
    }
    Err(Error::Field {
        path: info.path.clone(),
        field: "voxel data".into(),
        message: format!(
            "stored values {}..{} are {}..{} physical (slope {}, intercept {}): expected \
             physical values within ±{MAX_PHYSICAL:e}",
            stored[0], stored[1], ends[0], ends[1], info.value_map.slope, info.value_map.intercept
        ),
    })
}

/// How far a direction matrix read from a header may be from orthonormal: each
/// column's length from 1, and each pair's dot product from 0 (about 0.06°).
/// Headers written in single precision stay far inside it.
pub const ORTHONORMAL_TOLERANCE: f64 = 1e-3;

/// Checks that `direction` (unit vectors of the index axes, as columns) is
/// orthonormal within [`ORTHONORMAL_TOLERANCE`]: a sheared or scaled matrix is
/// a damaged header, and would place voxels where the scanner did not.
pub fn check_orthonormal(path: &Path, field: &str, direction: [[f64; 3]; 3]) -> Result<(), Error> {
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let bad = |message: String| Error::Field {
        path: path.to_owned(),
        field: field.to_owned(),
        message,
    };
    for (axis, column) in ["x", "y", "z"].into_iter().zip(direction) {
        let length = dot(column, column).sqrt();
        if !within(length - 1.0, ORTHONORMAL_TOLERANCE) {
            return Err(bad(format!(
                "the direction of index axis {axis} {column:?} has length {length}: expected \
                 unit vectors (orthonormal within {ORTHONORMAL_TOLERANCE})"
            )));
        }
    }
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        let cos = dot(direction[a], direction[b]);
        if !within(cos, ORTHONORMAL_TOLERANCE) {
            let axes = ["x", "y", "z"];
            return Err(bad(format!(
                "the directions of index axes {} {:?} and {} {:?} are {:.3}° apart: expected \
                 perpendicular axes (orthonormal within {ORTHONORMAL_TOLERANCE}); a sheared \
                 grid is not supported",
                axes[a],
                direction[a],
                axes[b],
                direction[b],
                cos.clamp(-1.0, 1.0).acos().to_degrees()
            )));
        }
    }
    Ok(())
}

/// The number of slices per slab that keeps a slab near [`SLAB_BYTES`] (at least 1).
pub fn slab_depth(info: &VolumeInfo) -> u32 {
    let depth = (SLAB_BYTES / info.slice_bytes().max(1)).max(1);
    u32::try_from(depth)
        .unwrap_or(u32::MAX)
        .min(info.geometry.dims[2])
}

/// Statistics of a whole volume, gathered slab by slab.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeStats {
    /// Smallest and largest stored value (NaNs ignored).
    pub stored_range: [f64; 2],
    /// Mean stored value.
    pub mean: f64,
    /// Voxels read.
    pub voxels: u64,
    /// NaN voxels (float data only).
    pub nans: u64,
}

/// Reads the whole volume slab by slab and gathers [`VolumeStats`], in memory
/// bounded by one slab. `progress` is called with the slices read so far.
/// Infinite values are refused (naming the slice and voxel): no value range or
/// rendering can be made of them; NaN is kept as a missing value.
pub fn scan(
    source: &mut dyn VolumeSource,
    mut progress: impl FnMut(u32),
) -> Result<VolumeStats, Error> {
    let info = source.info().clone();
    let depth = slab_depth(&info);
    let (mut lo, mut hi, mut sum, mut count, mut nans) =
        (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0u64, 0u64);
    let nz = info.geometry.dims[2];
    let mut z = 0;
    while z < nz {
        let d = depth.min(nz - z);
        let slab = source.read_slab(z, d)?;
        check_finite(&info, z, &slab)?;
        crate::volume::with_voxels!(&slab, v => {
            for &x in v {
                let x: f64 = x.into();
                if x.is_nan() {
                    nans += 1;
                    continue;
                }
                lo = lo.min(x);
                hi = hi.max(x);
                sum += x;
                count += 1;
            }
        });
        z += d;
        progress(z);
    }
    let stored_range = if count > 0 { [lo, hi] } else { [0.0, 0.0] };
    check_physical_range(&info, stored_range)?;
    Ok(VolumeStats {
        stored_range,
        mean: if count > 0 { sum / count as f64 } else { 0.0 },
        voxels: count + nans,
        nans,
    })
}

/// Refuses a slab (starting at slice `z0`) holding an infinite value, naming
/// the slice and voxel of the first.
fn check_finite(info: &VolumeInfo, z0: u32, slab: &VoxelData) -> Result<(), Error> {
    let VoxelData::F32(v) = slab else {
        return Ok(()); // integers are always finite
    };
    let Some(i) = v.iter().position(|x| x.is_infinite()) else {
        return Ok(());
    };
    let slice = info.geometry.slice_voxels().max(1);
    let nx = u64::from(info.geometry.dims[0]).max(1);
    let (z, within) = (u64::from(z0) + i as u64 / slice, i as u64 % slice);
    Err(Error::Field {
        path: info.path.clone(),
        field: "voxel data".into(),
        message: format!(
            "slice {z} holds {x} at voxel (x {}, y {}): expected finite values (NaN is \
             accepted as a missing value, infinity is not)",
            within % nx,
            within / nx,
            x = v[i]
        ),
    })
}

/// A volume already in memory as a source (for ingesting the phantom or a
/// volume built in code).
#[derive(Debug, Clone)]
pub struct MemorySource {
    info: VolumeInfo,
    volume: std::sync::Arc<Volume>,
}

impl MemorySource {
    /// A source over `volume`, named `name` in listings.
    pub fn new(volume: std::sync::Arc<Volume>, name: &str) -> MemorySource {
        MemorySource {
            info: VolumeInfo {
                path: PathBuf::from(name),
                format: Format::Raw,
                geometry: volume.geometry,
                voxel_type: volume.voxel_type(),
                value_map: volume.value_map,
                unit: volume.unit.clone(),
                modality: volume.modality.clone(),
                description: None,
                study: Study::default(),
                notes: Vec::new(),
            },
            volume,
        }
    }
}

impl VolumeSource for MemorySource {
    fn info(&self) -> &VolumeInfo {
        &self.info
    }

    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<VoxelData, Error> {
        check_slab(&self.info, z0, depth)?;
        let slice = self.info.geometry.slice_voxels() as usize;
        Ok(self
            .volume
            .voxels
            .slice(z0 as usize * slice..(z0 + depth) as usize * slice))
    }
}

/// The largest volume [`load`] reads into memory, in bytes.
pub const MAX_LOAD_BYTES: u64 = 8 << 30;

/// Reads a whole volume into memory (for rendering small data directly and for
/// tests). Refuses volumes over [`MAX_LOAD_BYTES`]: those go through a brick store.
pub fn load(source: &mut dyn VolumeSource) -> Result<Volume, Error> {
    let info = source.info().clone();
    if info.total_bytes() > MAX_LOAD_BYTES {
        return Err(Error::Field {
            path: info.path.clone(),
            field: "size".into(),
            message: format!(
                "{} bytes of voxels: expected at most {MAX_LOAD_BYTES} to load into memory",
                info.total_bytes()
            ),
        });
    }
    let depth = slab_depth(&info);
    let mut voxels = VoxelData::zeros(info.voxel_type, 0);
    let nz = info.geometry.dims[2];
    let mut z = 0;
    while z < nz {
        let d = depth.min(nz - z);
        let slab = source.read_slab(z, d)?;
        check_finite(&info, z, &slab)?;
        voxels.append(slab)?;
        z += d;
    }
    let mut volume = Volume::new(info.name(), info.geometry, voxels, info.value_map)?;
    volume.unit = info.unit.clone();
    volume.modality = info.modality.clone();
    Ok(volume)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn absurd_dimensions_are_refused_before_any_allocation() {
        let p = Path::new("huge.nrrd");
        let err = check_dims(p, "sizes", [1_000_000; 3], 1).expect_err("absurd");
        let msg = err.to_string();
        assert!(
            msg.contains("huge.nrrd: sizes:") && msg.contains("per slice"),
            "{msg}"
        );
        let err = check_dims(p, "sizes", [1024, 1024, 2_000_000], 1).expect_err("too many voxels");
        assert!(
            err.to_string().contains("voxels: expected at most"),
            "{err}"
        );
        assert!(check_dims(p, "sizes", [0, 4, 4], 1).is_err());
        assert_eq!(
            check_dims(p, "sizes", [256, 256, 128], 2).expect("fine"),
            [256, 256, 128]
        );
    }
}
