//! [`DicomWeb`]: a client of one PACS's DICOMweb service (DICOM PS3.18):
//! QIDO-RS searches for studies and series, WADO-RS series metadata and
//! instances. Every answer is bounded ([`MAX_JSON_BYTES`],
//! [`DicomWeb::retrieve_instance`]'s limit), every request has a connect
//! and a read timeout, and every failure is a [`PacsError`] that names the
//! PACS and the URL (so the study and series) and says whether trying again
//! may help.

use std::io::Write;
use std::path::Path;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::task::{Context, Poll};
use std::time::Duration;

use bytes::Bytes;
use futures_util::Stream;
use reqwest::{StatusCode, Url};
use serde::Serialize;
use serde_json::Value;

use super::endpoint::Endpoint;
use super::query::{StudyQuery, check_uid};

/// Most bytes of a JSON answer (search results, a series' metadata).
pub const MAX_JSON_BYTES: usize = 128 * 1024 * 1024;
/// Most instances in one series.
pub const MAX_INSTANCES: usize = 100_000;
/// Most characters kept of a free-text attribute (descriptions, names).
const MAX_TEXT_CHARS: usize = 256;
/// Most bytes of a rendered image (a thumbnail) a PACS may send.
pub const MAX_RENDERED_BYTES: usize = 4 << 20;
/// Largest edge of a rendered image decoded, pixels.
const MAX_RENDERED_EDGE: u32 = 4096;
/// Time to open a connection.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// Most time one request may take, its whole body read.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(30 * 60);

/// `Accept` of an instance retrieval: the instance as stored (any transfer
/// syntax), so that its bytes are the ones a file export would hold.
const ACCEPT_INSTANCE: &str = "multipart/related; type=\"application/dicom\"; transfer-syntax=*";
/// `Accept` of searches and metadata.
const ACCEPT_JSON: &str = "application/dicom+json, application/json";

/// What went wrong talking to a PACS.
#[derive(Debug, thiserror::Error)]
pub enum PacsError {
    /// No connection (refused, no route, name unknown).
    #[error(
        "PACS {pacs}: {url}: cannot connect ({detail}); expected its DICOMweb service to be running there"
    )]
    Unreachable {
        /// The PACS's name.
        pacs: String,
        /// The request.
        url: String,
        /// What the connection said.
        detail: String,
    },
    /// No answer, or a stalled one, within the timeout.
    #[error("PACS {pacs}: {url}: no answer within {seconds} s (timeout)")]
    Timeout {
        /// The PACS's name.
        pacs: String,
        /// The request.
        url: String,
        /// The timeout.
        seconds: u64,
    },
    /// An HTTP status other than 200.
    #[error("PACS {pacs}: {url}: HTTP {status}{detail}")]
    Status {
        /// The PACS's name.
        pacs: String,
        /// The request.
        url: String,
        /// The status.
        status: u16,
        /// What it means here.
        detail: String,
    },
    /// The answer broke off while it was read.
    #[error("PACS {pacs}: {url}: the answer broke off ({detail})")]
    Transfer {
        /// The PACS's name.
        pacs: String,
        /// The request.
        url: String,
        /// What the connection said.
        detail: String,
    },
    /// An answer that is not what DICOMweb says it must be.
    #[error("PACS {pacs}: {url}: {what}")]
    Malformed {
        /// The PACS's name.
        pacs: String,
        /// The request.
        url: String,
        /// What is wrong, and what was expected.
        what: String,
    },
    /// The local file an instance goes to.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The error.
        source: std::io::Error,
    },
}

impl PacsError {
    /// Whether the same request may succeed later: no connection, a
    /// timeout, a broken-off answer, or a status that says so (5xx, 429).
    pub fn retryable(&self) -> bool {
        match self {
            PacsError::Unreachable { .. }
            | PacsError::Timeout { .. }
            | PacsError::Transfer { .. } => true,
            PacsError::Status { status, .. } => *status >= 500 || *status == 429,
            PacsError::Malformed { .. } | PacsError::Io { .. } => false,
        }
    }
}

