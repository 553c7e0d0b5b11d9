//! [`SlotAtlas`]: the packed atlas in memory as the CPU reads it best. The
//! GPU's atlas is one 3D texture, so a slot's 18³ texels lie in 324 rows
//! scattered over the texture (dozens of memory pages); here every slot's
//! texels are contiguous (x fastest, then y, then z within the slot), so a
//! ray crossing a block reads a few pages it keeps in cache. Texels are still
//! addressed in the GPU atlas's coordinates ([`SlotAtlas::load`],
//! [`SlotAtlas::sample_level`]) for the twins of the light stages; the ray
//! caster reads a slot directly ([`SlotAtlas::slot_base`],
//! [`SlotAtlas::sample_slot`]).

use blocks::lod::EMPTY;
use blocks::packing::{APRON, Packing, Region, slot_edge};
use blocks::store::LEVELS;
use glam::Vec3;
use wide::f32x4;

use rayon::prelude::*;

use super::Texture3d;
use super::occupancy::texel_may_show;
use super::packed::{BlockLocation, block_texel};
use super::texture::{blend, corners_from, deal, floor3, pair, round_down, split, trilinear};
use crate::packed_volume::PackedVolume;

/// The atlas of one packing, slot by slot; see the module docs.
#[derive(Debug, Clone)]
pub struct SlotAtlas {
    dims: [u32; 3],
    regions: [Region; LEVELS],
    /// Where each level's region starts in `texels`: at a multiple of 64,
    /// so that bits per texel ([`super::occupancy::visible_texels`]) split
    /// into whole words by region.
    region_base: [usize; LEVELS],
    /// Per block (block-statistics order), where its slot starts in `texels`
    /// (`usize::MAX` when the block is not stored).
    block_base: Vec<usize>,
    texels: Vec<f32>,
}

impl SlotAtlas {
    /// Room for every slot of `packing`'s regions, texels zero.
    pub fn new(packing: &Packing) -> SlotAtlas {
        let mut region_base = [0usize; LEVELS];
        let mut total = 0usize;
        for (level, region) in packing.regions.iter().enumerate() {
            total = total.next_multiple_of(64);
            region_base[level] = total;
            total += region_len(level, region);
        }
        let mut atlas = SlotAtlas {
            dims: packing.atlas_dims,
            regions: packing.regions,
            region_base,
            block_base: Vec::new(),
            texels: vec![0.0; total],
        };
        atlas.set_packing(packing);
        atlas
    }

    /// Takes the slots of `packing`, whose layout (regions) must be this
    /// atlas's: slots keep their texels, blocks move to theirs.
    pub fn set_packing(&mut self, packing: &Packing) {
        debug_assert_eq!(packing.regions, self.regions, "a packing of another layout");
        self.block_base = (0..packing.lod.len())
            .map(|b| {
                let level = packing.lod[b];
                if level == EMPTY || usize::from(level) >= LEVELS {
                    return usize::MAX;
                }
                self.slot_start(usize::from(level), packing.slot[b])
            })
            .collect();
    }

    /// Where slot `slot` of level `level` starts in the texels.
    fn slot_start(&self, level: usize, slot: u32) -> usize {
        let e = slot_edge(level) as usize;
        self.region_base[level] + slot as usize * e * e * e
    }

    /// Where level `level`'s slots lie in [`SlotAtlas::texels`] (slot after
    /// slot, each `slot_edge(level)³` texels), starting at a multiple of 64.
    pub fn region_texels(&self, level: usize) -> std::ops::Range<usize> {
        let start = self.region_base[level];
        start..start + region_len(level, &self.regions[level])
    }

    /// These slots holding `atlas`'s texels instead (a texture of the GPU
    /// atlas's shape, such as a light stage's), each slot's copied from where
    /// `index` (per block: atlas position of its first interior texel, level)
    /// places it, so that it is read slot by slot as the data is.
    pub fn with_texels_of(&self, atlas: &Texture3d, index: &[[u16; 4]]) -> SlotAtlas {
        let mut copy = SlotAtlas {
            dims: self.dims,
            regions: self.regions,
            region_base: self.region_base,
            block_base: self.block_base.clone(),
            texels: vec![0.0; self.texels.len()],
        };
        // Per level and slot, the atlas position of its first texel (the apron's).
        let mut corners: [Vec<Option<[i32; 3]>>; LEVELS] = std::array::from_fn(|level| {
            let e = slot_edge(level) as usize;
            vec![None; self.region_texels(level).len() / (e * e * e)]
        });
        for (&base, entry) in self.block_base.iter().zip(index) {
            let level = usize::from(entry[3]);
            if base == usize::MAX || level >= LEVELS {
                continue;
            }
            let e = slot_edge(level) as usize;
            let slot = (base - self.region_base[level]) / (e * e * e);
            let at = |a: usize| i32::from(entry[a]) - APRON as i32;
            corners[level][slot] = Some([at(0), at(1), at(2)]);
        }
        for (level, corners) in corners.iter().enumerate() {
            let e = slot_edge(level) as usize;
            let range = copy.region_texels(level);
            copy.texels[range]
                .par_chunks_mut(e * e * e)
                .zip(corners)
                .for_each(|(texels, corner)| {
                    let Some([x0, y0, z0]) = *corner else {
                        return;
                    };
                    for (i, t) in texels.iter_mut().enumerate() {
                        let (x, y, z) = ((i % e) as i32, (i / e % e) as i32, (i / (e * e)) as i32);
                        *t = atlas.load(x0 + x, y0 + y, z0 + z);
                    }
                });
        }
        copy
    }

