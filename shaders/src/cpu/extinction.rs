//! CPU twins of the extinction-based illumination stages
//! (`shaders/wgsl/extinction_sat.wgsl`, `ambient_occlusion.wgsl`,
//! `ambient_occlusion_reference.wgsl`, `soft_shadow.wgsl`, `shadow_ray.wgsl`,
//! and `shared/sat.wgsl`, `shared/extinction_light.wgsl`), loop for loop.
//! Grid-shaped outputs are RGBA per cell, x fastest, rounded through f16 as the
//! GPU's rgba16float textures store them.

use glam::{IVec3, Vec3, Vec4, Vec4Swizzles};
use rayon::prelude::*;

use std::time::Instant;

use blocks::TransferFunction;

use super::ColourTexture;
use super::march::{MAX_SAMPLE_OPACITY, classify_table};
use super::packed::{BlockLocation, PackedTexture};
use super::texture::{ceil_i32, floor, floor_i32, floor3};
use crate::GpuError;
use crate::extinction::update::{ExtinctionStages, update_extinction};
use crate::extinction::{
    AoMethod, ExtinctionParams, ExtinctionSettings, ExtinctionTimings, FIXED_ONE, LightUniform,
    MAX_CELL_DEPTH, MAX_CONE_CUBOIDS, ShadowMethod, Stage,
};
use crate::illumination::StageCache;

/// The most samples of one shadow ray (WGSL `MAX_RAY_STEPS`).
const MAX_RAY_STEPS: u32 = 8192;

/// The summed-area table: per channel (τ, τ·R, τ·G, τ·B) 64-bit fixed-point
/// sums, x fastest (WGSL `sat_tau`, `sat_r`, `sat_g`, `sat_b`).
#[derive(Debug, Clone)]
pub struct Sat {
    /// Cells along x, y, z.
    pub grid: [u32; 3],
    /// Channels in use (1 or 4).
    pub channels: u32,
    /// The channels; unused ones are empty.
    pub data: [Vec<u64>; 4],
}

impl Sat {
    /// WGSL `sat_index`.
    #[inline(always)]
    fn index(&self, c: IVec3) -> usize {
        let g = self.grid;
        ((c.z as u32 * g[1] + c.y as u32) * g[0] + c.x as u32) as usize
    }

    /// WGSL `sat_at`.
    #[inline(always)]
    pub fn at(&self, c: IVec3, ch: usize) -> u64 {
        if c.cmplt(IVec3::ZERO).any() {
            return 0;
        }
        self.data[ch][self.index(c)]
    }

    /// WGSL `cuboid_sum`: the exact sum over cells lo..=hi, clamped to the grid.
    #[inline(always)]
    pub fn cuboid_sum(&self, lo_in: IVec3, hi_in: IVec3, ch: usize) -> u64 {
        let lo = lo_in.max(IVec3::ZERO) - IVec3::ONE;
        let last = IVec3::new(
            self.grid[0] as i32 - 1,
            self.grid[1] as i32 - 1,
            self.grid[2] as i32 - 1,
        );
        let hi = hi_in.min(last);
        if hi.cmple(lo).any() {
            return 0;
        }
        let s = |x: i32, y: i32, z: i32| self.at(IVec3::new(x, y, z), ch);
        let plus = s(hi.x, hi.y, hi.z)
            .wrapping_add(s(lo.x, lo.y, hi.z))
            .wrapping_add(s(lo.x, hi.y, lo.z))
            .wrapping_add(s(hi.x, lo.y, lo.z));
        let minus = s(lo.x, hi.y, hi.z)
            .wrapping_add(s(hi.x, lo.y, hi.z))
            .wrapping_add(s(hi.x, hi.y, lo.z))
            .wrapping_add(s(lo.x, lo.y, lo.z));
        plus.wrapping_sub(minus)
    }
}

/// WGSL `depth_of`: a fixed-point sum as Δt·τ.
pub fn depth_of(v: u64) -> f32 {
    let (lo, hi) = (v as u32, (v >> 32) as u32);
    (hi as f32 * 4_294_967_296.0 + lo as f32) / FIXED_ONE
}

/// WGSL `fixed_of`: a cell's Δt·τ in fixed point.
pub fn fixed_of(depth: f32) -> u64 {
    // WGSL's f32 → u32 conversion saturates like Rust's `as`.
    u64::from((depth * FIXED_ONE + 0.5) as u32)
}

/// Index of grid cell `c` (x fastest).
fn cell_index(grid: [u32; 3], c: [u32; 3]) -> usize {
    ((c[2] * grid[1] + c[1]) * grid[0] + c[0]) as usize
}

