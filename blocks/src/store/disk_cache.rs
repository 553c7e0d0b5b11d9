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
//!
//! Ranges are kept one at a time ([`DiskCache::keep`] holds a lock): foyer
//! 0.22 numbers each entry before queueing it for its writer, and on
//! recovery stops reading a block at the first entry numbered lower than
//! the one before it. Readers keeping ranges at once from many threads
//! wrote entries out of order, and a restart found a third to two thirds of
//! them gone (read from the store again); the test below shows it. foyer
//! itself writes again a range read back from a block about to be
//! reclaimed, outside this lock: an inversion there costs the rest of that
//! block at the next restart (read from the store again).

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock};

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
/// rather than hold more. foyer's default is 16 MiB; an opening reads up to
/// 64 statistics objects of up to 1 MiB at once.
const SUBMIT_QUEUE_BYTES: usize = 256 << 20;

/// The process's disk cache, once [`open`] made it.
pub struct DiskCache {
    cache: HybridCache<String, Vec<u8>>,
    folder: PathBuf,
    hits: AtomicU64,
    misses: AtomicU64,
    /// Held while a range is kept: entries reach the writer in the order
    /// they are numbered (see the module's documentation).
    keeping: Mutex<()>,
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
    let cache = DiskCache::new(folder, mib)?;
    let _ = CACHE.set(cache);
    Ok(())
}

/// The process's disk cache, if [`open`] made one.
pub fn get() -> Option<&'static DiskCache> {
    CACHE.get()
}

impl DiskCache {
    /// Opens (or creates) a cache in `folder` with a budget of `mib` MiB.
    fn new(folder: &Path, mib: u64) -> Result<DiskCache, Error> {
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
        Ok(DiskCache {
            cache,
            folder: folder.to_owned(),
            hits: AtomicU64::new(0),
            misses: AtomicU64::new(0),
            keeping: Mutex::new(()),
            _lock: lock,
        })
    }

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
            let value = bytes.to_vec();
            let _one_at_a_time = self
                .keeping
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            self.cache.insert(key, value);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_kept_from_many_threads_at_once_are_all_answered_after_a_reopening() {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let (threads, each) = (8, 400);
        let key = move |t: usize, i: usize| {
            DiskCache::key(
                "s3://b/s.zarr/0/c/0/0/0",
                "etag x",
                &(0..(t * each + i) as u64),
            )
        };
        let cache = DiskCache::new(dir.path(), MIN_MIB).expect("a cache");
        std::thread::scope(|scope| {
            for t in 0..threads {
                let (cache, key) = (&cache, &key);
                scope.spawn(move || {
                    for i in 0..each {
                        cache.keep(key(t, i), &Bytes::from(vec![t as u8; 1500 + i]));
                    }
                });
            }
        });
        cache.close();
        drop(cache);

        let cache = DiskCache::new(dir.path(), MIN_MIB).expect("the cache again");
        let keys: Vec<(usize, usize)> = (0..threads)
            .flat_map(|t| (0..each).map(move |i| (t, i)))
            .collect();
        let found = super::super::remote::run(async move {
            let mut found = 0;
            for (t, i) in keys {
                if let Some(bytes) = cache.read(&key(t, i)).await {
                    assert_eq!(bytes.len(), 1500 + i);
                    assert!(bytes.iter().all(|&b| b == t as u8));
                    found += 1;
                }
            }
            found
        })
        .expect("the I/O runtime");
        assert_eq!(found, threads * each, "ranges answered after the reopening");
    }
}
