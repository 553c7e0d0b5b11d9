//! The levels of detail of one slab: level l is the volume averaged over boxes of
//! 2^l voxels per axis (the mean of the voxels present where a box hangs over the
//! volume's edge, NaNs left out).
//!
//! A slab is 16 slices deep (or what is left at the end), starting at a multiple
//! of 16, so every box of every level up to 4 lies inside one slab and slabs are
//! independent. Level 1 is summed from the voxels, each coarser level from the
//! sums and counts of the one before, in `f64`: every level is the exact box
//! average of level 0, rounded once to the voxel type.

use rayon::prelude::*;

use crate::{Voxel, VoxelData, VoxelType};

/// Levels of detail kept: 16³ (level 0) down to 1³ (level 4) per block.
pub const LEVELS: usize = 5;

/// Sums and counts of one level of a slab.
struct Sums {
    dims: [usize; 3],
    sum: Vec<f64>,
    count: Vec<u32>,
}

/// Level dims for level-0 dims `d` at level `l`: ceil(d / 2^l).
pub fn level_dims(d: [u32; 3], level: usize) -> [u32; 3] {
    d.map(|n| n.div_ceil(1 << level))
}

/// Level 1 sums from level-0 voxels.
fn first_sums<T: Voxel>(v: &[T], dims: [usize; 3]) -> Sums {
    let [nx, ny, nz] = dims;
    let out = [nx.div_ceil(2), ny.div_ceil(2), nz.div_ceil(2)];
    let plane = out[0] * out[1];
    let mut sum = vec![0.0f64; plane * out[2]];
    let mut count = vec![0u32; plane * out[2]];
    sum.par_chunks_mut(plane)
        .zip(count.par_chunks_mut(plane))
        .enumerate()
        .for_each(|(k, (s_plane, c_plane))| {
            for z in 2 * k..(2 * k + 2).min(nz) {
                for y in 0..ny {
                    let row = &v[(z * ny + y) * nx..][..nx];
                    let out_row = (y / 2) * out[0];
                    for (x, &value) in row.iter().enumerate() {
                        let value: f64 = value.into();
                        if !value.is_nan() {
                            s_plane[out_row + x / 2] += value;
                            c_plane[out_row + x / 2] += 1;
                        }
                    }
                }
            }
        });
    Sums {
        dims: out,
        sum,
        count,
    }
}

/// The next level's sums from this level's.
fn coarser(s: &Sums) -> Sums {
    let [nx, ny, nz] = s.dims;
    let out = [nx.div_ceil(2), ny.div_ceil(2), nz.div_ceil(2)];
    let plane = out[0] * out[1];
    let mut sum = vec![0.0f64; plane * out[2]];
    let mut count = vec![0u32; plane * out[2]];
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let i = (z * ny + y) * nx + x;
                let o = ((z / 2) * out[1] + y / 2) * out[0] + x / 2;
                sum[o] += s.sum[i];
                count[o] += s.count[i];
            }
        }
    }
    Sums {
        dims: out,
        sum,
        count,
    }
}

/// Averages back to the voxel type: rounded to nearest for integers (the
/// average of values of a type always fits it), NaN where a box had no value.
fn averages(s: &Sums, ty: VoxelType) -> VoxelData {
    let mean = s
        .sum
        .iter()
        .zip(&s.count)
        .map(|(&sum, &n)| if n == 0 { f64::NAN } else { sum / f64::from(n) });
    match ty {
        VoxelType::U8 => VoxelData::U8(mean.map(u8::from_f64).collect()),
        VoxelType::I8 => VoxelData::I8(mean.map(i8::from_f64).collect()),
        VoxelType::U16 => VoxelData::U16(mean.map(u16::from_f64).collect()),
        VoxelType::I16 => VoxelData::I16(mean.map(i16::from_f64).collect()),
        VoxelType::U32 => VoxelData::U32(mean.map(u32::from_f64).collect()),
        VoxelType::I32 => VoxelData::I32(mean.map(i32::from_f64).collect()),
        VoxelType::F32 => VoxelData::F32(mean.map(f32::from_f64).collect()),
    }
}

/// Every level of a slab of `dims` (x, y, depth): element l has dims
/// [`level_dims`]`(dims, l)`; level 0 is the slab itself.
pub fn levels(slab: VoxelData, dims: [u32; 3]) -> Vec<VoxelData> {
    let d = dims.map(|n| n as usize);
    let ty = slab.voxel_type();
    let mut out = Vec::with_capacity(LEVELS);
    let mut sums = crate::volume::with_voxels!(&slab, v => first_sums(v, d));
    out.push(slab);
    out.push(averages(&sums, ty));
    for _ in 2..LEVELS {
        sums = coarser(&sums);
        out.push(averages(&sums, ty));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_are_box_averages_including_partial_boxes() {
        // 3 × 1 × 1 voxels: level 1 averages (0, 10) and (20) alone.
        let l = levels(VoxelData::U16(vec![0, 10, 20]), [3, 1, 1]);
        assert_eq!(l[1], VoxelData::U16(vec![5, 20]));
        assert_eq!(l[2], VoxelData::U16(vec![10]));
        assert_eq!(l[4], VoxelData::U16(vec![10]));
    }

    #[test]
    fn coarse_levels_average_level_zero_directly_not_rounded_averages() {
        // 0, 0, 0, 1: level 1 rounds to (0, 1) (0.5 rounds up), whose average would
        // round to 1; the true level-2 mean is 0.25, which rounds to 0.
        let l = levels(VoxelData::U8(vec![0, 0, 0, 1]), [4, 1, 1]);
        assert_eq!(l[1], VoxelData::U8(vec![0, 1]));
        assert_eq!(l[2], VoxelData::U8(vec![0]));
    }

    #[test]
    fn nans_are_left_out_of_averages() {
        let l = levels(
            VoxelData::F32(vec![f32::NAN, 2.0, f32::NAN, f32::NAN]),
            [4, 1, 1],
        );
        assert_eq!(l[1].get(0), 2.0);
        assert!(l[1].get(1).is_nan());
        assert_eq!(l[2].get(0), 2.0);
    }

    #[test]
    fn level_dims_round_up() {
        assert_eq!(level_dims([256, 100, 17], 4), [16, 7, 2]);
        assert_eq!(level_dims([1, 1, 1], 3), [1, 1, 1]);
    }
}
