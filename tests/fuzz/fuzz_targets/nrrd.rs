//! NRRD: the first byte picks attached (`.nrrd`) or a detached header (`.nhdr`)
//! with its data file; the rest is the file.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    if pick & 1 == 0 {
        voxserve_fuzz::read_file("volume.nrrd", rest);
    } else {
        voxserve_fuzz::read_detached("volume.nhdr", rest);
    }
});
