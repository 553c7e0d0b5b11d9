//! The `voxserve` command line's subcommands and flags (clap): `serve`,
//! `render`, `info`, `ingest` and `settings`. The binary adds `bench`. The
//! view flags of `render` come from the settings schema ([`ViewArgs`]).

mod view_args;

use std::net::SocketAddr;
use std::path::PathBuf;

use blocks::ingest::OpenOptions;
use blocks::ingest::raw::{self, RawOptions};
use clap::builder::PossibleValuesParser;
use clap::{Args, Subcommand};
use shaders::settings::{Raw, SettingValue, Settings};
use shaders::{Backend, RendererChoice};

pub use view_args::ViewArgs;

use crate::dataset::PHANTOM_ID;

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Serve the web client and the render API, and print the URL to open.
    Serve(Box<ServeArgs>),
    /// Render one frame to a PNG file.
    Render(Box<RenderArgs>),
    /// Read a volume file or DICOM folder and print what it holds.
    Info(InfoArgs),
    /// Write a volume file or DICOM folder as a brick store (OME-Zarr, 16³ blocks
    /// at every level of detail), slab by slab in bounded memory.
    Ingest(IngestArgs),
    /// Check every file of a brick store against the manifest written at ingest
    /// (sizes and SHA-256); exits with an error naming each missing, changed or
    /// unexpected file.
    Verify(VerifyArgs),
    /// List every view setting: name, flag, what it takes and its default
    /// (`--json`: as `GET /api/settings` gives them).
    Settings(SettingsArgs),
    /// Studies on a PACS over DICOMweb: search them (QIDO-RS), list a
    /// study's series, fetch a series (WADO-RS) into a brick store.
    #[command(subcommand)]
    Pacs(PacsCommand),
    /// Make a static API token for scripts: prints the token (give it to the
    /// script; it is shown once) and, on standard error, the entry to add to
    /// the file `serve --api-tokens` reads (it holds only the token's hash).
    Token(TokenArgs),
}

/// `voxserve pacs …`.
#[derive(Debug, Subcommand)]
pub enum PacsCommand {
    /// Search a PACS's studies (QIDO-RS); one line per study (`--json`: one
    /// JSON object per line).
    Search(PacsSearchArgs),
    /// List a study's series (QIDO-RS).
    Series(PacsSeriesArgs),
    /// Fetch a series (WADO-RS, every instance as stored, several at a
    /// time) and write it as a brick store, as `ingest` writes the same
    /// files from a folder.
    Fetch(PacsFetchArgs),
}

/// Which PACS, and how to reach it.
#[derive(Debug, Args)]
pub struct PacsArgs {
    #[command(flatten)]
    pub link: PacsLinkArgs,
    /// Which PACS to ask, where several are given.
    #[arg(long, value_name = "NAME")]
    pub from: Option<String>,
}

/// The PACS (their DICOMweb services) and how to reach them.
#[derive(Debug, Args)]
pub struct PacsLinkArgs {
    /// A PACS's DICOMweb service: NAME=URL, e.g.
    /// main=https://pacs.example.org/dicom-web. Repeat for more.
    #[arg(long = "pacs", value_name = "NAME=URL",
          value_parser = crate::pacs::endpoint::parse_pacs)]
    pub pacs: Vec<crate::pacs::Endpoint>,
    /// The authorization a PACS needs: NAME=FILE, the file holding one line
    /// `Header-Name: value` or a bare token (sent as `Authorization: Bearer
    /// TOKEN`). Repeat for more.
    #[arg(long = "pacs-auth", value_name = "NAME=FILE",
          value_parser = crate::pacs::endpoint::parse_auth)]
    pub auth: Vec<(String, PathBuf)>,
    /// Seconds an answer may stall (no byte arriving) before it is given up.
    #[arg(long = "pacs-timeout-s", value_name = "SECONDS", default_value_t = 30,
          value_parser = clap::value_parser!(u64).range(1..=600))]
    pub timeout_s: u64,
}

