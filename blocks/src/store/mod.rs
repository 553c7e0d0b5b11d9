//! The brick store: a volume cut into 16³ blocks, kept at every level of detail,
//! compressed on disk as OME-Zarr 0.5 (Zarr v3), written and read with `zarrs`.
//!
//! # Layout on disk
//! ```text
//! STORE/zarr.json                 root group: OME `multiscales` + `voxserve` metadata
//! STORE/0 … STORE/4/zarr.json     one array per level, shape [z, y, x] = ceil(dims / 2^l)
//! STORE/L/c/Z/Y/X                 shards of 128³ voxels holding inner chunks of 16³,
//!                                 each zstd-compressed with its content checksum;
//!                                 the shard index carries a crc32c
//! STORE/voxserve/block_min_max    f64 [level, bz, by, bx, 2]: stored min and max
//! STORE/voxserve/block_histogram  u16 [level, bz, by, bx, 32]: over the stored range
//! STORE/voxserve/manifest.json    every other file with its size and SHA-256 (written last)
//! ```
//! Level l is the volume averaged over boxes of 2^l voxels. A flat-blocking block
//! at level l — the 16³ region of the full volume seen at (16 / 2^l)³ voxels — is
//! the matching sub-cube of a level-l inner chunk: block b lies in chunk b >> l.
//! Any Zarr v3 reader (zarr-python, napari, neuroglancer) can read the levels.
//!
//! # Completeness
//! `zarrs` leaves out a shard whose voxels all hold the fill value (0) and reads
//! a missing one as that value, so a deleted shard would look like air. The
//! [`manifest`] lists every file the ingest wrote; a listed file that is missing
//! is [`Error::Missing`] naming it (when the store opens, and on every read), and
//! a shard it does not list must be one whose blocks the statistics say are all
//! 0, which [`Store::open`] checks. Opening also checks the metadata files
//! against their SHA-256; `voxserve verify` checks every byte.
//!
//! # Crash safety
//! A store is written under a hidden temporary name beside its destination,
//! flushed to disk, and moved into place only when complete; its root metadata
//! carries `"complete": true` and the manifest is written after it. An existing
//! store is replaced by one atomic exchange of the two folders, so the
//! destination holds a complete store, old or new, at every moment
//! ([`ingest`]). An interrupted ingest leaves at most hidden folders
//! (`.NAME.partial-PID`, `.NAME.old-PID`), which [`Store::open`] refuses and the
//! next ingest removes. Corruption is caught by the checksums: a damaged shard
//! index or chunk reads as [`Error::Corrupt`] naming the shard file, never as
//! garbage voxels.
//!
//! # Layout of this module
//! - [`pyramid`]: box averages of a slab for every level.
//! - [`stats`]: [`BlockStats`], per-block min, max and histogram.
//! - [`ingest`]: the writer, slab by slab from any [`crate::VolumeSource`].
//! - [`manifest`]: the store's files and their checksums; `verify`.
//! - [`StoreLocation`]: where a store lives (a folder, memory).

pub mod disk_cache;
pub mod ingest;
mod location;
pub mod manifest;
pub mod pyramid;
pub mod remote;
pub mod stats;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use zarrs::array::codec::api::CodecOptions;
use zarrs::array::{
    Array, ArrayBytes, ArrayError, ArrayShardedReadableExt, ArrayShardedReadableExtCache,
};
use zarrs::filesystem::FilesystemStore;
use zarrs::group::Group;
use zarrs::storage::ReadableStorageTraits;

pub use ingest::{IngestOptions, IngestProgress, IngestSummary, ingest, ingest_in_memory};
pub use location::StoreLocation;
pub use manifest::{Manifest, Verification, verify};
pub use pyramid::{LEVELS, level_dims};
pub use remote::{Remote, is_url};
pub use stats::{BLOCK, BlockStats, HISTOGRAM_BINS, grid_index, grid_position};

use crate::geometry::GeometryFields;
use crate::{Error, Geometry, ValueMap, VoxelData, VoxelType};

/// The version of the `voxserve` metadata this code writes and reads (2: with
/// a manifest).
pub const FORMAT_VERSION: u32 = 2;
/// Shard edge in voxels (8 inner chunks per axis).
pub const SHARD: u32 = 128;

