//! CPU twin of the `raycast` stage over packed blocks (`shaders/wgsl/raycast.wgsl`),
//! function for function: the march of [`super::march`] over [`PackedTexture`].

use glam::Vec3;
use wide::f32x4;

use super::march::{CubicReads, Isa, Span, Storage, TfTable, faint, far_face_crossing, march_on};
use super::occupancy::VisibleBox;
use super::packed::{
    BLOCK, BlockLocation, EMPTY_LEVEL, PackedTexture, block_of, block_texel, empty_exit, voxel_edge,
};
use super::slot_atlas::{LEVEL0_EDGE, SLOT_APRON, cubic_gradient_of};
use super::texture::floor3;
use crate::illumination::Mode;
use crate::packed_volume::PackedVolume;
use crate::raycast::{FLAG_CUBIC_GRADIENT, FLAG_SKIP_EMPTY, RaycastParams};

/// How far (level-0 voxels) inside its block's faces a light read must lie
/// to be read from the sample's block without locating it: rounding moves
/// `block_of`'s faces by about 10⁻⁴ voxel.
const LIGHT_MARGIN: f32 = 1e-2;

impl Storage for PackedTexture {
    type Location = BlockLocation;

    fn locate(&self, p: &RaycastParams, tc: Vec3) -> BlockLocation {
        PackedTexture::locate(self, &p.volume, tc)
    }

    #[inline(always)]
    fn span(&self, p: &RaycastParams, origin: Vec3, dir: Vec3, t: f32) -> Span<BlockLocation> {
        let g = &p.volume;
        let block = block_of(g, origin + dir * t);
        let cell = Vec3::new(block[0] as f32, block[1] as f32, block[2] as f32);
        let t_max = far_face_crossing(cell, Vec3::from(g.texel) * BLOCK, origin, dir);
        let skipping = p.flags & FLAG_SKIP_EMPTY != 0;
        self.block_span(g, skipping, origin, dir, block, t_max, t)
    }

    #[inline(always)]
    fn next_span(
        &self,
        p: &RaycastParams,
        origin: Vec3,
        dir: Vec3,
        span: &Span<BlockLocation>,
        t: f32,
    ) -> Span<BlockLocation> {
        // A walk of the block grid: into the neighbour across the nearest
        // face, until the block holding the sample at `t`, or with
        // empty-space skipping the first stored block at or after it.
        let g = &p.volume;
        let skipping = p.flags & FLAG_SKIP_EMPTY != 0;
        let edge = Vec3::from(g.texel) * BLOCK;
        let t_delta = (edge / dir.abs()).min(Vec3::INFINITY);
        let (mut block, mut t_max) = (span.loc.block, span.t_max);
        let last = self.grid.map(|n| n as i32 - 1);
        loop {
            let axis = if t_max.x <= t_max.y && t_max.x <= t_max.z {
                0
            } else if t_max.y <= t_max.z {
                1
            } else {
                2
            };
            let enter = t_max[axis];
            block[axis] += if dir[axis] > 0.0 { 1 } else { -1 };
            t_max[axis] += t_delta[axis];
            if !(0..=last[axis]).contains(&block[axis]) {
                if skipping {
                    // Past the last stored block: nothing more to sample
                    // (the walk's rounding can cut a ray short by a hair
                    // where it leaves through an edge of the grid).
                    return Span {
                        enter: f32::INFINITY,
                        ..*span
                    };
                }
                // Out of the grid (rounding at the volume's edge): find the
                // sample's block anew.
                return self.span(p, origin, dir, t);
            }
            if t >= t_max.min_element() {
                continue;
            }
            if !skipping || self.index[self.block_index(block)][3] != EMPTY_LEVEL {
                let mut next = self.block_span(g, skipping, origin, dir, block, t_max, t);
                if t < enter {
                    next.enter = next.enter.max(enter);
                }
                return next;
            }
        }
    }

    #[inline(always)]
    fn sample_in(&self, _p: &RaycastParams, span: &Span<BlockLocation>, t: f32, _tc: Vec3) -> f32 {
        let loc = &span.loc;
        self.atlas.sample_slot(
            loc.slot,
            loc.slot_edge,
            span.texel_at_zero + span.texel_per_t * t,
        )
    }

