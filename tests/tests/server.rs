//! End-to-end tests of the HTTP API against a real server on port 0.

#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use voxserve_tests::checks::assert_front_view_of_phantom;
use voxserve_tests::gpu_or_skip;
use voxserve_tests::server::TestServer;

async fn get(url: &str) -> reqwest::Response {
    reqwest::get(url)
        .await
        .unwrap_or_else(|e| panic!("GET {url}: {e}"))
}

#[tokio::test]
async fn render_returns_a_png_in_which_the_phantom_is_visible() {
    let Some(gpu) = gpu_or_skip("render_returns_a_png_in_which_the_phantom_is_visible") else {
        return;
    };
    let server = TestServer::start(gpu, 64).await;
    let response =
        get(&server.url("/api/render?az=0&el=0&w=128&h=96&preset=ct-bone&shading=unshaded")).await;
    assert_eq!(response.status(), 200);
    assert_eq!(
        response.headers()["content-type"],
        "image/png",
        "content type"
    );
    assert!(response.headers().contains_key("x-render-ms"));
    let bytes = response.bytes().await.expect("body");
    let img = image::load_from_memory(&bytes)
        .expect("a decodable PNG")
        .to_rgba8();
    assert_eq!(img.dimensions(), (128, 96));
    let (coverage, mirror) = assert_front_view_of_phantom(&img);
    println!("phantom covers {coverage:.3} of the frame; mirror difference {mirror:.3}");
}

#[tokio::test]
async fn the_view_changes_with_the_camera() {
    let Some(gpu) = gpu_or_skip("the_view_changes_with_the_camera") else {
        return;
    };
    let server = TestServer::start(gpu, 64).await;
    let frame = |q: &'static str| {
        let url = server.url(&format!("/api/render?w=64&h=64&preset=ct-soft-tissue&{q}"));
        async move {
            let bytes = get(&url).await.bytes().await.expect("body");
            image::load_from_memory(&bytes).expect("PNG").to_rgba8()
        }
    };
    let front = frame("az=0").await;
    // A fit answers with its camera, which draws the same frame again.
    let url = server.url("/api/render?w=64&h=64&preset=ct-soft-tissue&az=30&fit=true");
    let response = get(&url).await;
    let camera = response.headers()["x-camera"]
        .to_str()
        .expect("text")
        .to_owned();
    assert!(
        camera.contains("fit=false") && camera.contains("tx="),
        "{camera}"
    );
    let fitted = response.bytes().await.expect("body");
    let again = get(&server.url(&format!(
        "/api/render?w=64&h=64&preset=ct-soft-tissue&{camera}"
    )))
    .await
    .bytes()
    .await
    .expect("body");
    assert_eq!(fitted, again, "the camera {camera} draws the fitted frame");
    let side = frame("az=90").await;
    let near = frame("az=0&dist=1.5").await;
    let (d_side, _) = voxserve_tests::image_compare::measure(&front, &side, 8);
    let (d_near, _) = voxserve_tests::image_compare::measure(&front, &near, 8);
    assert!(d_side.differing_fraction > 0.05, "side view: {d_side:?}");
    assert!(d_near.differing_fraction > 0.05, "closer view: {d_near:?}");
    let cov = voxserve_tests::checks::coverage;
    assert!(
        cov(&near) > cov(&front),
        "a closer camera shows a bigger phantom"
    );
}

