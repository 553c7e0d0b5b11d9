//! [`BlockCache`]: decoded inner chunks of a [`Store`] under a byte budget, safe
//! to share between threads.
//!
//! The unit cached is the decoded 16³ inner chunk of a level: it is a block at
//! level 0, and holds 8^l blocks at level l, so neighbouring coarse blocks (and
//! the aprons of their neighbours) come from one decode. A coarse chunk of a
//! store with box extremes is followed by them ([`Store::read_chunk_record`]):
//! a block's pinned chunks carry what [`crate::visibility`] needs. Eviction follows the
//! `quick_cache` policy (CLOCK-Pro style, close to LRU under scans) weighted by
//! bytes. Levels 3 and 4, at most 1/512 of the data, can be made resident: read
//! once and never evicted.
//!
//! # Reading off the render thread
//! A renderer must never wait for storage: [`BlockCache::pin_with_apron`]
//! hands it a block's chunks only when they are in memory, and otherwise
//! asks [`reader_pool`] threads (for a store on object storage,
//! [`remote_reader_pool`] threads) to read and decode them in the background
//! ([`BlockCache::request`]). Each chunk that arrives bumps
//! [`BlockCache::arrivals`] and wakes whoever waits
//! ([`BlockCache::wait_for_arrivals`], [`BlockCache::subscribe`]); a chunk whose
//! read failed keeps its error, which the next pin returns (for
//! [`RETRY_AFTER`] after a pin returned it, where the store did not answer:
//! then it is read again).

use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, OnceLock, PoisonError};
use std::time::{Duration, Instant};

use quick_cache::Weighter;
use quick_cache::sync::Cache;
use rayon::prelude::*;

use crate::store::{BLOCK, LEVELS, Store, StoreLocation, sub_cube};
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

/// The chunks a block needs, pinned in memory: chunk position → voxels.
pub type Pinned = HashMap<[u32; 3], Arc<VoxelData>>;

impl Loads {
    /// The error of `key`'s failed read. One that says the store did not
    /// answer is forgotten [`RETRY_AFTER`] after a pin first returned it
    /// (never before anyone saw it), so the chunk is read again.
    fn failure(&mut self, key: ChunkKey) -> Option<Arc<Error>> {
        let (error, reported) = self.failed.get(&key)?;
        let passing = matches!(error.as_ref(), Error::Unavailable { .. });
        if passing && reported.is_some_and(|t| t.elapsed() >= RETRY_AFTER) {
            self.failed.remove(&key);
            return None;
        }
        Some(error.clone())
    }

    /// Marks every failure not reported before as reported now, those of
    /// other chunks too: one refusal stands for them all (they are the same
    /// store not answering), so once it answers again they are all read
    /// again together rather than refusing one view after another, each
    /// for the next chunk that failed during the outage.
    fn report_all(&mut self) {
        let now = Instant::now();
        for (_, reported) in self.failed.values_mut() {
            if reported.is_none() {
                *reported = Some(now);
            }
        }
    }
}

/// A callback run after each chunk arrives.
type Listener = Box<dyn Fn() + Send + Sync>;

/// The threads that read and decode chunks in the background, shared by
/// every cache: their own pool, so a renderer's parallel work never queues
/// behind storage reads.
pub fn reader_pool() -> &'static rayon::ThreadPool {
    static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
    POOL.get_or_init(|| {
        let threads = std::thread::available_parallelism().map_or(2, |n| n.get().max(2));
        start_pool(threads, "block-reader")
    })
}

/// Requests in flight at once to a store on object storage: each waits a
/// round trip (tens of milliseconds to S3) while the CPU is idle, so a
/// reader thread per request rather than per core.
pub const REMOTE_READERS: usize = 96;

/// The threads that read chunks of stores on object storage
/// ([`REMOTE_READERS`]), shared by every cache of such a store.
pub fn remote_reader_pool() -> &'static rayon::ThreadPool {
    static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
    POOL.get_or_init(|| start_pool(REMOTE_READERS, "remote-reader"))
}

