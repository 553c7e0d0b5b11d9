//! The ray-marching stages on the GPU against their CPU twins: `raycast` over
//! packed blocks (`shaders::cpu::raycast`) and `reference` over one plain
//! texture (`shaders::cpu::reference`).
//!
//! Tolerance: the two differ only in arithmetic (hardware texture filtering keeps
//! fewer fraction bits than f32 trilinear interpolation, and transcendental
//! functions round differently), so across the image the mean absolute channel
//! difference stays below 0.5 of 255 and fewer than 1% of pixels differ by more
//! than 8 of 255 in any channel; the outliers are pixels where a ray grazes a
//! surface and one side's sample just crosses the transfer function's opacity
//! edge.

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use std::sync::Arc;

use blocks::{Preset, Volume, VoxelData};
use server::Dataset;
use shaders::cpu::CpuRenderer;
use shaders::cpu::march::Isa;
use shaders::{
    Backend, Camera, ClipBox, Frame, FrameRequest, GpuError, LightSettings, Projection, Rows,
    Shading,
};
use voxserve_tests::image_compare::{assert_similar, measure, to_image};
use voxserve_tests::phantom::{phantom_64, phantom_64_dataset};
use voxserve_tests::render::{
    TEST_GPU_BUDGET_BYTES, cpu_packed, cpu_reference, dataset_of, gpu_reference, gpu_renderer,
};
use voxserve_tests::{Tolerance, gpu_or_skip};

const TWIN_TOLERANCE: Tolerance = Tolerance {
    max_mean: 0.5,
    pixel_threshold: 8,
    max_differing_fraction: 0.01,
};

fn check_twins(name: &str, gpu_frame: &Frame, cpu_frame: &Frame) {
    let diff = assert_similar(
        &format!("twin-{name}"),
        gpu_frame,
        cpu_frame,
        &TWIN_TOLERANCE,
    );
    println!("{name}: GPU vs CPU twin: {diff:?}");
}

/// The same requests through the packed GPU renderer and the packed CPU twin.
fn compare_packed_twins(test: &str, dataset: &Dataset, requests: &[(&str, FrameRequest)]) {
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let mut renderer = gpu_renderer(gpu, dataset);
    for (name, request) in requests {
        let gpu_frame = renderer
            .render(request)
            .unwrap_or_else(|e| panic!("{name}: GPU render: {e}"));
        let cpu_frame = cpu_packed(Some(gpu), dataset, request);
        check_twins(name, &gpu_frame, &cpu_frame);
    }
}

fn phantom_request(
    preset: Preset,
    shading: Shading,
    camera: Camera,
    size: (u32, u32),
) -> FrameRequest {
    let range = phantom_64().value_range;
    FrameRequest {
        camera,
        shading,
        ..FrameRequest::new(size.0, size.1, preset.transfer_function(range))
    }
}

/// Views that exercise every branch of the march: shading modes, both
/// gradients, both projections, a camera inside the volume, a clip box, a background colour,
/// and mixed levels of detail.
fn phantom_requests() -> Vec<(&'static str, FrameRequest)> {
    let oblique = Camera {
        azimuth_deg: 35.0,
        elevation_deg: 20.0,
        ..Camera::default()
    };
    let inside = Camera {
        distance: 0.3,
        ..Camera::default()
    };
    let ortho = Camera {
        azimuth_deg: -50.0,
        elevation_deg: 10.0,
        projection: Projection::Orthographic,
        ..Camera::default()
    };
    vec![
        (
            "bone-shaded",
            phantom_request(
                Preset::CtBone,
                Shading::Gradient,
                Camera::default(),
                (96, 96),
            ),
        ),
        (
            "soft-tissue-unshaded-wide",
            phantom_request(Preset::CtSoftTissue, Shading::Unshaded, oblique, (128, 72)),
        ),
        (
            "generic-inside",
            phantom_request(Preset::Generic, Shading::Gradient, inside, (64, 80)),
        ),
        (
            "mip-orthographic",
            phantom_request(Preset::CtSoftTissue, Shading::Mip, ortho, (80, 80)),
        ),
        (
            "minip-oblique",
            phantom_request(Preset::Generic, Shading::MinIp, oblique, (64, 64)),
        ),
        (
            "bone-clipped-grey-background",
            FrameRequest {
                clip: ClipBox {
                    min: [0.1, 0.0, 0.2],
                    max: [0.9, 0.55, 0.8],
                },
                background: [0.3, 0.3, 0.35],
                ..phantom_request(Preset::CtBone, Shading::Gradient, oblique, (96, 96))
            },
        ),
        (
            "bone-central-differences",
            FrameRequest {
                cubic_gradient: false,
                ..phantom_request(Preset::CtBone, Shading::Gradient, oblique, (96, 96))
            },
        ),
        (
            "soft-tissue-reduced-9",
            FrameRequest {
                reduction: 9.0,
                ..phantom_request(Preset::CtSoftTissue, Shading::Gradient, oblique, (96, 96))
            },
        ),
        (
            "bone-reduced-35-orthographic",
            FrameRequest {
                reduction: 35.0,
                ..phantom_request(Preset::CtBone, Shading::Gradient, ortho, (96, 96))
            },
        ),
    ]
}

