//! Slice views (multiplanar reformatting): a plane through the volume,
//! sampled on the CPU from the same blocks the renderers read, shown in grey
//! through a window; the value of one voxel ([`probe`]); and the first
//! visible point along a pixel's ray of a 3D view ([`pick`]).
//!
//! **Planes.** A [`Plane`]'s axes in patient space (LPS) follow the
//! radiological convention: axial seen from the feet (the patient's right on
//! the image's left, anterior up), coronal from the front (superior up),
//! sagittal from the patient's left (anterior on the image's left). An
//! oblique plane is the base one turned by [`Orientation`]; turning the
//! crosshair in one view turns the other two planes about that view's
//! normal (each view has its orientation), so the three stay perpendicular.
//!
//! **Placement.** The plane passes through the crosshair (`cx`, `cy`, `cz`,
//! model mm: from the volume's centre, as the camera's target). The image is
//! centred on the volume's centre seen along the plane's normal (plus the
//! pan), so scrolling moves the plane, not the picture; at zoom 1 the
//! volume's box fills the image's width or height. [`SlicePlacement`] says
//! where each pixel lies; clients map the cursor through it.
//!
//! **Sampling.** Each pixel is the trilinear interpolant of the stored
//! values at the finest level its size needs (level 0 unless a pixel covers
//! two voxels or more), read from the block cache only where the chunk is in
//! memory: a missing chunk is requested from the background readers and its
//! pixels are sampled at the next coarser level in memory meanwhile (levels
//! 3 and 4 always are), and [`SliceFrame::pending_chunks`] says how many, so
//! the view refines when they arrive. A thick slab samples the normal at the
//! smallest spacing and combines with [`SlabMode`] (MIP, MinIP, average).

use std::collections::HashSet;
use std::sync::Arc;

use blocks::cache::{BlockCache, ChunkKey};
use blocks::store::{BLOCK, LEVELS, level_dims};
use blocks::{Geometry, TransferFunction, VoxelData};
use glam::{Mat3, Mat4, Quat, Vec2, Vec3, Vec4, Vec4Swizzles};
use rayon::prelude::*;

use crate::camera::{Camera, box_corners};
use crate::frame::{ClipBox, Frame, MAX_IMAGE_EDGE, Rows, Window};
use crate::raycast::VolumePlacement;
use crate::settings::{Choice, Expected, TextSetting};

/// The farthest a crosshair or pan may be from the volume's centre, mm.
pub const MAX_OFFSET_MM: f64 = 100_000.0;
/// The thickest slab, mm.
pub const MAX_SLAB_MM: f64 = 500.0;
/// The most samples a slab takes per pixel (a thicker slab spaces them wider).
pub const MAX_SLAB_SAMPLES: u32 = 256;
/// The closest zoom: 64 × the fitted view.
pub const MAX_ZOOM: f64 = 64.0;

/// A slice view's base plane.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Plane {
    /// Across the body's long axis, seen from the feet.
    #[default]
    Axial,
    /// Front to back, seen from the front.
    Coronal,
    /// Left to right, seen from the patient's left.
    Sagittal,
}

impl Choice for Plane {
    const ALL: &'static [Plane] = &[Plane::Axial, Plane::Coronal, Plane::Sagittal];

    fn name(self) -> &'static str {
        match self {
            Plane::Axial => "axial",
            Plane::Coronal => "coronal",
            Plane::Sagittal => "sagittal",
        }
    }

    fn doc(self) -> &'static str {
        match self {
            Plane::Axial => "across the long axis, seen from the feet",
            Plane::Coronal => "front to back, seen from the front",
            Plane::Sagittal => "left to right, seen from the patient's left",
        }
    }
}

impl Plane {
    /// The image's right and up in patient space (LPS) before any rotation.
    pub fn base_axes(self) -> (Vec3, Vec3) {
        match self {
            // The patient's left (+x) on the image's right, anterior (−y) up.
            Plane::Axial => (Vec3::X, Vec3::NEG_Y),
            Plane::Coronal => (Vec3::X, Vec3::Z),
            // Posterior (+y) on the image's right, superior up.
            Plane::Sagittal => (Vec3::Y, Vec3::Z),
        }
    }
}

/// How a thick slab's samples along the normal combine into a pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum SlabMode {
    /// The largest value (maximum intensity projection).
    #[default]
    Mip,
    /// The smallest value (minimum intensity projection).
    Minip,
    /// The mean value.
    Average,
}

impl Choice for SlabMode {
    const ALL: &'static [SlabMode] = &[SlabMode::Mip, SlabMode::Minip, SlabMode::Average];

    fn name(self) -> &'static str {
        match self {
            SlabMode::Mip => "mip",
            SlabMode::Minip => "minip",
            SlabMode::Average => "average",
        }
    }

    fn doc(self) -> &'static str {
        match self {
            SlabMode::Mip => "the largest value across the slab",
            SlabMode::Minip => "the smallest value across the slab",
            SlabMode::Average => "the mean value across the slab",
        }
    }
}

crate::choice_setting!(Plane, SlabMode);

/// A rotation of the crosshair's planes from their base orientation: a unit
/// quaternion W,X,Y,Z in patient space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Orientation(pub Quat);

