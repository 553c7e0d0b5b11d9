//! CPU only: the first lines of WGSL `main` (the ray through a pixel, its
//! crossings of the clipping box and of the box about what can show) for
//! the eight pixels of a row of a tile side by side, a lane each, with the
//! arithmetic of [`PixelRay`] and [`intersect_box`] in each lane in the
//! same order (the same bits: `eight_rays_side_by_side_are_each_the_bits_of_one`
//! checks). One ray at a time, the divisions and square roots of a ray's
//! set-up each took an instruction of their own; side by side they take
//! one for eight rays.

use glam::{Mat4, Vec2, Vec3};
use wide::f32x8;

use super::footprint::Reach;
use super::march::{PixelRay, REACH_MARGIN, TINY_DIRECTION, intersect_box, pixel_ndc};
use crate::raycast::RaycastParams;

/// Rays set up side by side: a tile's row of pixels.
pub const RAY_LANES: usize = 8;

/// What WGSL `main` finds of its ray before its loop (CPU only).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayStart {
    /// The ray's direction in model space, of unit length.
    pub dir: Vec3,
    /// Where it starts (the near plane), in texture space.
    pub tex_origin: Vec3,
    /// Its direction in texture space (`t` counts mm of model space).
    pub tex_dir: Vec3,
    /// Its stretch (`t`) inside the clipping box.
    pub span: Vec2,
    /// Its stretch where a sample may show: within the box about what can
    /// show and the depths it may meet a box at (`span` without skipping).
    pub seen: Vec2,
}

impl RayStart {
    /// The start of the ray through pixel `x` of image row `row`, which
    /// meets the boxes that can show within `reach`, with the box about
    /// what can show `extent` (`Storage::visible_extent`): one ray's
    /// arithmetic.
    #[inline(always)]
    pub fn new(
        p: &RaycastParams,
        extent: Option<(Vec3, Vec3)>,
        x: u32,
        row: u32,
        reach: Reach,
    ) -> RayStart {
        let ray = PixelRay::new(p, x, row);
        let (tex_origin, tex_dir) = ray.in_texture(p);
        let span = intersect_box(
            tex_origin,
            tex_dir,
            Vec3::from(p.clip_min),
            Vec3::from(p.clip_max),
        );
        // With empty-space skipping, the stretch of the ray where a sample
        // may be visible: none lie before `seen.x` or after `seen.y` (the
        // samples stay where the box puts them: from `span.x` on, a step
        // apart).
        let seen = match extent {
            Some((lo, hi)) => {
                let inside = intersect_box(tex_origin, tex_dir, lo, hi);
                let within = ray.within(reach);
                Vec2::new(inside.x.max(within.x), inside.y.min(span.y).min(within.y))
            }
            None => span,
        };
        RayStart {
            dir: ray.dir,
            tex_origin,
            tex_dir,
            span,
            seen,
        }
    }