/// The boundary of a body of DICOM instances (PS3.18 §8.6.1.2:
/// `multipart/related`, its `type` absent or `application/dicom`) from its
/// Content-Type; `None` when it is not one.
pub fn dicom_parts_boundary(content_type: &str) -> Option<String> {
    let mime = content_type.parse::<mime::Mime>().ok()?;
    if mime.type_() != mime::MULTIPART || mime.subtype() != "related" {
        return None;
    }
    if mime
        .get_param("type")
        .is_some_and(|t| t.as_str() != "application/dicom")
    {
        return None;
    }
    mime.get_param(mime::BOUNDARY)
        .map(|b| b.as_str().to_owned())
}

/// The parts of a multipart body `stream` with `boundary`, read with
/// multer, the body's end reported to it one poll late ([`EndAfterData`]).
pub fn dicom_parts<'a, S, O, E>(stream: S, boundary: String) -> multer::Multipart<'a>
where
    S: Stream<Item = Result<O, E>> + Send + 'a,
    O: Into<Bytes> + 'static,
    E: Into<Box<dyn std::error::Error + Send + Sync>> + 'static,
{
    multer::Multipart::new(
        EndAfterData {
            inner: Box::pin(stream),
            ended: false,
        },
        boundary,
    )
}

/// A body stream that reports its end only on a poll that brings no data.
///
/// multer 3.1.0, while it looks for the first boundary, reads the stream a
/// second time within one poll; when that second read brings the rest of
/// the body and its end together, it fails with "incomplete stream" without
/// looking at what it has just read (so a whole body arriving at once on a
/// busy machine was refused now and then). Reporting the end on the next
/// poll, after waking the task, lets it look first.
struct EndAfterData<'a, T> {
    inner: Pin<Box<dyn Stream<Item = T> + Send + 'a>>,
    /// The inner stream has ended (it is not polled again).
    ended: bool,
}

impl<T> Stream for EndAfterData<'_, T> {
    type Item = T;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<T>> {
        if self.ended {
            return Poll::Ready(None);
        }
        match self.inner.as_mut().poll_next(cx) {
            Poll::Ready(None) => {
                self.ended = true;
                cx.waker().wake_by_ref();
                Poll::Pending
            }
            other => other,
        }
    }
}

/// A study a search found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StudyRecord {
    /// StudyInstanceUID.
    pub study_uid: String,
    /// PatientName (its alphabetic form).
    pub patient_name: Option<String>,
    /// PatientID.
    pub patient_id: Option<String>,
    /// PatientBirthDate.
    pub patient_birth_date: Option<String>,
    /// StudyDate.
    pub study_date: Option<String>,
    /// AccessionNumber.
    pub accession_number: Option<String>,
    /// StudyDescription.
    pub description: Option<String>,
    /// ModalitiesInStudy.
    pub modalities: Vec<String>,
    /// NumberOfStudyRelatedSeries.
    pub series: Option<u64>,
    /// NumberOfStudyRelatedInstances.
    pub instances: Option<u64>,
}

/// A series of a study.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SeriesRecord {
    /// SeriesInstanceUID.
    pub series_uid: String,
    /// Modality.
    pub modality: Option<String>,
    /// SeriesDescription.
    pub description: Option<String>,
    /// SeriesNumber.
    pub number: Option<i64>,
    /// NumberOfSeriesRelatedInstances.
    pub instances: Option<u64>,
}

/// An instance of a series, from its metadata.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InstanceRecord {
    /// SOPInstanceUID.
    pub sop_uid: String,
    /// InstanceNumber.
    pub number: Option<i64>,
    /// NumberOfFrames (1 for single-frame images).
    pub frames: u64,
}

/// A client of one PACS's DICOMweb service.
#[derive(Debug, Clone)]
pub struct DicomWeb {
    endpoint: Endpoint,
    client: reqwest::Client,
    read_timeout: Duration,
}

