//! Extinction-based illumination (Schlegel, Makhinya, Pajarola 2011): ambient
//! occlusion, colour bleeding and cone soft shadows from a 3D summed-area
//! table (SAT) of extinction coefficients, computed on a regular grid over the
//! volume reconstructed from the packed blocks.
//!
//! Stages, each a WGSL compute shader with a CPU twin of the same name in
//! [`crate::cpu::extinction`]:
//! - `extinction_sat`: Δt·τ per grid cell from the packed blocks (empty blocks
//!   read nothing), then the SAT by three in-place prefix scans (x, y, z), with
//!   Δt·τ·RGB in the same passes for colour bleeding; 64-bit fixed-point sums
//!   keep every cuboid query exact (see the shader's header);
//! - `ambient_occlusion`: I_AO (eq. 4) and I_AO_RGB (eq. 5) from cuboid shells
//!   weighted by 1/r² (fig. 5);
//! - `soft_shadow`: per light, the cone towards it as cuboid queries along the
//!   main axis (eq. 7, fig. 7), summed with ambient light into the light cache;
//!
//! and the references they are measured against: `ambient_occlusion_reference`
//! (explicit sampling of the spherical neighbourhood) and `shadow_ray` (one
//! classic shadow ray per light).
//!
//! [`ExtinctionLighting`] owns the GPU resources and follows the paper's
//! algorithm 1: a transfer-function or data change rebuilds the SAT, the
//! ambient occlusion and the shadows; a light change recomputes the shadows
//! only; a camera change recomputes nothing. The ray caster reads the light
//! cache with one lookup per sample.

mod settings;

use std::time::Instant;

use glam::{Mat3, Vec3};

use crate::light::{LightInputs, texture_transforms};
use crate::packed_volume::{PackedLayout, PackedVolume};
use crate::pipeline::{self, ComputeStage, run};
use crate::raycast::VolumePlacement;
use crate::settings::{Json, stage_key};
use crate::volume_texture::VolumeTexture;
use crate::{GpuContext, GpuError};

pub use settings::{
    AoMethod, ExtinctionLight, ExtinctionLightKind, ExtinctionSettings, MAX_AO_SHELLS, MAX_LIGHTS,
    ShadowMethod,
};

/// The stages of extinction-based illumination in the order they run (the
/// paper's algorithm 1): a change of a setting recomputes from the stage it
/// `affects` on.
pub const STAGES: [&str; 3] = ["extinction_sat", "ambient_occlusion", "soft_shadow"];

/// Samples per grid side of the reference shadow ray (the paper's 250 per unit).
pub const SHADOW_RAY_SAMPLES: f32 = 250.0;
/// Fixed-point scale of SAT cells: one unit of Δt·τ.
pub const FIXED_ONE: f32 = 16_777_216.0;
/// The largest Δt·τ a cell holds (an opaque cell passes e^−4 ≈ 2 % of the light).
pub const MAX_CELL_DEPTH: f32 = 4.0;
/// The most cuboids per cone.
pub const MAX_CONE_CUBOIDS: u32 = 256;
/// The light cache's and ambient term's texel format.
pub const CACHE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// The extinction texture's texel format (Δt·τ per cell).
pub const EXTINCTION_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
/// Invocations per workgroup along each axis of the per-cell stages.
pub const WORKGROUP_EDGE: u32 = 4;
/// Invocations per workgroup along each axis of the scan (per line).
pub const SCAN_WORKGROUP_EDGE: u32 = 8;

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
        let h = texture.min_spacing();
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

