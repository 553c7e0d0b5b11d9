//! View sessions over WebSocket against a real server on port 0: frames of the
//! requested size that follow the camera, a lossless frame after idling,
//! latest state wins under a burst, the acknowledgement window, bad messages
//! refused without harm to the session or to others, the session cap,
//! shutdown closing every session, and a store that lost a shard answered with
//! an error naming it (over HTTP too), never drawn as air.
//!
//! Nothing here waits for time to pass: what did *not* happen is read from a
//! `status` reply, which comes in order after everything sent before it. The
//! only clock is [`PATIENCE`], a hang guard that no passing run reaches.
#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use server::encode::Lossless;
use server::protocol::{Encoding, FrameHeader, HEADER_LEN};
use server::stream::StreamSettings;
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream, connect_async};
use voxserve_tests::gpu_or_skip;
use voxserve_tests::server::TestServer;

type Socket = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// How long any single wait may take before the test fails.
const PATIENCE: Duration = Duration::from_secs(60);

/// What the server sent.
#[derive(Debug)]
enum Received {
    Json(serde_json::Value),
    Frame(FrameHeader, image::RgbaImage),
}

async fn connect(server: &TestServer) -> Socket {
    connect_with_hello(server).await.0
}

/// A session and its hello message.
async fn connect_with_hello(server: &TestServer) -> (Socket, serde_json::Value) {
    let (mut socket, _) = connect_async(server.ws_url("/api/stream"))
        .await
        .expect("WebSocket connects");
    match next(&mut socket).await {
        Received::Json(hello) => {
            assert_eq!(hello["type"], "hello", "{hello}");
            assert_eq!(hello["protocol"], server::protocol::PROTOCOL, "{hello}");
            (socket, hello)
        }
        Received::Frame(h, _) => panic!("expected hello first, got frame {h:?}"),
    }
}

/// The next message, decoded (frames checked: header, encoding, size).
async fn next(socket: &mut Socket) -> Received {
    loop {
        let message = tokio::time::timeout(PATIENCE, socket.next())
            .await
            .expect("a message within the patience")
            .expect("the socket stays open")
            .expect("a readable message");
        match message {
            Message::Text(text) => {
                return Received::Json(serde_json::from_str(text.as_str()).expect("JSON text"));
            }
            Message::Binary(bytes) => {
                let header = FrameHeader::parse(&bytes).expect("a frame header");
                let format = match header.encoding {
                    Encoding::Jpeg => image::ImageFormat::Jpeg,
                    Encoding::Png => image::ImageFormat::Png,
                    Encoding::Webp => image::ImageFormat::WebP,
                };
                let img = image::load_from_memory_with_format(&bytes[HEADER_LEN..], format)
                    .expect("a decodable image")
                    .to_rgba8();
                assert_eq!(
                    img.dimensions(),
                    (u32::from(header.width), u32::from(header.height)),
                    "the header's size is the image's"
                );
                return Received::Frame(header, img);
            }
            Message::Ping(_) | Message::Pong(_) => {}
            other => panic!("unexpected message {other:?}"),
        }
    }
}

async fn send(socket: &mut Socket, value: serde_json::Value) {
    socket
        .send(Message::Text(value.to_string().into()))
        .await
        .expect("send");
}

async fn ack(socket: &mut Socket, frame: u32) {
    send(socket, serde_json::json!({"type": "ack", "frame": frame})).await;
}

/// Reads (and acknowledges) frames until a lossless, converged one reflecting message
/// `id`; returns every frame seen.
async fn until_converged(socket: &mut Socket, id: u32) -> Vec<(FrameHeader, image::RgbaImage)> {
    let mut frames = Vec::new();
    loop {
        match next(socket).await {
            Received::Json(m) => panic!("unexpected message while waiting for frames: {m}"),
            Received::Frame(header, img) => {
                ack(socket, header.frame_id).await;
                // A lossless frame may show blocks still being read coarser
                // (`pending_blocks`); the converged one shows them all.
                let done = header.lossless && header.converged && header.message_id == id;
                frames.push((header, img));
                if done {
                    return frames;
                }
            }
        }
    }
}

