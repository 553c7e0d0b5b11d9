//! CPU twin of the `raycast` stage over packed blocks (`shaders/wgsl/raycast.wgsl`),
//! function for function: the march of [`super::march`] over [`PackedTexture`].

use glam::Vec3;

use super::march::{Storage, march};
use super::packed::{BLOCK, BlockLocation, PackedTexture, atlas_coord, empty_exit};
use crate::raycast::RaycastParams;

impl Storage for PackedTexture {
    type Location = BlockLocation;

    fn locate(&self, p: &RaycastParams, tc: Vec3) -> BlockLocation {
        PackedTexture::locate(self, &p.volume, tc)
    }

    fn is_empty(loc: &BlockLocation) -> bool {
        loc.empty
    }

    fn sample_at(&self, p: &RaycastParams, tc: Vec3, loc: &BlockLocation) -> f32 {
        self.atlas.sample_level(atlas_coord(&p.volume, tc, loc))
    }

    fn sample_neighbour(&self, p: &RaycastParams, tc: Vec3, home: &BlockLocation) -> f32 {
        let g = p.volume;
        let b = (tc * Vec3::from(g.volume_dims) / BLOCK).floor();
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
            Some(light) => Vec3::splat(light.sample_level(atlas_coord(&p.volume, tc, loc))),
            None => Vec3::ONE,
        }
    }

    fn empty_exit(&self, p: &RaycastParams, origin: Vec3, dir: Vec3, loc: &BlockLocation) -> f32 {
        empty_exit(&p.volume, origin, dir, loc)
    }
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
