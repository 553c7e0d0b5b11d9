//! `voxserve bench out-of-core`: a volume larger than the machine's memory,
//! end to end.
//!
//! A CT-like 16-bit volume of `--gib` GiB is generated slab by slab (never
//! whole, in memory or on disk: the disk then only needs room for the store)
//! and ingested into `--out`, a folder or a URL on object storage (written
//! locally, then uploaded, as `voxserve ingest` does): MB/s and the ingest's
//! peak resident memory. Then, the peak started afresh, the store is opened
//! and served by a server in this process (the real router, render worker and
//! session): the first view at `--first-reduction` (its first frame from the
//! resident coarse levels, then converged), the same view at full detail,
//! which the memory budgets (`--cache-mib`, `--gpu-budget-mib`) cap, then an
//! orbit of `--views` views, every second changing the transfer-function
//! preset; per view the time to its first and its converged frame, the
//! chunks read and the resident memory, and at the end the serving's peak.
//! `--reuse` serves a store an earlier run left at `--out` (a fresh process
//! then measures serving alone).

use std::path::PathBuf;
use std::time::Instant;

use blocks::ingest::{Format, Study, VolumeInfo, VolumeSource, check_slab};
use blocks::store::Store;
use blocks::{Geometry, ValueMap, VoxelData, VoxelType};
use rayon::prelude::*;

use super::args::BenchOutOfCoreArgs;
use super::stream::{Socket, connect, send_view, start_server, until_converged};
use super::{peak_rss_mib, reset_peak_rss, rss_mib};
use server::commands::{say, write_store};
use server::stream::StreamSettings;
use server::{Dataset, RenderService};

/// Spacing of the generated volume, mm (isotropic).
const SPACING_MM: f64 = 0.25;

/// The presets the orbit changes between, in turn.
const PRESETS: [&str; 3] = ["ct-angio", "ct-soft-tissue", "ct-bone"];

/// `voxserve bench out-of-core`; see the module docs.
pub fn out_of_core(args: &BenchOutOfCoreArgs) -> anyhow::Result<()> {
    if !args.reuse {
        ingest(args)?;
    }
    tokio::runtime::Runtime::new()?.block_on(serve(args))
}

/// The `out-of-core-ingest` line.
fn ingest(args: &BenchOutOfCoreArgs) -> anyhow::Result<()> {
    let mut source = GeneratedCt::new(args.slice_edge, args.gib);
    let peak_reset = reset_peak_rss();
    let written = write_store(
        &mut source,
        std::path::Path::new(&args.out),
        args.force,
        blocks::store::IngestOptions::default().zstd_level,
    )?;
    let summary = &written.summary;
    say(&serde_json::json!({
        "bench": "out-of-core-ingest",
        "store": written.store,
        "source": "generated CT-like, slab by slab",
        "dims": summary.dims,
        "voxel_type": summary.voxel_type.name(),
        "source_gib": summary.source_bytes as f64 / f64::from(1u32 << 30),
        "store_gib": summary.store_bytes as f64 / f64::from(1u32 << 30),
        "compression": summary.compression_ratio(),
        "scan_seconds": summary.scan_seconds,
        "seconds": summary.seconds,
        "mb_per_s": summary.mb_per_s(),
        "upload_seconds": written.upload_seconds,
        "peak_rss_mib": peak_rss_mib(),
        "peak_since_start": !peak_reset,
        "threads": rayon::current_num_threads(),
        "machine_memory_gib": machine_memory_gib(),
    })
    .to_string())
}

