//! View settings, each declared once: name, type, default, range, unit, group
//! and one doc line, in a [`settings!`](crate::settings!) declaration beside
//! the code that uses it. Everything else about a setting is derived from that
//! declaration: the `render` command line's flags, the query of
//! `GET /api/render`, typed JSON patches of view sessions, `GET /api/settings`
//! (from which the web client builds its controls), the settings table in the
//! README and the checks of [`Setting::validate`]. A refused value is a
//! [`SettingError`] naming the setting, the value and what was expected, the
//! same on every path.
//!
//! A settings struct implements [`Settings`]: its [`Settings::settings`] lists
//! its own fields and those of the settings structs nested in it (the frame
//! request nests the camera and each illumination mode's settings), each as a
//! [`Setting`] that reads and writes its field.

use std::fmt;
use std::marker::PhantomData;
use std::sync::OnceLock;

/// JSON, as settings are read from view-session patches and described.
pub use serde_json::Value as Json;

/// The most characters of a refused value a message repeats.
const SHOWN_CHARS: usize = 80;

/// What a setting is about; clients group their controls by it and the docs
/// list settings in this order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Group {
    /// Which dataset is shown.
    Data,
    /// Where the eye is and how it projects.
    Camera,
    /// The image's size and background.
    Image,
    /// Values → colour and opacity.
    Classification,
    /// How samples are lit and combined.
    Shading,
    /// How much of the data the GPU keeps.
    Detail,
    /// The part of the volume shown.
    Clip,
    /// Global light propagation (`shading=global`).
    GlobalLight,
    /// Extinction-based illumination (`shading=extinction`).
    Extinction,
}

impl Group {
    /// Every group, in the order the docs list them.
    pub const ALL: [Group; 9] = [
        Group::Data,
        Group::Camera,
        Group::Image,
        Group::Classification,
        Group::Shading,
        Group::Detail,
        Group::Clip,
        Group::GlobalLight,
        Group::Extinction,
    ];

    /// The group's name in `GET /api/settings`.
    pub fn name(self) -> &'static str {
        match self {
            Group::Data => "data",
            Group::Camera => "camera",
            Group::Image => "image",
            Group::Classification => "classification",
            Group::Shading => "shading",
            Group::Detail => "detail",
            Group::Clip => "clip",
            Group::GlobalLight => "global_light",
            Group::Extinction => "extinction",
        }
    }

    /// A title for headings and panels.
    pub fn title(self) -> &'static str {
        match self {
            Group::Data => "Data",
            Group::Camera => "Camera",
            Group::Image => "Image",
            Group::Classification => "Classification",
            Group::Shading => "Shading",
            Group::Detail => "Level of detail",
            Group::Clip => "Clip",
            Group::GlobalLight => "Global light (shading=global)",
            Group::Extinction => "Extinction-based illumination (shading=extinction)",
        }
    }
}

/// Whether clients show a setting among the first controls or tuck it away.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ui {
    /// Shown with the group.
    Basic,
    /// For experts and measurements: shown on request.
    Advanced,
}

impl Ui {
    /// The name in `GET /api/settings`.
    pub fn name(self) -> &'static str {
        match self {
            Ui::Basic => "basic",
            Ui::Advanced => "advanced",
        }
    }
}

/// Which values a setting takes beyond what its type says.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Check {
    /// A finite number in `min..=max`.
    Number {
        /// Smallest value.
        min: f64,
        /// Largest value.
        max: f64,
        /// What the number is, for messages: "a number of degrees".
        what: &'static str,
        /// Its unit for controls ("°", "px", …; empty when it has none).
        unit: &'static str,
    },
    /// A whole number in `min..=max`.
    Whole {
        /// Smallest value.
        min: u32,
        /// Largest value.
        max: u32,
        /// What the number is, for messages: "a whole number of pixels".
        what: &'static str,
        /// Its unit for controls.
        unit: &'static str,
    },
    /// One of a few whole numbers.
    OneOf {
        /// The values, smallest first.
        values: &'static [u32],
        /// Their unit for controls.
        unit: &'static str,
    },
    /// As the value's type says: choices, colours, text forms.
    Type,
}

/// A number in degrees, `min..=max`.
pub const fn degrees(min: f64, max: f64) -> Check {
    Check::Number {
        min,
        max,
        what: "a number of degrees",
        unit: "°",
    }
}

/// A finite number `min..=max`: `what` it is for messages, its `unit` for controls.
pub const fn number(min: f64, max: f64, what: &'static str, unit: &'static str) -> Check {
    Check::Number {
        min,
        max,
        what,
        unit,
    }
}

/// A whole number `min..=max`: `what` it is for messages, its `unit` for controls.
pub const fn whole(min: u32, max: u32, what: &'static str, unit: &'static str) -> Check {
    Check::Whole {
        min,
        max,
        what,
        unit,
    }
}

