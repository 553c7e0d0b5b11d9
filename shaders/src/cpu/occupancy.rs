//! Transparent texels inside blocks, for the CPU ray caster: a bit per texel
//! of the atlas that is clear where the transfer function gives zero
//! opacity to every value trilinear filtering can blend from the 2×2×2
//! texels from it. With empty-space skipping on, the march drops the
//! samples whose texels are all clear without reading them; they would
//! have been invisible, so every pixel stays what the GPU draws (its march
//! looks at each such sample and drops it; `tests/tests/raycast.rs` checks
//! skipping changes no pixel). Computed per transfer function and set of
//! shown blocks.

use blocks::packing::slot_edge;
use blocks::store::{LEVELS, grid_position};
use glam::Vec3;
use rayon::prelude::*;

use super::march::{inverse_direction, table_position};
use super::packed::BLOCK;
use super::slot_atlas::{SLOT_APRON, SlotAtlas};
use crate::packed_volume::PackedVolume;

/// Which texel values `classify` may make visible.
struct Visibility {
    /// `visible_before[i]`: table entries before `i` with opacity above zero.
    visible_before: Vec<u32>,
    value_scale: f32,
    value_offset: f32,
}

impl Visibility {
    fn new(g: &PackedVolume, transfer_function: &[[f32; 4]]) -> Self {
        let mut visible_before = Vec::with_capacity(transfer_function.len() + 1);
        visible_before.push(0u32);
        for entry in transfer_function {
            let last = visible_before.last().copied().unwrap_or(0);
            visible_before.push(last + u32::from(entry[3] > 0.0));
        }
        Visibility {
            visible_before,
            value_scale: g.value_scale,
            value_offset: g.value_offset,
        }
    }

    /// Any entry `classify` may blend for a texel value in `lo..=hi` opaque?
    fn any(&self, lo: f32, hi: f32) -> bool {
        let n = self.visible_before.len() as i32 - 1;
        if n <= 0 {
            return false;
        }
        let (a, b) = (
            lo * self.value_scale + self.value_offset,
            hi * self.value_scale + self.value_offset,
        );
        let tf_len = n as u32;
        let first = table_position(tf_len, a.min(b)).0.clamp(0, n - 1) as usize;
        let last = (table_position(tf_len, a.max(b)).0 + 1).clamp(0, n - 1) as usize;
        self.visible_before[last + 1] > self.visible_before[first]
    }
}

/// Per texel of the atlas (bit `i % 64` of word `i / 64` for texel `i` of
/// [`SlotAtlas::texels`]), set where a sample whose lowest texel it is may
/// be visible: where the transfer function gives opacity to a value between
/// the least and the greatest of the 2×2×2 texels from it (trilinear
/// filtering blends nothing else). Set for texels on a slot's last row,
/// column or slice, which are never a sample's lowest.
pub fn visible_texels(
    atlas: &SlotAtlas,
    g: &PackedVolume,
    transfer_function: &[[f32; 4]],
) -> Vec<u64> {
    let any_visible = Visibility::new(g, transfer_function);
    let texels = atlas.texels();
    let mut bits = vec![0u64; texels.len().div_ceil(64)];
    for level in 0..LEVELS {
        let region = atlas.region_texels(level);
        let words = region.start / 64..region.end.div_ceil(64).min(bits.len());
        let (Some(words), Some(region)) = (bits.get_mut(words), texels.get(region)) else {
            continue;
        };
        match slot_edge(level) {
            18 => region_visible::<18>(region, words, &any_visible),
            10 => region_visible::<10>(region, words, &any_visible),
            6 => region_visible::<6>(region, words, &any_visible),
            4 => region_visible::<4>(region, words, &any_visible),
            _ => region_visible::<3>(region, words, &any_visible),
        }
    }
    bits
}

/// The box in a block's slot outside which none of its samples can be
/// visible, in the slot's texel coordinates: per axis, from the least to
/// one past the greatest coordinate of the texels [`visible_texels`] sets
/// (a sample blends from the 2×2×2 texels whose lowest it lies within a
/// texel of; the slot's last texels, never a sample's lowest, left out),
/// widened by [`BOX_MARGIN`], and on to infinity where it reaches the
/// slot's first or last texel (the sampler clamps positions past them into
/// the slot). Empty (`lo` above `hi`) where no sample in the slot can be
/// visible. With empty-space skipping the march takes only the samples of
/// a ray within it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisibleBox {
    /// The least corner.
    pub lo: Vec3,
    /// The greatest corner.
    pub hi: Vec3,
}