    /// The texels at `tc` in block `loc`'s slot (positions outside the block
    /// clamped to its apron), filtered as the GPU filters its atlas there.
    #[inline(always)]
    pub fn sample_block(&self, g: &PackedVolume, tc: Vec3, loc: &BlockLocation) -> f32 {
        let (first, f) = block_corner(g, tc, loc);
        let edge = loc.slot_edge;
        trilinear(&self.texels, first, edge, edge * edge, f)
    }

    /// [`SlotAtlas::sample_block`], or `None` where `visible` (the bits of
    /// [`super::occupancy::visible_texels`]) says the sample cannot be
    /// visible: the transfer function gives every value it may blend no
    /// opacity, so a caller that weighs it by its opacity can leave it out.
    #[inline(always)]
    pub fn sample_block_visible(
        &self,
        g: &PackedVolume,
        tc: Vec3,
        loc: &BlockLocation,
        visible: Option<&[u64]>,
    ) -> Option<f32> {
        let (first, f) = block_corner(g, tc, loc);
        if visible.is_some_and(|bits| !texel_may_show(bits, first)) {
            return None;
        }
        let edge = loc.slot_edge;
        Some(trilinear(&self.texels, first, edge, edge * edge, f))
    }

    /// [`SlotAtlas::sample_slot`] of these slots and of `other`, an atlas
    /// of the same slots (such as [`SlotAtlas::with_texels_of`] makes), at
    /// once: the position and weights found once, the same values.
    #[inline(always)]
    pub fn sample_slot_with(
        &self,
        other: &SlotAtlas,
        base: usize,
        edge: usize,
        p: Vec3,
    ) -> (f32, f32) {
        let (first, f) = slot_corner(base, edge, p);
        let weights = RowWeights::of(f);
        (
            weights.blend(&self.texels, first, edge),
            weights.blend(&other.texels, first, edge),
        )
    }

    /// Atlas size in texels, as the GPU texture's.
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Where block `b`'s slot starts in [`SlotAtlas::texels`], or `None` when
    /// the block is not stored.
    pub fn slot_base(&self, b: usize) -> Option<usize> {
        self.block_base.get(b).copied().filter(|&s| s != usize::MAX)
    }

    /// The slots of those of `blocks` that are stored (`lod`, the packing's
    /// level per block, sizes them), each once and in texel order, to be
    /// written at the same time.
    pub fn slots_mut(
        &mut self,
        blocks: impl IntoIterator<Item = usize>,
        lod: &[u8],
    ) -> Vec<(usize, &mut [f32])> {
        let mut wanted: Vec<(usize, usize, usize)> = blocks
            .into_iter()
            .filter_map(|b| {
                let start = self.slot_base(b)?;
                let e = slot_edge(usize::from(*lod.get(b)?)) as usize;
                Some((start, e * e * e, b))
            })
            .collect();
        wanted.sort_unstable();
        let mut slots = Vec::with_capacity(wanted.len());
        let (mut rest, mut at): (&mut [f32], usize) = (&mut self.texels, 0);
        for (start, len, b) in wanted {
            // A block named twice is written once.
            if start < at || start + len > at + rest.len() {
                continue;
            }
            let (slot, tail) = std::mem::take(&mut rest)[start - at..].split_at_mut(len);
            slots.push((b, slot));
            (rest, at) = (tail, start + len);
        }
        slots
    }

    /// Every slot's texels.
    pub fn texels(&self) -> &[f32] {
        &self.texels
    }

    /// The texels of block `b`'s slot, an edge of `slot_edge(level)`, to write.
    pub fn slot_mut(&mut self, b: usize, level: usize) -> Option<&mut [f32]> {
        let start = self.slot_base(b)?;
        let e = slot_edge(level) as usize;
        self.texels.get_mut(start..start + e * e * e)
    }

    /// The texel at atlas coordinates (x, y, z), clamped to the atlas's edge,
    /// as the GPU texture holds it (zero between slots).
    pub fn load(&self, x: i32, y: i32, z: i32) -> f32 {
        let clamp = |v: i32, n: u32| v.clamp(0, n as i32 - 1) as u32;
        let (x, y, z) = (
            clamp(x, self.dims[0]),
            clamp(y, self.dims[1]),
            clamp(z, self.dims[2]),
        );
        for (level, region) in self.regions.iter().enumerate().rev() {
            if z < region.z0 {
                continue;
            }
            let e = slot_edge(level);
            let [sx, sy, sz] = region.slots;
            let (gx, gy, gz) = (x / e, y / e, (z - region.z0) / e);
            if gx >= sx || gy >= sy || gz >= sz {
                return 0.0;
            }
            let slot = (gz * sy + gy) * sx + gx;
            let (lx, ly, lz) = (x % e, y % e, (z - region.z0) % e);
            let e = e as usize;
            let at =
                self.slot_start(level, slot) + (lz as usize * e + ly as usize) * e + lx as usize;
            return self.texels.get(at).copied().unwrap_or(0.0);
        }
        0.0
    }

    /// Trilinear sample at atlas texture coordinates `tc`, as the GPU samples
    /// its atlas texture (linear filtering, clamp to edge).
    pub fn sample_level(&self, tc: Vec3) -> f32 {
        let dims = Vec3::new(
            self.dims[0] as f32,
            self.dims[1] as f32,
            self.dims[2] as f32,
        );
        let p = tc * dims - 0.5;
        let base = floor3(p);
        let f = p - base;
        let (x, y, z) = (base.x as i32, base.y as i32, base.z as i32);
        let corners = corners_from(x, y, z, |x, y, z| self.load(x, y, z));
        blend(corners, f.to_array(), 1.0)
    }

