//! Packed blocks resident on the GPU: the atlas (one 3D texture of slots, each a
//! block at its level with a one-voxel apron, see [`blocks::packing`]) and the
//! block index (a small `rgba16uint` 3D texture), and the same atlas in memory
//! for the CPU renderer ([`CpuAtlas`]) and the CPU twins ([`assemble_cpu`]).
//! [`Atlas`] is what both offer a [`crate::residency::Residency`].
//!
//! A full upload writes the atlas a row of slots at a time (a few MiB per write,
//! whatever the atlas's size); after a transfer-function or budget change only
//! the blocks [`blocks::packing::Packing::update`] lists are written, each into
//! its slot, and the index is rewritten whole (8 bytes per block).

use blocks::cache::BlockCache;
use blocks::packing::{Packing, slot_edge};
use blocks::store::LEVELS;
use blocks::{TransferFunction, VoxelData};
use rayon::prelude::*;

use crate::cpu::{PackedTexture, SlotAtlas};
use crate::packed_volume::PackedLayout;
use crate::volume_texture::{VolumeTexture, create_texture_3d, write_box};
use crate::{GpuContext, GpuError};

/// The atlas and index of one packing on the GPU.
#[derive(Debug)]
pub struct GpuAtlas {
    /// The atlas texture.
    pub atlas: wgpu::Texture,
    /// A view of it.
    pub atlas_view: wgpu::TextureView,
    /// The block index texture.
    pub index: wgpu::Texture,
    /// A view of it.
    pub index_view: wgpu::TextureView,
    /// What the atlas holds.
    pub packing: Packing,
    /// Sizes the shader needs.
    pub layout: PackedLayout,
}

/// Where an upload gets a block's voxels: block `b` (in block-statistics
/// order) at its level in `lod` (the packing's levels of every block), with
/// its one-voxel apron meeting its neighbours at their levels
/// ([`blocks::seams`]). The renderer passes voxels it pinned in memory, so an
/// upload never waits for storage.
pub type BlockSource<'a> = &'a (dyn Fn(usize, &[u8]) -> Result<VoxelData, GpuError> + Sync);

/// A source reading blocks through `cache` as the residency shows them for
/// `tf`, missing chunks on the caller's thread (the CPU twin, tests).
pub fn cache_source<'a>(
    cache: &'a BlockCache,
    tf: &'a TransferFunction,
) -> impl Fn(usize, &[u8]) -> Result<VoxelData, GpuError> + Sync + 'a {
    move |b, lod| {
        let grid = cache.store().meta().blocks;
        let block = cache.store().stats().block_position(b);
        let levels = blocks::seams::neighbourhood(lod, grid, block);
        Ok(cache.seamless_block(block, &levels, tf)?)
    }
}

/// The slot's voxels of block `b`: its level's data with the apron, as texel bytes.
fn slot_bytes(
    source: BlockSource<'_>,
    packing: &Packing,
    desc: &VolumeTexture,
    b: usize,
) -> Result<Vec<u8>, GpuError> {
    let voxels = source(b, &packing.lod)?;
    Ok(desc.texel_bytes(&voxels).into_owned())
}

/// Where a [`crate::residency::Residency`] keeps its packed blocks: on the
/// GPU ([`GpuAtlas`]) or in memory ([`CpuAtlas`]).
pub trait Atlas: Sized + Sync + std::fmt::Debug {
    /// What making and writing the atlas needs: the GPU, or nothing.
    type Device: ?Sized + Sync;
    /// The largest atlas edge in texels the device allows.
    fn max_edge(device: &Self::Device) -> u32;
    /// Bytes one texel of a volume stored as `desc` takes in this atlas.
    fn texel_bytes(desc: &VolumeTexture) -> u64;
    /// Makes the atlas of `packing` of a volume of `grid` blocks and writes
    /// every selected block from `source`.
    fn upload(
        device: &Self::Device,
        grid: [u32; 3],
        packing: Packing,
        desc: &VolumeTexture,
        source: BlockSource<'_>,
    ) -> Result<Self, GpuError>;
    /// Writes the blocks `uploads` of a new packing with the same layout into
    /// their slots, and the new index.
    fn update(
        &mut self,
        device: &Self::Device,
        packing: Packing,
        uploads: &[usize],
        desc: &VolumeTexture,
        source: BlockSource<'_>,
    ) -> Result<(), GpuError>;
    /// What the atlas holds.
    fn packing(&self) -> &Packing;
}

impl Atlas for GpuAtlas {
    type Device = GpuContext;

    fn max_edge(gpu: &GpuContext) -> u32 {
        gpu.device.limits().max_texture_dimension_3d
    }

