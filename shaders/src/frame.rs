//! [`FrameRequest`], what a client asks to see, and [`Frame`], the pixels it gets.

use std::fmt;

use blocks::{Preset, TransferFunction};

use crate::Camera;
use crate::extinction::ExtinctionSettings;
use crate::global_light::LightSettings;
use crate::settings::{Choice, Expected, SettingError, Settings, TextSetting};

/// The largest image edge in pixels.
pub const MAX_IMAGE_EDGE: u32 = 4096;

/// The largest data reduction a request may ask for.
pub const MAX_REDUCTION: f64 = 10_000.0;

/// How samples make a pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Shading {
    /// Emission–absorption compositing of transfer-function colours.
    Unshaded,
    /// Compositing with gradient Blinn–Phong, a light above and left of the eye.
    #[default]
    Gradient,
    /// Maximum intensity projection: the largest value met among visible
    /// ones, in grey through the window.
    Mip,
    /// Minimum intensity projection: the smallest visible value, in grey
    /// through the window.
    MinIp,
    /// Compositing lit by global light propagation with first-order scattering
    /// (shadows from a light anywhere, also inside the volume): see [`crate::light`].
    GlobalLight,
    /// Compositing lit by extinction-based illumination: ambient occlusion,
    /// colour bleeding and cone soft shadows from summed-area-table queries
    /// (several point, spot or directional lights): see [`crate::extinction`].
    Extinction,
}

impl Choice for Shading {
    const ALL: &'static [Shading] = &[
        Shading::Unshaded,
        Shading::Gradient,
        Shading::Mip,
        Shading::MinIp,
        Shading::GlobalLight,
        Shading::Extinction,
    ];

    fn name(self) -> &'static str {
        match self {
            Shading::Unshaded => "unshaded",
            Shading::Gradient => "gradient",
            Shading::Mip => "mip",
            Shading::MinIp => "minip",
            Shading::GlobalLight => "global",
            Shading::Extinction => "extinction",
        }
    }

    fn doc(self) -> &'static str {
        match self {
            Shading::Unshaded => "compositing of transfer-function colours, unlit",
            Shading::Gradient => "compositing lit by the data's gradient (Blinn-Phong)",
            Shading::Mip => {
                "maximum intensity projection of visible values, greyscale through the window"
            }
            Shading::MinIp => {
                "minimum intensity projection of visible values, greyscale through the window"
            }
            Shading::GlobalLight => {
                "global light propagation: shadows and first-order scattering from the light"
            }
            Shading::Extinction => {
                "extinction-based: ambient occlusion and soft shadows from a summed-area table"
            }
        }
    }
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

impl Choice for Compositing {
    const ALL: &'static [Compositing] = &[Compositing::Alpha, Compositing::Extinction];

    fn name(self) -> &'static str {
        match self {
            Compositing::Alpha => "alpha",
            Compositing::Extinction => "extinction",
        }
    }

    fn doc(self) -> &'static str {
        match self {
            Compositing::Alpha => "front-to-back alpha-blending",
            Compositing::Extinction => {
                "summed extinction coefficients exponentiated (eq. 2 of Schlegel et al.)"
            }
        }
    }
}

impl Choice for Preset {
    const ALL: &'static [Preset] = &Preset::ALL;

    fn name(self) -> &'static str {
        Preset::name(self)
    }

    fn doc(self) -> &'static str {
        self.description()
    }
}

crate::choice_setting!(Shading, Compositing, Preset);

macro_rules! display_choice {
    ($($t:ty),*) => {$(
        impl fmt::Display for $t {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(Choice::name(*self))
            }
        }
    )*};
}

display_choice!(Shading, Compositing, crate::Projection);

/// A band of an image's rows: `count` rows from row `first` (0 at the top).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rows {
    /// The band's top row in the image.
    pub first: u32,
    /// Rows in the band.
    pub count: u32,
}

impl Rows {
    /// Splits an image of `height` rows into bands of at most `per_band`
    /// rows, top to bottom.
    pub fn bands(height: u32, per_band: u32) -> impl Iterator<Item = Rows> {
        let per_band = per_band.max(1);
        (0..height)
            .step_by(per_band as usize)
            .map(move |first| Rows {
                first,
                count: per_band.min(height - first),
            })
    }
}

