//! One DICOM file.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    voxserve_fuzz::read_file("slice.dcm", data);
});
