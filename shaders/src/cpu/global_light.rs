//! CPU twins of the light stages, loop for loop like the WGSL:
//! `local_opacity`, `global_opacity`, `direct_light`, `in_scatter`,
//! `light_seams` and `direct_light_reference` (`shaders/wgsl/*.wgsl`), with the shared helpers of
//! `shared/slot.wgsl`, `shared/light.wgsl` and `shared/light_opacity.wgsl`.
//! Atlas-shaped results are `Vec<f32>` over every atlas texel (x fastest),
//! zero where no block is stored, as the GPU leaves them.

use glam::{Vec3, Vec4Swizzles};
use rayon::prelude::*;
use wide::f32x4;

use std::time::Instant;

use blocks::TransferFunction;
use blocks::packing::Packing;
use blocks::store::grid_position;

use super::full_table;
use super::march::{
    Classes4, TfTable, classify_table, corrected_opacity, corrected_opacity4, intersect_box,
};
use super::packed::{BLOCK, EMPTY_LEVEL, PackedTexture, RayBlocks};
use super::texture::ceil_i32;
use super::{SlotAtlas, Texture3d};
use crate::global_light::update::{LightStages, update_light};
use crate::global_light::{
    DirectLightMethod, LightParams, LightSetup, LightTimings, ScatterDirection, Stage, seam_passes,
};
use crate::illumination::{Refine, StageCache};
use crate::packed_volume::PackedLayout;
use crate::volume_texture::VolumeTexture;
use crate::{FrameRequest, GpuError, LightSettings};

/// A slot that holds no block.
const NO_BLOCK: u32 = u32::MAX;
/// How far past a block's exit `global_opacity` resumes (mm).
const RESUME: f32 = 1e-3;
/// WGSL `OPAQUE`: remaining transparency below which a light ray stops.
const OPAQUE: f32 = 1e-3;

/// WGSL `SlotTexel`: the texel's texture-space position, if it is a stored voxel.
pub fn slot_texel(p: &LightParams, slot_blocks: &[u32], texel: [u32; 3]) -> Option<Vec3> {
    if (0..3).any(|i| texel[i] as f32 >= p.volume.atlas_size[i]) {
        return None;
    }
    let mut first_slot = 0u32;
    for level in 0..5u32 {
        let [sx, sy, sz, z0] = p.regions[level as usize];
        let edge = (16 >> level) + 2;
        let z_end = z0 + sz * edge;
        if texel[2] >= z0 && texel[2] < z_end {
            let slot = [texel[0] / edge, texel[1] / edge, (texel[2] - z0) / edge];
            if slot[0] >= sx || slot[1] >= sy {
                return None;
            }
            let b = slot_blocks[(first_slot + (slot[2] * sy + slot[1]) * sx + slot[0]) as usize];
            if b == NO_BLOCK {
                return None;
            }
            let [gx, gy, _] = p.volume.block_grid;
            let block = Vec3::new(
                (b % gx) as f32,
                ((b / gx) % gy) as f32,
                (b / (gx * gy)) as f32,
            );
            let q = Vec3::new(
                (texel[0] - slot[0] * edge) as f32,
                (texel[1] - slot[1] * edge) as f32,
                (texel[2] - z0 - slot[2] * edge) as f32,
            ) - 1.0;
            let size = (1u32 << level) as f32;
            let pos = block * BLOCK + (q + 0.5) * size;
            return Some((pos / Vec3::from(p.volume.volume_dims)).clamp(Vec3::ZERO, Vec3::ONE));
        }
        first_slot += sx * sy * sz;
    }
    None
}

/// WGSL `LightRay`.
#[derive(Debug, Clone, Copy)]
struct LightRay {
    dir: Vec3,
    length: f32,
}

/// WGSL `ray_along`.
fn ray_along(p: &LightParams, tc0: Vec3, towards: Vec3, limit: f32) -> LightRay {
    let texture_from_model = p.texture_from_model;
    let dir = (texture_from_model * towards.extend(0.0)).xyz();
    let exit = intersect_box(tc0, dir, Vec3::ZERO, Vec3::ONE).y;
    LightRay {
        dir,
        length: exit.min(limit).max(0.0),
    }
}

