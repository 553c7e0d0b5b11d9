//! The manifest: every file of a store on disk with its size and SHA-256,
//! written at ingest after everything else, as `voxserve/manifest.json`.
//!
//! It is how a store knows which files it must hold. `zarrs` reads a missing
//! shard as the fill value, so a deleted shard would look like air; through
//! [`ManifestStorage`] a shard the manifest lists but the folder lacks is an
//! error naming the file instead, and a shard it does not list is one `zarrs`
//! left out because every voxel in it is the fill value (which the per-block
//! statistics confirm when the store opens). Opening a store checks that every
//! listed file is there and that the metadata (`zarr.json`) files are unchanged;
//! [`verify`] checks every byte.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sha2::Digest;
use zarrs::storage::byte_range::ByteRangeIterator;
use zarrs::storage::{
    MaybeBytes, MaybeBytesIterator, ReadableStorageTraits, StorageError, StoreKey,
};

use super::{StoreLocation, store_error};
use crate::Error;

/// Where the manifest lives inside a store.
pub const MANIFEST_KEY: &str = "voxserve/manifest.json";
/// The largest manifest read (a store of 2048³ voxels lists about 5 000 files
/// in under 1 MB).
pub const MAX_MANIFEST_BYTES: u64 = 64 << 20;
/// The most files a manifest may list.
const MAX_FILES: usize = 1 << 20;
/// The largest metadata file (`zarr.json`) read: a store's are a few KB.
pub const MAX_METADATA_BYTES: u64 = 16 << 20;
/// How many missing or damaged files a message names before it counts the rest.
const NAMED_IN_MESSAGES: usize = 3;

/// One file of the store.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileEntry {
    /// Its size in bytes.
    pub bytes: u64,
    /// Its SHA-256, lowercase hex.
    pub sha256: String,
}

/// Every file of a store, by key (its `/`-separated path inside the store).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always `sha256`.
    pub algorithm: String,
    /// The files.
    pub files: BTreeMap<String, FileEntry>,
}

/// A file of a store that does not match its manifest.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// The file.
    pub path: PathBuf,
    /// What is wrong with it.
    pub what: String,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.what)
    }
}

/// What [`verify`] found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Verification {
    /// Files the manifest lists.
    pub files: usize,
    /// Their bytes, read and hashed.
    pub bytes: u64,
    /// Every mismatch; empty when the store is intact.
    pub problems: Vec<Problem>,
}

impl Manifest {
    /// The manifest of every file now in `folder` (hashed in parallel).
    pub fn of_folder(folder: &Path) -> Result<Manifest, Error> {
        let mut keys = Vec::new();
        list_files(folder, "", &mut keys)?;
        let files = keys
            .into_par_iter()
            .map(|key| {
                let (bytes, sha256) = hash_file(&folder.join(&key))?;
                Ok((key, FileEntry { bytes, sha256 }))
            })
            .collect::<Result<BTreeMap<_, _>, Error>>()?;
        Ok(Manifest {
            algorithm: "sha256".into(),
            files,
        })
    }

    /// Writes the manifest into `folder` and flushes it to disk.
    pub fn write(&self, folder: &Path) -> Result<(), Error> {
        let path = folder.join(MANIFEST_KEY);
        let text = serde_json::to_vec_pretty(self)
            .map_err(|e| store_error(&path, "manifest", e.to_string()))?;
        let io = |source| Error::Io {
            path: path.clone(),
            source,
        };
        let mut file = std::fs::File::create(&path).map_err(io)?;
        std::io::Write::write_all(&mut file, &text).map_err(io)?;
        file.sync_all().map_err(io)
    }

    /// Reads the manifest of the store in `folder`.
    pub fn read(folder: &Path) -> Result<Manifest, Error> {
        let path = folder.join(MANIFEST_KEY);
        let file = std::fs::File::open(&path).map_err(|source| {
            if source.kind() == std::io::ErrorKind::NotFound {
                Manifest::missing(&path)
            } else {
                Error::Io {
                    path: path.clone(),
                    source,
                }
            }
        })?;
        let mut text = Vec::new();
        file.take(MAX_MANIFEST_BYTES + 1)
            .read_to_end(&mut text)
            .map_err(|source| Error::Io {
                path: path.clone(),
                source,
            })?;
        Manifest::parse(&text, &path)
    }

