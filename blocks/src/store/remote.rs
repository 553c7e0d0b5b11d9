//! Brick stores on object storage: S3 and S3-compatible servers, Google Cloud
//! Storage, Azure Blob Storage (through `object_store`), and read-only stores
//! behind plain HTTP(S).
//!
//! A store there has the same keys as on disk, under a prefix
//! (`s3://bucket/prefix/name.zarr/0/c/0/0/0`), so any Zarr reader can read it.
//! [`Remote`] is one such prefix. [`ObjectStorage`] reads it for `zarrs`: one
//! request per byte range (sizes come from the listing or the manifest, so
//! no `HEAD` precedes a range read), on a small runtime of its own, so
//! readers on any thread (inside an async runtime or not) block only
//! themselves. Every read carries the ETag the object had when the store was
//! opened (`If-Match`): an object replaced since (another ingest to the same
//! prefix) fails the read instead of mixing two volumes' blocks.
//!
//! Credentials and endpoints come from the usual environment variables
//! (`AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`, `AWS_SESSION_TOKEN`,
//! `AWS_REGION`, `AWS_ENDPOINT_URL` for an S3-compatible server; the
//! `GOOGLE_*` and `AZURE_*` ones), or from instance metadata where
//! `object_store` finds it. An `http://` endpoint is allowed when
//! `AWS_ENDPOINT_URL` names one.
//!
//! Writing ([`Remote::upload`]): an ingest writes the store to a local folder
//! first, then uploads it, only to an empty prefix or over a brick store:
//! the old manifest is deleted first (a store without one is refused as
//! incomplete), then every file goes up, then the files the old manifest
//! listed and the new one lacks are deleted (no other object), and the
//! manifest goes last.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use futures_util::{StreamExt, TryStreamExt};
use object_store::path::Path as ObjectPath;
use object_store::{
    ClientOptions, GetOptions, GetRange, ObjectStore, ObjectStoreExt, PutPayload, RetryConfig,
};
use zarrs::storage::byte_range::{ByteRange, ByteRangeIterator};
use zarrs::storage::{
    Bytes, MaybeBytes, MaybeBytesIterator, ReadableStorageTraits, StorageError, StoreKey,
};

use super::disk_cache::DiskCache;
use super::manifest::{MANIFEST_KEY, Manifest};
use crate::Error;

/// The largest object [`ObjectStorage::read_ahead`] reads ahead.
pub const READ_AHEAD_BYTES: u64 = 64 << 20;

/// The disk cache and the key there of `range` of `object` at `url`: none
/// without a cache, for an object that is neither listed with an ETag nor
/// in a manifest, or for a range too large to keep.
fn cached(url: &str, object: &Object, range: &Range<u64>) -> Option<(&'static DiskCache, String)> {
    let cache = super::disk_cache::get()?;
    let version = match (&object.e_tag, &object.sha256) {
        (Some(e_tag), _) => format!("etag {e_tag}"),
        (None, Some(sha256)) => format!("sha256 {sha256}"),
        (None, None) => return None,
    };
    let small = range.end - range.start <= super::disk_cache::MAX_ENTRY_BYTES as u64;
    (small && !range.is_empty()).then(|| (cache, DiskCache::key(url, &version, range)))
}

