// light_data: bindings 0–5 of the light stages that read the packed data
// (local_opacity, in_scatter, direct_light_reference); the Rust side builds
// the same list once (shaders/src/light.rs `LightPipelines::new`, `data`).
//   0 params             uniform LightParams
//   1 atlas              texture_3d<f32>, the packed data
//   2 atlas_sampler      linear filtering, clamp to edge
//   3 transfer_function  storage array<vec4<f32>>
//   4 block_index        texture_3d<u32> (rgba16uint)
//   5 slot_blocks        storage array<u32>: the block in each slot, or NO_BLOCK

@group(0) @binding(0) var<uniform> params: LightParams;
@group(0) @binding(1) var atlas: texture_3d<f32>;
@group(0) @binding(2) var atlas_sampler: sampler;
@group(0) @binding(3) var<storage, read> transfer_function: array<vec4<f32>>;
@group(0) @binding(4) var block_index: texture_3d<u32>;
@group(0) @binding(5) var<storage, read> slot_blocks: array<u32>;