    /// The error for a store without its manifest at `path`.
    pub fn missing(path: &Path) -> Error {
        store_error(
            path,
            "manifest",
            "missing: expected the list of the store's files that every complete \
             store holds (the ingest did not finish or the file was deleted; ingest again)",
        )
    }

    /// The manifest in `text`, read from `path`.
    pub fn parse(text: &[u8], path: &Path) -> Result<Manifest, Error> {
        if text.len() as u64 > MAX_MANIFEST_BYTES {
            return Err(store_error(
                path,
                "manifest",
                format!("larger than {MAX_MANIFEST_BYTES} bytes: expected a store's file list"),
            ));
        }
        let manifest: Manifest = serde_json::from_slice(text)
            .map_err(|e| store_error(path, "manifest", e.to_string()))?;
        manifest.checked(path)?;
        Ok(manifest)
    }

    /// Refuses a manifest whose algorithm, keys or count a writer never produces.
    fn checked(&self, path: &Path) -> Result<(), Error> {
        if self.algorithm != "sha256" {
            return Err(store_error(
                path,
                "algorithm",
                format!("'{}': expected sha256", self.algorithm),
            ));
        }
        if self.files.len() > MAX_FILES {
            return Err(store_error(
                path,
                "files",
                format!("{} files: expected at most {MAX_FILES}", self.files.len()),
            ));
        }
        for (key, entry) in &self.files {
            let plain = !key.is_empty()
                && key
                    .split('/')
                    .all(|part| !part.is_empty() && part != "." && part != "..")
                && !key.contains('\\');
            if !plain || key == MANIFEST_KEY || StoreKey::new(key.clone()).is_err() {
                return Err(store_error(
                    path,
                    "files",
                    format!("'{key}': expected a relative path inside the store"),
                ));
            }
            if entry.sha256.len() != 64 || !entry.sha256.bytes().all(|b| b.is_ascii_hexdigit()) {
                return Err(store_error(
                    path,
                    &format!("files.{key}.sha256"),
                    "expected 64 hex digits",
                ));
            }
        }
        Ok(())
    }

    /// Whether the manifest lists `key`.
    pub fn lists(&self, key: &str) -> bool {
        self.files.contains_key(key)
    }

    /// Checks that every listed file is in `folder` with its size, and that the
    /// metadata files (`zarr.json`) are unchanged: what opening a store checks.
    pub fn check_quick(&self, folder: &Path) -> Result<(), Error> {
        self.check_with(
            &|key| folder.join(key),
            &|key| {
                std::fs::metadata(folder.join(key))
                    .ok()
                    .filter(std::fs::Metadata::is_file)
                    .map(|m| m.len())
            },
            &|key| hash_file(&folder.join(key)).map(|(_, sha256)| sha256),
        )
    }

    /// What [`Manifest::check_quick`] checks, anywhere: `name` names a key in
    /// messages, `size` is its size (`None`: missing), `sha256` hashes it.
    pub fn check_with(
        &self,
        name: &dyn Fn(&str) -> PathBuf,
        size: &dyn Fn(&str) -> Option<u64>,
        sha256: &dyn Fn(&str) -> Result<String, Error>,
    ) -> Result<(), Error> {
        let mut missing = Vec::new();
        for (key, entry) in &self.files {
            match size(key) {
                Some(bytes) if bytes == entry.bytes => {}
                Some(bytes) => {
                    return Err(Error::Corrupt {
                        path: name(key),
                        codec: "store manifest".into(),
                        detail: format!(
                            "{bytes} bytes: the manifest says {}; the file was changed after \
                             ingest (run voxserve verify)",
                            entry.bytes
                        ),
                    });
                }
                None => missing.push(name(key)),
            }
        }
        if !missing.is_empty() {
            return Err(missing_files(&missing));
        }
        for (key, entry) in self
            .files
            .iter()
            .filter(|(key, _)| key.ends_with("zarr.json"))
        {
            if entry.bytes > MAX_METADATA_BYTES {
                return Err(store_error(
                    &name(key),
                    "size",
                    format!(
                        "{} bytes: expected metadata of at most {MAX_METADATA_BYTES} bytes",
                        entry.bytes
                    ),
                ));
            }
            if sha256(key)? != entry.sha256 {
                return Err(Error::Corrupt {
                    path: name(key),
                    codec: "store manifest".into(),
                    detail: "its SHA-256 differs from the manifest's: the metadata was changed \
                             after ingest (run voxserve verify; ingest again)"
                        .into(),
                });
            }
        }
        Ok(())
    }
}