/// `len` bytes from the disk cache where `cached` ([`cached`]) holds them,
/// else from `fetch`, kept there for next time.
async fn read_through(
    cached: Option<(&'static DiskCache, String)>,
    len: u64,
    fetch: impl Future<Output = Result<Bytes, object_store::Error>>,
) -> Result<Bytes, object_store::Error> {
    if let Some((cache, key)) = &cached
        && let Some(bytes) = cache.read(key).await
        && bytes.len() as u64 == len
    {
        return Ok(bytes);
    }
    let bytes = fetch.await?;
    if let Some((cache, key)) = cached {
        cache.keep(key, &bytes);
    }
    Ok(bytes)
}

/// The URL schemes of object stores.
pub const SCHEMES: [&str; 8] = ["s3", "s3a", "gs", "az", "abfs", "abfss", "http", "https"];
/// Requests in flight at once while uploading or checking a store.
const IN_FLIGHT: usize = 16;
/// Requests in flight at once while an opening reads ahead: its small
/// objects (the block statistics are one object per chunk of them) cost a
/// round trip each, not bandwidth.
const READ_AHEAD_IN_FLIGHT: usize = 64;
/// The longest wait for a connection.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(3);

/// How requests to object stores wait and retry (`--store-timeout-s`,
/// `--store-retries`, whose defaults are the server's); set once per
/// process with [`set_policy`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Policy {
    /// A request's longest wait for its whole answer: a stalled server
    /// fails the request, which is retried.
    pub timeout: Duration,
    /// Retries of a failed request (with exponential backoff) before the
    /// read fails.
    pub retries: usize,
}

static POLICY: OnceLock<Policy> = OnceLock::new();

/// Sets how every later request waits and retries; the first call wins.
pub fn set_policy(policy: Policy) {
    let _ = POLICY.set(policy);
}

/// The policy set, or the defaults.
fn policy() -> Policy {
    *POLICY.get_or_init(|| Policy {
        timeout: Duration::from_secs(15),
        retries: 4,
    })
}
/// Files up to this size are uploaded in one request; larger ones in parts.
const PART_BYTES: usize = 8 << 20;

/// Whether `name` is an object-store URL (`s3://…`, `https://…`).
pub fn is_url(name: &str) -> bool {
    name.split_once("://")
        .is_some_and(|(scheme, _)| SCHEMES.contains(&scheme.to_ascii_lowercase().as_str()))
}

/// One prefix of an object store holding one brick store (or, for `serve
/// --data`, several).
pub struct Remote {
    /// The URL, without a trailing `/`.
    url: String,
    /// The bucket or container (the host for HTTP).
    bucket: String,
    store: Arc<dyn ObjectStore>,
    prefix: ObjectPath,
    /// Whether the store can list (plain HTTP cannot).
    lists: bool,
}

impl std::fmt::Debug for Remote {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Remote")
            .field("url", &self.url)
            .finish_non_exhaustive()
    }
}

/// An object of a listing: its size and ETag.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Object {
    /// Its size in bytes.
    pub bytes: u64,
    /// Its ETag, when the store gives one.
    pub e_tag: Option<String>,
    /// Its SHA-256 by the store's manifest (lowercase hex), once known.
    pub sha256: Option<String>,
}

/// The runtime that drives every object-store request: its own, so that a
/// request can be waited for from any thread.
fn io_runtime() -> &'static tokio::runtime::Runtime {
    static RUNTIME: OnceLock<tokio::runtime::Runtime> = OnceLock::new();
    RUNTIME.get_or_init(|| {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("object-store-io")
            .enable_all()
            .build()
            .unwrap_or_else(|e| panic!("cannot start the object-store I/O runtime: {e}"))
    })
}

/// Runs `future` on the I/O runtime and waits for it on this thread.
pub(super) fn run<T: Send + 'static>(
    future: impl Future<Output = T> + Send + 'static,
) -> Option<T> {
    let (done, result) = std::sync::mpsc::sync_channel(1);
    io_runtime().spawn(async move {
        // The waiter may have gone (it never does before the result).
        let _ = done.send(future.await);
    });
    result.recv().ok()
}

