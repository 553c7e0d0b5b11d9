//! The brick store on generated volumes: exact round trips at every level for
//! sizes that are not multiples of 16, crash safety, corruption detection, the
//! block cache and its aprons, LOD selection on real statistics, and root
//! metadata that stores written by earlier code still read.

use std::path::Path;
use std::sync::Arc;

use blocks::cache::BlockCache;
use blocks::ingest;
use blocks::lod::Budget;
use blocks::store::{self, BLOCK, IngestOptions, LEVELS, Store, level_dims, pyramid};
use blocks::{Error, Geometry, Preset, VoxelData, VoxelType};

mod common;
use common::{Memory, noise_u16, reseal};

fn ingest_to(dir: &Path, source: &mut Memory) -> Result<Store, Error> {
    let out = dir.join("store");
    store::ingest(source, &out, &IngestOptions::default(), &mut |_| {})?;
    Store::open(&out)
}

/// Level `level` of `source` at level-l voxel (x, y, z), as the store should
/// hold it ([`pyramid::volume_level`] over the source's stored range).
fn level_value(source: &Memory, level: usize, x: u32, y: u32, z: u32) -> f64 {
    let dims = source.info.geometry.dims;
    let range = source.voxels.stored_range().expect("values");
    let l = pyramid::volume_level(&source.voxels, dims, range, level);
    let ld = level_dims(dims, level);
    l.get(((z * ld[1] + y) * ld[0] + x) as usize)
}

#[test]
fn every_block_at_every_level_round_trips_for_odd_sizes() {
    let dir = tempfile::tempdir().expect("temp");
    let dims = [37, 50, 21];
    let mut source = Memory::new(dims, noise_u16(dims));
    let store = ingest_to(dir.path(), &mut source).expect("ingest");
    assert_eq!(store.meta().geometry.dims, dims);
    assert_eq!(store.meta().blocks, [3, 4, 2]);
    assert_eq!(store.meta().value_map.intercept, -1024.0);
    for level in 0..LEVELS {
        let ld = level_dims(dims, level);
        let edge = BLOCK >> level;
        for bz in 0..2 {
            for by in 0..4 {
                for bx in 0..3 {
                    let block = store.read_block(level, [bx, by, bz]).expect("block");
                    for z in 0..edge {
                        for y in 0..edge {
                            for x in 0..edge {
                                let p = [bx * edge + x, by * edge + y, bz * edge + z];
                                let got = block.get(((z * edge + y) * edge + x) as usize);
                                let want = if (0..3).all(|a| p[a] < ld[a]) {
                                    level_value(&source, level, p[0], p[1], p[2])
                                } else {
                                    0.0
                                };
                                assert_eq!(
                                    got,
                                    want,
                                    "level {level} block {:?} voxel {p:?}",
                                    [bx, by, bz]
                                );
                            }
                        }
                    }
                }
            }
        }
    }
    // Block statistics agree with the voxels.
    let s = store.stats();
    for b in 0..s.block_count() {
        let pos = s.block_position(b);
        let block = store.read_block(0, pos).expect("block");
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for z in 0..16 {
            for y in 0..16 {
                for x in 0..16 {
                    let p = [pos[0] * 16 + x, pos[1] * 16 + y, pos[2] * 16 + z];
                    if (0..3).all(|a| p[a] < dims[a]) {
                        let v = block.get(((z * 16 + y) * 16 + x) as usize);
                        lo = lo.min(v);
                        hi = hi.max(v);
                    }
                }
            }
        }
        assert_eq!(s.min_max(0, b), [lo, hi], "block {pos:?}");
        let counted: u32 = s
            .histogram(0, b)
            .expect("level 0")
            .iter()
            .map(|&c| u32::from(c))
            .sum();
        let inside: u32 = (0..3).map(|a| (dims[a] - pos[a] * 16).min(16)).product();
        assert_eq!(counted, inside);
    }
}

#[test]
fn signed_and_float_volumes_round_trip() {
    let dir = tempfile::tempdir().expect("temp");
    let dims = [20, 17, 33];
    let n = dims.iter().product::<u32>() as i32;
    let mut source = Memory::new(
        dims,
        VoxelData::I16((0..n).map(|i| ((i * 7919) % 3000 - 1500) as i16).collect()),
    );
    let store = ingest_to(dir.path(), &mut source).expect("ingest i16");
    assert_eq!(store.voxel_type(), VoxelType::I16);
    let b = store.read_block(0, [1, 1, 2]).expect("block");
    assert_eq!(b.get(0), source.at(16, 16, 32));
    assert_eq!(
        store.read_block(2, [0, 0, 0]).expect("level 2").get(0),
        level_value(&source, 2, 0, 0, 0)
    );

    let dir = tempfile::tempdir().expect("temp");
    let mut source = Memory::new(
        dims,
        VoxelData::F32(
            (0..n)
                .map(|i| {
                    if i % 97 == 0 {
                        f32::NAN
                    } else {
                        i as f32 * 0.25
                    }
                })
                .collect(),
        ),
    );
    let store = ingest_to(dir.path(), &mut source).expect("ingest f32");
    let b = store.read_block(0, [0, 0, 0]).expect("block");
    assert!(b.get(0).is_nan());
    assert_eq!(b.get(1), 0.25);
    assert!(
        !store.meta().stored_range[0].is_nan(),
        "NaNs stay out of the range"
    );
}