    /// Trilinear sample at `p`, texel coordinates within the slot that starts
    /// at `base` with edge `edge` (texel centres at integers, the apron at 0
    /// and `edge − 1`), `p` kept in the slot: what the GPU's filtering reads
    /// there, since every texel it touches is the slot's.
    #[inline(always)]
    pub fn sample_slot(&self, base: usize, edge: usize, p: Vec3) -> f32 {
        let (first, f) = slot_corner(base, edge, p);
        RowWeights::of(f).blend(&self.texels, first, edge)
    }

    /// [`SlotAtlas::sample_slot`] at four positions at once, their
    /// coordinates along x, y and z side by side (the same arithmetic lane
    /// by lane, so the same values). With `visible`, the texels' bits of
    /// [`super::occupancy::visible_texels`]: `None` where none of the four
    /// samples can be visible (they are not read).
    #[inline(always)]
    pub fn sample_slot4(
        &self,
        base: usize,
        edge: usize,
        p: [f32x4; 3],
        visible: Option<&[u64]>,
    ) -> Option<[f32; 4]> {
        // The slot's edge as a constant: the eight texels a sample blends
        // at fixed offsets in a window of fixed size, one bounds check.
        match edge {
            18 => self.sample_slot4_edge::<18, { 18 * 18 + 18 + 2 }>(base, p, visible),
            10 => self.sample_slot4_edge::<10, { 10 * 10 + 10 + 2 }>(base, p, visible),
            6 => self.sample_slot4_edge::<6, { 6 * 6 + 6 + 2 }>(base, p, visible),
            4 => self.sample_slot4_edge::<4, { 4 * 4 + 4 + 2 }>(base, p, visible),
            _ => self.sample_slot4_edge::<3, { 3 * 3 + 3 + 2 }>(base, p, visible),
        }
    }

    /// [`SlotAtlas::sample_slot4`] in slots of edge `E`; `W` is the window
    /// of a sample's eight texels, `E² + E + 2`.
    #[inline(always)]
    fn sample_slot4_edge<const E: usize, const W: usize>(
        &self,
        base: usize,
        p: [f32x4; 3],
        visible: Option<&[u64]>,
    ) -> Option<[f32; 4]> {
        let last = f32x4::splat(last_position(E));
        let p = p.map(|v| v.fast_max(f32x4::ZERO).fast_min(last));
        let whole = p.map(round_down);
        let e = f32x4::splat(E as f32);
        // Whole numbers below 2²⁴: exact in floats.
        let offset = ((whole[2] * e + whole[1]) * e + whole[0])
            .fast_trunc_int()
            .to_array();
        if let Some(bits) = visible {
            let shown = |o: i32| texel_may_show(bits, base + o as usize);
            if !offset.into_iter().any(shown) {
                return None;
            }
        }
        let [fx, fy, fz] = [0, 1, 2].map(|a| p[a] - whole[a]);
        let (row, slice) = (E, E * E);
        // The slot, then each window in it: a sample's window starts at
        // most at (E − 2)·(E² + E + 1), where its last texel is the slot's
        // (`p` kept below E − 1), so `min` leaves every start as it is and
        // spares the windows' bounds checks.
        let size = E * E * E;
        let Some(slot) = self.texels.get(base..base + size) else {
            // Cannot happen: `base` is where this atlas put a slot of edge
            // `E` (`slot_base`). A debug build stops; a release build draws
            // the samples as zeros rather than read out of bounds.
            debug_assert!(
                self.texels.len() >= base + size,
                "a slot of edge {E} at texel {base}, past the atlas's {} texels",
                self.texels.len()
            );
            return Some([0.0; 4]);
        };
        let windows: [&[f32; W]; 4] = offset.map(|o| {
            let start = (o as u32 as usize).min(size - W);
            slot[start..start + W].try_into().expect("W texels")
        });
        // `blend`'s arithmetic written out for the four samples side by
        // side (each row's texel and the next along x dealt into two
        // vectors); building the eight corners for the generic function
        // made frames 20 % slower.
        // `four_samples_at_once_are_each_the_bits_of_one_sample` checks
        // that each lane is `sample_slot`'s value.
        let (gx, gy, gz) = (f32x4::ONE - fx, f32x4::ONE - fy, f32x4::ONE - fz);
        let w = [gy * gz, fy * gz, gy * fz, fy * fz];
        let corner = |c: usize, w: f32x4| {
            let (a, b) = deal(windows.map(|win| pair(win, c)));
            (a * gx + b * fx) * w
        };
        let sum = (corner(0, w[0]) + corner(row, w[1]))
            + (corner(slice, w[2]) + corner(slice + row, w[3]));
        Some(sum.to_array())
    }

    /// The central differences of the texel nearest `p` (texel coordinates
    /// within the slot at `base` of edge `edge`, centres at whole `p`; the
    /// nearest of its interior texels, so its neighbours are in the slot,
    /// its apron included): `texel(n + a) − texel(n − a)` for the unit
    /// steps `a` along x, y and z, six reads and no blend.
    #[inline(always)]
    pub fn nearest_differences(&self, base: usize, edge: usize, p: Vec3) -> Vec3 {
        let last = (edge - 1) as f32 - SLOT_APRON;
        // `floor(p + ½)` clamped to the interior, as one clamp and one
        // truncation of three lanes: the clamp's bounds are whole numbers,
        // so truncating the clamped value is flooring it (NaN clamps to
        // the low bound, as `Vec3::clamp` takes it).
        let [x, y, z, _] = (f32x4::from([p.x, p.y, p.z, 0.0]) + f32x4::splat(0.5))
            .max(f32x4::splat(SLOT_APRON))
            .min(f32x4::splat(last))
            .fast_trunc_int()
            .to_array()
            .map(|n| n as usize);
        let i = base + (z * edge + y) * edge + x;
        let slice = edge * edge;
        let t = &self.texels;
        Vec3::new(
            t[i + 1] - t[i - 1],
            t[i + edge] - t[i - edge],
            t[i + slice] - t[i - slice],
        )
    }