impl Default for Orientation {
    fn default() -> Orientation {
        Orientation(Quat::IDENTITY)
    }
}

impl TextSetting for Orientation {
    fn expected() -> String {
        "a rotation W,X,Y,Z (a quaternion, normalized; 1,0,0,0 is none)".into()
    }

    fn parse_text(text: &str) -> Result<Orientation, Expected> {
        let values: Vec<f32> = text
            .split(',')
            .map(|v| v.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|_| Expected(Self::expected()))?;
        let [w, x, y, z] = values[..] else {
            return Err(Expected(Self::expected()));
        };
        let q = Quat::from_xyzw(x, y, z, w);
        if !q.is_finite() || q.length() < 1e-3 || q.length() > 1e3 {
            return Err(Expected(Self::expected()));
        }
        Ok(Orientation(q.normalize()))
    }

    fn check_value(&self) -> Result<(), Expected> {
        if self.0.is_finite() && (self.0.length() - 1.0).abs() < 1e-3 {
            Ok(())
        } else {
            Err(Expected(Self::expected()))
        }
    }

    fn text(&self) -> String {
        let q = self.0;
        format!("{},{},{},{}", q.w, q.x, q.y, q.z)
    }
}

crate::text_setting!(Orientation);

crate::settings! {
    /// One slice view of a volume: where its plane lies, how it is framed,
    /// windowed and, for a slab, combined. A view session holds one per
    /// slice view; the plane comes from the view.
    #[derive(Debug, Clone, PartialEq)]
    pub struct SliceRequest in Slice {
        /// Image width in pixels.
        pub width: u32 = 512, "w" | "slice-width",
            whole(1, MAX_IMAGE_EDGE, "a whole number of pixels", "px");
        /// Image height in pixels.
        pub height: u32 = 512, "h" | "slice-height",
            whole(1, MAX_IMAGE_EDGE, "a whole number of pixels", "px");
        /// The crosshair's x (towards the patient's left), mm from the volume's centre.
        pub cx: f32 = 0.0, "cx",
            number(-MAX_OFFSET_MM, MAX_OFFSET_MM, "mm from the volume's centre", "mm");
        /// The crosshair's y (towards posterior), mm from the volume's centre.
        pub cy: f32 = 0.0, "cy",
            number(-MAX_OFFSET_MM, MAX_OFFSET_MM, "mm from the volume's centre", "mm");
        /// The crosshair's z (towards superior), mm from the volume's centre.
        pub cz: f32 = 0.0, "cz",
            number(-MAX_OFFSET_MM, MAX_OFFSET_MM, "mm from the volume's centre", "mm");
        /// This view's rotation from its base plane (oblique views).
        pub orient: Orientation = Orientation::default(), "orient", by_type();
        /// Magnification: 1 fits the volume in the view.
        pub zoom: f32 = 1.0, "zoom", number(0.1, MAX_ZOOM, "a factor", "×");
        /// Image centre's offset to the right of the volume's centre, mm.
        pub pan_x: f32 = 0.0, "px",
            number(-MAX_OFFSET_MM, MAX_OFFSET_MM, "mm", "mm");
        /// Image centre's offset upwards from the volume's centre, mm.
        pub pan_y: f32 = 0.0, "py",
            number(-MAX_OFFSET_MM, MAX_OFFSET_MM, "mm", "mm");
        /// Greyscale window CENTRE,WIDTH in physical units (e.g. 40,80 for
        /// brain in HU) [default: 40,400 for CT in HU, else the value range].
        pub window: Option<Window> = None, "window", by_type();
        /// Slab thickness in mm: 0 is one plane; thicker combines by slab_mode.
        pub slab_mm: f32 = 0.0, "slab",
            number(0.0, MAX_SLAB_MM, "a thickness", "mm");
        /// How a slab's samples combine.
        pub slab_mode: SlabMode = SlabMode::Mip, "slab_mode", by_type();
    }
    plain {
        /// The plane before rotation: the slice view's own.
        pub plane: Plane = Plane::Axial,
        /// Draw only these rows of the image (a costly slice is drawn band
        /// by band, so other frames can go between); all when `None`.
        pub rows: Option<Rows> = None,
        /// The normals of the crosshair's three planes (axial, coronal,
        /// sagittal) when each view has an orientation of its own (a view
        /// session knows all three); `None`: each turned as this one.
        pub crosshair_normals: Option<[[f32; 3]; 3]> = None,
    }
}

/// The window CT images open with (soft tissue), and CT's named windows, in HU.
pub const CT_WINDOWS: [(&str, Window); 6] = [
    (
        "brain",
        Window {
            centre: 40.0,
            width: 80.0,
        },
    ),
    (
        "subdural",
        Window {
            centre: 75.0,
            width: 215.0,
        },
    ),
    (
        "stroke",
        Window {
            centre: 32.0,
            width: 8.0,
        },
    ),
    (
        "bone",
        Window {
            centre: 600.0,
            width: 2800.0,
        },
    ),
    (
        "lung",
        Window {
            centre: -600.0,
            width: 1500.0,
        },
    ),
    (
        "abdomen",
        Window {
            centre: 40.0,
            width: 400.0,
        },
    ),
];

