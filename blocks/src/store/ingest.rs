//! The writer: any [`VolumeSource`] into a brick store, slab by slab.
//!
//! Two passes over the source. The first finds the stored-value range (the
//! histograms' bins divide it). The second reads 16-slice slabs; for each it
//! computes every level's box averages ([`super::pyramid`]), the statistics of
//! that row of blocks at every level, and hands the voxels to `zarrs`, which
//! writes the inner chunks into their shards as they come (partial shard
//! encoding), so memory holds about one slab whatever the volume's size. Coarse
//! levels collect 16 of their own slices before writing, so each inner chunk is
//! written once.

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use zarrs::array::codec::ZstdCodec;
use zarrs::array::codec::api::CodecOptions;
use zarrs::array::{Array, ArrayBuilder, ArrayBytes, ArraySubset, data_type};
use zarrs::filesystem::FilesystemStore;
use zarrs::group::GroupBuilder;
use zarrs::storage::store::MemoryStore;
use zarrs::storage::{ReadableStorageTraits, ReadableWritableStorageTraits};

use super::manifest::{self, Manifest};
use super::pyramid::{self, LEVELS, level_dims};
use super::stats::{BLOCK, BlockStats, HISTOGRAM_BINS};
use super::{FORMAT_VERSION, SHARD, StoreMeta, store_error};
use crate::ingest::{self, VolumeInfo, VolumeSource};
use crate::{Error, VoxelData, VoxelType};

/// How to ingest.
#[derive(Debug, Clone, PartialEq)]
pub struct IngestOptions {
    /// Replace an existing store at the destination.
    pub overwrite: bool,
    /// zstd compression level (1 fast … 19 small).
    pub zstd_level: i32,
    /// Fault injection for tests: abort the process at this point, as a crash
    /// or a kill would.
    pub fault: Option<FaultPoint>,
}

/// A point of an ingest where a test may make the process abort.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultPoint {
    /// After this many slabs were written.
    AfterSlabs(u32),
    /// With every level, the statistics and the root metadata written, before
    /// the manifest.
    BeforeManifest,
    /// With the new store complete and flushed, before it moves into place.
    BeforeReplace,
    /// After the exchange: the destination holds the new store, the temporary
    /// name the old one.
    AfterExchange,
    /// After the old store was renamed `.NAME.old-PID`, before it is removed.
    AfterMoveAside,
}

impl FaultPoint {
    /// The point named `text`: `after-slabs:N`, `before-manifest`,
    /// `before-replace`, `after-exchange` or `after-move-aside`.
    pub fn parse(text: &str) -> Option<FaultPoint> {
        Some(match text {
            "before-manifest" => FaultPoint::BeforeManifest,
            "before-replace" => FaultPoint::BeforeReplace,
            "after-exchange" => FaultPoint::AfterExchange,
            "after-move-aside" => FaultPoint::AfterMoveAside,
            _ => FaultPoint::AfterSlabs(text.strip_prefix("after-slabs:")?.parse().ok()?),
        })
    }

    /// Aborts the process if `self` is `at`.
    fn abort_at(this: Option<FaultPoint>, at: FaultPoint) {
        if this == Some(at) {
            std::process::abort();
        }
    }
}

impl Default for IngestOptions {
    fn default() -> IngestOptions {
        IngestOptions {
            overwrite: false,
            zstd_level: 3,
            fault: None,
        }
    }
}

/// Where an ingest is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IngestProgress {
    /// First pass (value range): slices read of the total.
    Scanning(u32, u32),
    /// Second pass (writing): slices written of the total.
    Writing(u32, u32),
}