/// The `out-of-core-view` lines and the `out-of-core-serve` summary.
async fn serve(args: &BenchOutOfCoreArgs) -> anyhow::Result<()> {
    let peak_reset = reset_peak_rss();
    let rss_start = rss_mib();
    let backend = args.renderer.backend()?;
    let adapter = backend.describe();
    let renderer = RenderService::start(backend, args.memory.gpu_budget_bytes(), 1)?;
    let start = Instant::now();
    let store = if blocks::store::is_url(&args.out) {
        Store::open_remote(&args.out)?
    } else {
        Store::open(PathBuf::from(&args.out).as_path())?
    };
    let dataset = Dataset::new(Dataset::id_of(&args.out), store, args.memory.cache_bytes())?;
    let open_ms = start.elapsed().as_secs_f64() * 1e3;
    let dims = dataset.dims();
    let cache = dataset.cache.clone();
    let settings = StreamSettings {
        // Still at once: the converged frame follows the last block.
        idle_ms: 0,
        ..StreamSettings::default()
    };
    let (url, stop) = start_server(vec![dataset], renderer, settings).await?;
    let mut socket = connect(&url).await?;
    let common = serde_json::json!({
        "store": args.out,
        "dims": dims,
        "adapter": adapter,
        "width": args.size,
        "height": args.size,
        "cache_mib": args.memory.cache_mib,
        "gpu_budget_mib": args.memory.gpu_budget_mib,
    });
    let say_view = |view: &str, mut line: serde_json::Value| {
        line["bench"] = "out-of-core-view".into();
        line["view"] = view.into();
        if let (Some(line), Some(common)) = (line.as_object_mut(), common.as_object()) {
            line.extend(common.clone());
        }
        say(&line.to_string())
    };
    let first_view = serde_json::json!({
        "w": args.size, "h": args.size, "az": 30, "el": 15,
        "reduction": args.first_reduction,
    });
    // The most resident memory after a view converged (NaN ignored by max).
    let mut rss_max = f64::NAN;
    let mut id = 1;
    let mut line = view(&mut socket, &cache, id, first_view).await?;
    line["open_ms"] = open_ms.into();
    rss_max = rss_max.max(line["rss_mib"].as_f64().unwrap_or(f64::NAN));
    say_view(&format!("first, {}:1", args.first_reduction), line)?;
    id += 1;
    let line = view(&mut socket, &cache, id, serde_json::json!({"reduction": 1})).await?;
    rss_max = rss_max.max(line["rss_mib"].as_f64().unwrap_or(f64::NAN));
    say_view("full detail (1:1 asked)", line)?;
    for k in 1..=args.views {
        id += 1;
        let az = 30.0 + 360.0 * f64::from(k) / f64::from(args.views);
        let mut set = serde_json::json!({"az": az});
        let preset = (k % 2 == 0).then(|| PRESETS[(k as usize / 2 - 1) % PRESETS.len()]);
        if let Some(preset) = preset {
            set["preset"] = preset.into();
        }
        let line = view(&mut socket, &cache, id, set).await?;
        rss_max = rss_max.max(line["rss_mib"].as_f64().unwrap_or(f64::NAN));
        let name = match preset {
            Some(p) => format!("orbit {k}/{}: az {az:.0}°, preset {p}", args.views),
            None => format!("orbit {k}/{}: az {az:.0}°", args.views),
        };
        say_view(&name, line)?;
    }
    drop(stop);
    say(&serde_json::json!({
        "bench": "out-of-core-serve",
        "store": args.out,
        "dims": dims,
        "views": args.views + 2,
        "rss_at_start_mib": rss_start,
        "rss_max_after_a_view_mib": rss_max,
        "peak_rss_mib": peak_rss_mib(),
        "peak_since_start": !peak_reset,
        "cache_mib": args.memory.cache_mib,
        "gpu_budget_mib": args.memory.gpu_budget_mib,
        "renderer": adapter,
        "machine_memory_gib": machine_memory_gib(),
    })
    .to_string())
}

/// Sends `set` as view message `id` and waits for its converged frame: the
/// view's figures as a JSON object.
async fn view(
    socket: &mut Socket,
    cache: &blocks::cache::BlockCache,
    id: u32,
    set: serde_json::Value,
) -> anyhow::Result<serde_json::Value> {
    let read_before = cache.arrivals() + cache.inline_reads();
    send_view(socket, id, set).await?;
    let frames = until_converged(socket, id).await?;
    let read = cache.arrivals() + cache.inline_reads() - read_before;
    let first = frames.first().map(|(h, ms)| (*ms, h.pending_blocks));
    let last = frames
        .last()
        .map(|(h, ms)| (*ms, h.reduction, h.memory_limited));
    let converged_ms = last.map_or(f64::NAN, |l| l.0);
    Ok(serde_json::json!({
        "first_frame_ms": first.map(|f| f.0),
        "first_frame_pending_blocks": first.map(|f| f.1),
        "converged_ms": converged_ms,
        "frames": frames.len(),
        "reduction": last.map(|l| l.1),
        "memory_limited": last.map(|l| l.2),
        "chunks_read": read,
        "chunks_per_s": read as f64 / (converged_ms / 1e3),
        "rss_mib": rss_mib(),
    }))
}

