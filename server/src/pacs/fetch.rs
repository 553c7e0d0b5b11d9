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
    fetch_series_with_preview(web, study, series, spool_in, options, progress, None).await
}

/// Instances a series needs for a preview to be taken first.
pub const PREVIEW_MIN_INSTANCES: usize = 64;
/// Images a preview holds, about.
pub const PREVIEW_IMAGES: usize = 32;

/// A receiver of a series' preview (see [`fetch_series_with_preview`]).
pub type Preview<'a> = Box<dyn FnOnce(Fetched) + Send + 'a>;

/// The instances of a preview: every k-th image in InstanceNumber order,
/// about [`PREVIEW_IMAGES`] of them, for a series of at least
/// [`PREVIEW_MIN_INSTANCES`] single-frame images all numbered (else none).
fn preview_sample(instances: &[InstanceRecord]) -> Vec<usize> {
    if instances.len() < PREVIEW_MIN_INSTANCES
        || instances
            .iter()
            .any(|i| i.frames != 1 || i.number.is_none())
    {
        return Vec::new();
    }
    let mut order: Vec<usize> = (0..instances.len()).collect();
    order.sort_by_key(|&i| instances[i].number);
    let stride = instances.len().div_ceil(PREVIEW_IMAGES);
    order.into_iter().step_by(stride).collect()
}

/// [`fetch_series`], retrieving a sample of the series first when it is
/// large enough ([`preview_sample`]): `preview` gets that sample, in a
/// spool folder of its own, while the rest is retrieved (nothing when
/// there is no sample). The sample's images are in the whole series too.
pub async fn fetch_series_with_preview(
    web: &DicomWeb,
    study: &str,
    series: &str,
    spool_in: &Path,
    options: FetchOptions,
    progress: Progress<'_>,
    preview: Option<Preview<'_>>,
) -> Result<Fetched, PacsError> {
    check_uid("StudyInstanceUID", study).map_err(|what| malformed(web, study, series, what))?;
    check_uid("SeriesInstanceUID", series).map_err(|what| malformed(web, study, series, what))?;
    let start = Instant::now();
    let instances = with_retries(options, || web.series_instances(study, series)).await?;
    let spool = || {
        tempfile::Builder::new()
            .prefix(".voxserve-fetch-")
            .tempdir_in(spool_in)
            .map_err(|source| PacsError::Io {
                path: spool_in.display().to_string(),
                source,
            })
    };
    let dir = spool()?;
    let url = web.url(&["studies", study, "series", series]).to_string();
    let count = Counts {
        total: instances.len(),
        done: AtomicUsize::new(0),
        bytes: AtomicU64::new(0),
    };
    progress(0, count.total, 0);
    let sample = if preview.is_some() {
        preview_sample(&instances)
    } else {
        Vec::new()
    };
    let mut rest: Vec<InstanceRecord> = instances.clone();
    if let Some(hand_over) = preview
        && !sample.is_empty()
    {
        let chosen: Vec<InstanceRecord> = sample.iter().map(|&i| instances[i].clone()).collect();
        let sample_dir = spool()?;
        retrieve(
            web,
            study,
            series,
            &chosen,
            sample_dir.path(),
            options,
            &count,
            progress,
        )
        .await?;
        for instance in &chosen {
            let name = format!("{}.dcm", instance.sop_uid);
            let (from, to) = (sample_dir.path().join(&name), dir.path().join(&name));
            std::fs::hard_link(&from, &to)
                .or_else(|_| std::fs::copy(&from, &to).map(drop))
                .map_err(|source| PacsError::Io {
                    path: to.display().to_string(),
                    source,
                })?;
        }
        rest.retain(|i| !chosen.iter().any(|c| c.sop_uid == i.sop_uid));
        hand_over(Fetched {
            dir: sample_dir,
            study: study.to_owned(),
            series: series.to_owned(),
            instances: chosen,
            bytes: count.bytes.load(Ordering::Relaxed),
            seconds: start.elapsed().as_secs_f64(),
            url: url.clone(),
        });
    }
    retrieve(
        web,
        study,
        series,
        &rest,
        dir.path(),
        options,
        &count,
        progress,
    )
    .await?;
    Ok(Fetched {
        dir,
        study: study.to_owned(),
        series: series.to_owned(),
        instances,
        bytes: count.bytes.into_inner(),
        seconds: start.elapsed().as_secs_f64(),
        url,
    })
}

/// Instances retrieved of all, and bytes, over a fetch's parts.
struct Counts {
    total: usize,
    done: AtomicUsize,
    bytes: AtomicU64,
}

/// Retrieves `instances` into `dir`, several at a time, counting them in
/// `count`.
#[expect(clippy::too_many_arguments, reason = "one fetch's parts, all needed")]
async fn retrieve(
    web: &DicomWeb,
    study: &str,
    series: &str,
    instances: &[InstanceRecord],
    dir: &Path,
    options: FetchOptions,
    count: &Counts,
    progress: Progress<'_>,
) -> Result<(), PacsError> {
    // By index, not by reference: a closure over `&InstanceRecord` would be
    // higher-ranked, and the future could not be spawned.
    futures_util::stream::iter(0..instances.len())
        .map(|i| {
            let instance = &instances[i];
            // Named by the SOP instance UID (digits and dots), so that an
            // error reading the file names the instance.
            let dest = dir.join(format!("{}.dcm", instance.sop_uid));
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
                let b = count.bytes.fetch_add(n, Ordering::Relaxed) + n;
                let d = count.done.fetch_add(1, Ordering::Relaxed) + 1;
                progress(d, count.total, b);
                Ok::<(), PacsError>(())
            }
        })
        .buffer_unordered(options.concurrency.max(1))
        .try_collect::<Vec<()>>()
        .await?;
    Ok(())
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