/// What the root metadata says about the volume, under the `voxserve` key.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoreMeta {
    /// [`FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// Written last: a store without it is incomplete.
    pub complete: bool,
    /// Display name.
    pub name: String,
    /// Level 0's geometry in LPS, stored as the keys `dims`, `spacing`,
    /// `origin` and `direction` of this record (the format stores have
    /// always had).
    #[serde(flatten)]
    pub geometry: Geometry,
    /// Voxel type name (`uint16`, …).
    pub voxel_type: String,
    /// Stored → physical values.
    pub value_map: ValueMap,
    /// Unit of physical values.
    pub unit: Option<String>,
    /// Imaging modality.
    pub modality: Option<String>,
    /// Description from the source.
    pub description: Option<String>,
    /// Patient and study, from DICOM headers (stores written before it have
    /// none; written only when something is known, so the record of a store
    /// without one stays as older versions wrote it).
    #[serde(default, skip_serializing_if = "crate::ingest::Study::is_empty")]
    pub study: crate::ingest::Study,
    /// Smallest and largest stored value (NaNs left out); the histogram range.
    pub stored_range: [f64; 2],
    /// Block edge (16).
    pub block_size: u32,
    /// Levels of detail (5).
    pub levels: u32,
    /// Histogram bins per block and level.
    pub histogram_bins: u32,
    /// Blocks along x, y, z.
    pub blocks: [u32; 3],
    /// The file or folder ingested.
    pub source: String,
    /// Its format.
    pub source_format: String,
    /// What the reader assumed or corrected.
    pub notes: Vec<String>,
}

impl StoreMeta {
    /// The voxel type.
    pub fn voxel_type(&self) -> Result<VoxelType, String> {
        VoxelType::from_name(&self.voxel_type)
            .ok_or_else(|| format!("voxel_type '{}': expected uint8 … float32", self.voxel_type))
    }

    /// The physical value range.
    pub fn value_range(&self) -> [f64; 2] {
        let [a, b] = self.stored_range.map(|v| self.value_map.physical(v));
        [a.min(b), a.max(b)]
    }
}

/// Where the root metadata keeps each part of the geometry.
const META_GEOMETRY_FIELDS: GeometryFields = GeometryFields {
    dims: "attributes.voxserve.dims",
    spacing: "attributes.voxserve.spacing",
    origin: "attributes.voxserve.origin",
    direction: "attributes.voxserve.direction",
};

/// An open brick store: on disk, or in memory (the phantom, files rendered
/// without an ingest).
pub struct Store {
    location: StoreLocation,
    meta: StoreMeta,
    voxel_type: VoxelType,
    /// The arrays of `ingest::voxel_arrays` the store holds: every level's,
    /// then the box extremes where the store has them.
    arrays: Vec<VoxelArray>,
    stats: BlockStats,
    /// The files a store on disk must hold (none for a store in memory).
    manifest: Option<Arc<Manifest>>,
    /// Where its files are read from ([`Store::check_readable`]).
    storage: Arc<dyn ReadableStorageTraits>,
    /// A store on object storage: what its opening read ahead, held until
    /// [`Store::end_opening`].
    read_ahead: Option<Arc<remote::ObjectStorage>>,
}

impl std::fmt::Debug for Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Store")
            .field("location", &self.location)
            .field("meta", &self.meta)
            .finish_non_exhaustive()
    }
}

/// One zarr array of voxels of a store, with its shard indexes cached.
struct VoxelArray {
    /// Its path inside the store, without the leading `/`.
    key: String,
    /// The level its voxels are at.
    level: usize,
    array: Array<dyn ReadableStorageTraits>,
    shard_index: ArrayShardedReadableExtCache,
}

/// Where the arrays of coarse level `level`'s box minima and maxima sit among
/// a store's [`VoxelArray`]s.
fn extremes_index(level: usize) -> (usize, usize) {
    (LEVELS + level - 1, 2 * LEVELS - 2 + level)
}

/// A [`Error::Field`] about the store at `path`.
fn store_error(path: &Path, field: &str, message: impl Into<String>) -> Error {
    Error::Field {
        path: path.to_owned(),
        field: field.to_owned(),
        message: message.into(),
    }
}