/// Every cell of `grid` in index order, for per-cell stages.
fn cells(grid: [u32; 3]) -> impl ParallelIterator<Item = [u32; 3]> {
    let [gx, gy, gz] = grid;
    (0..gx * gy * gz)
        .into_par_iter()
        .map(move |i| [i % gx, (i / gx) % gy, i / (gx * gy)])
}

/// As an rgba16float texel stores it.
fn f16_round(v: Vec4) -> [f32; 4] {
    v.to_array().map(|x| half::f16::from_f32(x).to_f32())
}

/// WGSL `extinction_sat`, both entry points: `reconstruct` over every cell,
/// then `scan` along x, y and z. Returns the SAT and the extinction texture
/// (Δt·τ per cell).
pub fn extinction_sat(
    p: &ExtinctionParams,
    packed: &PackedTexture,
    transfer_function: &[[f32; 4]],
) -> (Sat, Vec<f32>) {
    let g = p.volume;
    let grid = p.grid;
    let gridf = Vec3::new(grid[0] as f32, grid[1] as f32, grid[2] as f32);
    let n = p.sub as f32;
    // A sample no value of which the transfer function makes visible adds
    // nothing (its Δt·τ is 0): it is not read.
    let visible = packed.visible_texels.as_deref();
    // CPU only: a sample's texture coordinate along an axis depends on its
    // cell's and its own index along that axis alone: each is computed
    // once (by the shader's operations), `sub` per cell.
    let sub = p.sub as usize;
    let along = [0, 1, 2].map(|axis| {
        (0..grid[axis])
            .flat_map(|c| (0..p.sub).map(move |x| (c as f32 + (x as f32 + 0.5) / n) / gridf[axis]))
            .collect::<Vec<f32>>()
    });
    let reconstructed: Vec<Vec4> = cells(grid)
        .map(|gid| {
            let mut sum = Vec4::ZERO;
            let mut last: Option<BlockLocation> = None;
            let [ax, ay, az] = [0, 1, 2].map(|axis| {
                let first = gid[axis] as usize * sub;
                &along[axis][first..first + sub]
            });
            for &tz in az {
                for &ty in ay {
                    for &tx in ax {
                        let tc = Vec3::new(tx, ty, tz);
                        // The block of the sample before, which this one
                        // often shares, is not looked up again.
                        let loc = match &last {
                            Some(last) => packed.locate_near(&g, tc, last),
                            None => packed.locate(&g, tc),
                        };
                        last = Some(loc);
                        if loc.empty {
                            continue;
                        }
                        if let Some(value) =
                            packed.atlas.sample_block_visible(&g, tc, &loc, visible)
                        {
                            let rgba = classify_table(
                                p.volume.tf_len,
                                transfer_function,
                                value * p.volume.value_scale + p.volume.value_offset,
                            );
                            let depth =
                                -(1.0 - rgba.w.min(MAX_SAMPLE_OPACITY)).ln() * p.opacity_scale;
                            sum += Vec4::new(depth, depth * rgba.x, depth * rgba.y, depth * rgba.z);
                        }
                    }
                }
            }
            (sum / (n * n * n)).min(Vec4::splat(MAX_CELL_DEPTH))
        })
        .collect();
    let extinction: Vec<f32> = reconstructed.par_iter().map(|c| c.x).collect();
    let channels = p.channels as usize;
    let mut data: [Vec<u64>; 4] = Default::default();
    for (ch, out) in data.iter_mut().enumerate().take(channels) {
        *out = reconstructed.par_iter().map(|c| fixed_of(c[ch])).collect();
    }
    for axis in 0..3 {
        scan(grid, axis, &mut data[..channels]);
    }
    (
        Sat {
            grid,
            channels: p.channels,
            data,
        },
        extinction,
    )
}

/// WGSL `scan`: the inclusive prefix sum along `axis`, every line (the same
/// wrapping sums, run over whole rows and slices at once so the reads are
/// contiguous, rows or slices in parallel).
fn scan(grid: [u32; 3], axis: usize, channels: &mut [Vec<u64>]) {
    let [gx, gy, _] = grid.map(|n| n as usize);
    let add = |into: &mut [u64], from: &[u64]| {
        for (a, b) in into.iter_mut().zip(from) {
            *a = a.wrapping_add(*b);
        }
    };
    for data in channels {
        match axis {
            0 => data.par_chunks_mut(gx.max(1)).for_each(|row| {
                let mut run = 0u64;
                for v in row {
                    run = run.wrapping_add(*v);
                    *v = run;
                }
            }),
            1 => data.par_chunks_mut((gx * gy).max(1)).for_each(|slice| {
                for y in 1..gy {
                    let (before, rest) = slice.split_at_mut(y * gx);
                    add(&mut rest[..gx], &before[(y - 1) * gx..]);
                }
            }),
            _ => {
                let n = (gx * gy).max(1);
                for z in 1..data.len() / n {
                    let (before, rest) = data.split_at_mut(z * n);
                    let previous = &before[(z - 1) * n..];
                    rest[..n]
                        .par_chunks_mut(4096)
                        .zip(previous.par_chunks(4096))
                        .for_each(|(into, from)| add(into, from));
                }
            }
        }
    }
}

