//! `voxserve bench extinction`: extinction-based illumination measured the way
//! its paper reports it (Schlegel, Makhinya, Pajarola 2011, tables 1–3).
//!
//! Per dataset and SAT grid size:
//! - `extinction-sat` (table 2's text): the `extinction_sat` stage, the
//!   reconstruction from the packed blocks and the three scans, timed from
//!   submission to completion.
//! - `extinction-ao` (table 2): `ambient_occlusion` per shell count against
//!   `ambient_occlusion_reference`, explicit sampling of the sphere of
//!   `--ao-radius` cells, with ΔE*uv between frames lit by ambient light only
//!   through either term (the paper's fig. 2 comparison).
//! - `extinction-shadow` (table 3): `soft_shadow` per cone sampling frequency
//!   against `shadow_ray` (one classic shadow ray, 250 samples per volume side),
//!   one directional light, no ambient light, with ΔE*uv between the frames.
//! - `extinction-frame` (table 1): a frame with the light cache filled against
//!   an unlit and a gradient-shaded frame at `--size`².
//!
//! Stage timings come from renders at a small image size (the stages do not
//! depend on it), each the fastest of `--repeats` runs (the settings nudged by
//! a negligible amount so the stage runs again) except the SAT build and the
//! sampled AO (one run each: the latter takes minutes at 256³); frames
//! compared or timed are `--size`².

use shaders::colour_difference::{colour_difference, object_colour_difference};
use shaders::extinction::{
    AoMethod, ExtinctionSettings, ExtinctionTimings, ShadowMethod, grid_dims,
};
use shaders::{AnyRenderer, Backend, Frame, FrameRequest, Shading};

use super::args::BenchExtinctionArgs;
use super::light::{adapter_json, merge, unlit_and_gradient_ms, write_images};
use super::{bench_dataset, timed, view_request};
use blocks::TransferFunction;
use server::Dataset;
use server::commands::say;

/// Image edge of frames rendered only to run the stages.
const SMALL_EDGE: u32 = 32;

/// The extinction timings of the renderer's last frame.
fn timings_of(renderer: &AnyRenderer) -> anyhow::Result<ExtinctionTimings> {
    renderer
        .last_stats()
        .extinction()
        .copied()
        .ok_or_else(|| anyhow::anyhow!("the last frame computed no extinction terms"))
}

/// Adds the colour difference of `frame` against `reference` (over the image
/// and over the object's pixels) to `line`, and writes both frames and the
/// ΔE image as `STEM-METHOD.png` … when `--images` asks.
fn compare(
    args: &BenchExtinctionArgs,
    stem: &str,
    method: &str,
    frame: &Frame,
    reference: &Frame,
    line: &mut serde_json::Value,
) -> anyhow::Result<()> {
    // Frames are composited over a black background.
    let image = colour_difference(frame, reference).map_err(anyhow::Error::msg)?;
    let object = object_colour_difference(frame, reference, [0; 3]).map_err(anyhow::Error::msg)?;
    if let Some(dir) = &args.images {
        write_images(dir, stem, method, frame, reference)?;
    }
    if let Some(line) = line.as_object_mut() {
        line.insert("width".into(), args.size.into());
        line.insert("delta_e_rms".into(), image.rms.into());
        line.insert("delta_e_6".into(), image.above_6.into());
        line.insert("delta_e".into(), serde_json::to_value(image)?);
        line.insert("object_delta_e".into(), serde_json::to_value(object)?);
    }
    Ok(())
}

/// The fastest of `repeats` timings `time(r)` (r = 0, 1, …): on a shared
/// machine the least disturbed run is the best estimate of the stage's cost.
fn fastest_ms(
    repeats: u32,
    mut time: impl FnMut(u32) -> anyhow::Result<f64>,
) -> anyhow::Result<f64> {
    let ms = (0..repeats.max(1))
        .map(&mut time)
        .collect::<anyhow::Result<Vec<f64>>>()?;
    Ok(ms.into_iter().fold(f64::INFINITY, f64::min))
}

/// `settings` with the cone's growth moved by a negligible amount, so the
/// shadows are recomputed for repeat `r` of a timing.
fn nudge_cone(settings: &ExtinctionSettings, r: u32) -> ExtinctionSettings {
    ExtinctionSettings {
        cone_growth: settings.cone_growth + 1e-6 * (r + 1) as f32,
        ..settings.clone()
    }
}

/// `voxserve bench extinction`; see the module docs.
pub fn extinction(args: &BenchExtinctionArgs) -> anyhow::Result<()> {
    let backend = args.renderer.backend()?;
    let adapter = adapter_json(&backend);
    for name in &args.datasets {
        let Some((dataset, tf)) = bench_dataset(name, &args.data_dir, &args.data)? else {
            continue;
        };
        let mut bench = ExtinctionBench::new(&backend, args, &adapter, name, &dataset, tf)?;
        for &sat_size in &args.sat_sizes {
            bench.grid(sat_size)?;
        }
    }
    Ok(())
}