#[tokio::test]
async fn bad_queries_get_400_with_a_message_and_the_server_keeps_serving() {
    let Some(gpu) = gpu_or_skip("bad_queries_get_400_with_a_message_and_the_server_keeps_serving")
    else {
        return;
    };
    let server = TestServer::start(gpu, 32).await;
    let cases = [
        ("w=0", "w=\"0\""),
        ("w=100000", "w=\"100000\""),
        ("h=abc", "h=\"abc\""),
        (
            "preset=nonsense",
            "preset=\"nonsense\": expected one of ct-bone",
        ),
        ("az=north", "az=\"north\""),
        ("el=NaN", "el=\"NaN\""),
        ("dist=-1", "dist=\"-1\""),
        ("dataset=engine", "dataset=\"engine\""),
        ("colour=red", "unknown query parameter 'colour'"),
        ("w=64&w=64", "given twice"),
        (
            "clip=0,0,0,1,1",
            "clip=\"0,0,0,1,1\": expected six fractions",
        ),
        ("reduction=0", "reduction=\"0\""),
        (
            "proj=fisheye",
            "proj=\"fisheye\": expected one of perspective or orthographic",
        ),
        ("bg=xyz", "bg=\"xyz\": expected six hex digits"),
        ("shading=phong", "shading=\"phong\": expected one of"),
        (
            "shading=global&light=spot:0,0,1",
            "light=\"spot:0,0,1\": expected point:x,y,z",
        ),
        ("shading=global&svr=3", "svr=\"3\""),
        ("shading=global&segment=64", "segment=\"64\""),
        ("shading=global&bias=2", "bias=\"2\""),
        ("shading=global&directions=0", "directions=\"0\""),
        (
            "shading=extinction&lights=lamp:0,0,0",
            "light 'lamp:0,0,0': unknown kind",
        ),
        (
            "shading=extinction&ao_radius=2&ao_shells=3",
            "ao_shells=3: expected",
        ),
        ("shading=extinction&sat_size=1000", "sat_size=\"1000\""),
        ("shading=extinction&cone_growth=-1", "cone_growth=\"-1\""),
        (
            "compositing=over",
            "compositing=\"over\": expected one of alpha or extinction",
        ),
    ];
    for (query, expected) in cases {
        let response = get(&server.url(&format!("/api/render?{query}"))).await;
        assert_eq!(response.status(), 400, "{query}");
        let body: serde_json::Value = response.json_body().await;
        let message = body["error"].as_str().unwrap_or_default();
        assert!(message.contains(expected), "{query}: {message}");
    }
    let ok = get(&server.url("/api/render?w=32&h=32")).await;
    assert_eq!(
        ok.status(),
        200,
        "the server still renders after bad requests"
    );
}

#[tokio::test]
async fn every_shading_projection_clip_and_reduction_renders() {
    let Some(gpu) = gpu_or_skip("every_shading_projection_clip_and_reduction_renders") else {
        return;
    };
    let server = TestServer::start(gpu, 64).await;
    for query in [
        "shading=mip&proj=orthographic",
        "shading=minip&bg=203040",
        "shading=unshaded&clip=0,0,0,1,0.5,1",
        "shading=gradient&reduction=9",
        "shading=extinction&sat_size=24&ao_radius=3&colour_bleeding=true\
         &lights=point:0.5,0.5,0.5:ff8000:1;spot:1.5,0.5,0.5:-1,0,0:30:4080ff:1",
        "shading=extinction&compositing=extinction&sat_size=16&lights=",
    ] {
        let response = get(&server.url(&format!("/api/render?w=64&h=48&{query}"))).await;
        assert_eq!(response.status(), 200, "{query}");
        let reduction: f64 = response.headers()["x-reduction"]
            .to_str()
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{query}: X-Reduction"));
        let levels = response.headers()["x-levels"]
            .to_str()
            .unwrap_or_default()
            .to_owned();
        let bytes = response.bytes().await.expect("body");
        let img = image::load_from_memory(&bytes).expect("PNG").to_rgba8();
        assert_eq!(img.dimensions(), (64, 48), "{query}");
        println!("{query}: reduction {reduction}:1, levels {levels}");
        if query.contains("reduction=9") {
            assert!(reduction >= 8.5, "{query}: {reduction}");
        }
    }
}

