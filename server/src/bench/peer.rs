//! `voxserve bench peer`: voxserve against VTK's ray casters on the same raw
//! file, image size, sample step, transfer function and camera, interleaved
//! in one run (only ratios from one run are trustworthy on a shared machine).
//!
//! VTK runs through `vtk_bench.py` (`../shared/bench`) in a Python with
//! `vtk` and `numpy`: `--python`, else a virtual environment this benchmark
//! creates once under the user's cache folder. Each round runs VTK, then
//! voxserve at VTK's camera (read from its first JSON line), each turning
//! the camera by VTK's azimuth step between frames; the last line per
//! dataset and mode gives the ratio of the medians and both images'
//! coverage (the fraction of pixels off the background, as VTK counts it),
//! which must agree within 5 % for the ratio to compare like with like.
//! It also gives both images' solid coverage (pixels clearly off the
//! background), the framing without the faintest haze: where values vary
//! from voxel to voxel on the transfer function's faint opacity ramp, both
//! of VTK's mappers draw the haze brighter than exact compositing does (as
//! if each interpolated value were rounded up to a whole number before the
//! lookup), so more of VTK's faintest pixels cross the threshold. On the
//! engine's composite frame `tests/peer/exact_composite.py` (float64, from
//! the definition, neither renderer's code) counts coverage 0.213 and
//! voxserve 0.213, VTK's FixedPoint mapper 0.245 and its GPU mapper 0.242.
//!
//! Modes: `composite` (VTK FixedPoint composite against unshaded frames),
//! `phong` (FixedPoint Phong against gradient shading with the cubic
//! B-spline's normals, what still frames draw), `phong_central` (the same
//! with central differences, the normals VTK's FixedPoint mapper shades with
//! and voxserve's frames of a moving view), `global_light` and
//! `extinction` (FixedPoint Phong against frames lit by the cached light,
//! shaded with the cubic B-spline's normals as still frames are),
//! `extinction_central` (the same with central differences, as frames of a
//! moving view are),
//! `shadows` (VTK's GPU mapper with volumetric shadows against global light).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::Context;
use blocks::ingest::OpenOptions;
use blocks::ingest::raw::RawOptions;
use blocks::ingest::stream::SampleType;
use blocks::{TfPoint, TransferFunction, VoxelType};
use shaders::{AnyRenderer, Camera, Choice, FrameRequest, Shading};

use super::args::BenchPeerArgs;
use server::Dataset;
use server::commands::say;

/// The background both renderers draw on (`vtk_bench.py`'s).
const BACKGROUND: [f32; 3] = [0.1, 0.1, 0.12];
/// Coverages closer than this (relative) frame the same object alike.
const COVERAGE_AGREEMENT: f64 = 0.05;
/// A pixel counts toward coverage when its channels' differences from the
/// background sum to more than this, of 255: `vtk_bench.py`'s threshold.
const COVERAGE_THRESHOLD: i32 = 3;
/// The same for solid coverage: pixels clearly off the background, the
/// object's silhouette without its faint haze. VTK brightens thin haze over
/// varying values (see the module docs), so where a transfer function's
/// faint ramp covers many voxels (the engine's) the two renderers'
/// coverages differ by more than the framing does.
const SOLID_COVERAGE_THRESHOLD: i32 = 48;

/// A raw dataset both renderers read, with what VTK needs to read it.
#[derive(Debug, Clone, Copy)]
struct PeerDataset {
    name: &'static str,
    file: &'static str,
    dims: [u32; 3],
    voxel_type: VoxelType,
    vtk_dtype: &'static str,
    big_endian: bool,
    spacing: [f64; 3],
    /// The scalar values the transfer function's 0..1 axis spans (for CT,
    /// those of −1000 and +1000 HU; for the 8-bit CTs, their useful range).
    tf_range: [f32; 2],
}

