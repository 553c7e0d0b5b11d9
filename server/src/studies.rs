//! Studies from the PACS for the web client: `serve --pacs NAME=URL
//! --pacs-cache DIR` lets the study browser search the PACS through the
//! server (the browser never talks to the PACS), list a study's series and
//! open one; IHE Invoke Image Display (`GET /IHEInvokeImageDisplay`) opens
//! the viewer on a study or a patient's studies.
//!
//! Opening a series fetches it over WADO-RS ([`crate::pacs::fetch`]) into a
//! spool folder in the cache, bricks it into `DIR/SERIES_UID.zarr` and
//! offers it as a dataset whose id is its SeriesInstanceUID; the client
//! follows the job (instances fetched, slices bricked) and shows it once
//! it is ready. Stores in the cache are served again at start; past the
//! cache's budget (`--pacs-cache-mib`) the store used least recently is
//! removed (and no longer offered). One job per series at a time; at most
//! [`MAX_BRICKING`] series bricked at once.
//!
//! | route | what |
//! |---|---|
//! | `GET /api/pacs` | the PACS names |
//! | `GET /api/pacs/studies?pacs=&PatientID=&PatientName=&AccessionNumber=&StudyDate=&ModalitiesInStudy=&StudyInstanceUID=&limit=&offset=` | QIDO-RS study search |
//! | `GET /api/pacs/series?pacs=&study=` | a study's series |
//! | `POST /api/pacs/open?pacs=&study=&series=` | open a series (starts its job) |
//! | `GET /api/pacs/open?pacs=&study=&series=` | that job's state |
//! | `GET /api/pacs/thumbnail?pacs=&study=&series=` | a series' image as the PACS renders it (WADO-RS rendered), PNG within 96² |
//! | `GET /api/pacs/iid?…` | an IHE IID request resolved: the studies, the series, the one to show |
//! | `GET /IHEInvokeImageDisplay?…` | checks the request (a readable page when malformed) and sends the browser to the viewer with it |
//!
//! All but the last need authentication and, with a policy, one of its
//! `pacs_roles` (default `pacs`).

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::SystemTime;

