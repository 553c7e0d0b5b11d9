//! A read-through cache on local disk of what stores on object storage
//! answer (`--store-cache DIR`, `--store-cache-mib`): each byte range read
//! (an inner chunk of a shard, a shard index, a metadata object) is kept
//! under its object's URL, version and range, so a later read of the same
//! range of the same object, in this process or after a restart, comes from
//! disk. The version is the object's ETag, or, where the store lists none,
//! the SHA-256 the store's manifest gives it: a replaced object has another
//! and is never answered from the cache. The cache is `foyer`'s block
//! engine: a fixed-size file set under the folder, oldest blocks reclaimed
//! first, its index recovered when a process opens the folder again. One
//! process uses a folder at a time (a lock file says which).

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, Ordering};

use foyer::{
    BlockEngineConfig, DeviceBuilder, FsDeviceBuilder, HybridCache, HybridCacheBuilder,
    HybridCachePolicy, RecoverMode,
};
use zarrs::storage::Bytes;

use crate::Error;

/// The smallest budget: the block engine writes in blocks of
/// [`BLOCK_BYTES`] and needs several.
pub const MIN_MIB: u64 = 64;
/// The block engine's unit of writing and reclaiming.
const BLOCK_BYTES: usize = 4 << 20;
/// Ranges larger than this are not cached (they would fill blocks alone).
pub const MAX_ENTRY_BYTES: usize = 1 << 20;
/// Recently used ranges also kept in memory, bytes.
const MEMORY_BYTES: usize = 8 << 20;
/// Answers waiting in memory to be written to the folder, at most: beyond
/// this the cache drops further ones (read from the store again next time)
/// rather than hold more. With foyer's default, 16 MiB, a restart on a busy
/// machine (the test suite on two cores) found a third of a store's reads
/// missing: an opening's coarse shards and statistics arrive at once, faster
/// than the disk writes.
const SUBMIT_QUEUE_BYTES: usize = 256 << 20;

/// The process's disk cache, once [`open`] made it.
pub struct DiskCache {
    cache: HybridCache<String, Vec<u8>>,
    folder: PathBuf,
    hits: AtomicU64,
    misses: AtomicU64,
    /// Held open while the process runs: its lock keeps other processes out.
    _lock: File,
}

impl std::fmt::Debug for DiskCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DiskCache")
            .field("folder", &self.folder)
            .field("hits", &self.hits())
            .field("misses", &self.misses())
            .finish_non_exhaustive()
    }
}

static CACHE: OnceLock<DiskCache> = OnceLock::new();

/// Opens (or creates) the cache in `folder` with a budget of `mib` MiB for
/// this process's object-store reads; the first call wins. Refused when
/// another process uses the folder, or it cannot be made.
pub fn open(folder: &Path, mib: u64) -> Result<(), Error> {
    let failed = |message: String| Error::Field {
        path: folder.to_owned(),
        field: "--store-cache".into(),
        message,
    };
    if mib < MIN_MIB {
        return Err(failed(format!(
            "a budget of {mib} MiB: expected at least {MIN_MIB} (--store-cache-mib)"
        )));
    }
    std::fs::create_dir_all(folder)
        .map_err(|e| failed(format!("cannot create the folder: {e}")))?;
    let lock = File::create(folder.join("voxserve.lock"))
        .map_err(|e| failed(format!("cannot write in the folder: {e}")))?;
    match lock.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            return Err(failed(
                "in use by another voxserve process: expected a folder of this process's own"
                    .into(),
            ));
        }
        Err(std::fs::TryLockError::Error(e)) => {
            return Err(failed(format!("cannot lock the folder: {e}")));
        }
    }
    let bytes = usize::try_from(mib << 20).unwrap_or(usize::MAX);
    let device = FsDeviceBuilder::new(folder)
        .with_capacity(bytes)
        .build()
        .map_err(|e| failed(format!("{e}")))?;
    let build = HybridCacheBuilder::new()
        .with_name("voxserve-store-cache")
        .with_policy(HybridCachePolicy::WriteOnInsertion)
        .memory(MEMORY_BYTES)
        .with_weighter(|key: &String, value: &Vec<u8>| key.len() + value.len())
        .storage()
        .with_engine_config(
            BlockEngineConfig::new(device)
                .with_block_size(BLOCK_BYTES)
                .with_submit_queue_size_threshold(SUBMIT_QUEUE_BYTES),
        )
        .with_recover_mode(RecoverMode::Quiet)
        .build();
    let cache = super::remote::run(build)
        .ok_or_else(|| failed("the object-store I/O runtime stopped".into()))?
        .map_err(|e| failed(format!("{e}")))?;
    let _ = CACHE.set(DiskCache {
        cache,
        folder: folder.to_owned(),
        hits: AtomicU64::new(0),
        misses: AtomicU64::new(0),
        _lock: lock,
    });
    Ok(())
}

/// The process's disk cache, if [`open`] made one.
pub fn get() -> Option<&'static DiskCache> {
    CACHE.get()
}

impl DiskCache {
    /// The key of `range` of the object `url` in its `version` (its ETag,
    /// or its SHA-256 by the store's manifest).
    pub fn key(url: &str, version: &str, range: &std::ops::Range<u64>) -> String {
        format!("{url}\n{version}\n{}-{}", range.start, range.end)
    }

    /// The cached bytes of `key`, if any (a disk error reads as a miss).
    pub async fn read(&self, key: &String) -> Option<Bytes> {
        let found = match self.cache.get(key).await {
            Ok(found) => found,
            Err(e) => {
                tracing::warn!("store cache {}: {e}", self.folder.display());
                None
            }
        };
        match found {
            Some(entry) => {
                self.hits.fetch_add(1, Ordering::Relaxed);
                Some(Bytes::from(entry.value().clone()))
            }
            None => {
                self.misses.fetch_add(1, Ordering::Relaxed);
                None
            }
        }
    }

    /// Keeps `bytes` under `key` (written to disk in the background).
    pub fn keep(&self, key: String, bytes: &Bytes) {
        if bytes.len() <= MAX_ENTRY_BYTES {
            self.cache.insert(key, bytes.to_vec());
        }
    }

    /// Reads answered from the cache so far.
    pub fn hits(&self) -> u64 {
        self.hits.load(Ordering::Relaxed)
    }

    /// Reads the cache did not hold so far.
    pub fn misses(&self) -> u64 {
        self.misses.load(Ordering::Relaxed)
    }

    /// Writes what is still in memory to disk; the process is ending.
    pub fn close(&self) {
        let cache = self.cache.clone();
        let _ = super::remote::run(async move { cache.close().await });
    }
}