/// The window a slice opens with and its name: abdomen (soft tissue) for CT
/// in HU, else the whole value range (`range`).
pub fn default_window(ct_in_hu: bool, value_range: [f32; 2]) -> (&'static str, Window) {
    if ct_in_hu {
        CT_WINDOWS[5]
    } else {
        ("range", Window::spanning(value_range[0], value_range[1]))
    }
}

/// Where a slice image lies in model space (mm from the volume's centre):
/// pixel (x, y)'s centre is `corner + x·right + y·down`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SlicePlacement {
    /// The centre of pixel (0, 0).
    pub corner: [f32; 3],
    /// One pixel to the right.
    pub right: [f32; 3],
    /// One pixel down.
    pub down: [f32; 3],
    /// The unit normal, towards the viewer.
    pub normal: [f32; 3],
    /// The level of detail the image wants (0 finest): level 0 unless a
    /// pixel covers two voxels or more.
    pub level: usize,
    /// The crosshair, model mm.
    pub crosshair: [f32; 3],
    /// The normals of the crosshair's three planes (axial, coronal,
    /// sagittal, each turned by its view's orientation), whose lines
    /// through it a view draws.
    pub normals: [[f32; 3]; 3],
}

impl SliceRequest {
    /// The image's right, up and the normal towards the viewer (unit, patient space).
    pub fn axes(&self) -> [Vec3; 3] {
        let (right, up) = self.plane.base_axes();
        let q = self.orient.0;
        let (right, up) = (q * right, q * up);
        [right, up, right.cross(up)]
    }

    /// The crosshair, model mm.
    pub fn crosshair(&self) -> Vec3 {
        Vec3::new(self.cx, self.cy, self.cz)
    }

    /// Where the image lies for a volume of `geometry`.
    pub fn placement(&self, geometry: &Geometry) -> SlicePlacement {
        let model_from_texture = VolumePlacement::of_geometry(geometry).model_from_texture;
        let [right, up, normal] = self.axes();
        let corners =
            box_corners(Vec3::splat(-0.5), Vec3::splat(0.5)).map(|c| model_from_texture * c);
        let half = |axis: Vec3| {
            corners
                .iter()
                .map(|c| c.dot(axis).abs())
                .fold(0.0, f32::max)
        };
        let (w, h) = (self.width as f32, self.height as f32);
        let fit = (2.0 * half(right) / w).max(2.0 * half(up) / h);
        let mm = (fit / self.zoom).max(1e-6);
        let c = self.crosshair();
        let centre = normal * c.dot(normal) + right * self.pan_x + up * self.pan_y;
        let corner = centre - right * mm * (w / 2.0 - 0.5) + up * mm * (h / 2.0 - 0.5);
        let ratio = mm / geometry.min_spacing_f32();
        let level = if ratio < 2.0 {
            0
        } else {
            (ratio.log2().floor() as usize).min(LEVELS - 1)
        };
        let normals = self.crosshair_normals.unwrap_or_else(|| {
            [Plane::Axial, Plane::Coronal, Plane::Sagittal].map(|plane| {
                SliceRequest {
                    plane,
                    ..self.clone()
                }
                .axes()[2]
                    .to_array()
            })
        });
        SlicePlacement {
            corner: corner.to_array(),
            right: (right * mm).to_array(),
            down: (-up * mm).to_array(),
            normal: normal.to_array(),
            level,
            crosshair: c.to_array(),
            normals,
        }
    }

    /// Samples a pixel takes across the slab (1 without one) on a volume of
    /// `geometry`: the slab's thickness at the smallest spacing, at most
    /// [`MAX_SLAB_SAMPLES`].
    pub fn slab_samples(&self, geometry: &Geometry) -> u32 {
        if self.slab_mm <= 0.0 {
            return 1;
        }
        let steps = (self.slab_mm / geometry.min_spacing_f32()).ceil() as u32;
        (steps + 1).clamp(2, MAX_SLAB_SAMPLES)
    }
}

/// A rendered slice and what it was drawn from.
#[derive(Debug)]
pub struct SliceFrame {
    /// The pixels (grey, opaque; black outside the volume): the rows asked
    /// for (`rows`), else the whole image.
    pub frame: Frame,
    /// Where the image lies.
    pub placement: SlicePlacement,
    /// The window it was drawn through.
    pub window: Window,
    /// Chunks at the wanted level still being read: their pixels are
    /// coarser until they arrive.
    pub pending_chunks: usize,
}

/// Model mm → level-0 continuous voxel index (voxel centres at whole numbers).
#[derive(Debug, Clone, Copy)]
struct IndexMap {
    texture_from_model: Mat3,
    dims: Vec3,
}

impl IndexMap {
    fn of(geometry: &Geometry) -> IndexMap {
        let model_from_texture = VolumePlacement::of_geometry(geometry).model_from_texture;
        IndexMap {
            texture_from_model: model_from_texture.inverse(),
            dims: Vec3::from_array(geometry.dims.map(|d| d as f32)),
        }
    }