/// Asks for the session's status (as message `id`) and returns the reply,
/// which must be the next message: anything sent before it comes first.
async fn status(socket: &mut Socket, id: u32) -> serde_json::Value {
    send(socket, serde_json::json!({"type": "status", "id": id})).await;
    match next(socket).await {
        Received::Json(m) if m["type"] == "status" && m["id"] == id => m,
        Received::Json(m) => panic!("expected status {id}, got {m}"),
        Received::Frame(h, _) => panic!("expected status {id}, got frame {h:?}"),
    }
}

/// Asserts that the session has nothing more to send until the view
/// changes: no render running, none due, and `sent` the last frame the
/// client received.
async fn assert_quiet(socket: &mut Socket, id: u32, last_frame: u32) -> serde_json::Value {
    let status = status(socket, id).await;
    assert_eq!(status["rendering"], false, "{status}");
    assert_eq!(status["waiting"], "message", "{status}");
    assert_eq!(status["sent"], last_frame, "{status}");
    status
}

/// Reads until the server's close (frames before it are skipped) and then
/// until the socket ends (which sends the client's close reply); the
/// close's code.
async fn until_close(socket: &mut Socket) -> u16 {
    let mut code = None;
    loop {
        let message = tokio::time::timeout(PATIENCE, socket.next())
            .await
            .expect("a message within the patience");
        match message {
            Some(Ok(Message::Close(frame))) => {
                code = Some(frame.map_or(1005, |f| u16::from(f.code)));
            }
            Some(Ok(other)) => assert!(code.is_none(), "{other:?} after the close"),
            // The server drops the connection once it has the reply.
            None | Some(Err(_)) => return code.expect("a close before the socket ended"),
        }
    }
}

/// A server on the 32³ phantom and one session on it, or `None` when `test`
/// is skipped for want of a GPU.
async fn server_and_session(test: &str) -> Option<(TestServer, Socket)> {
    let gpu = gpu_or_skip(test)?;
    let server = TestServer::start(gpu, 32).await;
    let socket = connect(&server).await;
    Some((server, socket))
}

#[tokio::test]
async fn lossless_frames_can_be_webp_with_the_same_pixels_as_png() {
    let test = "lossless_frames_can_be_webp_with_the_same_pixels_as_png";
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let mut still = Vec::new();
    for lossless in [Lossless::Png, Lossless::Webp] {
        let server = TestServer::start_with(
            gpu,
            32,
            StreamSettings {
                lossless,
                ..StreamSettings::default()
            },
        )
        .await;
        let mut socket = connect(&server).await;
        send(
            &mut socket,
            serde_json::json!({"type": "view", "id": 1, "set": {"w": 48, "h": 40, "az": 20}}),
        )
        .await;
        let frames = until_converged(&mut socket, 1).await;
        let (header, image) = frames.last().expect("frames");
        let expected = match lossless {
            Lossless::Png => Encoding::Png,
            Lossless::Webp => Encoding::Webp,
        };
        assert_eq!(header.encoding, expected, "{header:?}");
        still.push(image.clone());
    }
    assert_eq!(still[0], still[1], "WebP lossless shows PNG's pixels");
}

