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
use shaders::{Camera, Frame, FrameRequest, GpuContext, Renderer, Shading};

use super::args::BenchExtinctionArgs;
use super::light::{adapter_json, merge, unlit_and_gradient_ms, write_images};
use crate::bench::{bench_dataset, timed};
use server::commands::say;

/// Image edge of frames rendered only to run the stages.
const SMALL_EDGE: u32 = 32;

/// The extinction timings of the renderer's last frame.
fn timings_of(renderer: &Renderer) -> anyhow::Result<ExtinctionTimings> {
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
    let gpu = GpuContext::new()?;
    let adapter = adapter_json(&gpu);
    for name in &args.datasets {
        let Some((dataset, tf)) = bench_dataset(name, &args.data_dir, &args.data)? else {
            continue;
        };
        let dims = dataset.dims();
        let mut renderer = Renderer::new(
            gpu.clone(),
            dataset.cache.clone(),
            args.data.gpu_budget_bytes(),
        )?;
        let request = |edge: u32, shading: Shading, extinction: ExtinctionSettings| FrameRequest {
            camera: Camera {
                azimuth_deg: 30.0,
                elevation_deg: 15.0,
                ..Camera::default()
            },
            shading,
            extinction,
            ..FrameRequest::new(edge, edge, tf.clone())
        };
        // The first frame selects and uploads the blocks.
        renderer.render(&request(
            SMALL_EDGE,
            Shading::Unshaded,
            ExtinctionSettings::default(),
        ))?;
        let stats = renderer.last_stats().clone();
        for &sat_size in &args.sat_sizes {
            let grid = grid_dims(renderer.volume_texture(), sat_size);
            let cells: u64 = grid.iter().map(|&n| u64::from(n)).product();
            let setting = serde_json::json!({
                "dataset": name,
                "dims": dims,
                "reduction": stats.reduction,
                "sat_size": sat_size,
                "grid": grid,
                "cells": cells,
                "repeats": args.repeats,
            });
            let with_reference = sat_size <= args.reference_max;
            let base = ExtinctionSettings {
                sat_size,
                ao_radius: args.ao_radius,
                ao_shells: args.ao_radius.min(3),
                cone_angle: args.cone_angle,
                ..ExtinctionSettings::default()
            };

            // The SAT: a fresh grid size rebuilds it.
            renderer.render(&request(SMALL_EDGE, Shading::Extinction, base.clone()))?;
            let first = timings_of(&renderer)?;
            let mut line = serde_json::json!({
                "bench": "extinction-sat",
                "sat_ms": first.sat_ms,
                "sat_ms_per_million_cells": first.sat_ms / (cells as f64 / 1e6),
            });
            merge(&mut line, &setting);
            merge(&mut line, &adapter);
            say(&line.to_string())?;

            // Table 2: ambient occlusion per shell count against explicit sampling.
            let ambient_only = ExtinctionSettings {
                lights: Vec::new(),
                ambient: 1.0,
                ..base.clone()
            };
            let sampled = ExtinctionSettings {
                ao_method: AoMethod::Sampled,
                ..ambient_only.clone()
            };
            let (sampled_ms, sampled_frame) = if with_reference {
                renderer.render(&request(SMALL_EDGE, Shading::Extinction, sampled.clone()))?;
                let ms = timings_of(&renderer)?.ambient_occlusion_ms;
                let frame = renderer.render(&request(args.size, Shading::Extinction, sampled))?;
                (Some(ms), Some(frame))
            } else {
                (None, None)
            };
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
                    renderer.render(&request(SMALL_EDGE, Shading::Extinction, nudged))?;
                    Ok(timings_of(&renderer)?.ambient_occlusion_ms)
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
                if let (Some(reference), true) = (&sampled_frame, radius == args.ao_radius) {
                    let frame =
                        renderer.render(&request(args.size, Shading::Extinction, settings))?;
                    let stem = format!("{name}-sat{sat_size}-ao-shells{shells}");
                    compare(args, &stem, "sat", &frame, reference, &mut line)?;
                }
                merge(&mut line, &setting);
                merge(&mut line, &adapter);
                say(&line.to_string())?;
            }

            // Table 3: soft shadows per cone sampling against one shadow ray.
            let shadows_only = ExtinctionSettings {
                ambient: 0.0,
                ..base.clone()
            };
            let ray = ExtinctionSettings {
                shadow_method: ShadowMethod::Ray,
                ..shadows_only.clone()
            };
            let (ray_ms, ray_frame) = if with_reference {
                let ms = fastest_ms(args.repeats, |r| {
                    renderer.render(&request(
                        SMALL_EDGE,
                        Shading::Extinction,
                        nudge_cone(&ray, r),
                    ))?;
                    Ok(timings_of(&renderer)?.soft_shadow_ms)
                })?;
                let frame = renderer.render(&request(args.size, Shading::Extinction, ray))?;
                (Some(ms), Some(frame))
            } else {
                (None, None)
            };
            for &frequency in &args.cone_frequencies {
                let settings = ExtinctionSettings {
                    cone_frequency: frequency,
                    ..shadows_only.clone()
                };
                let shadow_ms = fastest_ms(args.repeats, |r| {
                    renderer.render(&request(
                        SMALL_EDGE,
                        Shading::Extinction,
                        nudge_cone(&settings, r),
                    ))?;
                    Ok(timings_of(&renderer)?.soft_shadow_ms)
                })?;
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
                if let Some(reference) = &ray_frame {
                    let frame =
                        renderer.render(&request(args.size, Shading::Extinction, settings))?;
                    let stem = format!("{name}-sat{sat_size}-cone{frequency}");
                    compare(args, &stem, "cone", &frame, reference, &mut line)?;
                }
                merge(&mut line, &setting);
                merge(&mut line, &adapter);
                say(&line.to_string())?;
            }

            // Table 1: frames with the light cache filled against unlit ones.
            let lit = request(args.size, Shading::Extinction, base.clone());
            renderer.render(&lit)?;
            let update = timings_of(&renderer)?;
            let (_, lit_ms) = timed(args.frames, || renderer.render(&lit))?;
            let (unlit_ms, gradient_ms) = unlit_and_gradient_ms(&mut renderer, &lit, args.frames)?;
            let mut line = serde_json::json!({
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
            merge(&mut line, &setting);
            merge(&mut line, &adapter);
            say(&line.to_string())?;
        }
    }
    Ok(())
}
