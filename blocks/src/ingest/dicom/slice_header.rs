//! What one DICOM file's header says: [`SliceHeader`], read up to the pixel
//! data, with the attributes grouping, placing and decoding a slice need.

use std::path::{Path, PathBuf};

use dicom_core::Tag;
use dicom_dictionary_std::tags;
use dicom_object::{DefaultDicomObject, InMemDicomObject, OpenFileOptions};

use crate::Error;
use crate::ingest::boundary;
use crate::ingest::header::{field, read_prefix};

/// What one file's header says, read up to the pixel data.
#[derive(Debug, Clone)]
pub(super) struct SliceHeader {
    pub(super) path: PathBuf,
    /// The frame of the file (0 for single-frame images).
    pub(super) frame: u32,
    pub(super) series_uid: String,
    pub(super) series_description: Option<String>,
    pub(super) patient_name: Option<String>,
    pub(super) patient_id: Option<String>,
    pub(super) patient_birth_date: Option<String>,
    pub(super) study_date: Option<String>,
    pub(super) study_description: Option<String>,
    pub(super) modality: Option<String>,
    pub(super) rows: u32,
    pub(super) columns: u32,
    /// Row direction (x) then column direction (y), LPS.
    pub(super) orientation: Option<[f64; 6]>,
    pub(super) position: Option<[f64; 3]>,
    /// Spacing between rows (y), then between columns (x).
    pub(super) pixel_spacing: Option<[f64; 2]>,
    pub(super) slice_thickness: Option<f64>,
    pub(super) spacing_between_slices: Option<f64>,
    pub(super) bits_allocated: u16,
    pub(super) bits_stored: u16,
    pub(super) high_bit: u16,
    pub(super) pixel_representation: u16,
    pub(super) samples_per_pixel: u16,
    pub(super) photometric: String,
    /// Frames in the file.
    pub(super) frames: u32,
    pub(super) slope: f64,
    pub(super) intercept: f64,
    pub(super) padding: Option<(i64, i64)>,
    pub(super) rescale_type: Option<String>,
    pub(super) units: Option<String>,
}

impl SliceHeader {
    /// The file, and the frame of a multi-frame image, for messages.
    pub(super) fn label(&self) -> String {
        if self.frames > 1 {
            format!("{} (frame {})", self.path.display(), self.frame + 1)
        } else {
            self.path.display().to_string()
        }
    }