#[tokio::test]
async fn frames_follow_the_camera_at_the_requested_size_and_a_lossless_frame_follows_idling() {
    let Some((server, mut socket)) = server_and_session(
        "frames_follow_the_camera_at_the_requested_size_and_a_lossless_frame_follows_idling",
    )
    .await
    else {
        return;
    };
    send(
        &mut socket,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 64, "h": 48, "az": 0}}),
    )
    .await;
    let first = until_converged(&mut socket, 1).await;
    // The first render comes while the view is fresh: half size, JPEG.
    let (h, _) = &first[0];
    assert_eq!(
        (h.encoding, h.width, h.height),
        (Encoding::Jpeg, 32, 24),
        "{h:?}"
    );
    assert!(!h.lossless);
    let (full, front) = first.last().expect("frames");
    assert_eq!(
        (full.encoding, full.width, full.height),
        (Encoding::Webp, 64, 48),
        "{full:?}"
    );
    assert!(
        full.converged,
        "gradient shading converges at once: {full:?}"
    );
    assert!(full.render_ms > 0.0 && full.reduction >= 1.0, "{full:?}");
    // The device pixel ratio scales the frame; the camera changes its content.
    send(
        &mut socket,
        serde_json::json!({"type": "view", "id": 2, "set": {"az": 90, "w": 40, "h": 30}, "dpr": 2}),
    )
    .await;
    let second = until_converged(&mut socket, 2).await;
    let (full, side) = second.last().expect("frames");
    assert_eq!((full.width, full.height), (80, 60), "{full:?}");
    let front_small = image::imageops::resize(front, 80, 60, image::imageops::FilterType::Triangle);
    let differing = front_small
        .pixels()
        .zip(side.pixels())
        .filter(|(a, b)| a.0.iter().zip(b.0).any(|(x, y)| x.abs_diff(y) > 24))
        .count();
    assert!(
        differing > 80 * 60 / 20,
        "the view from the side differs: {differing} pixels"
    );
    // Still and converged: nothing more is sent.
    let quiet = assert_quiet(&mut socket, 1, full.frame_id).await;
    assert_eq!(
        (&quiet["view_id"], &quiet["acked"], &quiet["converged"]),
        (
            &serde_json::json!(2),
            &serde_json::json!(full.frame_id),
            &serde_json::json!(true)
        ),
        "{quiet}"
    );
    // The metrics saw the session and its frames of both kinds.
    let metrics = metrics(&server).await;
    for expected in [
        "voxserve_sessions_open 1",
        "voxserve_sessions_total 1",
        "voxserve_frames_total{source=\"stream\",quality=\"interactive\"}",
        "voxserve_frames_total{source=\"stream\",quality=\"full\"}",
        "voxserve_encode_seconds_count{format=\"jpeg\"}",
    ] {
        assert!(
            metrics.contains(expected),
            "/metrics lacks {expected}:\n{metrics}"
        );
    }
}

#[tokio::test]
async fn a_burst_of_100_camera_messages_renders_a_handful_of_frames_ending_on_the_last() {
    let Some((_server, mut socket)) = server_and_session(
        "a_burst_of_100_camera_messages_renders_a_handful_of_frames_ending_on_the_last",
    )
    .await
    else {
        return;
    };
    let view = |id: u32| serde_json::json!({"type": "view", "id": id, "set": {"w": 96, "h": 96, "az": f64::from(id) * 3.6}});
    send(&mut socket, view(1)).await;
    let Received::Frame(first, _) = next(&mut socket).await else {
        panic!("expected a frame");
    };
    assert_eq!(first.message_id, 1, "{first:?}");
    // The other 99 arrive while the first frame waits for its acknowledgement.
    for id in 2..=100u32 {
        send(&mut socket, view(id)).await;
    }
    let held = status(&mut socket, 1).await;
    assert_eq!(held["view_id"], 100, "{held}");
    assert_eq!(held["sent"], first.frame_id, "{held}");
    assert_eq!(held["waiting"], "ack", "{held}");
    ack(&mut socket, first.frame_id).await;
    let frames = until_converged(&mut socket, 100).await;
    let ids: Vec<u32> = frames.iter().map(|(h, _)| h.message_id).collect();
    println!(
        "100 messages: {} frames after the first, reflecting messages {ids:?}",
        frames.len()
    );
    assert!(
        ids.iter().all(|&id| id == 100),
        "every frame after the acknowledgement shows the last view: {ids:?}"
    );
    // An interactive frame (unless the view was still by then), the full one,
    // and, if that showed blocks still being read coarser, the refined one.
    assert!(frames.len() <= 3, "a handful of frames: {ids:?}");
    let (last, _) = frames.last().expect("frames");
    assert!(last.lossless && last.converged, "{last:?}");
    assert_quiet(&mut socket, 2, last.frame_id).await;
}

