//! `voxserve bench store`: how fast a brick store's view comes up from cold,
//! per store (on disk or on object storage), the stores alternating round
//! by round so that their figures come from the same run.
//!
//! Each round opens the store afresh (its metadata, block statistics and the
//! two coarsest levels, which stay resident: `open_ms`), starts a server in
//! this process on it (the real router, render worker and session), opens a
//! view session, asks for one still view of the default preset at
//! `--size`², and times from that message to the first frame (drawn from
//! what is in memory, finer blocks still pending) and to the converged
//! lossless one (`converged_ms`), with the chunks read meanwhile and their
//! rate. The operating system's page cache is not dropped between rounds:
//! a store on disk is warm after its first round; one on object storage is
//! read over the network every round.

use std::time::Instant;

use super::args::BenchStoreArgs;
use super::stream::{connect, send_view, start_server, until_converged};
use server::RenderService;
use server::commands::{load_dataset, say};
use server::stream::StreamSettings;

/// `voxserve bench store`; see the module docs.
pub fn store(args: &BenchStoreArgs) -> anyhow::Result<()> {
    tokio::runtime::Runtime::new()?.block_on(run(args))
}

async fn run(args: &BenchStoreArgs) -> anyhow::Result<()> {
    let backend = args.renderer.backend()?;
    let adapter = backend.describe();
    let renderer = RenderService::start(backend, args.data.gpu_budget_bytes(), 1)?;
    for round in 1..=args.rounds {
        for name in &args.stores {
            let start = Instant::now();
            let dataset = load_dataset(name, &args.data)?;
            let open_ms = start.elapsed().as_secs_f64() * 1e3;
            let cache = dataset.cache.clone();
            let settings = StreamSettings {
                // Still at once: the converged frame follows the last block.
                idle_ms: 0,
                ..StreamSettings::default()
            };
            let (url, stop) =
                start_server(vec![dataset.clone()], renderer.clone(), settings).await?;
            let mut socket = connect(&url).await?;
            let read_before = cache.arrivals() + cache.inline_reads();
            let disk = blocks::store::disk_cache::get();
            let disk_before = disk.map(|d| (d.hits(), d.misses()));
            send_view(
                &mut socket,
                1,
                serde_json::json!({"w": args.size, "h": args.size}),
            )
            .await?;
            let frames = until_converged(&mut socket, 1).await?;
            let read = cache.arrivals() + cache.inline_reads() - read_before;
            drop(stop);
            let first = frames
                .first()
                .map(|(h, ms)| (*ms, h.pending_blocks, h.render_ms, h.queue_ms));
            let converged_ms = frames.last().map_or(f64::NAN, |(_, ms)| *ms);
            say(&serde_json::json!({
                "bench": "store",
                "store": name,
                "on": if blocks::store::is_url(name) { "object storage" } else { "disk" },
                "round": round,
                "dims": dataset.dims(),
                "preset": dataset.default_preset().name(),
                "width": args.size,
                "height": args.size,
                "adapter": adapter,
                "open_ms": open_ms,
                "first_frame_ms": first.map(|f| f.0),
                "first_frame_pending_blocks": first.map(|f| f.1),
                "first_frame_render_ms": first.map(|f| f.2),
                "first_frame_queue_ms": first.map(|f| f.3),
                "render_worker_chunk_reads": cache.inline_reads(),
                "converged_ms": converged_ms,
                "frames": frames.len(),
                "chunks_read": read,
                "chunks_per_s": read as f64 / (converged_ms / 1e3),
                "cache_mib": args.data.cache_bytes() >> 20,
                "store_cache_hits": disk.zip(disk_before).map(|(d, b)| d.hits() - b.0),
                "store_cache_misses": disk.zip(disk_before).map(|(d, b)| d.misses() - b.1),
            })
            .to_string())?;
        }
    }
    Ok(())
}