/// One of `values` (in `unit`).
pub const fn one_of(values: &'static [u32], unit: &'static str) -> Check {
    Check::OneOf { values, unit }
}

/// Whatever the value's type takes.
pub const fn by_type() -> Check {
    Check::Type
}

impl Check {
    /// The unit for controls, if any.
    pub fn unit(&self) -> &'static str {
        match *self {
            Check::Number { unit, .. } | Check::Whole { unit, .. } | Check::OneOf { unit, .. } => {
                unit
            }
            Check::Type => "",
        }
    }

    /// What the check takes, for messages (`None`: as the type says).
    pub fn expected(&self) -> Option<String> {
        match *self {
            Check::Number { min, max, what, .. } => Some(format!("{what} from {min} to {max}")),
            Check::Whole { min, max, what, .. } => Some(format!("{what} from {min} to {max}")),
            Check::OneOf { values, .. } => Some(or_list(values)),
            Check::Type => None,
        }
    }

    /// Whether a number meets the check (finite, in range, whole where asked).
    fn admits(&self, value: f64) -> bool {
        if !value.is_finite() {
            return false;
        }
        match *self {
            Check::Number { min, max, .. } => (min..=max).contains(&value),
            Check::Whole { min, max, .. } => {
                value.fract() == 0.0 && (f64::from(min)..=f64::from(max)).contains(&value)
            }
            Check::OneOf { values, .. } => values.iter().any(|&v| f64::from(v) == value),
            Check::Type => true,
        }
    }
}

/// `a, b, c or d`.
pub fn or_list(items: &[impl fmt::Display]) -> String {
    let text: Vec<String> = items.iter().map(ToString::to_string).collect();
    match text.split_last() {
        None => String::new(),
        Some((last, [])) => last.clone(),
        Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
    }
}

/// A value as a client gave it.
#[derive(Debug, Clone, Copy)]
pub enum Raw<'a> {
    /// Text: a query parameter or a command-line value.
    Text(&'a str),
    /// JSON: a view-session patch.
    Json(&'a Json),
}

/// `text`, or its first [`SHOWN_CHARS`] characters and its length.
fn shortened(text: String) -> String {
    let count = text.chars().count();
    if count <= SHOWN_CHARS {
        return text;
    }
    let cut: String = text.chars().take(SHOWN_CHARS).collect();
    format!("{cut}… ({count} characters)")
}

impl Raw<'_> {
    /// The value as messages show it: quoted text, or JSON; at most
    /// [`SHOWN_CHARS`] characters of it.
    pub fn shown(&self) -> String {
        shortened(match self {
            Raw::Text(text) => format!("{text:?}"),
            Raw::Json(json) => json.to_string(),
        })
    }

    /// The text, or (for JSON) the string; `None` for JSON of another type.
    fn text(&self) -> Option<&str> {
        match self {
            Raw::Text(text) => Some(text),
            Raw::Json(Json::String(text)) => Some(text),
            Raw::Json(_) => None,
        }
    }

    /// The number: parsed text, or a JSON number (never a JSON string).
    fn number(&self) -> Option<f64> {
        match self {
            Raw::Text(text) => text.trim().parse().ok(),
            Raw::Json(json) => json.as_f64(),
        }
    }
}

/// A refused setting: which, the value given and what was expected. Every
/// path (`render` flags, `/api/render`, view sessions) says the same.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{setting}={value}: expected {expected}")]
pub struct SettingError {
    /// The setting's name (as in queries and view messages).
    pub setting: String,
    /// The value as given (quoted text, or JSON), shortened when long.
    pub value: String,
    /// What the setting takes, and what was wrong when that helps.
    pub expected: String,
}

impl SettingError {
    /// A refusal of `value` for `setting`.
    pub fn new(setting: &str, value: &Raw<'_>, expected: impl Into<String>) -> SettingError {
        SettingError {
            setting: setting.to_owned(),
            value: value.shown(),
            expected: expected.into(),
        }
    }

    /// A refusal of a current value (one the settings struct holds).
    pub fn of_value(setting: &str, value: impl fmt::Display, expected: impl Into<String>) -> Self {
        SettingError {
            setting: setting.to_owned(),
            value: shortened(value.to_string()),
            expected: expected.into(),
        }
    }
}

