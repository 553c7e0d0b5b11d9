//! [`Dataset`]: a brick store the server offers under an id, and [`DatasetInfo`],
//! what clients learn about it.
//!
//! Every dataset is rendered from a brick store: a store on disk (`voxserve
//! ingest`) is opened and read block by block as views need; the built-in phantom
//! and volume files named directly are bricked into a store held in memory
//! (compressed as on disk) when the server starts.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use blocks::cache::BlockCache;
use blocks::ingest::{self, MemorySource, OpenOptions};
use blocks::store::{IngestOptions, Store, ingest_in_memory};
use blocks::{Geometry, Preset, ValueMap};
use serde::Serialize;
use shaders::settings::SettingError;

/// The id of the built-in phantom.
pub const PHANTOM_ID: &str = "phantom";

/// A brick store offered under an id, with the cache its blocks are read through.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// Bumped after each chunk read in the background arrives: what frames
    /// waiting for blocks await ([`Dataset::settle`]).
    arrived: tokio::sync::watch::Receiver<u64>,
    /// The id in URLs (`dataset=ID`).
    pub id: String,
    /// The store.
    pub store: Arc<Store>,
    /// Decoded blocks of the store, shared by every renderer of it.
    pub cache: Arc<BlockCache>,
    /// [`Dataset::histogram`], summed once when the dataset is opened.
    histogram: Arc<(Vec<u64>, [f64; 2])>,
}

/// A transfer-function preset as clients list it.
#[derive(Debug, Clone, Serialize)]
pub struct PresetInfo {
    /// The name in URLs.
    pub name: &'static str,
    /// A one-line description.
    pub description: &'static str,
    /// Its transfer function over this dataset's values, in the text form of
    /// the `tf` parameter (a starting point for editing).
    pub tf: String,
}

/// A named greyscale window of slice views.
#[derive(Debug, Clone, Serialize)]
pub struct WindowInfo {
    /// The name (`brain`, `lung`, …).
    pub name: &'static str,
    /// The value shown mid-grey, physical units.
    pub centre: f32,
    /// From black to white, physical units.
    pub width: f32,
}

/// What `GET /api/datasets` says about a dataset.
#[derive(Debug, Clone, Serialize)]
pub struct DatasetInfo {
    /// The id in URLs.
    pub id: String,
    /// A display name.
    pub name: String,
    /// Level 0's dimensions, spacing, origin and direction (the keys `dims`,
    /// `spacing`, `origin`, `direction`).
    #[serde(flatten)]
    pub geometry: Geometry,
    /// The radius (mm) of the sphere about the volume's centre that holds
    /// it: the unit of the camera's `dist`, and what clients pan and zoom by.
    pub radius_mm: f32,
    /// 16³ blocks along x, y, z.
    pub blocks: [u32; 3],
    /// `uint8`, `uint16`, …
    pub voxel_type: String,
    /// Smallest and largest physical value.
    pub value_range: [f64; 2],
    /// Unit of the physical values, when known.
    pub unit: Option<String>,
    /// Imaging modality, when known.
    pub modality: Option<String>,
    /// Patient and study, from DICOM headers (each absent when unknown).
    pub study: ingest::Study,
    /// The transfer-function presets offered.
    pub presets: Vec<PresetInfo>,
    /// The preset a client should start with.
    pub default_preset: &'static str,
    /// Slice views' named greyscale windows (CT's in HU: brain, subdural,
    /// stroke, bone, lung, abdomen; none for other data), in the order
    /// clients number them.
    pub windows: Vec<WindowInfo>,
    /// The window slice views open with.
    pub default_window: WindowInfo,
    /// The level-0 voxels' histogram: counts in equal bins over
    /// `histogram_range` (physical units), for transfer-function editors.
    pub histogram: Vec<u64>,
    /// The physical values the histogram's bins divide evenly.
    pub histogram_range: [f64; 2],
}