    /// The cubic B-spline's derivative along x, y and z (per texel) at `p`,
    /// texel coordinates within the slot at `base` of edge `edge`, from the
    /// 4³ texels about it, weighed directly (separably). The shader reads
    /// the same sum as 8 trilinear reads per axis (Sigg and Hadwiger), which
    /// the GPU's filtering makes cheap and the CPU's does not: 64 texels
    /// instead of 192, the same value up to rounding. `p` must have its 4³
    /// texels in the slot (`floor(p) − 1 ≥ 0`, `floor(p) + 2 ≤ edge − 1`).
    #[inline(always)]
    pub fn cubic_gradient(&self, base: usize, edge: usize, p: Vec3) -> Vec3 {
        let i = p.floor();
        let first =
            base + ((i.z as usize - 1) * edge + (i.y as usize - 1)) * edge + (i.x as usize - 1);
        if edge == LEVEL0_EDGE {
            const E: usize = LEVEL0_EDGE;
            const W: usize = 3 * E * E + 3 * E + 4;
            if let Some(w) = self.texels.get(first..first + W) {
                let w: &[f32; W] = w.try_into().expect("W texels");
                return cubic_gradient_of(p - i, |k, j| four(w, (k * E + j) * E));
            }
        }
        cubic_gradient_of(p - i, |k, j| {
            let row: &[f32; 4] = self.texels[first + (k * edge + j) * edge..][..4]
                .try_into()
                .expect("four texels");
            f32x4::from(*row)
        })
    }

    /// `sample_slot(p + a) − sample_slot(p − a)` for the unit steps `a`
    /// along x, y and z, in a slot of level 0, for `p` with a texel and a
    /// half to spare on every side (`None` where it has not): both samples
    /// of a pair blend with `p`'s weights, so their difference is that blend
    /// of the texels' own differences, one trilinear blend for all three axes.
    #[inline(always)]
    pub fn central_differences(&self, base: usize, p: Vec3) -> Option<Vec3> {
        const E: usize = LEVEL0_EDGE;
        const ROW: usize = E;
        const SLICE: usize = E * E;
        // From the texel a slice and a texel before the first corner to
        // the one a slice and two texels after the last.
        const W: usize = 3 * SLICE + ROW + 4;
        let (x, fx) = split(p.x);
        let (y, fy) = split(p.y);
        let (z, fz) = split(p.z);
        let inside = |v: i32| (1..E as i32 - 2).contains(&v);
        if !(inside(x) && inside(y) && inside(z)) {
            return None;
        }
        let first = base + (z as usize * E + y as usize) * E + x as usize;
        let w: &[f32; W] = self
            .texels
            .get(first - SLICE - 1..first - SLICE - 1 + W)?
            .try_into()
            .ok()?;
        Some(blended_differences::<W, ROW, SLICE>(
            w,
            SLICE + 1,
            [fx, fy, fz],
        ))
    }

    /// [`SlotAtlas::central_differences`] where `p`'s reads reach a texel
    /// past its slot's apron (within half a texel of the slot's interior
    /// faces): the texels about `p` gathered first, those past a face from
    /// the slot of the block across it, `across[axis][side]` (side 0 below,
    /// 1 above), stored at level 0 too; as the shader's reads of the
    /// neighbour there find them (the apron holds that block's texels).
    /// `None` where a read needs a slot `across` has not.
    #[inline(always)]
    pub fn central_differences_across(
        &self,
        base: usize,
        p: Vec3,
        across: [[Option<usize>; 2]; 3],
    ) -> Option<Vec3> {
        const E: i32 = LEVEL0_EDGE as i32;
        // A slot's texel `c` along an axis is texel `c ∓ INTERIOR` of the
        // slot below or above along it.
        const INTERIOR: i32 = E - 2 * APRON as i32;
        let (x, fx) = split(p.x);
        let (y, fy) = split(p.y);
        let (z, fz) = split(p.z);
        let reachable = |v: i32| (0..E - 1).contains(&v);
        if !(reachable(x) && reachable(y) && reachable(z)) {
            return None;
        }
        // Where the row of texels at (y', z') (slot coordinates, one of
        // them at most past the apron) starts in `texels`.
        let row = |sy: i32, sz: i32| -> Option<usize> {
            let (slot, sy, sz) = if sy < 0 {
                (across[1][0]?, sy + INTERIOR, sz)
            } else if sy >= E {
                (across[1][1]?, sy - INTERIOR, sz)
            } else if sz < 0 {
                (across[2][0]?, sy, sz + INTERIOR)
            } else if sz >= E {
                (across[2][1]?, sy, sz - INTERIOR)
            } else {
                (base, sy, sz)
            };
            Some(slot + (sz * E + sy) as usize * E as usize)
        };
        let at = |i: usize| self.texels.get(i).copied();
        // Texels x − 1 … x + 2 of rows y − 1 … y + 2 and slices z − 1 … z + 2
        // (rows 4, slices 16 apart), those the differences read: x − 1 and
        // x + 2 in the four middle rows only, the corner rows not at all.
        let mut w = [0.0f32; 64];
        for k in 0..4 {
            for j in 0..4 {
                let middle = (1..3).contains(&j) && (1..3).contains(&k);
                if !middle && !(1..3).contains(&j) && !(1..3).contains(&k) {
                    continue;
                }
                let start = row(y - 1 + j as i32, z - 1 + k as i32)?;
                let lane = |i: usize| j * 4 + k * 16 + i;
                for i in 1..3 {
                    w[lane(i)] = at(start + (x as usize + i - 1))?;
                }
                if middle {
                    // The row is this slot's; x − 1 and x + 2 may be past it.
                    let before = x - 1;
                    w[lane(0)] = if before < 0 {
                        at(across[0][0]? + start - base + (before + INTERIOR) as usize)?
                    } else {
                        at(start + before as usize)?
                    };
                    let after = x + 2;
                    w[lane(3)] = if after >= E {
                        at(across[0][1]? + start - base + (after - INTERIOR) as usize)?
                    } else {
                        at(start + after as usize)?
                    };
                }
            }
        }
        Some(blended_differences::<64, 4, 16>(
            &w,
            16 + 4 + 1,
            [fx, fy, fz],
        ))
    }
}