#[tokio::test]
async fn global_light_refines_one_direction_per_request_and_keeps_the_light_when_the_camera_moves()
{
    let Some(gpu) = gpu_or_skip(
        "global_light_refines_one_direction_per_request_and_keeps_the_light_when_the_camera_moves",
    ) else {
        return;
    };
    let server = TestServer::start(gpu, 32).await;
    let base = "w=48&h=48&shading=global&scatter_radius=4&directions=3&svr=2";
    let query = format!("{base}&light=point:0.5,0.5,1.4");
    let refinement = |response: &reqwest::Response| {
        response.headers()["x-refinement"]
            .to_str()
            .unwrap_or_default()
            .to_owned()
    };
    let mut seen = Vec::new();
    for az in [0, 0, 40, 40] {
        let response = get(&server.url(&format!("/api/render?{query}&az={az}"))).await;
        assert_eq!(response.status(), 200, "az={az}");
        assert!(
            response.headers().contains_key("x-light-ms"),
            "az={az}: X-Light-Ms"
        );
        seen.push(refinement(&response));
    }
    // The first request computes the light with one direction, each later one
    // adds a direction, and moving the camera keeps what is computed.
    assert_eq!(seen, ["1/3", "2/3", "3/3", "3/3"]);
    let changed = get(&server.url(&format!("/api/render?{query}&bias=0.3"))).await;
    assert_eq!(refinement(&changed), "3/3", "I_bias applies at render time");
    let moved = get(&server.url(&format!("/api/render?{base}&light=point:0.5,0.5,1.6"))).await;
    assert_eq!(moved.status(), 200);
    assert_eq!(refinement(&moved), "1/3", "a moved light is recomputed");
}

#[tokio::test]
async fn concurrent_requests_are_all_answered() {
    let Some(gpu) = gpu_or_skip("concurrent_requests_are_all_answered") else {
        return;
    };
    let server = TestServer::start(gpu, 32).await;
    let requests = (0..6).map(|i| {
        let url = server.url(&format!("/api/render?w=48&h=48&az={}", i * 60));
        tokio::spawn(async move { get(&url).await.status() })
    });
    for handle in requests {
        assert_eq!(handle.await.expect("request task"), 200);
    }
}

#[tokio::test]
async fn the_web_client_and_dataset_list_are_served() {
    let Some(gpu) = gpu_or_skip("the_web_client_and_dataset_list_are_served") else {
        return;
    };
    let server = TestServer::start(gpu, 32).await;
    let index = get(&server.url("/")).await;
    assert_eq!(index.status(), 200);
    assert!(
        index.headers()["content-type"]
            .to_str()
            .unwrap_or_default()
            .starts_with("text/html")
    );
    let html = index.text().await.expect("body");
    assert!(
        html.contains("app.js"),
        "index.html loads the client module"
    );
    for module in ["/app.js", "/camera.js", "/stream.js"] {
        let r = get(&server.url(module)).await;
        assert_eq!(r.status(), 200, "{module}");
        let ct = r.headers()["content-type"]
            .to_str()
            .unwrap_or_default()
            .to_owned();
        assert!(ct.contains("javascript"), "{module}: {ct}");
    }
    assert_eq!(get(&server.url("/no-such-file.js")).await.status(), 404);

    let datasets: serde_json::Value = get(&server.url("/api/datasets")).await.json_body().await;
    let phantom = &datasets[0];
    assert_eq!(phantom["id"], "phantom");
    assert_eq!(phantom["dims"], serde_json::json!([32, 32, 32]));
    assert_eq!(phantom["unit"], "HU");
    // The camera's unit of distance: half the diagonal of the volume's box.
    let half_diagonal = (0..3)
        .map(|a| {
            let side = phantom["dims"][a].as_f64().unwrap_or(0.0)
                * phantom["spacing"][a].as_f64().unwrap_or(0.0);
            side * side
        })
        .sum::<f64>()
        .sqrt()
        / 2.0;
    let radius = phantom["radius_mm"].as_f64().unwrap_or(0.0);
    assert!(
        (radius - half_diagonal).abs() < 1e-3 * half_diagonal,
        "radius_mm {radius}, half diagonal {half_diagonal}"
    );
    assert_eq!(phantom["default_preset"], "ct-bone");
    assert!(phantom["presets"].as_array().is_some_and(|p| p.len() == 4));
    // The histogram counts every voxel once, over the value range in HU.
    let counts: u64 = phantom["histogram"]
        .as_array()
        .expect("a histogram")
        .iter()
        .filter_map(serde_json::Value::as_u64)
        .sum();
    assert_eq!(counts, 32 * 32 * 32);
    let range = phantom["histogram_range"].as_array().expect("a range");
    assert!(range[0].as_f64() < range[1].as_f64(), "{range:?}");
    let health: serde_json::Value = get(&server.url("/healthz")).await.json_body().await;
    assert_eq!(health["status"], "ok");
}

