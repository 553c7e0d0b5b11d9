// extinction_light: a light of the light cache seen from a cell, shared by
// soft_shadow and shadow_ray. Needs `params` (ExtinctionParams).
// CPU twin: shaders/src/cpu/extinction.rs (`towards`, `light_factor`).

// The vector from p (grid coordinates) towards the light: to its position for
// a point or spot light, the unit direction for a directional one.
fn towards(light: ExtinctionLight, p: vec3<f32>) -> vec3<f32> {
    if light.position.w == 0.0 {
        return light.position.xyz;
    }
    return light.position.xyz - p;
}

// How much of the light's colour reaches p before occlusion: 1, or a spot
// light's smooth falloff between its inner and outer half-angles.
fn light_factor(light: ExtinctionLight, p: vec3<f32>) -> f32 {
    if light.colour.w < -1.0 || light.position.w == 0.0 {
        return 1.0;
    }
    let d = p - light.position.xyz;
    let distance = length(d);
    if distance < 1e-6 {
        return 1.0;
    }
    let c = dot(d / distance, light.spot.xyz);
    return smoothstep(light.colour.w, light.spot.w, c);
}