impl Remote {
    /// The object store at `url`, with credentials and endpoint from the
    /// environment.
    pub fn parse(url: &str) -> Result<Remote, Error> {
        let trimmed = url.trim_end_matches('/');
        let bad = |message: String| Error::Field {
            path: PathBuf::from(url),
            field: "url".into(),
            message,
        };
        let parsed = url::Url::parse(trimmed).map_err(|e| {
            bad(format!(
                "{e}: expected an object-store URL such as s3://bucket/prefix/name.zarr"
            ))
        })?;
        let scheme = parsed.scheme().to_ascii_lowercase();
        if !SCHEMES.contains(&scheme.as_str()) {
            return Err(bad(format!(
                "scheme '{scheme}': expected one of {}",
                SCHEMES.join(", ")
            )));
        }
        let bucket = parsed.host_str().unwrap_or_default().to_owned();
        if bucket.is_empty() {
            return Err(bad(
                "no bucket: expected s3://bucket/prefix/name.zarr".into()
            ));
        }
        let Policy { timeout, retries } = policy();
        let client = ClientOptions::new()
            .with_timeout(timeout)
            .with_connect_timeout(CONNECT_TIMEOUT.min(timeout));
        // Retries end at whichever comes first: their count, or twice the
        // time they could take without backoff.
        let retry = RetryConfig {
            max_retries: retries,
            retry_timeout: timeout * 2 * (retries as u32 + 1),
            ..RetryConfig::default()
        };
        let built: Result<(Arc<dyn ObjectStore>, ObjectPath), object_store::Error> =
            if scheme == "s3" || scheme == "s3a" {
                let endpoint = std::env::var("AWS_ENDPOINT_URL")
                    .or_else(|_| std::env::var("AWS_ENDPOINT"))
                    .unwrap_or_default();
                object_store::aws::AmazonS3Builder::from_env()
                    .with_url(trimmed)
                    .with_client_options(client.with_allow_http(endpoint.starts_with("http://")))
                    .with_retry(retry)
                    .build()
                    .map(|s| {
                        let path = ObjectPath::from_url_path(parsed.path()).unwrap_or_default();
                        (Arc::new(s) as Arc<dyn ObjectStore>, path)
                    })
            } else {
                let mut options: Vec<(String, String)> = std::env::vars()
                    .filter(|(k, _)| k.starts_with("GOOGLE_") || k.starts_with("AZURE_"))
                    .map(|(k, v)| (k.to_ascii_lowercase(), v))
                    .collect();
                options.push(("timeout".into(), format!("{}s", timeout.as_secs())));
                options.push((
                    "connect_timeout".into(),
                    format!("{}s", CONNECT_TIMEOUT.min(timeout).as_secs()),
                ));
                if scheme == "http" {
                    options.push(("allow_http".into(), "true".into()));
                }
                object_store::parse_url_opts(&parsed, options)
                    .map(|(store, path)| (Arc::from(store), path))
            };
        let (store, prefix) = built.map_err(|e| bad(format!("{e}")))?;
        Ok(Remote {
            url: trimmed.to_owned(),
            bucket,
            store,
            prefix,
            lists: !scheme.starts_with("http"),
        })
    }

    /// The URL, without a trailing `/`.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// The last part of the URL's path (`head.zarr`).
    pub fn name(&self) -> &str {
        self.url.rsplit('/').next().unwrap_or(&self.url)
    }

    /// Whether the store can list its objects (plain HTTP cannot).
    pub fn lists(&self) -> bool {
        self.lists
    }

    /// How messages name `key` inside this prefix.
    pub fn file(&self, key: &str) -> PathBuf {
        if key.is_empty() {
            PathBuf::from(&self.url)
        } else {
            PathBuf::from(format!("{}/{key}", self.url))
        }
    }

    /// The same store under `key` (a `/`-separated path inside this prefix).
    pub fn child(&self, key: &str) -> Remote {
        Remote {
            url: format!("{}/{}", self.url, key.trim_matches('/')),
            bucket: self.bucket.clone(),
            store: self.store.clone(),
            prefix: self.path(key.trim_matches('/')),
            lists: self.lists,
        }
    }

    fn path(&self, key: &str) -> ObjectPath {
        key.split('/')
            .filter(|p| !p.is_empty())
            .fold(self.prefix.clone(), ObjectPath::join)
    }

