//! The `voxserve` command line: its subcommands and flags (clap).

use std::net::SocketAddr;
use std::path::PathBuf;

use blocks::Preset;
use blocks::ingest::OpenOptions;
use blocks::ingest::raw::{self, RawOptions};
use clap::builder::PossibleValuesParser;
use clap::{Args, Parser, Subcommand};
use shaders::Compositing;
use shaders::extinction::{self, AoMethod, ExtinctionLight, ExtinctionSettings, ShadowMethod};
use shaders::frame::{MAX_IMAGE_EDGE, MAX_REDUCTION, parse_colour};
use shaders::light::{self, LightSettings, LightSource};
use shaders::{ClipBox, Projection, Shading, camera};

use crate::dataset::PHANTOM_ID;

/// Remote viewing of large 3D scans and simulations in a browser.
///
/// voxserve renders volumes on the GPU (through wgpu: Vulkan, Metal, DX12 or GL;
/// Mesa's lavapipe where there is no GPU) and serves the frames to a thin web
/// client. Without a dataset it serves a built-in CT head phantom.
///
/// Environment: WGPU_BACKEND picks the graphics backend (vulkan, gl, metal, dx12),
/// WGPU_ADAPTER_NAME picks an adapter by part of its name, RUST_LOG sets the log
/// level (default info).
#[derive(Debug, Parser)]
#[command(name = "voxserve", version)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Serve the web client and the render API, and print the URL to open.
    Serve(ServeArgs),
    /// Render one frame to a PNG file.
    Render(RenderArgs),
    /// Read a volume file or DICOM folder and print what it holds.
    Info(InfoArgs),
    /// Write a volume file or DICOM folder as a brick store (OME-Zarr, 16³ blocks
    /// at every level of detail), slab by slab in bounded memory.
    Ingest(IngestArgs),
    /// Measure phantom generation, frame rendering and slab reading; prints JSON lines.
    Bench(BenchArgs),
}

/// Where the volume comes from.
#[derive(Debug, Clone, Args)]
pub struct DataArgs {
    /// Edge length in voxels of the built-in phantom (16 to 512); it is generated at start.
    #[arg(long, default_value_t = blocks::phantom::DEFAULT_SIZE,
          value_parser = clap::value_parser!(u32).range(
              i64::from(blocks::phantom::MIN_SIZE)..=i64::from(blocks::phantom::MAX_SIZE)))]
    pub phantom_size: u32,
    /// Decoded blocks kept in memory, MiB (the two coarsest levels stay resident on top).
    #[arg(long, default_value_t = 1024, value_name = "MIB",
          value_parser = clap::value_parser!(u64).range(16..=1 << 20))]
    pub cache_mib: u64,
    /// Voxels kept on the GPU at most, MiB: a volume whose selected blocks need
    /// more renders at coarser levels of detail.
    #[arg(long, default_value_t = 2048, value_name = "MIB",
          value_parser = clap::value_parser!(u64).range(16..=1 << 20))]
    pub gpu_budget_mib: u64,
    #[command(flatten)]
    pub input: InputArgs,
}

impl DataArgs {
    /// `--cache-mib` in bytes.
    pub fn cache_bytes(&self) -> u64 {
        self.cache_mib << 20
    }

    /// `--gpu-budget-mib` in bytes.
    pub fn gpu_budget_bytes(&self) -> u64 {
        self.gpu_budget_mib << 20
    }
}

