// The lit variant of `raycast`: the stored light I_s (global light propagation),
// atlas-shaped like the data, read at the sample's atlas coordinate: the one
// extra texture lookup per sample of eq. 12.
@group(0) @binding(6) var light_volume: texture_3d<f32>;

fn light_at(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    return vec3<f32>(textureSampleLevel(light_volume, atlas_sampler, atlas_coord(tc, loc), 0.0).r);
}
