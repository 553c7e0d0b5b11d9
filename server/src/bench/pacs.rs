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
        if args.iid {
            runtime.block_on(iid_round(args, round))?;
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

/// One IID request to the first frame, on a server with an empty cache.
async fn iid_round(args: &BenchPacsArgs, round: u32) -> anyhow::Result<()> {
    let web = dicomweb(&args.pacs)?;
    let pacs = web.name().to_owned();
    let cache = tempfile::tempdir()?;
    let studies = server::studies::Studies::new(vec![web], cache.path(), 1 << 40, 256 << 20)?;
    let renderer = server::RenderService::start(shaders::Backend::Cpu, 512 << 20, 2)?;
    let phantom = server::Dataset::phantom(32, 64 << 20)?;
    let mut state = server::AppState::new(
        vec![phantom],
        renderer,
        server::stream::StreamSettings::default(),
    );
    state.studies = Some(studies);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let url = format!("http://{}", listener.local_addr()?);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let running = tokio::spawn(server::run(listener, state, async {
        let _ = stopped.await;
    }));
    let http = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()?;
    let json = |r: reqwest::Response| async move {
        let status = r.status();
        let body: serde_json::Value = serde_json::from_slice(&r.bytes().await?)?;
        anyhow::ensure!(status.is_success(), "HTTP {status}: {body}");
        Ok::<_, anyhow::Error>(body)
    };
    let start = Instant::now();
    let query = format!("requestType=STUDY&studyUID={}", args.study);
    let launch = http
        .get(format!("{url}/IHEInvokeImageDisplay?{query}"))
        .send()
        .await?;
    anyhow::ensure!(
        launch.status().as_u16() == 303,
        "the launch answered {}",
        launch.status()
    );
    let resolved = json(
        http.get(format!("{url}/api/pacs/iid?{query}"))
            .send()
            .await?,
    )
    .await?;
    let resolve_s = start.elapsed().as_secs_f64();
    let series = resolved["show"]
        .as_str()
        .ok_or_else(|| anyhow::anyhow!("no series to show: {resolved}"))?
        .to_owned();
    let open = format!(
        "{url}/api/pacs/open?pacs={pacs}&study={}&series={series}",
        args.study
    );
    let mut job = json(http.post(&open).send().await?).await?;
    while job["state"] == "fetching" || job["state"] == "bricking" {
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        job = json(http.get(&open).send().await?).await?;
    }
    anyhow::ensure!(job["state"] == "ready", "opening the series: {job}");
    let open_s = start.elapsed().as_secs_f64() - resolve_s;
    let frame = http
        .get(format!("{url}/api/datasets/{series}/render?w=512&h=512"))
        .send()
        .await?;
    anyhow::ensure!(
        frame.status().is_success(),
        "the first frame: {}",
        frame.status()
    );
    let png = frame.bytes().await?;
    let total_s = start.elapsed().as_secs_f64();
    say(&serde_json::json!({
        "bench": "pacs",
        "round": round,
        "phase": "IHE Invoke Image Display to first frame",
        "pacs": pacs,
        "study": args.study,
        "series": series,
        "renderer": "cpu",
        "frame": "512x512 PNG",
        "instances": job["total"],
        "resolve_s": resolve_s,
        "fetch_and_brick_s": open_s,
        "first_frame_s": total_s - resolve_s - open_s,
        "total_s": total_s,
        "frame_bytes": png.len(),
    })
    .to_string())?;
    let _ = stop.send(());
    running.await??;
    Ok(())
}