/// Per block (x fastest), 1 where light-cache cells are ever read: blocks
/// within the reach of a stored one. The ray caster reads the cache one cell
/// towards the eye from samples in stored blocks, filtering over the cells
/// around that point, so cells up to 2½ cells from a stored block are read;
/// the margin covers that in whole blocks.
pub fn near_cells_mask(packing: &blocks::packing::Packing, params: &ExtinctionParams) -> Vec<u32> {
    let cell_voxels = (0..3)
        .map(|a| params.volume.volume_dims[a] / params.grid[a].max(1) as f32)
        .fold(1.0f32, f32::max);
    let margin = (2.5 * cell_voxels / blocks::store::BLOCK as f32)
        .ceil()
        .max(1.0) as u32;
    crate::light::near_blocks(packing, params.volume.block_grid, margin)
}

/// Workgroups for one invocation per cell of `grid`.
pub fn workgroups(grid: [u32; 3]) -> [u32; 3] {
    grid.map(|d| d.div_ceil(WORKGROUP_EDGE))
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

/// The compiled extinction stages.
#[derive(Debug)]
pub struct ExtinctionPipelines {
    /// `extinction_sat`, entry point `reconstruct`.
    pub reconstruct: ComputeStage,
    /// `extinction_sat`, entry point `scan`.
    pub scan: ComputeStage,
    /// `ambient_occlusion`.
    pub ambient_occlusion: ComputeStage,
    /// `ambient_occlusion_reference`.
    pub ambient_occlusion_reference: ComputeStage,
    /// `soft_shadow`.
    pub soft_shadow: ComputeStage,
    /// `shadow_ray`.
    pub shadow_ray: ComputeStage,
    sampler: wgpu::Sampler,
}

impl ExtinctionPipelines {
    /// Compiles the stages.
    pub fn new(gpu: &GpuContext) -> Result<ExtinctionPipelines, GpuError> {
        use pipeline::{
            float_texture_3d, sampler, storage_buffer, storage_buffer_rw, storage_texture,
            uint_texture_3d, unfilterable_texture_3d, uniform,
        };
        let params = || uniform(0, size_of::<ExtinctionParams>());
        let write = |b, format| {
            storage_texture(
                b,
                format,
                wgpu::StorageTextureAccess::WriteOnly,
                wgpu::TextureViewDimension::D3,
            )
        };
        let sat_layout = [
            params(),
            float_texture_3d(1),
            sampler(2),
            storage_buffer(3),
            uint_texture_3d(4),
            storage_buffer_rw(5),
            storage_buffer_rw(6),
            storage_buffer_rw(7),
            storage_buffer_rw(8),
            write(9, EXTINCTION_FORMAT),
        ];
        let sat_read = [
            params(),
            storage_buffer(1),
            storage_buffer(2),
            storage_buffer(3),
            storage_buffer(4),
        ];
        let mut ao = sat_read.to_vec();
        ao.extend([write(5, CACHE_FORMAT), storage_buffer(6)]);
        let mut shadow = sat_read.to_vec();
        shadow.extend([
            float_texture_3d(5),
            write(6, CACHE_FORMAT),
            storage_buffer(7),
        ]);
        let source = crate::wgsl::EXTINCTION_SAT;
        Ok(ExtinctionPipelines {
            reconstruct: ComputeStage::with_entry(
                gpu,
                "extinction_sat",
                "reconstruct",
                source,
                &sat_layout,
            )?,
            scan: ComputeStage::with_entry(gpu, "extinction_sat", "scan", source, &sat_layout)?,
            ambient_occlusion: ComputeStage::new(
                gpu,
                "ambient_occlusion",
                crate::wgsl::AMBIENT_OCCLUSION,
                &ao,
            )?,
            ambient_occlusion_reference: ComputeStage::new(
                gpu,
                "ambient_occlusion_reference",
                crate::wgsl::AMBIENT_OCCLUSION_REFERENCE,
                &[
                    params(),
                    unfilterable_texture_3d(1),
                    write(2, CACHE_FORMAT),
                    storage_buffer(3),
                ],
            )?,
            soft_shadow: ComputeStage::new(gpu, "soft_shadow", crate::wgsl::SOFT_SHADOW, &shadow)?,
            shadow_ray: ComputeStage::new(
                gpu,
                "shadow_ray",
                crate::wgsl::SHADOW_RAY,
                &[
                    params(),
                    unfilterable_texture_3d(1),
                    float_texture_3d(2),
                    write(3, CACHE_FORMAT),
                    storage_buffer(4),
                ],
            )?,
            sampler: pipeline::linear_sampler(gpu),
        })
    }
}

/// A grid-shaped 3D texture of the extinction stages.
#[derive(Debug)]
pub struct GridTexture {
    /// The texture.
    pub texture: wgpu::Texture,
    /// A view of it.
    pub view: wgpu::TextureView,
    /// Texels along x, y, z.
    pub dims: [u32; 3],
    format: wgpu::TextureFormat,
}

impl GridTexture {
    fn new(
        gpu: &GpuContext,
        label: &str,
        dims: [u32; 3],
        format: wgpu::TextureFormat,
    ) -> Result<GridTexture, GpuError> {
        let texture = crate::volume_texture::create_texture_3d_for(
            gpu,
            label,
            dims,
            format,
            wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::STORAGE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
        )?;
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(GridTexture {
            texture,
            view,
            dims,
            format,
        })
    }

    /// Reads every texel back as RGBA f32 (x fastest; one-channel textures fill r).
    pub fn read(&self, gpu: &GpuContext) -> Result<Vec<[f32; 4]>, GpuError> {
        let bytes = crate::light::read_texture_bytes(gpu, &self.texture, self.dims, self.format)?;
        Ok(match self.format {
            CACHE_FORMAT => bytes
                .chunks_exact(8)
                .map(|t| {
                    let h = |i: usize| half::f16::from_le_bytes([t[2 * i], t[2 * i + 1]]).to_f32();
                    [h(0), h(1), h(2), h(3)]
                })
                .collect(),
            _ => bytes
                .chunks_exact(4)
                .map(|t| [f32::from_le_bytes([t[0], t[1], t[2], t[3]]), 0.0, 0.0, 0.0])
                .collect(),
        })
    }
}

/// The extinction stages' GPU resources for one grid size.
#[derive(Debug)]
pub struct ExtinctionVolumes {
    /// The SAT, one buffer per channel (τ, τ·R, τ·G, τ·B) of 64-bit fixed-point
    /// sums; the colour buffers hold one entry when colour bleeding is off.
    pub sat: [wgpu::Buffer; 4],
    /// Δt·τ per cell (the references read it).
    pub extinction: GridTexture,
    /// I_AO per cell (rgb; a: grey).
    pub ambient: GridTexture,
    /// The light cache the ray caster reads.
    pub light_cache: GridTexture,
    /// [`near_cells_mask`]: per block, 1 where the cache's cells are read.
    near_blocks: wgpu::Buffer,
    params: wgpu::Buffer,
    scan_params: [wgpu::Buffer; 3],
    channels: u32,
}

impl ExtinctionVolumes {
    /// Allocates the SAT and textures for `grid` with `channels` SAT channels,
    /// refusing grids whose SAT buffer exceeds what the adapter can bind.
    pub fn new(
        gpu: &GpuContext,
        grid: [u32; 3],
        channels: u32,
        blocks: usize,
    ) -> Result<ExtinctionVolumes, GpuError> {
        let cells: u64 = grid.iter().map(|&n| u64::from(n)).product();
        let bytes = cells * 8;
        let limits = gpu.device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if bytes > limit {
            return Err(GpuError::Unsupported {
                what: format!(
                    "a summed-area table of {}x{}x{} cells ({} MiB per channel)",
                    grid[0],
                    grid[1],
                    grid[2],
                    bytes >> 20
                ),
                limit: format!(
                    "adapter '{}' binds storage buffers of at most {} MiB: lower the SAT size",
                    gpu.info.name,
                    limit >> 20
                ),
            });
        }
        let buffer = |label: &str, size: u64| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let colour_size = if channels == 4 { bytes } else { 8 };
        let uniform = |label: &str| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size_of::<ExtinctionParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let (sat, params, scan_params, near_blocks) =
            gpu.scoped("allocating the summed-area table", || {
                (
                    [
                        buffer("SAT τ", bytes),
                        buffer("SAT τ·R", colour_size),
                        buffer("SAT τ·G", colour_size),
                        buffer("SAT τ·B", colour_size),
                    ],
                    uniform("extinction params"),
                    [
                        uniform("SAT scan x"),
                        uniform("SAT scan y"),
                        uniform("SAT scan z"),
                    ],
                    buffer("near blocks", (blocks.max(1) * 4) as u64),
                )
            })?;
        Ok(ExtinctionVolumes {
            sat,
            extinction: GridTexture::new(gpu, "extinction", grid, EXTINCTION_FORMAT)?,
            ambient: GridTexture::new(gpu, "ambient occlusion", grid, CACHE_FORMAT)?,
            light_cache: GridTexture::new(gpu, "light cache", grid, CACHE_FORMAT)?,
            near_blocks,
            params,
            scan_params,
            channels,
        })
    }

    /// Reads channel `channel` of the SAT back (x fastest).
    pub fn read_sat(&self, gpu: &GpuContext, channel: usize) -> Result<Vec<u64>, GpuError> {
        let buffer = &self.sat[channel];
        let size = buffer.size();
        let staging = gpu.scoped("reading the summed-area table back", || {
            let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("SAT readback"),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
            gpu.queue.submit([encoder.finish()]);
            staging
        })?;
        gpu.read_buffer(&staging, "the summed-area table", |bytes| {
            bytes
                .chunks_exact(8)
                .map(|w| {
                    let lo = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
                    let hi = u32::from_le_bytes([w[4], w[5], w[6], w[7]]);
                    u64::from(lo) | (u64::from(hi) << 32)
                })
                .collect()
        })
    }

    /// Bindings 0–4 of the stages that query the SAT: params and the channels.
    fn sat_bindings(&self) -> Vec<wgpu::BindingResource<'_>> {
        let mut resources = vec![self.params.as_entire_binding()];
        resources.extend(self.sat.iter().map(wgpu::Buffer::as_entire_binding));
        resources
    }

    fn fits(&self, grid: [u32; 3], channels: u32, blocks: usize) -> bool {
        self.extinction.dims == grid
            && self.channels == channels
            && self.near_blocks.size() >= (blocks.max(1) * 4) as u64
    }
}

