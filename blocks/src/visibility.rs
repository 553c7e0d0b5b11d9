//! Thin structures kept visible at coarse levels, for the transfer function
//! in use.
//!
//! A coarse level's value is fitted to its box of 2^l level-0 voxels per
//! axis ([`crate::store::pyramid`]). A bone plate one voxel thick in a box of
//! 4³ keeps about a quarter of its contrast there, below the opacity ramp of
//! a bone transfer function: at 35:1 the plate vanished, and with it the
//! thin parts of the skull, the head holder and the edges of the orbits
//! (opaque pixels kept: CT head 98.98 %, VHF head 97.65 % of the
//! reference's). What a ray needs through such a box is the box's mean
//! optical depth, not the depth of its mean value.
//!
//! The store keeps, per coarse voxel, the smallest (a) and the largest (b)
//! level-0 value of its box. Reading the box as a mix of a and b in the
//! proportion its value m gives (share f = (m − a) / (b − a) of b), its mean
//! optical depth per voxel is about τ* = (1 − f) τ(a) + f τ(b), τ from the
//! transfer function ([`TransferFunction::optical_depth`]). Where τ(m) falls
//! short of τ*, the value is moved from m towards whichever of a and b is
//! the more opaque until τ = τ* (bisection: the transfer function need not
//! be monotonic). Not where a neighbouring coarse voxel (of the 3³, within
//! the chunk) already shows that extreme at ≥ [`SHOWN_NEARBY`] of its
//! depth: there the box is the edge of a solid, the fitted values already
//! put its surface in the right place, and moving them would thicken it.
//!
//! Measured against a step-1/8 reference at 128² (CPU renderer, gradient
//! shading, default presets, azimuth 30°, elevation 20°), opaque pixels kept
//! / ΔE*uv mean, before → after:
//!
//! | dataset | 9:1 | 35:1 |
//! |---|---|---|
//! | CT head | 99.32 % / 1.68 → 99.48 % / 1.68 | 98.98 % / 2.52 → 99.30 % / 2.46 |
//! | VHF head | 99.03 % / 0.35 → 99.43 % / 0.35 | 97.65 % / 0.65 → 99.51 % / 0.66 |
//! | engine | 99.92 % / 0.57 → 99.92 % / 0.57 | 99.76 % / 1.10 → 99.78 % / 1.12 |
//!
//! Without the neighbour test every box edge moves (measured on a
//! prototype: CT head 9:1 ΔE*uv 1.68 → 2.13). The voxel holding a plate
//! gets its box's mean depth, but the renderer classifies interpolated
//! values, whose profile is narrower than a tent of depths: a ray across a
//! plate one voxel thick keeps about 40 % of its depth at level 2 (unit
//! test), where the fitted level alone kept none.
//!
//! The residency applies this to every coarse chunk a block or a seam reads,
//! so aprons and seams see the same values as the blocks they copy; a change
//! of transfer function writes the coarse blocks again.

use std::sync::Arc;

use rayon::prelude::*;

use crate::store::BLOCK;
use crate::{TransferFunction, ValueMap, Voxel, VoxelData};

/// A neighbour showing the more opaque extreme at this share of its optical
/// depth makes the box an edge, left as it is (module docs).
pub const SHOWN_NEARBY: f64 = 0.75;
/// Bisection steps for the value that gives the box's depth.
const BISECTIONS: usize = 24;

/// Optical depth per level-0 voxel of stored values under a transfer function.
#[derive(Debug, Clone, Copy)]
pub struct Extinction<'a> {
    /// The transfer function, over physical values.
    pub tf: &'a TransferFunction,
    /// Stored → physical values.
    pub value_map: ValueMap,
}

impl Extinction<'_> {
    /// The optical depth at stored value `stored`.
    pub fn at(&self, stored: f64) -> f64 {
        self.tf
            .optical_depth(self.value_map.physical(stored) as f32)
    }
}

/// The 16³ values of a chunk record ([`crate::store::Store::read_chunk_record`]:
/// values, box minima, box maxima) with thin structures kept visible under
/// `extinction` (module docs). `None` for a record without extremes (level
/// 0, or a store written without them): its values are used as they are.
pub fn keep_thin_structures(record: &VoxelData, extinction: Extinction<'_>) -> Option<VoxelData> {
    let n = (BLOCK as usize).pow(3);
    if record.len() != 3 * n {
        return None;
    }
    Some(crate::volume::with_voxels!(record, v => VoxelData::from(kept(v, extinction))))
}

/// A cached chunk ([`crate::cache::BlockCache`]) with thin structures kept
/// visible under `extinction`: a new 16³ chunk for a record with extremes,
/// else the chunk itself.
pub fn kept_chunk(chunk: &Arc<VoxelData>, extinction: Extinction<'_>) -> Arc<VoxelData> {
    keep_thin_structures(chunk, extinction).map_or_else(|| Arc::clone(chunk), Arc::new)
}

