//! The `voxserve` binary as a user runs it: `--help`, `render` to a file, bad
//! flags, and `serve` printing its URL and answering `GET /api/render`.

use std::path::PathBuf;
use std::process::{Command, Output};
use std::time::Duration;

use voxserve_tests::Tolerance;
use voxserve_tests::checks::assert_front_view_of_phantom;
use voxserve_tests::gpu::require_gpu;
use voxserve_tests::image_compare::compare;

const VOXSERVE: &str = env!("CARGO_BIN_EXE_voxserve");

fn voxserve(args: &[&str]) -> Output {
    Command::new(VOXSERVE)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("running voxserve {args:?}: {e}"))
}

/// Runs voxserve with `args` where no GPU adapter exists: Linux has no DX12,
/// so this backend choice leaves none at all.
fn without_adapter(args: &[&str]) -> Output {
    Command::new(VOXSERVE)
        .args(args)
        .env("WGPU_BACKEND", "dx12")
        .output()
        .unwrap_or_else(|e| panic!("running voxserve {args:?}: {e}"))
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// True when the run failed only because there is no GPU, and that is allowed.
fn skipped_for_lack_of_gpu(test: &str, out: &Output) -> bool {
    !out.status.success() && failed_for_lack_of_gpu(test, &text(&out.stderr))
}

/// True when a failed run's `stderr` says only that there is no GPU, and
/// that is allowed.
fn failed_for_lack_of_gpu(test: &str, stderr: &str) -> bool {
    if !stderr.contains("no GPU adapter found") {
        return false;
    }
    assert!(
        !require_gpu(),
        "{test}: VOXSERVE_REQUIRE_GPU=1 but: {stderr}"
    );
    voxserve_tests::gpu::report_skip(test, "no GPU adapter");
    true
}

fn temp_path(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("voxserve-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

#[test]
fn help_explains_every_subcommand_and_flag() {
    let top = text(&voxserve(&["--help"]).stdout);
    for word in ["serve", "render", "bench", "WGPU_BACKEND"] {
        assert!(top.contains(word), "voxserve --help lacks {word}:\n{top}");
    }
    let render = text(&voxserve(&["render", "--help"]).stdout);
    for flag in [
        "--out",
        "--azimuth",
        "--elevation",
        "--distance",
        "--fov",
        "--width",
        "--height",
        "--preset",
        "--shading",
        "--step",
        "--renderer",
        "--phantom-size",
        "--projection",
        "--clip",
        "--reduction",
        "--background",
        "--gpu-budget-mib",
        "--cache-mib",
        "--light",
        "--light-colour",
        "--light-intensity",
        "--light-bias",
        "--segment",
        "--svr-scale",
        "--scatter-radius",
        "--directions",
        "--phase-g",
        "global",
        "minip",
        "ct-bone",
        "DATASET",
    ] {
        assert!(
            render.contains(flag),
            "render --help lacks {flag}:\n{render}"
        );
    }
    let serve = text(&voxserve(&["serve", "--help"]).stdout);
    for flag in ["--addr", "127.0.0.1:8080", "--phantom-size"] {
        assert!(serve.contains(flag), "serve --help lacks {flag}:\n{serve}");
    }
}

#[test]
fn bad_flags_are_refused_with_the_flag_named() {
    for (args, flag) in [
        (vec!["render", "--width", "0"], "--width"),
        (vec!["render", "--height", "100000"], "--height"),
        (vec!["render", "--azimuth", "north"], "--azimuth"),
        (vec!["render", "--preset", "bone"], "--preset"),
        (vec!["render", "--phantom-size", "8"], "--phantom-size"),
        (vec!["render", "--clip", "0,0,0,1,1"], "--clip"),
        (vec!["render", "--reduction", "0"], "--reduction"),
        (vec!["render", "--projection", "fisheye"], "--projection"),
        (vec!["render", "--background", "white"], "--background"),
        (vec!["render", "--renderer", "quantum"], "--renderer"),
        (vec!["serve", "--addr", "localhost"], "--addr"),
        // Anyone who reaches a non-loopback port would see every dataset.
        (
            vec!["serve", "--addr", "0.0.0.0:0"],
            "--insecure-allow-anonymous",
        ),
        (vec!["serve", "--host-name", "evil/x"], "--host-name"),
        (
            vec!["serve", "--allow-origin", "evil.example"],
            "--allow-origin",
        ),
        (vec!["serve", "--max-connections", "0"], "--max-connections"),
        (
            vec!["serve", "--trusted-proxy", "10.0.0.0/33"],
            "--trusted-proxy",
        ),
        (
            vec!["serve", "--sessions-per-client", "0"],
            "--sessions-per-client",
        ),
        (vec!["serve", "--session-idle-s", "0"], "--session-idle-s"),
        (
            vec!["serve", "--data", "/no/such/folder"],
            "--data /no/such/folder",
        ),
        (
            vec!["serve", "--resident-datasets", "0"],
            "--resident-datasets",
        ),
        (vec!["render", "--light", "spot:0,0,1"], "--light"),
        (vec!["render", "--light", "directional:0,0,0"], "--light"),
        (vec!["render", "--light", "point:0.5,nan,0.5"], "--light"),
        (vec!["render", "--light-colour", "yellow"], "--light-colour"),
        (
            vec!["render", "--light-intensity", "-1"],
            "--light-intensity",
        ),
        (vec!["render", "--light-bias", "1.5"], "--light-bias"),
        (vec!["render", "--light-bias", "-0.1"], "--light-bias"),
        (vec!["render", "--scatter-radius", "-2"], "--scatter-radius"),
        (vec!["render", "--segment", "2"], "--segment"),
        (vec!["render", "--svr-scale", "3"], "--svr-scale"),
        (
            vec!["render", "--scatter-radius", "100"],
            "--scatter-radius",
        ),
        (vec!["render", "--directions", "0"], "--directions"),
        (vec!["render", "--phase-g", "1"], "--phase-g"),
        (
            vec!["bench", "light", "--svr-scales", "1,5"],
            "--svr-scales",
        ),
        (vec!["bench", "light", "--segments", "64"], "--segments"),
        // Tokens of an issuer reached over plain HTTP could be read on the way.
        (
            vec![
                "serve",
                "--oidc-issuer",
                "http://id.example.org",
                "--oidc-audience",
                "a",
            ],
            "--oidc-issuer",
        ),
        (
            vec!["serve", "--oidc-issuer", "https://id.example.org"],
            "--oidc-audience",
        ),
        (
            vec!["serve", "--policy", "/no/such/policy.json"],
            "--policy",
        ),
        (
            vec!["serve", "--api-tokens", "/no/such/tokens.json"],
            "--api-tokens /no/such/tokens.json",
        ),
        (vec!["serve", "--tls-cert", "/no/cert.pem"], "--tls-key"),
        (
            vec![
                "serve",
                "--tls-cert",
                "/no/cert.pem",
                "--tls-key",
                "/no/key.pem",
            ],
            "--tls-cert /no/cert.pem",
        ),
        (
            vec!["serve", "--audit-log", "/no/such/folder/audit.jsonl"],
            "--audit-log",
        ),
        (
            vec!["serve", "--frame-ancestor", "emr.example.org"],
            "--frame-ancestor",
        ),
        (vec!["token", "--name", ""], "--name"),
    ] {
        let out = voxserve(&args);
        assert!(!out.status.success(), "{args:?} should fail");
        let stderr = text(&out.stderr);
        assert!(stderr.contains(flag), "{args:?}: {stderr}");
    }
    let out = voxserve(&["render", "engine.raw"]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("dataset 'engine.raw': no such file or folder"),
        "{}",
        text(&out.stderr)
    );
}

#[test]
fn render_writes_the_frame_and_gpu_and_cpu_twin_agree() {
    let common = [
        "--phantom-size",
        "64",
        "--width",
        "96",
        "--height",
        "80",
        "--azimuth",
        "25",
        "--reduction",
        "9",
        "--projection",
        "orthographic",
        "--clip",
        "0,0,0,1,0.7,1",
        "--background",
        "102030",
    ];
    let cpu_path = temp_path("cpu.png");
    let out = voxserve(
        &[
            &[
                "render",
                "--renderer",
                "cpu",
                "--out",
                cpu_path.to_str().expect("utf-8"),
            ][..],
            &common,
        ]
        .concat(),
    );
    assert!(
        out.status.success(),
        "render --renderer cpu: {}",
        text(&out.stderr)
    );
    let said = text(&out.stdout);
    let reduction: f64 = said
        .split("reduction ")
        .nth(1)
        .and_then(|rest| rest.split(':').next())
        .and_then(|r| r.parse().ok())
        .unwrap_or_else(|| panic!("no reduction in: {said}"));
    assert!(said.contains("wrote") && reduction >= 9.0, "{said}");
    let cpu = image::open(&cpu_path).expect("CPU PNG").to_rgba8();
    // Written beside its place and renamed into it: nothing else is left.
    let folder = cpu_path.parent().expect("folder");
    let partial: Vec<_> = std::fs::read_dir(folder)
        .expect("read folder")
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().ends_with(".partial"))
        .collect();
    assert!(partial.is_empty(), "{partial:?}");
    assert_eq!(cpu.dimensions(), (96, 80));
    assert!(
        voxserve_tests::checks::coverage(&cpu) > 0.1,
        "the phantom is in the CPU frame"
    );

    let gpu_path = temp_path("gpu.png");
    let out = voxserve(
        &[
            &[
                "render",
                "--renderer",
                "gpu",
                "--out",
                gpu_path.to_str().expect("utf-8"),
            ][..],
            &common,
        ]
        .concat(),
    );
    if skipped_for_lack_of_gpu("render_writes_the_frame_and_gpu_and_cpu_twin_agree", &out) {
        return;
    }
    assert!(out.status.success(), "render: {}", text(&out.stderr));
    let gpu = image::open(&gpu_path).expect("GPU PNG").to_rgba8();
    let tolerance = Tolerance {
        max_mean: 0.5,
        pixel_threshold: 8,
        max_differing_fraction: 0.01,
    };
    let dir = gpu_path.parent().expect("temp dir");
    compare("cli-gpu-vs-cpu", &gpu, &cpu, &tolerance, dir).unwrap_or_else(|m| panic!("{m}"));
}

#[cfg(target_os = "linux")]
#[test]
fn without_an_adapter_render_names_the_package_to_install() {
    let out = without_adapter(&[
        "render",
        "--renderer",
        "gpu",
        "--phantom-size",
        "16",
        "--out",
        "/dev/null",
    ]);
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(stderr.contains("no GPU adapter found"), "{stderr}");
    assert!(stderr.contains("mesa-vulkan-drivers"), "{stderr}");
    // `--renderer auto`, the default, renders on the CPU instead.
    let png = temp_path("auto.png");
    let out = without_adapter(&[
        "render",
        "--phantom-size",
        "16",
        "--width",
        "32",
        "--height",
        "32",
        "--out",
        png.to_str().expect("utf-8"),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("on CPU renderer"),
        "{}",
        text(&out.stdout)
    );
}

#[test]
fn render_refuses_an_output_it_cannot_write_before_rendering() {
    // Without an adapter any render on the GPU fails; a refusal that names
    // the output proves the output was checked first.
    let run = |out: &str| {
        let out = without_adapter(&[
            "render",
            "--renderer",
            "gpu",
            "--phantom-size",
            "16",
            "--out",
            out,
        ]);
        assert!(!out.status.success());
        text(&out.stderr)
    };
    let stderr = run("/nonexistent-voxserve-folder/x.png");
    assert!(
        stderr.contains("cannot write /nonexistent-voxserve-folder/x.png")
            && !stderr.contains("GPU adapter"),
        "{stderr}"
    );
    let folder = temp_path("output-folder");
    std::fs::create_dir_all(&folder).expect("folder");
    let stderr = run(folder.to_str().expect("UTF-8"));
    assert!(
        stderr.contains("a folder: expected a file name") && !stderr.contains("GPU adapter"),
        "{stderr}"
    );
    // An error is named once, not once per layer.
    let stderr = run("/nonexistent-voxserve-folder/x.png");
    assert_eq!(
        stderr.matches("No such file or directory").count(),
        1,
        "{stderr}"
    );
}

/// A GET of `url` with `token` (if any) by `client`: status and body.
async fn get_with(client: &reqwest::Client, url: &str, token: Option<&str>) -> (u16, String) {
    let mut request = client.get(url);
    if let Some(token) = token {
        request = request.bearer_auth(token);
    }
    let response = request.send().await.expect("an answer");
    (
        response.status().as_u16(),
        response.text().await.expect("a body"),
    )
}

#[tokio::test]
async fn token_then_serve_over_tls_with_api_tokens_a_policy_and_an_audit_log() {
    let dir = tempfile::tempdir().expect("temp");
    let path = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_owned();
    let made = voxserve(&["token", "--name", "ci-script", "--role", "radiology"]);
    assert!(made.status.success(), "{}", text(&made.stderr));
    let token = text(&made.stdout).trim().to_owned();
    let entry = text(&made.stderr)
        .lines()
        .last()
        .expect("the entry")
        .to_owned();
    assert!(
        token.starts_with("vxs_") && !entry.contains(&token[4..]),
        "{entry}"
    );
    std::fs::write(path("tokens.json"), format!("{{\"tokens\": [{entry}]}}")).expect("write");
    std::fs::write(
        path("policy.json"),
        r#"{"rules": [{"roles": ["radiology"], "datasets": ["phantom"]}]}"#,
    )
    .expect("write");
    let certified =
        rcgen::generate_simple_self_signed(vec!["127.0.0.1".to_owned()]).expect("a certificate");
    std::fs::write(path("cert.pem"), certified.cert.pem()).expect("write");
    std::fs::write(path("key.pem"), certified.signing_key.serialize_pem()).expect("write");
    let (tokens, policy, audit, cert, key) = (
        path("tokens.json"),
        path("policy.json"),
        path("audit.jsonl"),
        path("cert.pem"),
        path("key.pem"),
    );
    let args = [
        "serve",
        "--addr",
        "127.0.0.1:0",
        "--phantom-size",
        "32",
        "--renderer",
        "cpu",
        "--api-tokens",
        &tokens,
        "--policy",
        &policy,
        "--audit-log",
        &audit,
        "--tls-cert",
        &cert,
        "--tls-key",
        &key,
    ];
    let server = voxserve_tests::server::Spawned::start(VOXSERVE, &args)
        .await
        .unwrap_or_else(|stderr| panic!("serve exited: {stderr}"));
    assert!(
        server.url.starts_with("https://127.0.0.1:"),
        "{}",
        server.line
    );
    let client = reqwest::Client::builder()
        .tls_certs_only([
            reqwest::Certificate::from_pem(certified.cert.pem().as_bytes()).expect("PEM"),
        ])
        .build()
        .expect("a client");
    let list = format!("{}/api/datasets", server.url);
    assert_eq!(get_with(&client, &list, None).await.0, 401);
    let (status, body) = get_with(&client, &list, Some(&token)).await;
    assert_eq!(status, 200, "{body}");
    assert!(body.contains("\"phantom\""), "{body}");
    // Rotating the audit log: moved away, SIGHUP, the next event goes to a new file.
    std::fs::rename(&audit, path("audit.1")).expect("rotate");
    let hup = Command::new("kill")
        .args(["-HUP", &server.pid().to_string()])
        .status()
        .expect("kill -HUP");
    assert!(hup.success());
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while std::fs::metadata(&audit).is_err() {
        assert!(
            std::time::Instant::now() < deadline,
            "no new audit log after SIGHUP"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let (status, _) = get_with(
        &client,
        &format!("{}/api/datasets/phantom", server.url),
        Some(&token),
    )
    .await;
    assert_eq!(status, 200);
    let stderr = server.stop();
    let old = std::fs::read_to_string(path("audit.1")).expect("the rotated log");
    let new = std::fs::read_to_string(&audit).expect("the new log");
    let events = |text: &str| -> Vec<(String, String)> {
        text.lines()
            .map(|l| {
                let line: serde_json::Value = serde_json::from_str(l).expect("JSON");
                let field = |name: &str| line[name].as_str().unwrap_or("").to_owned();
                (field("event"), field("user"))
            })
            .collect()
    };
    let pair = |e: &str, u: &str| (e.to_owned(), u.to_owned());
    assert_eq!(
        events(&old),
        [pair("authenticate", ""), pair("list", "ci-script")],
        "{stderr}"
    );
    assert_eq!(events(&new), [pair("describe", "ci-script")], "{stderr}");
    assert!(
        !old.contains(&token) && !stderr.contains(&token),
        "a token in a log"
    );
}

#[tokio::test]
async fn serve_prints_its_url_and_renders_the_phantom() {
    // A folder with one brick store: served beside the phantom.
    let dir = tempfile::tempdir().expect("temp");
    let raw = dir.path().join("scan_24x20x18_uint16.raw");
    let bytes: Vec<u8> = (0..24 * 20 * 18u32)
        .flat_map(|i| (((i * 13) % 3000) as u16).to_le_bytes())
        .collect();
    std::fs::write(&raw, bytes).expect("raw");
    let data = dir.path().join("data");
    std::fs::create_dir(&data).expect("data folder");
    std::fs::write(data.join("notes.txt"), "not a store").expect("a stray file");
    for name in ["scan.zarr", "broken.zarr", "leftover.zarr"] {
        let out = voxserve(&[
            "ingest",
            raw.to_str().expect("utf-8"),
            "--out",
            data.join(name).to_str().expect("utf-8"),
        ]);
        assert!(out.status.success(), "ingest: {}", text(&out.stderr));
    }
    // A store missing a shard is not served; what a killed ingest left (a
    // complete store under a hidden name) is reported, never listed.
    let broken_shard = data.join("broken.zarr/0/c/0/0/0");
    std::fs::remove_file(&broken_shard).expect("delete a shard");
    let dead = Command::new("true").spawn().expect("spawn");
    let dead_pid = dead.id();
    let _ = { dead }.wait();
    let leftover = data.join(format!(".scan.zarr.old-{dead_pid}"));
    std::fs::rename(data.join("leftover.zarr"), &leftover).expect("rename");
    let data_arg = data.to_str().expect("utf-8");
    let args = [
        "serve",
        "--addr",
        "127.0.0.1:0",
        "--phantom-size",
        "64",
        "--data",
        data_arg,
    ];
    let server = match voxserve_tests::server::Spawned::start(VOXSERVE, &args).await {
        Ok(server) => server,
        Err(stderr) => {
            if failed_for_lack_of_gpu("serve_prints_its_url_and_renders_the_phantom", &stderr) {
                return;
            }
            panic!("serve exited: {stderr}");
        }
    };
    let (url, line) = (server.url.clone(), server.line.clone());
    let response = reqwest::get(format!("{url}/api/render?w=128&h=128&shading=unshaded"))
        .await
        .expect("GET /api/render");
    assert_eq!(response.status(), 200);
    let bytes = response.bytes().await.expect("body");
    let img = image::load_from_memory(&bytes).expect("PNG").to_rgba8();
    assert_front_view_of_phantom(&img);
    let bad = reqwest::get(format!("{url}/api/render?w=0"))
        .await
        .expect("GET");
    assert_eq!(bad.status(), 400);
    let again = reqwest::get(format!("{url}/api/render?w=32&h=32"))
        .await
        .expect("GET");
    assert_eq!(again.status(), 200, "still serving after a bad request");
    assert!(line.contains("phantom") && line.contains("scan"), "{line}");
    let list: serde_json::Value = serde_json::from_str(
        &reqwest::get(format!("{url}/api/datasets"))
            .await
            .expect("GET")
            .text()
            .await
            .expect("body"),
    )
    .expect("JSON");
    let ids: Vec<&str> = list
        .as_array()
        .expect("a list")
        .iter()
        .filter_map(|d| d["id"].as_str())
        .collect();
    assert_eq!(ids, ["phantom", "scan"]);
    let scan = reqwest::get(format!(
        "{url}/api/datasets/scan/render?w=32&h=24&preset=generic"
    ))
    .await
    .expect("GET");
    assert_eq!(scan.status(), 200);
    let img = image::load_from_memory(&scan.bytes().await.expect("body"))
        .expect("PNG")
        .to_rgba8();
    assert_eq!(img.dimensions(), (32, 24));
    let log = server.stop();
    assert!(
        log.contains("not serving")
            && log.contains(&format!("{}: missing", broken_shard.display())),
        "{log}"
    );
    assert!(
        log.contains(&format!(
            "{}: left by an ingest of scan.zarr",
            leftover.display()
        )),
        "{log}"
    );
}

#[test]
fn info_prints_what_a_file_holds_as_text_and_json() {
    let Some(data) =
        voxserve_tests::data::shared_data("info_prints_what_a_file_holds_as_text_and_json")
    else {
        return;
    };
    let engine = data.join("raw/engine_256x256x128_uint8.raw");
    let out = voxserve(&["info", engine.to_str().expect("utf-8")]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    for line in [
        "format:      raw",
        "dims:        256 × 256 × 128 voxels",
        "voxel type:  uint8",
        "values:      0 … 255, mean ",
    ] {
        assert!(stdout.contains(line), "missing '{line}' in:\n{stdout}");
    }
    let vhf = data.join("dicom/vhf_head");
    let out = voxserve(&["info", "--json", vhf.to_str().expect("utf-8")]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(json["dims"], serde_json::json!([512, 512, 234]));
    assert_eq!(json["voxel_type"], "int16");
    assert_eq!(json["unit"], "HU");
    assert_eq!(json["value_range"][0], -1024.0);
    assert_eq!(json["series"].as_array().map(Vec::len), Some(1));
    // The mean beside the physical range is physical too (HU here).
    let number = |key: &str| {
        json[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key}: {json}"))
    };
    let physical = number("mean_stored") * json["value_map"]["slope"].as_f64().expect("slope")
        + json["value_map"]["intercept"].as_f64().expect("intercept");
    assert!((number("mean") - physical).abs() < 1e-6, "{json}");
    assert!(number("mean") < number("mean_stored"), "{json}");

    let out = voxserve(&[
        "info",
        data.join("raw/cthead_256x256x113_uint16be.raw")
            .to_str()
            .expect("utf-8"),
        "--raw-endian",
        "little",
    ]);
    assert!(out.status.success(), "the flag overrides the name");
    let missing = voxserve(&["info", "/no/such/volume.nrrd"]);
    assert!(!missing.status.success());
    assert!(
        text(&missing.stderr).contains("/no/such/volume.nrrd"),
        "{}",
        text(&missing.stderr)
    );
}

#[test]
fn render_reads_a_volume_file() {
    let Some(data) = voxserve_tests::data::shared_data("render_reads_a_volume_file") else {
        return;
    };
    let nucleon = data.join("nrrd/nucleon.nrrd");
    let out_path = temp_path("nucleon.png");
    let out = voxserve(&[
        "render",
        nucleon.to_str().expect("utf-8"),
        "--renderer",
        "cpu",
        "--width",
        "64",
        "--height",
        "64",
        "--out",
        out_path.to_str().expect("utf-8"),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let img = image::open(&out_path).expect("PNG").to_rgba8();
    assert!(
        voxserve_tests::checks::coverage(&img) > 0.05,
        "the nucleon is in the frame"
    );
}

#[test]
fn ingest_writes_a_store_and_a_killed_ingest_leaves_none() {
    let dir = tempfile::tempdir().expect("temp");
    // A 40 × 30 × 70 uint16 raw volume, five slabs of 16 slices.
    let raw = dir.path().join("scan_40x30x70_uint16.raw");
    let bytes: Vec<u8> = (0..40 * 30 * 70u32)
        .flat_map(|i| (((i * 7) % 4000) as u16).to_le_bytes())
        .collect();
    std::fs::write(&raw, bytes).expect("raw");
    let store = dir.path().join("scan.zarr");
    let (raw_arg, store_arg) = (raw.to_str().expect("utf-8"), store.to_str().expect("utf-8"));

    // Killed after two slabs (the process aborts as a crash or SIGKILL would).
    let out = Command::new(VOXSERVE)
        .args(["ingest", raw_arg, "--out", store_arg])
        .env("VOXSERVE_FAULT_ABORT", "after-slabs:2")
        .output()
        .expect("run");
    assert!(!out.status.success(), "the ingest was aborted");
    assert!(!store.exists(), "no store at the destination");
    let partial: Vec<_> = std::fs::read_dir(dir.path())
        .expect("dir")
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().contains(".partial-"))
        .collect();
    assert_eq!(
        partial.len(),
        1,
        "the crash left its temporary folder behind"
    );
    let err = blocks::store::Store::open(partial[0].path())
        .expect_err("an unfinished store does not open");
    assert!(err.to_string().contains("did not finish"), "{err}");

    // A complete ingest, then a refused overwrite, then --force.
    let out = voxserve(&["ingest", raw_arg, "--out", store_arg]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let summary = text(&out.stdout);
    assert!(
        summary.contains("40 × 30 × 70 uint16 voxels")
            && summary.contains("compression")
            && summary.contains("MB/s"),
        "{summary}"
    );
    let store_ok = blocks::store::Store::open(&store).expect("opens");
    assert_eq!(store_ok.meta().geometry.dims, [40, 30, 70]);
    let left = std::fs::read_dir(dir.path())
        .expect("dir")
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().contains(".partial-"))
        .count();
    assert_eq!(
        left, 0,
        "the next ingest removed the dead one's temporary folder"
    );
    let again = voxserve(&["ingest", raw_arg, "--out", store_arg]);
    assert!(!again.status.success());
    assert!(
        text(&again.stderr).contains("--force"),
        "{}",
        text(&again.stderr)
    );
    let forced = voxserve(&["ingest", raw_arg, "--out", store_arg, "--force"]);
    assert!(forced.status.success(), "{}", text(&forced.stderr));
}

/// Writes a `nx × ny × nz` uint16 raw volume named for its size into `dir`.
fn raw_volume(dir: &std::path::Path, [nx, ny, nz]: [u32; 3]) -> PathBuf {
    let raw = dir.join(format!("scan_{nx}x{ny}x{nz}_uint16.raw"));
    let bytes: Vec<u8> = (0..nx * ny * nz)
        .flat_map(|i| (((i * 7) % 4000) as u16 + 1).to_le_bytes())
        .collect();
    std::fs::write(&raw, bytes).expect("raw");
    raw
}

#[test]
fn ingest_force_killed_at_any_step_leaves_a_complete_store_that_verify_accepts() {
    let dir = tempfile::tempdir().expect("temp");
    let old = raw_volume(dir.path(), [40, 30, 70]);
    let new = raw_volume(dir.path(), [40, 30, 90]);
    let store = dir.path().join("scan.zarr");
    let store_arg = store.to_str().expect("utf-8");
    // `ingest SOURCE --out scan.zarr --force`, aborted at `fault` if given.
    let ingest_force = |source: &PathBuf, fault: Option<&str>| {
        let mut command = Command::new(VOXSERVE);
        command.args([
            "ingest",
            source.to_str().expect("utf-8"),
            "--out",
            store_arg,
            "--force",
        ]);
        if let Some(point) = fault {
            command.env("VOXSERVE_FAULT_ABORT", point);
        }
        command.output().expect("run")
    };
    let hidden = || -> Vec<String> {
        std::fs::read_dir(dir.path())
            .expect("dir")
            .filter_map(Result::ok)
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with('.'))
            .collect()
    };
    for point in [
        "after-slabs:2",
        "before-manifest",
        "before-replace",
        "after-exchange",
        "after-move-aside",
    ] {
        let first = ingest_force(&old, None);
        assert!(first.status.success(), "{}", text(&first.stderr));
        // Killed (the process aborts as SIGKILL or a crash would) at `point`.
        let killed = ingest_force(&new, Some(point));
        assert!(!killed.status.success(), "{point}: aborted");
        let verified = voxserve(&["verify", store_arg]);
        assert!(
            verified.status.success() && text(&verified.stdout).contains(": intact: "),
            "{point}: {}{}",
            text(&verified.stdout),
            text(&verified.stderr)
        );
        let dims = blocks::store::Store::open(&store)
            .expect("opens")
            .meta()
            .geometry
            .dims;
        let expected = if point.starts_with("after-e") || point.starts_with("after-m") {
            [40, 30, 90]
        } else {
            [40, 30, 70]
        };
        assert_eq!(
            dims, expected,
            "{point}: the old store until the exchange, then the new"
        );
        let left = hidden();
        assert_eq!(left.len(), 1, "{point}: one leftover: {left:?}");
        assert!(
            blocks::store::ingest::leftover_of(&left[0]).is_some(),
            "{point}: {left:?}"
        );
    }
    // The next ingest removes what the killed one left.
    let last = ingest_force(&old, None);
    assert!(last.status.success(), "{}", text(&last.stderr));
    let left = hidden();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn info_render_and_verify_name_a_missing_shard_and_info_counts_every_file() {
    let dir = tempfile::tempdir().expect("temp");
    let raw = raw_volume(dir.path(), [20, 20, 150]);
    let store = dir.path().join("scan.zarr");
    let store_arg = store.to_str().expect("utf-8");
    let out = voxserve(&["ingest", raw.to_str().expect("utf-8"), "--out", store_arg]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    // The size counts every file, the statistics and metadata included.
    let out = voxserve(&["info", "--json", store_arg]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let usage = blocks::store::ingest::folder_usage(&store);
    let stats_bytes = blocks::store::ingest::folder_usage(&store.join("voxserve")).bytes;
    assert!(stats_bytes > 0);
    assert_eq!(json["store_bytes"], usage.bytes);
    assert_eq!(json["store_files"], usage.files);
    let info = text(&voxserve(&["info", store_arg]).stdout);
    let raw_mb = 20.0 * 20.0 * 150.0 * 2.0 / 1e6;
    let ratio = raw_mb / (usage.bytes as f64 / 1e6);
    assert!(
        ratio < 1.0,
        "a tiny volume's store is larger than its voxels"
    );
    assert!(info.contains(&format!("({ratio:.2}:1)")), "{info}");

    let shard = store.join("0/c/1/0/0");
    std::fs::remove_file(&shard).expect("delete");
    let named = format!("{}: missing", shard.display());
    for args in [
        vec!["info", store_arg],
        vec!["verify", store_arg],
        vec![
            "render",
            store_arg,
            "--width",
            "16",
            "--height",
            "16",
            "--out",
            "/dev/null",
        ],
    ] {
        let out = voxserve(&args);
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(stderr.contains(&named), "{args:?}: {stderr}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_drains_on_sigterm_and_exits_at_once_when_stopped_again() {
    let args = [
        "serve",
        "--addr",
        "127.0.0.1:0",
        "--phantom-size",
        "128",
        "--renderer",
        "cpu",
    ];
    let server = voxserve_tests::server::Spawned::start(VOXSERVE, &args)
        .await
        .unwrap_or_else(|stderr| panic!("serve did not start: {stderr}"));
    // A frame that takes seconds: the drain waits for it.
    let big = format!("{}/api/render?w=4096&h=4096&step=0.25", server.url);
    let big = tokio::spawn(async move { reqwest::get(&big).await.map(|r| r.status()) });
    tokio::time::sleep(Duration::from_millis(500)).await;
    server.terminate();
    let server = server
        .wait_exit(Duration::from_secs(1))
        .expect_err("the server waits for the frame in flight");
    // It accepts no more connections meanwhile.
    assert!(
        reqwest::get(format!("{}/healthz", server.url))
            .await
            .is_err(),
        "a draining server accepted a connection"
    );
    server.terminate();
    let Ok((status, stderr)) = server.wait_exit(Duration::from_secs(10)) else {
        panic!("stopped twice, the server did not exit within 10 s");
    };
    assert_eq!(status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("draining") && stderr.contains("exiting at once"),
        "{stderr}"
    );
    // The frame was cut off with the process.
    assert!(big.await.expect("the request task").is_err());
}

/// The JSON lines of `bench` output whose `bench` field is `kind`.
fn bench_lines(stdout: &str, kind: &str) -> Vec<serde_json::Value> {
    stdout
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| v["bench"] == kind)
        .collect()
}

#[test]
fn bench_extinction_times_the_cpu_renderer_s_stages() {
    let args = [
        "bench",
        "extinction",
        "--renderer",
        "cpu",
        "--datasets",
        "phantom",
        "--phantom-size",
        "32",
        "--sat-sizes",
        "16",
        "--shells",
        "2",
        "--ao-radius",
        "2",
        "--cone-frequencies",
        "20",
        "--size",
        "32",
        "--frames",
        "1",
        "--repeats",
        "1",
    ];
    let out = voxserve(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    for (kind, field) in [
        ("extinction-sat", "sat_ms"),
        ("extinction-ao", "ao_ms"),
        ("extinction-ao", "sampled_ms"),
        ("extinction-shadow", "soft_shadow_ms"),
        ("extinction-shadow", "shadow_ray_ms"),
        ("extinction-frame", "lit_ms"),
    ] {
        let lines = bench_lines(&stdout, kind);
        assert_eq!(lines.len(), 1, "{kind}: {stdout}");
        let line = &lines[0];
        assert_eq!(line["renderer"], "cpu", "{line}");
        // Every stage ran and was timed (a stage the CPU renderer did not
        // report would fail the benchmark or read 0).
        assert!(
            line[field].as_f64().is_some_and(|ms| ms > 0.0),
            "{kind}.{field}: {line}"
        );
    }
}

#[test]
fn bench_out_of_core_ingests_a_generated_volume_then_serves_it_and_serves_it_again() {
    let dir = tempfile::tempdir().expect("temp");
    let store = dir.path().join("generated.zarr");
    let store_arg = store.to_str().expect("utf-8");
    // 64 × 64 slices of 16-bit voxels, as many as make 4 MiB: 512.
    let args = [
        "bench",
        "out-of-core",
        "--out",
        store_arg,
        "--gib",
        "0.00390625",
        "--slice-edge",
        "64",
        "--views",
        "2",
        "--size",
        "64",
        "--renderer",
        "cpu",
    ];
    let out = voxserve(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    let ingest = bench_lines(&stdout, "out-of-core-ingest");
    assert_eq!(ingest.len(), 1, "{stdout}");
    assert_eq!(
        ingest[0]["dims"],
        serde_json::json!([64, 64, 512]),
        "{stdout}"
    );
    assert!(
        ingest[0]["peak_rss_mib"].as_f64().is_some_and(|m| m > 0.0),
        "{stdout}"
    );
    let opened = blocks::store::Store::open(&store).expect("the store opens");
    assert_eq!(opened.meta().geometry.dims, [64, 64, 512]);
    assert_eq!(opened.meta().unit.as_deref(), Some("HU"));

    let served = |stdout: &str| {
        let views = bench_lines(stdout, "out-of-core-view");
        // The first view, full detail, and the orbit's two (the second with a preset).
        assert_eq!(views.len(), 4, "{stdout}");
        for view in &views {
            let first = view["first_frame_ms"].as_f64().expect("a first frame");
            let converged = view["converged_ms"].as_f64().expect("a converged frame");
            assert!(first <= converged, "{view}");
            assert!(view["rss_mib"].as_f64().is_some_and(|m| m > 0.0), "{view}");
        }
        assert!(views[0]["open_ms"].as_f64().is_some(), "{stdout}");
        assert!(
            views[3]["view"]
                .as_str()
                .is_some_and(|v| v.contains("preset ct-angio")),
            "{stdout}"
        );
        let summary = bench_lines(stdout, "out-of-core-serve");
        assert_eq!(summary.len(), 1, "{stdout}");
        assert!(
            summary[0]["peak_rss_mib"].as_f64().is_some_and(|m| m > 0.0),
            "{stdout}"
        );
    };
    served(&stdout);

    // Again without --force: the store is not replaced.
    let again = voxserve(&args);
    assert!(!again.status.success(), "{}", text(&again.stdout));
    assert!(
        text(&again.stderr).contains("--force"),
        "{}",
        text(&again.stderr)
    );
    // --reuse serves the store the first run left, without ingesting.
    let mut reuse = args.to_vec();
    reuse.push("--reuse");
    let out = voxserve(&reuse);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(
        bench_lines(&stdout, "out-of-core-ingest").is_empty(),
        "{stdout}"
    );
    served(&stdout);
}
