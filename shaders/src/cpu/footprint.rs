//! CPU only: which pixels of a frame can show anything, from the boxes of
//! the blocks the transfer function shows, projected onto the image. With
//! empty-space skipping a ray whose pixel no box covers meets no sample that
//! can be visible, so the march leaves it as the background without walking
//! the block grid (the same bytes: such a ray composites nothing). A ray
//! that is marched starts and ends within the depths (NDC z) of the boxes
//! projected onto its tile of pixels: no sample before or after them can
//! show either.

use glam::{Vec3, Vec4};

use super::march::ndc_pixel;
use super::occupancy::VisibleBox;
use crate::raycast::RaycastParams;

/// Pixels a projected box is widened by on every side: far more than the
/// rounding of the projection (found from the inverse of the matrix the
/// rays are unprojected with) and of the rays' own arithmetic.
const MARGIN_PX: f32 = 2.0;

/// Smallest `w` (clip space) a box's corner may have: a box reaching to or
/// behind the eye projects onto no bounded rectangle, and the frame gets no
/// footprint.
const MIN_W: f32 = 1e-6;

/// Edge of the square tiles of pixels that share a range of depths.
const DEPTH_TILE: usize = 8;

/// The pixels of a band of rows (`first_row`, `rows` rows of `width`) that
/// some projected box covers, and per tile of [`DEPTH_TILE`]² pixels the
/// depths of the boxes projected onto it.
#[derive(Debug, Clone)]
pub struct Footprint {
    width: usize,
    first_row: u32,
    covered: Vec<bool>,
    /// Tiles per row.
    tiles_x: usize,
    /// Per tile the least and the greatest NDC z of the corners of the
    /// boxes whose rectangles reach it (empty, lo > hi, where none does).
    depths: Vec<[f32; 2]>,
}

/// The depths (NDC z) where a ray may meet a box: nothing to march where
/// `lo > hi`, and no bound on a side where that side is infinite.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reach {
    pub lo: f32,
    pub hi: f32,
}

impl Reach {
    /// Anywhere along the ray (no footprint).
    pub const ALL: Reach = Reach {
        lo: f32::NEG_INFINITY,
        hi: f32::INFINITY,
    };
    /// Nowhere.
    pub const NONE: Reach = Reach {
        lo: f32::INFINITY,
        hi: f32::NEG_INFINITY,
    };

    /// Whether the ray may meet a box at all.
    #[inline(always)]
    pub fn met(self) -> bool {
        self.lo <= self.hi
    }
}