use axum::Extension;
use axum::Json;
use axum::extract::{ConnectInfo, Query, State};
use axum::http::{StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use serde::Serialize;

use crate::app::Datasets;
use crate::audit::{Event, Outcome};
use crate::auth::Principal;
use crate::pacs::fetch::{FetchOptions, Fetched, Preview, fetch_series_with_preview, open_fetched};
use crate::pacs::query::{check_uid, check_value};
use crate::pacs::{DateRange, DicomWeb, SeriesRecord, StudyQuery, StudyRecord};
use crate::{AppError, AppState, Dataset};

/// Series bricked at once (bricking is CPU-bound; fetching is not limited
/// here but by the fetch's own concurrency).
pub const MAX_BRICKING: usize = 2;
/// The cache's folder of previews.
const PREVIEWS: &str = ".preview";
/// Jobs remembered (finished ones are forgotten oldest first past this).
const MAX_JOBS: usize = 256;
/// Most studies an IID PATIENT request lists.
const MAX_PATIENT_STUDIES: u32 = 1000;

/// What the server knows of one series being opened.
#[derive(Debug, Clone, Serialize)]
pub struct Job {
    /// `fetching`, `bricking`, `ready` or `failed`.
    pub state: &'static str,
    pub pacs: String,
    pub study: String,
    pub series: String,
    /// Instances fetched, of `total`.
    pub fetched: usize,
    pub total: usize,
    /// Bytes fetched.
    pub bytes: u64,
    /// Slices bricked, of `slices` (0 until bricking starts).
    pub bricked: u32,
    pub slices: u32,
    /// The dataset's id once ready, or once its preview is.
    pub dataset: Option<String>,
    /// Whether what `dataset` offers now is a preview: a sample of the
    /// series' images (every k-th), offered while the rest arrives and
    /// replaced by the whole series.
    pub preview: bool,
    /// Why it failed.
    pub error: Option<String>,
}

impl Job {
    /// A job of `series` in `state`, nothing done yet.
    fn new(pacs: &DicomWeb, study: &str, series: &str, state: &'static str) -> Job {
        Job {
            state,
            pacs: pacs.name().to_owned(),
            study: study.to_owned(),
            series: series.to_owned(),
            fetched: 0,
            total: 0,
            bytes: 0,
            bricked: 0,
            slices: 0,
            dataset: None,
            preview: false,
            error: None,
        }
    }
}

/// The PACS the server searches, its cache of fetched series and their jobs.
#[derive(Debug)]
pub struct Studies {
    pacs: Vec<DicomWeb>,
    cache: PathBuf,
    budget_bytes: u64,
    block_cache_bytes: u64,
    fetch: FetchOptions,
    jobs: Mutex<Vec<Job>>,
    bricking: tokio::sync::Semaphore,
}

impl Studies {
    /// Searches `pacs`, caching fetched series in `cache` (made if missing)
    /// up to `budget_bytes`; stores' decoded blocks cached up to
    /// `block_cache_bytes` each.
    ///
    /// # Errors
    /// When the cache folder cannot be made.
    pub fn new(
        pacs: Vec<DicomWeb>,
        cache: &Path,
        budget_bytes: u64,
        block_cache_bytes: u64,
    ) -> anyhow::Result<Arc<Studies>> {
        std::fs::create_dir_all(cache).map_err(|e| {
            anyhow::anyhow!("--pacs-cache {}: cannot make it: {e}", cache.display())
        })?;
        // Spool folders of fetches cut short when the server last stopped,
        // and the previews of the last run.
        let _ = std::fs::remove_dir_all(cache.join(PREVIEWS));
        if let Ok(entries) = std::fs::read_dir(cache) {
            for entry in entries.filter_map(Result::ok) {
                if entry
                    .file_name()
                    .to_string_lossy()
                    .starts_with(".voxserve-fetch-")
                {
                    let _ = std::fs::remove_dir_all(entry.path());
                }
            }
        }
        Ok(Arc::new(Studies {
            pacs,
            cache: cache.to_owned(),
            budget_bytes,
            block_cache_bytes,
            fetch: FetchOptions::default(),
            jobs: Mutex::new(Vec::new()),
            bricking: tokio::sync::Semaphore::new(MAX_BRICKING),
        }))
    }

    /// The stores cached before, to offer at start.
    ///
    /// # Errors
    /// When the cache folder cannot be listed.
    pub fn stores(&self) -> anyhow::Result<Vec<PathBuf>> {
        crate::commands::stores_in(&self.cache)
    }

    /// The PACS called `name` (the first when `None`).
    fn pick(&self, name: Option<&str>) -> Result<&DicomWeb, AppError> {
        match name {
            None => self
                .pacs
                .first()
                .ok_or_else(|| AppError::NotFound("no PACS is configured (--pacs)".into())),
            Some(name) => self.pacs.iter().find(|p| p.name() == name).ok_or_else(|| {
                AppError::NotFound(format!(
                    "PACS {name:?}: expected one of {}",
                    self.pacs
                        .iter()
                        .map(|p| p.name().to_owned())
                        .collect::<Vec<_>>()
                        .join(", ")
                ))
            }),
        }
    }

    /// The job of `series`, if there is one.
    fn job(&self, series: &str) -> Option<Job> {
        self.lock().iter().find(|j| j.series == series).cloned()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Job>> {
        self.jobs.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Changes the job of `series`.
    fn update(&self, series: &str, change: impl FnOnce(&mut Job)) {
        if let Some(job) = self.lock().iter_mut().find(|j| j.series == series) {
            change(job);
        }
    }

    /// Opens `series` of `study` from `pacs`: ready when it is served
    /// already, else its job (started unless one is under way).
    fn open(
        self: &Arc<Self>,
        pacs: &DicomWeb,
        study: &str,
        series: &str,
        datasets: &Datasets,
    ) -> Job {
        // A series being opened (its preview perhaps offered already) is
        // not ready: its job says how far it is.
        if let Some(job) = self
            .job(series)
            .filter(|j| j.state == "fetching" || j.state == "bricking")
        {
            return job;
        }
        if datasets.contains(series) {
            touch(&self.cache.join(format!("{series}.zarr")));
            let mut job = Job::new(pacs, study, series, "ready");
            job.dataset = Some(series.to_owned());
            return job;
        }
        let job = {
            let mut jobs = self.lock();
            if let Some(job) = jobs
                .iter()
                .find(|j| j.series == series && j.state != "failed" && j.state != "ready")
            {
                return job.clone();
            }
            jobs.retain(|j| j.series != series);
            if jobs.len() >= MAX_JOBS
                && let Some(i) = jobs
                    .iter()
                    .position(|j| j.state == "failed" || j.state == "ready")
            {
                jobs.remove(i);
            }
            let job = Job::new(pacs, study, series, "fetching");
            jobs.push(job.clone());
            job
        };
        let studies = Arc::clone(self);
        let (pacs, datasets) = (pacs.clone(), datasets.clone());
        let (study, series) = (job.study.clone(), job.series.clone());
        tokio::spawn(async move {
            match studies.run(&pacs, &study, &series, &datasets).await {
                Ok(()) => studies.update(&series, |j| {
                    j.state = "ready";
                    j.preview = false;
                    j.dataset = Some(series.clone());
                }),
                Err(e) => {
                    let why = format!("{e:#}");
                    tracing::error!("opening series {series} from PACS {}: {why}", pacs.name());
                    // A preview of a series that did not arrive whole is
                    // no longer offered.
                    let previewed = studies.job(&series).is_some_and(|j| j.preview);
                    if previewed {
                        datasets.remove(&series);
                    }
                    studies.update(&series, |j| {
                        j.state = "failed";
                        j.preview = false;
                        j.dataset = None;
                        j.error = Some(why);
                    });
                }
            }
        });
        job
    }

    /// Fetches, bricks and offers a series.
    async fn run(
        self: &Arc<Self>,
        pacs: &DicomWeb,
        study: &str,
        series: &str,
        datasets: &Datasets,
    ) -> anyhow::Result<()> {
        let progress = |done: usize, total: usize, bytes: u64| {
            self.update(series, |j| {
                j.fetched = done;
                j.total = total;
                j.bytes = bytes;
            });
        };
        // A sample of a large series is bricked and offered while the rest
        // arrives (into `.preview/`, kept until the next start or until the
        // series leaves the cache: a view may still be drawing from it).
        let (sample_tx, sample_rx) = tokio::sync::oneshot::channel::<Fetched>();
        let previewing = {
            let (studies, id, datasets) = (Arc::clone(self), series.to_owned(), datasets.clone());
            tokio::spawn(async move {
                let Ok(sample) = sample_rx.await else {
                    return;
                };
                let s = Arc::clone(&studies);
                let made = tokio::task::spawn_blocking(move || s.brick_preview(&sample)).await;
                match made {
                    Ok(Ok(dataset)) => {
                        let mut offered = false;
                        studies.update(&id, |j| {
                            if j.state == "fetching" {
                                j.preview = true;
                                j.dataset = Some(id.clone());
                                offered = true;
                            }
                        });
                        if offered {
                            datasets.add(dataset);
                        }
                    }
                    Ok(Err(e)) => tracing::warn!("series {id}: no preview: {e:#}"),
                    Err(e) => tracing::warn!("series {id}: no preview: {e}"),
                }
            })
        };
        let hand_over: Preview<'_> = Box::new(move |sample| {
            let _ = sample_tx.send(sample);
        });
        let fetched = fetch_series_with_preview(
            pacs,
            study,
            series,
            &self.cache,
            self.fetch,
            &progress,
            Some(hand_over),
        )
        .await;
        let _ = previewing.await;
        let fetched = fetched?;
        let _place = self.bricking.acquire().await?;
        self.update(series, |j| j.state = "bricking");
        let studies = Arc::clone(self);
        let id = series.to_owned();
        let dataset = tokio::task::spawn_blocking(move || -> anyhow::Result<Dataset> {
            let mut source = open_fetched(&fetched)?;
            let out = studies.cache.join(format!("{id}.zarr"));
            let options = blocks::store::IngestOptions {
                overwrite: true,
                ..blocks::store::IngestOptions::default()
            };
            blocks::store::ingest(source.as_mut(), &out, &options, &mut |p| {
                // Two passes: scanning the values, then writing the blocks.
                let (done, all) = match p {
                    blocks::store::IngestProgress::Scanning(done, all) => (done, 2 * all),
                    blocks::store::IngestProgress::Writing(done, all) => (all + done, 2 * all),
                };
                studies.update(&id, |j| {
                    j.bricked = done;
                    j.slices = all;
                });
            })?;
            drop(fetched);
            let store = blocks::store::Store::open(&out)?;
            Ok(Dataset::new(id, store, studies.block_cache_bytes)?)
        })
        .await??;
        datasets.add(dataset);
        tracing::info!(
            "series {series} of study {study} from PACS {} served",
            pacs.name()
        );
        self.evict(series, datasets);
        Ok(())
    }

    /// Bricks a sample of a series into `.preview/` and opens it.
    fn brick_preview(&self, sample: &Fetched) -> anyhow::Result<Dataset> {
        let mut source = open_fetched(sample)?;
        let out = self
            .cache
            .join(PREVIEWS)
            .join(format!("{}.zarr", sample.series));
        std::fs::create_dir_all(self.cache.join(PREVIEWS))?;
        let options = blocks::store::IngestOptions {
            overwrite: true,
            ..blocks::store::IngestOptions::default()
        };
        blocks::store::ingest(source.as_mut(), &out, &options, &mut |_| {})?;
        let store = blocks::store::Store::open(&out)?;
        Ok(Dataset::new(
            sample.series.clone(),
            store,
            self.block_cache_bytes,
        )?)
    }

    /// Removes the stores used least recently (never `keep`) until the
    /// cache fits its budget.
    fn evict(&self, keep: &str, datasets: &Datasets) {
        let Ok(entries) = std::fs::read_dir(&self.cache) else {
            return;
        };
        let mut stores: Vec<(SystemTime, u64, String, PathBuf)> = entries
            .filter_map(Result::ok)
            .filter_map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                let id = name.strip_suffix(".zarr")?.to_owned();
                let used = e.metadata().and_then(|m| m.modified()).ok()?;
                Some((used, folder_bytes(&e.path()), id, e.path()))
            })
            .collect();
        let mut total: u64 = stores.iter().map(|s| s.1).sum();
        stores.sort();
        for (_, bytes, id, path) in stores {
            if total <= self.budget_bytes {
                break;
            }
            if id == keep {
                continue;
            }
            datasets.remove(&id);
            let _ = std::fs::remove_dir_all(self.cache.join(PREVIEWS).join(format!("{id}.zarr")));
            match std::fs::remove_dir_all(&path) {
                Ok(()) => {
                    total -= bytes;
                    tracing::info!(
                        "--pacs-cache: removed series {id} ({} MB), used least recently, to stay within the budget",
                        bytes / 1_000_000
                    );
                }
                Err(e) => tracing::error!("--pacs-cache: cannot remove {}: {e}", path.display()),
            }
        }
    }
}

