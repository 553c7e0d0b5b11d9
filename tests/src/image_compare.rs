//! Image comparison under a tolerance, never byte equality: GPUs, drivers and the
//! CPU twins round differently.
//!
//! Two measures: the mean absolute difference over all channels of all pixels (in
//! 0..255 units), and the fraction of pixels whose largest channel difference
//! exceeds a per-pixel threshold. On failure the actual image and a difference
//! image (the per-pixel largest difference, amplified, red on black) are written
//! beside the reference as `NAME-actual.png` and `NAME-diff.png`.
//!
//! Golden images live in `tests/golden/NAME.png`; `VOXSERVE_BLESS=1` rewrites them
//! from the actual images (inspect them before committing).

use std::path::{Path, PathBuf};

use image::{Rgba, RgbaImage};
use shaders::Frame;

/// How different two images may be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerance {
    /// Largest accepted mean absolute channel difference (0..255 units).
    pub max_mean: f64,
    /// A pixel counts as differing when a channel differs by more than this.
    pub pixel_threshold: u8,
    /// Largest accepted fraction of differing pixels (0..1).
    pub max_differing_fraction: f64,
}

/// The measured difference between two images.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageDiff {
    /// Mean absolute channel difference (0..255 units).
    pub mean: f64,
    /// Fraction of pixels with a channel difference above the threshold.
    pub differing_fraction: f64,
    /// The largest channel difference anywhere.
    pub max: u8,
}

impl ImageDiff {
    /// Whether this difference is within `tol`.
    pub fn within(&self, tol: &Tolerance) -> bool {
        self.mean <= tol.max_mean && self.differing_fraction <= tol.max_differing_fraction
    }
}

/// An RGBA image from a rendered frame.
pub fn to_image(frame: &Frame) -> RgbaImage {
    RgbaImage::from_raw(frame.width, frame.height, frame.rgba.clone())
        .unwrap_or_else(|| panic!("{frame:?} holds {} bytes", frame.rgba.len()))
}

/// Measures how `actual` differs from `expected` (same size), counting pixels
/// with a channel difference above `pixel_threshold`, and draws the difference
/// image: each pixel's largest channel difference, times 8, in red.
///
/// # Panics
/// When the sizes differ.
pub fn measure(
    actual: &RgbaImage,
    expected: &RgbaImage,
    pixel_threshold: u8,
) -> (ImageDiff, RgbaImage) {
    assert_eq!(
        actual.dimensions(),
        expected.dimensions(),
        "images differ in size"
    );
    let (w, h) = actual.dimensions();
    let mut diff_image = RgbaImage::new(w, h);
    let (mut sum, mut max, mut differing) = (0u64, 0u8, 0usize);
    for ((a, e), d) in actual
        .pixels()
        .zip(expected.pixels())
        .zip(diff_image.pixels_mut())
    {
        let channel = |c: usize| a.0[c].abs_diff(e.0[c]);
        let largest = (0..4).map(channel).max().unwrap_or(0);
        sum += (0..4).map(|c| u64::from(channel(c))).sum::<u64>();
        max = max.max(largest);
        differing += usize::from(largest > pixel_threshold);
        *d = Rgba([largest.saturating_mul(8), 0, 0, 255]);
    }
    let pixels = (w as usize * h as usize).max(1) as f64;
    let measured = ImageDiff {
        mean: sum as f64 / (pixels * 4.0),
        differing_fraction: differing as f64 / pixels,
        max,
    };
    (measured, diff_image)
}

/// Compares `actual` with `expected` and, when they differ beyond `tol`, writes
/// `NAME-actual.png` and `NAME-diff.png` into `dir` and returns a message saying so.
pub fn compare(
    name: &str,
    actual: &RgbaImage,
    expected: &RgbaImage,
    tol: &Tolerance,
    dir: &Path,
) -> Result<ImageDiff, String> {
    let (measured, diff_image) = measure(actual, expected, tol.pixel_threshold);
    if measured.within(tol) {
        return Ok(measured);
    }
    let actual_path = dir.join(format!("{name}-actual.png"));
    let diff_path = dir.join(format!("{name}-diff.png"));
    let saved = actual
        .save(&actual_path)
        .and_then(|()| diff_image.save(&diff_path));
    let written = match saved {
        Ok(()) => format!(
            "wrote {} and {}",
            actual_path.display(),
            diff_path.display()
        ),
        Err(e) => format!("could not write the failure images: {e}"),
    };
    Err(format!(
        "{name}: images differ beyond tolerance: mean {:.3} (max {}), {:.4} of pixels differ by \
         more than {} (max {}); largest difference {}; {written}",
        measured.mean,
        tol.max_mean,
        measured.differing_fraction,
        tol.pixel_threshold,
        tol.max_differing_fraction,
        measured.max,
    ))
}

