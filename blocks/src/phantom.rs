//! The built-in dataset: a deterministic procedural CT head phantom.
//!
//! A 3D Shepp–Logan head (the ellipsoids of Kak and Slaney's 3D version of the
//! phantom) with a scalp layer added outside the skull and Hounsfield-like values:
//! air −1000 HU, scalp 40 HU, skull 1000 HU, brain 35 HU, ventricles (CSF) 5 HU,
//! and small lesions of 45–70 HU. Values are sums over the ellipsoids a voxel lies
//! in, plus a little zero-mean noise (σ ≈ 5 HU) from a hash of the voxel index, so
//! the phantom is the same on every machine and every run.
//!
//! Stored as 16-bit unsigned values with the usual CT offset: stored = HU + 1024,
//! so the value map is slope 1, intercept −1024.
//!
//! Edges are soft, as in a real scan, where the scanner's point-spread function
//! and partial volume blur every boundary over a voxel or two: a voxel's share of
//! an ellipsoid falls from 1 to 0 over ±[`EDGE_VOXELS`] of its approximate signed
//! distance to the surface. Without this, gradient shading shows every voxel step
//! of the surfaces as terraces. The edge is 1.5 voxels each side, not 1: an
//! edge sharper than that is more than trilinear interpolation reconstructs,
//! and where a surface crosses the voxel grid at different offsets the
//! interpolated profile changes its slope with the offset, which draws
//! concentric rings, one per voxel slice, on every smooth surface seen head-on
//! (in every shading, unshaded too, and at any step).
//!
//! Generation works row by row: along a row of constant y and z each ellipsoid
//! covers one interval of x, found by solving a quadratic. Voxels deep inside the
//! interval get the ellipsoid's full value through a difference array; only the
//! few voxels in the soft band near the surface evaluate a distance. The cost is a
//! few operations per voxel whatever the number of ellipsoids.

use rayon::prelude::*;

use crate::geometry::IDENTITY_DIRECTION;
use crate::{Error, Geometry, ValueMap, Volume, VoxelData};

/// The default edge length in voxels.
pub const DEFAULT_SIZE: u32 = 256;
/// The smallest edge length accepted.
pub const MIN_SIZE: u32 = 16;
/// The largest edge length accepted (512³ × 2 bytes = 256 MiB).
pub const MAX_SIZE: u32 = 512;
/// The physical edge of the phantom's cube, in millimetres (a head fits in it).
pub const EDGE_MM: f32 = 240.0;
/// The value of air, outside every ellipsoid.
pub const AIR_HU: f32 = -1000.0;
/// Peak-to-peak amplitude of the triangular noise (σ = amplitude / √6 ≈ 4.9 HU).
const NOISE_HU: f32 = 12.0;
/// Stored value = HU + this offset.
const STORED_OFFSET: f32 = 1024.0;
/// Half-width of the soft edge, in voxels (see the module docs).
pub const EDGE_VOXELS: f32 = 1.5;
/// Beyond this many voxels from a surface, a voxel is fully in or out.
const BAND_VOXELS: f32 = 3.5;

/// One ellipsoid of the phantom, in normalized coordinates where the cube spans
/// −1..1 along each axis: x towards the patient's left, y towards anterior, z
/// towards superior.
#[derive(Debug, Clone, Copy)]
struct Ellipsoid {
    center: [f32; 3],
    semi_axes: [f32; 3],
    /// Rotation about the z axis, degrees.
    rotation_deg: f32,
    /// Added to every voxel inside, Hounsfield units.
    delta_hu: f32,
}

const fn ellipsoid(
    center: [f32; 3],
    semi_axes: [f32; 3],
    rotation_deg: f32,
    delta_hu: f32,
) -> Ellipsoid {
    Ellipsoid {
        center,
        semi_axes,
        rotation_deg,
        delta_hu,
    }
}

