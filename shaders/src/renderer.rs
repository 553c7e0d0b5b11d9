//! The renderers: [`Renderer`] draws from packed blocks (the volume as the
//! level-of-detail selection keeps it on the GPU), [`ReferenceRenderer`] from
//! one plain full-resolution texture (tests and benchmarks only).
//!
//! [`Renderer`] keeps the blocks resident between frames. A frame whose transfer
//! function or data reduction differs from the last re-selects levels (a few
//! milliseconds from the block statistics) and uploads only the blocks that
//! changed; a camera change uploads nothing. The transfer-function table is
//! written only when it changes; the output texture and readback buffer stay
//! while the image size does.

use std::sync::Arc;
use std::time::Instant;

use blocks::cache::BlockCache;
use blocks::lod::LodSelection;
use blocks::packing::Packing;
use blocks::store::LEVELS;
use blocks::transfer_function::TABLE_LEN;
use blocks::{Preset, TransferFunction, Volume};

use crate::extinction::{Extinction, ExtinctionTimings};
use crate::global_light::{GlobalLight, LightTimings};
use crate::illumination::{Illumination, Inputs, Mode, Refine, Timings};
use crate::packed::{Atlas, GpuAtlas};
use crate::packed_volume::PackedLayout;
use crate::raycast::{MarchBindings, MarchPipeline, Stage};
use crate::residency::{Refresh, Residency, ResidencyStats, viewpoint};
use crate::volume_texture::{GpuVolume, VolumeDescription, VolumeTexture};
use crate::{Frame, FrameRequest, GpuContext, GpuError, RaycastParams};

/// What a frame may change: how far it brings the shown blocks towards its
/// target and how far it refines the light. One per way of drawing, for
/// both renderers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Draw {
    /// Waits for every block; one refinement step (`render`).
    Complete,
    /// Shows the blocks that arrived; one refinement step (`render_now`).
    Now,
    /// Waits for every block; every refinement left (`render_converged`).
    Converged,
    /// Shows the blocks shown now; no refinement step (`render_probe`).
    Probe,
}

impl Draw {
    /// How far a frame's band brings the shown blocks towards its target:
    /// every band after a frame's first shows the blocks the first did.
    pub(crate) fn refresh(self, request: &FrameRequest) -> Refresh {
        match self {
            Draw::Complete | Draw::Converged => Refresh::Complete,
            Draw::Probe => Refresh::Target,
            Draw::Now => Refresh::for_band(request.drawn_rows(), false),
        }
    }

    /// How far a frame's band refines the light: every step left for a
    /// converged frame; not at all for a later band of a frame (it shows
    /// the light its first band did), a probe, or when the renderer says
    /// it may not `step` (a moving view); else one step.
    pub(crate) fn refine(self, request: &FrameRequest, step: bool) -> Refine {
        match self {
            Draw::Converged => Refine::Converge,
            Draw::Probe => Refine::Hold,
            Draw::Complete | Draw::Now if request.drawn_rows().first > 0 || !step => Refine::Hold,
            Draw::Complete | Draw::Now => Refine::Step,
        }
    }
}

/// Rows of a texture-to-buffer copy are padded to this many bytes.
const ROW_ALIGN: u32 = wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;

/// The output texture of one image size and the buffer it is read back through.
#[derive(Debug)]
struct Target {
    width: u32,
    height: u32,
    texture: wgpu::Texture,
    view: wgpu::TextureView,
    readback: wgpu::Buffer,
    padded_row: u32,
}

/// What every renderer needs beside its voxels: uniforms, the transfer-function
/// table and the output.
#[derive(Debug)]
struct FrameResources {
    params: wgpu::Buffer,
    transfer_function: wgpu::Buffer,
    uploaded_tf: Option<TransferFunction>,
    target: Option<Target>,
    /// The last frame's bind group and what it binds: frames that bind the same
    /// views (a camera move) reuse it instead of allocating a descriptor set each.
    bind_group: Option<(BindKey, wgpu::BindGroup)>,
}

/// What a frame's bind group binds beside the renderer's own buffers.
#[derive(Debug, Clone, PartialEq, Eq)]
struct BindKey {
    stage: Stage,
    voxels: wgpu::TextureView,
    block_index: Option<wgpu::TextureView>,
    light_volume: Option<wgpu::TextureView>,
    output: wgpu::TextureView,
}