/// One dataset's renderer and the frames the extinction benchmark asks of it.
struct ExtinctionBench<'a> {
    args: &'a BenchExtinctionArgs,
    /// The adapter's fields, on every line.
    adapter: &'a serde_json::Value,
    name: &'a str,
    tf: TransferFunction,
    dims: [u32; 3],
    renderer: AnyRenderer,
    /// The data reduction the first frame's selection reached.
    reduction: f64,
}

/// One SAT grid size: the settings its measurements start from and the
/// fields every line about it carries.
struct Grid {
    sat_size: u32,
    cells: u64,
    /// Whether the references (explicit AO sampling, shadow rays) run.
    with_reference: bool,
    base: ExtinctionSettings,
    setting: serde_json::Value,
}

impl<'a> ExtinctionBench<'a> {
    /// The renderer for `dataset`, after a first frame that selects and
    /// uploads the blocks.
    fn new(
        backend: &Backend,
        args: &'a BenchExtinctionArgs,
        adapter: &'a serde_json::Value,
        name: &'a str,
        dataset: &Dataset,
        tf: TransferFunction,
    ) -> anyhow::Result<Self> {
        let mut renderer = backend.renderer(dataset.cache.clone(), args.data.gpu_budget_bytes())?;
        renderer.render(&FrameRequest {
            extinction: ExtinctionSettings::default(),
            ..view_request(SMALL_EDGE, Shading::Unshaded, &tf)
        })?;
        let reduction = renderer.last_stats().reduction;
        Ok(Self {
            args,
            adapter,
            name,
            tf,
            dims: dataset.dims(),
            renderer,
            reduction,
        })
    }

    /// A frame of the benchmarks' view with `extinction`.
    fn request(&self, edge: u32, shading: Shading, extinction: ExtinctionSettings) -> FrameRequest {
        FrameRequest {
            extinction,
            ..view_request(edge, shading, &self.tf)
        }
    }

    /// Runs the stages of `settings` with a frame of `SMALL_EDGE`²; their timings.
    fn stages(&mut self, settings: ExtinctionSettings) -> anyhow::Result<ExtinctionTimings> {
        self.renderer
            .render(&self.request(SMALL_EDGE, Shading::Extinction, settings))?;
        timings_of(&self.renderer)
    }

    /// A frame of `--size`² lit with `settings`, to compare.
    fn frame(&mut self, settings: ExtinctionSettings) -> anyhow::Result<Frame> {
        let size = self.args.size;
        Ok(self
            .renderer
            .render(&self.request(size, Shading::Extinction, settings))?)
    }

    /// The fastest soft-shadow time of `--repeats` runs of `settings`.
    fn soft_shadow_ms(&mut self, settings: &ExtinctionSettings) -> anyhow::Result<f64> {
        fastest_ms(self.args.repeats, |r| {
            Ok(self.stages(nudge_cone(settings, r))?.soft_shadow_ms)
        })
    }

    /// Prints `line` with the grid's `setting` and the adapter added.
    fn say(&self, mut line: serde_json::Value, setting: &serde_json::Value) -> anyhow::Result<()> {
        merge(&mut line, setting);
        merge(&mut line, self.adapter);
        say(&line.to_string())
    }

    /// Every measurement at one SAT grid size: the SAT build, table 2, table 3
    /// and table 1.
    fn grid(&mut self, sat_size: u32) -> anyhow::Result<()> {
        let args = self.args;
        let grid = grid_dims(self.renderer.volume_texture(), sat_size);
        let cells: u64 = grid.iter().map(|&n| u64::from(n)).product();
        let setting = serde_json::json!({
            "dataset": self.name,
            "dims": self.dims,
            "reduction": self.reduction,
            "sat_size": sat_size,
            "grid": grid,
            "cells": cells,
            "repeats": args.repeats,
        });
        let grid = Grid {
            sat_size,
            cells,
            with_reference: sat_size <= args.reference_max,
            base: ExtinctionSettings {
                sat_size,
                ao_radius: args.ao_radius,
                ao_shells: args.ao_radius.min(3),
                cone_angle: args.cone_angle,
                ..ExtinctionSettings::default()
            },
            setting,
        };
        self.sat(&grid)?;
        self.ambient_occlusion(&grid)?;
        self.soft_shadows(&grid)?;
        self.lit_frames(&grid)
    }

    /// The `extinction-sat` line: the SAT build (a fresh grid size rebuilds it).
    fn sat(&mut self, grid: &Grid) -> anyhow::Result<()> {
        let first = self.stages(grid.base.clone())?;
        let line = serde_json::json!({
            "bench": "extinction-sat",
            "sat_ms": first.sat_ms,
            "sat_ms_per_million_cells": first.sat_ms / (grid.cells as f64 / 1e6),
        });
        self.say(line, &grid.setting)
    }

