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