/// The numbers of a comma-separated list, or `None` when any is not one.
fn comma_numbers(text: &str) -> Option<Vec<f32>> {
    text.split(',')
        .map(|v| v.trim().parse::<f32>().ok())
        .collect()
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

impl ClipBox {
    /// The whole volume.
    pub const ALL: ClipBox = ClipBox {
        min: [0.0; 3],
        max: [1.0; 3],
    };
}

impl Default for ClipBox {
    fn default() -> ClipBox {
        ClipBox::ALL
    }
}

impl TextSetting for ClipBox {
    fn expected() -> String {
        "six fractions x0,y0,z0,x1,y1,z1 from 0 to 1 with each min below its max".into()
    }

    fn parse_text(text: &str) -> Result<ClipBox, Expected> {
        let values = comma_numbers(text).ok_or_else(|| Expected(Self::expected()))?;
        let [x0, y0, z0, x1, y1, z1] = values[..] else {
            return Err(Expected(Self::expected()));
        };
        let clip = ClipBox {
            min: [x0, y0, z0],
            max: [x1, y1, z1],
        };
        clip.check_value().map(|()| clip)
    }

    /// Finite, within 0..1, min below max on every axis.
    fn check_value(&self) -> Result<(), Expected> {
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
            Err(Expected(Self::expected()))
        }
    }

    fn text(&self) -> String {
        let [x0, y0, z0] = self.min;
        let [x1, y1, z1] = self.max;
        format!("{x0},{y0},{z0},{x1},{y1},{z1}")
    }
}

/// The largest magnitude of a window's centre or width, in physical units.
pub const MAX_WINDOW: f32 = 1.0e7;

/// A greyscale window, as radiologists set one: the value shown mid-grey
/// (centre, "level") and the span from black to white (width), in physical
/// units (e.g. HU).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// The value shown mid-grey.
    pub centre: f32,
    /// The span from black to white (> 0).
    pub width: f32,
}

impl Window {
    /// The window whose black and white are `lo` and `hi` (a width of at
    /// least a millionth of `hi`'s size or 1e-6 when they meet).
    pub fn spanning(lo: f32, hi: f32) -> Window {
        let width = (hi - lo).max(hi.abs().max(lo.abs()) * 1e-6).max(1e-6);
        Window {
            centre: lo + width / 2.0,
            width,
        }
    }

    /// The value shown black.
    pub fn low(&self) -> f32 {
        self.centre - self.width / 2.0
    }
}

impl TextSetting for Window {
    fn expected() -> String {
        format!("CENTRE,WIDTH in physical units, the width above 0, both within ±{MAX_WINDOW}")
    }

    fn parse_text(text: &str) -> Result<Window, Expected> {
        let values = comma_numbers(text).ok_or_else(|| Expected(Self::expected()))?;
        let [centre, width] = values[..] else {
            return Err(Expected(Self::expected()));
        };
        let window = Window { centre, width };
        window.check_value().map(|()| window)
    }

    fn check_value(&self) -> Result<(), Expected> {
        let within = |v: f32| v.is_finite() && v.abs() <= MAX_WINDOW;
        if within(self.centre) && within(self.width) && self.width > 0.0 {
            Ok(())
        } else {
            Err(Expected(Self::expected()))
        }
    }

    fn text(&self) -> String {
        format!("{},{}", self.centre, self.width)
    }
}

impl TextSetting for TransferFunction {
    fn expected() -> String {
        format!(
            "VALUE:RRGGBB:OPACITY,… in physical units, at most {} points in non-decreasing order",
            blocks::transfer_function::MAX_POINTS
        )
    }

    fn parse_text(text: &str) -> Result<TransferFunction, Expected> {
        TransferFunction::parse(text).map_err(|e| Expected(Self::expected()).because(e))
    }

    fn check_value(&self) -> Result<(), Expected> {
        TransferFunction::new(self.points().to_vec())
            .map(|_| ())
            .map_err(|e| Expected(Self::expected()).because(e))
    }

    fn text(&self) -> String {
        self.to_string()
    }
}

crate::text_setting!(ClipBox, TransferFunction, Window);