impl DicomWeb {
    /// A client of `endpoint` that gives up on an answer that stalls for
    /// `read_timeout`.
    pub fn new(endpoint: Endpoint, read_timeout: Duration) -> anyhow::Result<DicomWeb> {
        let client = reqwest::Client::builder()
            .connect_timeout(CONNECT_TIMEOUT)
            .read_timeout(read_timeout)
            .timeout(REQUEST_TIMEOUT)
            .redirect(reqwest::redirect::Policy::none())
            .build()
            .map_err(|e| {
                anyhow::anyhow!("PACS {}: cannot make an HTTP client: {e}", endpoint.name)
            })?;
        Ok(DicomWeb {
            endpoint,
            client,
            read_timeout,
        })
    }

    /// The PACS's name.
    pub fn name(&self) -> &str {
        &self.endpoint.name
    }

    /// The URL of `path` (segments after the service's root).
    pub fn url(&self, segments: &[&str]) -> Url {
        let mut url = self.endpoint.base.clone();
        if let Ok(mut path) = url.path_segments_mut() {
            path.pop_if_empty().extend(segments);
        }
        url
    }

    /// QIDO-RS: the studies matching `query`.
    pub async fn search_studies(&self, query: &StudyQuery) -> Result<Vec<StudyRecord>, PacsError> {
        let mut url = self.url(&["studies"]);
        url.query_pairs_mut().extend_pairs(query.pairs());
        let found = self.json_array(&url).await?;
        let limit = query.limit() as usize;
        if found.len() > limit {
            return Err(self.malformed(
                &url,
                format!(
                    "{} results: expected at most the limit of {limit}",
                    found.len()
                ),
            ));
        }
        found
            .iter()
            .map(|s| {
                let study_uid = uid(s, "0020000D").ok_or_else(|| {
                    self.malformed(
                        &url,
                        "a result without a valid StudyInstanceUID (0020,000D)".into(),
                    )
                })?;
                Ok(StudyRecord {
                    study_uid,
                    patient_name: text(s, "00100010"),
                    patient_id: text(s, "00100020"),
                    patient_birth_date: text(s, "00100030"),
                    study_date: text(s, "00080020"),
                    accession_number: text(s, "00080050"),
                    description: text(s, "00081030"),
                    modalities: values(s, "00080061")
                        .iter()
                        .filter_map(|v| v.as_str().map(clip))
                        .take(32)
                        .collect(),
                    series: number(s, "00201206").and_then(|n| u64::try_from(n).ok()),
                    instances: number(s, "00201208").and_then(|n| u64::try_from(n).ok()),
                })
            })
            .collect()
    }

    /// QIDO-RS: the series of `study`.
    pub async fn search_series(&self, study: &str) -> Result<Vec<SeriesRecord>, PacsError> {
        let url = self.url(&["studies", study, "series"]);
        let found = self.json_array(&url).await?;
        found
            .iter()
            .map(|s| {
                let series_uid = uid(s, "0020000E").ok_or_else(|| {
                    self.malformed(
                        &url,
                        "a result without a valid SeriesInstanceUID (0020,000E)".into(),
                    )
                })?;
                Ok(SeriesRecord {
                    series_uid,
                    modality: text(s, "00080060"),
                    description: text(s, "0008103E"),
                    number: number(s, "00200011"),
                    instances: number(s, "00201209").and_then(|n| u64::try_from(n).ok()),
                })
            })
            .collect()
    }

    /// WADO-RS: the instances of `series` in `study`, from its metadata
    /// (one record each; every one of the series).
    pub async fn series_instances(
        &self,
        study: &str,
        series: &str,
    ) -> Result<Vec<InstanceRecord>, PacsError> {
        let url = self.url(&["studies", study, "series", series, "metadata"]);
        let found = self.json_array(&url).await?;
        if found.is_empty() {
            return Err(self.malformed(&url, "no instances: expected the series' metadata".into()));
        }
        if found.len() > MAX_INSTANCES {
            return Err(self.malformed(
                &url,
                format!(
                    "{} instances: expected at most {MAX_INSTANCES}",
                    found.len()
                ),
            ));
        }
        let mut seen = std::collections::HashSet::new();
        found
            .iter()
            .map(|i| {
                let sop_uid = uid(i, "00080018")
                    .ok_or_else(|| self.malformed(&url, "an instance without a valid SOPInstanceUID (0008,0018)".into()))?;
                if let Some(other) = text(i, "0020000E").filter(|s| s != series) {
                    return Err(self.malformed(&url, format!("instance {sop_uid} belongs to series {other}: expected only series {series}")));
                }
                if !seen.insert(sop_uid.clone()) {
                    return Err(self.malformed(&url, format!("instance {sop_uid} listed twice")));
                }
                let frames = number(i, "00280008").unwrap_or(1);
                let frames = u64::try_from(frames).ok().filter(|&f| f >= 1).ok_or_else(|| {
                    self.malformed(&url, format!("instance {sop_uid}: NumberOfFrames {frames}; expected 1 or more"))
                })?;
                Ok(InstanceRecord {
                    sop_uid,
                    number: number(i, "00200013"),
                    frames,
                })
            })
            .collect()
    }

