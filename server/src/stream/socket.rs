//! A view session's I/O: [`run`] feeds a [`Session`] what arrives on its
//! socket, the frames it renders and the server's shutdown, and carries out
//! the session's actions: renders on the shared worker (encoded on the
//! blocking pool), replies and frames sent, and the close.
//!
//! Generic over the socket's halves (`Sink` and `Stream` of axum's
//! [`Message`]) so the loop can be driven by channels as well as by a
//! WebSocket.

use std::future::Future;
use std::pin::Pin;
use std::time::Duration;

use axum::extract::ws::{CloseFrame, Message, close_code};
use futures_util::{Sink, SinkExt, Stream, StreamExt};
use shaders::Camera;
use tokio::time::Instant;

use super::Place;
use super::session::{Action, Quality, Render, Session};
use crate::audit::{Event as Audited, Outcome};
use crate::client::Client;
use crate::protocol::{self, ClientMessage, Encoding, FrameHeader, Reply};
use crate::{AppState, Dataset, encode, metrics};

/// How long a session closed by the server waits for the client's close
/// before it drops the connection anyway.
const CLOSE_PATIENCE: Duration = Duration::from_secs(5);

/// A rendered and encoded frame: its header, its bytes, and the dataset's
/// chunk arrivals when it was planned.
#[derive(Debug)]
struct Encoded {
    header: FrameHeader,
    bytes: Vec<u8>,
    arrivals: u64,
    /// The camera a fit chose, when the view asked for one.
    camera: Option<Camera>,
    /// Where a slice frame lies: sent before it.
    slice: Option<Reply>,
}

/// A frame ready to send, or why there is none.
type Job = Pin<Box<dyn Future<Output = Result<Encoded, String>> + Send>>;

/// How long a session gathers blocks arriving before it shows them, and how
/// long it waits for any at all before it renders again anyway.
const BLOCKS_GATHER: Duration = Duration::from_millis(250);
const BLOCKS_PATIENCE: Duration = Duration::from_secs(5);

/// How a session ended.
#[derive(Debug, Clone, PartialEq, Eq)]
enum End {
    /// The client sent a close: the reply completes the handshake.
    Client,
    /// The socket broke or ended without a close.
    Gone,
    /// The server is shutting down: a close (1001) goes out.
    Shutdown,
    /// The client sent nothing for `session_idle_s`: a close
    /// ([`protocol::CLOSE_IDLE`]) goes out.
    Idle,
    /// The client broke the protocol (a message too long, a bad frame): a
    /// close with the code and reason goes out.
    Broken(u16, String),
    /// The peer answered no ping for [`protocol::PEER_PATIENCE`] seconds.
    Silent,
    /// The access token expired: a close ([`protocol::CLOSE_EXPIRED`]) goes
    /// out.
    Expired,
}

impl End {
    /// Why the session ended, for the audit trail.
    fn reason(&self) -> String {
        match self {
            End::Client => "closed by the client".into(),
            End::Gone => "the connection ended".into(),
            End::Shutdown => "the server shut down".into(),
            End::Idle => "idle".into(),
            End::Broken(code, reason) => format!("protocol error {code}: {reason}"),
            End::Silent => "the client stopped answering pings".into(),
            End::Expired => "the access token expired".into(),
        }
    }
}

/// Who opened a session, and the datasets it may see.
#[derive(Debug)]
pub(super) struct Caller {
    pub principal: crate::auth::Principal,
    pub datasets: std::sync::Arc<[Dataset]>,
}

/// What woke the loop.
#[derive(Debug)]
enum Event {
    Shutdown,
    Drain,
    Rendered(Result<Encoded, String>),
    BlocksArrived,
    Received(Message),
    Gone,
    Broken(String),
    Still,
    Timer,
}

/// When the session last heard from its client, and when it pings next.
#[derive(Debug)]
struct Liveness {
    /// The last text message (view, acknowledgement, status).
    message: Instant,
    /// The last message of any kind, pongs included.
    heard: Instant,
    /// The next ping.
    ping: Instant,
    idle: Duration,
    /// When the access token expires.
    expires: Option<Instant>,
}

impl Liveness {
    fn new(now: Instant, idle: Duration, expires: Option<std::time::SystemTime>) -> Liveness {
        // A year is never; the clamp keeps instants from overflowing.
        let year = Duration::from_secs(365 * 86_400);
        let expires = expires.map(|at| {
            let left = at
                .duration_since(std::time::SystemTime::now())
                .unwrap_or(Duration::ZERO);
            now + left.min(year)
        });
        Liveness {
            message: now,
            heard: now,
            ping: now + PING_INTERVAL,
            idle: idle.min(year),
            expires,
        }
    }