impl Dataset {
    /// A dataset over `store`, caching at most `cache_bytes` of decoded blocks
    /// beyond the coarsest levels, which stay resident.
    pub fn new(id: String, store: Store, cache_bytes: u64) -> Result<Dataset, blocks::Error> {
        let store = Arc::new(store);
        let mut cache = BlockCache::new(store.clone(), cache_bytes);
        cache.make_resident(&blocks::cache::RESIDENT_LEVELS)?;
        let (arrival, arrived) = tokio::sync::watch::channel(0u64);
        cache.subscribe(move || arrival.send_modify(|n| *n += 1));
        let histogram = Arc::new(level0_histogram(&store));
        Ok(Dataset {
            arrived,
            id,
            store,
            cache: Arc::new(cache),
            histogram,
        })
    }

    /// The built-in head phantom at `size`³ voxels, bricked in memory.
    pub fn phantom(size: u32, cache_bytes: u64) -> Result<Dataset, blocks::Error> {
        let volume = Arc::new(blocks::phantom::head(size)?);
        let mut source = MemorySource::new(volume, "phantom");
        let store = ingest_in_memory(&mut source, &IngestOptions::default())?;
        Dataset::new(PHANTOM_ID.to_owned(), store, cache_bytes)
    }

    /// A brick store, or a volume file or DICOM folder bricked in memory, under an
    /// id made from its name (`engine_256x256x128_uint8.raw` → `engine_256x256x128_uint8`).
    pub fn load(
        path: &Path,
        options: &OpenOptions,
        cache_bytes: u64,
    ) -> Result<Dataset, blocks::Error> {
        let store = if Store::is_store(path) {
            Store::open(path)?
        } else {
            let mut source = ingest::open(path, options)?;
            ingest_in_memory(source.as_mut(), &IngestOptions::default())?
        };
        Dataset::new(Dataset::id_of(&path.to_string_lossy()), store, cache_bytes)
    }

    /// The id of the dataset at `name` (a path or a URL): its last part without
    /// the extension (`…/engine_256x256x128_uint8.raw` → `engine_256x256x128_uint8`).
    pub fn id_of(name: &str) -> String {
        let name = name
            .trim_end_matches('/')
            .rsplit('/')
            .next()
            .filter(|n| !n.is_empty())
            .unwrap_or("volume");
        [
            ".nii.gz", ".raw", ".nrrd", ".nhdr", ".nii", ".mha", ".mhd", ".dcm", ".zarr",
        ]
        .iter()
        .find_map(|ext| name.strip_suffix(ext))
        .unwrap_or(name)
        .to_owned()
    }

    /// Waits until a chunk read in the background has arrived since
    /// `seen` ([`BlockCache::arrivals`]), then until the reads in flight are
    /// done or `gather` has passed (so one new frame shows many arrivals),
    /// or `patience` has passed in all: a frame that waits for blocks never
    /// hangs.
    pub async fn settle(&self, seen: u64, gather: Duration, patience: Duration) {
        let mut arrived = self.arrived.clone();
        let cache = &self.cache;
        let settled = async {
            while cache.arrivals() <= seen {
                if arrived.changed().await.is_err() {
                    return;
                }
            }
            let first = tokio::time::Instant::now();
            while cache.loading() > 0 && first.elapsed() < gather {
                let left = gather.saturating_sub(first.elapsed());
                let _ = tokio::time::timeout(left, arrived.changed()).await;
            }
        };
        let _ = tokio::time::timeout(patience, settled).await;
    }

    /// The display name.
    pub fn name(&self) -> &str {
        &self.store.meta().name
    }

    /// Level-0 voxels along x, y, z.
    pub fn dims(&self) -> [u32; 3] {
        self.store.meta().geometry.dims
    }

    /// The physical value range (what transfer-function presets are laid over).
    pub fn value_range(&self) -> [f32; 2] {
        self.store.meta().value_range().map(|v| v as f32)
    }

    /// Stored → physical values.
    pub fn value_map(&self) -> ValueMap {
        self.store.meta().value_map
    }

