// transfer_function: the 1D RGBA table, read like a 1D texture.
// Needs `params.volume.tf_len` and the binding `transfer_function: array<vec4<f32>>`.
// CPU twin: shaders/src/cpu/march.rs `classify`.

// Largest opacity fed to the opacity correction, so pow() never sees a zero base.
const MAX_SAMPLE_OPACITY: f32 = 0.9999;

// The transfer function at coordinate u (0..1), linearly interpolated between entry
// centres like a 1D texture with clamp to edge.
fn classify(u: f32) -> vec4<f32> {
    let n = i32(params.volume.tf_len);
    let x = clamp(u, 0.0, 1.0) * f32(n) - 0.5;
    let i0f = floor(x);
    let f = x - i0f;
    let i0 = i32(i0f);
    let a = transfer_function[clamp(i0, 0, n - 1)];
    let b = transfer_function[clamp(i0 + 1, 0, n - 1)];
    return mix(a, b, f);
}

// Opacity α for a step `exponent` times the reference step: α′ = 1 − (1 − α)^exponent.
fn corrected_opacity(a: f32, exponent: f32) -> f32 {
    return 1.0 - pow(1.0 - min(a, MAX_SAMPLE_OPACITY), exponent);
}