    #[inline(always)]
    fn sample4_in(
        &self,
        p: &RaycastParams,
        span: &Span<BlockLocation>,
        ts: [f32; 4],
        _origin: Vec3,
        _dir: Vec3,
    ) -> Option<[f32; 4]> {
        let t = f32x4::from(ts);
        let (a, b) = (span.texel_at_zero, span.texel_per_t);
        let axis = |a: f32, b: f32| f32x4::splat(a) + f32x4::splat(b) * t;
        let visible = self
            .visible_texels
            .as_deref()
            .filter(|_| p.flags & FLAG_SKIP_EMPTY != 0);
        self.atlas.sample_slot4(
            span.loc.slot,
            span.loc.slot_edge,
            [axis(a.x, b.x), axis(a.y, b.y), axis(a.z, b.z)],
            visible,
        )
    }

    #[inline(always)]
    fn gradient_in(
        &self,
        p: &RaycastParams,
        span: &Span<BlockLocation>,
        t: f32,
        tc: Vec3,
        weight: f32,
    ) -> Vec3 {
        let loc = &span.loc;
        let centre = span.texel_at_zero + span.texel_per_t * t;
        let h = Vec3::from(p.volume.texel);
        if faint(p, weight) {
            // The slot's texel centres are at whole `centre`.
            return self
                .atlas
                .nearest_differences(loc.slot, loc.slot_edge, centre)
                / (2.0 * h * voxel_edge(loc));
        }
        if p.flags & FLAG_CUBIC_GRADIENT != 0 {
            // The slot's texel centres are at whole `centre`, the block's
            // faces at ½ and edge − 1.5. Where every read is inside the
            // block (what `sample_neighbour` finds there), they are read
            // from its slot; else `sample_neighbour` reads them as the
            // shader does. The reads lie within the 4³ texels about
            // `centre` (from floor − 1 to floor + 2): where those are a
            // texel from the slot's edge, every read is inside, known
            // without the reads' positions (a dozen divisions).
            let per_voxel = h * voxel_edge(loc);
            let corner = centre.floor();
            let deep = loc.slot_edge as f32 - 4.0;
            let face = loc.slot_edge as f32 - 1.5;
            let inside =
                |x: Vec3| x.cmpge(Vec3::splat(0.5)).all() && x.cmplt(Vec3::splat(face)).all();
            // Every read in the block: its 4³ texels are in the slot. (No
            // closure for it: one called twice is compiled apart from the
            // march, without the instructions the march is built for.)
            let mut reads = None;
            if !(corner.cmpge(Vec3::splat(2.0)).all() && corner.cmple(Vec3::splat(deep)).all()) {
                let found = CubicReads::at(centre);
                let low = found.derivative_at[0].min(found.smooth_at[0]);
                let high = found.derivative_at[1].max(found.smooth_at[1]);
                if !(inside(low) && inside(high)) {
                    reads = Some((found, low, high));
                }
            }
            let Some((reads, low, high)) = reads else {
                return self.atlas.cubic_gradient(loc.slot, loc.slot_edge, centre) / per_voxel;
            };
            if let Some(g) = self.cubic_gradient_across(loc, centre, low, high) {
                return g / per_voxel;
            }
            // Near a face: the reads in the block from its slot, the others
            // from the slot of the block `sample_neighbour` finds them in,
            // each block found once while the reads stay in it.
            let interior = loc.slot_edge as f32 - 2.0 * SLOT_APRON;
            let mut last: Option<Beyond> = None;
            let g = reads.gradient(|x| {
                if inside(x) {
                    return self.atlas.sample_slot(loc.slot, loc.slot_edge, x);
                }
                // Slot position x lies x − ½ level voxels from the block's
                // corner: the blocks it is past along each axis.
                let s = ((x - Vec3::splat(SLOT_APRON - 0.5)) / interior).floor();
                let step = [s.x as i32, s.y as i32, s.z as i32];
                let there = match last {
                    Some(there) if there.step == step => there,
                    _ => *last.insert(self.beyond(loc, step)),
                };
                self.atlas
                    .sample_slot(there.slot, there.edge, there.position(x))
            });
            return g / per_voxel;
        }
        let local = span.local_at_zero + span.local_per_t * t;
        // A voxel from the block's faces along an axis, both neighbours
        // along it are in the block (what `sample_neighbour` finds), so
        // they are read from its slot.
        let inner = local.cmpge(Vec3::ONE) & local.cmplt(Vec3::splat(BLOCK - 1.0));
        // At level 0 the neighbours are a texel away. Within a voxel of a
        // face, the neighbour beyond it is read from the next block's slot,
        // whose texels this slot's apron holds where that block is stored
        // at level 0 too: this slot has them all where the sample is at
        // least half a voxel from the face; nearer, the reads reach one
        // texel past the apron, read from that block's slot.
        if loc.slot_edge == LEVEL0_EDGE
            && let Some(across) = if inner.all() {
                Some([[None; 2]; 3])
            } else {
                self.faces_reached_at_level0(loc, local)
            }
            && let Some(differences) = match self.atlas.central_differences(loc.slot, centre) {
                None => self
                    .atlas
                    .central_differences_across(loc.slot, centre, across),
                found => found,
            }
        {
            return differences / (2.0 * h);
        }
        let at = |p: Vec3| self.atlas.sample_slot(loc.slot, loc.slot_edge, p);
        let mut differences = Vec3::ZERO;
        for axis in 0..3 {
            let mut d = Vec3::ZERO;
            d[axis] = loc.scale;
            differences[axis] = if inner.test(axis) {
                at(centre + d) - at(centre - d)
            } else {
                // Within a voxel of a face: the neighbour beyond it may be
                // in the next block, the other one is in this one.
                let mut step = Vec3::ZERO;
                step[axis] = h[axis];
                if local[axis] < 1.0 {
                    at(centre + d) - self.sample_neighbour(p, tc - step, loc)
                } else {
                    self.sample_neighbour(p, tc + step, loc) - at(centre - d)
                }
            };
        }
        differences / (2.0 * h)
    }

