//! How far one rendered image is from another, as a viewer sees it: the CIE 1976
//! L*u*v* colour difference ΔE*uv per pixel (sRGB with a D65 white), and its
//! mean, root mean square, 99th percentile and the fraction of pixels above 6
//! (ΔE₆: clearly visible side by side). Used to report what a data reduction or
//! an illumination approximation costs against its full-resolution reference.
//!
//! Beside it: the mean of NVIDIA's ꟻLIP error map ([`flip_mean`], Andersson et
//! al. 2020, through the `nv-flip` crate), the figure rendering papers report,
//! and the share of the reference's opaque pixels an image still covers
//! ([`opaque_coverage`]), which counts holes that a mean hides.

use crate::{Frame, GpuError};

/// ΔE*uv statistics of one image against another.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ColourDifference {
    /// Mean ΔE*uv over all pixels.
    pub mean: f64,
    /// Root mean square ΔE*uv (ΔE_RMS).
    pub rms: f64,
    /// 99th percentile ΔE*uv.
    pub p99: f64,
    /// Largest ΔE*uv.
    pub max: f64,
    /// Fraction of pixels with ΔE*uv above 6 (ΔE₆).
    pub above_6: f64,
}

/// sRGB 8-bit → CIE L*u*v* (D65).
pub fn srgb_to_luv(rgb: [u8; 3]) -> [f64; 3] {
    let linear = rgb.map(|c| {
        let c = f64::from(c) / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    });
    let [r, g, b] = linear;
    let x = 0.4124 * r + 0.3576 * g + 0.1805 * b;
    let y = 0.2126 * r + 0.7152 * g + 0.0722 * b;
    let z = 0.0193 * r + 0.1192 * g + 0.9505 * b;
    // D65 white: Xn = 0.95047, Yn = 1, Zn = 1.08883.
    let (un, vn) = (0.197_839_3, 0.468_336_3);
    let l = if y > (6.0f64 / 29.0).powi(3) {
        116.0 * y.cbrt() - 16.0
    } else {
        (29.0f64 / 3.0).powi(3) * y
    };
    let d = x + 15.0 * y + 3.0 * z;
    if d <= 0.0 {
        return [l, 0.0, 0.0];
    }
    let (u, v) = (4.0 * x / d, 9.0 * y / d);
    [l, 13.0 * l * (u - un), 13.0 * l * (v - vn)]
}

/// ΔE*uv between two sRGB colours.
pub fn delta_e(a: [u8; 3], b: [u8; 3]) -> f64 {
    let (p, q) = (srgb_to_luv(a), srgb_to_luv(b));
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
}

/// The per-pixel ΔE*uv of `actual` against `reference` (alpha ignored).
///
/// # Errors
/// When the frames differ in size.
pub fn per_pixel(actual: &Frame, reference: &Frame) -> Result<Vec<f64>, GpuError> {
    same_size(actual, reference)?;
    Ok(actual
        .rgba
        .chunks_exact(4)
        .zip(reference.rgba.chunks_exact(4))
        .map(|(a, r)| delta_e([a[0], a[1], a[2]], [r[0], r[1], r[2]]))
        .collect())
}

/// The statistics of `actual` against `reference`.
///
/// # Errors
/// When the frames differ in size.
pub fn colour_difference(actual: &Frame, reference: &Frame) -> Result<ColourDifference, GpuError> {
    Ok(statistics(per_pixel(actual, reference)?))
}

/// The statistics of `actual` against `reference` over the object's pixels only:
/// those where either image differs from the `background` colour. A large empty
/// border then cannot dilute the figures.
///
/// # Errors
/// When the frames differ in size.
pub fn object_colour_difference(
    actual: &Frame,
    reference: &Frame,
    background: [u8; 3],
) -> Result<ColourDifference, GpuError> {
    let d = per_pixel(actual, reference)?;
    let is_object = |p: &[u8]| p[..3] != background;
    let object = d
        .into_iter()
        .zip(
            actual
                .rgba
                .chunks_exact(4)
                .zip(reference.rgba.chunks_exact(4)),
        )
        .filter(|(_, (a, r))| is_object(a) || is_object(r))
        .map(|(d, _)| d)
        .collect();
    Ok(statistics(object))
}