impl FrameResources {
    fn new(gpu: &GpuContext) -> Result<FrameResources, GpuError> {
        gpu.scoped("creating frame buffers", || FrameResources {
            params: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("raycast params"),
                size: size_of::<RaycastParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            transfer_function: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("transfer function"),
                size: (TABLE_LEN * size_of::<[f32; 4]>()) as u64,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            uploaded_tf: None,
            target: None,
            bind_group: None,
        })
    }

    /// Checks the request against the device, writes the table if it changed.
    fn prepare(
        &mut self,
        gpu: &GpuContext,
        request: &FrameRequest,
        tf: &TransferFunction,
        desc: &VolumeTexture,
    ) -> Result<(), GpuError> {
        request.validate()?;
        let max = gpu.device.limits().max_texture_dimension_2d;
        if request.width > max || request.height > max {
            return Err(GpuError::Unsupported {
                what: format!("a {}x{} image", request.width, request.height),
                limit: format!(
                    "adapter '{}' allows at most {max} pixels per side",
                    gpu.info.name
                ),
            });
        }
        if self.uploaded_tf.as_ref() != Some(tf) {
            let table = tf.table(desc.tf_domain, TABLE_LEN)?;
            gpu.queue
                .write_buffer(&self.transfer_function, 0, bytemuck::cast_slice(&table));
            self.uploaded_tf = Some(tf.clone());
        }
        Ok(())
    }

    /// Runs `pipeline` with `params` over `voxels` (and `block_index`, and
    /// `light_volume` when lit) and reads the frame back.
    fn draw(
        &mut self,
        gpu: &GpuContext,
        pipeline: &MarchPipeline,
        params: &RaycastParams,
        voxels: &wgpu::TextureView,
        block_index: Option<&wgpu::TextureView>,
        light_volume: Option<&wgpu::TextureView>,
    ) -> Result<Frame, GpuError> {
        gpu.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(params));
        let target = ensure_target(gpu, &mut self.target, params.width, params.height)?;
        let key = BindKey {
            stage: pipeline.stage(),
            voxels: voxels.clone(),
            block_index: block_index.cloned(),
            light_volume: light_volume.cloned(),
            output: target.view.clone(),
        };
        let bind_group = match self.bind_group.take() {
            Some((cached, group)) if cached == key => group,
            // Any old group (and the views it holds) is dropped before a new one.
            _ => pipeline.bind_group(
                gpu,
                MarchBindings {
                    params: &self.params,
                    voxels,
                    transfer_function: &self.transfer_function,
                    output: &target.view,
                    block_index,
                    light_volume,
                },
            )?,
        };
        let bind_group = &self.bind_group.insert((key, bind_group)).1;
        gpu.scoped("rendering a frame", || {
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("frame"),
                });
            pipeline.dispatch(&mut encoder, bind_group, params);
            encoder.copy_texture_to_buffer(
                target.texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: &target.readback,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(target.padded_row),
                        rows_per_image: Some(target.height),
                    },
                },
                wgpu::Extent3d {
                    width: target.width,
                    height: target.height,
                    depth_or_array_layers: 1,
                },
            );
            gpu.queue.submit([encoder.finish()]);
        })?;
        let row = target.width as usize * 4;
        let rgba = gpu.read_buffer(&target.readback, "the rendered frame", |bytes| {
            let mut rgba = Vec::with_capacity(row * target.height as usize);
            for padded in bytes.chunks(target.padded_row as usize) {
                rgba.extend_from_slice(&padded[..row]);
            }
            rgba
        })?;
        Ok(Frame {
            width: target.width,
            height: target.height,
            rgba,
        })
    }
}

/// What the last frame of a [`Renderer`] took and showed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RenderStats {
    /// The data reduction among the blocks the transfer function shows:
    /// their voxels at full resolution per voxel kept (the detail chosen).
    pub reduction: f64,
    /// The share of blocks the transfer function leaves empty (0 to 1): skipped
    /// at every detail, so not counted in `reduction`.
    pub empty_share: f64,
    /// The device could not hold the detail asked for: `reduction` is
    /// coarser than the request's because memory ran out.
    pub memory_limited: bool,
    /// Blocks per level on the GPU (levels 0 to 4).
    pub level_counts: [usize; LEVELS],
    /// Blocks uploaded for this frame (0 when only the camera moved).
    pub uploaded_blocks: usize,
    /// Whether the atlas was laid out anew.
    pub relayout: bool,
    /// Milliseconds spent selecting levels (0 when nothing was re-selected).
    pub select_ms: f64,
    /// Milliseconds spent uploading blocks and index.
    pub upload_ms: f64,
    /// Milliseconds from dispatch to pixels read back.
    pub draw_ms: f64,
    /// Blocks shown coarser than selected because their data is still being
    /// read in the background: later frames refine them.
    pub pending_blocks: usize,
    /// The illumination mode's stages of this frame (lit shading only).
    pub illumination: Option<Timings>,
    /// The camera the frame was drawn with when the request asked for a fit
    /// ([`crate::Camera::fit`]).
    pub camera: Option<crate::Camera>,
}

