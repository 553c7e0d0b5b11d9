//! Seamless level borders: the apron of a packed block whose neighbour is
//! shown at another level.
//!
//! A packed block is sampled with trilinear filtering up to half a texel
//! beyond its last voxel centre, so the value a ray sees on the face between
//! two blocks comes from both blocks' slots: from one side, the block's last
//! voxel blended with its apron; from the other, the neighbour's first voxel
//! blended with its own apron. With aprons copied from the neighbours at the
//! block's *own* level ([`crate::cache::BlockCache::block_with_apron`]), the
//! two sides agree only when both blocks have one level: between a level-0
//! and a level-2 block the fine side reconstructs the fine data and the
//! coarse side the coarse data, and the difference draws a step (a crack in
//! the image) at every border of levels.
//!
//! Here the finer of two blocks takes the coarser one's reconstruction on
//! their border: each of its apron voxels facing a coarser neighbour (level
//! m) is set so that trilinear filtering inside the block, at the border
//! (half a texel beyond its last voxel centre), gives the level-m volume's
//! own trilinear value there, which is what the coarser block, its apron
//! copied at its own level, reconstructs on its side. For a face voxel that
//! is `2 · Lm(border) − last`, with `last` the block's voxel next to it; for
//! edge and corner voxels (two or three directions out of the block) the same
//! over the 4 or 8 texels filtering blends there. The coarser block is left
//! as it was. So on a face between levels the two sides agree wherever the
//! coarser block's own aprons are at its level; a signal linear across the
//! border is reproduced exactly by both; what is left is where three or four
//! blocks of three levels meet. Ljung, Lundström and Ynnerman's interblock
//! interpolation blends up to eight blocks per sample near every border
//! instead; this keeps the renderer's sampling as it is, so the GPU and CPU
//! paths and every stage reading the atlas (both illumination modes) get the
//! same borders. The set values leave the voxel type's range only where a
//! fine block's edge differs from its coarse neighbour's by more than the
//! range allows (they saturate).
//!
//! A block's apron now depends on its neighbours' levels: when one changes,
//! the block is written again ([`neighbour_changed`]).

use std::collections::HashMap;
use std::sync::Arc;

use crate::cache::ChunkKey;
use crate::lod::EMPTY;
use crate::packing::{APRON, slot_edge};
use crate::store::{BLOCK, LEVELS, grid_index, grid_position, level_dims};
use crate::{Voxel, VoxelData};

/// The levels of a block and its 26 neighbours: entry
/// `(dz + 1) · 9 + (dy + 1) · 3 + (dx + 1)` for the neighbour at offset
/// (dx, dy, dz); the block itself is entry 13. [`EMPTY`] for neighbours that
/// are not shown or lie outside the block grid.
pub type Neighbourhood = [u8; 27];

/// Chunks of other levels a block's apron reads, by key.
pub type SeamChunks = HashMap<ChunkKey, Arc<VoxelData>>;

/// The entry of offset `d` in a [`Neighbourhood`].
fn entry(d: [i64; 3]) -> usize {
    ((d[2] + 1) * 9 + (d[1] + 1) * 3 + (d[0] + 1)) as usize
}

/// The block at offset `d` from `block` in a grid of `grid` blocks, if inside.
fn neighbour(block: [u32; 3], d: [i64; 3], grid: [u32; 3]) -> Option<[u32; 3]> {
    let mut n = [0u32; 3];
    for a in 0..3 {
        let v = i64::from(block[a]) + d[a];
        if v < 0 || v >= i64::from(grid[a]) {
            return None;
        }
        n[a] = v as u32;
    }
    Some(n)
}

/// The offsets of the 26 neighbours.
fn offsets() -> impl Iterator<Item = [i64; 3]> {
    (-1..=1)
        .flat_map(|z| (-1..=1).flat_map(move |y| (-1..=1).map(move |x| [x, y, z])))
        .filter(|d| *d != [0, 0, 0])
}

/// The levels around `block` in `lod` (per block, x fastest, over a grid of
/// `grid` blocks).
pub fn neighbourhood(lod: &[u8], grid: [u32; 3], block: [u32; 3]) -> Neighbourhood {
    let mut levels = [EMPTY; 27];
    levels[13] = lod.get(grid_index(grid, block)).copied().unwrap_or(EMPTY);
    for d in offsets() {
        if let Some(n) = neighbour(block, d, grid) {
            levels[entry(d)] = lod.get(grid_index(grid, n)).copied().unwrap_or(EMPTY);
        }
    }
    levels
}

