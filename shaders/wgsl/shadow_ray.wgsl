// shadow_ray: the classic shadow ray (the paper's fig. 4, left), the reference
// soft_shadow is measured against: per cell and light, Δt·τ summed along the
// straight line to the light at ray_step cells per sample (the paper's 250
// samples per volume edge), from where the cone's first cuboid starts (half a
// cell along the main axis) to the light or the grid's edge, reading each
// sample's cell; the cache is filled as soft_shadow fills it.
//
// Entry point: shared/light_cache_fill.wgsl.
// Dispatch: one invocation per cell, workgroups of 4×4×4.
// Bindings (group 0):
//   0 params             uniform ExtinctionParams
//   1 extinction         texture_3d<f32> (r32float), Δt·τ per cell
//   2 ambient            texture_3d<f32> (rgba16float), I_AO
//   3 light_cache        storage texture rgba16float, grid-shaped (written)
//   4 near_blocks        storage array<u32>, per block: 1 near a stored block
// CPU twin: shaders::cpu::extinction::shadow_ray (shaders/src/cpu/extinction.rs).

@group(0) @binding(0) var<uniform> params: ExtinctionParams;
@group(0) @binding(1) var extinction: texture_3d<f32>;
@group(0) @binding(2) var ambient: texture_3d<f32>;
@group(0) @binding(3) var light_cache: texture_storage_3d<rgba16float, write>;
@group(0) @binding(4) var<storage, read> near_blocks: array<u32>;

// The most samples of one shadow ray.
const MAX_RAY_STEPS: u32 = 8192u;

// Δt·τ summed along the ray from cell c to `light` (shared/light_cache_fill.wgsl
// calls it per light).
fn occlusion_depth(light: ExtinctionLight, c: vec3<i32>) -> f32 {
    let p = vec3<f32>(c) + 0.5;
    let v = towards(light, p);
    let distance = length(v);
    let va = max(abs(v.x), max(abs(v.y), abs(v.z)));
    if va < 1e-6 {
        return 0.0;
    }
    let dir = v / distance;
    var t_end = 1e9;
    if light.position.w != 0.0 {
        t_end = distance;
    }
    let last = vec3<i32>(params.grid) - vec3<i32>(1);
    var depth = 0.0;
    var t = 0.5 * distance / va + 0.5 * params.ray_step;
    for (var k = 0u; k < MAX_RAY_STEPS; k++) {
        if t > t_end {
            break;
        }
        let cell = vec3<i32>(floor(p + dir * t));
        if any(cell < vec3<i32>(0)) || any(cell > last) {
            break;
        }
        depth += textureLoad(extinction, cell, 0).r * params.ray_step;
        t += params.ray_step;
    }
    return depth;
}
