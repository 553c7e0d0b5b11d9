//! A series' pixels: the one [`PixelFormat`] every slice must share, and
//! decoding a slice (any transfer syntax dicom-pixeldata reads) into values in
//! the output domain: stored bits selected and sign-extended, MONOCHROME1
//! inverted, padding marked, and rescaled when slices disagree on the rescale.

use dicom_encoding::TransferSyntaxIndex;
use dicom_object::DefaultDicomObject;
use dicom_pixeldata::PixelDecoder;
use dicom_transfer_syntax_registry::TransferSyntaxRegistry;

use super::bounds;
use super::slice_header::SliceHeader;
use crate::ingest::boundary;
use crate::ingest::header::field;
use crate::{Error, VoxelData, VoxelType};

/// How stored samples become output voxels.
#[derive(Debug, Clone, Copy)]
pub(super) struct PixelFormat {
    bits_allocated: u16,
    bits_stored: u16,
    high_bit: u16,
    signed: bool,
    pub(super) monochrome1: bool,
}

impl PixelFormat {
    /// The pixel format of a series: every slice must share the first's
    /// BitsAllocated, BitsStored and PixelRepresentation, and be a grayscale
    /// single-frame image; the bits must be ones this reader decodes.
    pub(super) fn of_series(slices: &[SliceHeader]) -> Result<PixelFormat, Error> {
        check_one_format(slices)?;
        let first = &slices[0];
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
        Ok(PixelFormat {
            bits_allocated: first.bits_allocated,
            bits_stored: first.bits_stored,
            high_bit: first.high_bit,
            signed: first.pixel_representation == 1,
            monochrome1: first.photometric == "MONOCHROME1",
        })
    }

    /// Bytes per sample in the decoded pixel data.
    pub(super) fn sample_bytes(&self) -> u16 {
        self.bits_allocated / 8
    }

    /// The voxel type that holds every stored value.
    pub(super) fn voxel_type(&self) -> VoxelType {
        match (self.bits_allocated, self.signed) {
            (8, false) => VoxelType::U8,
            (8, true) => VoxelType::I8,
            (16, false) => VoxelType::U16,
            (16, true) => VoxelType::I16,
            (_, false) => VoxelType::U32,
            (_, true) => VoxelType::I32,
        }
    }

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

/// Checks that every slice shares the first's BitsAllocated, BitsStored and
/// PixelRepresentation and is a grayscale single-frame image.
fn check_one_format(slices: &[SliceHeader]) -> Result<(), Error> {
    let first = &slices[0];
    for s in slices {
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
    }
    Ok(())
}

/// Opens the file of slice `s` whole (its element lengths checked against
/// the file first), inside the panic boundary.
pub(super) fn open(s: &SliceHeader) -> Result<DefaultDicomObject, Error> {
    boundary::guard(&s.path, "DICOM", || {
        bounds::check_lengths(&s.path, false)?;
        dicom_object::open_file(&s.path).map_err(|e| {
            field(
                &s.path,
                "file",
                format!("{e}: expected a readable DICOM file"),
            )
        })
    })
}

/// Decodes slice `s` — its frame, for a multi-frame image — from `obj`, its
/// file, inside the panic boundary, then hands the decoded bytes (at least
/// one sample per pixel) to `use_pixels`.
fn with_decoded<T>(
    obj: &DefaultDicomObject,
    s: &SliceHeader,
    format: &PixelFormat,
    use_pixels: impl FnOnce(&[u8]) -> T,
) -> Result<T, Error> {
    let syntax = obj
        .meta()
        .transfer_syntax()
        .trim_end_matches('\0')
        .to_owned();
    let codec = match TransferSyntaxRegistry.get(&syntax) {
        Some(ts) => format!("{} ({syntax}) pixel data", ts.name()),
        None => format!("pixel data (transfer syntax {syntax})"),
    };
    let decoded = boundary::guard(&s.path, &codec, || {
        let decoded = if s.frames > 1 {
            obj.decode_pixel_data_frame(s.frame)
        } else {
            obj.decode_pixel_data()
        };
        decoded.map_err(|e| Error::Corrupt {
            path: s.path.clone(),
            codec: if s.frames > 1 {
                format!("{codec}, frame {}", s.frame + 1)
            } else {
                codec.clone()
            },
            detail: e.to_string(),
        })
    })?;
    let count = s.rows as usize * s.columns as usize;
    let bytes = decoded.data();
    let needed = count * usize::from(format.sample_bytes());
    if bytes.len() < needed {
        return Err(Error::Truncated {
            path: s.path.clone(),
            expected: needed as u64,
            got: bytes.len() as u64,
        });
    }
    Ok(use_pixels(&bytes[..needed]))
}

/// The output-domain value of pixel `p` of the decoded `bytes`, `None` when it
/// is padding. With `rescale_each`, values are rescaled to physical ones by the
/// slice's own RescaleSlope and RescaleIntercept.
fn value(
    s: &SliceHeader,
    format: &PixelFormat,
    rescale_each: bool,
    bytes: &[u8],
    p: usize,
) -> Option<f64> {
    let stored = format.sample(bytes, p);
    if s.padding
        .is_some_and(|(lo, hi)| (lo..=hi).contains(&stored))
    {
        return None;
    }
    let (smin, smax) = format.stored_range();
    let v = if format.monochrome1 {
        smin + smax - stored
    } else {
        stored
    };
    Some(if rescale_each {
        v as f64 * s.slope + s.intercept
    } else {
        v as f64
    })
}

/// The lowest value of slice `s` that is not padding (infinity when all is).
pub(super) fn lowest_unpadded(
    obj: &DefaultDicomObject,
    s: &SliceHeader,
    format: &PixelFormat,
    rescale_each: bool,
) -> Result<f64, Error> {
    with_decoded(obj, s, format, |bytes| {
        let count = bytes.len() / usize::from(format.sample_bytes());
        (0..count)
            .filter_map(|p| value(s, format, rescale_each, bytes, p))
            .fold(f64::INFINITY, f64::min)
    })
}

/// Decodes slice `s` straight into voxels of `voxel_type` (a few bytes per
/// pixel: the file, its decoded pixel data and the voxels), padded pixels set
/// to `fill`.
pub(super) fn decode(
    obj: &DefaultDicomObject,
    s: &SliceHeader,
    format: &PixelFormat,
    rescale_each: bool,
    fill: f64,
    voxel_type: VoxelType,
) -> Result<VoxelData, Error> {
    with_decoded(obj, s, format, |bytes| {
        let count = bytes.len() / usize::from(format.sample_bytes());
        let v = (0..count).map(|p| value(s, format, rescale_each, bytes, p).unwrap_or(fill));
        // Values fit their type: they come from that many stored bits.
        match voxel_type {
            VoxelType::U8 => VoxelData::U8(v.map(|x| x as u8).collect()),
            VoxelType::I8 => VoxelData::I8(v.map(|x| x as i8).collect()),
            VoxelType::U16 => VoxelData::U16(v.map(|x| x as u16).collect()),
            VoxelType::I16 => VoxelData::I16(v.map(|x| x as i16).collect()),
            VoxelType::U32 => VoxelData::U32(v.map(|x| x as u32).collect()),
            VoxelType::I32 => VoxelData::I32(v.map(|x| x as i32).collect()),
            VoxelType::F32 => VoxelData::F32(v.map(|x| x as f32).collect()),
        }
    })
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
