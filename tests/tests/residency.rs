//! Blocks resident on the GPU across frames: a camera change uploads nothing
//! at 1:1 and re-selects only when the view turns by more than
//! `VIEW_TURN_DEG`, a turn or a transfer-function change uploads only the
//! blocks that changed (and renders what a fresh renderer renders), and a
//! device budget too small for level 0 renders at the coarser levels the
//! selection chose. A transfer-function change at 35:1 writes the coarse
//! blocks again (they keep thin structures for one transfer function).

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use blocks::Preset;
use shaders::residency::VIEW_TURN_DEG;
use shaders::{Camera, FrameRequest, Renderer};
use voxserve_tests::checks::coverage;
use voxserve_tests::image_compare::{assert_similar, to_image};
use voxserve_tests::phantom::{phantom_64, phantom_64_dataset, phantom_64_on_disk};
use voxserve_tests::render::gpu_renderer;
use voxserve_tests::{Tolerance, gpu_or_skip};

/// Two renderers of the same blocks in different atlas slots: rounding only.
const SAME_BLOCKS: Tolerance = Tolerance {
    max_mean: 0.1,
    pixel_threshold: 4,
    max_differing_fraction: 0.001,
};

#[test]
fn camera_changes_upload_nothing_and_tf_changes_only_what_changed() {
    let Some(gpu) = gpu_or_skip("camera_changes_upload_nothing_and_tf_changes_only_what_changed")
    else {
        return;
    };
    let dataset = phantom_64_dataset();
    let range = phantom_64().value_range;
    let soft = FrameRequest::new(64, 64, Preset::CtSoftTissue.transfer_function(range));
    let mut renderer = gpu_renderer(gpu, dataset);
    renderer.render(&soft).expect("first frame");
    let first = renderer.last_stats().clone();
    assert!(first.relayout && first.uploaded_blocks > 0, "{first:?}");

    let turned = FrameRequest {
        camera: Camera {
            azimuth_deg: 70.0,
            ..Camera::default()
        },
        ..soft.clone()
    };
    // At 1:1 every block stays at level 0 from every side.
    renderer.render(&turned).expect("turned");
    let stats = renderer.last_stats();
    assert_eq!(
        (stats.uploaded_blocks, stats.relayout),
        (0, false),
        "{stats:?}"
    );
    // A turn within VIEW_TURN_DEG does not even select again.
    let nudged = FrameRequest {
        camera: Camera {
            azimuth_deg: 70.0 + VIEW_TURN_DEG as f32 * 0.8,
            ..Camera::default()
        },
        ..soft.clone()
    };
    renderer.render(&nudged).expect("nudged");
    let stats = renderer.last_stats();
    assert_eq!(
        (stats.uploaded_blocks, stats.relayout, stats.select_ms),
        (0, false, 0.0),
        "{stats:?}"
    );

    // Bone is visible wherever soft tissue is: every bone block is already resident.
    let bone = FrameRequest {
        tf: Some(Preset::CtBone.transfer_function(range)),
        ..turned.clone()
    };
    let frame = renderer.render(&bone).expect("bone");
    let stats = renderer.last_stats().clone();
    println!("soft tissue → bone: {stats:?}");
    assert!(!stats.relayout && stats.uploaded_blocks == 0, "{stats:?}");
    let fresh = gpu_renderer(gpu, dataset).render(&bone).expect("fresh");
    let diff = assert_similar("residency-bone", &frame, &fresh, &SAME_BLOCKS);
    println!("updated vs fresh renderer: {diff:?}");

    // A lower data reduction brings finer levels for some blocks, not all.
    let reduced = FrameRequest {
        reduction: 8.0,
        ..bone.clone()
    };
    renderer.render(&reduced).expect("reduced");
    let at_8 = renderer.last_stats().clone();
    let finer = FrameRequest {
        reduction: 4.0,
        ..bone
    };
    let frame = renderer.render(&finer).expect("finer");
    let stats = renderer.last_stats().clone();
    println!("8:1 → 4:1: {stats:?}");
    let resident: usize = stats.level_counts.iter().sum();
    assert!(stats.uploaded_blocks > 0, "{stats:?}");
    if !stats.relayout {
        assert!(
            stats.uploaded_blocks < resident,
            "only changed blocks: {stats:?} after {at_8:?}"
        );
    }
    let fresh = gpu_renderer(gpu, dataset).render(&finer).expect("fresh");
    assert_similar("residency-finer", &frame, &fresh, &SAME_BLOCKS);

    // Seen from the other side, the blocks the viewer now sees get the
    // detail: some blocks change level, not all.
    let behind = FrameRequest {
        camera: Camera {
            azimuth_deg: 250.0,
            ..Camera::default()
        },
        ..finer
    };
    let frame = renderer.render(&behind).expect("behind");
    let stats = renderer.last_stats().clone();
    println!("4:1 turned 180°: {stats:?}");
    assert!(stats.uploaded_blocks > 0, "{stats:?}");
    if !stats.relayout {
        assert!(
            stats.uploaded_blocks < resident,
            "only changed blocks: {stats:?}"
        );
    }
    let fresh = gpu_renderer(gpu, dataset).render(&behind).expect("fresh");
    assert_similar("residency-behind", &frame, &fresh, &SAME_BLOCKS);
}

