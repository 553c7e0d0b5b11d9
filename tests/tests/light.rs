//! Global light propagation: every stage of the mode's declared list on the
//! GPU against its CPU twin (`local_opacity`, `global_opacity`, `direct_light`
//! or `direct_light_reference`, `in_scatter` with the `light_seams` passes
//! after it; the reduced case has level borders, and the comparison fails
//! when either side leaves the passes out), the lit frame against the lit CPU
//! twin, and what is recomputed when.
//!
//! Tolerance per stage: the two sides differ only in arithmetic — hardware
//! trilinear filtering keeps 8 fraction bits of the weights, the CPU twin's
//! are f32 — so light values (0..1) agree to a mean absolute difference below
//! 1e-3 and a largest difference below 0.05 (a texel where a filtered sample
//! straddles a sharp opacity edge).

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use blocks::Preset;
use server::Dataset;
use shaders::cpu::global_light::{self as twin, LightInputs};
use shaders::global_light::{DirectLightMethod, LightParams, LightSource, Stage};
use shaders::illumination::{near_blocks, slot_blocks};
use shaders::volume_texture::VolumeTexture;
use shaders::{Camera, FrameRequest, GpuContext, LightSettings, Shading};
use voxserve_tests::gpu_or_skip;
use voxserve_tests::image_compare::assert_similar;
use voxserve_tests::phantom::{phantom_64, phantom_64_dataset};
use voxserve_tests::render::{cpu_raycast, gpu_renderer};

/// Largest accepted mean and maximum absolute difference of light values.
const STAGE_TOLERANCE: (f64, f64) = (1e-3, 0.05);

fn lit_request(light: LightSettings, reduction: f32) -> FrameRequest {
    FrameRequest {
        camera: Camera {
            azimuth_deg: 30.0,
            elevation_deg: 20.0,
            ..Camera::default()
        },
        shading: Shading::GlobalLight,
        reduction,
        light,
        ..FrameRequest::new(
            96,
            96,
            Preset::CtSoftTissue.transfer_function(phantom_64().value_range),
        )
    }
}

/// Mean and largest absolute difference of two arrays of the same length.
fn difference(name: &str, gpu: &[f32], cpu: &[f32]) -> (f64, f64) {
    assert_eq!(gpu.len(), cpu.len(), "{name}: sizes differ");
    let (mut sum, mut max) = (0.0f64, 0.0f64);
    for (a, b) in gpu.iter().zip(cpu) {
        let d = f64::from((a - b).abs());
        sum += d;
        max = max.max(d);
    }
    (sum / gpu.len().max(1) as f64, max)
}

fn check_stage(case: &str, stage: &str, gpu: &[f32], cpu: &[f32]) {
    let (mean, max) = difference(stage, gpu, cpu);
    println!(
        "{case}: {stage}: GPU vs CPU twin mean {mean:.2e}, max {max:.2e} over {} values",
        gpu.len()
    );
    let nonzero = cpu.iter().filter(|v| **v != 0.0).count();
    assert!(
        nonzero > 0,
        "{case}: {stage}: the CPU twin computed nothing"
    );
    assert!(
        mean <= STAGE_TOLERANCE.0 && max <= STAGE_TOLERANCE.1,
        "{case}: {stage}: mean {mean:.2e} (max {}), largest {max:.2e} (max {})",
        STAGE_TOLERANCE.0,
        STAGE_TOLERANCE.1
    );
}

/// Renders `request` on the GPU with the light converged, reads every light
/// texture back and compares each stage of [`Stage::ALL`] with its CPU twin
/// fed the GPU's own inputs (so differences do not compound).
fn compare_stages(gpu: &GpuContext, dataset: &Dataset, case: &str, request: &FrameRequest) {
    let mut renderer = gpu_renderer(gpu, dataset);
    let gpu_frame = renderer
        .render_converged(request)
        .unwrap_or_else(|e| panic!("{case}: {e}"));
    let light = renderer.global_light().expect("lit");
    let gpu_state = light
        .read_state(gpu)
        .unwrap_or_else(|e| panic!("{case}: readback: {e}"));
    let params: LightParams = *light.params().expect("params");
    let packing = renderer.packing().expect("packed").clone();
    let desc: VolumeTexture = *renderer.volume_texture();
    let tf = request.store_transfer_function(dataset.store.meta());
    let packed =
        shaders::packed::assemble_cpu(&dataset.cache, &packing, &desc, &tf).expect("atlas");
    let table = request
        .store_transfer_function(dataset.store.meta())
        .table(desc.tf_domain, 1024)
        .expect("table");
    let slots = slot_blocks(&packing);
    let svr = near_blocks(
        &packing,
        params.volume.block_grid,
        params.svr_margin_blocks(),
    );
    let inputs = LightInputs {
        params: &params,
        packed: &packed,
        tf: &table,
        slot_blocks: &slots,
        svr_blocks: &svr,
        directions: light.directions(),
        method: request.light.method,
    };
    for stage in Stage::ALL {
        let mut cpu_state = gpu_state.clone();
        twin::run(stage, &inputs, &mut cpu_state);
        check_stage(
            case,
            stage.shader(request.light.method),
            gpu_state.output(stage),
            cpu_state.output(stage),
        );
    }
    // The lit frame: the CPU ray caster lit by the GPU's light volume, so only
    // the ray caster's arithmetic differs.
    let mut cpu_packed = packed;
    cpu_packed.set_light(gpu_state.light_volume);
    let cpu_frame = cpu_raycast(dataset, &desc, &packing, &cpu_packed, request, &table);
    let tolerance = voxserve_tests::Tolerance {
        max_mean: 0.5,
        pixel_threshold: 8,
        max_differing_fraction: 0.01,
    };
    let diff = assert_similar(&format!("light-{case}"), &gpu_frame, &cpu_frame, &tolerance);
    println!("{case}: lit frame GPU vs CPU twin: {diff:?}");
}

