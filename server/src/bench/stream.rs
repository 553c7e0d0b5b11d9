//! `voxserve bench stream`: view sessions measured on loopback, against a
//! server in this process (the real router, render worker and sessions).
//!
//! - `stream-latency`, per image size and format: the time from sending a
//!   `view` message (a camera move) to receiving the frame that reflects it,
//!   one event at a time, p50 and p95, beside the render, queue and encode
//!   milliseconds the frames' headers report, and the frames' size in bytes.
//!   JPEG frames come from a server that never counts the view as still,
//!   lossless ones (PNG, then WebP) from a server that counts it still at once;
//!   all render at the full size (no interactive scaling or reduction), so the
//!   formats show the same pixels.
//! - `stream-sessions`, per number of concurrent sessions: every session moves
//!   its camera again as soon as its frame arrives, for `--seconds`; frames per
//!   second in all and per session (slowest ÷ fastest shows fairness), errors,
//!   and the process's resident memory before, ten times during, and after.
//! - `stream-hostile`: `--hostile-sessions` sessions (each from a loopback
//!   address of its own, as viewers on different machines) measured alone and
//!   beside a hostile client from another address (a session asking for 4096²
//!   frames that never acknowledges, and `GET /api/render` of 4096² frames
//!   kept waiting as many as it may), twice each, interleaved: their frame
//!   rates and the ratio beside ÷ alone.
//! - `stream-cold-change`: one session (A) changes the transfer function of a
//!   brick store on disk to one whose blocks are not in memory while another
//!   session (B) moves its camera on the benchmark's dataset; B's
//!   event-to-frame latency while A's blocks are read, against B's latency
//!   alone, in frame times; A's time to its first frame and to the refined
//!   one, and the chunks the render worker read itself (0: reads are off the
//!   render thread); then the change back and the same change again, both
//!   warm (their blocks in memory), for comparison.

use std::time::{Duration, Instant};

use anyhow::Context as _;
use futures_util::{SinkExt, StreamExt};
use tokio::net::TcpListener;
use tokio_tungstenite::tungstenite::Message;

use super::args::BenchStreamArgs;
use super::rss_mib;
use server::commands::{load_dataset, say};
use server::encode::Lossless;
use server::protocol::FrameHeader;
use server::stream::StreamSettings;
use server::{AppState, Dataset, RenderService};

pub(super) type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// How long one frame may take before the benchmark gives up.
const PATIENCE: Duration = Duration::from_secs(600);

/// `voxserve bench stream`; see the module docs.
pub fn stream(args: &BenchStreamArgs) -> anyhow::Result<()> {
    tokio::runtime::Runtime::new()?.block_on(run(args))
}

/// A server on 127.0.0.1 port 0; dropping the sender stops it.
pub(super) async fn start_server(
    datasets: Vec<Dataset>,
    renderer: RenderService,
    settings: StreamSettings,
) -> anyhow::Result<(String, tokio::sync::oneshot::Sender<()>)> {
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    let url = format!("ws://{}/api/stream", listener.local_addr()?);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let state = AppState::new(datasets, renderer, settings);
    tokio::spawn(async move {
        let shutdown = async {
            let _ = stopped.await;
        };
        if let Err(e) = server::run(listener, state, shutdown).await {
            tracing::error!("benchmark server failed: {e}");
        }
    });
    Ok((url, stop))
}

pub(super) async fn connect(url: &str) -> anyhow::Result<Socket> {
    // No Nagle on the viewer's side either, as browsers do.
    let (mut socket, _) = tokio_tungstenite::connect_async_with_config(url, None, true)
        .await
        .with_context(|| format!("connecting to {url}"))?;
    // The hello.
    next_frame(&mut socket, None).await?;
    Ok(socket)
}

/// The loopback address of viewer `n` (127.0.0.10 on): each a client of its
/// own, as viewers on different machines are.
fn viewer_address(n: u32) -> std::net::IpAddr {
    let [_, _, hi, lo] = (10 + n).to_be_bytes();
    std::net::IpAddr::from([127, 0, hi, lo])
}

/// A TCP connection to `addr` from the loopback address `from`.
async fn tcp_from(from: std::net::IpAddr, addr: &str) -> anyhow::Result<tokio::net::TcpStream> {
    let socket = tokio::net::TcpSocket::new_v4()?;
    socket.bind(std::net::SocketAddr::new(from, 0))?;
    let to: std::net::SocketAddr = addr.parse()?;
    socket
        .connect(to)
        .await
        .with_context(|| format!("connecting to {to} from {from}"))
}

