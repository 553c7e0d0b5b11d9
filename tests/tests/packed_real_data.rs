//! Packed rendering on real scans (the engine, the CT head and the VHF head
//! from `../shared/data`) against the full-resolution reference renderer, on
//! the CPU twins always and on the GPU when there is one.
//!
//! - With every block at level 0 the packed render must match the reference
//!   within rounding: that proves block addressing, aprons across block borders,
//!   gradients across borders and empty-block skipping.
//! - At 1:1, 9:1 and 35:1 with the default step the difference from the
//!   reference at step 1/8 voxel is measured and printed (CIE ΔE*uv mean and
//!   99th percentile, ꟻLIP, the share of the reference's opaque pixels still
//!   opaque), checked against bounds, and the reduced images are kept as
//!   goldens (128², `tests/golden/`).

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use blocks::Volume;
use blocks::ingest;
use blocks::lod::LodSelection;
use server::Dataset;
use shaders::colour_difference;

use shaders::{Camera, Frame, FrameRequest, GpuContext, Shading};
use voxserve_tests::image_compare::{
    assert_golden, assert_matches_golden, assert_similar, to_image,
};
use voxserve_tests::phantom::TEST_CACHE_BYTES;
use voxserve_tests::reference_data::{ReferenceDataset, reference_dataset};
use voxserve_tests::render::{cpu_packed, cpu_reference, gpu_reference, gpu_renderer};
use voxserve_tests::{Tolerance, gpu_or_skip};

/// Packed at level 0 vs reference: the same texels and the same samples, so
/// only rounding differs.
const LEVEL_0_TOLERANCE: Tolerance = Tolerance {
    max_mean: 0.05,
    pixel_threshold: 4,
    max_differing_fraction: 0.001,
};

/// A render against its golden: rounding only.
const GOLDEN_TOLERANCE: Tolerance = Tolerance {
    max_mean: 0.5,
    pixel_threshold: 8,
    max_differing_fraction: 0.01,
};

/// One real dataset: its reader settings, a store bricked in memory and the
/// volume read directly from the file.
struct Case {
    reference: ReferenceDataset,
    dataset: Dataset,
    /// The volume read directly from the file, when the test needs it.
    volume: Option<Volume>,
}

fn case(test: &str, name: &str, with_volume: bool) -> Option<Case> {
    let dir = voxserve_tests::data::shared_data(test)?;
    let reference =
        reference_dataset(&dir, name).unwrap_or_else(|| panic!("unknown dataset {name}"));
    let dataset = Dataset::load(&reference.path, &reference.options, TEST_CACHE_BYTES)
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let volume = with_volume.then(|| {
        let mut source = ingest::open(&reference.path, &reference.options)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        ingest::load(source.as_mut()).unwrap_or_else(|e| panic!("{name}: {e}"))
    });
    Some(Case {
        reference,
        dataset,
        volume,
    })
}

fn view(case: &Case, reduction: f32) -> FrameRequest {
    FrameRequest {
        camera: Camera {
            azimuth_deg: 30.0,
            elevation_deg: 20.0,
            ..Camera::default()
        },
        shading: Shading::Gradient,
        reduction,
        ..FrameRequest::new(128, 128, case.reference.transfer_function.clone())
    }
}

fn check_level_0(name: &str, packed: &Frame, reference: &Frame) {
    let diff = assert_similar(
        &format!("{name}-level0-vs-reference"),
        packed,
        reference,
        &LEVEL_0_TOLERANCE,
    );
    println!("{name}: packed at level 0 vs reference: {diff:?}");
}