    fn is_empty(loc: &BlockLocation) -> bool {
        loc.empty
    }

    #[inline(always)]
    fn sample_at(&self, p: &RaycastParams, tc: Vec3, loc: &BlockLocation) -> f32 {
        self.sample_block(&p.volume, tc, loc)
    }

    fn voxel_edge(loc: &BlockLocation) -> f32 {
        voxel_edge(loc)
    }

    #[inline(always)]
    fn sample_neighbour(&self, p: &RaycastParams, tc: Vec3, home: &BlockLocation) -> f32 {
        let g = p.volume;
        let b = floor3(tc * Vec3::from(g.volume_dims) / BLOCK);
        let block = [b.x as i32, b.y as i32, b.z as i32];
        if block == home.block {
            return self.sample_at(p, tc, home);
        }
        let other = Storage::locate(self, p, tc);
        if other.empty {
            return self.sample_at(p, tc, home);
        }
        self.sample_at(p, tc, &other)
    }

    fn nearest_difference_at(&self, p: &RaycastParams, tc: Vec3, loc: &BlockLocation) -> Vec3 {
        let centre = block_texel(&p.volume, tc, loc) + (SLOT_APRON - 0.5);
        let h = Vec3::from(p.volume.texel);
        self.atlas
            .nearest_differences(loc.slot, loc.slot_edge, centre)
            / (2.0 * h * voxel_edge(loc))
    }

    #[inline(always)]
    fn light_at(&self, p: &RaycastParams, span: &Span<BlockLocation>, t: f32, tc: Vec3) -> Vec3 {
        let loc = &span.loc;
        match (self.lit_by, &self.light_cache, &self.light) {
            // shared/light_cache.wgsl: grid-shaped, read at tc.
            (Some(Mode::Extinction), Some(cache), _) => cache.sample_level(tc),
            // shared/light_volume.wgsl: in the block tc lies in, else in
            // `loc`'s, read from that block's slot (its eight texels are in it).
            (Some(Mode::GlobalLight), _, Some(light)) => {
                // Well inside the sample's block (the usual case), tc's
                // block is that one: its slot position is the stretch's
                // affine map at t (the same texels and weights up to
                // rounding), no lookup.
                let local = span.local_at_zero + span.local_per_t * t;
                if local.cmpge(Vec3::splat(LIGHT_MARGIN)).all()
                    && local.cmple(Vec3::splat(BLOCK - LIGHT_MARGIN)).all()
                {
                    let at = span.texel_at_zero + span.texel_per_t * t;
                    return Vec3::splat(light.sample_slot(loc.slot, loc.slot_edge, at));
                }
                let there = self.locate_near(&p.volume, tc, loc);
                let home = if there.empty { loc } else { &there };
                Vec3::splat(light.sample_block(&p.volume, tc, home))
            }
            _ => Vec3::ONE,
        }
    }

    fn empty_exit(&self, p: &RaycastParams, origin: Vec3, dir: Vec3, loc: &BlockLocation) -> f32 {
        empty_exit(&p.volume, origin, dir, loc)
    }

    fn visible_cells(&self, p: &RaycastParams) -> Option<&[VisibleBox]> {
        self.visible_cells
            .as_deref()
            .filter(|_| p.flags & FLAG_SKIP_EMPTY != 0)
    }

    #[inline(always)]
    fn visible_extent(&self, p: &RaycastParams) -> Option<(Vec3, Vec3)> {
        self.visible_extent
            .filter(|_| p.flags & FLAG_SKIP_EMPTY != 0)
            .map(|b| (b.lo, b.hi))
    }
}

