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
