//! Level borders without steps: a smooth ramp whose blocks alternate between
//! level 0 and level 2, sampled as the ray caster samples the packed atlas
//! (`locate`, `atlas_coord`, trilinear filtering: the CPU twins of
//! `shared/packed.wgsl`, which the GPU path runs on the same atlas texels).
//!
//! Across a border the sampled value must not jump by more than the coarser
//! level's interpolation error of the signal *along* the border (what a
//! level-2 block sees of its level-0 neighbour's last layer at its own
//! spacing, halved: see `blocks::seams`), here well under the coarser level's
//! own error. With aprons copied at each block's own level, the jump is the
//! whole difference between the two levels' reconstructions at the border.

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use std::sync::Arc;

use blocks::geometry::IDENTITY_DIRECTION;
use blocks::lod::LodSelection;
use blocks::packing::{APRON, Packing};
use blocks::{Geometry, ValueMap, Volume, VoxelData};
use glam::Vec3;
use shaders::cpu::PackedTexture;
use shaders::cpu::packed::atlas_coord;
use shaders::packed::{Atlas, CPU_MAX_EDGE, CpuAtlas, CpuDevice, assemble_cpu};
use shaders::packed_volume::{PackedLayout, PackedVolume};
use shaders::volume_texture::{TexelFormat, VolumeTexture};
use voxserve_tests::render::dataset_of;

const DIMS: [u32; 3] = [64, 64, 32];

/// The ramp in stored units at `p` (level-0 voxel units, voxel i's centre at
/// i + 0.5): curved along every axis, so a coarse level misses some of it.
fn ramp(p: [f64; 3]) -> f64 {
    let q = |v: f64, n: u32| (v / f64::from(n)).powi(2);
    8000.0 + 30000.0 * q(p[0], DIMS[0]) + 12000.0 * q(p[1], DIMS[1]) + 8000.0 * q(p[2], DIMS[2])
}

fn ramp_volume() -> Volume {
    let [nx, ny, nz] = DIMS.map(|d| d as usize);
    let voxels = (0..nx * ny * nz)
        .map(|i| {
            let c = [i % nx, (i / nx) % ny, i / (nx * ny)].map(|v| v as f64 + 0.5);
            ramp(c).round() as u16
        })
        .collect();
    let geometry = Geometry {
        dims: DIMS,
        spacing: [1.0; 3],
        origin: [0.0; 3],
        direction: IDENTITY_DIRECTION,
    };
    Volume::new("ramp", geometry, VoxelData::U16(voxels), ValueMap::IDENTITY).expect("ramp")
}

/// The value the ray caster reads at `p` (level-0 voxel units), in stored units.
fn sample(packed: &PackedTexture, g: &PackedVolume, p: [f64; 3]) -> f64 {
    let tc = Vec3::new(
        (p[0] / f64::from(DIMS[0])) as f32,
        (p[1] / f64::from(DIMS[1])) as f32,
        (p[2] / f64::from(DIMS[2])) as f32,
    );
    let loc = packed.locate(g, tc);
    assert!(!loc.empty, "every block is stored");
    f64::from(packed.atlas.sample_level(atlas_coord(g, tc, &loc))) * f64::from(u16::MAX)
}

/// The largest jump across a block border: for every border plane along
/// every axis, lines across it on a grid of positions along it.
fn largest_step(packed: &PackedTexture, g: &PackedVolume) -> f64 {
    let eps = 1e-3;
    let mut largest: f64 = 0.0;
    for axis in 0..3 {
        let others = [(axis + 1) % 3, (axis + 2) % 3];
        for border in (16..DIMS[axis]).step_by(16) {
            // Half-voxel steps along the border, inside the range of the
            // coarser level's voxel centres (beyond it, at the volume's faces,
            // level 2 holds its last value on both sides of the border).
            for u in 4..DIMS[others[0]] * 2 - 4 {
                for v in 4..DIMS[others[1]] * 2 - 4 {
                    let mut p = [0.0; 3];
                    p[others[0]] = f64::from(u) * 0.5;
                    p[others[1]] = f64::from(v) * 0.5;
                    p[axis] = f64::from(border) - eps;
                    let before = sample(packed, g, p);
                    p[axis] = f64::from(border) + eps;
                    let after = sample(packed, g, p);
                    largest = largest.max((after - before).abs());
                }
            }
        }
    }
    largest
}

