//! [`Texture3d`]: a one-channel 3D texture sampled the way a GPU samples one with
//! linear filtering and clamp-to-edge addressing, for the CPU twins.

use std::ops::{Add, Mul, Sub};

use glam::Vec3;
use wide::f32x4;

/// `floor(x)` without a call into the C library (where the target has no
/// rounding instruction, `f32::floor` is one, and it dominated sampling):
/// truncation, one lower for negative non-integers. Exact for every `f32`.
#[inline]
pub fn floor(x: f32) -> f32 {
    if x.abs() >= 8_388_608.0 || x.is_nan() {
        // Already an integer (or NaN, which stays NaN).
        return x;
    }
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// Trilinear interpolation of eight texels at fractions `f` along x, y and
/// z, texel `c[i]` at the corner `(i & 1, i >> 1 & 1, i >> 2)`: each row's
/// two texels blended along x and weighed by the row's share along y and z,
/// the four rows summed in pairs. (The rows' weights are ready before the
/// texels arrive, so the blend waits on the reads for five steps where
/// three rounds of lerps take nine.) Of one value or of several side by
/// side in lanes (`one` is 1 in each), each lane the same arithmetic: the
/// CPU twins read their textures and slots through it
/// (`SlotAtlas::sample_slot4` writes it out for four samples at once).
#[inline(always)]
pub fn blend<T>(c: [T; 8], f: [T; 3], one: T) -> T
where
    T: Copy + Add<Output = T> + Sub<Output = T> + Mul<Output = T>,
{
    let [fx, fy, fz] = f;
    let (gx, gy, gz) = (one - fx, one - fy, one - fz);
    let y0z0 = (c[0] * gx + c[1] * fx) * (gy * gz);
    let y1z0 = (c[2] * gx + c[3] * fx) * (fy * gz);
    let y0z1 = (c[4] * gx + c[5] * fx) * (gy * fz);
    let y1z1 = (c[6] * gx + c[7] * fx) * (fy * fz);
    (y0z0 + y1z0) + (y0z1 + y1z1)
}

/// The 2×2×2 texels whose first (lowest) is `texels[first]`, rows `row`
/// and slices `slice` apart, in [`blend`]'s order.
#[inline(always)]
fn corners<T: Copy>(texels: &[T], first: usize, row: usize, slice: usize) -> [T; 8] {
    let t = &texels[first..first + slice + row + 2];
    [
        t[0],
        t[1],
        t[row],
        t[row + 1],
        t[slice],
        t[slice + 1],
        t[slice + row],
        t[slice + row + 1],
    ]
}

/// The 2×2×2 texels from (x, y, z) up, each read by `load` at its
/// coordinates, in [`blend`]'s order (where they are not known to lie in
/// one array: clamped reads at a texture's edge).
#[inline(always)]
pub fn corners_from<T>(x: i32, y: i32, z: i32, load: impl Fn(i32, i32, i32) -> T) -> [T; 8] {
    [0, 1, 2, 3, 4, 5, 6, 7].map(|c| load(x + (c & 1), y + (c >> 1 & 1), z + (c >> 2)))
}

/// Trilinear interpolation ([`blend`]) of the 2×2×2 texels whose first
/// (lowest) is `texels[first]`, rows `row` and slices `slice` apart, at
/// fractions `f`.
#[inline(always)]
pub fn trilinear(texels: &[f32], first: usize, row: usize, slice: usize, f: Vec3) -> f32 {
    blend(corners(texels, first, row, slice), f.to_array(), 1.0)
}

/// `x` as a whole number `i` and a fraction `x − i` in `0..=1`, for
/// `|x| < 2²²`: the whole number is `floor(x)`, or one less where `x` is
/// whole (the fraction is then 1, which interpolates alike). Rounding
/// `x − ½` to the nearest integer in the mantissa of `x − ½ + 1.5·2²³` takes
/// four instructions where `floor` and a saturating `as` take a dozen.
#[inline]
pub fn split(x: f32) -> (i32, f32) {
    let rounded = (x - 0.5) + MAGIC;
    let whole = rounded.to_bits() as i32 - MAGIC.to_bits() as i32;
    (whole, x - whole as f32)
}

/// 1.5·2²³: a float in `2²³..2²⁴` has no fraction bits, so adding it rounds
/// to a whole number.
const MAGIC: f32 = 12_582_912.0;

/// Per lane, [`split`]'s whole number as a float: `floor(x)`, or one less
/// where `x` is whole, for `|x| < 2²²`.
#[inline(always)]
pub fn round_down(x: f32x4) -> f32x4 {
    ((x - f32x4::splat(0.5)) + f32x4::splat(MAGIC)) - f32x4::splat(MAGIC)
}

/// Entries `i` and `i + 1` of `values`, side by side in one 64-bit word
/// (the first in its low half, as memory holds them): one read.
#[inline(always)]
pub fn pair<const N: usize>(values: &[f32; N], i: usize) -> u64 {
    u64::from(values[i].to_bits()) | u64::from(values[i + 1].to_bits()) << 32
}

/// Four [`pair`]s dealt into two vectors: lane `l` of the first holds pair
/// `l`'s first value, of the second its second (two shuffles, where
/// building each vector a value at a time takes four reads and three
/// inserts).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub fn deal(pairs: [u64; 4]) -> (f32x4, f32x4) {
    use safe_arch::{cast_to_m128_from_m128d, set_m128d, shuffle_abi_f32_all_m128};
    let two = |high: u64, low: u64| {
        cast_to_m128_from_m128d(set_m128d(f64::from_bits(high), f64::from_bits(low)))
    };
    // Lanes: pair 0's values, then pair 1's; pair 2's, then pair 3's.
    let (low, high) = (two(pairs[1], pairs[0]), two(pairs[3], pairs[2]));
    (
        bytemuck::cast(shuffle_abi_f32_all_m128::<0b10_00_10_00>(low, high)),
        bytemuck::cast(shuffle_abi_f32_all_m128::<0b11_01_11_01>(low, high)),
    )
}

