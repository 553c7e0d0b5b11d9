//! DICOM series, read with the dicom-rs crates.
//!
//! A folder is read file by file, headers only (up to the pixel data), in
//! parallel. Files are grouped by SeriesInstanceUID, and each series is split
//! by geometry (orientation, rows × columns, pixel spacing) so images of
//! different shapes are never stacked. A folder with several series lists them
//! and asks for one (`--series`).
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

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dicom_dictionary_std::tags;
use dicom_object::{DefaultDicomObject, OpenFileOptions};
use dicom_pixeldata::PixelDecoder;
use rayon::prelude::*;

use super::header::{field, read_prefix};
use super::{Format, VolumeInfo, VolumeSource, check_dims};
use crate::{Error, ValueMap, VoxelData, VoxelType};

/// Relative tolerance on slice spacing: differences between neighbouring slice
/// positions may deviate this much from the median difference.
pub const SPACING_TOLERANCE: f64 = 0.01;
/// Stacking directions further than this from the normal (radians, 0.06°) are
/// a gantry tilt.
const TILT_TOLERANCE: f64 = 1e-3;

/// What one file's header says, read up to the pixel data.
#[derive(Debug, Clone)]
struct SliceHeader {
    path: PathBuf,
    series_uid: String,
    series_description: Option<String>,
    modality: Option<String>,
    rows: u32,
    columns: u32,
    /// Row direction (x) then column direction (y), LPS.
    orientation: Option<[f64; 6]>,
    position: Option<[f64; 3]>,
    /// Spacing between rows (y), then between columns (x).
    pixel_spacing: Option<[f64; 2]>,
    slice_thickness: Option<f64>,
    spacing_between_slices: Option<f64>,
    bits_allocated: u16,
    bits_stored: u16,
    high_bit: u16,
    pixel_representation: u16,
    samples_per_pixel: u16,
    photometric: String,
    frames: u32,
    slope: f64,
    intercept: f64,
    padding: Option<(i64, i64)>,
    rescale_type: Option<String>,
    units: Option<String>,
}

impl SliceHeader {
    /// The key that splits a series into stacks of one geometry.
    fn geometry_key(&self) -> String {
        let round = |v: f64| format!("{v:.4}");
        let iop = self
            .orientation
            .map(|o| o.map(round).join(","))
            .unwrap_or_default();
        let ps = self
            .pixel_spacing
            .map(|p| p.map(round).join(","))
            .unwrap_or_default();
        format!("{}x{}|{iop}|{ps}", self.columns, self.rows)
    }
}

