//! Raw file names (`engine_256x256x128_uint8.raw`) and the `--raw-…` flags' text.
#![no_main]

libfuzzer_sys::fuzz_target!(|text: &str| {
    let _ = blocks::ingest::raw::parse_name(text);
    let _ = blocks::ingest::raw::parse_direction(text);
    let _ = blocks::ingest::raw::parse_flip(text);
    // A raw file named by the input, holding a few bytes.
    if !text.is_empty() && text.len() < 200 && !text.contains(['/', '\0']) {
        voxserve_fuzz::read_file(&format!("{text}.raw"), &[7; 64]);
    }
});
