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
//!
//! # Layout
//! - [`check`]: [`Check`], which values a setting takes beyond its type
//!   (ranges, a few whole numbers), and what messages say it takes.
//! - [`values`]: [`SettingValue`], how each field type is read from text and
//!   JSON, checked and shown; [`Choice`] enums and [`TextSetting`] text forms.
//! - [`field`]: [`Field`] and [`Nested`], the [`Setting`]s the macro makes.
//! - [`describe`](mod@describe): `GET /api/settings` and the README's tables.
//! - [`declare`]: the [`settings!`](crate::settings!) macro.

mod check;
pub mod declare;
pub mod describe;
mod field;
mod values;

use std::fmt;

pub use check::{Check, by_type, degrees, number, one_of, or_list, whole};
pub use describe::{by_group, describe, describe_all, markdown};
pub use field::{Field, Nested, nest, once};
pub use values::{Choice, SettingValue, TextSetting, read_choice, read_text};

/// JSON, as settings are read from view-session patches and described.
pub use serde_json::Value as Json;

/// The longest name a text setting of names takes.
pub const MAX_NAME_CHARS: usize = 256;
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
    /// Slice views (`shaders::slice`): their own settings, per view.
    Slice,
}

impl Group {
    /// Every group, in the order the docs list them.
    pub const ALL: [Group; 10] = [
        Group::Data,
        Group::Camera,
        Group::Image,
        Group::Classification,
        Group::Shading,
        Group::Detail,
        Group::Clip,
        Group::GlobalLight,
        Group::Extinction,
        Group::Slice,
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
            Group::Slice => "slice",
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
            Group::Slice => "Slice views",
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

/// What a setting takes, and what was wrong with a value when that helps: the
/// words after "expected" in a refusal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Expected(pub String);

impl fmt::Display for Expected {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl From<String> for Expected {
    fn from(text: String) -> Expected {
        Expected(text)
    }
}

impl From<&str> for Expected {
    fn from(text: &str) -> Expected {
        Expected(text.to_owned())
    }
}

impl Expected {
    /// What a value of this form takes, then what was wrong in parentheses.
    pub fn because(self, why: impl fmt::Display) -> Expected {
        Expected(format!("{} ({why})", self.0))
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
    pub fn new(setting: &str, value: &Raw<'_>, expected: impl fmt::Display) -> SettingError {
        SettingError {
            setting: setting.to_owned(),
            value: value.shown(),
            expected: expected.to_string(),
        }
    }

    /// A refusal of a current value (one the settings struct holds).
    pub fn of_value(setting: &str, value: impl fmt::Display, expected: impl fmt::Display) -> Self {
        SettingError {
            setting: setting.to_owned(),
            value: shortened(value.to_string()),
            expected: expected.to_string(),
        }
    }
}

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

    /// Whether the command line takes it as an argument rather than a flag
    /// (declared with an upper-case "flag", e.g. `DATASET`).
    pub fn is_argument(&self) -> bool {
        self.flag_given
            .is_some_and(|f| f.chars().all(|c| c.is_ascii_uppercase() || c == '_'))
    }

    /// How the command line names it: `--flag`, or the argument's name.
    pub fn command_line(&self) -> String {
        if self.is_argument() {
            self.flag().into_owned()
        } else {
            format!("--{}", self.flag())
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

    /// Every setting's spec and current value as text (as a query or a flag
    /// takes it), to write the settings back out (`name=text`, `--flag=text`).
    fn to_texts(&self) -> Vec<(&'static Spec, String)> {
        Self::settings()
            .iter()
            .map(|s| (s.spec(), s.text(self)))
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