/// Reads the header of one file (up to the pixel data).
fn read_header(path: &Path) -> Result<Option<SliceHeader>, Error> {
    let prefix = read_prefix(path, 132)?;
    if prefix.get(128..132) != Some(b"DICM") {
        return Err(field(
            path,
            "preamble",
            "no 'DICM' marker at byte 128: expected a DICOM file (move other files out of the series folder)",
        ));
    }
    let obj = OpenFileOptions::new()
        .read_until(tags::PIXEL_DATA)
        .open_file(path)
        .map_err(|e| {
            field(
                path,
                "header",
                format!("{e}: expected a readable DICOM file"),
            )
        })?;
    let Some(rows) = opt_int::<u32>(&obj, tags::ROWS) else {
        return Ok(None); // no image: DICOMDIR, structured report, …
    };
    let text = |tag| {
        obj.element_opt(tag)
            .ok()
            .flatten()
            .and_then(|e| e.to_str().ok())
            .map(|s| s.trim().to_owned())
            .filter(|s| !s.is_empty())
    };
    let floats = |tag| {
        obj.element_opt(tag)
            .ok()
            .flatten()
            .and_then(|e| e.to_multi_float64().ok())
    };
    let fixed =
        |tag, n: usize| floats(tag).filter(|v| v.len() == n && v.iter().all(|x| x.is_finite()));
    let series_uid = text(tags::SERIES_INSTANCE_UID).ok_or_else(|| {
        field(
            path,
            "SeriesInstanceUID (0020,000E)",
            "missing: expected every image to name its series",
        )
    })?;
    let padding = opt_int::<i64>(&obj, tags::PIXEL_PADDING_VALUE).map(|p| {
        let limit = opt_int::<i64>(&obj, tags::PIXEL_PADDING_RANGE_LIMIT).unwrap_or(p);
        (p.min(limit), p.max(limit))
    });
    Ok(Some(SliceHeader {
        path: path.to_owned(),
        series_uid,
        series_description: text(tags::SERIES_DESCRIPTION),
        modality: text(tags::MODALITY),
        rows,
        columns: opt_int(&obj, tags::COLUMNS).unwrap_or(0),
        orientation: fixed(tags::IMAGE_ORIENTATION_PATIENT, 6)
            .map(|v| [v[0], v[1], v[2], v[3], v[4], v[5]]),
        position: fixed(tags::IMAGE_POSITION_PATIENT, 3).map(|v| [v[0], v[1], v[2]]),
        pixel_spacing: fixed(tags::PIXEL_SPACING, 2).map(|v| [v[0], v[1]]),
        slice_thickness: fixed(tags::SLICE_THICKNESS, 1).map(|v| v[0]),
        spacing_between_slices: fixed(tags::SPACING_BETWEEN_SLICES, 1).map(|v| v[0]),
        bits_allocated: opt_int(&obj, tags::BITS_ALLOCATED).unwrap_or(16),
        bits_stored: opt_int(&obj, tags::BITS_STORED).unwrap_or(16),
        high_bit: opt_int(&obj, tags::HIGH_BIT).unwrap_or(15),
        pixel_representation: opt_int(&obj, tags::PIXEL_REPRESENTATION).unwrap_or(0),
        samples_per_pixel: opt_int(&obj, tags::SAMPLES_PER_PIXEL).unwrap_or(1),
        photometric: text(tags::PHOTOMETRIC_INTERPRETATION).unwrap_or_else(|| "MONOCHROME2".into()),
        frames: opt_int(&obj, tags::NUMBER_OF_FRAMES).unwrap_or(1),
        slope: fixed(tags::RESCALE_SLOPE, 1).map_or(1.0, |v| v[0]),
        intercept: fixed(tags::RESCALE_INTERCEPT, 1).map_or(0.0, |v| v[0]),
        padding,
        rescale_type: text(tags::RESCALE_TYPE),
        units: text(tags::UNITS),
    }))
}

/// An integer attribute, or `None` when absent or not an integer.
fn opt_int<T: DicomInt>(obj: &DefaultDicomObject, tag: dicom_core::Tag) -> Option<T> {
    obj.element_opt(tag).ok().flatten().and_then(T::read)
}

/// The integer types attributes are read as.
trait DicomInt: Sized {
    fn read(e: &dicom_object::mem::InMemElement) -> Option<Self>;
}

macro_rules! impl_dicom_int {
    ($($t:ty),*) => {$(
        impl DicomInt for $t {
            fn read(e: &dicom_object::mem::InMemElement) -> Option<Self> {
                e.to_int::<$t>().ok()
            }
        }
    )*};
}
impl_dicom_int!(u16, u32, i64);

/// One series (of one geometry) found in a folder.
#[derive(Debug)]
struct Stack {
    id: String,
    slices: Vec<SliceHeader>,
}

/// What a listing says about one series of a folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SeriesSummary {
    /// The id `--series` takes: the SeriesInstanceUID, with `/N` appended when
    /// the series holds images of several geometries.
    pub id: String,
    /// Modality, when given.
    pub modality: Option<String>,
    /// SeriesDescription, when given.
    pub description: Option<String>,
    /// Number of images.
    pub slices: usize,
    /// Columns × rows.
    pub size: [u32; 2],
}

impl std::fmt::Display for SeriesSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}  {} {} slices of {}x{}",
            self.id,
            self.modality.as_deref().unwrap_or("?"),
            self.slices,
            self.size[0],
            self.size[1]
        )?;
        if let Some(d) = &self.description {
            write!(f, "  \"{d}\"")?;
        }
        Ok(())
    }
}