/// Four [`pair`]s dealt into two vectors.
#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
pub fn deal(pairs: [u64; 4]) -> (f32x4, f32x4) {
    let half = |bits: u64| f32::from_bits(bits as u32);
    (
        f32x4::from(pairs.map(half)),
        f32x4::from(pairs.map(|p| half(p >> 32))),
    )
}

/// `floor(x)` as a whole number (`floor(x) as i32`, saturating, 0 for
/// NaN), branch-free: truncation, one less where that rounded up.
#[inline(always)]
pub fn floor_i32(x: f32) -> i32 {
    let i = x as i32;
    i.saturating_sub(i32::from(i as f32 > x))
}

/// `ceil(x)` as a whole number (`ceil(x) as i32`, saturating, 0 for NaN),
/// branch-free: truncation, one more where that rounded down.
#[inline(always)]
pub fn ceil_i32(x: f32) -> i32 {
    let i = x as i32;
    i.saturating_add(i32::from((i as f32) < x))
}

/// [`floor`] per component.
#[inline]
pub fn floor3(v: Vec3) -> Vec3 {
    Vec3::new(floor(v.x), floor(v.y), floor(v.z))
}

/// Where the texel at integer coordinates, clamped to the edge, lies in a
/// texture of `dims` texels stored x fastest.
fn clamped_index(dims: [u32; 3], x: i32, y: i32, z: i32) -> usize {
    let clamp = |v: i32, n: u32| v.clamp(0, n as i32 - 1) as usize;
    let (nx, ny) = (dims[0] as usize, dims[1] as usize);
    (clamp(z, dims[2]) * ny + clamp(y, dims[1])) * nx + clamp(x, dims[0])
}

/// Texel values x fastest, sampled at texture coordinates in 0..1 with texel
/// centres at (i + 0.5) / n.
#[derive(Debug, Clone)]
pub struct Texture3d {
    dims: [u32; 3],
    texels: Vec<f32>,
}

impl Texture3d {
    /// A texture of `dims` texels; `texels.len()` must equal their product.
    pub fn new(dims: [u32; 3], texels: Vec<f32>) -> Texture3d {
        assert_eq!(
            texels.len(),
            dims.iter().map(|&d| d as usize).product::<usize>(),
            "texel count must match dims {dims:?}"
        );
        Texture3d { dims, texels }
    }

    /// Texels along x, y, z.
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// The texels, x fastest, given back.
    pub fn into_texels(self) -> Vec<f32> {
        self.texels
    }

    /// The texels, x fastest, to write in place.
    pub fn texels_mut(&mut self) -> &mut [f32] {
        &mut self.texels
    }

    /// The texel at integer coordinates, clamped to the edge.
    pub fn load(&self, x: i32, y: i32, z: i32) -> f32 {
        self.texels[clamped_index(self.dims, x, y, z)]
    }

