//! CPU twin of `shaders/wgsl/shared/packed.wgsl`: addressing voxels in packed
//! block coordinates through the block index, for the `raycast` twin and the
//! light twins.

use glam::Vec3;

use blocks::packing::slot_edge;
use blocks::store::LEVELS;

use super::march::intersect_box;
use super::texture::floor3;
use super::{ColourTexture, SlotAtlas, Texture3d};
use crate::illumination::Mode;
use crate::packed_volume::PackedVolume;

/// Edge of a block in level-0 voxels.
pub const BLOCK: f32 = 16.0;
/// The index's level entry of a block that is not stored.
pub const EMPTY_LEVEL: u16 = u16::MAX;

/// The packed stages' voxel bindings on the CPU: the atlas, the block index,
/// and — for the lit ray caster — the light volume.
#[derive(Debug, Clone)]
pub struct PackedTexture {
    /// The atlas texels as the GPU samples them, slot by slot in memory.
    pub atlas: SlotAtlas,
    /// Per block (x fastest): atlas position of the first interior texel, level.
    pub index: Vec<[u16; 4]>,
    /// Blocks along x, y, z.
    pub grid: [u32; 3],
    /// The stored light I_s (lit rendering only), in the atlas's slots
    /// ([`SlotAtlas::with_texels_of`] the atlas-shaped light volume).
    pub light: Option<SlotAtlas>,
    /// The light cache of extinction-based illumination, grid-shaped, its
    /// colour channels side by side.
    pub light_cache: Option<ColourTexture>,
    /// Which of the two lights the ray caster reads, as the GPU compiles
    /// the mode's `raycast` stage (with `light_volume.wgsl` or
    /// `light_cache.wgsl`): a renderer keeps both while frames of either
    /// mode come.
    pub lit_by: Option<Mode>,
    /// CPU only: per block, its cells that may be visible under the current
    /// transfer function ([`super::occupancy`]); `None`: all may be.
    pub visible_cells: Option<Vec<u64>>,
    /// CPU only: per atlas texel, whether a sample blending from it may be
    /// visible ([`super::occupancy::visible_texels`]); `None`: all may be.
    pub visible_texels: Option<Vec<u64>>,
}

/// WGSL `Location`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlockLocation {
    /// The block is not stored.
    pub empty: bool,
    /// The block (x, y, z in the block grid).
    pub block: [i32; 3],
    /// Atlas texel position of the block's first interior texel.
    pub origin: Vec3,
    /// Level-l texels per level-0 voxel.
    pub scale: f32,
    /// CPU only: where the block's slot starts in the [`SlotAtlas`]'s texels.
    pub slot: usize,
    /// CPU only: the slot's edge in texels, its apron included.
    pub slot_edge: usize,
}

/// WGSL `voxel_edge`: the edge of a voxel of block `loc`'s level, in level-0 voxels.
pub fn voxel_edge(loc: &BlockLocation) -> f32 {
    1.0 / loc.scale
}

/// WGSL `block_of`.
#[inline(always)]
pub fn block_of(g: &PackedVolume, tc: Vec3) -> [i32; 3] {
    let last = g.block_grid.map(|n| n as i32 - 1);
    let b = floor3(tc * Vec3::from(g.volume_dims) / BLOCK);
    [
        (b.x as i32).clamp(0, last[0]),
        (b.y as i32).clamp(0, last[1]),
        (b.z as i32).clamp(0, last[2]),
    ]
}

/// WGSL `atlas_coord`.
pub fn atlas_coord(g: &PackedVolume, tc: Vec3, loc: &BlockLocation) -> Vec3 {
    (atlas_texel(g, tc, loc) + 0.5) / Vec3::from(g.atlas_size)
}

