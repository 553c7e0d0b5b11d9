//! The levels of detail of one slab. Level l has one value per box of 2^l
//! voxels per axis, at the box's centre, and the renderer reconstructs it by
//! trilinear interpolation between those values (as it does level 0). So level
//! l ≥ 1 holds the values whose trilinear interpolant is nearest level 0 in the
//! least-squares sense: the orthogonal projection of level 0 onto the trilinear
//! functions of that grid, not the box average. Averaging and then
//! interpolating blurs twice (a box, then a tent): a plate one voxel thick
//! averaged over 2³ voxels keeps half its value and, interpolated, less; the
//! projection keeps as much of it as a linear interpolant of that spacing can
//! show. Measured on the CT head (128², every shown block at one level, against
//! a step-1/8 reference): ΔE*uv 1.98 → 1.86 and opaque pixels kept 97.3 % →
//! 99.5 % at level 1; 4.16 → 3.06 at level 2.
//!
//! The projection is separable. Per axis, with s = 2^l and coarse value i
//! centred at c_i = (i + ½)s − ½ (level-0 voxel coordinates):
//! 1. **Analysis**: a_i = Σ_q φ_i(q) v_q / Σ_q φ_i(q) over the voxels present
//!    (NaNs left out), with the tent φ_i(q) = max(0, 1 − |q − c_i| / s) that
//!    the renderer interpolates with.
//! 2. **Normal equations** G c = a, G the Gram matrix of the sampled tents
//!    normalised alike: tridiagonal, (4s² − 1)/(6s²) on the diagonal and
//!    (2s² + 1)/(12s²) beside it. Its rows sum to 1, so a constant stays
//!    itself; at a line's ends (and beside a NaN) the missing neighbour
//!    reflects. Solved per line by the Thomas algorithm.
//!
//! A slab is 16 slices deep (or what is left at the end), starting at a multiple
//! of 16. Along z the tents and the equations stop at the slab's faces, so
//! every slab is computed alone, in a few slab-sized buffers whatever the
//! volume (within a slab the lines run whole; a block's coarse values depend
//! on its neighbours in x and y). Each level is projected from level 0 in
//! `f64` per line (`f32` between passes), clamped to the volume's value range
//! (the projection overshoots at sharp edges; it must not leave the range the
//! transfer function and the histograms cover) and rounded once to the voxel
//! type.

use rayon::prelude::*;

use crate::{Voxel, VoxelData, VoxelType};

/// Levels of detail kept: 16³ (level 0) down to 1³ (level 4) per block.
pub const LEVELS: usize = 5;

/// Level dims for level-0 dims `d` at level `l`: ceil(d / 2^l).
pub fn level_dims(d: [u32; 3], level: usize) -> [u32; 3] {
    d.map(|n| n.div_ceil(1 << level))
}

/// Per coarse value 0..ceil(n / s) along a line of `n` level-0 voxels: the
/// voxels its tent covers and their weights (module docs, step 1).
fn tents(n: usize, s: usize) -> Vec<Vec<(usize, f64)>> {
    (0..n.div_ceil(s))
        .map(|i| {
            let centre = (i as f64 + 0.5) * s as f64 - 0.5;
            (i.saturating_mul(s).saturating_sub(s)..((i + 2) * s).min(n))
                .map(|q| (q, 1.0 - (q as f64 - centre).abs() / s as f64))
                .filter(|&(_, w)| w > 0.0)
                .collect()
        })
        .collect()
}

/// The normalised Gram matrix of the sampled tents at spacing `s`: its
/// diagonal and the value beside it (module docs, step 2).
fn gram(s: usize) -> (f64, f64) {
    let s2 = (s * s) as f64;
    (
        (4.0 * s2 - 1.0) / (6.0 * s2),
        (2.0 * s2 + 1.0) / (12.0 * s2),
    )
}