/// The SHA-256 of `bytes`, lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The error for files the manifest lists that the store lacks.
fn missing_files(missing: &[PathBuf]) -> Error {
    let others = &missing[1..];
    let named: Vec<String> = others
        .iter()
        .take(NAMED_IN_MESSAGES)
        .map(|p| p.display().to_string())
        .collect();
    let also = match others.len() {
        0 => String::new(),
        n if n <= NAMED_IN_MESSAGES => format!(" (so are {})", named.join(", ")),
        n => format!(
            " (so are {} and {} more)",
            named.join(", "),
            n - NAMED_IN_MESSAGES
        ),
    };
    Error::Missing {
        path: missing[0].clone(),
        detail: format!(
            "the store's manifest lists it{also}; its voxels are unknown, not empty, so the \
             store is not drawn (restore the file or ingest again)"
        ),
    }
}

/// Checks every file of the store in `folder` against its manifest: sizes and
/// SHA-256 of all listed files, and no files beside them.
pub fn verify(folder: &Path) -> Result<Verification, Error> {
    let manifest = Manifest::read(folder)?;
    let mut problems: Vec<Problem> = manifest
        .files
        .par_iter()
        .filter_map(|(key, entry)| {
            let path = folder.join(key);
            let what = match hash_file(&path) {
                Err(Error::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
                    "missing: the manifest lists it".to_owned()
                }
                Err(e) => format!("unreadable: {e}"),
                Ok((bytes, _)) if bytes != entry.bytes => {
                    format!("{bytes} bytes: the manifest says {}", entry.bytes)
                }
                Ok((_, sha256)) if sha256 != entry.sha256 => {
                    "changed: its SHA-256 differs from the manifest's".to_owned()
                }
                Ok(_) => return None,
            };
            Some(Problem { path, what })
        })
        .collect();
    let mut present = Vec::new();
    list_files(folder, "", &mut present)?;
    problems.extend(
        present
            .into_iter()
            .filter(|key| key != MANIFEST_KEY && !manifest.lists(key))
            .map(|key| Problem {
                path: folder.join(key),
                what: "not in the manifest: a file no ingest wrote".into(),
            }),
    );
    problems.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(Verification {
        files: manifest.files.len(),
        bytes: manifest.files.values().map(|e| e.bytes).sum(),
        problems,
    })
}

/// Appends the keys of every file under `folder/prefix`, except the manifest.
/// Anything but folders and regular files (a link, a device) is an error.
fn list_files(folder: &Path, prefix: &str, keys: &mut Vec<String>) -> Result<(), Error> {
    let dir = folder.join(prefix);
    let io = |source| Error::Io {
        path: dir.clone(),
        source,
    };
    for entry in std::fs::read_dir(&dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let name = entry.file_name();
        let name = name.to_str().ok_or_else(|| {
            store_error(&entry.path(), "file name", "expected UTF-8 (a store key)")
        })?;
        let key = if prefix.is_empty() {
            name.to_owned()
        } else {
            format!("{prefix}/{name}")
        };
        let kind = entry.file_type().map_err(io)?;
        if kind.is_dir() {
            list_files(folder, &key, keys)?;
        } else if kind.is_file() {
            if key != MANIFEST_KEY {
                keys.push(key);
            }
        } else {
            return Err(store_error(
                &entry.path(),
                "file type",
                "expected a regular file or folder (a store holds no links or devices)",
            ));
        }
    }
    Ok(())
}