    /// The next instant something is due.
    fn due(&self) -> Instant {
        let due = self
            .ping
            .min(self.message + self.idle)
            .min(self.heard + PEER_PATIENCE);
        self.expires.map_or(due, |at| due.min(at))
    }

    /// A frame rendered from `started` to `now`. No ping goes out while one
    /// renders (the timer waits for it), so the peer could not be heard
    /// meanwhile: that time does not count as its silence (a render longer
    /// than [`PEER_PATIENCE`] would otherwise close a live session). A ping
    /// that fell due goes out at once.
    fn after_render(&mut self, started: Instant, now: Instant) {
        self.heard = (self.heard + now.saturating_duration_since(started)).min(now);
    }

    fn on_received(&mut self, now: Instant, message: &Message) {
        self.heard = now;
        if matches!(message, Message::Text(_)) {
            self.message = now;
        }
    }
}

const PING_INTERVAL: Duration = Duration::from_secs(protocol::PING_INTERVAL);
const PEER_PATIENCE: Duration = Duration::from_secs(protocol::PEER_PATIENCE);

/// Runs one session on a socket's halves until the client closes it, it
/// breaks, or the server shuts down; `place` (the session's place under the
/// cap) is freed as it ends.
pub(super) async fn run<S, R, E>(
    mut sink: S,
    mut stream: R,
    state: &AppState,
    place: Place,
    caller: Caller,
) where
    S: Sink<Message> + Unpin,
    R: Stream<Item = Result<Message, E>> + Unpin,
    E: std::fmt::Display,
{
    let address = place.address();
    let event = |name, outcome| Audited::new(name, Some(&caller.principal), Some(address), outcome);
    if sink
        .send(Message::Text(hello(state, &caller.datasets).into()))
        .await
        .is_err()
    {
        return;
    }
    state.metrics.session_opened();
    state.audit(&event("session-open", Outcome::Success));
    let mut session = Session::new(caller.datasets.clone(), state.stream);
    let end = drive(&mut sink, &mut stream, &mut session, state, &caller, &place).await;
    // Freed before the close handshake completes, so a client that has seen
    // it can open another session at once.
    drop(place);
    state.audit(&event("session-close", Outcome::Success).detail(end.reason()));
    match end {
        // Sends the close reply tungstenite has queued.
        End::Client => {
            let _ = sink.close().await;
        }
        End::Shutdown => {
            let close = (close_code::AWAY, "the server is shutting down".to_owned());
            closing(&mut sink, &mut stream, close).await;
        }
        End::Idle => {
            let reason = format!(
                "idle: no message for {} s; reconnect to go on",
                state.stream.session_idle_s
            );
            closing(&mut sink, &mut stream, (protocol::CLOSE_IDLE, reason)).await;
        }
        End::Broken(code, reason) => closing(&mut sink, &mut stream, (code, reason)).await,
        End::Expired => {
            let reason = "the access token expired; reconnect with a fresh one".to_owned();
            closing(&mut sink, &mut stream, (protocol::CLOSE_EXPIRED, reason)).await;
        }
        End::Gone | End::Silent => {}
    }
}

/// The first message: protocol version, datasets and stream settings.
fn hello(state: &AppState, datasets: &[Dataset]) -> String {
    serde_json::json!({
        "type": "hello",
        "protocol": protocol::PROTOCOL,
        "datasets": datasets.iter().map(Dataset::info).collect::<Vec<_>>(),
        "renderer": state.renderer.describe(),
        "settings": state.stream,
        "notice": state.notice.as_deref(),
    })
    .to_string()
}