impl From<ResidencyStats> for RenderStats {
    /// A frame's stats as far as the resident blocks go.
    fn from(r: ResidencyStats) -> RenderStats {
        RenderStats {
            uploaded_blocks: r.uploaded_blocks,
            relayout: r.relayout,
            select_ms: r.select_ms,
            upload_ms: r.upload_ms,
            pending_blocks: r.pending_blocks,
            ..RenderStats::default()
        }
    }
}

impl RenderStats {
    /// Global light propagation's stages of this frame.
    pub fn light(&self) -> Option<&LightTimings> {
        match &self.illumination {
            Some(Timings::GlobalLight(t)) => Some(t),
            _ => None,
        }
    }

    /// Extinction-based illumination's stages of this frame.
    pub fn extinction(&self) -> Option<&ExtinctionTimings> {
        match &self.illumination {
            Some(Timings::Extinction(t)) => Some(t),
            _ => None,
        }
    }

    /// Whether the frame is final for its view: every block at its selected
    /// level and nothing more to refine the light.
    pub fn converged(&self) -> bool {
        self.pending_blocks == 0 && self.illumination.as_ref().is_none_or(Timings::converged)
    }
}

/// An illumination mode in use: its GPU state and the ray-caster variant
/// that reads its light.
#[derive(Debug)]
struct LitMode {
    mode: Mode,
    state: Box<dyn Illumination>,
    pipeline: MarchPipeline,
}

/// Renders a brick store from the blocks its level-of-detail selection keeps on
/// the GPU; see the module docs.
pub struct Renderer {
    gpu: GpuContext,
    pipeline: MarchPipeline,
    cache: Arc<BlockCache>,
    desc: VolumeTexture,
    residency: Residency<GpuAtlas>,
    /// The illumination modes used so far: each one's GPU state and the
    /// ray-caster variant that reads its light.
    lit: Vec<LitMode>,
    frame: FrameResources,
    last: RenderStats,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("adapter", &self.gpu.info.name)
            .field("store", &self.cache.store().location())
            .field("last", &self.last)
            .finish_non_exhaustive()
    }
}

impl Renderer {
    /// A renderer of the store behind `cache` on `gpu`, keeping at most
    /// `budget_bytes` of voxels on the device.
    pub fn new(
        gpu: GpuContext,
        cache: Arc<BlockCache>,
        budget_bytes: u64,
    ) -> Result<Renderer, GpuError> {
        let store = cache.store();
        let desc = VolumeTexture::new(
            VolumeDescription::of_store(store.meta(), store.voxel_type()),
            gpu.device.features(),
        );
        let pipeline = MarchPipeline::new(&gpu, Stage::Raycast)?;
        let frame = FrameResources::new(&gpu)?;
        Ok(Renderer {
            gpu,
            pipeline,
            residency: Residency::new(Arc::clone(&cache), budget_bytes),
            cache,
            desc,
            lit: Vec::new(),
            frame,
            last: RenderStats::default(),
        })
    }

    /// The GPU this renderer runs on.
    pub fn gpu(&self) -> &GpuContext {
        &self.gpu
    }

    /// How voxels become texels.
    pub fn volume_texture(&self) -> &VolumeTexture {
        &self.desc
    }

    /// What the last frame took and showed.
    pub fn last_stats(&self) -> &RenderStats {
        &self.last
    }

    /// The level-of-detail selection in use, once a frame was rendered.
    pub fn selection(&self) -> Option<&LodSelection> {
        self.residency.selection()
    }

    /// The packing in use, once a frame was rendered.
    pub fn packing(&self) -> Option<&Packing> {
        self.residency.atlas().map(Atlas::packing)
    }

    /// The GPU state of illumination mode `mode`, once it was used.
    pub fn illumination(&self, mode: Mode) -> Option<&dyn Illumination> {
        self.lit.iter().find(|l| l.mode == mode).map(|l| &*l.state)
    }