/// WGSL `towards_light`: unit vector and distance (mm).
fn towards_light(p: &LightParams, tc0: Vec3) -> (Vec3, f32) {
    let light = glam::Vec4::from(p.light);
    if light.w == 0.0 {
        return (light.xyz(), 1e30);
    }
    let model_from_texture = p.model_from_texture;
    let here = (model_from_texture * tc0.extend(1.0)).xyz();
    let d = light.xyz() - here;
    let distance = d.length();
    if distance < 1e-6 {
        return (Vec3::Z, 0.0);
    }
    (d / distance, distance)
}

/// WGSL `light_ray`.
fn light_ray(p: &LightParams, tc0: Vec3) -> LightRay {
    let (towards, distance) = towards_light(p, tc0);
    ray_along(p, tc0, towards, distance)
}

/// WGSL `opacity_at` of a sample whose value is `value`.
#[inline]
fn opacity_of(p: &LightParams, tf: &[[f32; 4]], value: f32) -> f32 {
    let a = classify_table(
        p.volume.tf_len,
        tf,
        value * p.volume.value_scale + p.volume.value_offset,
    )
    .w;
    corrected_opacity(a, p.step / p.volume.reference_step)
}

/// [`opacity_of`] of four samples' values, lane by lane with its
/// arithmetic (the same bits), from `tf`, the table as the march reads it.
#[inline(always)]
fn opacities_of(p: &LightParams, tf: &TfTable, values: [f32; 4]) -> [f32; 4] {
    let us = f32x4::from(values) * f32x4::splat(p.volume.value_scale)
        + f32x4::splat(p.volume.value_offset);
    let a = Classes4::in_table(p.volume.tf_len, us.to_array()).opacity(tf);
    corrected_opacity4(a, p.step / p.volume.reference_step).to_array()
}

/// The ray parameters of samples `i` to `i + 3`, `step` apart, side by
/// side (each `sample · step`, as the loops find one).
#[inline(always)]
fn four_steps(i: u32, step: f32) -> f32x4 {
    f32x4::from([0, 1, 2, 3].map(|j| (i + j) as f32)) * f32x4::splat(step)
}

/// Runs `texel_main` for every texel of a grid of `dims` (as a dispatch of
/// whole workgroups would, skipping invocations past the edge).
fn per_texel(dims: [u32; 3], texel_main: impl Fn([u32; 3]) -> f32 + Sync) -> Vec<f32> {
    let [w, h, d] = dims;
    let mut out = vec![0.0f32; (w * h * d) as usize];
    out.par_chunks_mut((w * h) as usize)
        .enumerate()
        .for_each(|(z, slice)| {
            for y in 0..h {
                for x in 0..w {
                    slice[(y * w + x) as usize] = texel_main([x, y, z as u32]);
                }
            }
        });
    out
}

/// Twin of `local_opacity` (α_lp, eq. 6).
pub fn local_opacity(
    p: &LightParams,
    packed: &PackedTexture,
    tf: &[[f32; 4]],
    slot_blocks: &[u32],
) -> Vec<f32> {
    let g = p.volume;
    let table = full_table(tf).ok();
    per_texel(p.atlas_dims(), |gid| {
        let Some(tc0) = slot_texel(p, slot_blocks, gid) else {
            return 0.0;
        };
        let ray = light_ray(p, tc0);
        let end = p.segment.min(ray.length);
        let mut transparency = 1.0;
        // The block of the last sample, which the next often shares.
        let mut blocks = RayBlocks::new(packed, &g, tc0, ray.dir);
        let mut i = 1;
        while i <= p.max_steps {
            let t = i as f32 * p.step;
            if t > end {
                break;
            }
            let loc = *blocks.at(packed, &g, t);
            // Four samples at once where the loop would take all four in
            // this block (as `in_scatter` reads them).
            let last = (i + 3) as f32 * p.step;
            if let Some(table) = table
                && i + 3 <= p.max_steps
                && last <= end
                && blocks.holds(&g, last)
            {
                if !loc.empty {
                    let at = blocks.slot_positions(four_steps(i, p.step));
                    let values = packed
                        .atlas
                        .sample_slot4(loc.slot, loc.slot_edge, at, None)
                        .unwrap_or_default();
                    for a in opacities_of(p, table, values) {
                        transparency *= 1.0 - a;
                    }
                }
                i += 4;
                continue;
            }
            if !loc.empty {
                let value =
                    packed
                        .atlas
                        .sample_slot(loc.slot, loc.slot_edge, blocks.slot_position(t));
                transparency *= 1.0 - opacity_of(p, tf, value);
            }
            i += 1;
        }
        1.0 - transparency
    })
}