    /// The presets that suit this dataset, the one to start with first: CT
    /// ones for CT in HU, MR for MR, generic for all.
    pub fn presets(&self) -> &'static [Preset] {
        let m = self.store.meta();
        Preset::offered(m.modality.as_deref(), m.unit.as_deref())
    }

    /// The preset to start with: CT bone for CT in HU, MR for MR, generic otherwise.
    pub fn default_preset(&self) -> Preset {
        self.presets()[0]
    }

    /// Whether the values are CT in Hounsfield units (CT presets and windows suit it).
    pub fn is_ct_in_hu(&self) -> bool {
        let m = self.store.meta();
        m.modality.as_deref() == Some("CT") && m.unit.as_deref() == Some("HU")
    }

    /// The window slice views open with: soft tissue for CT in HU, else the
    /// value range ([`shaders::slice::default_window`]).
    pub fn default_window(&self) -> (&'static str, shaders::frame::Window) {
        shaders::slice::default_window(self.is_ct_in_hu(), self.value_range())
    }

    /// Refuses a preset that does not suit this dataset (a CT preset in
    /// Hounsfield units on 8-bit engine data is an opaque box).
    ///
    /// # Errors
    /// Names the preset, what it is for, and the presets this dataset offers.
    pub fn check_preset(&self, preset: Preset) -> Result<(), SettingError> {
        let m = self.store.meta();
        match preset.unsuited(m.modality.as_deref(), m.unit.as_deref()) {
            None => Ok(()),
            Some(why) => {
                let offered: Vec<&str> = self.presets().iter().map(|p| p.name()).collect();
                Err(SettingError::of_value(
                    "preset",
                    format!("{:?}", preset.name()),
                    format!(
                        "one of {} for dataset '{}' ({why})",
                        offered.join(", "),
                        self.id
                    ),
                ))
            }
        }
    }

    /// The level-0 histogram summed over every block, and the physical range
    /// its bins divide.
    pub fn histogram(&self) -> &(Vec<u64>, [f64; 2]) {
        &self.histogram
    }

    /// The public description.
    pub fn info(&self) -> DatasetInfo {
        let m = self.store.meta();
        let (histogram, histogram_range) = self.histogram().clone();
        DatasetInfo {
            id: self.id.clone(),
            name: m.name.clone(),
            geometry: m.geometry,
            radius_mm: shaders::raycast::VolumePlacement::of_geometry(&m.geometry).radius(),
            blocks: m.blocks,
            voxel_type: m.voxel_type.clone(),
            value_range: m.value_range(),
            unit: m.unit.clone(),
            modality: m.modality.clone(),
            study: m.study.clone(),
            presets: self
                .presets()
                .iter()
                .map(|p| PresetInfo {
                    name: p.name(),
                    description: p.description(),
                    tf: p.transfer_function(self.value_range()).to_string(),
                })
                .collect(),
            default_preset: self.default_preset().name(),
            windows: if self.is_ct_in_hu() {
                shaders::slice::CT_WINDOWS
                    .iter()
                    .map(|&(name, w)| WindowInfo {
                        name,
                        centre: w.centre,
                        width: w.width,
                    })
                    .collect()
            } else {
                Vec::new()
            },
            default_window: {
                let (name, w) = self.default_window();
                WindowInfo {
                    name,
                    centre: w.centre,
                    width: w.width,
                }
            },
            histogram,
            histogram_range,
        }
    }
}

/// The level-0 histogram of `store` summed over every block, and the physical
/// range its bins divide (bins reversed under a negative value-map slope).
fn level0_histogram(store: &Store) -> (Vec<u64>, [f64; 2]) {
    let stats = store.stats();
    let mut counts = vec![0u64; blocks::store::HISTOGRAM_BINS];
    for b in 0..stats.block_count() {
        for (c, &n) in counts
            .iter_mut()
            .zip(stats.histogram(0, b).unwrap_or_default())
        {
            *c += u64::from(n);
        }
    }
    let map = store.meta().value_map;
    let [lo, hi] = stats.range.map(|v| map.physical(v));
    if hi < lo {
        // A negative slope runs the bins backwards in physical units.
        counts.reverse();
        return (counts, [hi, lo]);
    }
    (counts, [lo, hi])
}