    /// [`RayStart::new`] of the pixels `x0 + j` of image row `row`, lane `j`
    /// within `reaches[j]`, side by side. Every lane is found, whatever its
    /// reach; a lane's start is what `new` finds for it, bit for bit.
    #[inline(always)]
    pub fn lanes(
        p: &RaycastParams,
        extent: Option<(Vec3, Vec3)>,
        x0: u32,
        row: u32,
        reaches: &[Reach; RAY_LANES],
    ) -> [RayStart; RAY_LANES] {
        // `pixel_ndc`: its y is the row's, its x each lane's.
        let ndc_y = f32x8::splat(pixel_ndc(p, x0, row).y);
        let xs: [f32; RAY_LANES] = std::array::from_fn(|j| (x0 + j as u32) as f32 + 0.5);
        let ndc_x =
            f32x8::from(xs) / f32x8::splat(p.width as f32) * f32x8::splat(2.0) - f32x8::splat(1.0);
        // `PixelRay::new`.
        let near_h = transform(&p.inv_view_proj, [ndc_x, ndc_y, ZERO, ONE]);
        let far_h = transform(&p.inv_view_proj, [ndc_x, ndc_y, ONE, ONE]);
        let origin = V3::from_h(near_h);
        let far = V3::from_h(far_h);
        let dir = far.sub(origin).normalize();
        // `PixelRay::in_texture`.
        let tex_origin = V3::xyz(transform(
            &p.texture_from_model,
            [origin.x, origin.y, origin.z, ONE],
        ));
        let tex_dir = V3::xyz(transform(
            &p.texture_from_model,
            [dir.x, dir.y, dir.z, ZERO],
        ));
        let inverse = tex_dir.inverse_direction();
        let span = crossing(
            tex_origin,
            inverse,
            V3::splat(Vec3::from(p.clip_min)),
            V3::splat(Vec3::from(p.clip_max)),
        );
        let seen = match extent {
            Some((lo, hi)) => {
                let inside = crossing(tex_origin, inverse, V3::splat(lo), V3::splat(hi));
                let within = within(near_h, far_h, origin, far, dir, reaches);
                [
                    inside[0].max(within[0]),
                    inside[1].min(span[1]).min(within[1]),
                ]
            }
            None => span,
        };
        let (dir, tex_origin, tex_dir) = (dir.lanes(), tex_origin.lanes(), tex_dir.lanes());
        let (span, seen) = (span.map(f32x8::to_array), seen.map(f32x8::to_array));
        std::array::from_fn(|j| RayStart {
            dir: dir[j],
            tex_origin: tex_origin[j],
            tex_dir: tex_dir[j],
            span: Vec2::new(span[0][j], span[1][j]),
            seen: Vec2::new(seen[0][j], seen[1][j]),
        })
    }
}

const ZERO: f32x8 = f32x8::ZERO;
const ONE: f32x8 = f32x8::ONE;

/// Eight 3-vectors, a lane each, with glam's `Vec3` arithmetic lane by lane.
#[derive(Debug, Clone, Copy)]
struct V3 {
    x: f32x8,
    y: f32x8,
    z: f32x8,
}

impl V3 {
    #[inline(always)]
    fn splat(v: Vec3) -> V3 {
        V3 {
            x: f32x8::splat(v.x),
            y: f32x8::splat(v.y),
            z: f32x8::splat(v.z),
        }
    }

    /// `Vec4::xyz`.
    #[inline(always)]
    fn xyz(h: [f32x8; 4]) -> V3 {
        V3 {
            x: h[0],
            y: h[1],
            z: h[2],
        }
    }

    /// Homogeneous coordinates as a point: `h.xyz() / h.w`.
    #[inline(always)]
    fn from_h(h: [f32x8; 4]) -> V3 {
        V3::xyz(h).div(h[3])
    }

    #[inline(always)]
    fn sub(self, o: V3) -> V3 {
        V3 {
            x: self.x - o.x,
            y: self.y - o.y,
            z: self.z - o.z,
        }
    }

    #[inline(always)]
    fn mul(self, o: V3) -> V3 {
        V3 {
            x: self.x * o.x,
            y: self.y * o.y,
            z: self.z * o.z,
        }
    }

    #[inline(always)]
    fn scale(self, s: f32x8) -> V3 {
        V3 {
            x: self.x * s,
            y: self.y * s,
            z: self.z * s,
        }
    }

    #[inline(always)]
    fn div(self, s: f32x8) -> V3 {
        V3 {
            x: self.x / s,
            y: self.y / s,
            z: self.z / s,
        }
    }

