//! [`ExtinctionParams`]: the uniforms of the extinction stages (the grid,
//! the ambient-occlusion shells, the lights in grid coordinates), built from
//! the settings and the volume.

use glam::{Mat3, Vec3};

use super::{
    AoMethod, ExtinctionLightKind, ExtinctionSettings, MAX_LIGHTS, SCAN_WORKGROUP_EDGE,
    SHADOW_RAY_SAMPLES,
};
use crate::illumination::texture_transforms;
use crate::packed_volume::{PackedLayout, PackedVolume};
use crate::raycast::VolumePlacement;
use crate::volume_texture::VolumeTexture;

/// One light in the uniforms, grid coordinates.
// keep in sync with shaders/wgsl/shared/extinction_params.wgsl `ExtinctionLight`
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LightUniform {
    /// Position (w = 1) or unit direction towards the light (w = 0).
    pub position: [f32; 4],
    /// Colour times intensity; w: cosine of a spot's outer half-angle, else −2.
    pub colour: [f32; 4],
    /// Spot axis (unit, from the light outwards) and cosine of the inner half-angle.
    pub spot: [f32; 4],
}

/// The uniforms of the extinction stages.
// keep in sync with shaders/wgsl/shared/extinction_params.wgsl `ExtinctionParams`
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ExtinctionParams {
    /// Grid cells along x, y, z.
    pub grid: [u32; 3],
    /// SAT channels: 1 (τ) or 4 (τ, τ·R, τ·G, τ·B).
    pub channels: u32,
    /// The packed volume.
    pub volume: PackedVolume,
    /// Δt·τ of a cell per unit of −ln(1 − α): cell edge / reference step.
    pub opacity_scale: f32,
    /// The shadow ray's step, cells.
    pub ray_step: f32,
    /// The cone's first cuboid length, cells.
    pub cone_first: f32,
    /// Growth of each cuboid's length.
    pub cone_growth: f32,
    /// The axis a scan pass sums.
    pub axis: u32,
    /// Reconstruction samples per cell edge.
    pub sub: u32,
    /// Ambient-occlusion radius R, cells.
    pub ao_radius: u32,
    /// Ambient-occlusion shells.
    pub ao_shells: u32,
    /// Ambient light I_A.
    pub ambient: f32,
    /// The ambient-occlusion weights summed over a full neighbourhood.
    pub ao_norm: f32,
    /// Ambient-occlusion strength.
    pub ao_strength: f32,
    /// tan of the cone's half-angle.
    pub cone_tan: f32,
    /// Lights in use.
    pub light_count: u32,
    /// Padding.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
    /// Padding.
    pub _pad2: u32,
    /// The lights.
    pub lights: [LightUniform; MAX_LIGHTS],
    /// Half-edge of each ambient-occlusion shell ([`AoShells`]), 4 per row.
    pub shell_radii: [[u32; 4]; 4],
    /// Weight of each ambient-occlusion shell, 4 per row.
    pub shell_weights: [[f32; 4]; 4],
}

/// Grid cells along each axis for `size` cells along the volume's longest
/// physical side: the others in proportion, so cells are near cubes in mm.
pub fn grid_dims(texture: &VolumeTexture, size: u32) -> [u32; 3] {
    let extent = extent_mm(texture);
    let longest = extent.max_element().max(1e-6);
    let e = extent.to_array();
    e.map(|x| ((x / longest * size as f32).round() as u32).clamp(1, size))
}

/// The edge of a grid cell for `size` cells along the longest side, mm (the
/// mean over the axes).
pub fn cell_mm(texture: &VolumeTexture, size: u32) -> f32 {
    let grid = grid_dims(texture, size);
    let cells = Vec3::new(grid[0] as f32, grid[1] as f32, grid[2] as f32);
    (extent_mm(texture) / cells).element_sum() / 3.0
}

/// The volume's extent along its index axes, mm.
fn extent_mm(texture: &VolumeTexture) -> Vec3 {
    let m = VolumePlacement::of(texture).model_from_texture;
    Vec3::new(m.x_axis.length(), m.y_axis.length(), m.z_axis.length())
}