/// `voxserve pacs search`.
#[derive(Debug, Args)]
pub struct PacsSearchArgs {
    #[command(flatten)]
    pub pacs: PacsArgs,
    /// PatientID (wildcards * and ?).
    #[arg(long, value_parser = |v: &str| crate::pacs::query::check_value("PatientID", v))]
    pub patient_id: Option<String>,
    /// PatientName (wildcards * and ?), e.g. "DOE^J*".
    #[arg(long, value_parser = |v: &str| crate::pacs::query::check_value("PatientName", v))]
    pub patient_name: Option<String>,
    /// AccessionNumber.
    #[arg(long, value_parser = |v: &str| crate::pacs::query::check_value("AccessionNumber", v))]
    pub accession: Option<String>,
    /// StudyDate: YYYYMMDD or a range YYYYMMDD-YYYYMMDD (either end may be left out).
    #[arg(long, value_parser = crate::pacs::DateRange::parse)]
    pub study_date: Option<crate::pacs::DateRange>,
    /// ModalitiesInStudy, e.g. CT.
    #[arg(long, value_parser = |v: &str| crate::pacs::query::check_value("ModalitiesInStudy", v))]
    pub modality: Option<String>,
    /// StudyInstanceUID.
    #[arg(long, value_parser = |v: &str| crate::pacs::query::check_uid("StudyInstanceUID", v))]
    pub study: Option<String>,
    /// Studies to list at most.
    #[arg(long, default_value_t = crate::pacs::query::DEFAULT_LIMIT,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(crate::pacs::query::MAX_LIMIT)))]
    pub limit: u32,
    /// Studies to pass over first.
    #[arg(long, default_value_t = 0)]
    pub offset: u32,
    /// Print JSON lines instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `voxserve pacs series`.
#[derive(Debug, Args)]
pub struct PacsSeriesArgs {
    #[command(flatten)]
    pub pacs: PacsArgs,
    /// StudyInstanceUID.
    #[arg(long, value_parser = |v: &str| crate::pacs::query::check_uid("StudyInstanceUID", v))]
    pub study: String,
    /// Print JSON lines instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `voxserve pacs fetch`.
#[derive(Debug, Args)]
pub struct PacsFetchArgs {
    #[command(flatten)]
    pub pacs: PacsArgs,
    /// StudyInstanceUID.
    #[arg(long, value_parser = |v: &str| crate::pacs::query::check_uid("StudyInstanceUID", v))]
    pub study: String,
    /// SeriesInstanceUID [default: the study's only series].
    #[arg(long, value_parser = |v: &str| crate::pacs::query::check_uid("SeriesInstanceUID", v))]
    pub series: Option<String>,
    /// The store to write (a folder; written under a temporary name and
    /// renamed when complete). The instances are kept beside it while they
    /// are read, and removed.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Replace the brick store at --out if there is one (as `ingest --force`).
    #[arg(long)]
    pub force: bool,
    /// zstd compression level, 1 (fast) to 19 (small).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(i32).range(1..=19))]
    pub zstd_level: i32,
    /// Instances retrieved at once.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub concurrency: u16,
    /// Most MiB of one instance.
    #[arg(long = "pacs-max-instance-mib", value_name = "MIB", default_value_t = 4096,
          value_parser = clap::value_parser!(u64).range(1..=65536))]
    pub max_instance_mib: u64,
}

/// `voxserve token`.
#[derive(Debug, Args)]
pub struct TokenArgs {
    /// Who the token is for (the user in the audit log).
    #[arg(long, value_parser = token_name)]
    pub name: String,
    /// A role of the token, as the policy file names roles. Repeat for more.
    #[arg(long = "role", value_name = "ROLE", value_parser = token_name)]
    pub roles: Vec<String>,
}

/// A token's name or role: 1 to 128 printable characters.
fn token_name(text: &str) -> Result<String, String> {
    if !text.is_empty() && text.len() <= 128 && text.chars().all(|c| !c.is_control()) {
        Ok(text.to_owned())
    } else {
        Err(format!("{text:?}: expected 1 to 128 printable characters"))
    }
}

/// `voxserve settings`.
#[derive(Debug, Args)]
pub struct SettingsArgs {
    /// Print JSON (as `GET /api/settings`) instead of Markdown tables.
    #[arg(long)]
    pub json: bool,
}

/// Which renderer draws.
#[derive(Debug, Clone, Copy, Args)]
pub struct RendererArgs {
    /// Which renderer draws: `auto` (the GPU; the CPU renderer when the only
    /// adapter is a software rasterizer such as lavapipe, or there is none),
    /// `gpu` (the best adapter, a software one too) or `cpu` (the CPU
    /// renderer, on every core: several times faster than a software
    /// adapter).
    #[arg(long = "renderer", default_value_t = RendererChoice::default(),
          value_name = "auto|gpu|cpu", value_parser = parse_renderer)]
    pub choice: RendererChoice,
}

/// `--renderer`'s value.
fn parse_renderer(text: &str) -> Result<RendererChoice, String> {
    RendererChoice::ALL
        .into_iter()
        .find(|c| c.name() == text)
        .ok_or_else(|| format!("expected auto, gpu or cpu, got '{text}'"))
}