/// How to read a volume file where its headers leave choices.
#[derive(Debug, Clone, Default, Args)]
pub struct InputArgs {
    /// The DICOM series to read from a folder that holds several (an id as
    /// `voxserve info FOLDER` lists them).
    #[arg(long, value_name = "UID")]
    pub series: Option<String>,
    /// Raw files: dimensions as XxYxZ, e.g. 256x256x128 [default: from the file name].
    #[arg(long, value_name = "XxYxZ", value_parser = parse_dims)]
    pub raw_dims: Option<[u64; 3]>,
    /// Raw files: the voxel type [default: from the file name].
    #[arg(long, value_name = "TYPE", value_parser = PossibleValuesParser::new(
        ["uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"]))]
    pub raw_type: Option<String>,
    /// Raw files: the byte order [default: from the file name (…be/…le), else little].
    #[arg(long, value_name = "ORDER", value_parser = PossibleValuesParser::new(["little", "big"]))]
    pub raw_endian: Option<String>,
    /// Raw files: bytes to skip at the start (a header voxserve does not read).
    #[arg(long, value_name = "BYTES", default_value_t = 0)]
    pub raw_offset: u64,
    /// Raw files: voxel spacing in mm as X,Y,Z [default: 1,1,1].
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_spacing)]
    pub raw_spacing: Option<[f64; 3]>,
}

impl InputArgs {
    /// The reader options these flags give.
    pub fn open_options(&self) -> OpenOptions {
        OpenOptions {
            series: self.series.clone(),
            raw: RawOptions {
                dims: self.raw_dims,
                sample: self.raw_type.as_deref().and_then(raw::sample_type),
                big_endian: self.raw_endian.as_deref().map(|e| e == "big"),
                offset: self.raw_offset,
                spacing: self.raw_spacing,
                direction: None,
            },
        }
    }
}

/// `voxserve ingest`.
#[derive(Debug, Args)]
pub struct IngestArgs {
    /// A volume file (raw, .nrrd, .nhdr, .nii, .nii.gz, .mha, .mhd, .dcm) or a folder of DICOM files.
    pub input: PathBuf,
    /// The store to write (a folder; written under a temporary name and renamed when complete).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Replace the store if it exists (the old one stays until the new one is complete).
    #[arg(long)]
    pub force: bool,
    /// zstd compression level, 1 (fast) to 19 (small).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(i32).range(1..=19))]
    pub zstd_level: i32,
    #[command(flatten)]
    pub input_options: InputArgs,
}

/// `voxserve info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// A volume file (raw, .nrrd, .nhdr, .nii, .nii.gz, .mha, .mhd, .dcm) or a folder of DICOM files.
    pub path: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub input: InputArgs,
}

/// `voxserve serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// The datasets to serve, the first being the default: `phantom` (the
    /// built-in CT head phantom), brick stores (`voxserve ingest`), volume
    /// files or folders of DICOM files (bricked in memory at start).
    #[arg(default_values_t = [PHANTOM_ID.to_owned()], value_name = "DATASET")]
    pub datasets: Vec<String>,
    /// Also serve every brick store in this folder (after the DATASETs).
    #[arg(long = "data", value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Datasets whose blocks stay on the GPU at once; the one used least
    /// recently is released when another is needed.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u64).range(1..=64))]
    pub resident_datasets: u64,
    /// Address and port to listen on; port 0 picks a free port.
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: SocketAddr,
    #[command(flatten)]
    pub stream: StreamArgs,
    #[command(flatten)]
    pub data: DataArgs,
}

/// How view sessions (`/api/stream`) trade quality for speed.
#[derive(Debug, Clone, Args)]
pub struct StreamArgs {
    /// Milliseconds without a view change after which the full-quality,
    /// lossless frame is rendered.
    #[arg(long, default_value_t = 150, value_parser = clap::value_parser!(u64).range(0..=60_000))]
    pub idle_ms: u64,
    /// Image size while the user interacts, as a fraction of the full size.
    #[arg(long, default_value_t = 0.5, value_parser = finite_in(0.1, 1.0))]
    pub interactive_scale: f32,
    /// Data reduction while the user interacts, as a multiple of the view's
    /// (not applied with global light or extinction-based illumination, whose
    /// light would be recomputed).
    #[arg(long, default_value_t = 4.0, value_parser = finite_in(1.0, 1000.0))]
    pub interactive_reduction: f32,
    /// JPEG quality (1 to 100) of frames while the user interacts.
    #[arg(long, default_value_t = 80, value_parser = clap::value_parser!(u8).range(1..=100))]
    pub jpeg_quality: u8,
    /// Format of the lossless full frames: webp (lossless WebP, about 28 %
    /// smaller than PNG) or png (a little faster to encode); `bench stream`
    /// measures both.
    #[arg(long, default_value = "webp", value_parser = |t: &str| t.parse::<crate::encode::Lossless>())]
    pub lossless: crate::encode::Lossless,
    /// Frames a session sends ahead of the client's acknowledgements.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub frames_in_flight: u32,
    /// View sessions open at most; more are refused (HTTP 503).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u64).range(1..=4096))]
    pub max_sessions: u64,
}

