//! CPU twin of the `raycast` stage (`shaders/wgsl/raycast.wgsl`), loop for loop.
//! Each function here has the name of its WGSL counterpart; [`raycast`] runs
//! `main` for every invocation of the dispatch grid.

use glam::{Mat4, Vec2, Vec3, Vec4, Vec4Swizzles};
use rayon::prelude::*;

use super::Texture3d;
use super::hash::{pcg_hash, unit_from_hash};
use crate::raycast::{FLAG_JITTER, FLAG_SHADED, RaycastParams, WORKGROUP_SIZE};

/// Largest opacity fed to the opacity correction (as in the shader).
const MAX_SAMPLE_OPACITY: f32 = 0.9999;

/// The stage's bindings, in binding order (the sampler, binding 2, is implied by
/// [`Texture3d::sample_level`]).
struct Bindings<'a> {
    params: &'a RaycastParams,
    volume: &'a Texture3d,
    transfer_function: &'a [[f32; 4]],
}

/// Renders into `output` (RGBA8, `params.width * params.height * 4` bytes) exactly
/// as the GPU dispatch of `raycast` does: one call of `main` per invocation.
pub fn raycast(
    params: &RaycastParams,
    volume: &Texture3d,
    transfer_function: &[[f32; 4]],
    output: &mut [u8],
) {
    let b = Bindings {
        params,
        volume,
        transfer_function,
    };
    let width = params.width as usize;
    let (groups_x, _) = params.workgroups();
    output
        .par_chunks_mut(width * 4)
        .enumerate()
        .for_each(|(y, row)| {
            // The dispatch covers whole workgroups; invocations past the image return early.
            for x in 0..groups_x * WORKGROUP_SIZE {
                if let Some(rgba) = main(&b, [x, y as u32]) {
                    row[x as usize * 4..x as usize * 4 + 4].copy_from_slice(&rgba);
                }
            }
        });
}

fn sample_volume(b: &Bindings<'_>, tc: Vec3) -> f32 {
    b.volume.sample_level(tc)
}

fn classify(b: &Bindings<'_>, u: f32) -> Vec4 {
    let n = b.params.tf_len as i32;
    let x = u.clamp(0.0, 1.0) * n as f32 - 0.5;
    let i0f = x.floor();
    let f = x - i0f;
    let i0 = i0f as i32;
    let a = Vec4::from(b.transfer_function[i0.clamp(0, n - 1) as usize]);
    let c = Vec4::from(b.transfer_function[(i0 + 1).clamp(0, n - 1) as usize]);
    a.lerp(c, f)
}

fn gradient(b: &Bindings<'_>, tc: Vec3) -> Vec3 {
    let p = b.params;
    let h = Vec3::from(p.texel);
    let dx = Vec3::new(h.x, 0.0, 0.0);
    let dy = Vec3::new(0.0, h.y, 0.0);
    let dz = Vec3::new(0.0, 0.0, h.z);
    let differences = Vec3::new(
        sample_volume(b, tc + dx) - sample_volume(b, tc - dx),
        sample_volume(b, tc + dy) - sample_volume(b, tc - dy),
        sample_volume(b, tc + dz) - sample_volume(b, tc - dz),
    );
    let per_texture_unit = differences / (2.0 * h);
    let gradient_from_texture = Mat4::from_cols_array_2d(&p.gradient_from_texture);
    (gradient_from_texture * per_texture_unit.extend(0.0)).xyz() * p.value_scale
}

fn shade(b: &Bindings<'_>, rgb: Vec3, tc: Vec3, view_dir: Vec3) -> Vec3 {
    let g = gradient(b, tc);
    let magnitude = g.length();
    if magnitude < b.params.gradient_threshold {
        return rgb;
    }
    let n = g / magnitude;
    let l = Vec3::from(b.params.light_dir);
    let h = (l - view_dir).normalize();
    let diffuse = n.dot(l).abs();
    let specular = n.dot(h).abs().powf(b.params.phong[3]);
    let [ambient, kd, ks, _] = b.params.phong;
    rgb * (ambient + kd * diffuse) + Vec3::splat(ks * specular)
}

fn intersect_box(origin: Vec3, dir: Vec3) -> Vec2 {
    let tiny = dir.abs().cmplt(Vec3::splat(1e-12));
    let safe_dir = Vec3::select(tiny, Vec3::splat(1e-12), dir);
    let inv = 1.0 / safe_dir;
    let t0 = -origin * inv;
    let t1 = (Vec3::ONE - origin) * inv;
    let lo = t0.min(t1);
    let hi = t0.max(t1);
    let enter = lo.x.max(lo.y).max(lo.z.max(0.0));
    let exit = hi.x.min(hi.y).min(hi.z);
    Vec2::new(enter, exit)
}

/// One invocation: the pixel at `gid`, or `None` past the image's edge.
fn main(b: &Bindings<'_>, gid: [u32; 2]) -> Option<[u8; 4]> {
    let p = b.params;
    if gid[0] >= p.width || gid[1] >= p.height {
        return None;
    }
    let pixel = Vec2::new(gid[0] as f32 + 0.5, gid[1] as f32 + 0.5);
    let ndc = Vec2::new(
        pixel.x / p.width as f32 * 2.0 - 1.0,
        1.0 - pixel.y / p.height as f32 * 2.0,
    );
    let inv_view_proj = Mat4::from_cols_array_2d(&p.inv_view_proj);
    let near = inv_view_proj * Vec4::new(ndc.x, ndc.y, 0.0, 1.0);
    let far = inv_view_proj * Vec4::new(ndc.x, ndc.y, 1.0, 1.0);
    let origin = near.xyz() / near.w;
    let dir = (far.xyz() / far.w - origin).normalize();
    let texture_from_model = Mat4::from_cols_array_2d(&p.texture_from_model);
    let tex_origin = (texture_from_model * origin.extend(1.0)).xyz();
    let tex_dir = (texture_from_model * dir.extend(0.0)).xyz();

    let span = intersect_box(tex_origin, tex_dir);
    let mut color = Vec3::ZERO;
    let mut alpha = 0.0f32;
    if span.x < span.y {
        let mut jitter = 0.0;
        if p.flags & FLAG_JITTER != 0 {
            jitter = unit_from_hash(pcg_hash(gid[1] * p.width + gid[0]));
        }
        let exponent = p.step / p.reference_step;
        let mut t = span.x + jitter * p.step;
        for _k in 0..p.max_steps {
            if t > span.y {
                break;
            }
            let tc = tex_origin + tex_dir * t;
            let u = sample_volume(b, tc) * p.value_scale + p.value_offset;
            let rgba = classify(b, u);
            if rgba.w > 0.0 {
                let a = 1.0 - (1.0 - rgba.w.min(MAX_SAMPLE_OPACITY)).powf(exponent);
                let mut rgb = rgba.xyz();
                if p.flags & FLAG_SHADED != 0 {
                    rgb = shade(b, rgb, tc, dir);
                }
                color += (1.0 - alpha) * a * rgb;
                alpha += (1.0 - alpha) * a;
                if alpha >= p.early_termination {
                    break;
                }
            }
            t += p.step;
        }
    }
    let out = color + (1.0 - alpha) * Vec4::from(p.background).xyz();
    let out = out.clamp(Vec3::ZERO, Vec3::ONE);
    // rgba8unorm stores round(v * 255).
    let unorm = |v: f32| (v * 255.0).round() as u8;
    Some([unorm(out.x), unorm(out.y), unorm(out.z), 255])
}