#[test]
fn every_light_stage_agrees_with_its_cpu_twin() {
    let Some(gpu) = gpu_or_skip("every_light_stage_agrees_with_its_cpu_twin") else {
        return;
    };
    let dataset = phantom_64_dataset();
    let cases = [
        (
            "directional-svr1-scatter",
            lit_request(
                LightSettings {
                    source: LightSource::Directional([-0.6, -0.5, 0.6]),
                    svr_scale: 1,
                    scatter_radius_voxels: 6.0,
                    directions: 6,
                    ..LightSettings::default()
                },
                1.0,
            ),
        ),
        (
            "point-inside-svr2-reduced",
            lit_request(
                LightSettings {
                    source: LightSource::Point([0.55, 0.4, 0.6]),
                    svr_scale: 2,
                    segment_voxels: 4,
                    scatter_radius_voxels: 4.0,
                    directions: 3,
                    phase_g: 0.5,
                    ..LightSettings::default()
                },
                9.0,
            ),
        ),
        (
            "point-outside-reference",
            lit_request(
                LightSettings {
                    source: LightSource::Point([1.6, -0.4, 0.9]),
                    scatter_radius_voxels: 0.0,
                    directions: 1,
                    method: DirectLightMethod::Reference,
                    ..LightSettings::default()
                },
                1.0,
            ),
        ),
    ];
    for (case, request) in cases {
        compare_stages(gpu, dataset, case, &request);
    }
}

#[test]
fn light_is_recomputed_on_light_and_tf_changes_refined_per_frame_and_kept_on_camera_moves() {
    let Some(gpu) = gpu_or_skip(
        "light_is_recomputed_on_light_and_tf_changes_refined_per_frame_and_kept_on_camera_moves",
    ) else {
        return;
    };
    let dataset = phantom_64_dataset();
    let mut renderer = gpu_renderer(gpu, dataset);
    // At 4:1, where levels that followed the camera would change the
    // blocks, and with them the light, at every turn.
    let mut request = lit_request(
        LightSettings {
            directions: 3,
            ..LightSettings::default()
        },
        4.0,
    );
    request.width = 32;
    request.height = 32;
    let mut frame = |r: &FrameRequest| {
        renderer.render(r).expect("render");
        *renderer.last_stats().light().expect("lit")
    };
    let first = frame(&request);
    assert!(
        first.recomputed && first.refined == 1 && first.directions == 3,
        "{first:?}"
    );
    assert!(
        first.local_opacity_ms > 0.0
            && first.global_opacity_ms > 0.0
            && first.direct_light_ms > 0.0
    );
    let second = frame(&request);
    assert!(
        !second.recomputed && second.refined == 2 && second.in_scatter_ms > 0.0,
        "{second:?}"
    );
    assert_eq!(
        second.local_opacity_ms, 0.0,
        "a refinement runs in_scatter only"
    );
    request.camera.azimuth_deg += 40.0;
    let third = frame(&request);
    assert!(
        !third.recomputed && third.refined == 3,
        "a camera move keeps refining: {third:?}"
    );
    request.camera.elevation_deg = -10.0;
    let converged = frame(&request);
    assert!(
        !converged.recomputed && converged.refined == 3 && converged.in_scatter_ms == 0.0,
        "{converged:?}"
    );
    // Colour and I_bias apply at render time.
    request.light.bias = 0.4;
    request.light.colour = [1.0, 0.8, 0.6];
    let recoloured = frame(&request);
    assert!(
        !recoloured.recomputed && recoloured.in_scatter_ms == 0.0,
        "{recoloured:?}"
    );
    // The transfer function and the light itself change the light.
    request.tf = Some(Preset::CtBone.transfer_function(phantom_64().value_range));
    assert!(
        frame(&request).recomputed,
        "a new transfer function relights"
    );
    request.light.source = LightSource::Point([0.5, 0.5, 0.5]);
    assert!(frame(&request).recomputed, "a moved light relights");
    request.light.scatter_radius_voxels = 12.0;
    assert!(
        frame(&request).recomputed,
        "a new scattering radius relights"
    );
}