/// What the extinction stages of one frame took, in milliseconds (0 for
/// stages that did not run).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ExtinctionTimings {
    /// `extinction_sat`: reconstruction and the three scans.
    pub sat_ms: f64,
    /// `ambient_occlusion` (or its reference).
    pub ambient_occlusion_ms: f64,
    /// `soft_shadow` (or `shadow_ray`), all lights.
    pub soft_shadow_ms: f64,
    /// The whole update of this frame.
    pub total_ms: f64,
    /// Grid cells along x, y, z.
    pub grid: [u32; 3],
}

/// The extinction-based illumination of one renderer: GPU resources and what
/// they were computed for. See the module docs.
#[derive(Debug)]
pub struct ExtinctionLighting {
    pipelines: ExtinctionPipelines,
    volumes: Option<ExtinctionVolumes>,
    sat_for: Option<(u64, blocks::TransferFunction, Vec<Json>)>,
    ao_for: Option<Vec<Json>>,
    shadows_for: Option<Vec<Json>>,
    params: Option<ExtinctionParams>,
}

impl ExtinctionLighting {
    /// Compiles the stages.
    pub fn new(gpu: &GpuContext) -> Result<ExtinctionLighting, GpuError> {
        Ok(ExtinctionLighting {
            pipelines: ExtinctionPipelines::new(gpu)?,
            volumes: None,
            sat_for: None,
            ao_for: None,
            shadows_for: None,
            params: None,
        })
    }

