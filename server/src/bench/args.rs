//! The flags of `voxserve bench` and its subcommands.

use std::path::PathBuf;

use clap::{Args, Subcommand};
use server::cli::{DataArgs, MemoryArgs, RendererArgs, finite_in, setting_value};
use server::dataset::PHANTOM_ID;
use shaders::Shading;

use super::peer::PeerMode;

/// `voxserve bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// What to measure.
    #[command(subcommand)]
    pub what: BenchCommand,
}

/// The benchmarks.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Frame rendering from packed blocks per dataset, image size and data
    /// reduction: with and without empty-block skipping, and against the
    /// full-resolution reference (time and ΔE colour difference; at step 1/8
    /// voxel ΔE, ꟻLIP and the share of its opaque pixels still covered).
    Render(Box<BenchRenderArgs>),
    /// Reading a generated raw volume slab by slab: MB/s and peak memory.
    Read(BenchReadArgs),
    /// The brick store: ingest MB/s and peak memory, random block reads (cold,
    /// warm, cached), LOD selection time and the reduction reached.
    Blocks(BenchBlocksArgs),
    /// Global light propagation: the colour difference ΔE of the piecewise
    /// light against the brute-force reference per data reduction and SVR size,
    /// and the paper's table 1: light update (A), one in-scattering refinement
    /// (B) and a lit frame (C) per data reduction, and (A) per SVR size and
    /// segment length.
    Light(Box<BenchLightArgs>),
    /// View sessions on loopback: event-to-frame latency (p50, p95) per image
    /// size for JPEG and lossless frames, encode time per format, frames per
    /// second with several concurrent sessions, and how long one session's
    /// frames wait while another changes to a transfer function whose blocks
    /// are not in memory.
    Stream(Box<BenchStreamArgs>),
    /// Slice views on loopback: the time from a scroll (a `view` message
    /// moving an axial slice by one voxel) to the frame that shows it, p50
    /// and p95, while scrolling (JPEG) and still (lossless), with the render
    /// and encode milliseconds and the frames drawn coarser while blocks
    /// were read.
    Slice(Box<BenchSliceArgs>),
    /// Brick stores from cold, on disk or on object storage, alternating
    /// round by round: opening (metadata, statistics, the coarse levels),
    /// the first frame of a view session and its converged frame, chunks
    /// read per second.
    Store(Box<BenchStoreArgs>),
    /// A volume larger than memory end to end: a generated CT-like volume
    /// ingested (MB/s, peak memory) into a store on disk or object storage,
    /// then served: opening, the first frame at a high data reduction,
    /// refinement within the memory budgets, and resident memory while the
    /// view orbits and the transfer function changes.
    OutOfCore(Box<BenchOutOfCoreArgs>),
    /// Extinction-based illumination as its paper reports it: summed-area-table
    /// build time per grid size, ambient occlusion per shell count against
    /// explicit sampling, soft shadows per cone sampling against one shadow
    /// ray (times and ΔE*uv), and lit against unlit frames.
    Extinction(Box<BenchExtinctionArgs>),
    /// voxserve against VTK's ray casters (`../shared/bench/vtk_bench.py`)
    /// on the same raw file, image size, step, transfer function and camera,
    /// interleaved in one run: the ratio of frame times per dataset and mode,
    /// and both images' coverage.
    Peer(Box<BenchPeerArgs>),
    /// A series from a PACS over DICOMweb: WADO-RS fetch (MB/s, instances
    /// per second) per concurrency, bricking what was fetched (MB/s, slices
    /// per second), and, interleaved, `ingest` of the same files from disk.
    Pacs(Box<BenchPacsArgs>),
}

/// `voxserve bench pacs`.
#[derive(Debug, Args)]
pub struct BenchPacsArgs {
    #[command(flatten)]
    pub pacs: server::cli::PacsArgs,
    /// StudyInstanceUID.
    #[arg(long, value_parser = |v: &str| server::pacs::query::check_uid("StudyInstanceUID", v))]
    pub study: String,
    /// SeriesInstanceUID [default: the study's only series].
    #[arg(long, value_parser = |v: &str| server::pacs::query::check_uid("SeriesInstanceUID", v))]
    pub series: Option<String>,
    /// The same series' files on disk, ingested in each round for comparison.
    #[arg(long, value_name = "FOLDER")]
    pub folder: Option<PathBuf>,
    /// Instances retrieved at once, comma separated: one run each per round.
    #[arg(long, value_delimiter = ',', default_values_t = [1u16, 8])]
    pub concurrency: Vec<u16>,
    /// Rounds.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub rounds: u32,
    /// Also time, per round, an IHE Invoke Image Display request for the
    /// study to the first frame of its series (a server on loopback with an
    /// empty cache, rendering on the CPU): the request checked and sent on,
    /// the study resolved, the series fetched and bricked, a 512² frame.
    #[arg(long)]
    pub iid: bool,
}

