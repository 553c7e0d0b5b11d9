//! The ray-marching stages and their uniforms: `raycast` renders packed blocks
//! through the block index (`shaders/wgsl/raycast.wgsl`; CPU twin
//! [`crate::cpu::raycast`]), `reference` renders one plain full-resolution
//! texture (`shaders/wgsl/reference.wgsl`; CPU twin [`crate::cpu::reference`]).
//! Both share the march of `shaders/wgsl/shared/march.wgsl`.
//!
//! [`RaycastParams`] is built once per frame from the [`FrameRequest`] and the
//! volume's geometry by [`RaycastParams::new`]; GPU stages and CPU twins read
//! exactly that struct, so they differ only in arithmetic.

use blocks::{Geometry, TransferFunction};
use glam::{Mat3, Mat4, Vec3, Vec4};

use crate::camera::box_corners;
use crate::illumination::Mode;
use crate::packed_volume::{PackedLayout, PackedVolume};
use crate::pipeline::ComputeStage;
use crate::volume_texture::VolumeTexture;
use crate::{Compositing, FrameRequest, GpuContext, GpuError, Shading};

/// Invocations per workgroup along x and y.
pub const WORKGROUP_SIZE: u32 = 8;
/// Accumulated opacity at which a ray stops.
pub const EARLY_TERMINATION: f32 = 0.99;
/// The least weight in its pixel at which a sample is shaded with the
/// frame's normal (the cubic B-spline's with [`FLAG_CUBIC_GRADIENT`], else
/// central differences blended from the eight texels about it): its weight is
/// the ray's transparency before it times its class's opacity (per reference
/// step, so the same samples at any step). Lighter samples, the faint haze in
/// front of and around a surface and most of a frame's shaded ones, are
/// shaded with the central differences of the texel nearest them (six reads,
/// no blend): at steps up to the reference step each moves its pixel by less
/// than one 8-bit step (its corrected opacity is at most its class's), and
/// their normals differ little, where the blend reads several times the
/// texels (a trilinear read per neighbour on the GPU) and the cubic normal
/// more.
pub const FAINT_WEIGHT: f32 = 1.0 / 256.0;
/// The light, in view space (x right, y up, z towards the eye): above and to the
/// left of the eye, so shapes read as lit from the upper left.
const LIGHT_IN_VIEW: Vec3 = Vec3::new(-0.35, 0.45, 1.0);
/// Blinn–Phong ambient, diffuse, specular and shininess.
const PHONG: [f32; 4] = [0.35, 0.65, 0.25, 24.0];
/// Gradients weaker than this fraction of the value range per voxel stay unshaded.
const GRADIENT_THRESHOLD_PER_VOXEL: f32 = 0.002;

/// [`RaycastParams::flags`] bit: jitter each ray's first sample.
pub const FLAG_JITTER: u32 = 1;
/// [`RaycastParams::flags`] bit: gradient Blinn–Phong shading of composited samples.
pub const FLAG_SHADED: u32 = 2;
/// [`RaycastParams::flags`] bit: jump over empty blocks.
pub const FLAG_SKIP_EMPTY: u32 = 4;
/// [`RaycastParams::flags`] bit: light samples with the stored light volume (eq. 12).
pub const FLAG_LIT: u32 = 8;
/// [`RaycastParams::flags`] bit: exponential extinction compositing (eq. 2 of
/// Schlegel et al.) instead of α-blending.
pub const FLAG_EXTINCTION: u32 = 16;
/// [`RaycastParams::flags`] bit: normals from the gradient of the cubic
/// B-spline reconstruction at each block's level, not from central
/// differences (`FrameRequest::cubic_gradient`).
pub const FLAG_CUBIC_GRADIENT: u32 = 32;
/// [`RaycastParams::mode`]: front-to-back compositing.
pub const MODE_COMPOSITE: u32 = 0;
/// [`RaycastParams::mode`]: maximum intensity projection.
pub const MODE_MIP: u32 = 1;
/// [`RaycastParams::mode`]: minimum intensity projection.
pub const MODE_MINIP: u32 = 2;

