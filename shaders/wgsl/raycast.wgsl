// raycast: direct volume rendering from packed blocks (flat multiresolution
// blocking). The GPU holds only the blocks the level-of-detail selection kept,
// each at its own level, packed by level in one atlas with a one-voxel apron;
// a block index maps every spatial block to its place in the atlas or marks it
// empty. Per sample: index lookup → atlas coordinate at the block's level →
// hardware trilinear filtering (the apron makes it right across block borders).
// Empty blocks are jumped over. Compositing, MIP/MinIP, clip box and shading
// are in shared/march.wgsl, block addressing in shared/packed.wgsl.
//
// Dispatch: one invocation per pixel, workgroups of 8×8, ceil(width / 8) × ceil(height / 8).
// Bindings (group 0):
//   0 params             uniform RaycastParams
//   1 atlas              texture_3d<f32>, one channel, packed blocks with aprons
//   2 atlas_sampler      linear filtering, clamp to edge
//   3 transfer_function  storage array<vec4<f32>>, tf_len RGBA entries over u in 0..1
//   4 output             storage texture rgba8unorm, width × height
//   5 block_index        texture_3d<u32> (rgba16uint), one texel per block:
//                        atlas position of the block's first interior texel, level
//                        (0..4; EMPTY_LEVEL when the block is not stored)
//   6 light_volume       texture_3d<f32> (r32float, atlas-shaped): the stored light
//                        I_s of global light propagation (lit variant only,
//                        shared/light_volume.wgsl; shared/no_light.wgsl otherwise)
// CPU twin: shaders::cpu::raycast (shaders/src/cpu/raycast.rs), loop for loop.

@group(0) @binding(0) var<uniform> params: RaycastParams;
@group(0) @binding(1) var atlas: texture_3d<f32>;
@group(0) @binding(2) var atlas_sampler: sampler;
@group(0) @binding(3) var<storage, read> transfer_function: array<vec4<f32>>;
@group(0) @binding(4) var output: texture_storage_2d<rgba8unorm, write>;
@group(0) @binding(5) var block_index: texture_3d<u32>;

// The texel value at tc read from block `loc`'s slot.
fn sample_at(tc: vec3<f32>, loc: Location) -> f32 {
    return textureSampleLevel(atlas, atlas_sampler, atlas_coord(tc, loc), 0.0).r;
}

// The central differences of the texel nearest tc in block `loc`'s slot
// (six texels, no filtering; at the block's faces the apron's), per unit of
// texture coordinate: the gradient of faint samples.
fn nearest_difference_at(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    let last = BLOCK * loc.scale - 1.0;
    let nearest = clamp(floor(block_texel(tc, loc)), vec3<f32>(0.0), vec3<f32>(last));
    let n = vec3<i32>(loc.origin + nearest);
    let dx = vec3<i32>(1, 0, 0);
    let dy = vec3<i32>(0, 1, 0);
    let dz = vec3<i32>(0, 0, 1);
    let differences = vec3<f32>(
        textureLoad(atlas, n + dx, 0).r - textureLoad(atlas, n - dx, 0).r,
        textureLoad(atlas, n + dy, 0).r - textureLoad(atlas, n - dy, 0).r,
        textureLoad(atlas, n + dz, 0).r - textureLoad(atlas, n - dz, 0).r,
    );
    return differences / (2.0 * params.volume.texel * voxel_edge(loc));
}

// The value at tc for a gradient around a sample in `home`: from the block tc
// falls in (at that block's level), or from home's apron when that block is
// empty, so central differences stay right across block borders.
fn sample_neighbour(tc: vec3<f32>, home: Location) -> f32 {
    let block = vec3<i32>(floor(tc * params.volume.volume_dims / BLOCK));
    if all(block == home.block) {
        return sample_at(tc, home);
    }
    let other = locate(tc);
    if other.empty {
        return sample_at(tc, home);
    }
    return sample_at(tc, other);
}