/// A type a setting's field can have: how it is read from text and JSON,
/// checked, and shown.
pub trait SettingValue: Clone + PartialEq + Send + Sync + 'static {
    /// The kind for clients: `number`, `whole`, `one_of`, `bool`, `choice`,
    /// `colour` or `text`.
    fn kind(check: &Check) -> &'static str;

    /// What the type takes, for messages, when the check does not say.
    fn expected() -> String;

    /// The choices (name, doc) of a choice.
    fn choices() -> Vec<(&'static str, &'static str)> {
        Vec::new()
    }

    /// Reads a value; on failure, what was expected (and what was wrong).
    fn read(raw: &Raw<'_>, check: &Check) -> Result<Self, String>;

    /// Checks a value held (set without [`SettingValue::read`]); on failure,
    /// what was expected.
    fn check(&self, check: &Check) -> Result<(), String>;

    /// The value as JSON (`GET /api/settings` defaults, view-session state).
    fn to_json(&self) -> Json;

    /// The value's text form, as a query or the command line gives it.
    fn to_text(&self) -> String;
}

/// What `check` expects of a number, else what `T` expects.
fn expected_of<T: SettingValue>(check: &Check) -> String {
    check.expected().unwrap_or_else(T::expected)
}

/// An `f32` as the shortest decimal that reads back as it (0.15, not
/// 0.15000000596046448).
fn f32_json(value: f32) -> Json {
    value
        .to_string()
        .parse::<f64>()
        .ok()
        .and_then(serde_json::Number::from_f64)
        .map_or(Json::Null, Json::Number)
}

impl SettingValue for f32 {
    fn kind(_: &Check) -> &'static str {
        "number"
    }

    fn expected() -> String {
        "a finite number".into()
    }

    fn read(raw: &Raw<'_>, check: &Check) -> Result<f32, String> {
        match raw.number() {
            Some(v) if check.admits(v) && (v as f32).is_finite() => Ok(v as f32),
            _ => Err(expected_of::<f32>(check)),
        }
    }

    fn check(&self, check: &Check) -> Result<(), String> {
        let v = f64::from(*self);
        // Bounds written as f64 (0.9) hold values read as f32 (0.9f32 > 0.9).
        let within = |min: f64, max: f64| {
            (f64::from(min as f32)..=f64::from(max as f32)).contains(&v) && v.is_finite()
        };
        let ok = match *check {
            Check::Number { min, max, .. } => within(min, max),
            _ => check.admits(v),
        };
        if ok {
            Ok(())
        } else {
            Err(expected_of::<f32>(check))
        }
    }

    fn to_json(&self) -> Json {
        f32_json(*self)
    }

    fn to_text(&self) -> String {
        self.to_string()
    }
}

impl SettingValue for u32 {
    fn kind(check: &Check) -> &'static str {
        match check {
            Check::OneOf { .. } => "one_of",
            _ => "whole",
        }
    }

    fn expected() -> String {
        format!("a whole number from 0 to {}", u32::MAX)
    }

    fn read(raw: &Raw<'_>, check: &Check) -> Result<u32, String> {
        let value = match raw {
            Raw::Text(text) => text.trim().parse::<u32>().ok(),
            Raw::Json(json) => json.as_u64().and_then(|v| u32::try_from(v).ok()),
        };
        match value {
            Some(v) if check.admits(f64::from(v)) => Ok(v),
            _ => Err(expected_of::<u32>(check)),
        }
    }

    fn check(&self, check: &Check) -> Result<(), String> {
        if check.admits(f64::from(*self)) {
            Ok(())
        } else {
            Err(expected_of::<u32>(check))
        }
    }

    fn to_json(&self) -> Json {
        Json::from(*self)
    }

    fn to_text(&self) -> String {
        self.to_string()
    }
}

impl SettingValue for bool {
    fn kind(_: &Check) -> &'static str {
        "bool"
    }

    fn expected() -> String {
        "true or false".into()
    }

    fn read(raw: &Raw<'_>, _: &Check) -> Result<bool, String> {
        match raw {
            Raw::Text("true") | Raw::Json(Json::Bool(true)) => Ok(true),
            Raw::Text("false") | Raw::Json(Json::Bool(false)) => Ok(false),
            _ => Err(bool::expected()),
        }
    }

    fn check(&self, _: &Check) -> Result<(), String> {
        Ok(())
    }

    fn to_json(&self) -> Json {
        Json::Bool(*self)
    }

    fn to_text(&self) -> String {
        self.to_string()
    }
}

/// A colour, `rrggbb`; channels 0..=1.
impl SettingValue for [f32; 3] {
    fn kind(_: &Check) -> &'static str {
        "colour"
    }

    fn expected() -> String {
        "six hex digits rrggbb".into()
    }

    fn read(raw: &Raw<'_>, _: &Check) -> Result<[f32; 3], String> {
        raw.text()
            .and_then(|t| blocks::transfer_function::parse_rgb_hex(t).ok())
            .ok_or_else(Self::expected)
    }

    fn check(&self, _: &Check) -> Result<(), String> {
        if self.iter().all(|c| (0.0..=1.0).contains(c)) {
            Ok(())
        } else {
            Err("each channel from 0 to 1".into())
        }
    }

    fn to_json(&self) -> Json {
        Json::String(self.to_text())
    }

    fn to_text(&self) -> String {
        let [r, g, b] = self.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8);
        format!("{r:02x}{g:02x}{b:02x}")
    }
}