    /// The light cache, once computed.
    pub fn light_cache(&self) -> Option<&wgpu::TextureView> {
        self.shadows_for
            .as_ref()
            .and(self.volumes.as_ref())
            .map(|v| &v.light_cache.view)
    }

    /// The SAT and textures, once computed (tests read them back).
    pub fn volumes(&self) -> Option<&ExtinctionVolumes> {
        self.volumes.as_ref()
    }

    /// The params of the last computation.
    pub fn params(&self) -> Option<&ExtinctionParams> {
        self.params.as_ref()
    }

    /// Forgets everything computed, so the next update recomputes it all.
    pub fn invalidate(&mut self) {
        self.sat_for = None;
        self.ao_for = None;
        self.shadows_for = None;
    }

    /// Brings the light cache up to date (algorithm 1): the SAT, ambient term
    /// and shadows when the data (`data_version`) or transfer function changed;
    /// the ambient term and shadows when only its settings did; the shadows
    /// alone when only the lights or cone did; nothing for a camera move.
    pub fn update(
        &mut self,
        gpu: &GpuContext,
        inputs: LightInputs<'_>,
        tf: &blocks::TransferFunction,
        settings: &ExtinctionSettings,
        data_version: u64,
    ) -> Result<ExtinctionTimings, GpuError> {
        settings.validate()?;
        let start = Instant::now();
        let params =
            ExtinctionParams::new(inputs.texture, settings, inputs.atlas.layout, inputs.tf_len);
        let mut timings = ExtinctionTimings {
            grid: params.grid,
            ..ExtinctionTimings::default()
        };
        let sat_key = (
            data_version,
            tf.clone(),
            stage_key(settings, &STAGES, "extinction_sat"),
        );
        if self.sat_for.as_ref() != Some(&sat_key) {
            self.invalidate();
            let mask = near_cells_mask(&inputs.atlas.packing, &params);
            if !self
                .volumes
                .as_ref()
                .is_some_and(|v| v.fits(params.grid, params.channels, mask.len()))
            {
                // The old buffers go before the new ones are made.
                self.volumes = None;
                self.volumes = Some(ExtinctionVolumes::new(
                    gpu,
                    params.grid,
                    params.channels,
                    mask.len(),
                )?);
            }
            if let Some(v) = &self.volumes {
                gpu.queue
                    .write_buffer(&v.near_blocks, 0, bytemuck::cast_slice(&mask));
            }
            timings.sat_ms = self.build_sat(gpu, inputs, &params)?;
            self.sat_for = Some(sat_key);
        }
        let Some(volumes) = &self.volumes else {
            return Err(GpuError::InvalidRequest("no extinction volumes".into()));
        };
        gpu.queue
            .write_buffer(&volumes.params, 0, bytemuck::bytes_of(&params));
        self.params = Some(params);
        let ao_key = stage_key(settings, &STAGES, "ambient_occlusion");
        if self.ao_for.as_ref() != Some(&ao_key) {
            self.shadows_for = None;
            timings.ambient_occlusion_ms = self.ambient(gpu, settings.ao_method)?;
            self.ao_for = Some(ao_key);
        }
        let shadow_key = stage_key(settings, &STAGES, "soft_shadow");
        if self.shadows_for.as_ref() != Some(&shadow_key) {
            timings.soft_shadow_ms = self.shadows(gpu, settings.shadow_method)?;
            self.shadows_for = Some(shadow_key);
        }
        timings.total_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(timings)
    }

