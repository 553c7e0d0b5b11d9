//! [`Residency`]: which blocks a renderer keeps in its atlas (on the GPU, or
//! in memory for the CPU renderer: any [`Atlas`]), at which level, and how it
//! gets there without the render thread ever waiting for storage.
//!
//! A frame's transfer function and data reduction give a *target* selection
//! ([`select_levels`]: a few milliseconds from the block statistics). What is
//! *shown* follows it as far as memory allows now: a block whose data at its
//! target level is decoded in memory is shown at that level (its chunks
//! pinned, then uploaded); one whose data is not yet there is requested from
//! the background readers ([`blocks::cache::BlockCache::request`]) and shown
//! meanwhile as it was, or, if it was not shown, at the finest level already
//! in memory (levels 3 and 4 always are). Each later frame shows what has
//! arrived, until nothing is pending. So a cold transfer-function change
//! renders at once from coarse data and refines as blocks arrive, and other
//! datasets' frames never wait for its reads.

use std::collections::HashMap;
use std::sync::Arc;

use blocks::cache::{BlockCache, ChunkKey, Pinned};
use blocks::lod::{self, Budget, EMPTY, LodSelection, Viewpoint};
use blocks::packing::{APRON, Packing};
use blocks::seams::{self, SeamChunks};
use blocks::store::{LEVELS, Store};
use blocks::{TransferFunction, VoxelData, visibility};
use rayon::prelude::*;

use crate::illumination::Mode;
use crate::packed::Atlas;
use crate::raycast::VolumePlacement;
use crate::volume_texture::VolumeTexture;
use crate::{FrameRequest, GpuError};

/// How long [`Residency::update_complete`] sleeps between checks when no
/// arrival wakes it.
const ARRIVAL_PATIENCE: std::time::Duration = std::time::Duration::from_millis(200);
/// Selections tried before a device budget is declared too small.
const MAX_SELECTIONS: usize = 12;
/// How far the view may turn, in degrees, before the levels are chosen again
/// for what the viewer now sees ([`lod::Viewpoint`]): a drag re-selects every
/// few degrees, not every frame.
pub const VIEW_TURN_DEG: f64 = 5.0;

/// What one update of the resident blocks did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ResidencyStats {
    /// Blocks uploaded.
    pub uploaded_blocks: usize,
    /// Whether the atlas was laid out anew.
    pub relayout: bool,
    /// Milliseconds spent selecting levels (0 when nothing was re-selected).
    pub select_ms: f64,
    /// Milliseconds spent uploading blocks and index.
    pub upload_ms: f64,
    /// Blocks shown coarser than selected because their data is still being
    /// read: later frames refine them.
    pub pending_blocks: usize,
}

/// How far [`Residency::update`] brings the shown blocks towards a frame's
/// target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refresh {
    /// Only a new target (another transfer function, reduction or view) is
    /// shown; blocks that arrived wait. A frame drawn band by band takes
    /// this for every band after its first: all its bands draw the blocks
    /// its first band drew (no band pays for an upload, and a frame never
    /// joins two sets of blocks), and the next frame shows what arrived.
    Target,
    /// Also show the blocks that arrived since the last update.
    Arrived,
    /// Also wait on this thread until no block is pending (the command
    /// line, tests and benchmarks; a server never waits).
    Complete,
}

impl Refresh {
    /// For a frame's band `rows`: [`Refresh::Target`] after its first band,
    /// else [`Refresh::Complete`] when `complete`, else [`Refresh::Arrived`].
    pub fn for_band(rows: crate::frame::Rows, complete: bool) -> Refresh {
        match (complete, rows.first) {
            (true, _) => Refresh::Complete,
            (false, 0) => Refresh::Arrived,
            (false, _) => Refresh::Target,
        }
    }
}

/// The selection a frame asks for.
#[derive(Debug)]
struct Target {
    tf: TransferFunction,
    reduction: f32,
    view: Option<Viewpoint>,
    selection: LodSelection,
}

impl Target {
    /// Whether this target still serves `tf` at `reduction` seen from `view`:
    /// the same transfer function and reduction, and a view turned by at
    /// most [`VIEW_TURN_DEG`].
    fn serves(&self, tf: &TransferFunction, reduction: f32, view: Option<&Viewpoint>) -> bool {
        let same_view = match (&self.view, view) {
            (Some(a), Some(b)) => a.angle_to(b) <= VIEW_TURN_DEG,
            (None, None) => true,
            _ => false,
        };
        self.tf == *tf && self.reduction == reduction && same_view
    }
}

