//! [`FrameRequest`], what a client asks to see, and [`Frame`], the pixels it gets.

use std::fmt;
use std::str::FromStr;

use blocks::TransferFunction;

use crate::Camera;
use crate::extinction::ExtinctionSettings;
use crate::light::LightSettings;

/// The largest image edge in pixels.
pub const MAX_IMAGE_EDGE: u32 = 4096;

/// How samples make a pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Shading {
    /// Emission–absorption compositing of transfer-function colours.
    Unshaded,
    /// Compositing with gradient Blinn–Phong, a light above and left of the eye.
    #[default]
    Gradient,
    /// Maximum intensity projection: the transfer function of the largest value
    /// met among visible ones.
    Mip,
    /// Minimum intensity projection: the smallest visible value.
    MinIp,
    /// Compositing lit by global light propagation with first-order scattering
    /// (shadows from a light anywhere, also inside the volume): see [`crate::light`].
    GlobalLight,
    /// Compositing lit by extinction-based illumination: ambient occlusion,
    /// colour bleeding and cone soft shadows from summed-area-table queries
    /// (several point, spot or directional lights): see [`crate::extinction`].
    Extinction,
}

/// How samples along a ray combine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Compositing {
    /// Front-to-back α-blending of opacity-corrected samples.
    #[default]
    Alpha,
    /// Exponential extinction (eq. 2 of Schlegel et al.): extinction
    /// coefficients τ = −ln(1 − α)/Δt summed along the ray and exponentiated.
    Extinction,
}

impl Compositing {
    /// The mode's name in URLs and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Compositing::Alpha => "alpha",
            Compositing::Extinction => "extinction",
        }
    }
}

impl fmt::Display for Compositing {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Compositing {
    type Err = String;

    fn from_str(name: &str) -> Result<Compositing, String> {
        match name {
            "alpha" => Ok(Compositing::Alpha),
            "extinction" => Ok(Compositing::Extinction),
            _ => Err(format!(
                "unknown compositing '{name}': expected alpha or extinction"
            )),
        }
    }
}

impl Shading {
    /// Every shading mode.
    pub const ALL: [Shading; 6] = [
        Shading::Unshaded,
        Shading::Gradient,
        Shading::Mip,
        Shading::MinIp,
        Shading::GlobalLight,
        Shading::Extinction,
    ];

    /// The mode's name in URLs and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Shading::Unshaded => "unshaded",
            Shading::Gradient => "gradient",
            Shading::Mip => "mip",
            Shading::MinIp => "minip",
            Shading::GlobalLight => "global",
            Shading::Extinction => "extinction",
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
            .ok_or_else(|| {
                format!(
                    "unknown shading '{name}': expected unshaded, gradient, mip, minip, global or \
                     extinction"
                )
            })
    }
}

/// An axis-aligned clip box in the volume's index space, as fractions of its
/// extent along x, y, z (0..1 keeps everything).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClipBox {
    /// Lower corner.
    pub min: [f32; 3],
    /// Upper corner.
    pub max: [f32; 3],
}

impl Default for ClipBox {
    fn default() -> ClipBox {
        ClipBox {
            min: [0.0; 3],
            max: [1.0; 3],
        }
    }
}

impl FromStr for ClipBox {
    type Err = String;

    /// `x0,y0,z0,x1,y1,z1`, each a fraction 0..1 of the volume's extent.
    fn from_str(text: &str) -> Result<ClipBox, String> {
        let refuse = || {
            format!(
                "clip box '{text}': expected six fractions x0,y0,z0,x1,y1,z1 from 0 to 1 with each \
                 min below its max"
            )
        };
        let values: Vec<f32> = text
            .split(',')
            .map(|v| v.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|_| refuse())?;
        let [x0, y0, z0, x1, y1, z1] = values[..] else {
            return Err(refuse());
        };
        let clip = ClipBox {
            min: [x0, y0, z0],
            max: [x1, y1, z1],
        };
        clip.validate().map_err(|_| refuse())?;
        Ok(clip)
    }
}

/// A colour written as six hex digits `rrggbb` (an optional leading `#`) →
/// channels in 0..=1.
pub fn parse_colour(text: &str) -> Result<[f32; 3], String> {
    blocks::transfer_function::parse_rgb_hex(text)
}

impl ClipBox {
    /// Checks the corners: finite, within 0..1, min below max on every axis.
    pub fn validate(&self) -> Result<(), String> {
        let ok = (0..3).all(|a| {
            let (lo, hi) = (self.min[a], self.max[a]);
            lo.is_finite()
                && hi.is_finite()
                && (0.0..=1.0).contains(&lo)
                && (0.0..=1.0).contains(&hi)
                && lo < hi
        });
        if ok {
            Ok(())
        } else {
            Err(format!(
                "clip box {:?}..{:?}: expected fractions 0..1 with min below max on every axis",
                self.min, self.max
            ))
        }
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
    /// The part of the volume shown.
    pub clip: ClipBox,
    /// Data reduction to render at (full-volume voxels per voxel kept on the
    /// GPU), 1 or more; the device budget may force more.
    pub reduction: f32,
    /// Jump over empty blocks (turned off only to measure what skipping saves).
    pub skip_empty: bool,
    /// The light of [`Shading::GlobalLight`].
    pub light: LightSettings,
    /// The illumination of [`Shading::Extinction`].
    pub extinction: ExtinctionSettings,
    /// How samples combine along a ray.
    pub compositing: Compositing,
}

/// The largest data reduction a request may ask for.
pub const MAX_REDUCTION: f32 = 10_000.0;

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
            clip: ClipBox::default(),
            reduction: 1.0,
            skip_empty: true,
            light: LightSettings::default(),
            extinction: ExtinctionSettings::default(),
            compositing: Compositing::default(),
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
        self.clip.validate()?;
        if !(self.reduction.is_finite() && (1.0..=MAX_REDUCTION).contains(&self.reduction)) {
            return Err(format!(
                "reduction = {}: expected 1 to {MAX_REDUCTION}",
                self.reduction
            ));
        }
        if self.shading == Shading::GlobalLight {
            self.light.validate()?;
        }
        if self.shading == Shading::Extinction {
            self.extinction.validate()?;
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
    fn clip_boxes_and_colours_parse_or_say_what_was_expected() {
        let clip: ClipBox = "0, 0.25, 0, 1, 1, 0.5".parse().expect("valid");
        assert_eq!(clip.min, [0.0, 0.25, 0.0]);
        assert_eq!(clip.max, [1.0, 1.0, 0.5]);
        for bad in [
            "",
            "0,0,0,1,1",
            "0,0,0,1,1,1,1",
            "0.5,0,0,0.5,1,1",
            "0,0,0,1,1,1.5",
            "x,0,0,1,1,1",
        ] {
            let e = bad.parse::<ClipBox>().expect_err(bad);
            assert!(e.contains("expected six fractions"), "{bad}: {e}");
        }
        assert_eq!(parse_colour("#ff8000"), Ok([1.0, 128.0 / 255.0, 0.0]));
        assert_eq!(parse_colour("000000"), Ok([0.0; 3]));
        for bad in ["red", "fff", "ff00zz", "#ff80000", "ffé000"] {
            assert!(
                parse_colour(bad).expect_err(bad).contains("six hex digits"),
                "{bad}"
            );
        }
    }

    #[test]
    fn shading_names_round_trip() {
        for s in Shading::ALL {
            assert_eq!(s.name().parse::<Shading>(), Ok(s));
        }
        assert!("phong".parse::<Shading>().is_err());
    }
}
