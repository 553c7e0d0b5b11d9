//! NIfTI-1: `.nii` (header and data in one file), `.nii.gz`, and `.hdr`/`.img`
//! pairs. The header is read by the `nifti` crate; the voxels stream through
//! [`StreamSource`].
//!
//! Geometry follows the standard's preference: the sform when `sform_code > 0`,
//! else the qform (quaternion) when `qform_code > 0`, else the voxel sizes alone.
//! NIfTI world space is RAS; it is converted to LPS. Spatial units (m, mm, µm)
//! become mm. `scl_slope`/`scl_inter` become the value map (a slope of 0 or NaN
//! means no scaling, as the standard says).

use std::io::BufReader;
use std::path::{Path, PathBuf};

use flate2::bufread::MultiGzDecoder;

use super::header::{data_file, field, open_file};
use super::stream::{Compression, SampleType, StreamLayout, StreamSource};
use super::{
    Format, ORTHONORMAL_TOLERANCE, VolumeInfo, check_dims, check_orthonormal, check_value_map,
};
use crate::geometry::{GeometryFields, spacing_and_direction};
use crate::{Error, Geometry, ValueMap, VoxelType};

/// The size of a NIfTI-1 header plus the 4-byte extension flag: the smallest
/// valid `vox_offset` of a single-file dataset.
const MIN_SINGLE_FILE_OFFSET: u64 = 352;

fn sample_type(datatype: i16) -> Option<SampleType> {
    let t = match datatype {
        2 => VoxelType::U8,
        4 => VoxelType::I16,
        8 => VoxelType::I32,
        16 => VoxelType::F32,
        64 => return Some(SampleType::F64),
        256 => VoxelType::I8,
        512 => VoxelType::U16,
        768 => VoxelType::U32,
        _ => return None,
    };
    Some(SampleType::Voxel(t))
}

fn datatype_name(datatype: i16) -> &'static str {
    match datatype {
        1 => "binary",
        32 => "complex64",
        128 => "rgb24",
        1024 => "int64",
        1280 => "uint64",
        1536 => "float128",
        1792 => "complex128",
        2048 => "complex256",
        2304 => "rgba32",
        _ => "unknown",
    }
}

fn is_gzip(path: &Path) -> Result<bool, Error> {
    Ok(super::header::read_prefix(path, 2)? == [0x1f, 0x8b])
}

/// Opens a NIfTI-1 dataset; the `.img` of a pair must lie in the header's
/// folder unless `allow_data_outside`.
pub fn open(path: &Path, allow_data_outside: bool) -> Result<StreamSource, Error> {
    let (h, gz) = read_header(path)?;
    let shape = Shape::read(path, &h)?;
    let mut notes = Vec::new();
    let geometry = read_geometry(path, &h, &shape, &mut notes)?;
    let value_map = value_map(&h);
    check_value_map(
        path,
        "scl_slope and scl_inter",
        value_map,
        shape.sample.voxel_type(),
    )?;
    let data = DataLocation::read(path, &h, gz, allow_data_outside, &mut notes)?;
    let description = String::from_utf8_lossy(&h.descrip)
        .trim_matches(char::from(0))
        .trim()
        .to_owned();
    let info = VolumeInfo {
        path: path.to_owned(),
        format: Format::Nifti,
        geometry,
        voxel_type: shape.sample.voxel_type(),
        value_map,
        unit: None,
        modality: None,
        description: (!description.is_empty()).then_some(description),
        study: crate::ingest::Study::default(),
        notes,
    };
    StreamSource::new(
        info,
        StreamLayout {
            data_path: data.path,
            compression: data.compression,
            file_offset: data.file_offset,
            skip: data.skip,
            sample: shape.sample,
            big_endian: h.endianness == nifti::Endianness::Big,
        },
    )
}

