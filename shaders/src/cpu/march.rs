//! CPU twin of `shaders/wgsl/shared/march.wgsl`: the ray march shared by the
//! `raycast` and `reference` twins, the shader's functions with its
//! arithmetic. Each twin supplies its voxel storage as a [`Storage`], the
//! counterpart of the functions a WGSL stage defines (`locate`, `sample_at`,
//! `sample_neighbour`, `light_at`, `empty_exit`). Where the GPU looks each
//! sample up, the CPU walks the block grid and takes the samples within a
//! block as a run, four at a time ([`Storage::sample4_in`], which drops
//! four samples the transfer function hides without reading them, and
//! [`Classes4`]), composited in order by the shader's loop body
//! (`Accumulator::add`).

use blocks::transfer_function::TABLE_LEN;
use glam::{Vec2, Vec3, Vec4, Vec4Swizzles};
use rayon::prelude::*;
use wide::{f32x4, i32x4};

use super::footprint::{Footprint, Reach};
use super::hash::{pcg_hash, unit_from_hash};
use super::occupancy::VisibleBox;
use super::ray_lanes::{RAY_LANES, RayStart};
use super::texture::{floor, round_down, split};
use crate::raycast::{
    FLAG_CUBIC_GRADIENT, FLAG_EXTINCTION, FLAG_JITTER, FLAG_LIT, FLAG_SHADED, FLAG_SKIP_EMPTY,
    MODE_COMPOSITE, MODE_MIP, RaycastParams, WORKGROUP_SIZE,
};

/// How far below `early_termination` a group of samples' opacity, found as
/// a product, must stay for all its lanes to be composited without the
/// chain of `Accumulator::add` (whose rounding moves it by far less).
const END_MARGIN: f32 = 1.0 / 65_536.0;

/// Largest opacity fed to the opacity correction (as in the shader).
pub const MAX_SAMPLE_OPACITY: f32 = 0.9999;

/// Where voxels come from: the stage-specific functions of the march.
pub trait Storage: Sync + Sized {
    /// Where a sample falls (WGSL `Location`).
    type Location: Copy;
    /// WGSL `locate`.
    fn locate(&self, p: &RaycastParams, tc: Vec3) -> Self::Location;
    /// CPU only: the stretch of the ray `origin + t·dir` from `t` on whose
    /// samples share one location (a block), found once for all of them
    /// where the GPU locates every sample; see [`Span`].
    fn span(&self, p: &RaycastParams, origin: Vec3, dir: Vec3, t: f32) -> Span<Self::Location>;
    /// CPU only: the stretch after `span` that holds the sample at `t`
    /// (`t ≥ span.exit`), found from `span` where the storage can walk to it.
    fn next_span(
        &self,
        p: &RaycastParams,
        origin: Vec3,
        dir: Vec3,
        span: &Span<Self::Location>,
        t: f32,
    ) -> Span<Self::Location> {
        let _ = span;
        self.span(p, origin, dir, t)
    }
    /// WGSL `sample_at` for the sample at `t` (at `tc`) in `span`.
    fn sample_in(&self, p: &RaycastParams, span: &Span<Self::Location>, t: f32, tc: Vec3) -> f32 {
        let _ = t;
        self.sample_at(p, tc, &span.loc)
    }
    /// CPU only: [`Storage::sample_in`] for the four samples at `ts` on the
    /// ray `origin + t·dir`, all in `span` (where lanes past the stretch's
    /// end read, they read something harmless; the march drops them), or
    /// `None` where the storage knows that with empty-space skipping the
    /// transfer function hides all four.
    #[inline(always)]
    fn sample4_in(
        &self,
        p: &RaycastParams,
        span: &Span<Self::Location>,
        ts: [f32; 4],
        origin: Vec3,
        dir: Vec3,
    ) -> Option<[f32; 4]> {
        Some(ts.map(|t| self.sample_in(p, span, t, origin + dir * t)))
    }
    /// WGSL `gradient_at` for the sample at `t` (at `tc`) in `span` of
    /// `weight` in its pixel.
    fn gradient_in(
        &self,
        p: &RaycastParams,
        span: &Span<Self::Location>,
        t: f32,
        tc: Vec3,
        weight: f32,
    ) -> Vec3 {
        let _ = t;
        gradient_at(self, p, tc, &span.loc, weight)
    }
    /// WGSL `Location.empty`.
    fn is_empty(loc: &Self::Location) -> bool;
    /// WGSL `sample_at`.
    fn sample_at(&self, p: &RaycastParams, tc: Vec3, loc: &Self::Location) -> f32;
    /// WGSL `voxel_edge`.
    fn voxel_edge(loc: &Self::Location) -> f32;
    /// WGSL `sample_neighbour`.
    fn sample_neighbour(&self, p: &RaycastParams, tc: Vec3, home: &Self::Location) -> f32;
    /// WGSL `nearest_difference_at`.
    fn nearest_difference_at(&self, p: &RaycastParams, tc: Vec3, loc: &Self::Location) -> Vec3;
    /// WGSL `light_at`: the stored light at `tc`, the ray's point at `t`
    /// (I_s of global light propagation, or the light cache's colour; 1
    /// where there is none), read from the sample's stretch `span` where
    /// the storage can.
    fn light_at(&self, p: &RaycastParams, span: &Span<Self::Location>, t: f32, tc: Vec3) -> Vec3;
    /// WGSL `empty_exit`.
    fn empty_exit(&self, p: &RaycastParams, origin: Vec3, dir: Vec3, loc: &Self::Location) -> f32;
    /// CPU only: with empty-space skipping, the box (`lo`, `hi` in texture
    /// coordinates) outside which no sample can be visible, where the
    /// storage knows one.
    fn visible_extent(&self, p: &RaycastParams) -> Option<(Vec3, Vec3)> {
        let _ = p;
        None
    }
    /// CPU only: with empty-space skipping, boxes in texture coordinates
    /// outside all of which no sample can be visible, where the storage
    /// knows them: the march leaves the rays that meet none as the
    /// background ([`Footprint`]).
    fn visible_cells(&self, p: &RaycastParams) -> Option<&[VisibleBox]> {
        let _ = p;
        None
    }
}

/// Where the samples of a stretch of a ray fall (the CPU's way of walking
/// the block grid: one lookup per block the ray crosses, not per sample).
#[derive(Debug, Clone, Copy)]
pub struct Span<L> {
    /// The location of every sample in the stretch.
    pub loc: L,
    /// The ray parameter where the stretch ends: samples at `t < exit` are
    /// in it (with empty-space skipping, the samples after it up to the
    /// next stretch are known to be invisible).
    pub exit: f32,
    /// Where it begins, with empty-space skipping: the samples before are
    /// known to be invisible (in empty blocks a walk of the block grid
    /// jumped, or outside what the storage knows may be visible); minus
    /// infinity otherwise.
    pub enter: f32,
    /// Storage-specific: the sample's texel position is `texel_at_zero + t·texel_per_t`.
    pub texel_at_zero: Vec3,
    /// See `texel_at_zero`.
    pub texel_per_t: Vec3,
    /// Storage-specific: the sample's position in level-0 voxels within its
    /// block is `local_at_zero + t·local_per_t`.
    pub local_at_zero: Vec3,
    /// See `local_at_zero`.
    pub local_per_t: Vec3,
    /// Storage-specific (a walk of the block grid): the ray parameter where
    /// the ray crosses the stretch's next boundary along x, y and z.
    pub t_max: Vec3,
}

/// The largest sample index a run of samples starts at: its four lanes'
/// indices are whole numbers as `i32` (they convert to floats as the
/// shader's `u32`s do). A ray that got this far has long left the volume
/// (its samples' positions stopped being distinct floats at 2²⁴).
const MAX_RUN_INDEX: u32 = i32::MAX as u32 - 4;

/// Columns of a tile of pixels, which a task renders row by row:
/// neighbouring rays read the same voxels, so a tile's rays find them in cache.
const TILE: usize = WORKGROUP_SIZE as usize;

// A tile's row of pixels is one set of rays found side by side.
const _: () = assert!(TILE == RAY_LANES);

/// Rows of pixels a task of the march renders, tile by tile: half a tile's
/// width, which leaves the cores less of a frame's end to wait for than
/// whole tiles did (ten alternating runs, composite: means of the ratios
/// to VTK 0.511 → 0.506 on the engine, 0.485 → 0.478 on the CT head).
const BAND_ROWS: usize = 4;