    /// Trilinear sample at texture coordinates `tc` (what `textureSampleLevel`
    /// returns with a linear, clamp-to-edge sampler).
    pub fn sample_level(&self, tc: Vec3) -> f32 {
        let dims = Vec3::new(
            self.dims[0] as f32,
            self.dims[1] as f32,
            self.dims[2] as f32,
        );
        self.sample_texel(tc * dims - 0.5)
    }

    /// Trilinear sample at texel position `p` (texel centres at integers): the
    /// eight texels around it read straight from memory when all are inside,
    /// else through [`Texture3d::load`]'s clamp to the edge.
    #[inline]
    pub fn sample_texel(&self, p: Vec3) -> f32 {
        let base = floor3(p);
        let f = p - base;
        let (x, y, z) = (base.x as i32, base.y as i32, base.z as i32);
        let [nx, ny, nz] = self.dims.map(|d| d as i32);
        if x >= 0 && y >= 0 && z >= 0 && x + 1 < nx && y + 1 < ny && z + 1 < nz {
            let (row, slice) = (nx as usize, (nx * ny) as usize);
            let first = (z as usize * ny as usize + y as usize) * row + x as usize;
            return trilinear(&self.texels, first, row, slice, f);
        }
        let corners = corners_from(x, y, z, |x, y, z| self.load(x, y, z));
        blend(corners, f.to_array(), 1.0)
    }
}

/// A 3D texture of colours (r, g, b and a fourth channel), sampled like a
/// [`Texture3d`] in every channel at once, the channels in SIMD lanes.
#[derive(Debug, Clone)]
pub struct ColourTexture {
    dims: [u32; 3],
    texels: Vec<f32x4>,
}

impl ColourTexture {
    /// A texture of `dims` texels; `texels.len()` must equal their product.
    pub fn new(dims: [u32; 3], texels: &[[f32; 4]]) -> ColourTexture {
        assert_eq!(
            texels.len(),
            dims.iter().map(|&d| d as usize).product::<usize>(),
            "texel count must match dims {dims:?}"
        );
        let texels = texels.iter().map(|&t| f32x4::from(t)).collect();
        ColourTexture { dims, texels }
    }

    /// The texel at integer coordinates, clamped to the edge.
    fn load(&self, x: i32, y: i32, z: i32) -> f32x4 {
        self.texels[clamped_index(self.dims, x, y, z)]
    }

