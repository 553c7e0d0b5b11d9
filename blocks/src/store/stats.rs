//! [`BlockStats`]: per block and per level, the smallest and largest stored value
//! and a histogram over the volume's stored range. Computed once at ingest and
//! kept in the store; the transfer function classifies and ranks blocks from
//! them without touching voxels.

use rayon::prelude::*;

use super::pyramid::{LEVELS, level_dims};
use crate::VoxelData;
use crate::volume::with_voxels;

/// Edge of a block in level-0 voxels.
pub const BLOCK: u32 = 16;
/// Histogram bins per block and level.
pub const HISTOGRAM_BINS: usize = 32;

/// Statistics of every block at every level.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockStats {
    /// Blocks along x, y, z.
    pub grid: [u32; 3],
    /// The stored-value range the histogram bins divide evenly.
    pub range: [f64; 2],
    /// `[min, max]` per level and block, level-major, then z, y, x of the block.
    pub minmax: Vec<f64>,
    /// [`HISTOGRAM_BINS`] counts per level and block, in the same order: of
    /// every level when written at ingest, of level 0 only when read from a
    /// store (the only level the transfer function ranks blocks by; the
    /// others would take four times its memory, 256 bytes per block).
    pub histogram: Vec<u16>,
}

/// Where block `b` of a grid of `grid` blocks is in every per-block list:
/// x fastest, then y, then z.
pub fn grid_index(grid: [u32; 3], b: [u32; 3]) -> usize {
    (b[2] as usize * grid[1] as usize + b[1] as usize) * grid[0] as usize + b[0] as usize
}

/// The block at index `i` of the per-block lists of a grid of `grid` blocks
/// ([`grid_index`] inverted).
pub fn grid_position(grid: [u32; 3], i: usize) -> [u32; 3] {
    let (gx, gy) = (grid[0] as usize, grid[1] as usize);
    [
        (i % gx) as u32,
        ((i / gx) % gy) as u32,
        (i / (gx * gy)) as u32,
    ]
}

impl BlockStats {
    /// Empty statistics for a grid (filled row by row).
    pub fn new(grid: [u32; 3], range: [f64; 2]) -> BlockStats {
        let blocks = grid.iter().map(|&g| g as usize).product::<usize>();
        BlockStats {
            grid,
            range,
            minmax: vec![f64::NAN; LEVELS * blocks * 2],
            histogram: vec![0; LEVELS * blocks * HISTOGRAM_BINS],
        }
    }

    /// The number of blocks.
    pub fn block_count(&self) -> usize {
        self.grid.iter().map(|&g| g as usize).product()
    }

    /// The linear index of block (x, y, z) ([`grid_index`]).
    pub fn block_index(&self, b: [u32; 3]) -> usize {
        grid_index(self.grid, b)
    }

    /// The block's grid position from its linear index ([`grid_position`]).
    pub fn block_position(&self, i: usize) -> [u32; 3] {
        grid_position(self.grid, i)
    }

    /// Smallest and largest stored value of block `b` at `level` (NaN if it holds none).
    pub fn min_max(&self, level: usize, b: usize) -> [f64; 2] {
        let i = (level * self.block_count() + b) * 2;
        [self.minmax[i], self.minmax[i + 1]]
    }

    /// The histogram of block `b` at `level`; `None` for a level these
    /// statistics do not hold (see [`BlockStats::histogram`]) or a block
    /// outside the grid.
    pub fn histogram(&self, level: usize, b: usize) -> Option<&[u16]> {
        let i = (level * self.block_count() + b) * HISTOGRAM_BINS;
        self.histogram.get(i..i + HISTOGRAM_BINS)
    }

    /// The stored-value interval of bin `k`.
    pub fn bin_edges(&self, k: usize) -> [f64; 2] {
        let [lo, hi] = self.range;
        let w = (hi - lo) / HISTOGRAM_BINS as f64;
        [lo + k as f64 * w, lo + (k + 1) as f64 * w]
    }