/// The ambient-occlusion shells for radius R and N shells: each shell's
/// half-edge (cells) and weight, and the weights summed over the whole
/// neighbourhood (the normaliser).
///
/// The outer cube has the volume of the sphere of radius R (half-edge
/// R·(π/6)^⅓ ≈ 0.806·R), so "radius R" means the same neighbourhood for the
/// shells and for explicit sampling; half-edges grow evenly to it, at least
/// one cell apart. A shell's weight is the mean of 1/|o|² over its cells (the
/// inverse square of its radius, eq. 8's w_A, taken over the cells it holds).
#[derive(Debug, Clone, PartialEq)]
pub struct AoShells {
    /// Half-edge of each shell's outer cube, cells.
    pub radii: Vec<u32>,
    /// Weight of each shell.
    pub weights: Vec<f32>,
    /// Σ over the neighbourhood's cells of their shell's weight.
    pub norm: f32,
}

impl AoShells {
    /// The shells of `shells` over radius `radius` (both ≥ 1).
    pub fn new(radius: u32, shells: u32) -> AoShells {
        let outer = f64::from(radius) * (std::f64::consts::PI / 6.0).cbrt();
        let mut radii = Vec::with_capacity(shells as usize);
        let mut prev = 0u32;
        for i in 0..shells {
            let r = (outer * f64::from(i + 1) / f64::from(shells)).round() as u32;
            prev = r.max(prev + 1);
            radii.push(prev);
        }
        // One pass over the outer cube: each cell adds 1/|o|² to the shell
        // its Chebyshev distance falls in (the params are built every frame).
        let mut sums = vec![0.0f64; radii.len()];
        let mut counts = vec![0u32; radii.len()];
        let r = prev as i32;
        for z in -r..=r {
            for y in -r..=r {
                for x in -r..=r {
                    let d = x.abs().max(y.abs()).max(z.abs()) as u32;
                    if d == 0 {
                        continue;
                    }
                    let shell = radii.partition_point(|&edge| edge < d);
                    sums[shell] += 1.0 / f64::from(x * x + y * y + z * z);
                    counts[shell] += 1;
                }
            }
        }
        let weights = sums
            .iter()
            .zip(&counts)
            .map(|(s, &n)| (s / f64::from(n)) as f32)
            .collect();
        AoShells {
            radii,
            weights,
            norm: sums.iter().sum::<f64>() as f32,
        }
    }
}

/// The sampled reference's weights summed over the sphere: Σ 1/|o|², 0 < |o| ≤ R.
pub fn sphere_norm(radius: u32) -> f32 {
    let r = radius as i32;
    let mut norm = 0.0f64;
    for z in -r..=r {
        for y in -r..=r {
            for x in -r..=r {
                let d2 = x * x + y * y + z * z;
                if d2 != 0 && d2 <= r * r {
                    norm += 1.0 / f64::from(d2);
                }
            }
        }
    }
    norm as f32
}

impl ExtinctionParams {
    /// The uniforms for `settings` over the volume stored as `texture`, packed
    /// with the atlas and block grid of `layout`, a table of `tf_len` entries.
    pub fn new(
        texture: &VolumeTexture,
        settings: &ExtinctionSettings,
        layout: PackedLayout,
        tf_len: u32,
    ) -> ExtinctionParams {
        let grid = grid_dims(texture, settings.sat_size);
        let cells = Vec3::new(grid[0] as f32, grid[1] as f32, grid[2] as f32);
        let cell_mm = cell_mm(texture, settings.sat_size);
        let h = texture.geometry.min_spacing_f32();
        let sub = (cell_mm / h).round().clamp(1.0, 4.0) as u32;
        let (_, texture_from_model) = texture_transforms(texture);
        let linear = Mat3::from_mat4(texture_from_model);
        // A patient-space direction in grid coordinates (unit length).
        let to_grid = |d: [f32; 3]| (linear * Vec3::from(d) * cells).normalize_or(Vec3::Z);
        let mut lights = [LightUniform::default(); MAX_LIGHTS];
        for (u, light) in lights.iter_mut().zip(&settings.lights) {
            let colour = Vec3::from(light.colour) * light.intensity;
            let mut spot = [0.0, 0.0, 1.0, 1.0];
            let mut outer = -2.0;
            let position = match light.kind {
                ExtinctionLightKind::Point(p) => (Vec3::from(p) * cells).extend(1.0),
                ExtinctionLightKind::Directional(d) => to_grid(d).extend(0.0),
                ExtinctionLightKind::Spot {
                    position,
                    direction,
                    angle,
                } => {
                    let axis = to_grid(direction);
                    outer = angle.to_radians().cos();
                    // A soft edge over the outer fifth of the cone.
                    spot = axis.extend((0.8 * angle).to_radians().cos()).to_array();
                    (Vec3::from(position) * cells).extend(1.0)
                }
            };
            *u = LightUniform {
                position: position.to_array(),
                colour: colour.extend(outer).to_array(),
                spot,
            };
        }
        let size = grid.iter().copied().max().unwrap_or(1) as f32;
        let shells = AoShells::new(settings.ao_radius, settings.ao_shells);
        let ao_norm = match settings.ao_method {
            AoMethod::Sat => shells.norm,
            AoMethod::Sampled => sphere_norm(settings.ao_radius),
        };
        let mut shell_radii = [[0u32; 4]; 4];
        let mut shell_weights = [[0.0f32; 4]; 4];
        for (i, (&r, &w)) in shells.radii.iter().zip(&shells.weights).enumerate() {
            shell_radii[i / 4][i % 4] = r;
            shell_weights[i / 4][i % 4] = w;
        }
        ExtinctionParams {
            grid,
            channels: if settings.colour_bleeding { 4 } else { 1 },
            volume: PackedVolume::new(texture, layout, tf_len),
            opacity_scale: cell_mm / h,
            ray_step: size / SHADOW_RAY_SAMPLES,
            cone_first: (size / settings.cone_frequency).max(1.0),
            cone_growth: settings.cone_growth,
            axis: 0,
            sub,
            ao_radius: settings.ao_radius,
            ao_shells: settings.ao_shells,
            ambient: settings.ambient,
            ao_norm,
            ao_strength: settings.ao_strength,
            cone_tan: settings.cone_angle.to_radians().tan(),
            light_count: settings.lights.len() as u32,
            _pad0: 0,
            _pad1: 0,
            _pad2: 0,
            lights,
            shell_radii,
            shell_weights,
        }
    }