impl PackedTexture {
    /// For a sample at `local` (level-0 voxels in `loc`'s block, a block
    /// at level 0), the slots of the blocks its central differences' reads
    /// beyond a face of `loc`'s reach (`[axis][side]`, side 0 below and 1
    /// above; `None` where they do not go): the one across each face within
    /// a voxel of the sample (reads step along one axis at a time, so never
    /// a diagonal neighbour). `None` unless each is stored at level 0 (or
    /// where it is outside the grid).
    #[inline(always)]
    fn faces_reached_at_level0(
        &self,
        loc: &BlockLocation,
        local: Vec3,
    ) -> Option<[[Option<usize>; 2]; 3]> {
        let level = self.index[self.block_index(loc.block)][3];
        let mut across = [[None; 2]; 3];
        for a in 0..3 {
            let side = if local[a] < 1.0 {
                0
            } else if local[a] >= BLOCK - 1.0 {
                1
            } else {
                continue;
            };
            let mut block = loc.block;
            block[a] += if side == 0 { -1 } else { 1 };
            if !(0..self.grid[a] as i32).contains(&block[a]) {
                return None;
            }
            let b = self.block_index(block);
            if self.index[b][3] != level {
                return None;
            }
            across[a][side] = Some(self.atlas.slot_base(b)?);
        }
        Some(across)
    }

    /// Where reads at positions of `home`'s slot that lie `step` blocks
    /// away (per axis) are read: in the slot of the block there (the grid's
    /// edge block where that is outside it), or, where that block is
    /// empty, in `home`'s own, clamped to its apron; as `sample_neighbour`
    /// and `atlas_texel` find them.
    fn beyond(&self, home: &BlockLocation, step: [i32; 3]) -> Beyond {
        let last = self.grid.map(|n| n as i32 - 1);
        let block = [0, 1, 2].map(|a| (home.block[a] + step[a]).clamp(0, last[a]));
        let there = self.locate_block(block);
        let read = if there.empty { home } else { &there };
        let corner = |l: &BlockLocation| glam::IVec3::from(l.block).as_vec3();
        Beyond {
            step,
            slot: read.slot,
            edge: read.slot_edge,
            ratio: read.scale / home.scale,
            offset: ((corner(home) - corner(read)) * BLOCK - 0.5 / home.scale) * read.scale,
            high: BLOCK * read.scale + 0.5,
        }
    }

    /// [`SlotAtlas::cubic_gradient`] (per texel of `loc`'s level) at slot
    /// position `centre` whose reads, from `low` to `high`, cross a face of
    /// `loc`'s block, where every block they reach is stored at its level:
    /// then each read beyond the face, which `sample_neighbour` takes from
    /// the neighbour's slot, blends the texels the neighbour's slot and this
    /// one's apron hold alike, so the 4³ texels are gathered from the slots
    /// they lie in and weighed directly. Where no block they reach is stored,
    /// `sample_neighbour` reads this block's slot clamped to its apron, so
    /// the texels beyond its edge are its edge's. `None` where a block they
    /// reach is at another level, or some are stored and some not (the reads
    /// then go through `sample_neighbour`).
    ///
    /// [`SlotAtlas::cubic_gradient`]: super::SlotAtlas::cubic_gradient
    #[inline]
    fn cubic_gradient_across(
        &self,
        loc: &BlockLocation,
        centre: Vec3,
        low: Vec3,
        high: Vec3,
    ) -> Option<Vec3> {
        let edge = loc.slot_edge as i32;
        let face = edge as f32 - 1.5;
        let interior = edge - 2 * SLOT_APRON as i32;
        let level = self.index[self.block_index(loc.block)][3];
        // Per axis, the neighbour the reads reach (−1, 0 or +1).
        let mut side = [0i32; 3];
        for a in 0..3 {
            let (below, above) = (low[a] < 0.5, high[a] >= face);
            side[a] = match (below, above) {
                (false, false) => 0,
                (true, false) => -1,
                (false, true) => 1,
                (true, true) => return None,
            };
        }
        // The slots of the blocks reached, by which axes step to the side
        // (bit 0 x, 1 y, 2 z). Either every block reached is stored at this
        // level (`Some(true)`), or none is (`Some(false)`: empty, or outside
        // the grid where `block_of` finds this block again), and
        // `sample_neighbour` reads this slot, clamped to its apron, as a
        // clamp to the edge of its texels does.
        let mut bases = [loc.slot; 8];
        let mut stored = None;
        for (c, base) in bases.iter_mut().enumerate() {
            let mut block = loc.block;
            let mut skip = c == 0;
            for a in 0..3 {
                if c >> a & 1 != 0 {
                    skip |= side[a] == 0;
                    block[a] += side[a];
                }
            }
            if skip {
                continue;
            }
            let inside = (0..3).all(|a| (0..self.grid[a] as i32).contains(&block[a]));
            let here = if inside {
                let b = self.block_index(block);
                match self.index[b][3] {
                    EMPTY_LEVEL => false,
                    l if l == level => {
                        *base = self.atlas.slot_base(b)?;
                        true
                    }
                    _ => return None,
                }
            } else {
                let last = self.grid.map(|n| n as i32 - 1);
                let clamped = [0, 1, 2].map(|a| block[a].clamp(0, last[a]));
                if clamped != loc.block {
                    return None;
                }
                false
            };
            if *stored.get_or_insert(here) != here {
                return None;
            }
        }
        let beyond = stored.unwrap_or(false);
        // Per axis and texel of the 4³: whether it lies beyond the face, and
        // where in its slot.
        let i = centre.floor();
        let first = [i.x as i32 - 1, i.y as i32 - 1, i.z as i32 - 1];
        let mut at = [[(0usize, 0usize); 4]; 3];
        for a in 0..3 {
            for (t, slot) in at[a].iter_mut().enumerate() {
                let x = first[a] + t as i32;
                let (step, inside) = if x < 0 {
                    (-1, if beyond { x + interior } else { 0 })
                } else if x > edge - 1 {
                    (1, if beyond { x - interior } else { edge - 1 })
                } else {
                    (0, x)
                };
                if step != 0 && step != side[a] {
                    return None;
                }
                *slot = (usize::from(step != 0) << a, inside as usize);
            }
        }
        let texels = self.atlas.texels();
        let e = loc.slot_edge;
        Some(cubic_gradient_of(centre - i, |k, j| {
            let (bz, z) = at[2][k];
            let (by, y) = at[1][j];
            let row = (z * e + y) * e;
            let [(b0, x0), (b1, x1), (b2, x2), (b3, x3)] = at[0];
            let texel = |b: usize, x: usize| texels[bases[b | by | bz] + row + x];
            f32x4::from([texel(b0, x0), texel(b1, x1), texel(b2, x2), texel(b3, x3)])
        }))
    }

