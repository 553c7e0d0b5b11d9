//! [`StageTexture`]: a 3D texture an illumination stage writes and the next
//! stages (or the ray caster) read, and reading such textures back for tests
//! and the CPU comparisons.

use crate::{GpuContext, GpuError};

/// A 3D texture a stage writes (storage) and others read (sampled).
#[derive(Debug)]
pub struct StageTexture {
    /// The texture.
    pub texture: wgpu::Texture,
    /// A view of it.
    pub view: wgpu::TextureView,
    /// Texels along x, y, z.
    pub dims: [u32; 3],
    /// The texel format.
    pub format: wgpu::TextureFormat,
}

impl StageTexture {
    /// A texture of `dims` texels of `format`, named `label` in errors.
    pub fn new(
        gpu: &GpuContext,
        label: &str,
        dims: [u32; 3],
        format: wgpu::TextureFormat,
    ) -> Result<StageTexture, GpuError> {
        let texture = crate::volume_texture::create_texture_3d_for(
            gpu,
            label,
            dims,
            format,
            wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::STORAGE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
        )?;
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(StageTexture {
            texture,
            view,
            dims,
            format,
        })
    }

    /// Reads every texel back (x fastest) of a one-channel 32-bit float texture.
    pub fn read(&self, gpu: &GpuContext) -> Result<Vec<f32>, GpuError> {
        read_texture_f32(gpu, &self.texture, self.dims)
    }

    /// Reads every texel back as RGBA f32 (x fastest): `rgba16float` textures
    /// as they are, one-channel 32-bit float ones into r.
    pub fn read_rgba(&self, gpu: &GpuContext) -> Result<Vec<[f32; 4]>, GpuError> {
        let bytes = read_texture_bytes(gpu, &self.texture, self.dims, self.format)?;
        Ok(match self.format {
            wgpu::TextureFormat::Rgba16Float => bytes
                .chunks_exact(8)
                .map(|t| {
                    let h = |i: usize| half::f16::from_le_bytes([t[2 * i], t[2 * i + 1]]).to_f32();
                    [h(0), h(1), h(2), h(3)]
                })
                .collect(),
            _ => bytes
                .chunks_exact(4)
                .map(|t| [f32::from_le_bytes([t[0], t[1], t[2], t[3]]), 0.0, 0.0, 0.0])
                .collect(),
        })
    }
}

/// Reads a 3D texture of 4-byte texels back, rows unpadded, x fastest.
fn read_texture_f32(
    gpu: &GpuContext,
    texture: &wgpu::Texture,
    dims: [u32; 3],
) -> Result<Vec<f32>, GpuError> {
    let bytes = read_texture_bytes(gpu, texture, dims, wgpu::TextureFormat::R32Float)?;
    Ok(bytemuck::pod_collect_to_vec::<u8, f32>(&bytes))
}

/// Reads a 3D texture of `format` back as bytes, rows unpadded, x fastest.
pub fn read_texture_bytes(
    gpu: &GpuContext,
    texture: &wgpu::Texture,
    dims: [u32; 3],
    format: wgpu::TextureFormat,
) -> Result<Vec<u8>, GpuError> {
    let [w, h, d] = dims;
    let texel = format.block_copy_size(None).unwrap_or(4);
    let row = w * texel;
    let padded =
        row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let mut out = Vec::with_capacity((row * h * d) as usize);
    // A slab of slices at a time keeps the readback buffer small.
    let slab = ((64u64 << 20) / (u64::from(padded) * u64::from(h))).clamp(1, u64::from(d)) as u32;
    let mut z = 0;
    while z < d {
        let depth = slab.min(d - z);
        let buffer = gpu.scoped("reading a stage texture back", || {
            let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("stage texture readback"),
                size: u64::from(padded) * u64::from(h) * u64::from(depth),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: 0, z },
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &buffer,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(padded),
                        rows_per_image: Some(h),
                    },
                },
                wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: depth,
                },
            );
            gpu.queue.submit([encoder.finish()]);
            buffer
        })?;
        gpu.read_buffer(&buffer, "a stage texture", |bytes| {
            for padded_row in bytes.chunks(padded as usize) {
                out.extend_from_slice(&padded_row[..row as usize]);
            }
        })?;
        z += depth;
    }
    Ok(out)
}
