//! The server as an attacker on the network meets it: pages of other sites,
//! foreign host names, idle sessions and connections that hold places, slow
//! headers, oversized messages, `HEAD` requests that would render. Each test
//! reproduces an attack and checks that it fails while ordinary use goes on.
//!
//! The servers render on the CPU (no GPU needed): nothing here is about
//! pictures.

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use std::net::{IpAddr, SocketAddr};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use server::access::Access;
use server::listen::ConnectionLimits;
use server::stream::StreamSettings;
use server::{AppState, Dataset, RenderService};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpSocket, TcpStream};
use tokio::sync::oneshot;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::{self, Message};
use voxserve_tests::server::Spawned;

const VOXSERVE: &str = env!("CARGO_BIN_EXE_voxserve");

/// Held by the tests that keep the CPU renderer busy, so that their timings
/// are not another test's frames (the renderers share rayon's threads).
static BUSY_RENDERER: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// A server on a loopback port, stopped when dropped.
struct Running {
    addr: SocketAddr,
    state: AppState,
    _stop: oneshot::Sender<()>,
}

async fn start(stream: StreamSettings, access: Access) -> Running {
    let renderer = RenderService::start(shaders::Backend::Cpu, 64 << 20, 1).expect("renderer");
    let phantom = Dataset::phantom(32, 16 << 20).expect("phantom");
    let state = AppState::new(vec![phantom], renderer, stream).with_access(access);
    let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let addr = listener.local_addr().expect("address");
    let (stop, stopped) = oneshot::channel::<()>();
    let shutdown = async {
        let _ = stopped.await;
    };
    tokio::spawn(server::run(listener, state.clone(), shutdown));
    Running {
        addr,
        state,
        _stop: stop,
    }
}

/// A TCP connection to `to` from the loopback address `from`.
async fn connect_from(from: IpAddr, to: SocketAddr) -> std::io::Result<TcpStream> {
    let socket = TcpSocket::new_v4()?;
    socket.bind(SocketAddr::new(from, 0))?;
    socket.connect(to).await
}

/// Sends `request` (raw HTTP/1.1) from `from` and returns the response's
/// head and body as text.
async fn raw_http(from: IpAddr, to: SocketAddr, request: &str) -> String {
    raw_http_within(from, to, request, Duration::from_secs(30)).await
}

/// [`raw_http`] waiting up to `patience` for the answer.
async fn raw_http_within(
    from: IpAddr,
    to: SocketAddr,
    request: &str,
    patience: Duration,
) -> String {
    let mut stream = connect_from(from, to).await.expect("connect");
    stream
        .write_all(request.as_bytes())
        .await
        .expect("send the request");
    let mut response = Vec::new();
    let read = stream.read_to_end(&mut response);
    tokio::time::timeout(patience, read)
        .await
        .unwrap_or_else(|_| panic!("an answer within {patience:?}"))
        .expect("read the answer");
    String::from_utf8_lossy(&response).into_owned()
}

/// A WebSocket handshake with `/api/stream` from `from` with `origin`.
async fn open_session(
    from: IpAddr,
    to: SocketAddr,
    origin: Option<&str>,
) -> Result<tokio_tungstenite::WebSocketStream<TcpStream>, tungstenite::Error> {
    let mut request = format!("ws://{to}/api/stream")
        .into_client_request()
        .expect("a request");
    if let Some(origin) = origin {
        request
            .headers_mut()
            .insert("origin", origin.parse().expect("a header value"));
    }
    let stream = connect_from(from, to)
        .await
        .map_err(tungstenite::Error::Io)?;
    let (socket, _) = tokio_tungstenite::client_async(request, stream).await?;
    Ok(socket)
}

/// The HTTP status a refused handshake got.
fn refused_with(result: Result<impl std::fmt::Debug, tungstenite::Error>) -> u16 {
    match result {
        Err(tungstenite::Error::Http(response)) => response.status().as_u16(),
        other => panic!("expected a refused handshake, got {other:?}"),
    }
}