/// The session's loop: asks it what to do, does it, waits for the next event.
async fn drive<S, R, E>(
    sink: &mut S,
    stream: &mut R,
    session: &mut Session,
    state: &AppState,
    caller: &Caller,
    place: &Place,
) -> End
where
    S: Sink<Message> + Unpin,
    R: Stream<Item = Result<Message, E>> + Unpin,
    E: std::fmt::Display,
{
    let mut job: Option<Job> = None;
    // When the render in `job` started.
    let mut job_started = Instant::now();
    let idle = Duration::from_secs(state.stream.session_idle_s);
    let mut liveness = Liveness::new(Instant::now(), idle, caller.principal.expires);
    // The dataset last recorded as viewed in the audit trail.
    let mut viewed: Option<String> = None;
    loop {
        let mut blocks = None;
        let still_at = match session.next_action(Instant::now()) {
            Action::Render(render) => {
                if viewed.as_deref() != Some(render.dataset.id.as_str()) {
                    viewed = Some(render.dataset.id.clone());
                    let line = Audited::new(
                        "view",
                        Some(&caller.principal),
                        Some(place.address()),
                        Outcome::Success,
                    )
                    .dataset(&render.dataset.id);
                    state.audit(&line);
                }
                job = Some(render_job(state, place.client().clone(), *render));
                job_started = Instant::now();
                continue;
            }
            Action::WaitForBlocks { dataset, seen } => {
                blocks = Some((dataset, seen));
                None
            }
            Action::Send(reply) => {
                if send_reply(sink, &reply).await.is_err() {
                    return End::Gone;
                }
                continue;
            }
            Action::Close => return End::Shutdown,
            Action::WaitUntil(at) => Some(at),
            Action::WaitForInput => None,
        };
        let event = tokio::select! {
            biased;
            () = state.shutdown.cancelled() => Event::Shutdown,
            () = state.draining.cancelled(), if !session.is_draining() => Event::Drain,
            done = rendered(&mut job), if job.is_some() => Event::Rendered(done),
            incoming = stream.next() => match incoming {
                Some(Ok(message)) => Event::Received(message),
                Some(Err(e)) => Event::Broken(e.to_string()),
                None => Event::Gone,
            },
            () = sleep_until(still_at), if still_at.is_some() => Event::Still,
            () = settle(blocks.as_ref()), if blocks.is_some() => Event::BlocksArrived,
            // Not while a frame renders: nothing is due that cannot wait
            // for it, and tests on tokio's paused clock would race ahead.
            () = tokio::time::sleep_until(liveness.due()), if job.is_none() => Event::Timer,
        };
        let now = Instant::now();
        match &event {
            Event::Received(message) => liveness.on_received(now, message),
            Event::Rendered(_) => liveness.after_render(job_started, now),
            Event::Timer => {
                if liveness.expires.is_some_and(|at| now >= at) {
                    return End::Expired;
                }
                if now >= liveness.heard + PEER_PATIENCE {
                    return End::Silent;
                }
                if now >= liveness.message + liveness.idle {
                    return End::Idle;
                }
                if now >= liveness.ping {
                    liveness.ping = now + PING_INTERVAL;
                    if sink.send(Message::Ping(Vec::new().into())).await.is_err() {
                        return End::Gone;
                    }
                }
                continue;
            }
            _ => {}
        }
        if matches!(event, Event::Received(Message::Text(_))) {
            // Datasets added (a study opened or received) or removed since:
            // a view message may name any the caller may see now.
            session.offer(state.visible(&caller.principal));
        }
        if let Some(end) = handle(event, sink, session, state).await {
            return end;
        }
    }
}

/// Feeds `event` to the session and sends what it gives; how the session
/// ended, if it did.
async fn handle<S>(
    event: Event,
    sink: &mut S,
    session: &mut Session,
    state: &AppState,
) -> Option<End>
where
    S: Sink<Message> + Unpin,
{
    let reply = match event {
        Event::Shutdown => {
            session.shut_down();
            None
        }
        Event::Drain => {
            session.drain();
            None
        }
        Event::Still | Event::Received(Message::Ping(_) | Message::Pong(_)) => None,
        Event::Gone => return Some(End::Gone),
        Event::Timer => None,
        Event::Broken(error) => return Some(broken(&error)),
        Event::Received(Message::Close(_)) => return Some(End::Client),
        Event::Received(Message::Text(text)) => {
            match protocol::parse_client_message(text.as_str()) {
                Ok(ClientMessage::Probe { id, at }) => Some(probe(session, id, at).await),
                Ok(ClientMessage::Pick { id, x, y }) => Some(pick(session, id, x, y).await),
                Ok(message) => session.on_message(Instant::now(), message),
                Err(refusal) => Some(Reply::error(refusal.id, refusal.message)),
            }
        }
        Event::Received(Message::Binary(_)) => {
            Some(Reply::error(None, "binary message: expected JSON text"))
        }
        Event::Rendered(Ok(frame)) => {
            if let Some(reply) = frame.camera.and_then(|c| session.on_fitted(c))
                && send_reply(sink, &reply).await.is_err()
            {
                return Some(End::Gone);
            }
            if let Some(reply) = &frame.slice
                && send_reply(sink, reply).await.is_err()
            {
                return Some(End::Gone);
            }
            if sink
                .send(Message::Binary(frame.bytes.into()))
                .await
                .is_err()
            {
                return Some(End::Gone);
            }
            let loading = (frame.header.pending_blocks > 0).then_some(frame.arrivals);
            session.on_frame_sent(frame.header.converged, loading);
            record_frame(state, &frame.header);
            None
        }
        Event::BlocksArrived => {
            session.on_blocks_arrived();
            None
        }
        Event::Rendered(Err(message)) => Some(session.on_render_failed(message)),
    };
    match reply {
        Some(reply) if send_reply(sink, &reply).await.is_err() => Some(End::Gone),
        _ => None,
    }
}

