//! CPU twins of the WGSL stages: each has the stage's name, reads the same
//! bindings in the same order, and is written loop for loop like the shader, so a
//! test can run a scene through both and compare. They are also the renderer of
//! last resort (`voxserve render --cpu`).
//!
//! - [`raycast`](mod@raycast): twin of `shaders/wgsl/raycast.wgsl`.
//! - [`texture`]: [`Texture3d`], a 3D texture sampled like the GPU samples one.
//! - [`hash`]: twin of `shaders/wgsl/shared/hash.wgsl`.

pub mod hash;
pub mod raycast;
pub mod texture;

pub use raycast::raycast;
pub use texture::Texture3d;

use blocks::Volume;

use crate::raycast::RaycastParams;
use crate::volume_texture::VolumeTexture;
use crate::{Frame, FrameRequest, GpuError};

/// Renders `request` of `volume` on the CPU through the twin of `raycast`, with
/// the texel format the GPU would use given `features` (the format decides the
/// value precision the shader sees).
pub fn render(
    volume: &Volume,
    request: &FrameRequest,
    features: wgpu::Features,
) -> Result<Frame, GpuError> {
    request.validate().map_err(GpuError::InvalidRequest)?;
    let desc = VolumeTexture::for_volume(volume, features);
    let texture = Texture3d::new(desc.dims, desc.texel_values(volume));
    let table = request
        .transfer_function
        .table(desc.tf_domain, blocks::transfer_function::TABLE_LEN)?;
    let params = RaycastParams::new(&desc, request, table.len() as u32);
    let mut rgba = vec![0u8; request.width as usize * request.height as usize * 4];
    raycast(&params, &texture, &table, &mut rgba);
    Ok(Frame {
        width: request.width,
        height: request.height,
        rgba,
    })
}