impl Store {
    /// Opens the complete store at `location`, loading its metadata and block
    /// statistics. A store in memory is reached only through the [`Store`]
    /// that made it.
    pub fn open(location: impl Into<StoreLocation>) -> Result<Store, Error> {
        let location = location.into();
        if let StoreLocation::Remote(url) = &location {
            return Store::open_remote(url);
        }
        let Some(path) = location.folder() else {
            return Err(store_error(
                &location.file(""),
                "location",
                "a store in memory cannot be opened again: expected a folder",
            ));
        };
        let root = path.join("zarr.json");
        if !root.is_file() {
            let partial = path
                .file_name()
                .is_some_and(|n| n.to_string_lossy().contains(".partial-"));
            return Err(store_error(
                path,
                "zarr.json",
                if partial {
                    "missing: this is the temporary folder of an ingest that did not finish; expected a complete store (ingest again)"
                } else {
                    "missing: expected a voxserve brick store (made by `voxserve ingest`)"
                },
            ));
        }
        let manifest = match Manifest::read(path) {
            Ok(manifest) => Arc::new(manifest),
            Err(missing) => return Err(older_format(&root).unwrap_or(missing)),
        };
        manifest.check_quick(path)?;
        let files: Arc<dyn ReadableStorageTraits> = Arc::new(
            FilesystemStore::new(path).map_err(|e| store_error(path, "store", format!("{e}")))?,
        );
        Store::with_manifest(files, manifest, location)
    }

    /// Opens the complete store at `url` on object storage ([`remote`]):
    /// checks its listing against the manifest as [`Store::open`] checks a
    /// folder (for a plain HTTP store, which cannot list, missing files are
    /// found when read).
    pub fn open_remote(url: &str) -> Result<Store, Error> {
        let remote = Arc::new(Remote::parse(url)?);
        let location = StoreLocation::Remote(remote.url().to_owned());
        // The listing and the manifest are asked for at once.
        let (listing, text) = std::thread::scope(|scope| {
            let listing = remote.lists().then(|| scope.spawn(|| remote.list()));
            let text = remote.get(manifest::MANIFEST_KEY, manifest::MAX_MANIFEST_BYTES);
            let listing = listing.map(|l| {
                l.join().unwrap_or_else(|_| {
                    Err(store_error(
                        &remote.file(""),
                        "listing",
                        "the listing thread failed",
                    ))
                })
            });
            (listing, text)
        });
        let listing = listing.transpose()?;
        let Some(text) = text? else {
            let root = remote.get("zarr.json", manifest::MAX_METADATA_BYTES)?;
            return Err(match root {
                Some(_) => Manifest::missing(&remote.file(manifest::MANIFEST_KEY)),
                None => store_error(
                    &remote.file("zarr.json"),
                    "zarr.json",
                    "missing: expected a voxserve brick store (made by `voxserve ingest \
                         --out URL`)",
                ),
            });
        };
        let manifest = Arc::new(Manifest::parse(
            &text,
            &remote.file(manifest::MANIFEST_KEY),
        )?);
        // The objects read: those the manifest lists, with their ETags where
        // the store lists, and the SHA-256 the manifest gives them.
        let objects: std::collections::BTreeMap<String, remote::Object> = manifest
            .files
            .iter()
            .filter_map(|(key, entry)| {
                let object = match &listing {
                    Some(listing) => listing.get(key)?.clone(),
                    None => remote::Object {
                        bytes: entry.bytes,
                        e_tag: None,
                        sha256: None,
                    },
                };
                let sha256 = Some(entry.sha256.clone());
                Some((key.clone(), remote::Object { sha256, ..object }))
            })
            .collect();
        let storage = Arc::new(remote::ObjectStorage::new(remote.clone(), objects.clone()));
        // What the opening reads, in one round of requests: every array's
        // and group's metadata, the block statistics, and the shards of the
        // levels a block cache keeps resident (and their box extremes), each
        // whole instead of a request per inner chunk.
        let resident: Vec<String> = ingest::voxel_arrays()
            .into_iter()
            .filter(|(level, _)| crate::cache::RESIDENT_LEVELS.contains(level))
            .map(|(_, key)| format!("{}/", key.trim_start_matches('/')))
            .collect();
        storage.read_ahead(manifest.files.keys().map(String::as_str).filter(|key| {
            key.ends_with("zarr.json")
                || key.starts_with("voxserve/block_min_max/")
                // Level 0's histograms: the others are not read (BlockStats::histogram).
                || key.starts_with("voxserve/block_histogram/c/0/")
                || resident
                    .iter()
                    .any(|prefix| key.starts_with(prefix.as_str()))
        }))?;
        manifest.check_with(
            &|key| remote.file(key),
            &|key| objects.get(key).map(|o| o.bytes),
            &|key| {
                let bytes = storage
                    .get(
                        &zarrs::storage::StoreKey::new(key)
                            .map_err(|e| store_error(&remote.file(key), "key", format!("{e}")))?,
                    )
                    .map_err(|e| store_error(&remote.file(key), "object", format!("{e}")))?
                    .ok_or_else(|| Error::Missing {
                        path: remote.file(key),
                        detail: "the store's manifest lists it".into(),
                    })?;
                Ok(manifest::sha256_hex(&bytes))
            },
        )?;
        let mut store = Store::with_manifest(storage.clone(), manifest, location)?;
        store.read_ahead = Some(storage);
        Ok(store)
    }