/// Answers probe `id` of model point `at`: the voxel there, read off the
/// loop's thread (a chunk not in memory is read now).
async fn probe(session: &Session, id: u32, at: [f32; 3]) -> Reply {
    let dataset = match session.probe_target() {
        Ok(dataset) => dataset,
        Err(e) => return Reply::error(Some(id), e.to_string()),
    };
    let unit = dataset.store.meta().unit.clone();
    let cache = dataset.cache.clone();
    let read = tokio::task::spawn_blocking(move || shaders::slice::probe(&cache, at)).await;
    match read {
        Ok(Ok(voxel)) => Reply::Probe { id, voxel, unit },
        Ok(Err(e)) => Reply::error(Some(id), format!("probe of '{}': {e}", dataset.id)),
        Err(e) => Reply::error(Some(id), format!("the probe failed: {e}")),
    }
}

/// Answers pick `id` at CSS pixel (`x`, `y`) of the 3D view: the first
/// point along its ray where the view turns opaque, read off the loop's
/// thread.
async fn pick(session: &Session, id: u32, x: f32, y: f32) -> Reply {
    let (dataset, frame, tf) = match session.pick_target() {
        Ok(target) => target,
        Err(e) => return Reply::error(Some(id), e.to_string()),
    };
    let cache = dataset.cache.clone();
    let read = tokio::task::spawn_blocking(move || {
        let ray = shaders::slice::PickRay {
            camera: &frame.camera,
            width: frame.width,
            height: frame.height,
            x,
            y,
            clip: frame.clip,
        };
        shaders::slice::pick(&cache, &ray, &tf)
    })
    .await;
    match read {
        Ok(Ok(at)) => Reply::Pick { id, at },
        Ok(Err(e)) => Reply::error(Some(id), format!("pick in '{}': {e}", dataset.id)),
        Err(e) => Reply::error(Some(id), format!("the pick failed: {e}")),
    }
}

async fn send_reply<S: Sink<Message> + Unpin>(sink: &mut S, reply: &Reply) -> Result<(), S::Error> {
    sink.send(Message::Text(reply.to_json().into())).await
}

/// Until blocks of `dataset` have arrived since `seen` (see
/// [`Dataset::settle`]); forever for `None`.
async fn settle(blocks: Option<&(Dataset, u64)>) {
    match blocks {
        Some((dataset, seen)) => {
            dataset.settle(*seen, BLOCKS_GATHER, BLOCKS_PATIENCE).await;
        }
        None => std::future::pending().await,
    }
}

/// The frame of `job` when it is done; pending while there is none. The
/// job stays in place when the wait is cancelled, and goes when it is done.
async fn rendered(job: &mut Option<Job>) -> Result<Encoded, String> {
    let Some(running) = job.as_mut() else {
        return std::future::pending().await;
    };
    let done = running.await;
    *job = None;
    done
}

/// Sleeps until `at`; forever for `None`.
async fn sleep_until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// How a session whose socket failed with `error` ends: a message too long
/// is closed with 1009 (too big), any other failure with 1002 (protocol
/// error), each with the reason (at most 120 bytes, as a close allows).
fn broken(error: &str) -> End {
    // The socket's errors are known only by their text here (the loop is
    // generic over the stream); tungstenite's for a message over the limit
    // says "Space limit exceeded".
    let code = if error.contains("Space limit exceeded") {
        close_code::SIZE
    } else {
        close_code::PROTOCOL
    };
    let mut reason = String::new();
    for c in error.chars() {
        if reason.len() + c.len_utf8() > 120 {
            break;
        }
        reason.push(c);
    }
    End::Broken(code, reason)
}