/// Where `request`'s camera sees a volume of `desc` from, for the level
/// selection: the direction towards the eye in millimetres along the
/// volume's index axes (the view's, for every block: what a block hides
/// barely changes across the few degrees a perspective view spans). `None`
/// under an illumination mode: its light is computed from every resident
/// block, so levels that followed the camera would recompute it on every
/// turn, during a drag too; there the levels follow the transfer function
/// alone and the light is kept while the camera moves.
pub fn viewpoint(request: &FrameRequest, desc: &VolumeTexture) -> Option<Viewpoint> {
    if Mode::of(request.shading).is_some() {
        return None;
    }
    let geometry = &desc.geometry;
    let radius = VolumePlacement::of(desc).radius();
    let toward_eye = -request.camera.basis(radius).forward;
    let direction = geometry.direction_f32();
    Some(Viewpoint {
        toward_eye: direction.map(|axis| f64::from(toward_eye.dot(glam::Vec3::from(axis)))),
        spacing: geometry.spacing,
    })
}

/// What is in the atlas.
#[derive(Debug)]
struct Shown<A> {
    atlas: A,
    selection: LodSelection,
    /// Per block, whether its apron was written without a chunk it needs to
    /// meet a neighbour of another level ([`blocks::seams`]): written again
    /// when the chunk arrives.
    rough: Vec<bool>,
    /// The transfer function its coarse blocks keep thin structures for
    /// ([`blocks::visibility`]).
    tf: TransferFunction,
}

/// The levels to show per block now, the chunks pinned for the blocks to
/// upload (by block: only those), and how many blocks wait for data.
struct Plan {
    lod: Vec<u8>,
    pins: HashMap<usize, Pinned>,
    pending: usize,
}

/// The blocks of one store in an atlas `A`; see the module docs.
#[derive(Debug)]
pub struct Residency<A> {
    cache: Arc<BlockCache>,
    device_budget_bytes: u64,
    target: Option<Target>,
    shown: Option<Shown<A>>,
    pending: usize,
    /// Bumped whenever the shown blocks change: light computed from them is stale.
    data_version: u64,
}

impl<A: Atlas> Residency<A> {
    /// Nothing resident yet, of the store behind `cache`, in at most
    /// `device_budget_bytes` of atlas.
    pub fn new(cache: Arc<BlockCache>, device_budget_bytes: u64) -> Residency<A> {
        Residency {
            cache,
            device_budget_bytes,
            target: None,
            shown: None,
            pending: 0,
            data_version: 0,
        }
    }

    /// The atlas, once a frame was rendered.
    pub fn atlas(&self) -> Option<&A> {
        self.shown.as_ref().map(|s| &s.atlas)
    }

    /// The atlas to write in place (the CPU renderer's light), once a frame
    /// was rendered.
    pub fn atlas_mut(&mut self) -> Option<&mut A> {
        self.shown.as_mut().map(|s| &mut s.atlas)
    }

    /// The selection shown, once a frame was rendered.
    pub fn selection(&self) -> Option<&LodSelection> {
        self.shown.as_ref().map(|s| &s.selection)
    }

    /// `request` with its camera fitted to the blocks shown, stray ones left
    /// out ([`crate::camera::FIT_STRAY`], [`crate::Camera::fitted`]) when it asks for a fit; when no block is
    /// shown the camera stays and only the fit is cleared. `None` when the
    /// request asks for no fit.
    pub fn fitted(&self, request: &FrameRequest, desc: &VolumeTexture) -> Option<FrameRequest> {
        if !request.camera.fit {
            return None;
        }
        let grid = self.cache.store().meta().blocks;
        let shown = self
            .selection()
            .and_then(|s| s.shown_voxels(grid, desc.geometry.dims, crate::camera::FIT_STRAY));
        let placement = VolumePlacement::of(desc);
        let aspect = request.width as f32 / request.height as f32;
        let camera = match shown {
            Some([lo, hi]) => {
                let (min, max) = placement.model_box(desc.geometry.dims, lo, hi);
                request.camera.fitted(min, max, placement.radius(), aspect)
            }
            None => crate::Camera {
                fit: false,
                ..request.camera
            },
        };
        Some(FrameRequest {
            camera,
            ..request.clone()
        })
    }

