//! Golden images: small lossless PNGs in `tests/golden/`, compared with a tolerance.
//!
//! Every golden is a packed render of the phantom's brick store (64³, bricked in
//! memory). The packed CPU twin renders every golden on every machine (it needs
//! no GPU), and the GPU renders it too when an adapter exists. Regenerate with `VOXSERVE_BLESS=1`
//! after an intended change, and look at the new images before committing them.

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use blocks::Preset;
use shaders::extinction::{ExtinctionLight, ExtinctionLightKind, ExtinctionSettings};
use shaders::{Camera, ClipBox, FrameRequest, LightSettings, LightSource, Projection, Shading};
use voxserve_tests::image_compare::{assert_golden, assert_matches_golden, to_image};
use voxserve_tests::phantom::{phantom_64, phantom_64_dataset};
use voxserve_tests::render::{cpu_packed, gpu_renderer};
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
        (
            "phantom-mip-orthographic",
            FrameRequest {
                camera: Camera {
                    azimuth_deg: 20.0,
                    elevation_deg: 10.0,
                    projection: Projection::Orthographic,
                    ..Camera::default()
                },
                shading: Shading::Mip,
                ..FrameRequest::new(96, 96, Preset::CtSoftTissue.transfer_function(range))
            },
        ),
        (
            "phantom-minip-side",
            FrameRequest {
                camera: Camera {
                    azimuth_deg: 90.0,
                    ..Camera::default()
                },
                shading: Shading::MinIp,
                background: [0.2, 0.25, 0.3],
                ..FrameRequest::new(96, 96, Preset::Generic.transfer_function(range))
            },
        ),
        (
            "phantom-bone-clipped",
            FrameRequest {
                camera: Camera {
                    azimuth_deg: -35.0,
                    elevation_deg: 30.0,
                    ..Camera::default()
                },
                clip: ClipBox {
                    min: [0.0, 0.0, 0.0],
                    max: [1.0, 0.5, 0.6],
                },
                ..FrameRequest::new(96, 96, Preset::CtSoftTissue.transfer_function(range))
            },
        ),
    ]
    .into_iter()
    .chain(light_goldens())
    .chain(extinction_goldens())
    .collect()
}

/// Global light propagation: a light outside and one inside the volume, I_bias
/// 0 and 0.2, a small and a large scattering radius.
fn light_goldens() -> Vec<(&'static str, FrameRequest)> {
    let range = phantom_64().value_range;
    let lit = |light: LightSettings| FrameRequest {
        camera: Camera {
            azimuth_deg: 25.0,
            elevation_deg: 15.0,
            ..Camera::default()
        },
        shading: Shading::GlobalLight,
        light: LightSettings {
            directions: 6,
            ..light
        },
        ..FrameRequest::new(96, 96, Preset::CtSoftTissue.transfer_function(range))
    };
    let outside = LightSettings {
        source: LightSource::Directional([-0.8, -0.3, 0.5]),
        scatter_radius_voxels: 4.0,
        ..LightSettings::default()
    };
    vec![
        (
            "phantom-light-outside-bias0",
            lit(LightSettings {
                bias: 0.0,
                ..outside
            }),
        ),
        (
            "phantom-light-outside-bias02",
            lit(LightSettings {
                bias: 0.2,
                ..outside
            }),
        ),
        (
            "phantom-light-inside",
            lit(LightSettings {
                source: LightSource::Point([0.5, 0.45, 0.55]),
                bias: 0.05,
                ..outside
            }),
        ),
        (
            "phantom-light-radius2",
            lit(LightSettings {
                scatter_radius_voxels: 2.0,
                bias: 0.0,
                ..outside
            }),
        ),
        (
            "phantom-light-radius16",
            lit(LightSettings {
                scatter_radius_voxels: 16.0,
                bias: 0.0,
                ..outside
            }),
        ),
    ]
}