    /// The error for a failed request about `key`, naming the object and,
    /// when access was refused, the bucket.
    fn error(&self, key: &str, e: &object_store::Error) -> Error {
        let path = self.file(key);
        // S3 errors other than on a single object (a listing's) come as
        // `Generic` with the HTTP status only in their text.
        let text = e.to_string();
        let refused = matches!(
            e,
            object_store::Error::PermissionDenied { .. }
                | object_store::Error::Unauthenticated { .. }
        ) || text.contains(" 403 Forbidden")
            || text.contains(" 401 Unauthorized");
        let message = match e {
            _ if refused => {
                format!(
                    "access denied to bucket '{}' ({e}): expected credentials that may read it \
                     (AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, or a role)",
                    self.bucket
                )
            }
            object_store::Error::Precondition { .. } => {
                "the object changed after the store was opened (another ingest to the same \
                 place?): its blocks are not mixed with the old ones; open the store again"
                    .into()
            }
            other => format!("{other}: the object store did not answer as expected"),
        };
        Error::Field {
            path,
            field: "object".into(),
            message,
        }
    }

    /// Every object under this prefix, by key inside it.
    pub fn list(&self) -> Result<BTreeMap<String, Object>, Error> {
        let store = self.store.clone();
        let prefix = self.prefix.clone();
        let listed = run(async move {
            store
                .list(Some(&prefix))
                .map_ok(|meta| {
                    let key = meta
                        .location
                        .prefix_match(&prefix)
                        .map(|parts| {
                            parts
                                .map(|p| p.as_ref().to_owned())
                                .collect::<Vec<_>>()
                                .join("/")
                        })
                        .unwrap_or_default();
                    (
                        key,
                        Object {
                            bytes: meta.size,
                            e_tag: meta.e_tag,
                            sha256: None,
                        },
                    )
                })
                .try_collect::<BTreeMap<_, _>>()
                .await
        })
        .ok_or_else(|| self.ended(""))?;
        listed.map_err(|e| self.error("", &e))
    }

    /// The folders directly under this prefix.
    pub fn folders(&self) -> Result<Vec<String>, Error> {
        let store = self.store.clone();
        let prefix = self.prefix.clone();
        let listed = run(async move { store.list_with_delimiter(Some(&prefix)).await })
            .ok_or_else(|| self.ended(""))?
            .map_err(|e| self.error("", &e))?;
        Ok(listed
            .common_prefixes
            .iter()
            .filter_map(|p| p.filename().map(str::to_owned))
            .collect())
    }

    fn ended(&self, key: &str) -> Error {
        Error::Field {
            path: self.file(key),
            field: "object".into(),
            message: "the object-store I/O runtime stopped".into(),
        }
    }

    /// The object `key` whole, `None` when there is none; refused over
    /// `max_bytes`.
    pub fn get(&self, key: &str, max_bytes: u64) -> Result<Option<Bytes>, Error> {
        let store = self.store.clone();
        let path = self.path(key);
        let got = run(async move {
            let head = match store.head(&path).await {
                Ok(head) => head,
                Err(e) => return Err(e),
            };
            if head.size > max_bytes {
                return Ok(Err(head.size));
            }
            let options = GetOptions {
                if_match: head.e_tag,
                ..GetOptions::default()
            };
            Ok(Ok(store.get_opts(&path, options).await?.bytes().await?))
        })
        .ok_or_else(|| self.ended(key))?;
        match got {
            Ok(Ok(bytes)) => Ok(Some(bytes)),
            Ok(Err(size)) => Err(Error::Field {
                path: self.file(key),
                field: "size".into(),
                message: format!("{size} bytes: expected at most {max_bytes}"),
            }),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(self.error(key, &e)),
        }
    }

