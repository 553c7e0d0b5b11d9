//! The error type of the `blocks` crate.

use std::path::PathBuf;

/// Everything that can go wrong while reading, building or classifying volume data.
/// Messages name the file, the field and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file or folder could not be opened or read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// A header field is missing, malformed or unsupported.
    #[error("{}: {field}: {message}", path.display())]
    Field {
        /// The file.
        path: PathBuf,
        /// The header field (or DICOM attribute) at fault.
        field: String,
        /// What is wrong and what was expected.
        message: String,
    },
    /// The voxel data ends before the header's dimensions are filled.
    #[error(
        "{}: truncated voxel data: the header promises {expected} bytes of voxels, the data ends \
         after {got}; expected a complete file (check dims, type and header offset)",
        path.display()
    )]
    Truncated {
        /// The data file.
        path: PathBuf,
        /// Bytes of voxel data the header promises.
        expected: u64,
        /// Bytes actually present.
        got: u64,
    },
    /// A compressed stream is corrupt.
    #[error("{}: corrupt {codec} data: {detail}", path.display())]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// The compression or codec (`gzip`, `zlib`, a DICOM transfer syntax).
        codec: String,
        /// The decoder's reason.
        detail: String,
    },
    /// A file a store must hold is missing: its voxels are unknown, never empty.
    #[error("{}: missing: {detail}", path.display())]
    Missing {
        /// The (first) missing file.
        path: PathBuf,
        /// Which files, and what it means for the view.
        detail: String,
    },
    /// A store on object storage did not answer (refused connections,
    /// timeouts after retries, server errors): its data is unknown for now,
    /// and reads are tried again ([`crate::BlockCache`] after
    /// [`crate::cache::RETRY_AFTER`]).
    #[error(
        "{}: unavailable: {detail}; what it holds is not drawn until the store answers \
         again (it is read again at a later frame)",
        path.display()
    )]
    Unavailable {
        /// The object.
        path: PathBuf,
        /// The store's or the network's reason.
        detail: String,
    },
    /// A decoder voxserve does not own panicked on this file (caught at the
    /// boundary of [`crate::ingest::boundary::guard`]).
    #[error(
        "{}: the {decoder} decoder failed on this file ({message}): expected a file it can \
         decode; the file is damaged, or uses a variant the decoder mishandles",
        path.display()
    )]
    DecoderPanic {
        /// The file.
        path: PathBuf,
        /// The decoder, e.g. `RLE Lossless pixel data`.
        decoder: String,
        /// The panic's message.
        message: String,
    },
    /// A folder holds several DICOM series and none was chosen.
    #[error(
        "{}: the folder holds {count} DICOM series; choose one with --series UID:\n{listing}",
        path.display()
    )]
    SeveralSeries {
        /// The folder.
        path: PathBuf,
        /// How many series.
        count: usize,
        /// One line per series: UID, description, slices, size.
        listing: String,
    },
    /// The input's format cannot be told from its name or first bytes.
    #[error(
        "{}: unknown volume format: expected a raw file (with --raw-dims and --raw-type, or a \
         name like engine_256x256x128_uint8.raw), NRRD (.nrrd, .nhdr), NIfTI-1 (.nii, .nii.gz), \
         MetaImage (.mha, .mhd), a DICOM file, or a folder of DICOM files",
        path.display()
    )]
    UnknownFormat {
        /// The input.
        path: PathBuf,
    },
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
    /// A chunk read in the background failed; the error it gave, shared by
    /// everyone who waits for that chunk.
    #[error(transparent)]
    Shared(#[from] std::sync::Arc<Error>),
}
