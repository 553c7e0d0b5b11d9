// raycast: direct volume rendering by ray casting.
//
// Per pixel, a ray from the camera crosses the volume (a box in texture space,
// a possibly oriented or sheared parallelepiped in model space); samples every
// `params.step` mm are classified by the 1D transfer function, their opacity
// corrected for the step length (α' = 1 − (1 − α)^(step / reference_step)),
// optionally shaded with gradient Blinn–Phong, and composited front to back
// (C += (1 − A) α' c, A += (1 − A) α') until the ray leaves the box or A reaches
// `params.early_termination` (early ray termination). The background shows
// through what remains: out = C + (1 − A) background.
//
// Dispatch: one invocation per pixel, workgroups of 8×8, ceil(width / 8) × ceil(height / 8).
// Bindings (group 0):
//   0 params             uniform RaycastParams
//   1 volume             texture_3d<f32>, one channel, normalized texel values
//   2 volume_sampler     linear filtering, clamp to edge
//   3 transfer_function  storage array<vec4<f32>>, tf_len RGBA entries over u in 0..1
//   4 output             storage texture rgba8unorm, width × height
// CPU twin: shaders::cpu::raycast (shaders/src/cpu/raycast.rs), loop for loop.

@group(0) @binding(0) var<uniform> params: RaycastParams;
@group(0) @binding(1) var volume: texture_3d<f32>;
@group(0) @binding(2) var volume_sampler: sampler;
@group(0) @binding(3) var<storage, read> transfer_function: array<vec4<f32>>;
@group(0) @binding(4) var output: texture_storage_2d<rgba8unorm, write>;

// Largest opacity fed to the opacity correction, so pow() never sees a zero base.
const MAX_SAMPLE_OPACITY: f32 = 0.9999;

// The volume's texel value at a texture-space position (trilinear, clamped to edge).
fn sample_volume(tc: vec3<f32>) -> f32 {
    return textureSampleLevel(volume, volume_sampler, tc, 0.0).r;
}

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

// The gradient of the transfer-function coordinate at tc, by central differences
// one voxel apart, in transfer-function units per mm of model space.
fn gradient(tc: vec3<f32>) -> vec3<f32> {
    let h = params.texel;
    let dx = vec3<f32>(h.x, 0.0, 0.0);
    let dy = vec3<f32>(0.0, h.y, 0.0);
    let dz = vec3<f32>(0.0, 0.0, h.z);
    let differences = vec3<f32>(
        sample_volume(tc + dx) - sample_volume(tc - dx),
        sample_volume(tc + dy) - sample_volume(tc - dy),
        sample_volume(tc + dz) - sample_volume(tc - dz),
    );
    let per_texture_unit = differences / (2.0 * h);
    return (params.gradient_from_texture * vec4<f32>(per_texture_unit, 0.0)).xyz * params.value_scale;
}

// Two-sided Blinn–Phong with the surface normal along the gradient.
fn shade(rgb: vec3<f32>, tc: vec3<f32>, view_dir: vec3<f32>) -> vec3<f32> {
    let g = gradient(tc);
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
// where it enters and leaves the unit box; enter > exit when it misses.
fn intersect_box(origin: vec3<f32>, dir: vec3<f32>) -> vec2<f32> {
    // Avoid dividing by an exact zero: a tiny component stands in for it.
    let safe_dir = select(dir, vec3<f32>(1e-12), abs(dir) < vec3<f32>(1e-12));
    let inv = 1.0 / safe_dir;
    let t0 = -origin * inv;
    let t1 = (vec3<f32>(1.0) - origin) * inv;
    let lo = min(t0, t1);
    let hi = max(t0, t1);
    let enter = max(max(lo.x, lo.y), max(lo.z, 0.0));
    let exit = min(min(hi.x, hi.y), hi.z);
    return vec2<f32>(enter, exit);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    // The pixel's ray: through the pixel centre, from the near plane to the far plane.
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

    let span = intersect_box(tex_origin, tex_dir);
    var color = vec3<f32>(0.0);
    var alpha = 0.0;
    if span.x < span.y {
        var jitter = 0.0;
        if (params.flags & FLAG_JITTER) != 0u {
            jitter = unit_from_hash(pcg_hash(gid.y * params.width + gid.x));
        }
        let exponent = params.step / params.reference_step;
        var t = span.x + jitter * params.step;
        for (var k = 0u; k < params.max_steps; k++) {
            if t > span.y {
                break;
            }
            let tc = tex_origin + tex_dir * t;
            let u = sample_volume(tc) * params.value_scale + params.value_offset;
            let rgba = classify(u);
            if rgba.a > 0.0 {
                let a = 1.0 - pow(1.0 - min(rgba.a, MAX_SAMPLE_OPACITY), exponent);
                var rgb = rgba.rgb;
                if (params.flags & FLAG_SHADED) != 0u {
                    rgb = shade(rgb, tc, dir);
                }
                color += (1.0 - alpha) * a * rgb;
                alpha += (1.0 - alpha) * a;
                if alpha >= params.early_termination {
                    break;
                }
            }
            t += params.step;
        }
    }
    let out = color + (1.0 - alpha) * params.background.rgb;
    textureStore(output, vec2<i32>(gid.xy), vec4<f32>(clamp(out, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0));
}