impl RendererArgs {
    /// The backend `--renderer` picks.
    pub fn backend(&self) -> Result<Backend, shaders::GpuError> {
        Backend::choose(self.choice)
    }
}

/// Where the volume comes from.
#[derive(Debug, Clone, Args)]
pub struct DataArgs {
    /// Edge length in voxels of the built-in phantom (16 to 512); it is generated at start.
    #[arg(long, default_value_t = blocks::phantom::DEFAULT_SIZE,
          value_parser = clap::value_parser!(u32).range(
              i64::from(blocks::phantom::MIN_SIZE)..=i64::from(blocks::phantom::MAX_SIZE)))]
    pub phantom_size: u32,
    #[command(flatten)]
    pub memory: MemoryArgs,
    #[command(flatten)]
    pub input: InputArgs,
}

/// How much memory blocks may take: decoded in memory, and in the
/// renderer's atlas.
#[derive(Debug, Clone, Copy, Args)]
pub struct MemoryArgs {
    /// Decoded blocks kept in memory, MiB (the two coarsest levels stay resident on top).
    #[arg(long, default_value_t = 1024, value_name = "MIB",
          value_parser = clap::value_parser!(u64).range(16..=1 << 20))]
    pub cache_mib: u64,
    /// Voxels kept in the renderer's atlas at most (GPU memory, or memory for
    /// the CPU renderer, which keeps 4 bytes per voxel), MiB: a volume whose
    /// selected blocks need more renders at coarser levels of detail.
    #[arg(long, default_value_t = 2048, value_name = "MIB",
          value_parser = clap::value_parser!(u64).range(16..=1 << 20))]
    pub gpu_budget_mib: u64,
}

impl MemoryArgs {
    /// `--cache-mib` in bytes.
    pub fn cache_bytes(&self) -> u64 {
        self.cache_mib << 20
    }

    /// `--gpu-budget-mib` in bytes.
    pub fn gpu_budget_bytes(&self) -> u64 {
        self.gpu_budget_mib << 20
    }
}

impl DataArgs {
    /// `--cache-mib` in bytes.
    pub fn cache_bytes(&self) -> u64 {
        self.memory.cache_bytes()
    }

    /// `--gpu-budget-mib` in bytes.
    pub fn gpu_budget_bytes(&self) -> u64 {
        self.memory.gpu_budget_bytes()
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
    /// Raw files: the index axes' unit vectors in patient LPS (x to the
    /// patient's left, y posterior, z superior), column by column:
    /// x1,y1,z1,x2,y2,z2,x3,y3,z3 [default: 1,0,0,0,1,0,0,0,1].
    #[arg(long, value_name = "X1,Y1,Z1,…", value_parser = raw::parse_direction,
          allow_hyphen_values = true, conflicts_with = "raw_flip")]
    pub raw_direction: Option<[[f64; 3]; 3]>,
    /// Raw files: index axes that run against patient LPS, e.g. z for a scan
    /// stored from the top of the head down.
    #[arg(long, value_name = "AXES", value_parser = raw::parse_flip)]
    pub raw_flip: Option<[bool; 3]>,
    /// Read data files that lie outside the header's folder: a detached NRRD
    /// `data file`, a MetaImage `ElementDataFile` or a NIfTI `.img` that is (or
    /// links to) a file elsewhere, and symbolic links in a DICOM folder to files
    /// outside it. Without it such files are refused, so a header cannot make
    /// voxserve read, say, /etc/passwd as voxels.
    #[arg(long)]
    pub allow_data_outside: bool,
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
                direction: self.raw_direction.or(self.raw_flip.map(raw::flip_axes)),
            },
            allow_data_outside: self.allow_data_outside,
        }
    }
}

