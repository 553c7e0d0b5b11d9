//! Transparent texels inside blocks, for the CPU ray caster: a bit per texel
//! of the atlas that is clear where the transfer function gives zero
//! opacity to every value trilinear filtering can blend from the 2×2×2
//! texels from it. With empty-space skipping on, the march drops the
//! samples whose texels are all clear without reading them; they would
//! have been invisible, so every pixel stays what the GPU draws (its march
//! looks at each such sample and drops it; `tests/tests/raycast.rs` checks
//! skipping changes no pixel). Computed per transfer function and set of
//! shown blocks.

use blocks::packing::slot_edge;
use blocks::store::LEVELS;
use rayon::prelude::*;

use super::march::table_position;
use super::slot_atlas::SlotAtlas;
use crate::packed_volume::PackedVolume;

/// Which texel values `classify` may make visible.
struct Visibility {
    /// `visible_before[i]`: table entries before `i` with opacity above zero.
    visible_before: Vec<u32>,
    value_scale: f32,
    value_offset: f32,
}

impl Visibility {
    fn new(g: &PackedVolume, transfer_function: &[[f32; 4]]) -> Self {
        let mut visible_before = Vec::with_capacity(transfer_function.len() + 1);
        visible_before.push(0u32);
        for entry in transfer_function {
            let last = visible_before.last().copied().unwrap_or(0);
            visible_before.push(last + u32::from(entry[3] > 0.0));
        }
        Visibility {
            visible_before,
            value_scale: g.value_scale,
            value_offset: g.value_offset,
        }
    }

    /// Any entry `classify` may blend for a texel value in `lo..=hi` opaque?
    fn any(&self, lo: f32, hi: f32) -> bool {
        let n = self.visible_before.len() as i32 - 1;
        if n <= 0 {
            return false;
        }
        let (a, b) = (
            lo * self.value_scale + self.value_offset,
            hi * self.value_scale + self.value_offset,
        );
        let tf_len = n as u32;
        let first = table_position(tf_len, a.min(b)).0.clamp(0, n - 1) as usize;
        let last = (table_position(tf_len, a.max(b)).0 + 1).clamp(0, n - 1) as usize;
        self.visible_before[last + 1] > self.visible_before[first]
    }
}

/// Per texel of the atlas (bit `i % 64` of word `i / 64` for texel `i` of
/// [`SlotAtlas::texels`]), set where a sample whose lowest texel it is may
/// be visible: where the transfer function gives opacity to a value between
/// the least and the greatest of the 2×2×2 texels from it (trilinear
/// filtering blends nothing else). Set for texels on a slot's last row,
/// column or slice, which are never a sample's lowest.
pub fn visible_texels(
    atlas: &SlotAtlas,
    g: &PackedVolume,
    transfer_function: &[[f32; 4]],
) -> Vec<u64> {
    let any_visible = Visibility::new(g, transfer_function);
    let texels = atlas.texels();
    let mut bits = vec![0u64; texels.len().div_ceil(64)];
    for level in 0..LEVELS {
        let region = atlas.region_texels(level);
        let words = region.start / 64..region.end.div_ceil(64).min(bits.len());
        let (Some(words), Some(region)) = (bits.get_mut(words), texels.get(region)) else {
            continue;
        };
        match slot_edge(level) {
            18 => region_visible::<18>(region, words, &any_visible),
            10 => region_visible::<10>(region, words, &any_visible),
            6 => region_visible::<6>(region, words, &any_visible),
            4 => region_visible::<4>(region, words, &any_visible),
            _ => region_visible::<3>(region, words, &any_visible),
        }
    }
    bits
}

/// Whether [`visible_texels`]' `bits` let a sample whose lowest texel is
/// texel `i` be visible (a texel past the bits' end may be).
#[inline(always)]
pub fn texel_may_show(bits: &[u64], i: usize) -> bool {
    bits.get(i / 64).is_none_or(|w| w >> (i % 64) & 1 != 0)
}

/// [`visible_texels`]'s bits `words` of one level's slots `region` (edge `E`).
fn region_visible<const E: usize>(region: &[f32], words: &mut [u64], any_visible: &Visibility) {
    const WORDS: usize = 64;
    words
        .par_chunks_mut(WORDS)
        .enumerate()
        .for_each(|(chunk, words)| {
            for (w, word) in words.iter_mut().enumerate() {
                let first = (chunk * WORDS + w) * 64;
                let mut bits = 0u64;
                for bit in 0..64.min(region.len().saturating_sub(first)) {
                    let i = first + bit;
                    let local = i % (E * E * E);
                    let (x, y, z) = (local % E, local / E % E, local / (E * E));
                    let shown = x + 1 >= E
                        || y + 1 >= E
                        || z + 1 >= E
                        || cube_visible::<E>(region, i, any_visible);
                    bits |= u64::from(shown) << bit;
                }
                *word = bits;
            }
        });
}

/// Whether a sample blending the 2×2×2 texels from `region[i]` (rows `E`
/// apart) may be visible.
#[inline]
fn cube_visible<const E: usize>(region: &[f32], i: usize, any_visible: &Visibility) -> bool {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for offset in [0, 1, E, E + 1, E * E, E * E + 1, E * E + E, E * E + E + 1] {
        let v = region.get(i + offset).copied().unwrap_or(0.0);
        lo = lo.min(v);
        hi = hi.max(v);
    }
    any_visible.any(lo, hi)
}
