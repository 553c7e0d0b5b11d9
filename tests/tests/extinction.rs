//! Extinction-based illumination: every stage on the GPU against its CPU twin
//! (`extinction_sat`, `ambient_occlusion`, `ambient_occlusion_reference`,
//! `soft_shadow`, `shadow_ray`), the lit frame against the lit CPU twin,
//! extinction compositing, SAT queries against brute-force sums, and what is
//! recomputed when.
//!
//! At 256³ the GPU's SAT queries equal brute-force sums of its own cells
//! exactly (relative tolerance 0).
//!
//! Tolerances: the SAT's cells come from `log` of filtered samples, which the
//! GPU and the CPU compute to a few ulps apart, so SAT entries agree to a
//! relative 1e-4 (the 64-bit sums themselves are exact); ambient and light
//! terms (0..~2, stored as f16) to a mean absolute 2e-3 and a largest 0.03.

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use blocks::Preset;
use server::Dataset;
use shaders::cpu::ColourTexture;
use shaders::cpu::extinction::{self as twin, ExtinctionInputs, ExtinctionState};
use shaders::extinction::{
    AoMethod, ExtinctionLight, ExtinctionLightKind, ExtinctionParams, ExtinctionSettings,
    ShadowMethod, Stage,
};
use shaders::volume_texture::VolumeTexture;
use shaders::{
    AnyRenderer, Backend, Camera, Compositing, Frame, FrameRequest, GpuContext, Shading,
};
use voxserve_tests::gpu_or_skip;
use voxserve_tests::image_compare::assert_similar;
use voxserve_tests::phantom::{phantom_64, phantom_64_dataset};
use voxserve_tests::render::{TEST_GPU_BUDGET_BYTES, cpu_raycast, gpu_renderer};

/// Largest accepted mean and maximum absolute difference of ambient and light terms.
const TERM_TOLERANCE: (f64, f64) = (2e-3, 0.03);

fn extinction_request(extinction: ExtinctionSettings) -> FrameRequest {
    FrameRequest {
        camera: Camera {
            azimuth_deg: 30.0,
            elevation_deg: 20.0,
            ..Camera::default()
        },
        shading: Shading::Extinction,
        extinction,
        ..FrameRequest::new(
            96,
            96,
            Preset::CtSoftTissue.transfer_function(phantom_64().value_range),
        )
    }
}

fn light(kind: ExtinctionLightKind, colour: [f32; 3]) -> ExtinctionLight {
    ExtinctionLight {
        kind,
        colour,
        intensity: 1.0,
    }
}

fn check_terms(case: &str, stage: &str, gpu: &[[f32; 4]], cpu: &[[f32; 4]]) {
    assert_eq!(gpu.len(), cpu.len(), "{case}: {stage}: sizes differ");
    let (mut sum, mut max) = (0.0f64, 0.0f64);
    for (a, b) in gpu.iter().zip(cpu) {
        for ch in 0..4 {
            let d = f64::from((a[ch] - b[ch]).abs());
            sum += d;
            max = max.max(d);
        }
    }
    let mean = sum / (4 * gpu.len().max(1)) as f64;
    println!(
        "{case}: {stage}: GPU vs CPU twin mean {mean:.2e}, max {max:.2e} over {} cells",
        gpu.len()
    );
    let spread = cpu.iter().map(|t| t[0]).fold(f32::INFINITY, f32::min)
        < cpu.iter().map(|t| t[0]).fold(f32::NEG_INFINITY, f32::max);
    assert!(spread, "{case}: {stage}: the CPU twin computed a constant");
    assert!(
        mean <= TERM_TOLERANCE.0 && max <= TERM_TOLERANCE.1,
        "{case}: {stage}: mean {mean:.2e} (max {}), largest {max:.2e} (max {})",
        TERM_TOLERANCE.0,
        TERM_TOLERANCE.1
    );
}

/// SAT channels agree to a relative `SAT_TOLERANCE` (their cells come from
/// `log` of filtered samples, a few ulps apart); cells likewise absolutely.
const SAT_TOLERANCE: f64 = 1e-4;

