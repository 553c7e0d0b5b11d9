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
//! (A) is the sum of the GPU stages `local_opacity`, `global_opacity`,
//! `direct_light` and the first `in_scatter` step, each timed from submission to
//! completion; allocation of the light textures is left out (it happens once per
//! size) and reported apart as `update_total_ms`.

use std::time::Instant;

use shaders::colour_difference::{colour_difference, object_colour_difference};
use shaders::global_light::{DirectLightMethod, LightTimings, svr_dims};
use shaders::{Camera, FrameRequest, GpuContext, LightSettings, Renderer, Shading};

use super::args::BenchLightArgs;
use crate::bench::{bench_dataset, timed};
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
fn light_of(renderer: &Renderer) -> anyhow::Result<LightTimings> {
    renderer
        .last_stats()
        .light()
        .copied()
        .ok_or_else(|| anyhow::anyhow!("the last frame computed no light"))
}

/// `voxserve bench light`; see the module docs.
pub fn light(args: &BenchLightArgs) -> anyhow::Result<()> {
    let gpu = GpuContext::new()?;
    let adapter = adapter_json(&gpu);
    let Some(&first_svr) = args.svr_scales.first() else {
        anyhow::bail!("--svr-scales: expected at least one of 1, 2, 4, 8");
    };
    for name in &args.datasets {
        let Some((dataset, tf)) = bench_dataset(name, &args.data_dir, &args.data)? else {
            continue;
        };
        let dims = dataset.dims();
        let volume_voxels: u64 = dims.iter().map(|&d| u64::from(d)).product();
        let mut renderer = Renderer::new(
            gpu.clone(),
            dataset.cache.clone(),
            args.data.gpu_budget_bytes(),
        )?;
        let request =
            |edge: u32, reduction: f32, shading: Shading, light: LightSettings| FrameRequest {
                camera: Camera {
                    azimuth_deg: 30.0,
                    elevation_deg: 15.0,
                    ..Camera::default()
                },
                shading,
                reduction,
                light,
                ..FrameRequest::new(edge, edge, tf.clone())
            };
        // No in-scattering and no bias: the light's error shows undiluted.
        let unscattered = |svr_scale: u32, segment_voxels: u32| LightSettings {
            svr_scale,
            segment_voxels,
            scatter_radius_voxels: 0.0,
            directions: 1,
            bias: 0.0,
            ..LightSettings::default()
        };
        let scattered = LightSettings {
            svr_scale: first_svr,
            segment_voxels: args.segment,
            scatter_radius_voxels: args.scatter_radius,
            directions: args.directions,
            ..LightSettings::default()
        };
        for &reduction in &args.reductions {
            // The first unlit frame selects and uploads the blocks.
            let unlit_small = request(UNLIT_EDGE, reduction, Shading::Unshaded, scattered);
            renderer.render(&unlit_small)?;
            let (_, unlit_512_ms) = timed(args.frames, || renderer.render(&unlit_small))?;
            let stats = renderer.last_stats().clone();
            let Some(selection) = renderer.selection() else {
                anyhow::bail!("no selection after a frame");
            };
            let kept_voxels = selection.kept_voxels;
            let non_empty = selection.non_empty;
            let setting = serde_json::json!({
                "dataset": name,
                "dims": dims,
                "volume_voxels": volume_voxels,
                "requested_reduction": reduction,
                "reduction": stats.reduction,
                "levels": stats.level_counts,
                "non_empty_blocks": non_empty,
                "kept_voxels": kept_voxels,
            });

            // The brute-force reference, then the piecewise light per SVR scale.
            let lit = request(
                args.size,
                reduction,
                Shading::GlobalLight,
                LightSettings {
                    method: DirectLightMethod::Reference,
                    ..unscattered(1, args.segment)
                },
            );
            let reference_frame = renderer.render_converged(&lit)?;
            let reference = light_of(&renderer)?;
            let background = lit
                .background
                .map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8);
            for (&segment, &svr) in args
                .quality_segments
                .iter()
                .flat_map(|s| args.svr_scales.iter().map(move |v| (s, v)))
            {
                let lit = request(
                    args.size,
                    reduction,
                    Shading::GlobalLight,
                    unscattered(svr, segment),
                );
                let frame = renderer.render_converged(&lit)?;
                let piecewise = light_of(&renderer)?;
                let piecewise_ms = piecewise.local_opacity_ms
                    + piecewise.global_opacity_ms
                    + piecewise.direct_light_ms;
                let image =
                    colour_difference(&frame, &reference_frame).map_err(anyhow::Error::msg)?;
                let object = object_colour_difference(&frame, &reference_frame, background)
                    .map_err(anyhow::Error::msg)?;
                if let Some(dir) = &args.images {
                    let stem = format!("{name}-reduction{reduction}-svr{svr}-segment{segment}");
                    write_images(dir, &stem, "piecewise", &frame, &reference_frame)?;
                }
                let mut line = serde_json::json!({
                    "bench": "light-quality",
                    "width": args.size,
                    "height": args.size,
                    "svr_scale": svr,
                    "svr_dims": svr_dims(dims, svr),
                    "segment_voxels": segment,
                    "scatter_radius_voxels": 0.0,
                    "bias": 0.0,
                    "delta_e_rms": image.rms,
                    "delta_e_6": image.above_6,
                    "delta_e": image,
                    "object_delta_e": object,
                    "piecewise_ms": piecewise_ms,
                    "piecewise": piecewise,
                    "brute_force_ms": reference.direct_light_ms,
                    "brute_force_over_piecewise": reference.direct_light_ms / piecewise_ms,
                });
                merge(&mut line, &setting);
                merge(&mut line, &adapter);
                say(&line.to_string())?;
            }

            // Table 1, left: (A), (B), (C) with in-scattering.
            let lit = request(args.size, reduction, Shading::GlobalLight, scattered);
            renderer.render(&lit)?;
            let a = light_of(&renderer)?;
            renderer.render(&lit)?;
            let b = light_of(&renderer)?;
            renderer.render_converged(&lit)?;
            let (_, c_ms) = timed(args.frames, || renderer.render(&lit))?;
            let (unlit_ms, gradient_ms) = unlit_and_gradient_ms(&mut renderer, &lit, args.frames)?;
            let a_ms = update_ms(&a);
            let mut line = serde_json::json!({
                "bench": "light-table-left",
                "width": args.size,
                "height": args.size,
                "svr_scale": first_svr,
                "svr_dims": svr_dims(dims, first_svr),
                "segment_voxels": args.segment,
                "scatter_radius_voxels": args.scatter_radius,
                "directions": args.directions,
                "frames": args.frames,
                "a_ms": a_ms,
                "a": a,
                "update_total_ms": a.total_ms,
                "a_ms_per_million_kept_voxels": a_ms / (kept_voxels as f64 / 1e6),
                "a_ms_per_million_volume_voxels": a_ms / (volume_voxels as f64 / 1e6),
                "b_ms": b.in_scatter_ms,
                "c_ms": c_ms,
                "unlit_ms": unlit_ms,
                "gradient_ms": gradient_ms,
                "c_over_unlit": c_ms / unlit_ms,
                "c_over_gradient": c_ms / gradient_ms,
                "unlit_512_ms": unlit_512_ms,
                "a_over_unlit_512": a_ms / unlit_512_ms,
            });
            merge(&mut line, &setting);
            merge(&mut line, &adapter);
            say(&line.to_string())?;

            // Table 1, right: (A) per SVR scale and segment length.
            if reduction == args.table_reduction {
                for &svr in &args.svr_scales {
                    for &segment in &args.segments {
                        let start = Instant::now();
                        renderer.render(&request(
                            SMALL_EDGE,
                            reduction,
                            Shading::GlobalLight,
                            unscattered(svr, segment),
                        ))?;
                        let wall_ms = start.elapsed().as_secs_f64() * 1e3;
                        let a = light_of(&renderer)?;
                        let mut line = serde_json::json!({
                            "bench": "light-table-right",
                            "svr_scale": svr,
                            "svr_dims": svr_dims(dims, svr),
                            "segment_voxels": segment,
                            "scatter_radius_voxels": 0.0,
                            "a_ms": update_ms(&a),
                            "a": a,
                            "frame_wall_ms": wall_ms,
                        });
                        merge(&mut line, &setting);
                        merge(&mut line, &adapter);
                        say(&line.to_string())?;
                    }
                }
            }
        }
    }
    Ok(())
}