    /// The key that splits a series into stacks of one geometry.
    pub(super) fn geometry_key(&self) -> String {
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

/// Whether `path` has the `DICM` marker at byte 128 of a DICOM file.
pub(super) fn has_dicom_marker(path: &Path) -> Result<bool, Error> {
    Ok(read_prefix(path, 132)?.get(128..132) == Some(b"DICM"))
}

/// The UIDs that file a DICOM instance: its study, series, SOP class and
/// SOP instance.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InstanceUids {
    /// StudyInstanceUID.
    pub study: String,
    /// SeriesInstanceUID.
    pub series: String,
    /// SOPClassUID, when given.
    pub class: Option<String>,
    /// SOPInstanceUID.
    pub instance: String,
}

/// The header of the DICOM file `path`, up to the pixel data: its `DICM`
/// marker checked (`hint` ends the message when it is missing), then its
/// element lengths against the file, then read inside the panic boundary.
fn open_header(path: &Path, hint: &str) -> Result<DefaultDicomObject, Error> {
    if !has_dicom_marker(path)? {
        return Err(field(
            path,
            "preamble",
            format!("no 'DICM' marker at byte 128: expected a DICOM file{hint}"),
        ));
    }
    boundary::guard(path, "DICOM header", || {
        super::bounds::check_lengths(path, true)?;
        OpenFileOptions::new()
            .read_until(tags::PIXEL_DATA)
            .open_file(path)
            .map_err(|e| {
                field(
                    path,
                    "header",
                    format!("{e}: expected a readable DICOM file"),
                )
            })
    })
}

/// Whether `text` is a DICOM UID (PS3.5 §9.1): at most 64 characters,
/// numbers joined by single dots (leading zeros, which the standard forbids
/// and some devices write, are let through). So a UID is never `.`, `..`
/// or empty, and is safe as a file or folder name.
pub fn is_uid(text: &str) -> bool {
    !text.is_empty()
        && text.len() <= 64
        && text
            .split('.')
            .all(|part| !part.is_empty() && part.bytes().all(|b| b.is_ascii_digit()))
}

/// The UIDs of the instance in `path` (its header only, element lengths
/// checked first, inside the panic boundary): each present and a valid UID
/// (1 to 64 digits and dots), SOPClassUID where given.
pub fn instance_uids(path: &Path) -> Result<InstanceUids, Error> {
    let obj = open_header(path, "")?;
    let uid = |tag: Tag, name: &str| -> Result<String, Error> {
        let value = text(&obj, tag)
            .map(|s| s.trim_end_matches('\0').to_owned())
            .ok_or_else(|| field(path, name, "missing: expected a UID"))?;
        if !is_uid(&value) {
            return Err(field(
                path,
                name,
                format!(
                    "{value:?}: expected a UID (numbers joined by dots, at most 64 characters)"
                ),
            ));
        }
        Ok(value)
    };
    Ok(InstanceUids {
        study: uid(tags::STUDY_INSTANCE_UID, "StudyInstanceUID (0020,000D)")?,
        series: uid(tags::SERIES_INSTANCE_UID, "SeriesInstanceUID (0020,000E)")?,
        class: uid(tags::SOP_CLASS_UID, "SOPClassUID (0008,0016)").ok(),
        instance: uid(tags::SOP_INSTANCE_UID, "SOPInstanceUID (0008,0018)")?,
    })
}

/// Most frames of one multi-frame image.
pub const MAX_FRAMES: u32 = 65_536;

/// Reads the header of one file (up to the pixel data): one [`SliceHeader`]
/// per frame (an enhanced multi-frame image gives one per frame, placed by
/// its functional groups), none for a file without an image.
pub(super) fn read_header(path: &Path) -> Result<Vec<SliceHeader>, Error> {
    let obj = open_header(path, " (move other files out of the series folder)")?;
    let Some(rows) = opt_int::<u32>(&obj, tags::ROWS) else {
        return Ok(Vec::new()); // no image: DICOMDIR, structured report, …
    };
    let series_uid = text(&obj, tags::SERIES_INSTANCE_UID).ok_or_else(|| {
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
    let frames = opt_int::<u32>(&obj, tags::NUMBER_OF_FRAMES)
        .unwrap_or(1)
        .max(1);
    if frames > MAX_FRAMES {
        return Err(field(
            path,
            "NumberOfFrames (0028,0008)",
            format!("{frames}: expected at most {MAX_FRAMES}"),
        ));
    }
    // Enhanced multi-frame images (PS3.3 C.7.6.16): what holds for every
    // frame in the shared functional groups, the rest per frame.
    let shared = items(&obj, tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE).first();
    let per_frame = items(&obj, tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE);
    if frames > 1 && per_frame.len() != frames as usize {
        return Err(field(
            path,
            "PerFrameFunctionalGroupsSequence (5200,9230)",
            format!(
                "{} items for {frames} frames: expected an enhanced multi-frame image, one item per frame placing it",
                per_frame.len()
            ),
        ));
    }
    let first = SliceHeader {
        path: path.to_owned(),
        frame: 0,
        series_uid,
        series_description: text(&obj, tags::SERIES_DESCRIPTION),
        patient_name: text(&obj, tags::PATIENT_NAME),
        patient_id: text(&obj, tags::PATIENT_ID),
        patient_birth_date: text(&obj, tags::PATIENT_BIRTH_DATE),
        study_date: text(&obj, tags::STUDY_DATE),
        study_description: text(&obj, tags::STUDY_DESCRIPTION),
        modality: text(&obj, tags::MODALITY),
        rows,
        columns: opt_int(&obj, tags::COLUMNS).unwrap_or(0),
        orientation: None,
        position: None,
        pixel_spacing: None,
        slice_thickness: None,
        spacing_between_slices: None,
        bits_allocated: opt_int(&obj, tags::BITS_ALLOCATED).unwrap_or(16),
        bits_stored: opt_int(&obj, tags::BITS_STORED).unwrap_or(16),
        high_bit: opt_int(&obj, tags::HIGH_BIT).unwrap_or(15),
        pixel_representation: opt_int(&obj, tags::PIXEL_REPRESENTATION).unwrap_or(0),
        samples_per_pixel: opt_int(&obj, tags::SAMPLES_PER_PIXEL).unwrap_or(1),
        photometric: text(&obj, tags::PHOTOMETRIC_INTERPRETATION)
            .unwrap_or_else(|| "MONOCHROME2".into()),
        frames,
        slope: 1.0,
        intercept: 0.0,
        padding,
        rescale_type: None,
        units: text(&obj, tags::UNITS),
    };
    Ok((0..frames)
        .map(|frame| {
            // Where an attribute is: in this frame's functional group
            // `group`, else in the shared one, else at the top level.
            let groups = [per_frame.get(frame as usize), shared];
            let find = |group: Tag, tag: Tag| {
                groups
                    .iter()
                    .flatten()
                    .find_map(|g| items(g, group).first().and_then(|i| fixed(i, tag)))
                    .or_else(|| fixed(&obj, tag))
            };
            let n = |v: Option<Vec<f64>>, len: usize| v.filter(|v| v.len() == len);
            let measures = tags::PIXEL_MEASURES_SEQUENCE;
            let transformation = tags::PIXEL_VALUE_TRANSFORMATION_SEQUENCE;
            let rescale_type = groups
                .iter()
                .flatten()
                .find_map(|g| {
                    items(g, transformation)
                        .first()
                        .and_then(|i| text(i, tags::RESCALE_TYPE))
                })
                .or_else(|| text(&obj, tags::RESCALE_TYPE));
            SliceHeader {
                frame,
                orientation: n(
                    find(
                        tags::PLANE_ORIENTATION_SEQUENCE,
                        tags::IMAGE_ORIENTATION_PATIENT,
                    ),
                    6,
                )
                .map(|v| [v[0], v[1], v[2], v[3], v[4], v[5]]),
                position: n(
                    find(tags::PLANE_POSITION_SEQUENCE, tags::IMAGE_POSITION_PATIENT),
                    3,
                )
                .map(|v| [v[0], v[1], v[2]]),
                pixel_spacing: n(find(measures, tags::PIXEL_SPACING), 2).map(|v| [v[0], v[1]]),
                slice_thickness: n(find(measures, tags::SLICE_THICKNESS), 1).map(|v| v[0]),
                spacing_between_slices: n(find(measures, tags::SPACING_BETWEEN_SLICES), 1)
                    .map(|v| v[0]),
                slope: n(find(transformation, tags::RESCALE_SLOPE), 1).map_or(1.0, |v| v[0]),
                intercept: n(find(transformation, tags::RESCALE_INTERCEPT), 1)
                    .map_or(0.0, |v| v[0]),
                rescale_type,
                ..first.clone()
            }
        })
        .collect())
}

/// The items of sequence `tag` (none when absent or not a sequence).
fn items(obj: &InMemDicomObject, tag: Tag) -> &[InMemDicomObject] {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.items())
        .unwrap_or(&[])
}

/// A text attribute, trimmed; `None` when absent or empty.
fn text(obj: &InMemDicomObject, tag: Tag) -> Option<String> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim().to_owned())
        .filter(|s| !s.is_empty())
}

/// A numeric attribute's values, all finite.
fn fixed(obj: &InMemDicomObject, tag: Tag) -> Option<Vec<f64>> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_multi_float64().ok())
        .filter(|v| v.iter().all(|x| x.is_finite()))
}

/// An integer attribute, or `None` when absent or not an integer.
fn opt_int<T: DicomInt>(obj: &InMemDicomObject, tag: Tag) -> Option<T> {
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