    /// The light of global light propagation, once computed.
    pub fn global_light(&self) -> Option<&GlobalLight> {
        self.illumination(Mode::GlobalLight)
            .and_then(|s| s.as_any().downcast_ref())
    }

    /// The extinction-based illumination, once computed.
    pub fn extinction(&self) -> Option<&Extinction> {
        self.illumination(Mode::Extinction)
            .and_then(|s| s.as_any().downcast_ref())
    }

    /// The resident atlas, once a frame was rendered.
    pub fn atlas(&self) -> Option<&GpuAtlas> {
        self.residency.atlas()
    }

    /// Renders one frame at the detail the request selects and reads it
    /// back, waiting on this thread for blocks still being read (the
    /// command line, tests and benchmarks; a server renders with
    /// [`Renderer::render_now`]). A lit mode is brought up to date first:
    /// global light recomputed from the first stale stage, else refined by
    /// one more direction.
    pub fn render(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        self.render_lit(request, Draw::Complete)
    }

    /// Renders one frame from the blocks in memory now, never waiting for
    /// storage: blocks still being read are shown coarser
    /// ([`RenderStats::pending_blocks`]) and later frames refine them.
    pub fn render_now(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        self.render_lit(request, Draw::Now)
    }

    /// Renders a health probe's frame: from the blocks shown now (blocks
    /// that arrived wait for the next view's frame) and the light as it
    /// is (no refinement step), so a probe drawing the last view's request
    /// changes nothing the views see.
    pub fn render_probe(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        self.render_lit(request, Draw::Probe)
    }

    /// Renders one frame with the light converged (every in-scattering
    /// direction in) at the detail the request selects (for still images
    /// and tests).
    pub fn render_converged(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        self.render_lit(request, Draw::Converged)
    }

    /// Prepares the blocks and brings the request's light up to date as
    /// `draw` says, and draws.
    fn render_lit(&mut self, request: &FrameRequest, draw: Draw) -> Result<Frame, GpuError> {
        let tf = request.store_transfer_function(self.cache.store().meta());
        self.frame.prepare(&self.gpu, request, &tf, &self.desc)?;
        let mut stats = RenderStats::from(self.residency.update_complete(
            &self.gpu,
            &self.desc,
            &tf,
            request.reduction,
            viewpoint(request, &self.desc),
            draw.refresh(request),
        )?);
        let fitted = self.residency.fitted(request, &self.desc);
        let request = fitted.as_ref().unwrap_or(request);
        stats.camera = fitted.as_ref().map(|r| r.camera);
        if let Some(mode) = Mode::of(request.shading) {
            let refine = draw.refine(request, true);
            stats.illumination = Some(self.update_illumination(mode, request, &tf, refine)?);
        }
        self.draw(request, &tf, stats)
    }

    /// Brings illumination mode `mode` up to date for `request` (every
    /// refinement when `converge`), making its state on first use.
    fn update_illumination(
        &mut self,
        mode: Mode,
        request: &FrameRequest,
        tf: &TransferFunction,
        refine: Refine,
    ) -> Result<Timings, GpuError> {
        if !self.lit.iter().any(|l| l.mode == mode) {
            self.lit.push(LitMode {
                mode,
                state: mode.create(&self.gpu)?,
                pipeline: MarchPipeline::new(&self.gpu, mode.raycast_stage())?,
            });
        }
        let (Some(atlas), Some(lit)) = (
            self.residency.atlas(),
            self.lit.iter_mut().find(|l| l.mode == mode),
        ) else {
            return Err(GpuError::InvalidRequest("no blocks are resident".into()));
        };
        let inputs = Inputs {
            atlas,
            transfer_function: &self.frame.transfer_function,
            texture: &self.desc,
            tf_len: TABLE_LEN as u32,
            tf,
            data_version: self.residency.data_version(),
        };
        lit.state.update(&self.gpu, inputs, request, refine)
    }

