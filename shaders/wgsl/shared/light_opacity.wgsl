// light_opacity: the opacity of one light step, from the packed data and the
// transfer function. Needs the bindings `atlas`, `atlas_sampler`,
// `transfer_function`, `block_index`.
// CPU twin: shaders/src/cpu/global_light.rs `opacity_of` (of the sample's value).

// The opacity of one light step h at tc, from the data and the transfer
// function, corrected for h against the reference step.
fn opacity_at(tc: vec3<f32>, loc: Location) -> f32 {
    let value = textureSampleLevel(atlas, atlas_sampler, atlas_coord(tc, loc), 0.0).r;
    let a = classify(value * params.volume.value_scale + params.volume.value_offset).a;
    return corrected_opacity(a, params.step / params.volume.reference_step);
}
