//! Global light propagation with local piecewise integration and first-order
//! scattering (Hernell, Ljung, Ynnerman 2008), computed in the packed block
//! coordinates of the multiresolution structure.
//!
//! Four stages, each a WGSL compute shader with a CPU twin of the same name in
//! [`crate::cpu::light`]:
//! - `local_opacity`: α_lp (eq. 6), per stored voxel, atlas-shaped;
//! - `global_opacity`: α_g (eq. 7), the shadow volume representation (SVR), a
//!   regular grid at 1:1 … 1:8 of the volume's resolution;
//! - `direct_light`: I_d (eq. 8), per stored voxel;
//! - `in_scatter`: I_s (eqs. 10, 11), one direction per refinement, blended
//!   into the light volume (eq. 13);
//!
//! and `direct_light_reference`, the brute-force I_d that tests and benchmarks
//! measure the piecewise method against. The ray caster reads the light volume
//! with one extra lookup per sample (eq. 12).
//!
//! [`Illumination`] owns the light's GPU resources and decides what to
//! recompute: a transfer-function, data or light change runs every stage and the
//! first in-scattering direction (the paper's update A); every later frame adds
//! one more direction (B) until all J are in; a camera change recomputes nothing.
//! Every stage's time is reported apart ([`LightTimings`]).

mod settings;

use std::time::Instant;

use blocks::packing::Packing;
use blocks::store::LEVELS;
use glam::{Mat4, Vec3};

use crate::packed::GpuAtlas;
use crate::packed_volume::{PackedLayout, PackedVolume};
use crate::pipeline::{self, ComputeStage, run};
use crate::raycast::VolumePlacement;
use crate::settings::{Json, Settings};
use crate::volume_texture::VolumeTexture;
use crate::{GpuContext, GpuError};

pub use settings::{
    LightSettings, LightSource, MAX_DIRECTIONS, MAX_INTENSITY, MAX_LIGHT_DISTANCE, check_direction,
    check_position, parse_vec3,
};

/// The stages of global light propagation in the order they run: a change of
/// a setting recomputes from the stage it `affects` on; `in_scatter` is then
/// refined one direction per frame.
pub const STAGES: [&str; 4] = [
    "local_opacity",
    "global_opacity",
    "direct_light",
    "in_scatter",
];

/// Invocations per workgroup along each axis of the light stages.
pub const WORKGROUP_EDGE: u32 = 4;
/// The light volumes' texel format: one f32 per texel.
pub const LIGHT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;

/// The uniforms of the light stages.
// keep in sync with shaders/wgsl/shared/light_params.wgsl `LightParams`
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LightParams {
    /// Texture space → model space (affine), column major.
    pub model_from_texture: Mat4,
    /// Model space → texture space (affine), column major.
    pub texture_from_model: Mat4,
    /// Point light: model position, w = 1; directional: unit vector towards it, w = 0.
    pub light: [f32; 4],
    /// in_scatter: this step's direction (model space); w = 1: towards the light instead.
    pub scatter_direction: [f32; 4],
    /// The packed volume.
    pub volume: PackedVolume,
    /// SVR points along x, y, z.
    pub svr_dims: [u32; 3],
    /// Light intensity I0.
    pub intensity: f32,
    /// Segment length L (mm).
    pub segment: f32,
    /// Scattering radius R_Ω (mm).
    pub scatter_radius: f32,
    /// The light step h (mm).
    pub step: f32,
    /// in_scatter: blend weight w_j / W_j (eq. 13).
    pub blend: f32,
    /// Per level: slots along x, y, z and the region's first atlas z.
    pub regions: [[u32; 4]; LEVELS],
    /// Upper bound on the steps of any march.
    pub max_steps: u32,
    /// Padding to a multiple of 16 bytes.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
    /// Padding.
    pub _pad2: u32,
}

/// The affine maps between texture space and model space of a volume.
pub fn texture_transforms(texture: &VolumeTexture) -> (Mat4, Mat4) {
    let placement = VolumePlacement::of(texture);
    let m = placement.model_from_texture;
    let model_from_texture = Mat4::from_cols(
        m.x_axis.extend(0.0),
        m.y_axis.extend(0.0),
        m.z_axis.extend(0.0),
        (-(m * Vec3::splat(0.5))).extend(1.0),
    );
    (model_from_texture, model_from_texture.inverse())
}

/// SVR points along each axis for `dims` voxels at `scale`.
pub fn svr_dims(dims: [u32; 3], scale: u32) -> [u32; 3] {
    dims.map(|d| d.div_ceil(scale.max(1)).max(1))
}

