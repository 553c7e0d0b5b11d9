//! `voxserve bench light`: global light propagation measured the way its paper
//! reports it (Hernell, Ljung, Ynnerman 2008, fig. 6 and table 1).
//!
//! Per dataset and data reduction:
//! - `light-quality`, per segment length and SVR scale: the colour difference ΔE*uv between a frame
//!   lit by the piecewise light (local segments of L voxels, the SVR) and one lit
//!   by the brute-force reference (every voxel integrated to the light at full
//!   resolution), both without in-scattering (R_Ω = 0) and with I_bias = 0, in the
//!   same packed coordinates: ΔE_RMS and ΔE₆ over the whole image (the paper's
//!   measure) and over the object's pixels only, with the light update time of
//!   each method.
//! - `light-table-left`: (A) the light update, (B) one in-scattering refinement
//!   and (C) a frame with the light computed, against an unlit frame, with the
//!   voxels the selection keeps, so (A) can be read per kept voxel.
//!
//! At `--table-reduction`, `light-table-right`: (A) per SVR scale and segment
//! length.
//!
//! (A) is the sum of the stages `local_opacity`, `global_opacity`,
//! `direct_light` and the first `in_scatter` step (with its `light_seams`
//! passes), each timed from submission to completion on the GPU, or as the
//! CPU renderer runs their twins (`--renderer cpu`); allocation of the light
//! textures is left out (it happens once per size) and reported apart as
//! `update_total_ms`.

use std::time::Instant;

use blocks::TransferFunction;
use shaders::colour_difference::{colour_difference, object_colour_difference};
use shaders::global_light::{DirectLightMethod, LightTimings, svr_dims};
use shaders::{AnyRenderer, Backend, Frame, FrameRequest, GpuError, LightSettings, Shading};

use super::args::BenchLightArgs;
use super::{bench_dataset, timed, view_request};
use server::Dataset;
use server::commands::say;

/// Image edge of frames rendered only to run the light stages.
const SMALL_EDGE: u32 = 64;
/// Image edge of the unlit frame (A) is compared with.
const UNLIT_EDGE: u32 = 512;

/// (A): the four stages of a light update, milliseconds.
fn update_ms(t: &LightTimings) -> f64 {
    t.local_opacity_ms + t.global_opacity_ms + t.direct_light_ms + t.in_scatter_ms
}

/// The light timings of the renderer's last frame.
fn light_of(renderer: &AnyRenderer) -> anyhow::Result<LightTimings> {
    renderer
        .last_stats()
        .light()
        .copied()
        .ok_or_else(|| anyhow::anyhow!("the last frame computed no light"))
}

/// The light without in-scattering and without bias, so its error shows
/// undiluted: what the quality comparison and the table of (A) use.
fn unscattered(svr_scale: u32, segment_voxels: u32) -> LightSettings {
    LightSettings {
        svr_scale,
        segment_voxels,
        scatter_radius_voxels: 0.0,
        directions: 1,
        bias: 0.0,
        ..LightSettings::default()
    }
}

/// `voxserve bench light`; see the module docs.
pub fn light(args: &BenchLightArgs) -> anyhow::Result<()> {
    let backend = args.renderer.backend()?;
    let adapter = adapter_json(&backend);
    let Some(&first_svr) = args.svr_scales.first() else {
        anyhow::bail!("--svr-scales: expected at least one of 1, 2, 4, 8");
    };
    for name in &args.datasets {
        let Some((dataset, tf)) = bench_dataset(name, &args.data_dir, &args.data)? else {
            continue;
        };
        let mut bench = LightBench::new(&backend, args, &adapter, name, &dataset, tf, first_svr)?;
        for &reduction in &args.reductions {
            bench.reduction(reduction)?;
        }
    }
    Ok(())
}

/// One dataset's renderer and the frames the light benchmark asks of it.
struct LightBench<'a> {
    args: &'a BenchLightArgs,
    /// The adapter's fields, on every line.
    adapter: &'a serde_json::Value,
    name: &'a str,
    tf: TransferFunction,
    dims: [u32; 3],
    renderer: AnyRenderer,
    /// The light of (A), (B) and (C): in-scattering at the first SVR scale.
    scattered: LightSettings,
}