const DATASETS: [PeerDataset; 3] = [
    PeerDataset {
        name: "engine",
        file: "raw/engine_256x256x128_uint8.raw",
        dims: [256, 256, 128],
        voxel_type: VoxelType::U8,
        vtk_dtype: "uint8",
        big_endian: false,
        spacing: [1.0; 3],
        tf_range: [40.0, 255.0],
    },
    PeerDataset {
        name: "bonsai",
        file: "raw/bonsai_256x256x256_uint8.raw",
        dims: [256, 256, 256],
        voxel_type: VoxelType::U8,
        vtk_dtype: "uint8",
        big_endian: false,
        spacing: [1.0; 3],
        tf_range: [40.0, 255.0],
    },
    PeerDataset {
        name: "cthead",
        file: "raw/cthead_256x256x113_uint16be.raw",
        dims: [256, 256, 113],
        voxel_type: VoxelType::U16,
        vtk_dtype: "uint16",
        big_endian: true,
        spacing: [1.0, 1.0, 2.0],
        // Stored as HU + 1024.
        tf_range: [24.0, 2024.0],
    },
];

/// What is compared: a VTK mapper and mode against a voxserve shading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PeerMode {
    /// FixedPoint composite against unshaded frames.
    Composite,
    /// FixedPoint Phong against gradient shading (cubic B-spline normals).
    Phong,
    /// FixedPoint Phong against gradient shading with central differences.
    PhongCentral,
    /// FixedPoint Phong against frames lit by cached global light.
    GlobalLight,
    /// FixedPoint Phong against frames lit by cached extinction-based light
    /// (cubic B-spline normals).
    Extinction,
    /// The same with central differences.
    ExtinctionCentral,
    /// VTK's GPU mapper with volumetric shadows against cached global light.
    Shadows,
}

impl PeerMode {
    /// Every mode, for parsing.
    pub const ALL: [PeerMode; 7] = [
        PeerMode::Composite,
        PeerMode::Phong,
        PeerMode::PhongCentral,
        PeerMode::GlobalLight,
        PeerMode::Extinction,
        PeerMode::ExtinctionCentral,
        PeerMode::Shadows,
    ];

    /// The name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            PeerMode::Composite => "composite",
            PeerMode::Phong => "phong",
            PeerMode::PhongCentral => "phong_central",
            PeerMode::GlobalLight => "global_light",
            PeerMode::Extinction => "extinction",
            PeerMode::ExtinctionCentral => "extinction_central",
            PeerMode::Shadows => "shadows",
        }
    }

    /// VTK's mapper and mode.
    fn vtk(self) -> (&'static str, &'static str) {
        match self {
            PeerMode::Composite => ("fixedpoint", "composite"),
            PeerMode::Phong
            | PeerMode::PhongCentral
            | PeerMode::GlobalLight
            | PeerMode::Extinction
            | PeerMode::ExtinctionCentral => ("fixedpoint", "phong"),
            PeerMode::Shadows => ("gpu", "shadows"),
        }
    }

    /// `--modes`' value.
    pub fn parse(text: &str) -> Result<PeerMode, String> {
        PeerMode::ALL
            .into_iter()
            .find(|m| m.name() == text)
            .ok_or_else(|| {
                let names: Vec<&str> = PeerMode::ALL.map(PeerMode::name).to_vec();
                format!("expected one of {}, got '{text}'", names.join(", "))
            })
    }

    /// voxserve's shading.
    fn shading(self) -> Shading {
        match self {
            PeerMode::Composite => Shading::Unshaded,
            PeerMode::Phong | PeerMode::PhongCentral => Shading::Gradient,
            PeerMode::GlobalLight | PeerMode::Shadows => Shading::GlobalLight,
            PeerMode::Extinction | PeerMode::ExtinctionCentral => Shading::Extinction,
        }
    }

    /// Whether voxserve shades with the cubic B-spline's normals (what still
    /// frames draw) rather than central differences.
    fn cubic_normals(self) -> bool {
        !matches!(self, PeerMode::PhongCentral | PeerMode::ExtinctionCentral)
    }

    /// The ratio (voxserve over VTK) the targets ask for at most.
    fn target_ratio(self) -> f64 {
        match self {
            PeerMode::Composite | PeerMode::Phong | PeerMode::PhongCentral => 0.5,
            PeerMode::GlobalLight | PeerMode::Extinction | PeerMode::ExtinctionCentral => 1.0,
            PeerMode::Shadows => 1.0 / 30.0,
        }
    }
}

