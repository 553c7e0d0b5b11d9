//! What the fuzz targets share: reading a file the way `voxserve info` and
//! `ingest` do, from bytes the fuzzer made, and a dataset to check views against.

use std::path::Path;
use std::sync::{Once, OnceLock};

use blocks::ingest::{self, OpenOptions};

/// At most this many slabs of 16 slices are read per input (the header and
/// the first slabs are where sizes are derived and checked).
const SLABS: u32 = 2;

/// Replaces libFuzzer's panic hook (which aborts on every panic) with one
/// that lets a panic inside a crates.io dependency unwind to voxserve's
/// decoder boundary (`blocks::ingest::boundary`), which turns it into an error
/// naming the file, as in the binary; a panic anywhere else, or one that
/// escapes the boundary (the fuzz target catches it and aborts), is a finding.
fn let_the_boundary_catch_dependency_panics() {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let fuzzer_hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let in_dependency = info
                .location()
                .is_some_and(|l| l.file().contains("/registry/src/"));
            if !in_dependency {
                fuzzer_hook(info);
            }
        }));
    });
}

/// Writes `bytes` as `name` into a fresh folder and reads it as a volume.
pub fn read_file(name: &str, bytes: &[u8]) {
    let dir = tempfile::tempdir().expect("temp folder");
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).expect("write input");
    read_volume(&path);
}

/// Splits `data` at a `#DATA#` line into a detached header, written as
/// `header_name`, and its data file `volume.raw` in the same folder, and reads
/// the header as a volume.
pub fn read_detached(header_name: &str, data: &[u8]) {
    let parts = split(data, b"\n#DATA#\n", 2);
    let dir = tempfile::tempdir().expect("temp");
    std::fs::write(
        dir.path().join("volume.raw"),
        parts.get(1).copied().unwrap_or(&[]),
    )
    .expect("data");
    let header = dir.path().join(header_name);
    std::fs::write(&header, parts[0]).expect("header");
    read_volume(&header);
}

/// Opens `path` (a file or a DICOM folder) and reads its first slabs; every
/// error is an answer, a panic, a hang or a huge allocation is a finding.
pub fn read_volume(path: &Path) {
    let_the_boundary_catch_dependency_panics();
    let Ok(mut source) = ingest::open(path, &OpenOptions::default()) else {
        return;
    };
    let nz = source.info().geometry.dims[2];
    for slab in 0..SLABS {
        let z0 = slab * 16;
        if z0 >= nz {
            break;
        }
        if source.read_slab(z0, 16.min(nz - z0)).is_err() {
            break;
        }
    }
}

/// Splits `data` at each `sep` into at most `max` parts.
pub fn split<'a>(data: &'a [u8], sep: &[u8], max: usize) -> Vec<&'a [u8]> {
    let mut parts = Vec::new();
    let mut rest = data;
    while parts.len() + 1 < max {
        match rest.windows(sep.len()).position(|w| w == sep) {
            Some(i) => {
                parts.push(&rest[..i]);
                rest = &rest[i + sep.len()..];
            }
            None => break,
        }
    }
    parts.push(rest);
    parts
}

/// The 16³ phantom as a dataset, made once.
pub fn datasets() -> &'static [server::Dataset] {
    static DATASETS: OnceLock<Vec<server::Dataset>> = OnceLock::new();
    DATASETS.get_or_init(|| vec![server::Dataset::phantom(16, 16 << 20).expect("phantom")])
}