/// What the selection at one data reduction kept, and the fields every line
/// at that reduction carries.
struct Selected {
    setting: serde_json::Value,
    kept_voxels: u64,
    /// Milliseconds of an unlit frame of `UNLIT_EDGE`², what (A) is compared with.
    unlit_512_ms: f64,
}

/// The brute-force light at one data reduction, what the piecewise light is
/// compared with.
struct Reference {
    frame: Frame,
    light: LightTimings,
    /// The frames' background colour, 8-bit: pixels of it are not the object's.
    background: [u8; 3],
}

impl<'a> LightBench<'a> {
    fn new(
        backend: &Backend,
        args: &'a BenchLightArgs,
        adapter: &'a serde_json::Value,
        name: &'a str,
        dataset: &Dataset,
        tf: TransferFunction,
        first_svr: u32,
    ) -> anyhow::Result<Self> {
        let renderer = backend.renderer(dataset.cache.clone(), args.data.gpu_budget_bytes())?;
        Ok(Self {
            args,
            adapter,
            name,
            tf,
            dims: dataset.dims(),
            renderer,
            scattered: LightSettings {
                svr_scale: first_svr,
                segment_voxels: args.segment,
                scatter_radius_voxels: args.scatter_radius,
                directions: args.directions,
                ..LightSettings::default()
            },
        })
    }

    /// A frame of the benchmarks' view at `reduction` with `light`.
    fn request(
        &self,
        edge: u32,
        reduction: f32,
        shading: Shading,
        light: LightSettings,
    ) -> FrameRequest {
        FrameRequest {
            reduction,
            light,
            ..view_request(edge, shading, &self.tf)
        }
    }

    fn volume_voxels(&self) -> u64 {
        self.dims.iter().map(|&d| u64::from(d)).product()
    }

    /// Prints `line` with the reduction's `setting` and the adapter added.
    fn say(&self, mut line: serde_json::Value, setting: &serde_json::Value) -> anyhow::Result<()> {
        merge(&mut line, setting);
        merge(&mut line, self.adapter);
        say(&line.to_string())
    }

    /// Every measurement at one data reduction: the quality comparison, table
    /// 1 left, and at `--table-reduction` table 1 right.
    fn reduction(&mut self, reduction: f32) -> anyhow::Result<()> {
        let selected = self.select(reduction)?;
        self.quality(reduction, &selected.setting)?;
        self.table_left(reduction, &selected)?;
        if reduction == self.args.table_reduction {
            self.table_right(reduction, &selected.setting)?;
        }
        Ok(())
    }

    /// Unlit frames of `UNLIT_EDGE`² at `reduction`: the first selects and
    /// uploads the blocks, the next `--frames` are timed.
    fn select(&mut self, reduction: f32) -> anyhow::Result<Selected> {
        let frames = self.args.frames;
        let unlit = self.request(UNLIT_EDGE, reduction, Shading::Unshaded, self.scattered);
        self.renderer.render(&unlit)?;
        let (_, unlit_512_ms) = timed(frames, || self.renderer.render(&unlit))?;
        let stats = self.renderer.last_stats().clone();
        let Some(selection) = self.renderer.selection() else {
            anyhow::bail!("no selection after a frame");
        };
        let setting = serde_json::json!({
            "dataset": self.name,
            "dims": self.dims,
            "volume_voxels": self.volume_voxels(),
            "requested_reduction": reduction,
            "reduction": stats.reduction,
            "levels": stats.level_counts,
            "non_empty_blocks": selection.non_empty,
            "kept_voxels": selection.kept_voxels,
        });
        Ok(Selected {
            setting,
            kept_voxels: selection.kept_voxels,
            unlit_512_ms,
        })
    }

