//! Headerless raw volumes: dimensions, type and byte order come from the command
//! line ([`RawOptions`]) or from a file name like `engine_256x256x128_uint8.raw`
//! or `cthead_256x256x113_uint16be.raw` (`be`/`le` after the type give the byte
//! order; little-endian otherwise). Spacing comes from the command line or is
//! taken as 1 mm.

use std::path::Path;

use super::header::field;
use super::stream::{Compression, SampleType, StreamLayout, StreamSource};
use super::{Format, IDENTITY, VolumeInfo, check_dims, check_spacing};
use crate::{Error, ValueMap, VoxelType};

/// The layout of a raw file, as given on the command line.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RawOptions {
    /// Voxels along x, y, z.
    pub dims: Option<[u64; 3]>,
    /// The sample type.
    pub sample: Option<SampleType>,
    /// Byte order of multi-byte samples.
    pub big_endian: Option<bool>,
    /// Bytes to skip at the start of the file (a header voxserve does not read).
    pub offset: u64,
    /// Voxel spacing, mm.
    pub spacing: Option<[f64; 3]>,
}

impl RawOptions {
    /// Whether any part of the layout was given (so the input is raw whatever its name).
    pub fn is_given(&self) -> bool {
        self.dims.is_some() || self.sample.is_some()
    }
}

/// A sample type by its name: the voxel type names (`uint8` … `float32`, `float`)
/// and `float64`/`double`.
pub fn sample_type(name: &str) -> Option<SampleType> {
    match name {
        "float64" | "double" => Some(SampleType::F64),
        _ => VoxelType::from_name(name).map(SampleType::Voxel),
    }
}

/// The names [`sample_type`] accepts, for messages.
pub const SAMPLE_NAMES: &str = "uint8, int8, uint16, int16, uint32, int32, float32, float64";

/// What a file name says: dimensions, sample type and byte order, e.g.
/// `engine_256x256x128_uint8.raw` → ([256, 256, 128], uint8, None).
pub fn parse_name(name: &str) -> Option<([u64; 3], SampleType, Option<bool>)> {
    let stem = name.rsplit_once('.').map_or(name, |(s, _)| s);
    let mut dims = None;
    let mut sample = None;
    for token in stem.split(['_', '-', '.']) {
        let parts: Vec<&str> = token.split('x').collect();
        if parts.len() == 3
            && let (Ok(x), Ok(y), Ok(z)) = (parts[0].parse(), parts[1].parse(), parts[2].parse())
        {
            dims = Some([x, y, z]);
            continue;
        }
        let lower = token.to_ascii_lowercase();
        let (base, endian) = match lower.strip_suffix("be") {
            Some(b) if sample_type(b).is_some() => (b.to_owned(), Some(true)),
            _ => match lower.strip_suffix("le") {
                Some(b) if sample_type(b).is_some() => (b.to_owned(), Some(false)),
                _ => (lower.clone(), None),
            },
        };
        if let Some(t) = sample_type(&base) {
            sample = Some((t, endian));
        }
    }
    let (sample, endian) = sample?;
    Some((dims?, sample, endian))
}

/// Opens a raw file with `options`, filling gaps from the file name.
pub fn open(path: &Path, options: &RawOptions) -> Result<StreamSource, Error> {
    let mut notes = Vec::new();
    let layout = Layout::resolve(path, options, &mut notes)?;
    let spacing = options.spacing.unwrap_or_else(|| {
        notes.push("spacing not given: assumed 1 mm on every axis".to_owned());
        [1.0; 3]
    });
    check_spacing(path, "spacing", spacing)?;
    let dims = check_dims(path, "dims", layout.dims, layout.sample.size() as u64)?;
    check_size(path, options.offset, dims, layout.sample)?;
    let info = VolumeInfo {
        path: path.to_owned(),
        format: Format::Raw,
        dims,
        voxel_type: layout.sample.voxel_type(),
        spacing,
        origin: [0.0; 3],
        direction: IDENTITY,
        value_map: ValueMap::IDENTITY,
        unit: None,
        modality: None,
        description: None,
        notes,
    };
    StreamSource::new(
        info,
        StreamLayout {
            data_path: path.to_owned(),
            compression: Compression::None,
            file_offset: options.offset,
            skip: 0,
            sample: layout.sample,
            big_endian: layout.big_endian,
        },
    )
}

/// Dimensions, sample type and byte order: from the options, else from the
/// file name.
struct Layout {
    dims: [u64; 3],
    sample: SampleType,
    big_endian: bool,
}

impl Layout {
    /// Refuses a file whose dimensions or type neither the options nor the name
    /// give; an unknown byte order of multi-byte samples is taken as
    /// little-endian, with a note.
    fn resolve(
        path: &Path,
        options: &RawOptions,
        notes: &mut Vec<String>,
    ) -> Result<Layout, Error> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let from_name = parse_name(&name);
        let dims = options.dims.or(from_name.map(|n| n.0)).ok_or_else(|| {
            field(
                path,
                "dims",
                "not given: expected --raw-dims XxYxZ or a file name like volume_256x256x128_uint8.raw",
            )
        })?;
        let sample = options
            .sample
            .or(from_name.map(|n| n.1))
            .ok_or_else(|| {
                field(
                    path,
                    "type",
                    format!("not given: expected --raw-type (one of {SAMPLE_NAMES}) or the type in the file name"),
                )
            })?;
        let big_endian = match options.big_endian.or(from_name.and_then(|n| n.2)) {
            Some(b) => b,
            None => {
                if sample.size() > 1 {
                    notes.push("byte order not given: assumed little-endian".to_owned());
                }
                false
            }
        };
        Ok(Layout {
            dims,
            sample,
            big_endian,
        })
    }
}

/// Checks that the file holds exactly the voxels after the header offset: a
/// raw file has nothing else to tell a wrong layout by.
fn check_size(path: &Path, offset: u64, dims: [u32; 3], sample: SampleType) -> Result<(), Error> {
    let size = super::header::file_len(path)?;
    let needed = super::stream::volume_bytes(dims, sample);
    let available = size.saturating_sub(offset);
    if available != needed {
        return Err(field(
            path,
            "size",
            format!(
                "{available} bytes after a {offset}-byte header offset, but {} × {} × {} voxels of \
                 {} bytes take {needed}: expected the file size to match (check dims, type and \
                 header offset)",
                dims[0],
                dims[1],
                dims[2],
                sample.size()
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_give_dims_type_and_byte_order() {
        assert_eq!(
            parse_name("engine_256x256x128_uint8.raw"),
            Some(([256, 256, 128], SampleType::Voxel(VoxelType::U8), None))
        );
        assert_eq!(
            parse_name("cthead_256x256x113_uint16be.raw"),
            Some((
                [256, 256, 113],
                SampleType::Voxel(VoxelType::U16),
                Some(true)
            ))
        );
        assert_eq!(
            parse_name("walnut_128x96x114_uint16le.raw"),
            Some((
                [128, 96, 114],
                SampleType::Voxel(VoxelType::U16),
                Some(false)
            ))
        );
        assert_eq!(
            parse_name("sim-64x64x64-float64.raw"),
            Some(([64, 64, 64], SampleType::F64, None))
        );
        assert_eq!(parse_name("volume.raw"), None);
        assert_eq!(parse_name("scan_12x12_uint8.raw"), None);
    }
}
