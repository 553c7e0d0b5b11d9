// LightParams: the uniforms of the light stages (local_opacity, global_opacity,
// direct_light, in_scatter, light_seams, direct_light_reference) of global light
// propagation (Hernell, Ljung, Ynnerman 2008).
// keep in sync with shaders/src/light/mod.rs `LightParams` (checked field by
// field: shaders::layout)
//
// Positions are in texture space (0..1 over the volume's box); distances along
// rays are model-space millimetres, as in the ray caster.
struct LightParams {
    // Texture space to model space (affine).
    model_from_texture: mat4x4<f32>,
    // Model space to texture space (affine).
    texture_from_model: mat4x4<f32>,
    // The light: model-space position (w = 1, point light) or unit vector
    // towards the light (w = 0, directional light).
    light: vec4<f32>,
    // in_scatter: the direction of this refinement step (model space, unit;
    // w = 1: towards the light instead), and its blend weight for eq. 13.
    scatter_direction: vec4<f32>,
    // The packed volume (shared/packed_volume.wgsl).
    volume: PackedVolume,
    // Points of the shadow volume (SVR) along x, y, z, and the light's intensity I0.
    svr_dims: vec3<u32>,
    intensity: f32,
    // Segment length L (mm), scattering radius R_Ω (mm), the light step h
    // (mm), and the blend weight w_j / W_j of this refinement (eq. 13).
    segment: f32,
    scatter_radius: f32,
    step: f32,
    blend: f32,
    // Per level: slots along x, y, z, and the atlas z where the level's region starts.
    regions: array<vec4<u32>, 5>,
    // Upper bound on steps of any march; light_seams: the level whose blocks'
    // aprons the pass writes, and how many axes those texels lie outside
    // their block along (1 faces, 2 edges, 3 corners); padding.
    max_steps: u32,
    seam_level: u32,
    seam_outward: u32,
    _pad0: u32,
}