    /// Drops what the opening of a store on object storage read ahead (its
    /// metadata, statistics and resident levels' shards): later reads go to
    /// the store again. [`crate::cache::BlockCache::make_resident`] calls it
    /// once the resident levels are in memory.
    pub fn end_opening(&self) {
        if let Some(storage) = &self.read_ahead {
            storage.forget_read_ahead();
        }
    }

    /// Opens the store in `files` whose manifest is `manifest`: reads go
    /// through [`manifest::ManifestStorage`], and the shards it leaves out
    /// are checked against the statistics.
    fn with_manifest(
        files: Arc<dyn ReadableStorageTraits>,
        manifest: Arc<Manifest>,
        location: StoreLocation,
    ) -> Result<Store, Error> {
        let storage: Arc<dyn ReadableStorageTraits> = Arc::new(manifest::ManifestStorage::new(
            files,
            manifest.clone(),
            location.clone(),
        ));
        let mut store = Store::from_storage(&storage, location)?;
        store.check_left_out_shards(&manifest)?;
        store.manifest = Some(manifest);
        Ok(store)
    }

    /// Opens a complete store in any zarrs storage found at `location`.
    pub fn from_storage(
        storage: &Arc<dyn ReadableStorageTraits>,
        location: StoreLocation,
    ) -> Result<Store, Error> {
        let root = location.file("zarr.json");
        let group = Group::open(storage.clone(), "/")
            .map_err(|e| store_error(&root, "zarr.json", format!("{e}")))?;
        let meta_json = group.attributes().get("voxserve").ok_or_else(|| {
            store_error(
                &root,
                "attributes.voxserve",
                "missing: expected a voxserve brick store",
            )
        })?;
        let meta: StoreMeta = serde_json::from_value(meta_json.clone())
            .map_err(|e| store_error(&root, "attributes.voxserve", format!("{e}")))?;
        if meta.format_version != FORMAT_VERSION {
            return Err(store_error(
                &root,
                "attributes.voxserve.format_version",
                format!("{}: expected {FORMAT_VERSION}", meta.format_version),
            ));
        }
        if !meta.complete {
            return Err(store_error(
                &root,
                "attributes.voxserve.complete",
                "false: the ingest did not finish",
            ));
        }
        let voxel_type = meta
            .voxel_type()
            .map_err(|m| store_error(&root, "attributes.voxserve.voxel_type", m))?;
        meta.geometry.checked(&root, &META_GEOMETRY_FIELDS)?;
        // Stores written before box extremes were kept hold the levels only:
        // the first extremes array's metadata tells.
        let all = ingest::voxel_arrays();
        let first_extremes = format!("{}/zarr.json", all[LEVELS].1.trim_start_matches('/'));
        let unreadable =
            |e: &dyn std::fmt::Display| store_error(&root, &first_extremes, format!("{e}"));
        let with_extremes = storage
            .get(&zarrs::storage::StoreKey::new(&first_extremes).map_err(|e| unreadable(&e))?)
            .map_err(|e| unreadable(&e))?
            .is_some();
        let kept = if with_extremes { all.len() } else { LEVELS };
        let mut arrays = Vec::new();
        for (level, key) in all.into_iter().take(kept) {
            let array = Array::open(storage.clone(), &key).map_err(|e| {
                store_error(
                    &location.file(key.trim_start_matches('/')),
                    "zarr.json",
                    format!("{e}"),
                )
            })?;
            // Every array holds voxels of the root's type: chunks of another
            // decode to another number of voxels.
            let want = ingest::zarr_type(voxel_type).0;
            if *array.data_type() != want {
                return Err(store_error(
                    &location.file(&format!("{}/zarr.json", key.trim_start_matches('/'))),
                    "data_type",
                    format!(
                        "{}: expected {} (attributes.voxserve.voxel_type of the root zarr.json)",
                        array.data_type(),
                        voxel_type.name()
                    ),
                ));
            }
            arrays.push(VoxelArray {
                key: key.trim_start_matches('/').to_owned(),
                level,
                shard_index: ArrayShardedReadableExtCache::new(&array),
                array,
            });
        }
        let stats = ingest::read_stats(storage, &location.file(""), &meta)?;
        Ok(Store {
            location,
            meta,
            voxel_type,
            arrays,
            stats,
            manifest: None,
            storage: storage.clone(),
            read_ahead: None,
        })
    }