/// How stores on object storage are reached (flags of every command).
#[derive(Debug, Clone, Args)]
pub struct ObjectStoreArgs {
    /// Longest wait, in seconds, for an object store's whole answer to one
    /// request (s3://, gs://, az://, https:// stores); a request that waits
    /// longer fails and is retried.
    #[arg(long, global = true, default_value_t = 15, value_name = "S",
          value_parser = clap::value_parser!(u64).range(1..=600))]
    pub store_timeout_s: u64,
    /// Retries of a failed object-store request, with exponential backoff,
    /// before its blocks are reported unavailable (they are read again at a
    /// later frame).
    #[arg(long, global = true, default_value_t = 4, value_name = "N",
          value_parser = clap::value_parser!(u64).range(0..=20))]
    pub store_retries: u64,
    /// A folder on local disk that keeps what stores on object storage
    /// answered (each chunk under its object's URL, version — its ETag, or
    /// the SHA-256 in the store's manifest — and byte range), so
    /// that later reads, after a restart too, come from disk; one process
    /// per folder. None by default: every read goes to the store.
    #[arg(long, global = true, value_name = "DIR")]
    pub store_cache: Option<PathBuf>,
    /// The store cache's size on disk, MiB; the oldest ranges make room.
    #[arg(long, global = true, default_value_t = 10_240, value_name = "MIB",
          value_parser = clap::value_parser!(u64).range(
              blocks::store::disk_cache::MIN_MIB..=(1 << 24)))]
    pub store_cache_mib: u64,
}

impl ObjectStoreArgs {
    /// The policy of every object-store request.
    pub fn policy(&self) -> blocks::store::remote::Policy {
        blocks::store::remote::Policy {
            timeout: std::time::Duration::from_secs(self.store_timeout_s),
            retries: self.store_retries as usize,
        }
    }
}

/// `voxserve ingest`.
#[derive(Debug, Args)]
pub struct IngestArgs {
    /// A volume file (raw, .nrrd, .nhdr, .nii, .nii.gz, .mha, .mhd, .dcm) or a folder of DICOM files.
    pub input: PathBuf,
    /// The store to write: a folder (written under a temporary name and renamed
    /// when complete), or an object-store URL (s3://bucket/prefix/name.zarr:
    /// written locally, then uploaded, its manifest last).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Replace the brick store at --out if there is one (only a brick store: any
    /// other file or folder is refused). The old store stays in place until the
    /// new one is complete and on disk, then the two are exchanged atomically.
    #[arg(long)]
    pub force: bool,
    /// zstd compression level, 1 (fast) to 19 (small).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(i32).range(1..=19))]
    pub zstd_level: i32,
    #[command(flatten)]
    pub input_options: InputArgs,
}

/// `voxserve verify`.
#[derive(Debug, Args)]
pub struct VerifyArgs {
    /// The brick store (a folder written by `voxserve ingest`, or its
    /// object-store URL).
    pub store: PathBuf,
}

/// `voxserve info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// A volume file (raw, .nrrd, .nhdr, .nii, .nii.gz, .mha, .mhd, .dcm), a folder of DICOM
    /// files, or a brick store (a folder or an object-store URL).
    pub path: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub input: InputArgs,
}

/// The most characters of `--notice`.
pub const MAX_NOTICE: usize = 200;

/// `--notice`: one line of at most [`MAX_NOTICE`] characters.
fn parse_notice(text: &str) -> Result<String, String> {
    if text.chars().count() > MAX_NOTICE {
        return Err(format!(
            "{} characters: expected at most {MAX_NOTICE}",
            text.chars().count()
        ));
    }
    if text.chars().any(char::is_control) {
        return Err("a control character: expected one line of text".into());
    }
    Ok(text.trim().to_owned())
}