    /// The continuous index of model point `p`, `None` outside the volume.
    fn index(&self, p: Vec3) -> Option<Vec3> {
        let t = self.texture_from_model * p + Vec3::splat(0.5);
        if t.cmplt(Vec3::ZERO).any() || t.cmpgt(Vec3::ONE).any() {
            return None;
        }
        Some(t * self.dims - Vec3::splat(0.5))
    }
}

/// How a [`Reader`] gets a chunk that is not in memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fetch {
    /// Not at all: fall back to a coarser level and note it (render paths).
    Cached,
    /// Read it now on this thread (probes and picks, off the render worker).
    Read,
}

/// Reads voxels of one store through its cache, remembering the last chunks.
struct Reader<'a> {
    cache: &'a BlockCache,
    dims: [[i64; 3]; LEVELS],
    fetch: Fetch,
    recent: [Option<(ChunkKey, Option<Arc<VoxelData>>)>; 8],
    /// The level samples are wanted at.
    wanted: usize,
    /// Chunks at the wanted level that were not in memory.
    missing: HashSet<ChunkKey>,
    error: Option<blocks::Error>,
}

fn value_at(data: &VoxelData, i: usize) -> f32 {
    match data {
        VoxelData::U8(v) => f32::from(v[i]),
        VoxelData::I8(v) => f32::from(v[i]),
        VoxelData::U16(v) => f32::from(v[i]),
        VoxelData::I16(v) => f32::from(v[i]),
        VoxelData::U32(v) => v[i] as f32,
        VoxelData::I32(v) => v[i] as f32,
        VoxelData::F32(v) => v[i],
    }
}

