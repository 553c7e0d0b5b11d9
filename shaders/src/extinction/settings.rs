//! The settings of extinction-based illumination ([`ExtinctionSettings`]) and
//! its lights ([`ExtinctionLight`]), each setting declared once with the stage
//! its change recomputes from (the paper's algorithm 1).

use std::fmt;

use crate::global_light::{MAX_INTENSITY, check_direction, check_position, parse_vec3};
use crate::settings::{Choice, Expected, SettingError, TextSetting};

/// The most lights at once.
pub const MAX_LIGHTS: usize = 4;
/// The most ambient-occlusion shells.
pub const MAX_AO_SHELLS: u32 = 16;

/// Where a light of the light cache is and how it shines.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ExtinctionLightKind {
    /// A point light, as fractions of the volume's box (0..1 is inside).
    Point([f32; 3]),
    /// A directional light: the vector towards it, in patient space (LPS).
    Directional([f32; 3]),
    /// A spot light at `position` (fractions of the box) shining along
    /// `direction` (patient space) within `angle` degrees of its axis.
    Spot {
        /// Where it is, fractions of the volume's box.
        position: [f32; 3],
        /// Its axis, patient space.
        direction: [f32; 3],
        /// Half-angle of its cone of light, degrees (0 < angle ≤ 90).
        angle: f32,
    },
}

/// One light of extinction-based illumination.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExtinctionLight {
    /// Where it is.
    pub kind: ExtinctionLightKind,
    /// Its colour (0..1 per channel).
    pub colour: [f32; 3],
    /// Its intensity (0..=[`MAX_INTENSITY`]).
    pub intensity: f32,
}

/// How the ambient occlusion is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AoMethod {
    /// Cuboid shells queried from the SAT (the paper's).
    #[default]
    Sat,
    /// Explicit sampling of the spherical neighbourhood (reference).
    Sampled,
}

/// How the shadows are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ShadowMethod {
    /// Cone of cuboid SAT queries (the paper's).
    #[default]
    Cone,
    /// One classic shadow ray per light (reference).
    Ray,
}

impl Choice for AoMethod {
    const ALL: &'static [AoMethod] = &[AoMethod::Sat, AoMethod::Sampled];

    fn name(self) -> &'static str {
        match self {
            AoMethod::Sat => "sat",
            AoMethod::Sampled => "sampled",
        }
    }

    fn doc(self) -> &'static str {
        match self {
            AoMethod::Sat => "cuboid shells queried from the summed-area table (the paper's)",
            AoMethod::Sampled => "explicit sampling of the sphere (the reference)",
        }
    }
}

impl Choice for ShadowMethod {
    const ALL: &'static [ShadowMethod] = &[ShadowMethod::Cone, ShadowMethod::Ray];

    fn name(self) -> &'static str {
        match self {
            ShadowMethod::Cone => "cone",
            ShadowMethod::Ray => "ray",
        }
    }

    fn doc(self) -> &'static str {
        match self {
            ShadowMethod::Cone => "a cone of cuboid summed-area-table queries (the paper's)",
            ShadowMethod::Ray => "one classic shadow ray per light (the reference)",
        }
    }
}

crate::choice_setting!(AoMethod, ShadowMethod);

impl ExtinctionLight {
    /// Checks position, direction, angle, colour and intensity; on failure,
    /// what was wrong.
    pub(crate) fn check(&self) -> Result<(), String> {
        match self.kind {
            ExtinctionLightKind::Point(p) => check_position(p)?,
            ExtinctionLightKind::Directional(d) => check_direction(d)?,
            ExtinctionLightKind::Spot {
                position,
                direction,
                angle,
            } => {
                check_position(position)?;
                check_direction(direction)?;
                if !(angle.is_finite() && angle > 0.0 && angle <= 90.0) {
                    return Err(format!(
                        "the spot angle {angle} is not more than 0 and at most 90 degrees"
                    ));
                }
            }
        }
        if !self.colour.iter().all(|c| (0.0..=1.0).contains(c)) {
            return Err(format!(
                "the colour {:?} is not channels from 0 to 1",
                self.colour
            ));
        }
        if !(self.intensity.is_finite() && (0.0..=MAX_INTENSITY as f32).contains(&self.intensity)) {
            return Err(format!(
                "the intensity {} is not from 0 to {MAX_INTENSITY}",
                self.intensity
            ));
        }
        Ok(())
    }