impl StreamArgs {
    /// The settings these flags give.
    pub fn settings(&self) -> crate::stream::StreamSettings {
        crate::stream::StreamSettings {
            idle_ms: self.idle_ms,
            interactive_scale: self.interactive_scale,
            interactive_reduction: self.interactive_reduction,
            jpeg_quality: self.jpeg_quality,
            lossless: self.lossless,
            frames_in_flight: self.frames_in_flight,
            max_sessions: usize::try_from(self.max_sessions).unwrap_or(usize::MAX),
        }
    }
}

/// `voxserve render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// The dataset to render: `phantom` (the built-in CT head phantom), a brick
    /// store (`voxserve ingest`), a volume file or a folder of DICOM files.
    #[arg(default_value = PHANTOM_ID)]
    pub dataset: String,
    /// The PNG file to write [default: DATASET.png].
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Camera azimuth in degrees about the vertical axis: 0 looks at the face (from
    /// anterior), 90 from the patient's left.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true,
          value_parser = finite_in(-3600.0, 3600.0))]
    pub azimuth: f32,
    /// Camera elevation in degrees above the horizontal, -90 to 90.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true,
          value_parser = finite_in(-camera::MAX_ELEVATION_DEG, camera::MAX_ELEVATION_DEG))]
    pub elevation: f32,
    /// Camera distance from the volume's centre, in radii of its bounding sphere
    /// (0.05 to 100; below 1 the camera is inside the volume).
    #[arg(long, default_value_t = 3.0,
          value_parser = finite_in(camera::MIN_DISTANCE, camera::MAX_DISTANCE))]
    pub distance: f32,
    /// Vertical field of view in degrees (1 to 120); orthographic views are as
    /// tall as perspective ones at the volume's centre.
    #[arg(long, default_value_t = 30.0,
          value_parser = finite_in(camera::FOV_RANGE_DEG.0, camera::FOV_RANGE_DEG.1))]
    pub fov: f32,
    /// Camera projection.
    #[arg(long, default_value = "perspective",
          value_parser = PossibleValuesParser::new(Projection::ALL.map(Projection::name)))]
    pub projection: String,
    /// Image width in pixels (1 to 4096).
    #[arg(long, default_value_t = 512,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
    pub width: u32,
    /// Image height in pixels (1 to 4096).
    #[arg(long, default_value_t = 512,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
    pub height: u32,
    /// Transfer-function preset [default: ct-bone for CT, mr for MR, else generic].
    #[arg(long, value_parser = PossibleValuesParser::new(Preset::ALL.map(Preset::name)))]
    pub preset: Option<String>,
    /// Shading: gradient (Blinn–Phong from the data's gradient), unshaded,
    /// mip (maximum intensity projection), minip (minimum intensity projection)
    /// global (global light propagation: shadows and first-order scattering
    /// from the light of --light; see the light flags) or extinction
    /// (extinction-based: ambient occlusion and cone soft shadows from --lights;
    /// see the extinction flags).
    #[arg(long, default_value = "gradient",
          value_parser = PossibleValuesParser::new(Shading::ALL.map(Shading::name)))]
    pub shading: String,
    /// Distance between samples along a ray, in voxels (0.05 to 4); smaller is finer.
    #[arg(long, default_value_t = 0.5,
          value_parser = finite_in(shaders::frame::STEP_RANGE_VOXELS.0, shaders::frame::STEP_RANGE_VOXELS.1))]
    pub step: f32,
    /// Show only this box of the volume: six fractions of its extent x0,y0,z0,x1,y1,z1.
    #[arg(long, value_name = "X0,Y0,Z0,X1,Y1,Z1", default_value = "0,0,0,1,1,1",
          value_parser = |t: &str| t.parse::<ClipBox>())]
    pub clip: ClipBox,
    /// Data reduction: full-volume voxels per voxel kept on the GPU (1 to 10000);
    /// levels of detail are chosen from the transfer function to meet it.
    #[arg(long, default_value_t = 1.0, value_parser = finite_in(1.0, MAX_REDUCTION))]
    pub reduction: f32,
    /// Background colour as six hex digits rrggbb.
    #[arg(long, value_name = "RRGGBB", default_value = "000000", value_parser = parse_colour)]
    pub background: [f32; 3],
    #[command(flatten)]
    pub light: LightArgs,
    #[command(flatten)]
    pub extinction: ExtinctionArgs,
    /// How samples combine along a ray: alpha (α-blending) or extinction
    /// (exponential extinction, eq. 2 of Schlegel et al.).
    #[arg(long, default_value = "alpha", value_parser = |t: &str| t.parse::<Compositing>())]
    pub compositing: Compositing,
    /// Render on the CPU with the ray caster's CPU twin instead of the GPU (slow;
    /// for checking, or where no GPU driver is installed).
    #[arg(long)]
    pub cpu: bool,
    #[command(flatten)]
    pub data: DataArgs,
}