    /// Fills the statistics of block row `bz` (all levels) from the levels of the
    /// slab that holds it; `slab_dims` are level 0's (x, y, depth).
    pub fn fill_row(&mut self, bz: u32, levels: &[VoxelData], slab_dims: [u32; 3]) {
        let [gx, gy, _] = self.grid;
        let blocks = self.block_count();
        let row_start = self.block_index([0, 0, bz]);
        let row_len = (gx * gy) as usize;
        let range = self.range;
        // For 8- and 16-bit data, the bin of every possible value, looked up per voxel.
        let lut = bin_lut(levels.first().map(VoxelData::voxel_type), range);
        for (level, data) in levels.iter().enumerate() {
            let dims = level_dims(slab_dims, level);
            let edge = BLOCK >> level;
            let mm = &mut self.minmax[(level * blocks + row_start) * 2..][..row_len * 2];
            let hist = &mut self.histogram[(level * blocks + row_start) * HISTOGRAM_BINS..]
                [..row_len * HISTOGRAM_BINS];
            mm.par_chunks_mut(2)
                .zip(hist.par_chunks_mut(HISTOGRAM_BINS))
                .enumerate()
                .for_each(|(i, (mm, hist))| {
                    let (bx, by) = (i as u32 % gx, i as u32 / gx);
                    let x0 = (bx * edge).min(dims[0]);
                    let y0 = (by * edge).min(dims[1]);
                    let (x1, y1) = ((x0 + edge).min(dims[0]), (y0 + edge).min(dims[1]));
                    let (lo, hi) = match (data, &lut) {
                        (VoxelData::U8(v), Some(lut)) => block_stats_lut(v, dims, [x0, x1], [y0, y1], lut, hist),
                        (VoxelData::I8(v), Some(lut)) => block_stats_lut(v, dims, [x0, x1], [y0, y1], lut, hist),
                        (VoxelData::U16(v), Some(lut)) => block_stats_lut(v, dims, [x0, x1], [y0, y1], lut, hist),
                        (VoxelData::I16(v), Some(lut)) => block_stats_lut(v, dims, [x0, x1], [y0, y1], lut, hist),
                        _ => with_voxels!(data, v => block_stats(v, dims, [x0, x1], [y0, y1], range, hist)),
                    };
                    mm[0] = lo;
                    mm[1] = hi;
                });
        }
    }
}

/// The histogram bin of a value.
fn bin_of(value: f64, range: [f64; 2]) -> usize {
    let scale = HISTOGRAM_BINS as f64 / (range[1] - range[0]).max(f64::MIN_POSITIVE);
    ((value - range[0]) * scale)
        .floor()
        .clamp(0.0, (HISTOGRAM_BINS - 1) as f64) as usize
}

/// The bin of every value of an 8- or 16-bit type, indexed by value − `min`.
struct BinLut {
    min: i32,
    bins: Vec<u8>,
}

/// A [`BinLut`] for 8- and 16-bit types; `None` for wider ones.
fn bin_lut(t: Option<crate::VoxelType>, range: [f64; 2]) -> Option<BinLut> {
    use crate::VoxelType::{I8, I16, U8, U16};
    let (min, n): (i32, i32) = match t? {
        U8 => (0, 256),
        I8 => (-128, 256),
        U16 => (0, 65536),
        I16 => (-32768, 65536),
        _ => return None,
    };
    Some(BinLut {
        min,
        bins: (min..min + n)
            .map(|v| bin_of(f64::from(v), range) as u8)
            .collect(),
    })
}

