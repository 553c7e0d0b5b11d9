//! [`Volume`]: a voxel grid held in memory, with its physical geometry and the map
//! from stored values to physical values.
//!
//! Voxels are stored x fastest, then y, then z (C order `[z][y][x]`), the layout of
//! every format voxserve reads. Index space follows patient LPS for medical data:
//! x grows towards the patient's left, y towards posterior, z towards superior.

use crate::{Error, Geometry};

/// The type of one stored voxel value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum VoxelType {
    /// Unsigned 8-bit integers.
    U8,
    /// Signed 8-bit integers.
    I8,
    /// Unsigned 16-bit integers.
    U16,
    /// Signed 16-bit integers.
    I16,
    /// Unsigned 32-bit integers.
    U32,
    /// Signed 32-bit integers.
    I32,
    /// 32-bit floats.
    F32,
}

impl VoxelType {
    /// Every voxel type.
    pub const ALL: [VoxelType; 7] = [
        VoxelType::U8,
        VoxelType::I8,
        VoxelType::U16,
        VoxelType::I16,
        VoxelType::U32,
        VoxelType::I32,
        VoxelType::F32,
    ];

    /// Bytes per voxel.
    pub fn size(self) -> usize {
        match self {
            VoxelType::U8 | VoxelType::I8 => 1,
            VoxelType::U16 | VoxelType::I16 => 2,
            VoxelType::U32 | VoxelType::I32 | VoxelType::F32 => 4,
        }
    }

    /// The largest stored value of an integer type, which a normalized GPU
    /// texture maps to 1.0; `None` for floats.
    pub fn max_stored(self) -> Option<f32> {
        match self {
            VoxelType::U8 => Some(f32::from(u8::MAX)),
            VoxelType::I8 => Some(f32::from(i8::MAX)),
            VoxelType::U16 => Some(f32::from(u16::MAX)),
            VoxelType::I16 => Some(f32::from(i16::MAX)),
            VoxelType::U32 => Some(u32::MAX as f32),
            VoxelType::I32 => Some(i32::MAX as f32),
            VoxelType::F32 => None,
        }
    }

    /// The name used in messages, file names and on the command line
    /// (`uint8`, `int8`, `uint16`, `int16`, `uint32`, `int32`, `float32`).
    pub fn name(self) -> &'static str {
        match self {
            VoxelType::U8 => "uint8",
            VoxelType::I8 => "int8",
            VoxelType::U16 => "uint16",
            VoxelType::I16 => "int16",
            VoxelType::U32 => "uint32",
            VoxelType::I32 => "int32",
            VoxelType::F32 => "float32",
        }
    }

    /// The type named `name` ([`VoxelType::name`], or `float` for `float32`).
    pub fn from_name(name: &str) -> Option<VoxelType> {
        if name == "float" {
            return Some(VoxelType::F32);
        }
        VoxelType::ALL.into_iter().find(|t| t.name() == name)
    }
}

/// A voxel value type: plain old data that widens to `f64` without loss.
pub trait Voxel: bytemuck::Pod + Into<f64> + PartialOrd + Send + Sync {
    /// The value from little-endian bytes (`size_of::<Self>()` of them).
    fn from_le(bytes: &[u8]) -> Self;
    /// The value from big-endian bytes.
    fn from_be(bytes: &[u8]) -> Self;
    /// The value nearest `v`: rounded to nearest and saturated for integers.
    fn from_f64(v: f64) -> Self;
}

macro_rules! impl_voxel {
    ($round:expr; $($t:ty),*) => {$(
        impl Voxel for $t {
            fn from_f64(v: f64) -> Self {
                // `as` saturates at the type's range (NaN becomes 0).
                $round(v) as $t
            }
            fn from_le(bytes: &[u8]) -> Self {
                let mut b = [0u8; size_of::<$t>()];
                b.copy_from_slice(bytes);
                <$t>::from_le_bytes(b)
            }
            fn from_be(bytes: &[u8]) -> Self {
                let mut b = [0u8; size_of::<$t>()];
                b.copy_from_slice(bytes);
                <$t>::from_be_bytes(b)
            }
        }
    )*};
}
impl_voxel!(f64::round; u8, i8, u16, i16, u32, i32);
impl_voxel!(std::convert::identity; f32);

