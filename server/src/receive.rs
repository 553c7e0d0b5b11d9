//! Studies pushed to voxserve: STOW-RS (`POST /dicom-web/studies`, DICOM
//! PS3.18 §10.5) keeps every instance received under `serve --receive DIR`,
//! series by series; a series is bricked once it is complete — no new
//! instance for the settling time (`--receive-settle-s`) — and then offered
//! as a dataset whose id is its SeriesInstanceUID. A series that fails to
//! brick (a missing slice, mixed geometries, a frame that does not decode)
//! is logged with the reason and not offered: nothing half-ingested is served.
//!
//! Layout of `DIR`: `incoming/` (parts being received), `series/UID/`
//! (the instances, named by SOPInstanceUID), `stores/UID.zarr` (the stores).
//! What `series/` and `stores/` hold is kept within `--receive-max-mib`:
//! past it, instances are refused (out of resources) until an operator
//! makes room; nothing kept is ever removed by the server.

use std::collections::HashMap;
use std::io::Write as _;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use axum::Extension;
use axum::body::Body;
use axum::extract::{ConnectInfo, Path as UrlPath, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::{Value, json};

use crate::app::Datasets;
use crate::audit::{Event, Outcome};
use crate::auth::Principal;
use crate::pacs::query::check_uid;
use crate::{AppError, AppState, Dataset};

/// Most bytes of one received instance.
pub const MAX_INSTANCE_BYTES: u64 = 2 << 30;
/// Most instances in one STOW-RS request.
pub const MAX_PARTS: usize = 100_000;

/// Where received studies go, and which series wait to be bricked.
#[derive(Debug)]
pub struct Receiver {
    dir: PathBuf,
    settle: Duration,
    cache_bytes: u64,
    /// The most `series/` and `stores/` may hold, bytes.
    budget: u64,
    /// What they hold (counted at start and after each bricking, added to
    /// as instances are kept).
    used: AtomicU64,
    /// Series with instances not yet bricked, and when the last arrived.
    pending: Mutex<HashMap<String, Instant>>,
}

/// One instance received: stored, or why not.
pub(crate) struct Outcome1 {
    pub class: Option<String>,
    pub instance: Option<String>,
    /// Its series, when it was kept.
    pub series: Option<String>,
    pub failure: Option<String>,
    /// Whether it failed for not being what the request claimed.
    pub mismatch: bool,
    /// Whether it was refused for want of room (`--receive-max-mib`).
    pub full: bool,
}

/// What a request says of an instance it sends, checked against the
/// instance's own header.
#[derive(Debug, Default)]
pub(crate) struct Claimed<'a> {
    /// StudyInstanceUID (the STOW-RS URL's study).
    pub study: Option<&'a str>,
    /// SOPClassUID (a C-STORE's AffectedSOPClassUID).
    pub class: Option<&'a str>,
    /// SOPInstanceUID (a C-STORE's AffectedSOPInstanceUID).
    pub instance: Option<&'a str>,
}

impl Receiver {
    /// Receives into `dir` (made if missing), bricking a series `settle`
    /// after its last instance, keeping at most `budget` bytes; stores'
    /// decoded blocks cached up to `cache_bytes`.
    pub fn new(
        dir: &Path,
        settle: Duration,
        cache_bytes: u64,
        budget: u64,
    ) -> anyhow::Result<Arc<Receiver>> {
        for sub in ["incoming", "series", "stores"] {
            std::fs::create_dir_all(dir.join(sub)).map_err(|e| {
                anyhow::anyhow!("--receive {}: cannot make {sub}/: {e}", dir.display())
            })?;
        }
        // Series received but not bricked when the server last stopped (or
        // added to since they were): bricked once the settling time passes.
        let mut pending = HashMap::new();
        let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
        let entries = std::fs::read_dir(dir.join("series"))
            .map_err(|e| anyhow::anyhow!("--receive {}: series/: {e}", dir.display()))?;
        for entry in entries.filter_map(Result::ok) {
            let uid = entry.file_name().to_string_lossy().into_owned();
            if !blocks::ingest::dicom::is_uid(&uid) {
                continue;
            }
            let store = dir.join("stores").join(format!("{uid}.zarr"));
            if modified(&store) < modified(&entry.path()) || !store.exists() {
                pending.insert(uid, Instant::now());
            }
        }
        if !pending.is_empty() {
            tracing::info!(
                "--receive {}: {} received series to brick",
                dir.display(),
                pending.len()
            );
        }
        let receiver = Receiver {
            dir: dir.to_owned(),
            settle,
            cache_bytes,
            budget,
            used: AtomicU64::new(0),
            pending: Mutex::new(pending),
        };
        receiver.count_used();
        Ok(Arc::new(receiver))
    }

