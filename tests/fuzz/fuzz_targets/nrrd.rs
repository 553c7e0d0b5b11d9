//! NRRD: the first byte picks attached (`.nrrd`) or a detached header (`.nhdr`)
//! with its data file; the rest is the file.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    if pick & 1 == 0 {
        voxserve_fuzz::read_file("volume.nrrd", rest);
        return;
    }
    // Header and data, separated by a line of its own.
    let parts = voxserve_fuzz::split(rest, b"\n#DATA#\n", 2);
    let dir = tempfile::tempdir().expect("temp");
    std::fs::write(
        dir.path().join("volume.raw"),
        parts.get(1).copied().unwrap_or(&[]),
    )
    .expect("data");
    std::fs::write(dir.path().join("volume.nhdr"), parts[0]).expect("header");
    voxserve_fuzz::read_volume(&dir.path().join("volume.nhdr"));
});