    /// Reads one light: `point:x,y,z`, `directional:x,y,z` or
    /// `spot:x,y,z:dx,dy,dz:angle`, each optionally followed by `:rrggbb`
    /// and `:intensity`; on failure, what was wrong.
    pub(crate) fn parse(text: &str) -> Result<ExtinctionLight, String> {
        let parts: Vec<&str> = text.split(':').map(str::trim).collect();
        let (kind, rest) = match parts.as_slice() {
            ["point", p, rest @ ..] => (ExtinctionLightKind::Point(parse_vec3(p)?), rest),
            ["directional" | "dir", d, rest @ ..] => {
                (ExtinctionLightKind::Directional(parse_vec3(d)?), rest)
            }
            ["spot", p, d, angle, rest @ ..] => (
                ExtinctionLightKind::Spot {
                    position: parse_vec3(p)?,
                    direction: parse_vec3(d)?,
                    angle: angle
                        .parse()
                        .map_err(|_| format!("the spot angle '{angle}' is not a number"))?,
                },
                rest,
            ),
            [kind, ..] => return Err(format!("unknown kind or missing fields '{kind}'")),
            [] => return Err("no light".into()),
        };
        let colour = |c: &str| {
            blocks::transfer_function::parse_rgb_hex(c)
                .ok_or_else(|| format!("the colour '{c}' is not six hex digits rrggbb"))
        };
        let mut light = ExtinctionLight {
            kind,
            colour: [1.0; 3],
            intensity: 1.0,
        };
        match rest {
            [] => {}
            [c] => light.colour = colour(c)?,
            [c, intensity] => {
                light.colour = colour(c)?;
                light.intensity = intensity
                    .parse()
                    .map_err(|_| format!("the intensity '{intensity}' is not a number"))?;
            }
            _ => return Err("too many fields".into()),
        }
        light.check().map(|()| light)
    }
}

impl fmt::Display for ExtinctionLight {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = |v: [f32; 3]| format!("{},{},{}", v[0], v[1], v[2]);
        match self.kind {
            ExtinctionLightKind::Point(p) => write!(f, "point:{}", v(p))?,
            ExtinctionLightKind::Directional(d) => write!(f, "directional:{}", v(d))?,
            ExtinctionLightKind::Spot {
                position,
                direction,
                angle,
            } => write!(f, "spot:{}:{}:{angle}", v(position), v(direction))?,
        }
        let [r, g, b] = self.colour.map(|c| (c * 255.0).round() as u8);
        write!(f, ":{r:02x}{g:02x}{b:02x}:{}", self.intensity)
    }
}

/// The lights, separated by `;` (empty: none).
impl TextSetting for Vec<ExtinctionLight> {
    fn expected() -> String {
        format!(
            "at most {MAX_LIGHTS} lights separated by ';', each point:x,y,z, directional:x,y,z or \
             spot:x,y,z:dx,dy,dz:angle, optionally followed by :rrggbb and :intensity"
        )
    }

    fn parse_text(text: &str) -> Result<Vec<ExtinctionLight>, Expected> {
        let lights: Vec<ExtinctionLight> = text
            .split(';')
            .filter(|t| !t.trim().is_empty())
            .map(|t| ExtinctionLight::parse(t).map_err(|why| format!("light '{t}': {why}")))
            .collect::<Result<_, _>>()
            .map_err(|why| Expected(Self::expected()).because(why))?;
        lights.check_value().map(|()| lights)
    }

    fn check_value(&self) -> Result<(), Expected> {
        if self.len() > MAX_LIGHTS {
            return Err(Expected(Self::expected()).because(format!("{} lights", self.len())));
        }
        self.iter()
            .try_for_each(ExtinctionLight::check)
            .map_err(|why| Expected(Self::expected()).because(why))
    }

    fn text(&self) -> String {
        self.iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join(";")
    }
}

crate::text_setting!(Vec<ExtinctionLight>);