#[test]
fn packed_gpu_and_cpu_twin_agree_on_the_phantom() {
    compare_packed_twins(
        "packed_gpu_and_cpu_twin_agree_on_the_phantom",
        phantom_64_dataset(),
        &phantom_requests(),
    );
}

#[test]
fn reference_gpu_and_cpu_twin_agree_on_the_phantom() {
    let Some(gpu) = gpu_or_skip("reference_gpu_and_cpu_twin_agree_on_the_phantom") else {
        return;
    };
    let mut reference = gpu_reference(gpu, phantom_64());
    for (name, request) in phantom_requests()
        .into_iter()
        .filter(|(_, r)| r.reduction == 1.0)
    {
        let gpu_frame = reference
            .render(&request)
            .unwrap_or_else(|e| panic!("{name}: GPU render: {e}"));
        let cpu_frame = cpu_reference(Some(gpu), phantom_64(), &request);
        check_twins(&format!("reference-{name}"), &gpu_frame, &cpu_frame);
    }
}

/// A bright sphere in a dark 40³ cube of 8-bit voxels: the r8unorm path, and
/// blocks cut short by the volume's edge (40 is not a multiple of 16).
fn sphere_u8() -> Volume {
    let n = 40u32;
    let voxels = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (i % n, (i / n) % n, i / (n * n));
            let d = [x, y, z].map(|c| c as f32 + 0.5 - n as f32 / 2.0);
            let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            (255.0 * (1.0 - r / (n as f32 * 0.4)).clamp(0.0, 1.0)) as u8
        })
        .collect();
    Volume::new(
        "sphere",
        blocks::Geometry::new([n, n, n], [1.0, 1.0, 1.5]),
        VoxelData::U8(voxels),
        blocks::ValueMap::IDENTITY,
    )
    .expect("valid volume")
}

#[test]
fn packed_gpu_and_cpu_twin_agree_on_an_8bit_volume_with_partial_blocks() {
    let volume = sphere_u8();
    let tf = Preset::Generic.transfer_function(volume.value_range);
    let camera = Camera {
        azimuth_deg: -60.0,
        elevation_deg: 45.0,
        ..Camera::default()
    };
    let request = FrameRequest {
        camera,
        ..FrameRequest::new(80, 80, tf)
    };
    let dataset = dataset_of(volume);
    compare_packed_twins(
        "packed_gpu_and_cpu_twin_agree_on_an_8bit_volume_with_partial_blocks",
        &dataset,
        &[
            ("sphere-u8", request.clone()),
            (
                "sphere-u8-mip",
                FrameRequest {
                    shading: Shading::Mip,
                    ..request.clone()
                },
            ),
            (
                "sphere-u8-reduced",
                FrameRequest {
                    reduction: 6.0,
                    ..request
                },
            ),
        ],
    );
}

#[test]
fn skipping_empty_blocks_changes_no_pixel() {
    let dataset = phantom_64_dataset();
    let gpu = gpu_or_skip("skipping_empty_blocks_changes_no_pixel");
    let mut renderer = gpu.map(|g| gpu_renderer(g, dataset));
    for (name, request) in phantom_requests() {
        let without = FrameRequest {
            skip_empty: false,
            ..request.clone()
        };
        assert_eq!(
            cpu_packed(gpu, dataset, &request),
            cpu_packed(gpu, dataset, &without),
            "{name}: the CPU twin's image changed with skipping"
        );
        if let Some(r) = renderer.as_mut() {
            let with = r.render(&request).expect("GPU render");
            let without = r.render(&without).expect("GPU render");
            assert_eq!(with, without, "{name}: the GPU image changed with skipping");
        }
    }
}

