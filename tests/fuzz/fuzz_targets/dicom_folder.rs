//! A folder of DICOM files (up to 8, split at `#FILE#`): grouping into series,
//! sorting, geometry, then the first slabs.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let dir = tempfile::tempdir().expect("temp");
    for (i, part) in voxserve_fuzz::split(data, b"#FILE#", 8).iter().enumerate() {
        std::fs::write(dir.path().join(format!("{i}.dcm")), part).expect("write");
    }
    voxserve_fuzz::read_volume(dir.path());
});
