//! Packing selected blocks into one 3D atlas, ordered by level of detail rather
//! than by position, and the [`BlockIndex`] that maps each spatial block to its
//! place in the atlas: the "packed block coordinates" rendering and
//! illumination work in.
//!
//! # Layout
//! The atlas is a stack of regions along z, one per level, finest first. Region
//! l is a grid of equal slots of `(16 / 2^l + 2)³` voxels: the block and a
//! one-voxel **apron** copied from its spatial neighbours at the same level.
//! With the apron, hardware trilinear filtering and central-difference
//! gradients at a block's edge read the right neighbour values instead of
//! whatever block sits next to it in the atlas (the cost: (18/16)³ ≈ 1.42× the
//! voxels at level 0). Where neighbouring blocks have different levels, the
//! finer block's apron meets the coarser one's reconstruction instead
//! ([`crate::seams`]).
//!
//! # Updates
//! When the transfer function or the budget changes, [`Packing::update`] keeps
//! the layout if every region still has room: blocks that keep their level keep
//! their slot, leaving blocks free theirs, and new ones take free slots. Only
//! the blocks in [`PackingUpdate::uploads`] need new voxels on the GPU.

use crate::Error;
use crate::lod::{EMPTY, LodSelection};
use crate::store::{BLOCK, LEVELS};

/// Voxels of apron on each side of a packed block.
pub const APRON: u32 = 1;

/// The edge of a level-l slot: the block plus its apron.
pub const fn slot_edge(level: usize) -> u32 {
    (BLOCK >> level) + 2 * APRON
}

/// One level's region of the atlas.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Region {
    /// The atlas z where the region starts.
    pub z0: u32,
    /// Slots along x, y, z.
    pub slots: [u32; 3],
}

impl Region {
    /// How many slots the region has.
    pub fn capacity(&self) -> u32 {
        self.slots.iter().product()
    }
}

/// Where every selected block lives in the atlas.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packing {
    /// Atlas size in voxels (x, y, z).
    pub atlas_dims: [u32; 3],
    /// One region per level.
    pub regions: [Region; LEVELS],
    /// Per block: its level, or [`EMPTY`].
    pub lod: Vec<u8>,
    /// Per block: its slot number in its level's region (`u32::MAX` when empty).
    pub slot: Vec<u32>,
}

/// What changed between two packings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PackingUpdate {
    /// The new packing.
    pub packing: Packing,
    /// Blocks whose voxels must be (re)uploaded: new, or moved to another level or slot.
    pub uploads: Vec<usize>,
    /// Blocks no longer stored.
    pub removed: Vec<usize>,
    /// True when the layout itself changed (every block is in `uploads`).
    pub relayout: bool,
}

impl Packing {
    /// A fresh packing of `selection` in an atlas no larger than `max_edge` voxels
    /// on any side (the device's 3D texture limit).
    pub fn new(selection: &LodSelection, max_edge: u32) -> Result<Packing, Error> {
        let counts = selection.level_counts();
        let regions = layout(counts, max_edge)?;
        let atlas_dims = atlas_dims(&regions);
        let mut next = [0u32; LEVELS];
        let slot = selection
            .lod
            .iter()
            .map(|&l| {
                if l == EMPTY {
                    u32::MAX
                } else {
                    let s = next[l as usize];
                    next[l as usize] += 1;
                    s
                }
            })
            .collect();
        Ok(Packing {
            atlas_dims,
            regions,
            lod: selection.lod.clone(),
            slot,
        })
    }

