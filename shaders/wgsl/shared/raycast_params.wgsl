// RaycastParams: the per-frame uniforms of the `raycast` stage.
// keep in sync with shaders/src/raycast.rs `RaycastParams`
//
// Model space is physical millimetres in patient LPS, shifted so the volume's
// centre is the origin. The volume occupies a parallelepiped there (its index
// axes follow the direction matrix, possibly sheared). Texture space maps that
// parallelepiped to 0..1 on each axis (texel centres at (i + 0.5) / n).
struct RaycastParams {
    // Clip space (x, y in -1..1, depth 0..1) to model space.
    inv_view_proj: mat4x4<f32>,
    // Model space to texture space (affine).
    texture_from_model: mat4x4<f32>,
    // Texture-space derivatives (per unit of texture coordinate) to model-space
    // gradients (per mm): the transpose of texture_from_model's linear part.
    gradient_from_texture: mat4x4<f32>,
    // One texel in texture coordinates (1 / dims), and the step between samples (mm).
    texel: vec3<f32>,
    step: f32,
    // Unit vector towards the light (model space), and the step that
    // transfer-function opacities refer to (mm): opacity correction uses
    // step / reference_step.
    light_dir: vec3<f32>,
    reference_step: f32,
    // Background colour behind the volume (rgb; a is ignored).
    background: vec4<f32>,
    // Blinn–Phong: ambient, diffuse, specular, shininess.
    phong: vec4<f32>,
    // Texel value → transfer-function coordinate: u = value * value_scale + value_offset.
    value_scale: f32,
    value_offset: f32,
    // Gradient magnitude (transfer-function units per mm) under which a sample
    // is left unshaded, and the accumulated opacity at which a ray stops.
    gradient_threshold: f32,
    early_termination: f32,
    // Upper bound on samples per ray, transfer-function entries, image size.
    max_steps: u32,
    tf_len: u32,
    width: u32,
    height: u32,
    // FLAG_* bits, padding.
    flags: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// Offset each ray's first sample by a per-pixel fraction of a step (hides wood-grain banding).
const FLAG_JITTER: u32 = 1u;
// Gradient Blinn–Phong shading; otherwise samples keep their transfer-function colour.
const FLAG_SHADED: u32 = 2u;