/// How far (texels) outside a [`VisibleBox`]'s texels a sample must lie to
/// be left out: far more than the rounding of the samples' positions,
/// which the march finds from the ray parameter in another order.
pub const BOX_MARGIN: f32 = 0.05;

impl VisibleBox {
    /// A box holding nothing.
    pub const EMPTY: VisibleBox = VisibleBox {
        lo: Vec3::INFINITY,
        hi: Vec3::NEG_INFINITY,
    };

    /// The ray parameters `(enter, exit)` between which the points
    /// `at_zero + t·per_t` are in the box; `enter ≥ exit` where none are.
    #[inline(always)]
    pub fn interval(&self, at_zero: Vec3, per_t: Vec3) -> (f32, f32) {
        if self.lo.x > self.hi.x {
            return (f32::INFINITY, f32::NEG_INFINITY);
        }
        // Along an axis the ray does not move along, the slab holds the
        // ray wholly or not at all: a huge reciprocal says so (`(lo − a)`
        // and `(hi − a)` then have signs that differ or agree).
        let inverse = inverse_direction(per_t);
        let t0 = (self.lo - at_zero) * inverse;
        let t1 = (self.hi - at_zero) * inverse;
        (t0.min(t1).max_element(), t0.max(t1).min_element())
    }
}

/// Per block of `index` (the block index's entries, x fastest), the
/// [`VisibleBox`] of its slot in `atlas` from `bits` ([`visible_texels`]);
/// [`VisibleBox::EMPTY`] for blocks not stored.
pub fn visible_boxes(atlas: &SlotAtlas, index: &[[u16; 4]], bits: &[u64]) -> Vec<VisibleBox> {
    index
        .par_iter()
        .enumerate()
        .map(|(b, entry)| {
            let Some(base) = atlas.slot_base(b) else {
                return VisibleBox::EMPTY;
            };
            let edge = slot_edge(usize::from(entry[3]).min(LEVELS - 1)) as usize;
            slot_box(bits, base, edge)
        })
        .collect()
}

/// The box, in texture coordinates (0 to 1 across the volume), outside
/// which no sample can be visible: about the blocks of `grid` (x fastest,
/// each [`BLOCK`] level-0 voxels on an edge, the volume `dims` voxels) whose
/// [`VisibleBox`] in `boxes` holds something, widened by a voxel (far more
/// than the rounding of the samples' positions); [`VisibleBox::EMPTY`]
/// where none does. With empty-space skipping the march takes only the
/// samples of a ray within it, so a ray that passes beside what the
/// transfer function shows walks no block.
pub fn visible_extent(boxes: &[VisibleBox], grid: [u32; 3], dims: Vec3) -> VisibleBox {
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for (b, found) in boxes.iter().enumerate() {
        if found.lo.x > found.hi.x {
            continue;
        }
        let cell = Vec3::from(grid_position(grid, b).map(|c| c as f32));
        lo = lo.min(cell * BLOCK);
        hi = hi.max((cell + 1.0) * BLOCK);
    }
    if lo.x > hi.x {
        return VisibleBox::EMPTY;
    }
    VisibleBox {
        lo: (lo - 1.0) / dims,
        hi: (hi + 1.0) / dims,
    }
}

/// Most boxes [`visible_cells`] gives: cells of more blocks beyond, so
/// that projecting them stays cheap for any volume.
pub const MAX_VISIBLE_CELLS: usize = 4096;

