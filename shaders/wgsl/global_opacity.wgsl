// global_opacity: α_g (eq. 7), the shadow volume representation (SVR): on a
// regular grid at a fraction of the volume's resolution, each point s0
// composites the local segments towards the light,
// α_g(s0) = 1 − Π (1 − α_lp(s_i)), s_i = s0 + i·L, reading α_lp by linear
// interpolation in its atlas. When s_i falls in an empty block, where no α_lp
// is stored, the ray advances to where it leaves that block (fig. 4): nothing
// in between is opaque. The grid is regular, not packed, so it interpolates
// linearly everywhere. Points in blocks that svr_blocks (near_blocks) marks 0 — farther from
// every non-empty block than a segment or R_Ω — are never read and are left 0.
//
// Dispatch: one invocation per SVR point, workgroups of 4×4×4.
// Bindings (group 0):
//   0 params             uniform LightParams
//   1 local_opacity      texture_3d<f32> (r32float), atlas-shaped α_lp
//   2 atlas_sampler      linear filtering, clamp to edge
//   3 block_index        texture_3d<u32> (rgba16uint)
//   4 shadow_volume      storage texture r32float, svr_dims (written)
//   5 svr_blocks         storage array<u32>, per block: 1 where the SVR is read
// CPU twin: shaders::cpu::global_light::global_opacity (shaders/src/cpu/global_light.rs).

@group(0) @binding(0) var<uniform> params: LightParams;
@group(0) @binding(1) var local_opacity: texture_3d<f32>;
@group(0) @binding(2) var atlas_sampler: sampler;
@group(0) @binding(3) var block_index: texture_3d<u32>;
@group(0) @binding(4) var shadow_volume: texture_storage_3d<r32float, write>;
@group(0) @binding(5) var<storage, read> svr_blocks: array<u32>;

// How far past a block's exit the ray resumes (mm), so the next lookup lands in
// the next block.
const RESUME: f32 = 1e-3;

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if any(gid >= params.svr_dims) {
        return;
    }
    let tc0 = (vec3<f32>(gid) + 0.5) / vec3<f32>(params.svr_dims);
    let block = min(vec3<u32>(tc0 * params.volume.volume_dims / BLOCK), params.volume.block_grid - 1u);
    let g = params.volume.block_grid;
    if svr_blocks[block.x + g.x * (block.y + g.y * block.z)] == 0u {
        textureStore(shadow_volume, gid, vec4<f32>(0.0));
        return;
    }
    let ray = light_ray(tc0);
    var transparency = 1.0;
    var t = 0.0;
    for (var k = 0u; k < params.max_steps; k++) {
        if t >= ray.length || transparency < OPAQUE {
            break;
        }
        let tc = tc0 + ray.dir * t;
        let loc = locate(tc);
        if loc.empty {
            t = max(t, empty_exit(tc0, ray.dir, loc)) + RESUME;
            continue;
        }
        let a = textureSampleLevel(local_opacity, atlas_sampler, atlas_coord(tc, loc), 0.0).r;
        transparency *= 1.0 - a;
        t += params.segment;
    }
    textureStore(shadow_volume, gid, vec4<f32>(1.0 - transparency, 0.0, 0.0, 0.0));
}
