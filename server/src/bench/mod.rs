//! `voxserve bench`: measurements printed as JSON lines, each with the settings
//! that produced it. Speed and memory targets are checked here, never by tests.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use blocks::ingest;
use shaders::colour_difference::colour_difference;
use shaders::{Camera, Choice, Frame, FrameRequest, GpuContext, ReferenceRenderer, Renderer};

use args::{BenchArgs, BenchBlocksArgs, BenchCommand, BenchReadArgs, BenchRenderArgs};
use reference_data::reference_dataset;
use server::Dataset;
use server::commands::{CPU_TWIN_FEATURES, say};
use server::dataset::PHANTOM_ID;

pub mod args;
mod extinction;
mod light;
pub mod reference_data;
mod stream;

use extinction::extinction;
use light::light;
use stream::stream;

/// Runs the benchmark `args` names.
pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    match &args.what {
        BenchCommand::Render(a) => render(a),
        BenchCommand::Read(a) => read(a),
        BenchCommand::Blocks(a) => blocks(a),
        BenchCommand::Light(a) => light(a),
        BenchCommand::Stream(a) => stream(a),
        BenchCommand::Extinction(a) => extinction(a),
    }
}

/// `voxserve bench render`: for each dataset, the packed renderer at every
/// image size and data reduction, with and without empty-block skipping, against
/// the full-resolution reference renderer (time and colour difference).
pub fn render(args: &BenchRenderArgs) -> anyhow::Result<()> {
    let gpu = GpuContext::new()?;
    let info = gpu.info.clone();
    let threads = std::thread::available_parallelism().map_or(1, usize::from);
    for name in &args.datasets {
        let start = Instant::now();
        let Some((dataset, tf)) = bench_dataset(name, &args.data_dir, &args.data)? else {
            continue;
        };
        let bricked_ms = start.elapsed().as_secs_f64() * 1e3;
        let volume = dataset.store.load_level(0)?;
        let mut reference = ReferenceRenderer::new(gpu.clone(), &volume)?;
        drop(volume);
        let mut renderer = Renderer::new(
            gpu.clone(),
            dataset.cache.clone(),
            args.data.gpu_budget_bytes(),
        )?;
        say(&serde_json::json!({
            "bench": "dataset",
            "dataset": name,
            "dims": dataset.dims(),
            "blocks": dataset.store.meta().blocks,
            "opened_and_bricked_ms": bricked_ms,
            "texel_format": format!("{:?}", renderer.volume_texture().format),
        })
        .to_string())?;
        for &edge in &args.sizes {
            for &shading in &args.shadings {
                let base = FrameRequest {
                    camera: Camera {
                        azimuth_deg: 30.0,
                        elevation_deg: 15.0,
                        ..Camera::default()
                    },
                    shading,
                    ..FrameRequest::new(edge, edge, tf.clone())
                };
                let (reference_frame, reference_ms) =
                    timed(args.frames, || reference.render(&base))?;
                for &reduction in &args.reductions {
                    let request = FrameRequest {
                        reduction,
                        ..base.clone()
                    };
                    // The first frame selects levels and uploads blocks: timed apart.
                    let first = Instant::now();
                    renderer.render(&request)?;
                    let first_ms = first.elapsed().as_secs_f64() * 1e3;
                    let stats = renderer.last_stats().clone();
                    let (frame, skip_ms) = timed(args.frames, || renderer.render(&request))?;
                    let no_skip = FrameRequest {
                        skip_empty: false,
                        ..request.clone()
                    };
                    let (_, no_skip_ms) = timed(args.frames, || renderer.render(&no_skip))?;
                    let error =
                        colour_difference(&frame, &reference_frame).map_err(anyhow::Error::msg)?;
                    let selection = renderer.selection();
                    let mut line = serde_json::json!({
                        "bench": "render",
                        "renderer": "gpu",
                        "adapter": info.name,
                        "backend": info.backend.to_string(),
                        "device_type": format!("{:?}", info.device_type),
                        "dataset": name,
                        "dims": dataset.dims(),
                        "shading": shading.name(),
                        "step_voxels": request.step_voxels,
                        "width": edge,
                        "height": edge,
                        "requested_reduction": reduction,
                        "reduction": stats.reduction,
                        "levels": stats.level_counts,
                        "non_empty_blocks": selection.map(|s| s.non_empty),
                        "blocks": selection.map(|s| s.lod.len()),
                        "first_frame_ms": first_ms,
                        "select_ms": stats.select_ms,
                        "upload_ms": stats.upload_ms,
                        "uploaded_blocks": stats.uploaded_blocks,
                        "frames": args.frames,
                        "ms_mean": skip_ms,
                        "no_skip_ms_mean": no_skip_ms,
                        "skip_speedup": no_skip_ms / skip_ms,
                        "reference_ms_mean": reference_ms,
                        "packed_vs_reference_speedup": reference_ms / skip_ms,
                        "mpix_per_s": f64::from(edge * edge) / 1e3 / skip_ms,
                        "delta_e_vs_reference": error,
                    });
                    say(&line.to_string())?;
                    if args.cpu {
                        let start = Instant::now();
                        let max_edge = gpu.device.limits().max_texture_dimension_3d;
                        shaders::cpu::render_packed(
                            &dataset.cache,
                            &request,
                            CPU_TWIN_FEATURES,
                            max_edge,
                        )?;
                        let ms = start.elapsed().as_secs_f64() * 1e3;
                        line = serde_json::json!({
                            "bench": "render",
                            "renderer": "cpu-twin",
                            "threads": threads,
                            "dataset": name,
                            "shading": shading.name(),
                            "width": edge,
                            "height": edge,
                            "requested_reduction": reduction,
                            "frames": 1,
                            "ms_mean": ms,
                            "note": "includes level selection and atlas assembly",
                        });
                        say(&line.to_string())?;
                    }
                }
            }
        }
    }
    Ok(())
}