/// The image series found in a folder, headers read.
#[derive(Debug)]
pub struct FolderScan {
    folder: PathBuf,
    stacks: Vec<Stack>,
}

impl FolderScan {
    /// Reads the headers of every file in `folder` (not its subfolders; files
    /// whose names start with a dot are skipped, files without an image are
    /// passed over, any other non-DICOM file is an error).
    pub fn new(folder: &Path) -> Result<FolderScan, Error> {
        let io_err = |source| Error::Io {
            path: folder.to_owned(),
            source,
        };
        let mut files: Vec<PathBuf> = std::fs::read_dir(folder)
            .map_err(io_err)?
            .filter_map(Result::ok)
            .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
            .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
            .map(|e| e.path())
            .collect();
        files.sort();
        let headers: Vec<Option<SliceHeader>> = files
            .par_iter()
            .map(|p| read_header(p))
            .collect::<Result<_, _>>()?;
        let images: Vec<SliceHeader> = headers.into_iter().flatten().collect();
        if images.is_empty() {
            return Err(field(
                folder,
                "images",
                "none found: expected DICOM image files in the folder",
            ));
        }
        Ok(FolderScan {
            folder: folder.to_owned(),
            stacks: group(images),
        })
    }

    /// One line per series.
    pub fn summaries(&self) -> Vec<SeriesSummary> {
        self.stacks.iter().map(FolderScan::summary_of).collect()
    }

    /// Opens the only series, or the one `series` names.
    pub fn open(self, series: Option<&str>) -> Result<DicomSeries, Error> {
        let folder = self.folder;
        let count = self.stacks.len();
        let listing = |stacks: &[Stack]| {
            stacks
                .iter()
                .map(|s| format!("  {}", FolderScan::summary_of(s)))
                .collect::<Vec<_>>()
                .join("\n")
        };
        let stack = match series {
            Some(wanted) => {
                let known: Vec<String> = self.stacks.iter().map(|s| s.id.clone()).collect();
                self.stacks
                    .into_iter()
                    .find(|s| s.id == wanted)
                    .ok_or_else(|| {
                        field(
                            &folder,
                            "--series",
                            format!("'{wanted}': expected one of {}", known.join(", ")),
                        )
                    })?
            }
            None if count == 1 => self
                .stacks
                .into_iter()
                .next()
                .ok_or_else(|| field(&folder, "images", "none found"))?,
            None => {
                return Err(Error::SeveralSeries {
                    path: folder.clone(),
                    count,
                    listing: listing(&self.stacks),
                });
            }
        };
        DicomSeries::new(&folder, stack.slices)
    }

    fn summary_of(stack: &Stack) -> SeriesSummary {
        let first = &stack.slices[0];
        SeriesSummary {
            id: stack.id.clone(),
            modality: first.modality.clone(),
            description: first.series_description.clone(),
            slices: stack.slices.len(),
            size: [first.columns, first.rows],
        }
    }
}

/// Opens the DICOM series in `folder`: the only one, or the one `series` names.
pub fn open_folder(folder: &Path, series: Option<&str>) -> Result<DicomSeries, Error> {
    FolderScan::new(folder)?.open(series)
}

/// Opens a single DICOM file as a one-slice volume.
pub fn open_file(path: &Path) -> Result<DicomSeries, Error> {
    let header = read_header(path)?
        .ok_or_else(|| field(path, "Rows (0028,0010)", "missing: expected an image"))?;
    DicomSeries::new(path, vec![header])
}

/// Groups images by series UID, then by geometry; ids are the UID, or
/// `UID/1`, `UID/2`, … when a series holds several geometries.
fn group(images: Vec<SliceHeader>) -> Vec<Stack> {
    let mut by_series: BTreeMap<String, BTreeMap<String, Vec<SliceHeader>>> = BTreeMap::new();
    for image in images {
        by_series
            .entry(image.series_uid.clone())
            .or_default()
            .entry(image.geometry_key())
            .or_default()
            .push(image);
    }
    let mut stacks = Vec::new();
    for (uid, geometries) in by_series {
        let several = geometries.len() > 1;
        for (i, (_, slices)) in geometries.into_iter().enumerate() {
            let id = if several {
                format!("{uid}/{}", i + 1)
            } else {
                uid.clone()
            };
            stacks.push(Stack { id, slices });
        }
    }
    stacks
}