    /// These params for scan pass `axis`.
    pub fn scanning(&self, axis: u32) -> ExtinctionParams {
        ExtinctionParams { axis, ..*self }
    }

    /// Cells in the grid.
    pub fn cells(&self) -> usize {
        self.grid.iter().map(|&n| n as usize).product()
    }
}

/// How far towards the eye from a sample the ray caster reads the light
/// cache, in cells ([`cell_mm`]). A cell's light leaves out its own
/// extinction but takes in its neighbours', so across a surface the cache
/// falls from lit to shadowed within a cell or two; read nearer than that
/// (it was read one cell towards the eye), the trilinear blend of the cells about the
/// read point varies with where the surface cuts the grid, and smooth
/// surfaces show the grid's layers as bands (rings on a sphere). Two cells
/// out the read's cells lie outside that fall; shadows move out by as much,
/// within their softness. (Read along the normal instead, the bands thinned
/// a little more where a surface is seen edge-on, but finding the point
/// made extinction-lit frames on the CPU 8–15 % slower.)
pub const LIGHT_READ_CELLS: f32 = 2.0;

/// Per block (x fastest), 1 where light-cache cells are ever read: blocks
/// within the reach of a stored one. The ray caster reads the cache
/// [`LIGHT_READ_CELLS`] of the mean cell edge towards the eye from samples
/// in stored blocks, at most twice as many cells along an axis of more than
/// one cell ([`grid_dims`] makes such an axis's cells ¾ to 1¼ of the longest
/// side's, and an axis of one cell at most 1½), filtering over the cells
/// around that point (1½ cells more); the margin covers that in whole blocks.
pub fn near_cells_mask(packing: &blocks::packing::Packing, params: &ExtinctionParams) -> Vec<u32> {
    let cell_voxels = (0..3)
        .map(|a| params.volume.volume_dims[a] / params.grid[a].max(1) as f32)
        .fold(1.0f32, f32::max);
    // The most cells along an axis that the mean cell edge spans (above).
    let cells_per_mean_edge = 2.0;
    let reach_cells = LIGHT_READ_CELLS * cells_per_mean_edge + 1.5;
    let margin = (reach_cells * cell_voxels / blocks::store::BLOCK as f32)
        .ceil()
        .max(1.0) as u32;
    crate::illumination::near_blocks(packing, params.volume.block_grid, margin)
}

/// Workgroups of a scan along `axis`: one invocation per line.
pub fn scan_workgroups(grid: [u32; 3], axis: u32) -> [u32; 3] {
    let a = axis as usize;
    let (b, c) = ((a + 1) % 3, (a + 2) % 3);
    [
        grid[b].div_ceil(SCAN_WORKGROUP_EDGE),
        grid[c].div_ceil(SCAN_WORKGROUP_EDGE),
        1,
    ]
}