impl<'a> Reader<'a> {
    fn new(cache: &'a BlockCache, fetch: Fetch, wanted: usize) -> Reader<'a> {
        let dims0 = cache.store().meta().geometry.dims;
        Reader {
            cache,
            dims: std::array::from_fn(|l| level_dims(dims0, l).map(i64::from)),
            fetch,
            recent: Default::default(),
            wanted,
            missing: HashSet::new(),
            error: None,
        }
    }

    /// Chunk `key`, if in memory (or read, under [`Fetch::Read`]).
    fn chunk(&mut self, key: ChunkKey) -> Option<&VoxelData> {
        let slot = (key.1[0] as usize
            ^ (key.1[1] as usize) << 1
            ^ (key.1[2] as usize) << 2
            ^ usize::from(key.0))
            & 7;
        let hit = matches!(&self.recent[slot], Some((k, _)) if *k == key);
        if !hit {
            let chunk = match self.fetch {
                Fetch::Cached => {
                    let chunk = self.cache.cached_chunk(key);
                    if chunk.is_none() && usize::from(key.0) == self.wanted {
                        self.missing.insert(key);
                    }
                    chunk
                }
                Fetch::Read => match self.cache.chunk(key) {
                    Ok(c) => Some(c),
                    Err(e) => {
                        self.error.get_or_insert(e);
                        None
                    }
                },
            };
            self.recent[slot] = Some((key, chunk));
        }
        self.recent[slot].as_ref().and_then(|(_, c)| c.as_deref())
    }

    /// The stored value of voxel `v` at `level` (clamped to the volume),
    /// if its chunk is at hand.
    fn voxel(&mut self, level: usize, v: [i64; 3]) -> Option<f32> {
        let dims = self.dims[level];
        let v: [i64; 3] = std::array::from_fn(|a| v[a].clamp(0, dims[a] - 1));
        let n = i64::from(BLOCK);
        let key = (level as u8, v.map(|c| (c / n) as u32));
        let i = ((v[2] % n) * n + v[1] % n) * n + v[0] % n;
        self.chunk(key).map(|c| value_at(c, i as usize))
    }

    /// The trilinear interpolant of the stored values at level-0 continuous
    /// index `f`, from `level` or, where its chunks are not at hand, the
    /// next coarser level that has them.
    fn sample(&mut self, level: usize, f: Vec3) -> Option<f32> {
        for l in level..LEVELS {
            let scale = (1u32 << l) as f32;
            let g = (f + Vec3::splat(0.5)) / scale - Vec3::splat(0.5);
            let base = g.floor();
            let w = g - base;
            let b = base.to_array().map(|x| x as i64);
            let mut v = [0.0f32; 8];
            let mut complete = true;
            for (corner, value) in v.iter_mut().enumerate() {
                let o = [corner & 1, (corner >> 1) & 1, corner >> 2].map(|x| x as i64);
                // Every corner is looked up: each missing chunk is noted.
                match self.voxel(l, [b[0] + o[0], b[1] + o[1], b[2] + o[2]]) {
                    Some(x) => *value = x,
                    None => complete = false,
                }
            }
            if complete {
                let x00 = v[0] + (v[1] - v[0]) * w.x;
                let x10 = v[2] + (v[3] - v[2]) * w.x;
                let x01 = v[4] + (v[5] - v[4]) * w.x;
                let x11 = v[6] + (v[7] - v[6]) * w.x;
                let y0 = x00 + (x10 - x00) * w.y;
                let y1 = x01 + (x11 - x01) * w.y;
                return Some(y0 + (y1 - y0) * w.z);
            }
            if self.error.is_some() {
                return None;
            }
        }
        None
    }
}

/// Renders `request` of the store behind `cache` through `window`, without
/// waiting for storage (see the module docs); chunks not in memory are
/// requested in the background.
///
/// # Errors
/// When a chunk the slice needs could not be read (named by its shard), or
/// no level of some pixel's data is in memory.
pub fn render(
    cache: &Arc<BlockCache>,
    request: &SliceRequest,
    window: Window,
) -> Result<SliceFrame, blocks::Error> {
    let meta = cache.store().meta();
    let geometry = meta.geometry;
    let placement = request.placement(&geometry);
    let map = meta.value_map;
    let to_index = IndexMap::of(&geometry);
    let normal = Vec3::from(placement.normal);
    let samples = request.slab_samples(&geometry);
    let offsets: Vec<f32> = (0..samples)
        .map(|i| {
            if samples == 1 {
                0.0
            } else {
                request.slab_mm * (i as f32 / (samples - 1) as f32 - 0.5)
            }
        })
        .collect();
    let rows = request.rows.unwrap_or(Rows {
        first: 0,
        count: request.height,
    });
    let first_row = rows.first.min(request.height) as usize;
    let (width, height) = (
        request.width as usize,
        (rows.count as usize).min(request.height as usize - first_row),
    );
    let corner = Vec3::from(placement.corner);
    let (right, down) = (Vec3::from(placement.right), Vec3::from(placement.down));
    let (low, span) = (window.low(), window.width);
    let mode = request.slab_mode;
    let level = placement.level;
    let mut rgba = vec![0u8; width * height * 4];
    let rows: Vec<(HashSet<ChunkKey>, bool)> = rgba
        .par_chunks_mut(width * 4)
        .enumerate()
        .map(|(band_row, row)| {
            let y = first_row + band_row;
            let mut reader = Reader::new(cache, Fetch::Cached, level);
            let mut unread = false;
            for (x, pixel) in row.chunks_exact_mut(4).enumerate() {
                let p = corner + right * x as f32 + down * y as f32;
                let (mut combined, mut count) = (0.0f32, 0u32);
                for &o in &offsets {
                    let Some(f) = to_index.index(p + normal * o) else {
                        continue;
                    };
                    let Some(stored) = reader.sample(level, f) else {
                        unread = true;
                        continue;
                    };
                    let value = map.slope * stored + map.intercept;
                    combined = match (count, mode) {
                        (0, _) => value,
                        (_, SlabMode::Mip) => combined.max(value),
                        (_, SlabMode::Minip) => combined.min(value),
                        (_, SlabMode::Average) => combined + value,
                    };
                    count += 1;
                }
                let grey = if count == 0 {
                    0
                } else {
                    if mode == SlabMode::Average {
                        combined /= count as f32;
                    }
                    (((combined - low) / span).clamp(0.0, 1.0) * 255.0).round() as u8
                };
                pixel.copy_from_slice(&[grey, grey, grey, 255]);
            }
            (reader.missing, unread)
        })
        .collect();
    let mut missing: Vec<ChunkKey> = rows.iter().flat_map(|(m, _)| m.iter().copied()).collect();
    missing.sort_unstable();
    missing.dedup();
    // A chunk whose read failed is an error, never a hole: pinning says so.
    if !missing.is_empty() {
        cache.pin(&missing, true)?;
    }
    if rows.iter().any(|(_, unread)| *unread) {
        return Err(blocks::Error::Missing {
            path: cache.store().location().file(""),
            detail: "a slice's data at every level, levels 3 and 4 included, which should be \
                     resident: nothing to show for some of its pixels"
                .into(),
        });
    }
    Ok(SliceFrame {
        frame: Frame {
            width: request.width,
            height: height as u32,
            rgba,
        },
        placement,
        window,
        pending_chunks: missing.len(),
    })
}

/// One voxel's value: its index and stored and physical values.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Probe {
    /// Voxel index (i, j, k), level 0.
    pub index: [u32; 3],
    /// The voxel's centre, model mm.
    pub at: [f32; 3],
    /// The physical value (e.g. HU).
    pub value: f64,
}

/// The level-0 voxel holding model point `at` (mm from the volume's
/// centre), read now on this thread; `None` outside the volume.
///
/// # Errors
/// When its chunk cannot be read.
pub fn probe(cache: &BlockCache, at: [f32; 3]) -> Result<Option<Probe>, blocks::Error> {
    let at = Vec3::from(at);
    let geometry = cache.store().meta().geometry;
    let Some(f) = IndexMap::of(&geometry).index(at) else {
        return Ok(None);
    };
    let dims = geometry.dims;
    let index: [u32; 3] =
        std::array::from_fn(|a| (f[a].round().max(0.0) as u32).min(dims[a].saturating_sub(1)));
    let mut reader = Reader::new(cache, Fetch::Read, 0);
    let stored = reader.voxel(0, index.map(i64::from));
    if let Some(e) = reader.error {
        return Err(e);
    }
    let Some(stored) = stored else {
        return Ok(None);
    };
    let model_from_texture = VolumePlacement::of_geometry(&geometry).model_from_texture;
    let t = Vec3::from_array(std::array::from_fn(|a| {
        (index[a] as f32 + 0.5) / dims[a] as f32 - 0.5
    }));
    Ok(Some(Probe {
        index,
        at: (model_from_texture * t).to_array(),
        value: cache.store().meta().value_map.physical(f64::from(stored)),
    }))
}

