//! Parsing helpers shared by the text headers (NRRD, MetaImage).

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::str::FromStr;

use crate::Error;

/// The longest text header read, in bytes: a header longer than this is binary
/// data or a mistake, not a header.
pub const MAX_HEADER_BYTES: usize = 1 << 20;

/// Opens a file, naming it in the error.
pub fn open_file(path: &Path) -> Result<std::fs::File, Error> {
    std::fs::File::open(path).map_err(|source| Error::Io {
        path: path.to_owned(),
        source,
    })
}

/// The size of a file in bytes, naming it in the error.
pub fn file_len(path: &Path) -> Result<u64, Error> {
    std::fs::metadata(path)
        .map(|m| m.len())
        .map_err(|source| Error::Io {
            path: path.to_owned(),
            source,
        })
}

/// The data file `name` that the header `header` names in `field`: resolved
/// against the header's folder, symbolic links followed, and required to be a
/// regular file inside that folder (unless `allow_outside`), so a header can
/// neither read a device nor reach files elsewhere.
pub fn data_file(
    header: &Path,
    field_name: &str,
    name: &str,
    allow_outside: bool,
) -> Result<PathBuf, Error> {
    let folder = header.parent().unwrap_or(Path::new("."));
    let folder = if folder.as_os_str().is_empty() {
        Path::new(".")
    } else {
        folder
    };
    let joined = folder.join(name);
    let resolved = joined.canonicalize().map_err(|e| {
        let why = if e.kind() == std::io::ErrorKind::NotFound {
            "not found".to_owned()
        } else {
            e.to_string()
        };
        field(
            header,
            field_name,
            format!(
                "{} {why}: expected the data file the header names",
                joined.display()
            ),
        )
    })?;
    let meta = std::fs::metadata(&resolved).map_err(|source| Error::Io {
        path: resolved.clone(),
        source,
    })?;
    if !meta.is_file() {
        return Err(field(
            header,
            field_name,
            format!(
                "'{name}' is {}: expected a regular data file",
                if meta.is_dir() {
                    "a folder"
                } else {
                    "not a regular file (a device, pipe or socket)"
                }
            ),
        ));
    }
    if !allow_outside {
        let home = folder.canonicalize().map_err(|source| Error::Io {
            path: folder.to_owned(),
            source,
        })?;
        if !resolved.starts_with(&home) {
            return Err(field(
                header,
                field_name,
                format!(
                    "'{name}' resolves to {}, outside the header's folder {}: expected a data \
                     file beside the header (give --allow-data-outside to read it anyway)",
                    resolved.display(),
                    home.display()
                ),
            ));
        }
    }
    Ok(resolved)
}

/// The first `n` bytes of a file (fewer if it is shorter).
pub fn read_prefix(path: &Path, n: usize) -> Result<Vec<u8>, Error> {
    let mut buf = Vec::with_capacity(n);
    open_file(path)?
        .take(n as u64)
        .read_to_end(&mut buf)
        .map_err(|source| Error::Io {
            path: path.to_owned(),
            source,
        })?;
    Ok(buf)
}

/// The lines of a text header and the number of bytes they take in the file.
#[derive(Debug)]
pub struct TextHeader {
    /// The lines, without line endings.
    pub lines: Vec<String>,
    /// Bytes from the start of the file to the first byte after the header.
    pub len: u64,
}

/// Reads header lines until `is_last` says a line ends the header (that line is
/// kept) or the file ends. Refuses headers over [`MAX_HEADER_BYTES`] and lines
/// that are not text.
pub fn read_text_header(path: &Path, is_last: impl Fn(&str) -> bool) -> Result<TextHeader, Error> {
    let mut reader = BufReader::new(open_file(path)?);
    let mut lines = Vec::new();
    let mut len = 0u64;
    let mut raw = Vec::new();
    loop {
        raw.clear();
        let n = reader
            .by_ref()
            .take((MAX_HEADER_BYTES + 1) as u64)
            .read_until(b'\n', &mut raw)
            .map_err(|source| Error::Io {
                path: path.to_owned(),
                source,
            })?;
        if n == 0 {
            break;
        }
        len += n as u64;
        if len > MAX_HEADER_BYTES as u64 {
            return Err(field(
                path,
                "header",
                format!("no end within {MAX_HEADER_BYTES} bytes: expected a text header"),
            ));
        }
        let text = std::str::from_utf8(&raw).map_err(|_| {
            field(
                path,
                "header",
                format!(
                    "line {} is not text: expected a text header",
                    lines.len() + 1
                ),
            )
        })?;
        let line = text.trim_end_matches(['\n', '\r']).to_owned();
        let last = is_last(&line);
        lines.push(line);
        if last {
            break;
        }
    }
    Ok(TextHeader { lines, len })
}

/// An [`Error::Field`].
pub fn field(path: &Path, field: &str, message: impl Into<String>) -> Error {
    Error::Field {
        path: path.to_owned(),
        field: field.to_owned(),
        message: message.into(),
    }
}

/// Whitespace-separated numbers, exactly `n` of them.
pub fn numbers<T: FromStr>(path: &Path, name: &str, text: &str, n: usize) -> Result<Vec<T>, Error> {
    let values: Option<Vec<T>> = text.split_whitespace().map(|w| w.parse().ok()).collect();
    match values {
        Some(v) if v.len() == n => Ok(v),
        _ => Err(field(path, name, format!("'{text}': expected {n} numbers"))),
    }
}

/// A NRRD vector `(x,y,z)` of `n` numbers.
pub fn vector(path: &Path, name: &str, text: &str, n: usize) -> Result<Vec<f64>, Error> {
    let inner = text
        .trim()
        .strip_prefix('(')
        .and_then(|t| t.strip_suffix(')'));
    let values: Option<Vec<f64>> =
        inner.and_then(|t| t.split(',').map(|w| w.trim().parse().ok()).collect());
    match values {
        Some(v) if v.len() == n && v.iter().all(|x| x.is_finite()) => Ok(v),
        _ => Err(field(
            path,
            name,
            format!("'{text}': expected a vector of {n} finite numbers like (1,0,0)"),
        )),
    }
}

/// A MetaImage boolean: `True`/`False` (any case), `1`/`0`.
pub fn boolean(path: &Path, name: &str, text: &str) -> Result<bool, Error> {
    match text.trim().to_ascii_lowercase().as_str() {
        "true" | "1" => Ok(true),
        "false" | "0" => Ok(false),
        _ => Err(field(
            path,
            name,
            format!("'{text}': expected True or False"),
        )),
    }
}

/// `value` as three `f64`s from a slice of exactly three.
pub fn three(v: &[f64]) -> [f64; 3] {
    [v[0], v[1], v[2]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vectors_and_numbers_parse_or_name_the_field() {
        let p = Path::new("h.nrrd");
        assert_eq!(
            vector(p, "space origin", "(1, -2.5,3)", 3).expect("ok"),
            [1.0, -2.5, 3.0]
        );
        let err = vector(p, "space origin", "1,2,3", 3).expect_err("no parens");
        assert!(
            err.to_string()
                .contains("h.nrrd: space origin: '1,2,3': expected a vector"),
            "{err}"
        );
        assert_eq!(
            numbers::<u64>(p, "sizes", "4 5 6", 3).expect("ok"),
            [4, 5, 6]
        );
        assert!(numbers::<u64>(p, "sizes", "4 five 6", 3).is_err());
        assert!(numbers::<u64>(p, "sizes", "4 5", 3).is_err());
        assert!(boolean(p, "CompressedData", "True").expect("ok"));
        assert!(boolean(p, "CompressedData", "yes").is_err());
    }
}
