//! How voxels become texels: the texel format of a volume, the texel values,
//! and the linear map from a sampled texel value to the transfer-function
//! coordinate. The same description serves the plain texture of the reference
//! renderer and the atlas of packed blocks.
//!
//! 8-bit volumes go to `r8unorm`/`r8snorm`, 16-bit volumes to `r16unorm`/`r16snorm`
//! where the adapter has `TEXTURE_FORMAT_16BIT_NORM`; all of these filter linearly
//! and keep every stored value exact. Everything else (16-bit without that
//! feature, 32-bit integers, floats) goes to `r16float` holding the
//! transfer-function coordinate itself, so the precision of half floats is spent
//! on the range the data occupies; NaN voxels become the bottom of the range.
//! Voxels live in textures, not storage buffers: some adapters cap storage
//! buffers at 128 MiB. [`GpuVolume::upload`] writes a plain texture in slabs of
//! z-slices.

use std::borrow::Cow;

use blocks::store::StoreMeta;
use blocks::{Geometry, ValueMap, Volume, VoxelData, VoxelType};

use crate::{GpuContext, GpuError};

/// Largest slab written to the GPU in one call.
pub const UPLOAD_SLAB_BYTES: usize = 32 << 20;

/// A texel format voxserve stores voxels in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TexelFormat {
    /// 8-bit normalized: texel = stored / 255.
    R8Unorm,
    /// 8-bit signed normalized: texel = max(stored / 127, −1).
    R8Snorm,
    /// 16-bit normalized: texel = stored / 65535.
    R16Unorm,
    /// 16-bit signed normalized: texel = max(stored / 32767, −1).
    R16Snorm,
    /// Half float holding the transfer-function coordinate.
    R16Float,
}

impl TexelFormat {
    /// The wgpu format.
    pub fn wgpu(self) -> wgpu::TextureFormat {
        match self {
            TexelFormat::R8Unorm => wgpu::TextureFormat::R8Unorm,
            TexelFormat::R8Snorm => wgpu::TextureFormat::R8Snorm,
            TexelFormat::R16Unorm => wgpu::TextureFormat::R16Unorm,
            TexelFormat::R16Snorm => wgpu::TextureFormat::R16Snorm,
            TexelFormat::R16Float => wgpu::TextureFormat::R16Float,
        }
    }

    /// Bytes per texel.
    pub fn size(self) -> usize {
        match self {
            TexelFormat::R8Unorm | TexelFormat::R8Snorm => 1,
            TexelFormat::R16Unorm | TexelFormat::R16Snorm | TexelFormat::R16Float => 2,
        }
    }
}

/// What a volume is, as far as texels care: in-memory volumes and stores both
/// describe themselves this way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeDescription {
    /// Level 0's dimensions, spacing, origin and direction.
    pub geometry: Geometry,
    /// Stored voxel type.
    pub voxel_type: VoxelType,
    /// Stored → physical values.
    pub value_map: ValueMap,
    /// Smallest and largest physical value.
    pub value_range: [f32; 2],
}

impl VolumeDescription {
    /// An in-memory volume's description.
    pub fn of_volume(v: &Volume) -> VolumeDescription {
        VolumeDescription {
            geometry: v.geometry,
            voxel_type: v.voxel_type(),
            value_map: v.value_map,
            value_range: v.value_range,
        }
    }

    /// A store's description (level 0).
    pub fn of_store(m: &StoreMeta, voxel_type: VoxelType) -> VolumeDescription {
        VolumeDescription {
            geometry: m.geometry,
            voxel_type,
            value_map: m.value_map,
            value_range: m.value_range().map(|v| v as f32),
        }
    }
}

/// The texel format of a volume and how its texels map to the transfer function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeTexture {
    /// Level 0's dimensions, spacing, origin and direction; the GPU's `f32`
    /// values come from its `*_f32` methods.
    pub geometry: Geometry,
    /// Storage format.
    pub format: TexelFormat,
    /// Stored voxel type.
    pub voxel_type: VoxelType,
    /// Stored → physical values.
    pub value_map: ValueMap,
    /// The physical value range the transfer-function table covers.
    pub tf_domain: [f32; 2],
    /// Transfer-function coordinate = texel * value_scale + value_offset.
    pub value_scale: f32,
    /// See `value_scale`.
    pub value_offset: f32,
}