/// The size and SHA-256 (lowercase hex) of a file.
fn hash_file(path: &Path) -> Result<(u64, String), Error> {
    let io = |source| Error::Io {
        path: path.to_owned(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut hasher = sha2::Sha256::new();
    let mut buffer = vec![0u8; 1 << 16];
    let mut bytes = 0u64;
    loop {
        let n = file.read(&mut buffer).map_err(io)?;
        if n == 0 {
            break;
        }
        hasher.update(&buffer[..n]);
        bytes += n as u64;
    }
    let hex = hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    Ok((bytes, hex))
}

/// Flushes every file and folder under `folder`, and `folder` itself, to disk.
pub fn sync_tree(folder: &Path) -> Result<(), Error> {
    let io = |source| Error::Io {
        path: folder.to_owned(),
        source,
    };
    for entry in std::fs::read_dir(folder).map_err(io)? {
        let entry = entry.map_err(io)?;
        let path = entry.path();
        if entry.file_type().map_err(io)?.is_dir() {
            sync_tree(&path)?;
        } else {
            std::fs::File::open(&path)
                .and_then(|f| f.sync_all())
                .map_err(|source| Error::Io { path, source })?;
        }
    }
    sync_folder(folder)
}

/// Flushes a folder's entries (names created, renamed or removed) to disk.
pub fn sync_folder(folder: &Path) -> Result<(), Error> {
    std::fs::File::open(folder)
        .and_then(|f| f.sync_all())
        .map_err(|source| Error::Io {
            path: folder.to_owned(),
            source,
        })
}

/// Storage that reads through `inner` and turns a key the manifest lists but
/// storage lacks into an error, where `zarrs` would read the fill value.
pub struct ManifestStorage {
    inner: Arc<dyn ReadableStorageTraits>,
    manifest: Arc<Manifest>,
    location: StoreLocation,
}

impl std::fmt::Debug for ManifestStorage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ManifestStorage")
            .field("location", &self.location)
            .field("listed", &self.manifest.files.len())
            .finish_non_exhaustive()
    }
}

impl ManifestStorage {
    /// Wraps `inner`, the storage of the store at `location`.
    pub fn new(
        inner: Arc<dyn ReadableStorageTraits>,
        manifest: Arc<Manifest>,
        location: StoreLocation,
    ) -> ManifestStorage {
        ManifestStorage {
            inner,
            manifest,
            location,
        }
    }

    /// `value`, or the error for a listed key that storage lacks.
    fn expected<T>(&self, key: &StoreKey, value: Option<T>) -> Result<Option<T>, StorageError> {
        if value.is_none() && self.manifest.lists(key.as_str()) {
            return Err(StorageError::IOError(Arc::new(std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!(
                    "{}: missing: the store's manifest lists it",
                    self.location.file(key.as_str()).display()
                ),
            ))));
        }
        Ok(value)
    }
}

impl ReadableStorageTraits for ManifestStorage {
    fn get_partial_many<'a>(
        &'a self,
        key: &StoreKey,
        byte_ranges: ByteRangeIterator<'a>,
    ) -> Result<MaybeBytesIterator<'a>, StorageError> {
        let value = self.inner.get_partial_many(key, byte_ranges)?;
        self.expected(key, value)
    }

    fn get(&self, key: &StoreKey) -> Result<MaybeBytes, StorageError> {
        let value = self.inner.get(key)?;
        self.expected(key, value)
    }

    fn size_key(&self, key: &StoreKey) -> Result<Option<u64>, StorageError> {
        let value = self.inner.size_key(key)?;
        self.expected(key, value)
    }

    fn supports_get_partial(&self) -> bool {
        self.inner.supports_get_partial()
    }
}