/// Marks a cached store as used now (its folder's modification time).
fn touch(path: &Path) {
    if let Ok(dir) = std::fs::File::open(path) {
        let _ = dir.set_modified(SystemTime::now());
    }
}

/// Bytes of the files under `path`.
pub(crate) fn folder_bytes(path: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(path) else {
        return 0;
    };
    entries
        .filter_map(Result::ok)
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => folder_bytes(&e.path()),
            Ok(t) if t.is_file() => e.metadata().map_or(0, |m| m.len()),
            _ => 0,
        })
        .sum()
}

/// The server's [`Studies`], if it has a PACS, for a principal allowed to
/// use it.
fn studies_for(
    state: &AppState,
    principal: &Principal,
    client: SocketAddr,
) -> Result<Arc<Studies>, AppError> {
    let Some(studies) = state.studies.clone() else {
        return Err(AppError::NotFound(
            "the server has no PACS; start it with --pacs NAME=URL --pacs-cache DIR".into(),
        ));
    };
    if !state.auth.may_use_pacs(principal) {
        state.audit(&Event::new(
            "pacs",
            Some(principal),
            Some(client.ip()),
            Outcome::Denied,
        ));
        return Err(AppError::Forbidden(format!(
            "{} has no PACS role (the policy file's pacs_roles)",
            principal.user
        )));
    }
    Ok(studies)
}