/// Reads the header with the `nifti` crate, through gzip when the file starts
/// with gzip's magic; says whether it did.
fn read_header(path: &Path) -> Result<(nifti::NiftiHeader, bool), Error> {
    let gz = is_gzip(path)?;
    let file = BufReader::new(open_file(path)?);
    let parsed = if gz {
        nifti::NiftiHeader::from_reader(MultiGzDecoder::new(file))
    } else {
        nifti::NiftiHeader::from_reader(file)
    };
    let h = parsed.map_err(|e| match e {
        nifti::NiftiError::Io(source) if gz => Error::Corrupt {
            path: path.to_owned(),
            codec: "gzip".into(),
            detail: source.to_string(),
        },
        nifti::NiftiError::Io(source) if source.kind() == std::io::ErrorKind::UnexpectedEof => {
            field(
                path,
                "header",
                "the file ends before the header does: expected a 348-byte NIfTI-1 header",
            )
        }
        nifti::NiftiError::Io(source) => Error::Io {
            path: path.to_owned(),
            source,
        },
        other => field(
            path,
            "header",
            format!("{other}: expected a NIfTI-1 header"),
        ),
    })?;
    Ok((h, gz))
}

/// The sample type and the dimensions of the one 3D volume a header describes.
struct Shape {
    sample: SampleType,
    /// `dim[0]`: how many of `dim[1..]` count.
    rank: usize,
    dims: [u32; 3],
}

impl Shape {
    fn read(path: &Path, h: &nifti::NiftiHeader) -> Result<Shape, Error> {
        let sample = sample_type(h.datatype).ok_or_else(|| {
            field(
                path,
                "datatype",
                format!(
                    "{} ({}): expected uint8 (2), int16 (4), int32 (8), float32 (16), float64 (64), \
                     int8 (256), uint16 (512) or uint32 (768)",
                    h.datatype,
                    datatype_name(h.datatype)
                ),
            )
        })?;
        let rank = usize::from(h.dim[0]);
        if !(1..=7).contains(&rank) {
            return Err(field(
                path,
                "dim[0]",
                format!("{rank}: expected 1 to 7 dimensions"),
            ));
        }
        let extra: u64 = h.dim[4..=rank.max(3)]
            .iter()
            .map(|&d| u64::from(d.max(1)))
            .product();
        if rank > 3 && extra > 1 {
            return Err(field(
                path,
                "dim",
                format!(
                    "{:?}: {extra} volumes: expected a single 3D volume",
                    &h.dim[1..=rank]
                ),
            ));
        }
        let size = |i: usize| if i <= rank { u64::from(h.dim[i]) } else { 1 };
        let dims = check_dims(
            path,
            "dim",
            [size(1), size(2), size(3)],
            sample.size() as u64,
        )?;
        Ok(Shape { sample, rank, dims })
    }
}

/// The geometry of the header's affine (see [`affine_ras`]) for a volume of
/// `shape`, converted from RAS in the header's unit to LPS in mm, and checked.
fn read_geometry(
    path: &Path,
    h: &nifti::NiftiHeader,
    shape: &Shape,
    notes: &mut Vec<String>,
) -> Result<Geometry, Error> {
    let unit_to_mm = unit_to_mm(h, notes);
    if h.sform_code <= 0 && h.qform_code > 0 {
        check_quaternion(path, h)?;
    }
    let (columns, origin_ras) = affine_ras(h, shape.rank, notes);
    // RAS → LPS: negate x and y; then units → mm.
    let to_lps = |v: [f64; 3]| [-v[0] * unit_to_mm, -v[1] * unit_to_mm, v[2] * unit_to_mm];
    let (spacing, direction) = spacing_and_direction(columns.map(to_lps));
    let affine_field = if h.sform_code > 0 { "srow" } else { "pixdim" };
    let geometry = Geometry {
        dims: shape.dims,
        spacing,
        origin: to_lps(origin_ras),
        direction,
    }
    .checked(
        path,
        &GeometryFields {
            dims: "dim",
            spacing: affine_field,
            origin: "qoffset or srow",
            direction: affine_field,
        },
    )?;
    let direction_field = if h.sform_code > 0 {
        "srow_x, srow_y, srow_z"
    } else {
        "quatern_b, quatern_c, quatern_d"
    };
    check_orthonormal(path, direction_field, geometry.direction)?;
    Ok(geometry)
}

