//! The error type of the `blocks` crate.

/// Everything that can go wrong while building or classifying volume data.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A value given for a named setting lies outside what that setting accepts.
    #[error("{what} = {value}: expected {expected}")]
    OutOfRange {
        /// The setting, e.g. `phantom size`.
        what: &'static str,
        /// The value that was given, as text.
        value: String,
        /// What would have been accepted.
        expected: String,
    },
    /// A transfer-function preset name that is not one of [`crate::Preset::ALL`].
    #[error("unknown transfer-function preset '{name}': expected one of {expected}")]
    UnknownPreset {
        /// The name that was given.
        name: String,
        /// The known names, comma separated.
        expected: String,
    },
    /// A volume whose parts disagree (voxel count against dimensions, bad spacing).
    #[error("invalid volume '{name}': {reason}")]
    InvalidVolume {
        /// The volume's name.
        name: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A transfer function that cannot be built into a table.
    #[error("invalid transfer function: {reason}")]
    InvalidTransferFunction {
        /// What is wrong with it.
        reason: String,
    },
}
