//! Nothing lost, nothing invented: a store knows which files it must hold. A
//! deleted shard is an error naming it (never air), a changed file is caught by
//! `verify` and changed metadata when the store opens, and `--force`
//! replaces only a brick store, atomically.

use std::path::{Path, PathBuf};

use blocks::cache::BlockCache;
use blocks::ingest::{VolumeInfo, VolumeSource};
use blocks::store::{self, IngestOptions, Store};
use blocks::{Error, VoxelData};

mod common;
use common::{Memory, noise_u16, reseal};

/// A 40 × 40 × 150 store: two level-0 shards along z (the second 22 slices deep).
fn two_shard_store(dir: &Path) -> (PathBuf, Memory) {
    let dims = [40, 40, 150];
    let mut source = Memory::new(dims, noise_u16(dims));
    let out = dir.join("scan.zarr");
    store::ingest(&mut source, &out, &IngestOptions::default(), &mut |_| {}).expect("ingest");
    (out, source)
}

fn force() -> IngestOptions {
    IngestOptions {
        overwrite: true,
        ..IngestOptions::default()
    }
}

#[test]
fn a_missing_shard_is_an_error_naming_it_when_opening_and_reading_never_air() {
    let dir = tempfile::tempdir().expect("temp");
    let (out, source) = two_shard_store(dir.path());
    let store = Store::open(&out).expect("opens");
    // Intact, a block of the second shard reads as written.
    let block = store.read_block(0, [0, 0, 8]).expect("reads");
    assert_eq!(block.get(0), source.at(0, 0, 128));

    let shard = out.join("0/c/1/0/0");
    std::fs::remove_file(&shard).expect("delete the shard");
    // Opening names it.
    let err = Store::open(&out).expect_err("a shard is missing");
    assert!(matches!(err, Error::Missing { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.starts_with(&format!("{}: missing: ", shard.display()))
            && msg.contains("unknown, not empty"),
        "{msg}"
    );
    // A store opened before the deletion: reading its blocks names the shard,
    // through the cache too; blocks of the other shard still read.
    let err = store.read_block(0, [0, 0, 8]).expect_err("missing");
    assert!(matches!(err, Error::Missing { .. }), "{err}");
    assert!(err.to_string().contains("0/c/1/0/0"), "{err}");
    let cache = BlockCache::new(std::sync::Arc::new(store), 1 << 20);
    let err = cache
        .block(0, [1, 1, 9])
        .expect_err("missing through the cache");
    assert!(err.to_string().contains("0/c/1/0/0: missing"), "{err}");
    cache
        .block(0, [1, 1, 1])
        .expect("the first shard still reads");

    // All of level 0 gone: the message counts the rest.
    std::fs::remove_dir_all(out.join("0/c")).expect("delete level 0");
    let msg = Store::open(&out).expect_err("level 0 is gone").to_string();
    assert!(
        msg.contains("missing") && msg.contains("0/c/0/0/0"),
        "{msg}"
    );
}

#[test]
fn a_shard_zarrs_left_out_because_all_its_voxels_are_zero_reads_as_zero() {
    let dir = tempfile::tempdir().expect("temp");
    // Data up to z = 127, zeros beyond: the second level-0 shard holds only 0.
    let dims = [20, 20, 140];
    let slice = 20 * 20;
    let voxels: Vec<u16> = (0..dims.iter().product::<u32>() as usize)
        .map(|i| {
            if i < 128 * slice {
                1 + (i % 97) as u16
            } else {
                0
            }
        })
        .collect();
    let mut source = Memory::new(dims, VoxelData::U16(voxels));
    let out = dir.path().join("zeros.zarr");
    store::ingest(&mut source, &out, &IngestOptions::default(), &mut |_| {}).expect("ingest");
    assert!(!out.join("0/c/1/0/0").exists(), "zarrs left the shard out");
    let store = Store::open(&out).expect("opens: the statistics say the shard is all 0");
    let block = store.read_block(0, [0, 0, 8]).expect("reads");
    assert_eq!((block.get(0), source.at(0, 0, 128)), (0.0, 0.0));

    // A manifest that lost a shard the statistics say holds data is damage.
    let manifest_path = out.join(store::manifest::MANIFEST_KEY);
    let mut manifest = store::Manifest::read(&out).expect("manifest");
    manifest.files.remove("0/c/0/0/0");
    std::fs::remove_file(out.join("0/c/0/0/0")).expect("delete");
    manifest.write(&out).expect("write");
    let msg = Store::open(&out).expect_err("damaged").to_string();
    assert!(
        msg.contains("0/c/0/0/0: missing: the block statistics say this shard holds data"),
        "{msg}"
    );
    assert!(manifest_path.is_file());
}

#[test]
fn verify_finds_a_deleted_shard_a_flipped_byte_anywhere_and_changed_metadata() {
    let dir = tempfile::tempdir().expect("temp");
    let (out, _) = two_shard_store(dir.path());
    let intact = store::verify(&out).expect("verify");
    assert!(intact.problems.is_empty(), "{:?}", intact.problems);
    assert!(intact.files > 10 && intact.bytes > 0, "{intact:?}");

    // A flipped byte in every shard file, one at a time (data and index).
    let shards: Vec<String> = store::Manifest::read(&out)
        .expect("manifest")
        .files
        .keys()
        .filter(|k| k.contains("/c/"))
        .cloned()
        .collect();
    assert!(shards.len() >= 7, "{shards:?}");
    for key in &shards {
        let path = out.join(key);
        let original = std::fs::read(&path).expect("read");
        for at in [0, original.len() / 2, original.len() - 1] {
            let mut bytes = original.clone();
            bytes[at] ^= 0x01;
            std::fs::write(&path, &bytes).expect("write");
            let report = store::verify(&out).expect("verify");
            assert_eq!(report.problems.len(), 1, "{key} byte {at}");
            assert_eq!(report.problems[0].path, path);
            assert!(report.problems[0].what.contains("SHA-256"), "{key}");
        }
        std::fs::write(&path, &original).expect("restore");
    }

    // zarr.json's spacing 1 → 7 (same length): verify and open both catch it.
    let root = out.join("zarr.json");
    let text = std::fs::read_to_string(&root).expect("read");
    let changed = text.replacen("0.75", "7.75", 1);
    assert_ne!(changed, text);
    std::fs::write(&root, changed.replacen(' ', "", 1)).expect("write");
    let report = store::verify(&out).expect("verify");
    assert_eq!(report.problems.len(), 1, "{:?}", report.problems);
    assert_eq!(report.problems[0].path, root);
    let err = Store::open(&out).expect_err("changed metadata");
    assert!(matches!(err, Error::Corrupt { .. }), "{err}");
    assert!(err.to_string().contains("zarr.json"), "{err}");
    std::fs::write(&root, text).expect("restore");

    // A deleted shard, and a file no ingest wrote.
    std::fs::remove_file(out.join(&shards[0])).expect("delete");
    std::fs::write(out.join("0/c/9"), b"stray").expect("stray");
    let report = store::verify(&out).expect("verify");
    let found: Vec<String> = report.problems.iter().map(ToString::to_string).collect();
    assert_eq!(found.len(), 2, "{found:?}");
    assert!(
        found
            .iter()
            .any(|p| p.contains(&shards[0]) && p.contains("missing")),
        "{found:?}"
    );
    assert!(
        found
            .iter()
            .any(|p| p.contains("0/c/9: not in the manifest")),
        "{found:?}"
    );
}

#[test]
fn a_hostile_manifest_is_refused_naming_the_field() {
    let dir = tempfile::tempdir().expect("temp");
    let (out, _) = two_shard_store(dir.path());
    let path = out.join(store::manifest::MANIFEST_KEY);
    let good = std::fs::read_to_string(&path).expect("read");
    let cases = [
        (
            good.replacen("\"0/c/0/0/0\"", "\"../../etc/passwd\"", 1),
            "expected a relative path inside the store",
        ),
        (
            good.replacen("\"sha256\"", "\"md5\"", 1),
            "algorithm: 'md5': expected sha256",
        ),
        ("{".to_owned(), "manifest: EOF"),
        ("7".to_owned(), "manifest: invalid type"),
    ];
    for (text, expected) in cases {
        std::fs::write(&path, &text).expect("write");
        let msg = Store::open(&out).expect_err("hostile").to_string();
        assert!(msg.contains(expected), "{expected}: {msg}");
        let msg = store::verify(&out).expect_err("hostile").to_string();
        assert!(msg.contains(expected), "{expected}: {msg}");
    }
    std::fs::remove_file(&path).expect("rm");
    let msg = Store::open(&out).expect_err("no manifest").to_string();
    assert!(msg.contains("manifest: missing"), "{msg}");
    std::fs::write(&path, good).expect("restore");
    reseal(&out);
    Store::open(&out).expect("opens again");
}

#[test]
fn force_replaces_only_a_brick_store_and_a_new_path_is_never_taken_twice() {
    let dir = tempfile::tempdir().expect("temp");
    let dims = [16, 16, 16];
    let mut source = Memory::new(dims, noise_u16(dims));
    // A folder of other files, and a file: kept, with and without --force.
    let folder = dir.path().join("papers");
    std::fs::create_dir(&folder).expect("mkdir");
    std::fs::write(folder.join("notes.txt"), b"keep me").expect("write");
    let file = dir.path().join("scan.txt");
    std::fs::write(&file, b"keep me too").expect("write");
    for target in [&folder, &file] {
        for options in [IngestOptions::default(), force()] {
            let msg = store::ingest(&mut source, target, &options, &mut |_| {})
                .expect_err("refused")
                .to_string();
            let expected = if options.overwrite {
                "exists and is not a voxserve brick store: --force replaces only a store"
            } else {
                "exists: expected a new path"
            };
            assert!(msg.contains(expected), "{msg}");
        }
    }
    assert_eq!(
        std::fs::read(folder.join("notes.txt")).expect("kept"),
        b"keep me"
    );
    assert_eq!(std::fs::read(&file).expect("kept"), b"keep me too");

    // A path that was free at the start but taken when the ingest finishes.
    let out = dir.path().join("race.zarr");
    let mut racing = Racing {
        inner: Memory::new(dims, noise_u16(dims)),
        take: out.clone(),
    };
    let msg = store::ingest(&mut racing, &out, &IngestOptions::default(), &mut |_| {})
        .expect_err("taken meanwhile")
        .to_string();
    assert!(msg.contains("another ingest finished there first"), "{msg}");
    assert!(
        out.join("other.txt").is_file(),
        "what took the path is kept"
    );
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .expect("dir")
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    assert!(left.is_empty(), "no temporary folder left: {left:?}");
}

/// A source that creates its destination while it is read, as a second ingest
/// to the same path finishing first would.
#[derive(Debug)]
struct Racing {
    inner: Memory,
    take: PathBuf,
}

impl VolumeSource for Racing {
    fn info(&self) -> &VolumeInfo {
        self.inner.info()
    }

    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<VoxelData, Error> {
        if !self.take.exists() {
            std::fs::create_dir(&self.take).expect("mkdir");
            std::fs::write(self.take.join("other.txt"), b"first").expect("write");
        }
        self.inner.read_slab(z0, depth)
    }
}

#[test]
fn leftovers_of_interrupted_ingests_are_recognised_by_name() {
    use store::ingest::leftover_of;
    assert_eq!(
        leftover_of(".scan.zarr.partial-123"),
        Some(("scan.zarr", 123))
    );
    assert_eq!(leftover_of(".scan.zarr.old-7"), Some(("scan.zarr", 7)));
    assert_eq!(leftover_of(".a.old-b.partial-9"), Some(("a.old-b", 9)));
    for other in ["scan.zarr", ".hidden", ".scan.partial-x", "scan.partial-1"] {
        assert_eq!(leftover_of(other), None, "{other}");
    }
}