/// The instructions the march is compiled for. The same source either way,
/// with the same arithmetic in the same order (Rust never fuses a multiply
/// and an add by itself), so the same bytes: x86-64-v3 adds AVX2, FMA, BMI
/// and SSE4.1's rounding, which turns `floor` from a call into the C
/// library into one instruction and shortens the vector code.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Isa {
    /// What the binary is built for (x86-64: SSE2).
    Baseline,
    /// x86-64-v3, where this processor has it (found at run time).
    X86_64V3,
}

impl Isa {
    /// The best this processor runs.
    pub fn best() -> Isa {
        if Isa::X86_64V3.is_supported() {
            Isa::X86_64V3
        } else {
            Isa::Baseline
        }
    }

    /// Its name, as benchmarks report it.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline instructions",
            Isa::X86_64V3 => "x86-64-v3",
        }
    }

    /// Whether this processor runs code built for `self`.
    pub fn is_supported(self) -> bool {
        match self {
            Isa::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            Isa::X86_64V3 => {
                std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                    && std::arch::is_x86_feature_detected!("bmi1")
                    && std::arch::is_x86_feature_detected!("bmi2")
                    && std::arch::is_x86_feature_detected!("lzcnt")
                    && std::arch::is_x86_feature_detected!("f16c")
                    && std::arch::is_x86_feature_detected!("movbe")
                    && std::arch::is_x86_feature_detected!("popcnt")
            }
            #[cfg(not(target_arch = "x86_64"))]
            Isa::X86_64V3 => false,
        }
    }
}

/// Renders into `output` (RGBA8, `params.width * params.height * 4` bytes) as the
/// GPU dispatch does: one call of `main` per invocation, bands of rows in
/// parallel, tile by tile within a band; with the best instructions this
/// processor has ([`Isa::best`]).
pub fn march<S: Storage>(
    params: &RaycastParams,
    storage: &S,
    transfer_function: &TfTable,
    output: &mut [u8],
) {
    march_on(Isa::best(), params, storage, transfer_function, output);
}

/// [`march`] with the code built for `isa`; the baseline's where this
/// processor does not run it.
pub fn march_on<S: Storage>(
    isa: Isa,
    params: &RaycastParams,
    storage: &S,
    transfer_function: &TfTable,
    output: &mut [u8],
) {
    match kind_of(params) {
        PLAIN => march_as::<S, PLAIN>(isa, params, storage, transfer_function, output),
        _ => march_as::<S, ANY>(isa, params, storage, transfer_function, output),
    }
}

/// What a build of the march serves (its `KIND`): any parameters, or
/// plain compositing, where the branches for shading, stored light and
/// extinction fold away and the loop keeps its variables in registers (a
/// build for compositing with gradient shading measured no faster).
const ANY: u8 = 0;
/// Compositing without shading, stored light or extinction.
const PLAIN: u8 = 1;

/// The build of the march for `p`.
fn kind_of(p: &RaycastParams) -> u8 {
    if p.mode == MODE_COMPOSITE && p.flags & (FLAG_SHADED | FLAG_LIT | FLAG_EXTINCTION) == 0 {
        PLAIN
    } else {
        ANY
    }
}

/// [`march_on`] built for parameters of kind `KIND` ([`kind_of`]).
fn march_as<S: Storage, const KIND: u8>(
    isa: Isa,
    params: &RaycastParams,
    storage: &S,
    transfer_function: &TfTable,
    output: &mut [u8],
) {
    let width = params.width as usize;
    let v3 = isa == Isa::X86_64V3 && isa.is_supported();
    let footprint = storage
        .visible_cells(params)
        .and_then(|cells| Footprint::new(params, cells));
    let footprint = footprint.as_ref();
    output
        .par_chunks_mut(width * 4 * BAND_ROWS)
        .enumerate()
        .for_each(|(band, rows)| {
            #[cfg(target_arch = "x86_64")]
            if v3 {
                #[expect(
                    unsafe_code,
                    reason = "a function built for features found at run time"
                )]
                // SAFETY: this processor has every feature the function is
                // built with (`Isa::is_supported`).
                unsafe {
                    march_band_v3::<S, KIND>(
                        params,
                        storage,
                        transfer_function,
                        footprint,
                        band,
                        rows,
                    );
                };
                return;
            }
            let _ = v3;
            march_band::<S, KIND>(params, storage, transfer_function, footprint, band, rows);
        });
}

/// [`march_band`] built for x86-64-v3.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,avx2,fma,bmi1,bmi2,lzcnt,f16c,movbe,popcnt,sse4.1,sse4.2")]
#[inline(never)]
fn march_band_v3<S: Storage, const KIND: u8>(
    params: &RaycastParams,
    storage: &S,
    transfer_function: &TfTable,
    footprint: Option<&Footprint>,
    band: usize,
    rows: &mut [u8],
) {
    march_band_body::<S, KIND>(params, storage, transfer_function, footprint, band, rows);
}

/// One band of rows of [`march`], tile by tile.
#[inline(never)]
fn march_band<S: Storage, const KIND: u8>(
    params: &RaycastParams,
    storage: &S,
    transfer_function: &TfTable,
    footprint: Option<&Footprint>,
    band: usize,
    rows: &mut [u8],
) {
    march_band_body::<S, KIND>(params, storage, transfer_function, footprint, band, rows);
}

/// The body of [`march_band`], inlined into each build of it.
#[inline(always)]
fn march_band_body<S: Storage, const KIND: u8>(
    params: &RaycastParams,
    storage: &S,
    transfer_function: &TfTable,
    footprint: Option<&Footprint>,
    band: usize,
    rows: &mut [u8],
) {
    let width = params.width as usize;
    let height = rows.len() / (width * 4);
    let extent = storage.visible_extent(params);
    // The pixel of a ray that meets nothing, found once.
    let background = pixel(params, &Accumulator::default());
    for x0 in (0..width).step_by(TILE) {
        for dy in 0..height {
            let y = (band * BAND_ROWS + dy) as u32;
            if y >= params.height {
                continue;
            }
            let row = y + params.first_row;
            // A ray no visible box's projection covers meets no sample
            // that can be visible: it is left unmarched, and not found.
            let reaches: [Reach; RAY_LANES] = std::array::from_fn(|j| {
                let x = x0 + j;
                if x >= width {
                    return Reach::NONE;
                }
                footprint.map_or(Reach::ALL, |f| f.reach(x as u32, row))
            });
            let met = reaches.map(Reach::met);
            let starts = met
                .contains(&true)
                .then(|| RayStart::lanes(params, extent, x0 as u32, row, &reaches));
            for (j, met) in met.into_iter().enumerate() {
                let x = x0 + j;
                if x >= width {
                    break;
                }
                let rgba = match &starts {
                    Some(starts) if met => main::<S, KIND>(
                        params,
                        storage,
                        transfer_function,
                        [x as u32, y],
                        &starts[j],
                    ),
                    _ => background,
                };
                let at = (dy * width + x) * 4;
                rows[at..at + 4].copy_from_slice(&rgba);
            }
        }
    }
}

/// WGSL `classify` (`shared/transfer_function.wgsl`), for a table of `tf_len` entries.
pub fn classify_table(tf_len: u32, transfer_function: &[[f32; 4]], u: f32) -> Vec4 {
    let n = tf_len as i32;
    let (i0, f) = table_position(tf_len, u);
    let a = Vec4::from(transfer_function[i0.clamp(0, n - 1) as usize]);
    let b = Vec4::from(transfer_function[(i0 + 1).clamp(0, n - 1) as usize]);
    a.lerp(b, f)
}

/// Where [`classify`] reads the table for four values at once: the table
/// positions side by side (the same arithmetic as [`table_position`], so
/// the same classes), the opacities first and the whole class of a lane
/// only where needed.
#[derive(Debug, Clone, Copy)]
pub struct Classes4 {
    lower: [i32; 4],
    upper: [i32; 4],
    fraction: [f32; 4],
}

impl Classes4 {
    /// The table positions of `us` in a table of `p.volume.tf_len` entries.
    #[inline(always)]
    pub fn new(p: &RaycastParams, us: [f32; 4]) -> Self {
        Self::in_table(p.volume.tf_len, us)
    }