#[tokio::test]
async fn without_acknowledgements_no_more_frames_come_and_the_next_shows_the_latest_view() {
    let Some((_server, mut socket)) = server_and_session(
        "without_acknowledgements_no_more_frames_come_and_the_next_shows_the_latest_view",
    )
    .await
    else {
        return;
    };
    send(
        &mut socket,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 48, "h": 48}}),
    )
    .await;
    let Received::Frame(first, _) = next(&mut socket).await else {
        panic!("expected a frame");
    };
    assert!(!first.lossless, "the first frame is interactive: {first:?}");
    // The lossless frame is due (now or once the view is still) but waits
    // for the acknowledgement; the session sleeps meanwhile (the session's
    // unit tests show it does not wake when the view turns still).
    let held = status(&mut socket, 1).await;
    assert_eq!(
        (
            &held["sent"],
            &held["acked"],
            &held["rendering"],
            &held["waiting"]
        ),
        (
            &serde_json::json!(first.frame_id),
            &serde_json::json!(0),
            &serde_json::json!(false),
            &serde_json::json!("ack")
        ),
        "{held}"
    );
    for id in 2..=5u32 {
        send(
            &mut socket,
            serde_json::json!({"type": "view", "id": id, "set": {"az": id * 20}}),
        )
        .await;
    }
    let held = status(&mut socket, 2).await;
    assert_eq!(held["view_id"], 5, "{held}");
    assert_eq!(
        held["sent"], first.frame_id,
        "no frame beyond the window: {held}"
    );
    assert_eq!(
        (&held["rendering"], &held["waiting"]),
        (&serde_json::json!(false), &serde_json::json!("ack")),
        "{held}"
    );
    ack(&mut socket, first.frame_id).await;
    let frames = until_converged(&mut socket, 5).await;
    assert_eq!(
        frames[0].0.message_id, 5,
        "the next frame shows the latest view"
    );
}

#[tokio::test]
async fn bad_messages_get_errors_and_neither_this_session_nor_another_is_harmed() {
    let Some(gpu) =
        gpu_or_skip("bad_messages_get_errors_and_neither_this_session_nor_another_is_harmed")
    else {
        return;
    };
    let server = TestServer::start(gpu, 32).await;
    let mut a = connect(&server).await;
    let mut b = connect(&server).await;
    send(
        &mut a,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 40, "h": 40}}),
    )
    .await;
    until_converged(&mut a, 1).await;
    let cases = [
        (
            "{\"type\": \"view\", \"id\": 2, \"set\": {\"az\": NaN}}".to_owned(),
            "not JSON",
        ),
        ("[]".to_owned(), "expected a JSON object"),
        (
            serde_json::json!({"type": "view", "id": 3, "camera": {}}).to_string(),
            "field 'camera': unknown",
        ),
        (
            serde_json::json!({"type": "view", "id": 4, "set": {"zoom": 2}}).to_string(),
            "unknown view setting 'zoom'",
        ),
        (
            serde_json::json!({"type": "view", "id": 5, "set": {"az": "NaN"}}).to_string(),
            "view setting az=\"NaN\"",
        ),
        (
            serde_json::json!({"type": "view", "id": 6, "set": {"w": 100000}}).to_string(),
            "view setting w=100000: expected a whole number of pixels from 1 to 4096",
        ),
        (
            serde_json::json!({"type": "view", "id": 7, "set": {"dataset": "lung"}}).to_string(),
            "view setting dataset=\"lung\"",
        ),
        (
            serde_json::json!({"type": "view", "id": 8, "dpr": 0}).to_string(),
            "field 'dpr'",
        ),
        (
            serde_json::json!({"type": "flush"}).to_string(),
            "message type 'flush'",
        ),
    ];
    for (text, expected) in cases {
        a.send(Message::Text(text.clone().into()))
            .await
            .expect("send");
        match next(&mut a).await {
            Received::Json(m) => {
                assert_eq!(m["type"], "error", "{text}: {m}");
                let message = m["message"].as_str().unwrap_or_default();
                assert!(message.contains(expected), "{text}: {message}");
            }
            Received::Frame(h, _) => panic!("{text}: expected an error, got frame {h:?}"),
        }
    }
    a.send(Message::Binary(vec![1, 2, 3].into()))
        .await
        .expect("send");
    assert!(matches!(next(&mut a).await, Received::Json(m) if m["type"] == "error"));
    // The session kept its view and still renders.
    send(
        &mut a,
        serde_json::json!({"type": "view", "id": 9, "set": {"az": 45}}),
    )
    .await;
    let frames = until_converged(&mut a, 9).await;
    assert_eq!(
        (
            frames.last().expect("frame").0.width,
            frames.last().expect("frame").0.height
        ),
        (40, 40)
    );
    // A transfer function of its own replaces the preset once that is removed (null).
    send(
        &mut a,
        serde_json::json!({"type": "view", "id": 10, "set": {"preset": "ct-angio"}}),
    )
    .await;
    until_converged(&mut a, 10).await;
    let tf = "-1000:000000:0,200:ffcc99:0.2,1500:ffffff:0.9";
    send(
        &mut a,
        serde_json::json!({"type": "view", "id": 11, "set": {"tf": tf}}),
    )
    .await;
    match next(&mut a).await {
        Received::Json(m) => assert!(
            m["message"]
                .as_str()
                .unwrap_or_default()
                .contains("a transfer function or a preset, not both"),
            "{m}"
        ),
        Received::Frame(h, _) => panic!("tf beside a preset should be refused, got {h:?}"),
    }
    send(
        &mut a,
        serde_json::json!({"type": "view", "id": 12, "set": {"tf": tf, "preset": null}}),
    )
    .await;
    until_converged(&mut a, 12).await;
    // The other session never noticed.
    send(
        &mut b,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 24, "h": 24}}),
    )
    .await;
    let frames = until_converged(&mut b, 1).await;
    assert!(frames.iter().all(|(h, _)| h.message_id == 1));
}