impl LightParams {
    /// The uniforms for lighting the volume stored as `texture`, packed as
    /// `packing` (`layout` its sizes), with `settings` and a transfer-function
    /// table of `tf_len` entries.
    pub fn new(
        texture: &VolumeTexture,
        settings: &LightSettings,
        packing: &Packing,
        layout: PackedLayout,
        tf_len: u32,
    ) -> LightParams {
        let (model_from_texture, texture_from_model) = texture_transforms(texture);
        let radius = VolumePlacement::of(texture).radius();
        let h = texture.min_spacing();
        let light = match settings.source {
            LightSource::Point(p) => model_from_texture
                .transform_point3(Vec3::from(p))
                .extend(1.0),
            LightSource::Directional(d) => Vec3::from(d).normalize_or(Vec3::Z).extend(0.0),
        };
        // The longest march: across the volume's bounding sphere and back in from a far light.
        let max_steps = (4.0 * radius / h).ceil() as u32 + 4;
        let mut regions = [[0u32; 4]; LEVELS];
        for (l, r) in packing.regions.iter().enumerate() {
            regions[l] = [r.slots[0], r.slots[1], r.slots[2], r.z0];
        }
        LightParams {
            model_from_texture,
            texture_from_model,
            light: light.into(),
            scatter_direction: [0.0, 0.0, 1.0, 1.0],
            volume: PackedVolume::new(texture, layout, tf_len),
            svr_dims: svr_dims(texture.dims, settings.svr_scale),
            intensity: settings.intensity,
            segment: settings.segment_voxels as f32 * h,
            scatter_radius: settings.scatter_radius_voxels * h,
            step: h,
            blend: 1.0,
            regions,
            max_steps,
            _pad0: 0,
            _pad1: 0,
            _pad2: 0,
        }
    }

    /// How many blocks around a non-empty one hold SVR points that
    /// `direct_light` and `in_scatter` may read ([`near_blocks`]): a segment or
    /// R_Ω, whichever is longer, in voxels of the smallest spacing (so never
    /// short along a coarser axis), plus one SVR cell for interpolation and
    /// two voxels to spare.
    pub fn svr_margin_blocks(&self) -> u32 {
        let reach = self.segment.max(self.scatter_radius) / self.step;
        let cell = (0..3)
            .map(|i| (self.volume.volume_dims[i] / self.svr_dims[i].max(1) as f32).ceil())
            .fold(1.0f32, f32::max);
        ((reach + cell + 2.0) / blocks::store::BLOCK as f32).ceil() as u32
    }

    /// These params for in-scattering step `direction`.
    pub fn scattering(&self, direction: &ScatterDirection) -> LightParams {
        let [x, y, z] = direction.towards;
        LightParams {
            scatter_direction: [x, y, z, if direction.to_light { 1.0 } else { 0.0 }],
            blend: direction.blend,
            ..*self
        }
    }

    /// The in-scattering directions of `settings` for these params, in refinement
    /// order (the light's direction from the volume's centre orients them).
    pub fn scatter_directions(&self, settings: &LightSettings) -> Vec<ScatterDirection> {
        // Model space is centred on the volume: a point light's position is its
        // direction from the centre.
        let to_light = Vec3::new(self.light[0], self.light[1], self.light[2]);
        scatter_directions(settings.directions, settings.phase_g, to_light)
    }

    /// Atlas texels along x, y, z.
    pub fn atlas_dims(&self) -> [u32; 3] {
        self.volume.atlas_dims()
    }
}

/// One in-scattering direction of the refinement sequence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScatterDirection {
    /// Unit vector (model space) the light is gathered from.
    pub towards: [f32; 3],
    /// Gather from the light's direction at each voxel instead (the first step).
    pub to_light: bool,
    /// Phase-function weight φ_j.
    pub weight: f32,
    /// Blend weight of this step: φ_j / Σ_{i≤j} φ_i (eq. 13 when φ is uniform).
    pub blend: f32,
}

/// The vertices of an octahedron subdivided `levels` times, on the unit sphere
/// (6, 18, 66, 258 vertices).
pub fn subdivided_octahedron(levels: u32) -> Vec<Vec3> {
    let mut vertices = vec![
        Vec3::X,
        Vec3::NEG_X,
        Vec3::Y,
        Vec3::NEG_Y,
        Vec3::Z,
        Vec3::NEG_Z,
    ];
    let mut faces: Vec<[usize; 3]> = vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    for _ in 0..levels {
        let mut midpoints = std::collections::HashMap::new();
        let mut midpoint = |a: usize, b: usize, vertices: &mut Vec<Vec3>| {
            *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                vertices.push(((vertices[a] + vertices[b]) * 0.5).normalize());
                vertices.len() - 1
            })
        };
        let mut next = Vec::with_capacity(faces.len() * 4);
        for [a, b, c] in faces {
            let ab = midpoint(a, b, &mut vertices);
            let bc = midpoint(b, c, &mut vertices);
            let ca = midpoint(c, a, &mut vertices);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    vertices
}