/// The texels' differences along x, y and z at the 2×2×2 texels from
/// `w[c]` (rows `ROW` and slices `SLICE` apart), blended trilinearly at
/// fractions `f`: a row of two corners at a time, their differences four
/// texels at a time (along x lanes 0 and 1 of the first subtraction, along
/// y and z lanes 1 and 2 of the others), gathered per corner and blended
/// along x, then y, then z.
#[inline(always)]
fn blended_differences<const W: usize, const ROW: usize, const SLICE: usize>(
    w: &[f32; W],
    c: usize,
    f: [f32; 3],
) -> Vec3 {
    // Functions, not closures: a closure the compiler does not inline is
    // compiled without the instructions the march is built for.
    let c00 = corner_differences::<W, ROW, SLICE>(w, c, f[0]);
    let c10 = corner_differences::<W, ROW, SLICE>(w, c + ROW, f[0]);
    let c01 = corner_differences::<W, ROW, SLICE>(w, c + SLICE, f[0]);
    let c11 = corner_differences::<W, ROW, SLICE>(w, c + SLICE + ROW, f[0]);
    let [dx, dy, dz, _] = lerp4(lerp4(c00, c10, f[1]), lerp4(c01, c11, f[1]), f[2]).to_array();
    Vec3::new(dx, dy, dz)
}

/// For [`blended_differences`]: the differences along x, y and z at the
/// row of two corners from `w[o]`, blended along x at fraction `fx`.
#[inline(always)]
fn corner_differences<const W: usize, const ROW: usize, const SLICE: usize>(
    w: &[f32; W],
    o: usize,
    fx: f32,
) -> f32x4 {
    let [dx, dy, dz] = [
        four(w, o + 1) - four(w, o - 1),
        four(w, o + ROW - 1) - four(w, o - ROW - 1),
        four(w, o + SLICE - 1) - four(w, o - SLICE - 1),
    ]
    .map(f32x4::to_array);
    let low = f32x4::from([dx[0], dy[1], dz[1], 0.0]);
    let high = f32x4::from([dx[1], dy[2], dz[2], 0.0]);
    lerp4(low, high, fx)
}

/// Four texels along x from `w[i]`.
#[inline(always)]
fn four<const W: usize>(w: &[f32; W], i: usize) -> f32x4 {
    f32x4::from(<[f32; 4]>::try_from(&w[i..i + 4]).expect("in w"))
}

/// `a` blended towards `b` by `t`, lane by lane.
#[inline(always)]
fn lerp4(a: f32x4, b: f32x4, t: f32) -> f32x4 {
    a + (b - a) * f32x4::splat(t)
}

/// The cubic B-spline's derivative along x, y and z (per texel) at
/// fraction `a` past texel 1 of a 4³ neighbourhood whose row `j` of slice
/// `k` (x along the row) `row(k, j)` gives: separably, each row once, x in
/// SIMD lanes. Each column of rows (one `j`) is weighed along z twice (the
/// B-spline's weights and its derivative's), those along y, then along x.
#[inline(always)]
pub fn cubic_gradient_of(a: Vec3, row: impl Fn(usize, usize) -> f32x4) -> Vec3 {
    let b = Vec3::ONE - a;
    // Per axis, the B-spline's weights w and its derivative's d for the
    // texels floor(p) − 1 … floor(p) + 2, six and two times theirs: each
    // derivative weighs with two weights, so the sums are 72 times theirs,
    // taken out at the end with one multiplication instead of a dozen
    // divisions per sample.
    let a2 = a * a;
    let a3 = a2 * a;
    let w = [
        b * b * b,
        3.0 * a3 - 6.0 * a2 + Vec3::splat(4.0),
        -3.0 * a3 + 3.0 * a2 + 3.0 * a + Vec3::ONE,
        a3,
    ];
    let d = [
        -(b * b),
        a * (3.0 * a - Vec3::splat(4.0)),
        -3.0 * a2 + 2.0 * a + Vec3::ONE,
        a2,
    ];
    let (mut smooth, mut along_y, mut along_z) = (f32x4::ZERO, f32x4::ZERO, f32x4::ZERO);
    for j in 0..4 {
        let (mut weighed, mut derived) = (f32x4::ZERO, f32x4::ZERO);
        for k in 0..4 {
            let r = row(k, j);
            weighed += f32x4::splat(w[k].z) * r;
            derived += f32x4::splat(d[k].z) * r;
        }
        smooth += f32x4::splat(w[j].y) * weighed;
        along_y += f32x4::splat(d[j].y) * weighed;
        along_z += f32x4::splat(w[j].y) * derived;
    }
    let wx = f32x4::from([w[0].x, w[1].x, w[2].x, w[3].x]);
    let dx = f32x4::from([d[0].x, d[1].x, d[2].x, d[3].x]);
    Vec3::new(
        (smooth * dx).reduce_add(),
        (along_y * wx).reduce_add(),
        (along_z * wx).reduce_add(),
    ) * (1.0 / 72.0)
}