crate::settings! {
    /// The settings of extinction-based illumination (`shading=extinction`).
    /// Each names the first [`super::Stage`] its change recomputes.
    #[derive(Debug, Clone, PartialEq)]
    pub struct ExtinctionSettings in Extinction {
        /// The lights, separated by ';' (at most 4): point:X,Y,Z (fractions of
        /// the volume's box; 0..1 is inside), directional:X,Y,Z (towards the
        /// light, patient LPS) or spot:X,Y,Z:DX,DY,DZ:ANGLE (position, axis,
        /// half-angle in degrees), each optionally followed by :RRGGBB and
        /// :INTENSITY. Empty: ambient light only.
        pub lights: Vec<ExtinctionLight> = vec![ExtinctionLight {
            // As global light propagation's default: from the upper left in
            // the default view.
            kind: ExtinctionLightKind::Directional([-0.6, -0.5, 0.62]),
            colour: [1.0; 3],
            intensity: 0.8,
        }], "lights", by_type(), affects "soft_shadow";
        /// Ambient light I_A.
        pub ambient: f32 = 0.5, "ambient", number(0.0, MAX_INTENSITY, "an intensity", ""),
            affects "soft_shadow";
        /// Grid cells of the summed-area table and light cache along the
        /// volume's longest side (the others in proportion).
        pub sat_size: u32 = 128, "sat_size", whole(16, 256, "a whole number of cells", "cells"),
            affects "extinction_sat", ui Advanced;
        /// Ambient-occlusion radius R in grid cells.
        pub ao_radius: u32 = 8, "ao_radius", whole(1, 32, "a whole number of cells", "cells"),
            affects "ambient_occlusion";
        /// Ambient-occlusion shells (at most the radius).
        pub ao_shells: u32 = 3, "ao_shells", whole(1, MAX_AO_SHELLS, "a number of shells", ""),
            affects "ambient_occlusion", ui Advanced;
        /// Ambient-occlusion strength: scales the exponent, the weighted mean
        /// Δt·τ of the neighbourhood (0.4: a flat opaque surface keeps about
        /// 45 % of the ambient light).
        pub ao_strength: f32 = 0.4, "ao_strength", number(0.0, 16.0, "a strength", ""),
            affects "ambient_occlusion";
        /// Colour bleeding: neighbours tint the ambient light with their colour.
        pub colour_bleeding: bool = false, "colour_bleeding", by_type(),
            affects "extinction_sat";
        /// Half-angle of the shadow cones in degrees (wider is softer).
        pub cone_angle: f32 = 3.0, "cone_angle", degrees(0.0, 45.0), affects "soft_shadow";
        /// Cuboids per volume side at the start of each cone.
        pub cone_frequency: f32 = 50.0, "cone_frequency",
            number(1.0, 1000.0, "a number of cuboids per volume side", ""),
            affects "soft_shadow", ui Advanced;
        /// Growth of each cone cuboid's length over the one before.
        pub cone_growth: f32 = 0.05, "cone_growth", number(0.0, 1.0, "a growth rate", ""),
            affects "soft_shadow", ui Advanced;
        /// Ambient occlusion by summed-area-table shells, or by explicit
        /// sampling of the sphere (the reference).
        pub ao_method: AoMethod = AoMethod::Sat, "ao_method", by_type(),
            affects "ambient_occlusion", ui Advanced;
        /// Shadows by summed-area-table cones, or one classic shadow ray per
        /// light (the reference).
        pub shadow_method: ShadowMethod = ShadowMethod::Cone, "shadow_method", by_type(),
            affects "soft_shadow", ui Advanced;
    }
}

impl ExtinctionSettings {
    /// Checks every setting, and what no single one can: at most as many
    /// shells as the radius, and no colour bleeding from the grey sampled
    /// reference.
    pub fn validate(&self) -> Result<(), SettingError> {
        crate::settings::Settings::validate_fields(self)?;
        if self.ao_shells > self.ao_radius {
            return Err(SettingError::of_value(
                "ao_shells",
                self.ao_shells,
                format!(
                    "a number of shells from 1 to {} (at most ao_radius={})",
                    self.ao_radius.min(MAX_AO_SHELLS),
                    self.ao_radius
                ),
            ));
        }
        if self.ao_method == AoMethod::Sampled && self.colour_bleeding {
            return Err(SettingError::of_value(
                "ao_method",
                "\"sampled\"",
                "sat with colour_bleeding=true (the sampled reference is grey only)",
            ));
        }
        Ok(())
    }
}
