//! A store that loses a shard while it is served: the HTTP render and a view
//! session answer an error naming the file, never an image with that part of
//! the volume drawn as air.

use futures_util::{SinkExt, StreamExt};
use tokio_tungstenite::connect_async;
use tokio_tungstenite::tungstenite::Message;
use voxserve_tests::gpu_or_skip;
use voxserve_tests::phantom::phantom_64_on_disk;
use voxserve_tests::server::TestServer;

/// How long any single wait may take before the test fails.
const PATIENCE: std::time::Duration = std::time::Duration::from_secs(60);

#[tokio::test]
async fn a_missing_shard_is_an_error_naming_it_over_http_and_websocket() {
    let test = "a_missing_shard_is_an_error_naming_it_over_http_and_websocket";
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp");
    // Opened as at start: only the two coarsest levels are in memory.
    let dataset = phantom_64_on_disk(dir.path());
    let shard = dir.path().join("cold.zarr/0/c/0/0/0");
    std::fs::remove_file(&shard).expect("delete level 0's shard");
    let server = TestServer::with_datasets(gpu, vec![dataset], 1, Default::default()).await;

    let response = reqwest::get(server.url("/api/render?w=48&h=48"))
        .await
        .expect("request");
    assert_eq!(response.status(), 500);
    let body: serde_json::Value =
        serde_json::from_str(&response.text().await.expect("body")).expect("JSON error");
    let message = body["error"].as_str().expect("an error message");
    assert!(
        message.starts_with("the volume data of this view cannot be read: ")
            && message.contains(&format!("{}: missing", shard.display())),
        "{message}"
    );

    let (mut socket, _) = connect_async(server.ws_url("/api/stream"))
        .await
        .expect("WebSocket connects");
    let view = serde_json::json!({"type": "view", "id": 1, "set": {"w": 40, "h": 40}});
    socket
        .send(Message::Text(view.to_string().into()))
        .await
        .expect("send");
    // Frames may come first, drawn from the coarse levels in memory while the
    // finer blocks load; then the error, and no converged frame before it.
    let error = loop {
        let message = tokio::time::timeout(PATIENCE, socket.next())
            .await
            .expect("a reply in time")
            .expect("the socket stays open")
            .expect("a message");
        match message {
            Message::Text(text) => {
                let json: serde_json::Value = serde_json::from_str(&text).expect("JSON");
                match json["type"].as_str() {
                    Some("error") => break json,
                    Some("hello" | "status" | "frame") => {}
                    other => panic!("unexpected {other:?}: {json}"),
                }
                assert_ne!(json["converged"], true, "{json}");
            }
            Message::Binary(_) => {}
            other => panic!("unexpected {other:?}"),
        }
    };
    let message = error["message"].as_str().expect("a message");
    assert!(message.contains("0/c/0/0/0: missing"), "{message}");
}
