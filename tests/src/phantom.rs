//! The phantom at the sizes tests use, generated once per test binary.

use std::sync::OnceLock;

use blocks::Volume;
use server::Dataset;

/// The edge length GPU tests use: 64³ keeps a software frame well under a second.
pub const TEST_SIZE: u32 = 64;

/// Decoded blocks a test dataset may cache.
pub const TEST_CACHE_BYTES: u64 = 256 << 20;

/// The head phantom at [`TEST_SIZE`]³.
pub fn phantom_64() -> &'static Volume {
    static PHANTOM: OnceLock<Volume> = OnceLock::new();
    PHANTOM
        .get_or_init(|| blocks::phantom::head(TEST_SIZE).unwrap_or_else(|e| panic!("phantom: {e}")))
}

/// The head phantom at [`TEST_SIZE`]³ as the server holds it: bricked into a
/// store in memory, read through a block cache.
pub fn phantom_64_dataset() -> &'static Dataset {
    static DATASET: OnceLock<Dataset> = OnceLock::new();
    DATASET.get_or_init(|| {
        Dataset::phantom(TEST_SIZE, TEST_CACHE_BYTES)
            .unwrap_or_else(|e| panic!("phantom dataset: {e}"))
    })
}

/// The head phantom at [`TEST_SIZE`]³ ingested into a store in `dir` and
/// opened as a server opens one at start: a cold cache, only the two coarsest
/// levels in memory.
///
/// # Panics
/// When ingesting or opening fails.
pub fn phantom_64_on_disk(dir: &std::path::Path) -> Dataset {
    let volume = std::sync::Arc::new(phantom_64().clone());
    let mut source = blocks::ingest::MemorySource::new(volume, "cold phantom");
    let path = dir.join("cold.zarr");
    let options = blocks::store::IngestOptions::default();
    blocks::store::ingest(&mut source, &path, &options, &mut |_| {})
        .unwrap_or_else(|e| panic!("ingest: {e}"));
    Dataset::load(&path, &Default::default(), TEST_CACHE_BYTES)
        .unwrap_or_else(|e| panic!("opening the store: {e}"))
}