/// How stored samples become output voxels.
#[derive(Debug, Clone, Copy)]
struct PixelFormat {
    bits_allocated: u16,
    bits_stored: u16,
    high_bit: u16,
    signed: bool,
    monochrome1: bool,
}

impl PixelFormat {
    /// The smallest and largest value BitsStored can hold.
    fn stored_range(&self) -> (i64, i64) {
        let bits = u32::from(self.bits_stored);
        if self.signed {
            (-(1i64 << (bits - 1)), (1i64 << (bits - 1)) - 1)
        } else {
            (0, (1i64 << bits) - 1)
        }
    }

    /// The stored value of the sample at `i` of the decoded bytes: the stored
    /// bits, sign-extended when signed. Returns the value before inversion.
    fn sample(&self, bytes: &[u8], i: usize) -> i64 {
        let raw: u64 = match self.bits_allocated {
            8 => u64::from(bytes[i]),
            16 => u64::from(u16::from_ne_bytes([bytes[2 * i], bytes[2 * i + 1]])),
            _ => u64::from(u32::from_ne_bytes([
                bytes[4 * i],
                bytes[4 * i + 1],
                bytes[4 * i + 2],
                bytes[4 * i + 3],
            ])),
        };
        let bits = u32::from(self.bits_stored);
        let shift = u32::from(self.high_bit + 1).saturating_sub(bits);
        let value = (raw >> shift) & ((1u64 << bits) - 1);
        if self.signed && value & (1 << (bits - 1)) != 0 {
            value as i64 - (1i64 << bits)
        } else {
            value as i64
        }
    }
}

/// A DICOM series as a [`VolumeSource`].
#[derive(Debug)]
pub struct DicomSeries {
    info: VolumeInfo,
    slices: Vec<SliceHeader>,
    format: PixelFormat,
    /// Per-slice rescale to f32, when slices disagree on it.
    rescale_each: bool,
    /// The value padded pixels take, in the output domain.
    padding_replacement: Option<f64>,
}