/// Closes the session with `close` (code and reason) and waits, a while, for
/// the client's close: dropping a connection with its messages unread would
/// reset it, and the client might never read the close.
async fn closing<S, R, E>(sink: &mut S, stream: &mut R, close: (u16, String))
where
    S: Sink<Message> + Unpin,
    R: Stream<Item = Result<Message, E>> + Unpin,
{
    let (code, reason) = close;
    let close = CloseFrame {
        code,
        reason: reason.into(),
    };
    if sink.send(Message::Close(Some(close))).await.is_err() {
        return;
    }
    let closed = async {
        while let Some(Ok(message)) = stream.next().await {
            if matches!(message, Message::Close(_)) {
                break;
            }
        }
    };
    if tokio::time::timeout(CLOSE_PATIENCE, closed).await.is_err() {
        tracing::debug!("a client did not answer the close in {CLOSE_PATIENCE:?}");
    }
}

/// Counts a sent frame in the metrics.
fn record_frame(state: &AppState, header: &FrameHeader) {
    let (quality, format) = match header.encoding {
        Encoding::Jpeg => (metrics::Quality::Interactive, metrics::Format::Jpeg),
        Encoding::Png => (metrics::Quality::Full, metrics::Format::Png),
        Encoding::Webp => (metrics::Quality::Full, metrics::Format::Webp),
    };
    state.metrics.frame(
        metrics::Source::Stream,
        quality,
        format,
        metrics::FrameTimes {
            render_ms: f64::from(header.render_ms),
            queue_ms: f64::from(header.queue_ms),
            encode_ms: f64::from(header.encode_ms),
        },
    );
}

/// Renders and encodes one frame for `client`.
fn render_job(state: &AppState, client: Client, render: Render) -> Job {
    let renderer = state.renderer.clone();
    let jpeg_quality = state.stream.jpeg_quality;
    let lossless = state.stream.lossless;
    let Render {
        quality,
        dataset,
        pane,
        request,
        slice,
        frame_id,
        message_id,
    } = render;
    Box::pin(async move {
        let rendered = match slice {
            None => renderer.render_waiting(&client, &dataset, request).await,
            Some((slice, window)) => {
                renderer
                    .render_slice_waiting(&client, &dataset, slice, window)
                    .await
            }
        }
        .map_err(|e| e.logged().to_string())?;
        let slice = rendered
            .slice
            .map(|(placement, window)| Reply::slice(pane, frame_id, placement, window));
        let converged = rendered.stats.converged();
        let light = rendered.stats.light().copied();
        let frame = rendered.frame;
        let (width, height) = (frame.width, frame.height);
        let start = std::time::Instant::now();
        let (encoding, image) = tokio::task::spawn_blocking(move || match quality {
            Quality::Interactive => encode::jpeg(&frame, jpeg_quality).map(|b| (Encoding::Jpeg, b)),
            Quality::Full => match lossless {
                encode::Lossless::Png => encode::png(&frame).map(|b| (Encoding::Png, b)),
                encode::Lossless::Webp => encode::webp(&frame).map(|b| (Encoding::Webp, b)),
            },
        })
        .await
        .map_err(|e| format!("the encoder task failed: {e}"))?
        .map_err(|e| format!("encoding the frame failed: {e}"))?;
        let header = FrameHeader {
            encoding,
            lossless: quality == Quality::Full,
            converged: quality == Quality::Full && converged,
            memory_limited: rendered.stats.memory_limited,
            pending_blocks: u16::try_from(rendered.stats.pending_blocks).unwrap_or(u16::MAX),
            width: width as u16,
            height: height as u16,
            refined: light.map_or(0, |l| l.refined as u16),
            directions: light.map_or(0, |l| l.directions as u16),
            frame_id,
            message_id,
            render_ms: rendered.render_ms as f32,
            encode_ms: (start.elapsed().as_secs_f64() * 1e3) as f32,
            reduction: rendered.stats.reduction as f32,
            queue_ms: rendered.queue_ms as f32,
            empty_share: rendered.stats.empty_share as f32,
            pane,
        };
        let mut bytes = Vec::with_capacity(protocol::HEADER_LEN + image.len());
        bytes.extend_from_slice(&header.to_bytes());
        bytes.extend_from_slice(&image);
        Ok(Encoded {
            header,
            bytes,
            arrivals: rendered.arrivals,
            camera: rendered.stats.camera,
            slice,
        })
    })
}

#[cfg(test)]
mod tests {
    use std::convert::Infallible;
    use std::net::IpAddr;

    use tokio::sync::mpsc;

    use super::*;
    use crate::RenderService;
    use crate::stream::StreamSettings;

    /// A session on channels: what the test sends, and what the loop sends.
    struct Channels {
        to_session: mpsc::Sender<Message>,
        from_session: mpsc::Receiver<Message>,
    }

    impl Channels {
        async fn send(&self, text: serde_json::Value) {
            let text = Message::Text(text.to_string().into());
            self.to_session.send(text).await.expect("the loop reads");
        }