/// The stored voxel values of a volume or a slab of one.
#[derive(Debug, Clone, PartialEq)]
pub enum VoxelData {
    /// Unsigned 8-bit voxels.
    U8(Vec<u8>),
    /// Signed 8-bit voxels.
    I8(Vec<i8>),
    /// Unsigned 16-bit voxels.
    U16(Vec<u16>),
    /// Signed 16-bit voxels.
    I16(Vec<i16>),
    /// Unsigned 32-bit voxels.
    U32(Vec<u32>),
    /// Signed 32-bit voxels.
    I32(Vec<i32>),
    /// 32-bit float voxels.
    F32(Vec<f32>),
}

/// Runs `$body` with `$v` bound to the typed vector inside a [`VoxelData`].
macro_rules! with_voxels {
    ($data:expr, $v:ident => $body:expr) => {
        match $data {
            $crate::VoxelData::U8($v) => $body,
            $crate::VoxelData::I8($v) => $body,
            $crate::VoxelData::U16($v) => $body,
            $crate::VoxelData::I16($v) => $body,
            $crate::VoxelData::U32($v) => $body,
            $crate::VoxelData::I32($v) => $body,
            $crate::VoxelData::F32($v) => $body,
        }
    };
}
pub(crate) use with_voxels;

macro_rules! impl_from_vec {
    ($($t:ty => $variant:ident),*) => {$(
        impl From<Vec<$t>> for VoxelData {
            fn from(v: Vec<$t>) -> VoxelData {
                VoxelData::$variant(v)
            }
        }
    )*};
}
impl_from_vec!(u8 => U8, i8 => I8, u16 => U16, i16 => I16, u32 => U32, i32 => I32, f32 => F32);

impl VoxelData {
    /// `len` zero voxels of type `ty`.
    pub fn zeros(ty: VoxelType, len: usize) -> VoxelData {
        match ty {
            VoxelType::U8 => VoxelData::U8(vec![0; len]),
            VoxelType::I8 => VoxelData::I8(vec![0; len]),
            VoxelType::U16 => VoxelData::U16(vec![0; len]),
            VoxelType::I16 => VoxelData::I16(vec![0; len]),
            VoxelType::U32 => VoxelData::U32(vec![0; len]),
            VoxelType::I32 => VoxelData::I32(vec![0; len]),
            VoxelType::F32 => VoxelData::F32(vec![0.0; len]),
        }
    }

    /// Decodes voxels of type `ty` from bytes in the given byte order.
    /// Trailing bytes that do not fill a voxel are ignored.
    pub fn from_bytes(ty: VoxelType, bytes: &[u8], big_endian: bool) -> VoxelData {
        fn decode<T: Voxel>(bytes: &[u8], big_endian: bool) -> Vec<T> {
            let chunks = bytes.chunks_exact(size_of::<T>());
            if big_endian {
                chunks.map(T::from_be).collect()
            } else {
                chunks.map(T::from_le).collect()
            }
        }
        match ty {
            VoxelType::U8 => VoxelData::U8(bytes.to_vec()),
            VoxelType::I8 => VoxelData::I8(bytemuck::cast_slice(bytes).to_vec()),
            VoxelType::U16 => VoxelData::U16(decode(bytes, big_endian)),
            VoxelType::I16 => VoxelData::I16(decode(bytes, big_endian)),
            VoxelType::U32 => VoxelData::U32(decode(bytes, big_endian)),
            VoxelType::I32 => VoxelData::I32(decode(bytes, big_endian)),
            VoxelType::F32 => VoxelData::F32(decode(bytes, big_endian)),
        }
    }

    /// The voxel type.
    pub fn voxel_type(&self) -> VoxelType {
        match self {
            VoxelData::U8(_) => VoxelType::U8,
            VoxelData::I8(_) => VoxelType::I8,
            VoxelData::U16(_) => VoxelType::U16,
            VoxelData::I16(_) => VoxelType::I16,
            VoxelData::U32(_) => VoxelType::U32,
            VoxelData::I32(_) => VoxelType::I32,
            VoxelData::F32(_) => VoxelType::F32,
        }
    }

    /// The number of voxels.
    pub fn len(&self) -> usize {
        with_voxels!(self, v => v.len())
    }

    /// Whether there are no voxels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The stored value at linear index `i`, widened to `f64` (exact for every type).
    pub fn get(&self, i: usize) -> f64 {
        with_voxels!(self, v => v[i].into())
    }