/// [`block_stats`] for 8- and 16-bit values, with bins from `lut`.
fn block_stats_lut<T: crate::Voxel + Into<i32> + Ord>(
    v: &[T],
    dims: [u32; 3],
    x: [u32; 2],
    y: [u32; 2],
    lut: &BinLut,
    hist: &mut [u16],
) -> (f64, f64) {
    let [nx, ny, nz] = dims.map(|d| d as usize);
    let (mut lo, mut hi): (Option<T>, Option<T>) = (None, None);
    let mut counts = [0u32; HISTOGRAM_BINS];
    for z in 0..nz {
        for yy in y[0] as usize..y[1] as usize {
            let row = &v[(z * ny + yy) * nx..][x[0] as usize..x[1] as usize];
            for &value in row {
                lo = Some(lo.map_or(value, |l| l.min(value)));
                hi = Some(hi.map_or(value, |h| h.max(value)));
                let index = (Into::<i32>::into(value) - lut.min) as usize;
                counts[usize::from(lut.bins[index])] += 1;
            }
        }
    }
    for (h, c) in hist.iter_mut().zip(counts) {
        *h = h.saturating_add(u16::try_from(c).unwrap_or(u16::MAX));
    }
    match (lo, hi) {
        (Some(l), Some(h)) => (l.into(), h.into()),
        _ => (f64::NAN, f64::NAN),
    }
}

/// Min, max and histogram of the voxels of `v` (dims `dims`) in x0..x1, y0..y1,
/// all z; NaNs left out.
fn block_stats<T: crate::Voxel>(
    v: &[T],
    dims: [u32; 3],
    x: [u32; 2],
    y: [u32; 2],
    range: [f64; 2],
    hist: &mut [u16],
) -> (f64, f64) {
    let [nx, ny, nz] = dims.map(|d| d as usize);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for z in 0..nz {
        for yy in y[0] as usize..y[1] as usize {
            let row = &v[(z * ny + yy) * nx..][x[0] as usize..x[1] as usize];
            for &value in row {
                let value: f64 = value.into();
                if value.is_nan() {
                    continue;
                }
                lo = lo.min(value);
                hi = hi.max(value);
                let bin = bin_of(value, range);
                hist[bin] = hist[bin].saturating_add(1);
            }
        }
    }
    if lo > hi {
        (f64::NAN, f64::NAN)
    } else {
        (lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::pyramid::levels;

    #[test]
    fn a_block_index_and_its_grid_position_invert_each_other() {
        let grid = [3, 5, 2];
        for i in 0..30 {
            let b = grid_position(grid, i);
            assert!((0..3).all(|a| b[a] < grid[a]), "block {i} at {b:?}");
            assert_eq!(grid_index(grid, b), i);
        }
        // x fastest, then y, then z.
        assert_eq!(grid_position(grid, 1), [1, 0, 0]);
        assert_eq!(grid_position(grid, 3), [0, 1, 0]);
        assert_eq!(grid_position(grid, 15), [0, 0, 1]);
    }

    #[test]
    fn a_row_of_blocks_gets_min_max_and_histograms_at_every_level() {
        // 32 × 16 × 16 voxels: two blocks; the left one 0, the right one 0..=255 along x.
        let (nx, ny, nz) = (32usize, 16usize, 16usize);
        let v: Vec<u8> = (0..nx * ny * nz)
            .map(|i| {
                let x = i % nx;
                if x < 16 { 0 } else { ((x - 16) * 17) as u8 }
            })
            .collect();
        let dims = [32, 16, 16];
        let l = levels(VoxelData::U8(v), dims, [0.0, 255.0]);
        let mut s = BlockStats::new([2, 1, 1], [0.0, 256.0]);
        s.fill_row(0, &l, dims);
        assert_eq!(s.min_max(0, 0), [0.0, 0.0]);
        assert_eq!(s.min_max(0, 1), [0.0, 255.0]);
        assert_eq!(s.histogram(0, 0).expect("level 0")[0], 4096);
        assert_eq!(
            s.histogram(0, 1)
                .expect("level 0")
                .iter()
                .map(|&c| u32::from(c))
                .sum::<u32>(),
            4096
        );
        // Level 4 is one voxel per block: its value.
        assert_eq!(s.min_max(4, 1), [l[4].get(1), l[4].get(1)]);
        assert_eq!(
            s.histogram(4, 1)
                .expect("level 4")
                .iter()
                .map(|&c| u32::from(c))
                .sum::<u32>(),
            1
        );
    }
}