/// One line's projection: the analysis of the values `value(q)` into `out`,
/// then the normal equations solved in place. `sweep` is scratch space.
fn project_line(
    value: impl Fn(usize) -> f64,
    tents: &[Vec<(usize, f64)>],
    (diag, off): (f64, f64),
    out: &mut Vec<f64>,
    sweep: &mut Vec<f64>,
) {
    out.clear();
    out.extend(tents.iter().map(|tent| {
        let (mut sum, mut weight) = (0.0, 0.0);
        for &(q, w) in tent {
            let v = value(q);
            if !v.is_nan() {
                sum += w * v;
                weight += w;
            }
        }
        if weight > 0.0 { sum / weight } else { f64::NAN }
    }));
    // Each run between NaNs is a system of its own, its ends reflecting.
    let mut start = 0;
    while start < out.len() {
        let len = out[start..].iter().take_while(|v| !v.is_nan()).count();
        if len > 1 {
            let run = &mut out[start..start + len];
            let b = |i: usize| {
                if i == 0 || i == len - 1 {
                    diag + off
                } else {
                    diag
                }
            };
            sweep.clear();
            sweep.resize(len, 0.0);
            // Thomas algorithm: forward elimination, then back substitution.
            let mut denominator = b(0);
            sweep[0] = off / denominator;
            run[0] /= denominator;
            for i in 1..len {
                denominator = b(i) - off * sweep[i - 1];
                sweep[i] = off / denominator;
                run[i] = (run[i] - off * run[i - 1]) / denominator;
            }
            for i in (0..len - 1).rev() {
                run[i] -= sweep[i] * run[i + 1];
            }
        }
        start += len.max(1);
    }
}

/// The voxels `v` (dims `d`, x fastest) projected onto the tents at spacing
/// `s`: ceil(d / s) values, x fastest, NaN where no voxel was.
fn project<T: Copy + Into<f64> + Sync>(v: &[T], d: [usize; 3], s: usize) -> Vec<f32> {
    let c = d.map(|n| n.div_ceil(s));
    let gram = gram(s);
    let [tx, ty, tz] = d.map(|n| tents(n, s));
    // x, then y, within each slice.
    let slices: Vec<Vec<f32>> = v
        .par_chunks(d[0] * d[1])
        .map(|slice| {
            let (mut line, mut sweep) = (Vec::new(), Vec::new());
            let mut along_x = vec![0f32; c[0] * d[1]];
            for (row, out) in slice.chunks(d[0]).zip(along_x.chunks_mut(c[0])) {
                project_line(|q| row[q].into(), &tx, gram, &mut line, &mut sweep);
                for (o, &l) in out.iter_mut().zip(&line) {
                    *o = l as f32;
                }
            }
            let mut along_y = vec![0f32; c[0] * c[1]];
            for x in 0..c[0] {
                let column = |q: usize| f64::from(along_x[q * c[0] + x]);
                project_line(column, &ty, gram, &mut line, &mut sweep);
                for (j, &l) in line.iter().enumerate() {
                    along_y[j * c[0] + x] = l as f32;
                }
            }
            along_y
        })
        .collect();
    // Then z, per column of the slices, gathered column by column.
    let plane = c[0] * c[1];
    let columns: Vec<f32> = (0..plane)
        .into_par_iter()
        .with_min_len(1024)
        .map_init(
            || (Vec::new(), Vec::new()),
            |(line, sweep), p| {
                project_line(|q| f64::from(slices[q][p]), &tz, gram, line, sweep);
                line.iter().map(|&l| l as f32).collect::<Vec<f32>>()
            },
        )
        .flatten_iter()
        .collect();
    let mut out = vec![0f32; plane * c[2]];
    for (p, column) in columns.chunks(c[2]).enumerate() {
        for (j, &value) in column.iter().enumerate() {
            out[j * plane + p] = value;
        }
    }
    out
}

