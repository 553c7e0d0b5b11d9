//! `voxserve bench render`: for each dataset, the packed renderer at every
//! image size and data reduction, with and without empty-block skipping, against
//! the full-resolution reference renderer (time and colour difference); with
//! `--cpu`, the packed CPU twin as well.

use std::time::Instant;

use shaders::colour_difference::colour_difference;
use shaders::{Camera, Choice, FrameRequest, GpuContext, ReferenceRenderer, Renderer};

use super::args::BenchRenderArgs;
use super::{bench_dataset, timed};
use server::commands::{CPU_TWIN_FEATURES, say};

/// `voxserve bench render`: for each dataset, the packed renderer at every
/// image size and data reduction, with and without empty-block skipping, against
/// the full-resolution reference renderer (time and colour difference).
pub fn render(args: &BenchRenderArgs) -> anyhow::Result<()> {
    let gpu = GpuContext::new()?;
    let info = gpu.info.clone();
    let threads = std::thread::available_parallelism().map_or(1, usize::from);
    for name in &args.datasets {
        let start = Instant::now();
        let Some((dataset, tf)) = bench_dataset(name, &args.data_dir, &args.data)? else {
            continue;
        };
        let bricked_ms = start.elapsed().as_secs_f64() * 1e3;
        let volume = dataset.store.load_level(0)?;
        let mut reference = ReferenceRenderer::new(gpu.clone(), &volume)?;
        drop(volume);
        let mut renderer = Renderer::new(
            gpu.clone(),
            dataset.cache.clone(),
            args.data.gpu_budget_bytes(),
        )?;
        say(&serde_json::json!({
            "bench": "dataset",
            "dataset": name,
            "dims": dataset.dims(),
            "blocks": dataset.store.meta().blocks,
            "opened_and_bricked_ms": bricked_ms,
            "texel_format": format!("{:?}", renderer.volume_texture().format),
        })
        .to_string())?;
        for &edge in &args.sizes {
            for &shading in &args.shadings {
                let base = FrameRequest {
                    camera: Camera {
                        azimuth_deg: 30.0,
                        elevation_deg: 15.0,
                        ..Camera::default()
                    },
                    shading,
                    ..FrameRequest::new(edge, edge, tf.clone())
                };
                let (reference_frame, reference_ms) =
                    timed(args.frames, || reference.render(&base))?;
                for &reduction in &args.reductions {
                    let request = FrameRequest {
                        reduction,
                        ..base.clone()
                    };
                    // The first frame selects levels and uploads blocks: timed apart.
                    let first = Instant::now();
                    renderer.render(&request)?;
                    let first_ms = first.elapsed().as_secs_f64() * 1e3;
                    let stats = renderer.last_stats().clone();
                    let (frame, skip_ms) = timed(args.frames, || renderer.render(&request))?;
                    let no_skip = FrameRequest {
                        skip_empty: false,
                        ..request.clone()
                    };
                    let (_, no_skip_ms) = timed(args.frames, || renderer.render(&no_skip))?;
                    let error =
                        colour_difference(&frame, &reference_frame).map_err(anyhow::Error::msg)?;
                    let selection = renderer.selection();
                    let mut line = serde_json::json!({
                        "bench": "render",
                        "renderer": "gpu",
                        "adapter": info.name,
                        "backend": info.backend.to_string(),
                        "device_type": format!("{:?}", info.device_type),
                        "dataset": name,
                        "dims": dataset.dims(),
                        "shading": shading.name(),
                        "step_voxels": request.step_voxels,
                        "width": edge,
                        "height": edge,
                        "requested_reduction": reduction,
                        "reduction": stats.reduction,
                        "levels": stats.level_counts,
                        "non_empty_blocks": selection.map(|s| s.non_empty),
                        "blocks": selection.map(|s| s.lod.len()),
                        "first_frame_ms": first_ms,
                        "select_ms": stats.select_ms,
                        "upload_ms": stats.upload_ms,
                        "uploaded_blocks": stats.uploaded_blocks,
                        "frames": args.frames,
                        "ms_mean": skip_ms,
                        "no_skip_ms_mean": no_skip_ms,
                        "skip_speedup": no_skip_ms / skip_ms,
                        "reference_ms_mean": reference_ms,
                        "packed_vs_reference_speedup": reference_ms / skip_ms,
                        "mpix_per_s": f64::from(edge * edge) / 1e3 / skip_ms,
                        "delta_e_vs_reference": error,
                    });
                    say(&line.to_string())?;
                    if args.cpu {
                        let start = Instant::now();
                        let max_edge = gpu.device.limits().max_texture_dimension_3d;
                        shaders::cpu::render_packed(
                            &dataset.cache,
                            &request,
                            CPU_TWIN_FEATURES,
                            max_edge,
                        )?;
                        let ms = start.elapsed().as_secs_f64() * 1e3;
                        line = serde_json::json!({
                            "bench": "render",
                            "renderer": "cpu-twin",
                            "threads": threads,
                            "dataset": name,
                            "shading": shading.name(),
                            "width": edge,
                            "height": edge,
                            "requested_reduction": reduction,
                            "frames": 1,
                            "ms_mean": ms,
                            "note": "includes level selection and atlas assembly",
                        });
                        say(&line.to_string())?;
                    }
                }
            }
        }
    }
    Ok(())
}
