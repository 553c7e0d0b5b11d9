//! What the store tests share: a volume in memory as a source, a generated
//! volume, and resealing a store after a deliberate change.

use std::path::Path;

use blocks::ingest::{self, VolumeInfo, VolumeSource};
use blocks::store::{self, BLOCK};
use blocks::{Error, Geometry, ValueMap, VoxelData};

/// An in-memory volume as a source, optionally failing at a slab.
#[derive(Debug)]
pub struct Memory {
    pub info: VolumeInfo,
    pub voxels: VoxelData,
    pub fail_at_slab: Option<u32>,
}

impl Memory {
    pub fn new(dims: [u32; 3], voxels: VoxelData) -> Memory {
        Memory {
            info: VolumeInfo {
                path: "memory.raw".into(),
                format: ingest::Format::Raw,
                geometry: Geometry {
                    dims,
                    spacing: [0.5, 0.75, 2.0],
                    origin: [10.0, -20.0, 30.0],
                    direction: blocks::geometry::IDENTITY_DIRECTION,
                },
                voxel_type: voxels.voxel_type(),
                value_map: ValueMap {
                    slope: 1.0,
                    intercept: -1024.0,
                },
                unit: Some("HU".into()),
                modality: Some("CT".into()),
                description: None,
                study: ingest::Study::default(),
                notes: vec![],
            },
            voxels,
            fail_at_slab: None,
        }
    }

    pub fn at(&self, x: u32, y: u32, z: u32) -> f64 {
        let [nx, ny, _] = self.info.geometry.dims;
        self.voxels.get(((z * ny + y) * nx + x) as usize)
    }
}

impl VolumeSource for Memory {
    fn info(&self) -> &VolumeInfo {
        &self.info
    }

    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<VoxelData, Error> {
        if self.fail_at_slab == Some(z0 / BLOCK) && depth <= BLOCK {
            return Err(Error::InvalidVolume {
                name: "memory".into(),
                reason: "injected failure".into(),
            });
        }
        let slice = (self.info.geometry.dims[0] * self.info.geometry.dims[1]) as usize;
        let range = z0 as usize * slice..(z0 + depth) as usize * slice;
        Ok(self.voxels.slice(range))
    }
}

/// A deterministic pseudo-random u16 volume with structure (so levels differ).
pub fn noise_u16(dims: [u32; 3]) -> VoxelData {
    let n = dims.iter().product::<u32>();
    VoxelData::U16(
        (0..n)
            .map(|i| {
                let h = u64::from(i).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 52;
                (h as u16).wrapping_add((i % dims[0]) as u16 * 37)
            })
            .collect(),
    )
}

/// Writes the manifest of the store in `folder` again, after a test changed
/// its metadata on purpose, so that opening gets past the checksums to the
/// checks behind them.
pub fn reseal(folder: &Path) {
    store::Manifest::of_folder(folder)
        .and_then(|m| m.write(folder))
        .expect("manifest");
}