#[test]
fn image_sizes_outside_1_to_4096_are_refused_before_rendering() {
    let dataset = phantom_64_dataset();
    let tf = Preset::CtBone.transfer_function(phantom_64().value_range);
    let gpu = gpu_or_skip("image_sizes_outside_1_to_4096_are_refused_before_rendering");
    let mut renderer = gpu.map(|g| gpu_renderer(g, dataset));
    for (w, h) in [(0, 64), (64, 0), (4097, 64), (64, 100_000)] {
        let request = FrameRequest::new(w, h, tf.clone());
        let cpu =
            shaders::cpu::render_packed(&dataset.cache, &request, wgpu::Features::empty(), 2048);
        let Err(GpuError::Setting(refusal)) = cpu else {
            panic!("{w}x{h}: expected a refusal from the CPU twin, got {cpu:?}");
        };
        assert!(refusal.expected.contains("1 to 4096"), "{refusal}");
        if let Some(r) = renderer.as_mut() {
            let gpu_result = r.render(&request);
            assert!(
                matches!(&gpu_result, Err(GpuError::Setting(e)) if e.expected.contains("1 to 4096")),
                "{w}x{h}: {gpu_result:?}"
            );
        }
    }
    // The largest size is accepted (checked on the request only: a 4096² software
    // frame belongs in a benchmark).
    assert!(FrameRequest::new(4096, 4096, tf).validate().is_ok());
}

/// `frames`, bands of one image top to bottom, as one frame.
fn stitched(frames: Vec<Frame>) -> Frame {
    let width = frames[0].width;
    let height = frames.iter().map(|f| f.height).sum();
    let rgba = frames.into_iter().flat_map(|f| f.rgba).collect();
    Frame {
        width,
        height,
        rgba,
    }
}

/// `request` drawn in bands of `per_band` rows by `render`, stitched.
fn in_bands(
    request: &FrameRequest,
    per_band: u32,
    mut render: impl FnMut(&FrameRequest) -> Frame,
) -> Frame {
    stitched(
        Rows::bands(request.height, per_band)
            .map(|rows| {
                let band = render(&FrameRequest {
                    rows: Some(rows),
                    ..request.clone()
                });
                assert_eq!((band.width, band.height), (request.width, rows.count));
                band
            })
            .collect(),
    )
}

/// The render worker draws a big frame band by band so that other clients'
/// frames go between: the bands, put together, are the frame drawn whole
/// (same rays, same jitter), on the CPU and on the GPU; with global light
/// the later bands show the light the first did (no refinement between).
#[test]
fn a_frame_drawn_band_by_band_is_the_frame_drawn_whole() {
    let dataset = phantom_64_dataset();
    let gpu = gpu_or_skip("a_frame_drawn_band_by_band_is_the_frame_drawn_whole");
    let mut renderer = gpu.map(|g| gpu_renderer(g, dataset));
    for (name, request) in phantom_requests() {
        for per_band in [1, 7, 32] {
            assert_eq!(
                in_bands(&request, per_band, |r| cpu_packed(gpu, dataset, r)),
                cpu_packed(gpu, dataset, &request),
                "{name}: the CPU twin's bands of {per_band} rows"
            );
        }
        if let Some(r) = renderer.as_mut() {
            let whole = r.render(&request).expect("GPU render");
            let bands = in_bands(&request, 13, |b| r.render(b).expect("GPU band"));
            assert_eq!(bands, whole, "{name}: the GPU's bands of 13 rows");
        }
    }
    // Interactive global light refines one step per frame: a banded frame
    // refines once, in its first band.
    let lit = FrameRequest {
        light: LightSettings {
            svr_scale: 4,
            ..LightSettings::default()
        },
        ..phantom_request(
            Preset::CtSoftTissue,
            Shading::GlobalLight,
            Camera::default(),
            (64, 64),
        )
    };
    for backend in gpu
        .map(|g| Backend::Gpu(g.clone()))
        .into_iter()
        .chain([Backend::Cpu])
    {
        let renderer = || {
            backend
                .renderer(dataset.cache.clone(), TEST_GPU_BUDGET_BYTES)
                .expect("renderer")
        };
        let (mut whole, mut banded) = (renderer(), renderer());
        for frame in 0..3 {
            let expected = whole.render_now(&lit).expect("whole frame");
            let bands = in_bands(&lit, 10, |b| banded.render_now(b).expect("band"));
            assert_eq!(
                bands,
                expected,
                "{}: lit frame {frame} in bands of 10 rows",
                backend.kind()
            );
        }
    }
}

