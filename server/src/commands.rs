//! What the `voxserve` subcommands do (their flags are in [`crate::cli`]).

use std::io::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use blocks::ingest::dicom::FolderScan;
use blocks::ingest::{self, VolumeSource};
use shaders::{Camera, FrameRequest, GpuContext, Renderer, Shading};
use tokio::net::TcpListener;

use crate::cli::{BenchArgs, DataArgs, InfoArgs, RenderArgs, ServeArgs};
use crate::dataset::PHANTOM_ID;
use crate::{AppState, Dataset, RenderService, encode};

/// The adapter features the CPU twin assumes: 16-bit volumes in `r16unorm`
/// textures, as on every Vulkan, Metal and DX12 adapter voxserve has met.
const CPU_TWIN_FEATURES: shaders::wgpu::Features =
    shaders::wgpu::Features::TEXTURE_FORMAT_16BIT_NORM;

/// Loads the dataset named on the command line: the phantom, or a volume file
/// or DICOM folder read into memory.
pub fn load_dataset(name: &str, data: &DataArgs) -> anyhow::Result<Dataset> {
    let start = Instant::now();
    if name == PHANTOM_ID {
        let dataset = Dataset::phantom(data.phantom_size)?;
        tracing::info!(
            "generated the {n}³ phantom in {:.0} ms",
            start.elapsed().as_secs_f64() * 1e3,
            n = data.phantom_size
        );
        return Ok(dataset);
    }
    let path = std::path::Path::new(name);
    if !path.exists() {
        anyhow::bail!(
            "dataset '{name}': no such file or folder: expected '{PHANTOM_ID}' (the built-in CT \
             head phantom), a volume file or a folder of DICOM files"
        );
    }
    let dataset = Dataset::load(path, &data.input.open_options())?;
    tracing::info!(
        "read {} ({:?} voxels) in {:.0} ms",
        path.display(),
        dataset.volume.dims,
        start.elapsed().as_secs_f64() * 1e3
    );
    Ok(dataset)
}

/// Writes a line to standard output (the command's result, not a log line).
fn say(line: &str) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")?;
    out.flush()?;
    Ok(())
}

/// `voxserve serve`: serves until Ctrl-C.
pub async fn serve(args: ServeArgs) -> anyhow::Result<()> {
    let dataset = load_dataset(&args.dataset, &args.data)?;
    let gpu = GpuContext::new()?;
    let renderer = RenderService::start(gpu, &dataset)?;
    let listener = TcpListener::bind(args.addr)
        .await
        .with_context(|| format!("cannot listen on {}", args.addr))?;
    let mut addr = listener.local_addr()?;
    if addr.ip().is_unspecified() {
        addr.set_ip(std::net::Ipv4Addr::LOCALHOST.into());
    }
    say(&format!(
        "voxserve: serving the {} ({:?} voxels) on {} at http://{addr}/",
        dataset.volume.name,
        dataset.volume.dims,
        renderer.adapter()
    ))?;
    let state = AppState { dataset, renderer };
    let shutdown = async {
        if let Err(e) = tokio::signal::ctrl_c().await {
            tracing::error!("cannot listen for Ctrl-C: {e}");
            std::future::pending::<()>().await;
        }
        tracing::info!("shutting down");
    };
    crate::run(listener, state, shutdown).await?;
    Ok(())
}

/// `voxserve render`: one frame to a PNG file.
pub fn render(args: RenderArgs) -> anyhow::Result<()> {
    let dataset = load_dataset(&args.dataset, &args.data)?;
    let preset = match &args.preset {
        Some(name) => name.parse()?,
        None => dataset.default_preset(),
    };
    let request = FrameRequest {
        camera: Camera {
            azimuth_deg: args.azimuth,
            elevation_deg: args.elevation,
            distance: args.distance,
            fov_y_deg: args.fov,
        },
        shading: args.shading.parse().map_err(anyhow::Error::msg)?,
        step_voxels: args.step,
        ..FrameRequest::new(
            args.width,
            args.height,
            preset.transfer_function(dataset.volume.value_range),
        )
    };
    let start = Instant::now();
    let (frame, device) = if args.cpu {
        (
            shaders::cpu::render(&dataset.volume, &request, CPU_TWIN_FEATURES)?,
            "the CPU twin".to_owned(),
        )
    } else {
        let gpu = GpuContext::new()?;
        let device = gpu.describe();
        let mut renderer = Renderer::new(gpu, &dataset.volume)?;
        (renderer.render(&request)?, device)
    };
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let out = args
        .out
        .unwrap_or_else(|| PathBuf::from(format!("{}.png", dataset.id)));
    let png = encode::png(&frame)?;
    std::fs::write(&out, png).with_context(|| format!("cannot write {}", out.display()))?;
    say(&format!(
        "wrote {} ({}x{}, {preset}, {}) in {ms:.0} ms on {device}",
        out.display(),
        frame.width,
        frame.height,
        request.shading
    ))
}

