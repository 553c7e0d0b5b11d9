// march: the per-pixel ray march shared by the `raycast` (packed blocks) and
// `reference` (one plain texture) stages. Each stage defines, for its storage:
//   struct Location { empty: bool, ... }          where a sample falls
//   fn locate(tc: vec3<f32>) -> Location
//   fn light_at(tc: vec3<f32>, loc: Location) -> f32   stored light I_s (FLAG_LIT)
//   fn sample_at(tc: vec3<f32>, loc: Location) -> f32       texel value
//   fn sample_neighbour(tc: vec3<f32>, home: Location) -> f32
//                                    texel value near a sample in `home` (gradients)
//   fn nearest_difference_at(tc: vec3<f32>, loc: Location) -> vec3<f32>
//                                    central differences of the texel nearest tc
//                                    in `loc`, per unit of texture coordinate
//   fn voxel_edge(loc: Location) -> f32
//                                    the edge of a voxel of `loc`'s level, in level-0 voxels
//   fn empty_exit(origin: vec3<f32>, dir: vec3<f32>, loc: Location) -> f32
// and the bindings `params`, `transfer_function`, `output`.
// CPU twin: shaders/src/cpu/march.rs, loop for loop.

// Whether a sample of `weight` in its pixel (the ray's transparency before it
// times its class's opacity) is faint: shaded with its nearest texel's
// central differences, not the frame's normal.
fn faint(weight: f32) -> bool {
    return weight < params.faint_weight;
}

// The gradient at a sample in `loc` of `weight` in its pixel, per unit of
// texture coordinate: for a faint sample its nearest texel's central
// differences, else the cubic B-spline's (FLAG_CUBIC_GRADIENT, still frames)
// or central differences (interactive frames).
fn gradient_at(tc: vec3<f32>, loc: Location, weight: f32) -> vec3<f32> {
    if faint(weight) {
        return nearest_difference_at(tc, loc);
    }
    if (params.flags & FLAG_CUBIC_GRADIENT) != 0u {
        return cubic_gradient_at(tc, loc);
    }
    return central_difference_at(tc, loc);
}

