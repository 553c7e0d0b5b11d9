// reference: the same ray march over one plain 3D texture holding the whole
// volume at full resolution — no blocks, no levels, nothing skipped. Used by
// tests and benchmarks to check and price the packed `raycast` stage.
//
// Dispatch: one invocation per pixel, workgroups of 8×8, ceil(width / 8) × ceil(height / 8).
// Bindings (group 0):
//   0 params             uniform RaycastParams
//   1 volume             texture_3d<f32>, one channel, the whole level-0 volume
//   2 volume_sampler     linear filtering, clamp to edge
//   3 transfer_function  storage array<vec4<f32>>, tf_len RGBA entries over u in 0..1
//   4 output             storage texture rgba8unorm, width × height
// CPU twin: shaders::cpu::reference (shaders/src/cpu/reference.rs), loop for loop.

@group(0) @binding(0) var<uniform> params: RaycastParams;
@group(0) @binding(1) var volume: texture_3d<f32>;
@group(0) @binding(2) var volume_sampler: sampler;
@group(0) @binding(3) var<storage, read> transfer_function: array<vec4<f32>>;
@group(0) @binding(4) var output: texture_storage_2d<rgba8unorm, write>;

struct Location {
    empty: bool,
}

fn locate(tc: vec3<f32>) -> Location {
    return Location(false);
}

// The reference holds every voxel at level 0.
fn voxel_edge(loc: Location) -> f32 {
    return 1.0;
}

fn sample_at(tc: vec3<f32>, loc: Location) -> f32 {
    return textureSampleLevel(volume, volume_sampler, tc, 0.0).r;
}

// The reference is never lit: illumination is compared packed against packed.
fn light_at(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    return vec3<f32>(1.0);
}

fn sample_neighbour(tc: vec3<f32>, home: Location) -> f32 {
    return sample_at(tc, home);
}

// The central differences of the voxel nearest tc (six texels, no
// filtering; clamped to the volume's edge), per unit of texture coordinate.
fn nearest_difference_at(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    let dims = vec3<i32>(textureDimensions(volume));
    let n = clamp(vec3<i32>(floor(tc * vec3<f32>(dims))), vec3<i32>(0), dims - 1);
    let differences = vec3<f32>(
        load_clamped(n + vec3<i32>(1, 0, 0)) - load_clamped(n - vec3<i32>(1, 0, 0)),
        load_clamped(n + vec3<i32>(0, 1, 0)) - load_clamped(n - vec3<i32>(0, 1, 0)),
        load_clamped(n + vec3<i32>(0, 0, 1)) - load_clamped(n - vec3<i32>(0, 0, 1)),
    );
    return differences / (2.0 * params.volume.texel);
}

// The voxel at `n`, clamped to the volume's edge.
fn load_clamped(n: vec3<i32>) -> f32 {
    let last = vec3<i32>(textureDimensions(volume)) - 1;
    return textureLoad(volume, clamp(n, vec3<i32>(0), last), 0).r;
}

// Never called: nothing is empty in a plain texture.
fn empty_exit(origin: vec3<f32>, dir: vec3<f32>, loc: Location) -> f32 {
    return 0.0;
}
