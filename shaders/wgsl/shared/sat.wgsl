// sat: reading the 3D summed-area table of Δt·τ (and Δt·τ·RGB) that
// extinction_sat builds: 64-bit fixed-point sums as vec2<u32> (lo, hi), one
// array per channel, x fastest. Needs `params.grid`, `params.channels` and the
// bindings `sat_tau`, `sat_r`, `sat_g`, `sat_b` (array<vec2<u32>>).
// CPU twin: shaders/src/cpu/extinction.rs (`Sat`).

fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    return vec2<u32>(lo, a.y + b.y + select(0u, 1u, lo < a.x));
}

fn sub64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return vec2<u32>(a.x - b.x, a.y - b.y - select(0u, 1u, a.x < b.x));
}

// A non-negative fixed-point sum as Δt·τ.
fn depth_of(v: vec2<u32>) -> f32 {
    return (f32(v.y) * 4294967296.0 + f32(v.x)) / FIXED_ONE;
}

fn sat_index(c: vec3<i32>) -> u32 {
    let g = params.grid;
    return (u32(c.z) * g.y + u32(c.y)) * g.x + u32(c.x);
}

// The SAT entry of channel `ch` at cell c: the sum over cells 0..=c; zero when
// any coordinate is below 0.
fn sat_at(c: vec3<i32>, ch: u32) -> vec2<u32> {
    if any(c < vec3<i32>(0)) {
        return vec2<u32>(0u);
    }
    let i = sat_index(c);
    switch ch {
        case 0u: { return sat_tau[i]; }
        case 1u: { return sat_r[i]; }
        case 2u: { return sat_g[i]; }
        default: { return sat_b[i]; }
    }
}

// The exact sum of channel `ch` over the cells lo..=hi (clamped to the grid;
// zero when empty): eight SAT entries by inclusion–exclusion.
fn cuboid_sum(lo_in: vec3<i32>, hi_in: vec3<i32>, ch: u32) -> vec2<u32> {
    let lo = max(lo_in, vec3<i32>(0)) - vec3<i32>(1);
    let hi = min(hi_in, vec3<i32>(params.grid) - vec3<i32>(1));
    if any(hi <= lo) {
        return vec2<u32>(0u);
    }
    var plus = add64(sat_at(hi, ch), sat_at(vec3<i32>(lo.x, lo.y, hi.z), ch));
    plus = add64(plus, sat_at(vec3<i32>(lo.x, hi.y, lo.z), ch));
    plus = add64(plus, sat_at(vec3<i32>(hi.x, lo.y, lo.z), ch));
    var minus = add64(sat_at(vec3<i32>(lo.x, hi.y, hi.z), ch), sat_at(vec3<i32>(hi.x, lo.y, hi.z), ch));
    minus = add64(minus, sat_at(vec3<i32>(hi.x, hi.y, lo.z), ch));
    minus = add64(minus, sat_at(lo, ch));
    return sub64(plus, minus);
}