    /// The table positions of `us` in a table of `n` entries.
    #[inline(always)]
    pub fn in_table(n: u32, us: [f32; 4]) -> Self {
        let x = f32x4::from(us).fast_max(f32x4::ZERO).fast_min(f32x4::ONE) * f32x4::splat(n as f32)
            - f32x4::splat(0.5);
        let whole = round_down(x);
        let last = i32x4::splat(n as i32 - 1);
        let i0 = whole.fast_trunc_int();
        Self {
            lower: i0.max(i32x4::ZERO).min(last).to_array(),
            upper: (i0 + i32x4::ONE).max(i32x4::ZERO).min(last).to_array(),
            fraction: (x - whole).to_array(),
        }
    }

    /// The four opacities, as [`Classes4::rgba`] has them (`Vec4::lerp`'s
    /// arithmetic lane by lane).
    #[inline(always)]
    pub fn opacity(&self, transfer_function: &TfTable) -> f32x4 {
        let at = |i: [i32; 4]| f32x4::from(i.map(|i| entry(transfer_function, i)[3]));
        let s = f32x4::from(self.fraction);
        at(self.lower) * (f32x4::ONE - s) + at(self.upper) * s
    }

    /// Lane `j`'s class.
    #[inline(always)]
    pub fn rgba(&self, transfer_function: &TfTable, j: usize) -> Vec4 {
        // A lane is below 4: the mask spares the bounds checks.
        let j = j & 3;
        let a = Vec4::from(entry(transfer_function, self.lower[j]));
        let b = Vec4::from(entry(transfer_function, self.upper[j]));
        a.lerp(b, self.fraction[j])
    }
}

/// The transfer function's table as the march reads it: `TABLE_LEN`
/// entries (what every renderer builds, and `p.volume.tf_len` then), so
/// that a table position is known to be in it once masked to that power of
/// two ([`entry`]), with no bounds check per read.
pub type TfTable = [[f32; 4]; TABLE_LEN];

const _: () = assert!(TABLE_LEN.is_power_of_two());

/// Entry `i` of `table`, for `i` in `0..TABLE_LEN` ([`Classes4::new`]
/// clamps its positions to the table): the mask leaves such an `i` as it
/// is and spares the bounds check.
#[inline(always)]
fn entry(table: &TfTable, i: i32) -> [f32; 4] {
    table[i as usize & (TABLE_LEN - 1)]
}

/// Where `classify` reads a table of `tf_len` entries for `u`: it blends
/// entry `i` (clamped to the table) and the next by the fraction returned.
#[inline]
pub fn table_position(tf_len: u32, u: f32) -> (i32, f32) {
    // floor(x) and x − floor(x) (or one less and 1, which blends alike).
    split(u.clamp(0.0, 1.0) * tf_len as f32 - 0.5)
}

/// WGSL `classify`.
pub fn classify(p: &RaycastParams, transfer_function: &[[f32; 4]], u: f32) -> Vec4 {
    classify_table(p.volume.tf_len, transfer_function, u)
}

/// [`corrected_opacity`] of four opacities, lane by lane with its arithmetic
/// (the square root, like the scalar one, is correctly rounded).
#[inline(always)]
pub fn corrected_opacity4(a: f32x4, exponent: f32) -> f32x4 {
    let transmittance = f32x4::ONE - a.fast_min(f32x4::splat(MAX_SAMPLE_OPACITY));
    if exponent == 1.0 {
        return f32x4::ONE - transmittance;
    }
    if exponent == 0.5 {
        return f32x4::ONE - transmittance.sqrt();
    }
    f32x4::from(a.to_array().map(|a| corrected_opacity(a, exponent)))
}

/// WGSL `corrected_opacity`.
pub fn corrected_opacity(a: f32, exponent: f32) -> f32 {
    let transmittance = 1.0 - a.min(MAX_SAMPLE_OPACITY);
    // The common steps without a call into the C library: 1 and ½ of the
    // reference step (powf(x, 0.5) is sqrt(x), both correctly rounded).
    if exponent == 1.0 {
        return 1.0 - transmittance;
    }
    if exponent == 0.5 {
        return 1.0 - transmittance.sqrt();
    }
    1.0 - transmittance.powf(exponent)
}

/// WGSL `faint`.
#[inline(always)]
pub fn faint(p: &RaycastParams, weight: f32) -> bool {
    weight < p.faint_weight
}

/// WGSL `gradient_at`.
pub fn gradient_at<S: Storage>(
    s: &S,
    p: &RaycastParams,
    tc: Vec3,
    loc: &S::Location,
    weight: f32,
) -> Vec3 {
    if faint(p, weight) {
        return s.nearest_difference_at(p, tc, loc);
    }
    if p.flags & FLAG_CUBIC_GRADIENT != 0 {
        return cubic_gradient_at(s, p, tc, loc);
    }
    central_difference_at(s, p, tc, loc)
}

/// WGSL `central_difference_at`.
pub fn central_difference_at<S: Storage>(
    s: &S,
    p: &RaycastParams,
    tc: Vec3,
    loc: &S::Location,
) -> Vec3 {
    let h = Vec3::from(p.volume.texel);
    let dx = Vec3::new(h.x, 0.0, 0.0);
    let dy = Vec3::new(0.0, h.y, 0.0);
    let dz = Vec3::new(0.0, 0.0, h.z);
    let differences = Vec3::new(
        s.sample_neighbour(p, tc + dx, loc) - s.sample_neighbour(p, tc - dx, loc),
        s.sample_neighbour(p, tc + dy, loc) - s.sample_neighbour(p, tc - dy, loc),
        s.sample_neighbour(p, tc + dz, loc) - s.sample_neighbour(p, tc - dz, loc),
    );
    differences / (2.0 * h)
}

/// The reads of WGSL `cubic_gradient_at` about a sample at `x` in voxels of
/// its level (voxel centres at whole `x`), per axis: where the trilinear
/// reads go and how they are weighed.
#[derive(Debug, Clone, Copy)]
pub struct CubicReads {
    /// The smoothing reads' positions (`p0`, `p1`), in the level's voxels.
    pub smooth_at: [Vec3; 2],
    /// Their weights (`s0`, `s1`).
    pub smooth: [Vec3; 2],
    /// The derivative's reads' positions (`q0`, `q1`), weighed −`e` and `e`.
    pub derivative_at: [Vec3; 2],
    /// `e`.
    pub e: Vec3,
}

impl CubicReads {
    /// The reads about `x` (WGSL `cubic_gradient_at`'s weights).
    #[inline(always)]
    pub fn at(x: Vec3) -> CubicReads {
        let i = x.floor();
        let a = x - i;
        let b = Vec3::ONE - a;
        let w0 = b * b * b / 6.0;
        let w1 = (3.0 * a * a * a - 6.0 * a * a + Vec3::splat(4.0)) / 6.0;
        let w3 = a * a * a / 6.0;
        let w2 = Vec3::ONE - w0 - w1 - w3;
        let d1 = a * (1.5 * a - Vec3::splat(2.0));
        let d3 = 0.5 * a * a;
        let e = Vec3::splat(0.5) + a * b;
        let s0 = w0 + w1;
        let s1 = w2 + w3;
        CubicReads {
            smooth_at: [i - Vec3::ONE + w1 / s0, i + Vec3::ONE + w3 / s1],
            smooth: [s0, s1],
            derivative_at: [i - Vec3::ONE - d1 / e, i + Vec3::ONE + d3 / e],
            e,
        }
    }