crate::settings! {
    /// Everything needed to render one frame of a volume: what a client asks
    /// to see. Its settings are declared here (and in the structs it nests);
    /// `render`'s flags, `/api/render`'s query, view-session patches and
    /// `GET /api/settings` all come from them.
    #[derive(Debug, Clone, PartialEq)]
    pub struct FrameRequest in Shading {
        /// Image width in pixels.
        pub width: u32 = 512, "w" | "width",
            whole(1, MAX_IMAGE_EDGE, "a whole number of pixels", "px"), group Image;
        /// Image height in pixels.
        pub height: u32 = 512, "h" | "height",
            whole(1, MAX_IMAGE_EDGE, "a whole number of pixels", "px"), group Image;
        /// Background colour as six hex digits rrggbb.
        pub background: [f32; 3] = [0.0; 3], "bg" | "background", by_type(), group Image;
        /// Transfer-function preset [default: ct-bone for CT in HU, mr for MR, else
        /// generic]; CT presets only for CT in HU, mr only for MR.
        pub preset: Option<Preset> = None, "preset", by_type(), group Classification;
        /// A transfer function instead of a preset: VALUE:RRGGBB:OPACITY,… in
        /// physical units (e.g. HU), opacity per step of the smallest spacing.
        pub tf: Option<TransferFunction> = None, "tf", by_type(), group Classification;
        /// Greyscale window of maximum and minimum intensity projections:
        /// CENTRE,WIDTH in physical units (e.g. 500,2000 in HU) [default: from
        /// where the transfer function's opacity rises above 0 to where it
        /// last falls back or ends].
        pub window: Option<Window> = None, "window", by_type(), group Classification;
        /// How samples are lit.
        pub shading: Shading = Shading::Gradient, "shading", by_type();
        /// How samples combine along a ray.
        pub compositing: Compositing = Compositing::Alpha, "compositing", by_type();
        /// Distance between samples along a ray, in voxels of the smallest
        /// spacing; smaller is finer.
        pub step_voxels: f32 = 0.5, "step", number(0.05, 4.0, "a number of voxels", "voxels");
        /// Data reduction among the blocks the transfer function shows: their
        /// voxels at full resolution per voxel kept; the transfer function
        /// chooses the blocks' levels of detail to meet it (the memory budget
        /// may force more). Blocks it leaves empty are skipped at any detail.
        pub reduction: f32 = 1.0, "reduction",
            number(1.0, MAX_REDUCTION, "a data reduction ratio", ":1"), group Detail;
        /// Show only this box of the volume: six fractions of its extent
        /// x0,y0,z0,x1,y1,z1.
        pub clip: ClipBox = ClipBox::ALL, "clip", by_type(), group Clip;
    }
    groups {
        /// Where the eye is.
        pub camera: Camera,
        /// The light of [`Shading::GlobalLight`].
        pub light: LightSettings,
        /// The illumination of [`Shading::Extinction`].
        pub extinction: ExtinctionSettings,
    }
    plain {
        /// Jump over empty blocks (turned off only to measure what skipping saves).
        pub skip_empty: bool = true,
        /// Shade with the gradient of the cubic B-spline reconstruction at
        /// each block's level (smooth normals: no rings on smooth surfaces,
        /// less noise) rather than central differences one level-0 voxel
        /// apart, which cost a quarter of the reads (interactive frames).
        /// Only samples that weigh at least
        /// [`crate::raycast::FAINT_WEIGHT`] in their pixel take either;
        /// lighter ones take their nearest texel's central differences.
        pub cubic_gradient: bool = true,
        /// Draw only these rows of the image (a big frame is drawn band by
        /// band, so other frames can go between); all when `None`.
        pub rows: Option<Rows> = None,
    }
}

impl FrameRequest {
    /// A request with default settings and the transfer function `tf`.
    pub fn new(width: u32, height: u32, tf: TransferFunction) -> FrameRequest {
        FrameRequest {
            width,
            height,
            tf: Some(tf),
            ..FrameRequest::default()
        }
    }

    /// The transfer function to classify with: `tf` when given, else the
    /// preset (by default `default`, the volume's own) laid over `value_range`.
    pub fn transfer_function(&self, value_range: [f32; 2], default: Preset) -> TransferFunction {
        match (&self.tf, self.preset) {
            (Some(tf), _) => tf.clone(),
            (None, preset) => preset.unwrap_or(default).transfer_function(value_range),
        }
    }

    /// The greyscale window of maximum and minimum intensity projections:
    /// the one given, else the span `tf` shows (else `value_range`).
    pub fn window_of(&self, tf: &TransferFunction, value_range: [f32; 2]) -> Window {
        self.window.unwrap_or_else(|| {
            let [lo, hi] = tf.shown_span().unwrap_or(value_range);
            Window::spanning(lo, hi)
        })
    }

