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
//!
//! On the same blocks, the light twins' rays must take the same values
//! whether they read four samples at once or one by one.

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use std::sync::Arc;

use blocks::TransferFunction;
use blocks::geometry::IDENTITY_DIRECTION;
use blocks::lod::LodSelection;
use blocks::packing::{APRON, Packing};
use blocks::store::grid_position;
use blocks::transfer_function::TABLE_LEN;
use blocks::{Geometry, ValueMap, Volume, VoxelData};
use glam::Vec3;
use server::Dataset;
use shaders::LightSettings;
use shaders::cpu::global_light::{self as twin, LightState};
use shaders::cpu::packed::atlas_coord;
use shaders::cpu::{PackedTexture, Texture3d};
use shaders::global_light::{LightSetup, LightSource, Stage};
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

/// Where `p` (level-0 voxel units) is in `packed`'s atlas, read as the ray
/// caster reads it: in the block `p` lies in.
fn atlas_position(packed: &PackedTexture, g: &PackedVolume, p: [f64; 3]) -> Vec3 {
    let tc = Vec3::new(
        (p[0] / f64::from(DIMS[0])) as f32,
        (p[1] / f64::from(DIMS[1])) as f32,
        (p[2] / f64::from(DIMS[2])) as f32,
    );
    let loc = packed.locate(g, tc);
    assert!(!loc.empty, "every block is stored");
    atlas_coord(g, tc, &loc)
}

/// The value the ray caster reads at `p` (level-0 voxel units), in stored units.
fn sample(packed: &PackedTexture, g: &PackedVolume, p: [f64; 3]) -> f64 {
    let at = atlas_position(packed, g, p);
    f64::from(packed.atlas.sample_level(at)) * f64::from(u16::MAX)
}

/// The stored light the lit ray caster reads at `p` (level-0 voxel units).
fn light_at(packed: &PackedTexture, g: &PackedVolume, light: &Texture3d, p: [f64; 3]) -> f64 {
    f64::from(light.sample_level(atlas_position(packed, g, p)))
}

/// The largest and the mean jump across a block border of what `read` gives:
/// for every border plane along every axis, lines across it on a grid of
/// positions along it.
fn steps(read: impl Fn([f64; 3]) -> f64) -> (f64, f64) {
    let eps = 1e-3;
    let mut largest: f64 = 0.0;
    let (mut sum, mut count) = (0.0, 0u32);
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
                    let before = read(p);
                    p[axis] = f64::from(border) + eps;
                    let after = read(p);
                    largest = largest.max((after - before).abs());
                    sum += (after - before).abs();
                    count += 1;
                }
            }
        }
    }
    (largest, sum / f64::from(count.max(1)))
}

/// The largest `error` inside the blocks of `level`, more than `margin`
/// voxels from their borders: with the difference from what the level
/// reconstructs, that level's interpolation error.
fn largest_error(lod: &[u8], level: u8, margin: f64, error: impl Fn([f64; 3]) -> f64) -> f64 {
    let grid = DIMS.map(|d| d / 16);
    let mut largest: f64 = 0.0;
    let steps = 64;
    for (b, _) in lod.iter().enumerate().filter(|(_, l)| **l == level) {
        let block = grid_position(grid, b);
        for i in 0..steps * steps {
            let t = [i % steps, (i / steps) % steps, (i * 7 + 3) % steps]
                .map(|s| margin + (16.0 - 2.0 * margin) * (f64::from(s as u32) + 0.5) / 64.0);
            let p = [0, 1, 2].map(|a| f64::from(block[a] * 16) + t[a]);
            largest = largest.max(error(p));
        }
    }
    largest
}

/// Levels 0 and 2 alternating over a grid of `grid` blocks, as a checkerboard.
fn checkerboard(grid: [u32; 3]) -> Vec<u8> {
    (0..grid.iter().product::<u32>())
        .map(|b| {
            let [x, y, z] = grid_position(grid, b as usize);
            if (x + y + z) % 2 == 0 { 0 } else { 2 }
        })
        .collect()
}

/// The ramp's blocks packed at levels `lod`: the packing, the texture's
/// description and the packed volume.
fn packing_of(lod: &[u8], grid: [u32; 3]) -> (Packing, VolumeTexture, PackedVolume) {
    let selection = LodSelection {
        full_voxels: u64::from(DIMS.iter().product::<u32>()),
        ..LodSelection::from_levels(lod.to_vec())
    };
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
    (packing, desc, g)
}