/// The machine's memory in GiB (Linux: MemTotal), if known.
fn machine_memory_gib() -> Option<f64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / f64::from(1u32 << 20))
}

/// A CT-like uint16 volume (stored = HU + 1024) generated slice by slice as
/// it is read: a body (soft tissue under a layer of fat and skin) in air, a
/// spine of vertebrae (cancellous bone in a cortical shell, discs between
/// them) and a contrast-filled aorta beside it, with noise, so that it
/// compresses like a scan and each preset shows different blocks.
#[derive(Debug)]
struct GeneratedCt {
    info: VolumeInfo,
}

impl GeneratedCt {
    /// `edge` × `edge` slices, as many as make `gib` GiB.
    fn new(edge: u32, gib: f32) -> GeneratedCt {
        let slice_bytes = u64::from(edge) * u64::from(edge) * 2;
        let nz = (f64::from(gib) * f64::from(1u32 << 30) / slice_bytes as f64)
            .ceil()
            .clamp(1.0, f64::from(u32::MAX)) as u32;
        let dims = [edge, edge, nz];
        GeneratedCt {
            info: VolumeInfo {
                path: PathBuf::from(format!("generated-ct-{edge}x{edge}x{nz}")),
                format: Format::Raw,
                geometry: Geometry::new(dims, [SPACING_MM; 3]),
                voxel_type: VoxelType::U16,
                value_map: ValueMap {
                    slope: 1.0,
                    intercept: -1024.0,
                },
                unit: Some("HU".into()),
                modality: Some("CT".into()),
                description: Some("generated CT-like volume (voxserve bench out-of-core)".into()),
                study: Study::default(),
                notes: Vec::new(),
            },
        }
    }
}

impl VolumeSource for GeneratedCt {
    fn info(&self) -> &VolumeInfo {
        &self.info
    }

    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<VoxelData, blocks::Error> {
        check_slab(&self.info, z0, depth)?;
        let [nx, ny, nz] = self.info.geometry.dims;
        let slice = nx as usize * ny as usize;
        let mut voxels = vec![0u16; slice * depth as usize];
        voxels
            .par_chunks_mut(nx as usize)
            .enumerate()
            .for_each(|(row, out)| {
                let y = (row % ny as usize) as u32;
                let z = z0 + (row / ny as usize) as u32;
                for (x, v) in out.iter_mut().enumerate() {
                    *v = ct_voxel(x as u32, y, z, [nx, ny, nz]);
                }
            });
        Ok(VoxelData::U16(voxels))
    }
}

/// The stored value (HU + 1024) of voxel (x, y, z) of [`GeneratedCt`].
fn ct_voxel(x: u32, y: u32, z: u32, dims: [u32; 3]) -> u16 {
    let [nx, ny, nz] = dims;
    let t = f64::from(z) / f64::from(nz.max(2) - 1);
    // Across the slice, -0.5 … 0.5 of its edge.
    let u = f64::from(x) / f64::from(nx) - 0.5;
    let v = f64::from(y) / f64::from(ny) - 0.5;
    let body = {
        let (a, b) = (0.36 + 0.05 * (t * std::f64::consts::PI).sin(), 0.28);
        ((u / a).powi(2) + (v / b).powi(2)).sqrt()
    };
    let spine = ((u).powi(2) + (v - 0.16).powi(2)).sqrt();
    let aorta = ((u + 0.07).powi(2) + (v - 0.06).powi(2)).sqrt();
    // A vertebra every 1/40 of the length, the last fifth of each a disc.
    let disc = (t * 40.0).fract() > 0.8;
    let hu = if body >= 1.0 {
        -1000.0
    } else if body > 0.985 {
        20.0 // skin
    } else if body > 0.92 {
        -100.0 // fat
    } else if spine < 0.055 && !disc {
        if spine > 0.045 { 1200.0 } else { 350.0 }
    } else if spine < 0.055 {
        80.0
    } else if aorta < 0.025 {
        if aorta > 0.022 { 60.0 } else { 300.0 }
    } else {
        40.0
    };
    let noise = (u64::from(x) << 40 ^ u64::from(y) << 20 ^ u64::from(z))
        .wrapping_mul(0x9e37_79b9_7f4a_7c15)
        >> 58;
    (hu + 1024.0 + noise as f64 - 32.0).clamp(0.0, 65535.0) as u16
}