/// A value of a few named choices (an enum), read and written by name.
pub trait Choice: Copy + PartialEq + Send + Sync + 'static {
    /// Every choice, in the order menus list them.
    const ALL: &'static [Self];

    /// The choice's name in queries, view messages and on the command line.
    fn name(self) -> &'static str;

    /// One line on what it does.
    fn doc(self) -> &'static str;

    /// The choice named `name`, if any.
    fn named(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|c| c.name() == name)
    }

    /// "one of a, b or c", for messages.
    fn expected() -> String {
        let names: Vec<&str> = Self::ALL.iter().map(|c| c.name()).collect();
        format!("one of {}", or_list(&names))
    }
}

/// Implements [`SettingValue`] for [`Choice`] enums.
#[macro_export]
macro_rules! choice_setting {
    ($($t:ty),* $(,)?) => {$(
        impl $crate::settings::SettingValue for $t {
            fn kind(_: &$crate::settings::Check) -> &'static str {
                "choice"
            }

            fn expected() -> String {
                <$t as $crate::settings::Choice>::expected()
            }

            fn choices() -> Vec<(&'static str, &'static str)> {
                <$t as $crate::settings::Choice>::ALL
                    .iter()
                    .map(|c| {
                        (
                            $crate::settings::Choice::name(*c),
                            $crate::settings::Choice::doc(*c),
                        )
                    })
                    .collect()
            }

            fn read(
                raw: &$crate::settings::Raw<'_>,
                _: &$crate::settings::Check,
            ) -> Result<$t, String> {
                $crate::settings::read_choice(raw)
            }

            fn check(&self, _: &$crate::settings::Check) -> Result<(), String> {
                Ok(())
            }

            fn to_json(&self) -> $crate::settings::Json {
                $crate::settings::Json::String(
                    $crate::settings::Choice::name(*self).to_owned(),
                )
            }

            fn to_text(&self) -> String {
                $crate::settings::Choice::name(*self).to_owned()
            }
        }
    )*};
}

/// Reads a choice by name (text, or a JSON string).
pub fn read_choice<C: Choice>(raw: &Raw<'_>) -> Result<C, String> {
    raw.text()
        .and_then(|t| C::named(t.trim()))
        .ok_or_else(C::expected)
}

/// A value with a text form of its own (a clip box, a light, a transfer
/// function): parsed and printed by the type, given as text or a JSON string.
pub trait TextSetting: Clone + PartialEq + Send + Sync + 'static {
    /// The text form, for messages: "six fractions x0,y0,z0,x1,y1,z1 …".
    fn expected() -> String;

    /// Parses the text form; on failure, what was expected and what was wrong.
    fn parse_text(text: &str) -> Result<Self, String>;

    /// Checks a value held; on failure, what was expected.
    fn check_value(&self) -> Result<(), String>;

    /// The text form.
    fn text(&self) -> String;
}

/// Implements [`SettingValue`] for [`TextSetting`] types.
#[macro_export]
macro_rules! text_setting {
    ($($t:ty),* $(,)?) => {$(
        impl $crate::settings::SettingValue for $t {
            fn kind(_: &$crate::settings::Check) -> &'static str {
                "text"
            }

            fn expected() -> String {
                <$t as $crate::settings::TextSetting>::expected()
            }

            fn read(
                raw: &$crate::settings::Raw<'_>,
                _: &$crate::settings::Check,
            ) -> Result<$t, String> {
                $crate::settings::read_text(raw)
            }

            fn check(&self, _: &$crate::settings::Check) -> Result<(), String> {
                $crate::settings::TextSetting::check_value(self)
            }

            fn to_json(&self) -> $crate::settings::Json {
                $crate::settings::Json::String($crate::settings::TextSetting::text(self))
            }

            fn to_text(&self) -> String {
                $crate::settings::TextSetting::text(self)
            }
        }
    )*};
}

/// Reads a text form (text, or a JSON string).
pub fn read_text<T: TextSetting>(raw: &Raw<'_>) -> Result<T, String> {
    match raw.text() {
        Some(text) => T::parse_text(text),
        None => Err(format!("text: {}", T::expected())),
    }
}

