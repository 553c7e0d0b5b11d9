// PackedVolume: the packed volume as every stage that reads packed blocks sees
// it (the `volume` member of each stage's params): the volume's and the atlas's
// sizes and how texel values map to the transfer function.
// keep in sync with shaders/src/packed_volume.rs `PackedVolume`
struct PackedVolume {
    // One level-0 voxel in texture coordinates (1 / dims), and the step
    // transfer-function opacities refer to (mm): opacity correction uses
    // step / reference_step.
    texel: vec3<f32>,
    reference_step: f32,
    // Level-0 voxels along x, y, z, and texel value → transfer-function
    // coordinate: u = value * value_scale + value_offset.
    volume_dims: vec3<f32>,
    value_scale: f32,
    // Atlas size in texels (1 without an atlas), and the offset of the map above.
    atlas_size: vec3<f32>,
    value_offset: f32,
    // Blocks along x, y, z, and transfer-function entries.
    block_grid: vec3<u32>,
    tf_len: u32,
}
