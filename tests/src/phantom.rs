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

/// A bright ball (250 of 8 bits) of radius 7 voxels inside the one block
/// (2, 1, 2) of a dark 64³ cube of 1 mm voxels: far from the cube's centre,
/// a small share of its box (what fitting the camera is tested on).
pub fn ball_off_centre() -> Volume {
    let n = 64u32;
    let centre = [40.0f32, 24.0, 40.0];
    let voxels = (0..n * n * n)
        .map(|i| {
            let p = [i % n, (i / n) % n, i / (n * n)];
            let r = (0..3)
                .map(|a| (p[a] as f32 + 0.5 - centre[a]).powi(2))
                .sum::<f32>()
                .sqrt();
            if r < 7.0 { 250 } else { 0 }
        })
        .collect();
    Volume::new(
        "ball",
        blocks::Geometry::new([n, n, n], [1.0, 1.0, 1.0]),
        blocks::VoxelData::U8(voxels),
        blocks::ValueMap::IDENTITY,
    )
    .unwrap_or_else(|e| panic!("the ball volume: {e}"))
}