/// `voxserve serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// The datasets to serve, the first being the default: `phantom` (the
    /// built-in CT head phantom), brick stores (`voxserve ingest`; folders, or
    /// s3://, gs://, az:// or https:// URLs), volume files or folders of DICOM
    /// files (bricked in memory at start).
    #[arg(default_values_t = [PHANTOM_ID.to_owned()], value_name = "DATASET")]
    pub datasets: Vec<String>,
    /// Also serve every brick store in this folder or object-store prefix
    /// (s3://bucket/prefix/), after the DATASETs.
    #[arg(long = "data", value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Receive studies (STOW-RS, `POST /dicom-web/studies`) into this
    /// folder: every instance is kept, and each series is bricked and
    /// served (its id: the SeriesInstanceUID) once no new instance of it
    /// has come for --receive-settle-s. Series received before are served
    /// at start.
    #[arg(long = "receive", value_name = "DIR")]
    pub receive_dir: Option<PathBuf>,
    /// Seconds without a new instance after which a received series counts
    /// as complete and is bricked.
    #[arg(long = "receive-settle-s", value_name = "SECONDS", default_value_t = 10,
          value_parser = clap::value_parser!(u64).range(1..=3600))]
    pub receive_settle_s: u64,
    /// The most the received instances and their stores in --receive may
    /// take, MiB; past it, instances are refused (out of resources) until
    /// room is made. Nothing received is removed by the server.
    #[arg(long = "receive-max-mib", value_name = "MIB", default_value_t = 100 << 10,
          value_parser = clap::value_parser!(u64).range(1..=1 << 30))]
    pub receive_max_mib: u64,
    /// Also receive studies over DICOM: a C-STORE service class provider
    /// on this port (at --addr's address; 0 picks a free one) that keeps
    /// instances where --receive does and answers C-ECHO. Associations must
    /// call --ae-title from a calling AE title --dicom-allow names.
    #[arg(long, value_name = "PORT", requires = "receive_dir")]
    pub dicom_port: Option<u16>,
    /// This server's DICOM AE title (1 to 16 characters).
    #[arg(long, value_name = "TITLE", default_value = "VOXSERVE",
          value_parser = crate::dimse::parse_ae_title)]
    pub ae_title: String,
    /// A calling AE title that may open DICOM associations (repeat for
    /// several; `*` allows any). Needed with --dicom-port.
    #[arg(long = "dicom-allow", value_name = "TITLE", value_parser = crate::dimse::parse_caller)]
    pub dicom_allow: Vec<String>,
    /// The PACS the web client's study browser and IHE Invoke Image Display
    /// search (the first is the default); needs --pacs-cache.
    #[command(flatten)]
    pub pacs: PacsLinkArgs,
    /// Where series opened from the PACS are bricked and kept (served again
    /// at start); the store used least recently goes past --pacs-cache-mib.
    #[arg(long, value_name = "DIR")]
    pub pacs_cache: Option<PathBuf>,
    /// The most the series kept in --pacs-cache may take, MiB (the series
    /// just opened is kept whatever its size).
    #[arg(long, value_name = "MIB", default_value_t = 20 << 10,
          value_parser = clap::value_parser!(u64).range(1..=1 << 30))]
    pub pacs_cache_mib: u64,
    /// Datasets whose blocks stay on the GPU at once; the one used least
    /// recently is released when another is needed.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u64).range(1..=64))]
    pub resident_datasets: u64,
    /// The most a frame may cost, in pixel-samples (width × height × the
    /// samples a ray may take at the frame's step); a costlier request is
    /// refused before it renders. Frames costing more than one turn of the
    /// render worker (512² × 256) are drawn band by band, other clients'
    /// frames between the bands.
    #[arg(long, default_value_t = crate::render_service::MAX_FRAME_COST,
          value_parser = clap::value_parser!(u64).range(crate::render_service::TURN_COST..=1 << 40))]
    pub max_frame_cost: u64,
    /// Address and port to listen on; port 0 picks a free port.
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: SocketAddr,
    /// Listen on an address other than loopback although voxserve has no
    /// authentication configured (--oidc-issuer, --api-tokens): anyone who
    /// reaches the port sees every dataset. Only behind a proxy that
    /// authenticates every request.
    #[arg(long)]
    pub insecure_allow_anonymous: bool,
    /// A line every viewer shows over the image, e.g. "Not for diagnostic
    /// use" (at most 200 characters, no control characters).
    #[arg(long, value_name = "TEXT", value_parser = parse_notice)]
    pub notice: Option<String>,
    /// Seconds the view sessions get to finish their frames when the server
    /// drains on SIGTERM or Ctrl-C (it stops accepting connections at once;
    /// each session sends the frame it renders and closes with 1001, on
    /// which the viewer reconnects: behind a load balancer, to another
    /// node); sessions still open then are closed.
    #[arg(long, value_name = "SECONDS", default_value_t = crate::app::DEFAULT_DRAIN.as_secs(), value_parser = clap::value_parser!(u64).range(0..=3600))]
    pub drain_s: u64,
    #[command(flatten)]
    pub auth: AuthArgs,
    #[command(flatten)]
    pub access: AccessArgs,
    #[command(flatten)]
    pub stream: StreamArgs,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub data: DataArgs,
}