/// [`slot_corner`] at `tc` in block `loc`'s slot: `atlas_texel` within the
/// slot, whose apron starts one texel before the block's first interior texel,
/// found without the slot's place in the atlas ([`block_texel`]).
#[inline(always)]
fn block_corner(g: &PackedVolume, tc: Vec3, loc: &BlockLocation) -> (usize, Vec3) {
    let in_slot = block_texel(g, tc, loc) + (SLOT_APRON - 0.5);
    slot_corner(loc.slot, loc.slot_edge, in_slot)
}

/// Where trilinear filtering at `p` in the slot at `base` of edge `edge`
/// starts (its lowest texel) and its weights, `p` kept in the slot.
#[inline(always)]
pub(super) fn slot_corner(base: usize, edge: usize, p: Vec3) -> (usize, Vec3) {
    let p = p.clamp(Vec3::ZERO, Vec3::splat(last_position(edge)));
    let (x, fx) = split(p.x);
    let (y, fy) = split(p.y);
    let (z, fz) = split(p.z);
    let (x, y, z) = (x as usize, y as usize, z as usize);
    (base + (z * edge + y) * edge + x, Vec3::new(fx, fy, fz))
}

/// [`blend`]'s weights at fractions `f` with its four rows side by side in
/// lanes (y0z0, y1z0, y0z1, y1z1): a sample's trilinear blend of a slot's
/// texels, each row's two texels one 64-bit read, the same arithmetic.
#[derive(Debug, Clone, Copy)]
struct RowWeights {
    /// The weights along x, 1 − fx and fx, in every lane.
    x0: f32x4,
    x1: f32x4,
    /// Each row's weight along y and z.
    rows: f32x4,
}

impl RowWeights {
    #[inline(always)]
    fn of(f: Vec3) -> Self {
        let (gy, gz) = (1.0 - f.y, 1.0 - f.z);
        RowWeights {
            x0: f32x4::splat(1.0 - f.x),
            x1: f32x4::splat(f.x),
            rows: f32x4::from([gy * gz, f.y * gz, gy * f.z, f.y * f.z]),
        }
    }

    /// The blend of the 2×2×2 texels whose first is `texels[first]`, rows
    /// `edge` and slices `edge²` apart.
    #[inline(always)]
    fn blend(&self, texels: &[f32], first: usize, edge: usize) -> f32 {
        let (row, slice) = (edge, edge * edge);
        let t = &texels[first..first + slice + row + 2];
        let two = |o: usize| u64::from(t[o].to_bits()) | u64::from(t[o + 1].to_bits()) << 32;
        let (low, high) = deal([two(0), two(row), two(slice), two(slice + row)]);
        let [y0z0, y1z0, y0z1, y1z1] = ((low * self.x0 + high * self.x1) * self.rows).to_array();
        (y0z0 + y1z0) + (y0z1 + y1z1)
    }
}

/// Texels of level `level`'s `region`: its slots, `slot_edge(level)³` each.
fn region_len(level: usize, region: &Region) -> usize {
    let e = slot_edge(level) as usize;
    region.slots.iter().map(|&s| s as usize).product::<usize>() * e * e * e
}

/// The last position a sample in a slot of edge `edge` is kept at: a hair
/// inside the last texel, so that the lower texel of each pair is at most the
/// one before the last (the fraction there is 1 − 2⁻¹², where the GPU's
/// filtering weights have 8 bits).
#[inline(always)]
fn last_position(edge: usize) -> f32 {
    (edge - 1) as f32 - 1.0 / 4096.0
}

/// The edge of a level-0 slot in texels.
pub const LEVEL0_EDGE: usize = slot_edge(0) as usize;

/// The apron's width, as a texel offset within a slot.
pub const SLOT_APRON: f32 = APRON as f32;

#[cfg(test)]
mod tests {
    use blocks::lod::LodSelection;

    use super::*;
    use crate::cpu::march::CubicReads;
    use crate::cpu::packed::BLOCK;

    #[test]
    fn a_block_is_sampled_alike_wherever_its_slot_lies_in_the_atlas() {
        // The same block (level 0 and level 2) with its first interior texel
        // near the atlas's corner and far from it: the texels a sample blends
        // and their weights are the same bits, so frames do not depend on
        // the layout the blocks' arrival order gave the atlas.
        let g = PackedVolume {
            texel: [1.0 / 256.0; 3],
            reference_step: 1.0,
            volume_dims: [256.0; 3],
            value_scale: 1.0,
            atlas_size: [4096.0; 3],
            value_offset: 0.0,
            block_grid: [16; 3],
            tf_len: 1024,
        };
        for level in [0u32, 2] {
            let edge = slot_edge(level as usize) as usize;
            let at = |origin: Vec3| BlockLocation {
                empty: false,
                block: [5, 9, 3],
                origin,
                scale: 1.0 / (1u32 << level) as f32,
                slot: 0,
                slot_edge: edge,
            };
            let near = at(Vec3::splat(SLOT_APRON));
            let far = at(Vec3::new(3001.0, 2047.0, 1537.0));
            for k in 0..20_000 {
                let f = |s: f32, b: f32| (b * BLOCK + (k as f32 * s).sin() * 9.0 + 8.0) / 256.0;
                let tc = Vec3::new(f(1.37, 5.0), f(2.71, 9.0), f(0.93, 3.0));
                assert_eq!(
                    block_corner(&g, tc, &near),
                    block_corner(&g, tc, &far),
                    "level {level} at {tc}"
                );
            }
        }
    }