/// A one-channel SAT of fixed-point `cells` (x fastest) by the twin's scans.
pub fn sat_from_cells(grid: [u32; 3], cells: &[u64]) -> Sat {
    let mut data: [Vec<u64>; 4] = Default::default();
    data[0] = cells.to_vec();
    for axis in 0..3 {
        scan(grid, axis, &mut data[..1]);
    }
    Sat {
        grid,
        channels: 1,
        data,
    }
}

/// WGSL `cell_is_read` (`shared/near_cells.wgsl`).
pub fn cell_is_read(p: &ExtinctionParams, near_blocks: &[u32], c: IVec3) -> bool {
    let grid = Vec3::new(p.grid[0] as f32, p.grid[1] as f32, p.grid[2] as f32);
    let tc = (c.as_vec3() + 0.5) / grid;
    let g = p.volume.block_grid;
    let last = IVec3::new(g[0] as i32 - 1, g[1] as i32 - 1, g[2] as i32 - 1);
    let b = floor3(tc * Vec3::from(p.volume.volume_dims) / super::packed::BLOCK)
        .as_ivec3()
        .clamp(IVec3::ZERO, last);
    near_blocks[(b.x as u32 + g[0] * (b.y as u32 + g[1] * b.z as u32)) as usize] != 0
}

/// [`cell_is_read`] for the cells of a grid, by the same arithmetic: a
/// cell's block along each axis depends on its coordinate along that axis
/// alone, so the blocks are found once per axis, not per cell.
struct ReadCells<'a> {
    near_blocks: &'a [u32],
    /// Per axis, the block of each cell coordinate.
    blocks: [Vec<u32>; 3],
    block_grid: [u32; 3],
}

