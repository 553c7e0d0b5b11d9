//! MetaImage (ITK's `.mha` with the data attached, `.mhd` with a separate data
//! file): `Key = Value` lines ending with `ElementDataFile`. Reads `NDims`,
//! `DimSize`, `ElementType`, `ElementSpacing` (or `ElementSize`), `Offset` (or
//! `Origin`, `Position`), `TransformMatrix` (or `Rotation`, `Orientation`),
//! `AnatomicalOrientation`, `BinaryDataByteOrderMSB` (or `ElementByteOrderMSB`),
//! `CompressedData` (zlib), `HeaderSize` and `ElementNumberOfChannels`.
//!
//! As in ITK, `TransformMatrix` lists the direction of index axis x first, then y,
//! then z, each in the physical frame, which MetaImage files from ITK put in LPS.
//! `AnatomicalOrientation` (e.g. `RPS`) is reported; the geometry comes from the
//! matrix.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::header::{
    boolean, data_file as data_file_path, field, numbers, read_text_header, three,
};
use super::stream::{Compression, SampleType, StreamLayout, StreamSource, trailing_data_offset};
use super::{Format, VolumeInfo, check_dims, check_orthonormal};
use crate::geometry::GeometryFields;
use crate::{Error, Geometry, ValueMap, VoxelType};

fn sample_type(name: &str) -> Option<SampleType> {
    let t = match name {
        "MET_UCHAR" => VoxelType::U8,
        "MET_CHAR" => VoxelType::I8,
        "MET_USHORT" => VoxelType::U16,
        "MET_SHORT" => VoxelType::I16,
        "MET_UINT" => VoxelType::U32,
        "MET_INT" => VoxelType::I32,
        "MET_FLOAT" => VoxelType::F32,
        "MET_DOUBLE" => return Some(SampleType::F64),
        _ => return None,
    };
    Some(SampleType::Voxel(t))
}

/// Opens a MetaImage file; a separate data file must lie in the header's
/// folder unless `allow_data_outside`.
pub fn open(path: &Path, allow_data_outside: bool) -> Result<StreamSource, Error> {
    let is_data_file_line = |line: &str| {
        line.split_once('=')
            .is_some_and(|(k, _)| k.trim().eq_ignore_ascii_case("ElementDataFile"))
    };
    let head = read_text_header(path, is_data_file_line)?;
    let fields = Fields::read(path, &head.lines)?;
    let data_file = fields.require("ElementDataFile")?;
    let samples = Samples::read(&fields)?;
    let mut notes = Vec::new();
    let dims = check_dims(path, "DimSize", samples.sizes, samples.sample.size() as u64)?;
    let geometry = read_geometry(&fields, samples.ndims, dims, &mut notes)?;
    let encoding = Encoding::read(&fields)?;
    let (data_path, file_offset) = data_location(
        &fields,
        DataFile {
            name: data_file,
            header_len: head.len,
            allow_outside: allow_data_outside,
        },
        encoding.compressed,
        dims,
        samples.sample,
    )?;
    let info = VolumeInfo {
        path: path.to_owned(),
        format: Format::MetaImage,
        geometry,
        voxel_type: samples.sample.voxel_type(),
        value_map: ValueMap::IDENTITY,
        unit: None,
        modality: fields
            .get("Modality")
            .map(|m| m.trim_start_matches("MET_MOD_").to_owned()),
        description: None,
        study: crate::ingest::Study::default(),
        notes,
    };
    StreamSource::new(
        info,
        StreamLayout {
            data_path,
            compression: if encoding.compressed {
                Compression::Zlib
            } else {
                Compression::None
            },
            file_offset,
            skip: 0,
            sample: samples.sample,
            big_endian: encoding.big_endian,
        },
    )
}

/// The `Key = Value` fields of a header; keys match in any case.
struct Fields<'a> {
    /// The header file, named in messages.
    path: &'a Path,
    /// Values by lower-case key.
    by_key: HashMap<String, String>,
}

