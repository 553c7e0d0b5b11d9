// direct_light_reference: I_d computed by brute force, the reference the
// piecewise method (local_opacity → global_opacity → direct_light) is measured
// against: from every stored voxel, opacity is integrated at full resolution
// all the way to the light (or out of the volume), on the same light steps
// t = i·h, i ≥ 1, with no segments, no interpolation and no SVR:
// I_d(s0) = I0 · Π (1 − α(s0 + i·h)). Empty blocks are jumped over on the
// ray's grid of steps. Same output as direct_light, so in_scatter and the
// ray caster run unchanged on it. For tests and benchmarks.
//
// Dispatch: one invocation per atlas texel, workgroups of 4×4×4.
// Bindings (group 0):
//   0–5                  shared/light_data.wgsl (params, the packed data, slot_blocks)
//   6 direct_light       storage texture r32float, atlas-shaped (written)
// CPU twin: shaders::cpu::global_light::direct_light_reference (shaders/src/cpu/global_light.rs).

@group(0) @binding(6) var direct_light: texture_storage_3d<r32float, write>;

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let voxel = slot_texel(gid);
    if !voxel.valid {
        return;
    }
    let ray = light_ray(voxel.tc);
    var transparency = 1.0;
    var i = 1u;
    for (var k = 0u; k < params.max_steps; k++) {
        let t = f32(i) * params.step;
        if t > ray.length || transparency < OPAQUE {
            break;
        }
        let tc = voxel.tc + ray.dir * t;
        let loc = locate(tc);
        if loc.empty {
            let exit = empty_exit(voxel.tc, ray.dir, loc);
            i = max(i + 1u, u32(ceil(exit / params.step)));
            continue;
        }
        transparency *= 1.0 - opacity_at(tc, loc);
        i += 1u;
    }
    textureStore(direct_light, gid, vec4<f32>(params.intensity * transparency, 0.0, 0.0, 0.0));
}