/// `voxserve bench peer`.
#[derive(Debug, Args)]
pub struct BenchPeerArgs {
    /// Datasets: engine, bonsai, cthead (from --data-dir; skipped with a
    /// warning when missing), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = ["engine", "bonsai", "cthead"].map(String::from))]
    pub datasets: Vec<String>,
    /// Where the real datasets are.
    #[arg(long, default_value = "../shared/data")]
    pub data_dir: PathBuf,
    /// Modes compared, comma separated: against VTK FixedPoint composite,
    /// phong (cubic B-spline normals), phong_central (central differences),
    /// global_light, extinction (cubic normals) and extinction_central
    /// (central differences); against VTK's GPU mapper shadows (slow).
    #[arg(long, value_delimiter = ',', default_value = "composite,phong,phong_central,global_light,extinction,extinction_central",
          value_parser = PeerMode::parse)]
    pub modes: Vec<PeerMode>,
    /// Image edge in pixels (square images).
    #[arg(long, default_value_t = 512, value_parser = setting_value::<u32>("w"))]
    pub size: u32,
    /// Distance between samples in voxels, for both renderers.
    #[arg(long, default_value_t = 0.5, value_parser = setting_value::<f32>("step"))]
    pub step: f32,
    /// Frames timed per run (each renderer turns the camera 2° between frames).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub frames: u32,
    /// Runs of each renderer per dataset and mode, alternating.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub rounds: u32,
    /// VTK's peer benchmark script.
    #[arg(long, default_value = "../shared/bench/vtk_bench.py")]
    pub vtk_bench: PathBuf,
    /// A Python that imports vtk and numpy [default: a virtual environment
    /// under the user's cache folder, created with pip the first time].
    #[arg(long)]
    pub python: Option<PathBuf>,
    /// Write both renderers' first frames here as PNG files.
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub memory: MemoryArgs,
}

/// `voxserve bench extinction`.
#[derive(Debug, Args)]
pub struct BenchExtinctionArgs {
    /// Datasets: `phantom`, and the real datasets engine, bonsai, cthead, vhf
    /// (from --data-dir; skipped with a warning when missing), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = ["engine", "cthead"].map(String::from))]
    pub datasets: Vec<String>,
    /// Where the real datasets are.
    #[arg(long, default_value = "../shared/data")]
    pub data_dir: PathBuf,
    /// SAT and light-cache grid sizes (cells along the longest side), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [64u32, 128, 192, 256],
          value_parser = setting_value::<u32>("sat_size"))]
    pub sat_sizes: Vec<u32>,
    /// Ambient-occlusion shell counts, comma separated (radius: the larger of
    /// --ao-radius and the count).
    #[arg(long, value_delimiter = ',', default_values_t = [3u32, 7, 11],
          value_parser = setting_value::<u32>("ao_shells"))]
    pub shells: Vec<u32>,
    /// Ambient-occlusion radius in cells of the comparison with explicit sampling.
    #[arg(long, default_value_t = 7,
          value_parser = setting_value::<u32>("ao_radius"))]
    pub ao_radius: u32,
    /// Cone sampling frequencies (cuboids per volume side), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [20.0f32, 50.0],
          value_parser = setting_value::<f32>("cone_frequency"))]
    pub cone_frequencies: Vec<f32>,
    /// Half-angle of the shadow cones, degrees.
    #[arg(long, default_value_t = 2.0, value_parser = setting_value::<f32>("cone_angle"))]
    pub cone_angle: f32,
    /// The largest grid the references (explicit AO sampling, shadow rays) run
    /// at; larger ones report the SAT methods only.
    #[arg(long, default_value_t = 256,
          value_parser = setting_value::<u32>("sat_size"))]
    pub reference_max: u32,
    /// Image edge in pixels (square) of the compared and timed frames.
    #[arg(long, default_value_t = 512,
          value_parser = setting_value::<u32>("w"))]
    pub size: u32,
    /// Frames timed per frame measurement.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub frames: u32,
    /// Runs per stage timing (AO, soft shadows, shadow ray); the fastest is reported.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub repeats: u32,
    /// Also write the compared frames and a ΔE error image per pair as PNGs here.
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub data: DataArgs,
}