    /// Reads the store's root metadata (`zarr.json`) again, through the
    /// storage its blocks come from: whether that answers now. A store on
    /// object storage that does not answer is [`Error::Unavailable`]; a
    /// root that is gone is [`Error::Missing`].
    pub fn check_readable(&self) -> Result<(), Error> {
        let path = self.location.file("zarr.json");
        let key = zarrs::storage::StoreKey::new("zarr.json")
            .map_err(|e| store_error(&path, "key", format!("{e}")))?;
        let gone = |path| Error::Missing {
            path,
            detail: "the store's root metadata is gone since the store was opened".into(),
        };
        match self.storage.get(&key) {
            Ok(Some(_)) => Ok(()),
            Ok(None) => Err(gone(path)),
            Err(zarrs::storage::StorageError::IOError(io)) => {
                if let Some(detail) = unreachable_io(&io) {
                    return Err(Error::Unavailable { path, detail });
                }
                if io.kind() == std::io::ErrorKind::NotFound {
                    return Err(gone(path));
                }
                Err(store_error(&path, "zarr.json", io.to_string()))
            }
            Err(e) => Err(store_error(&path, "zarr.json", e.to_string())),
        }
    }

    /// Checks that every shard the manifest does not list is one `zarrs` left
    /// out because all its voxels are 0: each of a level's blocks there must
    /// have the statistics `[0, 0]`, and a box-extremes shard may be missing
    /// only where level 0's smallest (or largest) value of each block is 0.
    fn check_left_out_shards(&self, manifest: &Manifest) -> Result<(), Error> {
        for (i, array) in self.arrays.iter().enumerate() {
            let level = array.level;
            let shards = self.chunk_grid(level).map(|n| n.div_ceil(CHUNKS_PER_SHARD));
            // Which statistic of which level says a block holds a value other than 0.
            let holds = |b: usize| {
                if i < LEVELS {
                    self.stats.min_max(level, b) != [0.0, 0.0]
                } else if i == extremes_index(level).0 {
                    self.stats.min_max(0, b)[0] != 0.0
                } else {
                    self.stats.min_max(0, b)[1] != 0.0
                }
            };
            // The first inner chunk of each shard that holds a block with data,
            // by the statistics.
            let mut holds_data = vec![None; shards.iter().map(|&n| n as usize).product()];
            for b in 0..self.stats.block_count() {
                if !holds(b) {
                    continue;
                }
                let chunk = self.stats.block_position(b).map(|c| c >> level);
                let [x, y, z] = chunk.map(|c| c / CHUNKS_PER_SHARD);
                holds_data[((z * shards[1] + y) * shards[0] + x) as usize] = Some(chunk);
            }
            for chunk in holds_data.into_iter().flatten() {
                let key = shard_key(&array.key, chunk);
                if !manifest.lists(&key) {
                    return Err(Error::Missing {
                        path: self.location.file(&key),
                        detail: "the block statistics say this shard holds data, but the \
                                 store's manifest does not list it: the store is damaged (run \
                                 voxserve verify; ingest again)"
                            .into(),
                    });
                }
            }
        }
        Ok(())
    }