/// The boxes, in texture coordinates, outside all of which no sample can be
/// visible: cells of 2ᵏ × 2ᵏ × 2ᵏ blocks of `grid` (the least k giving at
/// most [`MAX_VISIBLE_CELLS`]), each the box about the [`VisibleBox`]es in
/// `boxes` of its blocks (taken from their slots, at the level `index`
/// stores each at, to the volume; within each block's extent), widened by a
/// voxel as in [`visible_extent`]. The march's
/// [`super::footprint::Footprint`] projects them onto the image.
pub fn visible_cells(
    boxes: &[VisibleBox],
    index: &[[u16; 4]],
    grid: [u32; 3],
    dims: Vec3,
) -> Vec<VisibleBox> {
    // Each block's box in level-0 voxels of the volume.
    let shown: Vec<([u32; 3], Vec3, Vec3)> = boxes
        .iter()
        .zip(index)
        .enumerate()
        .filter(|(_, (found, _))| found.lo.x <= found.hi.x)
        .map(|(b, (found, entry))| {
            let block = grid_position(grid, b);
            let corner = Vec3::from(block.map(|c| c as f32)) * BLOCK;
            // Slot position s is (s − apron + ½) level texels from the
            // block's corner (`block_span`'s map, inverted); a box that
            // reaches a slot's edge is unbounded there.
            let per_texel = (1u32 << u32::from(entry[3]).min(LEVELS as u32 - 1)) as f32;
            let voxels = |s: Vec3| {
                ((s - (SLOT_APRON - 0.5)) * per_texel).clamp(Vec3::ZERO, Vec3::splat(BLOCK))
            };
            (block, corner + voxels(found.lo), corner + voxels(found.hi))
        })
        .collect();
    let mut k = 0;
    loop {
        let cells = grid.map(|n| n.div_ceil(1 << k) as usize);
        let mut at_cell = vec![usize::MAX; cells[0] * cells[1] * cells[2]];
        let mut found: Vec<(Vec3, Vec3)> = Vec::new();
        for &(block, lo, hi) in &shown {
            let c = block.map(|v| (v >> k) as usize);
            let at = &mut at_cell[(c[2] * cells[1] + c[1]) * cells[0] + c[0]];
            if *at == usize::MAX {
                *at = found.len();
                found.push((lo, hi));
            } else {
                let cell = &mut found[*at];
                *cell = (cell.0.min(lo), cell.1.max(hi));
            }
        }
        if found.len() <= MAX_VISIBLE_CELLS || k >= 31 {
            return found
                .into_iter()
                .map(|(lo, hi)| VisibleBox {
                    lo: (lo - 1.0) / dims,
                    hi: (hi + 1.0) / dims,
                })
                .collect();
        }
        k += 1;
    }
}

/// [`visible_boxes`]' box of the slot of edge `edge` at `base`.
fn slot_box(bits: &[u64], base: usize, edge: usize) -> VisibleBox {
    // A row's texels that can be a sample's lowest: all but its last.
    let len = edge - 1;
    let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
    for z in 0..len {
        for y in 0..len {
            let start = base + (z * edge + y) * edge;
            let (word, shift) = (start / 64, start % 64);
            // Texels past the bits' end may be visible (`texel_may_show`).
            let at = |w: usize| bits.get(w).copied().unwrap_or(u64::MAX);
            let mut row = at(word) >> shift;
            if shift + len > 64 {
                row |= at(word + 1) << (64 - shift);
            }
            row &= (1u64 << len) - 1;
            if row == 0 {
                continue;
            }
            let first = row.trailing_zeros() as usize;
            let last = 63 - row.leading_zeros() as usize;
            for (axis, (a, b)) in [(first, last), (y, y), (z, z)].into_iter().enumerate() {
                lo[axis] = lo[axis].min(a);
                hi[axis] = hi[axis].max(b + 1);
            }
        }
    }
    if lo[0] > hi[0] {
        return VisibleBox::EMPTY;
    }
    let low = |c: usize| {
        if c == 0 {
            f32::NEG_INFINITY
        } else {
            c as f32 - BOX_MARGIN
        }
    };
    let high = |c: usize| {
        if c >= len {
            f32::INFINITY
        } else {
            c as f32 + BOX_MARGIN
        }
    };
    VisibleBox {
        lo: Vec3::from(lo.map(low)),
        hi: Vec3::from(hi.map(high)),
    }
}

/// Whether [`visible_texels`]' `bits` let a sample whose lowest texel is
/// texel `i` be visible (a texel past the bits' end may be).
#[inline(always)]
pub fn texel_may_show(bits: &[u64], i: usize) -> bool {
    bits.get(i / 64).is_none_or(|w| w >> (i % 64) & 1 != 0)
}

/// [`visible_texels`]'s bits `words` of one level's slots `region` (edge `E`).
fn region_visible<const E: usize>(region: &[f32], words: &mut [u64], any_visible: &Visibility) {
    const WORDS: usize = 64;
    words
        .par_chunks_mut(WORDS)
        .enumerate()
        .for_each(|(chunk, words)| {
            for (w, word) in words.iter_mut().enumerate() {
                let first = (chunk * WORDS + w) * 64;
                let mut bits = 0u64;
                for bit in 0..64.min(region.len().saturating_sub(first)) {
                    let i = first + bit;
                    let local = i % (E * E * E);
                    let (x, y, z) = (local % E, local / E % E, local / (E * E));
                    let shown = x + 1 >= E
                        || y + 1 >= E
                        || z + 1 >= E
                        || cube_visible::<E>(region, i, any_visible);
                    bits |= u64::from(shown) << bit;
                }
                *word = bits;
            }
        });
}