/// Who may ask, what they may see, and where accesses are recorded.
#[derive(Debug, Clone, Args)]
pub struct AuthArgs {
    /// Accept OpenID Connect access tokens of this issuer (its `iss`, an
    /// https:// URL; http:// only on loopback); its discovery document gives
    /// the keys and the web client's login endpoints.
    #[arg(long, value_name = "URL", value_parser = issuer_url, requires = "oidc_audience")]
    pub oidc_issuer: Option<String>,
    /// The audience (`aud`) the issuer's tokens must name.
    #[arg(long, value_name = "AUD", requires = "oidc_issuer")]
    pub oidc_audience: Option<String>,
    /// The issuer's keys (JWKS) from this URL or file instead of its
    /// discovery document.
    #[arg(long, value_name = "URL|FILE", requires = "oidc_issuer")]
    pub oidc_jwks: Option<String>,
    /// The web client's OAuth client id at the issuer (a public client,
    /// authorization code with PKCE, redirect URI: this server's URL).
    #[arg(long, value_name = "ID", requires = "oidc_issuer")]
    pub oidc_client_id: Option<String>,
    /// The scopes the web client asks for.
    #[arg(
        long,
        value_name = "SCOPES",
        default_value = "openid profile",
        requires = "oidc_issuer"
    )]
    pub oidc_scopes: String,
    /// Seconds `serve` keeps trying to reach the issuer at start (it may
    /// start before its identity provider); a wrong answer fails at once.
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u64).range(0..=3600), requires = "oidc_issuer")]
    pub oidc_wait_s: u64,
    /// Accept the static API tokens listed (hashed) in this JSON file
    /// (`voxserve token` makes them).
    #[arg(long, value_name = "FILE")]
    pub api_tokens: Option<PathBuf>,
    /// Who may see which dataset: a JSON policy file (roles → dataset ids
    /// or patterns; see ARCHITECTURE.md). Without one, every authenticated
    /// user sees every dataset.
    #[arg(long, value_name = "FILE")]
    pub policy: Option<PathBuf>,
    /// Append one JSON line per access event to this file (opened again on
    /// SIGHUP, for rotation) instead of the log.
    #[arg(long, value_name = "FILE")]
    pub audit_log: Option<PathBuf>,
    /// Serve over TLS with this certificate chain (PEM; read again on SIGHUP).
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The TLS certificate's private key (PEM).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// A source that may show the web client in a frame (a record system:
    /// `https://emr.example.org`); by default no page may. Repeat for more.
    #[arg(long = "frame-ancestor", value_name = "ORIGIN", value_parser = origin)]
    pub frame_ancestors: Vec<String>,
}

/// `--oidc-issuer`: an https:// URL, or http:// on a loopback host.
fn issuer_url(text: &str) -> Result<String, String> {
    let loopback = ["http://127.0.0.1", "http://localhost", "http://[::1]"];
    let ok = text.starts_with("https://")
        || loopback.iter().any(|p| {
            text.strip_prefix(p)
                .is_some_and(|rest| rest.is_empty() || rest.starts_with([':', '/']))
        });
    if ok && text.len() <= 2048 {
        Ok(text.to_owned())
    } else {
        Err(format!(
            "{text:?}: expected the issuer's https:// URL (http:// only on 127.0.0.1, ::1 or localhost)"
        ))
    }
}

/// The connection limits' defaults, as `serve`'s flags show them.
const DEFAULT_LIMITS: crate::listen::ConnectionLimits = crate::listen::ConnectionLimits::DEFAULT;

/// Who may reach the server, and how many connections it keeps.
#[derive(Debug, Clone, Args)]
pub struct AccessArgs {
    /// A host name the server answers to (requests naming another host are
    /// refused, against DNS rebinding); IP addresses and `localhost` always
    /// work. Repeat for more.
    #[arg(long = "host-name", value_name = "NAME", value_parser = host_name)]
    pub host_names: Vec<String>,
    /// A web origin (`https://viewer.example.org`) whose pages may open view
    /// sessions besides the server's own. Repeat for more.
    #[arg(long = "allow-origin", value_name = "ORIGIN", value_parser = origin)]
    pub allowed_origins: Vec<String>,
    /// Connections open at most; beyond it the quietest is closed. Keep it
    /// below the open-file limit (`ulimit -n`).
    #[arg(long, default_value_t = DEFAULT_LIMITS.max_connections as u64, value_parser = clap::value_parser!(u64).range(16..=1_000_000))]
    pub max_connections: u64,
    /// Connections of one client address open at most; beyond it the
    /// client's quietest is closed.
    #[arg(long, default_value_t = DEFAULT_LIMITS.per_client as u64, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    pub connections_per_client: u64,
    /// Seconds a request's headers may take to arrive.
    #[arg(long, default_value_t = DEFAULT_LIMITS.header_timeout.as_secs(), value_parser = clap::value_parser!(u64).range(1..=600))]
    pub header_timeout_s: u64,
    /// Seconds a connection may stay without reading or writing before it is
    /// closed.
    #[arg(long, default_value_t = DEFAULT_LIMITS.idle_timeout.as_secs(), value_parser = clap::value_parser!(u64).range(1..=86_400))]
    pub idle_timeout_s: u64,
    /// API requests a second one client (a signed-in user, else an
    /// address) may make, sustained; beyond it (and the burst) 429 with
    /// Retry-After.
    #[arg(long, default_value_t = crate::client::RequestRate::DEFAULT.per_second, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub requests_per_second: u32,
    /// API requests one client may make at once above that rate.
    #[arg(long, default_value_t = crate::client::RequestRate::DEFAULT.burst, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub request_burst: u32,
    /// The IP address of a load balancer or reverse proxy in front of the
    /// server, or a network of them in CIDR notation (10.0.0.0/8,
    /// fd00::/8): for their requests the client is the address their
    /// X-Forwarded-For header names (the audit trail records it; per-client
    /// limits count it), and their own connections are not capped per
    /// client. Repeat for more.
    #[arg(long = "trusted-proxy", value_name = "ADDRESS|NETWORK", value_parser = crate::listen::parse_trusted_proxy)]
    pub trusted_proxies: Vec<ipnet::IpNet>,
}

