//! [`TransferFunction`]: the map from physical values to colour and opacity, its
//! named [`Preset`]s, and the 1D RGBA table the GPU stages sample.
//!
//! Control points are in physical units (Hounsfield units for CT), so a preset
//! means the same tissue on every CT scan. Opacity is per reference step: the
//! opacity a sample contributes over one step of the volume's smallest spacing;
//! renderers correct it for their actual step length.

use std::fmt;
use std::str::FromStr;

use crate::Error;

/// The number of entries in a [`TransferFunction::table`] unless asked otherwise.
pub const TABLE_LEN: usize = 1024;
/// The most control points [`TransferFunction::parse`] accepts.
pub const MAX_POINTS: usize = 64;

/// Six hex digits `rrggbb` (a leading `#` allowed) → channels in 0..=1;
/// `None` for anything else.
pub fn parse_rgb_hex(text: &str) -> Option<[f32; 3]> {
    let hex = text.strip_prefix('#').unwrap_or(text);
    let channel = |i: usize| {
        hex.get(i..i + 2)
            .and_then(|h| u8::from_str_radix(h, 16).ok())
    };
    match (hex.len(), channel(0), channel(2), channel(4)) {
        (6, Some(r), Some(g), Some(b)) => Some([r, g, b].map(|c| f32::from(c) / 255.0)),
        _ => None,
    }
}

/// One control point: at `value`, the colour `rgb` and the opacity `opacity`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TfPoint {
    /// Physical value (e.g. HU).
    pub value: f32,
    /// Colour, each channel 0..=1 (display sRGB).
    pub rgb: [f32; 3],
    /// Opacity per reference step, 0..=1.
    pub opacity: f32,
}

impl TfPoint {
    /// A point with colour and opacity.
    pub const fn new(value: f32, rgb: [f32; 3], opacity: f32) -> TfPoint {
        TfPoint {
            value,
            rgb,
            opacity,
        }
    }
}

/// A piecewise-linear transfer function over physical values; constant beyond its
/// first and last control points.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TransferFunction {
    points: Vec<TfPoint>,
}

impl TransferFunction {
    /// Builds a transfer function from control points, which must be finite, in
    /// non-decreasing order of value, with colour and opacity in 0..=1.
    pub fn new(points: Vec<TfPoint>) -> Result<TransferFunction, Error> {
        let invalid = |reason: String| Err(Error::InvalidTransferFunction { reason });
        if points.is_empty() {
            return invalid("no control points: expected at least one".into());
        }
        for (i, p) in points.iter().enumerate() {
            if !p.value.is_finite() {
                return invalid(format!(
                    "point {i}: value {}: expected a finite number",
                    p.value
                ));
            }
            let unit = |x: f32| (0.0..=1.0).contains(&x);
            if !p.rgb.into_iter().all(unit) {
                return invalid(format!(
                    "point {i}: rgb {:?}: expected each channel in 0..=1",
                    p.rgb
                ));
            }
            if !unit(p.opacity) {
                return invalid(format!("point {i}: opacity {}: expected 0..=1", p.opacity));
            }
            if i > 0 && p.value < points[i - 1].value {
                return invalid(format!(
                    "point {i}: value {} after {}: expected values in non-decreasing order",
                    p.value,
                    points[i - 1].value
                ));
            }
        }
        Ok(TransferFunction { points })
    }

    /// The control points.
    pub fn points(&self) -> &[TfPoint] {
        &self.points
    }