fn level_0_matches_the_reference(test: &str, name: &str) {
    let Some(case) = case(test, name, true) else {
        return;
    };
    let volume = case.volume.as_ref().expect("loaded");
    let gpu = gpu_or_skip(test);
    let request = view(&case, 1.0);
    let cpu = cpu_packed(gpu, &case.dataset, &request);
    let reference = cpu_reference(gpu, volume, &request);
    check_level_0(&format!("{name}-cpu"), &cpu, &reference);
    let without_skipping = cpu_packed(
        gpu,
        &case.dataset,
        &FrameRequest {
            skip_empty: false,
            ..request.clone()
        },
    );
    assert_eq!(cpu, without_skipping, "{name}: skipping changed the image");
    let Some(gpu) = gpu else {
        return;
    };
    let mut renderer = gpu_renderer(gpu, &case.dataset);
    let packed = renderer.render(&request).expect("GPU packed render");
    let stats = renderer.last_stats();
    assert_eq!(
        stats.level_counts[1..],
        [0; 4],
        "{name}: 1:1 keeps every stored block at level 0"
    );
    let reference = gpu_reference(gpu, volume)
        .render(&request)
        .expect("GPU reference render");
    check_level_0(&format!("{name}-gpu"), &packed, &reference);
}

#[test]
fn engine_packed_at_level_0_matches_the_reference() {
    level_0_matches_the_reference("engine_packed_at_level_0_matches_the_reference", "engine");
}

#[test]
fn cthead_packed_at_level_0_matches_the_reference() {
    level_0_matches_the_reference("cthead_packed_at_level_0_matches_the_reference", "cthead");
}

/// The view `request` over a black and over a white background: the frame
/// over black (what the goldens keep), its per-pixel opacity and the
/// selection that drew it.
fn render_twice(case: &Case, gpu: Option<&GpuContext>, request: &FrameRequest) -> Rendered {
    let (features, max_edge) = voxserve_tests::render::cpu_twin_device(gpu);
    let render = |background| {
        let request = FrameRequest {
            background,
            ..request.clone()
        };
        shaders::cpu::render_packed(&case.dataset.cache, &request, features, max_edge)
            .unwrap_or_else(|e| panic!("{}:1: {e}", request.reduction))
    };
    let (frame, selection) = render([0.0; 3]);
    let (on_white, _) = render([1.0; 3]);
    let opacity = colour_difference::opacity(&frame, &on_white).expect("same size");
    Rendered {
        frame,
        opacity,
        selection,
    }
}

struct Rendered {
    frame: Frame,
    opacity: Vec<f32>,
    selection: LodSelection,
}

/// What a bound on one data reduction's error allows.
struct Bound {
    ratio: f32,
    /// Largest mean ΔE*uv against the step-1/8 reference.
    mean_delta_e: f64,
    /// Largest 99th percentile ΔE*uv.
    p99_delta_e: f64,
    /// Smallest share of the reference's opaque pixels still opaque.
    coverage: f64,
}