/// The head: scalp, skull, brain, then the Shepp–Logan features inside the brain.
/// Scalp and skull are thicker than in Shepp–Logan's table (5 and 6 mm) so both
/// survive the soft edges at coarse sizes.
const HEAD: [Ellipsoid; 13] = [
    ellipsoid([0.0, 0.0, 0.0], [0.73, 0.96, 0.95], 0.0, 1040.0), // scalp → 40 HU
    ellipsoid([0.0, 0.0, 0.0], [0.69, 0.92, 0.90], 0.0, 960.0),  // skull → 1000 HU
    ellipsoid([0.0, -0.0184, 0.0], [0.64, 0.86, 0.85], 0.0, -965.0), // brain → 35 HU
    ellipsoid([0.22, 0.0, -0.25], [0.11, 0.31, 0.22], -18.0, -30.0), // ventricle → 5 HU
    ellipsoid([-0.22, 0.0, -0.25], [0.16, 0.41, 0.21], 18.0, -30.0), // ventricle → 5 HU
    ellipsoid([0.0, 0.35, -0.25], [0.21, 0.25, 0.5], 0.0, 10.0), // → 45 HU
    ellipsoid([0.0, 0.1, -0.25], [0.046, 0.046, 0.046], 0.0, 25.0), // → 70 HU (inside the one above)
    ellipsoid([0.0, -0.1, -0.25], [0.046, 0.046, 0.046], 0.0, 35.0), // → 70 HU
    ellipsoid([-0.08, -0.605, -0.25], [0.046, 0.023, 0.02], 0.0, 35.0), // → 70 HU
    ellipsoid([0.0, -0.605, -0.25], [0.023, 0.023, 0.02], 0.0, 35.0), // → 70 HU
    ellipsoid([0.06, -0.605, -0.25], [0.023, 0.046, 0.02], 0.0, 35.0), // → 70 HU
    ellipsoid([0.06, -0.105, 0.625], [0.056, 0.04, 0.1], 90.0, 25.0), // → 60 HU
    ellipsoid([0.0, 0.1, 0.625], [0.056, 0.056, 0.1], 0.0, -25.0),  // → 10 HU
];

impl Ellipsoid {
    /// The point relative to the centre, in the ellipsoid's own axes.
    fn local(&self, p: [f32; 3]) -> [f32; 3] {
        let (sin, cos) = self.rotation_deg.to_radians().sin_cos();
        let (dx, dy) = (p[0] - self.center[0], p[1] - self.center[1]);
        [
            cos * dx + sin * dy,
            -sin * dx + cos * dy,
            p[2] - self.center[2],
        ]
    }

    /// The normalized x interval covered on the row at (y, z) by this ellipsoid
    /// with every semi-axis grown by `grow` (negative shrinks), or `None` when the
    /// row misses it.
    fn row_interval(&self, y: f32, z: f32, grow: f32) -> Option<(f32, f32)> {
        let [a, b, c] = self.semi_axes.map(|s| s + grow);
        if a <= 0.0 || b <= 0.0 || c <= 0.0 {
            return None;
        }
        let (sin, cos) = self.rotation_deg.to_radians().sin_cos();
        let dy = y - self.center[1];
        let dz = z - self.center[2];
        // With dx = x - cx, the rotated point is q = (cos dx + sin dy, −sin dx + cos dy, dz),
        // and (qx/a)² + (qy/b)² + (qz/c)² ≤ 1 is a quadratic A dx² + B dx + C ≤ 0.
        let (a2, b2) = (a * a, b * b);
        let qa = cos * cos / a2 + sin * sin / b2;
        let qb = 2.0 * sin * cos * dy * (1.0 / a2 - 1.0 / b2);
        let qc = (sin * dy).powi(2) / a2 + (cos * dy).powi(2) / b2 + dz * dz / (c * c) - 1.0;
        let disc = qb * qb - 4.0 * qa * qc;
        if disc < 0.0 {
            return None;
        }
        let root = disc.sqrt();
        let x0 = self.center[0] + (-qb - root) / (2.0 * qa);
        let x1 = self.center[0] + (-qb + root) / (2.0 * qa);
        Some((x0, x1))
    }