/// The largest difference from the ramp inside the blocks of `level`, more
/// than `margin` voxels from their borders: that level's interpolation error.
fn interpolation_error(
    packed: &PackedTexture,
    g: &PackedVolume,
    lod: &[u8],
    level: u8,
    margin: f64,
) -> f64 {
    let grid = DIMS.map(|d| d / 16);
    let mut largest: f64 = 0.0;
    let steps = 64;
    for (b, _) in lod.iter().enumerate().filter(|(_, l)| **l == level) {
        let block = [
            b as u32 % grid[0],
            (b as u32 / grid[0]) % grid[1],
            b as u32 / (grid[0] * grid[1]),
        ];
        for i in 0..steps * steps {
            let t = [i % steps, (i / steps) % steps, (i * 7 + 3) % steps]
                .map(|s| margin + (16.0 - 2.0 * margin) * (f64::from(s as u32) + 0.5) / 64.0);
            let p = [0, 1, 2].map(|a| f64::from(block[a] * 16) + t[a]);
            largest = largest.max((sample(packed, g, p) - ramp(p)).abs());
        }
    }
    largest
}

#[test]
fn blocks_of_levels_0_and_2_meet_without_a_step() {
    let dataset = dataset_of(ramp_volume());
    let grid = dataset.store.meta().blocks;
    let lod: Vec<u8> = (0..grid.iter().product::<u32>())
        .map(|b| {
            let (x, y, z) = (
                b % grid[0],
                (b / grid[0]) % grid[1],
                b / (grid[0] * grid[1]),
            );
            if (x + y + z) % 2 == 0 { 0 } else { 2 }
        })
        .collect();
    let selection = LodSelection {
        lod: Vec::new(),
        kept_voxels: 0,
        budget_voxels: 0,
        capped: false,
        full_voxels: u64::from(DIMS.iter().product::<u32>()),
        non_empty: 0,
        over_budget: false,
        error: 0.0,
    }
    .with_levels(lod.clone());
    let packing = Packing::new(&selection, CPU_MAX_EDGE).expect("packing");
    let desc = VolumeTexture::for_volume(&ramp_volume(), shaders::cpu::CPU_FEATURES);
    assert_eq!(
        desc.format,
        TexelFormat::R16Unorm,
        "stored units are texel × 65535"
    );
    let g = PackedVolume::new(
        &desc,
        PackedLayout {
            atlas_dims: packing.atlas_dims,
            block_grid: grid,
        },
        1,
    );

    // One opacity for every value: no box is thin structure, so the atlas
    // holds the stored levels (blocks::visibility changes nothing).
    let uniform = blocks::TransferFunction::parse("0:ffffff:0.5").expect("tf");
    let seamless = assemble_cpu(&dataset.cache, &packing, &desc, &uniform).expect("atlas");
    // The same atlas with every apron copied at its block's own level.
    let cache = Arc::clone(&dataset.cache);
    let same_level = move |b: usize, lod: &[u8]| {
        let block = cache.store().stats().block_position(b);
        Ok(cache.block_with_apron(usize::from(lod[b]), block, APRON)?)
    };
    let device = CpuDevice {
        max_edge: CPU_MAX_EDGE,
    };
    let same_level = CpuAtlas::upload(&device, grid, packing.clone(), &desc, &same_level)
        .expect("atlas")
        .texture;

    let coarse_error = interpolation_error(&seamless, &g, &lod, 2, 2.0);
    let fine_error = interpolation_error(&seamless, &g, &lod, 0, 1.0);
    let step = largest_step(&seamless, &g);
    let step_same_level = largest_step(&same_level, &g);
    println!(
        "ramp {DIMS:?} u16, levels 0 and 2 alternating: interpolation error level 2 {coarse_error:.1}, \
         level 0 {fine_error:.1}; largest step at a border {step:.1} (aprons at the block's own level: \
         {step_same_level:.1})"
    );
    assert!(
        fine_error < 0.1 * coarse_error,
        "level 0 reconstructs the ramp far closer than level 2: {fine_error:.1} against {coarse_error:.1}"
    );
    assert!(
        step <= 0.5 * coarse_error,
        "a step of {step:.1} at a level border, more than half the coarser level's interpolation \
         error {coarse_error:.1}"
    );
    // The measure sees the steps seamless aprons remove.
    assert!(
        step_same_level > 0.5 * coarse_error,
        "aprons at their block's own level step by {step_same_level:.1}, expected more than \
         {:.1}",
        0.5 * coarse_error
    );
}