#[tokio::test]
async fn sessions_beyond_the_cap_are_refused_and_a_closed_session_frees_its_place() {
    let Some(gpu) =
        gpu_or_skip("sessions_beyond_the_cap_are_refused_and_a_closed_session_frees_its_place")
    else {
        return;
    };
    let settings = StreamSettings {
        max_sessions: 2,
        ..StreamSettings::default()
    };
    let server = TestServer::start_with(gpu, 32, settings).await;
    let mut a = connect(&server).await;
    let _b = connect(&server).await;
    match connect_async(server.ws_url("/api/stream")).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
            assert_eq!(response.status(), 503);
        }
        other => panic!(
            "a third session should be refused, got {:?}",
            other.map(|_| ())
        ),
    }
    // Closing a session frees its place before the close handshake
    // completes: once the client has the server's close, a new session opens.
    a.close(None).await.expect("close");
    until_close(&mut a).await;
    let open = metrics(&server).await;
    assert!(open.contains("voxserve_sessions_open 1\n"), "{open}");
    let _c = connect(&server).await;
    let open = metrics(&server).await;
    assert!(open.contains("voxserve_sessions_open 2\n"), "{open}");
}

async fn metrics(server: &TestServer) -> String {
    get_text(server, "/metrics").await
}

/// The body of `GET path`.
async fn get_text(server: &TestServer, path: &str) -> String {
    reqwest::get(server.url(path))
        .await
        .unwrap_or_else(|e| panic!("GET {path}: {e}"))
        .text()
        .await
        .expect("body")
}

#[tokio::test]
async fn shutdown_closes_every_session_with_going_away_and_run_returns() {
    let Some(gpu) = gpu_or_skip("shutdown_closes_every_session_with_going_away_and_run_returns")
    else {
        return;
    };
    let server = TestServer::start(gpu, 32).await;
    let mut idle = connect(&server).await;
    let mut busy = connect(&server).await;
    // One session has converged, the other has just asked for a frame.
    send(
        &mut idle,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 32, "h": 32}}),
    )
    .await;
    until_converged(&mut idle, 1).await;
    send(
        &mut busy,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 64, "h": 64, "shading": "global"}}),
    )
    .await;
    let stopped = tokio::spawn(server.shut_down());
    assert_eq!(until_close(&mut idle).await, 1001, "going away");
    assert_eq!(until_close(&mut busy).await, 1001, "going away");
    tokio::time::timeout(PATIENCE, stopped)
        .await
        .expect("run returns within the patience")
        .expect("the shutdown task")
        .expect("run returns Ok");
}