impl VolumeTexture {
    /// Chooses the format for a volume given the device's features and derives
    /// the texel → transfer-function map.
    pub fn new(v: VolumeDescription, features: wgpu::Features) -> VolumeTexture {
        let norm16 = features.contains(wgpu::Features::TEXTURE_FORMAT_16BIT_NORM);
        let format = match v.voxel_type {
            VoxelType::U8 => TexelFormat::R8Unorm,
            VoxelType::I8 => TexelFormat::R8Snorm,
            VoxelType::U16 if norm16 => TexelFormat::R16Unorm,
            VoxelType::I16 if norm16 => TexelFormat::R16Snorm,
            _ => TexelFormat::R16Float,
        };
        let tf_domain = tf_domain(v.value_range);
        let width = tf_domain[1] - tf_domain[0];
        let (value_scale, value_offset) = match (format, v.voxel_type.max_stored()) {
            (TexelFormat::R16Float, _) | (_, None) => (1.0, 0.0),
            (_, Some(max_stored)) => {
                // texel t = stored / max; physical = stored * slope + intercept;
                // u = (physical - domain_min) / width.
                (
                    max_stored * v.value_map.slope / width,
                    (v.value_map.intercept - tf_domain[0]) / width,
                )
            }
        };
        VolumeTexture {
            geometry: v.geometry,
            format,
            voxel_type: v.voxel_type,
            value_map: v.value_map,
            tf_domain,
            value_scale,
            value_offset,
        }
    }

    /// [`VolumeTexture::new`] for an in-memory volume.
    pub fn for_volume(volume: &Volume, features: wgpu::Features) -> VolumeTexture {
        VolumeTexture::new(VolumeDescription::of_volume(volume), features)
    }

    /// The texel values of `data` as the GPU samples them, as `f32`: what the CPU
    /// twins read.
    pub fn texel_values(&self, data: &VoxelData) -> Vec<f32> {
        // The normalized conversions of the WebGPU spec; snorm clamps the most
        // negative value to −1.
        match (self.format, data) {
            (TexelFormat::R8Unorm, VoxelData::U8(v)) => {
                v.iter().map(|&s| f32::from(s) / 255.0).collect()
            }
            (TexelFormat::R8Snorm, VoxelData::I8(v)) => v
                .iter()
                .map(|&s| (f32::from(s) / 127.0).max(-1.0))
                .collect(),
            (TexelFormat::R16Unorm, VoxelData::U16(v)) => {
                v.iter().map(|&s| f32::from(s) / 65535.0).collect()
            }
            (TexelFormat::R16Snorm, VoxelData::I16(v)) => v
                .iter()
                .map(|&s| (f32::from(s) / 32767.0).max(-1.0))
                .collect(),
            _ => self.half_texels(data).iter().map(|h| h.to_f32()).collect(),
        }
    }

    /// The texel bytes of `data` to upload.
    pub fn texel_bytes<'a>(&self, data: &'a VoxelData) -> Cow<'a, [u8]> {
        match self.format {
            TexelFormat::R8Unorm
            | TexelFormat::R8Snorm
            | TexelFormat::R16Unorm
            | TexelFormat::R16Snorm => data.as_bytes().into(),
            TexelFormat::R16Float => bytemuck::cast_slice::<half::f16, u8>(&self.half_texels(data))
                .to_vec()
                .into(),
        }
    }

    /// Texels as half floats holding the transfer-function coordinate.
    fn half_texels(&self, data: &VoxelData) -> Vec<half::f16> {
        let [lo, hi] = self.tf_domain;
        (0..data.len())
            .map(|i| {
                let physical = self.value_map.physical(data.get(i));
                let u = (physical - f64::from(lo)) / f64::from(hi - lo);
                half::f16::from_f64(if u.is_nan() { 0.0 } else { u })
            })
            .collect()
    }
}

/// The transfer-function domain for a physical value range: the range itself, or
/// one unit around it when the volume is constant.
fn tf_domain(range: [f32; 2]) -> [f32; 2] {
    if range[1] > range[0] {
        range
    } else {
        [range[0] - 0.5, range[0] + 0.5]
    }
}

/// A 3D texture of one-channel texels on the GPU, sampled by shaders and
/// written by uploads.
pub fn create_texture_3d(
    gpu: &GpuContext,
    label: &str,
    dims: [u32; 3],
    format: wgpu::TextureFormat,
) -> Result<wgpu::Texture, GpuError> {
    create_texture_3d_for(
        gpu,
        label,
        dims,
        format,
        wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
    )
}

/// A 3D texture of one-channel texels on the GPU with `usage`; dimensions
/// beyond the adapter's limit are refused with the numbers.
pub fn create_texture_3d_for(
    gpu: &GpuContext,
    label: &str,
    dims: [u32; 3],
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> Result<wgpu::Texture, GpuError> {
    let max = gpu.device.limits().max_texture_dimension_3d;
    if dims.iter().any(|&d| d > max || d == 0) {
        return Err(GpuError::Unsupported {
            what: format!("a 3D texture '{label}' of {dims:?} texels"),
            limit: format!(
                "adapter '{}' allows 1 to {max} texels per axis",
                gpu.info.name
            ),
        });
    }
    gpu.scoped(&format!("creating the {label} texture"), || {
        gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width: dims[0],
                height: dims[1],
                depth_or_array_layers: dims[2],
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format,
            usage,
            view_formats: &[],
        })
    })
}