    /// WADO-RS rendered series (PS3.18 §9.5.1.2): an image of the series
    /// (the PACS's choice) as the PACS renders it for display, asked for
    /// within `edge`² pixels; decoded here (a JPEG or PNG of at most
    /// [`MAX_RENDERED_BYTES`] and [`MAX_RENDERED_EDGE`]² pixels) and given
    /// back scaled to fit `edge`², as PNG.
    pub async fn series_thumbnail(
        &self,
        study: &str,
        series: &str,
        edge: u32,
    ) -> Result<Vec<u8>, PacsError> {
        let mut url = self.url(&["studies", study, "series", series, "rendered"]);
        // The comma as is: some PACS (Orthanc) do not decode `%2C` here.
        url.set_query(Some(&format!("viewport={edge},{edge}")));
        // JPEG: what every PACS must render (and one type only: Orthanc
        // refuses a list).
        let mut response = self.get(&url, "image/jpeg").await?;
        let mut body = Vec::new();
        while let Some(chunk) = response
            .chunk()
            .await
            .map_err(|e| self.transport_error(&url, &e))?
        {
            if body.len() + chunk.len() > MAX_RENDERED_BYTES {
                return Err(self.malformed(
                    &url,
                    format!("an image of over {MAX_RENDERED_BYTES} bytes: expected a small rendered image"),
                ));
            }
            body.extend_from_slice(&chunk);
        }
        let mut reader = image::ImageReader::new(std::io::Cursor::new(&body))
            .with_guessed_format()
            .map_err(|e| self.malformed(&url, format!("{e}: expected a JPEG or PNG image")))?;
        let mut limits = image::Limits::default();
        limits.max_image_width = Some(MAX_RENDERED_EDGE);
        limits.max_image_height = Some(MAX_RENDERED_EDGE);
        limits.max_alloc = Some(256 << 20);
        reader.limits(limits);
        let decoded = reader
            .decode()
            .map_err(|e| self.malformed(&url, format!("{e}: expected a JPEG or PNG image")))?;
        let small = decoded.thumbnail(edge, edge);
        let mut png = Vec::new();
        small
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .map_err(|e| self.malformed(&url, format!("cannot encode it again: {e}")))?;
        Ok(png)
    }