/// Per block of a grid of `grid` blocks, whether its apron must be written
/// again going from levels `old` to `new` (per block, x fastest): a
/// neighbour's level changed and it is coarser than the block (now or
/// before). A neighbour that turns finer, same-level or empty from
/// something not coarser leaves the apron as it was: at the block's level.
pub fn neighbour_changed(old: &[u8], new: &[u8], grid: [u32; 3]) -> Vec<bool> {
    let mut touched = vec![false; new.len()];
    for (c, (&was, &now)) in old.iter().zip(new).enumerate().filter(|(_, (o, n))| o != n) {
        let block = grid_position(grid, c);
        for d in offsets() {
            let Some(b) = neighbour(block, d, grid).map(|n| grid_index(grid, n)) else {
                continue;
            };
            let Some(&own) = new.get(b) else {
                continue;
            };
            if usize::from(own) < LEVELS && (coarser(was, own) || coarser(now, own)) {
                touched[b] = true;
            }
        }
    }
    touched
}

/// Whether a neighbour at `level` is shown coarser than a block at `own`:
/// the block's apron facing it meets its reconstruction.
fn coarser(level: u8, own: u8) -> bool {
    level > own && usize::from(level) < LEVELS
}

/// The chunks of coarser levels the apron of `block` (at the level in entry
/// 13 of `levels`) reads in a volume of level-0 `dims` and `grid` blocks: for
/// each neighbour shown coarser, those its level's filtering reads on the
/// border with it.
pub fn seam_chunks(
    block: [u32; 3],
    grid: [u32; 3],
    dims: [u32; 3],
    levels: &Neighbourhood,
) -> Vec<ChunkKey> {
    let own = levels[13];
    let mut keys = Vec::new();
    for d in offsets() {
        let m = levels[entry(d)];
        if neighbour(block, d, grid).is_none() || !coarser(m, own) {
            continue;
        }
        let last = level_dims(dims, usize::from(m)).map(|n| n.saturating_sub(1));
        let range = [0, 1, 2].map(|a| {
            // Level-0 positions the apron's border points take along axis a.
            let (lo, hi) = match d[a] {
                1 => ((block[a] + 1) * BLOCK, (block[a] + 1) * BLOCK),
                -1 => (block[a] * BLOCK, block[a] * BLOCK),
                _ => (block[a] * BLOCK, (block[a] + 1) * BLOCK),
            };
            let voxel = |p: u32| ((p >> m).saturating_sub(1), ((p >> m) + 1).min(last[a]));
            (voxel(lo).0 / BLOCK, voxel(hi).1 / BLOCK)
        });
        for cz in range[2].0..=range[2].1 {
            for cy in range[1].0..=range[1].1 {
                for cx in range[0].0..=range[0].1 {
                    keys.push((m, [cx, cy, cz]));
                }
            }
        }
    }
    keys.sort_unstable();
    keys.dedup();
    keys
}

/// Rewrites the apron of `slot`, the voxels of `block` at its level (entry 13
/// of `levels`) with a one-voxel apron at that level, so that it meets each
/// neighbour shown at another level seamlessly (see the module docs), from
/// `chunks` ([`seam_chunks`]). `dims` are the volume's level-0 dims, `grid`
/// its block grid. Returns false when a chunk was missing: those apron voxels
/// keep their same-level values.
pub fn fix_apron(
    slot: &mut VoxelData,
    block: [u32; 3],
    grid: [u32; 3],
    dims: [u32; 3],
    levels: &Neighbourhood,
    chunks: &SeamChunks,
) -> bool {
    let own = levels[13];
    if usize::from(own) >= LEVELS
        || !offsets().any(|d| coarser(levels[entry(d)], own) && neighbour(block, d, grid).is_some())
    {
        return true;
    }
    let fix = Fix {
        block,
        grid,
        dims,
        levels,
        chunks,
    };
    crate::volume::with_voxels!(slot, v => fix.apply(v))
}

/// What [`fix_apron`] works with.
struct Fix<'a> {
    block: [u32; 3],
    grid: [u32; 3],
    dims: [u32; 3],
    levels: &'a Neighbourhood,
    chunks: &'a SeamChunks,
}