impl DicomSeries {
    fn new(path: &Path, mut slices: Vec<SliceHeader>) -> Result<DicomSeries, Error> {
        let first = slices[0].clone();
        let mut notes = Vec::new();
        // One pixel format for the whole series.
        for s in &slices {
            let check = |name: &str, a: u64, b: u64| {
                if a == b {
                    Ok(())
                } else {
                    Err(field(
                        &s.path,
                        name,
                        format!("{a}: expected {b} as in {}", first.path.display()),
                    ))
                }
            };
            check(
                "BitsAllocated (0028,0100)",
                s.bits_allocated.into(),
                first.bits_allocated.into(),
            )?;
            check(
                "BitsStored (0028,0101)",
                s.bits_stored.into(),
                first.bits_stored.into(),
            )?;
            check(
                "PixelRepresentation (0028,0103)",
                s.pixel_representation.into(),
                first.pixel_representation.into(),
            )?;
            if s.samples_per_pixel != 1 {
                return Err(field(
                    &s.path,
                    "SamplesPerPixel (0028,0002)",
                    format!("{}: expected 1 (grayscale)", s.samples_per_pixel),
                ));
            }
            if s.frames != 1 {
                return Err(field(
                    &s.path,
                    "NumberOfFrames (0028,0008)",
                    format!(
                        "{}: expected single-frame images (multi-frame objects are not supported yet)",
                        s.frames
                    ),
                ));
            }
        }
        if ![8, 16, 32].contains(&first.bits_allocated) {
            return Err(field(
                &first.path,
                "BitsAllocated (0028,0100)",
                format!("{}: expected 8, 16 or 32", first.bits_allocated),
            ));
        }
        if first.bits_stored == 0
            || first.bits_stored > first.bits_allocated
            || first.high_bit >= first.bits_allocated
        {
            return Err(field(
                &first.path,
                "BitsStored (0028,0101)",
                format!(
                    "{} (HighBit {}): expected 1 to BitsAllocated ({})",
                    first.bits_stored, first.high_bit, first.bits_allocated
                ),
            ));
        }
        let format = PixelFormat {
            bits_allocated: first.bits_allocated,
            bits_stored: first.bits_stored,
            high_bit: first.high_bit,
            signed: first.pixel_representation == 1,
            monochrome1: first.photometric == "MONOCHROME1",
        };
        if format.monochrome1 {
            notes.push("MONOCHROME1: values inverted so that higher is brighter".to_owned());
        }

        let (row_dir, col_dir) = match first.orientation {
            Some(o) => ([o[0], o[1], o[2]], [o[3], o[4], o[5]]),
            None if slices.len() == 1 => {
                notes.push("no ImageOrientationPatient: assumed axial".to_owned());
                ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
            }
            None => {
                return Err(field(
                    &first.path,
                    "ImageOrientationPatient (0020,0037)",
                    "missing: expected it to stack the slices",
                ));
            }
        };
        let normal = cross(row_dir, col_dir);
        if (dot(normal, normal) - 1.0).abs() > 1e-3 {
            return Err(field(
                &first.path,
                "ImageOrientationPatient (0020,0037)",
                format!(
                    "{:?}: expected two orthogonal unit vectors",
                    first.orientation
                ),
            ));
        }
        let [row_spacing, column_spacing] = first.pixel_spacing.unwrap_or_else(|| {
            notes.push("no PixelSpacing: assumed 1 mm".to_owned());
            [1.0, 1.0]
        });
        let (slice_dir, slice_spacing) = if slices.len() == 1 {
            let s = first
                .spacing_between_slices
                .or(first.slice_thickness)
                .unwrap_or(1.0);
            (normal, if s > 0.0 { s } else { 1.0 })
        } else {
            stack_slices(&mut slices, normal, &mut notes)?
        };
        let spacing = [column_spacing, row_spacing, slice_spacing];
        super::check_spacing(&first.path, "PixelSpacing (0028,0030)", spacing)?;
        let dims = check_dims(
            path,
            "Rows, Columns and slices",
            [
                u64::from(first.columns),
                u64::from(first.rows),
                slices.len() as u64,
            ],
            u64::from(first.bits_allocated / 8),
        )?;

        let rescale_each = slices
            .iter()
            .any(|s| s.slope != first.slope || s.intercept != first.intercept);
        let (voxel_type, value_map) = if rescale_each {
            notes.push("RescaleSlope/RescaleIntercept differ between slices: each slice rescaled to physical values (float32)".to_owned());
            (VoxelType::F32, ValueMap::IDENTITY)
        } else {
            let t = match (format.bits_allocated, format.signed) {
                (8, false) => VoxelType::U8,
                (8, true) => VoxelType::I8,
                (16, false) => VoxelType::U16,
                (16, true) => VoxelType::I16,
                (_, false) => VoxelType::U32,
                (_, true) => VoxelType::I32,
            };
            (
                t,
                ValueMap {
                    slope: first.slope as f32,
                    intercept: first.intercept as f32,
                },
            )
        };
        let modality = first.modality.clone();
        let unit = match (&first.rescale_type, modality.as_deref()) {
            (Some(t), _) if t != "US" => Some(t.clone()),
            (_, Some("CT")) => Some("HU".to_owned()),
            (_, Some("PT")) => first.units.clone(),
            _ => None,
        };
        let info = VolumeInfo {
            path: path.to_owned(),
            format: Format::Dicom,
            dims,
            voxel_type,
            spacing,
            // After sorting, slice 0 is the lowest along the stacking direction.
            origin: slices[0].position.unwrap_or([0.0; 3]),
            direction: [row_dir, col_dir, slice_dir],
            value_map,
            unit,
            modality,
            description: first.series_description.clone(),
            notes,
        };
        let mut series = DicomSeries {
            info,
            slices,
            format,
            rescale_each,
            padding_replacement: None,
        };
        if series.slices.iter().any(|s| s.padding.is_some()) {
            series.padding_replacement = Some(series.lowest_unpadded_value()?);
            series.info.notes.push(format!(
                "PixelPaddingValue: padded pixels set to the lowest other value ({})",
                series.padding_replacement.unwrap_or_default()
            ));
        }
        Ok(series)
    }