    /// Parses the text form `VALUE:RRGGBB:OPACITY,…` (physical values, hex
    /// colours, opacities 0..1), e.g. `-200:000000:0,300:ffddcc:0.3,1200:ffffff:0.9`,
    /// at most [`MAX_POINTS`] points. [`fmt::Display`] writes the same form.
    ///
    /// # Errors
    /// [`Error::InvalidTransferFunction`], naming the point and what was expected.
    pub fn parse(text: &str) -> Result<TransferFunction, Error> {
        let invalid = |reason: String| Error::InvalidTransferFunction { reason };
        let parts: Vec<&str> = text.split(',').map(str::trim).collect();
        if parts.len() > MAX_POINTS {
            return Err(invalid(format!(
                "{} points: expected at most {MAX_POINTS}",
                parts.len()
            )));
        }
        let points = parts
            .iter()
            .enumerate()
            .map(|(i, part)| {
                let expected = || {
                    format!(
                        "point {i} '{part}': expected VALUE:RRGGBB:OPACITY, e.g. 300:ffddcc:0.3"
                    )
                };
                let mut fields = part.split(':');
                let (Some(value), Some(colour), Some(opacity), None) =
                    (fields.next(), fields.next(), fields.next(), fields.next())
                else {
                    return Err(expected());
                };
                let value: f32 = value.parse().map_err(|_| expected())?;
                let opacity: f32 = opacity.parse().map_err(|_| expected())?;
                let rgb = parse_rgb_hex(colour).ok_or_else(|| {
                    format!("point {i}: colour '{colour}': expected six hex digits rrggbb")
                })?;
                Ok(TfPoint::new(value, rgb, opacity))
            })
            .collect::<Result<Vec<_>, String>>()
            .map_err(invalid)?;
        TransferFunction::new(points)
    }

    /// Colour and opacity `[r, g, b, opacity]` at a physical value.
    pub fn evaluate(&self, value: f32) -> [f32; 4] {
        let rgba = |p: &TfPoint| [p.rgb[0], p.rgb[1], p.rgb[2], p.opacity];
        let upper = self.points.partition_point(|p| p.value <= value);
        if upper == 0 {
            return rgba(&self.points[0]);
        }
        if upper == self.points.len() {
            return rgba(&self.points[upper - 1]);
        }
        let (a, b) = (&self.points[upper - 1], &self.points[upper]);
        let t = (value - a.value) / (b.value - a.value);
        let (ca, cb) = (rgba(a), rgba(b));
        std::array::from_fn(|c| ca[c] + (cb[c] - ca[c]) * t)
    }

    /// The table that GPU stages sample: `len` RGBA entries over the physical
    /// `domain`, entry `i` holding the value at `domain[0] + (i + 0.5) / len *
    /// (domain[1] − domain[0])`, the centre convention of a 1D texture.
    pub fn table(&self, domain: [f32; 2], len: usize) -> Result<Vec<[f32; 4]>, Error> {
        if !(domain[0].is_finite() && domain[1].is_finite() && domain[1] > domain[0]) {
            return Err(Error::InvalidTransferFunction {
                reason: format!("table domain {domain:?}: expected finite bounds with min < max"),
            });
        }
        if len < 2 {
            return Err(Error::InvalidTransferFunction {
                reason: format!("table length {len}: expected at least 2 entries"),
            });
        }
        let width = domain[1] - domain[0];
        Ok((0..len)
            .map(|i| self.evaluate(domain[0] + (i as f32 + 0.5) / len as f32 * width))
            .collect())
    }

    /// The optical depth of a sample one voxel long at a physical value:
    /// −ln(1 − opacity), the opacity capped at 0.999 (a finite depth for an
    /// opaque value).
    pub fn optical_depth(&self, value: f32) -> f64 {
        let alpha = f64::from(self.evaluate(value)[3]).clamp(0.0, 0.999);
        -(1.0 - alpha).ln()
    }

    /// The span of values this transfer function shows: from the last point
    /// of no opacity before the first point with some (the first point when
    /// that has some) to the first point of no opacity after the last with
    /// some (else the last point). `None` when it shows nothing.
    pub fn shown_span(&self) -> Option<[f32; 2]> {
        let points = &self.points;
        let first = points.iter().position(|p| p.opacity > 0.0)?;
        let last = points.iter().rposition(|p| p.opacity > 0.0)?;
        let lo = points[first.saturating_sub(1)].value;
        let hi = points[(last + 1).min(points.len() - 1)].value;
        Some([lo, hi])
    }

    /// The largest opacity over a physical value interval: zero means a block whose
    /// values lie in `[lo, hi]` is empty under this transfer function.
    pub fn max_opacity(&self, lo: f32, hi: f32) -> f32 {
        let inside = self
            .points
            .iter()
            .filter(|p| p.value > lo && p.value < hi)
            .map(|p| p.opacity);
        inside
            .chain([self.evaluate(lo)[3], self.evaluate(hi)[3]])
            .fold(0.0, f32::max)
    }
}

