//! [`Renderer`]: one volume resident on the GPU, rendered frame by frame through
//! the `raycast` stage and read back as RGBA8.
//!
//! The transfer-function table is uploaded only when the transfer function
//! changes; the output texture and its readback buffer are kept while the image
//! size stays the same.

use blocks::transfer_function::TABLE_LEN;
use blocks::{TransferFunction, Volume};

use crate::raycast::RaycastBindings;
use crate::volume_texture::{GpuVolume, VolumeTexture};
use crate::{Frame, FrameRequest, GpuContext, GpuError, RaycastParams, RaycastPipeline};

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

/// A volume on the GPU and the pipeline that renders it.
#[derive(Debug)]
pub struct Renderer {
    gpu: GpuContext,
    pipeline: RaycastPipeline,
    volume: GpuVolume,
    params: wgpu::Buffer,
    transfer_function: wgpu::Buffer,
    uploaded_tf: Option<TransferFunction>,
    target: Option<Target>,
}

impl Renderer {
    /// Compiles the pipeline and uploads `volume`.
    pub fn new(gpu: GpuContext, volume: &Volume) -> Result<Renderer, GpuError> {
        let pipeline = RaycastPipeline::new(&gpu)?;
        let volume = GpuVolume::upload(&gpu, volume)?;
        let (params, transfer_function) = gpu.scoped("creating renderer buffers", || {
            let params = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("raycast params"),
                size: size_of::<RaycastParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let transfer_function = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("transfer function"),
                size: (TABLE_LEN * size_of::<[f32; 4]>()) as u64,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            (params, transfer_function)
        })?;
        Ok(Renderer {
            gpu,
            pipeline,
            volume,
            params,
            transfer_function,
            uploaded_tf: None,
            target: None,
        })
    }

    /// The GPU this renderer runs on.
    pub fn gpu(&self) -> &GpuContext {
        &self.gpu
    }

    /// How the volume is stored on the GPU.
    pub fn volume_texture(&self) -> &VolumeTexture {
        &self.volume.desc
    }

    /// Renders one frame and reads it back.
    pub fn render(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        request.validate().map_err(GpuError::InvalidRequest)?;
        let max = self.gpu.device.limits().max_texture_dimension_2d;
        if request.width > max || request.height > max {
            return Err(GpuError::Unsupported {
                what: format!("a {}x{} image", request.width, request.height),
                limit: format!(
                    "adapter '{}' allows at most {max} pixels per side",
                    self.gpu.info.name
                ),
            });
        }
        if self.uploaded_tf.as_ref() != Some(&request.transfer_function) {
            let table = request
                .transfer_function
                .table(self.volume.desc.tf_domain, TABLE_LEN)?;
            self.gpu
                .queue
                .write_buffer(&self.transfer_function, 0, bytemuck::cast_slice(&table));
            self.uploaded_tf = Some(request.transfer_function.clone());
        }
        let params = RaycastParams::new(&self.volume.desc, request, TABLE_LEN as u32);
        self.gpu
            .queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        let gpu = &self.gpu;
        let target = ensure_target(gpu, &mut self.target, request.width, request.height)?;
        gpu.scoped("rendering a frame", || {
            let bind_group = self.pipeline.bind_group(
                gpu,
                RaycastBindings {
                    params: &self.params,
                    volume: &self.volume.view,
                    transfer_function: &self.transfer_function,
                    output: &target.view,
                },
            );
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("frame"),
                });
            self.pipeline.dispatch(&mut encoder, &bind_group, &params);
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