        async fn next(&mut self) -> Message {
            let patience = Duration::from_secs(60);
            tokio::time::timeout(patience, self.next_untimed())
                .await
                .expect("a message within the patience")
        }

        /// The next message but pings, which are answered as a WebSocket
        /// client does; without a timeout (see [`Watchdog`]).
        async fn next_untimed(&mut self) -> Message {
            loop {
                match self.from_session.recv().await.expect("the loop is running") {
                    Message::Ping(payload) => {
                        let pong = Message::Pong(payload);
                        self.to_session.send(pong).await.expect("the loop reads");
                    }
                    message => return message,
                }
            }
        }

        async fn next_json(&mut self) -> serde_json::Value {
            match self.next().await {
                Message::Text(text) => serde_json::from_str(text.as_str()).expect("JSON"),
                other => panic!("expected JSON text, got {other:?}"),
            }
        }

        /// The next JSON message, acknowledging the frames that come
        /// before it (a view still refining while the session answers).
        async fn next_json_after_frames(&mut self) -> serde_json::Value {
            loop {
                match self.next().await {
                    Message::Text(text) => {
                        return serde_json::from_str(text.as_str()).expect("JSON");
                    }
                    Message::Binary(bytes) => {
                        let header = FrameHeader::parse(&bytes).expect("a header");
                        self.send(serde_json::json!({"type": "ack", "frame": header.frame_id}))
                            .await;
                    }
                    other => panic!("expected JSON text or a frame, got {other:?}"),
                }
            }
        }
    }

    /// Runs the loop of a new session of `state` on channels.
    fn start(state: &AppState) -> (Channels, tokio::task::JoinHandle<()>) {
        let (to_session, from_test) = mpsc::channel::<Message>(16);
        let (to_test, from_session) = mpsc::channel::<Message>(16);
        let sink = Box::pin(futures_util::sink::unfold(
            to_test,
            |tx, message| async move { tx.send(message).await.map(|()| tx) },
        ));
        let stream = Box::pin(futures_util::stream::unfold(
            from_test,
            |mut rx| async move { rx.recv().await.map(|m| (Ok::<_, Infallible>(m), rx)) },
        ));
        let place = state
            .sessions
            .try_open(IpAddr::from([127, 0, 0, 1]).into(), [127, 0, 0, 1].into())
            .expect("a place");
        let state = state.clone();
        let caller = Caller {
            principal: crate::auth::Principal::anonymous(),
            datasets: state.datasets.snapshot(),
        };
        let running = tokio::spawn(async move { run(sink, stream, &state, place, caller).await });
        let channels = Channels {
            to_session,
            from_session,
        };
        (channels, running)
    }

    /// Aborts the test process if it is still running after a minute of real
    /// time: a guard for tests on the paused clock, which cannot time out on
    /// tokio's clock (it jumps to any pending timer while a frame renders).
    struct Watchdog {
        _done: std::sync::mpsc::Sender<()>,
    }