/// The light of `--shading global` (global light propagation with first-order
/// scattering).
#[derive(Debug, Clone, Args)]
pub struct LightArgs {
    /// The light: point:X,Y,Z (a point light at fractions of the volume's box:
    /// 0..1 is inside it) or directional:X,Y,Z (towards the light, patient
    /// LPS axes: x left, y posterior, z superior).
    #[arg(long, value_name = "KIND:X,Y,Z", default_value = "directional:-0.6,-0.5,0.62",
          value_parser = |t: &str| t.parse::<LightSource>())]
    pub light: LightSource,
    /// The light's colour as six hex digits rrggbb.
    #[arg(long, value_name = "RRGGBB", default_value = "ffffff", value_parser = parse_colour)]
    pub light_colour: [f32; 3],
    /// The light's intensity I0 (0 to 16).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true,
          value_parser = finite_in(0.0, light::MAX_INTENSITY))]
    pub light_intensity: f32,
    /// The minimum light level I_bias (0 to 1): no region is darker.
    #[arg(long, default_value_t = 0.15, allow_negative_numbers = true,
          value_parser = finite_in(0.0, 1.0))]
    pub light_bias: f32,
    /// Length L of the local piecewise segments, in voxels (4 to 32).
    #[arg(long, default_value_t = 8,
          value_parser = clap::value_parser!(u32).range(i64::from(light::SEGMENT_RANGE.0)..=i64::from(light::SEGMENT_RANGE.1)))]
    pub segment: u32,
    /// Resolution of the shadow volume: one point per N³ voxels (1, 2, 4 or 8).
    #[arg(long, default_value_t = 2, value_parser = parse_svr_scale)]
    pub svr_scale: u32,
    /// Radius R_Ω of the in-scattering sphere, in voxels (0 to 64; 0: no in-scattering).
    #[arg(long, default_value_t = 8.0, allow_negative_numbers = true,
          value_parser = finite_in(0.0, light::MAX_SCATTER_RADIUS))]
    pub scatter_radius: f32,
    /// In-scattering directions J (1 to 258), refined one per frame.
    #[arg(long, default_value_t = 18,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(light::MAX_DIRECTIONS)))]
    pub directions: u32,
    /// Henyey–Greenstein asymmetry g of the phase function (-0.9 to 0.9; 0: isotropic).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true,
          value_parser = finite_in(light::PHASE_G_RANGE.0, light::PHASE_G_RANGE.1))]
    pub phase_g: f32,
}