    /// The SeriesInstanceUID.
    pub fn series_uid(&self) -> &str {
        &self.slices[0].series_uid
    }

    /// The lowest non-padding value of the series in the output domain (one pass
    /// over the pixels, made only for series that declare padding).
    fn lowest_unpadded_value(&self) -> Result<f64, Error> {
        let lows: Vec<f64> = (0..self.slices.len())
            .into_par_iter()
            .map(|i| {
                self.decode(i)
                    .map(|(values, _)| values.into_iter().flatten().fold(f64::INFINITY, f64::min))
            })
            .collect::<Result<_, _>>()?;
        let low = lows.into_iter().fold(f64::INFINITY, f64::min);
        Ok(if low.is_finite() { low } else { 0.0 })
    }

    /// Decodes slice `i` into output-domain values, `None` for padded pixels.
    fn decode(&self, i: usize) -> Result<(Vec<Option<f64>>, usize), Error> {
        let s = &self.slices[i];
        let obj = dicom_object::open_file(&s.path).map_err(|e| {
            field(
                &s.path,
                "file",
                format!("{e}: expected a readable DICOM file"),
            )
        })?;
        let syntax = obj
            .meta()
            .transfer_syntax()
            .trim_end_matches('\0')
            .to_owned();
        let decoded = obj.decode_pixel_data().map_err(|e| Error::Corrupt {
            path: s.path.clone(),
            codec: format!("pixel data (transfer syntax {syntax})"),
            detail: e.to_string(),
        })?;
        let count = s.rows as usize * s.columns as usize;
        let bytes = decoded.data();
        let needed = count * usize::from(self.format.bits_allocated / 8);
        if bytes.len() < needed {
            return Err(Error::Truncated {
                path: s.path.clone(),
                expected: needed as u64,
                got: bytes.len() as u64,
            });
        }
        let (smin, smax) = self.format.stored_range();
        let values = (0..count)
            .map(|p| {
                let stored = self.format.sample(bytes, p);
                if s.padding
                    .is_some_and(|(lo, hi)| (lo..=hi).contains(&stored))
                {
                    return None;
                }
                let v = if self.format.monochrome1 {
                    smin + smax - stored
                } else {
                    stored
                };
                Some(if self.rescale_each {
                    v as f64 * s.slope + s.intercept
                } else {
                    v as f64
                })
            })
            .collect();
        Ok((values, count))
    }

    /// Slice `i` as output voxels.
    fn slice(&self, i: usize) -> Result<VoxelData, Error> {
        let (values, _) = self.decode(i)?;
        let fill = self.padding_replacement.unwrap_or(0.0);
        let v = values.into_iter().map(|v| v.unwrap_or(fill));
        // Values fit their type: they come from that many stored bits.
        Ok(match self.info.voxel_type {
            VoxelType::U8 => VoxelData::U8(v.map(|x| x as u8).collect()),
            VoxelType::I8 => VoxelData::I8(v.map(|x| x as i8).collect()),
            VoxelType::U16 => VoxelData::U16(v.map(|x| x as u16).collect()),
            VoxelType::I16 => VoxelData::I16(v.map(|x| x as i16).collect()),
            VoxelType::U32 => VoxelData::U32(v.map(|x| x as u32).collect()),
            VoxelType::I32 => VoxelData::I32(v.map(|x| x as i32).collect()),
            VoxelType::F32 => VoxelData::F32(v.map(|x| x as f32).collect()),
        })
    }
}

