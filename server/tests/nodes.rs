//! Several render nodes behind a load balancer: two `voxserve serve`
//! processes serving one brick store from a real S3-compatible server
//! (`s3s-fs` on loopback), behind a real nginx with the configuration the
//! README documents (`tests/nginx/two-nodes.conf`). A viewer's session goes
//! through nginx; its node drains on SIGTERM (finishes the frame it renders,
//! closes the session with 1001, exits); the viewer reconnects through
//! nginx, reaches the other node with the same view, and sees the same
//! pixels. The nodes trust nginx's `X-Forwarded-For`: their audit trail
//! names the viewer's address, not nginx's.

use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use voxserve_tests::nginx::Nginx;
use voxserve_tests::s3::S3Server;
use voxserve_tests::server::{Spawned, sessions_open};

const VOXSERVE: &str = env!("CARGO_BIN_EXE_voxserve");

type Socket = tokio_tungstenite::WebSocketStream<tokio::net::TcpStream>;

/// A 64³ u8 volume: a ball of rising values with a ring of denser matter,
/// written as a raw file whose name gives its size and type.
fn write_volume(dir: &std::path::Path) -> std::path::PathBuf {
    const N: usize = 64;
    let mut voxels = vec![0_u8; N * N * N];
    for z in 0..N {
        for y in 0..N {
            for x in 0..N {
                let d = |c: usize| c as f32 - N as f32 / 2.0;
                let r = (d(x).powi(2) + d(y).powi(2) + d(z).powi(2)).sqrt();
                let value = if r < 12.0 {
                    255.0
                } else if r < 28.0 {
                    80.0 + 4.0 * (28.0 - r) + 2.0 * d(x).abs()
                } else {
                    0.0
                };
                voxels[(z * N + y) * N + x] = value.clamp(0.0, 255.0) as u8;
            }
        }
    }
    let file = dir.join("ball_64x64x64_uint8.raw");
    std::fs::write(&file, voxels).expect("writing the volume");
    file
}

/// `GET url`: the status and the body.
async fn get(url: &str) -> (u16, String) {
    let response = reqwest::get(url)
        .await
        .unwrap_or_else(|e| panic!("GET {url}: {e}"));
    let status = response.status().as_u16();
    (status, response.text().await.expect("a body"))
}

/// A frame as it came: its header's message id and flags, and the encoded
/// image after the 48-byte header.
struct Frame {
    message_id: u32,
    lossless: bool,
    converged: bool,
    image: Vec<u8>,
}

fn frame_of(bytes: &[u8]) -> Frame {
    assert!(bytes.len() > 48 && &bytes[..4] == b"VXF1", "not a frame");
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    Frame {
        message_id: u32_at(20),
        lossless: bytes[5] & 1 != 0,
        converged: bytes[5] & 2 != 0,
        image: bytes[48..].to_vec(),
    }
}

/// What came next on a session: a frame (acknowledged), or its close code.
enum Next {
    Frame(Frame),
    Closed(Option<CloseCode>),
}

async fn next(socket: &mut Socket, patience: Duration) -> Next {
    loop {
        let message = tokio::time::timeout(patience, socket.next())
            .await
            .expect("a message in time");
        match message {
            Some(Ok(Message::Binary(bytes))) => {
                let frame_id = u32::from_le_bytes(bytes[16..20].try_into().expect("4 bytes"));
                let ack = serde_json::json!({"type": "ack", "frame": frame_id});
                // The node may have closed meanwhile: the close comes next.
                let _ = socket.send(Message::Text(ack.to_string().into())).await;
                return Next::Frame(frame_of(&bytes));
            }
            Some(Ok(Message::Text(text))) => {
                let value: serde_json::Value =
                    serde_json::from_str(text.as_str()).expect("a JSON message");
                assert_ne!(value["type"], "error", "{value}");
            }
            Some(Ok(Message::Close(close))) => return Next::Closed(close.map(|c| c.code)),
            Some(Ok(_)) => {}
            Some(Err(e)) => panic!("the session broke: {e}"),
            None => return Next::Closed(None),
        }
    }
}