/// The next message that is not a ping, within `patience`.
async fn next_message(
    socket: &mut tokio_tungstenite::WebSocketStream<TcpStream>,
    patience: Duration,
) -> Message {
    loop {
        let message = tokio::time::timeout(patience, socket.next())
            .await
            .expect("a message in time")
            .expect("the socket is open")
            .expect("a message");
        if !matches!(message, Message::Ping(_) | Message::Pong(_)) {
            return message;
        }
    }
}

const LOCAL: IpAddr = IpAddr::V4(std::net::Ipv4Addr::LOCALHOST);

#[tokio::test]
async fn a_page_of_another_site_cannot_open_a_view_session() {
    let access = Access {
        allowed_origins: vec!["https://pacs.example.org".into()],
        ..Access::default()
    };
    let server = start(StreamSettings::default(), access).await;
    let status = refused_with(open_session(LOCAL, server.addr, Some("https://evil.example")).await);
    assert_eq!(status, 403);
    assert_eq!(server.state.sessions.open(), 0);
    // The server's own pages, configured origins and clients that are not
    // browsers (no Origin) get in.
    let own = format!("http://{}", server.addr);
    for origin in [Some(own.as_str()), Some("https://pacs.example.org"), None] {
        let mut socket = open_session(LOCAL, server.addr, origin)
            .await
            .unwrap_or_else(|e| panic!("{origin:?}: {e}"));
        let hello = next_message(&mut socket, Duration::from_secs(10)).await;
        assert!(hello.to_text().expect("text").contains("\"hello\""));
    }
}

#[tokio::test]
async fn a_foreign_host_name_is_refused_against_dns_rebinding() {
    let access = Access {
        host_names: vec!["viewer.example.org".into()],
        ..Access::default()
    };
    let server = start(StreamSettings::default(), access).await;
    let ask = |host: &str| {
        format!("GET /api/datasets HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n")
    };
    let refused = raw_http(LOCAL, server.addr, &ask("evil.example:8080")).await;
    assert!(refused.starts_with("HTTP/1.1 421"), "{refused}");
    assert!(
        refused.contains("not a name of this server") && !refused.contains("phantom"),
        "{refused}"
    );
    for host in [
        server.addr.to_string(),
        "localhost".into(),
        "viewer.example.org".into(),
    ] {
        let answer = raw_http(LOCAL, server.addr, &ask(&host)).await;
        assert!(answer.starts_with("HTTP/1.1 200"), "{host}: {answer}");
    }
}

#[tokio::test]
async fn idle_sessions_are_closed_so_a_new_viewer_gets_in() {
    let stream = StreamSettings {
        max_sessions: 16,
        sessions_per_client: 32,
        session_idle_s: 2,
        ..StreamSettings::default()
    };
    let server = start(stream, Access::default()).await;
    let mut idle = Vec::new();
    for _ in 0..16 {
        let mut socket = open_session(LOCAL, server.addr, None)
            .await
            .expect("a place");
        next_message(&mut socket, Duration::from_secs(10)).await;
        idle.push(socket);
    }
    let status = refused_with(open_session(LOCAL, server.addr, None).await);
    assert_eq!(status, 503, "the server is full");
    // Sessions that send nothing are closed with 4408 and the reason.
    for socket in &mut idle {
        match next_message(socket, Duration::from_secs(20)).await {
            Message::Close(Some(close)) => {
                assert_eq!(u16::from(close.code), 4408);
                assert!(close.reason.contains("idle"), "{}", close.reason);
            }
            other => panic!("expected a close, got {other:?}"),
        }
    }
    let mut viewer = open_session(LOCAL, server.addr, None)
        .await
        .expect("a place after the idle sessions were closed");
    let hello = next_message(&mut viewer, Duration::from_secs(10)).await;
    assert!(hello.to_text().expect("text").contains("\"hello\""));
}