    fn texel_bytes(desc: &VolumeTexture) -> u64 {
        desc.format.size() as u64
    }

    /// Creates the textures for `packing` of a volume of `grid` blocks and
    /// uploads every selected block from `source`.
    fn upload(
        gpu: &GpuContext,
        grid: [u32; 3],
        packing: Packing,
        desc: &VolumeTexture,
        source: BlockSource<'_>,
    ) -> Result<GpuAtlas, GpuError> {
        let atlas = create_texture_3d(gpu, "atlas", packing.atlas_dims, desc.format.wgpu())?;
        let index = create_index(gpu, grid)?;
        for level in 0..LEVELS {
            upload_region(gpu, &atlas, &packing, level, desc, source)?;
        }
        let mut gpu_atlas = GpuAtlas {
            atlas_view: atlas.create_view(&wgpu::TextureViewDescriptor::default()),
            atlas,
            index_view: index.create_view(&wgpu::TextureViewDescriptor::default()),
            index,
            layout: PackedLayout {
                atlas_dims: packing.atlas_dims,
                block_grid: grid,
            },
            packing,
        };
        gpu_atlas.write_index(gpu)?;
        gpu.wait("uploading the atlas")?;
        Ok(gpu_atlas)
    }

    /// Writes the blocks `uploads` of a new packing with the same layout into
    /// their slots, and the new index.
    fn update(
        &mut self,
        gpu: &GpuContext,
        packing: Packing,
        uploads: &[usize],
        desc: &VolumeTexture,
        source: BlockSource<'_>,
    ) -> Result<(), GpuError> {
        let texel = desc.format.size();
        for chunk in uploads.chunks(256) {
            let slots: Vec<(usize, Vec<u8>)> = chunk
                .par_iter()
                .map(|&b| slot_bytes(source, &packing, desc, b).map(|s| (b, s)))
                .collect::<Result<_, _>>()?;
            gpu.scoped("uploading changed blocks", || {
                for (b, data) in &slots {
                    if let Some(origin) = packing.slot_origin(*b) {
                        let e = slot_edge(usize::from(packing.lod[*b]));
                        write_box(gpu, &self.atlas, origin, [e, e, e], texel, data);
                    }
                }
                gpu.queue.submit([]);
            })?;
        }
        self.packing = packing;
        self.write_index(gpu)?;
        gpu.wait("uploading changed blocks")
    }

    fn packing(&self) -> &Packing {
        &self.packing
    }
}

impl GpuAtlas {
    fn write_index(&mut self, gpu: &GpuContext) -> Result<(), GpuError> {
        let grid = self.layout.block_grid;
        let index = self.packing.block_index(grid);
        gpu.scoped("writing the block index", || {
            write_box(
                gpu,
                &self.index,
                [0, 0, 0],
                grid,
                8,
                bytemuck::cast_slice(&index.entries),
            );
            gpu.queue.submit([]);
        })
    }
}

/// The block index texture of a volume of `grid` blocks.
fn create_index(gpu: &GpuContext, grid: [u32; 3]) -> Result<wgpu::Texture, GpuError> {
    gpu.scoped("creating the block index", || {
        gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("block index"),
            size: wgpu::Extent3d {
                width: grid[0],
                height: grid[1],
                depth_or_array_layers: grid[2],
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format: wgpu::TextureFormat::Rgba16Uint,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        })
    })
}

/// Uploads the blocks of `level` into their region of `atlas`, a row of
/// slots per write (a few MiB, whatever the atlas's size).
fn upload_region(
    gpu: &GpuContext,
    atlas: &wgpu::Texture,
    packing: &Packing,
    level: usize,
    desc: &VolumeTexture,
    source: BlockSource<'_>,
) -> Result<(), GpuError> {
    let texel = desc.format.size();
    let region = packing.regions[level];
    let edge = slot_edge(level);
    let per_row = region.slots[0];
    let mut rows: Vec<Vec<usize>> = vec![Vec::new(); (region.slots[1] * region.slots[2]) as usize];
    for b in (0..packing.lod.len()).filter(|&b| usize::from(packing.lod[b]) == level) {
        rows[(packing.slot[b] / per_row) as usize].push(b);
    }
    let width = per_row * edge;
    let e = edge as usize;
    for (row, members) in rows.iter().enumerate().filter(|(_, m)| !m.is_empty()) {
        let mut bytes = vec![0u8; width as usize * e * e * texel];
        let slots: Vec<(usize, Vec<u8>)> = members
            .par_iter()
            .map(|&b| slot_bytes(source, packing, desc, b).map(|s| (b, s)))
            .collect::<Result<_, _>>()?;
        for (b, data) in slots {
            let x0 = (packing.slot[b] % per_row * edge) as usize;
            for zy in 0..e * e {
                let src = zy * e * texel;
                let dst = (zy * width as usize + x0) * texel;
                bytes[dst..dst + e * texel].copy_from_slice(&data[src..src + e * texel]);
            }
        }
        let row = row as u32;
        let origin = [
            0,
            (row % region.slots[1]) * edge,
            region.z0 + (row / region.slots[1]) * edge,
        ];
        gpu.scoped("uploading atlas slots", || {
            write_box(gpu, atlas, origin, [width, edge, edge], texel, &bytes);
            gpu.queue.submit([]);
        })?;
    }
    Ok(())
}