/// An optional value: absent (`None`) means "as the data says" (a preset
/// chosen by modality, no transfer function of one's own, the server's
/// first dataset). JSON `null` and the setting's removal both give `None`.
impl<T: SettingValue> SettingValue for Option<T> {
    fn kind(check: &Check) -> &'static str {
        T::kind(check)
    }

    fn expected() -> String {
        T::expected()
    }

    fn choices() -> Vec<(&'static str, &'static str)> {
        T::choices()
    }

    fn read(raw: &Raw<'_>, check: &Check) -> Result<Option<T>, String> {
        T::read(raw, check).map(Some)
    }

    fn check(&self, check: &Check) -> Result<(), String> {
        self.as_ref().map_or(Ok(()), |v| v.check(check))
    }

    fn to_json(&self) -> Json {
        self.as_ref().map_or(Json::Null, T::to_json)
    }

    fn to_text(&self) -> String {
        self.as_ref().map_or_else(String::new, T::to_text)
    }
}

/// A name: 1 to 128 characters of letters, digits and `-_.`, as dataset ids are.
impl TextSetting for String {
    fn expected() -> String {
        "an id of 1 to 128 letters, digits, '-', '_' or '.'".into()
    }

    fn parse_text(text: &str) -> Result<String, String> {
        let value = text.to_owned();
        value.check_value().map(|()| value)
    }

    fn check_value(&self) -> Result<(), String> {
        let ok = (1..=128).contains(&self.chars().count())
            && self
                .chars()
                .all(|c| c.is_alphanumeric() || matches!(c, '-' | '_' | '.'));
        if ok {
            Ok(())
        } else {
            Err(<String as TextSetting>::expected())
        }
    }

    fn text(&self) -> String {
        self.clone()
    }
}

text_setting!(String);

/// A declared setting's description: everything but the field it sets.
#[derive(Debug, Clone, Copy)]
pub struct Spec {
    /// The name in queries, view messages and `GET /api/settings`.
    pub name: &'static str,
    /// The `render` command line's flag (without `--`) when it is not the
    /// name with `_` as `-`.
    pub flag_given: Option<&'static str>,
    /// What it is about.
    pub group: Group,
    /// The doc comment of its declaration.
    pub doc: &'static str,
    /// Which values it takes beyond its type.
    pub check: Check,
    /// The first cached stage of its illumination mode a change recomputes
    /// (`None`: nothing cached depends on it; it applies when a frame is drawn).
    pub affects: Option<&'static str>,
    /// Shown at once, or on request.
    pub ui: Ui,
}

impl Spec {
    /// The `render` command line's flag, without `--`.
    pub fn flag(&self) -> std::borrow::Cow<'static, str> {
        match self.flag_given {
            Some(flag) => flag.into(),
            None => self.name.replace('_', "-").into(),
        }
    }

    /// The doc comment as one line.
    pub fn doc_line(&self) -> String {
        self.doc
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect::<Vec<_>>()
            .join(" ")
    }
}

/// One setting of the settings struct `S`: its [`Spec`] and access to its field.
pub trait Setting<S>: Send + Sync {
    /// What it is.
    fn spec(&self) -> &Spec;

    /// Sets the field from `raw`, or says why not (the field is unchanged then).
    fn set(&self, settings: &mut S, raw: &Raw<'_>) -> Result<(), SettingError>;

    /// Sets the field back to its default.
    fn reset(&self, settings: &mut S);

    /// Checks the field's value.
    fn validate(&self, settings: &S) -> Result<(), SettingError>;

    /// The field's value as JSON.
    fn json(&self, settings: &S) -> Json;

    /// The field's value in its text form.
    fn text(&self, settings: &S) -> String;

    /// The default as JSON.
    fn default_json(&self) -> Json;

    /// The default in its text form.
    fn default_text(&self) -> String;

    /// The kind: `number`, `whole`, `one_of`, `bool`, `choice`, `colour` or `text`.
    fn kind(&self) -> &'static str;

    /// What it takes, for messages and docs.
    fn expected(&self) -> String;

    /// Its choices (name, doc), for choices.
    fn choices(&self) -> Vec<(&'static str, &'static str)>;
}

/// A field of type `T` of the settings struct `S`, as the
/// [`settings!`](crate::settings!) macro declares it.
pub struct Field<S, T> {
    /// What it is.
    pub spec: Spec,
    /// The field.
    pub get: fn(&S) -> &T,
    /// The field, to change.
    pub get_mut: fn(&mut S) -> &mut T,
    /// Its default.
    pub default: fn() -> T,
}

impl<S, T> fmt::Debug for Field<S, T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Field").field("spec", &self.spec).finish()
    }
}

impl<S, T: SettingValue> Setting<S> for Field<S, T> {
    fn spec(&self) -> &Spec {
        &self.spec
    }

