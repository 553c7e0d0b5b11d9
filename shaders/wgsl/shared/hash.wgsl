// pcg_hash: a 32-bit integer hash (PCG output function), for per-pixel jitter.
// keep in sync with shaders/src/cpu/hash.rs `pcg_hash`
fn pcg_hash(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// A value in 0..1 from the top 24 bits of a hash.
fn unit_from_hash(h: u32) -> f32 {
    return f32(h >> 8u) * (1.0 / 16777216.0);
}