/// The J in-scattering directions in refinement order: the light's direction
/// first (per voxel), then the vertices of the smallest subdivided octahedron
/// with at least J vertices, turned so one vertex points at the light (that one
/// is the light's direction) and ordered farthest-first so that every prefix
/// covers the sphere evenly. Weights follow the Henyey–Greenstein phase
/// function of asymmetry `g` about the light's direction seen from the volume's
/// centre (`to_light`, model space).
pub fn scatter_directions(directions: u32, g: f32, to_light: Vec3) -> Vec<ScatterDirection> {
    let to_light = to_light.normalize_or(Vec3::Z);
    let levels = (0..4)
        .find(|&l| subdivided_octahedron(l).len() >= directions as usize)
        .unwrap_or(3);
    let rotation = glam::Quat::from_rotation_arc(Vec3::X, to_light);
    let rest: Vec<Vec3> = subdivided_octahedron(levels)
        .into_iter()
        .skip(1)
        .map(|v| rotation * v)
        .collect();
    // Farthest-first order, starting from the light's direction.
    let mut chosen = vec![to_light];
    let mut left = rest;
    while chosen.len() < directions as usize && !left.is_empty() {
        let (i, _) = left
            .iter()
            .enumerate()
            .map(|(i, v)| {
                (
                    i,
                    chosen
                        .iter()
                        .map(|c| c.dot(*v))
                        .fold(f32::NEG_INFINITY, f32::max),
                )
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((0, 0.0));
        chosen.push(left.swap_remove(i));
    }
    let phase = |cos: f32| (1.0 - g * g) / (1.0 + g * g - 2.0 * g * cos).powf(1.5);
    let mut total = 0.0;
    chosen
        .iter()
        .enumerate()
        .map(|(j, v)| {
            let weight = phase(v.dot(to_light));
            total += weight;
            ScatterDirection {
                towards: (*v).into(),
                to_light: j == 0,
                weight,
                blend: weight / total,
            }
        })
        .collect()
}

/// Per slot of every level's region, in region order and slot order (x
/// fastest): the block it holds (its index in the block grid, x fastest), or
/// `u32::MAX`.
pub fn slot_blocks(packing: &Packing) -> Vec<u32> {
    let mut first = [0usize; LEVELS];
    let mut total = 0usize;
    for (l, r) in packing.regions.iter().enumerate() {
        first[l] = total;
        total += r.capacity() as usize;
    }
    let mut slots = vec![u32::MAX; total.max(1)];
    for (b, (&level, &slot)) in packing.lod.iter().zip(&packing.slot).enumerate() {
        if usize::from(level) < LEVELS {
            slots[first[usize::from(level)] + slot as usize] = b as u32;
        }
    }
    slots
}

/// Per block of the block grid (x fastest): 1 for blocks within
/// `margin_blocks` (along every axis) of a non-empty block, else 0 — where a
/// light term is ever read. `global_opacity` computes SVR points only there
/// (`direct_light` reads the SVR one segment from a stored voxel and
/// `in_scatter` at R_Ω from one), and the extinction stages fill only light-cache
/// cells there (the ray caster reads the cache one cell from a stored sample),
/// so the light's cost follows the kept blocks, not the volume. A separable
/// dilation, so the cost is linear in blocks whatever the margin.
pub fn near_blocks(packing: &Packing, grid: [u32; 3], margin_blocks: u32) -> Vec<u32> {
    let [nx, ny, nz] = grid.map(|g| g as usize);
    let m = margin_blocks as usize;
    let mut mask: Vec<u32> = packing
        .lod
        .iter()
        .map(|&l| u32::from(usize::from(l) < LEVELS))
        .collect();
    mask.resize(nx * ny * nz, 0);
    let strides = [1, nx, nx * ny];
    for (axis, n) in [nx, ny, nz].into_iter().enumerate() {
        let stride = strides[axis];
        let mut next = vec![0u32; mask.len()];
        for (i, out) in next.iter_mut().enumerate() {
            let c = (i / stride) % n;
            let base = i - c * stride;
            let (lo, hi) = (c.saturating_sub(m), (c + m).min(n - 1));
            *out = u32::from((lo..=hi).any(|k| mask[base + k * stride] != 0));
        }
        mask = next;
    }
    mask
}

/// Workgroups of the light stages covering `dims` invocations.
pub fn workgroups(dims: [u32; 3]) -> [u32; 3] {
    dims.map(|d| d.div_ceil(WORKGROUP_EDGE))
}

/// The compiled light stages.
#[derive(Debug)]
pub struct LightPipelines {
    /// `local_opacity`.
    pub local_opacity: ComputeStage,
    /// `global_opacity`.
    pub global_opacity: ComputeStage,
    /// `direct_light`.
    pub direct_light: ComputeStage,
    /// `in_scatter`.
    pub in_scatter: ComputeStage,
    /// `direct_light_reference`.
    pub direct_light_reference: ComputeStage,
    sampler: wgpu::Sampler,
}

impl LightPipelines {
    /// Compiles the stages; refused on adapters whose 32-bit float textures do
    /// not filter.
    pub fn new(gpu: &GpuContext) -> Result<LightPipelines, GpuError> {
        if !gpu
            .device
            .features()
            .contains(wgpu::Features::FLOAT32_FILTERABLE)
        {
            return Err(GpuError::Unsupported {
                what: "global light propagation".into(),
                limit: format!(
                    "adapter '{}' cannot filter 32-bit float textures (wgpu feature FLOAT32_FILTERABLE)",
                    gpu.info.name
                ),
            });
        }
        use pipeline::{
            float_texture_3d as float3d, sampler, storage_buffer, storage_texture, uint_texture_3d,
            uniform,
        };
        let params = || uniform(0, size_of::<LightParams>());
        let write = |b| {
            storage_texture(
                b,
                LIGHT_FORMAT,
                wgpu::StorageTextureAccess::WriteOnly,
                wgpu::TextureViewDimension::D3,
            )
        };
        let read_write = |b| {
            storage_texture(
                b,
                LIGHT_FORMAT,
                wgpu::StorageTextureAccess::ReadWrite,
                wgpu::TextureViewDimension::D3,
            )
        };
        let data = |entries: &mut Vec<wgpu::BindGroupLayoutEntry>| {
            entries.extend([
                float3d(1),
                sampler(2),
                storage_buffer(3),
                uint_texture_3d(4),
                storage_buffer(5),
            ]);
        };
        let mut local = vec![params()];
        data(&mut local);
        local.push(write(6));
        let mut reference = vec![params()];
        data(&mut reference);
        reference.push(write(6));
        let mut scatter = vec![params()];
        data(&mut scatter);
        scatter.extend([float3d(6), float3d(7), read_write(8)]);
        Ok(LightPipelines {
            local_opacity: ComputeStage::new(
                gpu,
                "local_opacity",
                crate::wgsl::LOCAL_OPACITY,
                &local,
            )?,
            global_opacity: ComputeStage::new(
                gpu,
                "global_opacity",
                crate::wgsl::GLOBAL_OPACITY,
                &[
                    params(),
                    float3d(1),
                    sampler(2),
                    uint_texture_3d(3),
                    write(4),
                    storage_buffer(5),
                ],
            )?,
            direct_light: ComputeStage::new(
                gpu,
                "direct_light",
                crate::wgsl::DIRECT_LIGHT,
                &[
                    params(),
                    float3d(1),
                    float3d(2),
                    sampler(3),
                    storage_buffer(4),
                    write(5),
                ],
            )?,
            in_scatter: ComputeStage::new(gpu, "in_scatter", crate::wgsl::IN_SCATTER, &scatter)?,
            direct_light_reference: ComputeStage::new(
                gpu,
                "direct_light_reference",
                crate::wgsl::DIRECT_LIGHT_REFERENCE,
                &reference,
            )?,
            sampler: pipeline::linear_sampler(gpu),
        })
    }
}

/// A 3D texture of f32 texels the light stages write and the others read.
#[derive(Debug)]
pub struct LightTexture {
    /// The texture.
    pub texture: wgpu::Texture,
    /// A view of it.
    pub view: wgpu::TextureView,
    /// Texels along x, y, z.
    pub dims: [u32; 3],
}

impl LightTexture {
    fn new(gpu: &GpuContext, label: &str, dims: [u32; 3]) -> Result<LightTexture, GpuError> {
        let texture = crate::volume_texture::create_texture_3d_for(
            gpu,
            label,
            dims,
            LIGHT_FORMAT,
            wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::STORAGE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
        )?;
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(LightTexture {
            texture,
            view,
            dims,
        })
    }

    /// Reads every texel back (x fastest), for tests and the CPU comparison.
    pub fn read(&self, gpu: &GpuContext) -> Result<Vec<f32>, GpuError> {
        read_texture_f32(gpu, &self.texture, self.dims)
    }
}

/// Reads a 3D texture of 4-byte texels back, rows unpadded, x fastest.
pub fn read_texture_f32(
    gpu: &GpuContext,
    texture: &wgpu::Texture,
    dims: [u32; 3],
) -> Result<Vec<f32>, GpuError> {
    let bytes = read_texture_bytes(gpu, texture, dims, wgpu::TextureFormat::R32Float)?;
    Ok(bytemuck::pod_collect_to_vec::<u8, f32>(&bytes))
}

/// Reads a 3D texture of `format` back as bytes, rows unpadded, x fastest.
pub fn read_texture_bytes(
    gpu: &GpuContext,
    texture: &wgpu::Texture,
    dims: [u32; 3],
    format: wgpu::TextureFormat,
) -> Result<Vec<u8>, GpuError> {
    let [w, h, d] = dims;
    let texel = format.block_copy_size(None).unwrap_or(4);
    let row = w * texel;
    let padded =
        row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let mut out = Vec::with_capacity((row * h * d) as usize);
    // A slab of slices at a time keeps the readback buffer small.
    let slab = ((64u64 << 20) / (u64::from(padded) * u64::from(h))).clamp(1, u64::from(d)) as u32;
    let mut z = 0;
    while z < d {
        let depth = slab.min(d - z);
        let buffer = gpu.scoped("reading a light texture back", || {
            let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("light readback"),
                size: u64::from(padded) * u64::from(h) * u64::from(depth),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: 0, z },
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: &buffer,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(padded),
                        rows_per_image: Some(h),
                    },
                },
                wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: depth,
                },
            );
            gpu.queue.submit([encoder.finish()]);
            buffer
        })?;
        gpu.read_buffer(&buffer, "a light texture", |bytes| {
            for padded_row in bytes.chunks(padded as usize) {
                out.extend_from_slice(&padded_row[..row as usize]);
            }
        })?;
        z += depth;
    }
    Ok(out)
}