/// Twin of `global_opacity` (α_g, eq. 7): the SVR, `p.svr_dims` points.
/// `index` supplies the block index (its atlas is not read); points in blocks
/// that `svr_blocks` ([`crate::illumination::near_blocks`] for the SVR's margin) marks 0 are left 0.
pub fn global_opacity(
    p: &LightParams,
    local_opacity: &SlotAtlas,
    index: &PackedTexture,
    svr_blocks: &[u32],
) -> Vec<f32> {
    let g = p.volume;
    let svr = Vec3::new(
        p.svr_dims[0] as f32,
        p.svr_dims[1] as f32,
        p.svr_dims[2] as f32,
    );
    let dims = Vec3::from(p.volume.volume_dims);
    let [gx, gy, gz] = p.volume.block_grid;
    per_texel(p.svr_dims, |gid| {
        let tc0 = (Vec3::new(gid[0] as f32, gid[1] as f32, gid[2] as f32) + 0.5) / svr;
        let block = (tc0 * dims / BLOCK)
            .as_uvec3()
            .min(glam::UVec3::new(gx, gy, gz) - 1);
        if svr_blocks
            .get((block.x + gx * (block.y + gy * block.z)) as usize)
            .is_none_or(|&m| m == 0)
        {
            return 0.0;
        }
        let ray = light_ray(p, tc0);
        let mut transparency = 1.0;
        let mut t = 0.0f32;
        // The block of the last segment's end, which the next often shares.
        let mut blocks = RayBlocks::new(index, &g, tc0, ray.dir);
        for _k in 0..p.max_steps {
            if t >= ray.length || transparency < OPAQUE {
                break;
            }
            let loc = *blocks.at(index, &g, t);
            if loc.empty {
                t = t.max(blocks.exit(&g)) + RESUME;
                continue;
            }
            // atlas_coord's texel in the slot (the same eight texels, the
            // same weights up to rounding).
            let a = local_opacity.sample_slot(loc.slot, loc.slot_edge, blocks.slot_position(t));
            transparency *= 1.0 - a;
            t += p.segment;
        }
        1.0 - transparency
    })
}

/// Twin of `direct_light` (I_d, eq. 8).
pub fn direct_light(
    p: &LightParams,
    local_opacity: &Texture3d,
    shadow_volume: &Texture3d,
    slot_blocks: &[u32],
) -> Vec<f32> {
    per_texel(p.atlas_dims(), |gid| {
        let Some(tc0) = slot_texel(p, slot_blocks, gid) else {
            return 0.0;
        };
        let first = local_opacity.load(gid[0] as i32, gid[1] as i32, gid[2] as i32);
        let ray = light_ray(p, tc0);
        let mut rest = 0.0;
        if ray.length > p.segment {
            let s1 = tc0 + ray.dir * p.segment;
            rest = shadow_volume.sample_level(s1);
        }
        p.intensity * (1.0 - rest) * (1.0 - first)
    })
}