    /// The colour (r, g, b) [`Texture3d::sample_level`] gives per channel at
    /// texture coordinates `tc`, the same arithmetic lane by lane.
    #[inline(always)]
    pub fn sample_level(&self, tc: Vec3) -> Vec3 {
        let [nx, ny, nz] = self.dims.map(|d| d as i32);
        let p = tc * Vec3::new(nx as f32, ny as f32, nz as f32) - 0.5;
        let base = floor3(p);
        let f = p - base;
        let (x, y, z) = (base.x as i32, base.y as i32, base.z as i32);
        let corners: [f32x4; 8] =
            if x >= 0 && y >= 0 && z >= 0 && x + 1 < nx && y + 1 < ny && z + 1 < nz {
                let (row, slice) = (nx as usize, (nx * ny) as usize);
                let first = (z as usize * ny as usize + y as usize) * row + x as usize;
                corners(&self.texels, first, row, slice)
            } else {
                corners_from(x, y, z, |x, y, z| self.load(x, y, z))
            };
        let f = f.to_array().map(f32x4::splat);
        let [r, g, b, _] = blend(corners, f, f32x4::ONE).to_array();
        Vec3::new(r, g, b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_pairs_dealt_put_each_pair_s_values_in_its_lane() {
        // Distinct values, a negative zero and a NaN among them: the bits
        // must arrive unchanged.
        let values: [f32; 9] = [1.5, -0.0, 3.25, f32::NAN, -7.0, 1e-40, 9.0, 0.1, -2.5];
        let at = [0, 3, 7, 2];
        let (first, second) = deal(at.map(|i| pair(&values, i)));
        let bits = |v: f32x4| v.to_array().map(f32::to_bits);
        assert_eq!(bits(first), at.map(|i| values[i].to_bits()));
        assert_eq!(bits(second), at.map(|i| values[i + 1].to_bits()));
    }

    #[test]
    fn a_colour_texture_samples_each_channel_as_a_texture_of_it_does() {
        let dims = [5u32, 4, 3];
        let n = 5 * 4 * 3;
        let texels: Vec<[f32; 4]> = (0..n)
            .map(|i| {
                let v = (i * 7919 % 101) as f32 / 100.0;
                [v, 1.0 - v, (i as f32 * 0.3).sin(), 0.0]
            })
            .collect();
        let colour = ColourTexture::new(dims, &texels);
        let channels =
            [0, 1, 2].map(|c| Texture3d::new(dims, texels.iter().map(|t| t[c]).collect()));
        // Inside, and past every edge (clamped).
        for i in 0..500 {
            let u = |k: u32| ((i * k) % 997) as f32 / 996.0 * 1.4 - 0.2;
            let tc = Vec3::new(u(31), u(57), u(89));
            let got = colour.sample_level(tc);
            let want = Vec3::new(
                channels[0].sample_level(tc),
                channels[1].sample_level(tc),
                channels[2].sample_level(tc),
            );
            assert_eq!(got, want, "at {tc}");
        }
    }

    #[test]
    fn floor_i32_and_ceil_i32_are_floor_and_ceil_as_whole_numbers() {
        let mut values = vec![
            0.0f32,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            15.999_999,
            16.0,
            -16.000_002,
            8_388_607.5,
            8_388_608.0,
            -8_388_609.0,
            3e9,
            -3e9,
            f32::MAX,
            f32::MIN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
        ];
        let mut x = 1.0e-3f32;
        while x < 1e10 {
            values.extend([x, -x, x.next_up(), (-x).next_down()]);
            x *= 1.37;
        }
        for v in values {
            assert_eq!(floor_i32(v), v.floor() as i32, "floor of {v}");
            assert_eq!(ceil_i32(v), v.ceil() as i32, "ceil of {v}");
        }
    }

    #[test]
    fn texel_centres_return_texels_and_midpoints_average() {
        let t = Texture3d::new([2, 1, 1], vec![0.0, 1.0]);
        assert_eq!(t.sample_level(Vec3::new(0.25, 0.5, 0.5)), 0.0);
        assert_eq!(t.sample_level(Vec3::new(0.75, 0.5, 0.5)), 1.0);
        assert_eq!(t.sample_level(Vec3::new(0.5, 0.5, 0.5)), 0.5);
    }

    #[test]
    fn outside_the_texture_clamps_to_the_edge() {
        let t = Texture3d::new([2, 1, 1], vec![0.25, 1.0]);
        assert_eq!(t.sample_level(Vec3::new(-3.0, 0.5, 0.5)), 0.25);
        assert_eq!(t.sample_level(Vec3::new(7.0, 9.0, -1.0)), 1.0);
    }

    #[test]
    fn floor_matches_the_library() {
        for x in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.999,
            -2.001,
            1e7,
            -1e7,
            8_388_607.5,
            -8_388_607.5,
            3e9,
            -3e9,
            f32::MAX,
            f32::MIN,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ] {
            assert_eq!(floor(x), x.floor(), "floor({x})");
        }
        assert!(floor(f32::NAN).is_nan());
    }

    #[test]
    fn split_gives_the_floor_and_a_fraction_up_to_one() {
        for x in [
            0.0f32, 0.25, 0.5, 0.999_999, 1.0, 1.5, 2.0, 17.0, 17.25, 1023.5, -0.5, -0.25,
        ] {
            let (whole, fraction) = split(x);
            assert!(
                (0.0..=1.0).contains(&fraction),
                "split({x}) = {whole}, {fraction}"
            );
            assert_eq!(whole as f32 + fraction, x, "split({x})");
            assert!(whole == x.floor() as i32 || (x == x.floor() && whole == x as i32 - 1));
        }
    }

    #[test]
    fn inside_and_at_the_edge_sample_alike() {
        let texels = (0..4 * 3 * 2).map(|i| (i * i % 7) as f32).collect();
        let t = Texture3d::new([4, 3, 2], texels);
        // Interpolating by hand from `load` must match the direct read inside.
        let p = Vec3::new(1.25, 0.5, 0.75);
        let base = floor3(p);
        let f = p - base;
        let mut expected = 0.0;
        for corner in 0..8 {
            let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
            let w = [f.x, f.y, f.z]
                .iter()
                .zip(d)
                .map(|(&f, d)| if d == 1 { f } else { 1.0 - f })
                .product::<f32>();
            expected += w * t.load(1 + d[0], d[1], d[2]);
        }
        assert!((t.sample_texel(p) - expected).abs() < 1e-5);
    }
}
