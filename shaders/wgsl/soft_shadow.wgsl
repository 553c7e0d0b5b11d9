// soft_shadow: directional soft shadows and scattering I_Sh (eq. 7) by cuboid
// SAT queries along a cone towards each light (fig. 7, sec. 3.3), and the
// light cache: per cell, ambient plus every light,
//   cache = I_A · I_AO_RGB + Σ_L colour_L · spot_L · exp(−Σ_k h_k · SAT(Q_k)).
// The cone's main axis is the grid axis nearest the direction to the light;
// cuboid k spans main-axis cells (prev + 1)..=round(d_k), d_k advancing by a
// spacing that starts at cone_first cells and grows by cone_growth per cuboid,
// and across the other axes the cone's cross-section at the slab's middle
// (half-width mid·|v|/|v_a|·tan θ + ½ cell, centred on the cone's axis). The
// weight h_k = ℓ_k / V_q (the paper's inverse query size, times the length
// ℓ_k the axis runs through the slab) makes each term the mean Δt·τ of the
// cuboid over that length, so a narrow cone converges to the shadow ray.
// Cuboids stop at the light (point and spot lights, inside the volume too) or
// where the main axis leaves the grid; cells outside the grid count as empty.
//
// Entry point: shared/light_cache_fill.wgsl.
// Dispatch: one invocation per cell, workgroups of 4×4×4.
// Bindings (group 0):
//   0 params             uniform ExtinctionParams (lights in grid coordinates)
//   1–4 sat_tau, sat_r, sat_g, sat_b   storage array<vec2<u32>> (read; only
//                        sat_tau is queried, the others share ambient_occlusion's list)
//   5 ambient            texture_3d<f32> (rgba16float), I_AO from ambient_occlusion
//   6 light_cache        storage texture rgba16float, grid-shaped (written)
//   7 near_blocks        storage array<u32>, per block: 1 near a stored block
// CPU twin: shaders::cpu::extinction::soft_shadow (shaders/src/cpu/extinction.rs).

@group(0) @binding(0) var<uniform> params: ExtinctionParams;
@group(0) @binding(1) var<storage, read> sat_tau: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> sat_r: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> sat_g: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read> sat_b: array<vec2<u32>>;
@group(0) @binding(5) var ambient: texture_3d<f32>;
@group(0) @binding(6) var light_cache: texture_storage_3d<rgba16float, write>;
@group(0) @binding(7) var<storage, read> near_blocks: array<u32>;

// Σ_k h_k · SAT(Q_k): the optical depth through the cone from cell c towards
// `light` (shared/light_cache_fill.wgsl calls it per light).
fn occlusion_depth(light: ExtinctionLight, c: vec3<i32>) -> f32 {
    let p = vec3<f32>(c) + 0.5;
    let v = towards(light, p);
    let av = abs(v);
    var a = 0u;
    if av.y > av[a] {
        a = 1u;
    }
    if av.z > av[a] {
        a = 2u;
    }
    let va = av[a];
    if va < 1e-6 {
        return 0.0;
    }
    var d_end = 1e9;
    if light.position.w != 0.0 {
        d_end = va;
    }
    let b = (a + 1u) % 3u;
    let e = (a + 2u) % 3u;
    let sign = select(-1, 1, v[a] >= 0.0);
    let slope = v / va;
    let slant = length(v) / va;
    let last = vec3<i32>(params.grid) - vec3<i32>(1);
    var depth = 0.0;
    var prev = 0;
    var dist = 0.0;
    var spacing = params.cone_first;
    for (var k = 0u; k < MAX_CONE_CUBOIDS; k++) {
        dist += spacing;
        spacing *= 1.0 + params.cone_growth;
        let start = prev + 1;
        if f32(start) > d_end {
            break;
        }
        let end = min(max(i32(floor(dist + 0.5)), start), i32(floor(d_end)));
        let m0 = c[a] + sign * start;
        let m1 = c[a] + sign * end;
        var lo = vec3<i32>(0);
        var hi = vec3<i32>(0);
        lo[a] = min(m0, m1);
        hi[a] = max(m0, m1);
        if hi[a] < 0 || lo[a] > last[a] {
            break;
        }
        let mid = 0.5 * (f32(start) + f32(end));
        let w = mid * slant * params.cone_tan + 0.5;
        let cb = p[b] + slope[b] * mid;
        let ce = p[e] + slope[e] * mid;
        lo[b] = i32(floor(cb - w));
        hi[b] = max(i32(ceil(cb + w)) - 1, lo[b]);
        lo[e] = i32(floor(ce - w));
        hi[e] = max(i32(ceil(ce + w)) - 1, lo[e]);
        let size = vec3<f32>(hi - lo + vec3<i32>(1));
        let volume = size.x * size.y * size.z;
        depth += depth_of(cuboid_sum(lo, hi, 0u)) / volume * f32(end - start + 1) * slant;
        prev = end;
    }
    return depth;
}