/// The named transfer functions every dataset offers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Preset {
    /// CT: bone opaque and ivory, everything else clear.
    CtBone,
    /// CT: skin as a faint shell, soft tissue nearly clear, bone opaque.
    CtSoftTissue,
    /// CT angiography: contrast-filled vessels (150–500 HU) red, bone faint.
    CtAngio,
    /// MR: a warm grey ramp over the upper part of the value range.
    Mr,
    /// Any data: a grey ramp from 15% of the value range to its top.
    Generic,
}

impl Preset {
    /// Every preset, in the order menus list them.
    pub const ALL: [Preset; 5] = [
        Preset::CtBone,
        Preset::CtSoftTissue,
        Preset::CtAngio,
        Preset::Mr,
        Preset::Generic,
    ];

    /// The preset's name in URLs and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Preset::CtBone => "ct-bone",
            Preset::CtSoftTissue => "ct-soft-tissue",
            Preset::CtAngio => "ct-angio",
            Preset::Mr => "mr",
            Preset::Generic => "generic",
        }
    }

    /// The presets that suit a volume of `modality` whose physical values are
    /// in `unit`, the one to start with first: the CT presets (laid out in
    /// Hounsfield units) only for CT in HU, the MR one for MR, and the
    /// generic one (laid over the value range) for every volume.
    pub fn offered(modality: Option<&str>, unit: Option<&str>) -> &'static [Preset] {
        match (modality, unit) {
            (Some("CT"), Some("HU")) => &[
                Preset::CtBone,
                Preset::CtSoftTissue,
                Preset::CtAngio,
                Preset::Generic,
            ],
            (Some("MR"), _) => &[Preset::Mr, Preset::Generic],
            _ => &[Preset::Generic],
        }
    }

    /// The preset a volume of `modality` in `unit` starts with: CT bone for
    /// CT in HU, MR for MR, generic otherwise.
    pub fn for_data(modality: Option<&str>, unit: Option<&str>) -> Preset {
        Preset::offered(modality, unit)[0]
    }

    /// Why this preset does not suit a volume of `modality` in `unit`, or
    /// `None` when it is among [`Preset::offered`].
    pub fn unsuited(self, modality: Option<&str>, unit: Option<&str>) -> Option<String> {
        if Preset::offered(modality, unit).contains(&self) {
            return None;
        }
        let what = match (modality, unit) {
            (Some(m), Some(u)) => format!("{m} in {u}"),
            (Some(m), None) => format!("{m} without a unit"),
            (None, Some(u)) => format!("of no modality, in {u}"),
            (None, None) => "of no modality or unit".to_owned(),
        };
        let wants = match self {
            Preset::CtBone | Preset::CtSoftTissue | Preset::CtAngio => "CT in HU",
            Preset::Mr => "MR",
            Preset::Generic => "any volume",
        };
        Some(format!("{self} is for {wants} and the volume is {what}"))
    }

    /// A one-line description for menus and `--help`.
    pub fn description(self) -> &'static str {
        match self {
            Preset::CtBone => "CT bone: opaque ivory bone above ~300 HU",
            Preset::CtSoftTissue => "CT soft tissue: faint skin, clear soft tissue, opaque bone",
            Preset::CtAngio => "CT angiography: contrast vessels 150-500 HU in red, faint bone",
            Preset::Mr => "MR: warm grey ramp over the upper value range",
            Preset::Generic => "any data: grey ramp from 15% of the value range",
        }
    }

    /// The transfer function of this preset for a volume whose physical values
    /// span `value_range`. CT presets are in Hounsfield units and ignore the range;
    /// the others scale to it.
    pub fn transfer_function(self, value_range: [f32; 2]) -> TransferFunction {
        let [lo, hi] = value_range;
        let at = |f: f32| lo + (hi - lo) * f;
        let points = match self {
            Preset::CtBone => vec![
                TfPoint::new(150.0, [0.55, 0.25, 0.15], 0.0),
                TfPoint::new(300.0, [0.90, 0.80, 0.65], 0.25),
                TfPoint::new(700.0, [1.00, 0.97, 0.90], 0.85),
                TfPoint::new(2000.0, [1.00, 1.00, 1.00], 0.90),
            ],
            Preset::CtSoftTissue => vec![
                TfPoint::new(-600.0, [0.80, 0.50, 0.40], 0.0),
                TfPoint::new(-300.0, [0.90, 0.60, 0.50], 0.15),
                TfPoint::new(-100.0, [0.90, 0.60, 0.50], 0.04),
                TfPoint::new(100.0, [0.85, 0.45, 0.40], 0.03),
                TfPoint::new(200.0, [0.90, 0.80, 0.65], 0.10),
                TfPoint::new(500.0, [1.00, 0.95, 0.85], 0.70),
                TfPoint::new(2000.0, [1.00, 1.00, 1.00], 0.80),
            ],
            Preset::CtAngio => vec![
                TfPoint::new(100.0, [0.60, 0.05, 0.05], 0.0),
                TfPoint::new(150.0, [0.80, 0.10, 0.08], 0.30),
                TfPoint::new(400.0, [1.00, 0.35, 0.25], 0.70),
                TfPoint::new(500.0, [0.95, 0.90, 0.85], 0.05),
                TfPoint::new(2000.0, [1.00, 1.00, 1.00], 0.10),
            ],
            Preset::Mr => vec![
                TfPoint::new(at(0.15), [0.30, 0.25, 0.20], 0.0),
                TfPoint::new(at(0.40), [0.80, 0.70, 0.60], 0.20),
                TfPoint::new(at(1.00), [1.00, 0.98, 0.95], 0.60),
            ],
            Preset::Generic => vec![
                TfPoint::new(at(0.15), [0.0, 0.0, 0.0], 0.0),
                TfPoint::new(at(1.00), [1.0, 1.0, 1.0], 0.80),
            ],
        };
        TransferFunction { points }
    }
}

