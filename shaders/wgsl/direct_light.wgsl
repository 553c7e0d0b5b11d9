// direct_light: I_d (eq. 8), the light reaching every stored voxel:
// I_d(s0) = I0 · (1 − α_g(s1)) · (1 − α_lp(s0)), with the first segment's
// opacity α_lp(s0) at full resolution (the voxel's own texel) and the rest,
// from s1 = s0 + L on, interpolated from the SVR. Nothing lies beyond the
// light or outside the volume.
//
// Dispatch: one invocation per atlas texel, workgroups of 4×4×4.
// Bindings (group 0):
//   0 params             uniform LightParams
//   1 local_opacity      texture_3d<f32> (r32float), atlas-shaped α_lp
//   2 shadow_volume      texture_3d<f32> (r32float), the SVR α_g
//   3 atlas_sampler      linear filtering, clamp to edge
//   4 slot_blocks        storage array<u32>
//   5 direct_light       storage texture r32float, atlas-shaped (written)
// CPU twin: shaders::cpu::global_light::direct_light (shaders/src/cpu/global_light.rs).

@group(0) @binding(0) var<uniform> params: LightParams;
@group(0) @binding(1) var local_opacity: texture_3d<f32>;
@group(0) @binding(2) var shadow_volume: texture_3d<f32>;
@group(0) @binding(3) var atlas_sampler: sampler;
@group(0) @binding(4) var<storage, read> slot_blocks: array<u32>;
@group(0) @binding(5) var direct_light: texture_storage_3d<r32float, write>;

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let voxel = slot_texel(gid);
    if !voxel.valid {
        return;
    }
    let first = textureLoad(local_opacity, gid, 0).r;
    let ray = light_ray(voxel.tc);
    var rest = 0.0;
    if ray.length > params.segment {
        let s1 = voxel.tc + ray.dir * params.segment;
        rest = textureSampleLevel(shadow_volume, atlas_sampler, s1, 0.0).r;
    }
    let light = params.intensity * (1.0 - rest) * (1.0 - first);
    textureStore(direct_light, gid, vec4<f32>(light, 0.0, 0.0, 0.0));
}
