// The extinction-lit variant of `raycast`: the light cache of extinction-based
// illumination (ambient occlusion and soft shadows, grid-shaped over the
// volume's box), read at the sample's texture coordinate: the one extra
// texture lookup per sample of Schlegel et al.'s algorithm 1.
@group(0) @binding(6) var light_volume: texture_3d<f32>;

fn light_at(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    return textureSampleLevel(light_volume, atlas_sampler, tc, 0.0).rgb;
}
