//! Facts about a rendered image that say the volume is really in it, beyond
//! "some bytes came back": how much of the image it covers, and how close the
//! image is to its own left–right mirror.

use image::RgbaImage;

/// The fraction of pixels that differ from the black background (any colour
/// channel above 10 of 255).
pub fn coverage(img: &RgbaImage) -> f64 {
    let covered = img
        .pixels()
        .filter(|p| p.0[..3].iter().any(|&c| c > 10))
        .count();
    covered as f64 / img.pixels().len().max(1) as f64
}

/// The mean absolute channel difference (0..255) between the image and its
/// left–right mirror: 0 for a perfectly symmetric image.
pub fn mirror_difference(img: &RgbaImage) -> f64 {
    let (w, h) = img.dimensions();
    let mut sum = 0u64;
    for y in 0..h {
        for x in 0..w {
            let (a, b) = (img.get_pixel(x, y), img.get_pixel(w - 1 - x, y));
            sum += (0..3)
                .map(|c| u64::from(a.0[c].abs_diff(b.0[c])))
                .sum::<u64>();
        }
    }
    sum as f64 / (f64::from(w) * f64::from(h) * 3.0)
}

/// The centroid of the covered pixels, as fractions of width and height.
pub fn centroid(img: &RgbaImage) -> (f64, f64) {
    let (mut sx, mut sy, mut n) = (0.0f64, 0.0f64, 0.0f64);
    for (x, y, p) in img.enumerate_pixels() {
        if p.0[..3].iter().any(|&c| c > 10) {
            sx += f64::from(x) + 0.5;
            sy += f64::from(y) + 0.5;
            n += 1.0;
        }
    }
    let (w, h) = img.dimensions();
    (
        sx / n.max(1.0) / f64::from(w),
        sy / n.max(1.0) / f64::from(h),
    )
}

/// Asserts that an unshaded front view of the head phantom shows it: centred,
/// covering a plausible share of the image, and left–right symmetric like the
/// skull (shading would break the symmetry: the light comes from the upper left).
/// Returns coverage and mirror difference.
///
/// # Panics
/// When any of the three facts fails, with the measured values.
pub fn assert_front_view_of_phantom(img: &RgbaImage) -> (f64, f64) {
    let c = coverage(img);
    let m = mirror_difference(img);
    let (cx, cy) = centroid(img);
    assert!(
        (0.15..=0.8).contains(&c),
        "phantom covers {c:.3} of the image: expected 0.15 to 0.8"
    );
    assert!(
        m < 3.0,
        "mirror difference {m:.3}: expected a left-right symmetric image (< 3)"
    );
    assert!(
        (cx - 0.5).abs() < 0.05 && (cy - 0.5).abs() < 0.05,
        "phantom centroid at ({cx:.3}, {cy:.3}): expected the image centre"
    );
    (c, m)
}

/// Per pixel of `frame` (row by row), its luminance (Rec. 601, 0 to 255) less
/// the luminance blurred by a 7-pixel box along x, then along y (edges
/// repeated), twice: what is left is detail a few pixels across, such as
/// rings on a smooth surface.
pub fn high_pass_luminance(frame: &shaders::Frame) -> Vec<f64> {
    const REACH: usize = 3;
    let (w, h) = (frame.width as usize, frame.height as usize);
    let luminance: Vec<f64> = frame
        .rgba
        .chunks(4)
        .map(|p| 0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2]))
        .collect();
    let box_blur = |image: &[f64], along_x: bool| -> Vec<f64> {
        let (n, stride, lines, line_stride) = if along_x { (w, 1, h, w) } else { (h, w, w, 1) };
        let mut out = vec![0.0; image.len()];
        for line in 0..lines {
            for i in 0..n {
                let sum: f64 = (i as isize - REACH as isize..=(i + REACH) as isize)
                    .map(|j| {
                        image[line * line_stride + j.clamp(0, n as isize - 1) as usize * stride]
                    })
                    .sum();
                out[line * line_stride + i * stride] = sum / (2 * REACH + 1) as f64;
            }
        }
        out
    };
    let mut blurred = luminance.clone();
    for _ in 0..2 {
        blurred = box_blur(&box_blur(&blurred, true), false);
    }
    luminance.iter().zip(&blurred).map(|(l, b)| l - b).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgba;

    #[test]
    fn a_centred_disc_is_covered_symmetric_and_centred_and_a_corner_blob_is_not() {
        let disc = RgbaImage::from_fn(64, 64, |x, y| {
            let (dx, dy) = (f64::from(x) - 31.5, f64::from(y) - 31.5);
            let v = if dx.hypot(dy) < 20.0 { 200 } else { 0 };
            Rgba([v, v, v, 255])
        });
        assert_front_view_of_phantom(&disc);
        let corner = RgbaImage::from_fn(64, 64, |x, y| {
            let v = if x < 30 && y < 30 { 200 } else { 0 };
            Rgba([v, v, v, 255])
        });
        assert!(mirror_difference(&corner) > 3.0);
        assert!(centroid(&corner).0 < 0.3);
    }
}
