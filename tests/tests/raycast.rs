//! The `raycast` stage on the GPU against its CPU twin `shaders::cpu::raycast`.
//!
//! Tolerance: the two differ only in arithmetic (hardware texture filtering keeps
//! fewer fraction bits than f32 trilinear interpolation, and transcendental
//! functions round differently), so across the image the mean absolute channel
//! difference stays below 0.5 of 255 and fewer than 1% of pixels differ by more
//! than 8 of 255 in any channel; the outliers are pixels where a ray grazes a
//! surface and one side's sample just crosses the transfer function's opacity
//! edge.

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use blocks::{Preset, Volume, VoxelData};
use shaders::{Camera, FrameRequest, Renderer, Shading};
use voxserve_tests::image_compare::{compare, golden_dir, to_image};
use voxserve_tests::phantom::phantom_64;
use voxserve_tests::{Tolerance, gpu_or_skip};

const TWIN_TOLERANCE: Tolerance = Tolerance {
    max_mean: 0.5,
    pixel_threshold: 8,
    max_differing_fraction: 0.01,
};

/// The same requests through the GPU and the CPU twin, compared.
fn compare_twins(test: &str, volume: &Volume, requests: &[(&str, FrameRequest)]) {
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let mut renderer =
        Renderer::new(gpu.clone(), volume).unwrap_or_else(|e| panic!("{test}: renderer: {e}"));
    let features = gpu.device.features();
    for (name, request) in requests {
        let gpu_frame = renderer
            .render(request)
            .unwrap_or_else(|e| panic!("{name}: GPU render: {e}"));
        let cpu_frame = shaders::cpu::render(volume, request, features)
            .unwrap_or_else(|e| panic!("{name}: CPU render: {e}"));
        let diff = compare(
            &format!("twin-{name}"),
            &to_image(&gpu_frame),
            &to_image(&cpu_frame),
            &TWIN_TOLERANCE,
            &golden_dir(),
        )
        .unwrap_or_else(|msg| panic!("{msg}"));
        println!("{name}: GPU vs CPU twin: {diff:?}");
        to_image(&gpu_frame)
            .save(format!("/tmp/{name}-gpu.png"))
            .ok();
    }
}

fn request(preset: Preset, shading: Shading, camera: Camera, size: (u32, u32)) -> FrameRequest {
    let range = phantom_64().value_range;
    FrameRequest {
        camera,
        shading,
        ..FrameRequest::new(size.0, size.1, preset.transfer_function(range))
    }
}

#[test]
fn gpu_and_cpu_twin_agree_on_the_phantom() {
    let oblique = Camera {
        azimuth_deg: 35.0,
        elevation_deg: 20.0,
        ..Camera::default()
    };
    let inside = Camera {
        distance: 0.3,
        ..Camera::default()
    };
    compare_twins(
        "gpu_and_cpu_twin_agree_on_the_phantom",
        phantom_64(),
        &[
            (
                "bone-shaded",
                request(
                    Preset::CtBone,
                    Shading::Gradient,
                    Camera::default(),
                    (96, 96),
                ),
            ),
            (
                "soft-tissue-unshaded-wide",
                request(Preset::CtSoftTissue, Shading::Unshaded, oblique, (128, 72)),
            ),
            (
                "generic-inside",
                request(Preset::Generic, Shading::Gradient, inside, (64, 80)),
            ),
        ],
    );
}

#[test]
fn gpu_and_cpu_twin_agree_on_an_8bit_volume() {
    // A bright sphere in a dark cube, 8-bit: exercises the r8unorm path.
    let n = 40u32;
    let voxels = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (i % n, (i / n) % n, i / (n * n));
            let d = [x, y, z].map(|c| c as f32 + 0.5 - n as f32 / 2.0);
            let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            (255.0 * (1.0 - r / (n as f32 * 0.4)).clamp(0.0, 1.0)) as u8
        })
        .collect();
    let volume = Volume::new(
        "sphere",
        [n, n, n],
        [1.0, 1.0, 1.5],
        VoxelData::U8(voxels),
        blocks::ValueMap::IDENTITY,
    )
    .expect("valid volume");
    let tf = Preset::Generic.transfer_function(volume.value_range);
    let req = FrameRequest {
        camera: Camera {
            azimuth_deg: -60.0,
            elevation_deg: 45.0,
            ..Camera::default()
        },
        ..FrameRequest::new(80, 80, tf)
    };
    compare_twins(
        "gpu_and_cpu_twin_agree_on_an_8bit_volume",
        &volume,
        &[("sphere-u8", req)],
    );
}
