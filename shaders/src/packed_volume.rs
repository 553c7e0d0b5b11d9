//! [`PackedVolume`]: the packed volume as every stage that reads packed blocks
//! sees it (the ray caster and both illumination modes' stages), one uniform
//! block mirrored in WGSL (`shaders/wgsl/shared/packed_volume.wgsl`) and read
//! by the CPU twins alike; [`PackedLayout`]: the sizes of a packing.

use crate::volume_texture::VolumeTexture;

/// What the packed stage needs beyond the volume: the atlas and block grid sizes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PackedLayout {
    /// Atlas size in texels.
    pub atlas_dims: [u32; 3],
    /// Blocks along x, y, z.
    pub block_grid: [u32; 3],
}

/// Addressing and classifying packed blocks: the volume's and the atlas's
/// sizes and how texel values map to the transfer function.
// keep in sync with shaders/wgsl/shared/packed_volume.wgsl `PackedVolume`
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PackedVolume {
    /// One level-0 voxel in texture coordinates: 1 / dims.
    pub texel: [f32; 3],
    /// The step transfer-function opacities refer to (mm): the smallest spacing.
    pub reference_step: f32,
    /// Level-0 voxels along x, y, z.
    pub volume_dims: [f32; 3],
    /// Texel value → transfer-function coordinate: scale.
    pub value_scale: f32,
    /// Atlas size in texels (1 where there is no atlas: the reference stage).
    pub atlas_size: [f32; 3],
    /// Texel value → transfer-function coordinate: offset.
    pub value_offset: f32,
    /// Blocks along x, y, z.
    pub block_grid: [u32; 3],
    /// Entries in the transfer-function table.
    pub tf_len: u32,
}

impl PackedVolume {
    /// The volume stored as `texture`, packed as `layout`, classified by a
    /// table of `tf_len` entries.
    pub fn new(texture: &VolumeTexture, layout: PackedLayout, tf_len: u32) -> PackedVolume {
        PackedVolume {
            texel: texture.geometry.dims.map(|d| 1.0 / d as f32),
            reference_step: texture.geometry.min_spacing_f32(),
            volume_dims: texture.geometry.dims.map(|d| d as f32),
            value_scale: texture.value_scale,
            atlas_size: layout.atlas_dims.map(|d| d.max(1) as f32),
            value_offset: texture.value_offset,
            block_grid: layout.block_grid,
            tf_len,
        }
    }

    /// Atlas texels along x, y, z.
    pub fn atlas_dims(&self) -> [u32; 3] {
        self.atlas_size.map(|s| s as u32)
    }
}
