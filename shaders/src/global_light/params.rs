//! [`LightParams`]: the uniforms of the global light stages, built from the
//! settings, the volume and its packing.

use blocks::packing::Packing;
use blocks::store::LEVELS;
use glam::{Mat4, Vec3};

use super::{LightSettings, LightSource, ScatterDirection, scatter_directions};
use crate::illumination::{near_blocks, slot_blocks, texture_transforms};
use crate::packed_volume::{PackedLayout, PackedVolume};
use crate::raycast::VolumePlacement;
use crate::volume_texture::VolumeTexture;

/// The uniforms of the light stages.
// keep in sync with shaders/wgsl/shared/light_params.wgsl `LightParams`
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LightParams {
    /// Texture space → model space (affine), column major.
    pub model_from_texture: Mat4,
    /// Model space → texture space (affine), column major.
    pub texture_from_model: Mat4,
    /// Point light: model position, w = 1; directional: unit vector towards it, w = 0.
    pub light: [f32; 4],
    /// in_scatter: this step's direction (model space); w = 1: towards the light instead.
    pub scatter_direction: [f32; 4],
    /// The packed volume.
    pub volume: PackedVolume,
    /// SVR points along x, y, z.
    pub svr_dims: [u32; 3],
    /// Light intensity I0.
    pub intensity: f32,
    /// Segment length L (mm).
    pub segment: f32,
    /// Scattering radius R_Ω (mm).
    pub scatter_radius: f32,
    /// The light step h (mm).
    pub step: f32,
    /// in_scatter: blend weight w_j / W_j (eq. 13).
    pub blend: f32,
    /// Per level: slots along x, y, z and the region's first atlas z.
    pub regions: [[u32; 4]; LEVELS],
    /// Upper bound on the steps of any march.
    pub max_steps: u32,
    /// light_seams: the level whose blocks' aprons this pass writes.
    pub seam_level: u32,
    /// light_seams: how many axes the texels this pass writes lie outside
    /// their block along (1 faces, 2 edges, 3 corners).
    pub seam_outward: u32,
    /// Padding to a multiple of 16 bytes.
    pub _pad0: u32,
}

/// SVR points along each axis for `dims` voxels at `scale`.
pub fn svr_dims(dims: [u32; 3], scale: u32) -> [u32; 3] {
    dims.map(|d| d.div_ceil(scale.max(1)).max(1))
}

impl LightParams {
    /// The uniforms for lighting the volume stored as `texture`, packed as
    /// `packing` (`layout` its sizes), with `settings` and a transfer-function
    /// table of `tf_len` entries.
    pub fn new(
        texture: &VolumeTexture,
        settings: &LightSettings,
        packing: &Packing,
        layout: PackedLayout,
        tf_len: u32,
    ) -> LightParams {
        let (model_from_texture, texture_from_model) = texture_transforms(texture);
        let radius = VolumePlacement::of(texture).radius();
        let h = texture.geometry.min_spacing_f32();
        let light = match settings.source {
            LightSource::Point(p) => model_from_texture
                .transform_point3(Vec3::from(p))
                .extend(1.0),
            LightSource::Directional(d) => Vec3::from(d).normalize_or(Vec3::Z).extend(0.0),
        };
        // The longest march: across the volume's bounding sphere and back in from a far light.
        let max_steps = (4.0 * radius / h).ceil() as u32 + 4;
        let mut regions = [[0u32; 4]; LEVELS];
        for (l, r) in packing.regions.iter().enumerate() {
            regions[l] = [r.slots[0], r.slots[1], r.slots[2], r.z0];
        }
        LightParams {
            model_from_texture,
            texture_from_model,
            light: light.into(),
            scatter_direction: [0.0, 0.0, 1.0, 1.0],
            volume: PackedVolume::new(texture, layout, tf_len),
            svr_dims: svr_dims(texture.geometry.dims, settings.svr_scale),
            intensity: settings.intensity,
            segment: settings.segment_voxels as f32 * h,
            scatter_radius: settings.scatter_radius_voxels * h,
            step: h,
            blend: 1.0,
            regions,
            max_steps,
            seam_level: 0,
            seam_outward: 0,
            _pad0: 0,
        }
    }