    /// The stretch of the ray in `block`, which it leaves at the smallest of
    /// `t_max` (never before `t`). With empty-space `skipping`, its samples
    /// outside the block's [`VisibleBox`] are left out: the stretch begins
    /// (`enter`) where the ray enters the box and ends where it leaves it,
    /// or holds none where the ray misses it.
    #[inline(always)]
    #[expect(
        clippy::too_many_arguments,
        reason = "the walk's state, passed as it is"
    )]
    fn block_span(
        &self,
        g: &PackedVolume,
        skipping: bool,
        origin: Vec3,
        dir: Vec3,
        block: [i32; 3],
        t_max: Vec3,
        t: f32,
    ) -> Span<BlockLocation> {
        let loc = self.locate_block(block);
        let dims = Vec3::from(g.volume_dims);
        let corner = Vec3::new(block[0] as f32, block[1] as f32, block[2] as f32) * BLOCK;
        // `atlas_texel` unclamped, as a function of t.
        let local_at_zero = origin * dims - corner;
        let local_per_t = dir * dims;
        let texel_at_zero = local_at_zero * loc.scale + (SLOT_APRON - 0.5);
        let texel_per_t = local_per_t * loc.scale;
        let mut enter = f32::NEG_INFINITY;
        // Never behind `t`: a stretch ends at the next sample at the latest.
        let mut exit = t_max.min_element().max(t);
        if let Some(boxes) = self.visible_boxes.as_deref().filter(|_| skipping)
            && !loc.empty
        {
            let seen = boxes
                .get(self.block_index(block))
                .map_or((f32::NEG_INFINITY, f32::INFINITY), |b| {
                    b.interval(texel_at_zero, texel_per_t)
                });
            // The box's stretch of the ray within the block's (the box
            // reaches past the block where it reaches the slot's edge).
            let seen = (seen.0, seen.1.min(exit));
            if seen.0 < seen.1 && seen.1 > t {
                (enter, exit) = seen;
            } else {
                // No sample from `t` on can be visible: on to the next block.
                enter = exit;
            }
        }
        Span {
            loc,
            enter,
            exit,
            // Within the slot, whose first interior texel is at the apron's width.
            texel_at_zero,
            texel_per_t,
            local_at_zero,
            local_per_t,
            t_max,
        }
    }
}

