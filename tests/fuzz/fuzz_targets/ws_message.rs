//! View-session messages over WebSocket, and the view patches they carry.
#![no_main]

libfuzzer_sys::fuzz_target!(|text: &str| {
    let Ok(message) = server::protocol::parse_client_message(text) else {
        return;
    };
    if let server::protocol::ClientMessage::View { set, .. } = message {
        let datasets = voxserve_fuzz::datasets();
        let mut view = server::View::from_query(&[], datasets).expect("the default view");
        let _ = view.patch(&set, datasets);
    }
});
