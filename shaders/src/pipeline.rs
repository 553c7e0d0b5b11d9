//! Small builders for compute pipelines: bind group layout entries by kind, a
//! pipeline with its layout from WGSL source, and the linear clamp sampler
//! every stage filters with.

use crate::{GpuContext, GpuError};

/// A layout entry visible to compute shaders.
fn entry(binding: u32, ty: wgpu::BindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty,
        count: None,
    }
}

/// A uniform buffer of `size` bytes.
pub fn uniform(binding: u32, size: usize) -> wgpu::BindGroupLayoutEntry {
    entry(
        binding,
        wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: wgpu::BufferSize::new(size as u64),
        },
    )
}

/// A read-only storage buffer.
pub fn storage_buffer(binding: u32) -> wgpu::BindGroupLayoutEntry {
    entry(
        binding,
        wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
    )
}

/// A read-write storage buffer.
pub fn storage_buffer_rw(binding: u32) -> wgpu::BindGroupLayoutEntry {
    entry(
        binding,
        wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: false },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
    )
}

/// A float 3D texture read with `textureLoad` only (32-bit floats need not filter).
pub fn unfilterable_texture_3d(binding: u32) -> wgpu::BindGroupLayoutEntry {
    entry(
        binding,
        wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D3,
            multisampled: false,
        },
    )
}

/// A filterable float 3D texture.
pub fn float_texture_3d(binding: u32) -> wgpu::BindGroupLayoutEntry {
    entry(
        binding,
        wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: true },
            view_dimension: wgpu::TextureViewDimension::D3,
            multisampled: false,
        },
    )
}

/// An unsigned-integer 3D texture (the block index).
pub fn uint_texture_3d(binding: u32) -> wgpu::BindGroupLayoutEntry {
    entry(
        binding,
        wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Uint,
            view_dimension: wgpu::TextureViewDimension::D3,
            multisampled: false,
        },
    )
}

/// A filtering sampler.
pub fn sampler(binding: u32) -> wgpu::BindGroupLayoutEntry {
    entry(
        binding,
        wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
    )
}

/// A storage texture of `format` and `dimension`.
pub fn storage_texture(
    binding: u32,
    format: wgpu::TextureFormat,
    access: wgpu::StorageTextureAccess,
    dimension: wgpu::TextureViewDimension,
) -> wgpu::BindGroupLayoutEntry {
    entry(
        binding,
        wgpu::BindingType::StorageTexture {
            access,
            format,
            view_dimension: dimension,
        },
    )
}

/// A compiled compute stage (entry point `main` unless named) and its one bind
/// group layout.
#[derive(Debug)]
pub struct ComputeStage {
    /// The stage's name, for labels and errors.
    pub name: &'static str,
    /// The pipeline.
    pub pipeline: wgpu::ComputePipeline,
    /// Group 0's layout.
    pub layout: wgpu::BindGroupLayout,
}

impl ComputeStage {
    /// Compiles `source` with group 0 laid out as `entries`.
    pub fn new(
        gpu: &GpuContext,
        name: &'static str,
        source: &str,
        entries: &[wgpu::BindGroupLayoutEntry],
    ) -> Result<ComputeStage, GpuError> {
        ComputeStage::with_entry(gpu, name, "main", source, entries)
    }

    /// Compiles entry point `entry` of `source` with group 0 laid out as `entries`.
    pub fn with_entry(
        gpu: &GpuContext,
        name: &'static str,
        entry: &str,
        source: &str,
        entries: &[wgpu::BindGroupLayoutEntry],
    ) -> Result<ComputeStage, GpuError> {
        gpu.scoped(&format!("building the {name} pipeline"), || {
            let device = &gpu.device;
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(name),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(name),
                entries,
            });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(name),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(name),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            });
            ComputeStage {
                name,
                pipeline,
                layout,
            }
        })
    }

    /// A bind group of `resources`, bound in order from binding 0.
    pub fn bind_group(
        &self,
        gpu: &GpuContext,
        resources: &[wgpu::BindingResource<'_>],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry<'_>> = resources
            .iter()
            .enumerate()
            .map(|(i, r)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: r.clone(),
            })
            .collect();
        gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(self.name),
            layout: &self.layout,
            entries: &entries,
        })
    }

    /// Records one dispatch of `groups` workgroups.
    pub fn dispatch(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        bind_group: &wgpu::BindGroup,
        groups: [u32; 3],
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(self.name),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
    }
}

/// Runs one stage to completion (a bind group of `resources`, `groups`
/// workgroups) and returns its wall time in milliseconds.
pub fn run(
    gpu: &GpuContext,
    stage: &ComputeStage,
    resources: &[wgpu::BindingResource<'_>],
    groups: [u32; 3],
) -> Result<f64, GpuError> {
    let start = std::time::Instant::now();
    gpu.scoped(&format!("running {}", stage.name), || {
        let bind_group = stage.bind_group(gpu, resources);
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some(stage.name),
            });
        stage.dispatch(&mut encoder, &bind_group, groups);
        gpu.queue.submit([encoder.finish()]);
    })?;
    gpu.wait(stage.name)?;
    Ok(start.elapsed().as_secs_f64() * 1e3)
}

/// The sampler every stage filters with: linear, clamp to edge.
pub fn linear_sampler(gpu: &GpuContext) -> wgpu::Sampler {
    gpu.device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("linear clamp"),
        address_mode_u: wgpu::AddressMode::ClampToEdge,
        address_mode_v: wgpu::AddressMode::ClampToEdge,
        address_mode_w: wgpu::AddressMode::ClampToEdge,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        ..Default::default()
    })
}