    /// The files a store on disk or on object storage must hold (none for
    /// one in memory).
    pub fn manifest(&self) -> Option<&Manifest> {
        self.manifest.as_deref()
    }

    /// Where the store lives.
    pub fn location(&self) -> &StoreLocation {
        &self.location
    }

    /// The root metadata.
    pub fn meta(&self) -> &StoreMeta {
        &self.meta
    }

    /// The voxel type.
    pub fn voxel_type(&self) -> VoxelType {
        self.voxel_type
    }

    /// Per-block statistics.
    pub fn stats(&self) -> &BlockStats {
        &self.stats
    }

    /// Inner chunks along x, y, z at `level`.
    pub fn chunk_grid(&self, level: usize) -> [u32; 3] {
        level_dims(self.meta.geometry.dims, level).map(|n| n.div_ceil(BLOCK))
    }

    /// How messages name the shard file that holds inner chunk `chunk` (x, y, z) of `level`.
    pub fn shard_path(&self, level: usize, chunk: [u32; 3]) -> PathBuf {
        self.location.file(&shard_key(&level.to_string(), chunk))
    }

    /// The decoded 16³ inner chunk `chunk` (x, y, z) of `level`; voxels beyond the
    /// volume's edge hold 0.
    pub fn read_chunk(&self, level: usize, chunk: [u32; 3]) -> Result<VoxelData, Error> {
        self.check_chunk(level, chunk)?;
        self.read_subchunk(&self.arrays[level], chunk)
    }

    /// Whether the store keeps each coarse voxel's box extremes
    /// ([`Store::read_box_extremes`]); stores written before they were kept
    /// do not.
    pub fn has_box_extremes(&self) -> bool {
        self.arrays.len() > LEVELS
    }

    /// For inner chunk `chunk` of coarse `level` (1 to 4): per voxel, the
    /// smallest and the largest level-0 value in its box of 2^l voxels per
    /// axis ([`pyramid::box_extremes`]). `None` at level 0 and for a store
    /// without them.
    pub fn read_box_extremes(
        &self,
        level: usize,
        chunk: [u32; 3],
    ) -> Result<Option<(VoxelData, VoxelData)>, Error> {
        self.check_chunk(level, chunk)?;
        if level == 0 || !self.has_box_extremes() {
            return Ok(None);
        }
        let (min, max) = extremes_index(level);
        Ok(Some((
            self.read_subchunk(&self.arrays[min], chunk)?,
            self.read_subchunk(&self.arrays[max], chunk)?,
        )))
    }

    /// What a [`crate::BlockCache`] keeps of inner chunk `chunk` of `level`:
    /// its 16³ values, followed at a coarse level of a store with box
    /// extremes by the 16³ box minima and the 16³ box maxima.
    pub fn read_chunk_record(&self, level: usize, chunk: [u32; 3]) -> Result<VoxelData, Error> {
        let mut record = self.read_chunk(level, chunk)?;
        if let Some((min, max)) = self.read_box_extremes(level, chunk)? {
            record.append(min)?;
            record.append(max)?;
        }
        Ok(record)
    }

    /// An error unless `chunk` lies within `level`'s chunk grid.
    fn check_chunk(&self, level: usize, chunk: [u32; 3]) -> Result<(), Error> {
        let grid = self.chunk_grid(level.min(LEVELS - 1));
        if level >= LEVELS || chunk.iter().zip(grid).any(|(&c, g)| c >= g) {
            return Err(store_error(
                &self.location.file(""),
                "chunk",
                format!(
                    "level {level} chunk {chunk:?}: expected a level below {LEVELS} and a chunk within {grid:?}"
                ),
            ));
        }
        Ok(())
    }