/// The light's GPU resources for one atlas layout and SVR size.
#[derive(Debug)]
pub struct LightVolumes {
    /// α_lp, atlas-shaped.
    pub local_opacity: LightTexture,
    /// α_g, the SVR.
    pub shadow_volume: LightTexture,
    /// I_d, atlas-shaped.
    pub direct_light: LightTexture,
    /// I_s, atlas-shaped: what the ray caster reads.
    pub light_volume: LightTexture,
    params: wgpu::Buffer,
    slot_blocks: wgpu::Buffer,
    slot_capacity: usize,
    /// [`near_blocks`] for the SVR's margin, one u32 per block.
    svr_blocks: wgpu::Buffer,
    block_count: usize,
}

impl LightVolumes {
    /// Allocates the textures for atlases of `atlas_dims` and an SVR of `svr_dims`.
    pub fn new(
        gpu: &GpuContext,
        atlas_dims: [u32; 3],
        svr_dims: [u32; 3],
        slots: usize,
        block_count: usize,
    ) -> Result<LightVolumes, GpuError> {
        let buffers = gpu.scoped("creating light buffers", || {
            (
                gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("light params"),
                    size: size_of::<LightParams>() as u64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
                gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("slot blocks"),
                    size: (slots.max(1) * 4) as u64,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
                gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("svr blocks"),
                    size: (block_count.max(1) * 4) as u64,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
            )
        })?;
        Ok(LightVolumes {
            local_opacity: LightTexture::new(gpu, "local opacity atlas", atlas_dims)?,
            shadow_volume: LightTexture::new(gpu, "shadow volume", svr_dims)?,
            direct_light: LightTexture::new(gpu, "direct light atlas", atlas_dims)?,
            light_volume: LightTexture::new(gpu, "light volume", atlas_dims)?,
            params: buffers.0,
            slot_blocks: buffers.1,
            slot_capacity: slots.max(1),
            svr_blocks: buffers.2,
            block_count: block_count.max(1),
        })
    }