/// The mean of the ꟻLIP error map (0 to 1; alpha ignored) of `actual` against
/// `reference`, for a viewer at 67 pixels per degree (a 0.7 m distance from a
/// 24-inch 4K monitor, the ꟻLIP default).
///
/// # Errors
/// When the frames differ in size.
pub fn flip_mean(actual: &Frame, reference: &Frame) -> Result<f64, GpuError> {
    same_size(actual, reference)?;
    let rgb = |f: &Frame| {
        let data: Vec<u8> = f
            .rgba
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect();
        nv_flip::FlipImageRgb8::with_data(f.width, f.height, &data)
    };
    let map = nv_flip::flip(
        rgb(reference),
        rgb(actual),
        nv_flip::DEFAULT_PIXELS_PER_DEGREE,
    );
    Ok(nv_flip::FlipPool::from_image(&map).mean().into())
}

/// Per pixel, the opacity (0 to 1) of a view rendered twice, once on a black
/// and once on a white background: over black a pixel is C, over white
/// C + (1 − α), so α = 1 − (white − black), averaged over the three channels.
///
/// # Errors
/// When the frames differ in size.
pub fn opacity(on_black: &Frame, on_white: &Frame) -> Result<Vec<f32>, GpuError> {
    same_size(on_black, on_white)?;
    Ok(on_black
        .rgba
        .chunks_exact(4)
        .zip(on_white.rgba.chunks_exact(4))
        .map(|(b, w)| {
            let through: f32 = (0..3)
                .map(|c| f32::from(w[c]) - f32::from(b[c]))
                .sum::<f32>()
                / (3.0 * 255.0);
            (1.0 - through).clamp(0.0, 1.0)
        })
        .collect())
}

/// Of the pixels where `reference` is at least half opaque, the share where
/// `actual` is too (1 when the reference has none): 1 − the share of holes.
/// Opacities as [`opacity`] gives them.
pub fn opaque_coverage(actual: &[f32], reference: &[f32]) -> f64 {
    let (mut opaque, mut covered) = (0usize, 0usize);
    for (&a, &r) in actual.iter().zip(reference) {
        if r >= 0.5 {
            opaque += 1;
            covered += usize::from(a >= 0.5);
        }
    }
    if opaque == 0 {
        1.0
    } else {
        covered as f64 / opaque as f64
    }
}

fn same_size(a: &Frame, b: &Frame) -> Result<(), GpuError> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(GpuError::InvalidRequest(format!(
            "cannot compare a {}x{} image with a {}x{} one",
            a.width, a.height, b.width, b.height
        )));
    }
    Ok(())
}