    /// `extinction-ao` lines (table 2): ambient occlusion per shell count
    /// against explicit sampling, ambient light only.
    fn ambient_occlusion(&mut self, grid: &Grid) -> anyhow::Result<()> {
        let args = self.args;
        let ambient_only = ExtinctionSettings {
            lights: Vec::new(),
            ambient: 1.0,
            ..grid.base.clone()
        };
        let sampled = if grid.with_reference {
            Some(self.sampled_ao(&ambient_only)?)
        } else {
            None
        };
        let sampled_ms = sampled.as_ref().map(|&(ms, _)| ms);
        for &shells in &args.shells {
            let radius = args.ao_radius.max(shells);
            let settings = ExtinctionSettings {
                ao_radius: radius,
                ao_shells: shells,
                ..ambient_only.clone()
            };
            let ao_ms = fastest_ms(args.repeats, |r| {
                let nudged = ExtinctionSettings {
                    ao_strength: settings.ao_strength + 1e-3 * (r + 1) as f32,
                    ..settings.clone()
                };
                Ok(self.stages(nudged)?.ambient_occlusion_ms)
            })?;
            let mut line = serde_json::json!({
                "bench": "extinction-ao",
                "shells": shells,
                "ao_radius": radius,
                "ao_ms": ao_ms,
                "sampled_radius": args.ao_radius,
                "sampled_ms": sampled_ms,
                "sampled_over_sat": sampled_ms.map(|s| s / ao_ms),
            });
            if let (Some((_, reference)), true) = (&sampled, radius == args.ao_radius) {
                let frame = self.frame(settings)?;
                let stem = format!("{}-sat{}-ao-shells{shells}", self.name, grid.sat_size);
                compare(args, &stem, "sat", &frame, reference, &mut line)?;
            }
            self.say(line, &grid.setting)?;
        }
        Ok(())
    }

    /// The reference of table 2: ambient occlusion by explicit sampling of the
    /// sphere (one run: it takes minutes at 256³), its time and frame.
    fn sampled_ao(&mut self, ambient_only: &ExtinctionSettings) -> anyhow::Result<(f64, Frame)> {
        let sampled = ExtinctionSettings {
            ao_method: AoMethod::Sampled,
            ..ambient_only.clone()
        };
        let ms = self.stages(sampled.clone())?.ambient_occlusion_ms;
        Ok((ms, self.frame(sampled)?))
    }

    /// `extinction-shadow` lines (table 3): soft shadows per cone sampling
    /// frequency against one shadow ray, one directional light, no ambient light.
    fn soft_shadows(&mut self, grid: &Grid) -> anyhow::Result<()> {
        let args = self.args;
        let shadows_only = ExtinctionSettings {
            ambient: 0.0,
            ..grid.base.clone()
        };
        let ray = if grid.with_reference {
            let ray = ExtinctionSettings {
                shadow_method: ShadowMethod::Ray,
                ..shadows_only.clone()
            };
            Some((self.soft_shadow_ms(&ray)?, self.frame(ray)?))
        } else {
            None
        };
        let ray_ms = ray.as_ref().map(|&(ms, _)| ms);
        for &frequency in &args.cone_frequencies {
            let settings = ExtinctionSettings {
                cone_frequency: frequency,
                ..shadows_only.clone()
            };
            let shadow_ms = self.soft_shadow_ms(&settings)?;
            let mut line = serde_json::json!({
                "bench": "extinction-shadow",
                "cone_frequency": frequency,
                "cone_angle": args.cone_angle,
                "cone_growth": settings.cone_growth,
                "lights": 1,
                "soft_shadow_ms": shadow_ms,
                "shadow_ray_ms": ray_ms,
                "soft_shadow_over_ray": ray_ms.map(|r| shadow_ms / r),
            });
            if let Some((_, reference)) = &ray {
                let frame = self.frame(settings)?;
                let stem = format!("{}-sat{}-cone{frequency}", self.name, grid.sat_size);
                compare(args, &stem, "cone", &frame, reference, &mut line)?;
            }
            self.say(line, &grid.setting)?;
        }
        Ok(())
    }

    /// The `extinction-frame` line (table 1): frames with the light cache
    /// filled against unlit and gradient-shaded ones.
    fn lit_frames(&mut self, grid: &Grid) -> anyhow::Result<()> {
        let args = self.args;
        let base = &grid.base;
        let lit = self.request(args.size, Shading::Extinction, base.clone());
        self.renderer.render(&lit)?;
        let update = timings_of(&self.renderer)?;
        let (_, lit_ms) = timed(args.frames, || self.renderer.render(&lit))?;
        let renderer = &mut self.renderer;
        let (unlit_ms, gradient_ms) =
            unlit_and_gradient_ms(|r| renderer.render(r), &lit, args.frames)?;
        let line = serde_json::json!({
            "bench": "extinction-frame",
            "width": args.size,
            "height": args.size,
            "frames": args.frames,
            "lights": base.lights.len(),
            "ao_shells": base.ao_shells,
            "ao_radius": base.ao_radius,
            "cone_frequency": base.cone_frequency,
            "cone_angle": base.cone_angle,
            "update": update,
            "lit_ms": lit_ms,
            "unlit_ms": unlit_ms,
            "gradient_ms": gradient_ms,
            "lit_fps": 1e3 / lit_ms,
            "unlit_fps": 1e3 / unlit_ms,
            "lit_over_unlit": lit_ms / unlit_ms,
            "lit_over_gradient": lit_ms / gradient_ms,
        });
        self.say(line, &grid.setting)
    }
}
