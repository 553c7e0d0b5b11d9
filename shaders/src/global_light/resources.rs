//! [`LightVolumes`]: the global light's textures and buffers for one atlas
//! layout and shadow-volume size.

use super::{LIGHT_FORMAT, LightParams};
use crate::illumination::StageTexture;
use crate::{GpuContext, GpuError};

/// The light's GPU resources for one atlas layout and SVR size.
#[derive(Debug)]
pub struct LightVolumes {
    /// α_lp, atlas-shaped.
    pub local_opacity: StageTexture,
    /// α_g, the SVR.
    pub shadow_volume: StageTexture,
    /// I_d, atlas-shaped.
    pub direct_light: StageTexture,
    /// I_s, atlas-shaped: what the ray caster reads.
    pub light_volume: StageTexture,
    pub(super) params: wgpu::Buffer,
    pub(super) slot_blocks: wgpu::Buffer,
    slot_capacity: usize,
    /// [`crate::illumination::near_blocks`] for the SVR's margin, one u32 per block.
    pub(super) svr_blocks: wgpu::Buffer,
    block_count: usize,
}

impl LightVolumes {
    /// Allocates the textures for atlases of `atlas_dims` and an SVR of `svr_dims`.
    pub fn new(
        gpu: &GpuContext,
        atlas_dims: [u32; 3],
        svr_dims: [u32; 3],
        slots: usize,
        block_count: usize,
    ) -> Result<LightVolumes, GpuError> {
        let buffers = gpu.scoped("creating light buffers", || {
            (
                gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("light params"),
                    size: size_of::<LightParams>() as u64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
                gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("slot blocks"),
                    size: (slots.max(1) * 4) as u64,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
                gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("svr blocks"),
                    size: (block_count.max(1) * 4) as u64,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
            )
        })?;
        Ok(LightVolumes {
            local_opacity: StageTexture::new(gpu, "local opacity atlas", atlas_dims, LIGHT_FORMAT)?,
            shadow_volume: StageTexture::new(gpu, "shadow volume", svr_dims, LIGHT_FORMAT)?,
            direct_light: StageTexture::new(gpu, "direct light atlas", atlas_dims, LIGHT_FORMAT)?,
            light_volume: StageTexture::new(gpu, "light volume", atlas_dims, LIGHT_FORMAT)?,
            params: buffers.0,
            slot_blocks: buffers.1,
            slot_capacity: slots.max(1),
            svr_blocks: buffers.2,
            block_count: block_count.max(1),
        })
    }

    pub(super) fn fits(
        &self,
        atlas_dims: [u32; 3],
        svr_dims: [u32; 3],
        slots: usize,
        block_count: usize,
    ) -> bool {
        self.local_opacity.dims == atlas_dims
            && self.shadow_volume.dims == svr_dims
            && self.slot_capacity >= slots
            && self.block_count >= block_count
    }
}