/// [`connect`] from the loopback address `from`.
async fn connect_from(url: &str, from: std::net::IpAddr) -> anyhow::Result<Socket> {
    let host = url
        .trim_start_matches("ws://")
        .split('/')
        .next()
        .unwrap_or_default();
    let stream = tcp_from(from, host).await?;
    let (mut socket, _) =
        tokio_tungstenite::client_async(url, tokio_tungstenite::MaybeTlsStream::Plain(stream))
            .await
            .with_context(|| format!("connecting to {url} from {from}"))?;
    next_frame(&mut socket, None).await?;
    Ok(socket)
}

/// Waits for the frame reflecting message `id` (any frame for `None`, which
/// also accepts the hello); acknowledges it.
pub(super) async fn next_frame(
    socket: &mut Socket,
    id: Option<u32>,
) -> anyhow::Result<Option<FrameHeader>> {
    Ok(next_frame_sized(socket, id)
        .await?
        .map(|(header, _)| header))
}

/// [`next_frame`] with the frame's size in bytes (header included).
pub(super) async fn next_frame_sized(
    socket: &mut Socket,
    id: Option<u32>,
) -> anyhow::Result<Option<(FrameHeader, usize)>> {
    loop {
        let message = tokio::time::timeout(PATIENCE, socket.next())
            .await
            .context("no frame within the patience")?
            .context("the server closed the session")??;
        match message {
            Message::Binary(bytes) => {
                let header = FrameHeader::parse(&bytes)?;
                let ack = serde_json::json!({"type": "ack", "frame": header.frame_id});
                socket.send(Message::Text(ack.to_string().into())).await?;
                if id.is_none_or(|id| header.message_id == id) {
                    return Ok(Some((header, bytes.len())));
                }
            }
            Message::Text(text) => {
                let value: serde_json::Value = serde_json::from_str(text.as_str())?;
                if value["type"] == "error" {
                    anyhow::bail!("the server refused a message: {}", value["message"]);
                }
                if id.is_none() {
                    return Ok(None);
                }
            }
            _ => {}
        }
    }
}

pub(super) async fn send_view(
    socket: &mut Socket,
    id: u32,
    set: serde_json::Value,
) -> anyhow::Result<()> {
    let view = serde_json::json!({"type": "view", "id": id, "set": set});
    socket.send(Message::Text(view.to_string().into())).await?;
    Ok(())
}

/// The `q` quantile (0..=1) of `values` (sorted in place).
pub(super) fn quantile(values: &mut [f64], q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    let i = ((values.len() as f64 * q).ceil() as usize).saturating_sub(1);
    values.get(i).copied().unwrap_or(f64::NAN)
}

/// Per format, a server in this process: latency lines per image size, and
/// on the JPEG server the frame rate per number of sessions.
async fn run(args: &BenchStreamArgs) -> anyhow::Result<()> {
    let dataset = load_dataset(&args.dataset, &args.data)?;
    let backend = args.renderer.backend()?;
    let adapter = backend.describe();
    // Two datasets resident: the cold-change measurement's two sessions.
    let renderer = RenderService::start(backend, args.data.gpu_budget_bytes(), 2)?;
    let full_size = StreamSettings {
        interactive_scale: 1.0,
        interactive_reduction: 1.0,
        // Every session comes from this process's one address.
        max_sessions: 4096,
        sessions_per_client: 4096,
        ..StreamSettings::default()
    };
    // JPEG from a server that never counts the view as still; lossless frames
    // (PNG, then WebP) from one that always does.
    for (format, idle_ms, lossless) in [
        ("jpeg", 3_600_000u64, Lossless::Png),
        ("png", 0, Lossless::Png),
        ("webp", 0, Lossless::Webp),
    ] {
        let settings = StreamSettings {
            idle_ms,
            lossless,
            ..full_size
        };
        let (url, stop) = start_server(vec![dataset.clone()], renderer.clone(), settings).await?;
        for &edge in &args.sizes {
            latency(&url, edge, format, args, &adapter, &dataset).await?;
        }
        if format == "jpeg" {
            for &n in &args.sessions {
                sessions(&url, n, args, &adapter, &dataset).await?;
            }
            if args.hostile_sessions > 0 {
                hostile(&url, args, &adapter, &dataset).await?;
            }
        }
        drop(stop);
    }
    cold_change(args, &adapter, renderer, dataset).await
}

