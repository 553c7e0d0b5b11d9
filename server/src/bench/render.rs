//! `voxserve bench render`: for each dataset, the packed renderer (GPU or
//! CPU, `--renderer`) at every image size and data reduction, with and without
//! empty-block skipping, against the full-resolution reference renderer of
//! the same backend: time, and colour difference against the reference at the
//! same step and against the reference at step 1/8 voxel (ΔE*uv, ꟻLIP, and the
//! share of the reference's opaque pixels the packed frame still covers).

use std::time::Instant;

use blocks::{TransferFunction, Volume};
use shaders::colour_difference::{self, colour_difference};
use shaders::cpu::CPU_FEATURES;
use shaders::{
    AnyRenderer, Backend, Choice, Frame, FrameRequest, GpuError, ReferenceRenderer, Shading,
};

use super::args::BenchRenderArgs;
use super::{bench_dataset, timed, view_request};
use server::Dataset;
use server::commands::say;

/// `voxserve bench render`; see the module docs.
pub fn render(args: &BenchRenderArgs) -> anyhow::Result<()> {
    let backend = args.renderer.backend()?;
    for name in &args.datasets {
        let start = Instant::now();
        let Some((dataset, tf)) = bench_dataset(name, &args.data_dir, &args.data)? else {
            continue;
        };
        let bricked_ms = start.elapsed().as_secs_f64() * 1e3;
        let mut bench = RenderBench::new(&backend, args, name, dataset, tf)?;
        say(&bench.dataset_line(bricked_ms).to_string())?;
        for &edge in &args.sizes {
            for &shading in &args.shadings {
                bench.view(edge, shading)?;
            }
        }
    }
    Ok(())
}

/// The step of the finest reference, in voxels.
const FINE_STEP_VOXELS: f32 = 0.125;

/// The full-resolution reference at [`FINE_STEP_VOXELS`]: its frame over the
/// view's background and its per-pixel opacity.
struct Fine {
    frame: Frame,
    opacity: Vec<f32>,
}

/// `request` over a white background (to measure opacity beside the frame
/// over the view's black one).
fn on_white(request: &FrameRequest) -> FrameRequest {
    FrameRequest {
        background: [1.0; 3],
        ..request.clone()
    }
}

/// The full-resolution reference a backend's packed renderer is compared
/// with: the GPU's reference stage, or its CPU twin.
enum Reference {
    Gpu(Box<ReferenceRenderer>),
    Cpu(Box<Volume>),
}

impl Reference {
    fn render(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        match self {
            Reference::Gpu(r) => r.render(request),
            Reference::Cpu(volume) => shaders::cpu::render_reference(volume, request, CPU_FEATURES),
        }
    }
}

/// One dataset with its two renderers: the packed one measured and the
/// full-resolution reference it is compared with.
struct RenderBench<'a> {
    backend: &'a Backend,
    args: &'a BenchRenderArgs,
    name: &'a str,
    dataset: Dataset,
    tf: TransferFunction,
    reference: Reference,
    renderer: AnyRenderer,
}

impl<'a> RenderBench<'a> {
    fn new(
        backend: &'a Backend,
        args: &'a BenchRenderArgs,
        name: &'a str,
        dataset: Dataset,
        tf: TransferFunction,
    ) -> anyhow::Result<Self> {
        let volume = dataset.store.load_level(0)?;
        let reference = match backend {
            Backend::Gpu(gpu) => {
                Reference::Gpu(Box::new(ReferenceRenderer::new(gpu.clone(), &volume)?))
            }
            Backend::Cpu => Reference::Cpu(Box::new(volume)),
        };
        let renderer = backend.renderer(dataset.cache.clone(), args.data.gpu_budget_bytes())?;
        Ok(Self {
            backend,
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

    /// One image size and shading: the reference frames (at the view's step,
    /// timed, and at step 1/8 over black and white), then the packed renderer
    /// at every data reduction.
    fn view(&mut self, edge: u32, shading: Shading) -> anyhow::Result<()> {
        let base = view_request(edge, shading, &self.tf);
        let (reference_frame, reference_ms) =
            timed(self.args.frames, || self.reference.render(&base))?;
        let fine = FrameRequest {
            step_voxels: FINE_STEP_VOXELS,
            ..base.clone()
        };
        let frame = self.reference.render(&fine)?;
        let on_white = self.reference.render(&on_white(&fine))?;
        let fine = Fine {
            opacity: colour_difference::opacity(&frame, &on_white)?,
            frame,
        };
        for &reduction in &self.args.reductions {
            let request = FrameRequest {
                reduction,
                ..base.clone()
            };
            say(&self
                .packed(&request, &reference_frame, reference_ms, &fine)?
                .to_string())?;
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
        fine: &Fine,
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
        let fine_error = colour_difference(&frame, &fine.frame)?;
        let flip = colour_difference::flip_mean(&frame, &fine.frame)?;
        let opacity = colour_difference::opacity(&frame, &renderer.render(&on_white(request))?)?;
        let coverage = colour_difference::opaque_coverage(&opacity, &fine.opacity);
        let selection = renderer.selection();
        Ok(serde_json::json!({
            "bench": "render",
            "renderer": self.backend.kind(),
            "adapter": self.backend.describe(),
            "threads": rayon::current_num_threads(),
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
            "fine_step_voxels": FINE_STEP_VOXELS,
            "delta_e_vs_fine_reference": fine_error,
            "flip_vs_fine_reference": flip,
            "opaque_coverage_of_fine_reference": coverage,
        }))
    }
}
