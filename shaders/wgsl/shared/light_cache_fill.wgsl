// light_cache_fill: the entry point of soft_shadow and shadow_ray. Per cell,
// the light cache holds the ambient light through I_AO plus every light
// through its occlusion:
//   cache = I_A · I_AO_RGB + Σ_L colour_L · spot_L · exp(−occlusion_depth(L, c)).
// Each stage defines `occlusion_depth(light: ExtinctionLight, c: vec3<i32>) -> f32`
// and the bindings `ambient` (texture_3d<f32>), `light_cache` (rgba16float) and
// `near_blocks`; cells the ray caster never reads get 0 (shared/near_cells.wgsl).
// CPU twin: shaders/src/cpu/extinction.rs `fill_cache`.

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if any(gid >= params.grid) {
        return;
    }
    let c = vec3<i32>(gid);
    if !cell_is_read(c) {
        textureStore(light_cache, gid, vec4<f32>(0.0));
        return;
    }
    let p = vec3<f32>(c) + 0.5;
    var light = params.ambient * textureLoad(ambient, c, 0).rgb;
    for (var l = 0u; l < params.light_count; l++) {
        let source = params.lights[l];
        let f = light_factor(source, p);
        if f > 0.0 {
            light += source.colour.rgb * f * exp(-occlusion_depth(source, c));
        }
    }
    textureStore(light_cache, gid, vec4<f32>(light, 1.0));
}
