//! Transparent cells inside blocks, for the CPU ray caster: each stored block
//! is cut into 4×4×4 cells of 4³ level-0 voxels, and a cell is *transparent*
//! when the transfer function gives zero opacity to every value trilinear
//! filtering can produce in it (the range of the texels it reads, with a
//! texel of margin). With empty-space skipping on, a ray jumps over
//! transparent cells as it jumps over empty blocks; the samples it skips
//! would have been invisible, so every pixel stays what the GPU draws (its
//! march looks at each such sample and drops it; `tests/tests/raycast.rs`
//! checks skipping changes no pixel). Computed per transfer function and set
//! of shown blocks.

use blocks::packing::{APRON, slot_edge};
use blocks::store::LEVELS;
use rayon::prelude::*;

use super::march::{Cell, table_position};
use super::packed::{BLOCK, EMPTY_LEVEL, PackedTexture};
use super::slot_atlas::SlotAtlas;
use super::texture::{floor, split};
use crate::packed_volume::PackedVolume;
use glam::Vec3;

/// Cells along each axis of a block.
pub const CELLS: usize = 4;
/// Edge of a cell in level-0 voxels.
pub const CELL: f32 = BLOCK / CELLS as f32;

/// Per block (block-grid order), a bit per cell (x fastest, bit
/// `(z·4 + y)·4 + x`) that is set where the cell may be visible.
pub fn visible_cells(
    packed: &PackedTexture,
    g: &PackedVolume,
    transfer_function: &[[f32; 4]],
) -> Vec<u64> {
    let any_visible = Visibility::new(g, transfer_function);
    packed
        .index
        .par_iter()
        .enumerate()
        .map(|(b, entry)| match packed.atlas.slot_base(b) {
            Some(base) if entry[3] != EMPTY_LEVEL => {
                let level = usize::from(entry[3]).min(LEVELS - 1);
                block_cells(&packed.atlas.texels()[base..], level, &any_visible)
            }
            _ => 0,
        })
        .collect()
}

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

/// The visible-cell bits of a block at `level` whose slot's texels start
/// `slot`.
fn block_cells(slot: &[f32], level: usize, any_visible: &Visibility) -> u64 {
    let e = slot_edge(level) as i32;
    let scale = 1.0 / (1u32 << level) as f32;
    let apron = APRON as i32;
    // The slot texels samples in cell `c` along one axis may read: those
    // around its texel span, a texel of margin, kept in the slot.
    let span = |c: usize| {
        let lo = floor(c as f32 * CELL * scale - 0.5) as i32 + apron - 1;
        let hi = floor((c + 1) as f32 * CELL * scale - 0.5) as i32 + apron + 2;
        (lo.max(0) as usize, hi.min(e - 1) as usize)
    };
    let e = e as usize;
    let mut bits = 0u64;
    for cz in 0..CELLS {
        let (z0, z1) = span(cz);
        for cy in 0..CELLS {
            let (y0, y1) = span(cy);
            for cx in 0..CELLS {
                let (x0, x1) = span(cx);
                let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                for z in z0..=z1 {
                    for y in y0..=y1 {
                        for &v in &slot[(z * e + y) * e + x0..=(z * e + y) * e + x1] {
                            lo = lo.min(v);
                            hi = hi.max(v);
                        }
                    }
                }
                if any_visible.any(lo, hi) {
                    bits |= 1 << ((cz * CELLS + cy) * CELLS + cx);
                }
            }
        }
    }
    bits
}