impl<'a> ReadCells<'a> {
    fn new(p: &ExtinctionParams, near_blocks: &'a [u32]) -> ReadCells<'a> {
        let g = p.volume.block_grid;
        let blocks = [0, 1, 2].map(|axis| {
            (0..p.grid[axis])
                .map(|c| {
                    let tc = (c as f32 + 0.5) / p.grid[axis] as f32;
                    let b = floor(tc * p.volume.volume_dims[axis] / super::packed::BLOCK);
                    (b as i32).clamp(0, g[axis] as i32 - 1) as u32
                })
                .collect()
        });
        ReadCells {
            near_blocks,
            blocks,
            block_grid: g,
        }
    }

    /// Whether cell `c` is read.
    #[inline(always)]
    fn holds(&self, c: [u32; 3]) -> bool {
        let [bx, by, bz] = [0, 1, 2].map(|axis| self.blocks[axis][c[axis] as usize]);
        let g = self.block_grid;
        self.near_blocks[(bx + g[0] * (by + g[1] * bz)) as usize] != 0
    }
}

/// WGSL `ambient_occlusion`: I_AO per cell (rgb, a: grey).
pub fn ambient_occlusion(p: &ExtinctionParams, sat: &Sat, near_blocks: &[u32]) -> Vec<[f32; 4]> {
    let colour = p.channels == 4;
    let read = ReadCells::new(p, near_blocks);
    cells(p.grid)
        .map(|gid| {
            let c = IVec3::new(gid[0] as i32, gid[1] as i32, gid[2] as i32);
            if !read.holds(gid) {
                return [1.0; 4];
            }
            let mut inner = [sat.cuboid_sum(c, c, 0), 0, 0, 0];
            if colour {
                for (ch, v) in inner.iter_mut().enumerate().skip(1) {
                    *v = sat.cuboid_sum(c, c, ch);
                }
            }
            let mut depth = Vec4::ZERO;
            for i in 0..p.ao_shells {
                let (row, col) = (i as usize / 4, i as usize % 4);
                let r = p.shell_radii[row][col] as i32;
                let w = p.shell_weights[row][col];
                let lo = c - IVec3::splat(r);
                let hi = c + IVec3::splat(r);
                let tau = sat.cuboid_sum(lo, hi, 0);
                depth.x += depth_of(tau.wrapping_sub(inner[0])) * w;
                inner[0] = tau;
                if colour {
                    for ch in 1..4 {
                        let sum = sat.cuboid_sum(lo, hi, ch);
                        depth[ch] += depth_of(sum.wrapping_sub(inner[ch])) * w;
                        inner[ch] = sum;
                    }
                }
            }
            let k = p.ao_strength / p.ao_norm;
            let grey = (-k * depth.x).exp();
            let mut out = Vec4::splat(grey);
            if colour {
                let bleed = (Vec3::splat(depth.x) - depth.yzw()).max(Vec3::ZERO);
                out = (-k * bleed).exp().extend(grey);
            }
            f16_round(out)
        })
        .collect()
}

/// WGSL `ambient_occlusion_reference`: I_AO by explicit sampling of the sphere.
pub fn ambient_occlusion_reference(
    p: &ExtinctionParams,
    extinction: &[f32],
    near_blocks: &[u32],
) -> Vec<[f32; 4]> {
    let grid = p.grid;
    let read = ReadCells::new(p, near_blocks);
    cells(grid)
        .map(|gid| {
            let c = IVec3::new(gid[0] as i32, gid[1] as i32, gid[2] as i32);
            if !read.holds(gid) {
                return [1.0; 4];
            }
            let r = p.ao_radius as i32;
            let r2 = r * r;
            let last = IVec3::new(grid[0] as i32, grid[1] as i32, grid[2] as i32) - 1;
            let mut depth = 0.0f32;
            for z in -r..=r {
                for y in -r..=r {
                    for x in -r..=r {
                        let d2 = x * x + y * y + z * z;
                        let q = c + IVec3::new(x, y, z);
                        if d2 == 0 || d2 > r2 || q.cmplt(IVec3::ZERO).any() || q.cmpgt(last).any() {
                            continue;
                        }
                        let at = cell_index(grid, [q.x as u32, q.y as u32, q.z as u32]);
                        depth += extinction[at] / d2 as f32;
                    }
                }
            }
            let grey = (-p.ao_strength * depth / p.ao_norm).exp();
            f16_round(Vec4::splat(grey))
        })
        .collect()
}

/// WGSL `towards`.
fn towards(light: &LightUniform, p: Vec3) -> Vec3 {
    let position = Vec4::from(light.position);
    if position.w == 0.0 {
        return position.xyz();
    }
    position.xyz() - p
}

/// WGSL `smoothstep`.
fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// WGSL `light_factor`.
fn light_factor(light: &LightUniform, p: Vec3) -> f32 {
    if light.colour[3] < -1.0 || light.position[3] == 0.0 {
        return 1.0;
    }
    let d = p - Vec4::from(light.position).xyz();
    let distance = d.length();
    if distance < 1e-6 {
        return 1.0;
    }
    let c = (d / distance).dot(Vec4::from(light.spot).xyz());
    smoothstep(light.colour[3], light.spot[3], c)
}

/// The cone of WGSL `occlusion_depth` (`soft_shadow`) from a cell towards a
/// light: its main axis `a` (the other two `b` and `e`), which way it runs
/// along it, its slope per cell along `a` and how far it may go.
#[derive(Debug, Clone, Copy)]
struct Cone {
    a: usize,
    b: usize,
    e: usize,
    sign: i32,
    slope: Vec3,
    slant: f32,
    d_end: f32,
}

impl Cone {
    /// The cone from the cell centred at `pos` towards `light`; `None` where
    /// the light is at the cell (its depth is 0).
    #[inline(always)]
    fn towards(light: &LightUniform, pos: Vec3) -> Option<Cone> {
        let v = towards(light, pos);
        let av = v.abs();
        let mut a = 0usize;
        if av.y > av[a] {
            a = 1;
        }
        if av.z > av[a] {
            a = 2;
        }
        let va = av[a];
        if va < 1e-6 {
            return None;
        }
        let mut d_end = 1e9f32;
        if light.position[3] != 0.0 {
            d_end = va;
        }
        Some(Cone {
            a,
            b: (a + 1) % 3,
            e: (a + 2) % 3,
            sign: if v[a] >= 0.0 { 1 } else { -1 },
            slope: v / va,
            slant: v.length() / va,
            d_end,
        })
    }

    /// The cone's cuboids in order, as WGSL `occlusion_depth`'s loop steps
    /// through them: what of each is the same for every cell (the loop
    /// stops earlier where a cuboid leaves the grid).
    #[inline(always)]
    fn cuboids<'a>(&'a self, p: &'a ExtinctionParams) -> impl Iterator<Item = Cuboid> + 'a {
        let (mut prev, mut dist, mut spacing) = (0i32, 0.0f32, p.cone_first);
        (0..MAX_CONE_CUBOIDS).map_while(move |_| {
            dist += spacing;
            spacing *= 1.0 + p.cone_growth;
            let start = prev + 1;
            if start as f32 > self.d_end {
                return None;
            }
            let end = floor_i32(dist + 0.5).max(start).min(floor_i32(self.d_end));
            let mid = 0.5 * (start as f32 + end as f32);
            prev = end;
            Some(Cuboid {
                start,
                end,
                half_width: mid * self.slant * p.cone_tan + 0.5,
                along_b: self.slope[self.b] * mid,
                along_e: self.slope[self.e] * mid,
                length: (end - start + 1) as f32,
            })
        })
    }