/// Twin of `in_scatter` (I_s, eqs. 11, 13): blends this step's light into
/// `light_volume` (atlas-shaped, updated in place).
pub fn in_scatter(
    p: &LightParams,
    packed: &PackedTexture,
    tf: &[[f32; 4]],
    slot_blocks: &[u32],
    direct_light: &Texture3d,
    shadow_volume: &Texture3d,
    light_volume: &mut [f32],
) {
    let g = p.volume;
    let direct_slots = packed.atlas.with_texels_of(direct_light, &packed.index);
    let table = full_table(tf).ok();
    let stored = light_volume.to_vec();
    let [w, h, _] = p.atlas_dims();
    let next = per_texel(p.atlas_dims(), |gid| {
        let index = ((gid[2] * h + gid[1]) * w + gid[0]) as usize;
        let Some(tc0) = slot_texel(p, slot_blocks, gid) else {
            return stored[index];
        };
        let mut light = 0.0;
        if p.scatter_radius <= 0.0 {
            light = direct_light.load(gid[0] as i32, gid[1] as i32, gid[2] as i32);
        } else {
            let mut towards = Vec3::new(
                p.scatter_direction[0],
                p.scatter_direction[1],
                p.scatter_direction[2],
            );
            if p.scatter_direction[3] != 0.0 {
                towards = towards_light(p, tc0).0;
            }
            let ray = ray_along(p, tc0, towards, p.scatter_radius);
            let mut transparency = 1.0;
            let mut i = 0u32;
            // The block of the last sample, which the next often shares.
            let mut blocks = RayBlocks::new(packed, &g, tc0, ray.dir);
            let mut k = 0;
            while k < p.max_steps {
                let t = i as f32 * p.step;
                if t > ray.length || transparency < OPAQUE {
                    break;
                }
                let loc = *blocks.at(packed, &g, t);
                k += 1;
                if loc.empty {
                    i = (i + 1).max(ceil_i32(blocks.exit(&g) / p.step).max(0) as u32);
                    continue;
                }
                // Four samples at once where the loop would take all four in
                // this block: read and classified side by side, composited
                // one by one as below (the same values in the same order).
                let last = (i + 3) as f32 * p.step;
                if let Some(table) = table
                    && k + 3 <= p.max_steps
                    && last <= ray.length
                    && blocks.holds(&g, last)
                {
                    let at = blocks.slot_positions(four_steps(i, p.step));
                    let read = |atlas: &SlotAtlas| {
                        atlas
                            .sample_slot4(loc.slot, loc.slot_edge, at, None)
                            .unwrap_or_default()
                    };
                    let (values, lit) = (read(&packed.atlas), read(&direct_slots));
                    let a = opacities_of(p, table, values);
                    for j in 0..4 {
                        if transparency < OPAQUE {
                            break;
                        }
                        light += transparency * a[j] * lit[j];
                        transparency *= 1.0 - a[j];
                    }
                    i += 4;
                    k += 3;
                    continue;
                }
                // The data and, at atlas_coord's texel in the slot (the same
                // eight texels, the same weights up to rounding), I_d.
                let (value, lit) = packed.atlas.sample_slot_with(
                    &direct_slots,
                    loc.slot,
                    loc.slot_edge,
                    blocks.slot_position(t),
                );
                let a = opacity_of(p, tf, value);
                light += transparency * a * lit;
                transparency *= 1.0 - a;
                i += 1;
            }
            let surface = tc0 + ray.dir * ray.length;
            let beyond = p.intensity * (1.0 - shadow_volume.sample_level(surface));
            light += transparency * beyond;
        }
        p.blend * light + (1.0 - p.blend) * stored[index]
    });
    light_volume.copy_from_slice(&next);
}

/// Twin of `light_seams`: the passes of
/// [`crate::global_light::SEAM_PASSES`] with work to do
/// ([`seam_passes`] of the levels in `packed`'s index) in order over
/// `light_volume` (atlas-shaped, updated in place).
pub fn light_seams(
    p: &LightParams,
    packed: &PackedTexture,
    slot_blocks: &[u32],
    light_volume: &mut [f32],
) {
    let lod: Vec<u8> = packed
        .index
        .iter()
        .map(|e| u8::try_from(e[3]).unwrap_or(blocks::lod::EMPTY))
        .collect();
    for (level, outward) in seam_passes(&lod, packed.grid) {
        light_seams_pass(
            &p.seam_pass(level, outward),
            packed,
            slot_blocks,
            light_volume,
        );
    }
}