    /// `extinction_sat`: reconstruction, then the scans along x, y and z.
    fn build_sat(
        &self,
        gpu: &GpuContext,
        inputs: LightInputs<'_>,
        params: &ExtinctionParams,
    ) -> Result<f64, GpuError> {
        let Some(v) = &self.volumes else {
            return Ok(0.0);
        };
        gpu.queue
            .write_buffer(&v.params, 0, bytemuck::bytes_of(params));
        for (axis, buffer) in v.scan_params.iter().enumerate() {
            gpu.queue
                .write_buffer(buffer, 0, bytemuck::bytes_of(&params.scanning(axis as u32)));
        }
        let p = &self.pipelines;
        let base = vec![
            v.params.as_entire_binding(),
            wgpu::BindingResource::TextureView(&inputs.atlas.atlas_view),
            wgpu::BindingResource::Sampler(&p.sampler),
            inputs.transfer_function.as_entire_binding(),
            wgpu::BindingResource::TextureView(&inputs.atlas.index_view),
            v.sat[0].as_entire_binding(),
            v.sat[1].as_entire_binding(),
            v.sat[2].as_entire_binding(),
            v.sat[3].as_entire_binding(),
            wgpu::BindingResource::TextureView(&v.extinction.view),
        ];
        let mut ms = run(gpu, &p.reconstruct, &base, workgroups(params.grid))?;
        for (axis, uniforms) in v.scan_params.iter().enumerate() {
            let mut resources = base.clone();
            resources[0] = uniforms.as_entire_binding();
            ms += run(
                gpu,
                &p.scan,
                &resources,
                scan_workgroups(params.grid, axis as u32),
            )?;
        }
        Ok(ms)
    }