    fn set(&self, settings: &mut S, raw: &Raw<'_>) -> Result<(), SettingError> {
        let value = T::read(raw, &self.spec.check)
            .map_err(|expected| SettingError::new(self.spec.name, raw, expected))?;
        *(self.get_mut)(settings) = value;
        Ok(())
    }

    fn reset(&self, settings: &mut S) {
        *(self.get_mut)(settings) = (self.default)();
    }

    fn validate(&self, settings: &S) -> Result<(), SettingError> {
        let value = (self.get)(settings);
        value
            .check(&self.spec.check)
            .map_err(|expected| SettingError::of_value(self.spec.name, value.to_json(), expected))
    }

    fn json(&self, settings: &S) -> Json {
        (self.get)(settings).to_json()
    }

    fn text(&self, settings: &S) -> String {
        (self.get)(settings).to_text()
    }

    fn default_json(&self) -> Json {
        (self.default)().to_json()
    }

    fn default_text(&self) -> String {
        (self.default)().to_text()
    }

    fn kind(&self) -> &'static str {
        T::kind(&self.spec.check)
    }

    fn expected(&self) -> String {
        expected_of::<T>(&self.spec.check)
    }

    fn choices(&self) -> Vec<(&'static str, &'static str)> {
        T::choices()
    }
}

/// A setting of the settings struct `I` nested in `O` (the camera in the
/// frame request): the inner setting through the outer struct's field.
pub struct Nested<O: 'static, I: 'static> {
    inner: &'static dyn Setting<I>,
    get: fn(&O) -> &I,
    get_mut: fn(&mut O) -> &mut I,
    _outer: PhantomData<fn(&O)>,
}

impl<O: 'static, I: 'static> fmt::Debug for Nested<O, I> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Nested")
            .field("spec", self.inner.spec())
            .finish()
    }
}

impl<O: 'static, I: 'static> Nested<O, I> {
    /// `inner`, reached through `get` and `get_mut`.
    pub fn new(
        inner: &'static dyn Setting<I>,
        get: fn(&O) -> &I,
        get_mut: fn(&mut O) -> &mut I,
    ) -> Nested<O, I> {
        Nested {
            inner,
            get,
            get_mut,
            _outer: PhantomData,
        }
    }
}

impl<O: 'static, I: 'static> Setting<O> for Nested<O, I> {
    fn spec(&self) -> &Spec {
        self.inner.spec()
    }

    fn set(&self, settings: &mut O, raw: &Raw<'_>) -> Result<(), SettingError> {
        self.inner.set((self.get_mut)(settings), raw)
    }

    fn reset(&self, settings: &mut O) {
        self.inner.reset((self.get_mut)(settings));
    }

    fn validate(&self, settings: &O) -> Result<(), SettingError> {
        self.inner.validate((self.get)(settings))
    }

    fn json(&self, settings: &O) -> Json {
        self.inner.json((self.get)(settings))
    }

    fn text(&self, settings: &O) -> String {
        self.inner.text((self.get)(settings))
    }

    fn default_json(&self) -> Json {
        self.inner.default_json()
    }

    fn default_text(&self) -> String {
        self.inner.default_text()
    }

    fn kind(&self) -> &'static str {
        self.inner.kind()
    }

    fn expected(&self) -> String {
        self.inner.expected()
    }

    fn choices(&self) -> Vec<(&'static str, &'static str)> {
        self.inner.choices()
    }
}

/// A struct of settings declared with [`settings!`](crate::settings!).
pub trait Settings: Default + Sized + 'static {
    /// Every setting: the struct's own, then those of the structs nested in it.
    fn settings() -> &'static [&'static dyn Setting<Self>];

    /// The setting named `name`, if there is one.
    fn setting(name: &str) -> Option<&'static dyn Setting<Self>> {
        Self::settings()
            .iter()
            .copied()
            .find(|s| s.spec().name == name)
    }

    /// Checks every setting's value, naming the first one out of range.
    fn validate_fields(&self) -> Result<(), SettingError> {
        Self::settings().iter().try_for_each(|s| s.validate(self))
    }

    /// Sets `name` from `raw`; unknown names are refused, naming the known ones.
    fn set_named(&mut self, name: &str, raw: &Raw<'_>) -> Result<(), SettingError> {
        let setting = Self::setting(name).ok_or_else(|| unknown::<Self>(name, raw))?;
        setting.set(self, raw)
    }

    /// Sets `name` back to its default; unknown names are refused.
    fn reset_named(&mut self, name: &str) -> Result<(), SettingError> {
        let setting =
            Self::setting(name).ok_or_else(|| unknown::<Self>(name, &Raw::Json(&Json::Null)))?;
        setting.reset(self);
        Ok(())
    }

    /// Every setting's current value, by name.
    fn to_json(&self) -> serde_json::Map<String, Json> {
        Self::settings()
            .iter()
            .map(|s| (s.spec().name.to_owned(), s.json(self)))
            .collect()
    }
}

