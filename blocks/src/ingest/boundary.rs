//! The boundary around decoders voxserve does not own: a panic inside one
//! (dicom-rs' RLE decoder indexing past a short segment, say) becomes an
//! [`Error::DecoderPanic`] naming the file and the decoder, and takes nothing
//! else down.
//!
//! The process-wide panic hook ([`install_panic_hook`], installed by the
//! binary) knows whether a panic happened inside a boundary: those are logged
//! at debug level only, since the boundary's error reports them; every other
//! panic still goes to the previous hook, as a crash should.

use std::any::Any;
use std::cell::Cell;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use crate::Error;

thread_local! {
    /// How many boundaries the current thread is inside.
    static DEPTH: Cell<u32> = const { Cell::new(0) };
}

/// Runs `decode` (reading `path` with `decoder`, e.g. `RLE Lossless pixel
/// data`) and turns a panic inside it into an [`Error::DecoderPanic`].
pub fn guard<T>(
    path: &Path,
    decoder: &str,
    decode: impl FnOnce() -> Result<T, Error>,
) -> Result<T, Error> {
    DEPTH.with(|d| d.set(d.get() + 1));
    // The closure's state is dropped with the panic; nothing it touched is
    // used afterwards, so unwind safety holds.
    let result = catch_unwind(AssertUnwindSafe(decode));
    DEPTH.with(|d| d.set(d.get().saturating_sub(1)));
    result.unwrap_or_else(|payload| {
        Err(Error::DecoderPanic {
            path: path.to_owned(),
            decoder: decoder.to_owned(),
            message: panic_message(payload.as_ref()),
        })
    })
}

/// Whether the current thread is inside a [`guard`].
pub fn inside_guard() -> bool {
    DEPTH.with(Cell::get) > 0
}

/// The text a panic was raised with.
fn panic_message(payload: &(dyn Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_owned()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "(no message)".to_owned()
    }
}

/// Installs a panic hook that logs panics inside a [`guard`] at debug level
/// (the guard's error says what failed, once) and hands every other panic to
/// the hook installed before.
pub fn install_panic_hook() {
    let previous = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if inside_guard() {
            tracing::debug!("a decoder panicked (reported as an error): {info}");
        } else {
            previous(info);
        }
    }));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_inside_the_guard_becomes_an_error_naming_file_and_decoder() {
        let err = guard(
            Path::new("x.dcm"),
            "RLE Lossless pixel data",
            || -> Result<(), Error> {
                let v: Vec<u8> = Vec::new();
                let i = v.len() + 1;
                Err(Error::OutOfRange {
                    what: "never",
                    value: v[i].to_string(),
                    expected: String::new(),
                })
            },
        )
        .expect_err("panics");
        let msg = err.to_string();
        assert!(
            msg.starts_with("x.dcm: the RLE Lossless pixel data decoder failed")
                && msg.contains("index out of bounds"),
            "{msg}"
        );
        assert!(!inside_guard());
        assert_eq!(guard(Path::new("x"), "d", || Ok(3)).expect("no panic"), 3);
    }
}