/// `voxserve bench stream`.
#[derive(Debug, Args)]
pub struct BenchStreamArgs {
    /// The dataset: `phantom`, a brick store, a volume file or a DICOM folder.
    #[arg(default_value = PHANTOM_ID)]
    pub dataset: String,
    /// Image edges for the latency measurements (square), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [512u32, 1024],
          value_parser = setting_value::<u32>("w"))]
    pub sizes: Vec<u32>,
    /// Camera events timed per size and format.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub events: u32,
    /// Concurrent sessions for the frame-rate measurements, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 4, 16],
          value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub sessions: Vec<u32>,
    /// Sessions measured alone and beside a hostile client (`stream-hostile`);
    /// 0 skips it.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(0..=4096))]
    pub hostile_sessions: u32,
    /// Image edge of the frame-rate measurements.
    #[arg(long, default_value_t = 256,
          value_parser = setting_value::<u32>("w"))]
    pub session_size: u32,
    /// Seconds each frame-rate measurement runs.
    #[arg(long, default_value_t = 5.0, value_parser = finite_in(0.1, 3600.0))]
    pub seconds: f32,
    /// Edge of the phantom ingested to disk for the cold transfer-function
    /// change (voxels).
    #[arg(long, default_value_t = 256,
          value_parser = clap::value_parser!(u32).range(
              i64::from(blocks::phantom::MIN_SIZE)..=i64::from(blocks::phantom::MAX_SIZE)))]
    pub cold_phantom: u32,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub data: DataArgs,
}

/// `voxserve bench slice`.
#[derive(Debug, Args)]
pub struct BenchSliceArgs {
    /// The dataset: `phantom`, a brick store, a volume file or a DICOM folder.
    #[arg(default_value = PHANTOM_ID)]
    pub dataset: String,
    /// Image edge in pixels (square).
    #[arg(long, default_value_t = 512, value_parser = setting_value::<u32>("w"))]
    pub size: u32,
    /// Scroll events timed per run.
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub events: u32,
    /// Slab thickness in mm (0: one plane).
    #[arg(long, default_value_t = 0.0, value_parser = finite_in(0.0, 500.0))]
    pub slab: f32,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub data: DataArgs,
}

/// `voxserve bench store`.
#[derive(Debug, Args)]
pub struct BenchStoreArgs {
    /// Brick stores: folders, or URLs on object storage (`s3://…`).
    #[arg(required = true)]
    pub stores: Vec<String>,
    /// Image edge in pixels (square).
    #[arg(long, default_value_t = 512, value_parser = setting_value::<u32>("w"))]
    pub size: u32,
    /// Rounds; each opens every store afresh, in turn.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub rounds: u32,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub data: DataArgs,
}

/// `voxserve bench out-of-core`.
#[derive(Debug, Args)]
pub struct BenchOutOfCoreArgs {
    /// Where the store goes: a folder, or a URL on object storage (`s3://…`).
    #[arg(long)]
    pub out: String,
    /// Size of the generated volume, GiB of 16-bit voxels.
    #[arg(long, default_value_t = 32.0, value_parser = finite_in(0.001, 4096.0))]
    pub gib: f32,
    /// Voxels along x and y of each slice of the generated volume; z makes up
    /// the size (the ingest holds about one 16-slice slab of them in memory).
    #[arg(long, default_value_t = 1536,
          value_parser = clap::value_parser!(u32).range(16..=16384))]
    pub slice_edge: u32,
    /// Replace a store already at --out.
    #[arg(long, conflicts_with = "reuse")]
    pub force: bool,
    /// Serve the store already at --out (from an earlier run) instead of
    /// ingesting one.
    #[arg(long)]
    pub reuse: bool,
    /// Image edge in pixels (square).
    #[arg(long, default_value_t = 512, value_parser = setting_value::<u32>("w"))]
    pub size: u32,
    /// The data reduction of the first view; the views after it ask for full
    /// detail (1:1), which the memory budgets cap.
    #[arg(long, default_value_t = 200.0, value_parser = setting_value::<f32>("reduction"))]
    pub first_reduction: f32,
    /// Views of the orbit after the first two, each 360°/VIEWS further round;
    /// every second one also changes the transfer-function preset.
    #[arg(long, default_value_t = 8,
          value_parser = clap::value_parser!(u32).range(1..=360))]
    pub views: u32,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub memory: MemoryArgs,
}

