//! NRRD (teem's "nearly raw raster data"): a text header, attached (data after a
//! blank line) or detached (`data file:` names the data). Encodings raw and gzip;
//! `sizes`, `type` (with its synonyms), `endian`, `spacings` or `space
//! directions`, `space origin`, `space`, `byte skip` and `line skip`.
//!
//! No NRRD crate exists; this reads the part of the format volumes use.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::header::{self, field, numbers, read_text_header, three, vector};
use super::stream::{Compression, SampleType, StreamLayout, StreamSource, trailing_data_offset};
use super::{Format, VolumeInfo, check_dims, check_orthonormal};
use crate::geometry::{GeometryFields, IDENTITY_DIRECTION, spacing_and_direction};
use crate::{Error, Geometry, ValueMap, VoxelType};

/// The NRRD type names and synonyms for each sample type.
fn sample_type(name: &str) -> Option<SampleType> {
    let t = match name {
        "signed char" | "int8" | "int8_t" => VoxelType::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => VoxelType::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            VoxelType::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => {
            VoxelType::U16
        }
        "int" | "signed int" | "int32" | "int32_t" => VoxelType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => VoxelType::U32,
        "float" => VoxelType::F32,
        "double" => return Some(SampleType::F64),
        _ => return None,
    };
    Some(SampleType::Voxel(t))
}

/// Signs that turn a NRRD `space` into LPS, axis by axis.
fn space_to_lps(path: &Path, space: &str) -> Result<([f64; 3], Option<String>), Error> {
    Ok(match space {
        "left-posterior-superior" | "LPS" => ([1.0, 1.0, 1.0], None),
        "right-anterior-superior" | "RAS" => ([-1.0, -1.0, 1.0], None),
        "left-anterior-superior" | "LAS" => ([1.0, -1.0, 1.0], None),
        "scanner-xyz" | "3D-right-handed" | "3D-left-handed" => (
            [1.0, 1.0, 1.0],
            Some(format!("space '{space}' is not anatomical: taken as LPS")),
        ),
        other => {
            return Err(field(
                path,
                "space",
                format!(
                    "'{other}': expected a 3D space (left-posterior-superior, \
                     right-anterior-superior, left-anterior-superior, scanner-xyz)"
                ),
            ));
        }
    })
}

/// Opens a NRRD file (`.nrrd` attached or `.nhdr` detached); a detached data
/// file must lie in the header's folder unless `allow_data_outside`.
pub fn open(path: &Path, allow_data_outside: bool) -> Result<StreamSource, Error> {
    let head = read_text_header(path, str::is_empty)?;
    let fields = Fields::read(path, &head.lines)?;
    let samples = Samples::read(&fields)?;
    let mut notes = Vec::new();
    let dims = check_dims(path, "sizes", samples.sizes, samples.sample.size() as u64)?;
    let geometry = read_geometry(&fields, samples.dimension, dims, &mut notes)?;
    let (data_path, file_offset, skip) =
        data_location(&fields, head.len, &samples, dims, allow_data_outside)?;
    let info = VolumeInfo {
        path: path.to_owned(),
        format: Format::Nrrd,
        geometry,
        voxel_type: samples.sample.voxel_type(),
        value_map: ValueMap::IDENTITY,
        unit: None,
        modality: None,
        description: fields.get("content").map(str::to_owned),
        study: crate::ingest::Study::default(),
        notes,
    };
    StreamSource::new(
        info,
        StreamLayout {
            data_path,
            compression: samples.compression,
            file_offset,
            skip,
            sample: samples.sample,
            big_endian: samples.big_endian,
        },
    )
}

/// The fields of a NRRD header by name, read after checking the magic line;
/// comments and `key:=value` pairs are passed over.
struct Fields<'a> {
    /// The header file, named in messages.
    path: &'a Path,
    by_name: HashMap<String, String>,
}