/// The CPU renderer keeps the GPU's update policy (a change recomputes with
/// one in-scattering direction, later frames blend one more each), but
/// refines only while the view stays: a drag draws from the light there is.
/// Stepping through every direction leaves what converging at once does.
#[test]
fn the_cpu_renderer_lights_in_steps_that_a_moving_view_holds() {
    let dataset = phantom_64_dataset();
    let mut renderer = shaders::cpu::CpuRenderer::new(dataset.cache.clone(), 512 << 20);
    let mut request = lit_request(
        LightSettings {
            directions: 3,
            ..LightSettings::default()
        },
        4.0,
    );
    request.width = 48;
    request.height = 48;
    let mut frame = |r: &FrameRequest| {
        let image = renderer.render(r).expect("render");
        (image, *renderer.last_stats().light().expect("lit"))
    };
    let (_, first) = frame(&request);
    assert!(
        first.recomputed && first.refined == 1 && first.directions == 3,
        "{first:?}"
    );
    assert!(first.local_opacity_ms > 0.0 && first.in_scatter_ms > 0.0);
    let (_, second) = frame(&request);
    assert!(
        !second.recomputed && second.refined == 2 && second.local_opacity_ms == 0.0,
        "the same view refines: {second:?}"
    );
    let still = request.clone();
    request.camera.azimuth_deg += 40.0;
    let (_, moved) = frame(&request);
    assert!(
        !moved.recomputed && moved.refined == 2 && moved.in_scatter_ms == 0.0,
        "a moving view holds the light: {moved:?}"
    );
    let (_, stays) = frame(&request);
    assert_eq!(stays.refined, 3, "then it stays, and refines: {stays:?}");
    let (stepped, last) = frame(&still);
    assert!(last.in_scatter_ms == 0.0, "converged: {last:?}");
    let mut fresh = shaders::cpu::CpuRenderer::new(dataset.cache.clone(), 512 << 20);
    let at_once = fresh.render_converged(&still).expect("render");
    assert_eq!(
        stepped.rgba, at_once.rgba,
        "the light stepped through every direction is the light converged at once"
    );
    // A new transfer function relights, with one direction again.
    request.tf = Some(Preset::CtBone.transfer_function(phantom_64().value_range));
    let (_, relit) = frame(&request);
    assert!(relit.recomputed && relit.refined == 1, "{relit:?}");
}

#[test]
fn bad_light_settings_are_refused_before_anything_runs() {
    let dataset = phantom_64_dataset();
    let request = lit_request(
        LightSettings {
            svr_scale: 3,
            ..LightSettings::default()
        },
        1.0,
    );
    let cpu = shaders::cpu::render_packed(
        &dataset.cache,
        &request,
        wgpu::Features::TEXTURE_FORMAT_16BIT_NORM,
        2048,
    );
    assert!(
        matches!(&cpu, Err(shaders::GpuError::Setting(e)) if e.to_string().contains("svr=3")),
        "{cpu:?}"
    );
    if let Some(gpu) = gpu_or_skip("bad_light_settings_are_refused_before_anything_runs") {
        let result = gpu_renderer(gpu, dataset).render(&request);
        assert!(
            matches!(&result, Err(shaders::GpuError::Setting(e)) if e.to_string().contains("svr=3")),
            "{result:?}"
        );
    }
}

/// A bone ball of radius 40 voxels in a 96³ cube, its surface a 1-voxel ramp:
/// a smooth surface that crosses the voxel grid at every depth.
fn ball() -> blocks::Volume {
    let n = 96u32;
    let centre = 48.0f32;
    let voxels = (0..n * n * n)
        .map(|i| {
            let p = [i % n, (i / n) % n, i / (n * n)];
            let r = (0..3)
                .map(|a| (p[a] as f32 + 0.5 - centre).powi(2))
                .sum::<f32>()
                .sqrt();
            ((40.0 - r + 0.5).clamp(0.0, 1.0) * 2000.0) as u16
        })
        .collect();
    blocks::Volume::new(
        "ball",
        blocks::Geometry::new([n, n, n], [1.0; 3]),
        blocks::VoxelData::U16(voxels),
        blocks::ValueMap::IDENTITY,
    )
    .unwrap_or_else(|e| panic!("the ball: {e}"))
}