/// `voxserve bench`: JSON lines with the settings that produced them.
pub fn bench(args: &BenchArgs) -> anyhow::Result<()> {
    if let Some(gib) = args.read_gib {
        return bench_read(gib);
    }
    let size = args.data.phantom_size;
    let mut generation_ms = Vec::new();
    let mut dataset = None;
    for _ in 0..3 {
        let start = Instant::now();
        dataset = Some(Dataset::phantom(size)?);
        generation_ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    let Some(dataset) = dataset else {
        anyhow::bail!("the phantom was never generated");
    };
    let threads = std::thread::available_parallelism().map_or(1, usize::from);
    say(&serde_json::json!({
        "bench": "phantom",
        "size": size,
        "voxels": dataset.volume.voxel_count(),
        "threads": threads,
        "runs": generation_ms.len(),
        "ms_min": min(&generation_ms),
        "ms_mean": mean(&generation_ms),
    })
    .to_string())?;

    let gpu = GpuContext::new()?;
    let info = gpu.info.clone();
    let mut renderer = Renderer::new(gpu, &dataset.volume)?;
    let preset = dataset.default_preset();
    let texel_format = format!("{:?}", renderer.volume_texture().format);
    for &edge in &args.sizes {
        for shading in Shading::ALL {
            let request = FrameRequest {
                camera: Camera {
                    azimuth_deg: 30.0,
                    elevation_deg: 15.0,
                    ..Camera::default()
                },
                shading,
                ..FrameRequest::new(
                    edge,
                    edge,
                    preset.transfer_function(dataset.volume.value_range),
                )
            };
            let mut times = Vec::new();
            renderer.render(&request)?;
            for _ in 0..args.frames {
                let start = Instant::now();
                renderer.render(&request)?;
                times.push(start.elapsed().as_secs_f64() * 1e3);
            }
            let mut line = serde_json::json!({
                "bench": "render",
                "renderer": "gpu",
                "adapter": info.name,
                "backend": info.backend.to_string(),
                "device_type": format!("{:?}", info.device_type),
                "dataset": dataset.id,
                "dims": dataset.volume.dims,
                "texel_format": texel_format,
                "preset": preset.name(),
                "shading": shading.name(),
                "step_voxels": request.step_voxels,
                "width": edge,
                "height": edge,
                "frames": times.len(),
                "ms_min": min(&times),
                "ms_mean": mean(&times),
                "mpix_per_s": f64::from(edge * edge) / 1e3 / mean(&times),
            });
            say(&line.to_string())?;
            if args.cpu {
                let start = Instant::now();
                shaders::cpu::render(&dataset.volume, &request, CPU_TWIN_FEATURES)?;
                let ms = start.elapsed().as_secs_f64() * 1e3;
                line["renderer"] = "cpu-twin".into();
                line["adapter"] = serde_json::Value::Null;
                line["threads"] = threads.into();
                line["frames"] = 1.into();
                line["ms_min"] = ms.into();
                line["ms_mean"] = ms.into();
                line["mpix_per_s"] = (f64::from(edge * edge) / 1e3 / ms).into();
                say(&line.to_string())?;
            }
        }
    }
    Ok(())
}

fn min(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::INFINITY, f64::min)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// `voxserve info`: what a file or DICOM folder holds, and its value statistics
/// (a full read, slab by slab).
pub fn info(args: &InfoArgs) -> anyhow::Result<()> {
    let options = args.input.open_options();
    let mut series = None;
    let mut source: Box<dyn VolumeSource> = if args.path.is_dir() {
        let scan = FolderScan::new(&args.path)?;
        let summaries = scan.summaries();
        if summaries.len() > 1 && options.series.is_none() && !args.json {
            say(&format!(
                "{}: {} DICOM series",
                args.path.display(),
                summaries.len()
            ))?;
            for s in &summaries {
                say(&format!("  {s}"))?;
            }
        }
        series = Some(summaries);
        Box::new(scan.open(options.series.as_deref())?)
    } else {
        ingest::open(&args.path, &options)?
    };
    let info = source.info().clone();
    let bar = progress_bar(u64::from(info.dims[2]), "reading slices");
    let stats = ingest::scan(source.as_mut(), |z| bar.set_position(u64::from(z)))?;
    bar.finish_and_clear();
    let physical = stats.stored_range.map(|v| info.value_map.physical(v));
    let (lo, hi) = (physical[0].min(physical[1]), physical[0].max(physical[1]));
    if args.json {
        let json = serde_json::json!({
            "path": info.path,
            "format": info.format.to_string(),
            "dims": info.dims,
            "voxel_type": info.voxel_type.name(),
            "spacing": info.spacing,
            "origin": info.origin,
            "direction": info.direction,
            "value_map": { "slope": info.value_map.slope, "intercept": info.value_map.intercept },
            "stored_range": stats.stored_range,
            "value_range": [lo, hi],
            "mean_stored": stats.mean,
            "nan_voxels": stats.nans,
            "unit": info.unit,
            "modality": info.modality,
            "description": info.description,
            "notes": info.notes,
            "series": series.map(|list| list.iter().map(|s| serde_json::json!({
                "id": s.id, "modality": s.modality, "description": s.description,
                "slices": s.slices, "columns": s.size[0], "rows": s.size[1],
            })).collect::<Vec<_>>()),
        });
        return say(&serde_json::to_string_pretty(&json)?);
    }
    let v3 = |v: [f64; 3]| format!("({}, {}, {})", g(v[0]), g(v[1]), g(v[2]));
    let unit = info
        .unit
        .as_deref()
        .map(|u| format!(" {u}"))
        .unwrap_or_default();
    let mut lines = vec![
        format!("path:        {}", info.path.display()),
        format!("format:      {}", info.format),
        format!(
            "dims:        {} × {} × {} voxels",
            info.dims[0], info.dims[1], info.dims[2]
        ),
        format!("voxel type:  {}", info.voxel_type.name()),
        format!(
            "spacing:     {} × {} × {} mm",
            g(info.spacing[0]),
            g(info.spacing[1]),
            g(info.spacing[2])
        ),
        format!("origin:      {} mm (LPS)", v3(info.origin)),
        format!(
            "direction:   x {}  y {}  z {}",
            v3(info.direction[0]),
            v3(info.direction[1]),
            v3(info.direction[2])
        ),
        format!(
            "value map:   physical = stored × {} + {}",
            g(f64::from(info.value_map.slope)),
            g(f64::from(info.value_map.intercept))
        ),
        format!(
            "values:      {} … {}{unit} (stored {} … {}, mean {})",
            g(lo),
            g(hi),
            g(stats.stored_range[0]),
            g(stats.stored_range[1]),
            g(stats.mean)
        ),
        format!(
            "modality:    {}",
            info.modality.as_deref().unwrap_or("unknown")
        ),
    ];
    if stats.nans > 0 {
        lines.push(format!("NaN voxels:  {}", stats.nans));
    }
    if let Some(d) = &info.description {
        lines.push(format!("description: {d}"));
    }
    if let Some(list) = &series {
        lines.push(format!("series:      {} in the folder", list.len()));
        lines.extend(list.iter().map(|s| format!("  {s}")));
    }
    lines.extend(info.notes.iter().map(|n| format!("note:        {n}")));
    say(&lines.join("\n"))
}

/// A number in its shortest form with at most 6 significant digits.
fn g(x: f64) -> String {
    let x = if x == 0.0 { 0.0 } else { x }; // no "-0"
    if x == x.trunc() && x.abs() < 1e15 {
        format!("{x:.0}")
    } else {
        let s = format!("{x:.6}");
        s.trim_end_matches('0').trim_end_matches('.').to_owned()
    }
}

/// A progress bar on standard error, hidden when it is not a terminal.
fn progress_bar(len: u64, message: &'static str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len).with_message(message);
    if let Ok(style) =
        indicatif::ProgressStyle::with_template("{msg} {bar:40} {pos}/{len} {elapsed}")
    {
        bar.set_style(style);
    }
    bar
}

/// `voxserve bench --read-gib N`: writes a generated uint16 volume of N GiB to a
/// temporary raw file, reads it back slab by slab through the raw reader, checks
/// every voxel's value, and reports MB/s and the process's peak memory.
fn bench_read(gib: f32) -> anyhow::Result<()> {
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
    {
        let file = std::fs::File::create(&path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        let mut out = std::io::BufWriter::with_capacity(8 << 20, file);
        let mut slice = Vec::with_capacity(slice_bytes as usize);
        for z in 0..nz {
            slice.clear();
            for y in 0..NY {
                for x in 0..NX {
                    slice.extend_from_slice(&value(x, y, z).to_le_bytes());
                }
            }
            out.write_all(&slice)?;
        }
        out.flush()?;
    }
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
