//! `voxserve bench blocks`: the brick store on a generated CT-like volume
//! (ingest, random block reads) and LOD selection on it, on the 512³ phantom and
//! on the engine and CT head when the datasets are there.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use blocks::lod::Budget;
use blocks::store::{IngestOptions, Store};
use blocks::{Preset, TfPoint, TransferFunction, ingest};

use super::args::BenchBlocksArgs;
use super::reference_data::reference_dataset;
use super::{Scratch, peak_rss_mib, write_uint16_raw};
use server::commands::say;

/// `voxserve bench blocks`: ingest, random block reads and LOD selection.
pub fn blocks(args: &BenchBlocksArgs) -> anyhow::Result<()> {
    let scratch = Scratch::new("blocks")?;
    let store_path = ingest_generated(&scratch.0, args.gib)?;
    let store = block_reads(&store_path, args)?;
    // LOD selection: on the generated volume, on the 512³ phantom (32 768
    // blocks), and on the engine and CT head when the datasets are there.
    let bone_raw = TransferFunction::new(vec![
        TfPoint::new(1100.0, [0.9, 0.8, 0.7], 0.0),
        TfPoint::new(1500.0, [0.9, 0.8, 0.7], 0.3),
        TfPoint::new(2000.0, [1.0, 1.0, 1.0], 0.9),
    ])?;
    report_selections("generated CT-like", &store, &bone_raw)?;
    phantom_selections(&scratch.0)?;
    dataset_selections(&scratch.0, &args.data)
}

/// An `ingest` line: a generated CT-like volume of `gib` GiB written as a raw
/// file in `dir` and ingested into a brick store there; returns the store's path.
fn ingest_generated(dir: &Path, gib: f32) -> anyhow::Result<PathBuf> {
    let raw = write_ct_like(dir, gib)?;
    let mut source = ingest::open(&raw, &ingest::OpenOptions::default())?;
    let store_path = dir.join("generated");
    let summary = blocks::store::ingest(
        source.as_mut(),
        &store_path,
        &IngestOptions::default(),
        &mut |_| {},
    )?;
    drop(source);
    std::fs::remove_file(&raw)?;
    say(&serde_json::json!({
        "bench": "ingest",
        "source": "generated CT-like raw",
        "dims": summary.dims,
        "voxel_type": summary.voxel_type.name(),
        "source_bytes": summary.source_bytes,
        "store_bytes": summary.store_bytes,
        "compression": summary.compression_ratio(),
        "scan_seconds": summary.scan_seconds,
        "seconds": summary.seconds,
        "mb_per_s": summary.mb_per_s(),
        "peak_rss_mib": peak_rss_mib(),
        "threads": rayon::current_num_threads(),
        "zstd_level": IngestOptions::default().zstd_level,
    })
    .to_string())?;
    Ok(store_path)
}

/// `block_reads` lines: random level-0 block reads from a fresh store (shard
/// indexes read as met), the same blocks again (indexes cached, chunks
/// decoded), and from a cache; returns the store.
fn block_reads(store_path: &Path, args: &BenchBlocksArgs) -> anyhow::Result<Arc<Store>> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads as usize)
        .build()?;
    let fresh = Store::open(store_path)?;
    let keys = random_blocks(fresh.meta().blocks, args.reads);
    let cold = reads_per_second(&pool, &keys, |b| fresh.read_block(0, b))?;
    let warm = reads_per_second(&pool, &keys, |b| fresh.read_block(0, b))?;
    let store = Arc::new(fresh);
    let chunk_bytes = 16 * 16 * 16 * store.voxel_type().size() as u64;
    let cache =
        blocks::cache::BlockCache::new(store.clone(), u64::from(args.reads) * chunk_bytes * 2);
    reads_per_second(&pool, &keys, |b| cache.block(0, b))?;
    let cached = reads_per_second(&pool, &keys, |b| cache.block(0, b))?;
    for (mode, per_s, what) in [
        (
            "cold",
            cold,
            "new store handle: shard index and chunk read and decoded (OS page cache not dropped)",
        ),
        (
            "warm",
            warm,
            "shard indexes cached, chunk read and zstd-decoded",
        ),
        ("cached", cached, "BlockCache hit"),
    ] {
        say(&serde_json::json!({
            "bench": "block_reads",
            "mode": mode,
            "what": what,
            "level": 0,
            "reads": args.reads,
            "threads": args.threads,
            "dims": store.meta().geometry.dims,
            "per_s": per_s,
        })
        .to_string())?;
    }
    Ok(store)
}

/// `lod_selection` lines of the 512³ phantom (32 768 blocks), ingested in `dir`.
fn phantom_selections(dir: &Path) -> anyhow::Result<()> {
    let phantom = Arc::new(blocks::phantom::head(512)?);
    let mut source = ingest::MemorySource::new(phantom.clone(), "phantom-512");
    let phantom_path = dir.join("phantom");
    blocks::store::ingest(
        &mut source,
        &phantom_path,
        &IngestOptions::default(),
        &mut |_| {},
    )?;
    let tf = Preset::CtBone.transfer_function(phantom.value_range);
    report_selections("phantom 512³", &Store::open(&phantom_path)?, &tf)
}

