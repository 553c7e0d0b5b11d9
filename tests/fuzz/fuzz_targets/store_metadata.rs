//! A brick store's metadata: the root `zarr.json` (the input) of a small real
//! store, with the manifest made for it so that opening reaches every check
//! behind the checksums; then a block is read.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

/// A 20 × 20 × 20 store ingested once; each input runs on a copy.
fn template() -> &'static PathBuf {
    static TEMPLATE: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &TEMPLATE
        .get_or_init(|| {
            let dir = tempfile::tempdir().expect("temp");
            let volume = std::sync::Arc::new(blocks::phantom::head(20).expect("phantom"));
            let mut source = blocks::ingest::MemorySource::new(volume, "phantom");
            let path = dir.path().join("store");
            blocks::store::ingest(&mut source, &path, &Default::default(), &mut |_| {})
                .expect("ingest");
            (dir, path)
        })
        .1
}

fn copy(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("read_dir").flatten() {
        let target = to.join(entry.file_name());
        if entry.file_type().expect("type").is_dir() {
            copy(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).expect("copy");
        }
    }
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let dir = tempfile::tempdir().expect("temp");
    let store = dir.path().join("store");
    copy(template(), &store);
    std::fs::write(store.join("zarr.json"), data).expect("write");
    let manifest = blocks::store::Manifest::of_folder(&store).expect("manifest");
    manifest.write(&store).expect("write manifest");
    if let Ok(opened) = blocks::store::Store::open(&store) {
        let _ = opened.read_block(0, [0, 0, 0]);
        let _ = opened.meta().value_range();
    }
});