    /// Changes whenever the shown blocks change.
    pub fn data_version(&self) -> u64 {
        self.data_version
    }

    /// Blocks shown coarser than selected, or with aprons not yet meeting a
    /// neighbour's level, waiting for their data.
    pub fn pending(&self) -> usize {
        self.pending
    }

    /// Brings the atlas towards the selection for `tf` at data reduction
    /// `reduction` (among the blocks `tf` shows), seen from `view` if given,
    /// never reading storage on this thread: see the module docs. Blocks
    /// that arrived are shown unless `refresh` is [`Refresh::Target`].
    pub fn update(
        &mut self,
        device: &A::Device,
        desc: &VolumeTexture,
        tf: &TransferFunction,
        reduction: f32,
        view: Option<Viewpoint>,
        refresh: Refresh,
    ) -> Result<ResidencyStats, GpuError> {
        let mut stats = ResidencyStats::default();
        let retarget = !self
            .target
            .as_ref()
            .is_some_and(|t| t.serves(tf, reduction, view.as_ref()));
        if retarget {
            let start = std::time::Instant::now();
            let device_budget = self.device_budget(device, desc);
            let store = self.cache.store();
            let (selection, _) = select_levels(store, tf, reduction, view.as_ref(), device_budget)?;
            stats.select_ms = start.elapsed().as_secs_f64() * 1e3;
            self.target = Some(Target {
                tf: tf.clone(),
                reduction,
                view,
                selection,
            });
        } else if self.pending == 0 || refresh == Refresh::Target {
            stats.pending_blocks = self.pending;
            return Ok(stats);
        }
        let start = std::time::Instant::now();
        self.show(device, desc, &mut stats)?;
        stats.upload_ms = start.elapsed().as_secs_f64() * 1e3;
        stats.pending_blocks = self.pending;
        Ok(stats)
    }

    /// [`Residency::update`], then, with [`Refresh::Complete`], again as
    /// blocks arrive until none is pending, waiting on this thread for the
    /// background reads: the totals of every update.
    pub fn update_complete(
        &mut self,
        device: &A::Device,
        desc: &VolumeTexture,
        tf: &TransferFunction,
        reduction: f32,
        view: Option<Viewpoint>,
        refresh: Refresh,
    ) -> Result<ResidencyStats, GpuError> {
        let mut stats = self.update(device, desc, tf, reduction, view, refresh)?;
        while refresh == Refresh::Complete && stats.pending_blocks > 0 {
            let seen = self.cache.arrivals();
            if self.cache.loading() > 0 {
                self.cache.wait_for_arrivals(seen, ARRIVAL_PATIENCE);
            }
            let more = self.update(device, desc, tf, reduction, view, refresh)?;
            stats = ResidencyStats {
                uploaded_blocks: stats.uploaded_blocks + more.uploaded_blocks,
                relayout: stats.relayout || more.relayout,
                select_ms: stats.select_ms + more.select_ms,
                upload_ms: stats.upload_ms + more.upload_ms,
                pending_blocks: more.pending_blocks,
            };
        }
        Ok(stats)
    }

    /// What the device can hold.
    fn device_budget(&self, device: &A::Device, desc: &VolumeTexture) -> DeviceBudget {
        DeviceBudget {
            bytes: self.device_budget_bytes,
            texel_bytes: A::texel_bytes(desc),
            max_edge: A::max_edge(device),
        }
    }