/// Opens a view session at `url` (through nginx) from the loopback address
/// `from`, and reads its hello.
async fn open(url: &str, from: [u8; 4]) -> Socket {
    let address: std::net::SocketAddr = url
        .trim_start_matches("http://")
        .parse()
        .expect("an address");
    let tcp = tokio::net::TcpSocket::new_v4().expect("a socket");
    tcp.bind((std::net::Ipv4Addr::from(from), 0).into())
        .expect("binding a loopback address");
    let stream = tcp.connect(address).await.expect("connecting to nginx");
    let ws = url.replace("http://", "ws://");
    let (mut socket, _) = tokio_tungstenite::client_async(format!("{ws}/api/stream"), stream)
        .await
        .expect("a view session through nginx");
    let hello = tokio::time::timeout(Duration::from_secs(30), socket.next())
        .await
        .expect("a hello in time")
        .expect("the socket is open")
        .expect("a message");
    let hello: serde_json::Value =
        serde_json::from_str(hello.to_text().expect("text")).expect("JSON");
    assert_eq!(hello["type"], "hello", "{hello}");
    socket
}

async fn send_view(socket: &mut Socket, id: u32, set: serde_json::Value) {
    let view = serde_json::json!({"type": "view", "id": id, "set": set});
    socket
        .send(Message::Text(view.to_string().into()))
        .await
        .expect("sending a view");
}

/// The full frame (lossless, converged) of view message `id`.
async fn full_frame(socket: &mut Socket, id: u32) -> Frame {
    let start = Instant::now();
    loop {
        match next(socket, Duration::from_secs(60)).await {
            Next::Frame(frame) if frame.message_id == id && frame.lossless && frame.converged => {
                return frame;
            }
            Next::Frame(_) => {}
            Next::Closed(code) => panic!("the session closed ({code:?}) before its full frame"),
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no full frame within 120 s"
        );
    }
}

