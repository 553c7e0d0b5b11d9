// packed: addressing voxels in packed block coordinates (flat multiresolution
// blocking). The block index (rgba16uint, one texel per 16³ block) gives each
// block's slot in the atlas (the atlas position of its first interior texel)
// and its level, or EMPTY_LEVEL when the block is not stored. Slots hold the
// block at its level with a one-texel apron of its neighbours, so filtering
// inside a slot is right up to half a texel beyond the block.
// Needs `params.volume.volume_dims`, `params.volume.block_grid`, `params.volume.atlas_size`,
// `params.volume.texel` and the binding `block_index: texture_3d<u32>`.
// Constants in shared/blocks.wgsl.
// CPU twin: shaders/src/cpu/packed.rs.

struct Location {
    empty: bool,
    // The block (x, y, z in the block grid).
    block: vec3<i32>,
    // Atlas texel position of the block's first interior texel.
    origin: vec3<f32>,
    // Level-l texels per level-0 voxel: 1 / 2^level.
    scale: f32,
}

// The block texture coordinate tc falls in (clamped to the grid).
fn block_of(tc: vec3<f32>) -> vec3<i32> {
    let last = vec3<i32>(params.volume.block_grid) - vec3<i32>(1);
    return clamp(vec3<i32>(floor(tc * params.volume.volume_dims / BLOCK)), vec3<i32>(0), last);
}

fn locate(tc: vec3<f32>) -> Location {
    let block = block_of(tc);
    let entry = textureLoad(block_index, block, 0);
    var loc: Location;
    loc.empty = entry.w == EMPTY_LEVEL;
    loc.block = block;
    loc.origin = vec3<f32>(entry.xyz);
    loc.scale = 1.0 / f32(1u << min(entry.w, 4u));
    return loc;
}

// The edge of a voxel of block `loc`'s level, in level-0 voxels.
fn voxel_edge(loc: Location) -> f32 {
    return 1.0 / loc.scale;
}

// The normalized atlas coordinate of tc in block `loc`'s slot; positions outside
// the block are clamped to its apron, so filtering never reads another slot.
// Every atlas-shaped texture (data, local opacity, light) is read here.
fn atlas_coord(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    return (loc.origin + block_texel(tc, loc)) / params.volume.atlas_size;
}

// tc in block `loc`'s level texels from its corner (texel centres at whole
// + ½), kept within its apron.
fn block_texel(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    let p = tc * params.volume.volume_dims;
    let local = (p - vec3<f32>(loc.block) * BLOCK) * loc.scale;
    let edge = BLOCK * loc.scale;
    return clamp(local, vec3<f32>(-0.5), vec3<f32>(edge + 0.5));
}

// Where the ray (texture-space origin, direction per mm) leaves block `loc`
// (model-space t).
fn empty_exit(origin: vec3<f32>, dir: vec3<f32>, loc: Location) -> f32 {
    let lo = vec3<f32>(loc.block) * BLOCK * params.volume.texel;
    let hi = min(lo + BLOCK * params.volume.texel, vec3<f32>(1.0));
    return intersect_box(origin, dir, lo, hi).y;
}