    /// `Vec3::dot`.
    #[inline(always)]
    fn dot(self, o: V3) -> f32x8 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }

    /// `Vec3::length`.
    #[inline(always)]
    fn length(self) -> f32x8 {
        self.dot(self).sqrt()
    }

    /// `Vec3::normalize`: times the reciprocal of the length.
    #[inline(always)]
    fn normalize(self) -> V3 {
        self.scale(ONE / self.length())
    }

    /// [`super::march::inverse_direction`].
    #[inline(always)]
    fn inverse_direction(self) -> V3 {
        let safe = |d: f32x8| {
            let tiny = d.abs().simd_lt(f32x8::splat(TINY_DIRECTION));
            ONE / tiny.select(f32x8::splat(TINY_DIRECTION), d)
        };
        V3 {
            x: safe(self.x),
            y: safe(self.y),
            z: safe(self.z),
        }
    }

    fn lanes(self) -> [Vec3; RAY_LANES] {
        let (x, y, z) = (self.x.to_array(), self.y.to_array(), self.z.to_array());
        std::array::from_fn(|j| Vec3::new(x[j], y[j], z[j]))
    }
}

/// `m * v` (glam's `Mat4::mul_vec4`: the columns weighed by `v`'s x, y, z
/// and w, summed in that order), lane by lane.
#[inline(always)]
fn transform(m: &Mat4, v: [f32x8; 4]) -> [f32x8; 4] {
    let columns = [m.x_axis, m.y_axis, m.z_axis, m.w_axis];
    let column = |c: usize, k: usize| f32x8::splat(columns[c][k]);
    std::array::from_fn(|k| {
        column(0, k) * v[0] + column(1, k) * v[1] + column(2, k) * v[2] + column(3, k) * v[3]
    })
}

/// [`super::march::intersect_box_inverse`] lane by lane: where each ray
/// enters and leaves the box `lo`..`hi`.
#[inline(always)]
fn crossing(origin: V3, inverse: V3, lo: V3, hi: V3) -> [f32x8; 2] {
    let t0 = lo.sub(origin).mul(inverse);
    let t1 = hi.sub(origin).mul(inverse);
    // glam's `Vec3::min` and `max` (`a < b ? a : b`, `a > b ? a : b`) are
    // the processor's; the scalar `f32::min` and `max` after them ignore a
    // NaN, as wide's `min` and `max` do.
    let near = [
        t0.x.fast_min(t1.x),
        t0.y.fast_min(t1.y),
        t0.z.fast_min(t1.z),
    ];
    let far = [
        t0.x.fast_max(t1.x),
        t0.y.fast_max(t1.y),
        t0.z.fast_max(t1.z),
    ];
    [
        near[0].max(near[1]).max(near[2].max(ZERO)),
        far[0].min(far[1]).min(far[2]),
    ]
}

/// [`PixelRay::within`] lane by lane, lane `j` within `reaches[j]`.
#[inline(always)]
fn within(
    near_h: [f32x8; 4],
    far_h: [f32x8; 4],
    origin: V3,
    far: V3,
    dir: V3,
    reaches: &[Reach; RAY_LANES],
) -> [f32x8; 2] {
    let bounded = |z: f32| z.is_finite() && z < 1.0;
    let mask = |side: fn(&Reach) -> f32| {
        f32x8::from(reaches.map(|r| if bounded(side(&r)) { 1.0 } else { 0.0 })).simd_gt(ZERO)
    };
    let (lo_bounded, hi_bounded) = (mask(|r| r.lo), mask(|r| r.hi));
    let unbounded = [f32x8::splat(f32::NEG_INFINITY), f32x8::splat(f32::INFINITY)];
    if !(lo_bounded | hi_bounded).any() {
        return unbounded;
    }
    let margin = f32x8::splat(REACH_MARGIN) * far.sub(origin).length();
    // The point of NDC depth z: its homogeneous coordinates blend the near
    // and far planes' points.
    let t_at = |z: f32x8| {
        let q: [f32x8; 4] = std::array::from_fn(|k| near_h[k] * (ONE - z) + far_h[k] * z);
        V3::from_h(q).sub(origin).dot(dir)
    };
    // Depths that are not bounded give no bound: any finite stand-in will
    // do, its `t` is not kept.
    let depth = |side: fn(&Reach) -> f32| {
        f32x8::from(reaches.map(|r| if bounded(side(&r)) { side(&r) } else { 0.0 }))
    };
    let lo = t_at(depth(|r| r.lo)) - margin;
    let hi = t_at(depth(|r| r.hi)) + margin;
    [
        (lo_bounded & lo.is_finite()).select(lo, unbounded[0]),
        (hi_bounded & hi.is_finite()).select(hi, unbounded[1]),
    ]
}