/// A `stream-latency` line: `--events` camera moves on one session with
/// frames of `edge`² in `format`, each timed until its frame arrives.
async fn latency(
    url: &str,
    edge: u32,
    format: &str,
    args: &BenchStreamArgs,
    adapter: &str,
    dataset: &Dataset,
) -> anyhow::Result<()> {
    let mut socket = connect(url).await?;
    // The first frame selects and uploads blocks: not timed.
    send_view(&mut socket, 1, serde_json::json!({"w": edge, "h": edge})).await?;
    next_frame(&mut socket, Some(1)).await?;
    let mut id = 2;
    let mut m = camera_moves(&mut socket, &mut id, args.events, None).await?;
    // Before the quantiles sort the columns.
    let mut overhead: Vec<f64> = m
        .latency
        .iter()
        .zip(&m.render)
        .map(|(l, r)| l - r)
        .collect();
    say(&serde_json::json!({
        "bench": "stream-latency",
        "adapter": adapter,
        "dataset": dataset.name(),
        "format": format,
        "width": edge,
        "height": edge,
        "events": args.events,
        "latency_ms_p50": quantile(&mut m.latency, 0.5),
        "latency_ms_p95": quantile(&mut m.latency, 0.95),
        "latency_minus_render_ms_p50": quantile(&mut overhead, 0.5),
        "latency_minus_render_ms_p95": quantile(&mut overhead, 0.95),
        "render_ms_p50": quantile(&mut m.render, 0.5),
        "encode_ms_p50": quantile(&mut m.encode, 0.5),
        "encode_ms_p95": quantile(&mut m.encode, 0.95),
        "queue_ms_p50": quantile(&mut m.queue, 0.5),
        "pixels_per_frame": m.pixels / args.events.max(1) as usize,
        "frame_bytes_p50": quantile(&mut m.bytes, 0.5),
    })
    .to_string())
}

/// `--hostile-sessions` sessions measured as `stream-sessions` does, alone
/// and beside a hostile client (from an address of its own: a session asking
/// for 4096² frames that never acknowledges one, and `GET /api/render` of
/// 4096² frames kept waiting as many as it may, asked again when refused),
/// twice each, interleaved: the `stream-hostile` line.
async fn hostile(
    url: &str,
    args: &BenchStreamArgs,
    adapter: &str,
    dataset: &Dataset,
) -> anyhow::Result<()> {
    let n = args.hostile_sessions;
    let mut alone = Vec::new();
    let mut beside = Vec::new();
    let mut hostile_frames = 0u64;
    for _ in 0..2 {
        alone.push(session_rates(url, n, args).await?);
        let attacker = viewer_address(n + 100);
        let stop = tokio_util::sync::CancellationToken::new();
        let mut attack = Vec::new();
        {
            // Never acknowledged: the server sends one frame and waits.
            let mut socket = connect_from(url, attacker).await?;
            send_view(&mut socket, 1, serde_json::json!({"w": 4096, "h": 4096})).await?;
            let stop = stop.clone();
            attack.push(tokio::spawn(async move {
                stop.cancelled().await;
                drop(socket);
                0u64
            }));
        }
        let host = url
            .trim_start_matches("ws://")
            .split('/')
            .next()
            .unwrap_or_default()
            .to_owned();
        for _ in 0..3 {
            let (stop, host) = (stop.clone(), host.clone());
            attack.push(tokio::spawn(async move {
                let mut rendered = 0u64;
                let request = "GET /api/render?w=4096&h=4096 HTTP/1.1\r\nHost: localhost\r\n\
                               Connection: close\r\n\r\n";
                while !stop.is_cancelled() {
                    let Ok(mut stream) = tcp_from(attacker, &host).await else {
                        break;
                    };
                    if tokio::io::AsyncWriteExt::write_all(&mut stream, request.as_bytes())
                        .await
                        .is_err()
                    {
                        break;
                    }
                    let mut answer = Vec::new();
                    tokio::select! {
                        _ = stop.cancelled() => break,
                        read = tokio::io::AsyncReadExt::read_to_end(&mut stream, &mut answer) => {
                            if read.is_err() {
                                break;
                            }
                        }
                    }
                    if answer.starts_with(b"HTTP/1.1 200") {
                        rendered += 1;
                    } else {
                        tokio::time::sleep(Duration::from_millis(20)).await;
                    }
                }
                rendered
            }));
        }
        beside.push(session_rates(url, n, args).await?);
        stop.cancel();
        for task in attack {
            hostile_frames += task.await.unwrap_or(0);
        }
    }
    let mean = |runs: &[Rates]| runs.iter().map(|r| r.total).sum::<f64>() / runs.len() as f64;
    let min = |runs: &[Rates]| runs.iter().map(|r| r.slowest).fold(f64::INFINITY, f64::min);
    let errors: usize = alone.iter().chain(&beside).map(|r| r.errors.len()).sum();
    say(&serde_json::json!({
        "bench": "stream-hostile",
        "adapter": adapter,
        "dataset": dataset.name(),
        "format": "jpeg",
        "sessions": n,
        "width": args.session_size,
        "height": args.session_size,
        "seconds": args.seconds,
        "runs": 2,
        "frames_per_s_alone": alone.iter().map(|r| r.total).collect::<Vec<_>>(),
        "frames_per_s_beside_hostile": beside.iter().map(|r| r.total).collect::<Vec<_>>(),
        "beside_over_alone": mean(&beside) / mean(&alone),
        "per_session_fps_min_alone": min(&alone),
        "per_session_fps_min_beside_hostile": min(&beside),
        "hostile_4096_frames_rendered": hostile_frames,
        "errors": errors,
    })
    .to_string())
}