/// Compares what `stage` wrote on the GPU with what its twin wrote.
fn check_stage_output(
    case: &str,
    name: &str,
    stage: Stage,
    gpu: &ExtinctionState,
    cpu: &ExtinctionState,
) {
    match stage {
        Stage::ExtinctionSat => {
            for ch in 0..gpu.sat.channels as usize {
                let (g, c) = (&gpu.sat.data[ch], &cpu.sat.data[ch]);
                assert_eq!(g.len(), c.len(), "{case}: SAT size");
                let worst = g
                    .iter()
                    .zip(c)
                    .map(|(g, c)| (*g as f64 - *c as f64).abs() / (*c as f64).max(16_777_216.0))
                    .fold(0.0f64, f64::max);
                println!("{case}: {name} channel {ch}: largest relative difference {worst:.2e}");
                assert!(
                    worst <= SAT_TOLERANCE,
                    "{case}: SAT channel {ch} differs by {worst:.2e}"
                );
                assert!(*c.last().expect("cells") > 0, "{case}: empty SAT");
            }
            let worst = gpu
                .extinction
                .iter()
                .zip(&cpu.extinction)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(
                f64::from(worst) <= SAT_TOLERANCE,
                "{case}: extinction cells differ by {worst}"
            );
        }
        Stage::AmbientOcclusion => check_terms(case, name, &gpu.ambient, &cpu.ambient),
        Stage::SoftShadow => check_terms(case, name, &gpu.light_cache, &cpu.light_cache),
    }
}

/// Renders `request` on the GPU, reads the SAT and every texture back and
/// compares each stage of [`Stage::ALL`] with its CPU twin fed the GPU's own
/// inputs (so differences do not compound).
fn compare_stages(gpu: &GpuContext, dataset: &Dataset, case: &str, request: &FrameRequest) {
    let mut renderer = gpu_renderer(gpu, dataset);
    let gpu_frame = renderer
        .render(request)
        .unwrap_or_else(|e| panic!("{case}: {e}"));
    let lighting = renderer.extinction().expect("extinction lighting");
    let gpu_state = lighting
        .read_state(gpu)
        .unwrap_or_else(|e| panic!("{case}: readback: {e}"));
    let params: ExtinctionParams = *lighting.params().expect("params");
    let packing = renderer.packing().expect("packed").clone();
    let desc: VolumeTexture = *renderer.volume_texture();
    let tf = request.store_transfer_function(dataset.store.meta());
    let packed =
        shaders::packed::assemble_cpu(&dataset.cache, &packing, &desc, &tf).expect("atlas");
    let table = request
        .store_transfer_function(dataset.store.meta())
        .table(desc.tf_domain, 1024)
        .expect("table");
    let near = shaders::extinction::near_cells_mask(&packing, &params);
    let read = near.iter().filter(|&&b| b != 0).count();
    println!("{case}: {read} of {} blocks near stored ones", near.len());
    let inputs = ExtinctionInputs {
        params: &params,
        settings: &request.extinction,
        packed: &packed,
        tf: &table,
        near_blocks: &near,
    };
    for stage in Stage::ALL {
        let mut cpu_state = gpu_state.clone();
        twin::run(stage, &inputs, &mut cpu_state);
        let name = stage.shader(&request.extinction);
        check_stage_output(case, name, stage, &gpu_state, &cpu_state);
    }
    // The lit frame: the CPU ray caster reading the GPU's light cache.
    let mut cpu_packed = packed;
    cpu_packed.set_light_cache(ColourTexture::new(params.grid, &gpu_state.light_cache));
    let cpu_frame = cpu_raycast(dataset, &desc, &packing, &cpu_packed, request, &table);
    let tolerance = voxserve_tests::Tolerance {
        max_mean: 0.5,
        pixel_threshold: 8,
        max_differing_fraction: 0.01,
    };
    let diff = assert_similar(
        &format!("extinction-{case}"),
        &gpu_frame,
        &cpu_frame,
        &tolerance,
    );
    println!("{case}: lit frame GPU vs CPU twin: {diff:?}");
}

#[test]
fn every_extinction_stage_agrees_with_its_cpu_twin() {
    let Some(gpu) = gpu_or_skip("every_extinction_stage_agrees_with_its_cpu_twin") else {
        return;
    };
    let dataset = phantom_64_dataset();
    let base = ExtinctionSettings {
        sat_size: 32,
        ao_radius: 4,
        ao_shells: 3,
        ..ExtinctionSettings::default()
    };
    let cases = [
        (
            "colour-bleeding-two-lights",
            extinction_request(ExtinctionSettings {
                colour_bleeding: true,
                lights: vec![
                    light(
                        ExtinctionLightKind::Point([0.5, 0.45, 0.55]),
                        [1.0, 0.6, 0.3],
                    ),
                    light(
                        ExtinctionLightKind::Spot {
                            position: [1.4, 0.5, 1.2],
                            direction: [-1.0, 0.0, -0.8],
                            angle: 35.0,
                        },
                        [0.3, 0.6, 1.0],
                    ),
                ],
                cone_angle: 8.0,
                ..base.clone()
            }),
        ),
        (
            "references",
            extinction_request(ExtinctionSettings {
                ao_method: AoMethod::Sampled,
                shadow_method: ShadowMethod::Ray,
                ..base.clone()
            }),
        ),
        (
            "extinction-compositing-directional",
            FrameRequest {
                compositing: Compositing::Extinction,
                ..extinction_request(ExtinctionSettings {
                    sat_size: 40,
                    cone_growth: 0.2,
                    ..base.clone()
                })
            },
        ),
    ];
    for (case, request) in cases {
        compare_stages(gpu, dataset, case, &request);
    }
}

