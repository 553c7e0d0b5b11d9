//! [`BlockCache`]: decoded inner chunks of a [`Store`] under a byte budget, safe
//! to share between threads.
//!
//! The unit cached is the decoded 16³ inner chunk of a level: it is a block at
//! level 0, and holds 8^l blocks at level l, so neighbouring coarse blocks (and
//! the aprons of their neighbours) come from one decode. Eviction follows the
//! `quick_cache` policy (CLOCK-Pro style, close to LRU under scans) weighted by
//! bytes. Levels 3 and 4, at most 1/512 of the data, can be made resident: read
//! once and never evicted.

use std::collections::HashMap;
use std::sync::Arc;

use quick_cache::Weighter;
use quick_cache::sync::Cache;
use rayon::prelude::*;

use crate::store::{BLOCK, LEVELS, Store, sub_cube};
use crate::{Error, VoxelData};

/// A chunk's key: level and chunk position (x, y, z).
pub type ChunkKey = (u8, [u32; 3]);

#[derive(Debug, Clone, Copy)]
struct Bytes;

impl Weighter<ChunkKey, Arc<VoxelData>> for Bytes {
    fn weight(&self, _key: &ChunkKey, value: &Arc<VoxelData>) -> u64 {
        value.as_bytes().len() as u64
    }
}

/// Decoded chunks of one store; see the module docs.
pub struct BlockCache {
    store: Arc<Store>,
    chunks: Cache<ChunkKey, Arc<VoxelData>, Bytes>,
    resident: HashMap<ChunkKey, Arc<VoxelData>>,
}

impl std::fmt::Debug for BlockCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlockCache")
            .field("store", &self.store.path())
            .field("cached_bytes", &self.chunks.weight())
            .field("resident_chunks", &self.resident.len())
            .finish()
    }
}

impl BlockCache {
    /// A cache holding at most `budget_bytes` of decoded chunks (resident levels
    /// come on top).
    pub fn new(store: Arc<Store>, budget_bytes: u64) -> BlockCache {
        let chunk_bytes = u64::from(BLOCK).pow(3) * store.voxel_type().size() as u64;
        let estimated_items = (budget_bytes / chunk_bytes).max(1) as usize;
        BlockCache {
            store,
            chunks: Cache::with_weighter(estimated_items, budget_bytes.max(chunk_bytes), Bytes),
            resident: HashMap::new(),
        }
    }

    /// Reads every chunk of `levels` and keeps them outside the budget.
    pub fn make_resident(&mut self, levels: &[usize]) -> Result<(), Error> {
        let keys: Vec<ChunkKey> = levels
            .iter()
            .filter(|&&l| l < LEVELS)
            .flat_map(|&level| {
                let [gx, gy, gz] = self.store.chunk_grid(level);
                (0..gz).flat_map(move |z| {
                    (0..gy).flat_map(move |y| (0..gx).map(move |x| (level as u8, [x, y, z])))
                })
            })
            .collect();
        let store = &self.store;
        let chunks: Vec<(ChunkKey, Arc<VoxelData>)> = keys
            .into_par_iter()
            .map(|key| Ok((key, Arc::new(store.read_chunk(usize::from(key.0), key.1)?))))
            .collect::<Result<_, Error>>()?;
        self.resident.extend(chunks);
        Ok(())
    }

    /// The store.
    pub fn store(&self) -> &Arc<Store> {
        &self.store
    }

    /// Bytes of decoded chunks held under the budget now.
    pub fn cached_bytes(&self) -> u64 {
        self.chunks.weight()
    }

    /// Chunk reads served from the budgeted cache so far (resident levels not
    /// counted).
    pub fn hits(&self) -> u64 {
        self.chunks.hits()
    }

    /// Chunk reads that had to read and decode from the store so far.
    pub fn misses(&self) -> u64 {
        self.chunks.misses()
    }