    /// The transfer function to classify the store described by `meta` with.
    pub fn store_transfer_function(&self, meta: &blocks::store::StoreMeta) -> TransferFunction {
        self.transfer_function(
            meta.value_range().map(|v| v as f32),
            Preset::for_data(meta.modality.as_deref(), meta.unit.as_deref()),
        )
    }

    /// The transfer function to classify `volume` with.
    pub fn volume_transfer_function(&self, volume: &blocks::Volume) -> TransferFunction {
        self.transfer_function(
            volume.value_range,
            Preset::for_data(volume.modality.as_deref(), volume.unit.as_deref()),
        )
    }

    /// The rows drawn: [`FrameRequest::rows`] within the image, else all.
    pub fn drawn_rows(&self) -> Rows {
        let height = self.height.max(1);
        match self.rows {
            Some(rows) => {
                let first = rows.first.min(height - 1);
                Rows {
                    first,
                    count: rows.count.clamp(1, height - first),
                }
            }
            None => Rows {
                first: 0,
                count: height,
            },
        }
    }

    /// Checks every setting, and what no single setting can: a transfer
    /// function and a preset are not both given, and the settings of the
    /// shading's illumination agree with each other.
    pub fn validate(&self) -> Result<(), SettingError> {
        self.validate_fields()?;
        if let (Some(tf), Some(preset)) = (&self.tf, self.preset) {
            return Err(SettingError::of_value(
                "tf",
                format!("{:?}", tf.text()),
                format!("a transfer function or a preset, not both (preset={preset}); remove one"),
            ));
        }
        match self.shading {
            Shading::Extinction => self.extinction.validate(),
            _ => Ok(()),
        }
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
    use crate::settings::Raw;

    #[test]
    fn validation_names_the_bad_setting() {
        let tf = Preset::CtBone.transfer_function([-1024.0, 3071.0]);
        let mut r = FrameRequest::new(64, 64, tf);
        assert!(r.validate().is_ok());
        r.width = 0;
        let e = r.validate().expect_err("w=0");
        assert_eq!((e.setting.as_str(), e.value.as_str()), ("w", "0"), "{e}");
        r.width = 100_000;
        assert!(
            r.validate()
                .expect_err("huge")
                .expected
                .contains("1 to 4096")
        );
        r.width = 64;
        r.step_voxels = f32::NAN;
        assert_eq!(r.validate().expect_err("NaN step").setting, "step");
        r.step_voxels = 0.5;
        r.preset = Some(Preset::Mr);
        assert!(
            r.validate()
                .expect_err("both")
                .expected
                .contains("not both")
        );
    }

    #[test]
    fn clip_boxes_and_colours_parse_or_say_what_was_expected() {
        let clip = ClipBox::parse_text("0, 0.25, 0, 1, 1, 0.5").expect("valid");
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
            let e = ClipBox::parse_text(bad).expect_err(bad);
            assert!(e.0.contains("six fractions"), "{bad}: {e}");
        }
        let mut r = FrameRequest::default();
        r.set_named("bg", &Raw::Text("#ff8000")).expect("colour");
        assert_eq!(r.background, [1.0, 128.0 / 255.0, 0.0]);
        for bad in ["red", "fff", "ff00zz", "#ff80000", "ffé000"] {
            let e = r.set_named("bg", &Raw::Text(bad)).expect_err(bad);
            assert!(e.expected.contains("six hex digits"), "{bad}: {e}");
        }
    }

    #[test]
    fn shading_names_round_trip() {
        for &s in Shading::ALL {
            assert_eq!(Shading::named(s.name()), Some(s));
        }
        assert!(Shading::named("phong").is_none());
    }

    #[test]
    fn the_transfer_function_comes_from_tf_then_preset_then_the_volumes_own() {
        let range = [-1024.0, 3071.0];
        let mut r = FrameRequest::default();
        assert_eq!(
            r.transfer_function(range, Preset::CtBone),
            Preset::CtBone.transfer_function(range)
        );
        r.preset = Some(Preset::CtAngio);
        assert_eq!(
            r.transfer_function(range, Preset::Mr),
            Preset::CtAngio.transfer_function(range)
        );
        let own = TransferFunction::parse("0:ffffff:0,100:ffffff:1").expect("tf");
        r.preset = None;
        r.tf = Some(own.clone());
        assert_eq!(r.transfer_function(range, Preset::CtBone), own);
    }
}