    #[test]
    fn cubic_gradients_weighed_directly_equal_the_shaders_trilinear_reads() {
        // A level-0 and a level-2 slot filled with uneven values.
        let selection = LodSelection::from_levels(vec![0u8, 2]);
        let packing = Packing::new(&selection, 2048).expect("packing");
        let mut atlas = SlotAtlas::new(&packing);
        for (b, level) in [(0usize, 0usize), (1, 2)] {
            let slot = atlas.slot_mut(b, level).expect("slot");
            for (i, t) in slot.iter_mut().enumerate() {
                *t = ((i * 7919) % 1000) as f32 / 1000.0 + (i as f32 * 0.01).sin();
            }
        }
        for (b, level) in [(0usize, 0usize), (1, 2)] {
            let base = atlas.slot_base(b).expect("stored");
            let edge = slot_edge(level) as usize;
            // Positions whose 4³ texels lie in the slot, fractions all over.
            let span = (edge - 3) as f32 - 1.0;
            for k in 0..200 {
                let f = |s: f32| 1.0 + ((k as f32 * s).sin() * 0.5 + 0.5) * span;
                let p = Vec3::new(f(1.3), f(2.7), f(0.9));
                let direct = atlas.cubic_gradient(base, edge, p);
                let reads = CubicReads::at(p).gradient(|x| atlas.sample_slot(base, edge, x));
                let scale = reads.abs().max_element().max(1.0);
                assert!(
                    (direct - reads).abs().max_element() < 1e-4 * scale,
                    "level {level} at {p}: {direct} vs {reads}"
                );
            }
        }
    }

    /// An atlas with a slot of every level (block `l` at level `l`), each
    /// filled with uneven values.
    fn uneven_slot_of_every_level() -> SlotAtlas {
        let levels: Vec<u8> = (0..LEVELS as u8).collect();
        let packing = Packing::new(&LodSelection::from_levels(levels), 2048).expect("packing");
        let mut atlas = SlotAtlas::new(&packing);
        for level in 0..LEVELS {
            let slot = atlas.slot_mut(level, level).expect("slot");
            for (i, t) in slot.iter_mut().enumerate() {
                *t = ((i * 7919) % 1000) as f32 / 1000.0 + (i as f32 * 0.37).sin();
            }
        }
        atlas
    }