    /// How many blocks around a non-empty one hold SVR points that
    /// `direct_light` and `in_scatter` may read ([`near_blocks`]): a segment or
    /// R_Ω, whichever is longer, in voxels of the smallest spacing (so never
    /// short along a coarser axis), plus one SVR cell for interpolation and
    /// two voxels to spare.
    pub fn svr_margin_blocks(&self) -> u32 {
        let reach = self.segment.max(self.scatter_radius) / self.step;
        let cell = (0..3)
            .map(|i| (self.volume.volume_dims[i] / self.svr_dims[i].max(1) as f32).ceil())
            .fold(1.0f32, f32::max);
        ((reach + cell + 2.0) / blocks::store::BLOCK as f32).ceil() as u32
    }

    /// These params for in-scattering step `direction`.
    pub fn scattering(&self, direction: &ScatterDirection) -> LightParams {
        let [x, y, z] = direction.towards;
        LightParams {
            scatter_direction: [x, y, z, if direction.to_light { 1.0 } else { 0.0 }],
            blend: direction.blend,
            ..*self
        }
    }

    /// These params for the `light_seams` pass of `level` and `outward`
    /// ([`super::SEAM_PASSES`]).
    pub fn seam_pass(&self, level: u32, outward: u32) -> LightParams {
        LightParams {
            seam_level: level,
            seam_outward: outward,
            ..*self
        }
    }

    /// The in-scattering directions of `settings` for these params, in refinement
    /// order (the light's direction from the volume's centre orients them).
    pub fn scatter_directions(&self, settings: &LightSettings) -> Vec<ScatterDirection> {
        // Model space is centred on the volume: a point light's position is its
        // direction from the centre.
        let to_light = Vec3::new(self.light[0], self.light[1], self.light[2]);
        scatter_directions(settings.directions, settings.phase_g, to_light)
    }

    /// Atlas texels along x, y, z.
    pub fn atlas_dims(&self) -> [u32; 3] {
        self.volume.atlas_dims()
    }
}

/// What the light stages read besides the data and each other's results, for
/// one set of settings over one packing: the uniforms, the block in each
/// slot, the SVR's mask of blocks and the in-scattering directions. The GPU
/// update, the CPU renderer and the converged CPU twins build it one way.
#[derive(Debug, Clone)]
pub struct LightSetup {
    /// The uniforms.
    pub params: LightParams,
    /// [`crate::illumination::slot_blocks`] of the packing.
    pub slot_blocks: Vec<u32>,
    /// [`crate::illumination::near_blocks`] for the SVR's margin.
    pub svr_blocks: Vec<u32>,
    /// The in-scattering directions, in refinement order.
    pub directions: Vec<ScatterDirection>,
}

impl LightSetup {
    /// The setup for lighting the volume stored as `texture`, packed as
    /// `packing` (`layout` its sizes), with `settings` and a
    /// transfer-function table of `tf_len` entries.
    pub fn new(
        texture: &VolumeTexture,
        settings: &LightSettings,
        packing: &Packing,
        layout: PackedLayout,
        tf_len: u32,
    ) -> LightSetup {
        let params = LightParams::new(texture, settings, packing, layout, tf_len);
        LightSetup {
            slot_blocks: slot_blocks(packing),
            svr_blocks: near_blocks(
                packing,
                params.volume.block_grid,
                params.svr_margin_blocks(),
            ),
            directions: params.scatter_directions(settings),
            params,
        }
    }

    /// The CPU twins' inputs for this setup over `packed` data, classified
    /// by the table `tf`, with the direct light by `method`.
    pub fn twin_inputs<'a>(
        &'a self,
        packed: &'a crate::cpu::PackedTexture,
        tf: &'a [[f32; 4]],
        method: super::DirectLightMethod,
    ) -> crate::cpu::global_light::LightInputs<'a> {
        crate::cpu::global_light::LightInputs {
            params: &self.params,
            packed,
            tf,
            slot_blocks: &self.slot_blocks,
            svr_blocks: &self.svr_blocks,
            directions: &self.directions,
            method,
        }
    }
}