    /// The B-spline's derivative along each axis per voxel of the level,
    /// from `read` (the trilinear reconstruction at a position in the
    /// level's voxels), in the shader's order.
    #[inline(always)]
    pub fn gradient(&self, mut read: impl FnMut(Vec3) -> f32) -> Vec3 {
        let [p0, p1] = self.smooth_at;
        let [s0, s1] = self.smooth;
        let [q0, q1] = self.derivative_at;
        let mut g = Vec3::ZERO;
        for k in 0..4u32 {
            let first = k & 1 != 0;
            let second = k & 2 != 0;
            let pick = |on: bool, a: Vec3, b: Vec3| if on { b } else { a };
            let (x1, wx1) = (pick(first, p0, p1).x, pick(first, s0, s1).x);
            let (y1, wy1) = (pick(first, p0, p1).y, pick(first, s0, s1).y);
            let (y2, wy2) = (pick(second, p0, p1).y, pick(second, s0, s1).y);
            let (z2, wz2) = (pick(second, p0, p1).z, pick(second, s0, s1).z);
            g.x += wy1 * wz2 * (read(Vec3::new(q1.x, y1, z2)) - read(Vec3::new(q0.x, y1, z2)));
            g.y += wx1 * wz2 * (read(Vec3::new(x1, q1.y, z2)) - read(Vec3::new(x1, q0.y, z2)));
            g.z += wx1 * wy2 * (read(Vec3::new(x1, y2, q1.z)) - read(Vec3::new(x1, y2, q0.z)));
        }
        g * self.e
    }
}

/// WGSL `cubic_gradient_at`.
pub fn cubic_gradient_at<S: Storage>(
    s: &S,
    p: &RaycastParams,
    tc: Vec3,
    loc: &S::Location,
) -> Vec3 {
    let h = Vec3::from(p.volume.texel) * S::voxel_edge(loc);
    let reads = CubicReads::at(tc / h - Vec3::splat(0.5));
    reads.gradient(|x| s.sample_neighbour(p, (x + Vec3::splat(0.5)) * h, loc)) / h
}

/// WGSL `shade` for four samples side by side, for a ray whose
/// [`half_vector`] is `h`: lane by lane the arithmetic of one sample
/// (colours `rgb` and gradients `g` per axis, a lane per sample).
#[inline(always)]
fn shade(p: &RaycastParams, rgb: [f32x4; 3], g: [f32x4; 3], h: Vec3) -> [f32x4; 3] {
    let [gx, gy, gz] = g;
    let magnitude = (gx * gx + gy * gy + gz * gz).sqrt();
    let flat = magnitude.simd_lt(f32x4::splat(p.gradient_threshold));
    // One division, not three.
    let recip = f32x4::ONE / magnitude;
    let [nx, ny, nz] = [gx * recip, gy * recip, gz * recip];
    let dot = |v: [f32; 3]| nx * v[0] + ny * v[1] + nz * v[2];
    let diffuse = dot(p.light_dir).abs();
    let specular = pow4(dot(h.to_array()).abs(), p.phong[3]);
    let [ambient, kd, ks, _] = p.phong;
    let factor = f32x4::splat(ambient) + f32x4::splat(kd) * diffuse;
    let highlight = f32x4::splat(ks) * specular;
    rgb.map(|c| flat.select(c, c * factor + highlight))
}

/// The shown lanes of a group of four samples (bit `j` for lane `j`) and
/// where they lie: the ray parameters `ts` along `tex_origin + t·tex_dir`.
struct Shown {
    lanes: u32,
    /// The shown lanes' weights in the pixel (WGSL `main`'s `weight`) as far
    /// as the march reads them (whether each is `faint`: see [`weights`]),
    /// found for shaded samples (zero otherwise).
    weights: [f32; 4],
    ts: [f32; 4],
    tex_origin: Vec3,
    tex_dir: Vec3,
}

/// Of the `showing` lanes (a mask), those composited before the ray ends,
/// for a ray whose opacity so far is `alpha`: `Accumulator::add`'s opacity
/// after each (compositing without extinction, the lanes' corrected
/// opacities `corrected`), up to the first at or above `early_termination`.
/// Where the opacity after the whole group (one minus the product of the
/// transparencies, within rounding of `add`'s chain) stays `END_MARGIN`
/// below the end, that is every showing lane, found without the chain.
#[inline(always)]
fn composited_lanes(showing: f32x4, mut alpha: f32, corrected: f32x4, p: &RaycastParams) -> u32 {
    let shown = showing.to_bitmask();
    let [a, b, c, d] = showing
        .select(f32x4::ONE - corrected, f32x4::ONE)
        .to_array();
    let corrected = corrected.to_array();
    let after = 1.0 - (1.0 - alpha) * ((a * b) * (c * d));
    if after < p.early_termination - END_MARGIN {
        return shown;
    }
    let mut kept = 0;
    for j in Lanes(shown) {
        kept |= 1 << j;
        alpha += (1.0 - alpha) * corrected[j];
        if alpha >= p.early_termination {
            break;
        }
    }
    kept
}

/// WGSL `main`'s `weight` of each of the `shown` lanes (a bit each), for a
/// ray whose opacity so far is `alpha`, as far as the march reads it
/// (whether it is `faint`): its transparency before the lane times the
/// lane's class opacity (`opacity`), the opacity after each lane found
/// from its corrected opacity as `Accumulator::add` composites it (with
/// extinction, 1 − exp(−Σ Δt·τ) is the same up to rounding). A lane's
/// weight is at most the transparency before the group times its opacity
/// (the opacity only grows, rounding too): where that bound is faint for
/// every shown lane, so is each weight, and the bounds stand for them,
/// found without the chain.
#[inline(always)]
fn weights(
    p: &RaycastParams,
    shown: u32,
    mut alpha: f32,
    opacity: &f32x4,
    corrected: &[f32; 4],
) -> [f32; 4] {
    let bound = f32x4::splat(1.0 - alpha) * *opacity;
    if shown & !bound.simd_lt(f32x4::splat(p.faint_weight)).to_bitmask() == 0 {
        return bound.to_array();
    }
    let opacity = opacity.to_array();
    let mut weights = [0.0; 4];
    for j in Lanes(shown) {
        weights[j] = (1.0 - alpha) * opacity[j];
        alpha += (1.0 - alpha) * corrected[j].min(MAX_SAMPLE_OPACITY);
    }
    weights
}

/// The lanes set in a mask (a bit each, bit `j` for lane `j`), in order.
/// An iterator, not a function taking a closure: a closure the compiler
/// does not inline is compiled apart from the march, without the
/// instructions `march_band_v3` is built for.
struct Lanes(u32);

impl Iterator for Lanes {
    type Item = usize;

    #[inline(always)]
    fn next(&mut self) -> Option<usize> {
        if self.0 == 0 {
            return None;
        }
        let j = self.0.trailing_zeros() as usize;
        self.0 &= self.0 - 1;
        Some(j)
    }
}

/// The body of WGSL `main`'s loop from the gradient to the light (eq.
/// 12), for the shown samples of a group of four in `span` at once, each
/// lane the shader's arithmetic for one sample: with [`FLAG_SHADED`] their
/// gradients (in the model's frame) and then their shading side by side,
/// with [`FLAG_LIT`] the light each is lit by. `rgbas`' colours are
/// replaced by the results (the lanes not shown are left as they are).
/// Done before the samples are composited (which depends on the samples
/// before), the four samples' reads overlap.
#[inline(always)]
fn colour_shown<S: Storage>(
    p: &RaycastParams,
    s: &S,
    span: &Span<S::Location>,
    shown: &Shown,
    half: Vec3,
    rgbas: &mut [Vec4; 4],
) {
    if p.flags & FLAG_SHADED != 0 {
        let mut g = [[0.0f32; 4]; 3];
        for j in Lanes(shown.lanes) {
            let t = shown.ts[j];
            let tc = shown.tex_origin + shown.tex_dir * t;
            let weight = shown.weights[j];
            let gradient =
                (p.gradient_from_texture * s.gradient_in(p, span, t, tc, weight).extend(0.0)).xyz()
                    * p.volume.value_scale;
            for (axis, lanes) in g.iter_mut().enumerate() {
                lanes[j] = gradient[axis];
            }
        }
        let channel = |c: usize| f32x4::from(rgbas.map(|v| v[c]));
        let shaded = shade(
            p,
            [channel(0), channel(1), channel(2)],
            g.map(f32x4::from),
            half,
        )
        .map(f32x4::to_array);
        for j in Lanes(shown.lanes) {
            rgbas[j] = Vec4::new(shaded[0][j], shaded[1][j], shaded[2][j], rgbas[j].w);
        }
    }
    if p.flags & FLAG_LIT != 0 {
        for j in Lanes(shown.lanes) {
            rgbas[j] = lit(p, s, span, shown.ts[j], shown, rgbas[j]);
        }
    }
}

