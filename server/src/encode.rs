//! Frame encoding for HTTP responses and view sessions: PNG, WebP lossless and JPEG.

use image::ImageEncoder;
use image::codecs::jpeg::JpegEncoder;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::codecs::webp::WebPEncoder;
use shaders::Frame;

/// Writes `frame` as opaque RGB (frames are composited over the background,
/// so alpha carries nothing) through `encoder`.
fn write_rgb(frame: &Frame, encoder: impl ImageEncoder) -> Result<(), image::ImageError> {
    let rgb: Vec<u8> = frame
        .rgba
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    encoder.write_image(
        &rgb,
        frame.width,
        frame.height,
        image::ExtendedColorType::Rgb8,
    )
}

/// Encodes a frame as an RGB PNG. Fast compression: a frame is encoded for
/// every view change.
pub fn png(frame: &Frame) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Vec::with_capacity(frame.rgba.len() / 4);
    write_rgb(
        frame,
        PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive),
    )?;
    Ok(out)
}

/// Encodes a frame as a lossless WebP (smaller than PNG, slower to encode).
pub fn webp(frame: &Frame) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Vec::with_capacity(frame.rgba.len() / 4);
    write_rgb(frame, WebPEncoder::new_lossless(&mut out))?;
    Ok(out)
}

/// A lossless image format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Lossless {
    /// PNG with fast compression.
    Png,
    /// WebP lossless.
    Webp,
}

/// Encodes a frame as a baseline JPEG of `quality` (1–100): small and fast,
/// for frames shown while the user interacts.
pub fn jpeg(frame: &Frame, quality: u8) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Vec::with_capacity(frame.rgba.len() / 16);
    write_rgb(
        frame,
        JpegEncoder::new_with_quality(&mut out, quality.clamp(1, 100)),
    )?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_round_trips_through_png() {
        let frame = Frame {
            width: 3,
            height: 2,
            rgba: (0..24)
                .map(|i| if i % 4 == 3 { 255 } else { i * 10 })
                .collect(),
        };
        let bytes = png(&frame).expect("encodes");
        let back = image::load_from_memory(&bytes).expect("decodes").to_rgba8();
        assert_eq!(back.dimensions(), (3, 2));
        assert_eq!(back.into_raw(), frame.rgba);
    }

    #[test]
    fn a_frame_round_trips_through_webp() {
        let frame = Frame {
            width: 5,
            height: 3,
            rgba: (0..60)
                .map(|i| if i % 4 == 3 { 255 } else { (i * 7) as u8 })
                .collect(),
        };
        let bytes = webp(&frame).expect("encodes");
        let back = image::load_from_memory_with_format(&bytes, image::ImageFormat::WebP)
            .expect("decodes")
            .to_rgba8();
        assert_eq!(back.dimensions(), (5, 3));
        assert_eq!(back.into_raw(), frame.rgba);
    }

    #[test]
    fn a_flat_frame_survives_jpeg_within_a_few_levels() {
        let frame = Frame {
            width: 16,
            height: 8,
            rgba: [90u8, 140, 200, 255].repeat(16 * 8),
        };
        let bytes = jpeg(&frame, 90).expect("encodes");
        let back = image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg)
            .expect("decodes")
            .to_rgba8();
        assert_eq!(back.dimensions(), (16, 8));
        for (got, want) in back.into_raw().iter().zip(&frame.rgba) {
            assert!(got.abs_diff(*want) <= 3, "{got} vs {want}");
        }
    }
}