    fn fits(
        &self,
        atlas_dims: [u32; 3],
        svr_dims: [u32; 3],
        slots: usize,
        block_count: usize,
    ) -> bool {
        self.local_opacity.dims == atlas_dims
            && self.shadow_volume.dims == svr_dims
            && self.slot_capacity >= slots
            && self.block_count >= block_count
    }
}

/// What the light stages of one frame took, in milliseconds (0 for stages
/// that did not run).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct LightTimings {
    /// `local_opacity`.
    pub local_opacity_ms: f64,
    /// `global_opacity`.
    pub global_opacity_ms: f64,
    /// `direct_light` (or `direct_light_reference`).
    pub direct_light_ms: f64,
    /// `in_scatter`, all steps this frame.
    pub in_scatter_ms: f64,
    /// The whole light update of this frame.
    pub total_ms: f64,
    /// True when every stage ran (the paper's update A).
    pub recomputed: bool,
    /// In-scattering directions blended so far (j).
    pub refined: u32,
    /// Directions in all (J).
    pub directions: u32,
}

/// The inputs a light computation reads: the resident blocks and the
/// transfer-function table.
#[derive(Debug, Clone, Copy)]
pub struct LightInputs<'a> {
    /// The packed data and its index.
    pub atlas: &'a GpuAtlas,
    /// The transfer-function table, `array<vec4<f32>>`.
    pub transfer_function: &'a wgpu::Buffer,
    /// How texels map to the transfer function.
    pub texture: &'a VolumeTexture,
    /// Entries in the table.
    pub tf_len: u32,
}