    /// Counts what `series/` and `stores/` hold.
    fn count_used(&self) {
        let used = crate::studies::folder_bytes(&self.dir.join("series"))
            + crate::studies::folder_bytes(&self.dir.join("stores"));
        self.used.store(used, Ordering::Relaxed);
    }

    /// Why nothing more can be received now, if so.
    pub(crate) fn full(&self) -> Option<String> {
        let used = self.used.load(Ordering::Relaxed);
        (used >= self.budget).then(|| {
            format!(
                "{} holds {} MiB of received studies, its --receive-max-mib of {} MiB: make room",
                self.dir.display(),
                used >> 20,
                self.budget >> 20
            )
        })
    }

    /// The stores of series received before, to offer at start.
    pub fn stores(&self) -> anyhow::Result<Vec<PathBuf>> {
        crate::commands::stores_in(&self.dir.join("stores"))
    }

    /// Bricks every series that has settled, until `shutdown`, offering each
    /// in `datasets`.
    pub fn spawn_settler(
        self: &Arc<Self>,
        datasets: Datasets,
        shutdown: tokio_util::sync::CancellationToken,
    ) {
        let receiver = Arc::clone(self);
        tokio::spawn(async move {
            loop {
                tokio::select! {
                    () = shutdown.cancelled() => return,
                    () = tokio::time::sleep(Duration::from_millis(250)) => {}
                }
                let settled: Vec<String> = {
                    let mut pending = receiver
                        .pending
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner);
                    let due: Vec<String> = pending
                        .iter()
                        .filter(|(_, last)| last.elapsed() >= receiver.settle)
                        .map(|(uid, _)| uid.clone())
                        .collect();
                    for uid in &due {
                        pending.remove(uid);
                    }
                    due
                };
                for uid in settled {
                    let r = Arc::clone(&receiver);
                    let brick =
                        tokio::task::spawn_blocking(move || r.brick(&uid).map_err(|e| (uid, e)));
                    match brick.await {
                        Ok(Ok(dataset)) => {
                            tracing::info!(
                                "received series {} bricked and served (dataset id {0})",
                                dataset.id
                            );
                            datasets.add(dataset);
                        }
                        Ok(Err((uid, e))) => {
                            tracing::error!("received series {uid} not offered: {e:#}");
                        }
                        Err(e) => tracing::error!("bricking a received series failed: {e}"),
                    }
                }
            }
        });
    }

    /// Bricks received series `uid` into its store and opens it.
    fn brick(&self, uid: &str) -> anyhow::Result<Dataset> {
        let folder = self.dir.join("series").join(uid);
        let options = blocks::ingest::OpenOptions {
            series: Some(uid.to_owned()),
            ..blocks::ingest::OpenOptions::default()
        };
        let mut source = blocks::ingest::open(&folder, &options)?;
        let out = self.dir.join("stores").join(format!("{uid}.zarr"));
        let ingest = blocks::store::IngestOptions {
            overwrite: true,
            ..blocks::store::IngestOptions::default()
        };
        let bricked = blocks::store::ingest(source.as_mut(), &out, &ingest, &mut |_| {});
        self.count_used();
        bricked?;
        let store = blocks::store::Store::open(&out)?;
        Ok(Dataset::new(uid.to_owned(), store, self.cache_bytes)?)
    }

    /// A new file in `incoming/`, for an instance being received.
    pub(crate) fn incoming_file(&self) -> std::io::Result<tempfile::NamedTempFile> {
        tempfile::NamedTempFile::new_in(self.dir.join("incoming"))
    }

    /// Keeps one received instance (its bytes in `file`): read its header,
    /// check its UIDs (and that it is what the request `claimed`), and move
    /// it to its series' folder.
    pub(crate) fn keep(&self, file: tempfile::NamedTempFile, claimed: &Claimed<'_>) -> Outcome1 {
        let uids = match blocks::ingest::dicom::instance_uids(file.path()) {
            Ok(uids) => uids,
            Err(e) => {
                return Outcome1 {
                    class: None,
                    instance: None,
                    series: None,
                    failure: Some(e.to_string()),
                    mismatch: false,
                    full: false,
                };
            }
        };
        let blocks::ingest::dicom::InstanceUids {
            study: their_study,
            series,
            class,
            instance,
        } = uids;
        let fail = |why: String, instance: Option<String>, mismatch: bool| Outcome1 {
            class: class.clone(),
            instance,
            series: None,
            failure: Some(why),
            mismatch,
            full: false,
        };
        if let Some(study) = claimed.study
            && study != their_study
        {
            return fail(
                format!(
                    "StudyInstanceUID {their_study}: expected {study}, the study of the request's URL"
                ),
                Some(instance),
                true,
            );
        }
        if let Some(claimed) = claimed.instance
            && claimed != instance
        {
            return fail(
                format!("SOPInstanceUID {instance}: expected {claimed}, the request's"),
                Some(instance),
                true,
            );
        }
        if let Some(claimed) = claimed.class
            && Some(claimed) != class.as_deref()
        {
            return fail(
                format!(
                    "SOPClassUID {}: expected {claimed}, the request's",
                    class.as_deref().unwrap_or("missing")
                ),
                Some(instance),
                true,
            );
        }
        let size = file.as_file().metadata().map_or(0, |m| m.len());
        // Refused once the budget is reached (it may be passed by the one
        // instance that reaches it).
        if let Some(why) = self.full() {
            return Outcome1 {
                full: true,
                ..fail(why, Some(instance), false)
            };
        }
        let folder = self.dir.join("series").join(&series);
        let kept = std::fs::create_dir_all(&folder)
            .map_err(|e| e.to_string())
            .and_then(|()| {
                file.persist(folder.join(format!("{instance}.dcm")))
                    .map(drop)
                    .map_err(|e| e.to_string())
            });
        if let Err(e) = kept {
            return fail(format!("cannot keep it: {e}"), Some(instance), false);
        }
        self.used.fetch_add(size, Ordering::Relaxed);
        self.pending
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .insert(series.clone(), Instant::now());
        Outcome1 {
            class,
            instance: Some(instance),
            series: Some(series),
            failure: None,
            mismatch: false,
            full: false,
        }
    }
}