/// The pool that reads `store`'s chunks.
fn pool_of(store: &Store) -> &'static rayon::ThreadPool {
    match store.location() {
        StoreLocation::Remote(_) => remote_reader_pool(),
        StoreLocation::Folder(_) | StoreLocation::Memory(_) => reader_pool(),
    }
}

/// A pool of `threads` named `name-N`, or of one thread where that many
/// cannot start.
fn start_pool(threads: usize, name: &'static str) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(move |i| format!("{name}-{i}"))
        .build()
        .unwrap_or_else(|_| {
            // Without threads of its own the pool would not read at all:
            // one thread is the least that keeps renders refining.
            rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap_or_else(|e| panic!("cannot start a block reader thread: {e}"))
        })
}

/// How long a chunk whose store did not answer ([`Error::Unavailable`])
/// keeps that error, once a pin has returned it, before it is read again;
/// other failures (missing, corrupt) are kept.
pub const RETRY_AFTER: Duration = Duration::from_secs(1);

/// What the background reads are doing.
#[derive(Default)]
struct Loads {
    /// Chunks being read now.
    in_flight: HashSet<ChunkKey>,
    /// Chunks whose read failed, with the error and when a pin first
    /// returned it.
    failed: HashMap<ChunkKey, (Arc<Error>, Option<Instant>)>,
    /// Called after each arrival.
    listeners: Vec<Listener>,
}

/// The coarse levels a dataset keeps in memory whole, outside the cache's
/// budget ([`BlockCache::make_resident`]): a frame can always be drawn from
/// them while finer blocks are read. Opening a store on object storage reads
/// their shards whole, in the opening's one round of requests.
pub const RESIDENT_LEVELS: [usize; 2] = [3, 4];

/// Decoded chunks of one store; see the module docs.
pub struct BlockCache {
    store: Arc<Store>,
    chunks: Cache<ChunkKey, Arc<VoxelData>, Bytes>,
    resident: HashMap<ChunkKey, Arc<VoxelData>>,
    loads: Mutex<Loads>,
    /// Chunks arrived from background reads (or failed) so far.
    arrivals: AtomicU64,
    /// Notified with `loads` after each arrival.
    arrived: Condvar,
    /// Chunks read on the caller's thread (not in the background) so far.
    inline_reads: AtomicU64,
}