    /// `light-quality` lines: the brute-force reference, then the piecewise
    /// light per segment length and SVR scale against it.
    fn quality(&mut self, reduction: f32, setting: &serde_json::Value) -> anyhow::Result<()> {
        let args = self.args;
        let lit = self.request(
            args.size,
            reduction,
            Shading::GlobalLight,
            LightSettings {
                method: DirectLightMethod::Reference,
                ..unscattered(1, args.segment)
            },
        );
        let frame = self.renderer.render_converged(&lit)?;
        let reference = Reference {
            frame,
            light: light_of(&self.renderer)?,
            background: lit
                .background
                .map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8),
        };
        for &segment in &args.quality_segments {
            for &svr in &args.svr_scales {
                let line = self.quality_line(reduction, svr, segment, &reference)?;
                self.say(line, setting)?;
            }
        }
        Ok(())
    }

    /// A `light-quality` line: the piecewise light with SVR scale `svr` and
    /// segments of `segment` voxels against `reference` (ΔE*uv over the image
    /// and over the object), and both methods' time.
    fn quality_line(
        &mut self,
        reduction: f32,
        svr: u32,
        segment: u32,
        reference: &Reference,
    ) -> anyhow::Result<serde_json::Value> {
        let args = self.args;
        let lit = self.request(
            args.size,
            reduction,
            Shading::GlobalLight,
            unscattered(svr, segment),
        );
        let frame = self.renderer.render_converged(&lit)?;
        let piecewise = light_of(&self.renderer)?;
        let piecewise_ms =
            piecewise.local_opacity_ms + piecewise.global_opacity_ms + piecewise.direct_light_ms;
        let image = colour_difference(&frame, &reference.frame).map_err(anyhow::Error::msg)?;
        let object = object_colour_difference(&frame, &reference.frame, reference.background)
            .map_err(anyhow::Error::msg)?;
        if let Some(dir) = &args.images {
            let stem = format!(
                "{}-reduction{reduction}-svr{svr}-segment{segment}",
                self.name
            );
            write_images(dir, &stem, "piecewise", &frame, &reference.frame)?;
        }
        let brute_force_ms = reference.light.direct_light_ms;
        Ok(serde_json::json!({
            "bench": "light-quality",
            "width": args.size,
            "height": args.size,
            "svr_scale": svr,
            "svr_dims": svr_dims(self.dims, svr),
            "segment_voxels": segment,
            "scatter_radius_voxels": 0.0,
            "bias": 0.0,
            "delta_e_rms": image.rms,
            "delta_e_6": image.above_6,
            "delta_e": image,
            "object_delta_e": object,
            "piecewise_ms": piecewise_ms,
            "piecewise": piecewise,
            "brute_force_ms": brute_force_ms,
            "brute_force_over_piecewise": brute_force_ms / piecewise_ms,
        }))
    }

    /// The `light-table-left` line (table 1, left): (A) the light update, (B)
    /// one in-scattering refinement and (C) a lit frame, against unlit and
    /// gradient-shaded frames.
    fn table_left(&mut self, reduction: f32, selected: &Selected) -> anyhow::Result<()> {
        let args = self.args;
        let lit = self.request(args.size, reduction, Shading::GlobalLight, self.scattered);
        self.renderer.render(&lit)?;
        let a = light_of(&self.renderer)?;
        self.renderer.render(&lit)?;
        let b = light_of(&self.renderer)?;
        self.renderer.render_converged(&lit)?;
        let (_, c_ms) = timed(args.frames, || self.renderer.render(&lit))?;
        let renderer = &mut self.renderer;
        let (unlit_ms, gradient_ms) =
            unlit_and_gradient_ms(|r| renderer.render(r), &lit, args.frames)?;
        let a_ms = update_ms(&a);
        let svr = self.scattered.svr_scale;
        let line = serde_json::json!({
            "bench": "light-table-left",
            "width": args.size,
            "height": args.size,
            "svr_scale": svr,
            "svr_dims": svr_dims(self.dims, svr),
            "segment_voxels": args.segment,
            "scatter_radius_voxels": args.scatter_radius,
            "directions": args.directions,
            "frames": args.frames,
            "a_ms": a_ms,
            "a": a,
            "update_total_ms": a.total_ms,
            "a_ms_per_million_kept_voxels": a_ms / (selected.kept_voxels as f64 / 1e6),
            "a_ms_per_million_volume_voxels": a_ms / (self.volume_voxels() as f64 / 1e6),
            "b_ms": b.in_scatter_ms,
            "c_ms": c_ms,
            "unlit_ms": unlit_ms,
            "gradient_ms": gradient_ms,
            "c_over_unlit": c_ms / unlit_ms,
            "c_over_gradient": c_ms / gradient_ms,
            "unlit_512_ms": selected.unlit_512_ms,
            "a_over_unlit_512": a_ms / selected.unlit_512_ms,
        });
        self.say(line, &selected.setting)
    }

    /// `light-table-right` lines (table 1, right): (A) per SVR scale and
    /// segment length, each from one frame of `SMALL_EDGE`².
    fn table_right(&mut self, reduction: f32, setting: &serde_json::Value) -> anyhow::Result<()> {
        let args = self.args;
        for &svr in &args.svr_scales {
            for &segment in &args.segments {
                let start = Instant::now();
                self.renderer.render(&self.request(
                    SMALL_EDGE,
                    reduction,
                    Shading::GlobalLight,
                    unscattered(svr, segment),
                ))?;
                let wall_ms = start.elapsed().as_secs_f64() * 1e3;
                let a = light_of(&self.renderer)?;
                let line = serde_json::json!({
                    "bench": "light-table-right",
                    "svr_scale": svr,
                    "svr_dims": svr_dims(self.dims, svr),
                    "segment_voxels": segment,
                    "scatter_radius_voxels": 0.0,
                    "a_ms": update_ms(&a),
                    "a": a,
                    "frame_wall_ms": wall_ms,
                });
                self.say(line, setting)?;
            }
        }
        Ok(())
    }
}