    /// Inner chunk `chunk` of `array`, decoded.
    fn read_subchunk(&self, array: &VoxelArray, chunk: [u32; 3]) -> Result<VoxelData, Error> {
        let [x, y, z] = chunk.map(u64::from);
        let bytes: ArrayBytes<'static> = array
            .array
            .retrieve_subchunk_opt(&array.shard_index, &[z, y, x], &CodecOptions::default())
            .map_err(|e| self.read_error(array, chunk, e))?;
        let shard = || self.location.file(&shard_key(&array.key, chunk));
        let raw = bytes
            .into_fixed()
            .map_err(|e| store_error(&shard(), "chunk", format!("{e}")))?;
        let want = (BLOCK as usize).pow(3) * self.voxel_type.size();
        if raw.len() != want {
            return Err(store_error(
                &shard(),
                "chunk",
                format!(
                    "chunk {chunk:?} decoded to {} bytes: expected {want} ({}³ {} voxels)",
                    raw.len(),
                    BLOCK,
                    self.voxel_type.name()
                ),
            ));
        }
        Ok(VoxelData::from_bytes(self.voxel_type, &raw, false))
    }

    /// Block `block` (x, y, z in the block grid) at `level`: (16 / 2^l)³ voxels,
    /// the matching sub-cube of the level's inner chunk.
    pub fn read_block(&self, level: usize, block: [u32; 3]) -> Result<VoxelData, Error> {
        let chunk = block.map(|b| b >> level);
        let data = self.read_chunk(level, chunk)?;
        Ok(sub_cube(&data, block, level))
    }

    /// Whether `path` is a folder holding a brick store: its root metadata
    /// names one, or it has the `voxserve` folder of one (metadata too large
    /// to read here is left to [`Store::open`] to refuse).
    pub fn is_store(path: &Path) -> bool {
        use std::io::Read;
        let mut text = Vec::new();
        let read = std::fs::File::open(path.join("zarr.json"))
            .and_then(|f| f.take(manifest::MAX_METADATA_BYTES).read_to_end(&mut text));
        read.is_ok()
            && (path.join("voxserve").is_dir() || text.windows(10).any(|w| w == b"\"voxserve\""))
    }

    /// A whole level in memory as a [`Volume`](crate::Volume) (for data that fits;
    /// refused over [`crate::ingest::MAX_LOAD_BYTES`]).
    pub fn load_level(&self, level: usize) -> Result<crate::Volume, Error> {
        let geometry = self.meta.geometry.level(level.min(LEVELS - 1));
        let bytes = geometry.voxel_count() * self.voxel_type.size() as u64;
        if level >= LEVELS || bytes > crate::ingest::MAX_LOAD_BYTES {
            return Err(store_error(
                &self.location.file(""),
                "level",
                format!(
                    "level {level} ({bytes} bytes): expected a level below {LEVELS} of at most {} bytes",
                    crate::ingest::MAX_LOAD_BYTES
                ),
            ));
        }
        let dims = geometry.dims;
        let whole = zarrs::array::ArraySubset::new_with_shape(
            [dims[2], dims[1], dims[0]].map(u64::from).to_vec(),
        );
        let raw: ArrayBytes<'static> = self.arrays[level]
            .array
            .retrieve_array_subset_opt(&whole, &CodecOptions::default())
            .map_err(|e| self.read_error(&self.arrays[level], [0; 3], e))?;
        let raw = raw
            .into_fixed()
            .map_err(|e| store_error(&self.location.file(""), "level", format!("{e}")))?;
        let voxels = VoxelData::from_bytes(self.voxel_type, &raw, false);
        let mut volume = crate::Volume::new(
            self.meta.name.clone(),
            geometry,
            voxels,
            self.meta.value_map,
        )?;
        volume.unit = self.meta.unit.clone();
        volume.modality = self.meta.modality.clone();
        Ok(volume)
    }

