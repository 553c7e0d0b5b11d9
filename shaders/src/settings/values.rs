//! [`SettingValue`]: how each type a setting's field can have is read from
//! text (queries, the command line) and JSON (view sessions), checked and
//! shown; [`Choice`] enums and [`TextSetting`] text forms.

use super::{Check, Expected, Json, MAX_NAME_CHARS, Raw, or_list};

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
    fn read(raw: &Raw<'_>, check: &Check) -> Result<Self, Expected>;

    /// Checks a value held (set without [`SettingValue::read`]); on failure,
    /// what was expected.
    fn check(&self, check: &Check) -> Result<(), Expected>;

    /// The value as JSON (`GET /api/settings` defaults, view-session state).
    fn to_json(&self) -> Json;

    /// The value's text form, as a query or the command line gives it.
    fn to_text(&self) -> String;
}

/// What `check` expects of a number, else what `T` expects.
pub(super) fn expected_of<T: SettingValue>(check: &Check) -> Expected {
    Expected(check.expected().unwrap_or_else(T::expected))
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

    fn read(raw: &Raw<'_>, check: &Check) -> Result<f32, Expected> {
        match raw.number() {
            Some(v) if check.admits(v) && (v as f32).is_finite() => Ok(v as f32),
            _ => Err(expected_of::<f32>(check)),
        }
    }

    fn check(&self, check: &Check) -> Result<(), Expected> {
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

    fn read(raw: &Raw<'_>, check: &Check) -> Result<u32, Expected> {
        // Read as a number, so 12 and 12.0 are the same (JSON has one kind of number).
        match raw.number() {
            Some(v)
                if check.admits(v)
                    && v.fract() == 0.0
                    && (0.0..=f64::from(u32::MAX)).contains(&v) =>
            {
                Ok(v as u32)
            }
            _ => Err(expected_of::<u32>(check)),
        }
    }

    fn check(&self, check: &Check) -> Result<(), Expected> {
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

    fn read(raw: &Raw<'_>, _: &Check) -> Result<bool, Expected> {
        match raw {
            Raw::Text("true") | Raw::Json(Json::Bool(true)) => Ok(true),
            Raw::Text("false") | Raw::Json(Json::Bool(false)) => Ok(false),
            _ => Err(Expected(bool::expected())),
        }
    }

    fn check(&self, _: &Check) -> Result<(), Expected> {
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

    fn read(raw: &Raw<'_>, _: &Check) -> Result<[f32; 3], Expected> {
        raw.text()
            .and_then(blocks::transfer_function::parse_rgb_hex)
            .ok_or_else(|| Expected(Self::expected()))
    }

    fn check(&self, _: &Check) -> Result<(), Expected> {
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
            ) -> Result<$t, $crate::settings::Expected> {
                $crate::settings::read_choice(raw)
            }

            fn check(&self, _: &$crate::settings::Check) -> Result<(), $crate::settings::Expected> {
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
pub fn read_choice<C: Choice>(raw: &Raw<'_>) -> Result<C, Expected> {
    raw.text()
        .and_then(|t| C::named(t.trim()))
        .ok_or_else(|| Expected(C::expected()))
}

/// A value with a text form of its own (a clip box, a light, a transfer
/// function): parsed and printed by the type, given as text or a JSON string.
pub trait TextSetting: Clone + PartialEq + Send + Sync + 'static {
    /// The text form, for messages: "six fractions x0,y0,z0,x1,y1,z1 …".
    fn expected() -> String;

    /// Parses the text form; on failure, what was expected and what was wrong.
    fn parse_text(text: &str) -> Result<Self, Expected>;

    /// Checks a value held; on failure, what was expected.
    fn check_value(&self) -> Result<(), Expected>;

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
            ) -> Result<$t, $crate::settings::Expected> {
                $crate::settings::read_text(raw)
            }

            fn check(&self, _: &$crate::settings::Check) -> Result<(), $crate::settings::Expected> {
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
pub fn read_text<T: TextSetting>(raw: &Raw<'_>) -> Result<T, Expected> {
    match raw.text() {
        Some(text) => T::parse_text(text),
        None => Err(Expected(format!("text: {}", T::expected()))),
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

    fn read(raw: &Raw<'_>, check: &Check) -> Result<Option<T>, Expected> {
        T::read(raw, check).map(Some)
    }

    fn check(&self, check: &Check) -> Result<(), Expected> {
        self.as_ref().map_or(Ok(()), |v| v.check(check))
    }

    fn to_json(&self) -> Json {
        self.as_ref().map_or(Json::Null, T::to_json)
    }

    fn to_text(&self) -> String {
        self.as_ref().map_or_else(String::new, T::to_text)
    }
}

/// A name (a dataset's id): any text of at most [`MAX_NAME_CHARS`]
/// characters; whoever uses it says which names there are.
impl TextSetting for String {
    fn expected() -> String {
        format!("a name of at most {MAX_NAME_CHARS} characters")
    }

    fn parse_text(text: &str) -> Result<String, Expected> {
        let value = text.to_owned();
        value.check_value().map(|()| value)
    }

    fn check_value(&self) -> Result<(), Expected> {
        if self.chars().count() <= MAX_NAME_CHARS {
            Ok(())
        } else {
            Err(Expected(<String as TextSetting>::expected()))
        }
    }

    fn text(&self) -> String {
        self.clone()
    }
}

text_setting!(String);