#[test]
fn an_interrupted_ingest_leaves_no_store() {
    let dir = tempfile::tempdir().expect("temp");
    let dims = [40, 40, 60];
    let mut source = Memory::new(dims, noise_u16(dims));
    source.fail_at_slab = Some(2);
    let out = dir.path().join("store");
    let err = store::ingest(&mut source, &out, &IngestOptions::default(), &mut |_| {})
        .expect_err("fails");
    assert!(err.to_string().contains("injected failure"), "{err}");
    assert!(!out.exists(), "no store at the destination");
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).expect("dir").collect();
    assert!(
        leftovers.is_empty(),
        "the temporary folder is removed: {leftovers:?}"
    );
    assert!(Store::open(&out).is_err());
}

#[test]
fn an_existing_store_is_kept_unless_replaced() {
    let dir = tempfile::tempdir().expect("temp");
    let dims = [16, 16, 16];
    let mut source = Memory::new(dims, noise_u16(dims));
    let out = dir.path().join("store");
    store::ingest(&mut source, &out, &IngestOptions::default(), &mut |_| {}).expect("first");
    let err = store::ingest(&mut source, &out, &IngestOptions::default(), &mut |_| {})
        .expect_err("exists");
    assert!(
        err.to_string()
            .contains("exists: expected a new path (or --force"),
        "{err}"
    );
    let replace = IngestOptions {
        overwrite: true,
        ..IngestOptions::default()
    };
    store::ingest(&mut source, &out, &replace, &mut |_| {}).expect("replaced");
    Store::open(&out).expect("the new store opens");
    assert_eq!(
        std::fs::read_dir(dir.path()).expect("dir").count(),
        1,
        "no old or temporary folders left"
    );
}

#[test]
fn folders_that_are_not_complete_stores_are_refused() {
    let dir = tempfile::tempdir().expect("temp");
    let partial = dir.path().join(".scan.partial-123");
    std::fs::create_dir(&partial).expect("mkdir");
    let msg = Store::open(&partial).expect_err("partial").to_string();
    assert!(msg.contains("did not finish"), "{msg}");
    let dims = [16, 16, 16];
    let mut source = Memory::new(dims, noise_u16(dims));
    let store = ingest_to(dir.path(), &mut source).expect("ingest");
    let folder = store.location().file("");
    let root = store.location().file("zarr.json");
    let text = std::fs::read_to_string(&root).expect("read");
    std::fs::write(
        &root,
        text.replace("\"complete\": true", "\"complete\": false"),
    )
    .expect("write");
    reseal(&folder);
    let msg = Store::open(store.location().clone())
        .expect_err("incomplete")
        .to_string();
    assert!(msg.contains("complete: false"), "{msg}");
}

/// The `voxserve` record of `zarr.json` as stores wrote it before the
/// geometry became one type: the 100³ phantom ingested by that code, verbatim.
const PHANTOM_100_META_BEFORE_GEOMETRY: &str = r#"{"format_version":1,"complete":true,"name":"phantom","dims":[100,100,100],"voxel_type":"uint16","spacing":[2.4000000953674316,2.4000000953674316,2.4000000953674316],"origin":[-118.80000305175781,-118.80000305175781,-118.80000305175781],"direction":[[1.0,0.0,0.0],[0.0,1.0,0.0],[0.0,0.0,1.0]],"value_map":{"slope":1.0,"intercept":-1024.0},"unit":"HU","modality":"CT","description":null,"stored_range":[18.0,2030.0],"block_size":16,"levels":5,"histogram_bins":32,"blocks":[7,7,7],"source":"phantom","source_format":"raw","notes":[]}"#;

/// [`PHANTOM_100_META_BEFORE_GEOMETRY`], parsed.
fn old_meta() -> serde_json::Value {
    serde_json::from_str(PHANTOM_100_META_BEFORE_GEOMETRY).expect("valid JSON")
}