    /// Uploads the complete store in `folder` here (see the module's
    /// documentation for the order), `IN_FLIGHT` files at a time; returns
    /// the files and bytes uploaded.
    pub fn upload(&self, folder: &Path) -> Result<(usize, u64), Error> {
        let manifest = Manifest::read(folder)?;
        let before = self.list()?;
        // What the old store listed: only its files are ever deleted, never
        // other objects under the prefix.
        let old = match self.get(MANIFEST_KEY, super::manifest::MAX_MANIFEST_BYTES)? {
            Some(text) => Some(Manifest::parse(&text, &self.file(MANIFEST_KEY))?),
            None => None,
        };
        if old.is_none() && !before.is_empty() {
            return Err(Error::Field {
                path: self.file(""),
                field: "output".into(),
                message: format!(
                    "holds {} objects but no brick store: expected an empty prefix or a brick \
                     store to replace (nothing was written)",
                    before.len()
                ),
            });
        }
        let store = self.store.clone();
        if before.contains_key(MANIFEST_KEY) {
            let path = self.path(MANIFEST_KEY);
            let store = store.clone();
            run(async move { store.delete(&path).await })
                .ok_or_else(|| self.ended(MANIFEST_KEY))?
                .map_err(|e| self.error(MANIFEST_KEY, &e))?;
        }
        let files: Vec<(String, PathBuf, ObjectPath)> = manifest
            .files
            .keys()
            .map(|key| (key.clone(), folder.join(key), self.path(key)))
            .collect();
        let bytes: u64 = manifest.files.values().map(|f| f.bytes).sum();
        let count = files.len();
        let uploads = {
            let store = store.clone();
            run(async move {
                futures_util::stream::iter(files)
                    .map(|(key, file, path)| {
                        let store = store.clone();
                        async move { upload_file(store, &file, &path).await.map_err(|e| (key, e)) }
                    })
                    .buffer_unordered(IN_FLIGHT)
                    .try_collect::<Vec<()>>()
                    .await
            })
        };
        match uploads.ok_or_else(|| self.ended(""))? {
            Ok(_) => {}
            Err((key, UploadError::Read(source))) => {
                return Err(Error::Io {
                    path: folder.join(key),
                    source,
                });
            }
            Err((key, UploadError::Store(e))) => return Err(self.error(&key, &e)),
        }
        let stale: Vec<ObjectPath> = old
            .iter()
            .flat_map(|old| old.files.keys())
            .filter(|key| before.contains_key(*key) && !manifest.lists(key))
            .map(|key| self.path(key))
            .collect();
        if !stale.is_empty() {
            let store = store.clone();
            run(async move {
                let paths =
                    futures_util::stream::iter(stale.into_iter().map(Ok::<_, object_store::Error>))
                        .boxed();
                store.delete_stream(paths).try_collect::<Vec<_>>().await
            })
            .ok_or_else(|| self.ended(""))?
            .map_err(|e| self.error("", &e))?;
        }
        let manifest_file = folder.join(MANIFEST_KEY);
        let manifest_path = self.path(MANIFEST_KEY);
        run(async move { upload_file(store, &manifest_file, &manifest_path).await })
            .ok_or_else(|| self.ended(MANIFEST_KEY))?
            .map_err(|e| match e {
                UploadError::Read(source) => Error::Io {
                    path: folder.join(MANIFEST_KEY),
                    source,
                },
                UploadError::Store(e) => self.error(MANIFEST_KEY, &e),
            })?;
        Ok((count + 1, bytes))
    }
}

