// slot: which stored voxel an atlas texel is, for the light stages that run
// once per atlas texel. Needs the binding `slot_blocks: array<u32>` (per slot
// of every level's region, the block it holds, x fastest, or NO_BLOCK).
// CPU twin: shaders/src/cpu/global_light.rs `slot_texel`.

// An atlas texel as a stored voxel: its texture-space position (clamped into
// the volume's box: apron texels beyond the volume's edge repeat the edge,
// as the data's apron does), or valid = false for texels of no block and
// invocations beyond the atlas.
struct SlotTexel {
    valid: bool,
    tc: vec3<f32>,
}

fn slot_texel(texel: vec3<u32>) -> SlotTexel {
    var out: SlotTexel;
    out.valid = false;
    if any(vec3<f32>(texel) >= params.volume.atlas_size) {
        return out;
    }
    var first_slot = 0u;
    for (var level = 0u; level < 5u; level++) {
        let region = params.regions[level];
        let edge = (16u >> level) + 2u;
        let z_end = region.w + region.z * edge;
        if texel.z >= region.w && texel.z < z_end {
            let slot = vec3<u32>(texel.x / edge, texel.y / edge, (texel.z - region.w) / edge);
            if slot.x >= region.x || slot.y >= region.y {
                return out;
            }
            let b = slot_blocks[first_slot + (slot.z * region.y + slot.y) * region.x + slot.x];
            if b == NO_BLOCK {
                return out;
            }
            let grid = params.volume.block_grid;
            let block = vec3<u32>(b % grid.x, (b / grid.x) % grid.y, b / (grid.x * grid.y));
            // The texel's level-l index within the block: -1 and 16 / 2^l are apron.
            let q = vec3<f32>(texel - vec3<u32>(0u, 0u, region.w) - slot * edge) - 1.0;
            let size = f32(1u << level);
            let p = vec3<f32>(block) * BLOCK + (q + 0.5) * size;
            out.valid = true;
            out.tc = clamp(p / params.volume.volume_dims, vec3<f32>(0.0), vec3<f32>(1.0));
            return out;
        }
        first_slot += region.x * region.y * region.z;
    }
    return out;
}