/// What `n` sessions moving their cameras as fast as frames come did over
/// `--seconds`.
struct Rates {
    total: f64,
    slowest: f64,
    fastest: f64,
    errors: Vec<String>,
}

/// `n` sessions, each from an address of its own, moving their cameras as
/// fast as frames come, for `--seconds`.
async fn session_rates(url: &str, n: u32, args: &BenchStreamArgs) -> anyhow::Result<Rates> {
    let edge = args.session_size;
    let run_for = Duration::from_secs_f32(args.seconds);
    let tasks: Vec<_> = (0..n)
        .map(|s| {
            let url = url.to_owned();
            tokio::spawn(async move {
                let mut socket = connect_from(&url, viewer_address(s)).await?;
                send_view(&mut socket, 1, serde_json::json!({"w": edge, "h": edge})).await?;
                next_frame(&mut socket, Some(1)).await?;
                let start = Instant::now();
                let mut frames = 0u32;
                let mut id = 1;
                while start.elapsed() < run_for {
                    id += 1;
                    let az = f64::from(s) * 40.0 + f64::from(id) * 5.0;
                    send_view(&mut socket, id, serde_json::json!({"az": az})).await?;
                    next_frame(&mut socket, Some(id)).await?;
                    frames += 1;
                }
                anyhow::Ok(f64::from(frames) / start.elapsed().as_secs_f64())
            })
        })
        .collect();
    let mut rates = Vec::new();
    let mut errors = Vec::new();
    for task in tasks {
        match task.await {
            Ok(Ok(rate)) => rates.push(rate),
            Ok(Err(e)) => errors.push(e.to_string()),
            Err(e) => errors.push(e.to_string()),
        }
    }
    Ok(Rates {
        total: rates.iter().sum(),
        slowest: rates.iter().copied().fold(f64::INFINITY, f64::min),
        fastest: rates.iter().copied().fold(0.0, f64::max),
        errors,
    })
}

/// `n` sessions moving their cameras as fast as frames come, for `--seconds`.
async fn sessions(
    url: &str,
    n: u32,
    args: &BenchStreamArgs,
    adapter: &str,
    dataset: &Dataset,
) -> anyhow::Result<()> {
    let edge = args.session_size;
    let rss_before = rss_mib();
    let run_for = Duration::from_secs_f32(args.seconds);
    // Resident memory ten times over the run: flat after warm-up, or growing.
    let sampler = tokio::spawn(async move {
        let mut samples = Vec::new();
        for _ in 0..10 {
            tokio::time::sleep(run_for / 10).await;
            samples.push(rss_mib());
        }
        samples
    });
    let rates = session_rates(url, n, args).await?;
    say(&serde_json::json!({
        "bench": "stream-sessions",
        "adapter": adapter,
        "dataset": dataset.name(),
        "format": "jpeg",
        "sessions": n,
        "width": edge,
        "height": edge,
        "seconds": args.seconds,
        "frames_per_s": rates.total,
        "per_session_fps_min": rates.slowest,
        "per_session_fps_max": rates.fastest,
        "slowest_over_fastest": rates.slowest / rates.fastest,
        "errors": rates.errors.len(),
        "first_error": rates.errors.first(),
        "rss_mib_before": rss_before,
        "rss_mib_after": rss_mib(),
        "rss_mib_during": sampler.await.unwrap_or_default(),
    })
    .to_string())?;
    Ok(())
}

