// RaycastParams: the per-frame uniforms of the `raycast` and `reference` stages.
// keep in sync with shaders/src/raycast.rs `RaycastParams` (checked field by
// field: shaders::layout)
//
// Model space is physical millimetres in patient LPS, shifted so the volume's
// centre is the origin. The volume occupies a parallelepiped there (its index
// axes follow the direction matrix, possibly sheared). Texture space maps that
// parallelepiped to 0..1 on each axis (level-0 voxel i's centre at (i + 0.5) / n).
struct RaycastParams {
    // Clip space (x, y in -1..1, depth 0..1) to model space.
    inv_view_proj: mat4x4<f32>,
    // Model space to texture space (affine).
    texture_from_model: mat4x4<f32>,
    // Texture-space derivatives (per unit of texture coordinate) to model-space
    // gradients (per mm): the transpose of texture_from_model's linear part.
    gradient_from_texture: mat4x4<f32>,
    // The packed volume (shared/packed_volume.wgsl; the reference stage has
    // no atlas: atlas_size 1, block_grid 0).
    volume: PackedVolume,
    // Unit vector towards the light (model space), and the step between samples (mm).
    light_dir: vec3<f32>,
    step: f32,
    // The clip box in texture space (0..1 keeps everything), and the
    // accumulated opacity at which a ray stops.
    clip_min: vec3<f32>,
    early_termination: f32,
    clip_max: vec3<f32>,
    // Gradient magnitude (transfer-function units per mm) under which a sample
    // is left unshaded.
    gradient_threshold: f32,
    // Background colour behind the volume (rgb; a is ignored).
    background: vec4<f32>,
    // Light colour (rgb, times the light's intensity) and I_bias (a), for FLAG_LIT
    // (extinction-based illumination: white and 0, the cache holds the colour).
    light: vec4<f32>,
    // Blinn–Phong: ambient, diffuse, specular, shininess.
    phong: vec4<f32>,
    // The size of what this dispatch draws (a band of the image's rows, or all
    // of them), FLAG_* bits and MODE_*.
    width: u32,
    height: u32,
    flags: u32,
    mode: u32,
    // The upper bound on samples per ray; how far towards the eye (mm) the
    // light is read (two light-cache cells for extinction-based illumination, so
    // a surface reads the light just outside it, not a blend with the shadowed
    // cells behind it; else 0); the image row this dispatch's first row is and
    // the image's height in rows (a big image is drawn band by band).
    max_steps: u32,
    light_offset: f32,
    first_row: u32,
    image_height: u32,
    // The greyscale window of MODE_MIP and MODE_MINIP in transfer-function
    // coordinates: the value shown black (x) and the span to white (y).
    window: vec2<f32>,
    // The least weight of a sample in its pixel (the ray's transparency before
    // it times its class's opacity) shaded with the frame's normal (cubic with
    // FLAG_CUBIC_GRADIENT, else blended central differences); lighter ones
    // take their nearest texel's central differences.
    faint_weight: f32,
}

// Offset each ray's first sample by a per-pixel fraction of a step (hides wood-grain banding).
const FLAG_JITTER: u32 = 1u;
// Gradient Blinn–Phong shading of composited samples.
const FLAG_SHADED: u32 = 2u;
// Jump over empty blocks instead of stepping through them.
const FLAG_SKIP_EMPTY: u32 = 4u;
// Light each sample with the stored light volume (global light propagation, eq. 12).
const FLAG_LIT: u32 = 8u;
// Exponential extinction compositing (eq. 2 of Schlegel et al.) instead of α-blending.
const FLAG_EXTINCTION: u32 = 16u;
// Normals from the cubic B-spline's gradient, not central differences (still frames).
const FLAG_CUBIC_GRADIENT: u32 = 32u;

// Front-to-back emission–absorption compositing.
const MODE_COMPOSITE: u32 = 0u;
// Maximum intensity projection: the largest value met (among visible ones),
// in grey through the window.
const MODE_MIP: u32 = 1u;
// Minimum intensity projection: the smallest value met (among visible ones),
// in grey through the window.
const MODE_MINIP: u32 = 2u;