    /// The decoded chunk `key`, from memory or read and decoded now.
    pub fn chunk(&self, key: ChunkKey) -> Result<Arc<VoxelData>, Error> {
        if let Some(c) = self.resident.get(&key) {
            return Ok(c.clone());
        }
        self.chunks.get_or_insert_with(&key, || {
            self.store
                .read_chunk(usize::from(key.0), key.1)
                .map(Arc::new)
        })
    }

    /// Many chunks at once: the missing ones are read and decoded in parallel.
    pub fn chunks(&self, keys: &[ChunkKey]) -> Vec<Result<Arc<VoxelData>, Error>> {
        keys.par_iter().map(|&k| self.chunk(k)).collect()
    }

    /// Loads `keys` ahead of use; errors show up when the chunks are asked for.
    pub fn prefetch(&self, keys: &[ChunkKey]) {
        let _ = self.chunks(keys);
    }

    /// Block `block` at `level`: (16 / 2^l)³ voxels.
    pub fn block(&self, level: usize, block: [u32; 3]) -> Result<VoxelData, Error> {
        let chunk = self.chunk((level as u8, block.map(|b| b >> level)))?;
        Ok(sub_cube(&chunk, block, level))
    }

    /// Block `block` at `level` with a border of `apron` voxels on every side,
    /// copied from its spatial neighbours at the same level (edge voxels repeated
    /// at the volume's boundary): (16 / 2^l + 2·apron)³ voxels.
    pub fn block_with_apron(
        &self,
        level: usize,
        block: [u32; 3],
        apron: u32,
    ) -> Result<VoxelData, Error> {
        let edge = BLOCK >> level;
        let side = edge + 2 * apron;
        let dims = crate::store::level_dims(self.store.meta().geometry.dims, level);
        let start = block.map(|b| i64::from(b * edge) - i64::from(apron));
        let clamp = |v: i64, n: u32| v.clamp(0, i64::from(n) - 1) as u32;
        // The chunks the slot touches, fetched once each.
        let lo = [0, 1, 2].map(|a| clamp(start[a], dims[a]) / BLOCK);
        let hi = [0, 1, 2].map(|a| clamp(start[a] + i64::from(side) - 1, dims[a]) / BLOCK);
        let mut keys = Vec::new();
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    keys.push((level as u8, [x, y, z]));
                }
            }
        }
        let chunks: HashMap<[u32; 3], Arc<VoxelData>> = keys
            .iter()
            .zip(self.chunks(&keys))
            .map(|(k, c)| c.map(|c| (k.1, c)))
            .collect::<Result<_, _>>()?;
        let n = BLOCK as usize;
        let mut index = Vec::with_capacity((side as usize).pow(3));
        for z in 0..i64::from(side) {
            for y in 0..i64::from(side) {
                for x in 0..i64::from(side) {
                    let p = [
                        clamp(start[0] + x, dims[0]),
                        clamp(start[1] + y, dims[1]),
                        clamp(start[2] + z, dims[2]),
                    ];
                    let c = p.map(|v| v / BLOCK);
                    let o = p.map(|v| (v % BLOCK) as usize);
                    index.push((c, (o[2] * n + o[1]) * n + o[0]));
                }
            }
        }
        let Some(any) = chunks.values().next().cloned() else {
            return Ok(VoxelData::zeros(self.store.voxel_type(), 0));
        };
        Ok(
            crate::volume::with_voxels!(any.as_ref(), v => VoxelData::from(gather(v, &chunks, &index))),
        )
    }
}

/// The voxels at `index` (chunk, offset) of `chunks`, all of the type of `_like`.
fn gather<T: crate::Voxel>(
    _like: &[T],
    chunks: &HashMap<[u32; 3], Arc<VoxelData>>,
    index: &[([u32; 3], usize)],
) -> Vec<T> {
    index
        .iter()
        .map(|(c, i)| {
            // Every chunk of one store has one voxel type, laid out as `T`.
            let values: &[T] = bytemuck::cast_slice(chunks[c].as_bytes());
            values[*i]
        })
        .collect()
}