    /// Shows what memory allows of the target now: uploads the blocks whose
    /// level changes (or every block, when the atlas is laid out anew), and
    /// writes again the blocks whose aprons must meet a neighbour's new level
    /// ([`blocks::seams`]).
    fn show(
        &mut self,
        device: &A::Device,
        desc: &VolumeTexture,
        stats: &mut ResidencyStats,
    ) -> Result<(), GpuError> {
        let Some(target) = &self.target else {
            return Ok(());
        };
        let shown_lod = self.shown.as_ref().map(|s| s.selection.lod.as_slice());
        let rough_before = self
            .shown
            .as_ref()
            .is_some_and(|s| s.rough.iter().any(|&r| r));
        let mut plan = plan(&self.cache, &target.selection, shown_lod)?;
        self.pending = plan.pending;
        let same_levels = shown_lod == Some(plan.lod.as_slice());
        // Coarse blocks keep thin structures for one transfer function: a
        // change writes them again.
        let reclassify = self.cache.store().has_box_extremes()
            && self.shown.as_ref().is_some_and(|s| s.tf != target.tf);
        if same_levels && !rough_before && !reclassify {
            return Ok(());
        }
        let max_edge = A::max_edge(device);
        let selection = target.selection.with_levels(plan.lod.clone());
        let grid = self.cache.store().meta().blocks;
        let kept = self.shown.take();
        let update = match &kept {
            Some(shown) => Some(shown.atlas.packing().update(&selection, max_edge)?),
            None => None,
        };
        match (kept, update) {
            (Some(shown), Some(update)) if !update.relayout => {
                // Blocks that keep their slot but whose aprons meet a
                // neighbour's new level, or were written without every chunk.
                let touched = seams::neighbour_changed(&shown.selection.lod, &plan.lod, grid);
                let mut uploads = update.uploads;
                let moved: std::collections::HashSet<usize> = uploads.iter().copied().collect();
                let again: Vec<(usize, Option<Pinned>)> = (0..plan.lod.len())
                    .into_par_iter()
                    .filter(|&b| {
                        plan.lod[b] != EMPTY
                            && !moved.contains(&b)
                            && (touched[b]
                                || shown.rough.get(b).copied().unwrap_or(false)
                                || (reclassify && plan.lod[b] > 0))
                    })
                    .map(|b| {
                        let block = self.cache.store().stats().block_position(b);
                        let pins = self.cache.pin_with_apron(
                            usize::from(plan.lod[b]),
                            block,
                            APRON,
                            true,
                        )?;
                        Ok((b, pins))
                    })
                    .collect::<Result<_, GpuError>>()?;
                let mut rough = shown.rough;
                rough.resize(plan.lod.len(), false);
                // A block no longer shown has no apron left to finish.
                for (r, &level) in rough.iter_mut().zip(&plan.lod) {
                    *r &= level != EMPTY;
                }
                for (b, pins) in again {
                    match pins {
                        Some(pins) => {
                            plan.pins.insert(b, pins);
                            uploads.push(b);
                        }
                        // Its chunks are on their way: written when they arrive.
                        None => rough[b] = true,
                    }
                }
                if uploads.is_empty() && same_levels {
                    self.pending += rough.iter().filter(|&&r| r).count();
                    let tf = target.tf.clone();
                    self.shown = Some(Shown { rough, tf, ..shown });
                    return Ok(());
                }
                let mut seams = pin_seams(&self.cache, &plan.lod, &uploads, &mut rough)?;
                keep_thin_structures(
                    &self.cache,
                    &target.tf,
                    &plan.lod,
                    &mut plan.pins,
                    &mut seams,
                );
                self.data_version += 1;
                stats.uploaded_blocks = uploads.len();
                let source = pinned_source(&self.cache, &plan.pins, &seams);
                let mut atlas = shown.atlas;
                atlas.update(device, update.packing, &uploads, desc, &source)?;
                self.pending += rough.iter().filter(|&&r| r).count();
                self.shown = Some(Shown {
                    atlas,
                    selection,
                    rough,
                    tf: target.tf.clone(),
                });
            }
            (kept, _) => {
                // The old atlas goes before the new one is made.
                drop(kept);
                self.data_version += 1;
                let (selection, mut plan) = self.fresh_plan(plan)?;
                let packing = Packing::new(&selection, max_edge)?;
                stats.uploaded_blocks = selection.non_empty;
                stats.relayout = true;
                let every: Vec<usize> = (0..plan.lod.len())
                    .filter(|&b| plan.lod[b] != EMPTY)
                    .collect();
                let mut rough = vec![false; plan.lod.len()];
                let mut seams = pin_seams(&self.cache, &plan.lod, &every, &mut rough)?;
                let tf = target.tf.clone();
                keep_thin_structures(&self.cache, &tf, &plan.lod, &mut plan.pins, &mut seams);
                let source = pinned_source(&self.cache, &plan.pins, &seams);
                let atlas = A::upload(device, grid, packing, desc, &source)?;
                self.pending = plan.pending + rough.iter().filter(|&&r| r).count();
                self.shown = Some(Shown {
                    atlas,
                    selection,
                    rough,
                    tf,
                });
            }
        }
        Ok(())
    }