    /// The smallest and largest stored value (NaNs ignored), or `None` when there
    /// are no comparable voxels.
    pub fn stored_range(&self) -> Option<[f64; 2]> {
        fn range<T: Voxel>(v: &[T]) -> Option<[f64; 2]> {
            let mut values = v.iter().map(|&x| x.into()).filter(|x: &f64| !x.is_nan());
            let first = values.next()?;
            Some(values.fold([first, first], |[lo, hi], x| [lo.min(x), hi.max(x)]))
        }
        with_voxels!(self, v => range(v))
    }

    /// The voxels as little-endian bytes (the in-memory layout on every target
    /// voxserve builds for), ready for a GPU upload or a file.
    pub fn as_bytes(&self) -> &[u8] {
        with_voxels!(self, v => bytemuck::cast_slice(v))
    }

    /// The voxels' memory as bytes, to be filled in place.
    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        with_voxels!(self, v => bytemuck::cast_slice_mut(v))
    }

    /// Reverses the byte order of every voxel (for data stored in the other order).
    pub fn swap_bytes(&mut self) {
        match self {
            VoxelData::U8(_) | VoxelData::I8(_) => {}
            VoxelData::U16(v) => v.iter_mut().for_each(|x| *x = x.swap_bytes()),
            VoxelData::I16(v) => v.iter_mut().for_each(|x| *x = x.swap_bytes()),
            VoxelData::U32(v) => v.iter_mut().for_each(|x| *x = x.swap_bytes()),
            VoxelData::I32(v) => v.iter_mut().for_each(|x| *x = x.swap_bytes()),
            VoxelData::F32(v) => v
                .iter_mut()
                .for_each(|x| *x = f32::from_bits(x.to_bits().swap_bytes())),
        }
    }

    /// A copy of the voxels in `range` (linear indices).
    pub fn slice(&self, range: std::ops::Range<usize>) -> VoxelData {
        with_voxels!(self, v => VoxelData::from(v[range].to_vec()))
    }

    /// Appends `other`, which must hold the same voxel type.
    pub fn append(&mut self, other: VoxelData) -> Result<(), Error> {
        let (want, got) = (self.voxel_type(), other.voxel_type());
        match (self, other) {
            (VoxelData::U8(a), VoxelData::U8(b)) => a.extend(b),
            (VoxelData::I8(a), VoxelData::I8(b)) => a.extend(b),
            (VoxelData::U16(a), VoxelData::U16(b)) => a.extend(b),
            (VoxelData::I16(a), VoxelData::I16(b)) => a.extend(b),
            (VoxelData::U32(a), VoxelData::U32(b)) => a.extend(b),
            (VoxelData::I32(a), VoxelData::I32(b)) => a.extend(b),
            (VoxelData::F32(a), VoxelData::F32(b)) => a.extend(b),
            _ => {
                return Err(Error::InvalidVolume {
                    name: "slab".into(),
                    reason: format!(
                        "{} voxels appended to {}: expected one type",
                        got.name(),
                        want.name()
                    ),
                });
            }
        }
        Ok(())
    }
}

/// The linear map from stored values to physical values
/// (DICOM's RescaleSlope and RescaleIntercept): `physical = stored * slope + intercept`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ValueMap {
    /// Physical units per stored unit.
    pub slope: f32,
    /// The physical value of stored 0.
    pub intercept: f32,
}

impl ValueMap {
    /// Stored values are physical values.
    pub const IDENTITY: ValueMap = ValueMap {
        slope: 1.0,
        intercept: 0.0,
    };

    /// The physical value of a stored value.
    pub fn physical(self, stored: f64) -> f64 {
        stored * f64::from(self.slope) + f64::from(self.intercept)
    }
}

/// A volume held in memory: voxels, geometry and value map.
#[derive(Debug, Clone)]
pub struct Volume {
    /// A short name for listings and messages.
    pub name: String,
    /// Dimensions, spacing, origin and direction.
    pub geometry: Geometry,
    /// The stored values, x fastest.
    pub voxels: VoxelData,
    /// Stored → physical values.
    pub value_map: ValueMap,
    /// The smallest and largest physical value present.
    pub value_range: [f32; 2],
    /// The unit of physical values, e.g. `HU`, when known.
    pub unit: Option<String>,
    /// The imaging modality, e.g. `CT`, when known.
    pub modality: Option<String>,
}