impl LightArgs {
    /// The light settings these flags give.
    pub fn settings(&self) -> LightSettings {
        LightSettings {
            source: self.light,
            colour: self.light_colour,
            intensity: self.light_intensity,
            segment_voxels: self.segment,
            svr_scale: self.svr_scale,
            scatter_radius_voxels: self.scatter_radius,
            directions: self.directions,
            phase_g: self.phase_g,
            bias: self.light_bias,
        }
    }
}

/// Lights of `--lights`, parsed as one value (clap would repeat a plain `Vec`).
pub type Lights = Vec<ExtinctionLight>;

/// The illumination of `--shading extinction` (ambient occlusion, colour
/// bleeding and cone soft shadows from a summed-area table of extinction).
#[derive(Debug, Clone, Args)]
pub struct ExtinctionArgs {
    /// The lights, separated by ';' (at most 4): point:X,Y,Z (fractions of the
    /// volume's box; 0..1 is inside), directional:X,Y,Z (towards the light,
    /// patient LPS) or spot:X,Y,Z:DX,DY,DZ:ANGLE (position, axis, half-angle in
    /// degrees), each optionally followed by :RRGGBB and :INTENSITY. Empty: ambient only.
    #[arg(long, value_name = "LIGHTS", default_value = "directional:-0.6,-0.5,0.62:ffffff:0.8",
          value_parser = extinction::parse_lights, allow_hyphen_values = true)]
    pub lights: Lights,
    /// Ambient light I_A (0 to 16).
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true,
          value_parser = finite_in(0.0, light::MAX_INTENSITY))]
    pub ambient: f32,
    /// Grid cells of the summed-area table and light cache along the volume's
    /// longest side (16 to 256; the others in proportion).
    #[arg(long, default_value_t = 128,
          value_parser = clap::value_parser!(u32).range(i64::from(extinction::SAT_SIZE_RANGE.0)..=i64::from(extinction::SAT_SIZE_RANGE.1)))]
    pub sat_size: u32,
    /// Ambient-occlusion radius R in grid cells (1 to 32).
    #[arg(long, default_value_t = 8,
          value_parser = clap::value_parser!(u32).range(i64::from(extinction::AO_RADIUS_RANGE.0)..=i64::from(extinction::AO_RADIUS_RANGE.1)))]
    pub ao_radius: u32,
    /// Ambient-occlusion shells (1 to 16, at most the radius).
    #[arg(long, default_value_t = 3,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(extinction::MAX_AO_SHELLS)))]
    pub ao_shells: u32,
    /// Ambient-occlusion strength (0 to 16): scales the exponent, the weighted
    /// mean Δt·τ of the neighbourhood (0.4: a flat opaque surface keeps about
    /// 45 % of the ambient light).
    #[arg(long, default_value_t = 0.4, allow_negative_numbers = true,
          value_parser = finite_in(0.0, extinction::MAX_AO_STRENGTH))]
    pub ao_strength: f32,
    /// Colour bleeding: neighbours tint the ambient light with their colour.
    #[arg(long)]
    pub colour_bleeding: bool,
    /// Half-angle of the shadow cones in degrees (0 to 45; wider is softer).
    #[arg(long, default_value_t = 3.0, allow_negative_numbers = true,
          value_parser = finite_in(0.0, extinction::MAX_CONE_ANGLE))]
    pub cone_angle: f32,
    /// Cuboids per volume side at the start of each cone (1 to 1000).
    #[arg(long, default_value_t = 50.0, allow_negative_numbers = true,
          value_parser = finite_in(extinction::CONE_FREQUENCY_RANGE.0, extinction::CONE_FREQUENCY_RANGE.1))]
    pub cone_frequency: f32,
    /// Growth of each cone cuboid's length over the one before (0 to 1).
    #[arg(long, default_value_t = 0.05, allow_negative_numbers = true,
          value_parser = finite_in(0.0, extinction::MAX_CONE_GROWTH))]
    pub cone_growth: f32,
    /// Ambient occlusion by SAT shells (sat) or by explicit sampling of the
    /// sphere (sampled, the reference).
    #[arg(long, default_value = "sat", value_parser = |t: &str| t.parse::<AoMethod>())]
    pub ao_method: AoMethod,
    /// Shadows by SAT cones (cone) or one classic shadow ray per light (ray, the reference).
    #[arg(long, default_value = "cone", value_parser = |t: &str| t.parse::<ShadowMethod>())]
    pub shadow_method: ShadowMethod,
}