/// WGSL `slot_light`: the stored light of the level-`m` slot whose first
/// interior texel is at atlas texel `origin`, filtered at `u`.
fn slot_light(light: &[f32], atlas: [u32; 3], origin: [i32; 3], m: u32, u: Vec3) -> f32 {
    let n = 16i32 >> m;
    let q = u.clamp(Vec3::splat(-1.0), Vec3::splat(n as f32));
    let i0 = q.floor();
    let f = q - i0;
    let i0 = [i0.x as i32, i0.y as i32, i0.z as i32];
    let i1 = i0.map(|i| (i + 1).min(n));
    let load = |k: usize| {
        let t: [i32; 3] =
            [0, 1, 2].map(|a| origin[a] + if k >> a & 1 == 1 { i1[a] } else { i0[a] });
        light[((t[2] as u32 * atlas[1] + t[1] as u32) * atlas[0] + t[0] as u32) as usize]
    };
    let mix = |a: f32, b: f32, t: f32| a * (1.0 - t) + b * t;
    let x = [0, 2, 4, 6].map(|k| mix(load(k), load(k + 1), f.x));
    mix(mix(x[0], x[1], f.y), mix(x[2], x[3], f.y), f.z)
}

/// One `light_seams` dispatch: the pass of `p.seam_level` and `p.seam_outward`.
/// Within a pass no texel reads another the pass writes, so the values are
/// computed first and written after, as the GPU's invocations would.
fn light_seams_pass(
    p: &LightParams,
    packed: &PackedTexture,
    slot_blocks: &[u32],
    light: &mut [f32],
) {
    let level = p.seam_level;
    let region = p.regions[level as usize];
    let edge = (16u32 >> level) + 2;
    let atlas = p.atlas_dims();
    let first_slot: u32 = p.regions[..level as usize]
        .iter()
        .map(|r| r[0] * r[1] * r[2])
        .sum();
    let grid = p.volume.block_grid;
    let read: &[f32] = light;
    // What the WGSL's main writes for invocation `gid`, a texel of `slot`
    // (holding block `b`), if anything. Only apron texels can write and the
    // others return at once, so only the slots' shells are visited below.
    let texel_value = |slot: [u32; 3], b: u32, gid: [u32; 3]| -> Option<(usize, f32)> {
        let block = grid_position(grid, b as usize).map(|v| v as i32);
        let c = [0, 1, 2].map(|a| (gid[a] - slot[a] * edge) as i32);
        let d = c.map(|v| {
            if v == 0 {
                -1
            } else if v == edge as i32 - 1 {
                1
            } else {
                0
            }
        });
        let outward = d.iter().filter(|&&v| v != 0).count() as u32;
        if outward != p.seam_outward {
            return None;
        }
        let n = [0, 1, 2].map(|a| block[a] + d[a]);
        if (0..3).any(|a| n[a] < 0 || n[a] >= grid[a] as i32) {
            return None;
        }
        let entry = packed.index[packed.block_index(n)];
        let m = u32::from(entry[3]);
        if entry[3] == EMPTY_LEVEL || m <= level {
            return None;
        }
        let spacing = (1u32 << level) as f32;
        let border = [0, 1, 2].map(|a| {
            let start = block[a] as f32 * BLOCK;
            match d[a] {
                1 => start + BLOCK,
                -1 => start,
                _ => start + (c[a] as f32 - 0.5) * spacing,
            }
        });
        let u = (Vec3::from(border) - Vec3::new(n[0] as f32, n[1] as f32, n[2] as f32) * BLOCK)
            / (1u32 << m) as f32
            - 0.5;
        let origin = [0, 1, 2].map(|a| i32::from(entry[a]));
        let target = slot_light(read, atlas, origin, m, u);
        let texel = [gid[0], gid[1], gid[2] + region[3]];
        let mut others = 0.0;
        for mask in 1..8usize {
            let step = [0, 1, 2].map(|a| mask >> a & 1 == 1);
            if (0..3).any(|a| step[a] && d[a] == 0) {
                continue;
            }
            let t = [0, 1, 2].map(|a| (texel[a] as i32 - if step[a] { d[a] } else { 0 }) as u32);
            others += read[((t[2] * atlas[1] + t[1]) * atlas[0] + t[0]) as usize];
        }
        let corners = (1u32 << p.seam_outward) as f32;
        let index = ((texel[2] * atlas[1] + texel[1]) * atlas[0] + texel[0]) as usize;
        Some((index, corners * target - others))
    };
    let slots = (region[0] * region[1] * region[2]) as usize;
    let last = edge - 1;
    let writes: Vec<(usize, f32)> = (0..slots)
        .into_par_iter()
        .flat_map_iter(|s| {
            let s = s as u32;
            let slot = [
                s % region[0],
                (s / region[0]) % region[1],
                s / (region[0] * region[1]),
            ];
            let b = slot_blocks[(first_slot + s) as usize];
            let shell = (0..edge).flat_map(move |z| {
                (0..edge).flat_map(move |y| {
                    let inner = z != 0 && z != last && y != 0 && y != last;
                    let step = if inner { last } else { 1 };
                    (0..edge).step_by(step as usize).map(move |x| [x, y, z])
                })
            });
            shell
                .filter(move |_| b != NO_BLOCK)
                .filter_map(move |c| texel_value(slot, b, [0, 1, 2].map(|a| slot[a] * edge + c[a])))
        })
        .collect();
    for (index, value) in writes {
        light[index] = value;
    }
}