    /// Approximate signed distance from `p` to the surface (negative inside), in
    /// normalized units: the implicit function over its gradient's length, exact
    /// to first order near the surface, which is all the soft edge needs.
    fn signed_distance(&self, p: [f32; 3]) -> f32 {
        let q = self.local(p);
        let a = self.semi_axes;
        let f: f32 = (0..3).map(|i| (q[i] / a[i]).powi(2)).sum::<f32>() - 1.0;
        let grad = (0..3)
            .map(|i| (2.0 * q[i] / (a[i] * a[i])).powi(2))
            .sum::<f32>()
            .sqrt();
        if grad > f32::EPSILON {
            f / grad
        } else {
            f32::NEG_INFINITY
        }
    }
}

/// The share of a voxel inside a surface at signed distance `d` voxels: 1 deep
/// inside, 0 far outside, a smooth step over ±[`EDGE_VOXELS`].
fn coverage(d: f32) -> f32 {
    let t = ((EDGE_VOXELS - d) / (2.0 * EDGE_VOXELS)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// SplitMix64: a fast, well-mixed hash of the voxel index for the noise.
fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

/// Zero-mean triangular noise in −NOISE_HU/2 ..= NOISE_HU/2 for a voxel index.
fn noise_hu(index: u64) -> f32 {
    let h = splitmix64(index);
    let unit = |bits: u64| (bits & 0xff_ffff) as f32 / 16_777_216.0;
    (unit(h) + unit(h >> 32) - 1.0) * (NOISE_HU * 0.5)
}

/// Generates the head phantom as a cube of `size`³ voxels.
///
/// `size` must lie in [`MIN_SIZE`]..=[`MAX_SIZE`]. The cube is [`EDGE_MM`] wide
/// whatever the size, so the spacing is `EDGE_MM / size` on every axis, and it is
/// centred on the physical origin.
pub fn head(size: u32) -> Result<Volume, Error> {
    if !(MIN_SIZE..=MAX_SIZE).contains(&size) {
        return Err(Error::OutOfRange {
            what: "phantom size",
            value: size.to_string(),
            expected: format!("an edge length in voxels from {MIN_SIZE} to {MAX_SIZE}"),
        });
    }
    let grid = Grid { size };
    let n = grid.n();
    let mut voxels = vec![0u16; n * n * n];
    voxels
        .par_chunks_mut(n * n)
        .enumerate()
        .for_each(|(k, slice)| fill_slice(grid, k, slice));
    // Worked out in f32, as the phantom always has, so its stores keep the
    // same numbers.
    let spacing = EDGE_MM / size as f32;
    let centre = -(size as f32 - 1.0) * 0.5 * spacing;
    let geometry = Geometry {
        dims: [size; 3],
        spacing: [f64::from(spacing); 3],
        origin: [f64::from(centre); 3],
        direction: IDENTITY_DIRECTION,
    };
    let mut volume = Volume::new(
        "head phantom",
        geometry,
        VoxelData::U16(voxels),
        ValueMap {
            slope: 1.0,
            intercept: -STORED_OFFSET,
        },
    )?;
    volume.unit = Some("HU".into());
    volume.modality = Some("CT".into());
    Ok(volume)
}

/// The voxel grid of a `size`³ phantom in normalized coordinates (−1..1).
#[derive(Debug, Clone, Copy)]
struct Grid {
    size: u32,
}

impl Grid {
    /// Voxels along each axis.
    fn n(self) -> usize {
        self.size as usize
    }

    /// The normalized coordinate of voxel `i`'s centre.
    fn to_normalized(self, i: usize) -> f32 {
        (i as f32 + 0.5) / self.size as f32 * 2.0 - 1.0
    }

    /// One voxel's width in normalized units.
    fn voxel(self) -> f32 {
        2.0 / self.size as f32
    }

    /// The first voxel whose centre lies at or after `x`: voxel i is inside an
    /// interval when its centre (i + 0.5) / n * 2 - 1 lies in it.
    fn first(self, x: f32) -> usize {
        ((x + 1.0) * 0.5 * self.size as f32 - 0.5).ceil().max(0.0) as usize
    }

    /// The last voxel whose centre lies at or before `x`, or `None` when none does.
    fn last(self, x: f32) -> Option<usize> {
        let i = ((x + 1.0) * 0.5 * self.size as f32 - 0.5).floor();
        if i < 0.0 {
            None
        } else {
            Some((i as usize).min(self.n() - 1))
        }
    }
}

/// Fills z-slice `k` (`n`² stored values), row by row.
fn fill_slice(grid: Grid, k: usize, slice: &mut [u16]) {
    let n = grid.n();
    let z = grid.to_normalized(k);
    // Per row, a difference array (+Δ where an ellipsoid's inner interval
    // starts, −Δ one past where it ends) and the soft edges' shares; a prefix
    // sum of the first plus the second gives every voxel's value.
    let mut steps = vec![0.0f32; n + 1];
    let mut edges = vec![0.0f32; n];
    for (j, row) in slice.chunks_mut(n).enumerate() {
        // Index y grows towards posterior (LPS); the table's y grows anterior.
        let y = -grid.to_normalized(j);
        steps.fill(0.0);
        edges.fill(0.0);
        for e in &HEAD {
            add_to_row(grid, e, y, z, &mut steps, &mut edges);
        }
        let row_start = ((k * n + j) * n) as u64;
        let mut hu = AIR_HU;
        for (i, stored) in row.iter_mut().enumerate() {
            hu += steps[i];
            let value = hu + edges[i] + noise_hu(row_start + i as u64) + STORED_OFFSET;
            *stored = value.round().clamp(0.0, f32::from(u16::MAX)) as u16;
        }
    }
}

/// Adds ellipsoid `e` to the row at (`y`, `z`): its value over the voxels deep
/// inside as a step in `steps`, and its share of the voxels in the soft band
/// near the surface into `edges`.
fn add_to_row(grid: Grid, e: &Ellipsoid, y: f32, z: f32, steps: &mut [f32], edges: &mut [f32]) {
    let voxel = grid.voxel();
    let band = BAND_VOXELS * voxel;
    let Some((o0, o1)) = e.row_interval(y, z, band) else {
        return;
    };
    let (Some(outer_last), outer_first) = (grid.last(o1), grid.first(o0)) else {
        return;
    };
    let inner = e
        .row_interval(y, z, -band)
        .and_then(|(i0, i1)| Some((grid.first(i0), grid.last(i1)?)))
        .filter(|(a, b)| a <= b);
    let mut soft = |i: usize| {
        let d = e.signed_distance([grid.to_normalized(i), y, z]) / voxel;
        edges[i] += e.delta_hu * coverage(d);
    };
    match inner {
        Some((inner_first, inner_last)) => {
            steps[inner_first] += e.delta_hu;
            steps[inner_last + 1] -= e.delta_hu;
            (outer_first..inner_first).for_each(&mut soft);
            (inner_last + 1..=outer_last).for_each(&mut soft);
        }
        None => (outer_first..=outer_last).for_each(&mut soft),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The physical value at a normalized position (x left, y anterior, z superior).
    fn hu_at(v: &Volume, p: [f32; 3]) -> f32 {
        let n = v.geometry.dims[0] as f32;
        let idx = |t: f32| (((t + 1.0) * 0.5 * n) as u32).min(v.geometry.dims[0] - 1);
        v.physical_at(idx(p[0]), idx(-p[1]), idx(p[2])) as f32
    }

    #[test]
    fn tissues_have_their_hounsfield_values() {
        let v = head(128).expect("phantom");
        let near = |got: f32, want: f32| (got - want).abs() <= NOISE_HU;
        assert!(near(hu_at(&v, [0.95, 0.95, 0.95]), -1000.0), "air");
        assert!(near(hu_at(&v, [0.71, 0.0, 0.0]), 40.0), "scalp");
        assert!(near(hu_at(&v, [0.665, 0.0, 0.0]), 1000.0), "skull");
        assert!(near(hu_at(&v, [0.3, 0.5, 0.3]), 35.0), "brain");
        assert!(near(hu_at(&v, [0.22, 0.0, -0.25]), 5.0), "ventricle");
        let lesion = hu_at(&v, [0.0, 0.1, -0.25]);
        assert!(near(lesion, 70.0), "lesion {lesion}");
    }

    #[test]
    fn noise_is_zero_mean_and_small() {
        let v = head(64).expect("phantom");
        // Air outside the head: the mean of many voxels is −1000 within a fraction of an HU.
        let corner: Vec<f32> = (0..8)
            .flat_map(|z| (0..8).flat_map(move |y| (0..8).map(move |x| (x, y, z))))
            .map(|(x, y, z)| v.physical_at(x, y, z) as f32)
            .collect();
        let mean = corner.iter().sum::<f32>() / corner.len() as f32;
        assert!((mean - AIR_HU).abs() < 1.0, "mean air {mean}");
        assert!(
            corner
                .iter()
                .all(|h| (h - AIR_HU).abs() <= NOISE_HU * 0.5 + 0.5)
        );
    }

    #[test]
    fn generation_is_deterministic() {
        let a = head(48).expect("phantom");
        let b = head(48).expect("phantom");
        assert_eq!(a.voxels, b.voxels);
    }

    #[test]
    fn geometry_is_centred_with_isotropic_spacing() {
        let v = head(64).expect("phantom");
        let g = v.geometry;
        assert_eq!(g.dims, [64; 3]);
        assert_eq!(g.spacing_f32(), [EDGE_MM / 64.0; 3]);
        let last_centre = g.origin[0] + 63.0 * g.spacing[0];
        assert!((g.origin[0] + last_centre).abs() < 1e-3);
        assert_eq!(v.unit.as_deref(), Some("HU"));
        // At 64³ the 6 mm skull is under two voxels thick and its soft edges
        // keep it below 1000 HU; at 128³ its core reaches bone.
        let v = head(128).expect("phantom");
        assert!(v.value_range[0] < -990.0 && v.value_range[1] > 990.0);
    }

    #[test]
    fn the_skull_is_left_right_symmetric() {
        // Scalp, skull and brain are symmetric; only the small features inside the
        // brain (below 100 HU) are not. Mirrored bone voxels differ by noise only.
        let v = head(64).expect("phantom");
        for z in 0..64 {
            for y in 0..64 {
                for x in 0..32 {
                    let (a, b) = (v.physical_at(x, y, z), v.physical_at(63 - x, y, z));
                    if a.max(b) > 300.0 {
                        assert!(
                            (a - b).abs() <= f64::from(NOISE_HU) + 1.0,
                            "({x},{y},{z}): {a} vs {b}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn edges_are_soft_and_monotone_across_the_skull_surface() {
        // Along +x from inside the skull into the scalp, HU falls from bone to soft
        // tissue through intermediate values, not in one step.
        let v = head(256).expect("phantom");
        let (y, z) = (128, 128);
        let profile: Vec<f32> = (212..220).map(|x| v.physical_at(x, y, z) as f32).collect();
        let intermediate = profile
            .iter()
            .filter(|h| **h > 200.0 && **h < 850.0)
            .count();
        assert!(intermediate >= 1, "{profile:?}");
        assert!(profile.first().is_some_and(|h| *h > 950.0), "{profile:?}");
        assert!(profile.last().is_some_and(|h| *h < 60.0), "{profile:?}");
        for w in profile.windows(2) {
            assert!(w[1] <= w[0] + NOISE_HU, "{profile:?}");
        }
    }

    #[test]
    fn coverage_is_a_smooth_step() {
        assert_eq!(coverage(-10.0), 1.0);
        assert_eq!(coverage(10.0), 0.0);
        assert!((coverage(0.0) - 0.5).abs() < 1e-6);
        assert!(coverage(-0.5) > coverage(0.5));
    }

    #[test]
    fn sizes_out_of_range_are_refused() {
        for size in [0, MIN_SIZE - 1, MAX_SIZE + 1] {
            let err = head(size).expect_err("size out of range");
            let msg = err.to_string();
            assert!(
                msg.contains("phantom size") && msg.contains("from 16 to 512"),
                "{msg}"
            );
        }
    }
}