impl ExtinctionArgs {
    /// The settings these flags give.
    pub fn settings(&self) -> ExtinctionSettings {
        ExtinctionSettings {
            sat_size: self.sat_size,
            ambient: self.ambient,
            ao_radius: self.ao_radius,
            ao_shells: self.ao_shells,
            ao_strength: self.ao_strength,
            colour_bleeding: self.colour_bleeding,
            lights: self.lights.clone(),
            cone_angle: self.cone_angle,
            cone_frequency: self.cone_frequency,
            cone_growth: self.cone_growth,
            ao_method: self.ao_method,
            shadow_method: self.shadow_method,
        }
    }
}

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
    /// full-resolution reference (time and ΔE colour difference).
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
    /// size for JPEG and lossless frames, encode time per format, and frames
    /// per second with several concurrent sessions.
    Stream(Box<BenchStreamArgs>),
    /// Extinction-based illumination as its paper reports it: summed-area-table
    /// build time per grid size, ambient occlusion per shell count against
    /// explicit sampling, soft shadows per cone sampling against one shadow
    /// ray (times and ΔE*uv), and lit against unlit frames.
    Extinction(Box<BenchExtinctionArgs>),
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
          value_parser = clap::value_parser!(u32).range(i64::from(extinction::SAT_SIZE_RANGE.0)..=i64::from(extinction::SAT_SIZE_RANGE.1)))]
    pub sat_sizes: Vec<u32>,
    /// Ambient-occlusion shell counts, comma separated (radius: the larger of
    /// --ao-radius and the count).
    #[arg(long, value_delimiter = ',', default_values_t = [3u32, 7, 11],
          value_parser = clap::value_parser!(u32).range(1..=i64::from(extinction::MAX_AO_SHELLS)))]
    pub shells: Vec<u32>,
    /// Ambient-occlusion radius in cells of the comparison with explicit sampling.
    #[arg(long, default_value_t = 7,
          value_parser = clap::value_parser!(u32).range(i64::from(extinction::AO_RADIUS_RANGE.0)..=i64::from(extinction::AO_RADIUS_RANGE.1)))]
    pub ao_radius: u32,
    /// Cone sampling frequencies (cuboids per volume side), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [20.0f32, 50.0],
          value_parser = finite_in(extinction::CONE_FREQUENCY_RANGE.0, extinction::CONE_FREQUENCY_RANGE.1))]
    pub cone_frequencies: Vec<f32>,
    /// Half-angle of the shadow cones, degrees.
    #[arg(long, default_value_t = 2.0, value_parser = finite_in(0.0, extinction::MAX_CONE_ANGLE))]
    pub cone_angle: f32,
    /// The largest grid the references (explicit AO sampling, shadow rays) run
    /// at; larger ones report the SAT methods only.
    #[arg(long, default_value_t = 256,
          value_parser = clap::value_parser!(u32).range(i64::from(extinction::SAT_SIZE_RANGE.0)..=i64::from(extinction::SAT_SIZE_RANGE.1)))]
    pub reference_max: u32,
    /// Image edge in pixels (square) of the compared and timed frames.
    #[arg(long, default_value_t = 512,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
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
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
    pub sizes: Vec<u32>,
    /// Camera events timed per size and format.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub events: u32,
    /// Concurrent sessions for the frame-rate measurements, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 4, 16],
          value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub sessions: Vec<u32>,
    /// Image edge of the frame-rate measurements.
    #[arg(long, default_value_t = 256,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
    pub session_size: u32,
    /// Seconds each frame-rate measurement runs.
    #[arg(long, default_value_t = 5.0, value_parser = finite_in(0.1, 3600.0))]
    pub seconds: f32,
    #[command(flatten)]
    pub data: DataArgs,
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
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
    pub size: u32,
    /// Data reductions (full voxels per voxel on the GPU), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 9.0, 35.0],
          value_parser = finite_in(1.0, MAX_REDUCTION))]
    pub reductions: Vec<f32>,
    /// SVR scales (1, 2, 4 or 8 voxels per SVR point along each axis), comma
    /// separated; the first one is used for (B) and (C).
    #[arg(long, value_delimiter = ',', default_values_t = [1u32, 2, 4, 8],
          value_parser = parse_svr_scale)]
    pub svr_scales: Vec<u32>,
    /// Segment lengths L in voxels for the table of (A) per SVR size and
    /// segment length, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [4u32, 8, 16, 32],
          value_parser = clap::value_parser!(u32).range(i64::from(light::SEGMENT_RANGE.0)..=i64::from(light::SEGMENT_RANGE.1)))]
    pub segments: Vec<u32>,
    /// Segment lengths L in voxels of the colour difference, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [8u32, 16],
          value_parser = clap::value_parser!(u32).range(i64::from(light::SEGMENT_RANGE.0)..=i64::from(light::SEGMENT_RANGE.1)))]
    pub quality_segments: Vec<u32>,
    /// Segment length L in voxels of (A), (B) and (C) per data reduction (the
    /// paper's: 8).
    #[arg(long, default_value_t = 8,
          value_parser = clap::value_parser!(u32).range(i64::from(light::SEGMENT_RANGE.0)..=i64::from(light::SEGMENT_RANGE.1)))]
    pub segment: u32,
    /// The data reduction of the table of (A) per SVR size and segment length
    /// (the paper's is 8.9:1).
    #[arg(long, default_value_t = 9.0, value_parser = finite_in(1.0, MAX_REDUCTION))]
    pub table_reduction: f32,
    /// Scattering radius R_Ω in voxels for (B).
    #[arg(long, default_value_t = 16.0, value_parser = finite_in(0.5, light::MAX_SCATTER_RADIUS))]
    pub scatter_radius: f32,
    /// In-scattering directions J for (B).
    #[arg(long, default_value_t = 18, value_parser = clap::value_parser!(u32).range(2..=i64::from(light::MAX_DIRECTIONS)))]
    pub directions: u32,
    /// Frames timed per frame measurement.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub frames: u32,
    /// Also write, per compared pair, the piecewise and reference frames and a
    /// ΔE error image (black 0, red 6 and above) as PNGs into this folder.
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,
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
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
    pub sizes: Vec<u32>,
    /// Data reductions to render at (full voxels per voxel on the GPU), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 9.0, 35.0],
          value_parser = finite_in(1.0, MAX_REDUCTION))]
    pub reductions: Vec<f32>,
    /// Shading modes, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [Shading::Gradient],
          value_parser = |t: &str| t.parse::<Shading>())]
    pub shadings: Vec<Shading>,
    /// Frames timed per measurement (after the frame that selects and uploads).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub frames: u32,
    /// Also time the packed CPU twin (slow).
    #[arg(long)]
    pub cpu: bool,
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

