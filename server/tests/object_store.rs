//! Brick stores on S3: `voxserve ingest --out s3://…` and `render s3://…`
//! against a real S3-compatible server (`s3s-fs`) on a loopback port, as a
//! user runs them, with the endpoint and credentials in the environment.

use std::path::Path;
use std::process::{Command, Output};
use std::time::Duration;

use voxserve_tests::s3::S3Server;

const VOXSERVE: &str = env!("CARGO_BIN_EXE_voxserve");

fn voxserve(env: &[(String, String)], args: &[&str]) -> Output {
    Command::new(VOXSERVE)
        .args(args)
        .envs(env.iter().map(|(k, v)| (k, v)))
        .output()
        .unwrap_or_else(|e| panic!("running voxserve {args:?}: {e}"))
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Renders `dataset` on the CPU at 192² into `out`; its pixels, or the
/// failed run's standard error.
fn render(env: &[(String, String)], dataset: &str, out: &Path) -> Result<image::RgbaImage, String> {
    render_with(env, dataset, out, &[])
}

/// [`render`] with the further arguments `more`.
fn render_with(
    env: &[(String, String)],
    dataset: &str,
    out: &Path,
    more: &[&str],
) -> Result<image::RgbaImage, String> {
    let mut args = vec![
        "render",
        dataset,
        "--renderer",
        "cpu",
        "--width",
        "192",
        "--height",
        "192",
        "--out",
        out.to_str().expect("utf-8"),
    ];
    args.extend_from_slice(more);
    let run = voxserve(env, &args);
    if !run.status.success() {
        return Err(text(&run.stderr));
    }
    Ok(image::open(out).expect("a PNG").to_rgba8())
}

#[test]
fn a_store_ingested_to_s3_renders_pixel_for_pixel_as_the_same_store_on_disk() {
    let test = "a_store_ingested_to_s3_renders_pixel_for_pixel_as_the_same_store_on_disk";
    let Some(data) = voxserve_tests::data::shared_data(test) else {
        return;
    };
    let engine = data.join("raw/engine_256x256x128_uint8.raw");
    let engine = engine.to_str().expect("utf-8");
    let dir = tempfile::tempdir().expect("temp");
    let s3 = S3Server::start(&["scans"]);
    let env = s3.env();
    let url = "s3://scans/ct/engine.zarr";

    let out = voxserve(&env, &["ingest", engine, "--out", url]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains(url), "{}", text(&out.stdout));
    assert!(
        s3.object_file("scans", "ct/engine.zarr/voxserve/manifest.json")
            .is_file()
    );
    let local = dir.path().join("engine.zarr");
    let out = voxserve(
        &[],
        &["ingest", engine, "--out", local.to_str().expect("utf-8")],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));

    let from_s3 = render(&env, url, &dir.path().join("s3.png")).expect("a frame from S3");
    let from_disk = render(
        &[],
        local.to_str().expect("utf-8"),
        &dir.path().join("disk.png"),
    )
    .expect("a frame from disk");
    assert!(
        voxserve_tests::checks::coverage(&from_disk) > 0.05,
        "the engine is drawn"
    );
    assert!(
        from_s3 == from_disk,
        "the frame from S3 differs from the frame of the same store on disk"
    );

    // `bench store` times both from cold, alternating; a view session's
    // first frame comes before or with the converged one, and the render
    // worker never reads a chunk itself.
    let out = voxserve(
        &env,
        &[
            "bench",
            "store",
            url,
            local.to_str().expect("utf-8"),
            "--renderer",
            "cpu",
            "--rounds",
            "1",
            "--size",
            "96",
        ],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let lines: Vec<serde_json::Value> = text(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    let on: Vec<&str> = lines.iter().filter_map(|l| l["on"].as_str()).collect();
    assert_eq!(on, ["object storage", "disk"], "{lines:?}");
    for line in &lines {
        let ms = |key: &str| line[key].as_f64().unwrap_or(f64::NAN);
        assert!(ms("open_ms") > 0.0, "{line}");
        assert!(ms("first_frame_ms") <= ms("converged_ms"), "{line}");
        assert!(line["chunks_read"].as_u64() > Some(0), "{line}");
        assert_eq!(line["render_worker_chunk_reads"], 0, "{line}");
    }

    // An ingest onto a store replaces it only when asked to.
    let out = voxserve(&env, &["ingest", engine, "--out", url]);
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains(url) && stderr.contains("--force"),
        "{stderr}"
    );
    // --force replaces the store's files, and leaves other objects there.
    let beside = s3.object_file("scans", "ct/engine.zarr/notes.txt");
    std::fs::write(&beside, "kept").expect("an object beside the store");
    let out = voxserve(&env, &["ingest", engine, "--out", url, "--force"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(
        std::fs::read_to_string(&beside).ok().as_deref(),
        Some("kept")
    );
    // A prefix holding objects but no store is never written over.
    let other = s3.object_file("scans", "photos/a.jpg");
    std::fs::create_dir_all(other.parent().expect("a folder")).expect("a folder");
    std::fs::write(&other, "jpeg").expect("an object");
    let out = voxserve(
        &env,
        &["ingest", engine, "--out", "s3://scans/photos", "--force"],
    );
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("s3://scans/photos") && stderr.contains("no brick store"),
        "{stderr}"
    );
    assert_eq!(
        std::fs::read_to_string(&other).ok().as_deref(),
        Some("jpeg")
    );
    let again = render(&env, url, &dir.path().join("again.png")).expect("a frame from S3");
    assert!(
        again == from_disk,
        "the replaced store draws the same frame"
    );
}

#[test]
fn refused_credentials_and_missing_objects_are_named() {
    let dir = tempfile::tempdir().expect("temp");
    // A 40 × 30 × 70 uint16 volume.
    let raw = dir.path().join("scan_40x30x70_uint16.raw");
    let bytes: Vec<u8> = (0..40 * 30 * 70u32)
        .flat_map(|i| (((i * 7) % 4000) as u16).to_le_bytes())
        .collect();
    std::fs::write(&raw, bytes).expect("raw");
    let s3 = S3Server::start(&["scans"]);
    let url = "s3://scans/scan.zarr";
    let out = voxserve(
        &s3.env(),
        &["ingest", raw.to_str().expect("utf-8"), "--out", url],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let png = dir.path().join("scan.png");
    render(&s3.env(), url, &png).expect("a frame");

    // info and verify read it where it is.
    let out = voxserve(&s3.env(), &["info", url]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let info = text(&out.stdout);
    assert!(
        info.contains(url) && info.contains("40 × 30 × 70"),
        "{info}"
    );
    let out = voxserve(&s3.env(), &["verify", url]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("intact"),
        "{}",
        text(&out.stdout)
    );
    let shard = s3.object_file("scans", "scan.zarr/1/c/0/0/0");
    let mut bytes = std::fs::read(&shard).expect("a shard");
    let last = bytes.len() - 1;
    bytes[last / 2] ^= 0x40;
    std::fs::write(&shard, &bytes).expect("a changed shard");
    let out = voxserve(&s3.env(), &["verify", url]);
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("s3://scans/scan.zarr/1/c/0/0/0: changed"),
        "{stderr}"
    );
    bytes[last / 2] ^= 0x40;
    std::fs::write(&shard, &bytes).expect("the shard as it was");

    // Wrong credentials: the bucket is named, and what would let it be read.
    let wrong = s3.env_with_secret("not-the-secret");
    let stderr = render(&wrong, url, &png).expect_err("refused");
    assert!(
        stderr.contains("access denied to bucket 'scans'")
            && stderr.contains("AWS_SECRET_ACCESS_KEY"),
        "{stderr}"
    );

    // No store there.
    let stderr = render(&s3.env(), "s3://scans/none.zarr", &png).expect_err("no store");
    assert!(
        stderr.contains("s3://scans/none.zarr/zarr.json") && stderr.contains("missing"),
        "{stderr}"
    );

    // A shard deleted behind the store's back is missing data, not air.
    std::fs::remove_file(s3.object_file("scans", "scan.zarr/0/c/0/0/0")).expect("a shard");
    let stderr = render(&s3.env(), url, &png).expect_err("a missing shard");
    assert!(
        stderr.contains("s3://scans/scan.zarr/0/c/0/0/0") && stderr.contains("manifest lists it"),
        "{stderr}"
    );
}

/// `GET path` of `base`: the status, the body, and `X-Pending-Blocks`.
async fn get(base: &str, path: &str) -> (u16, Vec<u8>, Option<String>) {
    let response = reqwest::get(format!("{base}{path}"))
        .await
        .expect("a response");
    let status = response.status().as_u16();
    let pending = response
        .headers()
        .get("x-pending-blocks")
        .and_then(|v| v.to_str().ok())
        .map(str::to_owned);
    (
        status,
        response.bytes().await.expect("a body").to_vec(),
        pending,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_whose_object_store_stops_names_what_it_lacks_and_recovers_when_it_returns() {
    let test = "a_server_whose_object_store_stops_names_what_it_lacks_and_recovers_when_it_returns";
    let Some(data) = voxserve_tests::data::shared_data(test) else {
        return;
    };
    let engine = data.join("raw/engine_256x256x128_uint8.raw");
    let engine = engine.to_str().expect("utf-8");
    let dir = tempfile::tempdir().expect("temp");
    let mut s3 = S3Server::start(&["scans"]);
    let url = "s3://scans/ct/engine.zarr";
    let out = voxserve(&s3.env(), &["ingest", engine, "--out", url]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let local = dir.path().join("engine.zarr");
    let out = voxserve(
        &[],
        &["ingest", engine, "--out", local.to_str().expect("utf-8")],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let serve = |dataset: String, env: Vec<(String, String)>| async move {
        let args = [
            "serve",
            &dataset,
            "--addr",
            "127.0.0.1:0",
            "--renderer",
            "cpu",
        ];
        voxserve_tests::server::Spawned::start_with_env(VOXSERVE, &args, &env)
            .await
            .unwrap_or_else(|e| panic!("serve {dataset}: {e}"))
    };
    let from_s3 = serve(url.to_owned(), s3.env()).await;
    let from_disk = serve(local.to_string_lossy().into_owned(), Vec::new()).await;
    let view = "/api/render?w=160&h=160&preset=generic";

    // Opened (metadata, levels 3 and 4); the finer blocks are still on S3
    // when it stops: the frame is refused, naming the object and why.
    s3.stop();
    let (status, body, _) = get(&from_s3.url, view).await;
    let message = String::from_utf8_lossy(&body).into_owned();
    assert!(
        status >= 500
            && message.contains("s3://scans/ct/engine.zarr/")
            && message.contains("unavailable"),
        "{status}: {message}"
    );

    // /healthz says so once a probe has read the store's root again (the
    // last success is answered until then): 503 unavailable, naming it.
    let health = healthz_until(&from_s3.url, 503, Duration::from_secs(60)).await;
    assert!(
        health.contains("\"unavailable\"") && health.contains("s3://scans/ct/engine.zarr/"),
        "{health}"
    );

    // Back: after RETRY_AFTER the same view reads them and draws what the
    // store on disk draws (after at most one more refusal: reads under way
    // when the first was reported fail later, and are reported once too).
    s3.resume();
    let mut answers = Vec::new();
    let frame = loop {
        tokio::time::sleep(blocks::cache::RETRY_AFTER).await;
        let (status, frame, pending) = get(&from_s3.url, view).await;
        if status == 200 {
            assert_eq!(pending.as_deref(), Some("0"));
            break frame;
        }
        answers.push(format!("{status}: {}", String::from_utf8_lossy(&frame)));
        assert!(answers.len() < 3, "not drawn again: {answers:?}");
    };
    let (status, expected, _) = get(&from_disk.url, view).await;
    assert_eq!(status, 200);
    let frame = image::load_from_memory(&frame).expect("a PNG").to_rgba8();
    let expected = image::load_from_memory(&expected)
        .expect("a PNG")
        .to_rgba8();
    assert!(
        voxserve_tests::checks::coverage(&expected) > 0.05,
        "the engine is drawn"
    );
    assert!(
        frame == expected,
        "the recovered frame differs from the store on disk's"
    );
    // Ready again.
    healthz_until(&from_s3.url, 200, Duration::from_secs(30)).await;
}

/// Asks `base`'s `/healthz` every 200 ms until it answers `status`, within
/// `patience`; the body.
async fn healthz_until(base: &str, status: u16, patience: Duration) -> String {
    let start = std::time::Instant::now();
    loop {
        let (answer, body, _) = get(base, "/healthz").await;
        let body = String::from_utf8_lossy(&body).into_owned();
        if answer == status {
            return body;
        }
        assert!(
            start.elapsed() < patience,
            "/healthz did not answer {status} within {patience:?}: {answer} {body}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_answers_within_the_timeout_are_waited_for_and_slower_ones_reported_after_retries() {
    let dir = tempfile::tempdir().expect("temp");
    let raw = dir.path().join("scan_40x30x70_uint16.raw");
    let bytes: Vec<u8> = (0..40 * 30 * 70u32)
        .flat_map(|i| (((i * 7) % 4000) as u16).to_le_bytes())
        .collect();
    std::fs::write(&raw, bytes).expect("raw");
    let s3 = S3Server::start(&["scans"]);
    let url = "s3://scans/scan.zarr";
    let out = voxserve(
        &s3.env(),
        &["ingest", raw.to_str().expect("utf-8"), "--out", url],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let local = dir.path().join("scan.zarr");
    let out = voxserve(
        &[],
        &[
            "ingest",
            raw.to_str().expect("utf-8"),
            "--out",
            local.to_str().expect("utf-8"),
        ],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let policy = ["--store-timeout-s", "1", "--store-retries", "1"];
    let args = |dataset: &str| {
        let mut args = vec![
            "serve",
            dataset,
            "--addr",
            "127.0.0.1:0",
            "--renderer",
            "cpu",
        ];
        args.extend(policy);
        args.into_iter().map(str::to_owned).collect::<Vec<_>>()
    };
    let start = |args: Vec<String>, env: Vec<(String, String)>| async move {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        voxserve_tests::server::Spawned::start_with_env(VOXSERVE, &args, &env)
            .await
            .unwrap_or_else(|e| panic!("serve: {e}"))
    };
    let from_s3 = start(args(url), s3.env()).await;
    let from_disk = start(args(local.to_str().expect("utf-8")), Vec::new()).await;
    let view = "/api/render?w=96&h=96&preset=generic";

    // Every answer 2.5 s late, past the 1 s timeout: each read fails, is
    // tried once more, and the view is refused naming an object.
    s3.set_delay(Duration::from_millis(2500));
    let started = std::time::Instant::now();
    let (status, body, pending) = get(&from_s3.url, view).await;
    let message = String::from_utf8_lossy(&body).into_owned();
    assert!(
        status >= 500
            && message.contains("s3://scans/scan.zarr/")
            && message.contains("unavailable"),
        "{status} after {:?}, pending {pending:?}: {}",
        started.elapsed(),
        message.chars().take(300).collect::<String>()
    );
    assert!(
        started.elapsed() >= Duration::from_secs(2),
        "a timed-out read was tried again before it was reported ({:?})",
        started.elapsed()
    );

    // 300 ms late, within the timeout: waited for, and the view is drawn
    // as from the store on disk (after at most one more refusal: reads that
    // were under way when the first was reported fail later, and are
    // reported once too).
    s3.set_delay(Duration::from_millis(300));
    let mut answers = Vec::new();
    let frame = loop {
        tokio::time::sleep(blocks::cache::RETRY_AFTER).await;
        let (status, frame, pending) = get(&from_s3.url, view).await;
        if status == 200 {
            assert_eq!(pending.as_deref(), Some("0"));
            break frame;
        }
        answers.push(format!("{status}: {}", String::from_utf8_lossy(&frame)));
        assert!(answers.len() < 3, "not drawn again: {answers:?}");
    };
    let (_, expected, _) = get(&from_disk.url, view).await;
    let frame = image::load_from_memory(&frame).expect("a PNG").to_rgba8();
    let expected = image::load_from_memory(&expected)
        .expect("a PNG")
        .to_rgba8();
    assert!(
        frame == expected,
        "the frame read slowly differs from the store on disk's"
    );
}

#[test]
fn the_store_cache_answers_again_after_a_restart_and_never_for_a_replaced_store() {
    let test = "the_store_cache_answers_again_after_a_restart_and_never_for_a_replaced_store";
    let Some(data) = voxserve_tests::data::shared_data(test) else {
        return;
    };
    let engine = data.join("raw/engine_256x256x128_uint8.raw");
    let hydrogen = data.join("raw/hydrogen_atom_128x128x128_uint8.raw");
    let (engine, hydrogen) = (
        engine.to_str().expect("utf-8"),
        hydrogen.to_str().expect("utf-8"),
    );
    let dir = tempfile::tempdir().expect("temp");
    let s3 = S3Server::start(&["scans"]);
    let env = s3.env();
    let url = "s3://scans/ct/scan.zarr";
    let out = voxserve(&env, &["ingest", engine, "--out", url]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let cache = dir.path().join("cache");
    let cache = cache.to_str().expect("utf-8");
    // Renders through the cache in a new process: its pixels, and the
    // requests the S3 server was sent meanwhile.
    let cached_render = |name: &str| {
        let before = s3.requests();
        let more = ["--store-cache", cache, "--store-cache-mib", "64"];
        let image = render_with(&env, url, &dir.path().join(name), &more)
            .expect("a frame through the cache");
        (image, s3.requests() - before)
    };
    let (first, cold) = cached_render("first.png");
    let (again, warm) = cached_render("again.png");
    assert!(
        voxserve_tests::checks::coverage(&first) > 0.05,
        "the engine is drawn"
    );
    assert!(again == first, "the frame from the cache differs");
    // Warm: the listing and the manifest (which name the objects'
    // versions) are asked for; every block comes from the cache.
    assert!(
        cold >= 20 && warm <= 4,
        "requests to S3: {cold} with an empty cache, {warm} after a restart with it filled"
    );

    // One process per folder.
    let lock =
        std::fs::File::open(Path::new(cache).join("voxserve.lock")).expect("the cache's lock file");
    lock.lock()
        .expect("the lock, as another process would hold it");
    let run = voxserve(&env, &["render", url, "--store-cache", cache]);
    assert!(!run.status.success());
    let stderr = text(&run.stderr);
    assert!(
        stderr.contains(cache) && stderr.contains("in use by another voxserve process"),
        "{stderr}"
    );
    drop(lock);

    // Another volume ingested over the store: its objects have other
    // versions, so nothing of the engine's is answered from the cache.
    let out = voxserve(&env, &["ingest", hydrogen, "--out", url, "--force"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let (replaced, _) = cached_render("replaced.png");
    let local = dir.path().join("hydrogen.zarr");
    let out = voxserve(
        &[],
        &["ingest", hydrogen, "--out", local.to_str().expect("utf-8")],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let expected = render(
        &[],
        local.to_str().expect("utf-8"),
        &dir.path().join("expected.png"),
    )
    .expect("a frame of the new volume from disk");
    assert!(replaced != first, "the replaced store drew the old volume");
    assert!(
        replaced == expected,
        "the replaced store's frame through the cache differs from the new volume's"
    );
}
