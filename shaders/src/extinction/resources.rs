//! [`ExtinctionVolumes`]: the summed-area table and the extinction stages'
//! textures for one grid size.

use super::{CACHE_FORMAT, EXTINCTION_FORMAT, ExtinctionParams};
use crate::illumination::StageTexture;
use crate::{GpuContext, GpuError};

/// The extinction stages' GPU resources for one grid size.
#[derive(Debug)]
pub struct ExtinctionVolumes {
    /// The SAT, one buffer per channel (τ, τ·R, τ·G, τ·B) of 64-bit fixed-point
    /// sums; the colour buffers hold one entry when colour bleeding is off.
    pub sat: [wgpu::Buffer; 4],
    /// Δt·τ per cell (the references read it).
    pub extinction: StageTexture,
    /// I_AO per cell (rgb; a: grey).
    pub ambient: StageTexture,
    /// The light cache the ray caster reads.
    pub light_cache: StageTexture,
    /// [`super::near_cells_mask`]: per block, 1 where the cache's cells are read.
    pub(super) near_blocks: wgpu::Buffer,
    pub(super) params: wgpu::Buffer,
    pub(super) scan_params: [wgpu::Buffer; 3],
    channels: u32,
}

impl ExtinctionVolumes {
    /// Allocates the SAT and textures for `grid` with `channels` SAT channels,
    /// refusing grids whose SAT buffer exceeds what the adapter can bind.
    pub fn new(
        gpu: &GpuContext,
        grid: [u32; 3],
        channels: u32,
        blocks: usize,
    ) -> Result<ExtinctionVolumes, GpuError> {
        let cells: u64 = grid.iter().map(|&n| u64::from(n)).product();
        let bytes = cells * 8;
        let limits = gpu.device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if bytes > limit {
            return Err(GpuError::Unsupported {
                what: format!(
                    "a summed-area table of {}x{}x{} cells ({} MiB per channel)",
                    grid[0],
                    grid[1],
                    grid[2],
                    bytes >> 20
                ),
                limit: format!(
                    "adapter '{}' binds storage buffers of at most {} MiB: lower the SAT size",
                    gpu.info.name,
                    limit >> 20
                ),
            });
        }
        let buffer = |label: &str, size: u64| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let colour_size = if channels == 4 { bytes } else { 8 };
        let uniform = |label: &str| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size_of::<ExtinctionParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let (sat, params, scan_params, near_blocks) =
            gpu.scoped("allocating the summed-area table", || {
                (
                    [
                        buffer("SAT τ", bytes),
                        buffer("SAT τ·R", colour_size),
                        buffer("SAT τ·G", colour_size),
                        buffer("SAT τ·B", colour_size),
                    ],
                    uniform("extinction params"),
                    [
                        uniform("SAT scan x"),
                        uniform("SAT scan y"),
                        uniform("SAT scan z"),
                    ],
                    buffer("near blocks", (blocks.max(1) * 4) as u64),
                )
            })?;
        Ok(ExtinctionVolumes {
            sat,
            extinction: StageTexture::new(gpu, "extinction", grid, EXTINCTION_FORMAT)?,
            ambient: StageTexture::new(gpu, "ambient occlusion", grid, CACHE_FORMAT)?,
            light_cache: StageTexture::new(gpu, "light cache", grid, CACHE_FORMAT)?,
            near_blocks,
            params,
            scan_params,
            channels,
        })
    }

    /// Reads channel `channel` of the SAT back (x fastest).
    pub fn read_sat(&self, gpu: &GpuContext, channel: usize) -> Result<Vec<u64>, GpuError> {
        let buffer = &self.sat[channel];
        let size = buffer.size();
        let staging = gpu.scoped("reading the summed-area table back", || {
            let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("SAT readback"),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
            gpu.queue.submit([encoder.finish()]);
            staging
        })?;
        gpu.read_buffer(&staging, "the summed-area table", |bytes| {
            bytes
                .chunks_exact(8)
                .map(|w| {
                    let lo = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
                    let hi = u32::from_le_bytes([w[4], w[5], w[6], w[7]]);
                    u64::from(lo) | (u64::from(hi) << 32)
                })
                .collect()
        })
    }

    /// Bindings 0–4 of the stages that query the SAT: params and the channels.
    pub(super) fn sat_bindings(&self) -> Vec<wgpu::BindingResource<'_>> {
        let mut resources = vec![self.params.as_entire_binding()];
        resources.extend(self.sat.iter().map(wgpu::Buffer::as_entire_binding));
        resources
    }

    pub(super) fn fits(&self, grid: [u32; 3], channels: u32, blocks: usize) -> bool {
        self.extinction.dims == grid
            && self.channels == channels
            && self.near_blocks.size() >= (blocks.max(1) * 4) as u64
    }
}