/// Rings: the luminance of a smooth surface seen head-on, averaged over
/// ellipses about the point facing the eye, must not oscillate with the
/// radius. Concentric rings (one per voxel slice the surface crosses) are
/// exactly such an oscillation; jitter noise averages away over an ellipse's
/// many pixels.
#[test]
fn a_smooth_surface_seen_head_on_shows_no_rings() {
    let vault = Vault::new();
    // Across the image (x, left) the vertex curves with radius 70²/86 mm, up
    // and down (y) with 92²/86 mm: iso-depth lines are ellipses.
    let squash = (70.0f64 / 92.0).powi(2);
    let centre = vault.centre;
    let mut worst = 0.0f64;
    for shading in [Shading::Gradient, Shading::Unshaded] {
        let frame = vault.frame(shading);
        let residual = ring_residual(&frame, centre, squash);
        println!("{shading:?}: ring residual {residual:.3} of 255 about {centre:?}");
        worst = worst.max(residual);
    }
    // Measured: 0.14 with cubic normals (0.12 with central differences) at
    // edges of ±2 voxels; with the phantom's edges at ±1.5 voxels, 0.21, the
    // rings plain to see with the contrast stretched.
    assert!(worst < 0.17, "rings: residual {worst:.3}");
}

/// The phantom's skull vault under ct-bone, at 256³, zoomed until a pixel is
/// about 0.6 of a voxel, seen from straight above on the CPU twin at 128².
/// The vault's outer surface is an ellipsoid centred 10 mm anterior and 20 mm
/// superior of the cube's centre, semi-axes 70 (x), 92 (y) and 86 (z) mm;
/// its top, the vertex, faces the eye. A step of ⅛ voxel keeps the jitter's
/// noise below the rings.
struct Vault {
    dataset: Dataset,
    camera: Camera,
    range: [f32; 2],
    /// Where the vertex is drawn (pixels).
    centre: (f64, f64),
}

impl Vault {
    const SIZE: u32 = 128;

    fn new() -> Vault {
        let volume = blocks::phantom::head(256).expect("phantom");
        let range = volume.value_range;
        let radius = shaders::raycast::VolumePlacement::of_geometry(&volume.geometry).radius();
        let camera = Camera {
            fov_y_deg: 8.0,
            elevation_deg: 90.0,
            ..Camera::default()
        };
        // Model space is the volume's index axes (LPS: y towards posterior).
        let vertex = glam::Vec3::new(0.0, -10.0, 20.0 + 86.0);
        let ndc = camera.view_proj(radius, 1.0).project_point3(vertex);
        let size = Vault::SIZE as f32;
        let centre = (
            f64::from((ndc.x + 1.0) * 0.5 * size - 0.5),
            f64::from((1.0 - ndc.y) * 0.5 * size - 0.5),
        );
        Vault {
            dataset: dataset_of(volume),
            camera,
            range,
            centre,
        }
    }

    fn frame(&self, shading: Shading) -> Frame {
        let request = FrameRequest {
            camera: self.camera,
            shading,
            step_voxels: 0.125,
            ..FrameRequest::new(
                Vault::SIZE,
                Vault::SIZE,
                Preset::CtBone.transfer_function(self.range),
            )
        };
        cpu_packed(None, &self.dataset, &request)
    }
}

/// Extinction light read from its cache (cells of 2 voxels here) must not
/// lay the cache's layers over a smooth surface: the vault's detail a few
/// pixels across, lit by extinction light, stays that of gradient shading
/// (the same normals, no shadows: what is left is the surface's own
/// texture and the jitter's noise). Read one cell towards the eye (before
/// `LIGHT_READ_CELLS`), the light drew bands where the vault cuts the
/// cache's layers.
#[test]
fn extinction_light_lays_no_bands_on_a_smooth_surface() {
    let vault = Vault::new();
    let detail = |shading| surface_detail(&vault.frame(shading), vault.centre.0);
    let (gradient, extinction) = (detail(Shading::Gradient), detail(Shading::Extinction));
    println!("surface detail: gradient {gradient:.3}, extinction light {extinction:.3} of 255");
    // Measured: gradient 0.65; extinction light read two cells towards the
    // eye 0.73, read one cell towards it 2.01, the bands plain to see.
    assert!(
        extinction < 1.5 * gradient,
        "extinction light lays bands: detail {extinction:.3} against gradient shading's {gradient:.3}"
    );
}