#[tokio::test]
async fn one_client_holds_at_most_its_share_of_sessions() {
    let stream = StreamSettings {
        sessions_per_client: 2,
        ..StreamSettings::default()
    };
    let server = start(stream, Access::default()).await;
    let mut held = Vec::new();
    for _ in 0..2 {
        held.push(
            open_session(LOCAL, server.addr, None)
                .await
                .expect("a place"),
        );
    }
    let status = refused_with(open_session(LOCAL, server.addr, None).await);
    assert_eq!(status, 429);
    let other: IpAddr = [127, 0, 0, 2].into();
    open_session(other, server.addr, None)
        .await
        .expect("another client gets in");
    // A place comes back when a session ends.
    let mut first = held.remove(0);
    first.close(None).await.expect("close");
    while first.next().await.is_some() {}
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match open_session(LOCAL, server.addr, None).await {
            Ok(_) => break,
            // The place is freed as the session ends, a moment after the close.
            Err(_) if Instant::now() < deadline => {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            Err(e) => panic!("no place after closing a session: {e}"),
        }
    }
}

#[tokio::test]
async fn slow_headers_and_idle_connections_are_closed() {
    let access = Access {
        connections: ConnectionLimits {
            header_timeout: Duration::from_secs(1),
            idle_timeout: Duration::from_secs(2),
            ..ConnectionLimits::DEFAULT
        },
        ..Access::default()
    };
    let server = start(StreamSettings::default(), access).await;
    // Headers trickled a byte at a time, never finished.
    let mut slow = connect_from(LOCAL, server.addr).await.expect("connect");
    slow.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        .await
        .expect("send");
    let started = Instant::now();
    let trickle = async {
        loop {
            tokio::time::sleep(Duration::from_millis(200)).await;
            if slow.write_all(b"X").await.is_err() {
                return;
            }
            let mut byte = [0u8; 1];
            let read = tokio::time::timeout(Duration::from_millis(1), slow.read(&mut byte)).await;
            if matches!(read, Ok(Ok(0) | Err(_))) {
                return;
            }
        }
    };
    tokio::time::timeout(Duration::from_secs(10), trickle)
        .await
        .expect("the slow connection was closed");
    assert!(started.elapsed() < Duration::from_secs(5));
    // A keep-alive connection that goes quiet after a request.
    let mut quiet = connect_from(LOCAL, server.addr).await.expect("connect");
    quiet
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: localhost\r\n\r\n")
        .await
        .expect("send");
    let mut answer = vec![0u8; 4096];
    let n = quiet.read(&mut answer).await.expect("the answer");
    assert!(answer[..n].starts_with(b"HTTP/1.1 200"));
    let started = Instant::now();
    let end = tokio::time::timeout(Duration::from_secs(10), quiet.read(&mut answer))
        .await
        .expect("the quiet connection was closed");
    assert!(matches!(end, Ok(0) | Err(_)), "{end:?}");
    let waited = started.elapsed();
    assert!(
        waited >= Duration::from_millis(900) && waited < Duration::from_secs(6),
        "closed after {waited:?}"
    );
}