/// `vtk_bench.py`'s `build_tfs` (composite, Phong and shadow modes) as
/// voxserve control points over `range`: colour and opacity breakpoints
/// merged, each point carrying both functions' values there, so the
/// piecewise-linear function is the same.
fn vtk_transfer_function(range: [f32; 2]) -> TransferFunction {
    const COLOUR: [(f32, [f32; 3]); 6] = [
        (0.00, [0.0, 0.0, 0.0]),
        (0.45, [0.55, 0.25, 0.15]),
        (0.52, [0.88, 0.60, 0.50]),
        (0.64, [0.85, 0.15, 0.12]),
        (0.80, [1.00, 0.93, 0.80]),
        (1.00, [1.0, 1.0, 1.0]),
    ];
    const OPACITY: [(f32, f32); 8] = [
        (0.00, 0.0),
        (0.47, 0.0),
        (0.50, 0.002),
        (0.57, 0.002),
        (0.62, 0.25),
        (0.70, 0.50),
        (0.85, 0.85),
        (1.00, 0.95),
    ];
    fn lerp_at<const N: usize, T: Copy>(
        points: &[(f32, T); N],
        t: f32,
        mix: impl Fn(T, T, f32) -> T,
    ) -> T {
        let upper = points.partition_point(|p| p.0 <= t).clamp(1, N - 1);
        let (a, b) = (points[upper - 1], points[upper]);
        mix(a.1, b.1, ((t - a.0) / (b.0 - a.0)).clamp(0.0, 1.0))
    }
    let mut ts: Vec<f32> = COLOUR
        .iter()
        .map(|c| c.0)
        .chain(OPACITY.iter().map(|o| o.0))
        .collect();
    ts.sort_by(f32::total_cmp);
    ts.dedup();
    let points = ts
        .into_iter()
        .map(|t| {
            let rgb = lerp_at(&COLOUR, t, |a, b, f| {
                [0, 1, 2].map(|i| a[i] + (b[i] - a[i]) * f)
            });
            let opacity = lerp_at(&OPACITY, t, |a, b, f| a + (b - a) * f);
            TfPoint::new(range[0] + t * (range[1] - range[0]), rgb, opacity)
        })
        .collect();
    TransferFunction::new(points).expect("the points are ordered, finite and in 0..=1")
}

/// `voxserve bench peer`; see the module docs.
pub fn peer(args: &BenchPeerArgs) -> anyhow::Result<()> {
    let python = vtk_python(args.python.as_deref())?;
    let backend = args.renderer.backend()?;
    if let Some(dir) = &args.images {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--images: cannot create {}", dir.display()))?;
    }
    for name in &args.datasets {
        let Some(peer) = DATASETS.iter().find(|d| d.name == name) else {
            let names: Vec<&str> = DATASETS.iter().map(|d| d.name).collect();
            anyhow::bail!(
                "--datasets: unknown dataset '{name}': expected one of {}",
                names.join(", ")
            );
        };
        let path = args.data_dir.join(peer.file);
        if !path.exists() {
            tracing::warn!("{} not found: skipping {name}", path.display());
            continue;
        }
        let dataset = Dataset::load(&path, &open_options(peer), args.memory.cache_bytes())?;
        let mut renderer =
            backend.renderer(dataset.cache.clone(), args.memory.gpu_budget_bytes())?;
        for &mode in &args.modes {
            let run = PeerRun {
                args,
                python: &python,
                peer,
                path: &path,
                mode,
                backend: backend.describe(),
            };
            run.compare(&mut renderer)?;
        }
    }
    Ok(())
}

/// How voxserve reads a peer dataset: exactly what VTK is told.
fn open_options(peer: &PeerDataset) -> OpenOptions {
    OpenOptions {
        raw: RawOptions {
            dims: Some(peer.dims.map(u64::from)),
            sample: Some(SampleType::Voxel(peer.voxel_type)),
            big_endian: Some(peer.big_endian),
            spacing: Some(peer.spacing),
            ..RawOptions::default()
        },
        ..OpenOptions::default()
    }
}

/// One dataset and mode, compared over `--rounds` rounds.
struct PeerRun<'a> {
    args: &'a BenchPeerArgs,
    python: &'a Path,
    peer: &'a PeerDataset,
    path: &'a Path,
    mode: PeerMode,
    backend: String,
}

/// What one VTK run measured.
struct VtkRun {
    frame_ms: f64,
    coverage: Coverage,
    camera: Camera,
}