impl<'a> Fields<'a> {
    fn read(path: &'a Path, lines: &[String]) -> Result<Fields<'a>, Error> {
        let mut by_key = HashMap::new();
        for line in lines {
            if line.trim().is_empty() {
                continue;
            }
            let Some((key, value)) = line.split_once('=') else {
                return Err(field(
                    path,
                    "header",
                    format!("line '{line}': expected 'Key = Value'"),
                ));
            };
            by_key.insert(key.trim().to_ascii_lowercase(), value.trim().to_owned());
        }
        Ok(Fields { path, by_key })
    }

    fn get(&self, name: &str) -> Option<&str> {
        self.by_key
            .get(&name.to_ascii_lowercase())
            .map(String::as_str)
    }

    /// The first of `names` (synonyms) the header has, with its value.
    fn first(&self, names: &[&'static str]) -> Option<(&'static str, &str)> {
        names.iter().find_map(|n| self.get(n).map(|v| (*n, v)))
    }

    fn require(&self, name: &'static str) -> Result<&str, Error> {
        self.get(name)
            .ok_or_else(|| field(self.path, name, "missing: expected this field"))
    }
}

/// What the header says about the samples: an image of `NDims` axes of one
/// scalar type.
struct Samples {
    /// 3 for a volume, 2 for one slice.
    ndims: usize,
    sample: SampleType,
    /// Samples along x, y, z (one slice along z for a 2D image).
    sizes: [u64; 3],
}

impl Samples {
    fn read(fields: &Fields<'_>) -> Result<Samples, Error> {
        let path = fields.path;
        if let Some(object) = fields.get("ObjectType")
            && !object.eq_ignore_ascii_case("Image")
        {
            return Err(field(
                path,
                "ObjectType",
                format!("'{object}': expected Image"),
            ));
        }
        let ndims: usize = fields
            .require("NDims")?
            .parse()
            .map_err(|_| field(path, "NDims", "expected a whole number"))?;
        if !(2..=3).contains(&ndims) {
            return Err(field(
                path,
                "NDims",
                format!("{ndims}: expected 3 (a volume) or 2 (one slice)"),
            ));
        }
        if let Some(channels) = fields.get("ElementNumberOfChannels")
            && channels != "1"
        {
            return Err(field(
                path,
                "ElementNumberOfChannels",
                format!("{channels}: expected 1 (scalar voxels)"),
            ));
        }
        let type_name = fields.require("ElementType")?;
        let sample = sample_type(type_name).ok_or_else(|| {
            field(
                path,
                "ElementType",
                format!("'{type_name}': expected MET_UCHAR, MET_CHAR, MET_USHORT, MET_SHORT, MET_UINT, MET_INT, MET_FLOAT or MET_DOUBLE"),
            )
        })?;
        let sizes: Vec<u64> = numbers(path, "DimSize", fields.require("DimSize")?, ndims)?;
        Ok(Samples {
            ndims,
            sample,
            sizes: [sizes[0], sizes[1], sizes.get(2).copied().unwrap_or(1)],
        })
    }
}

/// The header fields each part of the geometry comes from.
const GEOMETRY_FIELDS: GeometryFields = GeometryFields {
    dims: "DimSize",
    spacing: "ElementSpacing",
    origin: "Offset",
    direction: "TransformMatrix",
};

/// Reads `ElementSpacing`, `Offset` and `TransformMatrix` (or their synonyms)
/// for a volume of `dims`, in the physical frame (LPS, as ITK writes it); a 2D
/// image gets a unit z axis. Assumptions go to `notes`.
fn read_geometry(
    fields: &Fields<'_>,
    ndims: usize,
    dims: [u32; 3],
    notes: &mut Vec<String>,
) -> Result<Geometry, Error> {
    let path = fields.path;
    let mut spacing: Vec<f64> = match fields.first(&["ElementSpacing", "ElementSize"]) {
        Some((name, text)) => numbers(path, name, text, ndims)?,
        None => {
            notes.push("no ElementSpacing: assumed 1 mm".to_owned());
            vec![1.0; ndims]
        }
    };
    let mut origin: Vec<f64> = match fields.first(&["Offset", "Origin", "Position"]) {
        Some((name, text)) => numbers(path, name, text, ndims)?,
        None => vec![0.0; ndims],
    };
    let mut matrix: Vec<f64> = match fields.first(&["TransformMatrix", "Rotation", "Orientation"]) {
        Some((name, text)) => numbers(path, name, text, ndims * ndims)?,
        None => (0..ndims * ndims)
            .map(|i| if i % (ndims + 1) == 0 { 1.0 } else { 0.0 })
            .collect(),
    };
    if ndims == 2 {
        spacing.push(1.0);
        origin.push(0.0);
        matrix = vec![
            matrix[0], matrix[1], 0.0, matrix[2], matrix[3], 0.0, 0.0, 0.0, 1.0,
        ];
    }
    if let Some(orientation) = fields.get("AnatomicalOrientation") {
        notes.push(format!(
            "AnatomicalOrientation {orientation} (geometry from TransformMatrix)"
        ));
    }
    let geometry = Geometry {
        dims,
        spacing: three(&spacing),
        origin: three(&origin),
        direction: [
            [matrix[0], matrix[1], matrix[2]],
            [matrix[3], matrix[4], matrix[5]],
            [matrix[6], matrix[7], matrix[8]],
        ],
    }
    .checked(path, &GEOMETRY_FIELDS)?;
    check_orthonormal(path, "TransformMatrix", geometry.direction)?;
    Ok(geometry)
}

/// How the voxel bytes are stored: byte order and zlib compression; text data
/// is refused.
struct Encoding {
    big_endian: bool,
    compressed: bool,
}

impl Encoding {
    fn read(fields: &Fields<'_>) -> Result<Encoding, Error> {
        let path = fields.path;
        let big_endian = match fields.first(&["BinaryDataByteOrderMSB", "ElementByteOrderMSB"]) {
            Some((name, text)) => boolean(path, name, text)?,
            None => false,
        };
        let compressed = match fields.get("CompressedData") {
            Some(text) => boolean(path, "CompressedData", text)?,
            None => false,
        };
        if fields
            .get("BinaryData")
            .is_some_and(|b| boolean(path, "BinaryData", b).ok() == Some(false))
        {
            return Err(field(
                path,
                "BinaryData",
                "False: expected binary voxel data (text data is not supported)",
            ));
        }
        Ok(Encoding {
            big_endian,
            compressed,
        })
    }
}

/// What the header says of the data file.
#[derive(Clone, Copy)]
struct DataFile<'a> {
    /// `ElementDataFile`.
    name: &'a str,
    /// Bytes of the header (where `LOCAL` data starts).
    header_len: u64,
    /// Whether the data file may lie outside the header's folder.
    allow_outside: bool,
}

/// Where the voxels are: the data file (`LOCAL`: after the header) and the
/// offset of the stream in it, after `HeaderSize`.
fn data_location(
    fields: &Fields<'_>,
    data: DataFile<'_>,
    compressed: bool,
    dims: [u32; 3],
    sample: SampleType,
) -> Result<(PathBuf, u64), Error> {
    let path = fields.path;
    let data_file = data.name;
    let (data_path, mut file_offset) = if data_file.eq_ignore_ascii_case("LOCAL") {
        (path.to_owned(), data.header_len)
    } else if data_file.starts_with("LIST")
        || data_file.contains('%')
        || data_file.split_whitespace().count() > 1
    {
        return Err(field(
            path,
            "ElementDataFile",
            format!(
                "'{data_file}': expected LOCAL or one data file (lists and patterns are not supported)"
            ),
        ));
    } else {
        (
            data_file_path(path, "ElementDataFile", data_file, data.allow_outside)?,
            0,
        )
    };
    match fields.get("HeaderSize") {
        None => {}
        Some("-1") if !compressed => {
            file_offset = trailing_data_offset(&data_path, dims, sample)?;
        }
        Some(n) => {
            let size = n.parse::<u64>().map_err(|_| {
                field(
                    path,
                    "HeaderSize",
                    format!("'{n}': expected a whole number, or -1 for uncompressed data"),
                )
            })?;
            let len = super::header::file_len(&data_path)?;
            file_offset = file_offset
                .checked_add(size)
                .filter(|&offset| offset <= len)
                .ok_or_else(|| {
                    field(
                        path,
                        "HeaderSize",
                        format!(
                            "{size}: the voxels would start past the end of {} ({len} bytes): \
                             expected a header size within the data file",
                            data_path.display()
                        ),
                    )
                })?;
        }
    }
    Ok((data_path, file_offset))
}
