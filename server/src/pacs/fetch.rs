//! A series from a PACS, to brick: its instances retrieved into a spool
//! folder ([`fetch_series`]), several at a time, each tried again after a
//! failure that may pass; then read by the DICOM folder reader
//! ([`open_fetched`]), so a series from a PACS is grouped, sorted and
//! checked as the same files on disk are, and makes the same store.
//!
//! The spool folder is removed when the [`Fetched`] is dropped, and a fetch
//! that fails leaves nothing behind: no series is bricked from part of it.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use blocks::ingest::{self, OpenOptions, VolumeInfo, VolumeSource};
use futures_util::{StreamExt, TryStreamExt};

use super::dicomweb::{DicomWeb, InstanceRecord, PacsError};
use super::query::check_uid;

/// How a series is fetched.
#[derive(Debug, Clone, Copy)]
pub struct FetchOptions {
    /// Instances retrieved at once.
    pub concurrency: usize,
    /// Tries per instance (a failure that may pass is tried again, after
    /// ½ s, doubling to 4 s).
    pub attempts: u32,
    /// Most bytes of one instance.
    pub max_instance_bytes: u64,
}

impl Default for FetchOptions {
    fn default() -> Self {
        FetchOptions {
            concurrency: 8,
            attempts: 4,
            max_instance_bytes: 4 << 30,
        }
    }
}

/// A series' instances on local disk.
#[derive(Debug)]
pub struct Fetched {
    /// The spool folder (removed when dropped).
    pub dir: tempfile::TempDir,
    /// StudyInstanceUID.
    pub study: String,
    /// SeriesInstanceUID.
    pub series: String,
    /// The series' instances, from its metadata.
    pub instances: Vec<InstanceRecord>,
    /// Bytes retrieved.
    pub bytes: u64,
    /// Time from the metadata request to the last instance.
    pub seconds: f64,
    /// Where the series is on the PACS (the store's `source`).
    pub url: String,
}

/// Progress of a fetch: instances done of all, bytes so far.
pub type Progress<'a> = &'a (dyn Fn(usize, usize, u64) + Sync);

/// Retrieves every instance of `series` in `study` into a new spool folder
/// under `spool_in`. Fails, removing the folder, at the first instance that
/// cannot be had after [`FetchOptions::attempts`] tries.
pub async fn fetch_series(
    web: &DicomWeb,
    study: &str,
    series: &str,
    spool_in: &Path,
    options: FetchOptions,
    progress: Progress<'_>,
) -> Result<Fetched, PacsError> {
    check_uid("StudyInstanceUID", study).map_err(|what| malformed(web, study, series, what))?;
    check_uid("SeriesInstanceUID", series).map_err(|what| malformed(web, study, series, what))?;
    let start = Instant::now();
    let instances = with_retries(options, || web.series_instances(study, series)).await?;
    let dir = tempfile::Builder::new()
        .prefix(".voxserve-fetch-")
        .tempdir_in(spool_in)
        .map_err(|source| PacsError::Io {
            path: spool_in.display().to_string(),
            source,
        })?;
    let total = instances.len();
    let (done, bytes) = (AtomicUsize::new(0), AtomicU64::new(0));
    progress(0, total, 0);
    // By index, not by reference: a closure over `&InstanceRecord` would be
    // higher-ranked, and the future could not be spawned.
    futures_util::stream::iter(0..instances.len())
        .map(|i| {
            let instance = &instances[i];
            // Named by the SOP instance UID (digits and dots), so that an
            // error reading the file names the instance.
            let dest = dir.path().join(format!("{}.dcm", instance.sop_uid));
            let (done, bytes) = (&done, &bytes);
            async move {
                let n = with_retries(options, || {
                    web.retrieve_instance(
                        study,
                        series,
                        &instance.sop_uid,
                        &dest,
                        options.max_instance_bytes,
                    )
                })
                .await?;
                let b = bytes.fetch_add(n, Ordering::Relaxed) + n;
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                progress(d, total, b);
                Ok::<(), PacsError>(())
            }
        })
        .buffer_unordered(options.concurrency.max(1))
        .try_collect::<Vec<()>>()
        .await?;
    Ok(Fetched {
        dir,
        study: study.to_owned(),
        series: series.to_owned(),
        instances,
        bytes: bytes.into_inner(),
        seconds: start.elapsed().as_secs_f64(),
        url: web.url(&["studies", study, "series", series]).to_string(),
    })
}

/// `request`, tried up to `options.attempts` times while its failure may
/// pass (after ½ s, doubling to 4 s).
async fn with_retries<T, F: Future<Output = Result<T, PacsError>>>(
    options: FetchOptions,
    mut request: impl FnMut() -> F,
) -> Result<T, PacsError> {
    let mut wait = Duration::from_millis(500);
    let mut attempt = 1;
    loop {
        match request().await {
            Ok(answer) => return Ok(answer),
            Err(e) if e.retryable() && attempt < options.attempts => {
                tracing::warn!(
                    "{e}; trying again in {} ms (try {attempt} of {})",
                    wait.as_millis(),
                    options.attempts
                );
                tokio::time::sleep(wait).await;
                wait = (wait * 2).min(Duration::from_secs(4));
                attempt += 1;
            }
            Err(e) => return Err(e),
        }
    }
}

fn malformed(web: &DicomWeb, study: &str, series: &str, what: String) -> PacsError {
    PacsError::Malformed {
        pacs: web.name().to_owned(),
        url: format!("study {study:?}, series {series:?}"),
        what,
    }
}

/// A fetched series as a volume: read from the spool folder by the DICOM
/// folder reader, with the series' place on the PACS as its source. Every
/// frame of every instance must have become a slice.
pub fn open_fetched(fetched: &Fetched) -> anyhow::Result<Box<dyn VolumeSource>> {
    let options = OpenOptions {
        series: Some(fetched.series.clone()),
        ..OpenOptions::default()
    };
    let inner = ingest::open(fetched.dir.path(), &options).map_err(|e| {
        anyhow::anyhow!("series {} of study {}: {e}", fetched.series, fetched.study)
    })?;
    let slices = u64::from(inner.info().geometry.dims[2]);
    let frames: u64 = fetched.instances.iter().map(|i| i.frames).sum();
    if slices != frames {
        anyhow::bail!(
            "series {} of study {}: {} instances of {frames} frames retrieved but {slices} slices read; expected one slice per frame",
            fetched.series,
            fetched.study,
            fetched.instances.len()
        );
    }
    let mut info = inner.info().clone();
    info.path = PathBuf::from(&fetched.url);
    Ok(Box::new(FromPacs { inner, info }))
}

/// A volume read from a spool folder, named by its place on the PACS.
#[derive(Debug)]
struct FromPacs {
    inner: Box<dyn VolumeSource>,
    info: VolumeInfo,
}

impl VolumeSource for FromPacs {
    fn info(&self) -> &VolumeInfo {
        &self.info
    }

    fn read_slab(&mut self, z0: u32, depth: u32) -> Result<blocks::VoxelData, blocks::Error> {
        self.inner.read_slab(z0, depth)
    }
}