/// An image's coverage at the two thresholds.
#[derive(Debug, Clone, Copy, Default)]
struct Coverage {
    /// [`COVERAGE_THRESHOLD`]: as `vtk_bench.py` counts it.
    any: f64,
    /// [`SOLID_COVERAGE_THRESHOLD`].
    solid: f64,
}

impl Coverage {
    /// The coverages of RGBA8 pixels `rgba`.
    fn of(rgba: &[u8]) -> Coverage {
        Coverage {
            any: coverage(rgba, COVERAGE_THRESHOLD),
            solid: coverage(rgba, SOLID_COVERAGE_THRESHOLD),
        }
    }
}

/// Whether coverage `ours` agrees with `theirs` within [`COVERAGE_AGREEMENT`].
fn agrees(ours: f64, theirs: f64) -> bool {
    (ours - theirs).abs() <= COVERAGE_AGREEMENT * theirs
}

impl PeerRun<'_> {
    fn compare(&self, renderer: &mut AnyRenderer) -> anyhow::Result<()> {
        let (mut vtk_ms, mut voxserve_ms) = (Vec::new(), Vec::new());
        let (mut vtk_coverage, mut voxserve_coverage) = (Coverage::default(), Coverage::default());
        for round in 0..self.args.rounds {
            let vtk = self.vtk(round)?;
            vtk_ms.push(vtk.frame_ms);
            vtk_coverage = vtk.coverage;
            let (ms, coverage) = self.voxserve(renderer, vtk.camera, round)?;
            voxserve_ms.push(ms);
            voxserve_coverage = coverage;
        }
        let (vtk, ours) = (median(&mut vtk_ms), median(&mut voxserve_ms));
        let ratio = ours / vtk;
        let agree = agrees(voxserve_coverage.any, vtk_coverage.any);
        say(&serde_json::json!({
            "bench": "peer",
            "dataset": self.peer.name,
            "mode": self.mode.name(),
            "vtk": format!("{} {}", self.mode.vtk().0, self.mode.vtk().1),
            "voxserve": format!("{} ({})", self.mode.shading().name(), self.backend),
            "width": self.args.size,
            "height": self.args.size,
            "step_voxels": self.args.step,
            "rounds": self.args.rounds,
            "vtk_ms_median": vtk,
            "voxserve_ms_median": ours,
            "ratio": ratio,
            "target_ratio": self.mode.target_ratio(),
            "met": ratio <= self.mode.target_ratio() && agree,
            "vtk_coverage": vtk_coverage.any,
            "voxserve_coverage": voxserve_coverage.any,
            "coverage_agrees": agree,
            "vtk_solid_coverage": vtk_coverage.solid,
            "voxserve_solid_coverage": voxserve_coverage.solid,
            "solid_coverage_agrees": agrees(voxserve_coverage.solid, vtk_coverage.solid),
        })
        .to_string())
    }

    /// Runs `vtk_bench.py` once; returns its median frame time, the first
    /// frame's coverage and its camera as voxserve's.
    fn vtk(&self, round: u32) -> anyhow::Result<VtkRun> {
        let (mapper, mode) = self.mode.vtk();
        let [lo, hi] = self.peer.tf_range;
        let mut command = Command::new(self.python);
        command
            .env("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
            .arg(&self.args.vtk_bench)
            .arg("--raw")
            .arg(self.path)
            .arg("--dims")
            .args(self.peer.dims.map(|d| d.to_string()))
            .args(["--dtype", self.peer.vtk_dtype])
            .args([
                "--endian",
                if self.peer.big_endian {
                    "big"
                } else {
                    "little"
                },
            ])
            .arg("--spacing")
            .args(self.peer.spacing.map(|s| s.to_string()))
            .args(["--tf-range", &lo.to_string(), &hi.to_string()])
            .args(["--size", &self.args.size.to_string()])
            .args(["--mapper", mapper, "--mode", mode])
            .args(["--step", &self.args.step.to_string()])
            .args(["--frames", &self.args.frames.to_string()])
            .args(["--min-frames", &self.args.frames.min(3).to_string()]);
        // VTK's first frame as a PNG, for its coverages: in `--images`, else
        // in a folder removed when this run ends.
        let scratch;
        let dir = match &self.args.images {
            Some(dir) => dir.as_path(),
            None => {
                scratch = tempfile::tempdir()
                    .context("cannot create a temporary folder for VTK's image")?;
                scratch.path()
            }
        };
        let png = dir.join(format!(
            "{}-{}-vtk-{round}.png",
            self.peer.name,
            self.mode.name()
        ));
        command.arg("--png").arg(&png);
        let output = command.output().with_context(|| {
            format!(
                "cannot run {} {}",
                self.python.display(),
                self.args.vtk_bench.display()
            )
        })?;
        let stdout = String::from_utf8_lossy(&output.stdout);
        if !output.status.success() {
            anyhow::bail!(
                "vtk_bench.py failed ({}): {}",
                output.status,
                String::from_utf8_lossy(&output.stderr)
            );
        }
        let lines: Vec<serde_json::Value> = stdout
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect();
        let metric = |name: &str| lines.iter().find(|l| l["metric"] == name);
        let (Some(first), Some(frames)) = (metric("first_frame_ms"), metric("frame_ms")) else {
            anyhow::bail!("vtk_bench.py printed no first_frame_ms and frame_ms lines: {stdout}");
        };
        for line in &lines {
            say(&serde_json::json!({"bench": "peer", "round": round, "vtk": line}).to_string())?;
        }
        let frame_ms = frames["value"]
            .as_f64()
            .context("vtk_bench.py's frame_ms line has no value")?;
        let image = image::open(&png)
            .with_context(|| format!("cannot read VTK's image {}", png.display()))?
            .to_rgba8();
        let coverage = Coverage::of(image.as_raw());
        Ok(VtkRun {
            frame_ms,
            coverage,
            camera: self.camera(&first["camera"])?,
        })
    }

    /// VTK's camera (position and focal point in voxel index × spacing
    /// units) as voxserve's orbit camera around the volume's centre.
    fn camera(&self, vtk: &serde_json::Value) -> anyhow::Result<Camera> {
        let vec3 = |key: &str| -> anyhow::Result<[f64; 3]> {
            serde_json::from_value(vtk[key].clone())
                .with_context(|| format!("vtk_bench.py's camera has no {key} of 3 numbers"))
        };
        let (position, focal) = (vec3("position")?, vec3("focal_point")?);
        let toward_eye: [f64; 3] = [0, 1, 2].map(|i| position[i] - focal[i]);
        let length = |v: [f64; 3]| v.iter().map(|c| c * c).sum::<f64>().sqrt();
        let view_angle = vtk["view_angle_deg"]
            .as_f64()
            .context("vtk_bench.py's camera has no view_angle_deg")?;
        let extent = [0, 1, 2].map(|i| f64::from(self.peer.dims[i]) * self.peer.spacing[i]);
        let radius = length(extent) / 2.0;
        let distance = length(toward_eye);
        let [x, y, z] = toward_eye.map(|c| c / distance);
        Ok(Camera {
            azimuth_deg: x.atan2(-y).to_degrees() as f32,
            elevation_deg: z.asin().to_degrees() as f32,
            distance: (distance / radius) as f32,
            fov_y_deg: view_angle as f32,
            ..Camera::default()
        })
    }

    /// voxserve at `camera`: the first frame (selection, atlas and light)
    /// untimed, then `--frames` frames turning by VTK's azimuth step; returns
    /// the median frame time and the first frame's coverage.
    fn voxserve(
        &self,
        renderer: &mut AnyRenderer,
        camera: Camera,
        round: u32,
    ) -> anyhow::Result<(f64, Coverage)> {
        let request = FrameRequest {
            camera,
            shading: self.mode.shading(),
            cubic_gradient: self.mode.cubic_normals(),
            background: BACKGROUND,
            step_voxels: self.args.step,
            ..FrameRequest::new(
                self.args.size,
                self.args.size,
                vtk_transfer_function(self.peer.tf_range),
            )
        };
        let start = Instant::now();
        let first = renderer.render_converged(&request)?;
        let first_ms = start.elapsed().as_secs_f64() * 1e3;
        if let Some(dir) = &self.args.images {
            let png = dir.join(format!(
                "{}-{}-voxserve-{round}.png",
                self.peer.name,
                self.mode.name()
            ));
            std::fs::write(&png, server::encode::png(&first)?)
                .with_context(|| format!("cannot write {}", png.display()))?;
        }
        let mut times = Vec::new();
        for k in 1..=self.args.frames {
            let turned = FrameRequest {
                camera: Camera {
                    azimuth_deg: camera.azimuth_deg + VTK_AZIMUTH_STEP * k as f32,
                    ..camera
                },
                ..request.clone()
            };
            let start = Instant::now();
            renderer.render(&turned)?;
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
        let frame_ms = median(&mut times);
        let coverage = Coverage::of(&first.rgba);
        say(&serde_json::json!({
            "bench": "peer",
            "round": round,
            "voxserve": {
                "dataset": self.peer.name,
                "mode": self.mode.name(),
                "shading": self.mode.shading().name(),
                "cubic_gradient": self.mode.cubic_normals(),
                "renderer": self.backend,
                "width": self.args.size,
                "height": self.args.size,
                "step_voxels": self.args.step,
                "reduction": renderer.last_stats().reduction,
                "levels": renderer.last_stats().level_counts,
                "first_frame_ms": first_ms,
                "frames": self.args.frames,
                "frame_ms": frame_ms,
                "coverage": coverage.any,
                "solid_coverage": coverage.solid,
                "camera": format!("{camera:?}"),
            },
        })
        .to_string())?;
        Ok((frame_ms, coverage))
    }
}

/// `vtk_bench.py`'s default camera turn between frames, degrees.
const VTK_AZIMUTH_STEP: f32 = 2.0;

/// The fraction of RGBA8 pixels `rgba` off the background: channel
/// differences from it summing to more than `threshold` of 255.
fn coverage(rgba: &[u8], threshold: i32) -> f64 {
    let background = BACKGROUND.map(|c| (c * 255.0).round() as i32);
    let covered = rgba
        .chunks_exact(4)
        .filter(|p| {
            (0..3)
                .map(|i| (i32::from(p[i]) - background[i]).abs())
                .sum::<i32>()
                > threshold
        })
        .count();
    covered as f64 / (rgba.len() / 4).max(1) as f64
}

/// The median of `values` (sorted in place); NaN when empty.
fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    match values.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => values[n / 2],
        n => (values[n / 2 - 1] + values[n / 2]) / 2.0,
    }
}