/// The `stream-cold-change` lines; see the module docs.
async fn cold_change(
    args: &BenchStreamArgs,
    adapter: &str,
    renderer: RenderService,
    warm: Dataset,
) -> anyhow::Result<()> {
    let scratch = super::Scratch::new("stream")?;
    let volume = std::sync::Arc::new(blocks::phantom::head(args.cold_phantom)?);
    let path = scratch.0.join("cold.zarr");
    let mut source = blocks::ingest::MemorySource::new(volume, "cold phantom");
    blocks::store::ingest(&mut source, &path, &Default::default(), &mut |_| {})?;
    let cold = Dataset::load(&path, &Default::default(), args.data.cache_bytes())?;
    let (cold_id, cold_cache) = (cold.id.clone(), cold.cache.clone());
    let from = cold.default_preset();
    let to = blocks::Preset::ALL
        .into_iter()
        .find(|&p| p != from)
        .context("a second preset")?;
    let (url, stop) = start_server(
        vec![warm.clone(), cold],
        renderer,
        StreamSettings::default(),
    )
    .await?;
    let edge = args.session_size;
    let mut a = connect(&url).await?;
    let set = serde_json::json!({"w": edge, "h": edge, "dataset": cold_id, "preset": from.name()});
    send_view(&mut a, 1, set).await?;
    until_converged(&mut a, 1).await?;
    let mut b = connect(&url).await?;
    send_view(&mut b, 1, serde_json::json!({"w": edge, "h": edge})).await?;
    next_frame(&mut b, Some(1)).await?;
    let mut b_id = 2;
    let mut line = ColdChangeLine {
        args,
        adapter,
        warm: &warm,
        alone: camera_moves(&mut b, &mut b_id, args.events, None).await?,
    };
    // The cold change (its blocks not in memory), then back and again: the
    // same changes warm (their blocks in memory).
    for (id, preset, kind) in [(2, to, "cold"), (3, from, "warm"), (4, to, "warm")] {
        let reads_before = cold_cache.inline_reads();
        let (a_frames, during) =
            change_while_moving((&mut a, id, preset), (&mut b, &mut b_id)).await?;
        let reads = cold_cache.inline_reads() - reads_before;
        say(&line
            .json(kind, preset, &a_frames, during, reads)
            .to_string())?;
    }
    drop(stop);
    Ok(())
}

/// Session A switches to `preset` as message `id` while B moves its camera
/// (from message `b_id` on) until A's converged frame: A's frames (header,
/// milliseconds since the change) and B's moves meanwhile.
async fn change_while_moving(
    (a, id, preset): (&mut Socket, u32, blocks::Preset),
    (b, b_id): (&mut Socket, &mut u32),
) -> anyhow::Result<(Vec<(FrameHeader, f64)>, Moves)> {
    let (done_tx, done_rx) = tokio::sync::watch::channel(false);
    send_view(a, id, serde_json::json!({"preset": preset.name()})).await?;
    let a_side = async {
        let frames = until_converged(a, id).await;
        let _ = done_tx.send(true);
        frames
    };
    let (a_frames, during) = tokio::join!(a_side, camera_moves(b, b_id, u32::MAX, Some(done_rx)));
    Ok((a_frames?, during?))
}

/// Camera moves, one entry per move: its event-to-frame milliseconds, and
/// its frame's render, queue and encode milliseconds and size in bytes
/// (header included); the pixels of all its frames.
#[derive(Debug, Default)]
struct Moves {
    latency: Vec<f64>,
    render: Vec<f64>,
    queue: Vec<f64>,
    encode: Vec<f64>,
    bytes: Vec<f64>,
    pixels: usize,
}