/// What a 3D view shows at one of its pixels.
#[derive(Debug, Clone, Copy)]
pub struct PickRay<'a> {
    /// The view's camera.
    pub camera: &'a Camera,
    /// The image's size, pixels.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// The pixel (fractions allowed), from the top left.
    pub x: f32,
    /// See `x`.
    pub y: f32,
    /// The part of the volume shown.
    pub clip: ClipBox,
}

/// The opacity along a ray at which a pick stops: where what the transfer
/// function shows turns more opaque than not.
pub const PICK_OPACITY: f32 = 0.5;

/// The first point along `ray` at which the volume, classified by `tf`,
/// has gathered [`PICK_OPACITY`] (front-to-back, level-0 data, a step of
/// half the smallest spacing), model mm; `None` when the ray stays clearer.
/// Reads chunks on this thread.
///
/// # Errors
/// When a chunk along the ray cannot be read.
pub fn pick(
    cache: &BlockCache,
    ray: &PickRay<'_>,
    tf: &TransferFunction,
) -> Result<Option<[f32; 3]>, blocks::Error> {
    let meta = cache.store().meta();
    let geometry = meta.geometry;
    let placement = VolumePlacement::of_geometry(&geometry);
    let aspect = ray.width as f32 / ray.height.max(1) as f32;
    let inverse: Mat4 = ray.camera.view_proj(placement.radius(), aspect).inverse();
    let ndc = Vec2::new(
        ray.x / ray.width.max(1) as f32 * 2.0 - 1.0,
        1.0 - ray.y / ray.height.max(1) as f32 * 2.0,
    );
    let near = inverse * Vec4::new(ndc.x, ndc.y, 0.0, 1.0);
    let far = inverse * Vec4::new(ndc.x, ndc.y, 1.0, 1.0);
    let origin = near.xyz() / near.w;
    let dir = (far.xyz() / far.w - origin).normalize();
    let texture_from_model = placement.model_from_texture.inverse();
    let (t_origin, t_dir) = (
        texture_from_model * origin + Vec3::splat(0.5),
        texture_from_model * dir,
    );
    let span = crate::cpu::march::intersect_box(
        t_origin,
        t_dir,
        Vec3::from(ray.clip.min),
        Vec3::from(ray.clip.max),
    );
    if span.x >= span.y {
        return Ok(None);
    }
    let to_index = IndexMap::of(&geometry);
    let reference = geometry.min_spacing_f32();
    let step = reference * 0.5;
    let mut reader = Reader::new(cache, Fetch::Read, 0);
    let map = meta.value_map;
    let mut transparency = 1.0f32;
    let mut t = span.x;
    let mut steps = 0u32;
    // The ray's length in the box bounds the march; the cap guards the loop.
    while t <= span.y && steps < 1 << 20 {
        let p = origin + dir * t;
        if let Some(f) = to_index.index(p) {
            let stored = reader.sample(0, f);
            if let Some(e) = reader.error.take() {
                return Err(e);
            }
            if let Some(stored) = stored {
                let alpha = tf.evaluate(map.slope * stored + map.intercept)[3].clamp(0.0, 1.0);
                let corrected = 1.0 - (1.0 - alpha).powf(step / reference);
                transparency *= 1.0 - corrected;
                if 1.0 - transparency >= PICK_OPACITY {
                    return Ok(Some(p.to_array()));
                }
            }
        }
        t += step;
        steps += 1;
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use blocks::Volume;
    use blocks::ingest::MemorySource;
    use blocks::store::{IngestOptions, ingest_in_memory};

    /// The phantom at `size`³ and a cache over its store (levels 3 and 4 resident).
    fn phantom(size: u32) -> (Arc<Volume>, Arc<BlockCache>) {
        let volume = Arc::new(blocks::phantom::head(size).expect("phantom"));
        let mut source = MemorySource::new(volume.clone(), "phantom");
        let store = ingest_in_memory(&mut source, &IngestOptions::default()).expect("store");
        let mut cache = BlockCache::new(Arc::new(store), 64 << 20);
        cache
            .make_resident(&blocks::cache::RESIDENT_LEVELS)
            .expect("resident");
        (volume, Arc::new(cache))
    }

    /// Every level-0 chunk read into `cache`.
    fn read_level0(cache: &BlockCache) {
        let [gx, gy, gz] = cache.store().chunk_grid(0);
        let keys: Vec<ChunkKey> = (0..gz)
            .flat_map(|z| (0..gy).flat_map(move |y| (0..gx).map(move |x| (0u8, [x, y, z]))))
            .collect();
        cache.prefetch(&keys);
    }

    fn grey(value: f64, window: Window) -> u8 {
        (((value as f32 - window.low()) / window.width).clamp(0.0, 1.0) * 255.0).round() as u8
    }

    #[test]
    fn an_axial_slice_is_the_volume_seen_from_the_feet_voxel_for_voxel() {
        let (volume, cache) = phantom(32);
        read_level0(&cache);
        let window = Window::spanning(volume.value_range[0], volume.value_range[1]);
        // A voxel a pixel; the plane through voxel 20's centre: z index 20
        // is 4.5 voxels above the centre (15.5).
        let s = spacing(&cache);
        let request = SliceRequest {
            width: 32,
            height: 32,
            cz: 4.5 * s,
            ..SliceRequest::default()
        };
        let slice = render(&cache, &request, window).expect("slice");
        assert_eq!(slice.pending_chunks, 0);
        assert_eq!(slice.placement.level, 0);
        let mut differing = 0;
        for y in 0..32u32 {
            for x in 0..32u32 {
                // The image's left is the patient's right (index 0), its top anterior (j 0).
                let expected = grey(volume.physical_at(x, y, 20), window);
                let got = slice.frame.rgba[((y * 32 + x) * 4) as usize];
                assert!(
                    got.abs_diff(expected) <= 1,
                    "pixel ({x}, {y}): {got}, voxel ({x}, {y}, 20): {expected}"
                );
                differing += usize::from(got != expected);
            }
        }
        assert!(differing < 32, "{differing} pixels off by one");
    }

    #[test]
    fn coronal_and_sagittal_slices_put_superior_up_and_anterior_left() {
        let (volume, cache) = phantom(32);
        read_level0(&cache);
        let window = Window::spanning(volume.value_range[0], volume.value_range[1]);
        let s = spacing(&cache);
        let at = |plane, x: u32, y: u32| {
            // Through voxel (12, 9, 20)'s centre.
            let request = SliceRequest {
                width: 32,
                height: 32,
                cx: -3.5 * s,
                cy: -6.5 * s,
                cz: 4.5 * s,
                plane,
                ..SliceRequest::default()
            };
            let slice = render(&cache, &request, window).expect("slice");
            slice.frame.rgba[((y * 32 + x) * 4) as usize]
        };
        for (i, j, k) in [(3, 9, 30), (25, 9, 2), (12, 9, 16)] {
            // Coronal: i to the right, k up.
            let expected = grey(volume.physical_at(i, j, k), window);
            assert!(at(Plane::Coronal, i, 31 - k).abs_diff(expected) <= 1);
        }
        for (i, j, k) in [(12, 3, 30), (12, 28, 2), (12, 16, 16)] {
            // Sagittal: j (posterior) to the right, k up.
            let expected = grey(volume.physical_at(i, j, k), window);
            assert!(at(Plane::Sagittal, j, 31 - k).abs_diff(expected) <= 1);
        }
    }

    #[test]
    fn a_slice_of_blocks_not_yet_read_is_drawn_coarser_and_asks_for_them() {
        let (volume, cache) = phantom(64);
        let window = Window::spanning(volume.value_range[0], volume.value_range[1]);
        let request = SliceRequest {
            width: 64,
            height: 64,
            ..SliceRequest::default()
        };
        let before = cache.arrivals();
        let coarse = render(&cache, &request, window).expect("slice");
        // 64³ in 16³ blocks: the plane between z 31 and 32 crosses 2 layers of 4 × 4.
        assert_eq!(coarse.pending_chunks, 32);
        assert!(
            coarse.frame.rgba.chunks(4).any(|p| p[0] > 0),
            "drawn from level 3"
        );
        while cache.arrivals() < before + 32 {
            cache.wait_for_arrivals(cache.arrivals(), std::time::Duration::from_secs(5));
        }
        let fine = render(&cache, &request, window).expect("slice");
        assert_eq!(fine.pending_chunks, 0);
        assert_ne!(coarse.frame.rgba, fine.frame.rgba);
    }

    #[test]
    fn slabs_combine_the_planes_across_them() {
        let (volume, cache) = phantom(32);
        read_level0(&cache);
        let window = Window::spanning(volume.value_range[0], volume.value_range[1]);
        let s = spacing(&cache);
        let slab = |mode, voxels: f32| {
            let request = SliceRequest {
                width: 32,
                height: 32,
                cz: 4.5 * s,
                slab_mm: voxels * s,
                slab_mode: mode,
                ..SliceRequest::default()
            };
            render(&cache, &request, window).expect("slab").frame.rgba
        };
        let one = slab(SlabMode::Mip, 0.0);
        let (mip, minip, mean) = (
            slab(SlabMode::Mip, 8.0),
            slab(SlabMode::Minip, 8.0),
            slab(SlabMode::Average, 8.0),
        );
        // Samples at z 16.5, 17.5 … 24.5: MIP ≥ the plane's value ≥ MinIP, the mean between.
        for i in (0..one.len()).step_by(4) {
            assert!(mip[i] >= one[i] && one[i] >= minip[i], "pixel {}", i / 4);
            assert!(mip[i] >= mean[i] && mean[i] >= minip[i], "pixel {}", i / 4);
        }
        assert!(mip.iter().zip(&one).filter(|(a, b)| a != b).count() > 20);
        let (x, y) = (16u32, 16u32);
        let max = (17..=24)
            .map(|k| volume.physical_at(x, y, k))
            .fold(f64::MIN, f64::max)
            .max((volume.physical_at(x, y, 16) + volume.physical_at(x, y, 17)) / 2.0);
        assert!(mip[((y * 32 + x) * 4) as usize].abs_diff(grey(max, window)) <= 1);
    }

    #[test]
    fn zoom_pan_and_scrolling_move_the_picture_as_expected() {
        let geometry = Geometry::new([100, 100, 50], [1.0, 1.0, 2.0]);
        let base = SliceRequest {
            width: 200,
            height: 100,
            ..SliceRequest::default()
        };
        let p = base.placement(&geometry);
        // 100 mm square across 100 px high: 1 mm a pixel.
        assert!((Vec3::from(p.right).length() - 1.0).abs() < 1e-5);
        let scrolled = SliceRequest {
            cz: 10.0,
            ..base.clone()
        }
        .placement(&geometry);
        assert_eq!(scrolled.corner[0], p.corner[0]);
        assert_eq!(scrolled.corner[2], p.corner[2] + 10.0);
        let zoomed = SliceRequest {
            zoom: 4.0,
            pan_x: 5.0,
            ..base.clone()
        }
        .placement(&geometry);
        assert!((Vec3::from(zoomed.right).length() - 0.25).abs() < 1e-6);
        // The image's centre (between pixels 99 and 100 across) moved 5 mm to the right.
        let centre = Vec3::from(zoomed.corner) + Vec3::from(zoomed.right) * 99.5;
        assert!((centre.x - 5.0).abs() < 1e-4, "{centre}");
        // 4 pixels a mm and more: level 0; 4 mm a pixel: level 2.
        assert_eq!(zoomed.level, 0);
        let small = SliceRequest {
            width: 25,
            height: 25,
            ..base
        }
        .placement(&geometry);
        assert_eq!(small.level, 2);
    }

    #[test]
    fn an_oblique_turn_keeps_the_views_perpendicular() {
        let turn = Orientation::parse_text("0.9238795,0,0,0.3826834").expect("45° about z");
        let axes = |plane| {
            SliceRequest {
                plane,
                orient: turn,
                ..SliceRequest::default()
            }
            .axes()
        };
        let (a, c, s) = (
            axes(Plane::Axial),
            axes(Plane::Coronal),
            axes(Plane::Sagittal),
        );
        assert!(a[2].dot(c[2]).abs() < 1e-6 && c[2].dot(s[2]).abs() < 1e-6);
        assert!(a[2].dot(Vec3::NEG_Z) > 0.999, "the axial plane stays axial");
        assert!(Orientation::parse_text("0,0,0,0").is_err());
        assert!(Orientation::parse_text("1,0,0").is_err());
        assert!(Orientation::parse_text("nan,0,0,1").is_err());
    }

    #[test]
    fn a_probe_reads_the_voxel_and_a_pick_stops_where_the_view_turns_opaque() {
        let (volume, cache) = phantom(32);
        let (i, j, k) = (7u32, 20u32, 11u32);
        let s = spacing(&cache);
        let at = Vec3::new(i as f32 - 15.5, j as f32 - 15.5, k as f32 - 15.5) * s;
        let probe = probe(&cache, (at + Vec3::splat(0.3 * s)).to_array())
            .expect("read")
            .expect("inside");
        assert_eq!(probe.index, [i, j, k]);
        assert_eq!(probe.value, volume.physical_at(i, j, k));
        assert!(Vec3::from(probe.at).distance(at) < 1e-4);
        assert!(probe_outside(&cache));

        // Opaque from bone's values up (300 HU): the ray through the image's
        // centre from the front stops where the trilinear value first crosses.
        let threshold = 300.0;
        let tf = TransferFunction::parse(&format!(
            "{}:ffffff:0,{}:ffffff:1,{}:ffffff:1",
            threshold - 1e-3,
            threshold,
            volume.value_range[1]
        ))
        .expect("tf");
        let camera = Camera::default();
        let ray = PickRay {
            camera: &camera,
            width: 64,
            height: 64,
            x: 32.0,
            y: 32.0,
            clip: ClipBox::ALL,
        };
        let hit = Vec3::from(pick(&cache, &ray, &tf).expect("read").expect("a hit"));
        let mut reader = Reader::new(&cache, Fetch::Read, 0);
        let index = IndexMap::of(&cache.store().meta().geometry);
        let mut value = |p: Vec3| {
            let stored = reader
                .sample(0, index.index(p).expect("inside"))
                .expect("value");
            volume.value_map.physical(f64::from(stored)) as f32
        };
        assert!(value(hit) >= threshold, "{hit}: {}", value(hit));
        // From the front (−y): a step (half a voxel) nearer the eye is below it.
        assert!(value(hit - Vec3::Y * 0.5 * s) < threshold);
        assert!(
            hit.x.abs() < 1e-3 && hit.z.abs() < 1e-3 && hit.y < 0.0,
            "{hit}"
        );
    }

    fn probe_outside(cache: &BlockCache) -> bool {
        let above = 16.01 * spacing(cache);
        probe(cache, [0.0, 0.0, above]).expect("read").is_none()
    }

    fn spacing(cache: &BlockCache) -> f32 {
        cache.store().meta().geometry.min_spacing_f32()
    }
}