/// Checks every object of the store at `url` against its manifest, as
/// [`super::verify`] checks a folder: sizes and SHA-256 of every listed
/// object (read `REMOTE_READERS` at a time), and no objects beside them.
pub fn verify(url: &str) -> Result<super::Verification, Error> {
    use rayon::prelude::*;
    let remote = Remote::parse(url)?;
    let text = remote
        .get(MANIFEST_KEY, super::manifest::MAX_MANIFEST_BYTES)?
        .ok_or_else(|| Manifest::missing(&remote.file(MANIFEST_KEY)))?;
    let manifest = Manifest::parse(&text, &remote.file(MANIFEST_KEY))?;
    let listing = remote.list()?;
    let problem = |key: &str, what: String| super::manifest::Problem {
        path: remote.file(key),
        what,
    };
    let mut problems: Vec<super::manifest::Problem> =
        crate::cache::remote_reader_pool().install(|| {
            manifest
                .files
                .par_iter()
                .filter_map(|(key, entry)| {
                    let missing = || "missing: the manifest lists it".to_owned();
                    let what = match listing.get(key) {
                        None => missing(),
                        Some(object) if object.bytes != entry.bytes => {
                            format!("{} bytes: the manifest says {}", object.bytes, entry.bytes)
                        }
                        Some(_) => match remote.get(key, entry.bytes) {
                            Ok(None) => missing(),
                            Err(e) => format!("unreadable: {e}"),
                            Ok(Some(bytes))
                                if super::manifest::sha256_hex(&bytes) != entry.sha256 =>
                            {
                                "changed: its SHA-256 differs from the manifest's".to_owned()
                            }
                            Ok(Some(_)) => return None,
                        },
                    };
                    Some(problem(key, what))
                })
                .collect()
        });
    problems.extend(
        listing
            .keys()
            .filter(|key| *key != MANIFEST_KEY && !manifest.lists(key))
            .map(|key| {
                problem(
                    key,
                    "not in the manifest: the ingest did not write it".into(),
                )
            }),
    );
    problems.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(super::Verification {
        files: manifest.files.len(),
        bytes: manifest.files.values().map(|f| f.bytes).sum(),
        problems,
    })
}

/// Why a file's upload failed.
#[derive(Debug)]
enum UploadError {
    Read(std::io::Error),
    Store(object_store::Error),
}

/// Uploads `file` to `path`: in one request, or in parts of `PART_BYTES`.
async fn upload_file(
    store: Arc<dyn ObjectStore>,
    file: &Path,
    path: &ObjectPath,
) -> Result<(), UploadError> {
    use tokio::io::AsyncReadExt;
    let mut reader = tokio::fs::File::open(file)
        .await
        .map_err(UploadError::Read)?;
    let size = reader.metadata().await.map_err(UploadError::Read)?.len();
    if size <= PART_BYTES as u64 {
        let mut bytes = Vec::with_capacity(size as usize);
        reader
            .read_to_end(&mut bytes)
            .await
            .map_err(UploadError::Read)?;
        store
            .put(path, PutPayload::from(bytes))
            .await
            .map_err(UploadError::Store)?;
        return Ok(());
    }
    let upload = store
        .put_multipart(path)
        .await
        .map_err(UploadError::Store)?;
    let mut parts = object_store::WriteMultipart::new_with_chunk_size(upload, PART_BYTES);
    let mut buffer = vec![0; 1 << 20];
    loop {
        let n = reader.read(&mut buffer).await.map_err(UploadError::Read)?;
        if n == 0 {
            break;
        }
        parts
            .wait_for_capacity(2)
            .await
            .map_err(UploadError::Store)?;
        parts.write(&buffer[..n]);
    }
    parts.finish().await.map_err(UploadError::Store)?;
    Ok(())
}

/// Why an object store's read failed in a way that may pass: it did not
/// answer, or answered with a server error.
#[derive(Debug)]
pub struct Unreachable(pub String);

impl std::fmt::Display for Unreachable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Unreachable {}

/// A store on object storage read by `zarrs`: the objects a listing (or the
/// manifest) names, each read with the ETag it had then. An object it does
/// not name reads as absent.
pub struct ObjectStorage {
    remote: Arc<Remote>,
    objects: BTreeMap<String, Object>,
    /// Whole objects read ahead ([`ObjectStorage::read_ahead`]), served from
    /// memory until [`ObjectStorage::forget_read_ahead`].
    read_ahead: std::sync::RwLock<BTreeMap<String, Bytes>>,
}