impl Volume {
    /// Builds a volume and checks that its parts agree (the geometry's
    /// invariants, the voxel count against the dimensions, the value map); the
    /// value range is computed from the voxels.
    pub fn new(
        name: impl Into<String>,
        geometry: Geometry,
        voxels: VoxelData,
        value_map: ValueMap,
    ) -> Result<Volume, Error> {
        let name = name.into();
        let invalid = |reason: String| Error::InvalidVolume {
            name: name.clone(),
            reason,
        };
        geometry
            .check()
            .map_err(|fault| invalid(fault.to_string()))?;
        let (dims, count) = (geometry.dims, geometry.voxel_count());
        if voxels.len() as u64 != count {
            return Err(invalid(format!(
                "{} voxels for dims {dims:?}: expected {count}",
                voxels.len()
            )));
        }
        if !(value_map.slope.is_finite()
            && value_map.slope != 0.0
            && value_map.intercept.is_finite())
        {
            return Err(invalid(format!(
                "value map {value_map:?}: expected a finite non-zero slope and a finite intercept"
            )));
        }
        let stored = voxels
            .stored_range()
            .ok_or_else(|| invalid("no voxels".into()))?;
        let (a, b) = (value_map.physical(stored[0]), value_map.physical(stored[1]));
        Ok(Volume {
            name,
            geometry,
            voxels,
            value_map,
            value_range: [a.min(b) as f32, a.max(b) as f32],
            unit: None,
            modality: None,
        })
    }

    /// The voxel type.
    pub fn voxel_type(&self) -> VoxelType {
        self.voxels.voxel_type()
    }

    /// The number of voxels.
    pub fn voxel_count(&self) -> usize {
        self.voxels.len()
    }

    /// Linear index of voxel (x, y, z).
    pub fn index(&self, x: u32, y: u32, z: u32) -> usize {
        let [nx, ny, _] = self.geometry.dims;
        (z as usize * ny as usize + y as usize) * nx as usize + x as usize
    }

    /// The physical value of voxel (x, y, z).
    pub fn physical_at(&self, x: u32, y: u32, z: u32) -> f64 {
        self.value_map
            .physical(self.voxels.get(self.index(x, y, z)))
    }

    /// The stored voxels as little-endian bytes, ready for a GPU upload.
    pub fn voxel_bytes(&self) -> &[u8] {
        self.voxels.as_bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny(voxels: VoxelData) -> Result<Volume, Error> {
        Volume::new(
            "tiny",
            Geometry::new([2, 2, 2], [1.0, 1.0, 2.0]),
            voxels,
            ValueMap::IDENTITY,
        )
    }

    #[test]
    fn value_range_follows_the_value_map() {
        let v = Volume::new(
            "ct",
            Geometry::new([2, 1, 1], [1.0; 3]),
            VoxelData::U16(vec![24, 2048]),
            ValueMap {
                slope: 1.0,
                intercept: -1024.0,
            },
        )
        .expect("valid volume");
        assert_eq!(v.value_range, [-1000.0, 1024.0]);
        assert_eq!(v.physical_at(1, 0, 0), 1024.0);
    }

    #[test]
    fn a_negative_slope_still_gives_an_ordered_range() {
        let v = Volume::new(
            "inverted",
            Geometry::new([2, 1, 1], [1.0; 3]),
            VoxelData::U8(vec![0, 255]),
            ValueMap {
                slope: -1.0,
                intercept: 0.0,
            },
        )
        .expect("valid volume");
        assert_eq!(v.value_range, [-255.0, 0.0]);
    }

    #[test]
    fn voxel_count_must_match_dims() {
        let err = tiny(VoxelData::U8(vec![0; 7])).expect_err("7 voxels for 2x2x2");
        let msg = err.to_string();
        assert!(
            msg.contains("7 voxels") && msg.contains("expected 8"),
            "{msg}"
        );
    }

    #[test]
    fn spacing_must_be_positive() {
        let err = Volume::new(
            "flat",
            Geometry::new([1, 1, 1], [1.0, 0.0, 1.0]),
            VoxelData::U8(vec![0]),
            ValueMap::IDENTITY,
        )
        .expect_err("zero spacing");
        assert!(err.to_string().contains("spacing"), "{err}");
    }

    #[test]
    fn u16_bytes_are_little_endian() {
        let v = tiny(VoxelData::U16(vec![0x0102; 8])).expect("valid volume");
        assert_eq!(&v.voxel_bytes()[..2], &[0x02, 0x01]);
        assert_eq!(v.voxel_bytes().len(), 16);
    }
}
