//! CPU twin of `shaders/wgsl/shared/packed.wgsl`: addressing voxels in packed
//! block coordinates through the block index, for the `raycast` twin and the
//! light twins.

use glam::Vec3;
use wide::f32x4;

use blocks::packing::slot_edge;
use blocks::store::LEVELS;

use super::march::{intersect_box_inverse, inverse_direction};
use super::occupancy::VisibleBox;
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
    /// CPU only: per atlas texel, whether a sample blending from it may be
    /// visible ([`super::occupancy::visible_texels`]); `None`: all may be.
    pub visible_texels: Option<Vec<u64>>,
    /// CPU only: per block (x fastest), the box in its slot outside which
    /// no sample can be visible, found from `visible_texels` with them
    /// ([`super::occupancy::visible_boxes`]); `None`: all may be.
    pub visible_boxes: Option<Vec<VisibleBox>>,
    /// CPU only: the box in texture coordinates outside which no sample
    /// can be visible, found from `visible_boxes` with them
    /// ([`super::occupancy::visible_extent`]); `None`: all may be.
    pub visible_extent: Option<VisibleBox>,
    /// CPU only: boxes in texture coordinates outside all of which no
    /// sample can be visible, found from `visible_boxes` with them
    /// ([`super::occupancy::visible_cells`]); `None`: all may be.
    pub visible_cells: Option<Vec<VisibleBox>>,
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

/// Level-l texels per level-0 voxel, 2⁻ˡ, per level (a table: the walk
/// finds it per block it enters, where a division waited on the index's read).
const LEVEL_SCALE: [f32; LEVELS] = {
    let mut scale = [1.0; LEVELS];
    let mut level = 1;
    while level < LEVELS {
        scale[level] = scale[level - 1] * 0.5;
        level += 1;
    }
    scale
};

/// WGSL `voxel_edge`: the edge of a voxel of block `loc`'s level, in level-0 voxels.
pub fn voxel_edge(loc: &BlockLocation) -> f32 {
    1.0 / loc.scale
}

/// WGSL `block_of`.
#[inline(always)]
pub fn block_of(g: &PackedVolume, tc: Vec3) -> [i32; 3] {
    let last = g.block_grid.map(|n| (n - 1) as f32);
    let b = tc * Vec3::from(g.volume_dims) / BLOCK;
    // `floor(b)` clamped to the grid, as one clamp and one truncation of
    // three lanes: the bounds are whole numbers, so truncating the clamped
    // value is flooring it (NaN clamps to the low bound, as floor_i32
    // takes it to 0).
    let [x, y, z, _] = f32x4::from([b.x, b.y, b.z, 0.0])
        .max(f32x4::ZERO)
        .min(f32x4::from([last[0], last[1], last[2], 0.0]))
        .fast_trunc_int()
        .to_array();
    [x, y, z]
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
    loc.origin + block_texel(g, tc, loc) - 0.5
}

/// WGSL `block_texel`, [`atlas_texel`] less the block's `origin` and ½: `tc` in the
/// block's level texels from its corner, kept within its apron. Where the
/// block's slot lies in the atlas plays no part, so samples found from it do
/// not move by a rounding error when a layout puts the slot elsewhere.
#[inline(always)]
pub fn block_texel(g: &PackedVolume, tc: Vec3, loc: &BlockLocation) -> Vec3 {
    let p = tc * Vec3::from(g.volume_dims);
    let block = Vec3::new(
        loc.block[0] as f32,
        loc.block[1] as f32,
        loc.block[2] as f32,
    );
    let local = (p - block * BLOCK) * loc.scale;
    let edge = BLOCK * loc.scale;
    local.clamp(Vec3::splat(-0.5), Vec3::splat(edge + 0.5))
}

/// WGSL `empty_exit`.
pub fn empty_exit(g: &PackedVolume, origin: Vec3, dir: Vec3, loc: &BlockLocation) -> f32 {
    empty_exit_inverse(g, origin, inverse_direction(dir), loc)
}

/// [`empty_exit`] for the ray whose direction's [`inverse_direction`] is `inv`.
#[inline]
fn empty_exit_inverse(g: &PackedVolume, origin: Vec3, inv: Vec3, loc: &BlockLocation) -> f32 {
    let block = Vec3::new(
        loc.block[0] as f32,
        loc.block[1] as f32,
        loc.block[2] as f32,
    );
    let texel = Vec3::from(g.texel);
    let lo = block * BLOCK * texel;
    let hi = (lo + BLOCK * texel).min(Vec3::ONE);
    intersect_box_inverse(origin, inv, lo, hi).y
}

/// CPU only: the blocks of the samples along a light stage's ray `origin +
/// t·dir`, each found as WGSL `locate` finds it (`block_of` of the sample's
/// position), the index read only where the block changes. Within a block
/// the sample's slot position is an affine function of `t` (the same texels
/// and weights as `atlas_texel` within the slot, up to rounding).
#[derive(Debug, Clone, Copy)]
pub struct RayBlocks {
    /// The block of the last sample, and its location.
    pub loc: BlockLocation,
    /// The sample's position in `loc`'s slot is `slot_at_zero + t·slot_per_t`.
    slot_at_zero: Vec3,
    /// See `slot_at_zero`.
    slot_per_t: Vec3,
    origin: Vec3,
    dir: Vec3,
    /// `dir`'s [`inverse_direction`].
    inverse: Vec3,
}