/// How I_d is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DirectLightMethod {
    /// The paper's: local segments, the SVR, eq. 8.
    Piecewise,
    /// Brute force, for reference.
    Reference,
}

/// The light of one renderer: GPU resources, what they were computed for, and
/// the refinement reached. See the module docs.
#[derive(Debug)]
pub struct Illumination {
    pipelines: LightPipelines,
    volumes: Option<LightVolumes>,
    /// (data version, transfer function, light key, method) of the stored light.
    computed_for: Option<(u64, blocks::TransferFunction, Vec<Json>, DirectLightMethod)>,
    directions: Vec<ScatterDirection>,
    params: Option<LightParams>,
    refined: usize,
}

impl Illumination {
    /// Compiles the light stages.
    pub fn new(gpu: &GpuContext) -> Result<Illumination, GpuError> {
        Ok(Illumination {
            pipelines: LightPipelines::new(gpu)?,
            volumes: None,
            computed_for: None,
            directions: Vec::new(),
            params: None,
            refined: 0,
        })
    }

    /// The stored light, once computed.
    pub fn light_volume(&self) -> Option<&wgpu::TextureView> {
        self.volumes.as_ref().map(|v| &v.light_volume.view)
    }

    /// The light's textures, once computed (tests read them back).
    pub fn volumes(&self) -> Option<&LightVolumes> {
        self.volumes.as_ref()
    }

    /// The params of the last computation.
    pub fn params(&self) -> Option<&LightParams> {
        self.params.as_ref()
    }

    /// Whether every in-scattering direction is in.
    pub fn converged(&self) -> bool {
        self.computed_for.is_some() && self.refined >= self.directions.len()
    }

    /// Forgets the stored light, so the next update recomputes it.
    pub fn invalidate(&mut self) {
        self.computed_for = None;
    }

    /// Brings the light up to date for one frame: everything (update A) when the
    /// data (`data_version`), transfer function, light or `method` changed,
    /// else one more in-scattering direction (refinement B) until all are in.
    pub fn update(
        &mut self,
        gpu: &GpuContext,
        inputs: LightInputs<'_>,
        tf: &blocks::TransferFunction,
        settings: &LightSettings,
        data_version: u64,
        method: DirectLightMethod,
    ) -> Result<LightTimings, GpuError> {
        settings.validate_fields()?;
        let start = Instant::now();
        let mut timings = LightTimings::default();
        let key = (
            data_version,
            tf.clone(),
            crate::settings::stage_key(settings, &STAGES, "in_scatter"),
            method,
        );
        if self.computed_for.as_ref() != Some(&key) {
            self.computed_for = None;
            self.recompute(gpu, inputs, settings, method, &mut timings)?;
            self.computed_for = Some(key);
            timings.recomputed = true;
        } else if self.refined < self.directions.len() {
            timings.in_scatter_ms += self.scatter(gpu, inputs, self.refined)?;
            self.refined += 1;
        }
        timings.total_ms = start.elapsed().as_secs_f64() * 1e3;
        timings.refined = self.refined as u32;
        timings.directions = self.directions.len() as u32;
        Ok(timings)
    }

    /// Runs every remaining refinement step (for a converged still image).
    pub fn converge(&mut self, gpu: &GpuContext, inputs: LightInputs<'_>) -> Result<f64, GpuError> {
        let mut ms = 0.0;
        while self.computed_for.is_some() && self.refined < self.directions.len() {
            ms += self.scatter(gpu, inputs, self.refined)?;
            self.refined += 1;
        }
        Ok(ms)
    }