/// The per-frame uniforms of the ray-marching stages.
// keep in sync with shaders/wgsl/shared/raycast_params.wgsl `RaycastParams`
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RaycastParams {
    /// Clip space → model space, column major.
    pub inv_view_proj: Mat4,
    /// Model space → texture space (affine), column major.
    pub texture_from_model: Mat4,
    /// Texture-space derivatives → model-space gradients (upper 3×3 used).
    pub gradient_from_texture: Mat4,
    /// The packed volume (`atlas_size` 1 and `block_grid` 0 for the reference stage).
    pub volume: PackedVolume,
    /// Unit vector towards the light, model space.
    pub light_dir: [f32; 3],
    /// Distance between samples (mm).
    pub step: f32,
    /// Clip box lower corner, texture space.
    pub clip_min: [f32; 3],
    /// Accumulated opacity at which a ray stops.
    pub early_termination: f32,
    /// Clip box upper corner, texture space.
    pub clip_max: [f32; 3],
    /// Gradient magnitude (transfer-function units per mm) under which samples stay unshaded.
    pub gradient_threshold: f32,
    /// Background colour (rgb, a unused).
    pub background: [f32; 4],
    /// Light colour times intensity (rgb) and I_bias (a), for [`FLAG_LIT`].
    pub light: [f32; 4],
    /// Blinn–Phong ambient, diffuse, specular, shininess.
    pub phong: [f32; 4],
    /// Image width in pixels.
    pub width: u32,
    /// Rows this dispatch draws: the image's height, or a band's
    /// ([`FrameRequest::rows`]).
    pub height: u32,
    /// `FLAG_*` bits.
    pub flags: u32,
    /// `MODE_*`.
    pub mode: u32,
    /// Upper bound on samples per ray.
    pub max_steps: u32,
    /// How far towards the eye (mm) the light is read, so a surface reads the
    /// light just outside it rather than a blend with the shadowed texels
    /// behind it: [`crate::extinction::LIGHT_READ_CELLS`] light-cache cells
    /// for extinction-based illumination,
    /// [`crate::illumination::LIGHT_READ_VOXELS`] voxels for global light;
    /// 0 otherwise.
    pub light_offset: f32,
    /// The image row this dispatch's first row is (0 unless a band).
    pub first_row: u32,
    /// The image's height in rows, which places the rays.
    pub image_height: u32,
    /// The greyscale window of [`MODE_MIP`] and [`MODE_MINIP`] in
    /// transfer-function coordinates: the value shown black (x) and the span
    /// to white (y).
    pub window: [f32; 2],
    /// [`FAINT_WEIGHT`].
    pub faint_weight: f32,
    /// Unused (the uniform's size, a multiple of 16 bytes).
    pub _pad0: f32,
}

/// Where the volume sits in model space: the linear map from texture offsets
/// (u − ½) to model millimetres, whose columns are the index axes' direction
/// times the volume's extent along them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumePlacement {
    /// Texture offset → model mm.
    pub model_from_texture: Mat3,
}

impl VolumePlacement {
    /// The placement of a volume stored as `texture`.
    pub fn of(texture: &VolumeTexture) -> VolumePlacement {
        VolumePlacement::of_geometry(&texture.geometry)
    }

    /// The placement of a volume of `geometry`.
    pub fn of_geometry(geometry: &Geometry) -> VolumePlacement {
        let extent = geometry.extent_mm_f32();
        let direction = geometry.direction_f32();
        let column = |i: usize| Vec3::from(direction[i]) * extent[i];
        VolumePlacement {
            model_from_texture: Mat3::from_cols(column(0), column(1), column(2)),
        }
    }

    /// The smallest model-space box (mm, axis-aligned) around the voxels
    /// `lo..hi` (index ranges, voxel edges) of a volume of `dims` voxels.
    pub fn model_box(&self, dims: [u32; 3], lo: [u32; 3], hi: [u32; 3]) -> (Vec3, Vec3) {
        let offset = |edge: [u32; 3]| {
            Vec3::from_array(std::array::from_fn(|a| {
                edge[a] as f32 / dims[a].max(1) as f32 - 0.5
            }))
        };
        let (mut min, mut max) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for corner in box_corners(offset(lo), offset(hi)) {
            let p = self.model_from_texture * corner;
            (min, max) = (min.min(p), max.max(p));
        }
        (min, max)
    }

    /// The radius of the sphere around the model origin that holds the volume.
    pub fn radius(&self) -> f32 {
        box_corners(Vec3::splat(-0.5), Vec3::splat(0.5))
            .iter()
            .map(|&c| (self.model_from_texture * c).length())
            .fold(0.0, f32::max)
    }
}

