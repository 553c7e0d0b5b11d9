//! [`FrameRequest`], what a client asks to see, and [`Frame`], the pixels it gets.

use std::fmt;
use std::str::FromStr;

use blocks::TransferFunction;

use crate::Camera;

/// The largest image edge in pixels.
pub const MAX_IMAGE_EDGE: u32 = 4096;

/// How samples are lit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Shading {
    /// Transfer-function colour only (emission–absorption).
    Unshaded,
    /// Gradient Blinn–Phong with a light above and to the left of the eye.
    #[default]
    Gradient,
}

impl Shading {
    /// Every shading mode.
    pub const ALL: [Shading; 2] = [Shading::Unshaded, Shading::Gradient];

    /// The mode's name in URLs and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Shading::Unshaded => "unshaded",
            Shading::Gradient => "gradient",
        }
    }
}

impl fmt::Display for Shading {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Shading {
    type Err = String;

    fn from_str(name: &str) -> Result<Shading, String> {
        Shading::ALL
            .into_iter()
            .find(|s| s.name() == name)
            .ok_or_else(|| format!("unknown shading '{name}': expected unshaded or gradient"))
    }
}

/// Everything needed to render one frame of a volume.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRequest {
    /// Where the eye is.
    pub camera: Camera,
    /// Image width in pixels, 1..=[`MAX_IMAGE_EDGE`].
    pub width: u32,
    /// Image height in pixels, 1..=[`MAX_IMAGE_EDGE`].
    pub height: u32,
    /// Value → colour and opacity.
    pub transfer_function: TransferFunction,
    /// How samples are lit.
    pub shading: Shading,
    /// Distance between samples along a ray, in voxels of the smallest spacing.
    pub step_voxels: f32,
    /// Background colour (sRGB, 0..=1).
    pub background: [f32; 3],
}

/// The accepted sample steps, in voxels.
pub const STEP_RANGE_VOXELS: (f32, f32) = (0.05, 4.0);

impl FrameRequest {
    /// A request with the default camera, shading, step and background.
    pub fn new(width: u32, height: u32, transfer_function: TransferFunction) -> FrameRequest {
        FrameRequest {
            camera: Camera::default(),
            width,
            height,
            transfer_function,
            shading: Shading::default(),
            step_voxels: 0.5,
            background: [0.0, 0.0, 0.0],
        }
    }

    /// Checks sizes, camera and step, naming the first field out of range.
    pub fn validate(&self) -> Result<(), String> {
        for (name, value) in [("width", self.width), ("height", self.height)] {
            if !(1..=MAX_IMAGE_EDGE).contains(&value) {
                return Err(format!(
                    "image {name} = {value}: expected 1 to {MAX_IMAGE_EDGE} pixels"
                ));
            }
        }
        self.camera.validate()?;
        let (lo, hi) = STEP_RANGE_VOXELS;
        if !(self.step_voxels.is_finite() && (lo..=hi).contains(&self.step_voxels)) {
            return Err(format!(
                "step = {}: expected {lo} to {hi} voxels",
                self.step_voxels
            ));
        }
        if !self.background.iter().all(|c| (0.0..=1.0).contains(c)) {
            return Err(format!(
                "background = {:?}: expected each channel in 0..=1",
                self.background
            ));
        }
        Ok(())
    }
}

/// A rendered image: RGBA8, rows top to bottom, no padding.
#[derive(Clone, PartialEq, Eq)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 4` bytes.
    pub rgba: Vec<u8>,
}

impl fmt::Debug for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Frame({}x{})", self.width, self.height)
    }
}

impl Frame {
    /// The RGBA value of pixel (x, y).
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = (y as usize * self.width as usize + x as usize) * 4;
        [
            self.rgba[i],
            self.rgba[i + 1],
            self.rgba[i + 2],
            self.rgba[i + 3],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use blocks::Preset;

    #[test]
    fn validation_names_the_bad_field() {
        let tf = Preset::CtBone.transfer_function([-1024.0, 3071.0]);
        let mut r = FrameRequest::new(64, 64, tf);
        assert!(r.validate().is_ok());
        r.width = 0;
        assert!(r.validate().expect_err("w=0").contains("width = 0"));
        r.width = 100_000;
        assert!(r.validate().expect_err("huge").contains("1 to 4096"));
        r.width = 64;
        r.step_voxels = f32::NAN;
        assert!(r.validate().expect_err("NaN step").contains("step"));
    }

    #[test]
    fn shading_names_round_trip() {
        for s in Shading::ALL {
            assert_eq!(s.name().parse::<Shading>(), Ok(s));
        }
        assert!("phong".parse::<Shading>().is_err());
    }
}
