//! `voxserve bench pacs`: a series from a PACS over DICOMweb, fetched
//! (WADO-RS, every instance as stored) at each concurrency and bricked, and
//! the same files ingested from disk, interleaved round by round.

use std::time::Instant;

use blocks::store::{self, IngestOptions};
use server::commands::{dicomweb, say};
use server::pacs::fetch::{FetchOptions, fetch_series, open_fetched};

use super::args::BenchPacsArgs;

/// Runs `voxserve bench pacs`.
pub fn pacs(args: &BenchPacsArgs) -> anyhow::Result<()> {
    let runtime = tokio::runtime::Runtime::new()?;
    let web = dicomweb(&args.pacs)?;
    let series = match &args.series {
        Some(s) => s.clone(),
        None => {
            let all = runtime.block_on(web.search_series(&args.study))?;
            match all.as_slice() {
                [only] => only.series_uid.clone(),
                _ => anyhow::bail!(
                    "study {}: {} series; say which with --series",
                    args.study,
                    all.len()
                ),
            }
        }
    };
    for round in 0..args.rounds {
        for &concurrency in &args.concurrency {
            let dir = tempfile::tempdir()?;
            let options = FetchOptions {
                concurrency: usize::from(concurrency),
                ..FetchOptions::default()
            };
            let fetched = runtime.block_on(fetch_series(
                &web,
                &args.study,
                &series,
                dir.path(),
                options,
                &|_, _, _| {},
            ))?;
            let start = Instant::now();
            let mut source = open_fetched(&fetched)?;
            let brick = store::ingest(
                source.as_mut(),
                &dir.path().join("store.zarr"),
                &IngestOptions::default(),
                &mut |_| {},
            )?;
            let brick_s = start.elapsed().as_secs_f64();
            let (instances, slices) = (fetched.instances.len(), brick.dims[2]);
            let mb = fetched.bytes as f64 / 1e6;
            say(&serde_json::json!({
                "bench": "pacs",
                "round": round,
                "pacs": web.name(),
                "study": args.study,
                "series": series,
                "concurrency": concurrency,
                "instances": instances,
                "slices": slices,
                "fetched_mb": mb,
                "fetch_s": fetched.seconds,
                "fetch_mb_per_s": mb / fetched.seconds,
                "fetch_instances_per_s": instances as f64 / fetched.seconds,
                "brick_s": brick_s,
                "brick_mb_per_s": brick.source_bytes as f64 / 1e6 / brick_s,
                "total_s": fetched.seconds + brick_s,
                "slices_per_s": f64::from(slices) / (fetched.seconds + brick_s),
            })
            .to_string())?;
        }
        if let Some(folder) = &args.folder {
            let dir = tempfile::tempdir()?;
            let start = Instant::now();
            let mut source = blocks::ingest::open(folder, &blocks::ingest::OpenOptions::default())?;
            let summary = store::ingest(
                source.as_mut(),
                &dir.path().join("store.zarr"),
                &IngestOptions::default(),
                &mut |_| {},
            )?;
            let s = start.elapsed().as_secs_f64();
            say(&serde_json::json!({
                "bench": "pacs",
                "round": round,
                "baseline": "ingest from disk",
                "folder": folder.display().to_string(),
                "slices": summary.dims[2],
                "total_s": s,
                "mb_per_s": summary.source_bytes as f64 / 1e6 / s,
                "slices_per_s": f64::from(summary.dims[2]) / s,
            })
            .to_string())?;
        }
    }
    Ok(())
}