    impl Watchdog {
        #[expect(
            clippy::print_stderr,
            reason = "the test's last words before it aborts"
        )]
        fn new(test: &'static str) -> Watchdog {
            let (done, wait) = std::sync::mpsc::channel();
            std::thread::spawn(move || {
                let patience = Duration::from_secs(60);
                if let Err(std::sync::mpsc::RecvTimeoutError::Timeout) = wait.recv_timeout(patience)
                {
                    eprintln!("{test}: no progress within {patience:?}");
                    std::process::abort();
                }
            });
            Watchdog { _done: done }
        }
    }

    #[test]
    fn a_render_longer_than_the_peer_s_patience_is_not_its_silence() {
        let start = Instant::now();
        let mut liveness = Liveness::new(start, Duration::from_secs(3600), None);
        // Last heard when a frame started, which rendered for 90 s: no ping
        // could go out meanwhile.
        let now = start + PEER_PATIENCE + Duration::from_secs(30);
        liveness.after_render(start, now);
        assert!(
            now < liveness.heard + PEER_PATIENCE,
            "a live session would close as silent after a long render"
        );
        // The ping that fell due during the render goes out at once.
        assert!(liveness.due() <= now);
        // Silence after the render still counts.
        assert!(now + PEER_PATIENCE >= liveness.heard + PEER_PATIENCE);
        // A quick render moves the silence clock on by its length only.
        let mut quick = Liveness::new(start, Duration::from_secs(3600), None);
        quick.after_render(start, start + Duration::from_millis(100));
        assert_eq!(quick.heard, start + Duration::from_millis(100));
    }

    #[tokio::test(start_paused = true)]
    async fn the_full_frame_follows_idle_ms_of_tokio_s_clock() {
        let test = "the_full_frame_follows_idle_ms_of_tokio_s_clock";
        let Some(gpu) = voxserve_tests::gpu_or_skip(test) else {
            return;
        };
        let _watchdog = Watchdog::new(test);
        let renderer = RenderService::start(shaders::Backend::Gpu(gpu.clone()), 64 << 20, 1)
            .expect("render worker");
        let phantom = Dataset::phantom(16, 16 << 20).expect("phantom");
        // An hour of stillness before the full frame: on the paused clock the
        // loop's timer fires as soon as nothing else is left to do.
        let idle = Duration::from_secs(3600);
        let settings = StreamSettings {
            idle_ms: idle.as_millis() as u64,
            // Not closed for want of messages while it waits; pings are
            // answered (`next_untimed`), so the peer is never silent.
            session_idle_s: 2 * idle.as_secs(),
            ..StreamSettings::default()
        };
        let state = AppState::new(vec![phantom], renderer, settings);
        let (mut client, running) = start(&state);
        let Message::Text(hello) = client.next_untimed().await else {
            panic!("expected the hello");
        };
        assert!(hello.as_str().contains("\"hello\""), "{hello}");
        let changed = Instant::now();
        client
            .send(serde_json::json!({"type": "view", "id": 1, "set": {"w": 20, "h": 10}}))
            .await;
        let mut headers = Vec::new();
        while headers.len() < 2 {
            let bytes = match client.next_untimed().await {
                Message::Binary(bytes) => bytes,
                other => panic!("expected a frame, got {other:?}"),
            };
            let header = FrameHeader::parse(&bytes).expect("a header");
            headers.push((header, changed.elapsed()));
            if headers.len() == 1 {
                // Acknowledged, the session waits for the view to be still.
                client
                    .send(serde_json::json!({"type": "ack", "frame": header.frame_id}))
                    .await;
                client
                    .send(serde_json::json!({"type": "status", "id": 2}))
                    .await;
                let Message::Text(status) = client.next_untimed().await else {
                    panic!("expected the status");
                };
                assert!(
                    status.as_str().contains("\"waiting\":\"still\""),
                    "{status}"
                );
            }
        }
        let [(interactive, at_interactive), (full, at_full)] = [headers[0], headers[1]];
        assert!(!interactive.lossless, "{interactive:?}");
        assert!(at_interactive < idle, "the interactive frame came at once");
        assert!(full.lossless && full.message_id == 1, "{full:?}");
        assert!(
            at_full >= idle,
            "the full frame waited {at_full:?} of tokio's clock"
        );
        state.shutdown.cancel();
        client
            .to_session
            .send(Message::Close(None))
            .await
            .expect("the loop reads");
        running.await.expect("the loop ends");
    }

    #[tokio::test]
    async fn the_loop_runs_on_channels_answers_in_order_and_closes_on_shutdown() {
        let test = "the_loop_runs_on_channels_answers_in_order_and_closes_on_shutdown";
        let Some(gpu) = voxserve_tests::gpu_or_skip(test) else {
            return;
        };
        let renderer = RenderService::start(shaders::Backend::Gpu(gpu.clone()), 64 << 20, 1)
            .expect("render worker");
        let phantom = Dataset::phantom(16, 16 << 20).expect("phantom");
        let state = AppState::new(vec![phantom], renderer, StreamSettings::default());
        let (mut client, running) = start(&state);
        assert_eq!(client.next_json().await["type"], "hello");
        client
            .send(serde_json::json!({"type": "view", "id": 1, "set": {"w": 20, "h": 10}}))
            .await;
        let last = loop {
            let Message::Binary(bytes) = client.next().await else {
                panic!("expected a frame");
            };
            let header = FrameHeader::parse(&bytes).expect("a header");
            client
                .send(serde_json::json!({"type": "ack", "frame": header.frame_id}))
                .await;
            if header.converged {
                break header;
            }
        };
        assert_eq!((last.width, last.height, last.message_id), (20, 10, 1));
        client
            .send(serde_json::json!({"type": "status", "id": 7}))
            .await;
        let status = client.next_json().await;
        assert_eq!(
            status,
            serde_json::json!({"type": "status", "id": 7, "view_id": 1, "sent": last.frame_id,
                "acked": last.frame_id, "rendering": false, "waiting": "message", "converged": true})
        );
        assert_eq!(state.sessions.open(), 1);
        state.shutdown.cancel();
        match client.next().await {
            Message::Close(Some(close)) => assert_eq!(close.code, close_code::AWAY),
            other => panic!("expected a close, got {other:?}"),
        }
        // The place is free before the client's close reply.
        assert_eq!(state.sessions.open(), 0);
        client
            .to_session
            .send(Message::Close(None))
            .await
            .expect("the loop reads");
        running.await.expect("the loop ends");
    }

    #[tokio::test]
    async fn a_slice_view_comes_placed_probes_read_voxels_and_picks_find_the_surface() {
        let renderer =
            RenderService::start(shaders::Backend::Cpu, 64 << 20, 1).expect("render worker");
        let phantom = Dataset::phantom(32, 16 << 20).expect("phantom");
        let volume = blocks::phantom::head(32).expect("phantom voxels");
        let state = AppState::new(vec![phantom], renderer, StreamSettings::default());
        let (mut client, running) = start(&state);
        assert_eq!(client.next_json().await["type"], "hello");
        client
            .send(serde_json::json!({"type": "layout", "panes": ["3d", "coronal"]}))
            .await;
        client
            .send(serde_json::json!({"type": "view", "id": 1, "set": {"w": 32, "h": 32}}))
            .await;
        client
            .send(
                serde_json::json!({"type": "view", "id": 2, "pane": "coronal",
                "set": {"w": 40, "h": 30, "cy": 5}}),
            )
            .await;
        // Frames of both views until the coronal one is converged; its
        // placement comes just before it.
        let mut placement = None;
        loop {
            match client.next().await {
                Message::Text(text) => {
                    let reply: serde_json::Value =
                        serde_json::from_str(text.as_str()).expect("JSON");
                    assert_eq!(reply["type"], "slice", "{reply}");
                    placement = Some(reply);
                }
                Message::Binary(bytes) => {
                    let header = FrameHeader::parse(&bytes).expect("a header");
                    client
                        .send(serde_json::json!({"type": "ack", "frame": header.frame_id}))
                        .await;
                    if header.pane == protocol::Pane::Volume {
                        continue;
                    }
                    let placed = placement.take().expect("a placement before the slice");
                    assert_eq!(placed["frame"], header.frame_id);
                    assert_eq!(placed["pane"], "coronal");
                    assert_eq!(
                        (header.width, header.height, header.message_id),
                        (40, 30, 2)
                    );
                    assert_eq!(
                        placed["placement"]["normal"],
                        serde_json::json!([0.0, -1.0, 0.0])
                    );
                    if header.converged {
                        break;
                    }
                }
                other => panic!("unexpected {other:?}"),
            }
        }
        // The voxel at the centre of voxel (3, 20, 9), and nothing outside.
        let s = volume.geometry.spacing[0] as f32;
        let at = |i: u32| (i as f32 - 15.5) * s;
        client
            .send(serde_json::json!({"type": "probe", "id": 3, "at": [at(3), at(20), at(9)]}))
            .await;
        let probe = client.next_json_after_frames().await;
        assert_eq!(
            probe["voxel"]["index"],
            serde_json::json!([3, 20, 9]),
            "{probe}"
        );
        assert_eq!(probe["voxel"]["value"], volume.physical_at(3, 20, 9));
        assert_eq!(probe["unit"], "HU");
        client
            .send(serde_json::json!({"type": "probe", "id": 4, "at": [0, 0, 1000]}))
            .await;
        assert_eq!(
            client.next_json_after_frames().await["voxel"],
            serde_json::Value::Null
        );
        client
            .send(serde_json::json!({"type": "probe", "id": 5, "at": [0, 0]}))
            .await;
        let refused = client.next_json_after_frames().await;
        assert_eq!(
            (&refused["type"], &refused["id"]),
            (&"error".into(), &5.into())
        );
        // The 3D view's middle, from the front: the skull in front of the centre.
        client
            .send(serde_json::json!({"type": "pick", "id": 6, "xy": [16, 16]}))
            .await;
        let pick = client.next_json_after_frames().await;
        assert_eq!(
            (&pick["type"], &pick["id"]),
            (&"pick".into(), &6.into()),
            "{pick}"
        );
        let y = pick["at"][1].as_f64().expect("a point");
        assert!(y < 0.0, "{pick}");
        client
            .send(serde_json::json!({"type": "pick", "id": 7, "xy": [0, 0]}))
            .await;
        assert_eq!(
            client.next_json_after_frames().await["at"],
            serde_json::Value::Null
        );
        state.shutdown.cancel();
        running.await.expect("the loop ends");
    }
}