    /// WADO-RS: instance `instance` of `series` in `study`, as stored (any
    /// transfer syntax), written to `dest` as a DICOM file; at most
    /// `max_bytes`. Returns its size.
    pub async fn retrieve_instance(
        &self,
        study: &str,
        series: &str,
        instance: &str,
        dest: &Path,
        max_bytes: u64,
    ) -> Result<u64, PacsError> {
        let url = self.url(&["studies", study, "series", series, "instances", instance]);
        let response = self.get(&url, ACCEPT_INSTANCE).await?;
        let content_type = response
            .headers()
            .get(reqwest::header::CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_owned();
        let boundary = dicom_parts_boundary(&content_type).ok_or_else(|| {
            self.malformed(
                &url,
                format!(
                    "Content-Type {content_type:?}: expected multipart/related; type=\"application/dicom\" with a boundary"
                ),
            )
        })?;
        let body = Body {
            received: Arc::default(),
            announced: response.content_length(),
        };
        let state = Some((response, Arc::clone(&body.received)));
        let stream = futures_util::stream::unfold(state, |state| async move {
            let (mut response, received) = state?;
            match response.chunk().await {
                Ok(Some(chunk)) => {
                    received.fetch_add(chunk.len() as u64, Ordering::Relaxed);
                    Some((
                        Ok::<Bytes, reqwest::Error>(chunk),
                        Some((response, received)),
                    ))
                }
                Ok(None) => None,
                Err(e) => Some((Err(e), None)),
            }
        });
        let mut parts = dicom_parts(stream, boundary);
        let mut part = match parts.next_field().await {
            Ok(Some(part)) => part,
            Ok(None) => return Err(self.malformed(&url, "no part: expected the instance".into())),
            Err(e) => return Err(self.multipart_error(&url, e, &body)),
        };
        if let Some(t) = part.content_type()
            && t.essence_str() != "application/dicom"
        {
            return Err(self.malformed(
                &url,
                format!("a part of type {t}: expected application/dicom"),
            ));
        }
        let written = self
            .write_part(&url, &mut part, &body, dest, max_bytes)
            .await;
        if written.is_err() {
            // No partial instance is left behind.
            let _ = std::fs::remove_file(dest);
        }
        let written = written?;
        // The part holds the body until dropped.
        drop(part);
        match parts.next_field().await {
            Ok(None) => {}
            Ok(Some(_)) => {
                return Err(self.malformed(&url, "several parts: expected one instance".into()));
            }
            Err(e) => return Err(self.multipart_error(&url, e, &body)),
        }
        if written < 132 {
            return Err(self.malformed(&url, format!("{written} bytes: expected a DICOM file")));
        }
        Ok(written)
    }

    /// Writes `part` to `dest`, at most `max_bytes`; returns its size.
    async fn write_part(
        &self,
        url: &Url,
        part: &mut multer::Field<'_>,
        body: &Body,
        dest: &Path,
        max_bytes: u64,
    ) -> Result<u64, PacsError> {
        let io = |source| PacsError::Io {
            path: dest.display().to_string(),
            source,
        };
        let mut file = std::fs::File::create(dest).map_err(io)?;
        let mut written = 0u64;
        loop {
            match part.chunk().await {
                Ok(Some(chunk)) => {
                    written += chunk.len() as u64;
                    if written > max_bytes {
                        return Err(self.malformed(url, format!(
                            "an instance of over {max_bytes} bytes: expected at most that (--pacs-max-instance-mib)"
                        )));
                    }
                    file.write_all(&chunk).map_err(io)?;
                }
                Ok(None) => break,
                Err(e) => return Err(self.multipart_error(url, e, body)),
            }
        }
        file.sync_all().map_err(io)?;
        Ok(written)
    }

    /// A GET of `url` answered 200.
    async fn get(&self, url: &Url, accept: &str) -> Result<reqwest::Response, PacsError> {
        let mut request = self
            .client
            .get(url.clone())
            .header(reqwest::header::ACCEPT, accept);
        if let Some((name, value)) = &self.endpoint.auth {
            request = request.header(name, value);
        }
        let response = request
            .send()
            .await
            .map_err(|e| self.transport_error(url, &e))?;
        let status = response.status();
        if status == StatusCode::OK {
            return Ok(response);
        }
        let detail = match status {
            StatusCode::NOT_FOUND => {
                ": not found; expected the study or series to exist on this PACS"
            }
            StatusCode::UNAUTHORIZED | StatusCode::FORBIDDEN => {
                ": refused; give the PACS's credentials with --pacs-auth"
            }
            StatusCode::NO_CONTENT => ": no content; expected the data asked for",
            s if s.is_server_error() => ": the PACS failed to answer",
            _ => ": expected 200",
        };
        Err(PacsError::Status {
            pacs: self.endpoint.name.clone(),
            url: url.to_string(),
            status: status.as_u16(),
            detail: detail.to_owned(),
        })
    }

    /// A JSON array at `url` (an empty answer, 204, is an empty array).
    async fn json_array(&self, url: &Url) -> Result<Vec<Value>, PacsError> {
        let mut response = match self.get(url, ACCEPT_JSON).await {
            Err(PacsError::Status { status: 204, .. }) => return Ok(Vec::new()),
            other => other?,
        };
        let mut body = Vec::new();
        while let Some(chunk) = response
            .chunk()
            .await
            .map_err(|e| self.transport_error(url, &e))?
        {
            if body.len() + chunk.len() > MAX_JSON_BYTES {
                return Err(self.malformed(
                    url,
                    format!("an answer of over {MAX_JSON_BYTES} bytes: expected at most that"),
                ));
            }
            body.extend_from_slice(&chunk);
        }
        if body.iter().all(u8::is_ascii_whitespace) {
            return Ok(Vec::new());
        }
        match serde_json::from_slice::<Value>(&body) {
            Ok(Value::Array(items)) if items.iter().all(Value::is_object) => Ok(items),
            Ok(_) => Err(self.malformed(
                url,
                "JSON that is not an array of objects: expected DICOM JSON (PS3.18 F.2)".into(),
            )),
            Err(e) => Err(self.malformed(url, format!("{e}: expected DICOM JSON"))),
        }
    }

    fn malformed(&self, url: &Url, what: String) -> PacsError {
        PacsError::Malformed {
            pacs: self.endpoint.name.clone(),
            url: url.to_string(),
            what,
        }
    }

    fn transport_error(&self, url: &Url, e: &reqwest::Error) -> PacsError {
        let (pacs, url) = (self.endpoint.name.clone(), url.to_string());
        let detail = error_chain(e);
        if e.is_timeout() {
            PacsError::Timeout {
                pacs,
                url,
                seconds: self.read_timeout.as_secs(),
            }
        } else if e.is_connect() {
            PacsError::Unreachable { pacs, url, detail }
        } else {
            PacsError::Transfer { pacs, url, detail }
        }
    }

    fn multipart_error(&self, url: &Url, e: multer::Error, body: &Body) -> PacsError {
        match e {
            multer::Error::StreamReadFailed(inner) => {
                match inner.downcast::<reqwest::Error>() {
                    Ok(e) => self.transport_error(url, &e),
                    Err(inner) => PacsError::Transfer {
                        pacs: self.endpoint.name.clone(),
                        url: url.to_string(),
                        detail: inner.to_string(),
                    },
                }
            }
            multer::Error::IncompleteStream | multer::Error::IncompleteFieldData { .. } => self.malformed(
                url,
                format!(
                    "the multipart body ended before its closing boundary, {}: expected a whole instance (truncated)",
                    body.extent()
                ),
            ),
            other => self.malformed(url, format!("{other}: expected a multipart/related body")),
        }
    }
}

/// What came of a response's body, for errors about it.
struct Body {
    /// Bytes read so far.
    received: Arc<AtomicU64>,
    /// Its Content-Length, where the response has one.
    announced: Option<u64>,
}

impl Body {
    /// How much of it arrived: "after R of the N bytes its Content-Length
    /// announced", or "after R bytes (no Content-Length)".
    fn extent(&self) -> String {
        let received = self.received.load(Ordering::Relaxed);
        match self.announced {
            Some(n) => format!("after {received} of the {n} bytes its Content-Length announced"),
            None => format!("after {received} bytes (no Content-Length)"),
        }
    }
}

/// An error's causes, joined (reqwest's own message repeats the URL,
/// which the error names already).
fn error_chain(e: &dyn std::error::Error) -> String {
    let Some(first) = e.source() else {
        return e.to_string();
    };
    let mut text = first.to_string();
    let mut cause = first.source();
    while let Some(c) = cause {
        let part = c.to_string();
        if !text.contains(&part) {
            text = format!("{text}: {part}");
        }
        cause = c.source();
    }
    text
}

/// The values of attribute `tag` (8 hex digits) of a DICOM JSON object.
fn values<'a>(object: &'a Value, tag: &str) -> &'a [Value] {
    object
        .get(tag)
        .and_then(|a| a.get("Value"))
        .and_then(Value::as_array)
        .map_or(&[], Vec::as_slice)
}