impl std::fmt::Debug for ObjectStorage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ObjectStorage")
            .field("remote", &self.remote)
            .field("objects", &self.objects.len())
            .finish()
    }
}

impl ObjectStorage {
    /// Reads `objects` of `remote`.
    pub fn new(remote: Arc<Remote>, objects: BTreeMap<String, Object>) -> ObjectStorage {
        ObjectStorage {
            remote,
            objects,
            read_ahead: std::sync::RwLock::default(),
        }
    }

    /// Reads the objects among `keys` that it reads (those of at most
    /// [`READ_AHEAD_BYTES`]) whole, `READ_AHEAD_IN_FLIGHT` at a time, and serves them
    /// from memory from now on: an opening reads its metadata and block
    /// statistics in one round of requests instead of one after another.
    pub fn read_ahead<'k>(&self, keys: impl IntoIterator<Item = &'k str>) -> Result<(), Error> {
        let wanted: Vec<(String, ObjectPath, Object, String)> = keys
            .into_iter()
            .filter_map(|key| {
                let object = self.objects.get(key)?;
                let url = self.remote.file(key).to_string_lossy().into_owned();
                (object.bytes <= READ_AHEAD_BYTES)
                    .then(|| (key.to_owned(), self.remote.path(key), object.clone(), url))
            })
            .collect();
        let store = self.remote.store.clone();
        let read = run(async move {
            futures_util::stream::iter(wanted)
                .map(|(key, path, object, url)| {
                    let store = store.clone();
                    let cached = cached(&url, &object, &(0..object.bytes));
                    async move {
                        let options = GetOptions {
                            if_match: object.e_tag,
                            ..GetOptions::default()
                        };
                        let fetch = async { store.get_opts(&path, options).await?.bytes().await };
                        match read_through(cached, object.bytes, fetch).await {
                            Ok(bytes) => Ok(Some((key, bytes))),
                            // Left for the read that needs it to report.
                            Err(object_store::Error::NotFound { .. }) => Ok(None),
                            Err(e) => Err((key, e)),
                        }
                    }
                })
                .buffered(READ_AHEAD_IN_FLIGHT)
                .try_collect::<Vec<Option<(String, Bytes)>>>()
                .await
        })
        .ok_or_else(|| self.remote.ended(""))?;
        let read = read.map_err(|(key, e)| self.remote.error(&key, &e))?;
        let mut held = self
            .read_ahead
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        held.extend(read.into_iter().flatten());
        Ok(())
    }

    /// Drops the objects read ahead: later reads go to the store again.
    pub fn forget_read_ahead(&self) {
        self.read_ahead
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clear();
    }

    /// The storage error for a failed request about `key`: one that may
    /// pass (no answer, a server error) is an [`Unreachable`] I/O error,
    /// which the store reads as [`Error::Unavailable`].
    fn failed(&self, key: &str, e: &object_store::Error) -> StorageError {
        let error = self.remote.error(key, e);
        let lasting = matches!(
            e,
            object_store::Error::Precondition { .. }
                | object_store::Error::PermissionDenied { .. }
                | object_store::Error::Unauthenticated { .. }
                | object_store::Error::InvalidPath { .. }
        ) || error.to_string().contains("access denied");
        if lasting {
            StorageError::Other(error.to_string())
        } else {
            StorageError::IOError(Arc::new(std::io::Error::other(Unreachable(format!("{e}")))))
        }
    }
}