/// Whether a sample blending the 2×2×2 texels from `region[i]` (rows `E`
/// apart) may be visible.
#[inline]
fn cube_visible<const E: usize>(region: &[f32], i: usize, any_visible: &Visibility) -> bool {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for offset in [0, 1, E, E + 1, E * E, E * E + 1, E * E + E, E * E + E + 1] {
        let v = region.get(i + offset).copied().unwrap_or(0.0);
        lo = lo.min(v);
        hi = hi.max(v);
    }
    any_visible.any(lo, hi)
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::{
        BOX_MARGIN, MAX_VISIBLE_CELLS, VisibleBox, slot_box, texel_may_show, visible_cells,
        visible_extent,
    };
    use crate::cpu::packed::BLOCK;
    use crate::cpu::slot_atlas::{SLOT_APRON, slot_corner};

    /// A slot of edge 10 at texel 70 of the bits (so its rows straddle
    /// words), a few of its texels set as `visible_texels` sets them (its
    /// last row, column and slice too).
    fn slot_bits(set: &[[usize; 3]]) -> (Vec<u64>, usize, usize) {
        let (base, edge) = (70usize, 10usize);
        let mut bits = vec![0u64; (base + edge * edge * edge).div_ceil(64) + 1];
        let mut put = |i: usize| bits[i / 64] |= 1 << (i % 64);
        for z in 0..edge {
            for y in 0..edge {
                for x in 0..edge {
                    let last = x + 1 == edge || y + 1 == edge || z + 1 == edge;
                    if last || set.contains(&[x, y, z]) {
                        put(base + (z * edge + y) * edge + x);
                    }
                }
            }
        }
        (bits, base, edge)
    }

    #[test]
    fn a_slot_s_box_holds_every_position_that_blends_from_a_visible_texel() {
        for set in [
            vec![[3, 4, 5]],
            vec![[2, 7, 1], [6, 3, 4]],
            vec![[0, 5, 5], [8, 8, 8]],
        ] {
            let (bits, base, edge) = slot_bits(&set);
            let b = slot_box(&bits, base, edge);
            let (mut inside, mut outside) = (0, 0);
            for i in 0..20_000u32 {
                let u = |k: u32| ((i * k) % 9973) as f32 / 9972.0 * 12.0 - 1.5;
                let p = Vec3::new(u(31), u(57), u(89));
                // The texel the sampler blends from first at `p`.
                let (lowest, _) = slot_corner(base, edge, p);
                let in_box = p.cmpge(b.lo).all() && p.cmple(b.hi).all();
                if texel_may_show(&bits, lowest) {
                    let texel = lowest - base;
                    assert!(in_box, "{p} blends from visible texel {texel}, box {b:?}");
                }
                if in_box { inside += 1 } else { outside += 1 }
            }
            // The box is the visible texels' and no more.
            assert!(inside > 0 && outside > inside, "{set:?}: {b:?}");
            let lo = set.iter().map(|c| c[1]).min().unwrap_or(0);
            if lo > 0 {
                assert_eq!(b.lo.y, lo as f32 - BOX_MARGIN, "{set:?}");
            }
        }
        let (bits, base, edge) = slot_bits(&[]);
        assert_eq!(slot_box(&bits, base, edge), VisibleBox::EMPTY);
    }

    #[test]
    fn a_ray_is_in_a_visible_box_between_its_interval_s_ends() {
        let b = VisibleBox {
            lo: Vec3::new(2.95, f32::NEG_INFINITY, 4.95),
            hi: Vec3::new(6.05, 3.05, 9.05),
        };
        let (mut hits, mut misses) = (0, 0);
        for i in 0..5000u32 {
            let u = |k: u32| ((i * k) % 997) as f32 / 996.0;
            let at_zero = Vec3::new(u(31), u(57), u(89)) * 12.0 - 1.0;
            // Some rays along axes and some along none.
            let mut per_t = Vec3::new(u(13), u(17), u(19)) * 2.0 - 1.0;
            if i % 5 == 0 {
                per_t[(i / 5 % 3) as usize] = 0.0;
            }
            let (enter, exit) = b.interval(at_zero, per_t);
            if enter < exit {
                hits += 1;
            } else {
                misses += 1;
            }
            for k in 0..400 {
                let t = k as f32 * 0.05 - 10.0;
                let p = at_zero + per_t * t;
                let in_box = p.cmpge(b.lo).all() && p.cmple(b.hi).all();
                let between = t >= enter - 1e-4 && t <= exit + 1e-4;
                assert!(!in_box || between, "{p} at {t} outside {enter}..{exit}");
            }
        }
        assert!(hits > 100 && misses > 100, "{hits} hits, {misses} misses");
    }

    #[test]
    fn the_visible_extent_holds_the_blocks_with_something_to_show_and_a_voxel_more() {
        // A grid of 3 × 2 × 4 blocks of 16 voxels over 40 × 32 × 60 voxels.
        assert_eq!(BLOCK, 16.0);
        let (grid, dims) = ([3u32, 2, 4], Vec3::new(40.0, 32.0, 60.0));
        let shows = VisibleBox {
            lo: Vec3::splat(2.0),
            hi: Vec3::splat(5.0),
        };
        let mut boxes = vec![VisibleBox::EMPTY; 24];
        assert_eq!(visible_extent(&boxes, grid, dims), VisibleBox::EMPTY);
        // Block (1, 0, 2), then also (2, 1, 3), the grid's last.
        boxes[1 + 2 * 6] = shows;
        let one = visible_extent(&boxes, grid, dims);
        assert_eq!(one.lo, Vec3::new(15.0, -1.0, 31.0) / dims);
        assert_eq!(one.hi, Vec3::new(33.0, 17.0, 49.0) / dims);
        boxes[2 + 3 + 3 * 6] = shows;
        let two = visible_extent(&boxes, grid, dims);
        assert_eq!(two.lo, one.lo);
        assert_eq!(two.hi, Vec3::new(49.0, 33.0, 65.0) / dims);
    }

    #[test]
    fn visible_cells_hold_each_block_s_box_in_voxels_and_a_voxel_more() {
        // The grid above; a box of slot texels 2 to 5 (apron 1) is level
        // texels 1.5 to 4.5 from the block's corner.
        assert_eq!(SLOT_APRON, 1.0);
        let (grid, dims) = ([3u32, 2, 4], Vec3::new(40.0, 32.0, 60.0));
        let shows = VisibleBox {
            lo: Vec3::splat(2.0),
            hi: Vec3::splat(5.0),
        };
        let mut boxes = vec![VisibleBox::EMPTY; 24];
        let mut index = vec![[0u16; 4]; 24];
        assert!(visible_cells(&boxes, &index, grid, dims).is_empty());
        // Block (1, 0, 2) at level 0; block (2, 1, 3) at level 1, its box
        // unbounded above (it reaches its slot's far faces).
        boxes[1 + 2 * 6] = shows;
        boxes[2 + 3 + 3 * 6] = VisibleBox {
            lo: Vec3::splat(2.0),
            hi: Vec3::INFINITY,
        };
        index[2 + 3 + 3 * 6][3] = 1;
        let cells = visible_cells(&boxes, &index, grid, dims);
        assert_eq!(cells.len(), 2);
        assert_eq!(
            cells[0].lo,
            Vec3::new(16.0 + 0.5, -1.0 + 1.5, 32.0 + 0.5) / dims
        );
        assert_eq!(cells[0].hi, Vec3::new(16.0 + 5.5, 5.5, 32.0 + 5.5) / dims);
        assert_eq!(
            cells[1].lo,
            Vec3::new(32.0 + 2.0, 16.0 + 2.0, 48.0 + 2.0) / dims
        );
        assert_eq!(cells[1].hi, Vec3::new(49.0, 33.0, 65.0) / dims);
    }

    #[test]
    fn visible_cells_take_more_blocks_each_past_the_most_cells() {
        // Every block of a 32 × 32 × 8 grid shows: 8 192 blocks, so cells
        // of 2³ blocks (1 024), each the box of its eight.
        let grid = [32u32, 32, 8];
        let dims = Vec3::new(512.0, 512.0, 128.0);
        let n = 32 * 32 * 8;
        let whole = VisibleBox {
            lo: Vec3::NEG_INFINITY,
            hi: Vec3::INFINITY,
        };
        let cells = visible_cells(&vec![whole; n], &vec![[0u16; 4]; n], grid, dims);
        assert_eq!(cells.len(), n / 8);
        assert!(cells.len() <= MAX_VISIBLE_CELLS);
        assert_eq!(cells[0].lo, Vec3::splat(-1.0) / dims);
        assert_eq!(cells[0].hi, Vec3::splat(33.0) / dims);
    }
}