    /// Renders the frame of `request` from what is resident, classified by `tf`.
    fn draw(
        &mut self,
        request: &FrameRequest,
        tf: &TransferFunction,
        mut stats: RenderStats,
    ) -> Result<Frame, GpuError> {
        let (Some(atlas), Some(selection)) = (self.residency.atlas(), self.residency.selection())
        else {
            return Err(GpuError::InvalidRequest("no blocks are resident".into()));
        };
        let params = RaycastParams::new(&self.desc, request, tf, TABLE_LEN as u32, atlas.layout);
        // The lit mode's pipeline and light, once computed; else unlit.
        let lit = Mode::of(request.shading)
            .and_then(|mode| self.lit.iter().find(|l| l.mode == mode))
            .and_then(|l| Some((&l.pipeline, l.state.light_view()?)));
        let (pipeline, light) = match lit {
            Some((p, light)) => (p, Some(light)),
            None => (&self.pipeline, None),
        };
        let start = Instant::now();
        let frame = self.frame.draw(
            &self.gpu,
            pipeline,
            &params,
            &atlas.atlas_view,
            Some(&atlas.index_view),
            light,
        )?;
        stats.draw_ms = start.elapsed().as_secs_f64() * 1e3;
        stats.reduction = selection.reduction();
        stats.empty_share = selection.empty_share();
        stats.memory_limited = selection.capped;
        stats.level_counts = selection.level_counts();
        self.last = stats;
        Ok(frame)
    }
}

/// Refuses a request to fit the camera: full-resolution references draw the
/// camera as given (a fit needs the packed renderer's blocks).
pub(crate) fn refuse_fit(request: &FrameRequest) -> Result<(), GpuError> {
    if request.camera.fit {
        return Err(GpuError::InvalidRequest(
            "the full-resolution reference draws the camera as given: fit with the packed renderer and pass the camera it chose".into(),
        ));
    }
    Ok(())
}

/// Renders one plain full-resolution texture: the reference the packed renderer
/// is checked and priced against.
#[derive(Debug)]
pub struct ReferenceRenderer {
    gpu: GpuContext,
    pipeline: MarchPipeline,
    volume: GpuVolume,
    /// The volume's physical value range and its own preset.
    classification: ([f32; 2], Preset),
    frame: FrameResources,
}

impl ReferenceRenderer {
    /// Compiles the pipeline and uploads `volume`.
    pub fn new(gpu: GpuContext, volume: &Volume) -> Result<ReferenceRenderer, GpuError> {
        let pipeline = MarchPipeline::new(&gpu, Stage::Reference)?;
        let own = Preset::for_data(volume.modality.as_deref(), volume.unit.as_deref());
        let classification = (volume.value_range, own);
        let volume = GpuVolume::upload(&gpu, volume)?;
        let frame = FrameResources::new(&gpu)?;
        Ok(ReferenceRenderer {
            gpu,
            pipeline,
            volume,
            classification,
            frame,
        })
    }

    /// How the volume is stored on the GPU.
    pub fn volume_texture(&self) -> &VolumeTexture {
        &self.volume.desc
    }

    /// Renders one frame and reads it back (`reduction` and `skip_empty` do
    /// not apply). The camera is drawn as given: a fit is refused (fit with a
    /// packed renderer and pass the camera it chose, as benchmarks do).
    pub fn render(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        refuse_fit(request)?;
        let (range, own) = self.classification;
        let tf = request.transfer_function(range, own);
        self.frame
            .prepare(&self.gpu, request, &tf, &self.volume.desc)?;
        let params = RaycastParams::new(
            &self.volume.desc,
            request,
            &tf,
            TABLE_LEN as u32,
            PackedLayout::default(),
        );
        self.frame.draw(
            &self.gpu,
            &self.pipeline,
            &params,
            &self.volume.view,
            None,
            None,
        )
    }
}

/// The output texture and readback buffer for `width` × `height`: the one in `slot`
/// when it fits, else a new one put there.
fn ensure_target<'a>(
    gpu: &GpuContext,
    slot: &'a mut Option<Target>,
    width: u32,
    height: u32,
) -> Result<&'a Target, GpuError> {
    let target = match slot.take() {
        Some(t) if t.width == width && t.height == height => t,
        // Any old target is dropped here, before the new one is allocated.
        _ => new_target(gpu, width, height)?,
    };
    Ok(slot.insert(target))
}

/// Allocates an output texture of `width` × `height` and its readback buffer.
fn new_target(gpu: &GpuContext, width: u32, height: u32) -> Result<Target, GpuError> {
    let padded_row = (width * 4).div_ceil(ROW_ALIGN) * ROW_ALIGN;
    gpu.scoped("allocating the frame target", || {
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("frame"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let readback = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame readback"),
            size: u64::from(padded_row) * u64::from(height),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Target {
            width,
            height,
            texture,
            view,
            readback,
            padded_row,
        }
    })
}