/// Eq. 12, g_k = (I_bias + (1 − I_bias)·I_s)·c·α with coloured light: the
/// colour `rgba` of the sample at `t` on `shown`'s ray in `span`, lit by the
/// light read `light_offset` back along the ray.
#[inline(always)]
fn lit<S: Storage>(
    p: &RaycastParams,
    s: &S,
    span: &Span<S::Location>,
    t: f32,
    ray: &Shown,
    rgba: Vec4,
) -> Vec4 {
    let bias = p.light[3];
    let colour = Vec3::new(p.light[0], p.light[1], p.light[2]);
    let t_light = t - p.light_offset;
    let light = s.light_at(p, span, t_light, ray.tex_origin + ray.tex_dir * t_light);
    (rgba.xyz() * (Vec3::splat(bias) + (1.0 - bias) * colour * light)).extend(rgba.w)
}

/// WGSL `shade`'s half vector between the light and the eye for a ray
/// along `view_dir` (CPU only: found once per ray, not per sample).
fn half_vector(p: &RaycastParams, view_dir: Vec3) -> Vec3 {
    (Vec3::from(p.light_dir) - view_dir).normalize()
}

/// WGSL `window_grey`.
fn window_grey(p: &RaycastParams, u: f32) -> f32 {
    ((u - p.window[0]) / p.window[1]).clamp(0.0, 1.0)
}

/// WGSL `pow(x, e)` for `x ≥ 0`, four at once: by squaring where `e` is a
/// whole number up to 64 (shininess is), without a call into the C library
/// (each squaring doubles the relative error so far: at most 2⁻¹⁸ for e ≤
/// 64, far below an 8-bit colour step); `powf` lane by lane otherwise.
#[inline]
fn pow4(x: f32x4, e: f32) -> f32x4 {
    let whole = e as u32;
    if whole as f32 != e || whole > 64 {
        return f32x4::from(x.to_array().map(|x| x.powf(e)));
    }
    let (mut n, mut square, mut power) = (whole, x, f32x4::ONE);
    while n > 0 {
        if n & 1 == 1 {
            power *= square;
        }
        square *= square;
        n >>= 1;
    }
    power
}

/// CPU only: per axis, the ray parameter where the ray `origin + t·dir`
/// crosses the far face (in its direction of travel) of the grid cell
/// `cell` of a grid with cells `edge` wide; infinity along axes it does not
/// move along. The walks of the block grid use it.
#[inline]
pub fn far_face_crossing(cell: Vec3, edge: Vec3, origin: Vec3, dir: Vec3) -> Vec3 {
    let ahead = Vec3::select(dir.cmpgt(Vec3::ZERO), Vec3::ONE, Vec3::ZERO);
    let face = (cell + ahead) * edge;
    Vec3::select(
        dir.abs().cmplt(Vec3::splat(TINY_DIRECTION)),
        Vec3::INFINITY,
        (face - origin) / dir,
    )
}

/// WGSL `intersect_box`.
pub fn intersect_box(origin: Vec3, dir: Vec3, lo: Vec3, hi: Vec3) -> Vec2 {
    intersect_box_inverse(origin, inverse_direction(dir), lo, hi)
}

/// A direction's component below which WGSL `intersect_box` takes it as
/// this (`ray.wgsl`'s `1e-12`), and the walks of the block grid as no
/// movement along its axis.
pub const TINY_DIRECTION: f32 = 1e-12;

/// The reciprocal of `dir` as WGSL `intersect_box` takes it (CPU only:
/// found once per ray for many boxes).
#[inline]
pub fn inverse_direction(dir: Vec3) -> Vec3 {
    let tiny = dir.abs().cmplt(Vec3::splat(TINY_DIRECTION));
    let safe_dir = Vec3::select(tiny, Vec3::splat(TINY_DIRECTION), dir);
    1.0 / safe_dir
}

/// WGSL `intersect_box` for the ray whose direction's
/// [`inverse_direction`] is `inv`.
#[inline]
pub fn intersect_box_inverse(origin: Vec3, inv: Vec3, lo: Vec3, hi: Vec3) -> Vec2 {
    let t0 = (lo - origin) * inv;
    let t1 = (hi - origin) * inv;
    let near = t0.min(t1);
    let far = t0.max(t1);
    let enter = near.x.max(near.y).max(near.z.max(0.0));
    let exit = far.x.min(far.y).min(far.z);
    Vec2::new(enter, exit)
}

/// A sample on a ray: its normalised value, its class's colour (shaded and
/// lit where the flags ask) and opacity, and that opacity corrected for the
/// step (`corrected_opacity`).
#[derive(Debug, Clone, Copy)]
struct Sample {
    u: f32,
    rgba: Vec4,
    a: f32,
}

/// What a ray has gathered so far: the variables of WGSL `main`'s loop.
#[derive(Debug, Default)]
struct Accumulator {
    /// The opacity correction's exponent (step over reference step).
    exponent: f32,
    color: Vec3,
    alpha: f32,
    /// Σ Δt·τ so far (extinction compositing).
    depth: f32,
    /// The ray's [`half_vector`] (gradient shading).
    half: Vec3,
    found: bool,
    extreme: f32,
}

impl Accumulator {
    /// The body of WGSL `main`'s loop after the light (eq. 12): the
    /// sample composited, or kept as the extreme value; true when the ray
    /// is done (early ray termination).
    #[inline(always)]
    fn add<const KIND: u8>(&mut self, p: &RaycastParams, sample: Sample) -> bool {
        let Sample { u, rgba, a } = sample;
        if rgba.w <= 0.0 {
            return false;
        }
        if KIND == ANY && p.mode != MODE_COMPOSITE {
            if !self.found {
                self.extreme = u;
                self.found = true;
            } else if p.mode == MODE_MIP {
                self.extreme = self.extreme.max(u);
            } else {
                self.extreme = self.extreme.min(u);
            }
            return false;
        }
        // Shaded and lit already where the flags ask (`colour_shown`).
        let rgb = rgba.xyz();
        if KIND == ANY && p.flags & FLAG_EXTINCTION != 0 {
            // Eq. 2 (Schlegel et al.): E_i·Δt·τ_i·exp(−Σ_{j≤i} Δt·τ_j).
            let dtau = -(1.0 - a.min(MAX_SAMPLE_OPACITY)).ln();
            self.depth += dtau;
            self.color += (-self.depth).exp() * dtau * rgb;
            self.alpha = 1.0 - (-self.depth).exp();
        } else {
            return self.add_shown(p, rgb, a);
        }
        self.alpha >= p.early_termination
    }

    /// [`Accumulator::add`] of a shown sample of colour `rgb` and corrected
    /// opacity `a`, composited without extinction.
    #[inline(always)]
    fn add_shown(&mut self, p: &RaycastParams, rgb: Vec3, a: f32) -> bool {
        self.color += (1.0 - self.alpha) * a * rgb;
        self.alpha += (1.0 - self.alpha) * a;
        self.alpha >= p.early_termination
    }
}

/// The centre of pixel `x` of image row `row` in NDC, as WGSL `main` finds
/// it (CPU only: [`PixelRay::new`]).
#[inline(always)]
pub(super) fn pixel_ndc(p: &RaycastParams, x: u32, row: u32) -> Vec2 {
    let pixel = Vec2::new(x as f32 + 0.5, row as f32 + 0.5);
    Vec2::new(
        pixel.x / p.width as f32 * 2.0 - 1.0,
        1.0 - pixel.y / p.image_height as f32 * 2.0,
    )
}

/// [`pixel_ndc`] inverted: the image position (x, row) whose pixel centre
/// lies at `ndc` (pixel centres at whole numbers).
#[inline]
pub(super) fn ndc_pixel(p: &RaycastParams, ndc: Vec2) -> Vec2 {
    Vec2::new(
        (ndc.x + 1.0) * 0.5 * p.width as f32 - 0.5,
        (1.0 - ndc.y) * 0.5 * p.image_height as f32 - 0.5,
    )
}

/// The ray WGSL `main` casts through a pixel (CPU only: its first lines).
#[derive(Debug, Clone, Copy)]
pub(super) struct PixelRay {
    /// Where the ray leaves the near plane (NDC depth 0), in model space,
    /// as homogeneous coordinates.
    pub near_h: Vec4,
    /// Where it meets the far plane (NDC depth 1), the same way.
    pub far_h: Vec4,
    /// `near_h` as a point.
    pub origin: Vec3,
    /// `far_h` as a point.
    pub far: Vec3,
    /// Its direction, of unit length: `t` counts mm of model space.
    pub dir: Vec3,
}