#[tokio::test]
async fn one_dataset_is_described_and_rendered_by_its_path_and_metrics_count_the_frames() {
    let Some(gpu) = gpu_or_skip(
        "one_dataset_is_described_and_rendered_by_its_path_and_metrics_count_the_frames",
    ) else {
        return;
    };
    let server = TestServer::start(gpu, 32).await;
    let one: serde_json::Value = get(&server.url("/api/datasets/phantom"))
        .await
        .json_body()
        .await;
    assert_eq!(one["id"], "phantom");
    let missing = get(&server.url("/api/datasets/lung")).await;
    assert_eq!(missing.status(), 404);
    let body = missing.json_body().await;
    assert!(
        body["error"]
            .as_str()
            .unwrap_or_default()
            .contains("dataset 'lung'"),
        "{body}"
    );
    let thumbnail = get(&server.url("/api/datasets/phantom/render?w=40&h=30&az=20")).await;
    assert_eq!(thumbnail.status(), 200);
    let img = image::load_from_memory(&thumbnail.bytes().await.expect("body"))
        .expect("PNG")
        .to_rgba8();
    assert_eq!(img.dimensions(), (40, 30));
    assert_eq!(
        get(&server.url("/api/datasets/lung/render?w=8&h=8"))
            .await
            .status(),
        404
    );
    let twice = get(&server.url("/api/datasets/phantom/render?dataset=phantom")).await;
    assert_eq!(twice.status(), 400);

    let metrics = get(&server.url("/metrics")).await;
    assert_eq!(metrics.status(), 200);
    assert!(
        metrics.headers()["content-type"]
            .to_str()
            .unwrap_or_default()
            .starts_with("application/openmetrics-text")
    );
    let text = metrics.text().await.expect("body");
    for expected in [
        "voxserve_frames_total{source=\"http\",quality=\"full\"} 1",
        "voxserve_sessions_open 0",
        "voxserve_render_seconds_count 1",
        "voxserve_encode_seconds_count{format=\"png\"} 1",
        "voxserve_block_cache_misses",
        "# EOF",
    ] {
        assert!(
            text.contains(expected),
            "/metrics lacks {expected}:\n{text}"
        );
    }
}

/// The image `/api/render?{query}` answers, as RGBA.
async fn render_png(server: &TestServer, query: &str) -> image::RgbaImage {
    let r = get(&server.url(&format!("/api/render?{query}"))).await;
    assert_eq!(r.status(), 200, "{query}");
    image::load_from_memory(&r.bytes().await.expect("body"))
        .expect("PNG")
        .to_rgba8()
}

/// The 90th percentile of the greys brighter than the black background.
fn bright_foreground(img: &image::RgbaImage) -> Option<u8> {
    let mut shown: Vec<u8> = img.pixels().map(|p| p.0[0]).filter(|&g| g > 0).collect();
    shown.sort_unstable();
    shown.get(shown.len() * 9 / 10).copied()
}