    /// For a fresh atlas every block is uploaded: each at its planned level
    /// if its chunks are in memory (pinned now), else at the finest level
    /// that is; never finer than the target, so the atlas fits.
    fn fresh_plan(&self, plan: Plan) -> Result<(LodSelection, Plan), GpuError> {
        let Some(target) = &self.target else {
            return Err(GpuError::InvalidRequest("no selection to show".into()));
        };
        let stats = self.cache.store().stats();
        let Plan {
            mut lod, mut pins, ..
        } = plan;
        // The blocks the plan kept as they were shown: pinned now.
        let unpinned: Vec<usize> = lod
            .par_iter()
            .enumerate()
            .filter(|&(b, &planned)| planned != EMPTY && !pins.contains_key(&b))
            .map(|(b, _)| b)
            .collect();
        let fresh: Vec<(usize, u8, Pinned)> = unpinned
            .into_par_iter()
            .map(|b| {
                let (want, planned) = (target.selection.lod[b], lod[b]);
                // Lower levels are finer: never keep one finer than the target.
                let level = planned.max(want);
                let block = stats.block_position(b);
                let asked = level == want;
                if let Some(pins) =
                    self.cache
                        .pin_with_apron(usize::from(level), block, APRON, asked)?
                {
                    return Ok((b, level, pins));
                }
                let (level, pins) = finest_in_memory(&self.cache, block, want)?;
                Ok((b, level, pins))
            })
            .collect::<Result<_, GpuError>>()?;
        for (b, level, chunks) in fresh {
            lod[b] = level;
            pins.insert(b, chunks);
        }
        // Shown coarser than the target: waiting for data.
        let want = &target.selection.lod;
        let pending = lod
            .par_iter()
            .zip(want.par_iter())
            .filter(|&(&l, &w)| l != EMPTY && l != w)
            .count();
        let plan = Plan { lod, pins, pending };
        Ok((target.selection.with_levels(plan.lod.clone()), plan))
    }
}

/// Per block, the level to show now (see the module docs) and, for blocks
/// whose level changes, their pinned chunks.
fn plan(
    cache: &Arc<BlockCache>,
    target: &LodSelection,
    shown: Option<&[u8]>,
) -> Result<Plan, GpuError> {
    let stats = cache.store().stats();
    let changes: Vec<(usize, u8, Option<Pinned>, bool)> = target
        .lod
        .par_iter()
        .enumerate()
        .filter(|&(b, &want)| want != EMPTY && want != shown.map_or(EMPTY, |s| s[b]))
        .map(|(b, &want)| {
            let now = shown.map_or(EMPTY, |s| s[b]);
            let block = stats.block_position(b);
            if let Some(pins) = cache.pin_with_apron(usize::from(want), block, APRON, true)? {
                return Ok((b, want, Some(pins), false));
            }
            if now != EMPTY {
                return Ok((b, now, None, true));
            }
            let (level, pins) = finest_in_memory(cache, block, want)?;
            Ok((b, level, Some(pins), true))
        })
        .collect::<Result<_, GpuError>>()?;
    let mut lod = target.lod.clone();
    let mut pins = HashMap::with_capacity(changes.len());
    let mut pending = 0;
    for (b, level, chunks, waits) in changes {
        lod[b] = level;
        pending += usize::from(waits);
        if let Some(chunks) = chunks {
            pins.insert(b, chunks);
        }
    }
    Ok(Plan { lod, pins, pending })
}

/// The finest level coarser than `want` at which `block`'s chunks are in
/// memory, pinned; without one (a cache whose coarse levels are not
/// resident), level 4 read now.
fn finest_in_memory(
    cache: &Arc<BlockCache>,
    block: [u32; 3],
    want: u8,
) -> Result<(u8, Pinned), GpuError> {
    for level in usize::from(want) + 1..LEVELS {
        if let Some(pins) = cache.pin_with_apron(level, block, APRON, false)? {
            return Ok((level as u8, pins));
        }
    }
    let coarsest = LEVELS - 1;
    cache.block_with_apron(coarsest, block, APRON)?;
    let pins = cache
        .pin_with_apron(coarsest, block, APRON, false)?
        .unwrap_or_default();
    Ok((coarsest as u8, pins))
}

