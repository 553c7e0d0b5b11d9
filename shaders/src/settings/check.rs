//! [`Check`]: which values a setting takes beyond what its type says, and
//! the words messages use for them.

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
    pub fn admits(&self, value: f64) -> bool {
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
pub fn or_list(items: &[impl std::fmt::Display]) -> String {
    let text: Vec<String> = items.iter().map(ToString::to_string).collect();
    match text.split_last() {
        None => String::new(),
        Some((last, [])) => last.clone(),
        Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
    }
}
