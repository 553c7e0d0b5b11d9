//! Element lengths checked against the file before dicom-object reads it.
//!
//! dicom-rs allocates an element's value from the length its header declares
//! before reading it: a 1 KB file declaring 0xFFFFFFF0 bytes makes it zero
//! 4 GB first. [`check_lengths`] walks the file with dicom-parser's lazy reader
//! (values skipped, never read into memory) and refuses any value or item that
//! runs past the end of the file, so the real read that follows allocates at
//! most what the file holds.

use std::fs::File;
use std::io::{BufReader, Seek, SeekFrom};
use std::path::Path;

use dicom_dictionary_std::tags;
use dicom_encoding::transfer_syntax::Codec;
use dicom_encoding::{TransferSyntax, TransferSyntaxIndex};
use dicom_parser::StatefulDecode;
use dicom_parser::dataset::LazyDataToken;
use dicom_parser::dataset::lazy_read::LazyDataSetReader;
use dicom_transfer_syntax_registry::TransferSyntaxRegistry;

use crate::Error;
use crate::ingest::header::{field, file_len, open_file};

/// Where the file meta group starts: after the 128-byte preamble and `DICM`.
const META_START: u64 = 132;
/// The transfer syntax of the file meta group: Explicit VR Little Endian.
const META_SYNTAX: &str = "1.2.840.10008.1.2.1";

/// Checks every element and item length of `path` (a file with the `DICM`
/// marker at byte 128) against the bytes left in the file; with
/// `until_pixel_data`, stops at the top-level PixelData header (whose length is
/// checked too), as a header read does.
pub(super) fn check_lengths(path: &Path, until_pixel_data: bool) -> Result<(), Error> {
    let size = file_len(path)?;
    let mut reader = BufReader::new(open_file(path)?);
    let (syntax_uid, meta_end) = read_meta(path, size, &mut reader)?;
    let syntax = TransferSyntaxRegistry.get(&syntax_uid).ok_or_else(|| {
        field(
            path,
            "TransferSyntaxUID (0002,0010)",
            format!("'{syntax_uid}': expected a transfer syntax voxserve knows"),
        )
    })?;
    if matches!(syntax.codec(), Codec::Dataset(_)) {
        return Err(field(
            path,
            "TransferSyntaxUID (0002,0010)",
            format!(
                "{} ({syntax_uid}): expected a data set that is not deflated",
                syntax.name()
            ),
        ));
    }
    reader
        .seek(SeekFrom::Start(meta_end))
        .map_err(|source| Error::Io {
            path: path.to_owned(),
            source,
        })?;
    check_data_set(path, size, reader, syntax, until_pixel_data)
}

/// The size of one value of a binary VR: a value's length must be a multiple
/// of it, or dicom-rs reads a different number of bytes than the length says
/// and the rest of the file is parsed out of step (a 2-byte FD made it read a
/// later 540 MB length).
fn value_unit(vr: dicom_core::VR) -> Option<u64> {
    use dicom_core::VR;
    match vr {
        VR::FD | VR::OD | VR::SV | VR::UV | VR::OV => Some(8),
        VR::FL | VR::OF | VR::SL | VR::UL | VR::OL | VR::AT => Some(4),
        VR::SS | VR::US | VR::OW => Some(2),
        _ => None,
    }
}

/// The error for a value of `len` bytes at byte `at` of a `size`-byte file.
fn too_long(path: &Path, what: &str, len: u64, at: u64, size: u64) -> Error {
    field(
        path,
        what,
        format!(
            "declares {len} bytes at byte {at}, but the file has {size} bytes: expected a length \
             within the file (the file is truncated or damaged)"
        ),
    )
}

/// An error of the lazy reader, as a message naming the file.
fn parse_error(path: &Path, e: &dyn std::error::Error) -> Error {
    field(
        path,
        "header",
        format!("{e}: expected a readable DICOM file"),
    )
}

