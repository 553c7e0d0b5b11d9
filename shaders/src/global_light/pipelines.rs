//! [`LightPipelines`]: the global light stages compiled, with their bind
//! group layouts.

use super::{LIGHT_FORMAT, LightParams};
use crate::pipeline::{
    self, ComputeStage, float_texture_3d as float3d, sampler, storage_buffer, storage_texture,
    uint_texture_3d, uniform,
};
use crate::{GpuContext, GpuError};

/// The compiled light stages.
#[derive(Debug)]
pub struct LightPipelines {
    /// `local_opacity`.
    pub local_opacity: ComputeStage,
    /// `global_opacity`.
    pub global_opacity: ComputeStage,
    /// `direct_light`.
    pub direct_light: ComputeStage,
    /// `in_scatter`.
    pub in_scatter: ComputeStage,
    /// `light_seams`.
    pub light_seams: ComputeStage,
    /// `direct_light_reference`.
    pub direct_light_reference: ComputeStage,
    /// The linear clamp sampler every stage filters with.
    pub sampler: wgpu::Sampler,
}

impl LightPipelines {
    /// Compiles the stages; refused on adapters whose 32-bit float textures do
    /// not filter.
    pub fn new(gpu: &GpuContext) -> Result<LightPipelines, GpuError> {
        if !gpu
            .device
            .features()
            .contains(wgpu::Features::FLOAT32_FILTERABLE)
        {
            return Err(GpuError::Unsupported {
                what: "global light propagation".into(),
                limit: format!(
                    "adapter '{}' cannot filter 32-bit float textures (wgpu feature FLOAT32_FILTERABLE)",
                    gpu.info.name
                ),
            });
        }
        let stage = |name, source, layout: &[wgpu::BindGroupLayoutEntry]| {
            ComputeStage::new(gpu, name, source, layout)
        };
        Ok(LightPipelines {
            local_opacity: stage(
                "local_opacity",
                crate::wgsl::LOCAL_OPACITY,
                &with_data([write(6)]),
            )?,
            global_opacity: stage(
                "global_opacity",
                crate::wgsl::GLOBAL_OPACITY,
                &[
                    params(),
                    float3d(1),
                    sampler(2),
                    uint_texture_3d(3),
                    write(4),
                    storage_buffer(5),
                ],
            )?,
            direct_light: stage(
                "direct_light",
                crate::wgsl::DIRECT_LIGHT,
                &[
                    params(),
                    float3d(1),
                    float3d(2),
                    sampler(3),
                    storage_buffer(4),
                    write(5),
                ],
            )?,
            in_scatter: stage(
                "in_scatter",
                crate::wgsl::IN_SCATTER,
                &with_data([float3d(6), float3d(7), read_write(8)]),
            )?,
            light_seams: stage(
                "light_seams",
                crate::wgsl::LIGHT_SEAMS,
                &[
                    params(),
                    uint_texture_3d(1),
                    storage_buffer(2),
                    read_write(3),
                ],
            )?,
            direct_light_reference: stage(
                "direct_light_reference",
                crate::wgsl::DIRECT_LIGHT_REFERENCE,
                &with_data([write(6)]),
            )?,
            sampler: pipeline::linear_sampler(gpu),
        })
    }
}

/// Binding 0: the params.
fn params() -> wgpu::BindGroupLayoutEntry {
    uniform(0, size_of::<LightParams>())
}

/// A light texture the stage writes.
fn write(binding: u32) -> wgpu::BindGroupLayoutEntry {
    storage_texture(
        binding,
        LIGHT_FORMAT,
        wgpu::StorageTextureAccess::WriteOnly,
        wgpu::TextureViewDimension::D3,
    )
}

/// A light texture the stage reads and writes (in_scatter's blend).
fn read_write(binding: u32) -> wgpu::BindGroupLayoutEntry {
    storage_texture(
        binding,
        LIGHT_FORMAT,
        wgpu::StorageTextureAccess::ReadWrite,
        wgpu::TextureViewDimension::D3,
    )
}

/// The layout of the stages that read the packed data (params, atlas,
/// sampler, transfer function, block index, slot blocks), then `more`.
fn with_data<const N: usize>(
    more: [wgpu::BindGroupLayoutEntry; N],
) -> Vec<wgpu::BindGroupLayoutEntry> {
    let mut entries = vec![
        params(),
        float3d(1),
        sampler(2),
        storage_buffer(3),
        uint_texture_3d(4),
        storage_buffer(5),
    ];
    entries.extend(more);
    entries
}