/// `voxserve bench light`.
#[derive(Debug, Args)]
pub struct BenchLightArgs {
    /// Datasets: `phantom`, and the real datasets engine, bonsai, cthead, vhf
    /// (from --data-dir; skipped with a warning when missing), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = ["cthead", "vhf"].map(String::from))]
    pub datasets: Vec<String>,
    /// Where the real datasets are.
    #[arg(long, default_value = "../shared/data")]
    pub data_dir: PathBuf,
    /// Image edge in pixels (square) of the compared and timed frames.
    #[arg(long, default_value_t = 1024,
          value_parser = setting_value::<u32>("w"))]
    pub size: u32,
    /// Data reductions (full voxels per voxel on the GPU), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 9.0, 35.0],
          value_parser = setting_value::<f32>("reduction"))]
    pub reductions: Vec<f32>,
    /// SVR scales (1, 2, 4 or 8 voxels per SVR point along each axis), comma
    /// separated; the first one is used for (B) and (C).
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 2, 4, 8],
          value_parser = setting_value::<u32>("svr"))]
    pub svr_scales: Vec<u32>,
    /// Segment lengths L in voxels for the table of (A) per SVR size and
    /// segment length, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [4u32, 8, 16, 32],
          value_parser = setting_value::<u32>("segment"))]
    pub segments: Vec<u32>,
    /// Segment lengths L in voxels of the colour difference, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [8u32, 16],
          value_parser = setting_value::<u32>("segment"))]
    pub quality_segments: Vec<u32>,
    /// Segment length L in voxels of (A), (B) and (C) per data reduction (the
    /// paper's: 8).
    #[arg(long, default_value_t = 8,
          value_parser = setting_value::<u32>("segment"))]
    pub segment: u32,
    /// The data reduction of the table of (A) per SVR size and segment length
    /// (the paper's is 8.9:1).
    #[arg(long, default_value_t = 9.0, value_parser = setting_value::<f32>("reduction"))]
    pub table_reduction: f32,
    /// Scattering radius R_Ω in voxels for (B).
    #[arg(long, default_value_t = 16.0, value_parser = setting_value::<f32>("scatter_radius"))]
    pub scatter_radius: f32,
    /// In-scattering directions J for (B).
    #[arg(long, default_value_t = 18, value_parser = setting_value::<u32>("directions"))]
    pub directions: u32,
    /// Frames timed per frame measurement.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub frames: u32,
    /// Also write, per compared pair, the piecewise and reference frames and a
    /// ΔE error image (black 0, red 6 and above) as PNGs into this folder.
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub data: DataArgs,
}

/// `voxserve bench render`.
#[derive(Debug, Args)]
pub struct BenchRenderArgs {
    /// Datasets: `phantom`, and the real datasets engine, bonsai, cthead, vhf
    /// (from --data-dir; skipped with a warning when missing), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = ["phantom", "engine", "bonsai", "cthead", "vhf"].map(String::from))]
    pub datasets: Vec<String>,
    /// Where the real datasets are.
    #[arg(long, default_value = "../shared/data")]
    pub data_dir: PathBuf,
    /// Image edges to render, in pixels (square images), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [512u32, 1024],
          value_parser = setting_value::<u32>("w"))]
    pub sizes: Vec<u32>,
    /// Data reductions to render at (full voxels per voxel on the GPU), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 9.0, 35.0],
          value_parser = setting_value::<f32>("reduction"))]
    pub reductions: Vec<f32>,
    /// Shading modes, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [Shading::Gradient],
          value_parser = setting_value::<Shading>("shading"))]
    pub shadings: Vec<Shading>,
    /// Frames timed per measurement (after the frame that selects and uploads).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub frames: u32,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub data: DataArgs,
}

/// `voxserve bench read`.
#[derive(Debug, Args)]
pub struct BenchReadArgs {
    /// Size of the generated volume, GiB.
    #[arg(long, default_value_t = 2.0, value_parser = finite_in(0.01, 1024.0))]
    pub gib: f32,
}

/// `voxserve bench blocks`.
#[derive(Debug, Args)]
pub struct BenchBlocksArgs {
    /// Size of the generated 16-bit CT-like volume to ingest, GiB.
    #[arg(long, default_value_t = 2.0, value_parser = finite_in(0.01, 1024.0))]
    pub gib: f32,
    /// Random block reads per measurement.
    #[arg(long, default_value_t = 20_000, value_parser = clap::value_parser!(u32).range(1..=10_000_000))]
    pub reads: u32,
    /// Threads reading blocks.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=256))]
    pub threads: u32,
    /// Where the real datasets are (the engine and CT head are ingested and
    /// selected on when present).
    #[arg(long, default_value = "../shared/data")]
    pub data: PathBuf,
}
