//! [`ExtinctionPipelines`]: the extinction stages compiled, with their bind
//! group layouts.

use super::{CACHE_FORMAT, EXTINCTION_FORMAT, ExtinctionParams};
use crate::pipeline::{
    self, ComputeStage, float_texture_3d, sampler, storage_buffer, storage_buffer_rw,
    storage_texture, uint_texture_3d, unfilterable_texture_3d, uniform,
};
use crate::{GpuContext, GpuError};

/// The compiled extinction stages.
#[derive(Debug)]
pub struct ExtinctionPipelines {
    /// `extinction_sat`, entry point `reconstruct`.
    pub reconstruct: ComputeStage,
    /// `extinction_sat`, entry point `scan`.
    pub scan: ComputeStage,
    /// `ambient_occlusion`.
    pub ambient_occlusion: ComputeStage,
    /// `ambient_occlusion_reference`.
    pub ambient_occlusion_reference: ComputeStage,
    /// `soft_shadow`.
    pub soft_shadow: ComputeStage,
    /// `shadow_ray`.
    pub shadow_ray: ComputeStage,
    /// The linear clamp sampler every stage filters with.
    pub sampler: wgpu::Sampler,
}

impl ExtinctionPipelines {
    /// Compiles the stages.
    pub fn new(gpu: &GpuContext) -> Result<ExtinctionPipelines, GpuError> {
        let source = crate::wgsl::EXTINCTION_SAT;
        let sat = sat_layout();
        Ok(ExtinctionPipelines {
            reconstruct: ComputeStage::with_entry(
                gpu,
                "extinction_sat",
                "reconstruct",
                source,
                &sat,
            )?,
            scan: ComputeStage::with_entry(gpu, "extinction_sat", "scan", source, &sat)?,
            ambient_occlusion: ComputeStage::new(
                gpu,
                "ambient_occlusion",
                crate::wgsl::AMBIENT_OCCLUSION,
                &sat_read_and([write(5, CACHE_FORMAT), storage_buffer(6)]),
            )?,
            ambient_occlusion_reference: ComputeStage::new(
                gpu,
                "ambient_occlusion_reference",
                crate::wgsl::AMBIENT_OCCLUSION_REFERENCE,
                &[
                    params(),
                    unfilterable_texture_3d(1),
                    write(2, CACHE_FORMAT),
                    storage_buffer(3),
                ],
            )?,
            soft_shadow: ComputeStage::new(
                gpu,
                "soft_shadow",
                crate::wgsl::SOFT_SHADOW,
                &sat_read_and([
                    float_texture_3d(5),
                    write(6, CACHE_FORMAT),
                    storage_buffer(7),
                ]),
            )?,
            shadow_ray: ComputeStage::new(
                gpu,
                "shadow_ray",
                crate::wgsl::SHADOW_RAY,
                &[
                    params(),
                    unfilterable_texture_3d(1),
                    float_texture_3d(2),
                    write(3, CACHE_FORMAT),
                    storage_buffer(4),
                ],
            )?,
            sampler: pipeline::linear_sampler(gpu),
        })
    }
}

/// Binding 0: the params.
fn params() -> wgpu::BindGroupLayoutEntry {
    uniform(0, size_of::<ExtinctionParams>())
}

/// A texture of `format` the stage writes.
fn write(binding: u32, format: wgpu::TextureFormat) -> wgpu::BindGroupLayoutEntry {
    storage_texture(
        binding,
        format,
        wgpu::StorageTextureAccess::WriteOnly,
        wgpu::TextureViewDimension::D3,
    )
}

/// `extinction_sat`'s layout: params, atlas, sampler, transfer function,
/// block index, the four SAT channels (read-write) and the extinction texture.
fn sat_layout() -> [wgpu::BindGroupLayoutEntry; 10] {
    [
        params(),
        float_texture_3d(1),
        sampler(2),
        storage_buffer(3),
        uint_texture_3d(4),
        storage_buffer_rw(5),
        storage_buffer_rw(6),
        storage_buffer_rw(7),
        storage_buffer_rw(8),
        write(9, EXTINCTION_FORMAT),
    ]
}

/// The layout of a stage that queries the SAT (params, four channels), then `more`.
fn sat_read_and<const N: usize>(
    more: [wgpu::BindGroupLayoutEntry; N],
) -> Vec<wgpu::BindGroupLayoutEntry> {
    let mut entries = vec![
        params(),
        storage_buffer(1),
        storage_buffer(2),
        storage_buffer(3),
        storage_buffer(4),
    ];
    entries.extend(more);
    entries
}
