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

use super::march::{Cell, far_face_crossing, table_position};
use super::packed::{BLOCK, EMPTY_LEVEL, PackedTexture};
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
    // visible_before[i]: table entries before i with opacity above zero.
    let mut visible_before = Vec::with_capacity(transfer_function.len() + 1);
    visible_before.push(0u32);
    for entry in transfer_function {
        let last = visible_before.last().copied().unwrap_or(0);
        visible_before.push(last + u32::from(entry[3] > 0.0));
    }
    let n = transfer_function.len() as i32;
    // Any entry `classify` may blend for a texel value in lo..=hi opaque?
    let any_visible = |lo: f32, hi: f32| {
        let (a, b) = (
            lo * g.value_scale + g.value_offset,
            hi * g.value_scale + g.value_offset,
        );
        let tf_len = n as u32;
        let first = table_position(tf_len, a.min(b)).0.clamp(0, n - 1) as usize;
        let last = (table_position(tf_len, a.max(b)).0 + 1).clamp(0, n - 1) as usize;
        visible_before[last + 1] > visible_before[first]
    };
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

/// The visible-cell bits of a block at `level` whose slot's texels start
/// `slot`.
fn block_cells(slot: &[f32], level: usize, any_visible: &dyn Fn(f32, f32) -> bool) -> u64 {
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
                if any_visible(lo, hi) {
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
/// lookup.
#[inline]
pub fn cell_at(visible: u64, local_at_zero: Vec3, local_per_t: Vec3, t: f32) -> Cell {
    let last = (CELLS - 1) as i32;
    let local = local_at_zero + local_per_t * t;
    let index = |v: f32| split(v / CELL).0.clamp(0, last);
    let mut c = [index(local.x), index(local.y), index(local.z)];
    let bit = |c: [i32; 3]| (c[2] as usize * CELLS + c[1] as usize) * CELLS + c[0] as usize;
    let transparent = visible & (1 << bit(c)) == 0;
    let cell = Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32);
    let mut crossing = far_face_crossing(cell, Vec3::splat(CELL), local_at_zero, local_per_t);
    loop {
        let axis = if crossing.x <= crossing.y && crossing.x <= crossing.z {
            0
        } else if crossing.y <= crossing.z {
            1
        } else {
            2
        };
        let exit = crossing[axis];
        let ahead = local_per_t[axis] > 0.0;
        c[axis] += if ahead { 1 } else { -1 };
        if !(0..=last).contains(&c[axis]) || (visible & (1 << bit(c)) == 0) != transparent {
            return Cell { transparent, exit };
        }
        // The far face of the next cell along the axis, as
        // `far_face_crossing` finds it.
        let face = (c[axis] + i32::from(ahead)) as f32 * CELL;
        crossing[axis] = (face - local_at_zero[axis]) / local_per_t[axis];
    }
}