/// Waits until the node at `url` says it is ready (`/healthz` 200).
async fn ready(url: &str) {
    let start = Instant::now();
    loop {
        let (status, body) = get(&format!("{url}/healthz")).await;
        if status == 200 {
            assert!(body.contains("\"ok\""), "{body}");
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "{url} not ready within 60 s: {status} {body}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_whose_node_drains_reconnects_through_nginx_to_the_other_with_its_view() {
    let test = "a_viewer_whose_node_drains_reconnects_through_nginx_to_the_other_with_its_view";
    let dir = tempfile::tempdir().expect("temp");
    let volume = write_volume(dir.path());
    let s3 = S3Server::start(&["scans"]);
    let mut env = s3.env();
    env.push((
        "RUST_LOG".into(),
        "debug,hyper=info,h2=info,rustls=info".into(),
    ));
    let url = "s3://scans/nodes/ball.zarr";
    let ingest = std::process::Command::new(VOXSERVE)
        .args(["ingest", volume.to_str().expect("utf-8"), "--out", url])
        .envs(env.iter().map(|(k, v)| (k, v)))
        .output()
        .expect("running voxserve ingest");
    assert!(
        ingest.status.success(),
        "{}",
        String::from_utf8_lossy(&ingest.stderr)
    );
    let args = [
        "serve",
        url,
        "--addr",
        "127.0.0.1:0",
        "--renderer",
        "cpu",
        "--drain-s",
        "20",
        // nginx (a network of one address): the client is the address it
        // forwards.
        "--trusted-proxy",
        "127.0.0.1/32",
    ];
    let mut nodes = Vec::new();
    for _ in 0..2 {
        let node = Spawned::start_with_env(VOXSERVE, &args, &env)
            .await
            .unwrap_or_else(|stderr| panic!("a node did not start: {stderr}"));
        ready(&node.url).await;
        nodes.push(node);
    }
    let addresses: Vec<String> = nodes
        .iter()
        .map(|n| n.url.trim_start_matches("http://").to_owned())
        .collect();
    let addresses: Vec<&str> = addresses.iter().map(String::as_str).collect();
    let Some(nginx) = Nginx::start_or_skip(test, &addresses) else {
        return;
    };
    let (status, body) = get(&format!("{}/healthz", nginx.url)).await;
    assert_eq!(status, 200, "healthz through nginx: {body}");

    // A view, drawn in full through nginx by one node.
    let mut socket = open(&nginx.url, [127, 0, 0, 2]).await;
    send_view(
        &mut socket,
        1,
        serde_json::json!({"w": 160, "h": 160, "az": 30, "el": 20}),
    )
    .await;
    let first = full_frame(&mut socket, 1).await;
    let mut serving = None;
    for (i, node) in nodes.iter().enumerate() {
        if sessions_open(&node.url).await.expect("the node's /metrics") == 1 {
            assert!(serving.is_none(), "the session is on both nodes");
            serving = Some(i);
        }
    }
    let serving = serving.expect("the session is on one of the nodes");
    let other = 1 - serving;

    // Another client's big frame keeps the node's render worker busy (it
    // renders in turns of bands), so the view change below waits in the
    // queue: when the node is told to drain, that frame is still to come.
    // Both are finished: the HTTP frame is answered, the session's frame
    // sent, and only then does the session close, with 1001.
    let big = format!("{}/api/render?w=1536&h=1536&step=0.25", nodes[serving].url);
    let big = tokio::spawn(async move {
        reqwest::get(&big)
            .await
            .map(|r| r.status().as_u16())
            .map_err(|e| format!("{e:?}"))
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    send_view(&mut socket, 2, serde_json::json!({"az": 75})).await;
    tokio::time::sleep(Duration::from_millis(30)).await;
    let draining = nodes.remove(serving);
    draining.terminate();
    let mut frames_of_change = 0;
    let code = loop {
        let Ok(next) = tokio::time::timeout(
            Duration::from_secs(40),
            next(&mut socket, Duration::from_secs(60)),
        )
        .await
        else {
            let stderr = draining.stop();
            panic!("the session neither sent nor closed within 40 s of SIGTERM: {stderr}");
        };
        match next {
            Next::Frame(frame) => {
                if frame.message_id == 2 {
                    frames_of_change += 1;
                }
            }
            Next::Closed(code) => break code,
        }
    };
    assert_eq!(code, Some(CloseCode::Away), "the close on draining");
    assert!(
        frames_of_change >= 1,
        "the frame rendering when the node drained was not sent"
    );
    assert_eq!(
        big.await.expect("the big frame's request"),
        Ok(200),
        "the HTTP frame in flight when the node drained"
    );
    let Ok((exit, stderr)) = draining.wait_exit(Duration::from_secs(30)) else {
        panic!("the draining node did not exit within 30 s");
    };
    assert!(
        exit.success(),
        "the drained node exited with {exit}: {stderr}"
    );
    assert!(stderr.contains("draining"), "{stderr}");
    // The audit trail names the viewer, not nginx.
    assert!(
        stderr.contains("\"event\":\"session-open\"")
            && stderr.contains("\"client\":\"127.0.0.2\""),
        "{stderr}"
    );

    // The viewer reconnects through nginx (as the web client does after a
    // 1001) and sends its whole view: the other node draws it, and draws
    // the first view pixel for pixel as the drained node did.
    let mut socket = open(&nginx.url, [127, 0, 0, 2]).await;
    send_view(
        &mut socket,
        1,
        serde_json::json!({"w": 160, "h": 160, "az": 75, "el": 20}),
    )
    .await;
    full_frame(&mut socket, 1).await;
    let survivor = &nodes[0];
    assert_eq!(
        sessions_open(&survivor.url)
            .await
            .expect("the survivor's /metrics"),
        1,
        "the session reopened on the other node (index {other})"
    );
    send_view(&mut socket, 2, serde_json::json!({"az": 30})).await;
    let again = full_frame(&mut socket, 2).await;
    assert!(
        again.image == first.image,
        "the other node's frame of the first view differs from the drained node's"
    );
    let (status, body) = get(&format!("{}/healthz", nginx.url)).await;
    assert_eq!(
        status, 200,
        "healthz through nginx with one node left: {body}"
    );
    let _ = socket.close(None).await;
}
