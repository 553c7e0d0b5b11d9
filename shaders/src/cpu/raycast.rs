//! CPU twin of the `raycast` stage over packed blocks (`shaders/wgsl/raycast.wgsl`),
//! function for function.

use glam::Vec3;

use super::Texture3d;
use super::march::{Storage, intersect_box, march};
use crate::raycast::RaycastParams;

/// Edge of a block in level-0 voxels.
const BLOCK: f32 = 16.0;
/// The index's level entry of a block that is not stored.
const EMPTY_LEVEL: u16 = u16::MAX;

/// The packed stage's bindings on the CPU: the atlas and the block index.
#[derive(Debug, Clone)]
pub struct PackedTexture {
    /// The atlas texels as the GPU samples them.
    pub atlas: Texture3d,
    /// Per block (x fastest): atlas position of the first interior texel, level.
    pub index: Vec<[u16; 4]>,
    /// Blocks along x, y, z.
    pub grid: [u32; 3],
}

/// WGSL `Location` of the packed stage.
#[derive(Debug, Clone, Copy)]
pub struct BlockLocation {
    empty: bool,
    block: [i32; 3],
    origin: Vec3,
    scale: f32,
}

impl PackedTexture {
    fn entry(&self, block: [i32; 3]) -> [u16; 4] {
        let [gx, gy, _] = self.grid.map(|g| g as usize);
        self.index[(block[2] as usize * gy + block[1] as usize) * gx + block[0] as usize]
    }
}

impl Storage for PackedTexture {
    type Location = BlockLocation;

    fn locate(&self, p: &RaycastParams, tc: Vec3) -> BlockLocation {
        let v = tc * Vec3::from(p.volume_dims);
        let last = p.block_grid.map(|g| g as i32 - 1);
        let b = (v / BLOCK).floor();
        let block = [
            (b.x as i32).clamp(0, last[0]),
            (b.y as i32).clamp(0, last[1]),
            (b.z as i32).clamp(0, last[2]),
        ];
        let entry = self.entry(block);
        BlockLocation {
            empty: entry[3] == EMPTY_LEVEL,
            block,
            origin: Vec3::new(
                f32::from(entry[0]),
                f32::from(entry[1]),
                f32::from(entry[2]),
            ),
            scale: 1.0 / (1u32 << u32::from(entry[3]).min(4)) as f32,
        }
    }

    fn is_empty(loc: &BlockLocation) -> bool {
        loc.empty
    }

    fn sample_at(&self, p: &RaycastParams, tc: Vec3, loc: &BlockLocation) -> f32 {
        let v = tc * Vec3::from(p.volume_dims);
        let block = Vec3::new(
            loc.block[0] as f32,
            loc.block[1] as f32,
            loc.block[2] as f32,
        );
        let local = (v - block * BLOCK) * loc.scale;
        let edge = BLOCK * loc.scale;
        let inside = local.clamp(Vec3::splat(-0.5), Vec3::splat(edge + 0.5));
        self.atlas
            .sample_level((loc.origin + inside) / Vec3::from(p.atlas_size))
    }

    fn sample_neighbour(&self, p: &RaycastParams, tc: Vec3, home: &BlockLocation) -> f32 {
        let b = (tc * Vec3::from(p.volume_dims) / BLOCK).floor();
        let block = [b.x as i32, b.y as i32, b.z as i32];
        if block == home.block {
            return self.sample_at(p, tc, home);
        }
        let other = self.locate(p, tc);
        if other.empty {
            return self.sample_at(p, tc, home);
        }
        self.sample_at(p, tc, &other)
    }

    fn empty_exit(&self, p: &RaycastParams, origin: Vec3, dir: Vec3, loc: &BlockLocation) -> f32 {
        let texel = Vec3::from(p.texel);
        let block = Vec3::new(
            loc.block[0] as f32,
            loc.block[1] as f32,
            loc.block[2] as f32,
        );
        let lo = block * BLOCK * texel;
        let hi = (lo + BLOCK * texel).min(Vec3::ONE);
        intersect_box(origin, dir, lo, hi).y
    }
}

/// Renders like the `raycast` dispatch: packed blocks through the block index.
pub fn raycast(
    params: &RaycastParams,
    packed: &PackedTexture,
    transfer_function: &[[f32; 4]],
    output: &mut [u8],
) {
    march(params, packed, transfer_function, output);
}