/// The most samples a ray takes through a volume within `radius` mm of its
/// centre at `step` mm: the bound of the march's loop.
fn max_samples_per_ray(radius: f32, step: f32) -> u32 {
    (2.0 * radius / step).ceil() as u32 + 2
}

/// The most samples one pixel of `request` costs over a volume of
/// `geometry`: what the render worker prices a frame by (pixels × this).
pub fn samples_per_ray(geometry: &Geometry, request: &FrameRequest) -> u32 {
    let radius = VolumePlacement::of_geometry(geometry).radius();
    max_samples_per_ray(radius, request.step_voxels * geometry.min_spacing_f32())
}

impl RaycastParams {
    /// The uniforms for rendering `request` of the volume stored as `texture`,
    /// classified by `tf` as a table of `tf_len` entries, from packed blocks laid
    /// out as `packed` (zeros for the reference stage).
    pub fn new(
        texture: &VolumeTexture,
        request: &FrameRequest,
        tf: &TransferFunction,
        tf_len: u32,
        packed: PackedLayout,
    ) -> RaycastParams {
        let placement = VolumePlacement::of(texture);
        let radius = placement.radius();
        let texture_from_model_linear = placement.model_from_texture.inverse();
        let texture_from_model = Mat4::from_cols(
            texture_from_model_linear.x_axis.extend(0.0),
            texture_from_model_linear.y_axis.extend(0.0),
            texture_from_model_linear.z_axis.extend(0.0),
            Vec4::new(0.5, 0.5, 0.5, 1.0),
        );
        // tc = M p + ½, so ∂f/∂p = Mᵀ ∂f/∂tc.
        let gradient_from_texture = Mat4::from_mat3(texture_from_model_linear.transpose());
        let aspect = request.width as f32 / request.height as f32;
        let rows = request.drawn_rows();
        let inv_view_proj: Mat4 = request.camera.view_proj(radius, aspect).inverse();
        let basis = request.camera.basis(radius);
        let light = LIGHT_IN_VIEW.x * basis.right + LIGHT_IN_VIEW.y * basis.up
            - LIGHT_IN_VIEW.z * basis.forward;
        let min_spacing = texture.geometry.min_spacing_f32();
        let step = request.step_voxels * min_spacing;
        let max_steps = max_samples_per_ray(radius, step);
        let mut flags = FLAG_JITTER;
        if request.shading == Shading::Gradient {
            flags |= FLAG_SHADED;
        }
        if request.skip_empty {
            flags |= FLAG_SKIP_EMPTY;
        }
        let (mut lit, mut light_offset) = ([1.0, 1.0, 1.0, 0.0], 0.0);
        // A lit mode says how the ray caster reads its light.
        if let Some(mode) = Mode::of(request.shading) {
            let light = mode.raycast_light(request, texture);
            flags |= light.flags;
            (lit, light_offset) = (light.light, light.light_offset);
        }
        // Every shaded frame (gradient shading, and extinction light's
        // gradient factor) takes the normals the request asks for.
        if flags & FLAG_SHADED != 0 && request.cubic_gradient {
            flags |= FLAG_CUBIC_GRADIENT;
        }
        if request.compositing == Compositing::Extinction {
            flags |= FLAG_EXTINCTION;
        }
        let mode = match request.shading {
            Shading::Unshaded | Shading::Gradient | Shading::GlobalLight | Shading::Extinction => {
                MODE_COMPOSITE
            }
            Shading::Mip => MODE_MIP,
            Shading::MinIp => MODE_MINIP,
        };
        let [r, g, b] = request.background;
        // The window in transfer-function coordinates (0..1 over tf_domain).
        let [d0, d1] = texture.tf_domain;
        let window = request.window_of(tf, texture.tf_domain);
        let span = (d1 - d0).max(f32::MIN_POSITIVE);
        RaycastParams {
            inv_view_proj,
            texture_from_model,
            gradient_from_texture,
            volume: PackedVolume::new(texture, packed, tf_len),
            light_dir: light.normalize().into(),
            step,
            clip_min: request.clip.min,
            early_termination: EARLY_TERMINATION,
            clip_max: request.clip.max,
            gradient_threshold: GRADIENT_THRESHOLD_PER_VOXEL / min_spacing,
            background: [r, g, b, 1.0],
            light: lit,
            phong: PHONG,
            width: request.width,
            height: rows.count,
            flags,
            mode,
            max_steps,
            light_offset,
            first_row: rows.first,
            image_height: request.height,
            window: [(window.low() - d0) / span, window.width / span],
            faint_weight: FAINT_WEIGHT,
            _pad0: 0.0,
        }
    }