impl AccessArgs {
    /// The access these flags give.
    pub fn access(&self) -> crate::access::Access {
        crate::access::Access {
            host_names: self.host_names.clone(),
            allowed_origins: self.allowed_origins.clone(),
            connections: crate::listen::ConnectionLimits {
                max_connections: usize::try_from(self.max_connections).unwrap_or(usize::MAX),
                per_client: usize::try_from(self.connections_per_client).unwrap_or(usize::MAX),
                header_timeout: std::time::Duration::from_secs(self.header_timeout_s),
                idle_timeout: std::time::Duration::from_secs(self.idle_timeout_s),
            },
            requests: crate::client::RequestRate {
                per_second: self.requests_per_second,
                burst: self.request_burst,
            },
            trusted_proxies: self.trusted_proxies.clone(),
            ..crate::access::Access::default()
        }
    }
}

/// `--host-name`: a DNS name (letters, digits, `-` and `.`), lower-cased.
fn host_name(text: &str) -> Result<String, String> {
    let valid = !text.is_empty()
        && text.len() <= 253
        && text
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '.');
    if valid {
        Ok(text.to_ascii_lowercase())
    } else {
        Err(format!(
            "{text:?}: expected a host name of letters, digits, '-' and '.' (no port, no scheme)"
        ))
    }
}

/// `--allow-origin`: `http://` or `https://` and a host (and port), no path;
/// lower-cased.
fn origin(text: &str) -> Result<String, String> {
    let lower = text.trim_end_matches('/').to_ascii_lowercase();
    let authority = lower
        .strip_prefix("https://")
        .or_else(|| lower.strip_prefix("http://"));
    let valid = authority.is_some_and(|a| {
        !a.is_empty()
            && a.chars()
                .all(|c| c.is_ascii_alphanumeric() || "-.:[]".contains(c))
    });
    if valid {
        Ok(lower)
    } else {
        Err(format!(
            "{text:?}: expected an origin such as https://viewer.example.org (scheme, host, optional port; no path)"
        ))
    }
}

/// The stream settings' defaults, as `serve`'s flags show them.
const DEFAULT_STREAM: crate::stream::StreamSettings = crate::stream::StreamSettings::DEFAULT;

