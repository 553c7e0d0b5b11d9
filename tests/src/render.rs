//! Rendering a dataset for a test: packed on the GPU ([`shaders::Renderer`]),
//! packed on the CPU twin, and the full-resolution reference on either, with the
//! same atlas limit on both sides so their packings are identical.

use std::sync::Arc;

use blocks::Volume;
use blocks::ingest::MemorySource;
use blocks::store::{IngestOptions, ingest_in_memory};
use server::Dataset;
use shaders::{Frame, FrameRequest, GpuContext, ReferenceRenderer, Renderer};

use crate::phantom::TEST_CACHE_BYTES;

/// The atlas edge limit the CPU twin packs to without a GPU to match (what
/// Vulkan adapters commonly allow).
pub const CPU_TWIN_MAX_EDGE: u32 = 2048;

/// Device budget for test renderers: every test volume fits at level 0.
pub const TEST_GPU_BUDGET_BYTES: u64 = 512 << 20;

/// `volume` bricked into a store in memory, as the server does with files it is
/// given directly.
///
/// # Panics
/// When bricking fails.
pub fn dataset_of(volume: Volume) -> Dataset {
    let name = volume.name.clone();
    let mut source = MemorySource::new(Arc::new(volume), &name);
    let store = ingest_in_memory(&mut source, &IngestOptions::default())
        .unwrap_or_else(|e| panic!("bricking {name}: {e}"));
    Dataset::new(name, store, TEST_CACHE_BYTES).unwrap_or_else(|e| panic!("dataset: {e}"))
}

/// A packed renderer of `dataset` on `gpu`.
///
/// # Panics
/// When it cannot be built.
pub fn gpu_renderer(gpu: &GpuContext, dataset: &Dataset) -> Renderer {
    Renderer::new(gpu.clone(), dataset.cache.clone(), TEST_GPU_BUDGET_BYTES)
        .unwrap_or_else(|e| panic!("renderer of {}: {e}", dataset.id))
}

/// The features and atlas limit the CPU twin should assume to match `gpu` (or
/// the defaults without one).
pub fn cpu_twin_device(gpu: Option<&GpuContext>) -> (wgpu::Features, u32) {
    match gpu {
        Some(g) => (
            g.device.features(),
            g.device.limits().max_texture_dimension_3d,
        ),
        None => (shaders::cpu::CPU_FEATURES, CPU_TWIN_MAX_EDGE),
    }
}

/// `request` of `dataset` through the packed CPU twin, as on `gpu` (if any).
///
/// # Panics
/// When rendering fails.
pub fn cpu_packed(gpu: Option<&GpuContext>, dataset: &Dataset, request: &FrameRequest) -> Frame {
    let (features, max_edge) = cpu_twin_device(gpu);
    shaders::cpu::render_packed(&dataset.cache, request, features, max_edge)
        .unwrap_or_else(|e| panic!("CPU packed render of {}: {e}", dataset.id))
        .0
}

/// `request` of `volume` through the reference CPU twin, as on `gpu` (if any).
///
/// # Panics
/// When rendering fails.
pub fn cpu_reference(gpu: Option<&GpuContext>, volume: &Volume, request: &FrameRequest) -> Frame {
    let (features, _) = cpu_twin_device(gpu);
    shaders::cpu::render_reference(volume, request, features)
        .unwrap_or_else(|e| panic!("CPU reference render of {}: {e}", volume.name))
}

/// A reference renderer of `volume` on `gpu`.
///
/// # Panics
/// When it cannot be built.
pub fn gpu_reference(gpu: &GpuContext, volume: &Volume) -> ReferenceRenderer {
    ReferenceRenderer::new(gpu.clone(), volume)
        .unwrap_or_else(|e| panic!("reference renderer of {}: {e}", volume.name))
}

/// The `raycast` CPU twin's frame of `request` over `packed` (laid out as
/// `packing`, blocks of `dataset`), lit by whatever light `packed` carries:
/// what a GPU frame of the same packing is compared with.
pub fn cpu_raycast(
    dataset: &Dataset,
    desc: &shaders::volume_texture::VolumeTexture,
    packing: &blocks::packing::Packing,
    packed: &shaders::cpu::PackedTexture,
    request: &FrameRequest,
    table: &[[f32; 4]],
) -> Frame {
    let layout = shaders::packed_volume::PackedLayout {
        atlas_dims: packing.atlas_dims,
        block_grid: dataset.store.meta().blocks,
    };
    let tf = request.store_transfer_function(dataset.store.meta());
    let params = shaders::RaycastParams::new(desc, request, &tf, table.len() as u32, layout);
    let mut rgba = vec![0u8; (request.width * request.height * 4) as usize];
    let table = shaders::cpu::full_table(table).expect("a table of TABLE_LEN entries");
    shaders::cpu::raycast(&params, packed, table, &mut rgba);
    Frame {
        width: request.width,
        height: request.height,
        rgba,
    }
}
