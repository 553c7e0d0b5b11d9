//! [`StreamSource`]: voxels stored as one byte stream in a file, x fastest —
//! uncompressed, gzip or zlib — after some offset. Raw, NRRD, NIfTI and MetaImage
//! all end up here once their headers are read.
//!
//! Uncompressed data is read slab by slab with a seek. Compressed data cannot
//! seek: the decoder runs forward, skipping what precedes a slab, and restarts
//! from the top when asked to go back. Either way a slab read holds one slab.

use std::fs::File;
use std::io::{self, BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use flate2::bufread::{MultiGzDecoder, ZlibDecoder};

use super::header::{field, open_file};
use super::{VolumeInfo, VolumeSource};
use crate::{Error, VoxelData, VoxelType};

/// The largest ratio of decompressed to compressed size deflate can reach (about
/// 1032:1), with a margin: headers promising more are wrong.
const MAX_DEFLATE_RATIO: u64 = 1100;

/// How the stream is compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    /// Not compressed.
    None,
    /// gzip (RFC 1952), possibly several members.
    Gzip,
    /// zlib (RFC 1950), as MetaImage's `CompressedData`.
    Zlib,
}

impl Compression {
    fn name(self) -> &'static str {
        match self {
            Compression::None => "uncompressed",
            Compression::Gzip => "gzip",
            Compression::Zlib => "zlib",
        }
    }
}

/// The type of one sample in the file: a voxel type, or `f64`, which is
/// delivered as `f32`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleType {
    /// Stored as the voxel type itself.
    Voxel(VoxelType),
    /// 64-bit floats, narrowed to `f32` on reading.
    F64,
}

impl SampleType {
    /// Bytes per sample in the file.
    pub fn size(self) -> usize {
        match self {
            SampleType::Voxel(t) => t.size(),
            SampleType::F64 => 8,
        }
    }

    /// The voxel type slabs are delivered in.
    pub fn voxel_type(self) -> VoxelType {
        match self {
            SampleType::Voxel(t) => t,
            SampleType::F64 => VoxelType::F32,
        }
    }
}

/// Where and how the voxels are stored.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StreamLayout {
    /// The file holding the voxels.
    pub data_path: PathBuf,
    /// Its compression.
    pub compression: Compression,
    /// Where the (possibly compressed) stream starts in the file.
    pub file_offset: u64,
    /// Bytes of the decompressed stream before the first voxel.
    pub skip: u64,
    /// The sample type in the file.
    pub sample: SampleType,
    /// Whether multi-byte samples are big-endian.
    pub big_endian: bool,
}

/// An open decoder and how far into the decompressed stream it is.
struct Cursor {
    reader: Box<dyn Read + Send>,
    position: u64,
}

/// A volume read from a byte stream; see the module docs.
pub struct StreamSource {
    info: VolumeInfo,
    layout: StreamLayout,
    cursor: Option<Cursor>,
}

impl std::fmt::Debug for StreamSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StreamSource")
            .field("info", &self.info)
            .field("layout", &self.layout)
            .finish_non_exhaustive()
    }
}

impl StreamSource {
    /// A source over `layout`, after checking that the file can hold the voxels
    /// `info` describes (uncompressed: at least that many bytes; compressed: not
    /// more than deflate could expand the stream to).
    pub fn new(mut info: VolumeInfo, layout: StreamLayout) -> Result<StreamSource, Error> {
        info.voxel_type = layout.sample.voxel_type();
        let size = data_file_len(&info, &layout)?;
        if layout.file_offset > size {
            return Err(field(
                &info.path,
                "data offset",
                format!(
                    "the voxels would start at byte {} of {}, which has {size} bytes: expected \
                     an offset within the file (check the header size or byte skip)",
                    layout.file_offset,
                    layout.data_path.display()
                ),
            ));
        }
        let needed = layout
            .skip
            .checked_add(sample_bytes(&info, &layout))
            .ok_or_else(|| {
                field(
                    &info.path,
                    "byte skip",
                    format!(
                        "{} bytes to skip before the voxels: expected a skip within the data",
                        layout.skip
                    ),
                )
            })?;
        let available = size - layout.file_offset;
        match layout.compression {
            Compression::None if available < needed => {
                return Err(Error::Truncated {
                    path: layout.data_path.clone(),
                    expected: needed,
                    got: available,
                });
            }
            Compression::Gzip | Compression::Zlib
                if needed > available.saturating_mul(MAX_DEFLATE_RATIO) =>
            {
                return Err(field(
                    &info.path,
                    if layout.skip > 0 {
                        "byte skip or dimensions"
                    } else {
                        "dimensions"
                    },
                    format!(
                        "{} skipped bytes and {:?} voxels of {} bytes need {needed} bytes, more than \
                         the {available}-byte {} stream can expand to: expected a skip and \
                         dimensions that match the data",
                        layout.skip,
                        info.geometry.dims,
                        layout.sample.size(),
                        layout.compression.name()
                    ),
                ));
            }
            _ => {}
        }
        Ok(StreamSource {
            info,
            layout,
            cursor: None,
        })
    }

