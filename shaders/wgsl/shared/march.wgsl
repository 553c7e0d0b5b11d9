// march: the per-pixel ray march shared by the `raycast` (packed blocks) and
// `reference` (one plain texture) stages. Each stage defines, for its storage:
//   struct Location { empty: bool, ... }          where a sample falls
//   fn locate(tc: vec3<f32>) -> Location
//   fn sample_at(tc: vec3<f32>, loc: Location) -> f32       texel value
//   fn sample_neighbour(tc: vec3<f32>, home: Location) -> f32
//                                    texel value near a sample in `home` (gradients)
//   fn empty_exit(origin: vec3<f32>, dir: vec3<f32>, loc: Location) -> f32
// and the bindings `params`, `transfer_function`, `output`.
// CPU twin: shaders/src/cpu/march.rs, loop for loop.

// Largest opacity fed to the opacity correction, so pow() never sees a zero base.
const MAX_SAMPLE_OPACITY: f32 = 0.9999;

// The transfer function at coordinate u (0..1), linearly interpolated between entry
// centres like a 1D texture with clamp to edge.
fn classify(u: f32) -> vec4<f32> {
    let n = i32(params.tf_len);
    let x = clamp(u, 0.0, 1.0) * f32(n) - 0.5;
    let i0f = floor(x);
    let f = x - i0f;
    let i0 = i32(i0f);
    let a = transfer_function[clamp(i0, 0, n - 1)];
    let b = transfer_function[clamp(i0 + 1, 0, n - 1)];
    return mix(a, b, f);
}

// Central differences one level-0 voxel apart around a sample in `loc`, per
// unit of texture coordinate.
fn gradient_at(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    let h = params.texel;
    let dx = vec3<f32>(h.x, 0.0, 0.0);
    let dy = vec3<f32>(0.0, h.y, 0.0);
    let dz = vec3<f32>(0.0, 0.0, h.z);
    let differences = vec3<f32>(
        sample_neighbour(tc + dx, loc) - sample_neighbour(tc - dx, loc),
        sample_neighbour(tc + dy, loc) - sample_neighbour(tc - dy, loc),
        sample_neighbour(tc + dz, loc) - sample_neighbour(tc - dz, loc),
    );
    return differences / (2.0 * h);
}

// Two-sided Blinn–Phong with the surface normal along the gradient g (transfer-
// function units per mm).
fn shade(rgb: vec3<f32>, g: vec3<f32>, view_dir: vec3<f32>) -> vec3<f32> {
    let magnitude = length(g);
    if magnitude < params.gradient_threshold {
        return rgb;
    }
    let n = g / magnitude;
    let l = params.light_dir;
    let h = normalize(l - view_dir);
    let diffuse = abs(dot(n, l));
    let specular = pow(abs(dot(n, h)), params.phong.w);
    return rgb * (params.phong.x + params.phong.y * diffuse) + vec3<f32>(params.phong.z * specular);
}

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

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    // The pixel's ray: through the pixel centre, from the near plane to the far
    // plane (right for perspective and orthographic projections alike).
    let pixel = vec2<f32>(f32(gid.x) + 0.5, f32(gid.y) + 0.5);
    let ndc = vec2<f32>(
        pixel.x / f32(params.width) * 2.0 - 1.0,
        1.0 - pixel.y / f32(params.height) * 2.0,
    );
    let near = params.inv_view_proj * vec4<f32>(ndc, 0.0, 1.0);
    let far = params.inv_view_proj * vec4<f32>(ndc, 1.0, 1.0);
    let origin = near.xyz / near.w;
    let dir = normalize(far.xyz / far.w - origin);
    // The same ray in texture space; t still counts mm of model space.
    let tex_origin = (params.texture_from_model * vec4<f32>(origin, 1.0)).xyz;
    let tex_dir = (params.texture_from_model * vec4<f32>(dir, 0.0)).xyz;

    let span = intersect_box(tex_origin, tex_dir, params.clip_min, params.clip_max);
    var color = vec3<f32>(0.0);
    var alpha = 0.0;
    var found = false;
    var extreme = 0.0;
    if span.x < span.y {
        var jitter = 0.0;
        if (params.flags & FLAG_JITTER) != 0u {
            jitter = unit_from_hash(pcg_hash(gid.y * params.width + gid.x));
        }
        let exponent = params.step / params.reference_step;
        let first = span.x + jitter * params.step;
        // Samples sit at t = first + i * step, whatever was skipped: skipping
        // jumps i past an empty block, so it changes no sample's position.
        var i = 0u;
        for (var k = 0u; k < params.max_steps; k++) {
            let t = first + f32(i) * params.step;
            if t > span.y {
                break;
            }
            let tc = tex_origin + tex_dir * t;
            let loc = locate(tc);
            if loc.empty {
                // Nothing to see here: on to the first sample past the block's exit.
                var next = i + 1u;
                if (params.flags & FLAG_SKIP_EMPTY) != 0u {
                    let exit = empty_exit(tex_origin, tex_dir, loc);
                    next = max(next, u32(ceil((exit - first) / params.step)));
                }
                i = next;
                continue;
            }
            let u = sample_at(tc, loc) * params.value_scale + params.value_offset;
            let rgba = classify(u);
            if rgba.a > 0.0 {
                if params.mode == MODE_COMPOSITE {
                    let a = 1.0 - pow(1.0 - min(rgba.a, MAX_SAMPLE_OPACITY), exponent);
                    var rgb = rgba.rgb;
                    if (params.flags & FLAG_SHADED) != 0u {
                        let g = (params.gradient_from_texture * vec4<f32>(gradient_at(tc, loc), 0.0)).xyz
                            * params.value_scale;
                        rgb = shade(rgb, g, dir);
                    }
                    color += (1.0 - alpha) * a * rgb;
                    alpha += (1.0 - alpha) * a;
                    if alpha >= params.early_termination {
                        break;
                    }
                } else if !found {
                    extreme = u;
                    found = true;
                } else if params.mode == MODE_MIP {
                    extreme = max(extreme, u);
                } else {
                    extreme = min(extreme, u);
                }
            }
            i += 1u;
        }
    }
    var out = color + (1.0 - alpha) * params.background.rgb;
    if params.mode != MODE_COMPOSITE {
        out = params.background.rgb;
        if found {
            let c = classify(extreme);
            out = c.rgb * c.a + (1.0 - c.a) * params.background.rgb;
        }
    }
    textureStore(output, vec2<i32>(gid.xy), vec4<f32>(clamp(out, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0));
}