#[test]
fn blocks_of_levels_0_and_2_meet_without_a_step() {
    let dataset = dataset_of(ramp_volume());
    let grid = dataset.store.meta().blocks;
    let lod = checkerboard(grid);
    let (packing, desc, g) = packing_of(&lod, grid);

    // One opacity for every value: no box is thin structure, so the atlas
    // holds the stored levels (blocks::visibility changes nothing).
    let uniform = TransferFunction::parse("0:ffffff:0.5").expect("tf");
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

    let error = |p: [f64; 3]| (sample(&seamless, &g, p) - ramp(p)).abs();
    let coarse_error = largest_error(&lod, 2, 2.0, error);
    let fine_error = largest_error(&lod, 0, 1.0, error);
    let (step, _) = steps(|p| sample(&seamless, &g, p));
    let (step_same_level, _) = steps(|p| sample(&same_level, &g, p));
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

/// Global light on the ramp's blocks at levels `lod` (CPU twins, every
/// stage run, converged), with what produced it.
struct Lit {
    packed: PackedTexture,
    table: Vec<[f32; 4]>,
    setup: LightSetup,
    state: LightState,
}

/// [`Lit`] of the ramp's blocks at levels `lod`; and the direct light and
/// the SVR it read, as textures.
fn lit_blocks(
    dataset: &Dataset,
    lod: &[u8],
    tf: &TransferFunction,
    settings: &LightSettings,
) -> (Lit, Texture3d, Texture3d) {
    let grid = dataset.store.meta().blocks;
    let (packing, desc, _) = packing_of(lod, grid);
    let packed = assemble_cpu(&dataset.cache, &packing, &desc, tf).expect("atlas");
    let table = tf.table(desc.tf_domain, 1024).expect("table");
    let layout = PackedLayout {
        atlas_dims: packing.atlas_dims,
        block_grid: grid,
    };
    let setup = LightSetup::new(&desc, settings, &packing, layout, table.len() as u32);
    let inputs = setup.twin_inputs(&packed, &table, settings.method);
    let mut state = LightState::default();
    for stage in Stage::ALL {
        twin::run(stage, &inputs, &mut state);
    }
    let params = &setup.params;
    let direct = Texture3d::new(params.atlas_dims(), state.direct_light.clone());
    let shadow = Texture3d::new(params.svr_dims, state.shadow_volume.clone());
    let lit = Lit {
        packed,
        table,
        setup,
        state,
    };
    (lit, direct, shadow)
}

/// Global light on the ramp's blocks at levels `lod` (CPU twins, converged):
/// the stored light as the renderer keeps it, the same without
/// `light_seams`, the packed data and the packed volume.
fn light_of(
    dataset: &Dataset,
    lod: &[u8],
    tf: &TransferFunction,
    settings: &LightSettings,
) -> (Texture3d, Texture3d, PackedTexture, PackedVolume) {
    let (lit, direct, shadow) = lit_blocks(dataset, lod, tf, settings);
    let Lit {
        packed,
        table,
        setup,
        state,
    } = lit;
    let params = &setup.params;
    let atlas = params.atlas_dims();
    let mut without = vec![0.0; state.light_volume.len()];
    for d in &setup.directions {
        twin::in_scatter(
            &params.scattering(d),
            &packed,
            &table,
            &setup.slot_blocks,
            &direct,
            &shadow,
            &mut without,
        );
    }
    (
        Texture3d::new(atlas, state.light_volume),
        Texture3d::new(atlas, without),
        packed,
        params.volume,
    )
}

/// The stored light of global light propagation meets across level borders
/// as the data does: `light_seams` gives the finer block's apron the coarser
/// block's light on their border. The light's interpolation error is
/// measured against the light computed with every block at level 0.
#[test]
fn lit_blocks_of_levels_0_and_2_meet_without_a_step_in_the_light() {
    let dataset = dataset_of(ramp_volume());
    let grid = dataset.store.meta().blocks;
    let lod = checkerboard(grid);
    // Thin everywhere, thicker where the ramp is high: the light fades
    // smoothly across the volume and bends with the ramp.
    let tf = TransferFunction::parse("0:ffffff:0.01,65535:ffffff:0.08").expect("tf");
    let settings = LightSettings {
        source: LightSource::Directional([-0.6, -0.5, 0.6]),
        scatter_radius_voxels: 0.0,
        directions: 1,
        ..LightSettings::default()
    };
    let (seamless, without, packed, g) = light_of(&dataset, &lod, &tf, &settings);
    let level_0 = vec![0u8; lod.len()];
    let (full, _, full_packed, full_g) = light_of(&dataset, &level_0, &tf, &settings);

    let error = |p: [f64; 3]| {
        (light_at(&packed, &g, &seamless, p) - light_at(&full_packed, &full_g, &full, p)).abs()
    };
    // Level 0's blocks are lit through level 2's, so their light differs too.
    let coarse_error = largest_error(&lod, 2, 2.0, error);
    let fine_error = largest_error(&lod, 0, 1.0, error);
    let (step, mean) = steps(|p| light_at(&packed, &g, &seamless, p));
    let (step_without, mean_without) = steps(|p| light_at(&packed, &g, &without, p));
    println!(
        "ramp {DIMS:?}, global light, levels 0 and 2 alternating: light error against every \
         block at level 0: level 2 {coarse_error:.2e}, level 0 {fine_error:.2e}; step at a border \
         largest {step:.2e}, mean {mean:.2e} (without light_seams: {step_without:.2e}, \
         {mean_without:.2e})"
    );
    assert!(
        mean <= 0.25 * mean_without,
        "light_seams leaves a mean step of {mean:.2e} at level borders, more than a quarter \
         of the {mean_without:.2e} without"
    );
    assert!(
        step <= 0.5 * coarse_error,
        "a step of {step:.2e} in the light at a level border, more than half the coarser \
         level's interpolation error {coarse_error:.2e}"
    );
    // The measure sees the steps light_seams removes.
    assert!(
        step_without > 0.5 * coarse_error,
        "without light_seams the light steps by {step_without:.2e}, expected more than {:.2e}",
        0.5 * coarse_error
    );
}

/// Local opacity and in-scattering read four samples of a light ray side by
/// side where the four lie in one block, with a transfer-function table of `TABLE_LEN`
/// entries (what every renderer builds), and one by one with any other
/// table: the opacities and the light stored must be the same bits either way. Blocks of
/// levels 0 and 2 put faces between the groups, a point light in the
/// volume turns the rays every way, and opaque stretches end rays inside
/// groups.
#[test]
fn light_rays_read_four_samples_at_once_as_they_read_them_one_by_one() {
    let dataset = dataset_of(ramp_volume());
    let grid = dataset.store.meta().blocks;
    let lod = checkerboard(grid);
    let tf = TransferFunction::parse("0:ffffff:0.05,20000:ffffff:0.2,65535:ffffff:1").expect("tf");
    let settings = LightSettings {
        source: LightSource::Point([0.3, 0.6, 0.5]),
        scatter_radius_voxels: 8.0,
        directions: 6,
        ..LightSettings::default()
    };
    let (lit, direct, shadow) = lit_blocks(&dataset, &lod, &tf, &settings);
    let Lit {
        packed,
        table,
        setup,
        state,
    } = &lit;
    assert_eq!(
        table.len(),
        TABLE_LEN,
        "a table the march reads four at once"
    );
    // The same entries and one more past them, never read (the stages read
    // `tf_len` entries): a table the four-at-once reads do not take.
    let one_by_one: Vec<[f32; 4]> = table.iter().copied().chain([[0.0; 4]]).collect();
    let params = &setup.params;
    let mut four = vec![0.0; state.light_volume.len()];
    let mut one = four.clone();
    for d in &setup.directions {
        let p = params.scattering(d);
        let slots = &setup.slot_blocks;
        twin::in_scatter(&p, packed, table, slots, &direct, &shadow, &mut four);
        twin::in_scatter(&p, packed, &one_by_one, slots, &direct, &shadow, &mut one);
    }
    let slots = &setup.slot_blocks;
    let local = twin::local_opacity(params, packed, table, slots);
    let local_one = twin::local_opacity(params, packed, &one_by_one, slots);
    let opaque = local.iter().filter(|&&a| a > 0.0).count();
    let local_differ = local
        .iter()
        .zip(&local_one)
        .filter(|(a, b)| a.to_bits() != b.to_bits())
        .count();
    println!("local opacity: {opaque} texels not clear, {local_differ} differ");
    assert!(opaque > 10_000, "only {opaque} texels not clear");
    assert_eq!(
        local_differ, 0,
        "{local_differ} texels' local opacity differs"
    );
    let lighted = four.iter().filter(|&&l| l > 0.0).count();
    let differ = four
        .iter()
        .zip(&one)
        .filter(|(a, b)| a.to_bits() != b.to_bits())
        .count();
    println!(
        "in-scattering, {} directions: {lighted} texels lit, {differ} differ between four at once and one by one",
        setup.directions.len()
    );
    assert!(lighted > 10_000, "only {lighted} texels lit");
    assert_eq!(differ, 0, "{differ} texels' light differs");
}