fn pacs_error(e: &crate::pacs::PacsError) -> AppError {
    AppError::BadGateway(e.to_string())
}

/// `GET /api/pacs`.
pub async fn list(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
) -> Result<Json<serde_json::Value>, AppError> {
    let studies = studies_for(&state, &principal, client)?;
    let names: Vec<&str> = studies.pacs.iter().map(DicomWeb::name).collect();
    Ok(Json(serde_json::json!({ "pacs": names })))
}

/// A study found, and on which PACS.
#[derive(Debug, Serialize)]
pub struct Found {
    pacs: String,
    #[serde(flatten)]
    study: StudyRecord,
}

/// The query string's value of `key`, if given and not empty.
fn param<'a>(params: &'a HashMap<String, String>, key: &str) -> Option<&'a str> {
    params.get(key).map(|v| v.trim()).filter(|v| !v.is_empty())
}

fn number(params: &HashMap<String, String>, key: &str) -> Result<u32, AppError> {
    param(params, key).map_or(Ok(0), |v| {
        v.parse()
            .map_err(|_| AppError::BadRequest(format!("{key} {v:?}: expected a whole number")))
    })
}

/// `GET /api/pacs/studies`.
pub async fn search(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    Query(params): Query<HashMap<String, String>>,
) -> Result<Json<Vec<Found>>, AppError> {
    let studies = studies_for(&state, &principal, client)?;
    let pacs = studies.pick(param(&params, "pacs"))?;
    let text = |key: &str| -> Result<Option<String>, AppError> {
        param(&params, key)
            .map(|v| check_value(key, v).map_err(AppError::BadRequest))
            .transpose()
    };
    let query = StudyQuery {
        patient_name: text("PatientName")?,
        patient_id: text("PatientID")?,
        accession_number: text("AccessionNumber")?,
        study_date: param(&params, "StudyDate")
            .map(|v| {
                DateRange::parse(v).map_err(|e| AppError::BadRequest(format!("StudyDate: {e}")))
            })
            .transpose()?,
        modality: text("ModalitiesInStudy")?,
        study_uid: param(&params, "StudyInstanceUID")
            .map(|v| check_uid("StudyInstanceUID", v).map_err(AppError::BadRequest))
            .transpose()?,
        limit: number(&params, "limit")?,
        offset: number(&params, "offset")?,
    };
    query.check().map_err(AppError::BadRequest)?;
    let found = pacs
        .search_studies(&query)
        .await
        .map_err(|e| pacs_error(&e))?;
    state.audit(
        &Event::new(
            "pacs",
            Some(&principal),
            Some(client.ip()),
            Outcome::Success,
        )
        .detail(format!(
            "study search on PACS {}: {} found",
            pacs.name(),
            found.len()
        )),
    );
    Ok(Json(
        found
            .into_iter()
            .map(|study| Found {
                pacs: pacs.name().to_owned(),
                study,
            })
            .collect(),
    ))
}

