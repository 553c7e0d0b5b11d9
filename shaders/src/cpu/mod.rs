//! CPU twins of the WGSL stages: each has the stage's name, reads the same
//! bindings in the same order, and is written like the shader, so a test can
//! run a scene through both and compare. They are also the CPU renderer
//! ([`CpuRenderer`], `--renderer cpu`): the march differs from the shader only
//! where the CPU does better with the same pixels (walking the block grid,
//! reading slots directly, dropping transparent samples unread; see [`march`]).
//!
//! - [`raycast`](mod@raycast): twin of `shaders/wgsl/raycast.wgsl` (packed blocks).
//! - [`reference`](mod@reference): twin of `shaders/wgsl/reference.wgsl` (one
//!   plain texture).
//! - [`march`]: twin of `shaders/wgsl/shared/march.wgsl`, the ray march both share.
//! - [`packed`]: twin of `shaders/wgsl/shared/packed.wgsl`, block addressing.
//! - [`occupancy`]: CPU only, transparent texels inside blocks, whose
//!   samples the CPU march drops without reading them (pixels unchanged).
//! - [`footprint`]: CPU only, the pixels the boxes that can show cover.
//! - [`ray_lanes`]: CPU only, the first lines of WGSL `main` for eight
//!   pixels' rays side by side.
//! - [`global_light`]: twins of the global light stages (`local_opacity`,
//!   `global_opacity`, `direct_light`, `in_scatter`, `direct_light_reference`)
//!   and [`global_light::run`], which runs one stage of
//!   [`crate::global_light::Stage`] as the GPU does.
//! - [`extinction`]: twins of the extinction stages (`extinction_sat`,
//!   `ambient_occlusion`, `soft_shadow` and their references) and
//!   [`extinction::run`], likewise.
//! - [`texture`]: [`Texture3d`], a 3D texture sampled like the GPU samples one.
//! - [`slot_atlas`]: [`SlotAtlas`], the packed atlas with each slot's texels
//!   contiguous in memory, addressed like the GPU's atlas texture.
//! - [`hash`]: twin of `shaders/wgsl/shared/hash.wgsl`.
//!
//! [`render_packed`] and [`render_reference`] render whole frames the way
//! [`crate::Renderer`] and [`crate::ReferenceRenderer`] do on the GPU.

pub mod extinction;
pub mod footprint;
pub mod global_light;
pub mod hash;
pub mod march;
pub mod occupancy;
pub mod packed;
pub mod ray_lanes;
pub mod raycast;
pub mod reference;
pub mod renderer;
pub mod slot_atlas;
pub mod texture;

pub use packed::PackedTexture;
pub use raycast::raycast;
pub use reference::reference;
pub use renderer::{CPU_FEATURES, CpuRenderer};
pub use slot_atlas::SlotAtlas;
pub use texture::{ColourTexture, Texture3d};

use std::sync::Arc;

use blocks::Volume;
use blocks::cache::BlockCache;
use blocks::lod::LodSelection;
use blocks::transfer_function::TABLE_LEN;

use crate::packed_volume::PackedLayout;
use crate::raycast::RaycastParams;
use crate::volume_texture::VolumeTexture;
use crate::{Frame, FrameRequest, GpuError};

/// `table` as the march reads it ([`march::TfTable`]): an error unless it
/// has `TABLE_LEN` entries, as every table the renderers build has.
pub fn full_table(table: &[[f32; 4]]) -> Result<&march::TfTable, GpuError> {
    table.try_into().map_err(|_| {
        GpuError::InvalidRequest(format!(
            "transfer-function table of {} entries: expected {TABLE_LEN}",
            table.len()
        ))
    })
}

/// Renders `request` of the store behind `cache` on the CPU, converged,
/// through a [`CpuRenderer`] that stores texels as a GPU with `features`
/// does and packs into atlas edges of at most `max_edge` (no memory budget:
/// the request's data reduction alone selects levels). Returns the frame and
/// the selection.
pub fn render_packed(
    cache: &Arc<BlockCache>,
    request: &FrameRequest,
    features: wgpu::Features,
    max_edge: u32,
) -> Result<(Frame, LodSelection), GpuError> {
    let mut renderer = CpuRenderer::matching(Arc::clone(cache), u64::MAX, features, max_edge);
    let frame = renderer.render_converged(request)?;
    let selection = renderer
        .selection()
        .cloned()
        .ok_or_else(|| GpuError::InvalidRequest("no blocks were selected".into()))?;
    Ok((frame, selection))
}

/// Renders `request` of `volume` on the CPU through the twin of `reference`:
/// the whole volume at full resolution, texels in the format the GPU would use
/// given `features` (`reduction` and `skip_empty` do not apply).
pub fn render_reference(
    volume: &Volume,
    request: &FrameRequest,
    features: wgpu::Features,
) -> Result<Frame, GpuError> {
    request.validate()?;
    crate::renderer::refuse_fit(request)?;
    let desc = VolumeTexture::for_volume(volume, features);
    let texture = Texture3d::new(desc.geometry.dims, desc.texel_values(&volume.voxels));
    let tf = request.volume_transfer_function(volume);
    let table = tf.table(desc.tf_domain, TABLE_LEN)?;
    let params = RaycastParams::new(
        &desc,
        request,
        &tf,
        table.len() as u32,
        PackedLayout::default(),
    );
    let mut rgba = vec![0u8; params.width as usize * params.height as usize * 4];
    reference(&params, &texture, full_table(&table)?, &mut rgba);
    Ok(Frame {
        width: params.width,
        height: params.height,
        rgba,
    })
}