/// The dataset `name` of a benchmark (the phantom, or a real dataset from
/// `data_dir`) and its transfer function; `None`, with a warning, when the
/// dataset's file is missing.
pub(crate) fn bench_dataset(
    name: &str,
    data_dir: &Path,
    data: &server::cli::DataArgs,
) -> anyhow::Result<Option<(Dataset, blocks::TransferFunction)>> {
    if name == PHANTOM_ID {
        let dataset = Dataset::phantom(data.phantom_size, data.cache_bytes())?;
        let tf = dataset
            .default_preset()
            .transfer_function(dataset.value_range());
        return Ok(Some((dataset, tf)));
    }
    let Some(reference) = reference_dataset(data_dir, name) else {
        anyhow::bail!(
            "--datasets: unknown dataset '{name}': expected {PHANTOM_ID} or one of {}",
            reference_data::NAMES.join(", ")
        );
    };
    if !reference.path.exists() {
        tracing::warn!("{} not found: skipping {name}", reference.path.display());
        return Ok(None);
    }
    let dataset = Dataset::load(&reference.path, &reference.options, data.cache_bytes())?;
    Ok(Some((dataset, reference.transfer_function)))
}

/// Renders `frames` times and returns the last frame and the mean milliseconds.
pub(crate) fn timed(
    frames: u32,
    mut render: impl FnMut() -> Result<Frame, shaders::GpuError>,
) -> anyhow::Result<(Frame, f64)> {
    let mut last = None;
    let start = Instant::now();
    for _ in 0..frames.max(1) {
        last = Some(render()?);
    }
    let ms = start.elapsed().as_secs_f64() * 1e3 / f64::from(frames.max(1));
    let frame = last.ok_or_else(|| anyhow::anyhow!("no frame was rendered"))?;
    Ok((frame, ms))
}