impl ReadableStorageTraits for ObjectStorage {
    fn get_partial_many<'a>(
        &'a self,
        key: &StoreKey,
        byte_ranges: ByteRangeIterator<'a>,
    ) -> Result<MaybeBytesIterator<'a>, StorageError> {
        let Some(object) = self.objects.get(key.as_str()) else {
            return Ok(None);
        };
        let ranges: Vec<Range<u64>> = byte_ranges
            .map(|range: ByteRange| range.to_range(object.bytes))
            .collect();
        if ranges
            .iter()
            .any(|r| r.start > r.end || r.end > object.bytes)
        {
            return Err(StorageError::Other(format!(
                "{}: a byte range beyond its {} bytes",
                self.remote.file(key.as_str()).display(),
                object.bytes
            )));
        }
        if let Some(whole) = self
            .read_ahead
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .get(key.as_str())
        {
            // The ranges lie within the object's size, which its ETag fixes.
            let parts: Vec<Bytes> = ranges
                .iter()
                .map(|r| whole.slice(r.start as usize..r.end as usize))
                .collect();
            return Ok(Some(Box::new(parts.into_iter().map(Ok))));
        }
        let store = self.remote.store.clone();
        let path = self.remote.path(key.as_str());
        let url = self
            .remote
            .file(key.as_str())
            .to_string_lossy()
            .into_owned();
        let object = object.clone();
        let read = run(async move {
            futures_util::stream::iter(ranges)
                .map(|range| {
                    let (store, path, e_tag) = (store.clone(), path.clone(), object.e_tag.clone());
                    let cached = cached(&url, &object, &range);
                    async move {
                        if range.is_empty() {
                            return Ok(Bytes::new());
                        }
                        let len = range.end - range.start;
                        let options = GetOptions {
                            if_match: e_tag,
                            range: Some(GetRange::Bounded(range)),
                            ..GetOptions::default()
                        };
                        let fetch = async { store.get_opts(&path, options).await?.bytes().await };
                        read_through(cached, len, fetch).await
                    }
                })
                .buffered(IN_FLIGHT)
                .try_collect::<Vec<Bytes>>()
                .await
        })
        .ok_or_else(|| StorageError::Other("the object-store I/O runtime stopped".into()))?;
        match read {
            Ok(parts) => Ok(Some(Box::new(parts.into_iter().map(Ok)))),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(self.failed(key.as_str(), &e)),
        }
    }

    fn get(&self, key: &StoreKey) -> Result<MaybeBytes, StorageError> {
        let Some(object) = self.objects.get(key.as_str()) else {
            return Ok(None);
        };
        let whole = ByteRange::FromStart(0, Some(object.bytes));
        match self.get_partial_many(key, Box::new(std::iter::once(whole)))? {
            Some(mut parts) => parts.next().transpose(),
            None => Ok(None),
        }
    }

    fn size_key(&self, key: &StoreKey) -> Result<Option<u64>, StorageError> {
        Ok(self.objects.get(key.as_str()).map(|o| o.bytes))
    }

    fn supports_get_partial(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_name_object_stores_and_refuse_other_schemes() {
        assert!(is_url("s3://bucket/head.zarr"));
        assert!(is_url("HTTPS://example.org/head.zarr"));
        assert!(!is_url("/data/head.zarr"));
        assert!(!is_url("ftp://host/head.zarr"));
        let e = Remote::parse("s3:///head.zarr")
            .expect_err("no bucket")
            .to_string();
        assert!(e.contains("no bucket"), "{e}");
        let remote = Remote::parse("s3://bucket/prefix/head.zarr/").expect("an S3 URL");
        assert_eq!(remote.url(), "s3://bucket/prefix/head.zarr");
        assert_eq!(remote.name(), "head.zarr");
        assert_eq!(
            remote.file("0/c/0/0/0"),
            Path::new("s3://bucket/prefix/head.zarr/0/c/0/0/0")
        );
        assert_eq!(
            remote.path("0/zarr.json").as_ref(),
            "prefix/head.zarr/0/zarr.json"
        );
        assert_eq!(
            remote.child("x.zarr").url(),
            "s3://bucket/prefix/head.zarr/x.zarr"
        );
    }
}