/// Extinction-based illumination: ambient occlusion only, colour bleeding, one
/// soft-shadow light, two lights of different colours, a light inside the volume.
fn extinction_goldens() -> Vec<(&'static str, FrameRequest)> {
    let range = phantom_64().value_range;
    let lit = |extinction: ExtinctionSettings| FrameRequest {
        camera: Camera {
            azimuth_deg: 25.0,
            elevation_deg: 15.0,
            ..Camera::default()
        },
        shading: Shading::Extinction,
        extinction: ExtinctionSettings {
            sat_size: 48,
            ao_radius: 4,
            ao_shells: 2,
            ..extinction
        },
        ..FrameRequest::new(96, 96, Preset::CtSoftTissue.transfer_function(range))
    };
    let light = |kind, colour| ExtinctionLight {
        kind,
        colour,
        intensity: 1.0,
    };
    let ambient_only = ExtinctionSettings {
        lights: Vec::new(),
        ambient: 1.0,
        ao_strength: 0.6,
        ..ExtinctionSettings::default()
    };
    vec![
        ("phantom-extinction-ao", lit(ambient_only.clone())),
        (
            "phantom-extinction-colour-bleeding",
            lit(ExtinctionSettings {
                colour_bleeding: true,
                ao_strength: 1.5,
                ..ambient_only
            }),
        ),
        (
            "phantom-extinction-one-light",
            lit(ExtinctionSettings {
                ambient: 0.3,
                lights: vec![light(
                    ExtinctionLightKind::Directional([-0.8, -0.3, 0.5]),
                    [1.0; 3],
                )],
                cone_angle: 5.0,
                ..ExtinctionSettings::default()
            }),
        ),
        (
            "phantom-extinction-two-lights",
            lit(ExtinctionSettings {
                ambient: 0.2,
                lights: vec![
                    light(
                        ExtinctionLightKind::Point([-0.6, 0.2, 0.8]),
                        [1.0, 0.45, 0.2],
                    ),
                    light(
                        ExtinctionLightKind::Spot {
                            position: [1.6, 0.1, 0.6],
                            direction: [-1.0, 0.3, 0.0],
                            angle: 30.0,
                        },
                        [0.25, 0.5, 1.0],
                    ),
                ],
                ..ExtinctionSettings::default()
            }),
        ),
        (
            // Clipped open, so the inside lit from within shows.
            "phantom-extinction-light-inside",
            FrameRequest {
                clip: ClipBox {
                    min: [0.0, 0.5, 0.0],
                    max: [1.0, 1.0, 1.0],
                },
                ..lit(ExtinctionSettings {
                    ambient: 0.1,
                    lights: vec![ExtinctionLight {
                        intensity: 2.0,
                        ..light(
                            ExtinctionLightKind::Point([0.5, 0.6, 0.55]),
                            [1.0, 0.9, 0.7],
                        )
                    }],
                    cone_angle: 10.0,
                    ..ExtinctionSettings::default()
                })
            },
        ),
    ]
}

#[test]
fn cpu_twin_matches_the_golden_images() {
    for (name, request) in goldens() {
        let frame = cpu_packed(None, phantom_64_dataset(), &request);
        let diff = assert_golden(name, &to_image(&frame), &GOLDEN_TOLERANCE);
        println!("{name}: CPU twin vs golden: {diff:?}");
    }
}

#[test]
fn gpu_matches_the_golden_images() {
    let Some(gpu) = gpu_or_skip("gpu_matches_the_golden_images") else {
        return;
    };
    let mut renderer = gpu_renderer(gpu, phantom_64_dataset());
    for (name, request) in goldens() {
        let frame = renderer
            .render_converged(&request)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        // The GPU result is compared, never blessed: the CPU twin writes goldens.
        let diff = assert_matches_golden(name, &frame, &GOLDEN_TOLERANCE);
        println!("{name}: GPU vs golden: {diff:?}");
    }
}