/// `lod_selection` lines of the engine and the CT head from the data folder
/// `data` (read and classified as [`reference_dataset`] says), ingested in
/// `dir`; a dataset that is missing is skipped with a warning.
fn dataset_selections(dir: &Path, data: &Path) -> anyhow::Result<()> {
    for name in ["engine", "cthead"] {
        let Some(dataset) = reference_dataset(data, name) else {
            anyhow::bail!("no reference dataset is named {name}");
        };
        if !dataset.path.exists() {
            tracing::warn!(
                "{} not found: skipping the {name} selection",
                dataset.path.display()
            );
            continue;
        }
        let mut source = ingest::open(&dataset.path, &dataset.options)?;
        let out = dir.join(name);
        blocks::store::ingest(
            source.as_mut(),
            &out,
            &IngestOptions::default(),
            &mut |_| {},
        )?;
        report_selections(name, &Store::open(&out)?, &dataset.transfer_function)?;
    }
    Ok(())
}

/// Writes a CT-like uint16 volume of about `gib` GiB (1024² slices, stored =
/// HU + 1024): air with noise around an elliptic body of soft tissue inside a
/// bone shell, so it compresses like a scan, not like a pattern.
fn write_ct_like(dir: &Path, gib: f32) -> anyhow::Result<PathBuf> {
    const N: u32 = 1024;
    let slice_bytes = u64::from(N) * u64::from(N) * 2;
    let nz = ((f64::from(gib) * f64::from(1u32 << 30)) / slice_bytes as f64)
        .ceil()
        .max(1.0) as u32;
    let path = dir.join(format!("ct_{N}x{N}x{nz}_uint16.raw"));
    write_uint16_raw(&path, [N, N, nz], |x, y, z| {
        let t = f64::from(z) / f64::from(nz.max(2) - 1);
        let (a, b) = (0.35 + 0.08 * (t * std::f64::consts::PI).sin(), 0.42);
        let u = (f64::from(x) / f64::from(N) - 0.5) / a;
        let v = (f64::from(y) / f64::from(N) - 0.5) / b;
        let r = (u * u + v * v).sqrt();
        let hu = if r < 0.88 {
            40.0
        } else if r < 0.95 {
            1000.0
        } else if r < 1.0 {
            0.0
        } else {
            -1000.0
        };
        let h = (u64::from(x) << 40 ^ u64::from(y) << 20 ^ u64::from(z))
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            >> 58;
        (hu + 1024.0 + h as f64 - 32.0).clamp(0.0, 65535.0) as u16
    })?;
    Ok(path)
}

/// Random level-0 block positions in `grid` (a fixed-seed LCG, so runs compare).
fn random_blocks(grid: [u32; 3], n: u32) -> Vec<[u32; 3]> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    (0..n)
        .map(|_| {
            let mut next = |m: u32| {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                ((state >> 33) % u64::from(m)) as u32
            };
            [next(grid[0]), next(grid[1]), next(grid[2])]
        })
        .collect()
}

/// Times `f` over `keys` on `pool`, returning reads per second.
fn reads_per_second(
    pool: &rayon::ThreadPool,
    keys: &[[u32; 3]],
    f: impl Fn([u32; 3]) -> Result<blocks::VoxelData, blocks::Error> + Sync,
) -> anyhow::Result<f64> {
    use rayon::prelude::*;
    let start = Instant::now();
    pool.install(|| keys.par_iter().try_for_each(|&k| f(k).map(drop)))?;
    Ok(keys.len() as f64 / start.elapsed().as_secs_f64())
}

/// Median and minimum milliseconds of 21 LOD selections.
fn time_selection(
    store: &Store,
    tf: &TransferFunction,
    budget: Budget,
) -> (blocks::lod::LodSelection, f64, f64) {
    let full = store.meta().geometry.voxel_count();
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..21 {
        let start = Instant::now();
        last = Some(blocks::lod::select(
            store.stats(),
            store.meta().value_map,
            tf,
            full,
            budget,
            None,
        ));
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let selection = last.unwrap_or_else(|| {
        blocks::lod::select(
            store.stats(),
            store.meta().value_map,
            tf,
            full,
            budget,
            None,
        )
    });
    (selection, times[times.len() / 2], times[0])
}

/// Selections at data reductions 9:1 and 35:1 on `store`, as JSON lines.
fn report_selections(dataset: &str, store: &Store, tf: &TransferFunction) -> anyhow::Result<()> {
    for ratio in [9.0, 35.0] {
        let (sel, median, min) = time_selection(store, tf, Budget::reduction(ratio));
        say(&serde_json::json!({
            "bench": "lod_selection",
            "dataset": dataset,
            "dims": store.meta().geometry.dims,
            "blocks": sel.lod.len(),
            "non_empty": sel.non_empty,
            "reduction_asked": ratio,
            "budget_voxels": sel.budget_voxels,
            "kept_voxels": sel.kept_voxels,
            "reduction": sel.reduction(),
            "empty_share": sel.empty_share(),
            "levels": sel.level_counts(),
            "runs": 21,
            "ms_median": median,
            "ms_min": min,
            "threads": rayon::current_num_threads(),
        })
        .to_string())?;
    }
    Ok(())
}