    #[test]
    fn nearest_differences_are_the_nearest_interior_texels_at_any_position() {
        // A slot of every level filled with uneven values, read at
        // positions all over it, past its edges, at half-texel ties and at
        // NaN and infinities: each must be the central differences of the
        // interior texel `floor(p + ½)` clamps to, bit for bit.
        let atlas = uneven_slot_of_every_level();
        let odd = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -3e9,
            3e9,
            -0.5,
            0.5,
            1.5,
        ];
        for level in 0..LEVELS {
            let base = atlas.slot_base(level).expect("stored");
            let edge = slot_edge(level) as usize;
            let last = (edge - 1) as f32 - SLOT_APRON;
            let texel = |x: f32, y: f32, z: f32| {
                atlas.texels[base + (z as usize * edge + y as usize) * edge + x as usize]
            };
            let reach = edge as f32 + 2.0;
            for k in 0..2_000 {
                let at = |s: f32| match k % 7 {
                    // Ties: texel centres plus a half.
                    0 => ((k as f32 * s).sin().mul_add(0.5, 0.5) * reach).floor() - 1.5,
                    1 => odd[(k / 7 + (s * 10.0) as usize) % odd.len()],
                    _ => (k as f32 * s).sin().mul_add(0.5, 0.5) * reach - 2.0,
                };
                let p = Vec3::new(at(1.3), at(2.7), at(0.9));
                let n =
                    floor3(p + Vec3::splat(0.5)).clamp(Vec3::splat(SLOT_APRON), Vec3::splat(last));
                let expected = Vec3::new(
                    texel(n.x + 1.0, n.y, n.z) - texel(n.x - 1.0, n.y, n.z),
                    texel(n.x, n.y + 1.0, n.z) - texel(n.x, n.y - 1.0, n.z),
                    texel(n.x, n.y, n.z + 1.0) - texel(n.x, n.y, n.z - 1.0),
                );
                let found = atlas.nearest_differences(base, edge, p);
                assert_eq!(
                    found.to_array().map(f32::to_bits),
                    expected.to_array().map(f32::to_bits),
                    "level {level} at {p}: {found} vs {expected}"
                );
            }
        }
    }

    #[test]
    fn four_samples_at_once_are_each_the_bits_of_one_sample() {
        // A slot of every level filled with uneven values, sampled at
        // positions all over it and past its edges (clamped): each lane of
        // `sample_slot4` must be `sample_slot` at its position, bit for bit,
        // and both `trilinear`'s blend of the eight texels.
        let atlas = uneven_slot_of_every_level();
        for level in 0..LEVELS {
            let base = atlas.slot_base(level).expect("stored");
            let edge = slot_edge(level) as usize;
            let reach = edge as f32 + 1.0;
            for k in 0..250 {
                let at = |lane: usize, s: f32| {
                    ((k * 4 + lane) as f32 * s).sin().mul_add(0.5, 0.5) * reach - 1.0
                };
                let positions: [Vec3; 4] =
                    [0, 1, 2, 3].map(|l| Vec3::new(at(l, 1.3), at(l, 2.7), at(l, 0.9)));
                let axis = |a: usize| f32x4::from(positions.map(|p| p[a]));
                let four = atlas
                    .sample_slot4(base, edge, [axis(0), axis(1), axis(2)], None)
                    .expect("read without visibility bits");
                for (lane, p) in positions.into_iter().enumerate() {
                    let one = atlas.sample_slot(base, edge, p);
                    assert_eq!(
                        four[lane].to_bits(),
                        one.to_bits(),
                        "level {level}, lane {lane} at {p}: {} vs {one}",
                        four[lane]
                    );
                    // And `sample_slot` is `trilinear` of the eight texels.
                    let (first, f) = slot_corner(base, edge, p);
                    let blended = trilinear(&atlas.texels, first, edge, edge * edge, f);
                    assert_eq!(one.to_bits(), blended.to_bits(), "level {level} at {p}");
                    let (a, b) = atlas.sample_slot_with(&atlas, base, edge, p);
                    assert_eq!(
                        [a, b].map(f32::to_bits),
                        [one.to_bits(); 2],
                        "level {level} at {p}"
                    );
                }
            }
        }
    }

    #[test]
    fn central_differences_across_a_face_are_those_of_the_field_the_slots_hold() {
        // A level-0 block (slot 0) and its six face neighbours (slots 1–6),
        // each slot holding its part of one uneven field, aprons included.
        let field = |w: [i32; 3]| {
            let i = (w[0] + 40) * 1009 + (w[1] + 40) * 7919 + (w[2] + 40) * 104_729;
            (i % 997) as f32 / 997.0 + (w[0] as f32 * 0.3).sin()
        };
        let offsets: [[i32; 3]; 7] = [
            [0, 0, 0],
            [-1, 0, 0],
            [1, 0, 0],
            [0, -1, 0],
            [0, 1, 0],
            [0, 0, -1],
            [0, 0, 1],
        ];
        let selection = LodSelection::from_levels(vec![0u8; 7]);
        let packing = Packing::new(&selection, 2048).expect("packing");
        let mut atlas = SlotAtlas::new(&packing);
        let e = LEVEL0_EDGE as i32;
        for (b, o) in offsets.iter().enumerate() {
            let slot = atlas.slot_mut(b, 0).expect("slot");
            for (i, t) in slot.iter_mut().enumerate() {
                let c = [i as i32 % e, i as i32 / e % e, i as i32 / (e * e)];
                *t = field([0, 1, 2].map(|a| o[a] * 16 + c[a] - 1));
            }
        }
        let base = |b: usize| atlas.slot_base(b).expect("stored");
        let across = [
            [Some(base(1)), Some(base(2))],
            [Some(base(3)), Some(base(4))],
            [Some(base(5)), Some(base(6))],
        ];
        // The field's trilinear reconstruction at slot position q of slot 0.
        let read = |q: Vec3| {
            let c = q.floor();
            let f = q - c;
            let mut sum = 0.0;
            for corner in 0..8 {
                let d: [i32; 3] = [corner & 1, corner >> 1 & 1, corner >> 2];
                let w = [0, 1, 2].map(|a| c[a] as i32 + d[a] - 1);
                let weight = [0, 1, 2]
                    .map(|a| if d[a] == 1 { f[a] } else { 1.0 - f[a] })
                    .iter()
                    .product::<f32>();
                sum += weight * field(w);
            }
            sum
        };
        let mut across_faces = 0;
        for k in 0..2000 {
            // Slot positions in the block's interior (0.5 to 16.5), every
            // other one within half a texel of a face along each axis.
            let f = |s: f32| {
                let u = (k as f32 * s).sin() * 0.5 + 0.5;
                if k % 2 == 0 {
                    0.5 + u * 15.99
                } else if u < 0.5 {
                    0.5 + u
                } else {
                    16.0 + (u - 0.5) * 0.99
                }
            };
            let p = Vec3::new(f(1.3), f(2.7), f(0.9));
            let ours = match atlas.central_differences(base(0), p) {
                Some(d) => d,
                None => {
                    across_faces += 1;
                    atlas
                        .central_differences_across(base(0), p, across)
                        .expect("the faces' slots are given")
                }
            };
            let expected = Vec3::new(
                read(p + Vec3::X) - read(p - Vec3::X),
                read(p + Vec3::Y) - read(p - Vec3::Y),
                read(p + Vec3::Z) - read(p - Vec3::Z),
            );
            assert!(
                (ours - expected).abs().max_element() < 1e-4,
                "at {p}: {ours} vs {expected}"
            );
            // Without the slot a read needs, no answer.
            let x = p.x - 0.5;
            if !(0.5..15.5).contains(&x) {
                let mut without = across;
                without[0] = [None, None];
                assert!(
                    atlas
                        .central_differences_across(base(0), p, without)
                        .is_none()
                );
            }
        }
        assert!(
            across_faces > 200,
            "{across_faces} positions read across a face"
        );
    }

    #[test]
    fn slots_to_write_at_once_are_each_stored_block_s_own_once() {
        let lod = vec![0u8, EMPTY, 2, 0, 1];
        let packing = Packing::new(&LodSelection::from_levels(lod.clone()), 2048).expect("packing");
        let mut atlas = SlotAtlas::new(&packing);
        // Named out of order, one twice, one not stored, one beyond the grid.
        for (b, slot) in atlas.slots_mut([4, 0, 1, 3, 0, 2, 9], &lod) {
            slot.fill(b as f32 + 1.0);
        }
        for b in [0usize, 2, 3, 4] {
            let slot = atlas.slot_mut(b, usize::from(lod[b])).expect("stored");
            let e = slot_edge(usize::from(lod[b])) as usize;
            assert_eq!(slot.len(), e * e * e);
            assert!(
                slot.iter().all(|&t| t == b as f32 + 1.0),
                "block {b}'s slot"
            );
        }
        let written = atlas.texels().iter().filter(|&&t| t != 0.0).count();
        let slots: usize = [0usize, 2, 3, 4]
            .iter()
            .map(|&b| (slot_edge(usize::from(lod[b])) as usize).pow(3))
            .sum();
        assert_eq!(written, slots, "texels outside the slots");
    }
}
