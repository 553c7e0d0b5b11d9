//! `/api/render` query strings: every view setting (the transfer function and
//! the lights among them) parsed and checked as the server does.
#![no_main]

libfuzzer_sys::fuzz_target!(|text: &str| {
    let pairs: Vec<(String, String)> = text
        .split('&')
        .take(64)
        .map(|pair| match pair.split_once('=') {
            Some((k, v)) => (k.to_owned(), v.to_owned()),
            None => (pair.to_owned(), String::new()),
        })
        .collect();
    let datasets = voxserve_fuzz::datasets();
    if let Ok(view) = server::View::from_query(&pairs, datasets) {
        let _ = view.frame.transfer_function([0.0, 1000.0], blocks::Preset::CtBone);
    }
});
