// ambient_occlusion: I_AO (eq. 4) and colour bleeding I_AO_RGB (eq. 5) per
// light-cache cell from the SAT, by cuboid shells (fig. 5, sec. 3.2). Shell i
// (0..N−1) is the cube of half-edge r_i cells around the cell minus the cube
// of r_{i−1} (r_{−1} = 0: the cell itself is left out); the outer cube has the
// volume of the sphere of radius R. Its sum of Δt·τ, one SAT query
// difference, is weighted by w_i, the mean 1/|o|² over its cells (eq. 8's
// inverse square of the shell's radius; both per shell in params):
//   D = Σ_i (SAT(Sh_i) − SAT(Sh_{i−1})) · w_i.
// D over the same weights for a full neighbourhood (ao_norm, cells outside
// the grid count as empty) is the weighted mean Δt·τ per cell (at most
// MAX_CELL_DEPTH), the exponent of eq. 8 with w_A = r^−2 made independent of
// the number of shells and of R:
//   I_AO = exp(−strength · D / ao_norm).
// A flat opaque surface (half its neighbourhood at the cap) reads
// exp(−2·strength), a crevice less, open space 1.
// Colour bleeding reads eq. 5's C_RGB as the colour a neighbour scatters, so
// the light it takes away is Δt·τ·(1 − C_RGB): channel c uses
// SAT_τ − SAT_τc, tinting a cell towards its neighbours' colour.
//
// Dispatch: one invocation per cell, workgroups of 4×4×4.
// Bindings (group 0):
//   0 params             uniform ExtinctionParams
//   1–4 sat_tau, sat_r, sat_g, sat_b   storage array<vec2<u32>> (read)
//   5 ambient            storage texture rgba16float, grid-shaped (written):
//                        I_AO per channel (rgb; grey without colour bleeding), a: I_AO of τ
//                        (1 in cells the ray caster never reads, shared/near_cells.wgsl)
//   6 near_blocks        storage array<u32>, per block: 1 near a stored block
// CPU twin: shaders::cpu::extinction::ambient_occlusion (shaders/src/cpu/extinction.rs).

@group(0) @binding(0) var<uniform> params: ExtinctionParams;
@group(0) @binding(1) var<storage, read> sat_tau: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> sat_r: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> sat_g: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read> sat_b: array<vec2<u32>>;
@group(0) @binding(5) var ambient: texture_storage_3d<rgba16float, write>;
@group(0) @binding(6) var<storage, read> near_blocks: array<u32>;

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
    let colour = params.channels == 4u;
    // Sums of the cube inside the current shell: the cell itself first.
    var inner = array<vec2<u32>, 4>(
        cuboid_sum(c, c, 0u), vec2<u32>(0u), vec2<u32>(0u), vec2<u32>(0u));
    if colour {
        inner[1] = cuboid_sum(c, c, 1u);
        inner[2] = cuboid_sum(c, c, 2u);
        inner[3] = cuboid_sum(c, c, 3u);
    }
    var depth = vec4<f32>(0.0);
    for (var i = 0u; i < params.ao_shells; i++) {
        let r = i32(params.shell_radii[i / 4u][i % 4u]);
        let w = params.shell_weights[i / 4u][i % 4u];
        let lo = c - vec3<i32>(r);
        let hi = c + vec3<i32>(r);
        let tau = cuboid_sum(lo, hi, 0u);
        depth.x += depth_of(sub64(tau, inner[0])) * w;
        inner[0] = tau;
        if colour {
            for (var ch = 1u; ch < 4u; ch++) {
                let sum = cuboid_sum(lo, hi, ch);
                depth[ch] += depth_of(sub64(sum, inner[ch])) * w;
                inner[ch] = sum;
            }
        }
    }
    let k = params.ao_strength / params.ao_norm;
    let grey = exp(-k * depth.x);
    var out = vec4<f32>(grey, grey, grey, grey);
    if colour {
        // Δt·τ·(1 − C) = Δt·τ − Δt·τ·C, never below zero.
        out = vec4<f32>(exp(-k * max(vec3<f32>(depth.x) - depth.yzw, vec3<f32>(0.0))), grey);
    }
    textureStore(ambient, gid, out);
}
