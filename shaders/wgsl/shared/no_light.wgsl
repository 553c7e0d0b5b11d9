// The unlit variant of `raycast`: no light volume is bound.
fn light_at(tc: vec3<f32>, loc: Location) -> f32 {
    return 1.0;
}