    /// The packing for a new selection, reusing this one's layout and slots when
    /// the regions have room.
    pub fn update(&self, selection: &LodSelection, max_edge: u32) -> Result<PackingUpdate, Error> {
        let counts = selection.level_counts();
        let removed: Vec<usize> = (0..self.lod.len())
            .filter(|&b| self.lod[b] != EMPTY && selection.lod[b] == EMPTY)
            .collect();
        let fits = (0..LEVELS).all(|l| counts[l] as u64 <= u64::from(self.regions[l].capacity()));
        if !fits || selection.lod.len() != self.lod.len() {
            let packing = Packing::new(selection, max_edge)?;
            let uploads = (0..packing.lod.len())
                .filter(|&b| packing.lod[b] != EMPTY)
                .collect();
            return Ok(PackingUpdate {
                packing,
                uploads,
                removed,
                relayout: true,
            });
        }
        // Free slots per level: those not held by a block that keeps its level.
        let mut used: Vec<Vec<bool>> = self
            .regions
            .iter()
            .map(|r| vec![false; r.capacity() as usize])
            .collect();
        let mut slot = vec![u32::MAX; self.lod.len()];
        for b in 0..self.lod.len() {
            if selection.lod[b] != EMPTY && selection.lod[b] == self.lod[b] {
                slot[b] = self.slot[b];
                used[self.lod[b] as usize][self.slot[b] as usize] = true;
            }
        }
        let mut free: Vec<std::vec::IntoIter<u32>> = used
            .iter()
            .map(|u| {
                (0..u.len() as u32)
                    .filter(|&s| !u[s as usize])
                    .collect::<Vec<_>>()
                    .into_iter()
            })
            .collect();
        let mut uploads = Vec::new();
        for (b, (&l, s)) in selection.lod.iter().zip(slot.iter_mut()).enumerate() {
            if l != EMPTY && *s == u32::MAX {
                // Room was checked above: every region holds its count.
                *s = free[l as usize].next().unwrap_or(u32::MAX);
                uploads.push(b);
            }
        }
        Ok(PackingUpdate {
            packing: Packing {
                atlas_dims: self.atlas_dims,
                regions: self.regions,
                lod: selection.lod.clone(),
                slot,
            },
            uploads,
            removed,
            relayout: false,
        })
    }

    /// The atlas voxel where block `b`'s slot starts (its apron's corner).
    pub fn slot_origin(&self, b: usize) -> Option<[u32; 3]> {
        let level = *self.lod.get(b)? as usize;
        if level >= LEVELS {
            return None;
        }
        let r = self.regions[level];
        let s = self.slot[b];
        let edge = slot_edge(level);
        let (sx, sy) = (r.slots[0], r.slots[1]);
        Some([
            (s % sx) * edge,
            ((s / sx) % sy) * edge,
            r.z0 + (s / (sx * sy)) * edge,
        ])
    }

    /// Voxels the atlas holds (slots of selected blocks, aprons included).
    pub fn packed_voxels(&self) -> u64 {
        self.lod
            .iter()
            .filter(|&&l| l != EMPTY)
            .map(|&l| u64::from(slot_edge(l as usize)).pow(3))
            .sum()
    }

    /// The index a renderer reads: per spatial block of `grid`, the atlas voxel
    /// where the block's interior starts and its level.
    pub fn block_index(&self, grid: [u32; 3]) -> BlockIndex {
        let entries = (0..self.lod.len())
            .map(|b| match self.slot_origin(b) {
                Some(o) => {
                    let [x, y, z] = o.map(|v| (v + APRON) as u16);
                    [x, y, z, u16::from(self.lod[b])]
                }
                None => [0, 0, 0, BlockIndex::EMPTY],
            })
            .collect();
        BlockIndex { grid, entries }
    }
}

/// One texel per spatial block, ready for an `rgba16uint` 3D texture: the atlas
/// position (x, y, z) of the block's first interior voxel, and its level (or
/// [`BlockIndex::EMPTY`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BlockIndex {
    /// Blocks along x, y, z.
    pub grid: [u32; 3],
    /// `[x, y, z, level]` per block, x fastest.
    pub entries: Vec<[u16; 4]>,
}

impl BlockIndex {
    /// The level entry of a block that is not stored.
    pub const EMPTY: u16 = u16::MAX;
}

/// Region sizes for `counts` blocks per level, in an atlas whose x and y edge is
/// the same for all regions, chosen near the cube root of the total volume.
fn layout(counts: [usize; LEVELS], max_edge: u32) -> Result<[Region; LEVELS], Error> {
    let total: u64 = (0..LEVELS)
        .map(|l| counts[l] as u64 * u64::from(slot_edge(l)).pow(3))
        .sum();
    let slot0 = slot_edge(0);
    // Start near a cube and widen until the stack of regions fits in depth.
    let mut edge = ((total as f64).cbrt().ceil() as u32).div_ceil(slot0).max(1) * slot0;
    loop {
        let edge_now = edge.min(max_edge);
        let mut z = 0u32;
        let mut regions = [Region {
            z0: 0,
            slots: [0; 3],
        }; LEVELS];
        for (l, region) in regions.iter_mut().enumerate() {
            let s = slot_edge(l);
            let per_row = (edge_now / s).max(1);
            let layers = (counts[l] as u32).div_ceil(per_row * per_row);
            *region = Region {
                z0: z,
                slots: [per_row, per_row, layers],
            };
            z += layers * s;
        }
        if z <= max_edge {
            return Ok(regions);
        }
        if edge >= max_edge {
            return Err(Error::InvalidVolume {
                name: "atlas".into(),
                reason: format!(
                    "{total} voxels of blocks do not fit a 3D texture of {max_edge}³: expected a smaller budget"
                ),
            });
        }
        edge = (edge + slot0).min(max_edge);
    }
}