/// The RMS, in 255ths of luminance, of the luminance less its blur (a 7-pixel
/// box along x and y, twice) within `radius` pixels of the image's centre.
fn high_pass_rms(frame: &shaders::Frame, radius: f64) -> f64 {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let detail = voxserve_tests::checks::high_pass_luminance(frame);
    let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    let (mut sum, mut n) = (0.0, 0.0);
    for y in 0..h {
        for x in 0..w {
            if (x as f64 - cx).hypot(y as f64 - cy) < radius {
                sum += detail[y * w + x].powi(2);
                n += 1.0;
            }
        }
    }
    (sum / n).sqrt()
}

/// Rings: read at the sample, the stored light of a surface blends the lit
/// texels outside it with those inside that its own opacity shadows, in
/// proportions that change with where the surface cuts the texel grid, and a
/// smooth surface shows rings (on the VHF skull at 1:1, plain to see). Read
/// `LIGHT_READ_VOXELS` towards the eye, in the block the point lies in, the
/// ball's lit face is smooth: the luminance's high-pass RMS over its middle
/// is measured at 10.5 of 255 read at the sample, 0.4 read two voxels out.
#[test]
fn a_lit_smooth_surface_shows_no_rings() {
    let dataset = voxserve_tests::render::dataset_of(ball());
    let tf = blocks::TransferFunction::new(vec![
        blocks::TfPoint::new(800.0, [0.9, 0.85, 0.8], 0.0),
        blocks::TfPoint::new(1200.0, [0.9, 0.85, 0.8], 0.9),
    ])
    .unwrap_or_else(|e| panic!("tf: {e}"));
    // The direct light alone (no in-scattering, a coarse shadow volume)
    // keeps the test short: the rings are its self-shadowing.
    let request = FrameRequest {
        camera: Camera {
            fov_y_deg: 30.0,
            ..Camera::default()
        },
        shading: Shading::GlobalLight,
        light: LightSettings {
            scatter_radius_voxels: 0.0,
            svr_scale: 4,
            source: LightSource::Directional([0.0, -1.0, 0.3]),
            ..LightSettings::default()
        },
        ..FrameRequest::new(128, 128, tf)
    };
    let cpu = shaders::cpu::render_packed(
        &dataset.cache,
        &request,
        shaders::cpu::CPU_FEATURES,
        voxserve_tests::render::CPU_TWIN_MAX_EDGE,
    )
    .unwrap_or_else(|e| panic!("CPU render: {e}"))
    .0;
    let mut frames = vec![("CPU", cpu)];
    if let Some(gpu) = gpu_or_skip("a_lit_smooth_surface_shows_no_rings") {
        let frame = gpu_renderer(gpu, &dataset)
            .render(&request)
            .unwrap_or_else(|e| panic!("GPU render: {e}"));
        frames.push(("GPU", frame));
    }
    for (side, frame) in frames {
        let rms = high_pass_rms(&frame, 30.0);
        println!("{side}: high-pass RMS {rms:.2} of 255 over the lit face");
        assert!(rms < 2.0, "{side}: rings, high-pass RMS {rms:.2}");
    }
}

/// One CPU renderer drawing global light and extinction-based light in turn
/// (two sessions on one dataset) draws each as a renderer of that mode alone.
#[test]
fn a_renderer_drawing_both_lit_modes_in_turn_draws_each_with_its_own_light() {
    let dataset = phantom_64_dataset();
    let mut request = lit_request(LightSettings::default(), 4.0);
    request.width = 48;
    request.height = 48;
    let global = request.clone();
    let extinction = FrameRequest {
        shading: Shading::Extinction,
        ..request
    };
    let alone = |r: &FrameRequest| {
        shaders::cpu::CpuRenderer::new(dataset.cache.clone(), 512 << 20)
            .render_converged(r)
            .expect("render")
    };
    let (global_alone, extinction_alone) = (alone(&global), alone(&extinction));
    assert_ne!(
        global_alone.rgba, extinction_alone.rgba,
        "the two lights differ on the phantom"
    );
    let mut both = shaders::cpu::CpuRenderer::new(dataset.cache.clone(), 512 << 20);
    for (i, (r, want)) in [
        (&global, &global_alone),
        (&extinction, &extinction_alone),
        (&global, &global_alone),
        (&extinction, &extinction_alone),
    ]
    .into_iter()
    .enumerate()
    {
        let got = both.render_converged(r).expect("render");
        assert!(got.rgba == want.rgba, "frame {i} ({:?})", r.shading);
    }
}