/// The block that reads beyond a block's faces, `step` blocks away, are
/// read from ([`PackedTexture::beyond`]): its slot, and how a position in
/// the home block's slot maps into it.
#[derive(Debug, Clone, Copy)]
struct Beyond {
    step: [i32; 3],
    slot: usize,
    edge: usize,
    /// The block's texels per texel of the home block's level.
    ratio: f32,
    /// Where position 0 of the home block's slot lies, in this block's
    /// level voxels from its corner.
    offset: Vec3,
    /// The block's edge in its level voxels, plus ½: `atlas_texel`
    /// clamps to −½ … this.
    high: f32,
}

impl Beyond {
    /// The position in the block's slot of position `x` in the home
    /// block's slot (`atlas_texel` within the slot: clamped to its apron).
    #[inline(always)]
    fn position(&self, x: Vec3) -> Vec3 {
        (self.ratio * x + self.offset).clamp(Vec3::splat(-0.5), Vec3::splat(self.high))
            + Vec3::splat(0.5)
    }
}

/// Renders like the `raycast` dispatch: packed blocks through the block index
/// (lit by `packed.light` when the params say so).
pub fn raycast(
    params: &RaycastParams,
    packed: &PackedTexture,
    transfer_function: &TfTable,
    output: &mut [u8],
) {
    raycast_on(Isa::best(), params, packed, transfer_function, output);
}

/// [`raycast`] with the march built for `isa` (see [`march_on`]).
pub fn raycast_on(
    isa: Isa,
    params: &RaycastParams,
    packed: &PackedTexture,
    transfer_function: &TfTable,
    output: &mut [u8],
) {
    march_on(isa, params, packed, transfer_function, output);
}

#[cfg(test)]
mod tests {
    use blocks::lod::{EMPTY, LodSelection};
    use blocks::packing::{Packing, slot_edge};
    use glam::Vec3;

    use super::super::march::{Storage, central_difference_at, cubic_gradient_at};
    use super::super::packed::{
        BLOCK, BlockLocation, EMPTY_LEVEL, PackedTexture, RayBlocks, block_texel,
    };
    use super::super::slot_atlas::SlotAtlas;
    use crate::raycast::{FLAG_CUBIC_GRADIENT, RaycastParams};

    /// A smooth but uneven field of a level's voxel position.
    fn field(v: Vec3) -> f32 {
        (v.x * 0.37).sin() * (v.y * 0.23 + 0.4).cos() + 0.05 * v.z + 0.01 * v.x * v.y
    }

    /// 3³ blocks of 16³ voxels: most at level 0, one beside the centre
    /// empty, one at level 1 beside it, and two side by side at level 1 in
    /// a corner; every slot (apron included) holds the field at its level.
    fn blocks() -> (PackedTexture, RaycastParams) {
        let mut lod = vec![0u8; 27];
        lod[at(2, 1, 1)] = EMPTY;
        lod[at(1, 2, 1)] = 1;
        lod[at(0, 0, 0)] = 1;
        lod[at(1, 0, 0)] = 1;
        blocks_at(&lod)
    }

    /// Block (x, y, z)'s index in a grid of 3³.
    fn at(x: usize, y: usize, z: usize) -> usize {
        (z * 3 + y) * 3 + x
    }

    /// 3³ blocks of 16³ voxels at the levels `lod` gives (or empty); every
    /// slot (apron included) holds the field at its level.
    fn blocks_at(lod: &[u8]) -> (PackedTexture, RaycastParams) {
        let n = 3usize;
        let selection = LodSelection::from_levels(lod.to_vec());
        let packing = Packing::new(&selection, 2048).expect("packing");
        let mut atlas = SlotAtlas::new(&packing);
        let mut index = Vec::new();
        for (b, &level) in lod.iter().enumerate() {
            if level == EMPTY {
                index.push([0, 0, 0, EMPTY_LEVEL]);
                continue;
            }
            index.push([0, 0, 0, u16::from(level)]);
            let level = usize::from(level);
            let edge = slot_edge(level) as usize;
            let voxels = (BLOCK as usize) >> level;
            let corner =
                Vec3::new((b % n) as f32, (b / n % n) as f32, (b / (n * n)) as f32) * voxels as f32;
            let slot = atlas.slot_mut(b, level).expect("slot");
            for (i, t) in slot.iter_mut().enumerate() {
                let texel = Vec3::new(
                    (i % edge) as f32,
                    (i / edge % edge) as f32,
                    (i / (edge * edge)) as f32,
                );
                *t = field(corner + texel - Vec3::ONE);
            }
        }
        let packed = PackedTexture {
            atlas,
            index,
            grid: [n as u32; 3],
            light: None,
            light_cache: None,
            lit_by: None,
            visible_texels: None,
            visible_boxes: None,
            visible_extent: None,
            visible_cells: None,
        };
        let mut params: RaycastParams = bytemuck::Zeroable::zeroed();
        let voxels = (n as f32) * BLOCK;
        params.volume.texel = [1.0 / voxels; 3];
        params.volume.volume_dims = [voxels; 3];
        params.volume.block_grid = [n as u32; 3];
        params.flags = FLAG_CUBIC_GRADIENT;
        (packed, params)
    }