/// The cell holding the sample at `t` on a ray whose position in level-0
/// voxels within the block is `local_at_zero + t·local_per_t`, given the
/// block's visible-cell bits `visible`, and the cells after it the ray
/// crosses in the block that are alike (all transparent or all possibly
/// visible): the march jumps them, or samples them as one run, with one
/// lookup. A walk of the block's 4³ cells (a 3D DDA) with each axis's state
/// in registers: the cell's bit moves by ±1, ±4 or ±16, and a far face's
/// crossing is its distance times the direction's reciprocal, where a
/// division would stall the walk. That moves a crossing by an ulp or so,
/// far less than the texel of margin cells are found visible with.
#[inline(always)]
pub fn cell_at(visible: u64, local_at_zero: Vec3, local_per_t: Vec3, t: f32) -> Cell {
    let last = (CELLS - 1) as i32;
    let local = local_at_zero + local_per_t * t;
    let index = |v: f32| split(v / CELL).0.clamp(0, last);
    let c = [index(local.x), index(local.y), index(local.z)];
    let mut bit = (c[2] * CELLS as i32 + c[1]) * CELLS as i32 + c[0];
    let transparent = visible >> bit & 1 == 0;
    let ahead = local_per_t.cmpgt(Vec3::ZERO);
    let inverse = 1.0 / local_per_t;
    let still = local_per_t.abs().cmplt(Vec3::splat(1e-12));
    // The far faces (in the direction of travel) of the cell, where the ray
    // crosses them (never, along an axis it does not move along), the cells
    // left ahead in the block, and the bit's step to the next cell.
    let cell = Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32);
    let mut face = (cell + Vec3::select(ahead, Vec3::ONE, Vec3::ZERO)) * CELL;
    let face_step = Vec3::select(ahead, Vec3::splat(CELL), Vec3::splat(-CELL));
    let mut crossing = Vec3::select(still, Vec3::INFINITY, (face - local_at_zero) * inverse);
    let toward = |axis: usize| {
        if ahead.test(axis) {
            last - c[axis]
        } else {
            c[axis]
        }
    };
    let mut left = [toward(0), toward(1), toward(2)];
    let stride = |axis: usize| {
        let s = (CELLS as i32).pow(axis as u32);
        if ahead.test(axis) { s } else { -s }
    };
    let step = [stride(0), stride(1), stride(2)];
    loop {
        let axis = if crossing.x <= crossing.y && crossing.x <= crossing.z {
            0
        } else if crossing.y <= crossing.z {
            1
        } else {
            2
        };
        // Unrolled per axis, so that every index is a constant.
        macro_rules! cross {
            ($axis:literal, $field:ident) => {{
                let exit = crossing.$field;
                if left[$axis] == 0 {
                    return Cell { transparent, exit };
                }
                left[$axis] -= 1;
                bit += step[$axis];
                if (visible >> bit & 1 == 0) != transparent {
                    return Cell { transparent, exit };
                }
                face.$field += face_step.$field;
                crossing.$field = if still.test($axis) {
                    f32::INFINITY
                } else {
                    (face.$field - local_at_zero.$field) * inverse.$field
                };
            }};
        }
        match axis {
            0 => cross!(0, x),
            1 => cross!(1, y),
            _ => cross!(2, z),
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::{CELL, CELLS, cell_at};
    use crate::cpu::hash::{pcg_hash, unit_from_hash};

    /// Whether the cell holding `local` (level-0 voxels in the block) may
    /// be visible, or `None` outside the block.
    fn shown_at(visible: u64, local: Vec3) -> Option<bool> {
        let inside = local.cmpge(Vec3::ZERO).all() && local.cmplt(Vec3::splat(CELL * 4.0)).all();
        inside.then(|| {
            let c = (local / CELL).floor();
            let bit = (c.z as usize * CELLS + c.y as usize) * CELLS + c.x as usize;
            visible >> bit & 1 != 0
        })
    }

    #[test]
    fn a_cell_s_exit_is_where_the_ray_meets_a_cell_unlike_it_or_leaves_the_block() {
        struct Draws(u32);
        impl Draws {
            fn word(&mut self) -> u32 {
                self.0 = pcg_hash(self.0);
                self.0
            }
            fn unit(&mut self) -> f32 {
                unit_from_hash(self.word())
            }
        }
        let mut draw = Draws(7);
        let mut checked = 0;
        for _ in 0..4000 {
            // Clusters of like cells: a few random boxes of visible ones,
            // or a random mask.
            let visible = if draw.unit() < 0.5 {
                let (high, low) = (draw.word(), draw.word());
                u64::from(high) << 32 | u64::from(low)
            } else {
                let (lo, hi) = (
                    [0; 3].map(|_| (draw.unit() * 4.0) as usize),
                    [0; 3].map(|_| (draw.unit() * 5.0) as usize),
                );
                let mut bits = 0u64;
                for z in lo[2]..hi[2].max(lo[2]) {
                    for y in lo[1]..hi[1].max(lo[1]) {
                        for x in lo[0]..hi[0].max(lo[0]) {
                            bits |= 1 << ((z * CELLS + y) * CELLS + x);
                        }
                    }
                }
                bits
            };
            // Directions along an axis or a face's diagonal too.
            let mut dir = Vec3::new(draw.unit(), draw.unit(), draw.unit()) * 2.0 - Vec3::ONE;
            if draw.unit() < 0.2 {
                dir[(draw.unit() * 3.0) as usize % 3] = 0.0;
            }
            let Some(dir) = dir.try_normalize() else {
                continue;
            };
            let per_t = dir * (0.5 + draw.unit());
            let start = Vec3::new(draw.unit(), draw.unit(), draw.unit()) * (CELL * 4.0);
            let t = draw.unit() * 3.0;
            let at_zero = start - per_t * t;
            let cell = cell_at(visible, at_zero, per_t, t);
            let shown = shown_at(visible, start).expect("inside");
            assert_eq!(cell.transparent, !shown, "the cell at t");
            assert!(cell.exit >= t - 1e-4, "exit {} before t {t}", cell.exit);
            // Every point before the exit lies in a like cell…
            let eps = 1e-3;
            for k in 0..=64 {
                let u = t + (cell.exit - eps - t).max(0.0) * k as f32 / 64.0;
                let there = shown_at(visible, at_zero + per_t * u);
                assert!(
                    there.is_none_or(|s| s == shown),
                    "at {u} before exit {} from {t}: {there:?}",
                    cell.exit
                );
            }
            // …and just past it the ray has left the block or met an unlike
            // one (unless it crosses two faces at once there: a corner).
            let (before, after) = (
                at_zero + per_t * (cell.exit - eps),
                at_zero + per_t * (cell.exit + eps),
            );
            let moved = (before / CELL).floor().cmpne((after / CELL).floor());
            if moved.bitmask().count_ones() > 1 {
                continue;
            }
            let past = shown_at(visible, after);
            assert!(
                past != Some(shown),
                "past exit {} from {t}: {past:?}",
                cell.exit
            );
            checked += 1;
        }
        assert!(checked > 3500);
    }
}
