//! Which blocks and slots the illumination stages work on: the block each
//! atlas slot holds ([`slot_blocks`]), and the blocks near stored ones
//! ([`near_blocks`]), where a light term is ever read.

use blocks::packing::Packing;
use blocks::store::LEVELS;

/// Per slot of every level's region, in region order and slot order (x
/// fastest): the block it holds (its index in the block grid, x fastest), or
/// `u32::MAX`.
pub fn slot_blocks(packing: &Packing) -> Vec<u32> {
    let mut first = [0usize; LEVELS];
    let mut total = 0usize;
    for (l, r) in packing.regions.iter().enumerate() {
        first[l] = total;
        total += r.capacity() as usize;
    }
    let mut slots = vec![u32::MAX; total.max(1)];
    for (b, (&level, &slot)) in packing.lod.iter().zip(&packing.slot).enumerate() {
        if usize::from(level) < LEVELS {
            slots[first[usize::from(level)] + slot as usize] = b as u32;
        }
    }
    slots
}

/// Per block of the block grid (x fastest): 1 for blocks within
/// `margin_blocks` (along every axis) of a non-empty block, else 0 — where a
/// light term is ever read. `global_opacity` computes SVR points only there
/// (`direct_light` reads the SVR one segment from a stored voxel and
/// `in_scatter` at R_Ω from one), and the extinction stages fill only light-cache
/// cells there (the ray caster reads the cache two cells from a stored
/// sample: `extinction::near_cells_mask`),
/// so the light's cost follows the kept blocks, not the volume. A separable
/// dilation, so the cost is linear in blocks whatever the margin.
pub fn near_blocks(packing: &Packing, grid: [u32; 3], margin_blocks: u32) -> Vec<u32> {
    let [nx, ny, nz] = grid.map(|g| g as usize);
    let m = margin_blocks as usize;
    let mut mask: Vec<u32> = packing
        .lod
        .iter()
        .map(|&l| u32::from(usize::from(l) < LEVELS))
        .collect();
    mask.resize(nx * ny * nz, 0);
    let strides = [1, nx, nx * ny];
    for (axis, n) in [nx, ny, nz].into_iter().enumerate() {
        let stride = strides[axis];
        let mut next = vec![0u32; mask.len()];
        for (i, out) in next.iter_mut().enumerate() {
            let c = (i / stride) % n;
            let base = i - c * stride;
            let (lo, hi) = (c.saturating_sub(m), (c + m).min(n - 1));
            *out = u32::from((lo..=hi).any(|k| mask[base + k * stride] != 0));
        }
        mask = next;
    }
    mask
}