/// Twin of `direct_light_reference` (brute-force I_d).
pub fn direct_light_reference(
    p: &LightParams,
    packed: &PackedTexture,
    tf: &[[f32; 4]],
    slot_blocks: &[u32],
) -> Vec<f32> {
    let g = p.volume;
    per_texel(p.atlas_dims(), |gid| {
        let Some(tc0) = slot_texel(p, slot_blocks, gid) else {
            return 0.0;
        };
        let ray = light_ray(p, tc0);
        let mut transparency = 1.0;
        let mut i = 1u32;
        // The block of the last sample, which the next often shares.
        let mut blocks = RayBlocks::new(packed, &g, tc0, ray.dir);
        for _k in 0..p.max_steps {
            let t = i as f32 * p.step;
            if t > ray.length || transparency < OPAQUE {
                break;
            }
            let loc = *blocks.at(packed, &g, t);
            if loc.empty {
                i = (i + 1).max(ceil_i32(blocks.exit(&g) / p.step).max(0) as u32);
                continue;
            }
            let value = packed
                .atlas
                .sample_slot(loc.slot, loc.slot_edge, blocks.slot_position(t));
            transparency *= 1.0 - opacity_of(p, tf, value);
            i += 1;
        }
        p.intensity * transparency
    })
}

/// Every texture of one light computation on the CPU, as the stages leave
/// them: what each stage writes and the later ones read.
#[derive(Debug, Clone, Default)]
pub struct LightState {
    /// α_lp, atlas-shaped.
    pub local_opacity: Vec<f32>,
    /// α_g, the SVR.
    pub shadow_volume: Vec<f32>,
    /// I_d, atlas-shaped.
    pub direct_light: Vec<f32>,
    /// I_s after every direction and `light_seams`, atlas-shaped.
    pub light_volume: Vec<f32>,
}

impl LightState {
    /// What `stage` writes.
    pub fn output(&self, stage: Stage) -> &[f32] {
        match stage {
            Stage::LocalOpacity => &self.local_opacity,
            Stage::GlobalOpacity => &self.shadow_volume,
            Stage::DirectLight => &self.direct_light,
            Stage::InScatter => &self.light_volume,
        }
    }
}

/// What the light stages read besides each other's results.
#[derive(Debug, Clone, Copy)]
pub struct LightInputs<'a> {
    /// The uniforms.
    pub params: &'a LightParams,
    /// The packed data.
    pub packed: &'a PackedTexture,
    /// The transfer-function table.
    pub tf: &'a [[f32; 4]],
    /// [`crate::illumination::slot_blocks`] of the packing.
    pub slot_blocks: &'a [u32],
    /// [`crate::illumination::near_blocks`] for the SVR's margin.
    pub svr_blocks: &'a [u32],
    /// The in-scattering directions, in order.
    pub directions: &'a [ScatterDirection],
    /// How I_d is computed.
    pub method: DirectLightMethod,
}

