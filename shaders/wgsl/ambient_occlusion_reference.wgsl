// ambient_occlusion_reference: I_AO (eq. 4) by explicit sampling of the
// spherical neighbourhood (the paper's fig. 2 and 5, left): every cell o with
// 0 < |o| ≤ R (cells) around the cell, its Δt·τ weighted by 1/|o|²,
//   D = Σ Δt·τ(c + o) / |o|²,   I_AO = exp(−strength · D / norm),
// norm the same weights summed over the whole sphere (cells outside the grid
// count as empty). The measure `ambient_occlusion` is compared against; grey
// only (no colour bleeding).
//
// Dispatch: one invocation per cell, workgroups of 4×4×4.
// Bindings (group 0):
//   0 params             uniform ExtinctionParams (ao_norm: the sphere's norm)
//   1 extinction         texture_3d<f32> (r32float), Δt·τ per cell
//   2 ambient            storage texture rgba16float, grid-shaped (written; 1 in
//                        cells the ray caster never reads, shared/near_cells.wgsl)
//   3 near_blocks        storage array<u32>, per block: 1 near a stored block
// CPU twin: shaders::cpu::extinction::ambient_occlusion_reference.

@group(0) @binding(0) var<uniform> params: ExtinctionParams;
@group(0) @binding(1) var extinction: texture_3d<f32>;
@group(0) @binding(2) var ambient: texture_storage_3d<rgba16float, write>;
@group(0) @binding(3) var<storage, read> near_blocks: array<u32>;

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if any(gid >= params.grid) {
        return;
    }
    let c = vec3<i32>(gid);
    if !cell_is_read(c) {
        textureStore(ambient, gid, vec4<f32>(1.0));
        return;
    }
    let r = i32(params.ao_radius);
    let r2 = r * r;
    let last = vec3<i32>(params.grid) - vec3<i32>(1);
    var depth = 0.0;
    for (var z = -r; z <= r; z++) {
        for (var y = -r; y <= r; y++) {
            for (var x = -r; x <= r; x++) {
                let d2 = x * x + y * y + z * z;
                let p = c + vec3<i32>(x, y, z);
                if d2 == 0 || d2 > r2 || any(p < vec3<i32>(0)) || any(p > last) {
                    continue;
                }
                depth += textureLoad(extinction, p, 0).r / f32(d2);
            }
        }
    }
    let grey = exp(-params.ao_strength * depth / params.ao_norm);
    textureStore(ambient, gid, vec4<f32>(grey));
}