/// A Python that imports `vtk` and `numpy`: `explicit` if given, else a
/// virtual environment under the user's cache folder, created (with `pip
/// install vtk numpy`) the first time.
fn vtk_python(explicit: Option<&Path>) -> anyhow::Result<PathBuf> {
    if let Some(python) = explicit {
        return Ok(python.to_path_buf());
    }
    let cache = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .context("neither XDG_CACHE_HOME nor HOME is set: pass --python")?;
    let venv = cache.join("voxserve").join("vtk-venv");
    let python = venv.join("bin").join("python");
    let has_vtk = |python: &Path| {
        Command::new(python)
            .args(["-c", "import vtk, numpy"])
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if has_vtk(&python) {
        return Ok(python);
    }
    tracing::info!("creating {} with vtk and numpy (once)", venv.display());
    let run = |command: &mut Command| -> anyhow::Result<()> {
        let output = command
            .output()
            .with_context(|| format!("cannot run {command:?}"))?;
        anyhow::ensure!(
            output.status.success(),
            "{command:?} failed: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        Ok(())
    };
    run(Command::new("python3").arg("-m").arg("venv").arg(&venv))?;
    run(Command::new(&python).args(["-m", "pip", "install", "--quiet", "vtk", "numpy"]))?;
    anyhow::ensure!(
        has_vtk(&python),
        "{} still cannot import vtk and numpy",
        python.display()
    );
    Ok(python)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pixel this far off the background along each channel (clamped to bytes).
    fn pixel(off: i32) -> [u8; 4] {
        let background = BACKGROUND.map(|c| (c * 255.0).round() as i32);
        let c = |i: usize| (background[i] + off).clamp(0, 255) as u8;
        [c(0), c(1), c(2), 255]
    }

    #[test]
    fn faint_haze_counts_toward_coverage_but_not_solid_coverage() {
        // Background, haze 2 off per channel (6 in all), an object 30 off (90).
        let rgba: Vec<u8> = [pixel(0), pixel(0), pixel(2), pixel(30)]
            .into_iter()
            .flatten()
            .collect();
        let c = Coverage::of(&rgba);
        assert_eq!((c.any, c.solid), (0.5, 0.25));
        assert!(agrees(0.2449, 0.24) && !agrees(0.2132, 0.2449));
    }
}