/// Runs `stage`'s twin, reading the earlier stages' results from `state` and
/// writing its own there (in-scattering: every direction, converged).
pub fn run(stage: Stage, inputs: &LightInputs<'_>, state: &mut LightState) {
    let p = inputs.params;
    let atlas = p.atlas_dims();
    let local = || Texture3d::new(atlas, state.local_opacity.clone());
    let shadow = || Texture3d::new(p.svr_dims, state.shadow_volume.clone());
    match (stage, inputs.method) {
        (Stage::LocalOpacity, _) => {
            state.local_opacity = local_opacity(p, inputs.packed, inputs.tf, inputs.slot_blocks);
        }
        (Stage::GlobalOpacity, _) => {
            let local = inputs
                .packed
                .atlas
                .with_texels_of(&local(), &inputs.packed.index);
            state.shadow_volume = global_opacity(p, &local, inputs.packed, inputs.svr_blocks);
        }
        (Stage::DirectLight, DirectLightMethod::Piecewise) => {
            state.direct_light = direct_light(p, &local(), &shadow(), inputs.slot_blocks);
        }
        (Stage::DirectLight, DirectLightMethod::Reference) => {
            state.direct_light =
                direct_light_reference(p, inputs.packed, inputs.tf, inputs.slot_blocks);
        }
        (Stage::InScatter, _) => {
            state.light_volume = vec![0.0f32; state.direct_light.len()];
            for d in inputs.directions {
                scatter_step(inputs, state, d);
            }
        }
    }
}

/// One in-scattering step as the GPU update runs it: `in_scatter` along
/// `direction` into `state.light_volume`, then `light_seams`.
pub fn scatter_step(
    inputs: &LightInputs<'_>,
    state: &mut LightState,
    direction: &ScatterDirection,
) {
    let p = inputs.params;
    // I_d and the SVR lent as textures for the step and given back: a step
    // runs every frame of a still view, too often to copy them.
    let direct = Texture3d::new(p.atlas_dims(), std::mem::take(&mut state.direct_light));
    let shadow = Texture3d::new(p.svr_dims, std::mem::take(&mut state.shadow_volume));
    in_scatter(
        &p.scattering(direction),
        inputs.packed,
        inputs.tf,
        inputs.slot_blocks,
        &direct,
        &shadow,
        &mut state.light_volume,
    );
    light_seams(
        p,
        inputs.packed,
        inputs.slot_blocks,
        &mut state.light_volume,
    );
    state.direct_light = direct.into_texels();
    state.shadow_volume = shadow.into_texels();
}

/// The whole light computation as [`crate::global_light::GlobalLight`] runs
/// it, converged: every stage of [`Stage::ALL`] in order.
pub fn compute_light(inputs: &LightInputs<'_>) -> LightState {
    let mut state = LightState::default();
    for stage in Stage::ALL {
        run(stage, inputs, &mut state);
    }
    state
}

/// What the CPU renderer's light stages read besides the settings.
#[derive(Debug, Clone, Copy)]
pub struct CpuLightInputs<'a> {
    /// How voxels become texels.
    pub desc: &'a VolumeTexture,
    /// The resident blocks' packing and its sizes.
    pub packing: &'a Packing,
    /// The atlas's sizes.
    pub layout: PackedLayout,
    /// The packed data.
    pub packed: &'a PackedTexture,
    /// The transfer-function table.
    pub tf: &'a [[f32; 4]],
}

/// Global light on the CPU renderer, brought up to date frame by frame under
/// the policy the GPU's [`crate::global_light::GlobalLight`] follows
/// ([`update_light`]): a change recomputes from the first stage it affects
/// with one in-scattering direction (update A), each later frame that asks
/// for it blends one more direction in (B), a still image all of them.
#[derive(Debug, Default)]
pub struct CpuGlobalLight {
    cache: StageCache,
    state: LightState,
    setup: Option<LightSetup>,
    method: DirectLightMethod,
    refined: usize,
}

impl CpuGlobalLight {
    /// Brings the light up to date for `request` over the resident data of
    /// `data_version` classified by `tf`, as far as `refine` says.
    pub fn update(
        &mut self,
        inputs: CpuLightInputs<'_>,
        request: &FrameRequest,
        data_version: u64,
        tf: &TransferFunction,
        refine: Refine,
    ) -> Result<LightTimings, GpuError> {
        let keys = StageCache::keys_of(&Stage::NAMES, &request.light, data_version, tf);
        update_light(self, inputs, keys, &request.light, refine)
    }