/// The RMS, in 255ths of luminance, of the detail a few pixels across
/// (`high_pass_luminance`) over the pixels at least 8 pixels inside the
/// drawn surface, leaving out the columns within 2 pixels of `centre_x`
/// (the sagittal sinus grooves the vault's midline).
fn surface_detail(frame: &Frame, centre_x: f64) -> f64 {
    const INSET: i64 = 8;
    let (w, h) = (i64::from(frame.width), i64::from(frame.height));
    let detail = voxserve_tests::checks::high_pass_luminance(frame);
    let drawn = |x: i64, y: i64| {
        x >= 0 && y >= 0 && x < w && y < h && {
            let i = ((y * w + x) * 4) as usize;
            frame.rgba[i..i + 3].iter().any(|&c| c > 20)
        }
    };
    let (mut sum, mut n) = (0.0f64, 0u32);
    for y in 0..h {
        for x in 0..w {
            if (x as f64 - centre_x).abs() <= 2.0 {
                continue;
            }
            let inside =
                (-INSET..=INSET).all(|dy| (-INSET..=INSET).all(|dx| drawn(x + dx, y + dy)));
            if inside {
                sum += detail[(y * w + x) as usize].powi(2);
                n += 1;
            }
        }
    }
    (sum / f64::from(n.max(1))).sqrt()
}

/// The RMS, in 255ths of luminance, of what oscillates with the radius at
/// periods of a few pixels: the luminance less its blur (a 7-pixel box,
/// twice), averaged over elliptical rings half a pixel wide about `centre`
/// (pixels), 4 to 40 pixels out. The ellipses follow the surface's
/// iso-depth lines: `squash` scales dy² (the ratio of the surface's radii of
/// curvature across and up and down). The two columns either side of the
/// centre are left out: the sagittal sinus grooves the vault's midline.
fn ring_residual(frame: &Frame, centre: (f64, f64), squash: f64) -> f64 {
    const BINS_PER_PIXEL: f64 = 2.0;
    const RADII: std::ops::RangeInclusive<f64> = 4.0..=40.0;
    let (w, h) = (frame.width as usize, frame.height as usize);
    let detail = voxserve_tests::checks::high_pass_luminance(frame);
    let (cx, cy) = centre;
    let bins = (RADII.end() * BINS_PER_PIXEL) as usize + 1;
    let mut sums = vec![(0.0f64, 0u32); bins];
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = (x as f64 - cx, y as f64 - cy);
            let r = (dx * dx + dy * dy * squash).sqrt();
            if RADII.contains(&r) && dx.abs() > 2.0 {
                let bin = &mut sums[(r * BINS_PER_PIXEL) as usize];
                bin.0 += detail[y * w + x];
                bin.1 += 1;
            }
        }
    }
    let means: Vec<f64> = sums
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|&(s, n)| s / f64::from(n))
        .collect();
    (means.iter().map(|m| m * m).sum::<f64>() / means.len() as f64).sqrt()
}

/// The bounding box of the pixels brighter than the black background:
/// (x0, y0, x1, y1), pixel edges.
fn drawn_box(frame: &Frame) -> (u32, u32, u32, u32) {
    let mut b = (u32::MAX, u32::MAX, 0, 0);
    for (i, px) in frame.rgba.chunks(4).enumerate() {
        if px[..3].iter().any(|&c| c > 10) {
            let (x, y) = (i as u32 % frame.width, i as u32 / frame.width);
            b = (b.0.min(x), b.1.min(y), b.2.max(x + 1), b.3.max(y + 1));
        }
    }
    b
}