/// [`atlas_coord`] in texels (texel centres at integers), what
/// [`Texture3d::sample_texel`] reads: inside the block's slot, its apron
/// included, so every texel trilinear filtering touches is the block's own.
#[inline(always)]
pub fn atlas_texel(g: &PackedVolume, tc: Vec3, loc: &BlockLocation) -> Vec3 {
    let p = tc * Vec3::from(g.volume_dims);
    let block = Vec3::new(
        loc.block[0] as f32,
        loc.block[1] as f32,
        loc.block[2] as f32,
    );
    let local = (p - block * BLOCK) * loc.scale;
    let edge = BLOCK * loc.scale;
    let inside = local.clamp(Vec3::splat(-0.5), Vec3::splat(edge + 0.5));
    loc.origin + inside - 0.5
}

/// WGSL `empty_exit`.
pub fn empty_exit(g: &PackedVolume, origin: Vec3, dir: Vec3, loc: &BlockLocation) -> f32 {
    let block = Vec3::new(
        loc.block[0] as f32,
        loc.block[1] as f32,
        loc.block[2] as f32,
    );
    let texel = Vec3::from(g.texel);
    let lo = block * BLOCK * texel;
    let hi = (lo + BLOCK * texel).min(Vec3::ONE);
    intersect_box(origin, dir, lo, hi).y
}

impl PackedTexture {
    /// The data at `tc` in block `loc`'s slot (positions outside the block
    /// clamped to its apron), filtered as the GPU filters its atlas there:
    /// read straight from the slot, whose texels are contiguous, instead of
    /// finding each of the eight texels' slot from its atlas position.
    #[inline]
    pub fn sample_block(&self, g: &PackedVolume, tc: Vec3, loc: &BlockLocation) -> f32 {
        self.atlas.sample_block(g, tc, loc)
    }

    /// Lights the ray caster with `light_volume`, the light I_s in the
    /// atlas's shape (as the light stages write it), read slot by slot.
    pub fn set_light(&mut self, light_volume: Vec<f32>) {
        let light = Texture3d::new(self.atlas.dims(), light_volume);
        self.light = Some(self.atlas.with_texels_of(&light, &self.index));
        self.lit_by = Some(Mode::GlobalLight);
    }

    /// Lights the ray caster with `cache`, extinction-based illumination's
    /// light cache.
    pub fn set_light_cache(&mut self, cache: ColourTexture) {
        self.light_cache = Some(cache);
        self.lit_by = Some(Mode::Extinction);
    }

    /// WGSL `locate`.
    pub fn locate(&self, g: &PackedVolume, tc: Vec3) -> BlockLocation {
        self.locate_block(block_of(g, tc))
    }

    /// [`PackedTexture::locate`] for a step from `last`, the location of the
    /// step before, whose block the next often shares (then not looked up).
    #[inline(always)]
    pub fn locate_near(&self, g: &PackedVolume, tc: Vec3, last: &BlockLocation) -> BlockLocation {
        let block = block_of(g, tc);
        if block == last.block {
            return *last;
        }
        self.locate_block(block)
    }

    /// Where `block` (in the grid) is in the index and the per-block tables.
    #[inline]
    pub fn block_index(&self, block: [i32; 3]) -> usize {
        let [gx, gy, _] = self.grid.map(|n| n as usize);
        (block[2] as usize * gy + block[1] as usize) * gx + block[0] as usize
    }

    /// The location of every sample in `block`: the index entry read.
    #[inline(always)]
    pub fn locate_block(&self, block: [i32; 3]) -> BlockLocation {
        let b = self.block_index(block);
        let entry = self.index[b];
        let empty = entry[3] == EMPTY_LEVEL;
        let slot = self.atlas.slot_base(b);
        debug_assert!(
            empty || slot.is_some(),
            "block {b} is indexed but has no slot"
        );
        BlockLocation {
            empty,
            slot: slot.unwrap_or(0),
            slot_edge: slot_edge(usize::from(entry[3]).min(LEVELS - 1)) as usize,
            block,
            origin: Vec3::new(
                f32::from(entry[0]),
                f32::from(entry[1]),
                f32::from(entry[2]),
            ),
            scale: 1.0 / (1u32 << u32::from(entry[3]).min(4)) as f32,
        }
    }
}