#[tokio::test]
async fn a_session_switches_datasets_and_one_resident_renderer_serves_both_in_turn() {
    let test = "a_session_switches_datasets_and_one_resident_renderer_serves_both_in_turn";
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let phantom = server::Dataset::phantom(32, 64 << 20).expect("phantom");
    let small = {
        let volume = std::sync::Arc::new(blocks::phantom::head(24).expect("head"));
        let mut source = blocks::ingest::MemorySource::new(volume, "small head");
        let store =
            blocks::store::ingest_in_memory(&mut source, &Default::default()).expect("store");
        server::Dataset::new("small".into(), store, 64 << 20).expect("dataset")
    };
    // One renderer at a time: every switch releases one dataset and loads the other.
    let server =
        TestServer::with_datasets(gpu, vec![phantom, small], 1, StreamSettings::default()).await;
    let mut socket = connect(&server).await;
    let mut id = 0;
    for dataset in ["small", "phantom", "small"] {
        id += 1;
        send(
            &mut socket,
            serde_json::json!({"type": "view", "id": id, "set": {"w": 36, "h": 36, "dataset": dataset}}),
        )
        .await;
        let frames = until_converged(&mut socket, id).await;
        let (last, img) = frames.last().expect("frames");
        assert_eq!((last.width, last.height), (36, 36), "{dataset}");
        let lit = img
            .pixels()
            .filter(|p| p.0[..3].iter().any(|&c| c > 30))
            .count();
        assert!(
            lit > 36 * 36 / 20,
            "{dataset}: the head shows ({lit} pixels)"
        );
    }
}

#[tokio::test]
async fn a_cold_transfer_function_change_renders_from_memory_while_another_session_is_served() {
    let test =
        "a_cold_transfer_function_change_renders_from_memory_while_another_session_is_served";
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let cold = voxserve_tests::phantom::phantom_64_on_disk(dir.path());
    let cold_cache = cold.cache.clone();
    let warm = server::Dataset::phantom(32, 64 << 20).expect("phantom");
    let server =
        TestServer::with_datasets(gpu, vec![warm, cold], 2, StreamSettings::default()).await;
    let mut a = connect(&server).await;
    let mut b = connect(&server).await;
    // A changes to a transfer function whose blocks are not in memory; B asks
    // for a frame of the other dataset at once.
    send(
        &mut a,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 48, "h": 48, "dataset": "cold", "preset": "ct-soft-tissue"}}),
    )
    .await;
    send(
        &mut b,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 48, "h": 48}}),
    )
    .await;
    let a_frames = until_converged(&mut a, 1).await;
    let b_frames = until_converged(&mut b, 1).await;
    let summary = |frames: &[(FrameHeader, image::RgbaImage)]| -> Vec<(u16, f32, f32)> {
        frames
            .iter()
            .map(|(h, _)| (h.pending_blocks, h.render_ms, h.queue_ms))
            .collect()
    };
    println!(
        "cold session (pending blocks, render ms, queue ms): {:?}; other session: {:?}",
        summary(&a_frames),
        summary(&b_frames)
    );
    // The cold change was drawn from what was in memory, blocks coarser, and
    // refined as they arrived: the render worker read nothing itself, so its
    // frames took one frame's time and the other session waited at most one.
    assert!(
        a_frames.iter().any(|(h, _)| h.pending_blocks > 0),
        "a frame showed blocks still being read: {:?}",
        summary(&a_frames)
    );
    let (last, _) = a_frames.last().expect("frames");
    assert_eq!(last.pending_blocks, 0, "{last:?}");
    assert_eq!(
        cold_cache.inline_reads(),
        0,
        "the render worker read no chunk itself"
    );
    assert!(b_frames.iter().all(|(h, _)| h.message_id == 1));
}

#[tokio::test]
async fn a_missing_shard_is_an_error_naming_it_over_http_and_websocket() {
    let test = "a_missing_shard_is_an_error_naming_it_over_http_and_websocket";
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp");
    // Opened as at start: only the two coarsest levels are in memory.
    let dataset = voxserve_tests::phantom::phantom_64_on_disk(dir.path());
    let shard = dir.path().join("cold.zarr/0/c/0/0/0");
    std::fs::remove_file(&shard).expect("delete level 0's shard");
    let server = TestServer::with_datasets(gpu, vec![dataset], 1, StreamSettings::default()).await;

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

    let mut socket = connect(&server).await;
    send(
        &mut socket,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 40, "h": 40}}),
    )
    .await;
    // Frames may come first, drawn from the coarse levels in memory while the
    // finer blocks load; then the error, and no converged frame or status
    // before it. Frames are acknowledged as a client does: the session sends
    // no more (and so renders no more) until they are, and whether the failed
    // read shows in the first frame or a later one is a race.
    let error = loop {
        match next(&mut socket).await {
            Received::Json(json) => {
                match json["type"].as_str() {
                    Some("error") => break json,
                    Some("status" | "frame") => {}
                    other => panic!("unexpected {other:?}: {json}"),
                }
                assert_ne!(json["converged"], true, "{json}");
            }
            Received::Frame(header, _) => {
                assert!(!header.converged, "{header:?}");
                ack(&mut socket, header.frame_id).await;
            }
        }
    };
    let message = error["message"].as_str().expect("a message");
    assert!(message.contains("0/c/0/0/0: missing"), "{message}");
}