fn kept<T: Voxel>(record: &[T], extinction: Extinction<'_>) -> Vec<T> {
    let side = BLOCK as usize;
    let n = side.pow(3);
    let (values, rest) = record.split_at(n);
    let (min, max) = rest.split_at(n);
    let value = |i: usize| -> f64 { values[i].into() };
    let depth: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let m = value(i);
            if m.is_nan() { 0.0 } else { extinction.at(m) }
        })
        .collect();
    (0..n)
        .into_par_iter()
        .map(|i| {
            let (m, a, b): (f64, f64, f64) = (value(i), min[i].into(), max[i].into());
            if m.is_nan() || a.is_nan() || b.is_nan() || b <= a {
                return values[i];
            }
            let (depth_a, depth_b) = (extinction.at(a), extinction.at(b));
            let f = ((m - a) / (b - a)).clamp(0.0, 1.0);
            let target = (1.0 - f) * depth_a + f * depth_b;
            if depth[i] >= target {
                return values[i];
            }
            let (towards, deepest) = if depth_b >= depth_a {
                (b, depth_b)
            } else {
                (a, depth_a)
            };
            let (x, y, z) = (i % side, i / side % side, i / (side * side));
            let near = |c: usize| c.saturating_sub(1)..=(c + 1).min(side - 1);
            let shown_nearby = near(z).any(|nz| {
                near(y).any(|ny| {
                    near(x).any(|nx| depth[(nz * side + ny) * side + nx] >= SHOWN_NEARBY * deepest)
                })
            });
            if shown_nearby {
                return values[i];
            }
            // τ(lo) < target ≤ τ(hi) throughout.
            let (mut lo, mut hi) = (m, towards);
            for _ in 0..BISECTIONS {
                let mid = 0.5 * (lo + hi);
                if extinction.at(mid) < target {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            T::from_f64(hi)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::MemorySource;
    use crate::store::{IngestOptions, ingest_in_memory};
    use crate::{Geometry, Volume};

    /// 64³ u16 of 0 with a bone plate one voxel thick at x = 33 and a solid
    /// from x = 46 on (so the box x 44..47 of level 2 is half bone), as a
    /// store; its level-2 chunk record (one chunk: 16³).
    fn record() -> VoxelData {
        let n = 64usize;
        let voxels: Vec<u16> = (0..n * n * n)
            .map(|i| if i % n == 33 || i % n >= 46 { 1000 } else { 0 })
            .collect();
        let volume = Volume::new(
            "plate",
            Geometry::new([64; 3], [1.0; 3]),
            VoxelData::U16(voxels),
            ValueMap::IDENTITY,
        )
        .expect("volume");
        let mut source = MemorySource::new(Arc::new(volume), "plate");
        let store = ingest_in_memory(&mut source, &IngestOptions::default()).expect("store");
        assert!(store.has_box_extremes());
        store.read_chunk_record(2, [0, 0, 0]).expect("chunk")
    }

    /// Bone shows from 500 up: a quarter of the plate's contrast does not.
    fn bone() -> TransferFunction {
        TransferFunction::parse("500:000000:0,900:ffffff:1").expect("tf")
    }

    /// Level-2 value along x (at y = z = 8).
    fn row(v: &VoxelData) -> Vec<f64> {
        let VoxelData::U16(v) = v else {
            panic!("u16 in, u16 out")
        };
        (0..16)
            .map(|x| f64::from(v[(8 * 16 + 8) * 16 + x]))
            .collect()
    }

    #[test]
    fn a_thin_plate_keeps_its_optical_depth_and_a_solids_edge_stays_where_it_was() {
        let record = record();
        let tf = bone();
        let extinction = Extinction {
            tf: &tf,
            value_map: ValueMap::IDENTITY,
        };
        let kept = keep_thin_structures(&record, extinction).expect("a coarse record");
        let (before, after) = (row(&record), row(&kept));
        // A ray across the plate: the optical depth of the trilinear profile
        // between the level-2 voxels on either side of it (4 level-0 voxels apart).
        let across = |r: &[f64]| -> f64 {
            (0..=64)
                .map(|k| {
                    let x = 6.0 + 4.0 * f64::from(k) / 64.0;
                    let (i, t) = (x.floor() as usize, x.fract());
                    extinction.at(r[i] * (1.0 - t) + r[i + 1] * t) * 4.0 * 4.0 / 64.0
                })
                .sum()
        };
        let plate = extinction.at(1000.0); // one level-0 voxel of bone
        assert!(
            across(&before) < 0.05 * plate,
            "the fitted level keeps {:.3} of the plate's depth {plate:.3}: this test needs it faded ({before:?})",
            across(&before)
        );
        // The voxel holding the plate gets the box's mean depth, but the
        // renderer classifies interpolated values, whose profile is narrower
        // than a tent of depths: a ray keeps part of the plate's depth (2.7
        // of 6.9 here: opacity 0.93 instead of 0.999), far from none.
        let depth = across(&after);
        assert!(
            depth > 0.25 * plate && depth < 2.0 * plate,
            "kept: depth {depth:.3} across the plate, expected {:.3} to {:.3} ({after:?})",
            0.25 * plate,
            2.0 * plate
        );
        // The solid's edge (x = 46: the box 44..47 is half bone) and the
        // solid itself stay; so does the empty space away from the plate.
        for x in [0, 1, 2, 3, 4, 5, 11, 12, 13, 14, 15] {
            assert_eq!(after[x], before[x], "x = {x}: {before:?} → {after:?}");
        }
        // Without box extremes (level 0) nothing is kept or changed.
        let values = VoxelData::U16(vec![0; 4096]);
        assert!(keep_thin_structures(&values, extinction).is_none());
    }
}