impl RayBlocks {
    /// The ray's blocks, at the block holding `origin`.
    #[inline]
    pub fn new(packed: &PackedTexture, g: &PackedVolume, origin: Vec3, dir: Vec3) -> RayBlocks {
        let mut blocks = RayBlocks {
            loc: packed.locate_block(block_of(g, origin)),
            slot_at_zero: Vec3::ZERO,
            slot_per_t: Vec3::ZERO,
            origin,
            dir,
            inverse: inverse_direction(dir),
        };
        blocks.enter(g);
        blocks
    }

    /// Moves to the block of the sample at `t` (WGSL `locate`), and returns it.
    #[inline(always)]
    pub fn at(&mut self, packed: &PackedTexture, g: &PackedVolume, t: f32) -> &BlockLocation {
        let block = block_of(g, self.origin + self.dir * t);
        if block != self.loc.block {
            self.loc = packed.locate_block(block);
            self.enter(g);
        }
        &self.loc
    }

    /// WGSL `empty_exit` of the block.
    #[inline]
    pub fn exit(&self, g: &PackedVolume) -> f32 {
        empty_exit_inverse(g, self.origin, self.inverse, &self.loc)
    }

    /// The slot position's affine map for the block just entered.
    #[inline(always)]
    fn enter(&mut self, g: &PackedVolume) {
        let dims = Vec3::from(g.volume_dims);
        let b = self.loc.block;
        let corner = Vec3::new(b[0] as f32, b[1] as f32, b[2] as f32) * BLOCK;
        // `atlas_texel` in the slot, whose first interior texel is at the
        // apron's width (1): level-l texels from the block's corner, less ½.
        self.slot_at_zero = (self.origin * dims - corner) * self.loc.scale + 0.5;
        self.slot_per_t = self.dir * dims * self.loc.scale;
    }

    /// The position in the block's slot of the sample at `t` (not yet kept
    /// in the slot: [`SlotAtlas::sample_slot`] keeps it).
    #[inline(always)]
    pub fn slot_position(&self, t: f32) -> Vec3 {
        self.slot_at_zero + self.slot_per_t * t
    }

    /// Whether the sample at `t` is in the block of the last (WGSL
    /// `locate` finds it there). Along a ray each coordinate of `block_of`
    /// only grows or only shrinks with `t`, so a later sample in the block
    /// has every sample between in it too.
    #[inline(always)]
    pub fn holds(&self, g: &PackedVolume, t: f32) -> bool {
        block_of(g, self.origin + self.dir * t) == self.loc.block
    }

    /// [`RayBlocks::slot_position`] of four samples, their coordinates
    /// along x, y and z side by side (the same arithmetic lane by lane).
    #[inline(always)]
    pub fn slot_positions(&self, t: f32x4) -> [f32x4; 3] {
        [0, 1, 2].map(|a| f32x4::splat(self.slot_at_zero[a]) + f32x4::splat(self.slot_per_t[a]) * t)
    }
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
            scale: LEVEL_SCALE[usize::from(entry[3]).min(LEVELS - 1)],
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::block_of;
    use crate::cpu::texture::floor_i32;
    use crate::packed_volume::PackedVolume;

    #[test]
    fn block_of_is_the_floor_of_the_position_in_blocks_clamped_to_the_grid() {
        // A grid of 16 × 7 × 2 blocks whose last blocks are partial, read
        // on every face and a float's step either side of it, past the
        // grid's edges, and at NaN and infinities: each block must be the
        // floor of the position in blocks, clamped to the grid, lane by lane.
        let g = PackedVolume {
            texel: [1.0 / 256.0, 1.0 / 100.0, 1.0 / 20.0],
            reference_step: 1.0,
            volume_dims: [256.0, 100.0, 20.0],
            value_scale: 1.0,
            atlas_size: [1.0; 3],
            value_offset: 0.0,
            block_grid: [16, 7, 2],
            tf_len: 2,
        };
        let mut positions = vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -3e9,
            3e9,
            -0.0,
            -1e-30,
        ];
        for face in 0..=20 {
            for dims in g.volume_dims {
                let tc = face as f32 * 16.0 / dims;
                positions.extend([tc.next_down(), tc, tc.next_up(), tc + 0.3 / dims]);
            }
        }
        let mut compared = 0;
        for &x in &positions {
            for &y in positions.iter().step_by(7) {
                for &z in positions.iter().step_by(11) {
                    let tc = Vec3::new(x, y, z);
                    let b = tc * Vec3::from(g.volume_dims) / 16.0;
                    let want =
                        [0, 1, 2].map(|a| floor_i32(b[a]).clamp(0, g.block_grid[a] as i32 - 1));
                    assert_eq!(block_of(&g, tc), want, "at {tc}");
                    compared += 1;
                }
            }
        }
        assert!(compared > 20_000, "{compared}");
    }
}
