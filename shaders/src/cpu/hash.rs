//! Twin of `shaders/wgsl/shared/hash.wgsl`.

/// PCG output hash of a 32-bit value.
// keep in sync with shaders/wgsl/shared/hash.wgsl `pcg_hash`
pub fn pcg_hash(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// A value in 0..1 from the top 24 bits of a hash.
pub fn unit_from_hash(h: u32) -> f32 {
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_values_spread_over_the_unit_interval() {
        let values: Vec<f32> = (0..4096).map(|i| unit_from_hash(pcg_hash(i))).collect();
        assert!(values.iter().all(|v| (0.0..1.0).contains(v)));
        let mean = values.iter().sum::<f32>() / values.len() as f32;
        assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
        // Neighbouring pixels get unrelated values.
        assert_ne!(pcg_hash(0), pcg_hash(1));
    }
}