/// `voxserve bench read`: writes a generated uint16 volume of N GiB to a
/// temporary raw file, reads it back slab by slab through the raw reader, checks
/// every voxel's value, and reports MB/s and the process's peak memory.
pub fn read(args: &BenchReadArgs) -> anyhow::Result<()> {
    let gib = args.gib;
    const NX: u32 = 2048;
    const NY: u32 = 2048;
    let slice_bytes = u64::from(NX) * u64::from(NY) * 2;
    let nz = ((f64::from(gib) * f64::from(1u32 << 30)) / slice_bytes as f64)
        .ceil()
        .max(1.0) as u32;
    let path = std::env::temp_dir().join(format!(
        "voxserve-bench-{}_{NX}x{NY}x{nz}_uint16.raw",
        std::process::id()
    ));
    // The file goes away however this function ends.
    struct Remove(PathBuf);
    impl Drop for Remove {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }
    let _remove = Remove(path.clone());
    // Voxel (x, y, z) holds (x + 3y + 7z) mod 65536: cheap to generate and to check.
    let value =
        |x: u32, y: u32, z: u32| (x.wrapping_add(3 * y).wrapping_add(7 * z) & 0xffff) as u16;
    let start = Instant::now();
    write_uint16_raw(&path, [NX, NY, nz], value)?;
    let write_s = start.elapsed().as_secs_f64();
    let total = slice_bytes * u64::from(nz);

    let mut source = ingest::open(&path, &ingest::OpenOptions::default())?;
    let depth = ingest::slab_depth(source.info());
    let start = Instant::now();
    let mut z = 0;
    let mut mismatches = 0u64;
    while z < nz {
        let d = depth.min(nz - z);
        let slab = source.read_slab(z, d)?;
        let blocks::VoxelData::U16(v) = slab else {
            anyhow::bail!(
                "the raw reader returned {} voxels, expected uint16",
                slab.voxel_type().name()
            );
        };
        for (i, &got) in v.iter().enumerate() {
            let i = i as u64;
            let (x, y, zz) = (
                (i % u64::from(NX)) as u32,
                ((i / u64::from(NX)) % u64::from(NY)) as u32,
                z + (i / (u64::from(NX) * u64::from(NY))) as u32,
            );
            mismatches += u64::from(got != value(x, y, zz));
        }
        z += d;
    }
    let read_s = start.elapsed().as_secs_f64();
    if mismatches > 0 {
        anyhow::bail!("{mismatches} voxels read back wrong");
    }
    let mb = total as f64 / 1e6;
    say(&serde_json::json!({
        "bench": "read",
        "format": "raw",
        "dims": [NX, NY, nz],
        "voxel_type": "uint16",
        "bytes": total,
        "slab_bytes": u64::from(depth) * slice_bytes,
        "write_mb_s": mb / write_s,
        "read_mb_s": mb / read_s,
        "verified_voxels": total / 2,
        "peak_rss_mib": peak_rss_mib(),
    })
    .to_string())
}

/// The process's peak resident memory in MiB (Linux: VmHWM), if known.
fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// A temporary folder for a benchmark's files, removed when dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new(what: &str) -> anyhow::Result<Scratch> {
        let path =
            std::env::temp_dir().join(format!("voxserve-bench-{what}-{}", std::process::id()));
        std::fs::create_dir_all(&path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        Ok(Scratch(path))
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
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

/// Writes a little-endian uint16 raw volume of `dims`, voxel (x, y, z) =
/// `value(x, y, z)`, one slice in memory at a time.
fn write_uint16_raw(
    path: &Path,
    dims: [u32; 3],
    value: impl Fn(u32, u32, u32) -> u16,
) -> anyhow::Result<()> {
    let [nx, ny, nz] = dims;
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut out = std::io::BufWriter::with_capacity(8 << 20, file);
    let mut slice = Vec::with_capacity(nx as usize * ny as usize * 2);
    for z in 0..nz {
        slice.clear();
        for y in 0..ny {
            for x in 0..nx {
                slice.extend_from_slice(&value(x, y, z).to_le_bytes());
            }
        }
        out.write_all(&slice)?;
    }
    out.flush()?;
    Ok(())
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
    store: &blocks::store::Store,
    tf: &blocks::TransferFunction,
    budget: u64,
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
        ));
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let selection = last.unwrap_or_else(|| {
        blocks::lod::select(store.stats(), store.meta().value_map, tf, full, budget)
    });
    (selection, times[times.len() / 2], times[0])
}