impl Fix<'_> {
    fn apply<T: Voxel>(&self, slot: &mut [T]) -> bool {
        let own = usize::from(self.levels[13]);
        let side = slot_edge(own) as usize;
        if slot.len() != side * side * side {
            return false;
        }
        let last = side - 1;
        let out = |c: usize| -> i64 {
            if c == 0 {
                -1
            } else if c == last {
                1
            } else {
                0
            }
        };
        let at = |c: [usize; 3]| (c[2] * side + c[1]) * side + c[0];
        let spacing = f64::from(1u32 << own);
        let mut exact = true;
        // Faces, then edges, then corners: each blends texels set before it.
        for outward in 1..=3 {
            for i in 0..slot.len() {
                let c = [i % side, (i / side) % side, i / (side * side)];
                let d = c.map(out);
                if d.iter().filter(|&&v| v != 0).count() != outward {
                    continue;
                }
                let m = self.levels[entry(d)];
                if neighbour(self.block, d, self.grid).is_none() || !coarser(m, self.levels[13]) {
                    continue;
                }
                // The border point filtering reaches half a texel out: on the
                // block's faces along d, at the apron voxel's centre along the rest.
                let border = [0, 1, 2].map(|a| {
                    let start = f64::from(self.block[a] * BLOCK);
                    match d[a] {
                        1 => start + f64::from(BLOCK),
                        -1 => start,
                        _ => start + (c[a] as f64 - f64::from(APRON) + 0.5) * spacing,
                    }
                });
                let Some(target) = self.level_value(usize::from(m), border) else {
                    exact = false;
                    continue;
                };
                // Filtering there weighs equally this texel and the 2^k − 1
                // texels one step inwards along any subset of the d axes.
                let axes: Vec<usize> = (0..3).filter(|&a| d[a] != 0).collect();
                let corners = 1usize << axes.len();
                let others: f64 = (1..corners)
                    .map(|mask| {
                        let mut p = c;
                        for (k, &a) in axes.iter().enumerate() {
                            if mask >> k & 1 == 1 {
                                p[a] = (p[a] as i64 - d[a]) as usize;
                            }
                        }
                        slot[at(p)].into()
                    })
                    .sum();
                slot[i] = T::from_f64(corners as f64 * target - others);
            }
        }
        exact
    }

    /// Level `m` of the volume trilinearly interpolated at `p` (level-0 voxel
    /// units; clamped to the level's voxel centres). None when a chunk is missing.
    fn level_value(&self, m: usize, p: [f64; 3]) -> Option<f64> {
        let dims = level_dims(self.dims, m);
        let scale = f64::from(1u32 << m);
        let mut lo = [0u32; 3];
        let mut hi = [0u32; 3];
        let mut frac = [0f64; 3];
        for a in 0..3 {
            let last = dims[a].checked_sub(1)?;
            let u = (p[a] / scale - 0.5).clamp(0.0, f64::from(last));
            let i0 = u.floor() as u32;
            (lo[a], hi[a], frac[a]) = (i0, (i0 + 1).min(last), u - f64::from(i0));
        }
        let mut corners = [0f64; 8];
        for (k, corner) in corners.iter_mut().enumerate() {
            let v = [0, 1, 2].map(|a| if k >> a & 1 == 0 { lo[a] } else { hi[a] });
            let chunk = self.chunks.get(&(m as u8, v.map(|i| i / BLOCK)))?;
            let b = BLOCK as usize;
            let at = v.map(|i| (i % BLOCK) as usize);
            *corner = crate::volume::with_voxels!(chunk.as_ref(), c => {
                c.get((at[2] * b + at[1]) * b + at[0]).map(|&x| x.into())
            })?;
        }
        let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
        let x = [0, 2, 4, 6].map(|k| lerp(corners[k], corners[k + 1], frac[0]));
        let y = [lerp(x[0], x[1], frac[1]), lerp(x[2], x[3], frac[1])];
        Some(lerp(y[0], y[1], frac[2]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chunk of 16³ u16 voxels whose value is `f(x, y, z)` of the level's voxel index.
    fn chunk(f: impl Fn(usize, usize, usize) -> f64) -> Arc<VoxelData> {
        let b = BLOCK as usize;
        let v: Vec<u16> = (0..b * b * b)
            .map(|i| f(i % b, (i / b) % b, i / (b * b)).round() as u16)
            .collect();
        Arc::new(VoxelData::U16(v))
    }

    /// A slot of `level` whose every texel is 7.
    fn sevens(level: usize) -> VoxelData {
        VoxelData::U16(vec![7; (slot_edge(level) as usize).pow(3)])
    }

    #[test]
    fn neighbourhood_reads_levels_around_a_block_and_empty_outside_the_grid() {
        let grid = [3, 2, 1];
        let lod: Vec<u8> = (0..6).collect();
        let levels = neighbourhood(&lod, grid, [0, 0, 0]);
        assert_eq!(levels[13], 0);
        assert_eq!(levels[entry([1, 0, 0])], 1);
        assert_eq!(levels[entry([0, 1, 0])], 3);
        assert_eq!(levels[entry([1, 1, 0])], 4);
        assert_eq!(levels[entry([-1, 0, 0])], EMPTY);
        assert_eq!(levels[entry([0, 0, 1])], EMPTY);
    }

    #[test]
    fn a_neighbour_turning_coarser_touches_the_26_neighbours_only() {
        let grid = [4, 4, 4];
        let index = |x: usize, y: usize, z: usize| (z * 4 + y) * 4 + x;
        let old = vec![1u8; 64];
        let mut new = old.clone();
        new[index(1, 1, 2)] = 2;
        let touched = neighbour_changed(&old, &new, grid);
        assert_eq!(touched.iter().filter(|&&t| t).count(), 26);
        assert!(touched[index(0, 0, 1)], "(0, 0, 1) is a corner neighbour");
        assert!(
            !touched[index(1, 1, 2)],
            "the block itself is written anyway"
        );
        assert!(!touched[index(3, 1, 2)], "(3, 1, 2) is two blocks away");
        // Finer or empty: the neighbours' aprons stay at their own level.
        for level in [0, EMPTY] {
            new[index(1, 1, 2)] = level;
            let touched = neighbour_changed(&old, &new, grid);
            assert!(touched.iter().all(|&t| !t), "level {level}");
        }
        // From coarser back to the same level: written again.
        let mut was = vec![1u8; 64];
        was[index(1, 1, 2)] = 3;
        assert_eq!(
            neighbour_changed(&was, &old, grid)
                .iter()
                .filter(|&&t| t)
                .count(),
            26
        );
    }

    #[test]
    fn a_fine_blocks_apron_meets_its_coarse_neighbours_reconstruction_on_the_border() {
        // Block (0,0,0) at level 0, its +x neighbour (1,0,0) at level 2.
        let grid = [2, 1, 1];
        let dims = [32, 16, 16];
        let lod = [0u8, 2];
        let levels = neighbourhood(&lod, grid, [0, 0, 0]);
        assert_eq!(
            seam_chunks([0, 0, 0], grid, dims, &levels),
            vec![(2, [0, 0, 0])]
        );
        // Level 2: value = 100 · x + 10 · y (level-2 voxel indices).
        let coarse = chunk(|x, y, _| 100.0 * x as f64 + 10.0 * y as f64);
        let chunks: SeamChunks = [((2, [0, 0, 0]), coarse)].into();
        let side = slot_edge(0) as usize;
        let mut slot = sevens(0);
        assert!(fix_apron(
            &mut slot,
            [0, 0, 0],
            grid,
            dims,
            &levels,
            &chunks
        ));
        let VoxelData::U16(v) = slot else {
            unreachable!()
        };
        let at = |x: usize, y: usize, z: usize| v[(z * side + y) * side + x];
        // The +x apron (slot x = 17) at slot y = 5 (centre 4.5), z = 1 (0.5):
        // level 2 at the border point (16, 4.5, 0.5) is at level-2
        // coordinates (3.5, 0.625, clamped 0): 356.25; the block's voxel next
        // to it is 7, so the apron is 2 · 356.25 − 7.
        assert_eq!(at(17, 5, 1), 706);
        // What filtering reads on the border: the mean of the two.
        assert_eq!(
            (f64::from(at(16, 5, 1)) + f64::from(at(17, 5, 1))) / 2.0,
            356.5
        );
        // The −x apron has no neighbour (outside the grid); interior untouched.
        assert_eq!(at(0, 5, 5), 7);
        assert_eq!(at(16, 5, 5), 7);
        // Missing chunks leave the apron and say so.
        let mut slot = sevens(0);
        assert!(!fix_apron(
            &mut slot,
            [0, 0, 0],
            grid,
            dims,
            &levels,
            &SeamChunks::new()
        ));
        let VoxelData::U16(v) = slot else {
            unreachable!()
        };
        assert_eq!(v[(side + 5) * side + 17], 7);
    }

    #[test]
    fn a_coarse_blocks_apron_facing_a_finer_neighbour_stays_at_its_level() {
        let grid = [2, 1, 1];
        let lod = [0u8, 2];
        let levels = neighbourhood(&lod, grid, [1, 0, 0]);
        assert!(seam_chunks([1, 0, 0], grid, [32, 16, 16], &levels).is_empty());
        let mut slot = sevens(2);
        assert!(fix_apron(
            &mut slot,
            [1, 0, 0],
            grid,
            [32, 16, 16],
            &levels,
            &SeamChunks::new()
        ));
        assert_eq!(slot, sevens(2));
    }
}
