//! [`StoreLocation`]: where a brick store lives.

use std::fmt;
use std::path::{Path, PathBuf};

/// Where a brick store lives: a folder on a local file system, an object
/// store ([`super::remote`]), or memory (the built-in phantom, a file
/// rendered without an ingest). Messages about the store and its files name
/// it through [`StoreLocation::file`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StoreLocation {
    /// A folder on a local file system.
    Folder(PathBuf),
    /// A prefix of an object store, by URL (`s3://bucket/prefix/name.zarr`),
    /// without a trailing `/`.
    Remote(String),
    /// A store held in memory, under the name of what it was made from.
    Memory(String),
}

impl StoreLocation {
    /// The folder, for a store on a local file system.
    pub fn folder(&self) -> Option<&Path> {
        match self {
            StoreLocation::Folder(path) => Some(path),
            StoreLocation::Remote(_) | StoreLocation::Memory(_) => None,
        }
    }

    /// How messages name `key` (a `/`-separated path inside the store, `""`
    /// for the store itself): the file's path in a folder, its URL in an
    /// object store, `memory:NAME/KEY` in memory.
    pub fn file(&self, key: &str) -> PathBuf {
        match self {
            StoreLocation::Folder(path) if key.is_empty() => path.clone(),
            StoreLocation::Folder(path) => path.join(key),
            StoreLocation::Remote(url) if key.is_empty() => url.into(),
            StoreLocation::Remote(url) => format!("{url}/{key}").into(),
            StoreLocation::Memory(name) if key.is_empty() => format!("memory:{name}").into(),
            StoreLocation::Memory(name) => format!("memory:{name}/{key}").into(),
        }
    }
}

impl fmt::Display for StoreLocation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file("").display())
    }
}

/// A path as given on a command line: an object-store URL
/// ([`super::is_url`]) is a remote location, anything else a folder.
impl From<&Path> for StoreLocation {
    fn from(path: &Path) -> StoreLocation {
        match path.to_str() {
            Some(name) if super::is_url(name) => {
                StoreLocation::Remote(name.trim_end_matches('/').to_owned())
            }
            _ => StoreLocation::Folder(path.to_owned()),
        }
    }
}

impl From<&PathBuf> for StoreLocation {
    fn from(path: &PathBuf) -> StoreLocation {
        StoreLocation::from(path.as_path())
    }
}

impl From<PathBuf> for StoreLocation {
    fn from(path: PathBuf) -> StoreLocation {
        StoreLocation::from(path.as_path())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_files_in_folders_and_in_memory() {
        let folder = StoreLocation::from(Path::new("/data/head.zarr"));
        assert_eq!(folder.file(""), Path::new("/data/head.zarr"));
        assert_eq!(
            folder.file("0/c/0/0/1"),
            Path::new("/data/head.zarr/0/c/0/0/1")
        );
        assert_eq!(folder.folder(), Some(Path::new("/data/head.zarr")));
        let memory = StoreLocation::Memory("phantom".into());
        assert_eq!(memory.to_string(), "memory:phantom");
        assert_eq!(
            memory.file("zarr.json"),
            Path::new("memory:phantom/zarr.json")
        );
        assert_eq!(memory.folder(), None);
        let remote = StoreLocation::Remote("s3://bucket/scans/head.zarr".into());
        assert_eq!(
            remote.file("0/c/0/0/1"),
            Path::new("s3://bucket/scans/head.zarr/0/c/0/0/1")
        );
        assert_eq!(remote.to_string(), "s3://bucket/scans/head.zarr");
        assert_eq!(remote.folder(), None);
        assert_eq!(
            StoreLocation::from(Path::new("s3://bucket/scans/head.zarr/")),
            remote
        );
    }
}