    fn recompute(
        &mut self,
        gpu: &GpuContext,
        inputs: LightInputs<'_>,
        settings: &LightSettings,
        method: DirectLightMethod,
        timings: &mut LightTimings,
    ) -> Result<(), GpuError> {
        let packing = &inputs.atlas.packing;
        let params = LightParams::new(
            inputs.texture,
            settings,
            packing,
            inputs.atlas.layout,
            inputs.tf_len,
        );
        let slots = slot_blocks(packing);
        let atlas_dims = inputs.atlas.layout.atlas_dims;
        let svr = params.svr_dims;
        let svr_mask = near_blocks(
            packing,
            params.volume.block_grid,
            params.svr_margin_blocks(),
        );
        if !self
            .volumes
            .as_ref()
            .is_some_and(|v| v.fits(atlas_dims, svr, slots.len(), svr_mask.len()))
        {
            // The old textures go before the new ones are made.
            self.volumes = None;
            self.volumes = Some(LightVolumes::new(
                gpu,
                atlas_dims,
                svr,
                slots.len(),
                svr_mask.len(),
            )?);
        }
        let Some(volumes) = &self.volumes else {
            return Err(GpuError::InvalidRequest("no light volumes".into()));
        };
        gpu.queue
            .write_buffer(&volumes.slot_blocks, 0, bytemuck::cast_slice(&slots));
        gpu.queue
            .write_buffer(&volumes.svr_blocks, 0, bytemuck::cast_slice(&svr_mask));
        gpu.queue
            .write_buffer(&volumes.params, 0, bytemuck::bytes_of(&params));
        self.directions = params.scatter_directions(settings);
        self.params = Some(params);
        self.refined = 0;
        let p = &self.pipelines;
        let atlas_groups = workgroups(atlas_dims);
        let data = [
            volumes.params.as_entire_binding(),
            wgpu::BindingResource::TextureView(&inputs.atlas.atlas_view),
            wgpu::BindingResource::Sampler(&p.sampler),
            inputs.transfer_function.as_entire_binding(),
            wgpu::BindingResource::TextureView(&inputs.atlas.index_view),
            volumes.slot_blocks.as_entire_binding(),
        ];
        let global = [
            volumes.params.as_entire_binding(),
            wgpu::BindingResource::TextureView(&volumes.local_opacity.view),
            wgpu::BindingResource::Sampler(&p.sampler),
            wgpu::BindingResource::TextureView(&inputs.atlas.index_view),
            wgpu::BindingResource::TextureView(&volumes.shadow_volume.view),
            volumes.svr_blocks.as_entire_binding(),
        ];
        match method {
            DirectLightMethod::Piecewise => {
                let mut local = data.to_vec();
                local.push(wgpu::BindingResource::TextureView(
                    &volumes.local_opacity.view,
                ));
                timings.local_opacity_ms = run(gpu, &p.local_opacity, &local, atlas_groups)?;
                timings.global_opacity_ms = run(gpu, &p.global_opacity, &global, workgroups(svr))?;
                timings.direct_light_ms = run(
                    gpu,
                    &p.direct_light,
                    &[
                        volumes.params.as_entire_binding(),
                        wgpu::BindingResource::TextureView(&volumes.local_opacity.view),
                        wgpu::BindingResource::TextureView(&volumes.shadow_volume.view),
                        wgpu::BindingResource::Sampler(&p.sampler),
                        volumes.slot_blocks.as_entire_binding(),
                        wgpu::BindingResource::TextureView(&volumes.direct_light.view),
                    ],
                    atlas_groups,
                )?;
            }
            DirectLightMethod::Reference => {
                // The SVR is still needed for the light beyond R_Ω in in_scatter.
                let mut local = data.to_vec();
                local.push(wgpu::BindingResource::TextureView(
                    &volumes.local_opacity.view,
                ));
                run(gpu, &p.local_opacity, &local, atlas_groups)?;
                run(gpu, &p.global_opacity, &global, workgroups(svr))?;
                let mut reference = data.to_vec();
                reference.push(wgpu::BindingResource::TextureView(
                    &volumes.direct_light.view,
                ));
                timings.direct_light_ms =
                    run(gpu, &p.direct_light_reference, &reference, atlas_groups)?;
            }
        }
        timings.in_scatter_ms = self.scatter(gpu, inputs, 0)?;
        self.refined = 1;
        Ok(())
    }