/// Checks the qform quaternion (b, c, d): finite, and b² + c² + d² at most 1
/// (the standard allows rounding just above 1, which
/// [`ORTHONORMAL_TOLERANCE`] covers): a larger one is no rotation.
fn check_quaternion(path: &Path, h: &nifti::NiftiHeader) -> Result<(), Error> {
    let [b, c, d] = [h.quatern_b, h.quatern_c, h.quatern_d].map(f64::from);
    let norm = b * b + c * c + d * d;
    if norm.is_finite() && norm <= 1.0 + ORTHONORMAL_TOLERANCE {
        return Ok(());
    }
    Err(field(
        path,
        "quatern_b, quatern_c, quatern_d",
        format!(
            "({b}, {c}, {d}): b² + c² + d² = {norm}: expected at most 1 (a unit quaternion, \
             within {ORTHONORMAL_TOLERANCE})"
        ),
    ))
}

/// Millimetres per spatial unit of `xyzt_units` (mm, with a note, when unset).
fn unit_to_mm(h: &nifti::NiftiHeader, notes: &mut Vec<String>) -> f64 {
    match h.xyzt_units & 0x07 {
        1 => 1000.0,
        3 => 0.001,
        2 => 1.0,
        _ => {
            notes.push("spatial unit not given: assumed mm".to_owned());
            1.0
        }
    }
}

/// The affine's columns (index axes scaled by the voxel size) and its origin, in
/// RAS and the header's unit, as the standard prefers: the sform when
/// `sform_code > 0`, else the qform, else the voxel sizes alone.
fn affine_ras(
    h: &nifti::NiftiHeader,
    rank: usize,
    notes: &mut Vec<String>,
) -> ([[f64; 3]; 3], [f64; 3]) {
    let pixdim = |i: usize| {
        if i <= rank {
            f64::from(h.pixdim[i]).abs()
        } else {
            1.0
        }
    };
    if h.sform_code > 0 {
        let rows = [h.srow_x, h.srow_y, h.srow_z].map(|r| r.map(f64::from));
        let columns = [0, 1, 2].map(|c| [rows[0][c], rows[1][c], rows[2][c]]);
        (columns, [rows[0][3], rows[1][3], rows[2][3]])
    } else if h.qform_code > 0 {
        let r = quaternion_rotation(
            f64::from(h.quatern_b),
            f64::from(h.quatern_c),
            f64::from(h.quatern_d),
        );
        let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let scale = [pixdim(1), pixdim(2), pixdim(3) * qfac];
        let columns =
            [0, 1, 2].map(|c| [r[0][c] * scale[c], r[1][c] * scale[c], r[2][c] * scale[c]]);
        (
            columns,
            [h.quatern_x, h.quatern_y, h.quatern_z].map(f64::from),
        )
    } else {
        notes.push("no sform or qform: orientation unknown, index axes taken as RAS".to_owned());
        (
            [
                [pixdim(1), 0.0, 0.0],
                [0.0, pixdim(2), 0.0],
                [0.0, 0.0, pixdim(3)],
            ],
            [0.0; 3],
        )
    }
}

/// `scl_slope`/`scl_inter` as a value map; a slope of 0 or NaN means no scaling,
/// as the standard says. Anything else is taken as given, for
/// [`check_value_map`] to judge (an infinite slope is refused, not ignored).
fn value_map(h: &nifti::NiftiHeader) -> ValueMap {
    if h.scl_slope.is_nan() || h.scl_slope == 0.0 {
        ValueMap::IDENTITY
    } else {
        ValueMap {
            slope: h.scl_slope,
            intercept: h.scl_inter,
        }
    }
}

/// Where the voxels are: this file after `vox_offset`, or the `.img` of a pair.
struct DataLocation {
    path: PathBuf,
    compression: Compression,
    /// Where the (possibly compressed) stream starts in the file.
    file_offset: u64,
    /// Bytes of the decompressed stream before the first voxel.
    skip: u64,
}