/// Per box of `s` voxels per axis of `v` (dims `d`), whether it holds no
/// value (only NaNs).
fn empty_boxes(v: &[f32], d: [usize; 3], s: usize) -> Vec<bool> {
    let c = d.map(|n| n.div_ceil(s));
    let mut empty = vec![true; c[0] * c[1] * c[2]];
    for (i, &value) in v.iter().enumerate() {
        if !value.is_nan() {
            let (x, y, z) = (i % d[0], i / d[0] % d[1], i / (d[0] * d[1]));
            empty[((z / s) * c[1] + y / s) * c[0] + x / s] = false;
        }
    }
    empty
}

/// Projected values back to the voxel type: clamped to `range` (NaN stays
/// NaN) and rounded to nearest for integers.
fn to_voxels(values: &[f32], ty: VoxelType, range: [f64; 2]) -> VoxelData {
    let v = values.iter().map(|&v| {
        let v = f64::from(v);
        if v.is_nan() {
            v
        } else {
            v.clamp(range[0], range[1])
        }
    });
    match ty {
        VoxelType::U8 => VoxelData::U8(v.map(u8::from_f64).collect()),
        VoxelType::I8 => VoxelData::I8(v.map(i8::from_f64).collect()),
        VoxelType::U16 => VoxelData::U16(v.map(u16::from_f64).collect()),
        VoxelType::I16 => VoxelData::I16(v.map(i16::from_f64).collect()),
        VoxelType::U32 => VoxelData::U32(v.map(u32::from_f64).collect()),
        VoxelType::I32 => VoxelData::I32(v.map(i32::from_f64).collect()),
        VoxelType::F32 => VoxelData::F32(v.map(f32::from_f64).collect()),
    }
}

/// Every level of a slab of `dims` (x, y, depth) of a volume whose stored
/// values span `range`: element l has dims [`level_dims`]`(dims, l)`; level 0
/// is the slab itself.
pub fn levels(slab: VoxelData, dims: [u32; 3], range: [f64; 2]) -> Vec<VoxelData> {
    let d = dims.map(|n| n as usize);
    let ty = slab.voxel_type();
    let coarse: Vec<VoxelData> = (1..LEVELS)
        .map(|level| {
            let s = 1 << level;
            let mut values = crate::volume::with_voxels!(&slab, v => project(v, d, s));
            if let VoxelData::F32(v) = &slab {
                // A box without a voxel stays without a value: its
                // neighbours' tents reach into it, but nothing was measured.
                for (value, empty) in values.iter_mut().zip(empty_boxes(v, d, s)) {
                    if empty {
                        *value = f32::NAN;
                    }
                }
            }
            to_voxels(&values, ty, range)
        })
        .collect();
    std::iter::once(slab).chain(coarse).collect()
}

/// Per level 1..=4 of a slab of `dims` (x, y, depth): for every voxel of
/// that level, the smallest and the largest level-0 value in its box of 2^l
/// voxels per axis (NaNs left out; NaN where the box holds none), in the
/// voxel type. Element l − 1 is level l's (minima, maxima). With them the
/// renderer can tell a thin structure that a coarse value blurred away
/// ([`crate::visibility`]).
pub fn box_extremes(slab: &VoxelData, dims: [u32; 3]) -> Vec<(VoxelData, VoxelData)> {
    let d = dims.map(|n| n as usize);
    (1..LEVELS)
        .into_par_iter()
        .map(|level| {
            crate::volume::with_voxels!(slab, v => {
                let (lo, hi) = extremes_of(v, d, 1 << level);
                (VoxelData::from(lo), VoxelData::from(hi))
            })
        })
        .collect()
}