/// The largest atlas edge of a [`CpuAtlas`]: the block index holds atlas
/// positions as 16-bit integers.
pub const CPU_MAX_EDGE: u32 = 8192;

/// The packed blocks in memory, as the CPU renderer and the CPU twins read
/// them: texel values as the GPU samples them, and the block index.
#[derive(Debug, Clone)]
pub struct CpuAtlas {
    /// The atlas and index as the `raycast` twin binds them (no light).
    pub texture: PackedTexture,
    /// What the atlas holds.
    pub packing: Packing,
    /// Sizes the stages need.
    pub layout: PackedLayout,
}

impl CpuAtlas {
    /// Writes the slots of those of `blocks` that are stored (their voxels
    /// with the apron) from `source`: one parallel pass, each block decoded
    /// straight into its slot.
    fn write_slots(
        atlas: &mut SlotAtlas,
        packing: &Packing,
        desc: &VolumeTexture,
        source: BlockSource<'_>,
        blocks: impl IntoIterator<Item = usize>,
    ) -> Result<(), GpuError> {
        let lod = &packing.lod;
        atlas
            .slots_mut(blocks, lod)
            .into_par_iter()
            .try_for_each(|(b, slot)| {
                let voxels = source(b, lod)?;
                slot.copy_from_slice(&desc.texel_values(&voxels));
                Ok(())
            })
    }
}

/// What a [`CpuAtlas`] is made for: the largest atlas edge (the CPU
/// renderer's [`CPU_MAX_EDGE`], or a GPU's limit where a test packs exactly
/// as that GPU does).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CpuDevice {
    /// The largest atlas edge in texels.
    pub max_edge: u32,
}

impl Atlas for CpuAtlas {
    type Device = CpuDevice;

    fn max_edge(device: &CpuDevice) -> u32 {
        device.max_edge.min(CPU_MAX_EDGE)
    }

    fn texel_bytes(_desc: &VolumeTexture) -> u64 {
        size_of::<f32>() as u64
    }

    fn upload(
        _device: &CpuDevice,
        grid: [u32; 3],
        packing: Packing,
        desc: &VolumeTexture,
        source: BlockSource<'_>,
    ) -> Result<CpuAtlas, GpuError> {
        let dims = packing.atlas_dims;
        let mut atlas = SlotAtlas::new(&packing);
        CpuAtlas::write_slots(&mut atlas, &packing, desc, source, 0..packing.lod.len())?;
        Ok(CpuAtlas {
            texture: PackedTexture {
                atlas,
                index: packing.block_index(grid).entries,
                grid,
                light: None,
                light_cache: None,
                lit_by: None,
                visible_texels: None,
                visible_boxes: None,
                visible_extent: None,
                visible_cells: None,
            },
            layout: PackedLayout {
                atlas_dims: dims,
                block_grid: grid,
            },
            packing,
        })
    }

    fn update(
        &mut self,
        _device: &CpuDevice,
        packing: Packing,
        uploads: &[usize],
        desc: &VolumeTexture,
        source: BlockSource<'_>,
    ) -> Result<(), GpuError> {
        let atlas = &mut self.texture.atlas;
        atlas.set_packing(&packing);
        CpuAtlas::write_slots(atlas, &packing, desc, source, uploads.iter().copied())?;
        self.texture.index = packing.block_index(self.layout.block_grid).entries;
        self.packing = packing;
        Ok(())
    }

    fn packing(&self) -> &Packing {
        &self.packing
    }
}

/// The atlas of `packing` assembled in memory as the GPU samples it for
/// `tf`, with its index: the bindings of the `raycast` CPU twin.
pub fn assemble_cpu(
    cache: &BlockCache,
    packing: &Packing,
    desc: &VolumeTexture,
    tf: &TransferFunction,
) -> Result<PackedTexture, GpuError> {
    let grid = cache.store().meta().blocks;
    let source = cache_source(cache, tf);
    let device = CpuDevice {
        max_edge: CPU_MAX_EDGE,
    };
    Ok(CpuAtlas::upload(&device, grid, packing.clone(), desc, &source)?.texture)
}
