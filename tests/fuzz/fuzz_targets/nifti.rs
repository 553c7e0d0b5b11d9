//! NIfTI-1: the first byte picks `.nii` or `.nii.gz` (the rest gzip-compressed
//! as given).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let name = if pick & 1 == 0 {
        "volume.nii"
    } else {
        "volume.nii.gz"
    };
    voxserve_fuzz::read_file(name, rest);
});