    /// CPU only: [`Cone::cuboids`] up to the first that starts past the
    /// grid along the cone's axis, where every cell's loop has stopped: for
    /// a cone that is the same from every cell (a directional light's).
    fn cuboids_in_grid(&self, p: &ExtinctionParams) -> Vec<Cuboid> {
        let extent = p.grid[self.a] as i32;
        self.cuboids(p).take_while(|q| q.start <= extent).collect()
    }
}

/// One cuboid of a [`Cone`], relative to the cone's cell: cells `start` to
/// `end` along its axis, centred `along_b` and `along_e` off the cell's
/// centre, `half_width` (plus half a cell) wide.
#[derive(Debug, Clone, Copy)]
struct Cuboid {
    start: i32,
    end: i32,
    half_width: f32,
    along_b: f32,
    along_e: f32,
    length: f32,
}

/// WGSL `occlusion_depth` of `soft_shadow` at cell `c` through the cone's
/// `cuboids`.
#[inline(always)]
fn cone_depth(
    p: &ExtinctionParams,
    sat: &Sat,
    cone: &Cone,
    cuboids: impl Iterator<Item = Cuboid>,
    c: IVec3,
) -> f32 {
    let Cone {
        a,
        b,
        e,
        sign,
        slope,
        slant,
        ..
    } = *cone;
    let pos = c.as_vec3() + 0.5;
    let last = IVec3::new(p.grid[0] as i32, p.grid[1] as i32, p.grid[2] as i32) - 1;
    // CPU only: a cuboid beside the grid along b or e whose side moves away
    // from it faster than the cone widens has no later cuboid in the grid
    // either; they all add 0, so the cone ends there. (Its side moves by at
    // least a thousandth of a cell per cuboid, far more than rounding moves
    // it, so no later one comes back.)
    let widening = slant * p.cone_tan + 1e-3;
    let leaves = |lo: IVec3, hi: IVec3, axis: usize| {
        (lo[axis] > last[axis] && slope[axis] > widening)
            || (hi[axis] < 0 && slope[axis] < -widening)
    };
    let mut depth = 0.0f32;
    for q in cuboids {
        let m0 = c[a] + sign * q.start;
        let m1 = c[a] + sign * q.end;
        let mut lo = IVec3::ZERO;
        let mut hi = IVec3::ZERO;
        lo[a] = m0.min(m1);
        hi[a] = m0.max(m1);
        if hi[a] < 0 || lo[a] > last[a] {
            break;
        }
        let (cb, ce) = (pos[b] + q.along_b, pos[e] + q.along_e);
        lo[b] = floor_i32(cb - q.half_width);
        hi[b] = (ceil_i32(cb + q.half_width) - 1).max(lo[b]);
        lo[e] = floor_i32(ce - q.half_width);
        hi[e] = (ceil_i32(ce + q.half_width) - 1).max(lo[e]);
        if leaves(lo, hi, b) || leaves(lo, hi, e) {
            break;
        }
        let size = (hi - lo + IVec3::ONE).as_vec3();
        let volume = size.x * size.y * size.z;
        depth += depth_of(sat.cuboid_sum(lo, hi, 0)) / volume * q.length * slant;
    }
    depth
}

/// WGSL `light_cache_fill` (the entry point of `soft_shadow` and
/// `shadow_ray`): the light cache with `occlusion_depth` per light and cell.
fn fill_cache(
    p: &ExtinctionParams,
    ambient: &[[f32; 4]],
    near_blocks: &[u32],
    occlusion_depth: impl Fn(usize, &LightUniform, IVec3) -> f32 + Sync,
) -> Vec<[f32; 4]> {
    let lights = &p.lights[..p.light_count as usize];
    let read = ReadCells::new(p, near_blocks);
    cells(p.grid)
        .map(|gid| {
            let c = IVec3::new(gid[0] as i32, gid[1] as i32, gid[2] as i32);
            if !read.holds(gid) {
                return [0.0; 4];
            }
            let pos = c.as_vec3() + 0.5;
            let mut light = p.ambient * Vec4::from(ambient[cell_index(p.grid, gid)]).xyz();
            for (i, source) in lights.iter().enumerate() {
                let f = light_factor(source, pos);
                if f > 0.0 {
                    light += Vec4::from(source.colour).xyz()
                        * f
                        * (-occlusion_depth(i, source, c)).exp();
                }
            }
            f16_round(light.extend(1.0))
        })
        .collect()
}

/// WGSL `soft_shadow`: the light cache (ambient plus every light through its cone).
pub fn soft_shadow(
    p: &ExtinctionParams,
    sat: &Sat,
    ambient: &[[f32; 4]],
    near_blocks: &[u32],
) -> Vec<[f32; 4]> {
    // CPU only: a directional light's cone is the same from every cell
    // (`towards` does not depend on the cell), so its cuboids are stepped
    // through once.
    let lights = &p.lights[..p.light_count as usize];
    let parallel: Vec<Option<(Cone, Vec<Cuboid>)>> = lights
        .iter()
        .map(|light| {
            if light.position[3] != 0.0 {
                return None;
            }
            let cone = Cone::towards(light, Vec3::ZERO)?;
            Some((cone, cone.cuboids_in_grid(p)))
        })
        .collect();
    fill_cache(p, ambient, near_blocks, |i, light, c| match &parallel[i] {
        Some((cone, cuboids)) => cone_depth(p, sat, cone, cuboids.iter().copied(), c),
        None if light.position[3] == 0.0 => 0.0,
        None => match Cone::towards(light, c.as_vec3() + 0.5) {
            Some(cone) => cone_depth(p, sat, &cone, cone.cuboids(p), c),
            None => 0.0,
        },
    })
}

/// WGSL `occlusion_depth` of `shadow_ray`.
fn ray_depth(p: &ExtinctionParams, extinction: &[f32], light: &LightUniform, pos: Vec3) -> f32 {
    let v = towards(light, pos);
    let distance = v.length();
    let va = v.abs().max_element();
    if va < 1e-6 {
        return 0.0;
    }
    let dir = v / distance;
    let mut t_end = 1e9f32;
    if light.position[3] != 0.0 {
        t_end = distance;
    }
    let last = IVec3::new(p.grid[0] as i32, p.grid[1] as i32, p.grid[2] as i32) - 1;
    let mut depth = 0.0f32;
    let mut t = 0.5 * distance / va + 0.5 * p.ray_step;
    for _k in 0..MAX_RAY_STEPS {
        if t > t_end {
            break;
        }
        let cell = floor3(pos + dir * t).as_ivec3();
        if cell.cmplt(IVec3::ZERO).any() || cell.cmpgt(last).any() {
            break;
        }
        let at = cell_index(p.grid, [cell.x as u32, cell.y as u32, cell.z as u32]);
        depth += extinction[at] * p.ray_step;
        t += p.ray_step;
    }
    depth
}

/// WGSL `shadow_ray`: the light cache by one classic shadow ray per light.
pub fn shadow_ray(
    p: &ExtinctionParams,
    extinction: &[f32],
    ambient: &[[f32; 4]],
    near_blocks: &[u32],
) -> Vec<[f32; 4]> {
    fill_cache(p, ambient, near_blocks, |_, light, c| {
        ray_depth(p, extinction, light, c.as_vec3() + 0.5)
    })
}

/// Everything the extinction stages compute, on the CPU, as the stages leave
/// it: what each stage writes and the later ones read.
#[derive(Debug, Clone)]
pub struct ExtinctionState {
    /// The SAT.
    pub sat: Sat,
    /// Δt·τ per cell.
    pub extinction: Vec<f32>,
    /// I_AO per cell.
    pub ambient: Vec<[f32; 4]>,
    /// The light cache.
    pub light_cache: Vec<[f32; 4]>,
}

impl ExtinctionState {
    /// Nothing computed yet, for `p`'s grid.
    pub fn empty(p: &ExtinctionParams) -> ExtinctionState {
        ExtinctionState {
            sat: Sat {
                grid: p.grid,
                channels: p.channels,
                data: Default::default(),
            },
            extinction: Vec::new(),
            ambient: Vec::new(),
            light_cache: Vec::new(),
        }
    }
}

/// What the extinction stages read besides each other's results.
#[derive(Debug, Clone, Copy)]
pub struct ExtinctionInputs<'a> {
    /// The uniforms.
    pub params: &'a ExtinctionParams,
    /// The settings (for the stages' methods).
    pub settings: &'a ExtinctionSettings,
    /// The packed data.
    pub packed: &'a PackedTexture,
    /// The transfer-function table.
    pub tf: &'a [[f32; 4]],
    /// [`crate::extinction::near_cells_mask`]: the cells worth filling.
    pub near_blocks: &'a [u32],
}

