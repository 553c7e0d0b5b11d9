//! Golden images: small lossless PNGs in `tests/golden/`, compared with a tolerance.
//!
//! The CPU twin renders every golden on every machine (it needs no GPU), and the
//! GPU renders it too when an adapter exists. Regenerate with `VOXSERVE_BLESS=1`
//! after an intended change, and look at the new images before committing them.

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use blocks::Preset;
use shaders::{Camera, FrameRequest, Renderer, Shading};
use voxserve_tests::image_compare::{assert_golden, to_image};
use voxserve_tests::phantom::phantom_64;
use voxserve_tests::{Tolerance, gpu_or_skip};

/// Renders differ from the golden by rounding only: a mean below 0.5 of 255 and
/// under 1% of pixels off by more than 8.
const GOLDEN_TOLERANCE: Tolerance = Tolerance {
    max_mean: 0.5,
    pixel_threshold: 8,
    max_differing_fraction: 0.01,
};

fn goldens() -> Vec<(&'static str, FrameRequest)> {
    let range = phantom_64().value_range;
    vec![
        (
            "phantom-bone-front",
            FrameRequest::new(128, 128, Preset::CtBone.transfer_function(range)),
        ),
        (
            "phantom-soft-tissue-oblique",
            FrameRequest {
                camera: Camera {
                    azimuth_deg: 40.0,
                    elevation_deg: 25.0,
                    ..Camera::default()
                },
                ..FrameRequest::new(128, 96, Preset::CtSoftTissue.transfer_function(range))
            },
        ),
        (
            "phantom-generic-unshaded-side",
            FrameRequest {
                camera: Camera {
                    azimuth_deg: 90.0,
                    ..Camera::default()
                },
                shading: Shading::Unshaded,
                ..FrameRequest::new(96, 128, Preset::Generic.transfer_function(range))
            },
        ),
    ]
}

#[test]
fn cpu_twin_matches_the_golden_images() {
    for (name, request) in goldens() {
        let frame = shaders::cpu::render(
            phantom_64(),
            &request,
            wgpu::Features::TEXTURE_FORMAT_16BIT_NORM,
        )
        .unwrap_or_else(|e| panic!("{name}: {e}"));
        let diff = assert_golden(name, &to_image(&frame), &GOLDEN_TOLERANCE);
        println!("{name}: CPU twin vs golden: {diff:?}");
    }
}

#[test]
fn gpu_matches_the_golden_images() {
    let Some(gpu) = gpu_or_skip("gpu_matches_the_golden_images") else {
        return;
    };
    let mut renderer = Renderer::new(gpu.clone(), phantom_64()).expect("renderer");
    for (name, request) in goldens() {
        let frame = renderer
            .render(&request)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        // The GPU result is compared, never blessed: the CPU twin writes goldens.
        let diff = voxserve_tests::image_compare::compare(
            &format!("{name}-gpu"),
            &to_image(&frame),
            &image::open(voxserve_tests::image_compare::golden_dir().join(format!("{name}.png")))
                .unwrap_or_else(|e| panic!("{name}: golden missing: {e}"))
                .to_rgba8(),
            &GOLDEN_TOLERANCE,
            &voxserve_tests::image_compare::golden_dir(),
        )
        .unwrap_or_else(|msg| panic!("{msg}"));
        println!("{name}: GPU vs golden: {diff:?}");
    }
}