/// Renders at 1:1, 9:1 and 35:1 with the default step, measures each against
/// the full-resolution reference at step 1/8 voxel (the packed renderer at
/// level 0, which matches the reference renderer within rounding: see the
/// tests above), prints ΔE*uv, ꟻLIP and the opaque coverage, checks them
/// against `bounds` and compares the reduced images with their goldens. The
/// bounds sit a fifth to a third above what was measured when the goldens
/// were made, and never above the targets (mean ΔE*uv ≤ 1 at 1:1, ≤ 2 at 9:1,
/// ≤ 3 at 35:1), so a worse level selection or broken borders fail while
/// rounding does not. The opaque coverage is bounded by the target, 0.99 of
/// the reference's opaque pixels, at every reduction: without
/// `blocks::visibility` the CT head (0.9898) and the VHF head (0.9765) miss
/// it at 35:1, their thinnest structures (a head holder's edges, one voxel
/// thick) faded at level 2.
fn reduced_renders(test: &str, name: &str, bounds: [Bound; 3]) {
    let Some(case) = case(test, name, false) else {
        return;
    };
    let gpu = gpu_or_skip(test);
    let reference = render_twice(
        &case,
        gpu,
        &FrameRequest {
            step_voxels: 0.125,
            ..view(&case, 1.0)
        },
    );
    let mut renderer = gpu.map(|g| gpu_renderer(g, &case.dataset));
    for bound in bounds {
        let ratio = bound.ratio;
        let request = view(&case, ratio);
        let Rendered {
            frame,
            opacity,
            selection,
        } = render_twice(&case, gpu, &request);
        let reduction = selection.reduction();
        // Within 10 % of the reduction asked for (among the blocks shown).
        assert!(
            reduction >= f64::from(ratio) * 0.95 && reduction <= f64::from(ratio) * 1.1,
            "{name}: asked for {ratio}:1, got {reduction:.1}:1"
        );
        let error =
            colour_difference::colour_difference(&frame, &reference.frame).expect("same size");
        let flip = colour_difference::flip_mean(&frame, &reference.frame).expect("same size");
        let coverage = colour_difference::opaque_coverage(&opacity, &reference.opacity);
        println!(
            "{name} at {reduction:.1}:1 (levels {:?}) vs the reference at step 1/8: ΔE*uv mean {:.2}, \
             p99 {:.2}, RMS {:.2}, ΔE>6 on {:.1}% of pixels; FLIP {flip:.4}; \
             opaque coverage {:.2}%",
            selection.level_counts(),
            error.mean,
            error.p99,
            error.rms,
            error.above_6 * 100.0,
            coverage * 100.0,
        );
        assert!(
            error.mean <= bound.mean_delta_e,
            "{name} {ratio}:1: mean ΔE {:.2} above {}",
            error.mean,
            bound.mean_delta_e
        );
        assert!(
            error.p99 <= bound.p99_delta_e,
            "{name} {ratio}:1: ΔE p99 {:.2} above {}",
            error.p99,
            bound.p99_delta_e
        );
        assert!(
            coverage >= bound.coverage,
            "{name} {ratio}:1: opaque coverage {coverage:.4} below {}",
            bound.coverage
        );
        // 1:1, 9:1 and 35:1 side by side are the README's strip.
        let golden = format!("{name}-reduced-{ratio}to1");
        assert_golden(&golden, &to_image(&frame), &GOLDEN_TOLERANCE);
        if let Some(r) = renderer.as_mut() {
            let gpu_frame = r.render(&request).expect("GPU render");
            let diff = assert_matches_golden(&golden, &gpu_frame, &GOLDEN_TOLERANCE);
            println!("{golden}: GPU vs golden: {diff:?}");
        }
    }
}

const fn bound(ratio: f32, mean_delta_e: f64, p99_delta_e: f64, coverage: f64) -> Bound {
    Bound {
        ratio,
        mean_delta_e,
        p99_delta_e,
        coverage,
    }
}

/// At 1:1 with the default step the targets hold: mean ΔE*uv ≤ 1 and
/// p99 ≤ 10 against step 1/8 (measured: engine 0.13 / 0.91, CT head 0.31 /
/// 2.69, VHF head 0.07 / 1.46).
const FULL: Bound = bound(1.0, 1.0, 10.0, 0.995);

#[test]
fn engine_reduced_9_and_35_to_1_error_is_reported_and_bounded() {
    reduced_renders(
        "engine_reduced_9_and_35_to_1_error_is_reported_and_bounded",
        "engine",
        // Measured: 9:1 mean 0.57, p99 6.9, coverage 0.9992; 35:1 1.12, 12.9, 0.9978.
        [
            FULL,
            bound(9.0, 0.75, 9.0, 0.995),
            bound(35.0, 1.4, 16.0, 0.995),
        ],
    );
}

#[test]
fn cthead_reduced_9_and_35_to_1_error_is_reported_and_bounded() {
    reduced_renders(
        "cthead_reduced_9_and_35_to_1_error_is_reported_and_bounded",
        "cthead",
        // Measured: 9:1 mean 1.68, p99 19.9, coverage 0.9948; 35:1 2.46, 23.3, 0.9930.
        [
            FULL,
            bound(9.0, 2.0, 25.0, 0.99),
            bound(35.0, 3.0, 31.0, 0.99),
        ],
    );
}

#[test]
fn vhf_head_reduced_9_and_35_to_1_error_is_reported_and_bounded() {
    reduced_renders(
        "vhf_head_reduced_9_and_35_to_1_error_is_reported_and_bounded",
        "vhf",
        // Measured: 9:1 mean 0.35, p99 8.8, coverage 0.9943; 35:1 0.66, 15.3, 0.9951.
        [
            FULL,
            bound(9.0, 0.5, 11.5, 0.99),
            bound(35.0, 0.9, 20.0, 0.99),
        ],
    );
}