impl<'a> Fields<'a> {
    fn read(path: &'a Path, lines: &[String]) -> Result<Fields<'a>, Error> {
        let magic = lines.first().map(String::as_str).unwrap_or_default();
        if !magic.starts_with("NRRD000") {
            return Err(field(
                path,
                "magic",
                format!("'{magic}': expected a first line NRRD0001 to NRRD0005"),
            ));
        }
        let mut by_name = HashMap::new();
        for line in &lines[1..] {
            if line.is_empty() || line.starts_with('#') || line.contains(":=") {
                continue; // blank end, comment, or key/value pair
            }
            let Some((key, value)) = line.split_once(": ") else {
                return Err(field(
                    path,
                    "header",
                    format!("line '{line}': expected 'field: value'"),
                ));
            };
            by_name.insert(key.trim().to_owned(), value.trim().to_owned());
        }
        Ok(Fields { path, by_name })
    }

    fn get(&self, name: &str) -> Option<&str> {
        self.by_name.get(name).map(String::as_str)
    }

    fn require(&self, name: &str) -> Result<&str, Error> {
        self.get(name)
            .ok_or_else(|| field(self.path, name, "missing: expected this required field"))
    }
}

/// What the header says about the samples: how many, their type, and how they
/// are stored.
struct Samples {
    /// 3 for a volume, 2 for one slice.
    dimension: usize,
    sample: SampleType,
    /// Samples along x, y, z (one slice along z for a 2D image).
    sizes: [u64; 3],
    compression: Compression,
    big_endian: bool,
}

impl Samples {
    fn read(fields: &Fields<'_>) -> Result<Samples, Error> {
        let path = fields.path;
        let dimension: usize = fields
            .require("dimension")?
            .parse()
            .map_err(|_| field(path, "dimension", "expected a whole number"))?;
        if !(2..=3).contains(&dimension) {
            return Err(field(
                path,
                "dimension",
                format!(
                    "{dimension}: expected 3 (a volume) or 2 (one slice); vector or time series data is not supported"
                ),
            ));
        }
        let type_name = fields.require("type")?;
        let sample = sample_type(type_name).ok_or_else(|| {
            field(
                path,
                "type",
                format!("'{type_name}': expected an integer type of 8 to 32 bits, float or double"),
            )
        })?;
        let sizes: Vec<u64> = numbers(path, "sizes", fields.require("sizes")?, dimension)?;
        let compression = match fields.require("encoding")? {
            "raw" => Compression::None,
            "gzip" | "gz" => Compression::Gzip,
            other => {
                return Err(field(
                    path,
                    "encoding",
                    format!("'{other}': expected raw or gzip"),
                ));
            }
        };
        let big_endian = match fields.get("endian") {
            Some("big") => true,
            Some("little") => false,
            Some(other) => {
                return Err(field(
                    path,
                    "endian",
                    format!("'{other}': expected little or big"),
                ));
            }
            None if sample.size() > 1 => {
                return Err(field(
                    path,
                    "endian",
                    "missing: expected little or big for multi-byte types",
                ));
            }
            None => false,
        };
        Ok(Samples {
            dimension,
            sample,
            sizes: [sizes[0], sizes[1], sizes.get(2).copied().unwrap_or(1)],
            compression,
            big_endian,
        })
    }
}

/// The header fields each part of the geometry comes from.
const GEOMETRY_FIELDS: GeometryFields = GeometryFields {
    dims: "sizes",
    spacing: "space directions or spacings",
    origin: "space origin",
    direction: "space directions",
};

/// Reads `space`, `space directions` (or `spacings`) and `space origin`,
/// converted to LPS, for a volume of `dims`; a 2D image gets a unit z axis.
/// Assumptions go to `notes`.
fn read_geometry(
    fields: &Fields<'_>,
    dimension: usize,
    dims: [u32; 3],
    notes: &mut Vec<String>,
) -> Result<Geometry, Error> {
    let path = fields.path;
    let (signs, space_note) = match fields.get("space") {
        Some(space) => space_to_lps(path, space)?,
        None => ([1.0; 3], None),
    };
    notes.extend(space_note);
    let (mut spacing, mut direction) = match fields.get("space directions") {
        Some(dirs) => space_directions(path, dirs, dimension, signs)?,
        None => (spacings(fields, dimension, notes)?, IDENTITY_DIRECTION),
    };
    if dimension == 2 {
        spacing[2] = 1.0;
        direction[2] = [0.0, 0.0, 1.0];
    }
    let origin = match fields.get("space origin") {
        Some(text) => {
            let v = vector(path, "space origin", text, 3)?;
            [v[0] * signs[0], v[1] * signs[1], v[2] * signs[2]]
        }
        None => [0.0; 3],
    };
    let geometry = Geometry {
        dims,
        spacing,
        origin,
        direction,
    }
    .checked(path, &GEOMETRY_FIELDS)?;
    check_orthonormal(path, "space directions", geometry.direction)?;
    Ok(geometry)
}

/// Spacings and unit directions from `space directions`, one vector per axis,
/// each multiplied by `signs` into LPS.
fn space_directions(
    path: &Path,
    dirs: &str,
    dimension: usize,
    signs: [f64; 3],
) -> Result<([f64; 3], [[f64; 3]; 3]), Error> {
    let vectors: Vec<&str> = dirs.split_whitespace().collect();
    if vectors.len() != dimension {
        return Err(field(
            path,
            "space directions",
            format!("'{dirs}': expected {dimension} vectors"),
        ));
    }
    let mut columns = [[0.0; 3]; 3];
    for (column, text) in columns.iter_mut().zip(&vectors) {
        let v = vector(path, "space directions", text, 3)?;
        *column = [v[0] * signs[0], v[1] * signs[1], v[2] * signs[2]];
    }
    if dimension == 2 {
        columns[2] = [0.0, 0.0, 1.0];
    }
    Ok(spacing_and_direction(columns))
}

/// Spacings from `spacings`, or 1 mm (with a note) when the header has none.
fn spacings(
    fields: &Fields<'_>,
    dimension: usize,
    notes: &mut Vec<String>,
) -> Result<[f64; 3], Error> {
    Ok(match fields.get("spacings") {
        Some(text) => {
            let mut s: Vec<f64> = numbers(fields.path, "spacings", text, dimension)?;
            s.resize(3, 1.0);
            three(&s)
        }
        None => {
            notes.push("no spacings or space directions: assumed 1 mm".to_owned());
            [1.0; 3]
        }
    })
}

/// Where the voxels are: the data file (the header itself when attached), the
/// offset of the stream in it, and the bytes to skip in the decompressed
/// stream, after `data file`, `line skip` and `byte skip`.
fn data_location(
    fields: &Fields<'_>,
    header_len: u64,
    samples: &Samples,
    dims: [u32; 3],
    allow_outside: bool,
) -> Result<(PathBuf, u64, u64), Error> {
    let path = fields.path;
    let (compression, sample) = (samples.compression, samples.sample);
    let detached = fields.get("data file").or(fields.get("datafile"));
    let (data_path, mut file_offset) = match detached {
        Some(name) if name.starts_with("LIST") || name.split_whitespace().count() > 1 => {
            return Err(field(
                path,
                "data file",
                format!("'{name}': expected one data file (lists and patterns are not supported)"),
            ));
        }
        Some(name) => (
            header::data_file(path, "data file", name, allow_outside)?,
            0,
        ),
        None => (path.to_owned(), header_len),
    };
    if let Some(lines) = fields.get("line skip").or(fields.get("lineskip")) {
        let lines: u64 = lines
            .parse()
            .map_err(|_| field(path, "line skip", "expected a whole number"))?;
        file_offset = skip_lines(path, &data_path, file_offset, lines)?;
    }
    let mut skip = 0;
    match fields.get("byte skip").or(fields.get("byteskip")) {
        None => {}
        Some("-1") if compression == Compression::None => {
            file_offset = trailing_data_offset(&data_path, dims, sample)?;
        }
        Some(n) => {
            let n: u64 = n.parse().map_err(|_| {
                field(
                    path,
                    "byte skip",
                    format!("'{n}': expected a whole number, or -1 with raw encoding"),
                )
            })?;
            if compression == Compression::None {
                file_offset = file_offset.checked_add(n).ok_or_else(|| {
                    field(
                        path,
                        "byte skip",
                        format!("{n}: expected a skip within the data file"),
                    )
                })?;
            } else {
                skip = n;
            }
        }
    }
    Ok((data_path, file_offset, skip))
}

/// The offset after skipping `lines` text lines from `offset` in `path`
/// (`header` names the field in messages). The loop is bounded by the file:
/// a line takes at least one byte, so more lines than bytes are refused at
/// once, and a line longer than [`header::MAX_HEADER_BYTES`] is not text.
fn skip_lines(header: &Path, path: &Path, offset: u64, lines: u64) -> Result<u64, Error> {
    use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
    let io_err = |source| Error::Io {
        path: path.to_owned(),
        source,
    };
    let size = header::file_len(path)?;
    let ends_first = || {
        field(
            header,
            "line skip",
            format!(
                "{lines} lines: {} ends first ({size} bytes): expected at most as many lines as \
                 the data file holds",
                path.display()
            ),
        )
    };
    if lines > size.saturating_sub(offset) {
        return Err(ends_first());
    }
    let mut file = header::open_file(path)?;
    file.seek(SeekFrom::Start(offset)).map_err(io_err)?;
    let mut reader = BufReader::new(file);
    let mut position = offset;
    let mut line = Vec::new();
    for _ in 0..lines {
        line.clear();
        let n = reader
            .by_ref()
            .take(header::MAX_HEADER_BYTES as u64 + 1)
            .read_until(b'\n', &mut line)
            .map_err(io_err)?;
        if n == 0 {
            return Err(ends_first());
        }
        if n > header::MAX_HEADER_BYTES {
            return Err(field(
                header,
                "line skip",
                format!(
                    "a line at byte {position} of {} runs over {} bytes: expected text lines to skip",
                    path.display(),
                    header::MAX_HEADER_BYTES
                ),
            ));
        }
        position += n as u64;
    }
    Ok(position)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn type_synonyms_map_to_sample_types() {
        for (name, t) in [
            ("uchar", VoxelType::U8),
            ("uint8_t", VoxelType::U8),
            ("signed char", VoxelType::I8),
            ("short", VoxelType::I16),
            ("unsigned short int", VoxelType::U16),
            ("int", VoxelType::I32),
            ("uint32_t", VoxelType::U32),
            ("float", VoxelType::F32),
        ] {
            assert_eq!(sample_type(name), Some(SampleType::Voxel(t)), "{name}");
        }
        assert_eq!(sample_type("double"), Some(SampleType::F64));
        assert_eq!(sample_type("longlong"), None);
    }
}
