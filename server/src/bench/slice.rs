//! `voxserve bench slice`: a slice view scrolled on loopback, against a
//! server in this process (the real router, render worker and sessions).
//!
//! `slice-latency`, once while scrolling (JPEG frames: a server that never
//! counts the view as still) and once still (lossless WebP: a server that
//! counts it still at once): an axial slice of `--size`² through the
//! middle of the volume moves by one voxel per event, `--events` times
//! upwards from below the centre, and each event is timed from sending its
//! `view` message to receiving the frame that reflects it (p50, p95), beside
//! the render, queue and encode milliseconds the frames' headers report and
//! the share of frames drawn coarser while their blocks were read (a cold
//! cache: every 16 slices a new layer of blocks). The first frame reads the
//! levels and is not timed. The level the slice is sampled at (0: full
//! resolution, a pixel no larger than two voxels) is in the line.

use std::time::Instant;

use anyhow::Context as _;
use futures_util::SinkExt;
use tokio_tungstenite::tungstenite::Message;

use super::args::BenchSliceArgs;
use super::stream::{Socket, connect, next_frame, quantile, start_server};
use server::commands::{load_dataset, say};
use server::encode::Lossless;
use server::stream::StreamSettings;
use server::{Dataset, RenderService};
use shaders::slice::SliceRequest;

/// `voxserve bench slice`; see the module docs.
pub fn slice(args: &BenchSliceArgs) -> anyhow::Result<()> {
    tokio::runtime::Runtime::new()?.block_on(run(args))
}

async fn run(args: &BenchSliceArgs) -> anyhow::Result<()> {
    let backend = args.renderer.backend()?;
    let adapter = backend.describe();
    let renderer = RenderService::start(backend, args.data.gpu_budget_bytes(), 1)?;
    for (format, idle_ms) in [("jpeg", 3_600_000u64), ("webp", 0)] {
        // A fresh dataset (and cache) per run: both scroll through cold blocks.
        let dataset = load_dataset(&args.dataset, &args.data)?;
        let settings = StreamSettings {
            idle_ms,
            lossless: Lossless::Webp,
            ..StreamSettings::default()
        };
        let (url, stop) = start_server(vec![dataset.clone()], renderer.clone(), settings).await?;
        let mut socket = connect(&url).await?;
        scroll(&mut socket, format, args, &adapter, &dataset).await?;
        drop(stop);
    }
    Ok(())
}

async fn send(socket: &mut Socket, message: serde_json::Value) -> anyhow::Result<()> {
    socket
        .send(Message::Text(message.to_string().into()))
        .await?;
    Ok(())
}

/// One `slice-latency` line: `--events` scrolls of the axial view.
async fn scroll(
    socket: &mut Socket,
    format: &str,
    args: &BenchSliceArgs,
    adapter: &str,
    dataset: &Dataset,
) -> anyhow::Result<()> {
    let geometry = dataset.store.meta().geometry;
    let step = geometry.spacing[2] as f32;
    let start_z = -step * (args.events as f32 / 2.0).floor();
    send(
        socket,
        serde_json::json!({"type": "layout", "panes": ["axial"]}),
    )
    .await?;
    let view = |id: u32, set: serde_json::Value| serde_json::json!({"type": "view", "id": id, "pane": "axial", "set": set});
    let first = serde_json::json!({
        "w": args.size, "h": args.size, "cz": start_z, "slab": args.slab,
    });
    send(socket, view(1, first)).await?;
    next_frame(socket, Some(1))
        .await?
        .context("no first frame")?;
    let level = SliceRequest {
        width: args.size,
        height: args.size,
        ..SliceRequest::default()
    }
    .placement(&geometry)
    .level;
    let (mut latency, mut render, mut encode, mut queue) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut coarser = 0u32;
    for event in 1..=args.events {
        let id = event + 1;
        let cz = start_z + step * event as f32;
        let sent = Instant::now();
        send(socket, view(id, serde_json::json!({"cz": cz}))).await?;
        let header = next_frame(socket, Some(id))
            .await?
            .context("no frame for a scroll")?;
        latency.push(sent.elapsed().as_secs_f64() * 1e3);
        render.push(f64::from(header.render_ms));
        encode.push(f64::from(header.encode_ms));
        queue.push(f64::from(header.queue_ms));
        coarser += u32::from(header.pending_blocks > 0);
    }
    say(&serde_json::json!({
        "bench": "slice-latency",
        "adapter": adapter,
        "dataset": dataset.name(),
        "dims": geometry.dims,
        "format": format,
        "width": args.size,
        "height": args.size,
        "slab_mm": args.slab,
        "level": level,
        "events": args.events,
        "latency_ms_p50": quantile(&mut latency, 0.5),
        "latency_ms_p95": quantile(&mut latency, 0.95),
        "render_ms_p50": quantile(&mut render, 0.5),
        "render_ms_p95": quantile(&mut render, 0.95),
        "encode_ms_p50": quantile(&mut encode, 0.5),
        "queue_ms_p50": quantile(&mut queue, 0.5),
        "frames_drawn_coarser": coarser,
    })
    .to_string())
}
