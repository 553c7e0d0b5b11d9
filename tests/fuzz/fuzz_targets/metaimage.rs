//! MetaImage: the first byte picks `.mha` (data inside) or `.mhd` with a
//! detached data file.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    if pick & 1 == 0 {
        voxserve_fuzz::read_file("volume.mha", rest);
    } else {
        voxserve_fuzz::read_detached("volume.mhd", rest);
    }
});