    /// Workgroups to dispatch along x and y.
    pub fn workgroups(&self) -> (u32, u32) {
        (
            self.width.div_ceil(WORKGROUP_SIZE),
            self.height.div_ceil(WORKGROUP_SIZE),
        )
    }
}

/// Which ray-marching stage a pipeline runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// Packed blocks through the block index.
    Raycast,
    /// Packed blocks lit by a light volume (needs float32-filterable textures).
    RaycastLit,
    /// Packed blocks lit by the light cache of extinction-based illumination.
    RaycastExtinction,
    /// One plain texture.
    Reference,
}

impl Stage {
    fn name(self) -> &'static str {
        match self {
            Stage::Raycast => "raycast",
            Stage::RaycastLit => "raycast (lit)",
            Stage::RaycastExtinction => "raycast (light cache)",
            Stage::Reference => "reference",
        }
    }

    fn source(self) -> &'static str {
        match self {
            Stage::Raycast => crate::wgsl::RAYCAST,
            Stage::RaycastLit => crate::wgsl::RAYCAST_LIT,
            Stage::RaycastExtinction => crate::wgsl::RAYCAST_EXTINCTION,
            Stage::Reference => crate::wgsl::REFERENCE,
        }
    }
}

/// A compiled ray-marching stage and its bind group layout.
#[derive(Debug)]
pub struct MarchPipeline {
    stage: Stage,
    compute: ComputeStage,
    sampler: wgpu::Sampler,
}

/// The resources a ray-marching stage binds, in binding order.
#[derive(Debug, Clone, Copy)]
pub struct MarchBindings<'a> {
    /// 0: uniform [`RaycastParams`].
    pub params: &'a wgpu::Buffer,
    /// 1: the atlas (raycast) or the volume (reference).
    pub voxels: &'a wgpu::TextureView,
    /// 3: the transfer-function table, `array<vec4<f32>>`.
    pub transfer_function: &'a wgpu::Buffer,
    /// 4: the rgba8unorm output texture.
    pub output: &'a wgpu::TextureView,
    /// 5: the block index (raycast only).
    pub block_index: Option<&'a wgpu::TextureView>,
    /// 6: the light volume (lit raycast only).
    pub light_volume: Option<&'a wgpu::TextureView>,
}

impl MarchPipeline {
    /// Compiles `stage` (every voxel format voxserve uses filters linearly).
    pub fn new(gpu: &GpuContext, stage: Stage) -> Result<MarchPipeline, GpuError> {
        use crate::pipeline::{
            float_texture_3d, sampler, storage_buffer, storage_texture, uint_texture_3d, uniform,
        };
        let mut entries = vec![
            uniform(0, size_of::<RaycastParams>()),
            float_texture_3d(1),
            sampler(2),
            storage_buffer(3),
            storage_texture(
                4,
                wgpu::TextureFormat::Rgba8Unorm,
                wgpu::StorageTextureAccess::WriteOnly,
                wgpu::TextureViewDimension::D2,
            ),
        ];
        if stage != Stage::Reference {
            entries.push(uint_texture_3d(5));
        }
        if matches!(stage, Stage::RaycastLit | Stage::RaycastExtinction) {
            entries.push(float_texture_3d(6));
        }
        Ok(MarchPipeline {
            stage,
            compute: ComputeStage::new(gpu, stage.name(), stage.source(), &entries)?,
            sampler: crate::pipeline::linear_sampler(gpu),
        })
    }

    /// A bind group over `bindings`.
    pub fn bind_group(
        &self,
        gpu: &GpuContext,
        bindings: MarchBindings<'_>,
    ) -> Result<wgpu::BindGroup, GpuError> {
        let mut resources = vec![
            bindings.params.as_entire_binding(),
            wgpu::BindingResource::TextureView(bindings.voxels),
            wgpu::BindingResource::Sampler(&self.sampler),
            bindings.transfer_function.as_entire_binding(),
            wgpu::BindingResource::TextureView(bindings.output),
        ];
        if self.stage != Stage::Reference {
            let index = bindings.block_index.ok_or_else(|| {
                GpuError::InvalidRequest("the raycast stage needs a block index".into())
            })?;
            resources.push(wgpu::BindingResource::TextureView(index));
        }
        if matches!(self.stage, Stage::RaycastLit | Stage::RaycastExtinction) {
            let light = bindings.light_volume.ok_or_else(|| {
                GpuError::InvalidRequest("the lit raycast stage needs a light volume".into())
            })?;
            resources.push(wgpu::BindingResource::TextureView(light));
        }
        Ok(self.compute.bind_group(gpu, &resources))
    }