// Central differences one level-0 voxel apart around a sample in `loc`, per
// unit of texture coordinate. Taken from the trilinear reconstruction, they
// change slope at every voxel plane: where a smooth surface crosses the
// planes at a slant, its shading shows rings.
fn central_difference_at(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    let h = params.volume.texel;
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

// The gradient of the cubic B-spline reconstruction on the voxel grid of
// `loc`'s level, per unit of texture coordinate: twice continuously
// differentiable, so normals turn smoothly across voxel planes (no rings),
// and it averages noise over 4 voxels a side. Per component, 8 trilinear
// reads at positions that fold the 4 × 4 × 4 B-spline weights into the
// filtering (Sigg and Hadwiger 2005): along the derivative's axis the
// derivative's weights (−e at q0, +e at q1), across it the smoothing ones
// (s0 at p0, s1 at p1).
fn cubic_gradient_at(tc: vec3<f32>, loc: Location) -> vec3<f32> {
    let h = params.volume.texel * voxel_edge(loc);
    // Voxel centres of the level at whole x.
    let x = tc / h - 0.5;
    let i = floor(x);
    let a = x - i;
    let b = 1.0 - a;
    let w0 = b * b * b / 6.0;
    let w1 = (3.0 * a * a * a - 6.0 * a * a + 4.0) / 6.0;
    let w3 = a * a * a / 6.0;
    let w2 = 1.0 - w0 - w1 - w3;
    let d1 = a * (1.5 * a - 2.0);
    let d3 = 0.5 * a * a;
    // d0 + d1 = −(d2 + d3) = −e, and e ≥ ½.
    let e = 0.5 + a * b;
    let s0 = w0 + w1;
    let s1 = w2 + w3;
    let p0 = (i - 0.5 + w1 / s0) * h;
    let p1 = (i + 1.5 + w3 / s1) * h;
    let q0 = (i - 0.5 - d1 / e) * h;
    let q1 = (i + 1.5 + d3 / e) * h;
    var g = vec3<f32>(0.0);
    for (var k = 0u; k < 4u; k++) {
        let first = (k & 1u) != 0u;
        let second = (k & 2u) != 0u;
        let x1 = select(p0.x, p1.x, first);
        let wx1 = select(s0.x, s1.x, first);
        let y1 = select(p0.y, p1.y, first);
        let wy1 = select(s0.y, s1.y, first);
        let y2 = select(p0.y, p1.y, second);
        let wy2 = select(s0.y, s1.y, second);
        let z2 = select(p0.z, p1.z, second);
        let wz2 = select(s0.z, s1.z, second);
        g.x += wy1 * wz2 * (sample_neighbour(vec3<f32>(q1.x, y1, z2), loc)
            - sample_neighbour(vec3<f32>(q0.x, y1, z2), loc));
        g.y += wx1 * wz2 * (sample_neighbour(vec3<f32>(x1, q1.y, z2), loc)
            - sample_neighbour(vec3<f32>(x1, q0.y, z2), loc));
        g.z += wx1 * wy2 * (sample_neighbour(vec3<f32>(x1, y2, q1.z), loc)
            - sample_neighbour(vec3<f32>(x1, y2, q0.z), loc));
    }
    return g * e / h;
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

// The grey a projected value u (transfer-function coordinates) shows through
// the window: black at its low end, white at its high end.
fn window_grey(u: f32) -> f32 {
    return clamp((u - params.window.x) / params.window.y, 0.0, 1.0);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    // The pixel's ray: through the pixel centre, from the near plane to the far
    // plane (right for perspective and orthographic projections alike).
    // Rows count in the whole image: a band is drawn as that part of it.
    let row = gid.y + params.first_row;
    let pixel = vec2<f32>(f32(gid.x) + 0.5, f32(row) + 0.5);
    let ndc = vec2<f32>(
        pixel.x / f32(params.width) * 2.0 - 1.0,
        1.0 - pixel.y / f32(params.image_height) * 2.0,
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
    // Σ Δt·τ so far (extinction compositing).
    var depth = 0.0;
    var found = false;
    var extreme = 0.0;
    if span.x < span.y {
        var jitter = 0.0;
        if (params.flags & FLAG_JITTER) != 0u {
            jitter = unit_from_hash(pcg_hash(row * params.width + gid.x));
        }
        let exponent = params.step / params.volume.reference_step;
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
            let u = sample_at(tc, loc) * params.volume.value_scale + params.volume.value_offset;
            let rgba = classify(u);
            if rgba.a > 0.0 {
                if params.mode == MODE_COMPOSITE {
                    let a = corrected_opacity(rgba.a, exponent);
                    var rgb = rgba.rgb;
                    if (params.flags & FLAG_SHADED) != 0u {
                        let weight = (1.0 - alpha) * rgba.a;
                        let g = (params.gradient_from_texture * vec4<f32>(gradient_at(tc, loc, weight), 0.0)).xyz
                            * params.volume.value_scale;
                        rgb = shade(rgb, g, dir);
                    }
                    if (params.flags & FLAG_LIT) != 0u {
                        // Eq. 12: g_k = (I_bias + (1 − I_bias)·I_s)·c·α, with coloured light.
                        let bias = params.light.a;
                        rgb = rgb * (vec3<f32>(bias) + (1.0 - bias) * params.light.rgb * light_at(tc - tex_dir * params.light_offset, loc));
                    }
                    if (params.flags & FLAG_EXTINCTION) != 0u {
                        // Eq. 2 (Schlegel et al.): Δt·τ_i from the corrected
                        // opacity, E_i·Δt·τ_i·exp(−Σ_{j≤i} Δt·τ_j) with the
                        // extinctions summed along the ray.
                        let dtau = -log(1.0 - min(a, MAX_SAMPLE_OPACITY));
                        depth += dtau;
                        color += exp(-depth) * dtau * rgb;
                        alpha = 1.0 - exp(-depth);
                    } else {
                        color += (1.0 - alpha) * a * rgb;
                        alpha += (1.0 - alpha) * a;
                    }
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
            out = vec3<f32>(window_grey(extreme));
        }
    }
    textureStore(output, vec2<i32>(gid.xy), vec4<f32>(clamp(out, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0));
}