#[test]
fn a_small_device_budget_renders_at_coarser_levels() {
    let Some(gpu) = gpu_or_skip("a_small_device_budget_renders_at_coarser_levels") else {
        return;
    };
    let dataset = phantom_64_dataset();
    // 48 KiB: 24k 16-bit texels for a volume of 262k voxels.
    let budget_bytes = 48 << 10;
    let mut renderer =
        Renderer::new(gpu.clone(), dataset.cache.clone(), budget_bytes).expect("renderer");
    let request = FrameRequest::new(
        64,
        64,
        Preset::CtSoftTissue.transfer_function(phantom_64().value_range),
    );
    let frame = renderer.render(&request).expect("render within the budget");
    let stats = renderer.last_stats();
    let packing = renderer.packing().expect("packed");
    let atlas_bytes = packing
        .atlas_dims
        .iter()
        .map(|&d| u64::from(d))
        .product::<u64>()
        * 2;
    println!(
        "budget {budget_bytes} B: {stats:?}, atlas {:?} = {atlas_bytes} B",
        packing.atlas_dims
    );
    assert!(stats.reduction >= 10.0 && stats.memory_limited, "{stats:?}");
    assert!(stats.level_counts[0] < 64, "{stats:?}");
    assert!(
        atlas_bytes <= budget_bytes,
        "the atlas ({atlas_bytes} B) exceeds the budget"
    );
    assert!(coverage(&to_image(&frame)) > 0.2, "the head is still drawn");
}

#[test]
fn a_device_budget_too_small_for_every_block_at_level_4_is_refused_with_the_numbers() {
    let Some(gpu) = gpu_or_skip(
        "a_device_budget_too_small_for_every_block_at_level_4_is_refused_with_the_numbers",
    ) else {
        return;
    };
    let dataset = phantom_64_dataset();
    let mut renderer = Renderer::new(gpu.clone(), dataset.cache.clone(), 256).expect("renderer");
    let request = FrameRequest::new(
        64,
        64,
        Preset::CtSoftTissue.transfer_function(phantom_64().value_range),
    );
    let err = renderer
        .render(&request)
        .expect_err("256 bytes cannot hold the head")
        .to_string();
    assert!(
        err.contains("GPU budget of 256 bytes") && err.contains("level 4"),
        "{err}"
    );
}

#[test]
fn a_cold_transfer_function_change_renders_at_once_from_memory_and_refines_as_blocks_arrive() {
    let test =
        "a_cold_transfer_function_change_renders_at_once_from_memory_and_refines_as_blocks_arrive";
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let dataset = phantom_64_on_disk(dir.path());
    let cache = &dataset.cache;
    let range = phantom_64().value_range;
    let soft = FrameRequest::new(64, 64, Preset::CtSoftTissue.transfer_function(range));
    let mut renderer = gpu_renderer(gpu, &dataset);
    let inline = cache.inline_reads();
    let mut seen = cache.arrivals();
    let first = renderer.render_now(&soft).expect("first frame");
    let stats = renderer.last_stats().clone();
    println!("cold first frame: {stats:?}");
    assert!(
        stats.pending_blocks > 0,
        "level-0 blocks are read in the background, shown coarser meanwhile: {stats:?}"
    );
    assert!(!stats.converged(), "{stats:?}");
    assert_eq!(
        cache.inline_reads(),
        inline,
        "the render thread read nothing"
    );
    assert!(
        coverage(&to_image(&first)) > 0.05,
        "the head shows from coarse data at once"
    );
    // Each later frame shows what has arrived, until nothing is pending.
    let mut frames = 1;
    let mut frame = first;
    while renderer.last_stats().pending_blocks > 0 {
        cache.wait_for_arrivals(seen, std::time::Duration::from_secs(5));
        seen = cache.arrivals();
        frame = renderer.render_now(&soft).expect("refining frame");
        frames += 1;
        assert!(frames < 1000, "the blocks never all arrived");
    }
    println!("{frames} frames until every block was in");
    assert_eq!(
        cache.inline_reads(),
        inline,
        "the render thread read nothing"
    );
    assert!(renderer.last_stats().converged());
    // The refined frame is the full-detail frame a waiting renderer draws.
    let full = gpu_renderer(gpu, &dataset)
        .render(&soft)
        .expect("full detail");
    let diff = assert_similar("residency-cold-refined", &frame, &full, &SAME_BLOCKS);
    println!("refined vs full detail: {diff:?}");
}

