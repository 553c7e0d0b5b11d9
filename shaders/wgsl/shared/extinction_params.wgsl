// ExtinctionParams: the uniforms of the extinction-based illumination stages
// (extinction_sat, ambient_occlusion, soft_shadow and their references).
// keep in sync with shaders/src/extinction/mod.rs `ExtinctionParams` (checked
// field by field: shaders::layout)
//
// The stages work on a regular grid (the SAT grid, also the light cache's)
// covering the volume's box, cell i's centre at texture coordinate (i + 0.5) / n.
// Grid coordinates below are continuous cell units: cell i spans [i, i + 1).

// One light of the light cache, in grid coordinates.
struct ExtinctionLight {
    // Point or spot light: position (w = 1); directional: unit vector towards
    // the light (w = 0).
    position: vec4<f32>,
    // Colour times intensity (rgb); w: cosine of a spot light's outer half-angle
    // (below -1: not a spot light).
    colour: vec4<f32>,
    // Spot light: unit axis from the light outwards (xyz), cosine of the inner
    // half-angle (w).
    spot: vec4<f32>,
}

struct ExtinctionParams {
    // Grid cells along x, y, z, and SAT channels (1: τ only; 4: τ and τ·RGB).
    grid: vec3<u32>,
    channels: u32,
    // The packed volume (shared/packed_volume.wgsl).
    volume: PackedVolume,
    // Δt·τ of a cell per unit of −ln(1 − α): the cell's edge over the step
    // opacities refer to; the shadow-ray step (cells); the cone's first cuboid
    // length along the main axis (cells) and its growth per cuboid.
    opacity_scale: f32,
    ray_step: f32,
    cone_first: f32,
    cone_growth: f32,
    // extinction_sat scan: the axis summed (0, 1, 2); samples per cell edge of
    // the reconstruction; ambient occlusion radius R (cells) and shell count.
    axis: u32,
    sub: u32,
    ao_radius: u32,
    ao_shells: u32,
    // Ambient light I_A; the sum of shell weights over a full neighbourhood
    // (normalises the AO sum to a mean); AO strength; tan of the cone half-angle.
    ambient: f32,
    ao_norm: f32,
    ao_strength: f32,
    cone_tan: f32,
    // Lights in use; padding.
    light_count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    lights: array<ExtinctionLight, 4>,
    // Ambient-occlusion shells: half-edge (cells) and weight of shell i at
    // [i / 4][i % 4] (shaders/src/extinction.rs `AoShells`).
    shell_radii: array<vec4<u32>, 4>,
    shell_weights: array<vec4<f32>, 4>,
}

// Fixed-point SAT values: one unit of Δt·τ is 2^24; sums are 64-bit integers
// (lo, hi words) so every cuboid query is exact whatever the grid size.
const FIXED_ONE: f32 = 16777216.0;
// The largest Δt·τ a cell holds: an opaque cell passes e^−4 ≈ 2 % of the
// light, so shadows barely change, and neighbourhood means stay bounded.
const MAX_CELL_DEPTH: f32 = 4.0;
// The most cuboids per cone.
const MAX_CONE_CUBOIDS: u32 = 256u;
