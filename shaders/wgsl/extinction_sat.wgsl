// extinction_sat: the 3D summed-area table (SAT) of Δt·τ, and of Δt·τ·RGB for
// colour bleeding in the same passes (Schlegel et al. 2011, sec. 3.1), on a
// regular grid over the volume. Two entry points:
//   reconstruct: each cell's Δt·τ from the packed blocks, the mean over sub³
//     samples of τ = −ln(1 − α)/h (h the step TF opacities refer to) times the
//     cell's edge Δt; samples in empty blocks are zero and read nothing. Also
//     writes the cell values to `extinction` (the shadow-ray and sampled-AO
//     references read them).
//   scan: the inclusive prefix sum along `params.axis`, in place, one
//     invocation per grid line; three scans (x, y, z) turn cells into the SAT.
// Precision: cells are fixed point (2^24 per unit of Δt·τ, at most
// MAX_CELL_DEPTH = 4 per cell) and sums 64-bit integers (two u32 words), so a
// 256³ grid of opaque cells (< 2^50) never overflows and every cuboid query is exact up to the
// cells' rounding (2^-25 each); f32 sums would lose all digits of a small
// cuboid's sum next to a large SAT entry.
//
// Dispatch: reconstruct: one invocation per cell, workgroups of 4×4×4;
//           scan: one per line across the other two axes, workgroups of 8×8.
// Bindings (group 0):
//   0 params             uniform ExtinctionParams
//   1 atlas              texture_3d<f32>, the packed data
//   2 atlas_sampler      linear filtering, clamp to edge
//   3 transfer_function  storage array<vec4<f32>>
//   4 block_index        texture_3d<u32> (rgba16uint)
//   5–8 sat_tau, sat_r, sat_g, sat_b   storage array<vec2<u32>>, read-write
//                        (sat_r/g/b only when params.channels == 4)
//   9 extinction         storage texture r32float, grid-shaped (written)
// CPU twin: shaders::cpu::extinction::extinction_sat (shaders/src/cpu/extinction.rs).

@group(0) @binding(0) var<uniform> params: ExtinctionParams;
@group(0) @binding(1) var atlas: texture_3d<f32>;
@group(0) @binding(2) var atlas_sampler: sampler;
@group(0) @binding(3) var<storage, read> transfer_function: array<vec4<f32>>;
@group(0) @binding(4) var block_index: texture_3d<u32>;
@group(0) @binding(5) var<storage, read_write> sat_tau: array<vec2<u32>>;
@group(0) @binding(6) var<storage, read_write> sat_r: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read_write> sat_g: array<vec2<u32>>;
@group(0) @binding(8) var<storage, read_write> sat_b: array<vec2<u32>>;
@group(0) @binding(9) var extinction: texture_storage_3d<r32float, write>;

fn fixed_of(depth: f32) -> vec2<u32> {
    return vec2<u32>(u32(depth * FIXED_ONE + 0.5), 0u);
}

@compute @workgroup_size(4, 4, 4)
fn reconstruct(@builtin(global_invocation_id) gid: vec3<u32>) {
    if any(gid >= params.grid) {
        return;
    }
    let n = f32(params.sub);
    let grid = vec3<f32>(params.grid);
    var sum = vec4<f32>(0.0);
    for (var z = 0u; z < params.sub; z++) {
        for (var y = 0u; y < params.sub; y++) {
            for (var x = 0u; x < params.sub; x++) {
                let tc = (vec3<f32>(gid) + (vec3<f32>(f32(x), f32(y), f32(z)) + 0.5) / n) / grid;
                let loc = locate(tc);
                if !loc.empty {
                    let value = textureSampleLevel(atlas, atlas_sampler, atlas_coord(tc, loc), 0.0).r;
                    let rgba = classify(value * params.volume.value_scale + params.volume.value_offset);
                    let depth = -log(1.0 - min(rgba.a, MAX_SAMPLE_OPACITY)) * params.opacity_scale;
                    sum += vec4<f32>(depth, depth * rgba.rgb);
                }
            }
        }
    }
    let cell = min(sum / (n * n * n), vec4<f32>(MAX_CELL_DEPTH));
    let i = sat_index(vec3<i32>(gid));
    sat_tau[i] = fixed_of(cell.x);
    if params.channels == 4u {
        sat_r[i] = fixed_of(cell.y);
        sat_g[i] = fixed_of(cell.z);
        sat_b[i] = fixed_of(cell.w);
    }
    textureStore(extinction, gid, vec4<f32>(cell.x, 0.0, 0.0, 0.0));
}

@compute @workgroup_size(8, 8, 1)
fn scan(@builtin(global_invocation_id) gid: vec3<u32>) {
    let a = params.axis;
    let b = (a + 1u) % 3u;
    let c = (a + 2u) % 3u;
    if gid.x >= params.grid[b] || gid.y >= params.grid[c] {
        return;
    }
    var cell = vec3<i32>(0);
    cell[b] = i32(gid.x);
    cell[c] = i32(gid.y);
    var run_tau = vec2<u32>(0u);
    var run_r = vec2<u32>(0u);
    var run_g = vec2<u32>(0u);
    var run_b = vec2<u32>(0u);
    for (var k = 0u; k < params.grid[a]; k++) {
        cell[a] = i32(k);
        let i = sat_index(cell);
        run_tau = add64(run_tau, sat_tau[i]);
        sat_tau[i] = run_tau;
        if params.channels == 4u {
            run_r = add64(run_r, sat_r[i]);
            sat_r[i] = run_r;
            run_g = add64(run_g, sat_g[i]);
            sat_g[i] = run_g;
            run_b = add64(run_b, sat_b[i]);
            sat_b[i] = run_b;
        }
    }
}