/// Compares two rendered frames under `tol`; on failure writes
/// `tests/golden/NAME-actual.png` and `NAME-diff.png` and panics saying so.
///
/// # Panics
/// When the frames differ beyond `tol`.
pub fn assert_similar(name: &str, actual: &Frame, expected: &Frame, tol: &Tolerance) -> ImageDiff {
    compare(
        name,
        &to_image(actual),
        &to_image(expected),
        tol,
        &golden_dir(),
    )
    .unwrap_or_else(|msg| panic!("{msg}"))
}

/// Compares a rendered frame with the golden image `tests/golden/NAME.png`
/// without ever rewriting it (renders other than the blessing one).
///
/// # Panics
/// When the golden is missing or the frame differs beyond `tol`.
pub fn assert_matches_golden(name: &str, actual: &Frame, tol: &Tolerance) -> ImageDiff {
    let dir = golden_dir();
    let expected = image::open(dir.join(format!("{name}.png")))
        .unwrap_or_else(|e| panic!("golden image {name}.png cannot be read: {e}"))
        .to_rgba8();
    compare(
        &format!("{name}-check"),
        &to_image(actual),
        &expected,
        tol,
        &dir,
    )
    .unwrap_or_else(|msg| panic!("{msg}"))
}

/// The folder of golden images: `tests/golden/`.
pub fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("golden")
}

/// Compares `actual` with the golden image `tests/golden/NAME.png`
/// (or rewrites it when `VOXSERVE_BLESS=1`).
pub fn assert_golden(name: &str, actual: &RgbaImage, tol: &Tolerance) -> ImageDiff {
    let dir = golden_dir();
    let path = dir.join(format!("{name}.png"));
    if std::env::var("VOXSERVE_BLESS").is_ok_and(|v| v == "1") {
        actual
            .save(&path)
            .unwrap_or_else(|e| panic!("writing {}: {e}", path.display()));
    }
    let expected = image::open(&path)
        .unwrap_or_else(|e| {
            panic!(
                "golden image {} cannot be read ({e}); run with VOXSERVE_BLESS=1 to create it",
                path.display()
            )
        })
        .to_rgba8();
    compare(name, actual, &expected, tol, &dir).unwrap_or_else(|msg| panic!("{msg}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(w: u32, h: u32, v: u8) -> RgbaImage {
        RgbaImage::from_pixel(w, h, Rgba([v, v, v, 255]))
    }

    #[test]
    fn identical_images_do_not_differ() {
        let a = flat(4, 4, 10);
        let (d, _) = measure(&a, &a, 0);
        assert_eq!((d.mean, d.differing_fraction, d.max), (0.0, 0.0, 0));
    }

    #[test]
    fn one_bright_pixel_is_counted() {
        let a = flat(4, 4, 10);
        let mut b = a.clone();
        b.put_pixel(1, 1, Rgba([110, 10, 10, 255]));
        let (d, diff) = measure(&b, &a, 2);
        assert_eq!(diff.get_pixel(1, 1).0, [255, 0, 0, 255]);
        assert_eq!(d.max, 100);
        assert_eq!(d.differing_fraction, 1.0 / 16.0);
        assert!((d.mean - 100.0 / 64.0).abs() < 1e-9);
    }

    #[test]
    fn a_failed_comparison_writes_actual_and_diff_images() {
        let dir = std::env::temp_dir().join(format!("voxserve-compare-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let tol = Tolerance {
            max_mean: 0.1,
            pixel_threshold: 0,
            max_differing_fraction: 0.0,
        };
        let err =
            compare("case", &flat(4, 4, 0), &flat(4, 4, 50), &tol, &dir).expect_err("they differ");
        assert!(err.contains("case-actual.png"), "{err}");
        assert!(dir.join("case-actual.png").exists());
        assert!(dir.join("case-diff.png").exists());
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }
}