#[test]
fn a_fitted_camera_centres_and_frames_what_the_transfer_function_shows() {
    let dataset = dataset_of(voxserve_tests::phantom::ball_off_centre());
    let tf = Preset::Generic.transfer_function([0.0, 255.0]);
    let plain = FrameRequest {
        camera: Camera {
            azimuth_deg: 25.0,
            elevation_deg: 15.0,
            ..Camera::default()
        },
        ..FrameRequest::new(96, 64, tf)
    };
    let fit = FrameRequest {
        camera: Camera {
            fit: true,
            ..plain.camera
        },
        ..plain.clone()
    };
    let gpu = gpu_or_skip("a_fitted_camera_centres_and_frames_what_the_transfer_function_shows");
    let mut renderers = vec![(
        "CPU",
        Backend::Cpu.renderer(dataset.cache.clone(), TEST_GPU_BUDGET_BYTES),
    )];
    if let Some(g) = gpu {
        renderers.push((
            "GPU",
            Backend::Gpu(g.clone()).renderer(dataset.cache.clone(), TEST_GPU_BUDGET_BYTES),
        ));
    }
    for (name, renderer) in renderers {
        let mut renderer = renderer.unwrap_or_else(|e| panic!("{name} renderer: {e}"));
        let small = drawn_box(&renderer.render(&plain).expect("default camera"));
        assert_eq!(renderer.last_stats().camera, None, "{name}: no fit asked");
        let framed = renderer.render(&fit).expect("fitted camera");
        let camera = renderer
            .last_stats()
            .camera
            .expect("the camera the fit chose");
        println!(
            "{name}: default camera draws {small:?}, fitted {:?} with {camera:?}",
            drawn_box(&framed)
        );
        assert!(
            !camera.fit && camera.azimuth_deg == 25.0,
            "{name}: {camera:?}"
        );
        // Block (2, 1, 2) spans voxels 32..48, 16..32, 32..48: its centre is
        // 8, −8, 8 mm from the cube's.
        assert!(
            (camera.target() - glam::Vec3::new(8.0, -8.0, 8.0)).length() < 0.05,
            "{name}: target {:?}",
            camera.target()
        );
        let (x0, y0, x1, y1) = drawn_box(&framed);
        let centre = (f64::from(x0 + x1) / 2.0, f64::from(y0 + y1) / 2.0);
        assert!(
            (centre.0 - 48.0).abs() <= 2.0 && (centre.1 - 32.0).abs() <= 2.0,
            "{name}: the ball is drawn around {centre:?}, not the image's centre"
        );
        // The block's box spans 85 % of the 64-pixel side seen obliquely; the
        // ball inside it about 0.5.
        let extent = f64::from((x1 - x0).max(y1 - y0)) / 64.0;
        assert!(
            (0.45..=0.87).contains(&extent),
            "{name}: the ball spans {extent:.2} of the smaller side"
        );
        let small_extent = f64::from((small.2 - small.0).max(small.3 - small.1)) / 64.0;
        assert!(
            small_extent < 0.3,
            "{name}: the default camera draws it {small_extent:.2} tall"
        );
        // The fitted camera, asked for again, draws the same frame.
        let again = renderer
            .render(&FrameRequest {
                camera,
                ..plain.clone()
            })
            .expect("the chosen camera");
        assert_eq!(
            again, framed,
            "{name}: the chosen camera draws another frame"
        );
    }
}

/// The CPU renderer's march built for x86-64-v3 (chosen at run time where
/// the processor has it) draws the same bytes as the baseline build: the
/// same source with the same arithmetic, so any difference is a fused or
/// reordered operation that changes pixels.
#[test]
fn the_march_built_for_x86_64_v3_draws_the_baseline_s_bytes() {
    if !Isa::X86_64V3.is_supported() {
        println!("this processor has no x86-64-v3: only the baseline build runs here");
        return;
    }
    let dataset = phantom_64_dataset();
    let range = phantom_64().value_range;
    let oblique = Camera {
        azimuth_deg: 25.0,
        elevation_deg: 15.0,
        ..Camera::default()
    };
    let lit = |shading| FrameRequest {
        camera: oblique,
        shading,
        ..FrameRequest::new(96, 96, Preset::CtSoftTissue.transfer_function(range))
    };
    let mut requests = phantom_requests();
    requests.push(("global-light", lit(Shading::GlobalLight)));
    requests.push(("extinction", lit(Shading::Extinction)));
    let mut differing = Vec::new();
    for (name, request) in &requests {
        let frames = [Isa::Baseline, Isa::X86_64V3].map(|isa| {
            let mut renderer = CpuRenderer::new(Arc::clone(&dataset.cache), u64::MAX);
            renderer.set_isa(isa);
            renderer
                .render_converged(request)
                .unwrap_or_else(|e| panic!("{name}: CPU render ({isa:?}): {e}"))
        });
        let [baseline, v3] = &frames;
        assert!(
            baseline.rgba.iter().any(|&c| c != baseline.rgba[0]),
            "{name}: a blank frame"
        );
        let changed = baseline
            .rgba
            .iter()
            .zip(&v3.rgba)
            .filter(|(a, b)| a != b)
            .count();
        if changed > 0 {
            differing.push(format!("{name}: {changed} bytes"));
        }
    }
    assert!(
        differing.is_empty(),
        "x86-64-v3 frames differ: {differing:?}"
    );
}