/// Coarse blocks keep thin structures visible for one transfer function
/// (`blocks::visibility`): after a change of transfer function every coarse
/// block is written again, so the frame is a fresh renderer's, on the CPU
/// renderer (no GPU needed).
#[test]
fn a_transfer_function_change_writes_the_coarse_blocks_again() {
    let dataset = phantom_64_dataset();
    let range = phantom_64().value_range;
    let renderer = || shaders::cpu::CpuRenderer::new(dataset.cache.clone(), 512 << 20);
    let at = |preset: Preset| FrameRequest {
        reduction: 35.0,
        ..FrameRequest::new(64, 64, preset.transfer_function(range))
    };
    let mut updated = renderer();
    updated
        .render(&at(Preset::CtSoftTissue))
        .expect("soft tissue");
    for preset in [Preset::CtBone, Preset::CtAngio] {
        let request = at(preset);
        let frame = updated.render(&request).expect("changed");
        let stats = updated.last_stats().clone();
        println!("→ {preset:?} at 35:1: {stats:?}");
        let fresh = renderer().render(&request).expect("fresh");
        let diff = assert_similar(
            &format!("residency-reclassified-{preset:?}"),
            &frame,
            &fresh,
            &SAME_BLOCKS,
        );
        println!("updated vs fresh renderer: {diff:?}");
    }
}

/// A frame drawn band by band draws every band from the blocks its first
/// band drew: blocks that arrive meanwhile wait for the next frame (no band
/// pays for an upload, and one frame never joins two sets of blocks), on the
/// CPU renderer (no GPU needed).
#[test]
fn the_bands_of_a_frame_draw_the_blocks_its_first_band_drew() {
    let dir = tempfile::tempdir().expect("temp dir");
    let dataset = phantom_64_on_disk(dir.path());
    let cache = &dataset.cache;
    let range = phantom_64().value_range;
    let soft = FrameRequest::new(64, 64, Preset::CtSoftTissue.transfer_function(range));
    let band = |first: u32| FrameRequest {
        rows: Some(shaders::Rows { first, count: 16 }),
        ..soft.clone()
    };
    let mut renderer = shaders::cpu::CpuRenderer::new(cache.clone(), 512 << 20);
    let seen = cache.arrivals();
    renderer.render_now(&band(0)).expect("first band");
    let first = renderer.last_stats().clone();
    assert!(first.pending_blocks > 0, "cold: blocks are read: {first:?}");
    // Every block the first band asked for arrives before the later bands.
    let mut arrived = cache.arrivals();
    while cache.loading() > 0 {
        arrived = cache.wait_for_arrivals(arrived, std::time::Duration::from_secs(5));
    }
    assert!(cache.arrivals() > seen, "blocks arrived");
    for first_row in [16, 32, 48] {
        renderer.render_now(&band(first_row)).expect("later band");
        let stats = renderer.last_stats().clone();
        assert_eq!(
            (stats.uploaded_blocks, stats.relayout, stats.select_ms),
            (0, false, 0.0),
            "band at row {first_row}: {stats:?}"
        );
        assert_eq!(
            stats.pending_blocks, first.pending_blocks,
            "still drawn coarser, so the frame is drawn again"
        );
    }
    // The next frame's first band shows what arrived.
    renderer.render_now(&band(0)).expect("next frame");
    let next = renderer.last_stats().clone();
    assert!(
        next.uploaded_blocks > 0 && next.pending_blocks < first.pending_blocks,
        "{next:?}"
    );
}