#[tokio::test]
async fn mip_and_minip_are_greyscale_through_the_window() {
    let test = "mip_and_minip_are_greyscale_through_the_window";
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let server = TestServer::start(gpu, 48).await;
    let view = "w=64&h=64&az=0&el=0&preset=ct-bone&fit=true";
    for shading in ["mip", "minip"] {
        let img = render_png(&server, &format!("{view}&shading={shading}")).await;
        let coloured = img
            .pixels()
            .filter(|p| p.0[0] != p.0[1] || p.0[1] != p.0[2])
            .count();
        assert_eq!(coloured, 0, "{shading}: every pixel grey");
        assert!(
            bright_foreground(&img).is_some(),
            "{shading}: something shows"
        );
    }
    // ct-bone shows 150 to 2000 HU: the phantom's bone (1000 HU, the
    // brightest tenth of the pixels) is a middle grey by default; a window
    // from -100 to 100 HU makes it white, one centred on it a middle grey.
    let mip = |window: &str| format!("{view}&shading=mip{window}");
    let grey = |img: &image::RgbaImage| bright_foreground(img).unwrap_or(0);
    let default = grey(&render_png(&server, &mip("")).await);
    let narrow = grey(&render_png(&server, &mip("&window=0,200")).await);
    let centred = grey(&render_png(&server, &mip("&window=1000,400")).await);
    println!(
        "MIP 90th-percentile grey: default {default}, window 0,200 {narrow}, 1000,400 {centred}"
    );
    assert!((80..=150).contains(&default), "default window: {default}");
    assert_eq!(narrow, 255, "bone above the window is white");
    assert!((70..=180).contains(&centred), "centred window: {centred}");
}

/// The names of a dataset's presets as `/api/datasets` lists them.
fn preset_names(dataset: &serde_json::Value) -> Vec<String> {
    dataset["presets"]
        .as_array()
        .map(|all| {
            all.iter()
                .filter_map(|p| p["name"].as_str().map(str::to_owned))
                .collect()
        })
        .unwrap_or_default()
}

#[tokio::test]
async fn presets_suit_the_data_and_a_ct_preset_on_other_data_is_refused_by_name() {
    let test = "presets_suit_the_data_and_a_ct_preset_on_other_data_is_refused_by_name";
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    // The head's values with no modality or unit, as from a raw file.
    let plain = {
        let mut volume = blocks::phantom::head(24).expect("head");
        volume.modality = None;
        volume.unit = None;
        volume.name = "plain".into();
        voxserve_tests::render::dataset_of(volume)
    };
    let phantom = server::Dataset::phantom(24, 64 << 20).expect("phantom");
    let server = TestServer::with_datasets(
        gpu,
        vec![phantom, plain],
        2,
        server::stream::StreamSettings::default(),
    )
    .await;
    let datasets: serde_json::Value = get(&server.url("/api/datasets")).await.json_body().await;
    assert_eq!(
        preset_names(&datasets[0]),
        ["ct-bone", "ct-soft-tissue", "ct-angio", "generic"]
    );
    assert_eq!(datasets[1]["id"], "plain");
    assert_eq!(preset_names(&datasets[1]), ["generic"]);
    assert_eq!(datasets[1]["default_preset"], "generic");

    let refused =
        get(&server.url("/api/render?dataset=plain&preset=ct-soft-tissue&w=16&h=16")).await;
    assert_eq!(refused.status(), 400);
    let message = refused.json_body().await["error"]
        .as_str()
        .unwrap_or_default()
        .to_owned();
    println!("{message}");
    for part in [
        "preset",
        "ct-soft-tissue",
        "one of generic",
        "'plain'",
        "CT in HU",
    ] {
        assert!(message.contains(part), "{part:?} in {message}");
    }
    for ok in [
        "/api/render?dataset=plain&preset=generic&w=16&h=16",
        "/api/render?dataset=plain&w=16&h=16",
        "/api/render?dataset=phantom&preset=ct-angio&w=16&h=16",
    ] {
        assert_eq!(get(&server.url(ok)).await.status(), 200, "{ok}");
    }
}

/// JSON bodies without reqwest's `json` feature.
trait JsonBody {
    async fn json_body(self) -> serde_json::Value;
}

impl JsonBody for reqwest::Response {
    async fn json_body(self) -> serde_json::Value {
        let text = self.text().await.expect("body");
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("not JSON ({e}): {text}"))
    }
}
