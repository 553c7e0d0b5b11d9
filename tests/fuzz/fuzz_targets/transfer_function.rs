//! Transfer functions as `--tf` and the `tf` setting take them.
#![no_main]

libfuzzer_sys::fuzz_target!(|text: &str| {
    if let Ok(tf) = blocks::TransferFunction::parse(text) {
        let _ = tf.table([0.0, 1000.0], 256);
    }
});