    /// Opens the stream at its start (after `file_offset`, decompressing).
    fn open_stream(&self) -> Result<Cursor, Error> {
        let path = &self.layout.data_path;
        let mut file = open_file(path)?;
        file.seek(SeekFrom::Start(self.layout.file_offset))
            .map_err(|source| Error::Io {
                path: path.clone(),
                source,
            })?;
        let buffered = BufReader::with_capacity(1 << 20, file);
        let reader: Box<dyn Read + Send> = match self.layout.compression {
            Compression::None => Box::new(buffered),
            Compression::Gzip => Box::new(MultiGzDecoder::new(buffered)),
            Compression::Zlib => Box::new(ZlibDecoder::new(buffered)),
        };
        Ok(Cursor {
            reader,
            position: 0,
        })
    }

    /// Turns an I/O error of the stream into a corrupt-data or I/O error.
    fn stream_error(&self, e: io::Error) -> Error {
        let path = self.layout.data_path.clone();
        match (self.layout.compression, e.kind()) {
            (
                Compression::Gzip | Compression::Zlib,
                io::ErrorKind::InvalidInput
                | io::ErrorKind::InvalidData
                | io::ErrorKind::UnexpectedEof,
            ) => Error::Corrupt {
                path,
                codec: self.layout.compression.name().into(),
                detail: e.to_string(),
            },
            _ => Error::Io { path, source: e },
        }
    }

    /// Reads `len` bytes at `start` of the decompressed stream (after `skip`).
    fn read_bytes(&mut self, start: u64, len: usize) -> Result<Vec<u8>, Error> {
        let mut buf = vec![0u8; len];
        self.read_into(start, &mut buf)?;
        Ok(buf)
    }

    /// Fills `buf` from `start` of the decompressed stream (after `skip`).
    fn read_into(&mut self, start: u64, buf: &mut [u8]) -> Result<(), Error> {
        if self.layout.compression == Compression::None {
            // Uncompressed: seek straight there, no decoder state to keep.
            let path = &self.layout.data_path;
            let io_err = |source| Error::Io {
                path: path.clone(),
                source,
            };
            let mut file: File = open_file(path)?;
            file.seek(SeekFrom::Start(self.layout.file_offset + start))
                .map_err(io_err)?;
            let got = read_full(&mut file, buf).map_err(io_err)?;
            return self.complete(buf.len(), got, start);
        }
        let mut cursor = match self.cursor.take() {
            Some(c) if c.position <= start => c,
            _ => self.open_stream()?,
        };
        let gap = start - cursor.position;
        let skipped = io::copy(&mut cursor.reader.by_ref().take(gap), &mut io::sink())
            .map_err(|e| self.stream_error(e))?;
        cursor.position += skipped;
        if skipped < gap {
            return Err(self.truncated(cursor.position));
        }
        let got = read_full(&mut cursor.reader, buf).map_err(|e| self.stream_error(e))?;
        cursor.position += got as u64;
        if cursor.position == self.layout.skip + sample_bytes(&self.info, &self.layout) {
            // The last voxel is read: run the decoder to the end of the stream so
            // it checks the stream's checksum (gzip CRC-32, zlib Adler-32), which
            // is the only way to catch corruption that still decodes.
            io::copy(&mut cursor.reader, &mut io::sink()).map_err(|e| self.stream_error(e))?;
        } else {
            self.cursor = Some(cursor);
        }
        self.complete(buf.len(), got, start)
    }