    /// The stored light I_s, atlas-shaped (what the lit ray caster reads).
    pub fn light_volume(&self) -> &[f32] {
        &self.state.light_volume
    }
}

impl LightStages for CpuGlobalLight {
    type Inputs<'a> = CpuLightInputs<'a>;

    fn cache(&mut self) -> &mut StageCache {
        &mut self.cache
    }

    fn refinement(&self) -> (usize, usize) {
        let directions = self.setup.as_ref().map_or(0, |s| s.directions.len());
        (self.refined, directions)
    }

    fn prepare(
        &mut self,
        inputs: CpuLightInputs<'_>,
        settings: &LightSettings,
    ) -> Result<bool, GpuError> {
        let setup = LightSetup::new(
            inputs.desc,
            settings,
            inputs.packing,
            inputs.layout,
            inputs.tf.len() as u32,
        );
        let (new, old) = (&setup.params, self.setup.as_ref().map(|s| &s.params));
        let fits = old.is_some_and(|old| {
            old.atlas_dims() == new.atlas_dims() && old.svr_dims == new.svr_dims
        });
        self.method = settings.method;
        self.setup = Some(setup);
        if !fits {
            self.state = LightState::default();
        }
        Ok(!fits)
    }

    fn run(&mut self, inputs: CpuLightInputs<'_>, stage: Stage) -> Result<f64, GpuError> {
        if stage == Stage::InScatter {
            self.refined = 0;
            self.state.light_volume = vec![0.0; self.state.direct_light.len()];
            return self.scatter_step(inputs);
        }
        let start = Instant::now();
        let setup = self
            .setup
            .as_ref()
            .ok_or_else(|| GpuError::InvalidRequest("the light was not prepared".into()))?;
        let twin = setup.twin_inputs(inputs.packed, inputs.tf, self.method);
        run(stage, &twin, &mut self.state);
        Ok(start.elapsed().as_secs_f64() * 1e3)
    }

    fn scatter_step(&mut self, inputs: CpuLightInputs<'_>) -> Result<f64, GpuError> {
        let start = Instant::now();
        let Some(setup) = &self.setup else {
            return Ok(0.0);
        };
        let Some(direction) = setup.directions.get(self.refined) else {
            return Ok(0.0);
        };
        let twin = setup.twin_inputs(inputs.packed, inputs.tf, self.method);
        scatter_step(&twin, &mut self.state, direction);
        self.refined += 1;
        Ok(start.elapsed().as_secs_f64() * 1e3)
    }
}

#[cfg(test)]
mod tests {
    use blocks::transfer_function::TABLE_LEN;

    use super::super::full_table;
    use super::{opacities_of, opacity_of};
    use crate::global_light::LightParams;

    #[test]
    fn four_opacities_at_once_are_each_the_bits_of_one() {
        // An uneven table, values below, across and above its domain, and
        // steps that take each of `corrected_opacity`'s ways (1, ½ and
        // other exponents): every lane must be `opacity_of`'s value.
        let mut p: LightParams = bytemuck::Zeroable::zeroed();
        p.volume.tf_len = TABLE_LEN as u32;
        p.volume.value_scale = 1.3 / 65535.0;
        p.volume.value_offset = -0.1;
        p.volume.reference_step = 1.0;
        let tf: Vec<[f32; 4]> = (0..TABLE_LEN)
            .map(|i| {
                let x = i as f32 / TABLE_LEN as f32;
                [x, 1.0 - x, 0.5, (x * 37.3).sin().abs()]
            })
            .collect();
        let table = full_table(&tf).expect("a full table");
        for step in [1.0, 0.5, 0.37, 2.0] {
            p.step = step;
            for k in 0..5_000u32 {
                let values = [0, 1, 2, 3].map(|j| ((k * 4 + j) as f32 * 7.77) % 70_000.0 - 1_000.0);
                let four = opacities_of(&p, table, values);
                for j in 0..4 {
                    let one = opacity_of(&p, &tf, values[j]);
                    assert_eq!(
                        four[j].to_bits(),
                        one.to_bits(),
                        "value {} at step {step}",
                        values[j]
                    );
                }
            }
        }
    }
}