    fn read_error(&self, array: &VoxelArray, chunk: [u32; 3], e: ArrayError) -> Error {
        let level = array.level;
        let key = shard_key(&array.key, chunk);
        let shard = self.location.file(&key);
        let missing = match self.location.folder() {
            Some(_) => !shard.is_file(),
            // ManifestStorage's error for a listed object the store lacks.
            None => is_not_found(&e),
        };
        if let Some(manifest) = &self.manifest
            && manifest.lists(&key)
            && missing
        {
            return Error::Missing {
                path: shard,
                detail: format!(
                    "the store's manifest lists this shard (inner chunk {chunk:?} of level \
                     {level}); its voxels are unknown, not empty, so the view is not drawn \
                     (restore the file or ingest again)"
                ),
            };
        }
        if let Some(why) = unreachable(&e) {
            return Error::Unavailable {
                path: shard,
                detail: format!("inner chunk {chunk:?} of level {level}: {why}"),
            };
        }
        match e {
            ArrayError::CodecError(codec) => Error::Corrupt {
                path: shard,
                codec: "zarr shard".into(),
                detail: format!("inner chunk {chunk:?} of level {level}: {codec}"),
            },
            other => store_error(
                &shard,
                "shard",
                format!("inner chunk {chunk:?} of level {level}: {other}"),
            ),
        }
    }
}

/// The I/O error a storage read failed with, where `e` is one (zarrs
/// forwards I/O errors transparently, so they are not among its sources).
fn storage_io(e: &ArrayError) -> Option<&std::io::Error> {
    use zarrs::array::codec::api::CodecError;
    use zarrs::storage::StorageError;
    match e {
        ArrayError::StorageError(StorageError::IOError(io))
        | ArrayError::CodecError(
            CodecError::StorageError(StorageError::IOError(io)) | CodecError::IOError(io),
        ) => Some(io),
        _ => None,
    }
}

/// Why an object store did not answer, where `e` comes from that
/// ([`remote::Unreachable`]).
fn unreachable(e: &ArrayError) -> Option<String> {
    storage_io(e).and_then(unreachable_io)
}

/// Why an object store did not answer, where the I/O error `io` says so
/// ([`remote::Unreachable`]).
fn unreachable_io(io: &std::io::Error) -> Option<String> {
    io.get_ref()?
        .downcast_ref::<remote::Unreachable>()
        .map(|why| why.0.clone())
}

/// Whether `e` comes from an I/O error of kind `NotFound`.
fn is_not_found(e: &ArrayError) -> bool {
    storage_io(e).is_some_and(|io| io.kind() == std::io::ErrorKind::NotFound)
}

/// Inner chunks per shard along each axis.
const CHUNKS_PER_SHARD: u32 = SHARD / BLOCK;

/// The key of the shard file that holds inner chunk `chunk` (x, y, z) of the
/// array at `array` (e.g. `2` for level 2's values).
fn shard_key(array: &str, chunk: [u32; 3]) -> String {
    let [x, y, z] = chunk.map(|c| c / CHUNKS_PER_SHARD);
    format!("{array}/c/{z}/{y}/{x}")
}

/// For a store without a manifest, the error that names its older format, if
/// its root metadata says so.
fn older_format(root: &Path) -> Option<Error> {
    use std::io::Read;
    let mut text = Vec::new();
    std::fs::File::open(root)
        .ok()?
        .take(1 << 20)
        .read_to_end(&mut text)
        .ok()?;
    let json: serde_json::Value = serde_json::from_slice(&text).ok()?;
    let version = json
        .pointer("/attributes/voxserve/format_version")?
        .as_u64()?;
    (version < u64::from(FORMAT_VERSION)).then(|| {
        store_error(
            root,
            "attributes.voxserve.format_version",
            format!(
                "{version}: expected {FORMAT_VERSION} (a store with a manifest of its files); \
                 ingest the source again"
            ),
        )
    })
}

/// The (16 / 2^l)³ sub-cube of a 16³ level-l chunk that is block `block`.
pub fn sub_cube(chunk: &VoxelData, block: [u32; 3], level: usize) -> VoxelData {
    let edge = (BLOCK >> level) as usize;
    let n = BLOCK as usize;
    let offset = block.map(|b| (b as usize & ((1 << level) - 1)) * edge);
    let pick = |z: usize, y: usize| ((offset[2] + z) * n + offset[1] + y) * n + offset[0];
    crate::volume::with_voxels!(chunk, v => {
        let mut out = Vec::with_capacity(edge * edge * edge);
        for z in 0..edge {
            for y in 0..edge {
                let start = pick(z, y);
                out.extend_from_slice(&v[start..start + edge]);
            }
        }
        VoxelData::from(out)
    })
}