impl std::fmt::Debug for BlockCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlockCache")
            .field("store", &self.store.location())
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
            loads: Mutex::new(Loads::default()),
            arrivals: AtomicU64::new(0),
            arrived: Condvar::new(),
            inline_reads: AtomicU64::new(0),
        }
    }

    /// Reads every chunk of `levels` and keeps them outside the budget; then
    /// the store's opening is over ([`Store::end_opening`]).
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
        let chunks: Result<Vec<(ChunkKey, Arc<VoxelData>)>, Error> = pool_of(store).install(|| {
            keys.into_par_iter()
                .map(|key| {
                    Ok((
                        key,
                        Arc::new(store.read_chunk_record(usize::from(key.0), key.1)?),
                    ))
                })
                .collect::<Result<_, Error>>()
        });
        store.end_opening();
        self.resident.extend(chunks?);
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

    /// The decoded chunk `key`, from memory or read and decoded now, on the
    /// caller's thread.
    pub fn chunk(&self, key: ChunkKey) -> Result<Arc<VoxelData>, Error> {
        if let Some(c) = self.resident.get(&key) {
            return Ok(c.clone());
        }
        self.chunks.get_or_insert_with(&key, || {
            self.inline_reads.fetch_add(1, Ordering::Relaxed);
            self.store
                .read_chunk_record(usize::from(key.0), key.1)
                .map(Arc::new)
        })
    }

    /// The decoded chunk `key` if it is in memory, without reading.
    pub fn cached_chunk(&self, key: ChunkKey) -> Option<Arc<VoxelData>> {
        self.resident
            .get(&key)
            .cloned()
            .or_else(|| self.chunks.get(&key))
    }

    /// Chunks read on a caller's thread so far ([`BlockCache::chunk`] misses):
    /// a renderer that pins instead never adds to it.
    pub fn inline_reads(&self) -> u64 {
        self.inline_reads.load(Ordering::Relaxed)
    }

    /// Chunks that arrived from background reads (or failed) so far.
    pub fn arrivals(&self) -> u64 {
        self.arrivals.load(Ordering::Acquire)
    }

    /// Chunks being read in the background now.
    pub fn loading(&self) -> usize {
        self.lock_loads().in_flight.len()
    }

    /// Runs `listener` after every arrival (the server turns it into an
    /// async notification).
    pub fn subscribe(&self, listener: impl Fn() + Send + Sync + 'static) {
        self.lock_loads().listeners.push(Box::new(listener));
    }

    /// Waits (blocking this thread) until more than `seen` chunks have
    /// arrived, or `timeout` passes; the arrivals then.
    pub fn wait_for_arrivals(&self, seen: u64, timeout: Duration) -> u64 {
        let loads = self.lock_loads();
        let (_loads, _) = self
            .arrived
            .wait_timeout_while(loads, timeout, |_| self.arrivals() <= seen)
            .unwrap_or_else(PoisonError::into_inner);
        self.arrivals()
    }

    fn lock_loads(&self) -> std::sync::MutexGuard<'_, Loads> {
        // A panicking listener cannot leave the sets half-updated.
        self.loads.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Reads `keys` in the background (those not in memory, not already being
    /// read, and not failed before).
    pub fn request(self: &Arc<Self>, keys: &[ChunkKey]) {
        let mut loads = self.lock_loads();
        for &key in keys {
            if loads.in_flight.contains(&key)
                || loads.failure(key).is_some()
                || self.resident.contains_key(&key)
                || self.chunks.peek(&key).is_some()
            {
                continue;
            }
            loads.in_flight.insert(key);
            let cache = Arc::clone(self);
            pool_of(&self.store).spawn(move || cache.read_in_background(key));
        }
    }

    /// A background read of `key`: into the cache, or its error kept.
    fn read_in_background(&self, key: ChunkKey) {
        let read = self.store.read_chunk_record(usize::from(key.0), key.1);
        let mut loads = self.lock_loads();
        match read {
            Ok(voxels) => self.chunks.insert(key, Arc::new(voxels)),
            Err(e) => {
                loads.failed.insert(key, (Arc::new(e), None));
            }
        }
        loads.in_flight.remove(&key);
        self.arrivals.fetch_add(1, Ordering::AcqRel);
        self.arrived.notify_all();
        for listener in &loads.listeners {
            listener();
        }
    }

    /// The chunks block `block` at `level` with a border of `apron` voxels
    /// needs, if every one is in memory: pinned, so eviction cannot take them
    /// before [`BlockCache::assemble_with_apron`]. When some are missing,
    /// `Ok(None)`, and with `request` they are read in the background. A chunk
    /// whose background read failed gives its error.
    pub fn pin_with_apron(
        self: &Arc<Self>,
        level: usize,
        block: [u32; 3],
        apron: u32,
        request: bool,
    ) -> Result<Option<Pinned>, Error> {
        let keys = self.apron_chunks(level, block, apron);
        Ok(self
            .pin(&keys, request)?
            .map(|chunks| chunks.into_iter().map(|(k, c)| (k.1, c)).collect()))
    }

    /// The chunks `keys` if every one is in memory, pinned; otherwise as
    /// [`BlockCache::pin_with_apron`].
    pub fn pin(
        self: &Arc<Self>,
        keys: &[ChunkKey],
        request: bool,
    ) -> Result<Option<HashMap<ChunkKey, Arc<VoxelData>>>, Error> {
        let mut pinned = HashMap::with_capacity(keys.len());
        let mut missing = Vec::new();
        for &key in keys {
            match self.cached_chunk(key) {
                Some(chunk) => {
                    pinned.insert(key, chunk);
                }
                None => missing.push(key),
            }
        }
        if missing.is_empty() {
            return Ok(Some(pinned));
        }
        let mut loads = self.lock_loads();
        if let Some(e) = missing.iter().find_map(|&k| loads.failure(k)) {
            loads.report_all();
            return Err(Error::Shared(e));
        }
        drop(loads);
        if request {
            self.request(&missing);
        }
        Ok(None)
    }

    /// Many chunks at once: the missing ones are read and decoded in parallel.
    pub fn chunks(&self, keys: &[ChunkKey]) -> Vec<Result<Arc<VoxelData>, Error>> {
        pool_of(&self.store).install(|| keys.par_iter().map(|&k| self.chunk(k)).collect())
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
    /// at the volume's boundary): (16 / 2^l + 2·apron)³ voxels. Missing chunks
    /// are read on the caller's thread.
    pub fn block_with_apron(
        &self,
        level: usize,
        block: [u32; 3],
        apron: u32,
    ) -> Result<VoxelData, Error> {
        let keys = self.apron_chunks(level, block, apron);
        let chunks: Pinned = keys
            .iter()
            .zip(self.chunks(&keys))
            .map(|(k, c)| c.map(|c| (k.1, c)))
            .collect::<Result<_, _>>()?;
        Ok(self.assemble_with_apron(level, block, apron, &chunks))
    }

    /// Block `block` at the level in entry 13 of `levels` with a one-voxel
    /// apron that meets its neighbours at their levels in `levels` without a
    /// step ([`crate::seams`]), thin structures kept visible under `tf`
    /// ([`crate::visibility`]); missing chunks are read on the caller's thread.
    pub fn seamless_block(
        &self,
        block: [u32; 3],
        levels: &crate::seams::Neighbourhood,
        tf: &crate::TransferFunction,
    ) -> Result<VoxelData, Error> {
        let level = usize::from(levels[13]);
        let meta = self.store.meta();
        let extinction = crate::visibility::Extinction {
            tf,
            value_map: meta.value_map,
        };
        let kept = |c: Arc<VoxelData>| crate::visibility::kept_chunk(&c, extinction);
        let keys = self.apron_chunks(level, block, crate::packing::APRON);
        let pinned: Pinned = keys
            .iter()
            .zip(self.chunks(&keys))
            .map(|(k, c)| c.map(|c| (k.1, kept(c))))
            .collect::<Result<_, _>>()?;
        let mut voxels = self.assemble_with_apron(level, block, crate::packing::APRON, &pinned);
        let keys = crate::seams::seam_chunks(block, meta.blocks, meta.geometry.dims, levels);
        let chunks = keys
            .iter()
            .zip(self.chunks(&keys))
            .map(|(k, c)| c.map(|c| (*k, kept(c))))
            .collect::<Result<_, _>>()?;
        crate::seams::fix_apron(
            &mut voxels,
            block,
            meta.blocks,
            meta.geometry.dims,
            levels,
            &chunks,
        );
        Ok(voxels)
    }

    /// The chunks of `level` that block `block` with an `apron` touches.
    fn apron_chunks(&self, level: usize, block: [u32; 3], apron: u32) -> Vec<ChunkKey> {
        let (start, side, dims) = self.apron_box(level, block, apron);
        let clamp = |v: i64, n: u32| v.clamp(0, i64::from(n) - 1) as u32;
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
        keys
    }

    /// The first voxel (possibly outside the volume), the side and the
    /// level's dims of block `block` with an `apron`.
    fn apron_box(&self, level: usize, block: [u32; 3], apron: u32) -> ([i64; 3], u32, [u32; 3]) {
        let edge = BLOCK >> level;
        let dims = crate::store::level_dims(self.store.meta().geometry.dims, level);
        let start = block.map(|b| i64::from(b * edge) - i64::from(apron));
        (start, edge + 2 * apron, dims)
    }

    /// Block `block` at `level` with an `apron`, from its pinned `chunks`
    /// ([`BlockCache::pin_with_apron`]): no reads.
    pub fn assemble_with_apron(
        &self,
        level: usize,
        block: [u32; 3],
        apron: u32,
        chunks: &Pinned,
    ) -> VoxelData {
        let (start, side, dims) = self.apron_box(level, block, apron);
        let clamp = |v: i64, n: u32| v.clamp(0, i64::from(n) - 1) as u32;
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
            return VoxelData::zeros(self.store.voxel_type(), 0);
        };
        crate::volume::with_voxels!(any.as_ref(), v => VoxelData::from(gather(v, chunks, &index)))
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