impl PixelRay {
    /// The ray through pixel `x` of image row `row`, from the near plane to
    /// the far plane (right for perspective and orthographic projections
    /// alike).
    #[inline(always)]
    pub(super) fn new(p: &RaycastParams, x: u32, row: u32) -> PixelRay {
        let ndc = pixel_ndc(p, x, row);
        let inv_view_proj = p.inv_view_proj;
        let near_h = inv_view_proj * Vec4::new(ndc.x, ndc.y, 0.0, 1.0);
        let far_h = inv_view_proj * Vec4::new(ndc.x, ndc.y, 1.0, 1.0);
        let origin = near_h.xyz() / near_h.w;
        let far = far_h.xyz() / far_h.w;
        let dir = (far - origin).normalize();
        PixelRay {
            near_h,
            far_h,
            origin,
            far,
            dir,
        }
    }

    /// The same ray in texture space (`t` still counts mm of model space).
    #[inline(always)]
    pub(super) fn in_texture(&self, p: &RaycastParams) -> (Vec3, Vec3) {
        let texture_from_model = p.texture_from_model;
        (
            (texture_from_model * self.origin.extend(1.0)).xyz(),
            (texture_from_model * self.dir.extend(0.0)).xyz(),
        )
    }

    /// The stretch of the ray (its `t`) within the depths `reach`: wider by
    /// [`REACH_MARGIN`] of its length, and unbounded on a side whose depth
    /// is infinite or at or past the far plane (where NDC z stops following
    /// the depth).
    #[inline(always)]
    pub(super) fn within(&self, reach: Reach) -> Vec2 {
        let mut range = Vec2::new(f32::NEG_INFINITY, f32::INFINITY);
        let bounded = |z: f32| z.is_finite() && z < 1.0;
        if !(bounded(reach.lo) || bounded(reach.hi)) {
            return range;
        }
        let margin = REACH_MARGIN * (self.far - self.origin).length();
        // The point of NDC depth z lies on the ray: t is its distance. Its
        // homogeneous coordinates are affine in z (the inverse projection
        // is linear), so they blend the near and far planes' points.
        let t_at = |z: f32| {
            let q = self.near_h * (1.0 - z) + self.far_h * z;
            (q.xyz() / q.w - self.origin).dot(self.dir)
        };
        if bounded(reach.lo) {
            let t = t_at(reach.lo) - margin;
            if t.is_finite() {
                range.x = t;
            }
        }
        if bounded(reach.hi) {
            let t = t_at(reach.hi) + margin;
            if t.is_finite() {
                range.y = t;
            }
        }
        range
    }
}

/// How far past the depths of the boxes a ray may meet it is marched, as a
/// share of its length from the near to the far plane: far more than the
/// rounding of the depths and of their unprojection.
pub(super) const REACH_MARGIN: f32 = 1e-3;

/// WGSL `main` for the pixel at `gid`, whose ray starts as `start` finds
/// it ([`RayStart`]). CPU only: a ray is marched only within the reach of
/// the boxes of [`Storage::visible_cells`] (`start.seen`), and not at all
/// where it meets none (the caller draws the background there).
#[inline(always)]
fn main<S: Storage, const KIND: u8>(
    p: &RaycastParams,
    s: &S,
    tf: &TfTable,
    gid: [u32; 2],
    start: &RayStart,
) -> [u8; 4] {
    // Rows count in the whole image: a band is drawn as that part of it.
    let row = gid[1] + p.first_row;
    let RayStart {
        dir,
        tex_origin,
        tex_dir,
        span,
        seen,
    } = *start;
    let mut acc = Accumulator::default();
    if span.x < span.y && seen.x < seen.y {
        let mut jitter = 0.0;
        if p.flags & FLAG_JITTER != 0 {
            jitter = unit_from_hash(pcg_hash(row * p.width + gid[0]));
        }
        acc.exponent = p.step / p.volume.reference_step;
        if KIND == ANY && p.flags & FLAG_SHADED != 0 {
            acc.half = half_vector(p, dir);
        }
        let first = span.x + jitter * p.step;
        let inverse_step = 1.0 / p.step;
        // The first sample at or after `seen.x`.
        let mut i = steps_up(seen.x - first, p.step, inverse_step).max(0.0) as u32;
        let mut stretch = s.span(p, tex_origin, tex_dir, first + i as f32 * p.step);
        let skipping = p.flags & FLAG_SKIP_EMPTY != 0;
        // A jump from sample `i` to the first sample at or after `t` (at
        // least the next); WGSL's f32 → u32 conversion saturates like Rust's `as`.
        let jump = |i: u32, t: f32| (i + 1).max(steps_up(t - first, p.step, inverse_step) as u32);
        // Loop iterations, as the GPU counts them (a sample or a skip each).
        let mut k = 0u32;
        'march: while k < p.max_steps {
            let t = first + i as f32 * p.step;
            if t > seen.y || i > MAX_RUN_INDEX {
                break;
            }
            if t >= stretch.exit {
                stretch = s.next_span(p, tex_origin, tex_dir, &stretch, t);
            }
            if t < stretch.enter {
                // Known to be invisible (in the empty blocks the walk
                // jumped, as `empty_exit` jumps one block): on to the first
                // sample in the stretch.
                i = jump(i, stretch.enter);
                k += 1;
                continue;
            }
            let loc = &stretch.loc;
            if S::is_empty(loc) {
                i = if skipping {
                    jump(i, s.empty_exit(p, tex_origin, tex_dir, loc))
                } else {
                    i + 1
                };
                k += 1;
                continue;
            }
            // Samples at t < `limit` share the stretch. (A walk of 4³-voxel
            // cells inside blocks that jumped the transparent ones cost more
            // than it saved: the texel test of `sample4_in` drops their
            // samples four at a time for less.)
            let limit = stretch.exit;
            // The run of samples from `t` to `limit`, four at a time, the
            // first whatever `limit` says (a stretch never ends before its
            // first sample); samples the transfer function hides are
            // dropped before their class is looked up.
            let mut first_of_run = true;
            loop {
                // Sample indices stay far below 2³¹ here: the march stops
                // past the box, long before (see `MAX_RUN_INDEX`).
                let lanes = (i32x4::splat(i as i32) + i32x4::new([0, 1, 2, 3])).round_float();
                let tv = f32x4::splat(first) + lanes * f32x4::splat(p.step);
                let ts = tv.to_array();
                // The lanes in the run: those before the stretch's end, in
                // the box and within the step budget; the samples go up
                // along the ray, so they are the first `n` (the first of a
                // run always, whatever `limit` says).
                let inside = tv.simd_lt(f32x4::splat(limit)) & tv.simd_le(f32x4::splat(span.y));
                let mut n = (inside.to_bitmask().trailing_ones() as usize)
                    .min(p.max_steps.saturating_sub(k) as usize);
                if first_of_run {
                    n = n.max(1);
                    first_of_run = false;
                }
                if let Some(values) = s.sample4_in(p, &stretch, ts, tex_origin, tex_dir) {
                    let us = values.map(|v| v * p.volume.value_scale + p.volume.value_offset);
                    let classes = Classes4::new(p, us);
                    // Plain compositing takes every lane's class (a hidden
                    // one adds zero): their opacities are read with them,
                    // not apart.
                    let plain = (KIND == PLAIN).then(|| {
                        [
                            classes.rgba(tf, 0),
                            classes.rgba(tf, 1),
                            classes.rgba(tf, 2),
                            classes.rgba(tf, 3),
                        ]
                    });
                    let opacity = match &plain {
                        Some(classes) => f32x4::from(classes.map(|c| c.w)),
                        None => classes.opacity(tf),
                    };
                    // The lanes of the run that show.
                    let run = f32x4::from([0.0, 1.0, 2.0, 3.0]).simd_lt(f32x4::splat(n as f32));
                    let showing = opacity.simd_gt(f32x4::ZERO) & run;
                    let mut shown = showing.to_bitmask();
                    let corrected4 = corrected_opacity4(opacity, acc.exponent);
                    let corrected = corrected4.to_array();
                    let composite = KIND == PLAIN || KIND == ANY && p.mode == MODE_COMPOSITE;
                    // Shaded samples are coloured (shaded and lit) four at a
                    // time before they are composited; the others one by
                    // one as they are (which measured faster for them).
                    let shaded = KIND == ANY && composite && p.flags & FLAG_SHADED != 0;
                    let lit_alone = KIND == ANY && composite && !shaded && p.flags & FLAG_LIT != 0;
                    let extinction = KIND == ANY && p.flags & FLAG_EXTINCTION != 0;
                    let mut shown_at = Shown {
                        lanes: shown,
                        weights: [0.0; 4],
                        ts,
                        tex_origin,
                        tex_dir,
                    };
                    let mut rgbas = [Vec4::ZERO; 4];
                    if shaded {
                        if !extinction {
                            // Not the samples past the one that ends the ray.
                            shown_at.lanes = composited_lanes(showing, acc.alpha, corrected4, p);
                        }
                        shown_at.weights =
                            weights(p, shown_at.lanes, acc.alpha, &opacity, &corrected);
                        for j in Lanes(shown_at.lanes) {
                            rgbas[j] = classes.rgba(tf, j);
                        }
                        colour_shown(p, s, &stretch, &shown_at, acc.half, &mut rgbas);
                    }
                    if composite && !lit_alone && !extinction {
                        // Every lane of the run in turn, without branching
                        // on which show: a hidden one (its corrected opacity
                        // taken as zero) adds zero to the colour and the
                        // opacity, which leaves their bits as `add` leaves
                        // them by skipping it; the mispredicted branches
                        // cost more than compositing it.
                        let a = showing.select(corrected4, f32x4::ZERO).to_array();
                        for (j, a) in a.into_iter().enumerate() {
                            let rgb = if shaded {
                                rgbas[j].xyz()
                            } else if let Some(plain) = &plain {
                                plain[j & 3].xyz()
                            } else {
                                classes.rgba(tf, j).xyz()
                            };
                            if acc.add_shown(p, rgb, a) {
                                break 'march;
                            }
                        }
                        shown = 0;
                    }
                    for j in Lanes(shown) {
                        let mut rgba = if shaded {
                            rgbas[j]
                        } else {
                            classes.rgba(tf, j)
                        };
                        if lit_alone {
                            rgba = lit(p, s, &stretch, ts[j], &shown_at, rgba);
                        }
                        let sample = Sample {
                            u: us[j],
                            rgba,
                            a: corrected[j],
                        };
                        if acc.add::<KIND>(p, sample) {
                            break 'march;
                        }
                    }
                }
                i += n as u32;
                k += n as u32;
                if n < 4 {
                    continue 'march;
                }
            }
        }
    }
    pixel(p, &acc)
}

