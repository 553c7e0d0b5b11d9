//! Frame encoding for HTTP responses.

use image::ImageEncoder;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use shaders::Frame;

/// Encodes a frame as an opaque RGB PNG (frames are composited over the
/// background, so alpha carries nothing). Fast compression: a frame is encoded
/// for every view change.
pub fn png(frame: &Frame) -> Result<Vec<u8>, image::ImageError> {
    let rgb: Vec<u8> = frame
        .rgba
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    let mut out = Vec::with_capacity(rgb.len() / 2);
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
        .write_image(
            &rgb,
            frame.width,
            frame.height,
            image::ExtendedColorType::Rgb8,
        )?;
    Ok(out)
}

/// Encodes a frame as a baseline JPEG of `quality` (1–100): small and fast,
/// for frames shown while the user interacts.
pub fn jpeg(frame: &Frame, quality: u8) -> Result<Vec<u8>, image::ImageError> {
    let rgb: Vec<u8> = frame
        .rgba
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    let mut out = Vec::with_capacity(rgb.len() / 8);
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality.clamp(1, 100))
        .write_image(
            &rgb,
            frame.width,
            frame.height,
            image::ExtendedColorType::Rgb8,
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
}