/// The chunks of other levels the aprons of blocks `write` read at levels
/// `lod`, pinned where every one is in memory (the others are requested);
/// blocks written without them are marked in `rough`, the others cleared.
fn pin_seams(
    cache: &Arc<BlockCache>,
    lod: &[u8],
    write: &[usize],
    rough: &mut [bool],
) -> Result<HashMap<usize, SeamChunks>, GpuError> {
    let grid = cache.store().meta().blocks;
    let dims = cache.store().meta().geometry.dims;
    let stats = cache.store().stats();
    let pinned: Vec<(usize, Option<SeamChunks>)> = write
        .par_iter()
        .map(|&b| {
            let block = stats.block_position(b);
            let levels = seams::neighbourhood(lod, grid, block);
            let keys = seams::seam_chunks(block, grid, dims, &levels);
            Ok((b, cache.pin(&keys, true)?))
        })
        .collect::<Result<_, GpuError>>()?;
    let mut seams = HashMap::with_capacity(pinned.len());
    for (b, chunks) in pinned {
        if let Some(r) = rough.get_mut(b) {
            *r = chunks.is_none();
        }
        if let Some(chunks) = chunks {
            seams.insert(b, chunks);
        }
    }
    Ok(seams)
}

/// Replaces every coarse chunk in `pins` (per block, at its level in `lod`)
/// and in `seams` by its values with thin structures kept visible under `tf`
/// ([`blocks::visibility`]), each chunk computed once; chunks without box
/// extremes stay as they are.
fn keep_thin_structures(
    cache: &BlockCache,
    tf: &TransferFunction,
    lod: &[u8],
    pins: &mut HashMap<usize, Pinned>,
    seams: &mut HashMap<usize, SeamChunks>,
) {
    if !cache.store().has_box_extremes() {
        return;
    }
    let coarse = |level: u8| level > 0 && usize::from(level) < LEVELS;
    let mut records: HashMap<ChunkKey, Arc<VoxelData>> = HashMap::new();
    for (&b, chunks) in pins.iter() {
        let level = lod.get(b).copied().unwrap_or(EMPTY);
        if coarse(level) {
            for (&position, chunk) in chunks {
                records
                    .entry((level, position))
                    .or_insert_with(|| Arc::clone(chunk));
            }
        }
    }
    for chunks in seams.values() {
        for (&key, chunk) in chunks {
            if coarse(key.0) {
                records.entry(key).or_insert_with(|| Arc::clone(chunk));
            }
        }
    }
    let extinction = visibility::Extinction {
        tf,
        value_map: cache.store().meta().value_map,
    };
    let kept: HashMap<ChunkKey, Arc<VoxelData>> = records
        .into_par_iter()
        .map(|(key, record)| (key, visibility::kept_chunk(&record, extinction)))
        .collect();
    for (&b, chunks) in pins.iter_mut() {
        let level = lod.get(b).copied().unwrap_or(EMPTY);
        for (&position, chunk) in chunks.iter_mut() {
            if let Some(k) = kept.get(&(level, position)) {
                *chunk = Arc::clone(k);
            }
        }
    }
    for chunks in seams.values_mut() {
        for (key, chunk) in chunks.iter_mut() {
            if let Some(k) = kept.get(key) {
                *chunk = Arc::clone(k);
            }
        }
    }
}

/// A block source assembling each block from its pinned chunks, its apron
/// meeting its neighbours' levels where their chunks are in `seams`.
fn pinned_source<'a>(
    cache: &'a BlockCache,
    pins: &'a HashMap<usize, Pinned>,
    seams: &'a HashMap<usize, SeamChunks>,
) -> impl Fn(usize, &[u8]) -> Result<VoxelData, GpuError> + Sync + 'a {
    move |b, lod| {
        let block = cache.store().stats().block_position(b);
        let level = usize::from(lod[b]);
        let mut voxels = match pins.get(&b) {
            Some(pinned) => cache.assemble_with_apron(level, block, APRON, pinned),
            // Not planned to change: only a relayout uploads it, and relayouts pin every block.
            None => cache.block_with_apron(level, block, APRON)?,
        };
        if let Some(chunks) = seams.get(&b) {
            let meta = cache.store().meta();
            let levels = seams::neighbourhood(lod, meta.blocks, block);
            seams::fix_apron(
                &mut voxels,
                block,
                meta.blocks,
                meta.geometry.dims,
                &levels,
                chunks,
            );
        }
        Ok(voxels)
    }
}

