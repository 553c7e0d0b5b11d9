//! NRRD (teem's "nearly raw raster data"): a text header, attached (data after a
//! blank line) or detached (`data file:` names the data). Encodings raw and gzip;
//! `sizes`, `type` (with its synonyms), `endian`, `spacings` or `space
//! directions`, `space origin`, `space`, `byte skip` and `line skip`.
//!
//! No NRRD crate exists; this reads the part of the format volumes use.

use std::path::Path;

use super::header::{self, field, numbers, read_text_header, three, vector};
use super::stream::{Compression, SampleType, StreamLayout, StreamSource, trailing_data_offset};
use super::{Format, VolumeInfo, check_dims, check_spacing, spacing_and_direction};
use crate::{Error, ValueMap, VoxelType};

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

/// Opens a NRRD file (`.nrrd` attached or `.nhdr` detached).
pub fn open(path: &Path) -> Result<StreamSource, Error> {
    let head = read_text_header(path, str::is_empty)?;
    let magic = head.lines.first().map(String::as_str).unwrap_or_default();
    if !magic.starts_with("NRRD000") {
        return Err(field(
            path,
            "magic",
            format!("'{magic}': expected a first line NRRD0001 to NRRD0005"),
        ));
    }
    let mut fields = std::collections::HashMap::new();
    for line in &head.lines[1..] {
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
        fields.insert(key.trim().to_owned(), value.trim().to_owned());
    }
    let get = |name: &str| fields.get(name).map(String::as_str);
    let require = |name: &str| {
        get(name).ok_or_else(|| field(path, name, "missing: expected this required field"))
    };

    let dimension: usize = require("dimension")?
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
    let type_name = require("type")?;
    let sample = sample_type(type_name).ok_or_else(|| {
        field(
            path,
            "type",
            format!("'{type_name}': expected an integer type of 8 to 32 bits, float or double"),
        )
    })?;
    let mut sizes: Vec<u64> = numbers(path, "sizes", require("sizes")?, dimension)?;
    let encoding = require("encoding")?;
    let compression = match encoding {
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
    let big_endian = match get("endian") {
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

    let mut notes = Vec::new();
    let (signs, space_note) = match get("space") {
        Some(space) => space_to_lps(path, space)?,
        None => ([1.0; 3], None),
    };
    notes.extend(space_note);
    let (mut spacing, mut direction) = if let Some(dirs) = get("space directions") {
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
        spacing_and_direction(columns)
    } else {
        let spacing = match get("spacings") {
            Some(text) => {
                let mut s: Vec<f64> = numbers(path, "spacings", text, dimension)?;
                s.resize(3, 1.0);
                three(&s)
            }
            None => {
                notes.push("no spacings or space directions: assumed 1 mm".to_owned());
                [1.0; 3]
            }
        };
        (spacing, super::IDENTITY)
    };
    if dimension == 2 {
        sizes.push(1);
        spacing[2] = 1.0;
        direction[2] = [0.0, 0.0, 1.0];
    }
    check_spacing(path, "space directions or spacings", spacing)?;
    super::check_direction(path, "space directions", direction)?;
    let origin = match get("space origin") {
        Some(text) => {
            let v = vector(path, "space origin", text, 3)?;
            [v[0] * signs[0], v[1] * signs[1], v[2] * signs[2]]
        }
        None => [0.0; 3],
    };
    let dims = check_dims(path, "sizes", three_u64(&sizes), sample.size() as u64)?;

    // Where the voxels are: after the header, or in the data file.
    let detached = get("data file").or(get("datafile"));
    let (data_path, mut file_offset) = match detached {
        Some(name) if name.starts_with("LIST") || name.split_whitespace().count() > 1 => {
            return Err(field(
                path,
                "data file",
                format!("'{name}': expected one data file (lists and patterns are not supported)"),
            ));
        }
        Some(name) => {
            let base = path.parent().unwrap_or(Path::new("."));
            (base.join(name), 0)
        }
        None => (path.to_owned(), head.len),
    };
    if let Some(lines) = get("line skip").or(get("lineskip")) {
        let lines: u64 = lines
            .parse()
            .map_err(|_| field(path, "line skip", "expected a whole number"))?;
        file_offset = skip_lines(&data_path, file_offset, lines)?;
    }
    let mut skip = 0;
    match get("byte skip").or(get("byteskip")) {
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
                file_offset += n;
            } else {
                skip = n;
            }
        }
    }
    let info = VolumeInfo {
        path: path.to_owned(),
        format: Format::Nrrd,
        dims,
        voxel_type: sample.voxel_type(),
        spacing,
        origin,
        direction,
        value_map: ValueMap::IDENTITY,
        unit: None,
        modality: None,
        description: get("content").map(str::to_owned),
        notes,
    };
    StreamSource::new(
        info,
        StreamLayout {
            data_path,
            compression,
            file_offset,
            skip,
            sample,
            big_endian,
        },
    )
}

fn three_u64(v: &[u64]) -> [u64; 3] {
    [v[0], v[1], v[2]]
}

/// The offset after skipping `lines` text lines from `offset` in `path`.
fn skip_lines(path: &Path, offset: u64, lines: u64) -> Result<u64, Error> {
    use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
    let io_err = |source| Error::Io {
        path: path.to_owned(),
        source,
    };
    let mut file = header::open_file(path)?;
    file.seek(SeekFrom::Start(offset)).map_err(io_err)?;
    let mut reader = BufReader::new(file);
    let mut position = offset;
    let mut line = Vec::new();
    for _ in 0..lines {
        line.clear();
        let n = reader
            .by_ref()
            .take(header::MAX_HEADER_BYTES as u64)
            .read_until(b'\n', &mut line)
            .map_err(io_err)?;
        if n == 0 {
            return Err(field(
                path,
                "line skip",
                format!("{lines} lines: the file ends first"),
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