/// Runs `stage`'s twin by the settings' methods, reading the earlier stages'
/// results from `state` and writing its own there.
pub fn run(stage: Stage, inputs: &ExtinctionInputs<'_>, state: &mut ExtinctionState) {
    let p = inputs.params;
    let near = inputs.near_blocks;
    match stage {
        Stage::ExtinctionSat => {
            (state.sat, state.extinction) = extinction_sat(p, inputs.packed, inputs.tf);
        }
        Stage::AmbientOcclusion => {
            state.ambient = match inputs.settings.ao_method {
                AoMethod::Sat => ambient_occlusion(p, &state.sat, near),
                AoMethod::Sampled => ambient_occlusion_reference(p, &state.extinction, near),
            };
        }
        Stage::SoftShadow => {
            state.light_cache = match inputs.settings.shadow_method {
                ShadowMethod::Cone => soft_shadow(p, &state.sat, &state.ambient, near),
                ShadowMethod::Ray => shadow_ray(p, &state.extinction, &state.ambient, near),
            };
        }
    }
}

/// The whole computation as [`crate::extinction::Extinction`] runs it: every
/// stage of [`Stage::ALL`] in order, filling the cells the mask marks.
pub fn compute_extinction(inputs: &ExtinctionInputs<'_>) -> ExtinctionState {
    let mut state = ExtinctionState::empty(inputs.params);
    for stage in Stage::ALL {
        run(stage, inputs, &mut state);
    }
    state
}