impl Footprint {
    /// The footprint of `cells` (texture-coordinate boxes, `occupancy::visible_cells`)
    /// in the band of rows `p` draws; `None` where a box reaches behind the eye
    /// or the projection is not finite (every ray is marched then).
    pub fn new(p: &RaycastParams, cells: &[VisibleBox]) -> Option<Footprint> {
        let (width, rows) = (p.width as usize, p.height as usize);
        let clip_from_texture = p.inv_view_proj.inverse() * p.texture_from_model.inverse();
        if !clip_from_texture.is_finite() {
            return None;
        }
        let w = p.width as f32;
        let first = p.first_row as f32;
        // A 2D difference array of the rectangles, summed below: each box
        // costs four additions whatever its size on screen.
        let stride = width + 1;
        let mut sums = vec![0i32; stride * (rows + 1)];
        let tiles_x = width.div_ceil(DEPTH_TILE);
        let mut depths =
            vec![[f32::INFINITY, f32::NEG_INFINITY]; tiles_x * rows.div_ceil(DEPTH_TILE)];
        for cell in cells {
            let (mut lo, mut hi) = (glam::Vec2::INFINITY, glam::Vec2::NEG_INFINITY);
            // Depth is affine in the point (the view's z), and NDC z grows
            // with it: the box's least and greatest lie at corners.
            let (mut z_lo, mut z_hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for corner in 0..8 {
                let pick = |bit: usize, a: f32, b: f32| if corner >> bit & 1 == 0 { a } else { b };
                let t = Vec3::new(
                    pick(0, cell.lo.x, cell.hi.x),
                    pick(1, cell.lo.y, cell.hi.y),
                    pick(2, cell.lo.z, cell.hi.z),
                );
                let clip = clip_from_texture * Vec4::new(t.x, t.y, t.z, 1.0);
                if !clip.is_finite() || clip.w < MIN_W {
                    return None;
                }
                let ndc = clip.truncate() / clip.w;
                z_lo = z_lo.min(ndc.z);
                z_hi = z_hi.max(ndc.z);
                // In the band's rows.
                let pixel = ndc_pixel(p, ndc.truncate()) - glam::Vec2::new(0.0, first);
                lo = lo.min(pixel);
                hi = hi.max(pixel);
            }
            if !(lo.is_finite() && hi.is_finite() && z_lo.is_finite() && z_hi.is_finite()) {
                return None;
            }
            let (lo, hi) = (lo - MARGIN_PX, hi + MARGIN_PX);
            // Whole pixels from ⌈lo⌉ to ⌊hi⌋, within the band.
            let x0 = lo.x.ceil().max(0.0);
            let y0 = lo.y.ceil().max(0.0);
            let x1 = (hi.x.floor() + 1.0).min(w);
            let y1 = (hi.y.floor() + 1.0).min(rows as f32);
            if x0 >= x1 || y0 >= y1 {
                continue;
            }
            let [x0, y0, x1, y1] = [x0, y0, x1, y1].map(|v| v as usize);
            sums[y0 * stride + x0] += 1;
            sums[y0 * stride + x1] -= 1;
            sums[y1 * stride + x0] -= 1;
            sums[y1 * stride + x1] += 1;
            for ty in y0 / DEPTH_TILE..(y1 - 1) / DEPTH_TILE + 1 {
                for tx in x0 / DEPTH_TILE..(x1 - 1) / DEPTH_TILE + 1 {
                    let d = &mut depths[ty * tiles_x + tx];
                    *d = [d[0].min(z_lo), d[1].max(z_hi)];
                }
            }
        }
        let mut covered = vec![false; width * rows];
        let mut above = vec![0i32; width];
        for y in 0..rows {
            let mut run = 0;
            for x in 0..width {
                run += sums[y * stride + x];
                above[x] += run;
                covered[y * width + x] = above[x] > 0;
            }
        }
        Some(Footprint {
            width,
            first_row: p.first_row,
            covered,
            tiles_x,
            depths,
        })
    }

    /// Where the ray of pixel `x` of image row `row` (a row of the band) may
    /// meet a box: [`Reach::NONE`] where no box covers the pixel.
    #[inline(always)]
    pub fn reach(&self, x: u32, row: u32) -> Reach {
        let (x, y) = (x as usize, row.wrapping_sub(self.first_row) as usize);
        if x >= self.width {
            return Reach::ALL;
        }
        let tile = (y / DEPTH_TILE).wrapping_mul(self.tiles_x) + x / DEPTH_TILE;
        match self.covered.get(y.wrapping_mul(self.width).wrapping_add(x)) {
            Some(false) => Reach::NONE,
            Some(true) => {
                let [lo, hi] = self.depths[tile];
                Reach { lo, hi }
            }
            None => Reach::ALL,
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::camera::rh::proj::directx::{orthographic, perspective};
    use glam::camera::rh::view::look_to_mat4;
    use glam::{Mat4, Vec2};

    use super::*;
    use crate::cpu::march::{PixelRay, intersect_box, pixel_ndc};

    /// Parameters of a band of rows `first_row..first_row + rows` of a
    /// `width` × `image_height` image seen through `view_proj`, with the
    /// model's box [−1, 1]³ as the texture's [0, 1]³.
    fn params(
        view_proj: Mat4,
        width: u32,
        image_height: u32,
        first_row: u32,
        rows: u32,
    ) -> RaycastParams {
        let mut p: RaycastParams = bytemuck::Zeroable::zeroed();
        p.inv_view_proj = view_proj.inverse();
        p.texture_from_model =
            Mat4::from_translation(Vec3::splat(0.5)) * Mat4::from_scale(Vec3::splat(0.5));
        (p.width, p.image_height, p.first_row, p.height) = (width, image_height, first_row, rows);
        p
    }

    /// The stretch of the ray `main` casts through pixel `x` of image row
    /// `row` that lies in `cell`, where it meets it.
    fn meets(p: &RaycastParams, x: u32, row: u32, cell: &VisibleBox) -> Option<Vec2> {
        let (tex_origin, tex_dir) = PixelRay::new(p, x, row).in_texture(p);
        let span = intersect_box(tex_origin, tex_dir, cell.lo, cell.hi);
        (span.x < span.y).then_some(span)
    }

    #[test]
    fn a_pixel_centre_maps_to_ndc_and_back() {
        let p = params(Mat4::IDENTITY, 37, 23, 0, 23);
        for (x, row) in [(0, 0), (36, 22), (18, 11), (5, 17)] {
            let back = ndc_pixel(&p, pixel_ndc(&p, x, row));
            let error = (back - Vec2::new(x as f32, row as f32)).abs().max_element();
            assert!(error < 1e-4, "pixel ({x}, {row}) came back as {back}");
        }
        // The image's corners lie at NDC ±1, half a pixel beyond the
        // corner pixels' centres.
        assert_eq!(ndc_pixel(&p, Vec2::new(-1.0, 1.0)), Vec2::new(-0.5, -0.5));
        assert_eq!(ndc_pixel(&p, Vec2::new(1.0, -1.0)), Vec2::new(36.5, 22.5));
    }

    #[test]
    fn every_ray_that_meets_a_box_is_covered_and_others_are_not_all() {
        let eye = Vec3::new(0.4, -0.7, 3.1);
        let view = look_to_mat4(eye, -eye.normalize(), Vec3::Y);
        let cameras = [
            perspective(0.8, 1.25, 0.1, 10.0) * view,
            // Rays that start behind the eye, as the orthographic camera's.
            orthographic(-1.2, 1.2, -1.0, 1.0, -1.0, 10.0) * view,
        ];
        // Small boxes scattered through the volume.
        let cells: Vec<VisibleBox> = (0..12)
            .map(|k| {
                let f = |s: f32| ((k as f32 * s).sin() * 0.5 + 0.5) * 0.85;
                let lo = Vec3::new(f(1.7), f(2.3), f(0.9));
                VisibleBox {
                    lo,
                    hi: lo + Vec3::new(0.06, 0.1, 0.04),
                }
            })
            .collect();
        for view_proj in cameras {
            // The whole image, and a band of it.
            for (first_row, rows) in [(0, 64), (23, 17)] {
                let p = params(view_proj, 80, 64, first_row, rows);
                let footprint = Footprint::new(&p, &cells).expect("every box in front");
                let (mut met, mut left, mut shortened) = (0, 0, 0);
                for row in first_row..first_row + rows {
                    for x in 0..p.width {
                        let reach = footprint.reach(x, row);
                        let within = PixelRay::new(&p, x, row).within(reach);
                        let spans: Vec<Vec2> =
                            cells.iter().filter_map(|c| meets(&p, x, row, c)).collect();
                        if spans.is_empty() {
                            left += usize::from(!reach.met());
                            continue;
                        }
                        met += 1;
                        assert!(reach.met(), "pixel {x}, row {row}");
                        for span in &spans {
                            assert!(
                                within.x <= span.x && span.y <= within.y,
                                "pixel {x}, row {row}: a box from t = {} to {}, marched from {} to {}",
                                span.x,
                                span.y,
                                within.x,
                                within.y
                            );
                        }
                        // Bounded on both sides (the near plane lies
                        // in front of every box).
                        shortened += usize::from(within.x > 0.0 && within.y.is_finite());
                    }
                }
                assert!(met > 0 && left > 0, "{met} rays met, {left} left out");
                assert!(shortened * 2 > met, "{shortened} of {met} rays cut short");
                // Pixels outside the band: no bound.
                for (x, row) in [(p.width, first_row), (0, first_row + rows)] {
                    assert_eq!(footprint.reach(x, row), Reach::ALL, "pixel {x}, row {row}");
                }
            }
        }
    }

    #[test]
    fn a_box_reaching_behind_the_eye_gives_no_footprint() {
        let view = look_to_mat4(Vec3::new(0.0, 0.0, 0.2), Vec3::NEG_Z, Vec3::Y);
        let p = params(perspective(0.8, 1.0, 0.01, 10.0) * view, 32, 32, 0, 32);
        let around = VisibleBox {
            lo: Vec3::splat(0.2),
            hi: Vec3::splat(0.8),
        };
        assert!(Footprint::new(&p, &[around]).is_none());
    }
}