/// A series of a study, and whether it looks like a volume.
#[derive(Debug, Serialize)]
pub struct Listed {
    #[serde(flatten)]
    series: SeriesRecord,
    /// Whether it may be a volume: more than one image, or one that may
    /// hold several frames (what opening it tells for sure).
    volume: bool,
    /// Whether the server offers it already (cached).
    cached: bool,
}

/// Whether a series may be a volume, from its search record.
fn may_be_volume(series: &SeriesRecord) -> bool {
    let not_images = ["SR", "PR", "KO", "REG", "SEG", "RTSTRUCT", "RTPLAN", "DOC"];
    let modality = series.modality.as_deref().unwrap_or("");
    !not_images.contains(&modality) && series.instances.is_none_or(|n| n >= 1)
}

/// `GET /api/pacs/series`.
pub async fn series(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    Query(params): Query<HashMap<String, String>>,
) -> Result<Json<Vec<Listed>>, AppError> {
    let studies = studies_for(&state, &principal, client)?;
    let pacs = studies.pick(param(&params, "pacs"))?;
    let study =
        check_uid("study", param(&params, "study").unwrap_or("")).map_err(AppError::BadRequest)?;
    let list = pacs
        .search_series(&study)
        .await
        .map_err(|e| pacs_error(&e))?;
    Ok(Json(listed(list, &state.datasets)))
}

fn listed(list: Vec<SeriesRecord>, datasets: &Datasets) -> Vec<Listed> {
    let mut list: Vec<Listed> = list
        .into_iter()
        .map(|series| Listed {
            volume: may_be_volume(&series),
            cached: datasets.contains(&series.series_uid),
            series,
        })
        .collect();
    list.sort_by_key(|l| {
        (
            l.series.number.unwrap_or(i64::MAX),
            l.series.series_uid.clone(),
        )
    });
    list
}

/// Edge of a series' thumbnail, pixels.
pub const THUMBNAIL_EDGE: u32 = 96;

/// `GET /api/pacs/thumbnail`: a series' image as the PACS renders it.
pub async fn thumbnail(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    Query(params): Query<HashMap<String, String>>,
) -> Result<Response, AppError> {
    let studies = studies_for(&state, &principal, client)?;
    let pacs = studies.pick(param(&params, "pacs"))?;
    let study =
        check_uid("study", param(&params, "study").unwrap_or("")).map_err(AppError::BadRequest)?;
    let series = check_uid("series", param(&params, "series").unwrap_or(""))
        .map_err(AppError::BadRequest)?;
    let png = pacs
        .series_thumbnail(&study, &series, THUMBNAIL_EDGE)
        .await
        .map_err(|e| match e {
            crate::pacs::PacsError::Status { status: 404, .. } => AppError::NotFound(format!(
                "series {series}: PACS {} renders no image of it",
                pacs.name()
            )),
            e => pacs_error(&e),
        })?;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "private, max-age=3600"),
        ],
        png,
    )
        .into_response())
}

/// `POST /api/pacs/open`: starts opening a series.
pub async fn open(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    Query(params): Query<HashMap<String, String>>,
) -> Result<Json<Job>, AppError> {
    let studies = studies_for(&state, &principal, client)?;
    let pacs = studies.pick(param(&params, "pacs"))?;
    let study =
        check_uid("study", param(&params, "study").unwrap_or("")).map_err(AppError::BadRequest)?;
    let series = check_uid("series", param(&params, "series").unwrap_or(""))
        .map_err(AppError::BadRequest)?;
    let job = studies.open(pacs, &study, &series, &state.datasets);
    state.audit(
        &Event::new(
            "pacs",
            Some(&principal),
            Some(client.ip()),
            Outcome::Success,
        )
        .dataset(&series)
        .detail(format!(
            "open series of study {study} from PACS {}",
            pacs.name()
        )),
    );
    Ok(Json(job))
}

/// `GET /api/pacs/open`: how opening a series goes.
pub async fn progress(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    Query(params): Query<HashMap<String, String>>,
) -> Result<Json<Job>, AppError> {
    let studies = studies_for(&state, &principal, client)?;
    let series = check_uid("series", param(&params, "series").unwrap_or(""))
        .map_err(AppError::BadRequest)?;
    if let Some(job) = studies.job(&series) {
        return Ok(Json(job));
    }
    if state.datasets.contains(&series) {
        let pacs = studies.pick(param(&params, "pacs"))?;
        let study = param(&params, "study").unwrap_or("").to_owned();
        return Ok(Json(studies.open(pacs, &study, &series, &state.datasets)));
    }
    Err(AppError::NotFound(format!(
        "series {series}: not being opened (POST /api/pacs/open starts it)"
    )))
}

