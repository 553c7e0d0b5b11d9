//! The settings of global light propagation ([`LightSettings`]) and where
//! its light is ([`LightSource`]), each setting declared once with the stage
//! its change recomputes from.

use std::fmt;

use glam::Vec3;

use crate::settings::{Choice, Expected, TextSetting};

/// The largest light intensity I0 (and ambient light).
pub const MAX_INTENSITY: f64 = 16.0;
/// The most in-scattering directions J (a subdivided octahedron has 258 at level 3).
pub const MAX_DIRECTIONS: u32 = 258;
/// The farthest a point light may be from the volume, in volume boxes.
pub const MAX_LIGHT_DISTANCE: f32 = 100.0;

/// Where the light is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightSource {
    /// A point light, as fractions of the volume's box along its index axes
    /// (0..1 is inside the volume; anything else is outside).
    Point([f32; 3]),
    /// A directional light: the vector towards the light, in patient space
    /// (LPS: x to the patient's left, y posterior, z superior).
    Directional([f32; 3]),
}

impl fmt::Display for LightSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LightSource::Point([x, y, z]) => {
                write!(f, "point light at ({x}, {y}, {z}) of the volume")
            }
            LightSource::Directional([x, y, z]) => {
                write!(f, "directional light towards ({x}, {y}, {z})")
            }
        }
    }
}

/// Three comma-separated finite numbers, for light positions and directions.
pub(crate) fn parse_vec3(text: &str) -> Result<[f32; 3], String> {
    let values: Option<Vec<f32>> = text
        .split(',')
        .map(|v| v.trim().parse::<f32>().ok().filter(|x| x.is_finite()))
        .collect();
    match values.as_deref() {
        Some(&[x, y, z]) => Ok([x, y, z]),
        _ => Err(format!("'{text}' is not three numbers x,y,z")),
    }
}

/// A point light's position: fractions of the volume's box within ±100.
pub(crate) fn check_position(p: [f32; 3]) -> Result<(), String> {
    if p.iter()
        .all(|c| c.is_finite() && c.abs() <= MAX_LIGHT_DISTANCE)
    {
        Ok(())
    } else {
        Err(format!(
            "the position {p:?} is not fractions of the volume's box within ±{MAX_LIGHT_DISTANCE}"
        ))
    }
}

/// A direction: finite and not zero.
pub(crate) fn check_direction(d: [f32; 3]) -> Result<(), String> {
    if Vec3::from(d).is_finite() && Vec3::from(d).length() > 1e-6 {
        Ok(())
    } else {
        Err(format!("the direction {d:?} is zero or not finite"))
    }
}

impl TextSetting for LightSource {
    fn expected() -> String {
        "point:x,y,z (fractions of the volume's box) or directional:x,y,z (towards the light)"
            .into()
    }

    /// `point:x,y,z` (fractions of the volume's box) or `directional:x,y,z`
    /// (towards the light, patient space).
    fn parse_text(text: &str) -> Result<LightSource, Expected> {
        let refuse = |why: String| Expected(Self::expected()).because(why);
        let (kind, rest) = text
            .split_once(':')
            .ok_or_else(|| refuse("no kind".into()))?;
        let v = parse_vec3(rest).map_err(refuse)?;
        let source = match kind.trim() {
            "point" => LightSource::Point(v),
            "directional" | "dir" => LightSource::Directional(v),
            other => return Err(refuse(format!("unknown kind '{other}'"))),
        };
        source.check_value().map(|()| source)
    }

    fn check_value(&self) -> Result<(), Expected> {
        match *self {
            LightSource::Point(p) => check_position(p),
            LightSource::Directional(d) => check_direction(d),
        }
        .map_err(|why| Expected(Self::expected()).because(why))
    }

    fn text(&self) -> String {
        let v = |[x, y, z]: [f32; 3]| format!("{x},{y},{z}");
        match *self {
            LightSource::Point(p) => format!("point:{}", v(p)),
            LightSource::Directional(d) => format!("directional:{}", v(d)),
        }
    }
}

crate::text_setting!(LightSource);

/// How the direct light I_d is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DirectLightMethod {
    /// The paper's: local segments, the shadow volume, eq. 8.
    #[default]
    Piecewise,
    /// Brute force, every stored voxel marched to the light at full step:
    /// the reference the piecewise method is measured against.
    Reference,
}

impl Choice for DirectLightMethod {
    const ALL: &'static [DirectLightMethod] =
        &[DirectLightMethod::Piecewise, DirectLightMethod::Reference];

    fn name(self) -> &'static str {
        match self {
            DirectLightMethod::Piecewise => "piecewise",
            DirectLightMethod::Reference => "reference",
        }
    }

    fn doc(self) -> &'static str {
        match self {
            DirectLightMethod::Piecewise => "local piecewise integration (the paper's)",
            DirectLightMethod::Reference => {
                "every stored voxel marched to the light at full step (the reference)"
            }
        }
    }
}

crate::choice_setting!(DirectLightMethod);

crate::settings! {
    /// How the volume is lit by global light propagation (`shading=global`).
    /// Each setting names the first [`super::Stage`] its change
    /// recomputes; colour and I_bias apply when a frame is drawn.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct LightSettings in GlobalLight {
        /// The light: point:X,Y,Z (a point light at fractions of the volume's
        /// box: 0..1 is inside it) or directional:X,Y,Z (towards the light,
        /// patient LPS axes: x left, y posterior, z superior).
        pub source: LightSource = LightSource::Directional([-0.6, -0.5, 0.62]), "light",
            by_type(), affects "local_opacity";
        /// The light's colour as six hex digits rrggbb.
        pub colour: [f32; 3] = [1.0; 3], "light_colour", by_type();
        /// The light's intensity I0.
        pub intensity: f32 = 1.0, "light_intensity",
            number(0.0, MAX_INTENSITY, "an intensity", ""), affects "direct_light";
        /// The minimum light level I_bias: no region is darker.
        pub bias: f32 = 0.15, "bias" | "light-bias", number(0.0, 1.0, "a light level", "");
        /// Length L of the local piecewise segments, in voxels.
        pub segment_voxels: u32 = 8, "segment",
            whole(4, 32, "a whole number of voxels", "voxels"), affects "local_opacity",
            ui Advanced;
        /// Resolution of the shadow volume: one point per N³ voxels.
        pub svr_scale: u32 = 2, "svr" | "svr-scale", one_of(&[1, 2, 4, 8], "voxels"),
            affects "global_opacity", ui Advanced;
        /// Radius R_Ω of the in-scattering sphere in voxels (0: no in-scattering).
        pub scatter_radius_voxels: f32 = 8.0, "scatter_radius",
            number(0.0, 64.0, "a number of voxels", "voxels"), affects "global_opacity";
        /// In-scattering directions J, refined one per frame.
        pub directions: u32 = 18, "directions",
            whole(1, MAX_DIRECTIONS, "a number of directions", ""), affects "in_scatter",
            ui Advanced;
        /// Henyey–Greenstein asymmetry g of the phase function (0: isotropic,
        /// the paper's; above 0 favours directions near the light's).
        pub phase_g: f32 = 0.0, "phase_g", number(-0.9, 0.9, "an asymmetry", ""),
            affects "in_scatter", ui Advanced;
        /// The direct light by local piecewise integration, or by marching
        /// every stored voxel to the light (the reference).
        pub method: DirectLightMethod = DirectLightMethod::Piecewise, "light_method", by_type(),
            affects "direct_light", ui Advanced;
    }
}