    /// In-scattering step `j` (0-based) into the light volume.
    fn scatter(
        &self,
        gpu: &GpuContext,
        inputs: LightInputs<'_>,
        j: usize,
    ) -> Result<f64, GpuError> {
        let (Some(volumes), Some(params), Some(direction)) =
            (&self.volumes, &self.params, self.directions.get(j))
        else {
            return Ok(0.0);
        };
        let step = params.scattering(direction);
        // Each step gets its own uniform buffer: queue writes land before the
        // next submit, so one shared buffer would be overwritten too early.
        let step_params = gpu.scoped("writing in-scattering params", || {
            let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("in-scattering params"),
                size: size_of::<LightParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            gpu.queue
                .write_buffer(&buffer, 0, bytemuck::bytes_of(&step));
            buffer
        })?;
        let p = &self.pipelines;
        run(
            gpu,
            &p.in_scatter,
            &[
                step_params.as_entire_binding(),
                wgpu::BindingResource::TextureView(&inputs.atlas.atlas_view),
                wgpu::BindingResource::Sampler(&p.sampler),
                inputs.transfer_function.as_entire_binding(),
                wgpu::BindingResource::TextureView(&inputs.atlas.index_view),
                volumes.slot_blocks.as_entire_binding(),
                wgpu::BindingResource::TextureView(&volumes.direct_light.view),
                wgpu::BindingResource::TextureView(&volumes.shadow_volume.view),
                wgpu::BindingResource::TextureView(&volumes.light_volume.view),
            ],
            workgroups(volumes.light_volume.dims),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn near_blocks_mark_exactly_the_blocks_within_the_margin_of_a_kept_one() {
        let grid = [7u32, 5, 4];
        let n = (grid[0] * grid[1] * grid[2]) as usize;
        let mut lod = vec![blocks::lod::EMPTY; n];
        let kept = [(1u32, 1u32, 0u32), (6, 4, 3)];
        for &(x, y, z) in &kept {
            lod[(x + grid[0] * (y + grid[1] * z)) as usize] = 0;
        }
        let packing = Packing {
            atlas_dims: [18; 3],
            regions: [blocks::packing::Region {
                z0: 0,
                slots: [0; 3],
            }; LEVELS],
            lod,
            slot: vec![0; n],
        };
        for margin in 0..4u32 {
            let mask = near_blocks(&packing, grid, margin);
            for z in 0..grid[2] {
                for y in 0..grid[1] {
                    for x in 0..grid[0] {
                        let near = kept.iter().any(|&(kx, ky, kz)| {
                            kx.abs_diff(x) <= margin
                                && ky.abs_diff(y) <= margin
                                && kz.abs_diff(z) <= margin
                        });
                        let got = mask[(x + grid[0] * (y + grid[1] * z)) as usize];
                        assert_eq!(
                            got,
                            u32::from(near),
                            "margin {margin}, block ({x}, {y}, {z})"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn octahedron_subdivisions_have_the_known_vertex_counts_on_the_sphere() {
        for (level, count) in [(0, 6), (1, 18), (2, 66), (3, 258)] {
            let v = subdivided_octahedron(level);
            assert_eq!(v.len(), count);
            assert!(v.iter().all(|p| (p.length() - 1.0).abs() < 1e-5));
        }
    }

    #[test]
    fn scattering_starts_at_the_light_and_spreads_with_weights_that_blend_to_a_mean() {
        let to_light = Vec3::new(0.3, -0.5, 0.8);
        let d = scatter_directions(18, 0.0, to_light);
        assert_eq!(d.len(), 18);
        assert!(d[0].to_light && !d[1].to_light);
        assert!((Vec3::from(d[0].towards) - to_light.normalize()).length() < 1e-5);
        // The second direction is the farthest from the light's: opposite it.
        assert!(Vec3::from(d[1].towards).dot(to_light.normalize()) < -0.99);
        // Isotropic: blend = 1/j (eq. 13).
        for (j, s) in d.iter().enumerate() {
            assert!((s.blend - 1.0 / (j + 1) as f32).abs() < 1e-6);
        }
        // Forward scattering weighs directions near the light's more.
        let f = scatter_directions(6, 0.6, to_light);
        assert!(f[0].weight > f[2].weight && f[2].weight > f[1].weight);
        assert_eq!(scatter_directions(1, 0.0, to_light).len(), 1);
        assert_eq!(scatter_directions(7, 0.0, to_light).len(), 7);
    }

    #[test]
    fn settings_are_checked_field_by_field() {
        assert!(LightSettings::default().validate_fields().is_ok());
        let bad = [
            (
                LightSettings {
                    segment_voxels: 2,
                    ..Default::default()
                },
                "segment=2",
            ),
            (
                LightSettings {
                    svr_scale: 3,
                    ..Default::default()
                },
                "svr=3: expected 1, 2, 4 or 8",
            ),
            (
                LightSettings {
                    scatter_radius_voxels: f32::NAN,
                    ..Default::default()
                },
                "scatter_radius",
            ),
            (
                LightSettings {
                    directions: 0,
                    ..Default::default()
                },
                "directions=0",
            ),
            (
                LightSettings {
                    bias: 1.5,
                    ..Default::default()
                },
                "bias=1.5",
            ),
            (
                LightSettings {
                    phase_g: 1.0,
                    ..Default::default()
                },
                "phase_g",
            ),
            (
                LightSettings {
                    source: LightSource::Directional([0.0; 3]),
                    ..Default::default()
                },
                "zero",
            ),
            (
                LightSettings {
                    source: LightSource::Point([f32::INFINITY, 0.0, 0.0]),
                    ..Default::default()
                },
                "position",
            ),
        ];
        for (settings, want) in bad {
            let e = settings.validate_fields().expect_err(want).to_string();
            assert!(e.contains(want), "{e}");
        }
        use crate::settings::TextSetting;
        assert_eq!(
            LightSource::parse_text("point:0.5,0.5,0.5"),
            Ok(LightSource::Point([0.5; 3]))
        );
        assert_eq!(
            LightSource::parse_text("directional:0,0,1"),
            Ok(LightSource::Directional([0.0, 0.0, 1.0]))
        );
        for bad in ["sun:0,0,1", "point:1,2", "point", "directional:a,b,c"] {
            assert!(
                LightSource::parse_text(bad)
                    .expect_err(bad)
                    .contains("point:x,y,z"),
                "{bad}"
            );
        }
    }
}