/// How view sessions (`/api/stream`) trade quality for speed.
#[derive(Debug, Clone, Args)]
pub struct StreamArgs {
    /// Milliseconds without a view change after which the full-quality,
    /// lossless frame is rendered.
    #[arg(long, default_value_t = DEFAULT_STREAM.idle_ms, value_parser = clap::value_parser!(u64).range(0..=60_000))]
    pub idle_ms: u64,
    /// Image size while the user interacts, as a fraction of the full size.
    #[arg(long, default_value_t = DEFAULT_STREAM.interactive_scale, value_parser = finite_in(0.1, 1.0))]
    pub interactive_scale: f32,
    /// Data reduction while the user interacts, as a multiple of the view's
    /// (not applied with global light or extinction-based illumination, whose
    /// light would be recomputed).
    #[arg(long, default_value_t = DEFAULT_STREAM.interactive_reduction, value_parser = finite_in(1.0, 1000.0))]
    pub interactive_reduction: f32,
    /// JPEG quality (1 to 100) of frames while the user interacts.
    #[arg(long, default_value_t = DEFAULT_STREAM.jpeg_quality, value_parser = clap::value_parser!(u8).range(1..=100))]
    pub jpeg_quality: u8,
    /// Format of the lossless full frames: webp (lossless WebP, about 28 %
    /// smaller than PNG) or png (a little faster to encode); `bench stream`
    /// measures both.
    #[arg(long, value_enum, default_value_t = DEFAULT_STREAM.lossless)]
    pub lossless: crate::encode::Lossless,
    /// Frames a session sends ahead of the client's acknowledgements.
    #[arg(long, default_value_t = DEFAULT_STREAM.frames_in_flight, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub frames_in_flight: u32,
    /// View sessions open at most; more are refused (HTTP 503).
    #[arg(long, default_value_t = DEFAULT_STREAM.max_sessions as u64, value_parser = clap::value_parser!(u64).range(1..=4096))]
    pub max_sessions: u64,
    /// View sessions of one client address open at most; more are refused
    /// (HTTP 429).
    #[arg(long, default_value_t = DEFAULT_STREAM.sessions_per_client as u64, value_parser = clap::value_parser!(u64).range(1..=4096))]
    pub sessions_per_client: u64,
    /// Seconds without a message from a viewer (it sends one whenever the
    /// user acts) after which its session is closed, freeing its place; the
    /// viewer reconnects when the user acts again.
    #[arg(long, default_value_t = DEFAULT_STREAM.session_idle_s, value_parser = clap::value_parser!(u64).range(1..=86_400))]
    pub session_idle_s: u64,
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
            sessions_per_client: usize::try_from(self.sessions_per_client).unwrap_or(usize::MAX),
            session_idle_s: self.session_idle_s,
        }
    }
}

/// `voxserve render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// The dataset to render: `phantom` (the built-in CT head phantom), a brick
    /// store (`voxserve ingest`; a folder, or an s3://, gs://, az:// or https://
    /// URL), a volume file or a folder of DICOM files.
    #[arg(default_value = PHANTOM_ID)]
    pub dataset: String,
    /// The PNG file to write [default: DATASET.png].
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// The view: one flag per setting of `/api/render` (see `voxserve
    /// settings`).
    #[command(flatten)]
    pub view: ViewArgs,
    #[command(flatten)]
    pub renderer: RendererArgs,
    #[command(flatten)]
    pub data: DataArgs,
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

/// A clap value parser for a value of the view setting `name` (benchmarks
/// sweep settings): read and checked as the setting takes it.
///
/// # Panics
/// When no view setting is called `name` (a programming error, caught by
/// `the_cli_is_well_formed`).
pub fn setting_value<T: SettingValue>(
    name: &'static str,
) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync + 'static {
    let check = crate::View::setting(name)
        .unwrap_or_else(|| panic!("no view setting is called {name}"))
        .spec()
        .check;
    move |text| T::read(&Raw::Text(text), &check).map_err(|expected| format!("expected {expected}"))
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
    use clap::{CommandFactory, Parser};
    use shaders::Settings;

    /// The subcommands as the binary parses them (it adds `bench`).
    #[derive(Debug, Parser)]
    struct Cli {
        #[command(subcommand)]
        command: Command,
    }

    #[test]
    fn a_notice_is_one_line_of_at_most_200_characters() {
        let serve = |notice: &str| {
            Cli::try_parse_from(["voxserve", "serve", "--notice", notice]).map(|c| {
                match c.command {
                    Command::Serve(args) => args.notice,
                    _ => None,
                }
            })
        };
        assert_eq!(
            serve(" Not for diagnostic use ").ok().flatten().as_deref(),
            Some("Not for diagnostic use")
        );
        let long = "x".repeat(MAX_NOTICE + 1);
        let refused = serve(&long).expect_err("too long").to_string();
        assert!(
            refused.contains("--notice") && refused.contains("at most 200"),
            "{refused}"
        );
        let refused = serve("two\nlines").expect_err("a newline").to_string();
        assert!(refused.contains("one line"), "{refused}");
    }

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
        assert_eq!(args.view.frame.camera.azimuth_deg, -45.0);
        assert_eq!(args.view.frame.width, 64);
        assert_eq!(args.view.frame.preset, Some(blocks::Preset::CtAngio));
        // Every setting of the frame request is a flag.
        let render = Cli::command();
        let render = render.find_subcommand("render").expect("render");
        for setting in shaders::FrameRequest::settings() {
            let flag = setting.spec().flag();
            assert!(
                render.get_arguments().any(|a| a.get_long() == Some(&*flag)),
                "render lacks --{flag}"
            );
        }
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
            "--raw-flip",
            "z",
            "--allow-data-outside",
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
        assert_eq!(
            o.raw.direction,
            Some([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
        );
        assert!(o.allow_data_outside);
    }
}