    fn complete(&self, wanted: usize, got: usize, start: u64) -> Result<(), Error> {
        if got < wanted {
            Err(self.truncated(start + got as u64))
        } else {
            Ok(())
        }
    }

    fn truncated(&self, got: u64) -> Error {
        Error::Truncated {
            path: self.layout.data_path.clone(),
            expected: self.layout.skip + sample_bytes(&self.info, &self.layout),
            got,
        }
    }
}

/// Bytes of `sample`s in a volume of `dims`.
pub fn volume_bytes(dims: [u32; 3], sample: SampleType) -> u64 {
    dims.iter().map(|&d| u64::from(d)).product::<u64>() * sample.size() as u64
}

/// The offset of voxels stored at the very end of an uncompressed file (NRRD's
/// `byte skip: -1`, MetaImage's `HeaderSize = -1`).
pub fn trailing_data_offset(
    data_path: &Path,
    dims: [u32; 3],
    sample: SampleType,
) -> Result<u64, Error> {
    let size = super::header::file_len(data_path)?;
    let total = volume_bytes(dims, sample);
    size.checked_sub(total).ok_or(Error::Truncated {
        path: data_path.to_owned(),
        expected: total,
        got: size,
    })
}

/// The size of the data file, which must be a regular file (a device such as
/// `/dev/zero` would never end).
fn data_file_len(info: &VolumeInfo, layout: &StreamLayout) -> Result<u64, Error> {
    let meta = std::fs::metadata(&layout.data_path).map_err(|source| {
        if source.kind() == io::ErrorKind::NotFound && layout.data_path != info.path {
            field(
                &info.path,
                "data file",
                format!(
                    "{} not found: expected the data file the header names",
                    layout.data_path.display()
                ),
            )
        } else {
            Error::Io {
                path: layout.data_path.clone(),
                source,
            }
        }
    })?;
    if !meta.is_file() {
        return Err(field(
            &info.path,
            "data file",
            format!(
                "{} is not a regular file: expected a file holding the voxels",
                layout.data_path.display()
            ),
        ));
    }
    Ok(meta.len())
}

/// Bytes of samples in the whole volume.
fn sample_bytes(info: &VolumeInfo, layout: &StreamLayout) -> u64 {
    volume_bytes(info.geometry.dims, layout.sample)
}

/// Reads until `buf` is full or the stream ends; returns the bytes read.
fn read_full(reader: &mut impl Read, buf: &mut [u8]) -> io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match reader.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

impl VolumeSource for StreamSource {
    fn info(&self) -> &VolumeInfo {
        &self.info
    }

    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<VoxelData, Error> {
        super::check_slab(&self.info, z0, depth)?;
        let slice = self.info.geometry.slice_voxels() * self.layout.sample.size() as u64;
        let start = self.layout.skip + u64::from(z0) * slice;
        let len = usize::try_from(u64::from(depth) * slice).map_err(|_| {
            field(
                &self.info.path,
                "slab",
                format!("{depth} slices do not fit in memory"),
            )
        })?;
        let big = self.layout.big_endian;
        if let SampleType::Voxel(t) = self.layout.sample {
            // Read straight into the voxels' memory, then fix the byte order there.
            let mut voxels = VoxelData::zeros(t, len / t.size());
            self.read_into(start, voxels.as_bytes_mut())?;
            if big != cfg!(target_endian = "big") {
                voxels.swap_bytes();
            }
            return Ok(voxels);
        }
        let bytes = self.read_bytes(start, len)?;
        Ok(match self.layout.sample {
            SampleType::Voxel(t) => VoxelData::from_bytes(t, &bytes, big),
            SampleType::F64 => VoxelData::F32(
                bytes
                    .chunks_exact(8)
                    .map(|b| {
                        let mut a = [0u8; 8];
                        a.copy_from_slice(b);
                        let v = if big {
                            f64::from_be_bytes(a)
                        } else {
                            f64::from_le_bytes(a)
                        };
                        v as f32
                    })
                    .collect(),
            ),
        })
    }
}
