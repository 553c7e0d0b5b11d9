// The lit variant of `raycast`: the stored light I_s (global light propagation),
// atlas-shaped like the data, read at tc (a little towards the eye from the
// sample: `RaycastParams::light_offset`): the one extra texture lookup per
// sample of eq. 12. tc may lie in another block than the sample's: it is read
// in that block, or, where that block is empty (no light stored), in the
// sample's, clamped to its apron.
@group(0) @binding(6) var light_volume: texture_3d<f32>;

fn light_at(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    var home = loc;
    let there = locate(tc);
    if !there.empty {
        home = there;
    }
    return vec3<f32>(textureSampleLevel(light_volume, atlas_sampler, atlas_coord(tc, home), 0.0).r);
}