/// `POST /dicom-web/studies`.
pub async fn stow(
    state: State<AppState>,
    principal: Extension<Principal>,
    client: ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, AppError> {
    stow_into(state, principal, client, None, headers, body).await
}

/// `POST /dicom-web/studies/{study}`: instances of that study only.
pub async fn stow_study(
    state: State<AppState>,
    principal: Extension<Principal>,
    client: ConnectInfo<SocketAddr>,
    UrlPath(study): UrlPath<String>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, AppError> {
    check_uid("study", &study).map_err(AppError::BadRequest)?;
    stow_into(state, principal, client, Some(study), headers, body).await
}

async fn stow_into(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    study: Option<String>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, AppError> {
    if !state.auth.may_store(&principal) {
        let e = AppError::Forbidden(format!(
            "STOW-RS: {} has no store role (the policy file's store_roles)",
            principal.user
        ));
        state.audit(&Event::new(
            "store",
            Some(&principal),
            Some(client.ip()),
            Outcome::Denied,
        ));
        return Err(e);
    }
    let Some(receiver) = state.receiver.clone() else {
        return Err(AppError::NotFound(
            "STOW-RS: the server receives no studies; start it with --receive DIR".into(),
        ));
    };
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let Some(boundary) = crate::pacs::dicomweb::dicom_parts_boundary(content_type) else {
        return Ok((
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            format!(
                "STOW-RS: Content-Type {content_type:?}: expected multipart/related; type=\"application/dicom\" with a boundary"
            ),
        )
            .into_response());
    };
    if let Some(why) = receiver.full() {
        tracing::warn!("STOW-RS refused: {why}");
        return Ok((
            StatusCode::INSUFFICIENT_STORAGE,
            format!("STOW-RS: no room: {why}"),
        )
            .into_response());
    }
    let mut parts = crate::pacs::dicomweb::dicom_parts(body.into_data_stream(), boundary);
    let mut outcomes = Vec::new();
    loop {
        let mut part = match parts.next_field().await {
            Ok(Some(part)) => part,
            Ok(None) => break,
            Err(e) => {
                return Err(AppError::BadRequest(format!(
                    "STOW-RS: part {}: {e}; expected a multipart/related body of DICOM instances",
                    outcomes.len() + 1
                )));
            }
        };
        if outcomes.len() >= MAX_PARTS {
            return Err(AppError::BadRequest(format!(
                "STOW-RS: over {MAX_PARTS} instances: expected at most that many per request"
            )));
        }
        let n = outcomes.len() + 1;
        let wrong_type = part
            .content_type()
            .filter(|t| t.essence_str() != "application/dicom")
            .map(ToString::to_string);
        let mut file = receiver
            .incoming_file()
            .map_err(|e| AppError::Internal(format!("STOW-RS: cannot make a file: {e}")))?;
        let mut size = 0u64;
        loop {
            match part.chunk().await {
                Ok(Some(chunk)) => {
                    size += chunk.len() as u64;
                    if size > MAX_INSTANCE_BYTES {
                        return Err(AppError::BadRequest(format!(
                            "STOW-RS: part {n}: over {MAX_INSTANCE_BYTES} bytes: expected an instance of at most that"
                        )));
                    }
                    file.write_all(&chunk)
                        .map_err(|e| AppError::Internal(format!("STOW-RS: cannot write: {e}")))?;
                }
                Ok(None) => break,
                Err(e) => {
                    return Err(AppError::BadRequest(format!(
                        "STOW-RS: part {n}: {e}; expected a whole instance"
                    )));
                }
            }
        }
        if let Some(t) = wrong_type {
            outcomes.push(Outcome1 {
                class: None,
                instance: None,
                series: None,
                failure: Some(format!("part {n} of type {t}: expected application/dicom")),
                mismatch: false,
                full: false,
            });
            continue;
        }
        let r = Arc::clone(&receiver);
        let study = study.clone();
        let outcome = tokio::task::spawn_blocking(move || {
            r.keep(
                file,
                &Claimed {
                    study: study.as_deref(),
                    ..Claimed::default()
                },
            )
        })
        .await
        .map_err(|e| AppError::Internal(format!("STOW-RS: {e}")))?;
        outcomes.push(outcome);
    }
    let stored = outcomes.iter().filter(|o| o.failure.is_none()).count();
    let failed = outcomes.len() - stored;
    let outcome = if failed == 0 {
        Outcome::Success
    } else {
        Outcome::Denied
    };
    state.audit(
        &Event::new("store", Some(&principal), Some(client.ip()), outcome)
            .detail(format!("{stored} instances stored, {failed} refused")),
    );
    for o in outcomes.iter().filter(|o| o.failure.is_some()) {
        tracing::warn!(
            "STOW-RS: instance {} refused: {}",
            o.instance.as_deref().unwrap_or("?"),
            o.failure.as_deref().unwrap_or("")
        );
    }
    let item = |o: &Outcome1| {
        let mut item = json!({});
        if let Some(c) = &o.class {
            item["00081150"] = json!({"vr": "UI", "Value": [c]});
        }
        if let Some(i) = &o.instance {
            item["00081155"] = json!({"vr": "UI", "Value": [i]});
        }
        if o.failure.is_some() {
            // Out of resources, or processing failure (PS3.4 Annex GG).
            let reason = if o.full { 0xA700 } else { 0x0110 };
            item["00081197"] = json!({"vr": "US", "Value": [reason]});
        }
        item
    };
    let mut answer = json!({});
    let referenced: Vec<Value> = outcomes
        .iter()
        .filter(|o| o.failure.is_none())
        .map(item)
        .collect();
    let failures: Vec<Value> = outcomes
        .iter()
        .filter(|o| o.failure.is_some())
        .map(item)
        .collect();
    if !referenced.is_empty() {
        answer["00081199"] = json!({"vr": "SQ", "Value": referenced});
    }
    if !failures.is_empty() {
        answer["00081198"] = json!({"vr": "SQ", "Value": failures});
    }
    let status = match (stored, failed) {
        (0, 0) => {
            return Err(AppError::BadRequest(
                "STOW-RS: no instances: expected at least one part".into(),
            ));
        }
        (_, 0) => StatusCode::OK,
        (0, _) => StatusCode::CONFLICT,
        _ => StatusCode::ACCEPTED,
    };
    Ok((
        status,
        [(header::CONTENT_TYPE, "application/dicom+json")],
        answer.to_string(),
    )
        .into_response())
}