    #[test]
    fn a_light_ray_s_blocks_are_the_blocks_the_shader_locates() {
        let (packed, params) = blocks();
        let g = &params.volume;
        let mut near_faces = 0;
        for i in 0..2000u32 {
            let u = |k: u32| ((i * k) % 1009) as f32 / 1008.0;
            let origin = Vec3::new(u(37), u(101), u(53));
            // Some rays along an axis, some starting on a block's face.
            let dir = match i % 4 {
                0 => Vec3::new(0.0, 0.0, 1.0),
                1 => Vec3::new(u(71) - 0.5, u(13) - 0.5, u(29) - 0.5).normalize_or(Vec3::X),
                _ => Vec3::new(u(71) - 0.5, u(13) - 0.5, u(29) - 0.5).normalize_or(Vec3::Y),
            };
            let origin = if i % 4 == 2 {
                Vec3::new(16.0 / 48.0, origin.y, origin.z)
            } else {
                origin
            };
            let mut blocks = RayBlocks::new(&packed, g, origin, dir);
            // Steps of a third of a voxel, and samples just either side of
            // the faces the ray crosses.
            let mut t = 0.0f32;
            while t < 2.0 {
                let tc = origin + dir * t;
                if (0..3).any(|a| !(0.0..=1.0).contains(&tc[a])) {
                    break;
                }
                let want = packed.locate(g, tc);
                let got = *blocks.at(&packed, g, t);
                assert_eq!(got, want, "ray {i} from {origin} along {dir} at {t}");
                if !got.empty {
                    // `atlas_texel` in the slot (its first interior texel
                    // at 1), kept within the apron as the sample keeps it.
                    let slot = block_texel(g, tc, &got) + 0.5;
                    let edge = got.slot_edge as f32 - 1.0;
                    let position = blocks.slot_position(t).clamp(Vec3::ZERO, Vec3::splat(edge));
                    assert!(
                        (position - slot).abs().max_element() < 1e-3,
                        "ray {i} at {t}: slot position {position}, atlas_texel's {slot}"
                    );
                }
                let b = tc * 3.0;
                if (b - b.round()).abs().min_element() < 1e-3 {
                    near_faces += 1;
                }
                t = (t + 1.0 / 144.0).next_up();
            }
        }
        assert!(near_faces > 100, "only {near_faces} samples near faces");
    }

    #[test]
    fn cubic_gradients_near_block_faces_equal_the_shaders_reads_through_the_neighbours() {
        let (packed, params) = blocks();
        let (compared, near_face) = compare_cubic_gradients(&packed, &params);
        assert!(
            compared > 15_000 && near_face > 5_000,
            "{compared}, {near_face}"
        );
    }

    #[test]
    fn cubic_gradients_in_coarse_blocks_equal_the_shaders_reads_through_the_neighbours() {
        // Level 3 (2³ voxels a block: the reads reach past both faces of an
        // axis) beside levels 2 and 4 and an empty block: the reads of the
        // small slots of coarse levels cross faces everywhere.
        let mut lod = vec![3u8; 27];
        lod[at(0, 0, 0)] = 2;
        lod[at(1, 0, 0)] = 2;
        lod[at(2, 2, 2)] = 4;
        lod[at(0, 2, 2)] = EMPTY;
        let (packed, params) = blocks_at(&lod);
        let (compared, _) = compare_cubic_gradients(&packed, &params);
        assert!(compared > 15_000, "{compared}");
    }

    #[test]
    fn central_differences_near_block_faces_equal_the_shaders_reads_through_the_neighbours() {
        // Blocks at level 0 beside blocks at level 1 and an empty one.
        let (packed, mut params) = blocks();
        params.flags &= !FLAG_CUBIC_GRADIENT;
        let (compared, near_face) =
            compare_gradients(&packed, &params, central_difference_at::<PackedTexture>);
        assert!(
            compared > 15_000 && near_face > 5_000,
            "{compared}, {near_face}"
        );
    }