/// `text` cut to [`MAX_TEXT_CHARS`] characters, control characters dropped.
fn clip(text: &str) -> String {
    text.trim()
        .chars()
        .filter(|c| !c.is_control())
        .take(MAX_TEXT_CHARS)
        .collect()
}

/// The first value of `tag` as text (a person name's alphabetic form).
fn text(object: &Value, tag: &str) -> Option<String> {
    let first = values(object, tag).first()?;
    let s = match first {
        Value::String(s) => s.as_str(),
        Value::Object(pn) => pn.get("Alphabetic")?.as_str()?,
        _ => return None,
    };
    Some(clip(s)).filter(|s| !s.is_empty())
}

/// The first value of `tag` as a UID.
fn uid(object: &Value, tag: &str) -> Option<String> {
    let first = values(object, tag).first()?.as_str()?;
    check_uid(tag, first.trim()).ok()
}

/// The first value of `tag` as a whole number (IS values come as numbers
/// or as strings).
fn number(object: &Value, tag: &str) -> Option<i64> {
    match values(object, tag).first()? {
        Value::Number(n) => n.as_i64(),
        Value::String(s) => s.trim().parse().ok(),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dicom_json_attributes_are_read_as_their_vr_writes_them() {
        let object: Value = serde_json::json!({
            "00100010": {"vr": "PN", "Value": [{"Alphabetic": "Eve"}]},
            "00201208": {"vr": "IS", "Value": ["234"]},
            "00201206": {"vr": "IS", "Value": [1]},
            "0020000D": {"vr": "UI", "Value": ["1.2.3"]},
            "0020000E": {"vr": "UI", "Value": ["1.2.x"]},
            "0008103E": {"vr": "LO"},
        });
        assert_eq!(text(&object, "00100010").as_deref(), Some("Eve"));
        assert_eq!(number(&object, "00201208"), Some(234));
        assert_eq!(number(&object, "00201206"), Some(1));
        assert_eq!(uid(&object, "0020000D").as_deref(), Some("1.2.3"));
        assert_eq!(uid(&object, "0020000E"), None, "not a UID");
        assert_eq!(text(&object, "0008103E"), None, "no value");
        assert_eq!(clip(&"x".repeat(1000)).len(), MAX_TEXT_CHARS);
    }

    /// A body that arrives whole, with its end, on multer's second read of
    /// the stream within one poll (the first read found nothing yet).
    fn whole_body_on_second_read() -> impl Stream<Item = Result<Bytes, std::io::Error>> + Send {
        let body = Bytes::from_static(
            b"--b0\r\nContent-Type: application/dicom\r\n\r\nDICM pixels\r\n--b0--\r\n",
        );
        let mut reads = 0;
        futures_util::stream::poll_fn(move |cx| {
            reads += 1;
            match reads {
                1 => {
                    cx.waker().wake_by_ref();
                    Poll::Pending
                }
                2 => Poll::Ready(Some(Ok(body.clone()))),
                _ => Poll::Ready(None),
            }
        })
    }

    #[tokio::test]
    async fn a_body_whose_end_arrives_with_its_first_boundary_is_read_whole() {
        // multer alone refuses it: this is what `dicom_parts` is for.
        let mut bare = multer::Multipart::new(whole_body_on_second_read(), "b0");
        assert!(
            matches!(
                bare.next_field().await,
                Err(multer::Error::IncompleteStream)
            ),
            "multer reads this body whole by itself now: EndAfterData can go"
        );

        let mut parts = dicom_parts(whole_body_on_second_read(), "b0".into());
        let mut part = parts
            .next_field()
            .await
            .expect("a well-formed body")
            .expect("one part");
        assert_eq!(
            part.content_type().expect("a Content-Type").essence_str(),
            "application/dicom"
        );
        let mut data = Vec::new();
        while let Some(chunk) = part.chunk().await.expect("the part's data") {
            data.extend_from_slice(&chunk);
        }
        assert_eq!(data, b"DICM pixels");
        drop(part);
        assert!(
            parts
                .next_field()
                .await
                .expect("the closing boundary")
                .is_none(),
            "one part only"
        );
    }
}
