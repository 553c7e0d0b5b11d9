//! CPU twin of the `raycast` stage over packed blocks (`shaders/wgsl/raycast.wgsl`),
//! function for function: the march of [`super::march`] over [`PackedTexture`].

use glam::Vec3;

use super::march::{Span, Storage, gradient_at, march};
use super::packed::{BLOCK, BlockLocation, PackedTexture, atlas_texel, block_of, empty_exit};
use super::texture::floor3;
use crate::raycast::RaycastParams;

impl Storage for PackedTexture {
    type Location = BlockLocation;

    fn locate(&self, p: &RaycastParams, tc: Vec3) -> BlockLocation {
        PackedTexture::locate(self, &p.volume, tc)
    }

    fn span(&self, p: &RaycastParams, origin: Vec3, dir: Vec3, t: f32) -> Span<BlockLocation> {
        let g = &p.volume;
        let block = block_of(g, origin + dir * t);
        let loc = self.locate_block(block);
        // Never behind `t`: a stretch ends at the next sample at the latest.
        let exit = empty_exit(g, origin, dir, &loc).max(t);
        let dims = Vec3::from(g.volume_dims);
        let corner = Vec3::new(block[0] as f32, block[1] as f32, block[2] as f32) * BLOCK;
        // `atlas_texel` unclamped, as a function of t.
        let local_at_zero = origin * dims - corner;
        let local_per_t = dir * dims;
        Span {
            loc,
            exit,
            texel_at_zero: loc.origin - 0.5 + local_at_zero * loc.scale,
            texel_per_t: local_per_t * loc.scale,
            local_at_zero,
            local_per_t,
        }
    }

    fn sample_in(&self, _p: &RaycastParams, span: &Span<BlockLocation>, t: f32, _tc: Vec3) -> f32 {
        self.atlas.sample_texel(slot_texel(span, t))
    }

    fn gradient_in(&self, p: &RaycastParams, span: &Span<BlockLocation>, t: f32, tc: Vec3) -> Vec3 {
        let local = span.local_at_zero + span.local_per_t * t;
        // A voxel from every face of the block: all six neighbours are in it
        // (what `sample_neighbour` finds), so they are read from its slot.
        let inner = local.cmpge(Vec3::ONE) & local.cmplt(Vec3::splat(BLOCK - 1.0));
        if !inner.all() {
            return gradient_at(self, p, tc, &span.loc);
        }
        let centre = slot_texel(span, t);
        let s = span.loc.scale;
        let h = Vec3::from(p.volume.texel);
        let at = |d: Vec3| self.atlas.sample_texel(centre + d);
        let differences = Vec3::new(
            at(Vec3::new(s, 0.0, 0.0)) - at(Vec3::new(-s, 0.0, 0.0)),
            at(Vec3::new(0.0, s, 0.0)) - at(Vec3::new(0.0, -s, 0.0)),
            at(Vec3::new(0.0, 0.0, s)) - at(Vec3::new(0.0, 0.0, -s)),
        );
        differences / (2.0 * h)
    }

    fn is_empty(loc: &BlockLocation) -> bool {
        loc.empty
    }

    fn sample_at(&self, p: &RaycastParams, tc: Vec3, loc: &BlockLocation) -> f32 {
        self.atlas.sample_texel(atlas_texel(&p.volume, tc, loc))
    }

    fn sample_neighbour(&self, p: &RaycastParams, tc: Vec3, home: &BlockLocation) -> f32 {
        let g = p.volume;
        let b = floor3(tc * Vec3::from(g.volume_dims) / BLOCK);
        let block = [b.x as i32, b.y as i32, b.z as i32];
        if block == home.block {
            return self.sample_at(p, tc, home);
        }
        let other = Storage::locate(self, p, tc);
        if other.empty {
            return self.sample_at(p, tc, home);
        }
        self.sample_at(p, tc, &other)
    }

    fn light_at(&self, p: &RaycastParams, tc: Vec3, loc: &BlockLocation) -> Vec3 {
        if let Some([r, g, b]) = &self.light_cache {
            // shared/light_cache.wgsl: grid-shaped, read at tc.
            return Vec3::new(r.sample_level(tc), g.sample_level(tc), b.sample_level(tc));
        }
        match &self.light {
            Some(light) => Vec3::splat(light.sample_texel(atlas_texel(&p.volume, tc, loc))),
            None => Vec3::ONE,
        }
    }

    fn empty_exit(&self, p: &RaycastParams, origin: Vec3, dir: Vec3, loc: &BlockLocation) -> f32 {
        empty_exit(&p.volume, origin, dir, loc)
    }
}

/// The atlas texel position of the sample at `t` in `span`, kept in the
/// block's slot (its apron included) as `atlas_texel` keeps it.
#[inline]
fn slot_texel(span: &Span<BlockLocation>, t: f32) -> Vec3 {
    let origin = span.loc.origin;
    let edge = BLOCK * span.loc.scale;
    (span.texel_at_zero + span.texel_per_t * t).clamp(origin - 1.0, origin + Vec3::splat(edge))
}

/// Renders like the `raycast` dispatch: packed blocks through the block index
/// (lit by `packed.light` when the params say so).
pub fn raycast(
    params: &RaycastParams,
    packed: &PackedTexture,
    transfer_function: &[[f32; 4]],
    output: &mut [u8],
) {
    march(params, packed, transfer_function, output);
}