/// What a cached result of `stage` (one of a mode's `stages`, in the order
/// they run) depends on among the settings of `S`: the values of those whose
/// change recomputes it, because they affect it or a stage before it.
pub fn stage_key<S: Settings>(settings: &S, stages: &[&str], stage: &str) -> Vec<Json> {
    let last = stages
        .iter()
        .position(|s| *s == stage)
        .unwrap_or(stages.len());
    S::settings()
        .iter()
        .filter(|s| {
            s.spec()
                .affects
                .and_then(|a| stages.iter().position(|s| *s == a))
                .is_some_and(|i| i <= last)
        })
        .map(|s| s.json(settings))
        .collect()
}

/// The refusal of an unknown setting `name`.
fn unknown<S: Settings>(name: &str, raw: &Raw<'_>) -> SettingError {
    let names: Vec<&str> = S::settings().iter().map(|s| s.spec().name).collect();
    SettingError {
        setting: name.chars().take(SHOWN_CHARS).collect(),
        value: raw.shown(),
        expected: format!("a known setting: one of {}", names.join(", ")),
    }
}

/// Lists the settings of `O`'s nested struct `I` as settings of `O` (the
/// [`settings!`](crate::settings!) macro's `groups` section).
pub fn nest<O: Settings, I: Settings>(
    get: fn(&O) -> &I,
    get_mut: fn(&mut O) -> &mut I,
) -> impl Iterator<Item = &'static dyn Setting<O>> {
    I::settings().iter().map(move |inner| {
        let nested: &'static dyn Setting<O> =
            Box::leak(Box::new(Nested::new(*inner, get, get_mut)));
        nested
    })
}

/// Builds a struct's setting list once (the [`settings!`](crate::settings!)
/// macro's [`Settings::settings`]).
pub fn once<S: 'static>(
    cell: &'static OnceLock<Vec<&'static dyn Setting<S>>>,
    build: impl FnOnce() -> Vec<&'static dyn Setting<S>>,
) -> &'static [&'static dyn Setting<S>] {
    cell.get_or_init(build)
}

/// A setting as `GET /api/settings` describes it.
pub fn describe<S>(setting: &dyn Setting<S>) -> Json {
    let spec = setting.spec();
    let mut entry = serde_json::json!({
        "name": spec.name,
        "flag": format!("--{}", spec.flag()),
        "group": spec.group.name(),
        "kind": setting.kind(),
        "doc": spec.doc_line(),
        "default": setting.default_json(),
        "expected": setting.expected(),
        "unit": spec.check.unit(),
        "ui": spec.ui.name(),
        "affects": spec.affects,
    });
    match spec.check {
        Check::Number { min, max, .. } => {
            entry["min"] = serde_json::json!(min);
            entry["max"] = serde_json::json!(max);
        }
        Check::Whole { min, max, .. } => {
            entry["min"] = serde_json::json!(min);
            entry["max"] = serde_json::json!(max);
        }
        Check::OneOf { values, .. } => entry["values"] = serde_json::json!(values),
        Check::Type => {}
    }
    let choices = setting.choices();
    if !choices.is_empty() {
        entry["choices"] = choices
            .iter()
            .map(|(name, doc)| serde_json::json!({"name": name, "doc": doc}))
            .collect();
    }
    entry
}

/// Every setting of `S` described, with the groups in order.
pub fn describe_all<S: Settings>() -> Json {
    let groups: Vec<Json> = Group::ALL
        .iter()
        .map(|g| serde_json::json!({"name": g.name(), "title": g.title()}))
        .collect();
    let settings: Vec<Json> = by_group::<S>().map(|s| describe(s)).collect();
    serde_json::json!({"groups": groups, "settings": settings})
}

/// The settings of `S`, group by group (declaration order within a group).
pub fn by_group<S: Settings>() -> impl Iterator<Item = &'static dyn Setting<S>> {
    let mut all = S::settings().to_vec();
    all.sort_by_key(|s| s.spec().group);
    all.into_iter()
}

/// The settings of `S` as a Markdown table per group, for the README.
pub fn markdown<S: Settings>() -> String {
    let mut out = String::new();
    for group in Group::ALL {
        let rows: Vec<String> = by_group::<S>()
            .filter(|s| s.spec().group == group)
            .map(|s| {
                let spec = s.spec();
                let default = match s.default_text() {
                    t if t.is_empty() => "—".to_owned(),
                    t => format!("`{t}`"),
                };
                format!(
                    "| `{}` | `--{}` | {} | {} | {default} |",
                    spec.name,
                    spec.flag(),
                    spec.doc_line().replace('|', "\\|"),
                    s.expected().replace('|', "\\|"),
                )
            })
            .collect();
        if rows.is_empty() {
            continue;
        }
        out.push_str(&format!(
            "\n**{}**\n\n| setting | flag | meaning | takes | default |\n|---|---|---|---|---|\n",
            group.title()
        ));
        for row in rows {
            out.push_str(&row);
            out.push('\n');
        }
    }
    out
}

