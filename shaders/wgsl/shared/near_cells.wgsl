// near_cells: which light-cache cells the ray caster can ever read. It reads
// the cache two cells from samples in stored blocks (LIGHT_READ_CELLS, see
// `extinction::near_cells_mask`), so only cells whose block
// lies within a margin of a stored block (the `near_blocks` mask, per block)
// are computed; the others are written neutral and never read. Needs
// `params.grid`, `params.volume.volume_dims`, `params.volume.block_grid`, BLOCK
// (shared/blocks.wgsl) and the binding `near_blocks: array<u32>`.
// CPU twin: shaders/src/cpu/extinction.rs `cell_is_read`.

fn cell_is_read(c: vec3<i32>) -> bool {
    let tc = (vec3<f32>(c) + 0.5) / vec3<f32>(params.grid);
    let last = vec3<i32>(params.volume.block_grid) - vec3<i32>(1);
    let b = clamp(vec3<i32>(floor(tc * params.volume.volume_dims / BLOCK)), vec3<i32>(0), last);
    let g = params.volume.block_grid;
    return near_blocks[u32(b.x) + g.x * (u32(b.y) + g.y * u32(b.z))] != 0u;
}