#[tokio::test]
async fn head_never_renders() {
    let server = start(StreamSettings::default(), Access::default()).await;
    let head = |query: &str| {
        format!("HEAD /api/render?{query} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
    };
    let started = Instant::now();
    let answer = raw_http(LOCAL, server.addr, &head("w=4096&h=4096")).await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    assert!(answer.contains("image/png"), "{answer}");
    let bad = raw_http(LOCAL, server.addr, &head("w=0")).await;
    assert!(bad.starts_with("HTTP/1.1 400"), "{bad}");
    let metrics = raw_http(
        LOCAL,
        server.addr,
        "GET /metrics HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n",
    )
    .await;
    let frames: Vec<&str> = metrics
        .lines()
        .filter(|l| l.starts_with("voxserve_frames_total{"))
        .collect();
    assert!(
        frames.iter().all(|l| l.ends_with(" 0")),
        "HEAD rendered: {frames:?}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "a 4096² HEAD took {:?}",
        started.elapsed()
    );
}

#[tokio::test]
async fn an_oversized_message_closes_the_session_with_a_short_reason() {
    let server = start(StreamSettings::default(), Access::default()).await;
    let mut socket = open_session(LOCAL, server.addr, None)
        .await
        .expect("a place");
    next_message(&mut socket, Duration::from_secs(10)).await;
    // A value padded to 60 kB (within the message limit): a short error.
    let padded = format!(
        "{{\"type\":\"view\",\"id\":1,\"set\":{{\"tf\":\"{}\"}}}}",
        " ".repeat(60_000)
    );
    socket
        .send(Message::Text(padded.into()))
        .await
        .expect("send");
    let error = next_message(&mut socket, Duration::from_secs(10)).await;
    let text = error.to_text().expect("text");
    assert!(
        text.contains("\"error\"") && text.len() < 1000,
        "{} bytes",
        text.len()
    );
    // 10 MB: the session is closed with 1009 and a short reason.
    let huge = format!(
        "{{\"type\":\"view\",\"id\":2,\"set\":{{\"w\":512{}}}}}",
        " ".repeat(10 << 20)
    );
    let _ = socket.send(Message::Text(huge.into())).await;
    match next_message(&mut socket, Duration::from_secs(20)).await {
        Message::Close(Some(close)) => {
            assert_eq!(u16::from(close.code), 1009);
            assert!(close.reason.len() <= 123, "{}", close.reason);
            assert!(close.reason.contains("too long"), "{}", close.reason);
        }
        other => panic!("expected a close, got {other:?}"),
    }
    // The server goes on.
    let mut next = open_session(LOCAL, server.addr, None)
        .await
        .expect("a place");
    next_message(&mut next, Duration::from_secs(10)).await;
}

#[tokio::test]
async fn eleven_hundred_idle_connections_leave_healthz_answering() {
    // The server as deployed: its own process, with the usual limit of
    // 1 024 open files.
    let command = format!(
        "ulimit -n 1024 && exec {VOXSERVE} serve --renderer cpu --phantom-size 32 --addr 127.0.0.1:0"
    );
    let server = Spawned::start("bash", &["-c", &command])
        .await
        .unwrap_or_else(|stderr| panic!("serve exited: {stderr}"));
    let addr: SocketAddr = server
        .url
        .strip_prefix("http://")
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(|| panic!("no address in {}", server.url));
    // 1 100 connections that never send a byte, from 20 addresses (so the
    // per-client cap alone cannot save the server).
    let mut idle = Vec::new();
    for i in 0..1100u32 {
        let from: IpAddr = [127, 0, 1, (i % 20) as u8 + 1].into();
        if let Ok(stream) = connect_from(from, addr).await {
            idle.push(stream);
        }
    }
    assert!(idle.len() > 1024, "only {} connections opened", idle.len());
    tokio::time::sleep(Duration::from_millis(500)).await;
    for from in [LOCAL, IpAddr::from([127, 0, 1, 1])] {
        let started = Instant::now();
        let answer = tokio::time::timeout(
            Duration::from_secs(5),
            raw_http(
                from,
                addr,
                "GET /healthz HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n",
            ),
        )
        .await
        .unwrap_or_else(|_| panic!("/healthz from {from} did not answer within 5 s"));
        assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
        assert!(started.elapsed() < Duration::from_secs(5));
    }
}

/// A response header's value as a number.
fn header_ms(response: &str, name: &str) -> f64 {
    response
        .lines()
        .find_map(|line| {
            let (key, value) = line.split_once(':')?;
            key.eq_ignore_ascii_case(name)
                .then(|| value.trim().parse().ok())
                .flatten()
        })
        .unwrap_or_else(|| panic!("no {name} in {response:.300}"))
}

fn get_render(edge: u32) -> String {
    get_render_at(edge, 0.5)
}

fn get_render_at(edge: u32, step: f32) -> String {
    format!(
        "GET /api/render?w={edge}&h={edge}&step={step} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"
    )
}

#[tokio::test]
async fn a_client_s_big_frames_do_not_hold_up_another_s_small_frame() {
    let _alone = BUSY_RENDERER.lock().await;
    let server = start(StreamSettings::default(), Access::default()).await;
    let (hog, viewer): (IpAddr, IpAddr) = ([127, 0, 0, 2].into(), [127, 0, 0, 3].into());
    // The blocks every frame below draws are in memory first: this test
    // measures turns, not reads. Else the hog's first frame draws every
    // band from the coarse blocks shown while the fine ones were read
    // (a frame never joins two sets of blocks), bands that cost the CPU
    // renderer up to three times the later frames' it is compared with.
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let warm = raw_http(viewer, server.addr, &get_render_at(64, 2.0)).await;
        assert!(warm.starts_with("HTTP/1.1 200"), "{warm:.300}");
        if header_ms(&warm, "x-pending-blocks") == 0.0 {
            break;
        }
        assert!(Instant::now() < deadline, "blocks still read after 60 s");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let bands_before = server.state.renderer.bands();
    // The hog asks for a 4096² frame, and keeps two more waiting (its
    // share), asking again whenever it is refused for having that many. A
    // step of 2 voxels keeps them several turns each (bands ≥ 4 below) while
    // the test stays short.
    let addr = server.addr;
    let first = tokio::spawn(async move {
        raw_http_within(
            hog,
            addr,
            &get_render_at(4096, 2.0),
            Duration::from_secs(300),
        )
        .await
    });
    let deadline = Instant::now() + Duration::from_secs(60);
    while server.state.renderer.bands() <= bands_before && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let mut hogging = Vec::new();
    for _ in 0..2 {
        let addr = server.addr;
        hogging.push(tokio::spawn(async move {
            loop {
                let answer = raw_http_within(
                    hog,
                    addr,
                    &get_render_at(4096, 2.0),
                    Duration::from_secs(300),
                )
                .await;
                if !answer.starts_with("HTTP/1.1 429") {
                    return answer;
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }));
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    // The viewer's small frames, one after another while the hog's render.
    let mut waits = Vec::new();
    for _ in 0..3 {
        let small = raw_http(viewer, server.addr, &get_render(64)).await;
        assert!(small.starts_with("HTTP/1.1 200"), "{small:.300}");
        waits.push(header_ms(&small, "x-queue-ms"));
    }
    let first = first.await.expect("the hog's first request");
    assert!(first.starts_with("HTTP/1.1 200"), "{first:.900}");
    let bands = header_ms(&first, "x-render-bands");
    assert!(
        bands >= 4.0,
        "a 4096² frame costs several turns: {bands} bands"
    );
    let frame_ms = header_ms(&first, "x-render-ms");
    let band_ms = header_ms(&first, "x-render-band-ms");
    // The others are dropped (their connections close, their frames are
    // abandoned).
    for task in hogging {
        task.abort();
    }
    // In arrival order a small frame would wait for whole 4096² frames; in
    // turn, for one round at most: the rest of the band rendering when it
    // came and the hog's next band (a band costs one turn, the cost budget:
    // 512² pixels × 256 samples).
    for waited in &waits {
        assert!(
            *waited <= band_ms * 2.0 + 100.0,
            "a 64² frame waited {waited:.0} ms behind 4096² frames of {frame_ms:.0} ms in \
             {bands} bands of at most {band_ms:.0} ms"
        );
    }
    println!(
        "64² frames waited {waits:?} ms beside 4096² frames of {bands} bands, the longest {band_ms:.0} ms"
    );
}

#[tokio::test]
async fn a_frame_costing_more_than_the_limit_is_refused_before_it_renders() {
    let _alone = BUSY_RENDERER.lock().await;
    let server = start(StreamSettings::default(), Access::default()).await;
    server.state.renderer.set_max_frame_cost(1 << 30);
    let answer = raw_http(LOCAL, server.addr, &get_render_at(4096, 0.05)).await;
    assert!(answer.starts_with("HTTP/1.1 400"), "{answer:.300}");
    assert!(
        answer.contains("pixel-samples") && answer.contains("4096x4096"),
        "{answer:.600}"
    );
    assert_eq!(server.state.renderer.bands(), 0, "nothing was drawn");
    // Within the limit, the same frame size renders.
    let answer = raw_http(LOCAL, server.addr, &get_render_at(1024, 0.5)).await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer:.300}");
}

#[tokio::test]
async fn a_frame_abandoned_partway_stops_rendering() {
    let _alone = BUSY_RENDERER.lock().await;
    let server = start(StreamSettings::default(), Access::default()).await;
    // 4096² at a step of 0.05 voxels: dozens of turns of the worker.
    let mut stream = connect_from(LOCAL, server.addr).await.expect("connect");
    stream
        .write_all(get_render_at(4096, 0.05).as_bytes())
        .await
        .expect("send");
    let deadline = Instant::now() + Duration::from_secs(20);
    while server.state.renderer.bands() < 2 && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert!(
        server.state.renderer.bands() >= 2,
        "the frame is being drawn"
    );
    drop(stream);
    let deadline = Instant::now() + Duration::from_secs(20);
    while server.state.renderer.abandoned() < 1 && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert_eq!(
        server.state.renderer.abandoned(),
        1,
        "the frame was dropped"
    );
    let bands = server.state.renderer.bands();
    assert!(
        bands < 20,
        "{bands} bands drawn of a frame of dozens: it stopped within a band of its client going"
    );
    // The worker is free again.
    let small = raw_http(LOCAL, server.addr, &get_render(64)).await;
    assert!(small.starts_with("HTTP/1.1 200"), "{small:.300}");
    assert_eq!(
        server.state.renderer.bands(),
        bands,
        "nothing more drawn of it"
    );
}

#[tokio::test]
async fn abandoned_requests_are_not_rendered() {
    let _alone = BUSY_RENDERER.lock().await;
    let server = start(StreamSettings::default(), Access::default()).await;
    // Four big frames asked for (by four clients, each within its share),
    // and the connections closed before they are done: those still waiting
    // (all but the one rendering, if it had started) are dropped unrendered.
    let mut gone = Vec::new();
    for i in 0..4u8 {
        let from: IpAddr = [127, 0, 0, 2 + i].into();
        let mut stream = connect_from(from, server.addr).await.expect("connect");
        stream
            .write_all(get_render(1536).as_bytes())
            .await
            .expect("send");
        gone.push(stream);
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    drop(gone);
    // The worker meets them in their turns (after smaller frames: a 64² one
    // here): each is counted, not rendered, so the count is reached soon.
    let small = raw_http(LOCAL, server.addr, &get_render(64)).await;
    assert!(small.starts_with("HTTP/1.1 200"), "{small:.300}");
    let deadline = Instant::now() + Duration::from_secs(10);
    while server.state.renderer.abandoned() < 3 && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let abandoned = server.state.renderer.abandoned();
    assert!((3..=4).contains(&abandoned), "{abandoned} abandoned");
}

#[tokio::test]
async fn a_client_asking_too_often_waits_and_others_do_not() {
    let access = Access {
        requests: server::client::RequestRate {
            per_second: 1,
            burst: 5,
        },
        ..Access::default()
    };
    let server = start(StreamSettings::default(), access).await;
    let (eager, other): (IpAddr, IpAddr) = ([127, 0, 0, 2].into(), [127, 0, 0, 3].into());
    let list = "GET /api/datasets HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n";
    for _ in 0..5 {
        let answer = raw_http(eager, server.addr, list).await;
        assert!(answer.starts_with("HTTP/1.1 200"), "{answer:.300}");
    }
    let refused = raw_http(eager, server.addr, list).await;
    assert!(refused.starts_with("HTTP/1.1 429"), "{refused:.300}");
    let retry = header_ms(&refused, "retry-after");
    assert!((1.0..=2.0).contains(&retry), "Retry-After: {retry}");
    assert!(
        refused.contains("127.0.0.2 is over its rate of 1 API requests a second"),
        "{refused:.400}"
    );
    let answer = raw_http(other, server.addr, list).await;
    assert!(
        answer.starts_with("HTTP/1.1 200"),
        "another client: {answer:.300}"
    );
    // The health check is not an API call: never limited.
    let health = raw_http(
        eager,
        server.addr,
        "GET /healthz HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n",
    )
    .await;
    assert!(health.starts_with("HTTP/1.1 200"), "{health:.300}");
}