/// What the CPU renderer's extinction stages read besides their settings.
#[derive(Debug, Clone, Copy)]
pub struct CpuExtinctionInputs<'a> {
    /// The blocks' packing (which cells are worth filling).
    pub packing: &'a blocks::packing::Packing,
    /// The packed data.
    pub packed: &'a PackedTexture,
    /// The transfer-function table.
    pub tf: &'a [[f32; 4]],
}

/// Extinction-based illumination on the CPU renderer, brought up to date
/// under the policy the GPU's [`crate::extinction::Extinction`] follows
/// ([`update_extinction`], the paper's algorithm 1): a change recomputes from
/// the first stage it affects (a light moved: the shadows alone), a camera
/// move nothing. Keeps every stage's result, as the GPU keeps its textures.
#[derive(Debug, Default)]
pub struct CpuExtinction {
    cache: StageCache,
    /// What the stages run with and their results (none before the first
    /// update).
    prepared: Option<Prepared>,
}

/// The uniforms, settings and near-cells mask [`CpuExtinction`]'s stages run
/// with, and the stages' results.
#[derive(Debug)]
struct Prepared {
    params: ExtinctionParams,
    settings: ExtinctionSettings,
    near: Vec<u32>,
    state: ExtinctionState,
}

impl CpuExtinction {
    /// Brings the light cache up to date for `settings` over the resident
    /// data of `data_version` classified by `tf`, the uniforms `params`.
    pub fn update(
        &mut self,
        inputs: CpuExtinctionInputs<'_>,
        params: &ExtinctionParams,
        settings: &ExtinctionSettings,
        data_version: u64,
        tf: &TransferFunction,
    ) -> Result<ExtinctionTimings, GpuError> {
        settings.validate()?;
        let keys = StageCache::keys_of(&Stage::NAMES, settings, data_version, tf);
        update_extinction(self, inputs, keys, params, settings)
    }

    /// The light cache, grid-shaped, once every stage has run.
    pub fn light_cache(&self) -> Option<ColourTexture> {
        let Prepared { params, state, .. } = self.prepared.as_ref()?;
        (self.cache.is_complete() && !state.light_cache.is_empty())
            .then(|| ColourTexture::new(params.grid, &state.light_cache))
    }
}

impl ExtinctionStages for CpuExtinction {
    type Inputs<'a> = CpuExtinctionInputs<'a>;

    fn cache(&mut self) -> &mut StageCache {
        &mut self.cache
    }

    fn prepare(
        &mut self,
        inputs: CpuExtinctionInputs<'_>,
        params: &ExtinctionParams,
        settings: &ExtinctionSettings,
    ) -> Result<bool, GpuError> {
        let near = crate::extinction::near_cells_mask(inputs.packing, params);
        // Results of another grid or channel count are of no use.
        let state = self
            .prepared
            .take()
            .filter(|old| {
                old.params.grid == params.grid
                    && old.params.channels == params.channels
                    && old.near.len() == near.len()
            })
            .map(|old| old.state);
        let fits = state.is_some();
        self.prepared = Some(Prepared {
            params: *params,
            settings: settings.clone(),
            near,
            state: state.unwrap_or_else(|| ExtinctionState::empty(params)),
        });
        Ok(!fits)
    }