#[test]
fn light_cache_follows_algorithm_1() {
    let dataset = phantom_64_dataset();
    let cpu = || {
        Backend::Cpu
            .renderer(dataset.cache.clone(), TEST_GPU_BUDGET_BYTES)
            .expect("CPU renderer")
    };
    // The CPU renderer's frames after each change equal a fresh renderer's,
    // which computes every stage: what is kept is what would be recomputed.
    let frames = follows_algorithm_1("CPU renderer", &mut cpu());
    for (step, (request, frame)) in frames.iter().enumerate() {
        let fresh = cpu().render(request).expect("render");
        assert!(
            fresh.rgba == frame.rgba,
            "step {step}: the CPU renderer's frame differs from a fresh renderer's"
        );
    }
    if let Some(gpu) = gpu_or_skip("light_cache_follows_algorithm_1 (GPU)") {
        let mut renderer = AnyRenderer::Gpu(Box::new(gpu_renderer(gpu, dataset)));
        follows_algorithm_1("GPU renderer", &mut renderer);
    }
}

/// Checks that `renderer` recomputes the extinction stages a change affects
/// and no others (algorithm 1); the requests and frames of each step.
fn follows_algorithm_1(name: &str, renderer: &mut AnyRenderer) -> Vec<(FrameRequest, Frame)> {
    let mut request = extinction_request(ExtinctionSettings {
        sat_size: 24,
        ao_radius: 3,
        ..ExtinctionSettings::default()
    });
    request.width = 32;
    request.height = 32;
    let mut frames = Vec::new();
    let mut frame = |r: &FrameRequest| {
        let frame = renderer.render(r).expect("render");
        frames.push((r.clone(), frame));
        *renderer
            .last_stats()
            .extinction()
            .expect("extinction timings")
    };
    let first = frame(&request);
    assert!(
        first.sat_ms > 0.0 && first.ambient_occlusion_ms > 0.0 && first.soft_shadow_ms > 0.0,
        "{name}: the first frame computes everything: {first:?}"
    );
    request.camera.azimuth_deg += 40.0;
    let moved = frame(&request);
    assert!(
        moved.sat_ms == 0.0 && moved.ambient_occlusion_ms == 0.0 && moved.soft_shadow_ms == 0.0,
        "{name}: a camera move recomputes nothing: {moved:?}"
    );
    request.extinction.lights[0].kind = ExtinctionLightKind::Point([0.2, 0.8, 0.5]);
    let relit = frame(&request);
    assert!(
        relit.sat_ms == 0.0 && relit.ambient_occlusion_ms == 0.0 && relit.soft_shadow_ms > 0.0,
        "{name}: a light change recomputes the shadows only: {relit:?}"
    );
    request.extinction.ao_radius = 2;
    request.extinction.ao_shells = 2;
    let ao = frame(&request);
    assert!(
        ao.sat_ms == 0.0 && ao.ambient_occlusion_ms > 0.0 && ao.soft_shadow_ms > 0.0,
        "{name}: an AO change recomputes AO and the cache: {ao:?}"
    );
    request.tf = Some(Preset::CtBone.transfer_function(phantom_64().value_range));
    let tf = frame(&request);
    assert!(
        tf.sat_ms > 0.0 && tf.ambient_occlusion_ms > 0.0 && tf.soft_shadow_ms > 0.0,
        "{name}: a transfer-function change recomputes everything: {tf:?}"
    );
    frames
}

/// The sum of `cells` (256³, x fastest) over lo..=hi clamped to the grid.
fn brute_force_sum(cells: &[u64], lo: [i32; 3], hi: [i32; 3]) -> u64 {
    let mut sum = 0u64;
    for z in lo[2].max(0)..=hi[2].min(255) {
        for y in lo[1].max(0)..=hi[1].min(255) {
            let row = (z as usize * 256 + y as usize) * 256;
            for x in lo[0].max(0)..=hi[0].min(255) {
                sum += cells[row + x as usize];
            }
        }
    }
    sum
}

