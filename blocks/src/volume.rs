//! [`Volume`]: a voxel grid held in memory, with its physical geometry and the map
//! from stored values to physical values.
//!
//! Voxels are stored x fastest, then y, then z (C order `[z][y][x]`), the layout of
//! every format voxserve reads. Index space follows patient LPS for medical data:
//! x grows towards the patient's left, y towards posterior, z towards superior.

use crate::Error;

/// The type of one stored voxel value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum VoxelType {
    /// Unsigned 8-bit values.
    U8,
    /// Unsigned 16-bit values.
    U16,
}

impl VoxelType {
    /// Bytes per voxel.
    pub fn size(self) -> usize {
        match self {
            VoxelType::U8 => 1,
            VoxelType::U16 => 2,
        }
    }

    /// The largest stored value, which a normalized GPU texture maps to 1.0.
    pub fn max_stored(self) -> f32 {
        match self {
            VoxelType::U8 => f32::from(u8::MAX),
            VoxelType::U16 => f32::from(u16::MAX),
        }
    }

    /// The name used in messages and file names (`uint8`, `uint16`).
    pub fn name(self) -> &'static str {
        match self {
            VoxelType::U8 => "uint8",
            VoxelType::U16 => "uint16",
        }
    }
}

/// The stored voxel values of a volume.
#[derive(Debug, Clone, PartialEq)]
pub enum VoxelData {
    /// 8-bit voxels.
    U8(Vec<u8>),
    /// 16-bit voxels.
    U16(Vec<u16>),
}

impl VoxelData {
    /// The voxel type.
    pub fn voxel_type(&self) -> VoxelType {
        match self {
            VoxelData::U8(_) => VoxelType::U8,
            VoxelData::U16(_) => VoxelType::U16,
        }
    }

    /// The number of voxels.
    pub fn len(&self) -> usize {
        match self {
            VoxelData::U8(v) => v.len(),
            VoxelData::U16(v) => v.len(),
        }
    }

    /// Whether there are no voxels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The stored value at linear index `i`, widened to `f32`.
    pub fn get(&self, i: usize) -> f32 {
        match self {
            VoxelData::U8(v) => f32::from(v[i]),
            VoxelData::U16(v) => f32::from(v[i]),
        }
    }

    /// The smallest and largest stored value, or `None` when there are no voxels.
    pub fn stored_range(&self) -> Option<[f32; 2]> {
        fn range<T: Copy + Ord + Into<f32>>(v: &[T]) -> Option<[f32; 2]> {
            let min = v.iter().copied().min()?;
            let max = v.iter().copied().max()?;
            Some([min.into(), max.into()])
        }
        match self {
            VoxelData::U8(v) => range(v),
            VoxelData::U16(v) => range(v),
        }
    }
}

/// The linear map from stored values to physical values
/// (DICOM's RescaleSlope and RescaleIntercept): `physical = stored * slope + intercept`.
#[derive(Debug, Clone, Copy, PartialEq)]
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
    pub fn physical(self, stored: f32) -> f32 {
        stored * self.slope + self.intercept
    }
}

/// A volume held in memory: voxels, geometry and value map.
#[derive(Debug, Clone)]
pub struct Volume {
    /// A short name for listings and messages.
    pub name: String,
    /// Voxels along x, y and z.
    pub dims: [u32; 3],
    /// Distance between voxel centres along x, y and z, in millimetres.
    pub spacing: [f32; 3],
    /// The physical position of the centre of voxel (0, 0, 0), in millimetres.
    pub origin: [f32; 3],
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
    /// Builds a volume and checks that its parts agree; the value range is computed
    /// from the voxels.
    pub fn new(
        name: impl Into<String>,
        dims: [u32; 3],
        spacing: [f32; 3],
        voxels: VoxelData,
        value_map: ValueMap,
    ) -> Result<Volume, Error> {
        let name = name.into();
        let invalid = |reason: String| Error::InvalidVolume {
            name: name.clone(),
            reason,
        };
        if dims.contains(&0) {
            return Err(invalid(format!(
                "dims {dims:?}: expected at least one voxel along every axis"
            )));
        }
        let count = dims.iter().map(|&d| d as usize).product::<usize>();
        if voxels.len() != count {
            return Err(invalid(format!(
                "{} voxels for dims {dims:?}: expected {count}",
                voxels.len()
            )));
        }
        if let Some(s) = spacing.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return Err(invalid(format!(
                "spacing {spacing:?} holds {s}: expected finite positive millimetres"
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
            dims,
            spacing,
            origin: [0.0; 3],
            voxels,
            value_map,
            value_range: [a.min(b), a.max(b)],
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
        let [nx, ny, _] = self.dims;
        (z as usize * ny as usize + y as usize) * nx as usize + x as usize
    }

    /// The physical value of voxel (x, y, z).
    pub fn physical_at(&self, x: u32, y: u32, z: u32) -> f32 {
        self.value_map
            .physical(self.voxels.get(self.index(x, y, z)))
    }

    /// The extent of the volume's box in millimetres: each voxel covers one
    /// spacing around its centre, so the box is `dims * spacing`.
    pub fn extent_mm(&self) -> [f32; 3] {
        [
            self.dims[0] as f32 * self.spacing[0],
            self.dims[1] as f32 * self.spacing[1],
            self.dims[2] as f32 * self.spacing[2],
        ]
    }

    /// The stored voxels as little-endian bytes, ready for a GPU upload.
    pub fn voxel_bytes(&self) -> &[u8] {
        match &self.voxels {
            VoxelData::U8(v) => v,
            // GPU uploads expect little-endian bytes; every target wgpu runs on is
            // little-endian, so the in-memory layout is already right.
            VoxelData::U16(v) => bytemuck::cast_slice(v),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny(voxels: VoxelData) -> Result<Volume, Error> {
        Volume::new(
            "tiny",
            [2, 2, 2],
            [1.0, 1.0, 2.0],
            voxels,
            ValueMap::IDENTITY,
        )
    }

    #[test]
    fn value_range_follows_the_value_map() {
        let v = Volume::new(
            "ct",
            [2, 1, 1],
            [1.0; 3],
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
            [2, 1, 1],
            [1.0; 3],
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
            [1, 1, 1],
            [1.0, 0.0, 1.0],
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