/// [`box_extremes`] of one level: boxes of `s` voxels per axis.
fn extremes_of<T: Voxel>(v: &[T], d: [usize; 3], s: usize) -> (Vec<T>, Vec<T>) {
    let c = d.map(|n| n.div_ceil(s));
    let boxes = c[0] * c[1] * c[2];
    // The type's largest and smallest values (±∞ for floats) until a value comes.
    let (mut lo, mut hi) = (
        vec![T::from_f64(f64::INFINITY); boxes],
        vec![T::from_f64(f64::NEG_INFINITY); boxes],
    );
    for z in 0..d[2] {
        for y in 0..d[1] {
            let row = &v[(z * d[1] + y) * d[0]..][..d[0]];
            let out = ((z / s) * c[1] + y / s) * c[0];
            for (x, &value) in row.iter().enumerate() {
                // NaN compares false: it never becomes an extreme.
                let j = out + x / s;
                if value < lo[j] {
                    lo[j] = value;
                }
                if value > hi[j] {
                    hi[j] = value;
                }
            }
        }
    }
    // Only a box of NaNs (floats) keeps lo > hi: it has no extremes.
    let nan = T::from_f64(f64::NAN);
    for (l, h) in lo.iter_mut().zip(hi.iter_mut()) {
        if *l > *h {
            (*l, *h) = (nan, nan);
        }
    }
    (lo, hi)
}