/// An IHE Invoke Image Display request (IHE RAD TF-2 §4.106), checked.
#[derive(Debug, Clone, PartialEq)]
pub enum Invoke {
    /// `requestType=STUDY`: by StudyInstanceUID or by AccessionNumber.
    Study {
        study_uids: Vec<String>,
        accession_numbers: Vec<String>,
    },
    /// `requestType=PATIENT`.
    Patient {
        patient_id: String,
        /// `lowerDateTime`, `upperDateTime` (their dates).
        dates: Option<DateRange>,
        /// `mostRecentResults`.
        most_recent: Option<u32>,
        /// `modalitiesInStudy`.
        modalities: Vec<String>,
    },
}

/// Checks an IID request's parameters: `requestType` (STUDY or PATIENT);
/// for STUDY `studyUID` or `accessionNumber` (comma-separated lists, not
/// both); for PATIENT `patientID` (its ID component) and optionally
/// `lowerDateTime`, `upperDateTime`, `mostRecentResults`,
/// `modalitiesInStudy`; `viewerType`, `diagnosticQuality` and
/// `keyImagesOnly` are checked and accepted (this viewer is the one type
/// there is; frames are lossless when still; every image is shown).
///
/// # Errors
/// Which parameter is wrong, and what was expected.
pub fn parse_invoke(params: &HashMap<String, String>) -> Result<Invoke, String> {
    let list = |key: &str| -> Vec<String> {
        param(params, key)
            .map(|v| {
                v.split(',')
                    .map(|s| s.trim().to_owned())
                    .filter(|s| !s.is_empty())
                    .collect()
            })
            .unwrap_or_default()
    };
    for key in ["diagnosticQuality", "keyImagesOnly"] {
        if let Some(v) = param(params, key)
            && v != "true"
            && v != "false"
        {
            return Err(format!("{key} {v:?}: expected true or false"));
        }
    }
    if let Some(v) = param(params, "viewerType") {
        check_value("viewerType", v)?;
    }
    match param(params, "requestType") {
        Some("STUDY") => {
            let (study_uids, accession_numbers) = (list("studyUID"), list("accessionNumber"));
            match (study_uids.is_empty(), accession_numbers.is_empty()) {
                (true, true) => {
                    return Err(
                        "requestType=STUDY without studyUID or accessionNumber: expected one of them"
                            .into(),
                    );
                }
                (false, false) => {
                    return Err(
                        "requestType=STUDY with both studyUID and accessionNumber: expected one of them"
                            .into(),
                    );
                }
                _ => {}
            }
            if study_uids.len() + accession_numbers.len() > 100 {
                return Err("over 100 studies: expected at most 100".into());
            }
            for uid in &study_uids {
                check_uid("studyUID", uid)?;
            }
            for number in &accession_numbers {
                check_value("accessionNumber", number)?;
            }
            Ok(Invoke::Study {
                study_uids,
                accession_numbers,
            })
        }
        Some("PATIENT") => {
            let id = param(params, "patientID")
                .ok_or("requestType=PATIENT without patientID: expected one")?;
            // The CX form ID^^^&ISSUER&ISO: the ID component.
            let patient_id = check_value("patientID", id.split('^').next().unwrap_or(id))?;
            let date = |key: &str| -> Result<Option<String>, String> {
                param(params, key)
                    .map(|v| {
                        let day = v.get(..10).unwrap_or(v);
                        let digits: String = day.chars().filter(char::is_ascii_digit).collect();
                        if digits.len() == 8 && day.len() == 10 && day.as_bytes()[4] == b'-' {
                            Ok(digits)
                        } else {
                            Err(format!(
                                "{key} {v:?}: expected an ISO 8601 date and time, e.g. 2026-11-26T08:00:00"
                            ))
                        }
                    })
                    .transpose()
            };
            let (lower, upper) = (date("lowerDateTime")?, date("upperDateTime")?);
            let dates = match (lower, upper) {
                (None, None) => None,
                (l, u) => Some(DateRange::parse(&format!(
                    "{}-{}",
                    l.unwrap_or_default(),
                    u.unwrap_or_default()
                ))?),
            };
            let most_recent = param(params, "mostRecentResults")
                .map(|v| {
                    v.parse::<u32>()
                        .ok()
                        .filter(|n| (1..=MAX_PATIENT_STUDIES).contains(n))
                        .ok_or_else(|| {
                            format!(
                                "mostRecentResults {v:?}: expected a whole number from 1 to {MAX_PATIENT_STUDIES}"
                            )
                        })
                })
                .transpose()?;
            let modalities = list("modalitiesInStudy");
            for m in &modalities {
                check_value("modalitiesInStudy", m)?;
            }
            Ok(Invoke::Patient {
                patient_id,
                dates,
                most_recent,
                modalities,
            })
        }
        Some(other) => Err(format!("requestType {other:?}: expected STUDY or PATIENT")),
        None => Err("no requestType: expected STUDY or PATIENT".into()),
    }
}