/// Walks the file meta group (Explicit VR Little Endian, its length given by
/// its first element, (0002,0000)); returns the transfer syntax UID and where
/// the data set starts.
fn read_meta(path: &Path, size: u64, reader: &mut BufReader<File>) -> Result<(String, u64), Error> {
    let io = |source| Error::Io {
        path: path.to_owned(),
        source,
    };
    reader.seek(SeekFrom::Start(META_START)).map_err(io)?;
    let meta_syntax = TransferSyntaxRegistry
        .get(META_SYNTAX)
        .ok_or_else(|| parse_error(path, &std::fmt::Error))?;
    let mut tokens =
        LazyDataSetReader::new_with_ts(reader, meta_syntax).map_err(|e| parse_error(path, &e))?;
    let (mut meta_end, mut syntax) = (None, None);
    while let Some(token) = tokens.advance() {
        let token = token.map_err(|e| parse_error(path, &e))?;
        let LazyDataToken::LazyValue { header, decoder } = token else {
            continue;
        };
        let at = decoder.position();
        let len = u64::from(header.len.0);
        let name = format!("file meta element {}", header.tag);
        if header.len.get().is_none() || len > size.saturating_sub(at) {
            return Err(too_long(path, &name, len, at, size));
        }
        let value = LazyDataToken::LazyValue { header, decoder }
            .into_value()
            .map_err(|e| parse_error(path, &e))?;
        match header.tag {
            tags::FILE_META_INFORMATION_GROUP_LENGTH => {
                let group = value.to_int::<u32>().map_err(|e| parse_error(path, &e))?;
                meta_end = Some(at + len + u64::from(group));
            }
            tags::TRANSFER_SYNTAX_UID => {
                syntax = Some(value.to_str().trim_end_matches(['\0', ' ']).to_owned());
            }
            _ => {}
        }
        let Some(end) = meta_end else {
            return Err(field(
                path,
                "FileMetaInformationGroupLength (0002,0000)",
                "missing: expected the file meta group to start with its length",
            ));
        };
        if end > size {
            return Err(too_long(path, "file meta group", end - at, at, size));
        }
        if at + len >= end {
            break; // the data set follows, in its own transfer syntax
        }
    }
    match (syntax, meta_end) {
        (Some(s), Some(end)) => Ok((s, end)),
        _ => Err(field(
            path,
            "TransferSyntaxUID (0002,0010)",
            "missing: expected it in the file meta group",
        )),
    }
}

/// Walks the data set, checking each value's and item's length against what
/// is left of the file and skipping it.
fn check_data_set(
    path: &Path,
    size: u64,
    reader: BufReader<File>,
    syntax: &TransferSyntax,
    until_pixel_data: bool,
) -> Result<(), Error> {
    let mut tokens =
        LazyDataSetReader::new_with_ts(reader, syntax).map_err(|e| parse_error(path, &e))?;
    let mut depth = 0u32;
    while let Some(token) = tokens.advance() {
        let token = token.map_err(|e| parse_error(path, &e))?;
        match token {
            LazyDataToken::SequenceStart { len, tag } => {
                if len.get().is_some_and(|l| u64::from(l) > size) {
                    return Err(too_long(
                        path,
                        &format!("sequence {tag}"),
                        len.0.into(),
                        0,
                        size,
                    ));
                }
                depth += 1;
            }
            LazyDataToken::PixelSequenceStart => {
                if until_pixel_data && depth == 0 {
                    return Ok(());
                }
                depth += 1;
            }
            LazyDataToken::SequenceEnd => depth = depth.saturating_sub(1),
            LazyDataToken::ItemStart { len } if len.get().is_some_and(|l| u64::from(l) > size) => {
                return Err(too_long(path, "item", len.0.into(), 0, size));
            }
            LazyDataToken::LazyValue { header, decoder } => {
                let at = decoder.position();
                let len = u64::from(header.len.0);
                if len > size.saturating_sub(at) {
                    return Err(too_long(
                        path,
                        &format!("element {}", header.tag),
                        len,
                        at,
                        size,
                    ));
                }
                if let Some(unit) = value_unit(header.vr)
                    && len % unit != 0
                {
                    return Err(field(
                        path,
                        &format!("element {}", header.tag),
                        format!(
                            "{len} bytes of VR {}: expected a multiple of {unit} (the file is \
                             damaged; a reader would fall out of step)",
                            header.vr
                        ),
                    ));
                }
                if until_pixel_data && depth == 0 && header.tag == tags::PIXEL_DATA {
                    return Ok(());
                }
                decoder
                    .skip_bytes(header.len.0)
                    .map_err(|e| parse_error(path, &e))?;
            }
            LazyDataToken::LazyItemValue { len, decoder } => {
                let at = decoder.position();
                if u64::from(len) > size.saturating_sub(at) {
                    return Err(too_long(path, "pixel data fragment", len.into(), at, size));
                }
                decoder.skip_bytes(len).map_err(|e| parse_error(path, &e))?;
            }
            _ => {}
        }
    }
    Ok(())
}