    /// Which stage this pipeline runs.
    pub fn stage(&self) -> Stage {
        self.stage
    }

    /// Records the dispatch for an image of `params.width` × `params.height`.
    pub fn dispatch(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        bind_group: &wgpu::BindGroup,
        params: &RaycastParams,
    ) {
        let (x, y) = params.workgroups();
        self.compute.dispatch(encoder, bind_group, [x, y, 1]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_are_a_multiple_of_16_bytes_like_the_wgsl_struct() {
        // WGSL: three mat4x4 (64 each), six vec3 + scalar pairs, four vec4s and
        // one vec3<u32> + scalar (16 each), eight scalars.
        assert_eq!(size_of::<RaycastParams>(), 3 * 64 + 11 * 16 + 8 * 4);
        assert_eq!(size_of::<RaycastParams>() % 16, 0);
    }

    /// An 8-bit volume of `geometry`, its values mapped to 0..1 as stored.
    fn u8_texture(geometry: Geometry) -> VolumeTexture {
        VolumeTexture {
            geometry,
            format: crate::volume_texture::TexelFormat::R8Unorm,
            voxel_type: blocks::VoxelType::U8,
            value_map: blocks::ValueMap::IDENTITY,
            tf_domain: [0.0, 1.0],
            value_scale: 1.0,
            value_offset: 0.0,
        }
    }

    #[test]
    fn every_shaded_frame_takes_the_normals_it_asks_for() {
        let texture = u8_texture(Geometry::new([8, 8, 8], [1.0; 3]));
        let tf = blocks::Preset::Generic.transfer_function([0.0, 1.0]);
        for shading in [
            Shading::Unshaded,
            Shading::Gradient,
            Shading::GlobalLight,
            Shading::Extinction,
            Shading::Mip,
        ] {
            for cubic_gradient in [false, true] {
                let request = FrameRequest {
                    shading,
                    cubic_gradient,
                    ..FrameRequest::new(8, 8, tf.clone())
                };
                let flags =
                    RaycastParams::new(&texture, &request, &tf, 16, PackedLayout::default()).flags;
                // Gradient shading and extinction light's gradient factor shade.
                let shaded = matches!(shading, Shading::Gradient | Shading::Extinction);
                assert_eq!(flags & FLAG_SHADED != 0, shaded, "{shading:?}");
                assert_eq!(
                    flags & FLAG_CUBIC_GRADIENT != 0,
                    shaded && cubic_gradient,
                    "{shading:?}, cubic_gradient {cubic_gradient}"
                );
            }
        }
    }

    #[test]
    fn texture_from_model_undoes_the_placement() {
        let texture = u8_texture(Geometry {
            direction: [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]],
            ..Geometry::new([10, 20, 5], [1.0, 0.5, 2.0])
        });
        let tf = blocks::Preset::Generic.transfer_function([0.0, 1.0]);
        let p = RaycastParams::new(
            &texture,
            &FrameRequest::new(8, 8, tf.clone()),
            &tf,
            16,
            PackedLayout::default(),
        );
        let m = p.texture_from_model;
        // Texture x runs along model −y over 10 mm; texture y along model +x over 10 mm.
        let tc = |v: Vec3| m.transform_point3(v);
        assert!((tc(Vec3::ZERO) - Vec3::splat(0.5)).length() < 1e-6);
        assert!((tc(Vec3::new(0.0, -5.0, 0.0)) - Vec3::new(1.0, 0.5, 0.5)).length() < 1e-6);
        assert!((tc(Vec3::new(5.0, 0.0, 0.0)) - Vec3::new(0.5, 1.0, 0.5)).length() < 1e-6);
        assert!((tc(Vec3::new(0.0, 0.0, -5.0)) - Vec3::new(0.5, 0.5, 1.0)).length() < 1e-6);
        let radius = VolumePlacement::of(&texture).radius();
        assert!((radius - 75.0f32.sqrt()).abs() < 1e-4, "{radius}");
    }
}