/// What an IID request resolves to.
#[derive(Debug, Serialize)]
pub struct Resolved {
    /// The studies found (newest first for a patient).
    studies: Vec<Found>,
    /// For a study request: the first study's series, and the one to show.
    series: Vec<Listed>,
    show: Option<String>,
}

/// The series of `list` to show first: one that may be a volume, of an
/// imaging modality, with the most images.
fn pick_series(list: &[Listed]) -> Option<String> {
    list.iter()
        .filter(|l| l.volume)
        .max_by_key(|l| {
            let imaging = matches!(
                l.series.modality.as_deref(),
                Some("CT" | "MR" | "PT" | "NM" | "US" | "XA")
            );
            (imaging, l.series.instances.unwrap_or(0))
        })
        .map(|l| l.series.series_uid.clone())
}

/// `GET /api/pacs/iid`: an IID request resolved on the PACS.
pub async fn resolve(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    Query(params): Query<HashMap<String, String>>,
) -> Result<Json<Resolved>, AppError> {
    let studies = studies_for(&state, &principal, client)?;
    let pacs = studies.pick(param(&params, "pacs"))?;
    let invoke = parse_invoke(&params).map_err(AppError::BadRequest)?;
    let found = |records: Vec<StudyRecord>| -> Vec<Found> {
        records
            .into_iter()
            .map(|study| Found {
                pacs: pacs.name().to_owned(),
                study,
            })
            .collect()
    };
    let mut resolved = Resolved {
        studies: Vec::new(),
        series: Vec::new(),
        show: None,
    };
    match invoke {
        Invoke::Study {
            study_uids,
            accession_numbers,
        } => {
            let keys = study_uids
                .iter()
                .map(|u| StudyQuery {
                    study_uid: Some(u.clone()),
                    ..StudyQuery::default()
                })
                .chain(accession_numbers.iter().map(|a| StudyQuery {
                    accession_number: Some(a.clone()),
                    ..StudyQuery::default()
                }));
            for query in keys {
                let records = pacs
                    .search_studies(&query)
                    .await
                    .map_err(|e| pacs_error(&e))?;
                resolved.studies.extend(found(records));
            }
            let Some(first) = resolved.studies.first() else {
                let asked = if study_uids.is_empty() {
                    format!("accession number {}", accession_numbers.join(", "))
                } else {
                    format!("study {}", study_uids.join(", "))
                };
                return Err(AppError::NotFound(format!(
                    "{asked}: not found on PACS {}",
                    pacs.name()
                )));
            };
            let list = pacs
                .search_series(&first.study.study_uid)
                .await
                .map_err(|e| pacs_error(&e))?;
            resolved.series = listed(list, &state.datasets);
            resolved.show = pick_series(&resolved.series);
            if resolved.show.is_none() {
                return Err(AppError::NotFound(format!(
                    "study {}: no series on PACS {} that may be a volume",
                    first.study.study_uid,
                    pacs.name()
                )));
            }
        }
        Invoke::Patient {
            patient_id,
            dates,
            most_recent,
            modalities,
        } => {
            let mut records = Vec::new();
            for modality in modalities.iter().map(Some).chain(
                // No modality named: one search for any.
                modalities.is_empty().then_some(None),
            ) {
                let query = StudyQuery {
                    patient_id: Some(patient_id.clone()),
                    study_date: dates,
                    modality: modality.cloned(),
                    limit: MAX_PATIENT_STUDIES,
                    ..StudyQuery::default()
                };
                for r in pacs
                    .search_studies(&query)
                    .await
                    .map_err(|e| pacs_error(&e))?
                {
                    if !records
                        .iter()
                        .any(|s: &StudyRecord| s.study_uid == r.study_uid)
                    {
                        records.push(r);
                    }
                }
            }
            records.sort_by(|a, b| b.study_date.cmp(&a.study_date));
            if let Some(n) = most_recent {
                records.truncate(n as usize);
            }
            if records.is_empty() {
                return Err(AppError::NotFound(format!(
                    "patient {patient_id}: no studies found on PACS {}",
                    pacs.name()
                )));
            }
            resolved.studies = found(records);
        }
    }
    state.audit(
        &Event::new(
            "pacs",
            Some(&principal),
            Some(client.ip()),
            Outcome::Success,
        )
        .detail(format!(
            "IHE Invoke Image Display on PACS {}: {} studies",
            pacs.name(),
            resolved.studies.len()
        )),
    );
    Ok(Json(resolved))
}

