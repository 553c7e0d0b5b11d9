// light_seams: level borders without a step in the stored light I_s, as
// blocks::seams makes them for the data. The stored light is atlas-shaped:
// each slot holds its block's light at the block's level with a one-texel
// apron, lit where each apron texel lies. Where a block meets a neighbour
// stored at a coarser level m, the ray caster filters the light on the block's
// side from the block's last texel and its apron, on the neighbour's side from
// the neighbour's level-m texels: two reconstructions that differ by the
// coarse level's interpolation error, a step at the border. Here each apron
// texel of the finer block facing the coarser one is set so that filtering
// inside the finer block, on the border, gives what the coarser block's slot
// gives there:
//   apron = 2^k · L_m(border) − (the 2^k − 1 other texels filtering blends there)
// with k the number of axes the texel lies outside its block along (1 on
// faces, 2 on edges, 3 at corners). The coarser block is left as it is.
//
// Passes (global_light::SEAM_PASSES): per level, coarsest first, so the
// coarser slots a pass reads are final; per level, faces, then edges, then
// corners, since each blends texels the earlier ones set. A pass runs after
// every in_scatter step and overwrites these texels whatever they held.
//
// Dispatch: one invocation per texel of level `params.seam_level`'s region of
// the atlas (x and y from 0, z from the region's first), workgroups of 4×4×4.
// Bindings (group 0):
//   0 params        uniform LightParams (seam_level, seam_outward)
//   1 block_index   texture_3d<u32> (rgba16uint)
//   2 slot_blocks   storage array<u32>: the block in each slot, or NO_BLOCK
//   3 light_volume  storage texture r32float, atlas-shaped I_s (read and written)
// CPU twin: shaders::cpu::global_light::light_seams (shaders/src/cpu/global_light.rs).

@group(0) @binding(0) var<uniform> params: LightParams;
@group(0) @binding(1) var block_index: texture_3d<u32>;
@group(0) @binding(2) var<storage, read> slot_blocks: array<u32>;
@group(0) @binding(3) var light_volume: texture_storage_3d<r32float, read_write>;

// The stored light of the level-m slot whose first interior texel is at
// atlas texel `origin`, filtered trilinearly at `u` (level-m texels from the
// first interior texel's centre), within the slot and its apron.
fn slot_light(origin: vec3<i32>, m: u32, u: vec3<f32>) -> f32 {
    let n = i32(16u >> m);
    let q = clamp(u, vec3<f32>(-1.0), vec3<f32>(f32(n)));
    let i0 = vec3<i32>(floor(q));
    let f = q - vec3<f32>(i0);
    let i1 = min(i0 + vec3<i32>(1), vec3<i32>(n));
    var corners: array<f32, 8>;
    for (var k = 0u; k < 8u; k++) {
        let pick = vec3<bool>((k & 1u) != 0u, (k & 2u) != 0u, (k & 4u) != 0u);
        corners[k] = textureLoad(light_volume, origin + select(i0, i1, pick)).r;
    }
    let x0 = mix(corners[0], corners[1], f.x);
    let x1 = mix(corners[2], corners[3], f.x);
    let x2 = mix(corners[4], corners[5], f.x);
    let x3 = mix(corners[6], corners[7], f.x);
    return mix(mix(x0, x1, f.y), mix(x2, x3, f.y), f.z);
}

@compute @workgroup_size(4, 4, 4)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let level = params.seam_level;
    let region = params.regions[level];
    let edge = (16u >> level) + 2u;
    let slot = gid / edge;
    if any(slot >= region.xyz) {
        return;
    }
    var first_slot = 0u;
    for (var l = 0u; l < level; l++) {
        let r = params.regions[l];
        first_slot += r.x * r.y * r.z;
    }
    let b = slot_blocks[first_slot + (slot.z * region.y + slot.y) * region.x + slot.x];
    if b == NO_BLOCK {
        return;
    }
    let grid = params.volume.block_grid;
    let block = vec3<i32>(vec3<u32>(b % grid.x, (b / grid.x) % grid.y, b / (grid.x * grid.y)));
    // The texel within the slot (0 and edge − 1 are apron) and the way out of
    // the block along each axis.
    let c = vec3<i32>(gid - slot * edge);
    let last = vec3<i32>(i32(edge) - 1);
    let d = select(vec3<i32>(0), vec3<i32>(-1), c == vec3<i32>(0))
        + select(vec3<i32>(0), vec3<i32>(1), c == last);
    let out = d != vec3<i32>(0);
    if u32(out.x) + u32(out.y) + u32(out.z) != params.seam_outward {
        return;
    }
    let n = block + d;
    if any(n < vec3<i32>(0)) || any(n >= vec3<i32>(grid)) {
        return;
    }
    let entry = textureLoad(block_index, n, 0);
    let m = entry.w;
    if m == EMPTY_LEVEL || m <= level {
        return;
    }
    // The border point filtering reaches half a texel out (level-0 voxels):
    // on the block's faces along d, at the apron texel's centre along the rest.
    let start = vec3<f32>(block) * BLOCK;
    var border = start + (vec3<f32>(c) - 0.5) * f32(1u << level);
    border = select(border, start + BLOCK, d == vec3<i32>(1));
    border = select(border, start, d == vec3<i32>(-1));
    let u = (border - vec3<f32>(n) * BLOCK) / f32(1u << m) - 0.5;
    let target_light = slot_light(vec3<i32>(entry.xyz), m, u);
    // Filtering there weighs equally this texel and the 2^k − 1 texels one
    // step inwards along any subset of the axes out.
    let texel = vec3<i32>(gid + vec3<u32>(0u, 0u, region.w));
    var others = 0.0;
    for (var mask = 1u; mask < 8u; mask++) {
        let step = vec3<bool>((mask & 1u) != 0u, (mask & 2u) != 0u, (mask & 4u) != 0u);
        if any(step & !out) {
            continue;
        }
        others += textureLoad(light_volume, texel - select(vec3<i32>(0), d, step)).r;
    }
    let corners = f32(1u << params.seam_outward);
    textureStore(light_volume, texel, vec4<f32>(corners * target_light - others, 0.0, 0.0, 0.0));
}