#[cfg(test)]
mod tests {
    use glam::camera::rh::proj::directx::{orthographic, perspective};
    use glam::camera::rh::view::look_to_mat4;

    use super::*;

    /// The bits of a start, NaNs alike whatever their payload.
    fn bits(s: &RayStart) -> Vec<u32> {
        let mut v = Vec::new();
        for x in [s.dir, s.tex_origin, s.tex_dir] {
            v.extend(x.to_array());
        }
        v.extend(s.span.to_array());
        v.extend(s.seen.to_array());
        v.into_iter()
            .map(|f| if f.is_nan() { u32::MAX } else { f.to_bits() })
            .collect()
    }

    #[test]
    fn eight_rays_side_by_side_are_each_the_bits_of_one() {
        let (width, height) = (45, 30);
        let mut checked = 0;
        for (k, eye) in [
            Vec3::new(0.4, -0.7, 3.1),
            Vec3::new(-2.5, 1.2, 0.3),
            Vec3::new(0.0, 0.0, 2.0),
        ]
        .into_iter()
        .enumerate()
        {
            let view = look_to_mat4(eye, -eye.normalize(), Vec3::Y);
            for view_proj in [
                perspective(0.8, 1.5, 0.1, 10.0) * view,
                orthographic(-1.2, 1.2, -0.8, 0.8, -1.0, 10.0) * view,
            ] {
                let mut p: RaycastParams = bytemuck::Zeroable::zeroed();
                p.inv_view_proj = view_proj.inverse();
                // A model of 2 × 1.6 × 1.2 about its centre.
                p.texture_from_model = Mat4::from_translation(Vec3::splat(0.5))
                    * Mat4::from_scale(Vec3::new(0.5, 0.625, 0.8 + 0.1 * k as f32));
                p.clip_min = [0.05, 0.0, 0.1];
                p.clip_max = [1.0, 0.9, 1.0];
                (p.width, p.image_height, p.first_row, p.height) = (width, height, 7, 16);
                let extents = [
                    None,
                    Some((Vec3::new(0.2, 0.1, 0.3), Vec3::new(0.7, 0.8, 0.6))),
                ];
                // Reaches of every kind: none, everywhere, bounded on both
                // sides, on one, and at or past the far plane.
                let reaches = [
                    Reach::NONE,
                    Reach::ALL,
                    Reach { lo: 0.2, hi: 0.9 },
                    Reach {
                        lo: f32::NEG_INFINITY,
                        hi: 0.95,
                    },
                    Reach { lo: 0.5, hi: 1.0 },
                    Reach { lo: 0.99, hi: 1.5 },
                    Reach {
                        lo: 0.0,
                        hi: f32::INFINITY,
                    },
                    Reach { lo: 0.3, hi: 0.31 },
                ];
                for extent in extents {
                    for row in p.first_row..p.first_row + p.height {
                        for x0 in (0..width).step_by(RAY_LANES) {
                            // Each lane its own reach, turning with the row.
                            let lane_reaches: [Reach; RAY_LANES] = std::array::from_fn(|j| {
                                reaches[(j + row as usize) % reaches.len()]
                            });
                            let lanes = RayStart::lanes(&p, extent, x0, row, &lane_reaches);
                            for (j, lane) in lanes.iter().enumerate() {
                                let one =
                                    RayStart::new(&p, extent, x0 + j as u32, row, lane_reaches[j]);
                                assert_eq!(
                                    bits(lane),
                                    bits(&one),
                                    "pixel ({}, {row}), lane {j}: {lane:?} against {one:?}",
                                    x0 + j as u32
                                );
                                checked += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(checked > 5000, "{checked} rays");
    }
}