impl fmt::Display for TransferFunction {
    /// The text form [`TransferFunction::parse`] reads.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, p) in self.points.iter().enumerate() {
            let [r, g, b] = p.rgb.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8);
            let comma = if i == 0 { "" } else { "," };
            write!(f, "{comma}{}:{r:02x}{g:02x}{b:02x}:{}", p.value, p.opacity)?;
        }
        Ok(())
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Preset {
    type Err = Error;

    fn from_str(name: &str) -> Result<Preset, Error> {
        Preset::ALL
            .into_iter()
            .find(|p| p.name() == name)
            .ok_or_else(|| Error::UnknownPreset {
                name: name.to_owned(),
                expected: Preset::ALL.map(Preset::name).join(", "),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shown_span_runs_from_the_rise_of_opacity_to_its_last_fall() {
        let span = |text: &str| TransferFunction::parse(text).expect("tf").shown_span();
        assert_eq!(
            Preset::CtBone
                .transfer_function([-1024.0, 3071.0])
                .shown_span(),
            Some([150.0, 2000.0])
        );
        assert_eq!(
            span("0:000000:0,100:ffffff:1,200:ffffff:0,900:ffffff:0"),
            Some([0.0, 200.0])
        );
        assert_eq!(span("50:ffffff:0.5,80:ffffff:0.5"), Some([50.0, 80.0]));
        assert_eq!(span("0:000000:0,100:ffffff:0"), None);
    }

    #[test]
    fn ct_presets_are_offered_only_for_ct_in_hounsfield_units() {
        let names = |m, u| {
            Preset::offered(m, u)
                .iter()
                .map(|p| p.name())
                .collect::<Vec<_>>()
        };
        assert_eq!(
            names(Some("CT"), Some("HU")),
            ["ct-bone", "ct-soft-tissue", "ct-angio", "generic"]
        );
        // CT windowed to 8 bits (a MetaImage of LIDC) is not in HU.
        assert_eq!(names(Some("CT"), None), ["generic"]);
        assert_eq!(names(Some("MR"), None), ["mr", "generic"]);
        assert_eq!(names(None, None), ["generic"]);
        assert_eq!(Preset::for_data(Some("CT"), Some("HU")), Preset::CtBone);
        assert_eq!(Preset::CtBone.unsuited(Some("CT"), Some("HU")), None);
        let why = Preset::CtSoftTissue.unsuited(None, None).expect("refused");
        assert!(
            why.contains("CT in HU") && why.contains("no modality"),
            "{why}"
        );
        assert!(Preset::Mr.unsuited(Some("CT"), Some("HU")).is_some());
    }

    #[test]
    fn the_text_form_round_trips_and_bad_text_is_refused_with_the_point_named() {
        let tf = TransferFunction::parse("-200:000000:0, 300:ffddcc:0.3,1200:FFFFFF:0.9")
            .expect("valid");
        assert_eq!(tf.points().len(), 3);
        assert_eq!(tf.points()[1].rgb, [1.0, 221.0 / 255.0, 204.0 / 255.0]);
        assert_eq!(
            tf.to_string(),
            "-200:000000:0,300:ffddcc:0.3,1200:ffffff:0.9"
        );
        assert_eq!(TransferFunction::parse(&tf.to_string()).ok(), Some(tf));
        for (text, expected) in [
            ("", "point 0 ''"),
            ("100:ffffff", "point 0 '100:ffffff'"),
            ("100:ffffff:0.5:1", "expected VALUE:RRGGBB:OPACITY"),
            ("abc:ffffff:0.5", "point 0 'abc:ffffff:0.5'"),
            ("0:fff:0.5", "point 0: colour 'fff'"),
            ("0:ffffff:1.5", "opacity 1.5"),
            ("10:ffffff:0,5:ffffff:0", "non-decreasing"),
            ("NaN:ffffff:0", "finite"),
        ] {
            let e = TransferFunction::parse(text).expect_err(text).to_string();
            assert!(e.contains(expected), "{text}: {e}");
        }
        let many = vec!["0:000000:0"; MAX_POINTS + 1].join(",");
        assert!(
            TransferFunction::parse(&many)
                .expect_err("too many")
                .to_string()
                .contains("at most 64")
        );
    }

    #[test]
    fn evaluate_interpolates_and_clamps() {
        let tf = TransferFunction::new(vec![
            TfPoint::new(0.0, [0.0, 0.0, 0.0], 0.0),
            TfPoint::new(10.0, [1.0, 0.5, 0.0], 1.0),
        ])
        .expect("valid");
        assert_eq!(tf.evaluate(-5.0), [0.0; 4]);
        assert_eq!(tf.evaluate(5.0), [0.5, 0.25, 0.0, 0.5]);
        assert_eq!(tf.evaluate(50.0), [1.0, 0.5, 0.0, 1.0]);
    }

    #[test]
    fn table_samples_entry_centres() {
        let tf = TransferFunction::new(vec![
            TfPoint::new(0.0, [0.0; 3], 0.0),
            TfPoint::new(4.0, [1.0; 3], 1.0),
        ])
        .expect("valid");
        let table = tf.table([0.0, 4.0], 4).expect("table");
        let opacities: Vec<f32> = table.iter().map(|e| e[3]).collect();
        assert_eq!(opacities, [0.125, 0.375, 0.625, 0.875]);
    }

    #[test]
    fn bad_points_are_refused_with_the_point_named() {
        let err = TransferFunction::new(vec![
            TfPoint::new(1.0, [0.0; 3], 0.0),
            TfPoint::new(0.0, [0.0; 3], 0.0),
        ])
        .expect_err("decreasing");
        assert!(err.to_string().contains("point 1"), "{err}");
        let err =
            TransferFunction::new(vec![TfPoint::new(0.0, [0.0; 3], 1.5)]).expect_err("opacity");
        assert!(err.to_string().contains("opacity 1.5"), "{err}");
        assert!(TransferFunction::new(vec![]).is_err());
    }

    #[test]
    fn bone_preset_is_clear_in_air_and_soft_tissue_and_opaque_in_bone() {
        let tf = Preset::CtBone.transfer_function([-1024.0, 3071.0]);
        assert_eq!(tf.evaluate(-1000.0)[3], 0.0);
        assert_eq!(tf.evaluate(40.0)[3], 0.0);
        assert!(tf.evaluate(1000.0)[3] > 0.8);
        assert_eq!(tf.max_opacity(-1024.0, 100.0), 0.0);
        assert!(tf.max_opacity(-1024.0, 400.0) > 0.0);
    }

    #[test]
    fn preset_names_round_trip_and_unknown_names_list_the_choices() {
        for p in Preset::ALL {
            assert_eq!(p.name().parse::<Preset>().expect("known"), p);
            let tf = p.transfer_function([0.0, 255.0]);
            assert!(
                TransferFunction::new(tf.points().to_vec()).is_ok(),
                "{p} is valid"
            );
        }
        let err = "bone".parse::<Preset>().expect_err("unknown");
        let msg = err.to_string();
        assert!(
            msg.contains("'bone'") && msg.contains("ct-bone, ct-soft-tissue"),
            "{msg}"
        );
    }
}
