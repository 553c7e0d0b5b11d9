//! `voxserve bench render`: for each dataset, the packed renderer at every
//! image size and data reduction, with and without empty-block skipping, against
//! the full-resolution reference renderer (time and colour difference); with
//! `--cpu`, the packed CPU twin as well.

use std::time::Instant;

use blocks::TransferFunction;
use shaders::colour_difference::colour_difference;
use shaders::{Choice, Frame, FrameRequest, GpuContext, ReferenceRenderer, Renderer, Shading};

use super::args::BenchRenderArgs;
use super::{bench_dataset, timed, view_request};
use server::Dataset;
use server::commands::{CPU_TWIN_FEATURES, say};

/// `voxserve bench render`; see the module docs.
pub fn render(args: &BenchRenderArgs) -> anyhow::Result<()> {
    let gpu = GpuContext::new()?;
    for name in &args.datasets {
        let start = Instant::now();
        let Some((dataset, tf)) = bench_dataset(name, &args.data_dir, &args.data)? else {
            continue;
        };
        let bricked_ms = start.elapsed().as_secs_f64() * 1e3;
        let mut bench = RenderBench::new(&gpu, args, name, dataset, tf)?;
        say(&bench.dataset_line(bricked_ms).to_string())?;
        for &edge in &args.sizes {
            for &shading in &args.shadings {
                bench.view(edge, shading)?;
            }
        }
    }
    Ok(())
}

/// One dataset with its two renderers: the packed one measured and the
/// full-resolution reference it is compared with.
struct RenderBench<'a> {
    gpu: &'a GpuContext,
    args: &'a BenchRenderArgs,
    name: &'a str,
    dataset: Dataset,
    tf: TransferFunction,
    reference: ReferenceRenderer,
    renderer: Renderer,
}

impl<'a> RenderBench<'a> {
    fn new(
        gpu: &'a GpuContext,
        args: &'a BenchRenderArgs,
        name: &'a str,
        dataset: Dataset,
        tf: TransferFunction,
    ) -> anyhow::Result<Self> {
        let volume = dataset.store.load_level(0)?;
        let reference = ReferenceRenderer::new(gpu.clone(), &volume)?;
        drop(volume);
        let renderer = Renderer::new(
            gpu.clone(),
            dataset.cache.clone(),
            args.data.gpu_budget_bytes(),
        )?;
        Ok(Self {
            gpu,
            args,
            name,
            dataset,
            tf,
            reference,
            renderer,
        })
    }

    /// The `dataset` line: the dataset's size, the time it took to open and
    /// brick, and the texel format its blocks have on the GPU.
    fn dataset_line(&self, bricked_ms: f64) -> serde_json::Value {
        serde_json::json!({
            "bench": "dataset",
            "dataset": self.name,
            "dims": self.dataset.dims(),
            "blocks": self.dataset.store.meta().blocks,
            "opened_and_bricked_ms": bricked_ms,
            "texel_format": format!("{:?}", self.renderer.volume_texture().format),
        })
    }

    /// One image size and shading: the reference frame, then the packed
    /// renderer (and the CPU twin when `--cpu` asks) at every data reduction.
    fn view(&mut self, edge: u32, shading: Shading) -> anyhow::Result<()> {
        let base = view_request(edge, shading, &self.tf);
        let (reference_frame, reference_ms) =
            timed(self.args.frames, || self.reference.render(&base))?;
        for &reduction in &self.args.reductions {
            let request = FrameRequest {
                reduction,
                ..base.clone()
            };
            say(&self
                .packed(&request, &reference_frame, reference_ms)?
                .to_string())?;
            if self.args.cpu {
                say(&self.cpu_twin(&request)?.to_string())?;
            }
        }
        Ok(())
    }

    /// A `render` line of the packed renderer on `request`: the first frame
    /// (level selection and uploads) timed apart, then frames with and without
    /// empty-block skipping, and the colour difference against the reference.
    fn packed(
        &mut self,
        request: &FrameRequest,
        reference_frame: &Frame,
        reference_ms: f64,
    ) -> anyhow::Result<serde_json::Value> {
        let frames = self.args.frames;
        let renderer = &mut self.renderer;
        let first = Instant::now();
        renderer.render(request)?;
        let first_ms = first.elapsed().as_secs_f64() * 1e3;
        let stats = renderer.last_stats().clone();
        let (frame, skip_ms) = timed(frames, || renderer.render(request))?;
        let no_skip = FrameRequest {
            skip_empty: false,
            ..request.clone()
        };
        let (_, no_skip_ms) = timed(frames, || renderer.render(&no_skip))?;
        let error = colour_difference(&frame, reference_frame).map_err(anyhow::Error::msg)?;
        let selection = renderer.selection();
        let info = &self.gpu.info;
        Ok(serde_json::json!({
            "bench": "render",
            "renderer": "gpu",
            "adapter": info.name,
            "backend": info.backend.to_string(),
            "device_type": format!("{:?}", info.device_type),
            "dataset": self.name,
            "dims": self.dataset.dims(),
            "shading": request.shading.name(),
            "step_voxels": request.step_voxels,
            "width": request.width,
            "height": request.height,
            "requested_reduction": request.reduction,
            "reduction": stats.reduction,
            "levels": stats.level_counts,
            "non_empty_blocks": selection.map(|s| s.non_empty),
            "blocks": selection.map(|s| s.lod.len()),
            "first_frame_ms": first_ms,
            "select_ms": stats.select_ms,
            "upload_ms": stats.upload_ms,
            "uploaded_blocks": stats.uploaded_blocks,
            "frames": frames,
            "ms_mean": skip_ms,
            "no_skip_ms_mean": no_skip_ms,
            "skip_speedup": no_skip_ms / skip_ms,
            "reference_ms_mean": reference_ms,
            "packed_vs_reference_speedup": reference_ms / skip_ms,
            "mpix_per_s": f64::from(request.width * request.height) / 1e3 / skip_ms,
            "delta_e_vs_reference": error,
        }))
    }

    /// A `render` line of the packed CPU twin on `request`, one frame.
    fn cpu_twin(&self, request: &FrameRequest) -> anyhow::Result<serde_json::Value> {
        let start = Instant::now();
        let max_edge = self.gpu.device.limits().max_texture_dimension_3d;
        shaders::cpu::render_packed(&self.dataset.cache, request, CPU_TWIN_FEATURES, max_edge)?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(serde_json::json!({
            "bench": "render",
            "renderer": "cpu-twin",
            "threads": std::thread::available_parallelism().map_or(1, usize::from),
            "dataset": self.name,
            "shading": request.shading.name(),
            "width": request.width,
            "height": request.height,
            "requested_reduction": request.reduction,
            "frames": 1,
            "ms_mean": ms,
            "note": "includes level selection and atlas assembly",
        }))
    }
}