/// Level `level` of a whole volume `voxels` of `dims` whose stored values
/// span `range`, computed slab by slab as ingest stores it (for checking a
/// store against its source).
///
/// # Panics
/// When `voxels` does not hold `dims` voxels.
pub fn volume_level(
    voxels: &VoxelData,
    dims: [u32; 3],
    range: [f64; 2],
    level: usize,
) -> VoxelData {
    let plane = dims[0] as usize * dims[1] as usize;
    assert_eq!(
        voxels.len(),
        plane * dims[2] as usize,
        "voxels for {dims:?}"
    );
    let mut out: Option<VoxelData> = None;
    for z0 in (0..dims[2]).step_by(16) {
        let depth = 16.min(dims[2] - z0);
        let slab = voxels.slice(z0 as usize * plane..(z0 + depth) as usize * plane);
        let mut l = levels(slab, [dims[0], dims[1], depth], range);
        let part = l.swap_remove(level);
        match &mut out {
            Some(o) => o.append(part).expect("same voxel type"),
            None => out = Some(part),
        }
    }
    out.unwrap_or_else(|| VoxelData::zeros(voxels.voxel_type(), 0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Level `level` of `v` (dims `d`) as f64, through [`levels`] with a
    /// range that clamps nothing.
    fn level(v: VoxelData, d: [u32; 3], level: usize) -> Vec<f64> {
        let l = levels(v, d, [-1e9, 1e9]);
        (0..l[level].len()).map(|i| l[level].get(i)).collect()
    }

    /// The trilinear interpolant of coarse values `c` (dims `cd`, spacing
    /// `s`) at level-0 voxel `q` (as the renderer reads a level: clamped at
    /// the edges).
    fn interpolate(c: &[f64], cd: [usize; 3], s: usize, q: [usize; 3]) -> f64 {
        let mut lo = [0usize; 3];
        let mut hi = [0usize; 3];
        let mut t = [0.0; 3];
        for a in 0..3 {
            let x = ((q[a] as f64 + 0.5) / s as f64 - 0.5).clamp(0.0, (cd[a] - 1) as f64);
            lo[a] = x.floor() as usize;
            hi[a] = (lo[a] + 1).min(cd[a] - 1);
            t[a] = x - lo[a] as f64;
        }
        let mut sum = 0.0;
        for corner in 0..8 {
            let pick = |a: usize| corner >> a & 1 == 1;
            let i = [0, 1, 2].map(|a| if pick(a) { hi[a] } else { lo[a] });
            let w: f64 = (0..3)
                .map(|a| if pick(a) { t[a] } else { 1.0 - t[a] })
                .product();
            sum += w * c[(i[2] * cd[1] + i[1]) * cd[0] + i[0]];
        }
        sum
    }

    /// The squared distance between `v` and the interpolant of `c`.
    fn residual(v: &[f64], d: [usize; 3], c: &[f64], s: usize) -> f64 {
        let cd = d.map(|n| n.div_ceil(s));
        let mut sum = 0.0;
        for z in 0..d[2] {
            for y in 0..d[1] {
                for x in 0..d[0] {
                    let r = v[(z * d[1] + y) * d[0] + x] - interpolate(c, cd, s, [x, y, z]);
                    sum += r * r;
                }
            }
        }
        sum
    }

    #[test]
    fn a_constant_stays_itself_at_every_level_including_partial_boxes() {
        for lvl in 1..LEVELS {
            let l = level_dims([37, 21, 11], lvl);
            let got = level(VoxelData::U16(vec![1234; 37 * 21 * 11]), [37, 21, 11], lvl);
            assert_eq!(got.len() as u32, l.iter().product::<u32>());
            assert!(got.iter().all(|&v| v == 1234.0), "level {lvl}: {got:?}");
        }
    }

    #[test]
    fn a_linear_ramp_is_reproduced_away_from_the_line_ends() {
        // v = 3x + 1000 along 64 voxels: the interpolant of a linear function
        // is the function, so the projection is exact where the reflected
        // ends no longer reach (their error shrinks by about a third per value).
        let d = [64u32, 2, 2];
        let v: Vec<f32> = (0..64 * 4).map(|i| (3 * (i % 64) + 1000) as f32).collect();
        for lvl in 1..4 {
            let s = 1usize << lvl;
            let got = level(VoxelData::F32(v.clone()), d, lvl);
            let n = 64 / s;
            for (i, &value) in got.iter().enumerate().take(n - 3).skip(3) {
                let centre = (i as f64 + 0.5) * s as f64 - 0.5;
                let want = 3.0 * centre + 1000.0;
                assert!(
                    (value - want).abs() < 0.02 * s as f64,
                    "level {lvl} value {i}: {value} vs {want}"
                );
            }
        }
    }

    #[test]
    fn the_projection_is_nearer_level_0_than_box_averages_and_than_any_nudge() {
        // Smooth structure with a sharp plate: what reductions must keep.
        let d = [24usize, 20, 16];
        let v: Vec<f64> = (0..d[0] * d[1] * d[2])
            .map(|i| {
                let (x, y, z) = (i % d[0], i / d[0] % d[1], i / (d[0] * d[1]));
                let smooth =
                    100.0 * ((x as f64) * 0.4).sin() * ((y as f64) * 0.3).cos() + 10.0 * z as f64;
                if x == 9 {
                    smooth + 800.0
                } else {
                    smooth + 400.0
                }
            })
            .collect();
        let dims = d.map(|n| n as u32);
        let data = VoxelData::F32(v.iter().map(|&x| x as f32).collect());
        for lvl in 1..3 {
            let s = 1usize << lvl;
            let cd = d.map(|n| n.div_ceil(s));
            let projected = level(data.clone(), dims, lvl);
            let boxes: Vec<f64> = (0..cd[0] * cd[1] * cd[2])
                .map(|i| {
                    let c = [i % cd[0], i / cd[0] % cd[1], i / (cd[0] * cd[1])];
                    let (mut sum, mut n) = (0.0, 0.0);
                    for z in c[2] * s..((c[2] + 1) * s).min(d[2]) {
                        for y in c[1] * s..((c[1] + 1) * s).min(d[1]) {
                            for x in c[0] * s..((c[0] + 1) * s).min(d[0]) {
                                sum += v[(z * d[1] + y) * d[0] + x];
                                n += 1.0;
                            }
                        }
                    }
                    sum / n
                })
                .collect();
            let best = residual(&v, d, &projected, s);
            let averaged = residual(&v, d, &boxes, s);
            assert!(
                best < averaged,
                "level {lvl}: {best} vs box averages {averaged}"
            );
            // The ends reflect rather than solve the truncated tents exactly,
            // so only interior values are at the optimum: nudging one either
            // way must not help.
            let i = (cd[2] / 2 * cd[1] + cd[1] / 2) * cd[0] + cd[0] / 2;
            for nudge in [-2.0, 2.0] {
                let mut c = projected.clone();
                c[i] += nudge;
                assert!(
                    residual(&v, d, &c, s) > best,
                    "level {lvl}: nudging value {i} by {nudge} helped"
                );
            }
        }
    }

    #[test]
    fn a_thin_plate_keeps_more_of_its_value_than_its_average() {
        // A plate one voxel thick at 1000 in 0: level 1's value there.
        let d = [16u32, 4, 4];
        let v: Vec<u16> = (0..16 * 16)
            .map(|i| if i % 16 == 6 { 1000 } else { 0 })
            .collect();
        let got = level(VoxelData::U16(v), d, 1);
        // Box average: 500 at x = 3 (voxels 6 and 7). The projection keeps more.
        assert!(got[3] > 600.0, "{got:?}");
    }

    #[test]
    fn values_are_clamped_to_the_range_and_nans_left_out() {
        // An edge 0 | 1000: the projection overshoots both ways; clamped.
        let v: Vec<u16> = (0..32 * 4)
            .map(|i| if i % 32 < 16 { 0 } else { 1000 })
            .collect();
        let l = levels(VoxelData::U16(v), [32, 2, 2], [0.0, 1000.0]);
        let got: Vec<f64> = (0..l[1].len()).map(|i| l[1].get(i)).collect();
        assert!(got.iter().all(|&v| (0.0..=1000.0).contains(&v)), "{got:?}");
        assert!(got.contains(&0.0) && got.contains(&1000.0), "{got:?}");
        // NaNs are left out; a box with none keeps NaN at level 1.
        let l = levels(
            VoxelData::F32(vec![f32::NAN, f32::NAN, 2.0, 2.0, 2.0, 2.0]),
            [6, 1, 1],
            [0.0, 10.0],
        );
        assert!(l[1].get(0).is_nan());
        assert_eq!(l[1].get(1), 2.0);
        assert_eq!(l[1].get(2), 2.0);
        assert_eq!(l[2].get(0), 2.0);
    }

    #[test]
    fn box_extremes_are_each_boxs_smallest_and_largest_value() {
        // 5 × 3 × 2 voxels: boxes of 2 per axis at level 1 (3 × 2 × 1 of them, the last
        // ones partial); a NaN is left out, and a box of NaNs only stays NaN.
        let mut v: Vec<f32> = (0..30).map(|i| ((i * 7) % 11) as f32).collect();
        v[0] = f32::NAN;
        for i in [4, 9, 14, 19, 24, 29] {
            v[i] = f32::NAN; // the last column: box x = 2 holds only NaNs
        }
        let extremes = box_extremes(&VoxelData::F32(v.clone()), [5, 3, 2]);
        assert_eq!(extremes.len(), LEVELS - 1);
        let (VoxelData::F32(lo), VoxelData::F32(hi)) = &extremes[0] else {
            panic!("f32 in, f32 out");
        };
        for (j, (&l, &h)) in lo.iter().zip(hi).enumerate() {
            let (bx, by) = (j % 3, j / 3);
            let inside: Vec<f32> = (0..30)
                .filter(|&i| (i % 5) / 2 == bx && (i / 5 % 3) / 2 == by && !v[i].is_nan())
                .map(|i| v[i])
                .collect();
            if inside.is_empty() {
                assert!(l.is_nan() && h.is_nan(), "box {j}");
            } else {
                assert_eq!(
                    l,
                    inside.iter().copied().fold(f32::INFINITY, f32::min),
                    "box {j}"
                );
                assert_eq!(
                    h,
                    inside.iter().copied().fold(f32::NEG_INFINITY, f32::max),
                    "box {j}"
                );
            }
        }
        // Level 4: one box for the whole slab.
        let (VoxelData::F32(lo), VoxelData::F32(hi)) = &extremes[3] else {
            panic!("f32 in, f32 out");
        };
        assert_eq!(
            (lo.as_slice(), hi.as_slice()),
            ([0.0].as_slice(), [10.0].as_slice())
        );
    }

    #[test]
    fn level_dims_round_up() {
        assert_eq!(level_dims([256, 100, 17], 4), [16, 7, 2]);
        assert_eq!(level_dims([1, 1, 1], 3), [1, 1, 1]);
    }
}