/// Mean, RMS, 99th percentile, maximum and ΔE₆ of per-pixel differences (all 0
/// for none).
pub fn statistics(mut d: Vec<f64>) -> ColourDifference {
    let n = d.len().max(1) as f64;
    let mean = d.iter().sum::<f64>() / n;
    let rms = (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    let above_6 = d.iter().filter(|&&x| x > 6.0).count() as f64 / n;
    d.sort_by(f64::total_cmp);
    let p99 = d
        .get(((d.len() as f64 * 0.99).ceil() as usize).saturating_sub(1))
        .copied()
        .unwrap_or(0.0);
    let max = d.last().copied().unwrap_or(0.0);
    ColourDifference {
        mean,
        rms,
        p99,
        max,
        above_6,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_and_black_are_100_apart_and_equal_colours_0() {
        let w = srgb_to_luv([255; 3]);
        assert!(
            (w[0] - 100.0).abs() < 0.01 && w[1].abs() < 0.05 && w[2].abs() < 0.05,
            "{w:?}"
        );
        assert_eq!(srgb_to_luv([0; 3]), [0.0; 3]);
        assert!((delta_e([0; 3], [255; 3]) - 100.0).abs() < 0.05);
        assert_eq!(delta_e([10, 200, 30], [10, 200, 30]), 0.0);
        // Pure sRGB red in L*u*v*: about (53.2, 175.0, 37.8).
        let red = srgb_to_luv([255, 0, 0]);
        assert!(
            (red[0] - 53.24).abs() < 0.1
                && (red[1] - 175.0).abs() < 0.5
                && (red[2] - 37.8).abs() < 0.5,
            "{red:?}"
        );
    }

    #[test]
    fn statistics_count_the_pixels_that_differ() {
        let frame = |px: &[[u8; 3]]| Frame {
            width: px.len() as u32,
            height: 1,
            rgba: px.iter().flat_map(|p| [p[0], p[1], p[2], 255]).collect(),
        };
        let mut a = vec![[100u8; 3]; 100];
        let b = a.clone();
        a[7] = [255; 3];
        let d = colour_difference(&frame(&a), &frame(&b)).expect("same size");
        let one = delta_e([255; 3], [100; 3]);
        assert!((d.mean - one / 100.0).abs() < 1e-9);
        assert!((d.max - one).abs() < 1e-9);
        assert_eq!(d.p99, 0.0);
        assert!((d.above_6 - 0.01).abs() < 1e-12);
        assert!(colour_difference(&frame(&a[..3]), &frame(&b)).is_err());
    }

    #[test]
    fn object_statistics_leave_the_background_out() {
        let frame = |px: &[[u8; 3]]| Frame {
            width: px.len() as u32,
            height: 1,
            rgba: px.iter().flat_map(|p| [p[0], p[1], p[2], 255]).collect(),
        };
        // 8 background pixels in both; 2 object pixels, one of them differing.
        let mut a = vec![[0u8; 3]; 10];
        a[3] = [200; 3];
        a[4] = [120; 3];
        let mut b = a.clone();
        b[4] = [60; 3];
        let d = object_colour_difference(&frame(&a), &frame(&b), [0; 3]).expect("same size");
        let one = delta_e([120; 3], [60; 3]);
        assert!((d.mean - one / 2.0).abs() < 1e-9, "{d:?}");
        assert!((d.above_6 - 0.5).abs() < 1e-12, "{d:?}");
        // A pixel that only one image covers counts.
        b[9] = [50; 3];
        let d = object_colour_difference(&frame(&a), &frame(&b), [0; 3]).expect("same size");
        assert!((d.above_6 - 2.0 / 3.0).abs() < 1e-12, "{d:?}");
        assert_eq!(statistics(Vec::new()).rms, 0.0);
    }

    fn flat(width: u32, px: impl Fn(u32) -> [u8; 3]) -> Frame {
        Frame {
            width,
            height: width,
            rgba: (0..width * width)
                .flat_map(|i| {
                    let [r, g, b] = px(i);
                    [r, g, b, 255]
                })
                .collect(),
        }
    }

    #[test]
    fn flip_is_zero_for_equal_images_and_grows_with_the_difference() {
        let reference = flat(32, |i| [(i % 32 * 8) as u8, 90, 40]);
        let same = flip_mean(&reference, &reference).expect("same size");
        assert!(same.abs() < 1e-6, "{same}");
        let near = flat(32, |i| [(i % 32 * 8) as u8, 100, 40]);
        let far = flat(32, |i| [(i % 32 * 8) as u8, 250, 40]);
        let (near, far) = (
            flip_mean(&near, &reference).expect("same size"),
            flip_mean(&far, &reference).expect("same size"),
        );
        assert!(0.0 < near && near < far && far <= 1.0, "{near} {far}");
        assert!(flip_mean(&flat(8, |_| [0; 3]), &reference).is_err());
    }

    #[test]
    fn opacity_comes_from_two_backgrounds_and_coverage_counts_holes() {
        // Half-transparent grey object: 64 over black, 64 + 127.5 over white.
        let black = flat(2, |i| if i < 2 { [64; 3] } else { [0; 3] });
        let white = flat(2, |i| if i < 2 { [192; 3] } else { [255; 3] });
        let alpha = opacity(&black, &white).expect("same size");
        assert!((alpha[0] - 0.498).abs() < 0.01, "{alpha:?}");
        assert_eq!(alpha[3], 0.0);
        let reference = [1.0, 0.9, 0.2, 0.6];
        assert_eq!(
            opaque_coverage(&[1.0, 0.5, 1.0, 0.1], &reference),
            2.0 / 3.0
        );
        assert_eq!(opaque_coverage(&[0.0; 4], &[0.1; 4]), 1.0);
    }
}