/// Selections at 9:1 and 35:1 budgets on `store`, as JSON lines.
fn report_selections(
    dataset: &str,
    store: &blocks::store::Store,
    tf: &blocks::TransferFunction,
) -> anyhow::Result<()> {
    let full = store.meta().geometry.voxel_count();
    for ratio in [9.0, 35.0] {
        let budget = (full as f64 / ratio) as u64;
        let (sel, median, min) = time_selection(store, tf, budget);
        say(&serde_json::json!({
            "bench": "lod_selection",
            "dataset": dataset,
            "dims": store.meta().geometry.dims,
            "blocks": sel.lod.len(),
            "non_empty": sel.non_empty,
            "budget_ratio": ratio,
            "budget_voxels": budget,
            "kept_voxels": sel.kept_voxels,
            "reduction": sel.reduction(),
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

/// `voxserve bench blocks`: ingest, random block reads and LOD selection.
pub fn blocks(args: &BenchBlocksArgs) -> anyhow::Result<()> {
    use std::sync::Arc;

    use blocks::store::{IngestOptions, Store};
    use blocks::{Preset, TfPoint, TransferFunction};

    let scratch = Scratch::new("blocks")?;
    // 1. Ingest a generated CT-like volume.
    let raw = write_ct_like(&scratch.0, args.gib)?;
    let mut source = ingest::open(&raw, &ingest::OpenOptions::default())?;
    let store_path = scratch.0.join("generated");
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

    // 2. Random level-0 block reads: a fresh store (shard indexes read as met),
    // the same blocks again (indexes cached, chunks decoded), and from a cache.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads as usize)
        .build()?;
    let fresh = Store::open(&store_path)?;
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

    // 3. LOD selection: on the generated volume, on the 512³ phantom (32 768
    // blocks), and on the engine and CT head when the datasets are there.
    let bone_raw = TransferFunction::new(vec![
        TfPoint::new(1100.0, [0.9, 0.8, 0.7], 0.0),
        TfPoint::new(1500.0, [0.9, 0.8, 0.7], 0.3),
        TfPoint::new(2000.0, [1.0, 1.0, 1.0], 0.9),
    ])?;
    report_selections("generated CT-like", &store, &bone_raw)?;
    let phantom = Arc::new(blocks::phantom::head(512)?);
    let mut source = ingest::MemorySource::new(phantom.clone(), "phantom-512");
    let phantom_path = scratch.0.join("phantom");
    blocks::store::ingest(
        &mut source,
        &phantom_path,
        &IngestOptions::default(),
        &mut |_| {},
    )?;
    let phantom_store = Store::open(&phantom_path)?;
    let tf = Preset::CtBone.transfer_function(phantom.value_range);
    report_selections("phantom 512³", &phantom_store, &tf)?;
    drop(phantom_store);

    let engine = args.data.join("raw/engine_256x256x128_uint8.raw");
    let cthead = args.data.join("raw/cthead_256x256x113_uint16be.raw");
    let metal = TransferFunction::new(vec![
        TfPoint::new(40.0, [0.6, 0.6, 0.7], 0.0),
        TfPoint::new(80.0, [0.8, 0.8, 0.9], 0.3),
        TfPoint::new(255.0, [1.0, 1.0, 1.0], 0.9),
    ])?;
    let skin_bone = TransferFunction::new(vec![
        TfPoint::new(500.0, [0.9, 0.6, 0.5], 0.0),
        TfPoint::new(700.0, [0.9, 0.6, 0.5], 0.15),
        TfPoint::new(1100.0, [0.9, 0.6, 0.5], 0.05),
        TfPoint::new(1300.0, [1.0, 1.0, 0.9], 0.9),
    ])?;
    for (name, path, spacing, tf) in [
        ("engine", engine, [1.0; 3], metal),
        ("cthead", cthead, [1.0, 1.0, 2.0], skin_bone),
    ] {
        if !path.exists() {
            tracing::warn!(
                "{} not found: skipping the {name} selection",
                path.display()
            );
            continue;
        }
        let options = ingest::OpenOptions {
            raw: ingest::raw::RawOptions {
                spacing: Some(spacing),
                ..Default::default()
            },
            ..Default::default()
        };
        let mut source = ingest::open(&path, &options)?;
        let out = scratch.0.join(name);
        blocks::store::ingest(
            source.as_mut(),
            &out,
            &IngestOptions::default(),
            &mut |_| {},
        )?;
        report_selections(name, &Store::open(&out)?, &tf)?;
    }
    Ok(())
}