/// `GET /IHEInvokeImageDisplay`: a malformed request gets a readable page
/// (400) naming the parameter; a well-formed one is sent to the viewer
/// (303), which resolves it after logging in and shows the study, the
/// patient's studies, or a readable message when there is nothing to show.
pub async fn invoke(
    State(state): State<AppState>,
    Query(params): Query<HashMap<String, String>>,
    uri: axum::http::Uri,
) -> Response {
    if state.studies.is_none() {
        return page(
            StatusCode::NOT_FOUND,
            "No PACS",
            "This voxserve has no PACS to show studies from (it was started without --pacs).",
        );
    }
    if let Err(why) = parse_invoke(&params) {
        return page(
            StatusCode::BAD_REQUEST,
            "Cannot open the images",
            &format!("The request to show images is not one voxserve understands: {why}."),
        );
    }
    let query = uri.query().unwrap_or("");
    (
        StatusCode::SEE_OTHER,
        [(header::LOCATION, format!("/#iid={}", percent(query)))],
    )
        .into_response()
}

/// `text` with every byte but unreserved ones percent-encoded.
fn percent(text: &str) -> String {
    text.bytes()
        .map(|b| {
            if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
                (b as char).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect()
}

/// A small readable HTML page.
fn page(status: StatusCode, title: &str, text: &str) -> Response {
    let escape = |s: &str| {
        s.replace('&', "&amp;")
            .replace('<', "&lt;")
            .replace('>', "&gt;")
            .replace('"', "&quot;")
    };
    let body = format!(
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><meta name=\"viewport\" content=\"width=device-width, initial-scale=1\"><title>voxserve: {}</title><style>body{{font:16px/1.5 system-ui,sans-serif;max-width:40em;margin:3em auto;padding:0 1em;background:#111;color:#eee}}h1{{font-size:1.4em}}</style></head><body><h1>{}</h1><p>{}</p></body></html>",
        escape(title),
        escape(title),
        escape(text)
    );
    (status, Html(body)).into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(pairs: &[(&str, &str)]) -> HashMap<String, String> {
        pairs
            .iter()
            .map(|(k, v)| ((*k).to_owned(), (*v).to_owned()))
            .collect()
    }

    #[test]
    fn iid_requests_are_checked() {
        assert_eq!(
            parse_invoke(&params(&[
                ("requestType", "STUDY"),
                ("studyUID", "1.2.3,1.2.4")
            ])),
            Ok(Invoke::Study {
                study_uids: vec!["1.2.3".into(), "1.2.4".into()],
                accession_numbers: vec![],
            })
        );
        assert!(
            parse_invoke(&params(&[
                ("requestType", "STUDY"),
                ("studyUID", "1.2.3"),
                ("accessionNumber", "A1")
            ]))
            .is_err()
        );
        assert!(parse_invoke(&params(&[("requestType", "STUDY")])).is_err());
        assert!(parse_invoke(&params(&[("requestType", "SERIES"), ("studyUID", "1.2")])).is_err());
        assert!(parse_invoke(&params(&[("requestType", "STUDY"), ("studyUID", "1..2")])).is_err());
        assert!(
            parse_invoke(&params(&[
                ("requestType", "STUDY"),
                ("studyUID", "1.2"),
                ("keyImagesOnly", "yes")
            ]))
            .is_err()
        );
        let patient = parse_invoke(&params(&[
            ("requestType", "PATIENT"),
            ("patientID", "12345^^^&1.2.3&ISO"),
            ("lowerDateTime", "2020-01-01T00:00:00"),
            ("mostRecentResults", "3"),
            ("modalitiesInStudy", "CT,MR"),
            ("viewerType", "IHE_BIR"),
            ("diagnosticQuality", "true"),
        ]))
        .expect("a patient request");
        let Invoke::Patient {
            patient_id,
            dates,
            most_recent,
            modalities,
        } = patient
        else {
            panic!("a patient request");
        };
        assert_eq!(patient_id, "12345");
        assert_eq!(dates.map(DateRange::to_query).as_deref(), Some("20200101-"));
        assert_eq!(most_recent, Some(3));
        assert_eq!(modalities, ["CT", "MR"]);
        assert!(
            parse_invoke(&params(&[
                ("requestType", "PATIENT"),
                ("patientID", "1"),
                ("lowerDateTime", "yesterday")
            ]))
            .is_err()
        );
        assert!(
            parse_invoke(&params(&[
                ("requestType", "PATIENT"),
                ("patientID", "1"),
                ("mostRecentResults", "0")
            ]))
            .is_err()
        );
        assert!(parse_invoke(&params(&[("requestType", "PATIENT")])).is_err());
    }
}
