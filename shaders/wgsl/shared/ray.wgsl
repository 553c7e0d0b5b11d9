// ray: where a ray meets an axis-aligned box.
// CPU twin: shaders/src/cpu/march.rs `intersect_box`.

// Distances along a texture-space ray (origin, dir per mm of model space) to
// where it enters and leaves the box lo..hi; enter > exit when it misses.
fn intersect_box(origin: vec3<f32>, dir: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> vec2<f32> {
    // Avoid dividing by an exact zero: a tiny component stands in for it.
    let safe_dir = select(dir, vec3<f32>(1e-12), abs(dir) < vec3<f32>(1e-12));
    let inv = 1.0 / safe_dir;
    let t0 = (lo - origin) * inv;
    let t1 = (hi - origin) * inv;
    let near = min(t0, t1);
    let far = max(t0, t1);
    let enter = max(max(near.x, near.y), max(near.z, 0.0));
    let exit = min(min(far.x, far.y), far.z);
    return vec2<f32>(enter, exit);
}