/// A server on the 32³ phantom with the CPU renderer: no GPU needed, it
/// runs everywhere.
async fn cpu_server() -> TestServer {
    let dataset = server::Dataset::phantom(32, 64 << 20).expect("phantom");
    TestServer::with_backend(
        shaders::Backend::Cpu,
        vec![dataset],
        1,
        StreamSettings::default(),
    )
    .await
}

#[tokio::test]
async fn a_server_on_the_cpu_renderer_streams_frames_and_says_which_renderer_serves() {
    let server = cpu_server().await;
    let (mut socket, hello) = connect_with_hello(&server).await;
    assert_eq!(hello["renderer"]["kind"], "cpu", "{hello}");
    send(
        &mut socket,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 48, "h": 40, "az": 20}}),
    )
    .await;
    let frames = until_converged(&mut socket, 1).await;
    let (header, image) = frames.last().expect("frames");
    assert_eq!((image.width(), image.height()), (48, 40), "{header:?}");
    assert!(
        image.pixels().any(|p| p.0[..3] != [0, 0, 0]),
        "the phantom is drawn"
    );
    let body = get_text(&server, "/api/datasets").await;
    let datasets: serde_json::Value = serde_json::from_str(&body).expect("JSON");
    assert_eq!(datasets[0]["renderer"]["kind"], "cpu", "{datasets}");
    let text = metrics(&server).await;
    assert!(
        text.contains("voxserve_renderer_info{kind=\"cpu\""),
        "{text}"
    );
}

#[tokio::test]
async fn a_fit_is_answered_with_the_camera_chosen_before_its_frame_and_the_session_keeps_it() {
    let server = cpu_server().await;
    let mut socket = connect(&server).await;
    send(
        &mut socket,
        serde_json::json!({"type": "view", "id": 1, "set": {"w": 48, "h": 40, "az": 20, "fit": true}}),
    )
    .await;
    let camera = match next(&mut socket).await {
        Received::Json(m) if m["type"] == "camera" => m["set"].clone(),
        Received::Json(m) => panic!("expected the camera first, got {m}"),
        Received::Frame(h, _) => panic!("expected the camera before frame {h:?}"),
    };
    assert_eq!(camera["fit"], false, "{camera}");
    assert_eq!(camera["az"], 20.0, "{camera}");
    let default_distance = shaders::Camera::default().distance;
    let distance = camera["dist"].as_f64().expect("dist");
    assert!(
        distance > 0.0 && (distance - f64::from(default_distance)).abs() > 0.01,
        "the fit chose the distance: {camera}"
    );
    for name in ["tx", "ty", "tz"] {
        assert!(camera[name].is_number(), "{name}: {camera}");
    }
    // Every frame of the view, interactive and full, is drawn with that
    // camera, and no second camera message comes: the session keeps it.
    let frames = until_converged(&mut socket, 1).await;
    let fitted = frames.last().expect("frames").1.clone();
    // The same camera sent as plain settings draws the same full frame.
    let mut set = camera.as_object().expect("an object").clone();
    set.insert("az".into(), serde_json::json!(21));
    send(
        &mut socket,
        serde_json::json!({"type": "view", "id": 2, "set": set}),
    )
    .await;
    until_converged(&mut socket, 2).await;
    send(
        &mut socket,
        serde_json::json!({"type": "view", "id": 3, "set": {"az": 20}}),
    )
    .await;
    let again = until_converged(&mut socket, 3).await;
    assert_eq!(
        again.last().expect("frames").1,
        fitted,
        "the session kept the fitted camera"
    );
}