/// `-floor(-(d / step))`, the whole steps in `d` rounded up, for `inverse`
/// = 1 / `step`: the product `d · inverse` rounded up where it lies far
/// enough from a whole number that the quotient, within a few units in the
/// last place of it, rounds up to the same; the quotient otherwise. The
/// same bits either way, without a division on the march's way from one
/// stretch of a ray to the next in nearly every case.
#[inline(always)]
fn steps_up(d: f32, step: f32, inverse: f32) -> f32 {
    let q = d * inverse;
    let up = -floor(-q);
    // Two roundings put q within 2⁻²² of d / step relatively, the quotient
    // one: 2⁻²⁰ of q holds both. Tiny and non-finite q divide.
    let margin = q.abs() * (1.0 / 1_048_576.0);
    if up - q > margin && q - (up - 1.0) > margin && margin > 1e-30 {
        up
    } else {
        -floor(-(d / step))
    }
}

/// The pixel a ray that composited `acc` draws (rgba8unorm).
#[inline(always)]
fn pixel(p: &RaycastParams, acc: &Accumulator) -> [u8; 4] {
    let Accumulator {
        color,
        alpha,
        found,
        extreme,
        ..
    } = *acc;
    let background = Vec4::from(p.background).xyz();
    let mut out = color + (1.0 - alpha) * background;
    if p.mode != MODE_COMPOSITE {
        out = background;
        if found {
            out = Vec3::splat(window_grey(p, extreme));
        }
    }
    let out = out.clamp(Vec3::ZERO, Vec3::ONE);
    // rgba8unorm stores round(v * 255).
    let unorm = |v: f32| (v * 255.0).round() as u8;
    [unorm(out.x), unorm(out.y), unorm(out.z), 255]
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use wide::f32x4;

    use super::{
        Lanes, MAX_SAMPLE_OPACITY, Storage, central_difference_at, composited_lanes,
        corrected_opacity, corrected_opacity4, cubic_gradient_at, floor, pow4, steps_up, weights,
    };
    use crate::cpu::Texture3d;
    use crate::cpu::hash::{pcg_hash, unit_from_hash};
    use crate::cpu::reference::PlainLocation;
    use crate::raycast::{FAINT_WEIGHT, RaycastParams};

    /// A cube of `n`³ voxels with values `f(x, y, z)` at the voxel centres
    /// (in voxels), and march parameters for it.
    fn field(n: u32, f: impl Fn(Vec3) -> f32) -> (Texture3d, RaycastParams) {
        let mut texels = Vec::new();
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    texels.push(f(Vec3::new(x as f32, y as f32, z as f32)));
                }
            }
        }
        let mut params: RaycastParams = bytemuck::Zeroable::zeroed();
        params.volume.texel = [1.0 / n as f32; 3];
        (Texture3d::new([n; 3], texels), params)
    }

    /// Points spread over the volume's middle, in voxels.
    fn points(n: u32, margin: f32) -> impl Iterator<Item = Vec3> {
        let span = n as f32 - 1.0 - 2.0 * margin;
        (0..200).map(move |i| {
            let u = |k: u32| ((i * k) % 199) as f32 / 198.0;
            Vec3::new(u(37), u(101), u(53)) * span + Vec3::splat(margin)
        })
    }

    #[test]
    fn cubic_gradients_are_exact_on_a_linear_field_as_central_differences_are() {
        let slope = Vec3::new(0.01, 0.02, -0.03);
        let (texture, params) = field(24, |p| 0.5 + slope.dot(p));
        // Per unit of texture coordinate: per voxel × 24.
        let want = slope * 24.0;
        for p in points(24, 2.0) {
            let tc = (p + Vec3::splat(0.5)) / 24.0;
            for (name, got) in [
                (
                    "cubic",
                    cubic_gradient_at(&texture, &params, tc, &PlainLocation),
                ),
                (
                    "central",
                    central_difference_at(&texture, &params, tc, &PlainLocation),
                ),
                (
                    "nearest",
                    texture.nearest_difference_at(&params, tc, &PlainLocation),
                ),
            ] {
                assert!(
                    (got - want).length() < 1e-4,
                    "{name} at {p}: {got} for {want}"
                );
            }
        }
    }

    /// The largest angle, in degrees, between the gradient `gradient` finds
    /// on the iso-surface of a ball with a soft edge and the ball's normal,
    /// over the cap within 50° of the view along z, where a surface crosses
    /// the voxel planes at every slant.
    fn worst_normal_error(
        gradient: fn(&Texture3d, &RaycastParams, Vec3, &PlainLocation) -> Vec3,
    ) -> f32 {
        // A logistic edge of scale 0.44 voxel: as steep as a Gaussian blur
        // of σ = 0.8 voxel (a sharp CT kernel), radius 20.3 voxels.
        let (n, centre, radius) = (48u32, Vec3::splat(23.7), 20.3);
        let (texture, params) = field(n, |p| {
            1.0 / (1.0 + ((p.distance(centre) - radius) / 0.44).exp())
        });
        let mut worst = 0.0f32;
        for i in 0..400 {
            let polar = (i as f32 / 400.0).sqrt() * 50f32.to_radians();
            let azimuth = i as f32 * 2.399_963;
            let normal = Vec3::new(
                polar.sin() * azimuth.cos(),
                polar.sin() * azimuth.sin(),
                polar.cos(),
            );
            let p = centre + normal * radius;
            let g = gradient(
                &texture,
                &params,
                (p + Vec3::splat(0.5)) / n as f32,
                &PlainLocation,
            );
            worst = worst.max((-g.normalize()).dot(normal).min(1.0).acos().to_degrees());
        }
        worst
    }

    #[test]
    fn cubic_normals_follow_a_curved_edge_that_central_differences_tilt() {
        let cubic = worst_normal_error(cubic_gradient_at);
        let central = worst_normal_error(central_difference_at);
        let nearest = worst_normal_error(Texture3d::nearest_difference_at);
        // Measured: 1.06°, 5.41° and 6.84° (the faint samples' normal: of
        // central differences' order).
        assert!(
            cubic < 1.5 && central > 3.0 * cubic && nearest < 8.0,
            "cubic {cubic:.2}°, central {central:.2}°, nearest texel {nearest:.2}°"
        );
    }

    #[test]
    fn steps_up_by_the_inverse_are_those_of_the_division() {
        // Steps of voxel spacings in mm and fractions of them; distances
        // of every size, and at and beside whole numbers of steps.
        let mut checked = 0;
        for step in [
            0.5f32,
            0.25,
            0.3515625,
            0.488_281_25,
            0.1,
            0.7,
            1.3,
            0.45,
            3.0e-3,
        ] {
            let inverse = 1.0 / step;
            let mut d = -3.7e5f32;
            let mut state = 0x9e37_79b9u32;
            for _ in 0..400 {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                let whole = (state >> 8) as f32 % 4096.0 - 2048.0;
                for x in [
                    d,
                    whole * step,
                    f32::from_bits((whole * step).to_bits().wrapping_add(1)),
                    f32::from_bits((whole * step).to_bits().wrapping_sub(1)),
                    (whole + 0.5) * step,
                ] {
                    let want = -floor(-(x / step));
                    let got = steps_up(x, step, inverse);
                    assert_eq!(
                        got.to_bits(),
                        want.to_bits(),
                        "{x} / {step}: {got} against {want}"
                    );
                    checked += 1;
                }
                // From −3.7·10⁵ through small distances to large ones.
                d = if d < 0.0 && d > -1e-3 {
                    1e-3
                } else if d < 0.0 {
                    d * 0.93
                } else {
                    d * 1.07
                };
            }
        }
        for (x, step) in [
            (0.0, 0.5),
            (-0.0, 0.5),
            (1e-40, 0.5),
            (-1e-40, 0.5),
            (f32::INFINITY, 0.5),
            (f32::NEG_INFINITY, 0.5),
            (1e30, 0.3),
            (-1e30, 0.3),
        ] {
            let (want, got) = (-floor(-(x / step)), steps_up(x, step, 1.0 / step));
            assert_eq!(got.to_bits(), want.to_bits(), "{x} / {step}");
        }
        let nan = steps_up(f32::NAN, 0.5, 2.0);
        assert!(nan.is_nan());
        assert!(checked > 1000, "{checked}");
    }

    #[test]
    fn four_corrected_opacities_are_the_scalar_ones_bit_for_bit() {
        for exponent in [1.0, 0.5, 0.25, 0.7, 2.0] {
            for i in 0..=1000 {
                let a = [i, 1000 - i, i / 3, 999].map(|i| i as f32 / 1000.0);
                let four = corrected_opacity4(f32x4::from(a), exponent).to_array();
                for (lane, a) in a.into_iter().enumerate() {
                    let one = corrected_opacity(a, exponent);
                    assert_eq!(
                        four[lane].to_bits(),
                        one.to_bits(),
                        "opacity {a}, exponent {exponent}: {} of four, {one} alone",
                        four[lane]
                    );
                }
            }
        }
    }

    /// A group of four samples as the march meets them, drawn from `i`: the
    /// ray's opacity so far (below `end`, often just below), the lanes'
    /// class opacities (faint haze to opaque; a lane past the run or
    /// transparent is not showing, and one past the run may have an
    /// opacity), their corrected opacities and the showing lanes' mask.
    fn group(i: u32, end: f32) -> (f32, f32x4, [f32; 4], f32x4) {
        let r = |k: u32| unit_from_hash(pcg_hash(i.wrapping_mul(16).wrapping_add(k)));
        let alpha = match i % 4 {
            0 => r(0) * end,
            1 => end - r(0) * 1e-3,
            2 => end - r(0) * 1e-6,
            _ => r(0) * r(1) * r(2),
        }
        .clamp(0.0, end.min(1.0) - f32::EPSILON);
        let opacity = [4, 5, 6, 7].map(|k| match (i >> k) % 4 {
            0 => 0.0,
            1 => r(k).powi(6),
            2 => r(k) * 0.05,
            _ => r(k),
        });
        let corrected = opacity.map(|a| corrected_opacity(a, 0.5));
        let run = (r(8) * 4.0) as usize + 1;
        let showing = f32x4::from(std::array::from_fn::<f32, 4, _>(|j| {
            if j < run && opacity[j] > 0.0 {
                1.0
            } else {
                0.0
            }
        }))
        .simd_gt(f32x4::ZERO);
        (alpha, f32x4::from(opacity), corrected, showing)
    }

    #[test]
    fn composited_lanes_found_without_the_chain_are_the_chains() {
        let mut params: RaycastParams = bytemuck::Zeroable::zeroed();
        let (mut whole, mut cut) = (0, 0);
        for end in [0.95, 0.99, 0.999, 1.0] {
            params.early_termination = end;
            for i in 0..100_000 {
                let (alpha, _, corrected, showing) = group(i, end);
                let shown = showing.to_bitmask();
                // `Accumulator::add`'s chain, lane by lane.
                let (mut chain, mut kept) = (alpha, 0);
                for j in Lanes(shown) {
                    kept |= 1 << j;
                    chain += (1.0 - chain) * corrected[j];
                    if chain >= end {
                        break;
                    }
                }
                let found = composited_lanes(showing, alpha, f32x4::from(corrected), &params);
                assert_eq!(
                    found, kept,
                    "end {end}, alpha {alpha}, {corrected:?}, lanes {shown:b}"
                );
                if kept == shown { whole += 1 } else { cut += 1 }
            }
        }
        // Both kinds of group were met: the ray ending inside one, and not.
        assert!(whole > 10_000 && cut > 10_000, "{whole} whole, {cut} cut");
    }

    #[test]
    fn weights_found_without_the_chain_are_faint_where_the_chains_are() {
        let mut params: RaycastParams = bytemuck::Zeroable::zeroed();
        let (mut bounds, mut chains) = (0, 0);
        for faint in [FAINT_WEIGHT, 1e-3, 0.05, 0.0, 2.0] {
            params.faint_weight = faint;
            for i in 0..100_000 {
                let (alpha, opacity, corrected, showing) = group(i, 1.0);
                let shown = showing.to_bitmask();
                let (mut chain, mut exact) = (alpha, [0.0; 4]);
                for j in Lanes(shown) {
                    exact[j] = (1.0 - chain) * opacity.to_array()[j];
                    chain += (1.0 - chain) * corrected[j].min(MAX_SAMPLE_OPACITY);
                }
                let found = weights(&params, shown, alpha, &opacity, &corrected);
                for j in Lanes(shown) {
                    assert_eq!(
                        found[j] < faint,
                        exact[j] < faint,
                        "faint below {faint}, alpha {alpha}, {opacity:?}, lane {j} of {shown:b}: \
                         {} found, {} exact",
                        found[j],
                        exact[j]
                    );
                }
                if Lanes(shown).any(|j| found[j] != exact[j]) {
                    bounds += 1;
                } else {
                    chains += 1;
                }
            }
        }
        // Both ways were taken: the bounds standing for the weights, and the chain.
        assert!(
            bounds > 10_000 && chains > 10_000,
            "{bounds} bounds, {chains} chains"
        );
    }

    #[test]
    fn pow_by_squaring_stays_within_2_to_the_minus_18_of_powf() {
        for e in [0.0, 1.0, 2.0, 7.0, 24.0, 64.0, 2.5, 65.0, 100.0] {
            for i in 0..=1000 {
                let x = i as f32 / 1000.0;
                let (ours, libm) = (pow4(f32x4::splat(x), e).to_array()[0], x.powf(e));
                let tolerance = libm / 262_144.0 + 1e-30;
                assert!(
                    (ours - libm).abs() <= tolerance,
                    "{x}^{e}: {ours} by squaring, {libm} by powf"
                );
            }
        }
    }
}