/// Writes `STEM-METHOD.png`, `STEM-reference.png` and `STEM-delta-e.png`
/// (ΔE*uv per pixel: black at 0, full red at 6 or more) into `dir`.
pub(crate) fn write_images(
    dir: &std::path::Path,
    stem: &str,
    method: &str,
    piecewise: &Frame,
    reference: &Frame,
) -> anyhow::Result<()> {
    use anyhow::Context as _;
    std::fs::create_dir_all(dir)
        .with_context(|| format!("--images: cannot create {}", dir.display()))?;
    let delta =
        shaders::colour_difference::per_pixel(piecewise, reference).map_err(anyhow::Error::msg)?;
    let error = Frame {
        width: piecewise.width,
        height: piecewise.height,
        rgba: delta
            .iter()
            .flat_map(|&d| {
                [
                    (d / 6.0).clamp(0.0, 1.0) as f32 * 255.0,
                    (d / 1.0).clamp(0.0, 1.0) as f32 * 64.0,
                    0.0,
                    255.0,
                ]
            })
            .map(|c| c.round() as u8)
            .collect(),
    };
    for (suffix, frame) in [
        (method, piecewise),
        ("reference", reference),
        ("delta-e", &error),
    ] {
        let path = dir.join(format!("{stem}-{suffix}.png"));
        let bytes = server::encode::png(frame)?;
        std::fs::write(&path, bytes)
            .with_context(|| format!("--images: cannot write {}", path.display()))?;
    }
    Ok(())
}

/// Milliseconds per frame of `lit` rendered unshaded and with gradient
/// shading instead, `frames` timed each: what a lit frame is compared with.
pub(crate) fn unlit_and_gradient_ms(
    mut render: impl FnMut(&FrameRequest) -> Result<Frame, GpuError>,
    lit: &FrameRequest,
    frames: u32,
) -> anyhow::Result<(f64, f64)> {
    let mut ms = [0.0; 2];
    for (out, shading) in ms.iter_mut().zip([Shading::Unshaded, Shading::Gradient]) {
        let request = FrameRequest {
            shading,
            ..lit.clone()
        };
        *out = timed(frames, || render(&request))?.1;
    }
    Ok((ms[0], ms[1]))
}

/// Which renderer draws, what it runs on and its threads, for every JSON line.
pub(crate) fn adapter_json(backend: &Backend) -> serde_json::Value {
    serde_json::json!({
        "renderer": backend.kind(),
        "adapter": backend.describe(),
        "threads": rayon::current_num_threads(),
    })
}

/// Adds the fields of `extra` to `line`.
pub(crate) fn merge(line: &mut serde_json::Value, extra: &serde_json::Value) {
    if let (Some(line), Some(extra)) = (line.as_object_mut(), extra.as_object()) {
        for (k, v) in extra {
            line.insert(k.clone(), v.clone());
        }
    }
}