/// Declares a struct of settings: its fields with their defaults and
/// [`Spec`]s, then (optionally) settings structs nested in it and plain fields
/// that are not settings. Generates the struct, its `Default` and its
/// [`Settings`] implementation.
///
/// ```ignore
/// shaders::settings! {
///     /// What a struct holds.
///     #[derive(Debug, Clone, PartialEq)]
///     pub struct Example in Camera {
///         /// One line on what the setting does (its doc everywhere).
///         pub zoom: f32 = 1.0, "zoom" | "zoom-factor", number(0.1, 10.0, "a factor", "×"),
///             group Camera, affects "stage_name", ui Advanced;
///     }
///     groups { pub camera: Camera }
///     plain { pub cached: bool = false }
/// }
/// ```
///
/// Each setting: the field, its type and default; its name (and a flag when
/// the command line's differs: `_` become `-` otherwise); its [`Check`]; and
/// optionally its group (the struct's otherwise), the first cached stage it
/// `affects` and its `ui` level.
#[macro_export]
macro_rules! settings {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident in $sgroup:ident {
            $(
                $(#[doc = $doc:literal])*
                $fvis:vis $field:ident : $ty:ty = $default:expr ,
                $key:literal $(| $flag:literal)? , $check:ident ( $($cargs:tt)* )
                $(, group $group:ident)?
                $(, affects $stage:literal)?
                $(, ui $ui:ident)?
                ;
            )*
        }
        $(groups {
            $(
                $(#[doc = $gdoc:literal])*
                $gvis:vis $gfield:ident : $gty:ty
            ),* $(,)?
        })?
        $(plain {
            $(
                $(#[doc = $pdoc:literal])*
                $pvis:vis $pfield:ident : $pty:ty = $pdefault:expr
            ),* $(,)?
        })?
    ) => {
        $(#[$meta])*
        $vis struct $name {
            $(
                $(#[doc = $doc])*
                $fvis $field: $ty,
            )*
            $($(
                $(#[doc = $gdoc])*
                $gvis $gfield: $gty,
            )*)?
            $($(
                $(#[doc = $pdoc])*
                $pvis $pfield: $pty,
            )*)?
        }

        impl Default for $name {
            fn default() -> $name {
                $name {
                    $($field: $default,)*
                    $($($gfield: Default::default(),)*)?
                    $($($pfield: $pdefault,)*)?
                }
            }
        }

        impl $crate::settings::Settings for $name {
            fn settings() -> &'static [&'static dyn $crate::settings::Setting<$name>] {
                static ALL: ::std::sync::OnceLock<
                    Vec<&'static dyn $crate::settings::Setting<$name>>,
                > = ::std::sync::OnceLock::new();
                $crate::settings::once(&ALL, || {
                    let own: Vec<&'static dyn $crate::settings::Setting<$name>> = vec![$(
                        ::std::boxed::Box::leak(::std::boxed::Box::new(
                            $crate::settings::Field::<$name, $ty> {
                                spec: $crate::settings::Spec {
                                    name: $key,
                                    flag_given: $crate::settings_or!(None $(, Some($flag))?),
                                    group: $crate::settings_or!(
                                        $crate::settings::Group::$sgroup
                                        $(, $crate::settings::Group::$group)?
                                    ),
                                    doc: concat!($($doc, "\n",)*),
                                    check: $crate::settings::$check($($cargs)*),
                                    affects: $crate::settings_or!(None $(, Some($stage))?),
                                    ui: $crate::settings_or!(
                                        $crate::settings::Ui::Basic
                                        $(, $crate::settings::Ui::$ui)?
                                    ),
                                },
                                get: |s: &$name| &s.$field,
                                get_mut: |s: &mut $name| &mut s.$field,
                                default: || $default,
                            },
                        )),
                    )*];
                    own.into_iter()
                        $($(
                            .chain($crate::settings::nest::<$name, $gty>(
                                |s: &$name| &s.$gfield,
                                |s: &mut $name| &mut s.$gfield,
                            ))
                        )*)?
                        .collect()
                })
            }
        }
    };
}

/// The second value if given, else the first (for [`settings!`](crate::settings!)).
#[doc(hidden)]
#[macro_export]
macro_rules! settings_or {
    ($default:expr) => {
        $default
    };
    ($default:expr, $given:expr) => {
        $given
    };
}
