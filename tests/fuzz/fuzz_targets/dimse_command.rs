//! DIMSE command sets as a DICOM peer sends them over an association.
#![no_main]

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    let _ = server::dimse::parse_command(bytes);
});