/// What the GPU can hold: a byte budget for the atlas, the texel size, and the
/// largest 3D texture edge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceBudget {
    /// Atlas bytes allowed.
    pub bytes: u64,
    /// Bytes per texel.
    pub texel_bytes: u64,
    /// The adapter's largest 3D texture edge.
    pub max_edge: u32,
}

impl DeviceBudget {
    /// No limit but the texture edge: the CPU twin's.
    pub fn unlimited(max_edge: u32) -> DeviceBudget {
        DeviceBudget {
            bytes: u64::MAX,
            texel_bytes: 1,
            max_edge,
        }
    }
}

/// Selects every block's level of detail for `tf` at data reduction
/// `reduction` among the blocks `tf` shows, seen from `view` if given. When a fresh packing of that
/// selection (slots with aprons, whole layers per level) would not fit
/// `device`, a cap on the voxels kept shrinks until it fits, then grows back
/// by bisection to use as much of the device as it can (the selection is
/// then [`LodSelection::capped`]). Returns the selection and its fresh packing.
pub fn select_levels(
    store: &Store,
    tf: &TransferFunction,
    reduction: f32,
    view: Option<&Viewpoint>,
    device: DeviceBudget,
) -> Result<(LodSelection, Packing), GpuError> {
    let full_voxels = store.meta().geometry.voxel_count();
    // The selection under a cap of `budget` voxels and its packing, if that
    // fits the device.
    let attempt = |budget: u64| {
        let selection = lod::select(
            store.stats(),
            store.meta().value_map,
            tf,
            full_voxels,
            Budget {
                reduction: f64::from(reduction),
                cap_voxels: budget,
            },
            view,
        );
        // A packing that does not fit the texture edge counts as too big.
        let packing = Packing::new(&selection, device.max_edge).ok();
        let bytes = packing.as_ref().map_or(u64::MAX, |p| {
            p.atlas_dims.iter().map(|&d| u64::from(d)).product::<u64>() * device.texel_bytes
        });
        let fits = packing.filter(|_| bytes <= device.bytes);
        (selection, fits, bytes)
    };
    let (selection, fits, mut bytes) = attempt(u64::MAX);
    if let Some(packing) = fits {
        return Ok((selection, packing));
    }
    // Shrink until a selection fits; `too_big` is the smallest budget known not to.
    let mut too_big = selection.budget_voxels.min(selection.kept_voxels);
    let mut best = None;
    let mut over_budget = selection.over_budget;
    for _ in 0..MAX_SELECTIONS {
        if over_budget || too_big <= 1 {
            break;
        }
        let shrink = if bytes == u64::MAX {
            0.5
        } else {
            (device.bytes as f64 / bytes as f64).min(0.9)
        };
        let budget = ((too_big as f64 * shrink) as u64).max(1);
        let (selection, fits, b) = attempt(budget);
        bytes = b;
        over_budget = selection.over_budget;
        match fits {
            Some(packing) => {
                best = Some((budget, selection, packing));
                break;
            }
            None => too_big = budget,
        }
    }
    let Some((mut fitting, mut selection, mut packing)) = best else {
        let coarsest = lod::select(
            store.stats(),
            store.meta().value_map,
            tf,
            full_voxels,
            Budget::voxels(0),
            None,
        );
        return Err(GpuError::Unsupported {
            what: format!(
                "the {} blocks the transfer function shows, even all at level 4 ({} voxels)",
                coarsest.non_empty, coarsest.kept_voxels
            ),
            limit: format!(
                "they do not fit the GPU budget of {} bytes in 3D textures of at most {} texels per side",
                device.bytes, device.max_edge
            ),
        });
    };
    // Grow back towards the smallest budget known too big.
    for _ in 0..MAX_SELECTIONS / 2 {
        if too_big - fitting <= too_big / 64 {
            break;
        }
        let budget = fitting + (too_big - fitting) / 2;
        match attempt(budget) {
            (s, Some(p), _) => (fitting, selection, packing) = (budget, s, p),
            _ => too_big = budget,
        }
    }
    Ok((selection, packing))
}