    fn run(&mut self, inputs: CpuExtinctionInputs<'_>, stage: Stage) -> Result<f64, GpuError> {
        let start = Instant::now();
        let Some(Prepared {
            params,
            settings,
            near,
            state,
        }) = &mut self.prepared
        else {
            return Err(GpuError::InvalidRequest(
                "the extinction stages were not prepared".into(),
            ));
        };
        let twin = ExtinctionInputs {
            params,
            settings,
            packed: inputs.packed,
            tf: inputs.tf,
            near_blocks: near,
        };
        run(stage, &twin, state);
        Ok(start.elapsed().as_secs_f64() * 1e3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cuboid_queries_equal_brute_force_sums_exactly() {
        let grid = [7, 5, 6];
        let n = 7 * 5 * 6;
        // Large values, so 32-bit sums would wrap.
        let values: Vec<u64> = (0..n as u64)
            .map(|i| (i * 2_654_435_761) % (4 << 24))
            .collect();
        let sat = sat_from_cells(grid, &values);
        for (lo, hi) in [
            ([0, 0, 0], [6, 4, 5]),
            ([2, 1, 3], [4, 4, 3]),
            ([-3, -2, -9], [1, 9, 2]),
            ([3, 3, 3], [3, 3, 3]),
            ([5, 0, 0], [4, 4, 5]),
        ] {
            let mut expected = 0u64;
            for z in lo[2].max(0)..=hi[2].min(5) {
                for y in lo[1].max(0)..=hi[1].min(4) {
                    for x in lo[0].max(0)..=hi[0].min(6) {
                        expected += values[cell_index(grid, [x as u32, y as u32, z as u32])];
                    }
                }
            }
            assert_eq!(
                sat.cuboid_sum(IVec3::from(lo), IVec3::from(hi), 0),
                expected,
                "{lo:?}..{hi:?}"
            );
        }
    }

    #[test]
    fn read_cells_are_those_cell_is_read_reads() {
        use crate::packed_volume::PackedVolume;
        // Grids finer and coarser than the blocks, not dividing them evenly.
        for (dims, grid) in [
            ([256.0, 256.0, 113.0], [128, 128, 113]),
            ([100.0, 37.0, 64.0], [23, 40, 7]),
        ] {
            let block_grid = dims.map(|d: f32| (d / 16.0).ceil() as u32);
            let mut p: ExtinctionParams = bytemuck::Zeroable::zeroed();
            p.grid = grid;
            p.volume = PackedVolume {
                block_grid,
                volume_dims: dims,
                ..p.volume
            };
            let blocks = block_grid.iter().product::<u32>();
            let near: Vec<u32> = (0..blocks).map(|i| u32::from(i * 7 % 3 == 0)).collect();
            let read = ReadCells::new(&p, &near);
            for z in 0..grid[2] {
                for y in 0..grid[1] {
                    for x in 0..grid[0] {
                        let c = IVec3::new(x as i32, y as i32, z as i32);
                        assert_eq!(
                            read.holds([x, y, z]),
                            cell_is_read(&p, &near, c),
                            "{dims:?} {grid:?} cell {c}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn a_directional_light_s_cuboids_found_once_give_each_cell_its_own_cone_s_depth() {
        let grid = [21u32, 17, 9];
        let n = u64::from(grid.iter().product::<u32>());
        let values: Vec<u64> = (0..n).map(|i| (i * 2_654_435_761) % (3 << 24)).collect();
        let sat = sat_from_cells(grid, &values);
        let mut p: ExtinctionParams = bytemuck::Zeroable::zeroed();
        p.grid = grid;
        p.cone_first = 1.3;
        p.cone_growth = 0.05;
        p.cone_tan = 2.0f32.to_radians().tan();
        for direction in [
            [0.3f32, -0.5, 0.8],
            [-1.0, 0.0, 0.0],
            [0.0, 0.7, -0.7],
            [0.01, 0.02, -1.0],
        ] {
            let light = LightUniform {
                position: [direction[0], direction[1], direction[2], 0.0],
                colour: [1.0, 1.0, 1.0, -2.0],
                spot: [0.0; 4],
            };
            p.lights[0] = light;
            p.light_count = 1;
            let once = Cone::towards(&light, Vec3::ZERO).expect("a direction");
            let extent = grid[once.a] as i32;
            let cuboids = once.cuboids_in_grid(&p);
            for i in 0..n as u32 {
                let c = IVec3::from_array(
                    blocks::store::grid_position(grid, i as usize).map(|v| v as i32),
                );
                let own = Cone::towards(&light, c.as_vec3() + 0.5).expect("a direction");
                let want = cone_depth(&p, &sat, &own, own.cuboids(&p), c);
                let got = cone_depth(&p, &sat, &once, cuboids.iter().copied(), c);
                assert_eq!(got.to_bits(), want.to_bits(), "{direction:?} cell {c}");
                assert!(want > 0.0 || c[once.a] == 0 || c[once.a] == extent - 1);
            }
        }
    }

    #[test]
    fn depths_convert_from_both_words() {
        assert_eq!(depth_of(1 << 24), 1.0);
        assert_eq!(depth_of(63 << 40), 63.0 * 65536.0);
        assert_eq!(fixed_of(2.5), 5 << 23);
    }
}
