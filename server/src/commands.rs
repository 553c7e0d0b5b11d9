//! The `voxserve` command line: `serve`, `render` and `bench`.

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use blocks::Preset;
use clap::builder::PossibleValuesParser;
use clap::{Args, Parser, Subcommand};
use shaders::frame::MAX_IMAGE_EDGE;
use shaders::{Camera, FrameRequest, GpuContext, Renderer, Shading, camera};
use tokio::net::TcpListener;

use crate::dataset::PHANTOM_ID;
use crate::{AppState, Dataset, RenderService, encode};

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
    /// Measure phantom generation and frame rendering; prints JSON lines.
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
}

/// `voxserve serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Address and port to listen on; port 0 picks a free port.
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: SocketAddr,
    #[command(flatten)]
    pub data: DataArgs,
}

/// `voxserve render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// The dataset to render: `phantom`, the built-in CT head phantom.
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
    /// Vertical field of view in degrees (1 to 120).
    #[arg(long, default_value_t = 30.0,
          value_parser = finite_in(camera::FOV_RANGE_DEG.0, camera::FOV_RANGE_DEG.1))]
    pub fov: f32,
    /// Image width in pixels (1 to 4096).
    #[arg(long, default_value_t = 512,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
    pub width: u32,
    /// Image height in pixels (1 to 4096).
    #[arg(long, default_value_t = 512,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
    pub height: u32,
    /// Transfer-function preset [default: ct-bone for CT data, else generic].
    #[arg(long, value_parser = PossibleValuesParser::new(Preset::ALL.map(Preset::name)))]
    pub preset: Option<String>,
    /// Shading: gradient (Blinn–Phong from the data's gradient) or unshaded.
    #[arg(long, default_value = "gradient",
          value_parser = PossibleValuesParser::new(Shading::ALL.map(Shading::name)))]
    pub shading: String,
    /// Distance between samples along a ray, in voxels (0.05 to 4); smaller is finer.
    #[arg(long, default_value_t = 0.5,
          value_parser = finite_in(shaders::frame::STEP_RANGE_VOXELS.0, shaders::frame::STEP_RANGE_VOXELS.1))]
    pub step: f32,
    /// Render on the CPU with the ray caster's CPU twin instead of the GPU (slow;
    /// for checking, or where no GPU driver is installed).
    #[arg(long)]
    pub cpu: bool,
    #[command(flatten)]
    pub data: DataArgs,
}

/// `voxserve bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Image edges to render, in pixels (square images), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [256u32, 512, 1024],
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_IMAGE_EDGE)))]
    pub sizes: Vec<u32>,
    /// Frames timed per size (after one untimed warm-up frame).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub frames: u32,
    /// Also time the CPU twin (slow).
    #[arg(long)]
    pub cpu: bool,
    #[command(flatten)]
    pub data: DataArgs,
}

/// The adapter features the CPU twin assumes: 16-bit volumes in `r16unorm`
/// textures, as on every Vulkan, Metal and DX12 adapter voxserve has met.
const CPU_TWIN_FEATURES: shaders::wgpu::Features =
    shaders::wgpu::Features::TEXTURE_FORMAT_16BIT_NORM;

/// A clap value parser for a finite number in `lo..=hi`.
fn finite_in(
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

/// Loads the dataset named on the command line.
fn load_dataset(name: &str, data: &DataArgs) -> anyhow::Result<Dataset> {
    if name != PHANTOM_ID {
        bail!("unknown dataset '{name}': expected '{PHANTOM_ID}', the built-in CT head phantom");
    }
    let start = Instant::now();
    let dataset = Dataset::phantom(data.phantom_size)?;
    tracing::info!(
        "generated the {n}³ phantom in {:.0} ms",
        start.elapsed().as_secs_f64() * 1e3,
        n = data.phantom_size
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
    let dataset = load_dataset(PHANTOM_ID, &args.data)?;
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
    let size = args.data.phantom_size;
    let mut generation_ms = Vec::new();
    let mut dataset = None;
    for _ in 0..3 {
        let start = Instant::now();
        dataset = Some(Dataset::phantom(size)?);
        generation_ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    let Some(dataset) = dataset else {
        bail!("the phantom was never generated");
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
        ] {
            let err = Cli::try_parse_from(["voxserve", "render", bad[0], bad[1]])
                .expect_err("invalid")
                .to_string();
            assert!(err.contains(bad[0]), "{bad:?}: {err}");
        }
    }

    #[test]
    fn an_unknown_dataset_is_refused() {
        let data = DataArgs { phantom_size: 16 };
        let err = load_dataset("engine", &data).expect_err("unknown");
        assert!(
            err.to_string().contains("unknown dataset 'engine'"),
            "{err}"
        );
    }
}
