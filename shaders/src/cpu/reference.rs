//! CPU twin of the `reference` stage (`shaders/wgsl/reference.wgsl`): the march
//! over one plain full-resolution texture.

use glam::Vec3;

use super::Texture3d;
use super::march::{Span, Storage, TfTable, march};
use crate::raycast::RaycastParams;

/// WGSL `Location` of the reference stage: nothing is ever empty.
#[derive(Debug, Clone, Copy)]
pub struct PlainLocation;

impl Storage for Texture3d {
    type Location = PlainLocation;

    fn locate(&self, _p: &RaycastParams, _tc: Vec3) -> PlainLocation {
        PlainLocation
    }

    fn span(&self, _p: &RaycastParams, _origin: Vec3, _dir: Vec3, _t: f32) -> Span<PlainLocation> {
        Span {
            loc: PlainLocation,
            exit: f32::INFINITY,
            enter: f32::NEG_INFINITY,
            texel_at_zero: Vec3::ZERO,
            texel_per_t: Vec3::ZERO,
            local_at_zero: Vec3::ZERO,
            local_per_t: Vec3::ZERO,
            t_max: Vec3::INFINITY,
        }
    }

    fn is_empty(_loc: &PlainLocation) -> bool {
        false
    }

    fn sample_at(&self, _p: &RaycastParams, tc: Vec3, _loc: &PlainLocation) -> f32 {
        self.sample_level(tc)
    }

    fn voxel_edge(_loc: &PlainLocation) -> f32 {
        1.0
    }

    fn sample_neighbour(&self, p: &RaycastParams, tc: Vec3, home: &PlainLocation) -> f32 {
        self.sample_at(p, tc, home)
    }

    fn nearest_difference_at(&self, p: &RaycastParams, tc: Vec3, _loc: &PlainLocation) -> Vec3 {
        let [w, h, d] = self.dims().map(|n| n as i32);
        let at =
            |n: u32, size: i32| ((tc[n as usize] * size as f32).floor() as i32).clamp(0, size - 1);
        let (x, y, z) = (at(0, w), at(1, h), at(2, d));
        let differences = Vec3::new(
            self.load(x + 1, y, z) - self.load(x - 1, y, z),
            self.load(x, y + 1, z) - self.load(x, y - 1, z),
            self.load(x, y, z + 1) - self.load(x, y, z - 1),
        );
        differences / (2.0 * Vec3::from(p.volume.texel))
    }

    fn light_at(
        &self,
        _p: &RaycastParams,
        _span: &Span<PlainLocation>,
        _t: f32,
        _tc: Vec3,
    ) -> Vec3 {
        Vec3::ONE
    }

    fn empty_exit(
        &self,
        _p: &RaycastParams,
        _origin: Vec3,
        _dir: Vec3,
        _loc: &PlainLocation,
    ) -> f32 {
        0.0
    }
}

/// Renders like the `reference` dispatch: one volume texture, no blocks.
pub fn reference(
    params: &RaycastParams,
    volume: &Texture3d,
    transfer_function: &TfTable,
    output: &mut [u8],
) {
    march(params, volume, transfer_function, output);
}
