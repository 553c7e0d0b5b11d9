//! [`CpuRenderer`]: a brick store rendered on the CPU, frame by frame, the way
//! [`crate::Renderer`] renders it on the GPU: the same level-of-detail
//! selection and residency (blocks packed into an atlas in memory, only
//! changed blocks rewritten, storage never read on the render thread), the
//! same stages through their CPU twins.
//!
//! Illumination follows what it depends on (the blocks shown, the transfer
//! function, the mode's settings) and is kept while they do not change: a
//! camera move only ray-casts. Global light is brought up to date as on the
//! GPU ([`CpuGlobalLight`]: a change recomputes with one in-scattering
//! direction, later frames blend one more each), but only frames of an
//! unchanged view refine it, so a drag draws from the light there is and a
//! still view converges; extinction-based illumination likewise recomputes
//! from the first stage a change affects ([`CpuExtinction`]: a light moved
//! recomputes the shadows alone).

use std::sync::Arc;
use std::time::Instant;

use glam::Vec3;

use blocks::TransferFunction;
use blocks::cache::BlockCache;
use blocks::lod::LodSelection;
use blocks::packing::Packing;
use blocks::transfer_function::TABLE_LEN;

use super::extinction::{CpuExtinction, CpuExtinctionInputs};
use super::global_light::{CpuGlobalLight, CpuLightInputs};
use super::march::{Isa, TfTable};
use super::occupancy::{visible_boxes, visible_cells, visible_extent, visible_texels};
use super::raycast::raycast_on;
use crate::extinction::ExtinctionParams;
use crate::illumination::{Mode, Refine, Timings};
use crate::packed::{Atlas, CPU_MAX_EDGE, CpuAtlas, CpuDevice};
use crate::packed_volume::PackedVolume;
use crate::raycast::RaycastParams;
use crate::renderer::{Draw, RenderStats};
use crate::residency::{Residency, viewpoint};
use crate::volume_texture::{VolumeDescription, VolumeTexture};
use crate::{Camera, Frame, FrameRequest, GpuError};

/// The texel formats the CPU renderer stores voxels as: those of a GPU with
/// 16-bit normalized textures, so CPU and GPU frames quantize alike.
pub const CPU_FEATURES: wgpu::Features = wgpu::Features::TEXTURE_FORMAT_16BIT_NORM;

/// Renders a brick store on the CPU; see the module docs.
#[derive(Debug)]
pub struct CpuRenderer {
    cache: Arc<BlockCache>,
    desc: VolumeTexture,
    device: CpuDevice,
    residency: Residency<CpuAtlas>,
    /// The transfer function's table, for the function it was made from:
    /// `TABLE_LEN` entries, as the march reads it.
    table: Option<(TransferFunction, Box<TfTable>)>,
    /// Global light's stages and refinement.
    global_light: CpuGlobalLight,
    /// Extinction-based illumination's stages.
    extinction: CpuExtinction,
    /// The view of the last frame drawn: light refines only while it stays.
    last_view: Option<(Camera, u32, u32)>,
    /// What the atlas's visible texels were computed for: the shown blocks
    /// and the transfer function.
    texels_for: Option<(u64, TransferFunction)>,
    /// The instructions the ray caster runs.
    isa: Isa,
    last: RenderStats,
}

impl CpuRenderer {
    /// A renderer of the store behind `cache`, keeping at most `budget_bytes`
    /// of atlas in memory.
    pub fn new(cache: Arc<BlockCache>, budget_bytes: u64) -> CpuRenderer {
        CpuRenderer::matching(cache, budget_bytes, CPU_FEATURES, CPU_MAX_EDGE)
    }