/// A sample is shaded with the frame's normal (cubic in still frames, blended
/// central differences in moving ones) only where it weighs at least
/// `FAINT_WEIGHT` in its pixel (the ray's transparency before it times its
/// class's opacity); the fainter ones take their nearest texel's central
/// differences. The reference twin's frames of the phantom's soft tissue
/// (faint haze in front of the surfaces), with either normal, at the house
/// weight against the same frame with no sample faint (weight 0) and with
/// every sample faint (an infinite weight): within a few 8-bit steps of the
/// first and far from the second, and not the first's bytes (the faint
/// samples did take their nearest texel's differences).
#[test]
fn only_faint_samples_are_shaded_with_their_nearest_texels_differences() {
    use shaders::packed_volume::PackedLayout;
    use shaders::raycast::FAINT_WEIGHT;
    use shaders::volume_texture::VolumeTexture;

    let volume = phantom_64();
    let still = FrameRequest {
        camera: Camera {
            azimuth_deg: 35.0,
            elevation_deg: 20.0,
            ..Camera::default()
        },
        shading: Shading::Gradient,
        ..FrameRequest::new(
            128,
            128,
            Preset::CtSoftTissue.transfer_function(volume.value_range),
        )
    };
    assert!(still.cubic_gradient, "still frames take cubic normals");
    let moving = FrameRequest {
        cubic_gradient: false,
        ..still.clone()
    };
    let desc = VolumeTexture::for_volume(volume, shaders::cpu::CPU_FEATURES);
    let texture =
        shaders::cpu::Texture3d::new(desc.geometry.dims, desc.texel_values(&volume.voxels));
    let tf = still.volume_transfer_function(volume);
    let table = tf
        .table(desc.tf_domain, blocks::transfer_function::TABLE_LEN)
        .expect("the transfer function's table");
    let draw = |request: &FrameRequest, weight: f32| {
        let mut params = shaders::RaycastParams::new(
            &desc,
            request,
            &tf,
            table.len() as u32,
            PackedLayout::default(),
        );
        params.faint_weight = weight;
        let mut rgba = vec![0u8; (request.width * request.height * 4) as usize];
        let table = shaders::cpu::full_table(&table).expect("a full table");
        shaders::cpu::reference(&params, &texture, table, &mut rgba);
        to_image(&Frame {
            width: request.width,
            height: request.height,
            rgba,
        })
    };
    let pixels = f64::from(still.width * still.height);
    for (name, request) in [("cubic", &still), ("central", &moving)] {
        let house = draw(request, FAINT_WEIGHT);
        let none_faint = draw(request, 0.0);
        let all_faint = draw(request, f32::INFINITY);
        let (to_full, _) = measure(&house, &none_faint, 0);
        let (to_faint, _) = measure(&house, &all_faint, 3);
        let differing = to_full.differing_fraction * pixels;
        let far = to_faint.differing_fraction * pixels;
        println!(
            "{name}: against no sample faint {differing} pixels differ, largest {}; against \
             every sample faint {far} pixels differ by more than 3, largest {}",
            to_full.max, to_faint.max
        );
        assert!(
            differing > 0.0,
            "{name}: every pixel as with no sample faint: no faint sample took its nearest \
             texel's differences"
        );
        assert!(
            to_full.max <= 3,
            "{name}: faint samples moved a pixel by more than 3 of 255"
        );
        assert!(
            far > 100.0,
            "{name}: the heavy samples' own normals did not show"
        );
    }
}