impl VolumeSource for DicomSeries {
    fn info(&self) -> &VolumeInfo {
        &self.info
    }

    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<VoxelData, Error> {
        super::check_slab(&self.info, z0, depth)?;
        let slices: Vec<VoxelData> = (z0..z0 + depth)
            .into_par_iter()
            .map(|z| self.slice(z as usize))
            .collect::<Result<_, _>>()?;
        let mut out = VoxelData::zeros(self.info.voxel_type, 0);
        for s in slices {
            out.append(s)?;
        }
        Ok(out)
    }
}

/// Sorts `slices` along `normal`, checks their spacing, and returns the stacking
/// direction and slice spacing (a sheared direction when the gantry is tilted).
fn stack_slices(
    slices: &mut [SliceHeader],
    normal: [f64; 3],
    notes: &mut Vec<String>,
) -> Result<([f64; 3], f64), Error> {
    for s in slices.iter() {
        if s.position.is_none() {
            return Err(field(
                &s.path,
                "ImagePositionPatient (0020,0032)",
                "missing: expected it on every slice to place the slice",
            ));
        }
    }
    let at = |s: &SliceHeader| dot(s.position.unwrap_or_default(), normal);
    slices.sort_by(|a, b| at(a).total_cmp(&at(b)));
    let distances: Vec<f64> = slices.windows(2).map(|w| at(&w[1]) - at(&w[0])).collect();
    let mut sorted = distances.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    for (w, d) in slices.windows(2).zip(&distances) {
        let (a, b) = (&w[0], &w[1]);
        let place = |s: &SliceHeader| format!("{} (at {:.3} mm)", s.path.display(), at(s));
        if *d < 1e-3 {
            return Err(field(
                &b.path,
                "ImagePositionPatient (0020,0032)",
                format!(
                    "same position as {}: expected one slice per position (duplicates or repeated acquisitions)",
                    place(a)
                ),
            ));
        }
        if (d - median).abs() > SPACING_TOLERANCE * median {
            let missing = (d / median).round() - 1.0;
            let message = if missing >= 1.0 {
                format!(
                    "missing slice: from {} to {} the gap is {d:.3} mm, expected {median:.3} mm (about {missing} slice(s) missing)",
                    place(a),
                    place(b)
                )
            } else {
                format!(
                    "uneven slice spacing: from {} to {} the gap is {d:.3} mm, expected {median:.3} mm ± {}%",
                    place(a),
                    place(b),
                    SPACING_TOLERANCE * 100.0
                )
            };
            return Err(field(&b.path, "ImagePositionPatient (0020,0032)", message));
        }
    }
    let (first, last) = (
        slices[0].position.unwrap_or_default(),
        slices[slices.len() - 1].position.unwrap_or_default(),
    );
    let steps = (slices.len() - 1) as f64;
    let step = [0, 1, 2].map(|i| (last[i] - first[i]) / steps);
    let length = dot(step, step).sqrt();
    let along = dot(step, normal) / length;
    if along < 1.0 - TILT_TOLERANCE {
        let angle = along.clamp(-1.0, 1.0).acos().to_degrees();
        notes.push(format!(
            "gantry tilt of {angle:.2}°: slices are stacked {length:.3} mm apart along a direction \
             {angle:.2}° off their normal; kept as a sheared affine"
        ));
        Ok((step.map(|x| x / length), length))
    } else {
        Ok((normal, median))
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn format(bits_stored: u16, signed: bool) -> PixelFormat {
        PixelFormat {
            bits_allocated: 16,
            bits_stored,
            high_bit: bits_stored - 1,
            signed,
            monochrome1: false,
        }
    }

    #[test]
    fn stored_bits_are_masked_and_sign_extended() {
        // 12 stored bits in 16: 0x0FFF is -1 when signed, 4095 when not; high bits ignored.
        let bytes = 0xF_FFFu16.to_ne_bytes();
        assert_eq!(format(12, true).sample(&bytes, 0), -1);
        assert_eq!(format(12, false).sample(&bytes, 0), 4095);
        let bytes = 0x0800u16.to_ne_bytes();
        assert_eq!(format(12, true).sample(&bytes, 0), -2048);
        assert_eq!(format(12, true).stored_range(), (-2048, 2047));
        assert_eq!(format(16, false).stored_range(), (0, 65535));
    }
}
