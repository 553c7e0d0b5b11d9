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

use std::time::{Duration, Instant};

use anyhow::Context as _;
use futures_util::{SinkExt, StreamExt};
use shaders::GpuContext;
use tokio::net::TcpListener;
use tokio_tungstenite::tungstenite::Message;

use super::args::BenchStreamArgs;
use server::commands::{load_dataset, say};
use server::encode::Lossless;
use server::protocol::FrameHeader;
use server::stream::StreamSettings;
use server::{AppState, Dataset, RenderService};

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// How long one frame may take before the benchmark gives up.
const PATIENCE: Duration = Duration::from_secs(600);

/// `voxserve bench stream`; see the module docs.
pub fn stream(args: &BenchStreamArgs) -> anyhow::Result<()> {
    tokio::runtime::Runtime::new()?.block_on(run(args))
}

/// A server on 127.0.0.1 port 0; dropping the sender stops it.
async fn start_server(
    dataset: Dataset,
    renderer: RenderService,
    settings: StreamSettings,
) -> anyhow::Result<(String, tokio::sync::oneshot::Sender<()>)> {
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    let url = format!("ws://{}/api/stream", listener.local_addr()?);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let state = AppState::new(vec![dataset], renderer, settings);
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

async fn connect(url: &str) -> anyhow::Result<Socket> {
    let (mut socket, _) = tokio_tungstenite::connect_async(url)
        .await
        .with_context(|| format!("connecting to {url}"))?;
    // The hello.
    next_frame(&mut socket, None).await?;
    Ok(socket)
}

/// Waits for the frame reflecting message `id` (any frame for `None`, which
/// also accepts the hello); acknowledges it.
async fn next_frame(socket: &mut Socket, id: Option<u32>) -> anyhow::Result<Option<FrameHeader>> {
    Ok(next_frame_sized(socket, id)
        .await?
        .map(|(header, _)| header))
}

/// [`next_frame`] with the frame's size in bytes (header included).
async fn next_frame_sized(
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

async fn send_view(socket: &mut Socket, id: u32, set: serde_json::Value) -> anyhow::Result<()> {
    let view = serde_json::json!({"type": "view", "id": id, "set": set});
    socket.send(Message::Text(view.to_string().into())).await?;
    Ok(())
}

/// The `q` quantile (0..=1) of `values` (sorted in place).
fn quantile(values: &mut [f64], q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    let i = ((values.len() as f64 * q).ceil() as usize).saturating_sub(1);
    values.get(i).copied().unwrap_or(f64::NAN)
}

/// The process's resident memory now, MiB (Linux: VmRSS), if known.
fn rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// Per format, a server in this process: latency lines per image size, and
/// on the JPEG server the frame rate per number of sessions.
async fn run(args: &BenchStreamArgs) -> anyhow::Result<()> {
    let dataset = load_dataset(&args.dataset, &args.data)?;
    let gpu = GpuContext::new()?;
    let adapter = gpu.info.name.clone();
    let renderer = RenderService::start(gpu, args.data.gpu_budget_bytes(), 1)?;
    let full_size = StreamSettings {
        interactive_scale: 1.0,
        interactive_reduction: 1.0,
        max_sessions: 4096,
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
        let (url, stop) = start_server(dataset.clone(), renderer.clone(), settings).await?;
        for &edge in &args.sizes {
            latency(&url, edge, format, args, &adapter, &dataset).await?;
        }
        if format == "jpeg" {
            for &n in &args.sessions {
                sessions(&url, n, args, &adapter, &dataset).await?;
            }
        }
        drop(stop);
    }
    Ok(())
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
    let (mut latency, mut overhead, mut render, mut encode, mut queue) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut pixels = 0usize;
    let mut sizes = Vec::new();
    for event in 0..args.events {
        let id = event + 2;
        let start = Instant::now();
        send_view(
            &mut socket,
            id,
            serde_json::json!({"az": f64::from(event) * 7.0}),
        )
        .await?;
        let Some((header, size)) = next_frame_sized(&mut socket, Some(id)).await? else {
            anyhow::bail!("no frame for message {id}");
        };
        sizes.push(size as f64);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        latency.push(ms);
        overhead.push(ms - f64::from(header.render_ms));
        render.push(f64::from(header.render_ms));
        encode.push(f64::from(header.encode_ms));
        queue.push(f64::from(header.queue_ms));
        pixels += usize::from(header.width) * usize::from(header.height);
    }
    say(&serde_json::json!({
        "bench": "stream-latency",
        "adapter": adapter,
        "dataset": dataset.name(),
        "format": format,
        "width": edge,
        "height": edge,
        "events": args.events,
        "latency_ms_p50": quantile(&mut latency, 0.5),
        "latency_ms_p95": quantile(&mut latency, 0.95),
        "latency_minus_render_ms_p50": quantile(&mut overhead, 0.5),
        "latency_minus_render_ms_p95": quantile(&mut overhead, 0.95),
        "render_ms_p50": quantile(&mut render, 0.5),
        "encode_ms_p50": quantile(&mut encode, 0.5),
        "encode_ms_p95": quantile(&mut encode, 0.95),
        "queue_ms_p50": quantile(&mut queue, 0.5),
        "pixels_per_frame": pixels / args.events.max(1) as usize,
        "frame_bytes_p50": quantile(&mut sizes, 0.5),
    })
    .to_string())
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
    let tasks: Vec<_> = (0..n)
        .map(|s| {
            let url = url.to_owned();
            tokio::spawn(async move {
                let mut socket = connect(&url).await?;
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
    // Resident memory ten times over the run: flat after warm-up, or growing.
    let sampler = tokio::spawn(async move {
        let mut samples = Vec::new();
        for _ in 0..10 {
            tokio::time::sleep(run_for / 10).await;
            samples.push(rss_mib());
        }
        samples
    });
    let mut rates = Vec::new();
    let mut errors = Vec::new();
    for task in tasks {
        match task.await {
            Ok(Ok(rate)) => rates.push(rate),
            Ok(Err(e)) => errors.push(e.to_string()),
            Err(e) => errors.push(e.to_string()),
        }
    }
    let total: f64 = rates.iter().sum();
    let slowest = rates.iter().copied().fold(f64::INFINITY, f64::min);
    let fastest = rates.iter().copied().fold(0.0, f64::max);
    say(&serde_json::json!({
        "bench": "stream-sessions",
        "adapter": adapter,
        "dataset": dataset.name(),
        "format": "jpeg",
        "sessions": n,
        "width": edge,
        "height": edge,
        "seconds": args.seconds,
        "frames_per_s": total,
        "per_session_fps_min": slowest,
        "per_session_fps_max": fastest,
        "slowest_over_fastest": slowest / fastest,
        "errors": errors.len(),
        "first_error": errors.first(),
        "rss_mib_before": rss_before,
        "rss_mib_after": rss_mib(),
        "rss_mib_during": sampler.await.unwrap_or_default(),
    })
    .to_string())?;
    Ok(())
}