/// What an ingest did.
#[derive(Debug, Clone, PartialEq)]
pub struct IngestSummary {
    /// Level-0 dims.
    pub dims: [u32; 3],
    /// Voxel type.
    pub voxel_type: VoxelType,
    /// Bytes of level-0 voxels in the source.
    pub source_bytes: u64,
    /// Bytes of the store on disk (all levels and statistics).
    pub store_bytes: u64,
    /// Blocks of the level-0 grid.
    pub blocks: usize,
    /// Blocks whose voxels all hold one value (e.g. air or padding).
    pub uniform_blocks: usize,
    /// Seconds of the first pass.
    pub scan_seconds: f64,
    /// Seconds of the whole ingest.
    pub seconds: f64,
}

impl IngestSummary {
    /// Source bytes per store byte.
    pub fn compression_ratio(&self) -> f64 {
        self.source_bytes as f64 / self.store_bytes.max(1) as f64
    }

    /// Megabytes of source voxels per second, both passes included.
    pub fn mb_per_s(&self) -> f64 {
        self.source_bytes as f64 / 1e6 / self.seconds.max(1e-9)
    }
}

/// Removes the temporary folder unless the ingest completed.
struct TempDir {
    path: PathBuf,
    keep: bool,
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if !self.keep {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

fn zarr_error(path: &Path, what: &str, e: impl std::fmt::Display) -> Error {
    store_error(path, what, e.to_string())
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> Error + '_ {
    move |source| Error::Io {
        path: path.to_owned(),
        source,
    }
}

/// The zarr data type and zero fill value of a voxel type.
pub(crate) fn zarr_type(t: VoxelType) -> (zarrs::array::DataType, zarrs::array::FillValue) {
    use zarrs::array::FillValue;
    match t {
        VoxelType::U8 => (data_type::uint8(), FillValue::from(0u8)),
        VoxelType::I8 => (data_type::int8(), FillValue::from(0i8)),
        VoxelType::U16 => (data_type::uint16(), FillValue::from(0u16)),
        VoxelType::I16 => (data_type::int16(), FillValue::from(0i16)),
        VoxelType::U32 => (data_type::uint32(), FillValue::from(0u32)),
        VoxelType::I32 => (data_type::int32(), FillValue::from(0i32)),
        VoxelType::F32 => (data_type::float32(), FillValue::from(0.0f32)),
    }
}

/// Writes `source` as a brick store in the folder `out` (see the module docs of
/// [`super`] for crash safety). An existing `out` is refused unless
/// `options.overwrite` is set, and then only if it is a brick store.
pub fn ingest(
    source: &mut dyn VolumeSource,
    out: &Path,
    options: &IngestOptions,
    progress: &mut dyn FnMut(IngestProgress),
) -> Result<IngestSummary, Error> {
    let start = Instant::now();
    check_destination(out, options.overwrite)?;
    let name = out
        .file_name()
        .ok_or_else(|| store_error(out, "output", "expected a folder name"))?
        .to_string_lossy()
        .into_owned();
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    };
    if !parent.is_dir() {
        return Err(store_error(
            out,
            "output",
            format!(
                "{} is not a folder: expected the store's parent folder to exist",
                parent.display()
            ),
        ));
    }
    remove_leftovers(&parent, &name);
    let temp = TempDir {
        path: parent.join(format!(".{name}.partial-{}", std::process::id())),
        keep: false,
    };
    if temp.path.exists() {
        std::fs::remove_dir_all(&temp.path).map_err(io_error(&temp.path))?;
    }
    std::fs::create_dir(&temp.path).map_err(io_error(&temp.path))?;
    let storage: Arc<dyn ReadableWritableStorageTraits> =
        Arc::new(FilesystemStore::new(&temp.path).map_err(|e| zarr_error(&temp.path, "store", e))?);
    let written = write_store(source, &storage, &temp.path, options, progress)?;
    FaultPoint::abort_at(options.fault, FaultPoint::BeforeManifest);
    let manifest = Manifest::of_folder(&temp.path)?;
    manifest.write(&temp.path)?;
    manifest::sync_tree(&temp.path)?;
    FaultPoint::abort_at(options.fault, FaultPoint::BeforeReplace);
    let mut temp = temp;
    move_into_place(&temp.path, out, options)?;
    temp.keep = true;
    Ok(IngestSummary {
        store_bytes: folder_usage(out).bytes,
        seconds: start.elapsed().as_secs_f64(),
        ..written
    })
}

/// Refuses an existing `out` unless `overwrite`, and then anything but a brick store.
fn check_destination(out: &Path, overwrite: bool) -> Result<(), Error> {
    if std::fs::symlink_metadata(out).is_err() {
        return Ok(());
    }
    if !overwrite {
        return Err(store_error(
            out,
            "output",
            "exists: expected a new path (or --force to replace the brick store there)",
        ));
    }
    if !out.is_dir() || !super::Store::is_store(out) {
        return Err(store_error(
            out,
            "output",
            "exists and is not a voxserve brick store: --force replaces only a store (remove \
             the path yourself, or choose another --out)",
        ));
    }
    Ok(())
}

/// Moves the complete store at `temp` to `out`. A new path is taken only if it
/// is still free; an existing store is exchanged with the new one in one atomic
/// step, then moved aside as `.NAME.old-PID` and removed. The parent folder is
/// flushed after each step.
fn move_into_place(temp: &Path, out: &Path, options: &IngestOptions) -> Result<(), Error> {
    use rustix::fs::{CWD, RenameFlags, renameat_with};
    let parent = temp.parent().unwrap_or(Path::new("."));
    let rename_error = |source: rustix::io::Errno| Error::Io {
        path: out.to_owned(),
        source: source.into(),
    };
    let taken = || {
        store_error(
            out,
            "output",
            "exists (another ingest finished there first): expected a new path (or --force \
             to replace the brick store there)",
        )
    };
    if std::fs::symlink_metadata(out).is_err() {
        return match renameat_with(CWD, temp, CWD, out, RenameFlags::NOREPLACE) {
            Ok(()) => manifest::sync_folder(parent),
            Err(rustix::io::Errno::EXIST) => Err(taken()),
            Err(e) => Err(rename_error(e)),
        };
    }
    if !options.overwrite {
        return Err(taken());
    }
    check_destination(out, options.overwrite)?;
    renameat_with(CWD, temp, CWD, out, RenameFlags::EXCHANGE).map_err(rename_error)?;
    manifest::sync_folder(parent)?;
    FaultPoint::abort_at(options.fault, FaultPoint::AfterExchange);
    // `temp` now holds the old store.
    let name = out.file_name().unwrap_or_default().to_string_lossy();
    let old = parent.join(format!(".{name}.old-{}", std::process::id()));
    std::fs::rename(temp, &old).map_err(io_error(&old))?;
    manifest::sync_folder(parent)?;
    FaultPoint::abort_at(options.fault, FaultPoint::AfterMoveAside);
    std::fs::remove_dir_all(&old).map_err(io_error(&old))?;
    manifest::sync_folder(parent)
}

/// Bricks `source` into a store held in memory (compressed as on disk), for
/// volumes rendered without an ingest: the built-in phantom, files given to
/// `render` and `serve`.
pub fn ingest_in_memory(
    source: &mut dyn VolumeSource,
    options: &IngestOptions,
) -> Result<super::Store, Error> {
    let location = super::StoreLocation::Memory(source.info().name());
    let path = location.file("");
    let storage = Arc::new(MemoryStore::new());
    let writable: Arc<dyn ReadableWritableStorageTraits> = storage.clone();
    write_store(source, &writable, &path, options, &mut |_| {})?;
    let readable: Arc<dyn ReadableStorageTraits> = storage;
    super::Store::from_storage(&readable, location)
}

/// Writes every level, the statistics and the root metadata of `source` into
/// `storage`; `path` names it in messages. The root metadata goes last.
fn write_store(
    source: &mut dyn VolumeSource,
    storage: &Arc<dyn ReadableWritableStorageTraits>,
    path: &Path,
    options: &IngestOptions,
    progress: &mut dyn FnMut(IngestProgress),
) -> Result<IngestSummary, Error> {
    let start = Instant::now();
    let info = source.info().clone();

    // First pass: the stored-value range.
    let nz = info.geometry.dims[2];
    let stats = ingest::scan(source, |z| progress(IngestProgress::Scanning(z, nz)))?;
    let range = stats.stored_range;
    let scan_seconds = start.elapsed().as_secs_f64();
    let arrays = level_arrays(storage, path, &info, options.zstd_level)?;
    let grid = info.geometry.dims.map(|n| n.div_ceil(BLOCK));
    let (min_max, histogram) = stats_arrays(storage, path, grid)?;

    let writer = SlabWriter {
        arrays: &arrays,
        min_max: &min_max,
        histogram: &histogram,
        dims: info.geometry.dims,
        voxel_type: info.voxel_type,
        path,
        last_row: grid[2] - 1,
        abort_after_slabs: match options.fault {
            Some(FaultPoint::AfterSlabs(n)) => Some(n),
            _ => None,
        },
    };
    let uniform_blocks = write_slabs(source, writer, grid, range, progress)?;

    // Root metadata last: only now does the folder describe a complete store.
    store_root_metadata(storage, path, &info, range, grid)?;

    Ok(IngestSummary {
        dims: info.geometry.dims,
        voxel_type: info.voxel_type,
        source_bytes: info.total_bytes(),
        store_bytes: 0,
        blocks: grid.iter().map(|&g| g as usize).product(),
        uniform_blocks,
        scan_seconds,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The zarr arrays of voxels a store holds, in the order a [`Slab`] carries
/// them: every level's values (`/0` … `/4`), then per coarse level the
/// smallest and the largest level-0 value of each voxel's box
/// (`/voxserve/box_min/1` … `/4`, `/voxserve/box_max/1` … `/4`,
/// [`pyramid::box_extremes`]). Each: z, y, x; shards of [`SHARD`]³ holding
/// [`BLOCK`]³ inner chunks.
pub(super) fn voxel_arrays() -> Vec<(usize, String)> {
    let values = (0..LEVELS).map(|l| (l, format!("/{l}")));
    let min = (1..LEVELS).map(|l| (l, format!("/voxserve/box_min/{l}")));
    let max = (1..LEVELS).map(|l| (l, format!("/voxserve/box_max/{l}")));
    values.chain(min).chain(max).collect()
}

/// Creates every array of [`voxel_arrays`] (zstd at `zstd_level`) and stores
/// its metadata.
fn level_arrays(
    storage: &Arc<dyn ReadableWritableStorageTraits>,
    path: &Path,
    info: &VolumeInfo,
    zstd_level: i32,
) -> Result<Vec<WritableArray>, Error> {
    let (zarr_dtype, fill) = zarr_type(info.voxel_type);
    for group in ["/voxserve", "/voxserve/box_min", "/voxserve/box_max"] {
        GroupBuilder::new()
            .build(storage.clone(), group)
            .and_then(|g| g.store_metadata().map_err(Into::into))
            .map_err(|e| zarr_error(path, group, e))?;
    }
    let mut arrays = Vec::new();
    for (level, key) in voxel_arrays() {
        let [nx, ny, nz] = level_dims(info.geometry.dims, level).map(u64::from);
        let array = ArrayBuilder::new(
            vec![nz, ny, nx],
            vec![u64::from(SHARD); 3],
            zarr_dtype.clone(),
            fill.clone(),
        )
        .subchunk_shape(vec![u64::from(BLOCK); 3])
        .bytes_to_bytes_codecs(vec![Arc::new(ZstdCodec::new(zstd_level, true))])
        .dimension_names(["z", "y", "x"].into())
        .build(storage.clone(), &key)
        .map_err(|e| zarr_error(path, "array", e))?;
        array
            .store_metadata()
            .map_err(|e| zarr_error(path, "array metadata", e))?;
        arrays.push(array);
    }
    Ok(arrays)
}

/// Second pass: reads `source` one row of blocks (16 slices) at a time,
/// computes the row's levels and statistics and hands them to `writer`.
/// Returns the number of uniform level-0 blocks.
fn write_slabs(
    source: &mut dyn VolumeSource,
    writer: SlabWriter<'_>,
    grid: [u32; 3],
    range: [f64; 2],
    progress: &mut dyn FnMut(IngestProgress),
) -> Result<usize, Error> {
    let (dims, path) = (writer.dims, writer.path);
    let nz = dims[2];
    // Reading and averaging run on this thread while a writer thread hands the
    // previous slab to zarrs: the two overlap, with at most one slab waiting.
    std::thread::scope(|scope| -> Result<usize, Error> {
        let (send, receive) = std::sync::mpsc::sync_channel::<Slab>(1);
        let written = scope.spawn(move || writer.run(receive));
        let mut uniform_blocks = 0;
        let mut produced = Ok(());
        for bz in 0..grid[2] {
            let z0 = bz * BLOCK;
            let depth = BLOCK.min(nz - z0);
            let slab = match source.read_slab(z0, depth) {
                Ok(slab) => slab,
                Err(e) => {
                    produced = Err(e);
                    break;
                }
            };
            let slab_dims = [dims[0], dims[1], depth];
            let extremes = pyramid::box_extremes(&slab, slab_dims);
            let mut levels = pyramid::levels(slab, slab_dims, range);
            let mut stats = BlockStats::new([grid[0], grid[1], 1], range);
            stats.fill_row(0, &levels, slab_dims);
            // In the order of `voxel_arrays`.
            let (min, max): (Vec<_>, Vec<_>) = extremes.into_iter().unzip();
            levels.extend(min.into_iter().chain(max));
            uniform_blocks += (0..stats.block_count())
                .filter(|&b| {
                    let [lo, hi] = stats.min_max(0, b);
                    lo == hi
                })
                .count();
            if send.send(Slab { bz, levels, stats }).is_err() {
                break; // the writer failed; its error is returned below
            }
            progress(IngestProgress::Writing(z0 + depth, nz));
        }
        drop(send);
        let written = written
            .join()
            .map_err(|_| store_error(path, "writer", "the writer thread panicked"))?;
        produced.and(written).map(|()| uniform_blocks)
    })
}

/// Stores the root group's attributes: the OME-Zarr `multiscales` and
/// voxserve's [`StoreMeta`] (marked complete).
fn store_root_metadata(
    storage: &Arc<dyn ReadableWritableStorageTraits>,
    path: &Path,
    info: &VolumeInfo,
    range: [f64; 2],
    grid: [u32; 3],
) -> Result<(), Error> {
    let meta = StoreMeta {
        format_version: FORMAT_VERSION,
        complete: true,
        name: info.name(),
        geometry: info.geometry,
        voxel_type: info.voxel_type.name().to_owned(),
        value_map: info.value_map,
        unit: info.unit.clone(),
        modality: info.modality.clone(),
        description: info.description.clone(),
        study: info.study.clone(),
        stored_range: range,
        block_size: BLOCK,
        levels: LEVELS as u32,
        histogram_bins: HISTOGRAM_BINS as u32,
        blocks: grid,
        source: info.path.display().to_string(),
        source_format: info.format.to_string(),
        notes: info.notes.clone(),
    };
    let mut attributes = serde_json::Map::new();
    attributes.insert("ome".into(), ome_multiscales(&meta));
    attributes.insert(
        "voxserve".into(),
        serde_json::to_value(&meta).map_err(|e| zarr_error(path, "metadata", e))?,
    );
    GroupBuilder::new()
        .attributes(attributes)
        .build(storage.clone(), "/")
        .and_then(|g| g.store_metadata().map_err(Into::into))
        .map_err(|e| zarr_error(path, "root metadata", e))?;
    Ok(())
}

/// One slab's output on its way to the writer.
struct Slab {
    bz: u32,
    /// The voxels of every array of [`voxel_arrays`], in its order.
    levels: Vec<VoxelData>,
    stats: BlockStats,
}

/// Writes slabs into the level arrays and the statistics arrays.
struct SlabWriter<'a> {
    arrays: &'a [Array<dyn ReadableWritableStorageTraits>],
    min_max: &'a Array<dyn ReadableWritableStorageTraits>,
    histogram: &'a Array<dyn ReadableWritableStorageTraits>,
    dims: [u32; 3],
    voxel_type: VoxelType,
    path: &'a Path,
    last_row: u32,
    abort_after_slabs: Option<u32>,
}

impl SlabWriter<'_> {
    fn run(self, slabs: std::sync::mpsc::Receiver<Slab>) -> Result<(), Error> {
        let mut codec_options = CodecOptions::default();
        codec_options.set_experimental_partial_encoding(true);
        // Per level: voxels waiting for 16 of that level's slices, and where they start.
        let arrays = voxel_arrays();
        let mut pending: Vec<(u32, VoxelData)> = arrays
            .iter()
            .map(|_| (0, VoxelData::zeros(self.voxel_type, 0)))
            .collect();
        let mut written = 0;
        for slab in slabs {
            write_stats_row(
                self.min_max,
                self.histogram,
                &slab.stats,
                slab.bz,
                self.path,
            )?;
            let last = slab.bz == self.last_row;
            for (i, data) in slab.levels.into_iter().enumerate() {
                let (level, key) = &arrays[i];
                let level = *level;
                let (pending_z0, buffer) = &mut pending[i];
                if buffer.is_empty() {
                    *pending_z0 = (slab.bz * BLOCK) >> level;
                    *buffer = data; // no copy while nothing waits (always so at level 0)
                } else {
                    buffer.append(data)?;
                }
                let dims = level_dims(self.dims, level);
                let plane = dims[0] as usize * dims[1] as usize;
                let slices = (buffer.len() / plane.max(1)) as u32;
                if slices >= BLOCK || (last && slices > 0) {
                    let full = std::mem::replace(buffer, VoxelData::zeros(self.voxel_type, 0));
                    let subset = ArraySubset::new_with_ranges(&[
                        u64::from(*pending_z0)..u64::from(*pending_z0 + slices),
                        0..u64::from(dims[1]),
                        0..u64::from(dims[0]),
                    ]);
                    self.arrays[i]
                        .store_array_subset_opt(
                            &subset,
                            ArrayBytes::new_flen(Cow::Borrowed(full.as_bytes())),
                            &codec_options,
                        )
                        .map_err(|e| {
                            zarr_error(&self.path.join(key.trim_start_matches('/')), "write", e)
                        })?;
                }
            }
            written += 1;
            if self.abort_after_slabs == Some(written) {
                std::process::abort();
            }
        }
        Ok(())
    }
}

/// A zarr array the ingest writes into.
type WritableArray = Array<dyn ReadableWritableStorageTraits>;

/// The two statistics arrays under `/voxserve`, one chunk per level and block row.
fn stats_arrays(
    storage: &Arc<dyn ReadableWritableStorageTraits>,
    path: &Path,
    grid: [u32; 3],
) -> Result<(WritableArray, WritableArray), Error> {
    GroupBuilder::new()
        .build(storage.clone(), "/voxserve")
        .and_then(|g| g.store_metadata().map_err(Into::into))
        .map_err(|e| zarr_error(path, "voxserve group", e))?;
    let [gx, gy, gz] = grid.map(u64::from);
    let levels = LEVELS as u64;
    let build = |name: &str, dtype, fill: zarrs::array::FillValue, last: u64| {
        let array = ArrayBuilder::new(
            vec![levels, gz, gy, gx, last],
            vec![1, 1, gy, gx, last],
            dtype,
            fill,
        )
        .bytes_to_bytes_codecs(vec![Arc::new(ZstdCodec::new(3, true))])
        .dimension_names(["level", "bz", "by", "bx", name].into())
        .build(storage.clone(), &format!("/voxserve/{name}"))
        .map_err(|e| zarr_error(path, name, e))?;
        array
            .store_metadata()
            .map_err(|e| zarr_error(path, name, e))?;
        Ok::<_, Error>(array)
    };
    Ok((
        build(
            "block_min_max",
            data_type::float64(),
            zarrs::array::FillValue::from(f64::NAN),
            2,
        )?,
        build(
            "block_histogram",
            data_type::uint16(),
            zarrs::array::FillValue::from(0u16),
            HISTOGRAM_BINS as u64,
        )?,
    ))
}

/// Stores the statistics of block row `bz` (a one-row [`BlockStats`]).
fn write_stats_row(
    min_max: &WritableArray,
    histogram: &WritableArray,
    row: &BlockStats,
    bz: u32,
    path: &Path,
) -> Result<(), Error> {
    let per_level = row.block_count();
    for level in 0..LEVELS {
        let chunk = [level as u64, u64::from(bz), 0, 0, 0];
        min_max
            .store_chunk(
                &chunk,
                &row.minmax[level * per_level * 2..][..per_level * 2],
            )
            .map_err(|e| zarr_error(path, "block_min_max", e))?;
        histogram
            .store_chunk(
                &chunk,
                &row.histogram[level * per_level * HISTOGRAM_BINS..][..per_level * HISTOGRAM_BINS],
            )
            .map_err(|e| zarr_error(path, "block_histogram", e))?;
    }
    Ok(())
}

/// Reads the statistics arrays of a store into memory.
pub(super) fn read_stats(
    storage: &Arc<dyn ReadableStorageTraits>,
    path: &Path,
    meta: &StoreMeta,
) -> Result<BlockStats, Error> {
    let open = |name: &str| {
        Array::open(storage.clone(), &format!("/voxserve/{name}"))
            .map_err(|e| zarr_error(&path.join("voxserve").join(name), "zarr.json", e))
    };
    let (min_max, histogram) = (open("block_min_max")?, open("block_histogram")?);
    let mut stats = BlockStats::new(meta.blocks, meta.stored_range);
    let whole =
        |a: &Array<dyn ReadableStorageTraits>| ArraySubset::new_with_shape(a.shape().to_vec());
    let read_error = |name: &str, e: zarrs::array::ArrayError| Error::Corrupt {
        path: path.join("voxserve").join(name),
        codec: "zarr array".into(),
        detail: e.to_string(),
    };
    let mm: Vec<f64> = min_max
        .retrieve_array_subset_opt(&whole(&min_max), &CodecOptions::default())
        .map_err(|e| read_error("block_min_max", e))?;
    // Level 0's histograms only (BlockStats::histogram): the first entry
    // along the level axis.
    let mut level_0 = histogram.shape().to_vec();
    if let Some(levels) = level_0.first_mut() {
        *levels = (*levels).min(1);
    }
    let hist: Vec<u16> = histogram
        .retrieve_array_subset_opt(
            &ArraySubset::new_with_shape(level_0),
            &CodecOptions::default(),
        )
        .map_err(|e| read_error("block_histogram", e))?;
    if mm.len() != stats.minmax.len() || hist.len() != stats.block_count() * HISTOGRAM_BINS {
        return Err(store_error(
            path,
            "voxserve statistics",
            "sizes do not match the block grid",
        ));
    }
    stats.minmax = mm;
    stats.histogram = hist;
    Ok(stats)
}

/// The OME-Zarr 0.5 `multiscales` attribute: per level, scale = spacing · 2^l and
/// the centre of its first voxel (the centre of its box of 2^l voxels).
fn ome_multiscales(meta: &StoreMeta) -> serde_json::Value {
    let axis =
        |name: &str| serde_json::json!({ "name": name, "type": "space", "unit": "millimeter" });
    let datasets: Vec<serde_json::Value> = (0..LEVELS)
        .map(|level| {
            let factor = f64::from(1u32 << level);
            let g = &meta.geometry;
            let scale = [2, 1, 0].map(|a| g.spacing[a] * factor);
            let translation = [2, 1, 0].map(|a| g.origin[a] + (factor - 1.0) / 2.0 * g.spacing[a]);
            serde_json::json!({
                "path": level.to_string(),
                "coordinateTransformations": [
                    { "type": "scale", "scale": scale },
                    { "type": "translation", "translation": translation },
                ],
            })
        })
        .collect();
    serde_json::json!({
        "version": "0.5",
        "multiscales": [{
            "name": meta.name,
            "axes": [axis("z"), axis("y"), axis("x")],
            "datasets": datasets,
            "type": "least-squares trilinear",
            "metadata": {
                "description": "per box of 2^l voxels per axis, centred on it, the values whose trilinear interpolant is nearest level 0 in the least-squares sense (within each 16-slice slab along z), clamped to the stored range",
            },
        }],
    })
}

/// What an ingest that did not finish may leave beside its destination `NAME`:
/// `.NAME.partial-PID` (the new store being written; after an exchange, the old
/// one) and `.NAME.old-PID` (the old store being removed). Returns the name of
/// the destination and the process that left it.
pub fn leftover_of(file_name: &str) -> Option<(&str, u32)> {
    let rest = file_name.strip_prefix('.')?;
    [".partial-", ".old-"].iter().find_map(|marker| {
        let (name, pid) = rest.rsplit_once(marker)?;
        Some((name, pid.parse().ok()?))
    })
}

/// Whether process `pid` runs (checked in /proc; `true` where there is none,
/// so nothing is removed there).
pub fn process_runs(pid: u32) -> bool {
    !Path::new("/proc/self").exists() || Path::new(&format!("/proc/{pid}")).exists()
}

/// Removes what ingests to the same destination left behind when they were
/// killed (see [`leftover_of`]), unless their process still runs.
fn remove_leftovers(parent: &Path, name: &str) {
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    for entry in entries.filter_map(Result::ok) {
        let file_name = entry.file_name().to_string_lossy().into_owned();
        match leftover_of(&file_name) {
            Some((of, pid)) if of == name && !process_runs(pid) => {
                tracing::info!(
                    "removing {}, left by an ingest that did not finish",
                    entry.path().display()
                );
                let _ = std::fs::remove_dir_all(entry.path());
            }
            _ => {}
        }
    }
}

/// What a folder takes: its files and bytes, and the bytes the file system
/// allocates for them and for the folders (what `du` counts).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FolderUsage {
    /// Regular files under the folder.
    pub files: u64,
    /// Their bytes.
    pub bytes: u64,
    /// Bytes allocated on disk for the files and every folder, the folder itself included.
    pub allocated: u64,
}

/// What the folder `path` takes (links are not followed).
pub fn folder_usage(path: &Path) -> FolderUsage {
    use std::os::unix::fs::MetadataExt;
    let mut usage = FolderUsage {
        allocated: std::fs::symlink_metadata(path).map_or(0, |m| m.blocks() * 512),
        ..FolderUsage::default()
    };
    let Ok(entries) = std::fs::read_dir(path) else {
        return usage;
    };
    for entry in entries.filter_map(Result::ok) {
        let Ok(meta) = entry.metadata() else {
            continue;
        };
        if meta.is_dir() {
            let inner = folder_usage(&entry.path());
            usage.files += inner.files;
            usage.bytes += inner.bytes;
            usage.allocated += inner.allocated;
        } else {
            usage.files += u64::from(meta.is_file());
            usage.bytes += meta.len();
            usage.allocated += meta.blocks() * 512;
        }
    }
    usage
}
