// local_opacity: α_lp (eq. 6), the opacity of one segment of length L from every
// stored voxel towards the light: α_lp(s0) = 1 − Π (1 − α(n_i)) over the light
// steps n_i = s0 + i·h, i = 1..L/h (the voxel's own sample belongs to the
// segment before it, so consecutive segments tile the ray), stopping at the
// light or the volume's edge. Computed for every texel of every stored block's
// slot, apron included, so the result is atlas-shaped like the data and filters
// the same way; its size follows the data reduction. Samples in empty blocks
// have zero opacity and read nothing.
//
// Dispatch: one invocation per atlas texel, workgroups of 4×4×4.
// Bindings (group 0):
//   0–5                  shared/light_data.wgsl (params, the packed data, slot_blocks)
//   6 local_opacity      storage texture r32float, atlas-shaped (written)
// CPU twin: shaders::cpu::global_light::local_opacity (shaders/src/cpu/global_light.rs).

@group(0) @binding(6) var local_opacity: texture_storage_3d<r32float, write>;

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let voxel = slot_texel(gid);
    if !voxel.valid {
        return;
    }
    let ray = light_ray(voxel.tc);
    let end = min(params.segment, ray.length);
    var transparency = 1.0;
    for (var i = 1u; i <= params.max_steps; i++) {
        let t = f32(i) * params.step;
        if t > end {
            break;
        }
        let tc = voxel.tc + ray.dir * t;
        let loc = locate(tc);
        if !loc.empty {
            transparency *= 1.0 - opacity_at(tc, loc);
        }
    }
    textureStore(local_opacity, gid, vec4<f32>(1.0 - transparency, 0.0, 0.0, 0.0));
}
