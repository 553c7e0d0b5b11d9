// RaycastParams: the per-frame uniforms of the `raycast` stage.
// keep in sync with shaders/src/raycast.rs `RaycastParams`
//
// Model space is physical millimetres with the volume's box centred on the origin.
// Texture space maps the box to 0..1 on each axis (texel centres at (i + 0.5) / n).
struct RaycastParams {
    // Clip space (x, y in -1..1, depth 0..1) to model space.
    inv_view_proj: mat4x4<f32>,
    // Model-space corner of the volume's box, and the step between samples (mm).
    box_min: vec3<f32>,
    step: f32,
    // Model-space size of the box, and the step that transfer-function opacities
    // refer to (mm): opacity correction uses step / reference_step.
    box_size: vec3<f32>,
    reference_step: f32,
    // Voxel spacing (mm), and the accumulated opacity at which a ray stops.
    voxel_size: vec3<f32>,
    early_termination: f32,
    // Unit vector towards the light (model space), and the gradient magnitude
    // (transfer-function units per mm) under which a sample is left unshaded.
    light_dir: vec3<f32>,
    gradient_threshold: f32,
    // Background colour behind the volume (rgb; a is ignored).
    background: vec4<f32>,
    // Blinn–Phong: ambient, diffuse, specular, shininess.
    phong: vec4<f32>,
    // Texel value → transfer-function coordinate: u = value * value_scale + value_offset.
    value_scale: f32,
    value_offset: f32,
    // Upper bound on samples per ray, and the number of transfer-function entries.
    max_steps: u32,
    tf_len: u32,
    // Image size in pixels, FLAG_* bits, padding.
    width: u32,
    height: u32,
    flags: u32,
    _pad: u32,
}

// Offset each ray's first sample by a per-pixel fraction of a step (hides wood-grain banding).
const FLAG_JITTER: u32 = 1u;
// Gradient Blinn–Phong shading; otherwise samples keep their transfer-function colour.
const FLAG_SHADED: u32 = 2u;