/// A clap value parser for a finite number in `lo..=hi`.
pub fn finite_in(
    lo: f32,
    hi: f32,
) -> impl Fn(&str) -> Result<f32, String> + Clone + Send + Sync + 'static {
    move |text| {
        let expected = || format!("expected a number from {lo} to {hi}, got '{text}'");
        let value: f32 = text.trim().parse().map_err(|_| expected())?;
        if value.is_finite() && (lo..=hi).contains(&value) {
            Ok(value)
        } else {
            Err(expected())
        }
    }
}

/// Parses an SVR scale: 1, 2, 4 or 8.
fn parse_svr_scale(text: &str) -> Result<u32, String> {
    text.trim()
        .parse::<u32>()
        .ok()
        .filter(|s| light::SVR_SCALES.contains(s))
        .ok_or_else(|| format!("expected 1, 2, 4 or 8, got '{text}'"))
}

/// Parses `XxYxZ` dimensions.
fn parse_dims(text: &str) -> Result<[u64; 3], String> {
    let parts: Vec<&str> = text.split('x').collect();
    let parsed: Option<Vec<u64>> = parts.iter().map(|p| p.trim().parse().ok()).collect();
    match parsed {
        Some(v) if v.len() == 3 && v.iter().all(|&d| d > 0) => Ok([v[0], v[1], v[2]]),
        _ => Err(format!(
            "expected three positive whole numbers like 256x256x128, got '{text}'"
        )),
    }
}