    #[test]
    fn faint_samples_nearest_texel_differences_are_the_shaders_reads() {
        // Blocks at levels 0, 1, 2, 3 and 4 and empty ones: the faint
        // samples' differences read from the span's slot position equal
        // WGSL `nearest_difference_at`'s from the sample's position.
        for lod in [vec![0u8; 27], {
            let mut lod = vec![1u8; 27];
            lod[at(0, 0, 0)] = 0;
            lod[at(1, 0, 0)] = 2;
            lod[at(2, 2, 2)] = 4;
            lod[at(1, 1, 1)] = 3;
            lod[at(0, 2, 2)] = EMPTY;
            lod
        }] {
            let (packed, mut params) = blocks_at(&lod);
            // Every sample of weight 1 (what `compare_gradients` asks) faint.
            params.faint_weight = 2.0;
            let (compared, near_face) = compare_gradients(&packed, &params, |s, p, tc, loc| {
                s.nearest_difference_at(p, tc, loc)
            });
            assert!(
                compared > 15_000 && near_face > 5_000,
                "{compared}, {near_face}"
            );
            // And they are the field's differences about the nearest voxel
            // of the block's level (the slots hold the field at their level).
            let h = params.volume.texel[0];
            let mut checked = 0;
            for i in 0..5_000u32 {
                let u = |k: u32| ((i.wrapping_mul(k) % 997) as f32 + 0.5) / 997.0;
                let v = Vec3::new(u(7919), u(104_729), u(1_299_709)) * 48.0;
                let tc = v / 48.0;
                let span = packed.span(&params, tc, Vec3::X, 0.0);
                if span.loc.empty {
                    continue;
                }
                let scale = span.loc.scale;
                let corner = Vec3::from(span.loc.block.map(|b| b as f32)) * BLOCK * scale;
                let n = (v * scale)
                    .floor()
                    .clamp(corner, corner + Vec3::splat(BLOCK * scale - 1.0));
                let want = Vec3::new(
                    field(n + Vec3::X) - field(n - Vec3::X),
                    field(n + Vec3::Y) - field(n - Vec3::Y),
                    field(n + Vec3::Z) - field(n - Vec3::Z),
                ) / (2.0 * h / scale);
                let got = packed.gradient_in(&params, &span, 0.0, tc, 1.0);
                assert!(
                    (got - want).abs().max_element() < 1e-3 * want.abs().max_element().max(1.0),
                    "at voxel {v} (block {:?}): {got} vs {want}",
                    span.loc.block
                );
                checked += 1;
            }
            assert!(checked > 4_000, "{checked}");
        }
    }

    /// [`compare_gradients`] with the shader's cubic gradient.
    fn compare_cubic_gradients(packed: &PackedTexture, params: &RaycastParams) -> (u32, u32) {
        compare_gradients(packed, params, cubic_gradient_at::<PackedTexture>)
    }

    /// Compares the gradient the ray caster takes from the slots with the
    /// shader's reads through `sample_neighbour` (`reference`, the shader's
    /// gradient function) at positions all over the volume: how many were
    /// compared, and how many lay within two voxels of a block's face.
    fn compare_gradients(
        packed: &PackedTexture,
        params: &RaycastParams,
        reference: fn(&PackedTexture, &RaycastParams, Vec3, &BlockLocation) -> Vec3,
    ) -> (u32, u32) {
        let params = *params;
        let dir = Vec3::new(0.6, 0.48, 0.64);
        let (mut compared, mut near_face) = (0, 0);
        for i in 0..20_000u32 {
            // Positions all over the volume, many within two voxels of a face.
            let u = |k: u32| ((i.wrapping_mul(k) % 9973) as f32 + 0.5) / 9973.0;
            let mut v = Vec3::new(u(7919), u(104_729), u(1_299_709)) * 48.0;
            if i % 2 == 0 {
                // Onto a face along one axis, give or take two voxels.
                let a = (i / 2 % 3) as usize;
                v[a] = (v[a] / BLOCK).round() * BLOCK + (u(31) - 0.5) * 4.0;
                v[a] = v[a].clamp(0.01, 47.99);
            }
            let tc = v / 48.0;
            let span = packed.span(&params, tc, dir, 0.0);
            if span.loc.empty {
                continue;
            }
            let local = v - Vec3::from(span.loc.block.map(|b| b as f32)) * BLOCK;
            if local.min_element() < 2.0 || local.max_element() > BLOCK - 2.0 {
                near_face += 1;
            }
            let direct = packed.gradient_in(&params, &span, 0.0, tc, 1.0);
            let reads = reference(packed, &params, tc, &span.loc);
            let scale = reads.abs().max_element().max(1.0);
            assert!(
                (direct - reads).abs().max_element() < 1e-3 * scale,
                "at voxel {v} (block {:?}): {direct} vs {reads}",
                span.loc.block
            );
            compared += 1;
        }
        (compared, near_face)
    }
}
