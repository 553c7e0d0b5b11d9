// in_scatter: I_s (eqs. 10, 11, 13), first-order in-scattering, one direction ω_j
// per dispatch. Along ω_j from every stored voxel s0, up to the scattering
// radius R_Ω, the direct light of the samples s_m is composited front to back
// with their opacities — light I_d(s_m) scattered towards s0 in the fraction
// α(s_m), dimmed by what lies between — and the light beyond R_Ω (the direct
// light at the sphere's surface, from the SVR) enters through what remains:
//   I_j = Σ_m I_d(s_m)·α(s_m)·Π_{i<m}(1 − α(s_i)) + Π_m(1 − α(s_m))·I0·(1 − α_g(s_M)).
// The result is blended into the stored light (eq. 13, weighted by the phase
// function): I ← w·I_j + (1 − w)·I with w = φ_j / Σ_{i≤j} φ_i, so after j of J
// directions the stored light is their φ-weighted mean and the image improves
// frame by frame. The first direction is the one towards the light. With
// R_Ω = 0 there is no in-scattering: I_s = I_d. Empty blocks are jumped over on
// the ray's grid of steps.
//
// Dispatch: one invocation per atlas texel, workgroups of 4×4×4.
// Bindings (group 0):
//   0–5                  shared/light_data.wgsl (params, the packed data, slot_blocks)
//   6 direct_light       texture_3d<f32> (r32float), atlas-shaped I_d
//   7 shadow_volume      texture_3d<f32> (r32float), the SVR α_g
//   8 light_volume       storage texture r32float, atlas-shaped I_s (read and written)
// CPU twin: shaders::cpu::global_light::in_scatter (shaders/src/cpu/global_light.rs).

@group(0) @binding(6) var direct_light: texture_3d<f32>;
@group(0) @binding(7) var shadow_volume: texture_3d<f32>;
@group(0) @binding(8) var light_volume: texture_storage_3d<r32float, read_write>;

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let voxel = slot_texel(gid);
    if !voxel.valid {
        return;
    }
    var light = 0.0;
    if params.scatter_radius <= 0.0 {
        light = textureLoad(direct_light, gid, 0).r;
    } else {
        var towards = params.scatter_direction.xyz;
        if params.scatter_direction.w != 0.0 {
            towards = towards_light(voxel.tc).xyz;
        }
        let ray = ray_along(voxel.tc, towards, params.scatter_radius);
        var transparency = 1.0;
        var i = 0u;
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
            let a = opacity_at(tc, loc);
            let lit = textureSampleLevel(direct_light, atlas_sampler, atlas_coord(tc, loc), 0.0).r;
            light += transparency * a * lit;
            transparency *= 1.0 - a;
            i += 1u;
        }
        let surface = voxel.tc + ray.dir * ray.length;
        let beyond = params.intensity * (1.0 - textureSampleLevel(shadow_volume, atlas_sampler, surface, 0.0).r);
        light += transparency * beyond;
    }
    let stored = textureLoad(light_volume, gid).r;
    let blended = params.blend * light + (1.0 - params.blend) * stored;
    textureStore(light_volume, gid, vec4<f32>(blended, 0.0, 0.0, 0.0));
}