/// Writes `STEM-METHOD.png`, `STEM-reference.png` and `STEM-delta-e.png`
/// (ΔE*uv per pixel: black at 0, full red at 6 or more) into `dir`.
pub(crate) fn write_images(
    dir: &std::path::Path,
    stem: &str,
    method: &str,
    piecewise: &shaders::Frame,
    reference: &shaders::Frame,
) -> anyhow::Result<()> {
    use anyhow::Context as _;
    std::fs::create_dir_all(dir)
        .with_context(|| format!("--images: cannot create {}", dir.display()))?;
    let delta =
        shaders::colour_difference::per_pixel(piecewise, reference).map_err(anyhow::Error::msg)?;
    let error = shaders::Frame {
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
    renderer: &mut Renderer,
    lit: &FrameRequest,
    frames: u32,
) -> anyhow::Result<(f64, f64)> {
    let mut ms = [0.0; 2];
    for (out, shading) in ms.iter_mut().zip([Shading::Unshaded, Shading::Gradient]) {
        let request = FrameRequest {
            shading,
            ..lit.clone()
        };
        *out = timed(frames, || renderer.render(&request))?.1;
    }
    Ok((ms[0], ms[1]))
}

/// The adapter's name, backend and device type, for every JSON line.
pub(crate) fn adapter_json(gpu: &GpuContext) -> serde_json::Value {
    serde_json::json!({
        "adapter": gpu.info.name,
        "backend": gpu.info.backend.to_string(),
        "device_type": format!("{:?}", gpu.info.device_type),
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
