//! `voxserve bench`: measurements printed as JSON lines, each with the settings
//! that produced it. Speed and memory targets are checked here, never by tests.
//!
//! One module per benchmark (`render`, `read`, `blocks`, `light`, `stream`,
//! `slice`, `store`, `out_of_core`, `extinction`, `peer`, `pacs`), its flags in `args`, the real datasets in `reference_data`;
//! this module dispatches and holds what several benchmarks share.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use shaders::{Camera, Frame, FrameRequest, Shading};

use args::{BenchArgs, BenchCommand};
use reference_data::reference_dataset;
use server::Dataset;
use server::dataset::PHANTOM_ID;

pub mod args;
mod blocks;
mod extinction;
mod light;
mod out_of_core;
mod pacs;
mod peer;
mod read;
pub mod reference_data;
mod render;
mod slice;
mod store;
mod stream;

use blocks::blocks;
use extinction::extinction;
use light::light;
use out_of_core::out_of_core;
use pacs::pacs;
use peer::peer;
use read::read;
use render::render;
use slice::slice;
use store::store;
use stream::stream;

/// Runs the benchmark `args` names.
pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    match &args.what {
        BenchCommand::Render(a) => render(a),
        BenchCommand::Read(a) => read(a),
        BenchCommand::Blocks(a) => blocks(a),
        BenchCommand::Light(a) => light(a),
        BenchCommand::Stream(a) => stream(a),
        BenchCommand::Slice(a) => slice(a),
        BenchCommand::Store(a) => store(a),
        BenchCommand::OutOfCore(a) => out_of_core(a),
        BenchCommand::Extinction(a) => extinction(a),
        BenchCommand::Peer(a) => peer(a),
        BenchCommand::Pacs(a) => pacs(a),
    }
}

/// The dataset `name` of a benchmark (the phantom, or a real dataset from
/// `data_dir`) and its transfer function; `None`, with a warning, when the
/// dataset's file is missing.
pub(crate) fn bench_dataset(
    name: &str,
    data_dir: &Path,
    data: &server::cli::DataArgs,
) -> anyhow::Result<Option<(Dataset, ::blocks::TransferFunction)>> {
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

/// A square frame of `edge` pixels of the view every rendering benchmark
/// measures: 30° around the volume and 15° above it.
pub(crate) fn view_request(
    edge: u32,
    shading: Shading,
    tf: &::blocks::TransferFunction,
) -> FrameRequest {
    FrameRequest {
        camera: Camera {
            azimuth_deg: 30.0,
            elevation_deg: 15.0,
            ..Camera::default()
        },
        shading,
        ..FrameRequest::new(edge, edge, tf.clone())
    }
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

/// A temporary folder for a benchmark's files, removed when dropped.
pub(crate) struct Scratch(pub(crate) PathBuf);

impl Scratch {
    pub(crate) fn new(what: &str) -> anyhow::Result<Scratch> {
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

/// The process's peak resident memory in MiB (Linux: VmHWM), if known.
fn peak_rss_mib() -> Option<f64> {
    proc_status_mib("VmHWM:")
}

/// The process's resident memory now, MiB (Linux: VmRSS), if known.
fn rss_mib() -> Option<f64> {
    proc_status_mib("VmRSS:")
}

/// A memory figure of `/proc/self/status` (its line starting with `field`) in MiB.
fn proc_status_mib(field: &str) -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(field))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// Starts the peak of [`peak_rss_mib`] afresh from the memory resident now
/// (Linux: writing 5 to `/proc/self/clear_refs`); whether it could.
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
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