    /// `ambient_occlusion` or its sampled reference into the ambient texture.
    fn ambient(&self, gpu: &GpuContext, method: AoMethod) -> Result<f64, GpuError> {
        let (Some(v), Some(params)) = (&self.volumes, &self.params) else {
            return Ok(0.0);
        };
        let p = &self.pipelines;
        let groups = workgroups(params.grid);
        match method {
            AoMethod::Sat => {
                let mut resources = v.sat_bindings();
                resources.extend([
                    wgpu::BindingResource::TextureView(&v.ambient.view),
                    v.near_blocks.as_entire_binding(),
                ]);
                run(gpu, &p.ambient_occlusion, &resources, groups)
            }
            AoMethod::Sampled => run(
                gpu,
                &p.ambient_occlusion_reference,
                &[
                    v.params.as_entire_binding(),
                    wgpu::BindingResource::TextureView(&v.extinction.view),
                    wgpu::BindingResource::TextureView(&v.ambient.view),
                    v.near_blocks.as_entire_binding(),
                ],
                groups,
            ),
        }
    }

    /// `soft_shadow` or `shadow_ray` into the light cache.
    fn shadows(&self, gpu: &GpuContext, method: ShadowMethod) -> Result<f64, GpuError> {
        let (Some(v), Some(params)) = (&self.volumes, &self.params) else {
            return Ok(0.0);
        };
        let p = &self.pipelines;
        let groups = workgroups(params.grid);
        match method {
            ShadowMethod::Cone => {
                let mut resources = v.sat_bindings();
                resources.extend([
                    wgpu::BindingResource::TextureView(&v.ambient.view),
                    wgpu::BindingResource::TextureView(&v.light_cache.view),
                    v.near_blocks.as_entire_binding(),
                ]);
                run(gpu, &p.soft_shadow, &resources, groups)
            }
            ShadowMethod::Ray => run(
                gpu,
                &p.shadow_ray,
                &[
                    v.params.as_entire_binding(),
                    wgpu::BindingResource::TextureView(&v.extinction.view),
                    wgpu::BindingResource::TextureView(&v.ambient.view),
                    wgpu::BindingResource::TextureView(&v.light_cache.view),
                    v.near_blocks.as_entire_binding(),
                ],
                groups,
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shells_grow_by_at_least_one_cell_to_the_sphere_volume() {
        for radius in 1..=32 {
            for shells in 1..=radius.min(MAX_AO_SHELLS) {
                let s = AoShells::new(radius, shells);
                let r = &s.radii;
                assert_eq!(r.len(), shells as usize);
                assert!(r[0] >= 1);
                assert!(r.windows(2).all(|w| w[1] > w[0]), "{r:?}");
                // The outer cube holds about the sphere's volume.
                let last = f64::from(*r.last().unwrap_or(&0));
                if shells * 2 <= radius {
                    assert!(
                        (last - 0.806 * f64::from(radius)).abs() <= 1.0,
                        "R {radius} N {shells}: {r:?}"
                    );
                }
                // Weights fall with distance.
                assert!(s.weights.windows(2).all(|w| w[1] < w[0]), "{:?}", s.weights);
            }
        }
    }

    #[test]
    fn the_norms_count_every_neighbour_once() {
        // One shell of half-edge 1: 6 faces at 1, 12 edges at ½, 8 corners at ⅓.
        let one = AoShells::new(1, 1);
        assert_eq!(one.radii, [1]);
        assert!((one.norm - (6.0 + 6.0 + 8.0 / 3.0)).abs() < 1e-5);
        assert!((one.weights[0] * 26.0 - one.norm).abs() < 1e-5);
        // Radius 1 sphere: 6 neighbours at distance 1.
        assert_eq!(sphere_norm(1), 6.0);
    }

    #[test]
    fn lights_parse_print_and_refuse_bad_fields() {
        use crate::settings::TextSetting;
        type Lights = Vec<ExtinctionLight>;
        let lights =
            Lights::parse_text("point:0.5,0.5,1.2;spot:0,0,0:1,1,1:30:ff8000:2").expect("valid");
        assert_eq!(lights.len(), 2);
        assert_eq!(lights[0].colour, [1.0; 3]);
        assert_eq!(lights[1].intensity, 2.0);
        assert_eq!(Lights::parse_text(&lights.text()), Ok(lights));
        for (text, field) in [
            ("lamp:1,2,3", "unknown kind"),
            ("point:1,2", "three numbers"),
            ("point:0,0,0:zz0000", "zz0000"),
            ("point:0,0,0:ffffff:99", "intensity"),
            ("spot:0,0,0:0,0,0:30", "direction"),
            ("spot:0,0,0:0,0,1:120", "angle"),
            ("directional:nan,0,1", "three numbers"),
        ] {
            let e = Lights::parse_text(text).expect_err(text);
            assert!(e.contains(field), "{text}: {e}");
        }
        let five = ["point:0,0,0"; 5].join(";");
        assert!(
            Lights::parse_text(&five)
                .expect_err("five")
                .contains("at most 4")
        );
    }

    #[test]
    fn settings_are_checked_field_by_field() {
        let ok = ExtinctionSettings::default();
        assert_eq!(ok.validate(), Ok(()));
        let cases: Vec<(ExtinctionSettings, &str)> = vec![
            (
                ExtinctionSettings {
                    sat_size: 8,
                    ..ok.clone()
                },
                "sat_size=8",
            ),
            (
                ExtinctionSettings {
                    ao_shells: 9,
                    ..ok.clone()
                },
                "ao_shells=9",
            ),
            (
                ExtinctionSettings {
                    ao_radius: 0,
                    ..ok.clone()
                },
                "ao_radius=0",
            ),
            (
                ExtinctionSettings {
                    cone_angle: f32::NAN,
                    ..ok.clone()
                },
                "cone_angle",
            ),
            (
                ExtinctionSettings {
                    cone_frequency: 0.0,
                    ..ok.clone()
                },
                "cone_frequency=0",
            ),
            (
                ExtinctionSettings {
                    cone_growth: 2.0,
                    ..ok.clone()
                },
                "cone_growth=2",
            ),
            (
                ExtinctionSettings {
                    ambient: -1.0,
                    ..ok.clone()
                },
                "ambient=-1",
            ),
            (
                ExtinctionSettings {
                    ao_method: AoMethod::Sampled,
                    colour_bleeding: true,
                    ..ok.clone()
                },
                "grey only",
            ),
        ];
        for (settings, field) in cases {
            let e = settings.validate().expect_err(field).to_string();
            assert!(e.contains(field), "{field}: {e}");
        }
    }
}