#[test]
fn metadata_written_before_the_geometry_type_reads_and_writes_back_unchanged() {
    let old = old_meta();
    let meta: store::StoreMeta = serde_json::from_value(old.clone()).expect("old metadata reads");
    let spacing = f64::from(blocks::phantom::EDGE_MM / 100.0);
    assert_eq!(
        meta.geometry,
        Geometry {
            dims: [100; 3],
            spacing: [spacing; 3],
            origin: [-118.80000305175781; 3],
            direction: blocks::geometry::IDENTITY_DIRECTION,
        }
    );
    assert_eq!(
        (meta.name.as_str(), meta.voxel_type.as_str()),
        ("phantom", "uint16")
    );
    assert_eq!(meta.blocks, [7; 3]);
    // Written again: the same keys, at the same level, with the same values.
    let again = serde_json::to_value(&meta).expect("serializes");
    let keys = |v: &serde_json::Value| {
        let mut k: Vec<String> = v.as_object().expect("an object").keys().cloned().collect();
        k.sort();
        k
    };
    assert_eq!(keys(&again), keys(&old));
    assert_eq!(again, old);
}

#[test]
fn a_new_store_writes_the_old_metadata_and_opens_with_it() {
    let dir = tempfile::tempdir().expect("temp");
    let path = dir.path().join("phantom.zarr");
    let volume = Arc::new(blocks::phantom::head(100).expect("phantom"));
    let mut source = ingest::MemorySource::new(volume, "phantom");
    store::ingest(&mut source, &path, &IngestOptions::default(), &mut |_| {}).expect("ingest");
    // What the old code reads: the same record it wrote itself, but for the
    // format version (2 since stores carry a manifest).
    let root = path.join("zarr.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&root).expect("read")).expect("JSON");
    let mut record = old_meta();
    record["format_version"] = store::FORMAT_VERSION.into();
    assert_eq!(json["attributes"]["voxserve"], record);
    // A store whose record the old code wrote opens (with the manifest made again
    // for the edited metadata).
    json["attributes"]["voxserve"] = record;
    std::fs::write(&root, json.to_string()).expect("write");
    reseal(&path);
    let store = Store::open(&path).expect("a store with the old record opens");
    assert_eq!(store.meta().geometry.dims, [100; 3]);
    // A store of format 1, without a manifest, is refused naming the format.
    json["attributes"]["voxserve"] = old_meta();
    std::fs::write(&root, json.to_string()).expect("write");
    std::fs::remove_file(path.join(store::manifest::MANIFEST_KEY)).expect("rm manifest");
    let msg = Store::open(&path).expect_err("format 1").to_string();
    assert!(
        msg.contains("format_version: 1: expected 2 (a store with a manifest of its files)"),
        "{msg}"
    );
    // Its geometry is checked on open, naming the key at fault.
    json["attributes"]["voxserve"] = old_meta();
    json["attributes"]["voxserve"]["format_version"] = store::FORMAT_VERSION.into();
    json["attributes"]["voxserve"]["spacing"] = serde_json::json!([2.4, 0.0, 2.4]);
    std::fs::write(&root, json.to_string()).expect("write");
    reseal(&path);
    let msg = Store::open(&path).expect_err("zero spacing").to_string();
    assert!(
        msg.contains("attributes.voxserve.spacing: [2.4, 0.0, 2.4]: expected finite positive"),
        "{msg}"
    );
}

#[test]
fn a_flipped_byte_in_a_shard_is_a_corruption_error_naming_the_shard() {
    let dir = tempfile::tempdir().expect("temp");
    let dims = [32, 32, 32];
    let mut source = Memory::new(dims, noise_u16(dims));
    let store = ingest_to(dir.path(), &mut source).expect("ingest");
    let shard = store.shard_path(0, [0, 0, 0]);
    let original = std::fs::read(&shard).expect("shard");
    // Bytes spread over the shard: inner chunks' data, and the index at the end.
    let positions: Vec<usize> = (1..8)
        .map(|i| original.len() * i / 8)
        .chain([original.len() - 10])
        .collect();
    for at in positions {
        let mut bytes = original.clone();
        bytes[at] ^= 0x5a;
        std::fs::write(&shard, &bytes).expect("write");
        let fresh = Store::open(store.location().clone()).expect("metadata is intact");
        // The flipped byte lies in one of the shard's eight level-0 blocks (or its index).
        let errors: Vec<Error> = (0..8u32)
            .filter_map(|i| fresh.read_block(0, [i % 2, (i / 2) % 2, i / 4]).err())
            .collect();
        assert!(
            !errors.is_empty(),
            "byte {at} of {}: no error",
            original.len()
        );
        for err in errors {
            let msg = err.to_string();
            assert!(matches!(err, Error::Corrupt { .. }), "byte {at}: {msg}");
            assert!(
                msg.contains(&shard.display().to_string()),
                "byte {at}: {msg}"
            );
        }
    }
    std::fs::write(&shard, &original).expect("restore");
}

#[test]
fn the_cache_serves_concurrent_readers_within_its_budget_and_aprons_copy_neighbours() {
    use rayon::prelude::*;
    let dir = tempfile::tempdir().expect("temp");
    let dims = [48, 40, 36];
    let mut source = Memory::new(dims, noise_u16(dims));
    let store = Arc::new(ingest_to(dir.path(), &mut source).expect("ingest"));
    let budget = 4 * 16 * 16 * 16 * 2; // four chunks
    let mut cache = BlockCache::new(store.clone(), budget);
    cache
        .make_resident(&blocks::cache::RESIDENT_LEVELS)
        .expect("resident");
    let keys: Vec<[u32; 3]> = (0..200)
        .map(|i| [i % 3, (i / 3) % 3, (i / 9) % 3])
        .collect();
    keys.par_iter().for_each(|&b| {
        let cached = cache.block(0, b).expect("cached");
        assert_eq!(cached, store.read_block(0, b).expect("direct"));
    });
    assert!(
        cache.cached_bytes() <= budget,
        "{} > {budget}",
        cache.cached_bytes()
    );

    // The apron of block (1, 0, 1) at level 1: neighbours' voxels, edges clamped.
    let a = cache.block_with_apron(1, [1, 0, 1], 1).expect("apron");
    let side = 8 + 2;
    assert_eq!(a.len(), side * side * side);
    let ld = level_dims(dims, 1);
    for (z, y, x) in [(0, 0, 0), (0, 5, 9), (9, 9, 9), (4, 0, 4)] {
        let p = [8 + x as i64 - 1, y as i64 - 1, 8 + z as i64 - 1];
        let c = [0, 1, 2].map(|i| p[i].clamp(0, i64::from(ld[i]) - 1) as u32);
        let want = level_value(&source, 1, c[0], c[1], c[2]);
        assert_eq!(
            a.get((z * side + y) * side + x),
            want,
            "apron voxel ({x}, {y}, {z}) → level-1 voxel {c:?}"
        );
    }
}

#[test]
fn lod_selection_on_stored_statistics_respects_budgets_and_skips_empty_blocks() {
    let dir = tempfile::tempdir().expect("temp");
    // A sphere of "bone" (2000) in "air" (0), 64³.
    let n = 64u32;
    let voxels = (0..n * n * n)
        .map(|i| {
            let p = [i % n, (i / n) % n, i / (n * n)].map(|c| c as f32 - 31.5);
            if (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() < 20.0 {
                3024u16
            } else {
                24
            }
        })
        .collect();
    let mut source = Memory::new([n; 3], VoxelData::U16(voxels));
    let store = ingest_to(dir.path(), &mut source).expect("ingest");
    let tf = Preset::CtBone.transfer_function(store.meta().value_range().map(|v| v as f32));
    let full = u64::from(n).pow(3);
    let map = store.meta().value_map;
    let sel = blocks::lod::select(store.stats(), map, &tf, full, Budget::reduction(1.0), None);
    // Blocks of pure air are empty; blocks touching the sphere are not.
    let air = store.stats().block_index([0, 0, 0]);
    let centre = store.stats().block_index([2, 2, 2]);
    assert_eq!(sel.lod[air], blocks::lod::EMPTY);
    assert_eq!(sel.lod[centre], 0, "unlimited budget: full resolution");
    for budget in [sel.non_empty as u64, full / 35, full / 9, full] {
        let s = blocks::lod::select(store.stats(), map, &tf, full, Budget::voxels(budget), None);
        assert!(s.kept_voxels <= budget, "{budget}: {}", s.kept_voxels);
        assert_eq!(s.lod[air], blocks::lod::EMPTY);
    }
}

/// A root whose voxel type is not its arrays' (a hand-edited `zarr.json`):
/// chunks would decode to another number of voxels, so the store is refused
/// when it opens, naming the array and the field (found by fuzzing, where it
/// panicked reading a block).
#[test]
fn a_root_voxel_type_other_than_the_arrays_is_refused_naming_the_array() {
    let dir = tempfile::tempdir().expect("temp");
    let dims = [20, 20, 20];
    let mut source = Memory::new(dims, noise_u16(dims));
    let store = ingest_to(dir.path(), &mut source).expect("ingest");
    let folder = store.location().file("");
    let root = store.location().file("zarr.json");
    let text = std::fs::read_to_string(&root).expect("read");
    for other in ["uint32", "uint8", "float32"] {
        let changed = text.replace("\"uint16\"", &format!("\"{other}\""));
        assert_ne!(changed, text);
        std::fs::write(&root, changed).expect("write");
        reseal(&folder);
        let msg = Store::open(store.location().clone())
            .expect_err("voxel type unlike the arrays'")
            .to_string();
        assert!(
            msg.contains("0/zarr.json") && msg.contains("data_type") && msg.contains(other),
            "{msg}"
        );
    }
}