/// Parses `X,Y,Z` spacing in mm.
fn parse_spacing(text: &str) -> Result<[f64; 3], String> {
    let parsed: Option<Vec<f64>> = text.split(',').map(|p| p.trim().parse().ok()).collect();
    match parsed {
        Some(v) if v.len() == 3 && v.iter().all(|s| s.is_finite() && *s > 0.0) => {
            Ok([v[0], v[1], v[2]])
        }
        _ => Err(format!(
            "expected three positive numbers of mm like 1,1,2.5, got '{text}'"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_cli_is_well_formed() {
        Cli::command().debug_assert();
    }

    #[test]
    fn render_flags_parse_and_bad_values_are_refused_with_the_flag_named() {
        let cli = Cli::try_parse_from([
            "voxserve",
            "render",
            "--azimuth",
            "-45",
            "--width",
            "64",
            "--preset",
            "ct-angio",
        ])
        .expect("valid");
        let Command::Render(args) = cli.command else {
            panic!("expected render");
        };
        assert_eq!(args.azimuth, -45.0);
        assert_eq!(args.width, 64);
        for bad in [
            ["--width", "0"],
            ["--width", "100000"],
            ["--azimuth", "north"],
            ["--elevation", "NaN"],
            ["--preset", "bone"],
            ["--shading", "phong"],
            ["--lights", "lamp:0,0,0"],
            ["--ao-radius", "64"],
            ["--sat-size", "1024"],
            ["--compositing", "over"],
            ["--shadow-method", "rays"],
            ["--projection", "fisheye"],
            ["--clip", "0,0,0,1,1"],
            ["--reduction", "0.5"],
            ["--background", "blue"],
            ["--gpu-budget-mib", "0"],
            ["--raw-dims", "256x256"],
            ["--raw-spacing", "1,0,1"],
            ["--raw-type", "uint12"],
        ] {
            let err = Cli::try_parse_from(["voxserve", "render", bad[0], bad[1]])
                .expect_err("invalid")
                .to_string();
            assert!(err.contains(bad[0]), "{bad:?}: {err}");
        }
    }

    #[test]
    fn raw_flags_become_open_options() {
        let cli = Cli::try_parse_from([
            "voxserve",
            "info",
            "x.bin",
            "--raw-dims",
            "4x5x6",
            "--raw-type",
            "int16",
            "--raw-endian",
            "big",
            "--raw-offset",
            "12",
            "--raw-spacing",
            "1,1,2.5",
        ])
        .expect("valid");
        let Command::Info(args) = cli.command else {
            panic!("expected info");
        };
        let o = args.input.open_options();
        assert_eq!(o.raw.dims, Some([4, 5, 6]));
        assert_eq!(o.raw.sample, raw::sample_type("int16"));
        assert_eq!(o.raw.big_endian, Some(true));
        assert_eq!(o.raw.offset, 12);
        assert_eq!(o.raw.spacing, Some([1.0, 1.0, 2.5]));
    }
}