fn atlas_dims(regions: &[Region; LEVELS]) -> [u32; 3] {
    let x = (0..LEVELS)
        .map(|l| regions[l].slots[0] * slot_edge(l))
        .max()
        .unwrap_or(1)
        .max(1);
    let y = (0..LEVELS)
        .map(|l| regions[l].slots[1] * slot_edge(l))
        .max()
        .unwrap_or(1)
        .max(1);
    let last = regions[LEVELS - 1];
    let z = (last.z0 + last.slots[2] * slot_edge(LEVELS - 1)).max(1);
    [x, y, z]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn selection(lod: Vec<u8>) -> LodSelection {
        LodSelection::from_levels(lod)
    }

    /// No two blocks' slots overlap, and every slot lies inside the atlas.
    fn assert_disjoint(p: &Packing) {
        let mut boxes: Vec<([u32; 3], u32)> = Vec::new();
        for b in 0..p.lod.len() {
            if let Some(o) = p.slot_origin(b) {
                let e = slot_edge(p.lod[b] as usize);
                assert!(
                    (0..3).all(|a| o[a] + e <= p.atlas_dims[a]),
                    "block {b} at {o:?} outside {:?}",
                    p.atlas_dims
                );
                for (other, oe) in &boxes {
                    let overlap = (0..3).all(|a| o[a] < other[a] + oe && other[a] < o[a] + e);
                    assert!(!overlap, "block {b} at {o:?} overlaps a slot at {other:?}");
                }
                boxes.push((o, e));
            }
        }
    }

    #[test]
    fn slots_are_disjoint_and_ordered_by_level() {
        let lod = vec![0, 4, EMPTY, 1, 0, 2, 3, 1, EMPTY, 0];
        let p = Packing::new(&selection(lod.clone()), 2048).expect("packs");
        assert_disjoint(&p);
        // Level-0 slots come first in z.
        let z0 = p.slot_origin(0).expect("stored")[2];
        let z4 = p.slot_origin(1).expect("stored")[2];
        assert!(z0 < z4);
        let index = p.block_index([10, 1, 1]);
        assert_eq!(index.entries[2][3], BlockIndex::EMPTY);
        assert_eq!(index.entries[3][3], 1);
        let o = p.slot_origin(3).expect("stored");
        assert_eq!(
            index.entries[3][..3],
            [o[0] + 1, o[1] + 1, o[2] + 1].map(|v| v as u16)
        );
        assert_eq!(
            p.packed_voxels(),
            3 * 18u64.pow(3) + 2 * 10u64.pow(3) + 6u64.pow(3) + 4u64.pow(3) + 27
        );
    }

    #[test]
    fn updates_keep_slots_of_unchanged_blocks_and_upload_only_the_changed() {
        let p = Packing::new(&selection(vec![0, 0, 1, 1, 2, 4]), 2048).expect("packs");
        // Block 0 stays; block 1 leaves; block 5 moves up from level 4 to level 0 (region 0 has room).
        let u = p
            .update(&selection(vec![0, EMPTY, 1, 2, 2, 0]), 2048)
            .expect("updates");
        assert!(!u.relayout);
        assert_eq!(u.removed, vec![1]);
        assert_eq!(u.uploads, vec![3, 5]);
        assert_eq!(u.packing.slot_origin(0), p.slot_origin(0));
        assert_eq!(u.packing.slot_origin(2), p.slot_origin(2));
        assert_disjoint(&u.packing);
    }

    #[test]
    fn an_atlas_that_cannot_fit_is_refused() {
        let err = Packing::new(&selection(vec![0; 5000]), 64).expect_err("too small");
        assert!(
            err.to_string().contains("do not fit a 3D texture of 64³"),
            "{err}"
        );
    }
}