    /// [`CpuRenderer::new`] storing texels as a GPU with `features` does and
    /// packing blocks into atlas edges of at most `max_edge` as it does, so
    /// its frames can be compared with that GPU's.
    pub fn matching(
        cache: Arc<BlockCache>,
        budget_bytes: u64,
        features: wgpu::Features,
        max_edge: u32,
    ) -> CpuRenderer {
        let store = cache.store();
        let desc = VolumeTexture::new(
            VolumeDescription::of_store(store.meta(), store.voxel_type()),
            features,
        );
        CpuRenderer {
            device: CpuDevice { max_edge },
            residency: Residency::new(Arc::clone(&cache), budget_bytes),
            cache,
            desc,
            table: None,
            global_light: CpuGlobalLight::default(),
            extinction: CpuExtinction::default(),
            last_view: None,
            texels_for: None,
            isa: Isa::best(),
            last: RenderStats::default(),
        }
    }

    /// Draws with the ray caster built for `isa` where this processor runs
    /// it (the best it runs by default; the frames are the same bytes).
    pub fn set_isa(&mut self, isa: Isa) {
        self.isa = isa;
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

    /// Renders one frame at the detail the request selects, waiting on this
    /// thread for blocks still being read (as [`crate::Renderer::render`]);
    /// global light refined by one direction when the view is the last
    /// frame's.
    pub fn render(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        self.render_lit(request, Draw::Complete)
    }

    /// Renders one frame from the blocks in memory now, never waiting for
    /// storage (as [`crate::Renderer::render_now`]).
    pub fn render_now(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        self.render_lit(request, Draw::Now)
    }

    /// Renders a health probe's frame, changing nothing the views see (as
    /// [`crate::Renderer::render_probe`]; nor is its view the one light
    /// refines for).
    pub fn render_probe(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        self.render_lit(request, Draw::Probe)
    }

    /// Renders one frame with the light converged (as
    /// [`crate::Renderer::render_converged`]).
    pub fn render_converged(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        self.render_lit(request, Draw::Converged)
    }

    /// Prepares the blocks and brings the request's light up to date as
    /// `draw` says, and draws.
    fn render_lit(&mut self, request: &FrameRequest, draw: Draw) -> Result<Frame, GpuError> {
        request.validate()?;
        let tf = request.store_transfer_function(self.cache.store().meta());
        let mut stats = RenderStats::from(self.residency.update_complete(
            &self.device,
            &self.desc,
            &tf,
            request.reduction,
            viewpoint(request, &self.desc),
            draw.refresh(request),
        )?);
        let fitted = self.residency.fitted(request, &self.desc);
        let request = fitted.as_ref().unwrap_or(request);
        stats.camera = fitted.as_ref().map(|r| r.camera);
        if self.table.as_ref().is_none_or(|(t, _)| *t != tf) {
            let table = tf.table(self.desc.tf_domain, TABLE_LEN)?;
            self.table = Some((tf.clone(), Box::new(*super::full_table(&table)?)));
        }
        self.update_visible_texels(&tf);
        // A moving view draws from the light there is.
        let view = (request.camera, request.width, request.height);
        let refine = draw.refine(request, self.last_view == Some(view));
        if request.drawn_rows().first == 0 && draw != Draw::Probe {
            self.last_view = Some(view);
        }
        match Mode::of(request.shading) {
            Some(Mode::GlobalLight) => {
                stats.illumination = self.update_global_light(request, &tf, refine)?;
            }
            Some(Mode::Extinction) => {
                stats.illumination = self.update_extinction(request, &tf)?;
            }
            None => {}
        }
        // Frames of the other mode may have left their light beside this one's.
        if let Some(atlas) = self.residency.atlas_mut() {
            atlas.texture.lit_by = Mode::of(request.shading);
        }
        self.draw(request, stats)
    }

    /// Finds the atlas's transparent texels for `tf` unless the shown blocks
    /// and the transfer function are those they were found for.
    fn update_visible_texels(&mut self, tf: &TransferFunction) {
        let key = (self.residency.data_version(), tf.clone());
        let (Some(atlas), Some((_, table))) = (self.residency.atlas_mut(), &self.table) else {
            return;
        };
        if self.texels_for.as_ref() == Some(&key) {
            return;
        }
        let g = PackedVolume::new(&self.desc, atlas.layout, table.len() as u32);
        let texture = &mut atlas.texture;
        let bits = visible_texels(&texture.atlas, &g, table.as_slice());
        let boxes = visible_boxes(&texture.atlas, &texture.index, &bits);
        let dims = Vec3::from(g.volume_dims);
        texture.visible_extent = Some(visible_extent(&boxes, texture.grid, dims));
        texture.visible_cells = Some(visible_cells(&boxes, &texture.index, texture.grid, dims));
        texture.visible_boxes = Some(boxes);
        texture.visible_texels = Some(bits);
        self.texels_for = Some(key);
    }

    /// Brings global light up to date for `request` as far as `refine` says
    /// and puts the stored light where the ray caster reads it; returns what
    /// its stages took.
    fn update_global_light(
        &mut self,
        request: &FrameRequest,
        tf: &TransferFunction,
        refine: Refine,
    ) -> Result<Option<Timings>, GpuError> {
        let data_version = self.residency.data_version();
        let (Some(atlas), Some((_, table))) = (self.residency.atlas_mut(), &self.table) else {
            return Ok(None);
        };
        let inputs = CpuLightInputs {
            desc: &self.desc,
            packing: &atlas.packing,
            layout: atlas.layout,
            packed: &atlas.texture,
            tf: table.as_slice(),
        };
        let timings = self
            .global_light
            .update(inputs, request, data_version, tf, refine)?;
        let texture = &mut atlas.texture;
        if timings.recomputed || timings.in_scatter_ms > 0.0 || texture.light.is_none() {
            texture.set_light(self.global_light.light_volume().to_vec());
        }
        Ok(Some(Timings::GlobalLight(timings)))
    }

    /// Brings the extinction light cache up to date (from the first stage
    /// whose inputs changed) and puts it where the ray caster reads it;
    /// returns what its stages took.
    fn update_extinction(
        &mut self,
        request: &FrameRequest,
        tf: &TransferFunction,
    ) -> Result<Option<Timings>, GpuError> {
        let data_version = self.residency.data_version();
        let (Some(atlas), Some((_, table))) = (self.residency.atlas_mut(), &self.table) else {
            return Ok(None);
        };
        let params = ExtinctionParams::new(
            &self.desc,
            &request.extinction,
            atlas.layout,
            table.len() as u32,
        );
        let inputs = CpuExtinctionInputs {
            packing: &atlas.packing,
            packed: &atlas.texture,
            tf: table.as_slice(),
        };
        let timings =
            self.extinction
                .update(inputs, &params, &request.extinction, data_version, tf)?;
        let texture = &mut atlas.texture;
        let recomputed =
            timings.sat_ms + timings.ambient_occlusion_ms + timings.soft_shadow_ms > 0.0;
        if (recomputed || texture.light_cache.is_none())
            && let Some(cache) = self.extinction.light_cache()
        {
            texture.set_light_cache(cache);
        }
        Ok(Some(Timings::Extinction(timings)))
    }

    /// Ray-casts the frame of `request` from what is resident.
    fn draw(&mut self, request: &FrameRequest, mut stats: RenderStats) -> Result<Frame, GpuError> {
        let (Some(atlas), Some(selection), Some((tf, table))) = (
            self.residency.atlas(),
            self.residency.selection(),
            &self.table,
        ) else {
            return Err(GpuError::InvalidRequest("no blocks are resident".into()));
        };
        let params = RaycastParams::new(&self.desc, request, tf, table.len() as u32, atlas.layout);
        let start = Instant::now();
        let mut rgba = vec![0u8; params.width as usize * params.height as usize * 4];
        raycast_on(self.isa, &params, &atlas.texture, table, &mut rgba);
        stats.draw_ms = start.elapsed().as_secs_f64() * 1e3;
        stats.reduction = selection.reduction();
        stats.empty_share = selection.empty_share();
        stats.memory_limited = selection.capped;
        stats.level_counts = selection.level_counts();
        self.last = stats;
        Ok(Frame {
            width: params.width,
            height: params.height,
            rgba,
        })
    }
}