/// Writes `bytes` (x fastest, `texel_size` bytes per texel) into `texture` as a
/// box of `size` texels at `origin`.
pub fn write_box(
    gpu: &GpuContext,
    texture: &wgpu::Texture,
    origin: [u32; 3],
    size: [u32; 3],
    texel_size: usize,
    bytes: &[u8],
) {
    gpu.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d {
                x: origin[0],
                y: origin[1],
                z: origin[2],
            },
            aspect: wgpu::TextureAspect::All,
        },
        bytes,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(size[0] * texel_size as u32),
            rows_per_image: Some(size[1]),
        },
        wgpu::Extent3d {
            width: size[0],
            height: size[1],
            depth_or_array_layers: size[2],
        },
    );
}

/// A whole volume resident on the GPU as one plain 3D texture (the reference renderer's).
#[derive(Debug)]
pub struct GpuVolume {
    /// The texture.
    pub texture: wgpu::Texture,
    /// A view of the whole texture.
    pub view: wgpu::TextureView,
    /// Its format and value map.
    pub desc: VolumeTexture,
}

impl GpuVolume {
    /// Creates the texture and writes the volume into it slab by slab.
    pub fn upload(gpu: &GpuContext, volume: &Volume) -> Result<GpuVolume, GpuError> {
        let desc = VolumeTexture::for_volume(volume, gpu.device.features());
        let dims = volume.geometry.dims;
        let texture = create_texture_3d(gpu, "volume", dims, desc.format.wgpu())?;
        let [nx, ny, nz] = dims;
        let bytes = desc.texel_bytes(&volume.voxels);
        let slice_bytes = volume.geometry.slice_voxels() as usize * desc.format.size();
        let slab_slices = (UPLOAD_SLAB_BYTES / slice_bytes).max(1) as u32;
        gpu.scoped("uploading the volume", || {
            let mut z = 0;
            while z < nz {
                let depth = slab_slices.min(nz - z);
                let start = z as usize * slice_bytes;
                let end = start + depth as usize * slice_bytes;
                write_box(
                    gpu,
                    &texture,
                    [0, 0, z],
                    [nx, ny, depth],
                    desc.format.size(),
                    &bytes[start..end],
                );
                // Submit each slab so the staging memory of the previous one is freed.
                gpu.queue.submit([]);
                z += depth;
            }
        })?;
        gpu.wait("uploading the volume")?;
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(GpuVolume {
            texture,
            view,
            desc,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use blocks::{ValueMap, VoxelData};

    fn ct(voxels: Vec<u16>) -> Volume {
        Volume::new(
            "ct",
            Geometry::new([voxels.len() as u32, 1, 1], [1.0; 3]),
            VoxelData::U16(voxels),
            ValueMap {
                slope: 1.0,
                intercept: -1024.0,
            },
        )
        .expect("valid volume")
    }

    #[test]
    fn unorm_texels_map_onto_the_value_range() {
        let v = ct(vec![24, 1024, 2024]);
        let t = VolumeTexture::for_volume(&v, wgpu::Features::TEXTURE_FORMAT_16BIT_NORM);
        assert_eq!(t.format, TexelFormat::R16Unorm);
        let texels = t.texel_values(&v.voxels);
        let u: Vec<f32> = texels
            .iter()
            .map(|x| x * t.value_scale + t.value_offset)
            .collect();
        for (got, want) in u.iter().zip([0.0, 0.5, 1.0]) {
            assert!((got - want).abs() < 1e-5, "{u:?}");
        }
    }

    #[test]
    fn without_16bit_norm_texels_hold_the_tf_coordinate_in_half_floats() {
        let v = ct(vec![24, 1024, 2024]);
        let t = VolumeTexture::for_volume(&v, wgpu::Features::empty());
        assert_eq!(t.format, TexelFormat::R16Float);
        assert_eq!((t.value_scale, t.value_offset), (1.0, 0.0));
        let texels = t.texel_values(&v.voxels);
        for (got, want) in texels.iter().zip([0.0, 0.5, 1.0]) {
            assert!((got - want).abs() < 1e-3, "{texels:?}");
        }
        assert_eq!(t.texel_bytes(&v.voxels).len(), 6);
    }

    #[test]
    fn a_constant_volume_gets_a_non_empty_domain() {
        let v = ct(vec![100, 100]);
        let t = VolumeTexture::for_volume(&v, wgpu::Features::TEXTURE_FORMAT_16BIT_NORM);
        assert!(t.tf_domain[1] > t.tf_domain[0]);
        assert!(t.value_scale.is_finite() && t.value_offset.is_finite());
    }
}