impl DataLocation {
    /// `gz` says whether the header file is gzip-compressed. A single file's
    /// `vox_offset` below the header's end is corrected, with a note.
    fn read(
        path: &Path,
        h: &nifti::NiftiHeader,
        gz: bool,
        allow_outside: bool,
        notes: &mut Vec<String>,
    ) -> Result<DataLocation, Error> {
        let magic = &h.magic[..3];
        let vox_offset = f64::from(h.vox_offset);
        if !(vox_offset.is_finite() && vox_offset >= 0.0 && vox_offset.fract() == 0.0) {
            return Err(field(
                path,
                "vox_offset",
                format!("{vox_offset}: expected a whole, non-negative byte offset"),
            ));
        }
        // A whole f32 of at most 2^64 fits u64; larger ones saturate, and the
        // stream's size check refuses them.
        let vox_offset = vox_offset as u64;
        let (data_path, compression, offset) = if magic == b"ni1" {
            let img = pair_data_file(path, allow_outside)?;
            let gz = is_gzip(&img)?;
            (
                img,
                if gz {
                    Compression::Gzip
                } else {
                    Compression::None
                },
                vox_offset,
            )
        } else {
            let offset = if vox_offset < MIN_SINGLE_FILE_OFFSET {
                notes.push(format!(
                    "vox_offset {vox_offset} is below {MIN_SINGLE_FILE_OFFSET}, invalid for a single file: using {MIN_SINGLE_FILE_OFFSET}"
                ));
                MIN_SINGLE_FILE_OFFSET
            } else {
                vox_offset
            };
            (
                path.to_owned(),
                if gz {
                    Compression::Gzip
                } else {
                    Compression::None
                },
                offset,
            )
        };
        let (file_offset, skip) = match compression {
            Compression::None => (offset, 0),
            _ => (0, offset),
        };
        Ok(DataLocation {
            path: data_path,
            compression,
            file_offset,
            skip,
        })
    }
}

/// The `.img` (or `.img.gz`) beside a `.hdr`: a regular file in the header's
/// folder (also when it is a symbolic link) unless `allow_outside`.
fn pair_data_file(header: &Path, allow_outside: bool) -> Result<PathBuf, Error> {
    let name = header
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let stem = name
        .strip_suffix(".hdr")
        .or_else(|| name.strip_suffix(".hdr.gz"))
        .unwrap_or(&name);
    let folder = header.parent().unwrap_or(Path::new(""));
    let img = [format!("{stem}.img"), format!("{stem}.img.gz")]
        .into_iter()
        .find(|n| folder.join(n).exists())
        .ok_or_else(|| {
            field(
                header,
                "data file",
                format!(
                    "{} not found: expected the image file of a NIfTI pair beside its header",
                    folder.join(format!("{stem}.img")).display()
                ),
            )
        })?;
    data_file(header, "data file", &img, allow_outside)
}

/// The rotation of NIfTI's qform quaternion (b, c, d); a = √(1 − b² − c² − d²).
fn quaternion_rotation(b: f64, c: f64, d: f64) -> [[f64; 3]; 3] {
    let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
    [
        [
            a * a + b * b - c * c - d * d,
            2.0 * (b * c - a * d),
            2.0 * (b * d + a * c),
        ],
        [
            2.0 * (b * c + a * d),
            a * a + c * c - b * b - d * d,
            2.0 * (c * d - a * b),
        ],
        [
            2.0 * (b * d - a * c),
            2.0 * (c * d + a * b),
            a * a + d * d - c * c - b * b,
        ],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_identity_quaternion_is_no_rotation_and_a_half_turn_flips_two_axes() {
        assert_eq!(
            quaternion_rotation(0.0, 0.0, 0.0),
            crate::geometry::IDENTITY_DIRECTION
        );
        // b = 1: 180° about x.
        assert_eq!(
            quaternion_rotation(1.0, 0.0, 0.0),
            [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
        );
    }

    #[test]
    fn datatypes_outside_the_supported_set_have_names() {
        assert_eq!(sample_type(512), Some(SampleType::Voxel(VoxelType::U16)));
        assert_eq!(sample_type(128), None);
        assert_eq!(datatype_name(128), "rgb24");
    }
}
