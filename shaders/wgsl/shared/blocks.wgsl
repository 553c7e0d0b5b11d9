// blocks: constants of flat multiresolution blocking.
// keep in sync with blocks/src/packing.rs, blocks/src/store/stats.rs

// Edge of a block in level-0 voxels.
const BLOCK: f32 = 16.0;
// The block index's level entry of a block that is not stored.
const EMPTY_LEVEL: u32 = 65535u;
// A slot of the atlas that holds no block (slot_blocks).
const NO_BLOCK: u32 = 0xffffffffu;