#[test]
fn a_sat_query_equals_the_brute_force_sum_at_256_cubed() {
    // A 256³ SAT of cells up to the largest Δt·τ (so 32-bit or f32 sums would
    // fail); queries from one cell to the whole grid. Exact in 64 bits: the
    // stated relative tolerance is 0.
    let grid = [256u32, 256, 256];
    let n = 256usize * 256 * 256;
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let values: Vec<u64> = (0..n)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state % (4 << 24)
        })
        .collect();
    let sat = twin::sat_from_cells(grid, &values);
    let boxes: [([i32; 3], [i32; 3]); 5] = [
        ([0, 0, 0], [255, 255, 255]),
        ([100, 17, 200], [100, 17, 200]),
        ([3, 250, 9], [40, 255, 90]),
        ([128, 0, 64], [255, 127, 191]),
        ([-10, 200, 250], [10, 300, 400]),
    ];
    for (lo, hi) in boxes {
        let expected = brute_force_sum(&values, lo, hi);
        let got = sat.cuboid_sum(glam::IVec3::from(lo), glam::IVec3::from(hi), 0);
        println!("{lo:?}..{hi:?}: SAT {got}, brute force {expected}");
        assert_eq!(got, expected, "{lo:?}..{hi:?}");
        let depth = f64::from(twin::depth_of(got));
        let exact = expected as f64 / 16_777_216.0;
        assert!(
            (depth - exact).abs() <= exact * 1e-6,
            "{lo:?}..{hi:?}: as Δt·τ {depth} vs {exact}"
        );
    }
}

#[test]
fn the_gpu_sat_at_256_cubed_equals_brute_force_sums_of_its_cells() {
    let Some(gpu) = gpu_or_skip("the_gpu_sat_at_256_cubed_equals_brute_force_sums_of_its_cells")
    else {
        return;
    };
    let dataset = phantom_64_dataset();
    let mut renderer = gpu_renderer(gpu, dataset);
    let request = FrameRequest {
        width: 16,
        height: 16,
        ..extinction_request(ExtinctionSettings {
            sat_size: 256,
            lights: Vec::new(),
            ao_radius: 1,
            ao_shells: 1,
            ..ExtinctionSettings::default()
        })
    };
    renderer.render(&request).expect("render");
    let lighting = renderer.extinction().expect("extinction lighting");
    let volumes = lighting.volumes().expect("volumes");
    let grid = lighting.params().expect("params").grid;
    assert_eq!(grid, [256, 256, 256]);
    // The GPU's own cells, in the fixed point the SAT sums.
    let cells: Vec<u64> = volumes
        .extinction
        .read(gpu)
        .expect("extinction readback")
        .iter()
        .map(|&t| twin::fixed_of(t))
        .collect();
    let mut data: [Vec<u64>; 4] = Default::default();
    data[0] = volumes.read_sat(gpu, 0).expect("SAT readback");
    let sat = twin::Sat {
        grid,
        channels: 1,
        data,
    };
    let boxes: [([i32; 3], [i32; 3]); 4] = [
        ([0, 0, 0], [255, 255, 255]),
        ([128, 100, 90], [128, 100, 90]),
        ([40, 60, 80], [200, 70, 81]),
        ([-5, 100, 100], [60, 140, 400]),
    ];
    for (lo, hi) in boxes {
        let expected = brute_force_sum(&cells, lo, hi);
        let got = sat.cuboid_sum(glam::IVec3::from(lo), glam::IVec3::from(hi), 0);
        println!("GPU SAT {lo:?}..{hi:?}: {got}, brute force over its cells {expected}");
        assert_eq!(got, expected, "{lo:?}..{hi:?}");
        assert!(expected > 0, "{lo:?}..{hi:?} holds extinction");
    }
}

#[test]
fn bad_extinction_settings_are_refused_before_anything_runs() {
    let dataset = phantom_64_dataset();
    let request = extinction_request(ExtinctionSettings {
        ao_shells: 20,
        ..ExtinctionSettings::default()
    });
    let cpu = shaders::cpu::render_packed(
        &dataset.cache,
        &request,
        wgpu::Features::TEXTURE_FORMAT_16BIT_NORM,
        2048,
    );
    assert!(
        matches!(&cpu, Err(shaders::GpuError::Setting(e)) if e.to_string().contains("ao_shells=20")),
        "{cpu:?}"
    );
    if let Some(gpu) = gpu_or_skip("bad_extinction_settings_are_refused_before_anything_runs") {
        let result = gpu_renderer(gpu, dataset).render(&request);
        assert!(
            matches!(&result, Err(shaders::GpuError::Setting(e)) if e.setting == "ao_shells"),
            "{result:?}"
        );
    }
}