/// What every `stream-cold-change` line shares.
struct ColdChangeLine<'a> {
    args: &'a BenchStreamArgs,
    adapter: &'a str,
    warm: &'a Dataset,
    /// B's moves with A idle.
    alone: Moves,
}

impl ColdChangeLine<'_> {
    /// The line for one change of A's (`kind`: cold or warm) to `preset`.
    fn json(
        &mut self,
        kind: &str,
        preset: blocks::Preset,
        a_frames: &[(FrameHeader, f64)],
        mut during: Moves,
        worker_reads: u64,
    ) -> serde_json::Value {
        let max = |v: &[f64]| v.iter().copied().fold(f64::NAN, f64::max);
        let first = a_frames.first().map(|(h, ms)| (h.pending_blocks, *ms));
        let a_render: Vec<f64> = a_frames
            .iter()
            .map(|(h, _)| f64::from(h.render_ms))
            .collect();
        // A frame time: the longest render of either session meanwhile.
        let frame_ms = max(&a_render).max(max(&during.render));
        let alone = &mut self.alone;
        serde_json::json!({
            "bench": "stream-cold-change",
            "change": kind,
            "adapter": self.adapter,
            "dataset": self.warm.name(),
            "cold_dataset": format!("phantom {}³, a brick store on disk (OS page cache not dropped)", self.args.cold_phantom),
            "preset": preset.name(),
            "width": self.args.session_size,
            "height": self.args.session_size,
            "a_first_frame_ms": first.map(|f| f.1),
            "a_first_frame_pending_blocks": first.map(|f| f.0),
            "a_converged_ms": a_frames.last().map(|(_, ms)| *ms),
            "a_frames": a_frames.len(),
            "a_render_ms_max": max(&a_render),
            "render_worker_chunk_reads": worker_reads,
            "b_events_alone": alone.latency.len(),
            "b_latency_ms_alone_p50": quantile(&mut alone.latency, 0.5),
            "b_latency_ms_alone_max": max(&alone.latency),
            "b_queue_ms_alone_max": max(&alone.queue),
            "b_events_during": during.latency.len(),
            "b_latency_ms_during_p50": quantile(&mut during.latency, 0.5),
            "b_latency_ms_during_max": max(&during.latency),
            "b_queue_ms_during_max": max(&during.queue),
            "frame_ms": frame_ms,
            "b_queue_in_frame_times": max(&during.queue) / frame_ms,
        })
    }
}

/// Camera moves on `socket` as messages `*id`, `*id + 1`, …, each timed
/// until its frame arrives: `events` of them, or until `until` turns true (at
/// least one).
async fn camera_moves(
    socket: &mut Socket,
    id: &mut u32,
    events: u32,
    mut until: Option<tokio::sync::watch::Receiver<bool>>,
) -> anyhow::Result<Moves> {
    let mut moves = Moves::default();
    while moves.latency.len() < events as usize {
        if !moves.latency.is_empty() && until.as_mut().is_some_and(|u| *u.borrow_and_update()) {
            break;
        }
        let start = Instant::now();
        let az = moves.latency.len() as f64 * 7.0;
        send_view(socket, *id, serde_json::json!({"az": az})).await?;
        let Some((header, bytes)) = next_frame_sized(socket, Some(*id)).await? else {
            anyhow::bail!("no frame for message {id}");
        };
        moves.latency.push(start.elapsed().as_secs_f64() * 1e3);
        moves.render.push(f64::from(header.render_ms));
        moves.queue.push(f64::from(header.queue_ms));
        moves.encode.push(f64::from(header.encode_ms));
        moves.bytes.push(bytes as f64);
        moves.pixels += usize::from(header.width) * usize::from(header.height);
        *id += 1;
    }
    Ok(moves)
}

/// Frames on `socket` until the lossless, converged one for message `id`,
/// each with the milliseconds since this call.
pub(super) async fn until_converged(
    socket: &mut Socket,
    id: u32,
) -> anyhow::Result<Vec<(FrameHeader, f64)>> {
    let start = Instant::now();
    let mut frames = Vec::new();
    loop {
        let Some(header) = next_frame(socket, Some(id)).await? else {
            anyhow::bail!("no frame for message {id}");
        };
        let done = header.lossless && header.converged;
        frames.push((header, start.elapsed().as_secs_f64() * 1e3));
        if done {
            return Ok(frames);
        }
    }
}
