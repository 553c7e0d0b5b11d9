//! The web client in a real headless Chromium (Debian's `chromium` and
//! `chromium-driver`, driven through WebDriver with fantoccini) against a real
//! server on port 0: the page draws a frame, a drag orbits the camera and
//! brings a new frame, switching the preset brings another, extinction shading
//! another, a drag with "Drag moves the light" ticked moves the light (a new
//! frame, new pixels), and a phone-sized window (390×844) gets a frame of its
//! own with nothing wider than the screen. On failure a screenshot is written
//! to `target/tmp/TEST.png`.
//!
//! A login test serves with OpenID Connect authentication against the test
//! issuer ([`voxserve_tests::issuer`]): the page goes to the issuer's login,
//! comes back with a code, exchanges it with its PKCE verifier, and draws a
//! frame; a launch URL with `access_token=` draws one too and leaves no token
//! in the address bar.
//!
//! A second test serves from the CPU renderer (`--renderer cpu`) and counts
//! the frames a 2-second drag brings: at least 5, with no other browser test
//! running meanwhile (the tests hold the machine shared, that one alone). A
//! third holds the one session place of a server: the page names the full
//! server in a banner below the toolbar, tries again at most 3 times in 7 s,
//! and draws once the place frees. A fourth restarts the server on the same
//! port without the dataset the page shows: the page
//! switches to one the new server offers and draws it at its own size. A
//! fifth loads the page through nginx (Debian's) in front of two nodes,
//! drags the view round, shuts down the node serving it: the page reconnects
//! through nginx to the other node and shows the same lossless frame.
//!
//! At 1400×900 a window/level drag across the transfer-function editor keeps
//! it on the histogram, and the preset chosen again restores it; the status
//! line speaks in words, the hint shows how to move the view, panels open
//! over the image and sliders show their values and apply while moving. At
//! 390×844 with touch emulation the toolbar folds, panels are a bottom sheet
//! and controls are at least 40 px tall. Screenshots of both layouts are kept
//! in `target/tmp/layout-*.png`. On the ball, the wheel zooms keeping the
//! point under the cursor in place, a right drag pans by as many pixels, and
//! the keyboard alone focuses the view, zooms, orbits and resets it. A link
//! copied from one tab reproduces the lossless frame in another, pixel for
//! pixel; Save image gives it as a PNG; the view's edges name the patient's
//! directions; the scale bar measures mm at the target. On a DICOM series
//! written for the test, the corners name the patient and the study, Info
//! hides them (remembered), and the server's `--notice` shows.
//!
//! IHE Invoke Image Display against a real Orthanc holding the VHF head:
//! the launch URL opens the viewer on the study's volume (fetched, bricked,
//! drawn), the Studies panel finds it by PatientID and lists its series, an
//! unknown study gives a page saying so (not a blank viewer) and a
//! malformed request a readable page naming the parameter.
//!
//! Skipped with a printed reason when `chromedriver` is missing, unless
//! `VOXSERVE_REQUIRE_BROWSER=1` (set by `.ci/run`, whose prerequisites install
//! it).
#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use std::net::TcpListener as StdListener;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{PoisonError, RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, Instant};

use fantoccini::actions::{ActionSequence, InputSource, MouseActions, PointerAction, TouchActions};
use fantoccini::{Client, ClientBuilder, Locator};
use server::stream::StreamSettings;
use voxserve_tests::gpu::report_skip;
use voxserve_tests::gpu_or_skip;
use voxserve_tests::issuer::Issuer;
use voxserve_tests::server::{TestServer, sessions_open};

/// How long the page may take to show each expected change.
const PATIENCE: Duration = Duration::from_secs(120);

/// The machine, as the browser tests (two at a time) share it: each holds
/// it shared while its browser is open; the one that counts the frames of a
/// drag holds it alone, so that it measures what two cores draw, not what
/// they draw beside another test's server and browser (beside one it saw 3
/// frames, alone 35–37).
static MACHINE: RwLock<()> = RwLock::new(());

/// A test's hold on [`MACHINE`], for as long as its browser is open.
enum Turn {
    Shared {
        _held: RwLockReadGuard<'static, ()>,
    },
    Alone {
        _held: RwLockWriteGuard<'static, ()>,
    },
}

impl Turn {
    fn shared() -> Turn {
        Turn::Shared {
            _held: MACHINE.read().unwrap_or_else(PoisonError::into_inner),
        }
    }

    fn alone() -> Turn {
        Turn::Alone {
            _held: MACHINE.write().unwrap_or_else(PoisonError::into_inner),
        }
    }
}

/// `chromedriver` on a free port, killed when dropped (then the test's
/// [`Turn`] ends).
struct Driver {
    child: Child,
    port: u16,
    _turn: Turn,
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn find(program: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")?
        .to_str()?
        .split(':')
        .map(|dir| PathBuf::from(dir).join(program))
        .find(|p| p.is_file())
}

fn start_driver(turn: Turn) -> Result<Driver, String> {
    let binary =
        find("chromedriver").ok_or("chromedriver is not installed (Debian: chromium-driver)")?;
    let port = StdListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map_err(|e| format!("no free port: {e}"))?
        .port();
    let child = Command::new(binary)
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("cannot start chromedriver: {e}"))?;
    Ok(Driver {
        child,
        port,
        _turn: turn,
    })
}

/// The number `script` computes in the page (NaN if it is not one).
async fn number(client: &Client, what: &str, script: &str) -> Result<f64, String> {
    Ok(client
        .execute(script, vec![])
        .await
        .map_err(|e| format!("{what}: {e}"))?
        .as_f64()
        .unwrap_or(f64::NAN))
}

/// A number the page computes, polled until `done` accepts it.
async fn wait_for(
    client: &Client,
    what: &str,
    script: &str,
    done: impl Fn(f64) -> bool,
) -> Result<f64, String> {
    let start = Instant::now();
    loop {
        let value = number(client, what, script).await?;
        if done(value) {
            return Ok(value);
        }
        if start.elapsed() > PATIENCE {
            return Err(format!("{what}: still {value} after {PATIENCE:?}"));
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

const FRAMES: &str = "return Number(document.getElementById('view').dataset.frames || 0);";
/// A fingerprint of what the canvas shows: the sum of a sparse grid of pixels
/// and the count of non-black ones (encoded as count·1e9 + sum).
const PIXELS: &str = "const c = document.getElementById('view');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let sum = 0, lit = 0;
    for (let i = 0; i < d.length; i += 4 * 97) { sum += d[i] + d[i + 1] + d[i + 2]; if (d[i] + d[i + 1] + d[i + 2] > 30) lit += 1; }
    return lit * 1e9 + sum;";

/// The lit pixels' bounding box: its longer side over the canvas's shorter one.
const EXTENT: &str = "const c = document.getElementById('view');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let x0 = c.width, y0 = c.height, x1 = -1, y1 = -1;
    for (let y = 0; y < c.height; y += 1) for (let x = 0; x < c.width; x += 1) {
      const i = 4 * (y * c.width + x);
      if (d[i] + d[i + 1] + d[i + 2] > 30) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); }
    }
    return x1 < 0 ? 0 : Math.max(x1 - x0 + 1, y1 - y0 + 1) / Math.min(c.width, c.height);";

async fn exercise(client: &Client, url: &str) -> Result<(), String> {
    client
        .goto(url)
        .await
        .map_err(|e| format!("loading {url}: {e}"))?;
    // A lossless frame of the still view arrives (after a first JPEG one).
    wait_for(client, "frames drawn", FRAMES, |n| n >= 1.0).await?;
    let first = wait_for(client, "a lit canvas", PIXELS, |v| v >= 1e9 * 20.0).await?;
    let frames = wait_for(client, "frames drawn", FRAMES, |n| n >= 1.0).await?;

    // Drag across the canvas to orbit.
    drag_across(client).await?;
    let after_drag = wait_for(client, "a frame after the drag", FRAMES, |n| n > frames).await?;
    wait_for(client, "the orbited view", PIXELS, |v| {
        (v - first).abs() > 0.5
    })
    .await?;

    // Switch the transfer-function preset.
    let shown = wait_for(client, "frames", FRAMES, |n| n >= after_drag).await?;
    let before = client
        .execute(PIXELS, vec![])
        .await
        .map_err(|e| format!("reading the canvas: {e}"))?
        .as_f64()
        .unwrap_or(f64::NAN);
    client
        .execute(
            "const s = document.getElementById('preset');
             s.value = 'ct-soft-tissue';
             s.dispatchEvent(new Event('change'));
             return s.value;",
            vec![],
        )
        .await
        .map_err(|e| format!("switching the preset: {e}"))?;
    wait_for(client, "a frame after the preset", FRAMES, |n| n > shown).await?;
    wait_for(client, "the soft-tissue view", PIXELS, |v| {
        (v - before).abs() > 0.5
    })
    .await?;
    // Extinction-based illumination, then drag the light instead of the camera.
    let shown = wait_for(client, "frames", FRAMES, |n| n >= 1.0).await?;
    let before = pixels(client).await?;
    client
        .execute(
            "const s = document.getElementById('shading');
             s.value = 'extinction';
             s.dispatchEvent(new Event('change'));
             document.getElementById('light-drag').checked = true;
             document.getElementById('light-panel').open = false;
             return s.value;",
            vec![],
        )
        .await
        .map_err(|e| format!("switching to extinction shading: {e}"))?;
    wait_for(client, "a frame with extinction", FRAMES, |n| n > shown).await?;
    let lit = wait_for(client, "the extinction view", PIXELS, |v| {
        (v - before).abs() > 0.5
    })
    .await?;
    let shown = wait_for(client, "frames", FRAMES, |n| n >= 1.0).await?;
    let azimuth_before = client
        .execute(
            "return document.getElementById('light-azimuth').value;",
            vec![],
        )
        .await
        .map_err(|e| format!("reading the light: {e}"))?;
    drag_across(client).await?;
    wait_for(client, "a frame after moving the light", FRAMES, |n| {
        n > shown
    })
    .await?;
    let azimuth_after = client
        .execute(
            "return document.getElementById('light-azimuth').value;",
            vec![],
        )
        .await
        .map_err(|e| format!("reading the light: {e}"))?;
    if azimuth_before == azimuth_after {
        return Err(format!(
            "dragging with 'Drag moves the light' left the light at azimuth {azimuth_after}"
        ));
    }
    wait_for(client, "the relit view", PIXELS, |v| (v - lit).abs() > 0.5).await?;

    // A phone-sized viewport: a new frame for the new size, nothing wider than the screen.
    let shown = wait_for(client, "frames", FRAMES, |n| n >= 1.0).await?;
    client
        .set_window_size(390, 844)
        .await
        .map_err(|e| format!("resizing the window: {e}"))?;
    wait_for(client, "a frame for the phone viewport", FRAMES, |n| {
        n > shown
    })
    .await?;
    wait_for(
        client,
        "page width over the viewport's",
        "return document.documentElement.scrollWidth - window.innerWidth;",
        |over| over <= 0.0,
    )
    .await?;

    let error = client
        .execute(
            "const e = document.getElementById('error'); return e.hidden ? '' : e.textContent;",
            vec![],
        )
        .await
        .map_err(|e| format!("reading the error box: {e}"))?;
    match error.as_str() {
        Some("") | None => Ok(()),
        Some(message) => Err(format!("the page shows an error: {message}")),
    }
}

/// The canvas's pixel sum, as [`PIXELS`] reads it.
async fn pixels(client: &Client) -> Result<f64, String> {
    number(client, "reading the canvas", PIXELS).await
}

/// Drags the mouse across the canvas from its centre to the right.
async fn drag_across(client: &Client) -> Result<(), String> {
    let wobble = |step: u32| if step.is_multiple_of(2) { 4.0 } else { 0.0 };
    drag(client, 0.0, 8, Duration::from_millis(30), 25.0, wobble).await
}

/// Presses the mouse `from_x` pixels right of the canvas's centre, moves it
/// `steps` times by `dx` to the right (and `dy(step)` down), each move taking
/// `step_time`, and releases it.
async fn drag(
    client: &Client,
    from_x: f64,
    steps: u32,
    step_time: Duration,
    dx: f64,
    dy: impl Fn(u32) -> f64,
) -> Result<(), String> {
    let canvas = client
        .find(Locator::Id("view"))
        .await
        .map_err(|e| format!("the canvas: {e}"))?;
    let mut drag = MouseActions::new("mouse".into())
        .then(PointerAction::MoveToElement {
            element: canvas,
            duration: None,
            x: from_x,
            y: 0.0,
        })
        .then(PointerAction::Down { button: 0 });
    for step in 1..=steps {
        drag = drag.then(PointerAction::MoveBy {
            duration: Some(step_time),
            x: dx,
            y: dy(step),
        });
    }
    drag = drag.then(PointerAction::Up { button: 0 });
    client
        .perform_actions(drag)
        .await
        .map_err(|e| format!("dragging: {e}"))
}

/// A headless Chromium session through `chromedriver`, or `None` (the test
/// skipped, with the reason printed) when there is none and
/// `VOXSERVE_REQUIRE_BROWSER` is not `1`.
async fn open_browser(test: &str) -> Option<(Driver, Client)> {
    open_browser_as(test, 640, 480, false).await
}

/// [`open_browser`] for a test that measures speed: it waits until no other
/// browser test runs, and none starts until it is done.
async fn open_browser_alone(test: &str) -> Option<(Driver, Client)> {
    open_browser_with(test, 640, 480, false, Turn::alone()).await
}

/// [`open_browser`] with a window of `width`×`height` CSS pixels; with
/// `touch`, as a phone: Chromium's mobile emulation of that size with a
/// touch screen (coarse pointer) at device pixel ratio 3.
async fn open_browser_as(
    test: &str,
    width: u32,
    height: u32,
    touch: bool,
) -> Option<(Driver, Client)> {
    open_browser_with(test, width, height, touch, Turn::shared()).await
}

/// [`open_browser_as`] holding the machine by `turn`.
async fn open_browser_with(
    test: &str,
    width: u32,
    height: u32,
    touch: bool,
    turn: Turn,
) -> Option<(Driver, Client)> {
    let require = std::env::var("VOXSERVE_REQUIRE_BROWSER").is_ok_and(|v| v == "1");
    let driver = match start_driver(turn) {
        Ok(d) => d,
        Err(reason) if require => panic!("{test}: VOXSERVE_REQUIRE_BROWSER=1 but {reason}"),
        Err(reason) => {
            report_skip(test, &reason);
            return None;
        }
    };
    let mut capabilities = serde_json::Map::new();
    let mut options = serde_json::json!({
        "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 format!("--window-size={width},{height}")],
    });
    if touch {
        options["mobileEmulation"] = serde_json::json!({
            "deviceMetrics": {"width": width, "height": height, "pixelRatio": 3.0, "touch": true},
        });
    }
    if let Some(chromium) = find("chromium") {
        options["binary"] = serde_json::json!(chromium);
    }
    capabilities.insert("goog:chromeOptions".into(), options);
    let webdriver = format!("http://127.0.0.1:{}", driver.port);
    let start = Instant::now();
    let client = loop {
        let connector = hyper_util::client::legacy::connect::HttpConnector::new();
        match ClientBuilder::new(connector)
            .capabilities(capabilities.clone())
            .connect(&webdriver)
            .await
        {
            Ok(client) => break client,
            Err(e) if start.elapsed() < Duration::from_secs(20) => {
                let _ = e;
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            Err(e) => panic!("{test}: cannot open a Chromium session: {e}"),
        }
    };
    Some((driver, client))
}

/// Closes the browser; on `result`'s failure, writes a screenshot first and
/// fails `test` naming it.
async fn finish(test: &str, client: Client, result: Result<(), String>) {
    if let Err(reason) = &result {
        let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("{test}.png"));
        match client.screenshot().await {
            Ok(png) => {
                let _ = std::fs::write(&path, png);
            }
            Err(e) => report_skip(test, &format!("no screenshot: {e}")),
        }
        let _ = client.close().await;
        panic!("{test}: {reason} (screenshot: {})", path.display());
    }
    client.close().await.expect("closing the browser");
}

#[tokio::test]
async fn the_page_draws_orbits_on_drag_and_switches_presets_in_headless_chromium() {
    let test = "the_page_draws_orbits_on_drag_and_switches_presets_in_headless_chromium";
    let Some(gpu) = gpu_or_skip(test) else {
        return;
    };
    let Some((_driver, client)) = open_browser(test).await else {
        return;
    };
    let server = TestServer::start(gpu, 64).await;
    let result = exercise(&client, &server.url("/")).await;
    finish(test, client, result).await;
}

/// The lit pixels' centroid, as fractions of the canvas (x·1e3 + y, each to 0.001).
const CENTROID: &str = "const c = document.getElementById('view');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let sx = 0, sy = 0, n = 0;
    for (let y = 0; y < c.height; y += 1) for (let x = 0; x < c.width; x += 1) {
      const i = 4 * (y * c.width + x);
      if (d[i] + d[i + 1] + d[i + 2] > 30) { sx += x + 0.5; sy += y + 0.5; n += 1; }
    }
    return n === 0 ? -1 : Math.round(1000 * sx / n / c.width) * 1e3 + Math.round(1000 * sy / n / c.height);";

/// Loads the page on a small ball far from its volume's centre; the first
/// view, and a reset after zooming out, frame it in the middle of the image.
async fn framing(client: &Client, url: &str) -> Result<(), String> {
    client
        .goto(url)
        .await
        .map_err(|e| format!("loading {url}: {e}"))?;
    let check = |when: &'static str| async move {
        // The default distance alone draws the ball at about a sixth of the
        // smaller side, off centre; fitted, its block fills 85 %.
        let extent = wait_for(client, when, EXTENT, |v| v >= 0.35).await?;
        let centroid = number(client, when, CENTROID).await?;
        let (cx, cy) = ((centroid / 1e3).round() / 1e3, (centroid % 1e3) / 1e3);
        if extent > 0.9 || (cx - 0.5).abs() > 0.08 || (cy - 0.5).abs() > 0.08 {
            return Err(format!(
                "{when}: the ball spans {extent:.2} around ({cx:.2}, {cy:.2})"
            ));
        }
        Ok::<f64, String>(extent)
    };
    let first = check("the first view").await?;
    // Zoom out, then reset.
    client
        .execute(
            "const c = document.getElementById('view');
             for (let i = 0; i < 5; i += 1) c.dispatchEvent(new WheelEvent('wheel', { deltaY: 300, cancelable: true }));
             return 0;",
            vec![],
        )
        .await
        .map_err(|e| format!("zooming out: {e}"))?;
    wait_for(client, "the zoomed-out view", EXTENT, |v| v < first * 0.5).await?;
    client
        .execute(
            "document.getElementById('reset').click(); return 0;",
            vec![],
        )
        .await
        .map_err(|e| format!("resetting: {e}"))?;
    check("the reset view").await?;
    Ok(())
}

/// The state of a server that renders on the CPU (no GPU needed) and offers
/// only a small ball off its volume's centre.
fn ball_state(stream: StreamSettings) -> server::AppState {
    let ball = voxserve_tests::render::dataset_of(voxserve_tests::phantom::ball_off_centre());
    let renderer =
        server::RenderService::start(shaders::Backend::Cpu, 512 << 20, 1).expect("render worker");
    server::AppState::new(vec![ball], renderer, stream)
}

#[tokio::test]
async fn the_first_view_and_a_reset_frame_what_the_transfer_function_shows() {
    let test = "the_first_view_and_a_reset_frame_what_the_transfer_function_shows";
    let Some((_driver, client)) = open_browser(test).await else {
        return;
    };
    let server = TestServer::serving(ball_state(StreamSettings::default())).await;
    let result = framing(&client, &server.url("/")).await;
    finish(test, client, result).await;
}

#[tokio::test]
async fn chromium_logs_in_through_the_issuer_and_sees_a_frame() {
    // No GPU needed: the server renders on the CPU.
    let test = "chromium_logs_in_through_the_issuer_and_sees_a_frame";
    let Some((_driver, client)) = open_browser(test).await else {
        return;
    };
    let issuer = Issuer::start().await;
    let oidc = server::auth::Oidc::connect(issuer.config())
        .await
        .expect("the issuer");
    let auth = server::auth::Auth {
        oidc: Some(oidc),
        policy: Some(
            server::auth::Policy::parse(
                r#"{"rules": [{"roles": ["radiology"], "datasets": ["*"]}]}"#,
            )
            .expect("policy"),
        ),
        ..server::auth::Auth::default()
    };
    let dataset = server::Dataset::phantom(32, 64 << 20).expect("phantom");
    let renderer =
        server::RenderService::start(shaders::Backend::Cpu, 64 << 20, 1).expect("renderer");
    let state = server::AppState::new(vec![dataset], renderer, StreamSettings::default())
        .with_auth(auth, server::audit::Audit::default());
    let server = TestServer::serving(state).await;
    issuer.log_in_as("dr.chromium", &["radiology"]);
    let result = async {
        client
            .goto(&server.url("/"))
            .await
            .map_err(|e| format!("opening the page: {e}"))?;
        wait_for(&client, "a frame after logging in", FRAMES, |n| n >= 1.0).await?;
        if issuer.issued() != 1 {
            return Err(format!(
                "the issuer issued {} tokens, expected 1",
                issuer.issued()
            ));
        }
        let address = client.current_url().await.map_err(|e| e.to_string())?;
        if address.query().is_some() {
            return Err(format!(
                "the address bar keeps the login's query: {address}"
            ));
        }
        // A launch URL, in a fresh tab state: the token is taken and removed.
        client
            .execute("sessionStorage.clear(); return 0;", vec![])
            .await
            .map_err(|e| e.to_string())?;
        let token = issuer.sign(
            jsonwebtoken::Algorithm::RS256,
            &issuer.claims("dr.launch", &["radiology"]),
        );
        client
            .goto(&server.url(&format!("/?access_token={token}")))
            .await
            .map_err(|e| format!("opening the launch URL: {e}"))?;
        wait_for(&client, "a frame after a launch", FRAMES, |n| n >= 1.0).await?;
        let address = client.current_url().await.map_err(|e| e.to_string())?;
        if address.as_str().contains(&token) {
            return Err("the address bar keeps the launch token".into());
        }
        if issuer.issued() != 1 {
            return Err("the launch URL went through the login again".into());
        }
        Ok(())
    }
    .await;
    finish(test, client, result).await;
}

/// Frames drawn during a drag of `seconds` across the canvas.
async fn frames_during_drag(client: &Client, seconds: f64) -> Result<f64, String> {
    let step_time = Duration::from_millis(50);
    let steps = (seconds / step_time.as_secs_f64()).round() as u32;
    let wobble = |step: u32| if step.is_multiple_of(2) { 1.0 } else { -1.0 };
    let before = number(client, "frames", FRAMES).await?;
    drag(client, -100.0, steps, step_time, 5.0, wobble).await?;
    Ok(number(client, "frames", FRAMES).await? - before)
}

#[tokio::test]
async fn on_the_cpu_renderer_a_two_second_drag_shows_at_least_five_frames_in_chromium() {
    // No GPU needed: the server renders on the CPU.
    let test = "on_the_cpu_renderer_a_two_second_drag_shows_at_least_five_frames_in_chromium";
    let Some((_driver, client)) = open_browser_alone(test).await else {
        return;
    };
    let dataset = server::Dataset::phantom(64, 256 << 20).expect("phantom");
    let server = TestServer::with_backend(
        shaders::Backend::Cpu,
        vec![dataset],
        1,
        StreamSettings::default(),
    )
    .await;
    let result = async {
        client
            .goto(&server.url("/"))
            .await
            .map_err(|e| format!("opening the page: {e}"))?;
        wait_for(&client, "a first frame", FRAMES, |n| n >= 1.0).await?;
        let frames = frames_during_drag(&client, 2.0).await?;
        println!("{test}: {frames} frames during a 2 s drag");
        if frames >= 5.0 {
            Ok(())
        } else {
            Err(format!(
                "{frames} frames during a 2 s drag: expected at least 5"
            ))
        }
    }
    .await;
    finish(test, client, result).await;
}

/// Whether the page's error banner shows, and says `what` (1 or 0).
fn banner_says(what: &str) -> String {
    format!(
        "const e = document.getElementById('error');
         return !e.hidden && e.textContent.includes({what:?}) ? 1 : 0;"
    )
}

const ATTEMPTS: &str = "return Number(document.getElementById('view').dataset.attempts || 0);";

/// With the server's one session place taken, the page says the server is
/// full and tries again less and less often; once the place frees, it opens
/// its session and draws.
async fn full_server(client: &Client, server: &TestServer) -> Result<(), String> {
    let (mut holder, _) = tokio_tungstenite::connect_async(server.ws_url("/api/stream"))
        .await
        .map_err(|e| format!("the test's own session: {e}"))?;
    // What the page asks to learn why its socket closed.
    let http = reqwest::Client::new();
    let probe = http
        .get(server.url("/api/stream"))
        .send()
        .await
        .map_err(|e| format!("GET /api/stream: {e}"))?;
    let retry = probe
        .headers()
        .get("retry-after")
        .and_then(|v| v.to_str().ok())
        .map(str::to_owned);
    if probe.status() != 503 || retry.as_deref() != Some("2") {
        return Err(format!(
            "GET /api/stream on a full server: {} with Retry-After {retry:?}, expected 503 and 2",
            probe.status()
        ));
    }
    let url = server.url("/");
    client
        .goto(&url)
        .await
        .map_err(|e| format!("loading {url}: {e}"))?;
    let full = banner_says("view sessions are open");
    wait_for(client, "the banner naming the full server", &full, |v| {
        v == 1.0
    })
    .await?;
    // Below the toolbar, whatever its rows (it covered the second row).
    let gap = number(
        client,
        "the banner's place",
        "const t = document.getElementById('toolbar').getBoundingClientRect();
         const e = document.getElementById('error').getBoundingClientRect();
         return e.top - t.bottom;",
    )
    .await?;
    println!("full server: the banner starts {gap:.0} px below the toolbar");
    if gap < 0.0 {
        return Err(format!("the banner overlaps the toolbar by {:.0} px", -gap));
    }
    let before = number(client, "attempts", ATTEMPTS).await?;
    tokio::time::sleep(Duration::from_secs(7)).await;
    let after = number(client, "attempts", ATTEMPTS).await?;
    println!("full server: {before} tries, then {after} after 7 s");
    // Waits of 2, 4, 8 s… after the first refusals: at most 3 more tries
    // in 7 s (retrying every second would be 7), and at least one.
    if !(after - before >= 1.0 && after - before <= 3.0) {
        return Err(format!(
            "the page tried {before} times, then {after} after 7 s: expected 1 to 3 more"
        ));
    }
    if number(client, "the banner", &full).await? != 1.0 {
        return Err("the banner no longer names the full server while it is full".into());
    }
    if number(client, "frames", FRAMES).await? != 0.0 {
        return Err("a frame arrived while the server was full".into());
    }
    holder
        .close(None)
        .await
        .map_err(|e| format!("closing the test's session: {e}"))?;
    drop(holder);
    let probe = http
        .get(server.url("/api/stream"))
        .send()
        .await
        .map_err(|e| format!("GET /api/stream: {e}"))?;
    if probe.status() != 426 {
        return Err(format!(
            "GET /api/stream with a place free: {}, expected 426",
            probe.status()
        ));
    }
    wait_for(client, "a frame once the place is free", FRAMES, |v| {
        v >= 1.0
    })
    .await?;
    Ok(())
}

#[tokio::test]
async fn a_full_server_is_named_and_retried_with_growing_waits_until_a_place_frees() {
    let test = "a_full_server_is_named_and_retried_with_growing_waits_until_a_place_frees";
    let Some((_driver, client)) = open_browser(test).await else {
        return;
    };
    let server = TestServer::serving(ball_state(StreamSettings {
        max_sessions: 1,
        ..StreamSettings::default()
    }))
    .await;
    let result = full_server(&client, &server).await;
    finish(test, client, result).await;
}

/// The status line's technical figures (its hover text).
const FIDELITY: &str = "return document.getElementById('fidelity').title;";

/// Whether the page shows a lossless frame of `dataset` as large as its
/// canvas (1 or 0).
fn full_frame_of(dataset: &str) -> String {
    format!(
        "const c = document.getElementById('view');
         const f = document.getElementById('fidelity').title;
         return document.getElementById('dataset').value === {dataset:?}
           && f.startsWith(`${{c.width}}×${{c.height}} lossless`) ? 1 : 0;"
    )
}

/// Loads the page at `url` and waits for its full-size frame of the
/// phantom (`what` names it in a timeout).
async fn open_full(client: &Client, url: &str, what: &str) -> Result<(), String> {
    client
        .goto(url)
        .await
        .map_err(|e| format!("loading {url}: {e}"))?;
    wait_for(client, what, &full_frame_of("phantom"), |v| v == 1.0).await?;
    Ok(())
}

/// The page draws the phantom; the server restarts on the same port
/// offering only the ball; the page takes the ball and draws it full size.
async fn restarted(client: &Client, first: TestServer) -> Result<(), String> {
    open_full(client, &first.url("/"), "the phantom, full size").await?;
    let address = first.base_url.trim_start_matches("http://").to_owned();
    first
        .shut_down()
        .await
        .map_err(|e| format!("stopping the first server: {e}"))?;
    let state = ball_state(StreamSettings::default());
    let id = state.datasets.snapshot()[0].id.clone();
    let _second = TestServer::serving_at(state, &address).await;
    let ball_drawn = wait_for(
        client,
        "the ball after the restart",
        &full_frame_of(&id),
        |v| v == 1.0,
    )
    .await;
    let fidelity = client
        .execute(FIDELITY, vec![])
        .await
        .map_err(|e| format!("fidelity: {e}"))?;
    println!("after the restart: {fidelity}");
    ball_drawn.map(|_| ())
}

#[tokio::test]
async fn after_a_restart_without_its_dataset_the_page_shows_one_the_server_offers_at_full_size() {
    let test =
        "after_a_restart_without_its_dataset_the_page_shows_one_the_server_offers_at_full_size";
    let Some((_driver, client)) = open_browser(test).await else {
        return;
    };
    let phantom = server::Dataset::phantom(32, 64 << 20).expect("phantom");
    let first = TestServer::with_backend(
        shaders::Backend::Cpu,
        vec![phantom],
        1,
        StreamSettings::default(),
    )
    .await;
    let result = restarted(&client, first).await;
    finish(test, client, result).await;
}

/// The page, loaded through nginx, draws a view it was dragged to; the node
/// serving it shuts down (its sessions closed with 1001, as a drain does);
/// the page reconnects through nginx, reaches the other node with its view
/// and shows the same lossless frame.
async fn reconnected(
    client: &Client,
    nginx: &voxserve_tests::nginx::Nginx,
    mut nodes: Vec<TestServer>,
) -> Result<(), String> {
    open_full(client, &format!("{}/", nginx.url), "the first full frame").await?;
    let first = pixels(client).await?;
    // A view of its own: dragged round, then still and lossless again.
    drag_across(client).await?;
    wait_for(client, "a frame of the dragged view", PIXELS, |p| {
        p != first
    })
    .await?;
    wait_for(
        client,
        "the dragged view, full",
        &full_frame_of("phantom"),
        |v| v == 1.0,
    )
    .await?;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let view = pixels(client).await?;
    let mut serving = None;
    for (i, node) in nodes.iter().enumerate() {
        if sessions_open(&node.base_url).await? == 1 {
            serving = Some(i);
        }
    }
    let serving = serving.ok_or("the session is on neither node")?;
    let frames = number(client, "frames", FRAMES).await?;
    nodes
        .remove(serving)
        .shut_down()
        .await
        .map_err(|e| format!("shutting the serving node down: {e}"))?;
    wait_for(client, "a frame from the other node", FRAMES, |n| {
        n > frames
    })
    .await?;
    wait_for(
        client,
        "the view again, full",
        &full_frame_of("phantom"),
        |v| v == 1.0,
    )
    .await?;
    let again = pixels(client).await?;
    let other = sessions_open(&nodes[0].base_url).await?;
    let fidelity = text(client, "fidelity", FIDELITY).await?;
    println!("after the node shut down: {fidelity}; sessions on the other node: {other}");
    if other != 1 {
        return Err(format!(
            "{other} sessions on the other node: expected the page's"
        ));
    }
    if again != view {
        return Err(format!(
            "the view after reconnecting differs: canvas fingerprint {again} (before {view})"
        ));
    }
    Ok(())
}

#[tokio::test]
async fn through_nginx_the_page_reconnects_to_the_other_node_with_its_view_when_its_node_goes() {
    let test =
        "through_nginx_the_page_reconnects_to_the_other_node_with_its_view_when_its_node_goes";
    let Some((_driver, client)) = open_browser(test).await else {
        return;
    };
    let nodes = vec![
        phantom_on_cpu(StreamSettings::default()).await,
        phantom_on_cpu(StreamSettings::default()).await,
    ];
    let addresses: Vec<String> = nodes
        .iter()
        .map(|n| n.base_url.trim_start_matches("http://").to_owned())
        .collect();
    let addresses: Vec<&str> = addresses.iter().map(String::as_str).collect();
    let Some(nginx) = voxserve_tests::nginx::Nginx::start_or_skip(test, &addresses) else {
        let _ = client.close().await;
        return;
    };
    let result = reconnected(&client, &nginx, nodes).await;
    if result.is_err() {
        println!("nginx: {}", nginx.log());
    }
    finish(test, client, result).await;
}

/// The string `script` computes in the page ("" if it is not one).
async fn text(client: &Client, what: &str, script: &str) -> Result<String, String> {
    Ok(client
        .execute(script, vec![])
        .await
        .map_err(|e| format!("{what}: {e}"))?
        .as_str()
        .unwrap_or_default()
        .to_owned())
}

/// Runs `script` in the page for its effect.
async fn run(client: &Client, what: &str, script: &str) -> Result<(), String> {
    client
        .execute(script, vec![])
        .await
        .map(|_| ())
        .map_err(|e| format!("{what}: {e}"))
}

/// Clicks Save image and waits until the page holds the saved file
/// (`#download.saved`, a Blob; the download link's name beside it).
async fn save_image(client: &Client) -> Result<(), String> {
    run(
        client,
        "Save image",
        "document.getElementById('save').click();",
    )
    .await?;
    wait_for(
        client,
        "the saved image",
        "return document.getElementById('download').saved ? 1 : 0;",
        |v| v == 1.0,
    )
    .await?;
    Ok(())
}

/// Loads `url` and waits for its first frame.
async fn open_page(client: &Client, url: &str) -> Result<(), String> {
    client
        .goto(url)
        .await
        .map_err(|e| format!("loading {url}: {e}"))?;
    wait_for(client, "frames drawn", FRAMES, |n| n >= 1.0).await?;
    Ok(())
}

/// Reloads the page and waits for its first frame.
async fn reload(client: &Client) -> Result<(), String> {
    client
        .refresh()
        .await
        .map_err(|e| format!("reloading: {e}"))?;
    wait_for(client, "frames drawn", FRAMES, |n| n >= 1.0).await?;
    Ok(())
}

/// What `GET /api/datasets` of `server` says.
async fn datasets_json(server: &TestServer) -> Result<serde_json::Value, String> {
    let body = reqwest::get(server.url("/api/datasets"))
        .await
        .map_err(|e| format!("GET /api/datasets: {e}"))?
        .bytes()
        .await
        .map_err(|e| format!("/api/datasets: {e}"))?;
    serde_json::from_slice(&body).map_err(|e| format!("/api/datasets: {e}"))
}

/// Keeps a screenshot of the page as a test artifact, `target/tmp/NAME.png`.
async fn keep_screenshot(client: &Client, name: &str) -> Result<(), String> {
    let png = client
        .screenshot()
        .await
        .map_err(|e| format!("screenshot {name}: {e}"))?;
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("{name}.png"));
    std::fs::write(&path, png).map_err(|e| format!("writing {}: {e}", path.display()))?;
    println!("screenshot: {}", path.display());
    Ok(())
}

/// A server of the phantom (CT in HU, 32³) rendering on the CPU.
async fn phantom_on_cpu(stream: StreamSettings) -> TestServer {
    let phantom = server::Dataset::phantom(32, 64 << 20).expect("phantom");
    TestServer::with_backend(shaders::Backend::Cpu, vec![phantom], 1, stream).await
}

/// The values a transfer function's text shows (`VALUE:RRGGBB:OPACITY,…`),
/// as `TransferFunction::shown_span` finds them.
fn shown_span(tf: &str) -> Option<[f32; 2]> {
    blocks::TransferFunction::parse(tf).ok()?.shown_span()
}

/// Drags the mouse across the element `id` from its centre, `steps` moves
/// of `dx` pixels right.
async fn drag_on(client: &Client, id: &str, steps: u32, dx: f64) -> Result<(), String> {
    let element = client
        .find(Locator::Id(id))
        .await
        .map_err(|e| format!("#{id}: {e}"))?;
    let mut drag = MouseActions::new("mouse".into())
        .then(PointerAction::MoveToElement {
            element,
            duration: None,
            x: 0.0,
            y: 0.0,
        })
        .then(PointerAction::Down { button: 0 });
    for _ in 0..steps {
        drag = drag.then(PointerAction::MoveBy {
            duration: Some(Duration::from_millis(20)),
            x: dx,
            y: 0.0,
        });
    }
    drag = drag.then(PointerAction::Up { button: 0 });
    client
        .perform_actions(drag)
        .await
        .map_err(|e| format!("dragging on #{id}: {e}"))
}

const STATUS: &str = "return document.getElementById('status').textContent;";
/// Whether the view is finished: lossless, converged, nothing loading (1 or 0).
const FINISHED: &str =
    "return document.getElementById('fidelity').classList.contains('busy') ? 0 : 1;";
const EDITED_TF: &str = "return document.getElementById('tf').dataset.tf || '';";

/// Window/level dragged 400 px across keeps the transfer function on the
/// histogram, the menu says it was edited, and choosing the preset again
/// restores it.
async fn tf_drag(client: &Client, server: &TestServer) -> Result<(), String> {
    open_page(client, &server.url("/")).await?;
    wait_for(client, "a lit canvas", PIXELS, |v| v >= 1e9).await?;
    wait_for(client, "the view finished", FINISHED, |v| v == 1.0).await?;
    let first = pixels(client).await?;
    let datasets = datasets_json(server).await?;
    let range = [
        datasets[0]["histogram_range"][0]
            .as_f64()
            .unwrap_or(f64::NAN) as f32,
        datasets[0]["histogram_range"][1]
            .as_f64()
            .unwrap_or(f64::NAN) as f32,
    ];
    let preset_tf = text(client, "the editor's points", EDITED_TF).await?;
    run(
        client,
        "opening the editor",
        "document.getElementById('tf-panel').open = true;",
    )
    .await?;
    let frames = number(client, "frames", FRAMES).await?;
    // 400 px to the left (the panel sits at the window's right edge, where
    // a drag to the right leaves the window; the editor keeps both ways alike).
    drag_on(client, "tf", 8, -50.0).await?;
    let edited = text(client, "the edited points", EDITED_TF).await?;
    let span = shown_span(&edited).ok_or(format!("the edited {edited} shows nothing"))?;
    let middle = (span[0] + span[1]) / 2.0;
    println!("tf drag: {preset_tf} → {edited}; range {range:?}, shown {span:?}");
    if !(range[0]..=range[1]).contains(&middle) {
        return Err(format!(
            "after a 400 px drag the window's middle {middle} left the range {range:?}"
        ));
    }
    let menu = text(
        client,
        "the preset menu",
        "const s = document.getElementById('preset');
         return `${s.value}|${s.options[s.selectedIndex].text}`;",
    )
    .await?;
    if menu != "|ct-bone (edited)" {
        return Err(format!(
            "the preset menu shows '{menu}', expected ct-bone (edited)"
        ));
    }
    wait_for(client, "a frame of the edit", FRAMES, |n| n > frames).await?;
    let shown = pixels(client).await?;
    let status = text(client, "the status line", STATUS).await?;
    println!("tf drag: status '{status}', pixels {shown}");
    if shown < 1e9 && !status.contains("Nothing is visible") {
        return Err(format!("a black image with the status '{status}'"));
    }
    // Choosing ct-bone again is a change, and restores its points and image.
    let frames = number(client, "frames", FRAMES).await?;
    run(
        client,
        "choosing ct-bone",
        "const s = document.getElementById('preset');
         s.value = 'ct-bone';
         s.dispatchEvent(new Event('change'));",
    )
    .await?;
    let restored = text(client, "the points", EDITED_TF).await?;
    if restored != preset_tf {
        return Err(format!("ct-bone again: {restored}, expected {preset_tf}"));
    }
    let options = number(
        client,
        "menu entries",
        "return document.getElementById('preset').options.length;",
    )
    .await?;
    if options != 4.0 {
        return Err(format!(
            "{options} presets listed after restoring: the edited entry stays"
        ));
    }
    wait_for(client, "a frame of ct-bone", FRAMES, |n| n > frames).await?;
    wait_for(client, "the view finished", FINISHED, |v| v == 1.0).await?;
    let again = pixels(client).await?;
    if (again - first).abs() > 0.5 {
        return Err(format!("ct-bone again shows {again}, first {first}"));
    }
    Ok(())
}

#[tokio::test]
async fn a_window_level_drag_keeps_the_transfer_function_on_the_histogram_and_the_preset_restores_it()
 {
    let test = "a_window_level_drag_keeps_the_transfer_function_on_the_histogram_and_the_preset_restores_it";
    let Some((_driver, client)) = open_browser_as(test, 1400, 900, false).await else {
        return;
    };
    let server = phantom_on_cpu(StreamSettings::default()).await;
    let result = tf_drag(&client, &server).await;
    finish(test, client, result).await;
}

/// Whether the hint shows (1 or 0).
const HINT_SHOWN: &str = "return document.getElementById('hint').hidden ? 0 : 1;";

/// Heights: the toolbar's, and every open panel's box (JSON).
const TOOLBAR_HEIGHT: &str =
    "return document.getElementById('toolbar').getBoundingClientRect().height;";

/// The controls a finger must hit, shown now, shorter than 40 px (JSON list
/// of `tag#id height`).
const SMALL_TARGETS: &str = "const shown = (e) => e.getClientRects().length > 0
       && getComputedStyle(e).visibility !== 'hidden';
    const targets = [...document.querySelectorAll(
      '#toolbar select, #toolbar button, #toolbar summary, #toolbar input[type=range], #toolbar input[type=color]')]
      .concat([...document.querySelectorAll('#toolbar input[type=checkbox]')].map((c) => c.closest('label') || c));
    return JSON.stringify(targets.filter(shown)
      .map((e) => [e.tagName.toLowerCase() + (e.id ? '#' + e.id : ''), e.getBoundingClientRect().height])
      .filter(([, h]) => h < 40));";

/// Every slider shows its value beside it (the names of those that do not).
const SILENT_SLIDERS: &str = "return JSON.stringify([...document.querySelectorAll('#toolbar input[type=range]')]
      .filter((i) => { const o = i.parentElement.querySelector('output'); return !o || o.textContent.trim() === ''; })
      .map((i) => i.id || i.title));";

/// The status line in words, its figures on hover, the interaction hint,
/// panels over the image that leave the toolbar's height alone, one open at
/// a time, sliders that show their values and apply as they move.
async fn desktop_layout(client: &Client, server: &TestServer) -> Result<(), String> {
    open_page(client, &server.url("/")).await?;
    if number(client, "the hint", HINT_SHOWN).await? != 1.0 {
        return Err("no interaction hint on a first visit".into());
    }
    let hint = text(
        client,
        "the hint",
        "return document.getElementById('hint').innerText;",
    )
    .await?;
    if !hint.contains("Drag") || !hint.contains("zoom") || hint.contains("pinch") {
        return Err(format!("the hint for a mouse says '{hint}'"));
    }
    wait_for(client, "the view finished", FINISHED, |v| v == 1.0).await?;
    let status = text(client, "the status line", STATUS).await?;
    let figures = text(client, "the figures", FIDELITY).await?;
    println!("status '{status}'; on hover '{figures}'");
    if ["reduction", "render", "encode", " ms", "latency"]
        .iter()
        .any(|jargon| status.contains(jargon))
        || !status.starts_with("Still image")
    {
        return Err(format!("the status line says '{status}'"));
    }
    if !figures.contains("reduction") || !figures.contains("render") {
        return Err(format!("the hover text says '{figures}'"));
    }
    keep_screenshot(client, "layout-1400x900").await?;
    // A drag on the image puts the hint away, for good; "?" brings it back.
    drag_across(client).await?;
    if number(client, "the hint", HINT_SHOWN).await? != 0.0 {
        return Err("the hint still shows after the view was moved".into());
    }
    reload(client).await?;
    if number(client, "the hint", HINT_SHOWN).await? != 0.0 {
        return Err("the hint shows again after a reload".into());
    }
    run(
        client,
        "the help button",
        "document.getElementById('help').click();",
    )
    .await?;
    if number(client, "the hint", HINT_SHOWN).await? != 1.0 {
        return Err("'?' does not show the hint".into());
    }
    run(
        client,
        "closing the hint",
        "document.getElementById('hint-close').click();",
    )
    .await?;

    // Global light's panel opens over the image: the toolbar keeps its height.
    let closed = number(client, "the toolbar", TOOLBAR_HEIGHT).await?;
    run(
        client,
        "global light",
        "const s = document.getElementById('shading');
         s.value = 'global';
         s.dispatchEvent(new Event('change'));
         document.getElementById('light-panel').open = true;",
    )
    .await?;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let open = number(client, "the toolbar", TOOLBAR_HEIGHT).await?;
    let panel = text(
        client,
        "the panel's box",
        "const r = document.querySelector('#light-panel > div').getBoundingClientRect();
         const t = document.getElementById('toolbar').getBoundingClientRect();
         return `${r.top - t.bottom},${innerHeight - r.bottom},${r.height}`;",
    )
    .await?;
    println!(
        "toolbar {closed} px; with Illumination open {open} px; panel (gap, room below, height) {panel}"
    );
    if open > closed + 1.0 || open > 100.0 {
        return Err(format!(
            "Illumination makes the toolbar {open} px tall ({closed} px closed)"
        ));
    }
    let place: Vec<f64> = panel.split(',').filter_map(|v| v.parse().ok()).collect();
    if place.len() != 3 || place[0] < 0.0 || place[1] < 0.0 || place[2] < 50.0 {
        return Err(format!(
            "the panel sits at (gap, room below, height) {panel}"
        ));
    }
    keep_screenshot(client, "layout-1400x900-illumination").await?;
    let silent = text(client, "sliders", SILENT_SLIDERS).await?;
    if silent != "[]" {
        return Err(format!("sliders without their value: {silent}"));
    }
    // A light slider applies as it moves, before it is let go.
    let frames = wait_for(client, "frames", FRAMES, |n| n >= 1.0).await?;
    run(
        client,
        "moving the azimuth slider",
        "const s = document.getElementById('light-azimuth');
         s.value = String(Number(s.value) + 40);
         s.dispatchEvent(new Event('input'));",
    )
    .await?;
    wait_for(client, "a frame while the slider moves", FRAMES, |n| {
        n > frames
    })
    .await?;
    // One panel at a time.
    run(
        client,
        "the clip panel",
        "document.getElementById('clip-panel').open = true;",
    )
    .await?;
    wait_for(
        client,
        "the light panel closed",
        "return document.getElementById('light-panel').open ? 0 : 1;",
        |v| v == 1.0,
    )
    .await?;
    Ok(())
}

#[tokio::test]
async fn the_status_speaks_plainly_a_hint_shows_how_to_move_and_panels_open_over_the_image() {
    let test = "the_status_speaks_plainly_a_hint_shows_how_to_move_and_panels_open_over_the_image";
    let Some((_driver, client)) = open_browser_as(test, 1400, 900, false).await else {
        return;
    };
    let server = phantom_on_cpu(StreamSettings::default()).await;
    let result = desktop_layout(&client, &server).await;
    finish(test, client, result).await;
}

/// On a phone: the toolbar folds to one row, a panel opens as a sheet at the
/// bottom, every control is at least 40 px tall, nothing is wider than the
/// screen, and the hint speaks of fingers.
async fn phone_layout(client: &Client, server: &TestServer) -> Result<(), String> {
    open_page(client, &server.url("/")).await?;
    let coarse = number(
        client,
        "the pointer",
        "return matchMedia('(pointer: coarse)').matches ? 1 : 0;",
    )
    .await?;
    if coarse != 1.0 {
        return Err("the emulated phone has no coarse pointer".into());
    }
    let hint = text(
        client,
        "the hint",
        "return document.getElementById('hint').innerText;",
    )
    .await?;
    if !hint.contains("pinch") || hint.contains("wheel") {
        return Err(format!("the hint on a phone says '{hint}'"));
    }
    let folded = number(client, "the toolbar", TOOLBAR_HEIGHT).await?;
    let small = text(client, "touch targets", SMALL_TARGETS).await?;
    let overflow = number(
        client,
        "page width over the viewport's",
        "const d = document.getElementById('dataset').getBoundingClientRect();
         return Math.max(document.documentElement.scrollWidth - innerWidth, d.right - innerWidth);",
    )
    .await?;
    println!("phone: toolbar {folded} px folded; small targets {small}; overflow {overflow} px");
    keep_screenshot(client, "layout-390x844").await?;
    if folded > 60.0 {
        return Err(format!("the folded toolbar is {folded} px tall"));
    }
    if small != "[]" {
        return Err(format!("controls under 40 px: {small}"));
    }
    if overflow > 0.0 {
        return Err(format!("{overflow} px wider than the screen"));
    }
    run(
        client,
        "the menu",
        "document.getElementById('menu').click();
         const s = document.getElementById('shading');
         s.value = 'global';
         s.dispatchEvent(new Event('change'));",
    )
    .await?;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let unfolded = number(client, "the toolbar", TOOLBAR_HEIGHT).await?;
    run(
        client,
        "the Illumination panel",
        "document.getElementById('light-panel').open = true;",
    )
    .await?;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let with_panel = number(client, "the toolbar", TOOLBAR_HEIGHT).await?;
    let sheet = text(
        client,
        "the sheet",
        "const r = document.querySelector('#light-panel > div').getBoundingClientRect();
         return `${innerHeight - r.bottom},${r.height / innerHeight},${r.left},${innerWidth - r.right}`;",
    )
    .await?;
    let small = text(client, "touch targets", SMALL_TARGETS).await?;
    println!(
        "phone: toolbar {unfolded} px unfolded, {with_panel} px with Illumination open; \
         sheet (gap below, share of height, left, right) {sheet}; small targets {small}"
    );
    keep_screenshot(client, "layout-390x844-illumination").await?;
    if with_panel > unfolded + 1.0 {
        return Err(format!(
            "Illumination makes the toolbar {with_panel} px tall ({unfolded} px without)"
        ));
    }
    let place: Vec<f64> = sheet.split(',').filter_map(|v| v.parse().ok()).collect();
    if place.len() != 4 || place[0].abs() > 1.0 || place[1] > 0.51 || place[2].abs() > 1.0 {
        return Err(format!("the sheet sits at {sheet}"));
    }
    if small != "[]" {
        return Err(format!("controls under 40 px with the panel open: {small}"));
    }
    Ok(())
}

#[tokio::test]
async fn on_a_phone_the_toolbar_folds_panels_are_a_bottom_sheet_and_targets_are_40_px() {
    let test = "on_a_phone_the_toolbar_folds_panels_are_a_bottom_sheet_and_targets_are_40_px";
    let Some((_driver, client)) = open_browser_as(test, 390, 844, true).await else {
        return;
    };
    let server = phantom_on_cpu(StreamSettings::default()).await;
    let result = phone_layout(&client, &server).await;
    finish(test, client, result).await;
}

/// The lit pixels' centroid as fractions of the canvas, and their extent.
async fn ball_place(client: &Client, when: &str) -> Result<(f64, f64, f64), String> {
    wait_for(client, when, FINISHED, |v| v == 1.0).await?;
    let centroid = number(client, when, CENTROID).await?;
    if centroid < 0.0 {
        return Err(format!("{when}: nothing shows"));
    }
    let extent = number(client, when, EXTENT).await?;
    Ok((
        (centroid / 1e3).round() / 1e3,
        (centroid % 1e3) / 1e3,
        extent,
    ))
}

/// Waits for a frame after `frames`, then for the view to finish, and says
/// where the ball is.
async fn ball_after(client: &Client, frames: f64, when: &str) -> Result<(f64, f64, f64), String> {
    wait_for(client, when, FRAMES, |n| n > frames).await?;
    let place = ball_place(client, when).await?;
    println!(
        "{when}: ball at ({:.3}, {:.3}), extent {:.3}",
        place.0, place.1, place.2
    );
    Ok(place)
}

/// Sends `keys` to the page's focused element.
async fn press(client: &Client, keys: &str) -> Result<(), String> {
    client
        .active_element()
        .await
        .map_err(|e| format!("the focused element: {e}"))?
        .send_keys(keys)
        .await
        .map_err(|e| format!("pressing {keys:?}: {e}"))
}

/// The wheel zooms towards the cursor, a right drag pans, and the view
/// works from the keyboard: Tab focuses it, + zooms, arrows orbit, R resets.
async fn pan_zoom_keys(client: &Client, url: &str) -> Result<(), String> {
    open_page(client, url).await?;
    let (x0, y0, e0) = ball_place(client, "the first view").await?;
    println!("first view: ball at ({x0:.3}, {y0:.3}), extent {e0:.3}");
    // Zoom in with the cursor a quarter of the width left of the centre:
    // the ball grows and moves away from the cursor, to the right.
    let frames = number(client, "frames", FRAMES).await?;
    run(
        client,
        "zooming in at the left",
        "const c = document.getElementById('view');
         const r = c.getBoundingClientRect();
         c.dispatchEvent(new WheelEvent('wheel', { deltaY: -400, cancelable: true,
           clientX: r.left + r.width * 0.25, clientY: r.top + r.height / 2 }));",
    )
    .await?;
    let (x1, _, e1) = ball_after(client, frames, "zoomed in at the left").await?;
    // Kept in place under the cursor: the ball's offset from it grows by the zoom.
    let expected = 0.25 + (x0 - 0.25) * e1 / e0;
    if e1 < e0 * 1.2 || (x1 - expected).abs() > 0.05 {
        return Err(format!(
            "zoomed in at x 0.25: the ball went from {x0:.3} (extent {e0:.3}) to {x1:.3} \
             (extent {e1:.3}); expected about {expected:.3}"
        ));
    }
    // Keyboard alone: Tab focuses the view (first in the page), R resets.
    client
        .find(Locator::Css("body"))
        .await
        .map_err(|e| format!("the page: {e}"))?
        .send_keys("\u{E004}")
        .await
        .map_err(|e| format!("Tab: {e}"))?;
    let focused = text(client, "the focus", "return document.activeElement.id;").await?;
    if focused != "view" {
        return Err(format!("Tab focused '{focused}', not the view"));
    }
    let frames = number(client, "frames", FRAMES).await?;
    press(client, "r").await?;
    let (x2, y2, e2) = ball_after(client, frames, "R").await?;
    if (x2 - x0).abs() > 0.03 || (y2 - y0).abs() > 0.03 || (e2 - e0).abs() > 0.05 {
        return Err(format!("R: the ball at ({x2:.3}, {y2:.3}), extent {e2:.3}"));
    }
    let frames = number(client, "frames", FRAMES).await?;
    press(client, "++").await?;
    let (_, _, e3) = ball_after(client, frames, "+ +").await?;
    if e3 < e2 * 1.15 {
        return Err(format!("+ +: extent {e2:.3} → {e3:.3}"));
    }
    let frames = number(client, "frames", FRAMES).await?;
    let before = pixels(client).await?;
    press(client, "\u{E012}\u{E012}").await?;
    wait_for(client, "a frame after ←", FRAMES, |n| n > frames).await?;
    wait_for(client, "the orbited view", PIXELS, |v| {
        (v - before).abs() > 0.5
    })
    .await?;
    let frames = number(client, "frames", FRAMES).await?;
    press(client, "r").await?;
    ball_after(client, frames, "R again").await?;
    // A right drag of 100 px to the right pans: the ball follows the pointer.
    let width = number(
        client,
        "the view's width",
        "return document.getElementById('view').getBoundingClientRect().width;",
    )
    .await?;
    let (x4, y4, _) = ball_place(client, "before the pan").await?;
    let frames = number(client, "frames", FRAMES).await?;
    let canvas = client
        .find(Locator::Id("view"))
        .await
        .map_err(|e| format!("the canvas: {e}"))?;
    let mut drag = MouseActions::new("mouse".into())
        .then(PointerAction::MoveToElement {
            element: canvas,
            duration: None,
            x: 0.0,
            y: 0.0,
        })
        .then(PointerAction::Down { button: 2 });
    for _ in 0..4 {
        drag = drag.then(PointerAction::MoveBy {
            duration: Some(Duration::from_millis(30)),
            x: 25.0,
            y: 0.0,
        });
    }
    drag = drag.then(PointerAction::Up { button: 2 });
    client
        .perform_actions(drag)
        .await
        .map_err(|e| format!("right-dragging: {e}"))?;
    let (x5, y5, _) = ball_after(client, frames, "panned 100 px right").await?;
    let moved = (x5 - x4) * width;
    if (moved - 100.0).abs() > 15.0 || (y5 - y4).abs() > 0.03 {
        return Err(format!(
            "a 100 px right drag moved the ball {moved:.0} px across and {:.3} down",
            y5 - y4
        ));
    }
    Ok(())
}

#[tokio::test]
async fn the_wheel_zooms_where_it_points_a_right_drag_pans_and_keys_move_the_view() {
    let test = "the_wheel_zooms_where_it_points_a_right_drag_pans_and_keys_move_the_view";
    let Some((_driver, client)) = open_browser(test).await else {
        return;
    };
    let server = TestServer::serving(ball_state(StreamSettings::default())).await;
    let result = pan_zoom_keys(&client, &server.url("/")).await;
    finish(test, client, result).await;
}

/// An FNV-1a hash of every pixel of the canvas (its whole image, exactly).
const CANVAS_HASH: &str = "const c = document.getElementById('view');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let h = 2166136261;
    for (let i = 0; i < d.length; i += 1) { h ^= d[i]; h = Math.imul(h, 16777619) >>> 0; }
    return h;";

/// The labels at the view's edges, `left right top bottom`.
const ORIENTATION: &str = "return ['left', 'right', 'top', 'bottom']
      .map((e) => document.getElementById(`orient-${e}`).textContent).join(' ');";

/// A link copied from one tab reproduces the same lossless frame in another,
/// pixel for pixel; Save image gives that frame as a PNG of its size; the
/// view's edges name the patient's directions; the scale bar measures mm.
async fn sharing(client: &Client, server: &TestServer) -> Result<(), String> {
    open_page(client, &server.url("/")).await?;
    wait_for(client, "the first view", FINISHED, |v| v == 1.0).await?;
    drag_across(client).await?;
    let frames = number(client, "frames", FRAMES).await?;
    run(
        client,
        "changing the view",
        "const set = (id, value) => { const s = document.getElementById(id); s.value = value; s.dispatchEvent(new Event('change')); };
         set('preset', 'ct-soft-tissue');
         set('shading', 'unshaded');
         set('reduction', '4');
         const x0 = document.querySelector('#clip input');
         x0.value = '150';
         x0.dispatchEvent(new Event('input'));",
    )
    .await?;
    wait_for(client, "a frame of the new view", FRAMES, |n| n > frames).await?;
    wait_for(client, "the new view finished", FINISHED, |v| v == 1.0).await?;
    let href = text(client, "the address", "return location.href;").await?;
    let hash = number(client, "the image", CANVAS_HASH).await?;
    println!("link: {href}");
    for part in [
        "preset=ct-soft-tissue",
        "shading=unshaded",
        "reduction=4",
        "clip=0.15",
        "az=",
        "dataset=phantom",
    ] {
        if !href.contains(part) {
            return Err(format!("the address {href} lacks {part}"));
        }
    }
    // Save image: the full lossless frame as PNG, the canvas's size.
    save_image(client).await?;
    let png = client
        .execute_async(
            "const done = arguments[arguments.length - 1];
             document.getElementById('download').saved.arrayBuffer()
               .then((b) => { const v = new DataView(b);
                 const c = document.getElementById('view');
                 done([v.getUint32(0), v.getUint32(16), v.getUint32(20), c.width, c.height,
                       document.getElementById('download').download]); })
               .catch((e) => done(String(e)));",
            vec![],
        )
        .await
        .map_err(|e| format!("reading the saved image: {e}"))?;
    println!("saved image (signature, width, height, canvas width, height, name): {png}");
    let values: Vec<f64> = png
        .as_array()
        .map(|a| {
            a.iter()
                .take(5)
                .filter_map(serde_json::Value::as_f64)
                .collect()
        })
        .unwrap_or_default();
    if values.len() != 5
        || values[0] != f64::from(0x8950_4e47_u32)
        || values[1] != values[3]
        || values[2] != values[4]
    {
        return Err(format!(
            "the saved image is {png}: expected a PNG of the canvas's size"
        ));
    }
    // The same view in a second tab, from the address alone.
    let first_tab = client
        .window()
        .await
        .map_err(|e| format!("this tab: {e}"))?;
    let tab = client
        .new_window(true)
        .await
        .map_err(|e| format!("a new tab: {e}"))?;
    client
        .switch_to_window(tab.handle)
        .await
        .map_err(|e| format!("switching tabs: {e}"))?;
    open_page(client, &href).await?;
    wait_for(client, "the linked view", FINISHED, |v| v == 1.0).await?;
    let again = number(client, "the linked image", CANVAS_HASH).await?;
    let controls = text(
        client,
        "the controls",
        "return ['preset', 'shading', 'reduction'].map((id) => document.getElementById(id).value).join(' ');",
    )
    .await?;
    println!("second tab: controls {controls}; image hash {again} (first {hash})");
    if controls != "ct-soft-tissue unshaded 4" {
        return Err(format!("the linked page's controls read {controls}"));
    }
    if again != hash {
        return Err(format!(
            "the linked view's image differs (hash {again}, first {hash})"
        ));
    }
    client
        .close_window()
        .await
        .map_err(|e| format!("closing the tab: {e}"))?;
    client
        .switch_to_window(first_tab)
        .await
        .map_err(|e| format!("back to the first tab: {e}"))?;
    // Facing the patient (azimuth 0): their right on the image's left.
    for (camera, expected) in [("az=0&el=0", "R L S I"), ("az=90&el=0", "A P S I")] {
        let url = server.url(&format!("/#dataset=phantom&{camera}&dist=3&tx=0&ty=0&tz=0"));
        open_page(client, &url).await?;
        let labels = text(client, "the orientation", ORIENTATION).await?;
        if labels != expected {
            return Err(format!(
                "at {camera} the edges read '{labels}', expected '{expected}'"
            ));
        }
    }
    wait_for(client, "frames drawn", FRAMES, |n| n >= 1.0).await?;
    keep_screenshot(client, "orientation-az90").await?;
    // The scale bar: its label over its length is the mm per pixel at the
    // target (distance 3 radii, the default field of view).
    let scale = text(
        client,
        "the scale bar",
        "const s = document.getElementById('scale');
         return `${s.querySelector('span').textContent}|${parseFloat(s.querySelector('div').style.width)}|${document.getElementById('view').clientHeight}`;",
    )
    .await?;
    let datasets = datasets_json(server).await?;
    let radius = datasets[0]["radius_mm"].as_f64().unwrap_or(f64::NAN);
    let parts: Vec<&str> = scale.split('|').collect();
    let mm: f64 = parts[0].trim_end_matches(" mm").parse().unwrap_or(f64::NAN);
    let (bar, height): (f64, f64) = (
        parts
            .get(1)
            .and_then(|v| v.parse().ok())
            .unwrap_or(f64::NAN),
        parts
            .get(2)
            .and_then(|v| v.parse().ok())
            .unwrap_or(f64::NAN),
    );
    let expected = 2.0 * 3.0 * radius * (15f64).to_radians().tan() / height;
    println!(
        "scale bar: {mm} mm over {bar} px; {:.4} mm per px, expected {expected:.4}",
        mm / bar
    );
    if ((mm / bar) / expected - 1.0).abs() > 0.005 {
        return Err(format!(
            "the scale bar says {scale}: {} mm per px, expected {expected}",
            mm / bar
        ));
    }
    Ok(())
}

#[tokio::test]
async fn a_link_reproduces_the_view_pixel_for_pixel_and_the_edges_name_the_patients_directions() {
    let test =
        "a_link_reproduces_the_view_pixel_for_pixel_and_the_edges_name_the_patients_directions";
    let Some((_driver, client)) = open_browser(test).await else {
        return;
    };
    let server = phantom_on_cpu(StreamSettings::default()).await;
    let result = sharing(&client, &server).await;
    finish(test, client, result).await;
}

/// A folder of 16 DICOM slices (16 × 16, 1 mm) of one CT series naming its
/// patient and study, as a scanner writes them.
fn dicom_series(dir: &std::path::Path) -> PathBuf {
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::tags;
    let folder = dir.join("ct-series");
    std::fs::create_dir_all(&folder).expect("the series folder");
    for z in 0..16u16 {
        let path = folder.join(format!("slice{z:02}.dcm"));
        voxserve_tests::malformed::dicom_slice(
            &path,
            16,
            16,
            voxserve_tests::malformed::EXPLICIT_LE,
            |obj| {
                let mut put = |tag, vr, value: PrimitiveValue| {
                    obj.put(DataElement::new(tag, vr, value));
                };
                put(
                    tags::SOP_INSTANCE_UID,
                    VR::UI,
                    format!("1.2.3.4.5.{z}").into(),
                );
                put(
                    tags::IMAGE_POSITION_PATIENT,
                    VR::DS,
                    format!("0\\0\\{z}").into(),
                );
                put(tags::PATIENT_NAME, VR::PN, "Doe^Jane".into());
                put(tags::PATIENT_ID, VR::LO, "MRN-0042".into());
                put(tags::PATIENT_BIRTH_DATE, VR::DA, "19700131".into());
                put(tags::STUDY_DATE, VR::DA, "20261124".into());
                put(tags::STUDY_DESCRIPTION, VR::LO, "CT HEAD WO".into());
                put(tags::SERIES_DESCRIPTION, VR::LO, "AXIAL 1.0".into());
                put(tags::SLICE_THICKNESS, VR::DS, "1".into());
                // A bright core (bone) in soft tissue.
                let pixels: Vec<u16> = (0..256u16)
                    .map(|i| {
                        let (x, y) = (i % 16, i / 16);
                        if (4..12).contains(&x) && (4..12).contains(&y) && (4..12).contains(&z) {
                            1000
                        } else {
                            40
                        }
                    })
                    .collect();
                put(tags::PIXEL_DATA, VR::OW, PrimitiveValue::U16(pixels.into()));
            },
        );
    }
    folder
}

/// The corners name the patient and the study from the DICOM headers, Info
/// hides and shows them, and the server's notice shows over the image.
async fn context(client: &Client, server: &TestServer) -> Result<(), String> {
    open_page(client, &server.url("/")).await?;
    let corners = text(
        client,
        "the corners",
        "return document.getElementById('context-patient').textContent + '|' +
                document.getElementById('context-study').textContent;",
    )
    .await?;
    println!("corners: {corners:?}");
    for part in [
        "Doe, Jane",
        "ID MRN-0042",
        "born 1970-01-31",
        "2026-11-24",
        "CT HEAD WO",
        "AXIAL 1.0",
        "CT · 1 mm slices",
    ] {
        if !corners.contains(part) {
            return Err(format!("the corners read {corners:?}: no {part:?}"));
        }
    }
    let notice = text(
        client,
        "the notice",
        "const n = document.getElementById('notice'); return n.hidden ? '' : n.textContent;",
    )
    .await?;
    if notice != "Not for diagnostic use" {
        return Err(format!("the notice reads {notice:?}"));
    }
    keep_screenshot(client, "context-corners").await?;
    let shown = "return document.getElementById('context').hidden ? 0 : 1;";
    run(
        client,
        "Info",
        "document.getElementById('context-toggle').click();",
    )
    .await?;
    if number(client, "the corners", shown).await? != 0.0 {
        return Err("Info did not hide the corners".into());
    }
    reload(client).await?;
    if number(client, "the corners", shown).await? != 0.0 {
        return Err("hidden corners show again after a reload".into());
    }
    run(
        client,
        "Info",
        "document.getElementById('context-toggle').click();",
    )
    .await?;
    if number(client, "the corners", shown).await? != 1.0 {
        return Err("Info did not show the corners again".into());
    }
    Ok(())
}

#[tokio::test]
async fn the_corners_name_the_patient_and_study_and_the_notice_shows() {
    let test = "the_corners_name_the_patient_and_study_and_the_notice_shows";
    let Some((_driver, client)) = open_browser(test).await else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let series = dicom_series(dir.path());
    let dataset = server::Dataset::load(&series, &Default::default(), 64 << 20)
        .unwrap_or_else(|e| panic!("the series: {e}"));
    let renderer =
        server::RenderService::start(shaders::Backend::Cpu, 512 << 20, 1).expect("render worker");
    let state = server::AppState::new(vec![dataset], renderer, StreamSettings::default())
        .with_notice(Some("Not for diagnostic use".into()));
    let server = TestServer::serving(state).await;
    let result = context(&client, &server).await;
    finish(test, client, result).await;
}

/// The slice view of `plane`, in the page's script.
fn pane_js(plane: &str) -> String {
    format!("document.querySelector('.slice-pane[data-pane=\"{plane}\"]')")
}

/// The script counting the frames the slice view of `plane` has drawn (0
/// before the page has built it).
fn frames_js(plane: &str) -> String {
    format!(
        "const p = {}; return p ? Number(p.dataset.frames || 0) : 0;",
        pane_js(plane)
    )
}

/// Frames the slice view of `plane` has drawn.
async fn pane_frames(client: &Client, plane: &str) -> Result<f64, String> {
    number(client, &format!("{plane} frames"), &frames_js(plane)).await
}

/// Waits until the slice view of `plane` shows its view losslessly, done.
async fn pane_settled(client: &Client, plane: &str) -> Result<(), String> {
    wait_for(
        client,
        &format!("the {plane} view settled"),
        &format!(
            "const p = {}; return p.dataset.lossless === 'true' && !p.querySelector('.pane-busy').classList.contains('on') ? 1 : 0;",
            pane_js(plane)
        ),
        |v| v == 1.0,
    )
    .await
    .map(|_| ())
}

/// The script reading a number of the address's hash (`fallback` when it
/// has none).
fn hash_js(name: &str, fallback: f64) -> String {
    format!(
        "const v = new URLSearchParams(location.hash.slice(1)).get('{name}'); return v === null ? {fallback} : Number(v);"
    )
}

/// A number of the address's hash (`fallback` when it has none).
async fn hash_number(client: &Client, name: &str, fallback: f64) -> Result<f64, String> {
    number(client, name, &hash_js(name, fallback)).await
}

/// How a test points at an element.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Gesture {
    /// The mouse moves over it.
    Hover,
    /// The mouse moves there and clicks.
    Click,
    /// A finger touches it.
    Tap,
}

/// Points at (`x`, `y`) CSS pixels from the centre of the element `css` by
/// `gesture`.
async fn point_at(
    client: &Client,
    css: &str,
    x: f64,
    y: f64,
    gesture: Gesture,
) -> Result<(), String> {
    let element = client
        .find(Locator::Css(css))
        .await
        .map_err(|e| format!("{css}: {e}"))?;
    let to = PointerAction::MoveToElement {
        element,
        duration: None,
        x,
        y,
    };
    let (down, up) = (
        PointerAction::Down { button: 0 },
        PointerAction::Up { button: 0 },
    );
    let actions: ActionSequence = match gesture {
        Gesture::Hover => MouseActions::new("mouse".into()).then(to).into(),
        Gesture::Click => MouseActions::new("mouse".into())
            .then(to)
            .then(down)
            .then(up)
            .into(),
        Gesture::Tap => TouchActions::new("finger".into())
            .then(to)
            .then(down)
            .then(up)
            .into(),
    };
    client
        .perform_actions(actions)
        .await
        .map_err(|e| format!("pointing at {css}: {e}"))
}

/// The voxel at (`x`, `y`) of the axial view pointed at by `gesture`, as
/// the page reads it out: its index and value.
async fn probed(
    client: &Client,
    gesture: Gesture,
    x: f64,
    y: f64,
) -> Result<([u32; 3], f64), String> {
    // An answer still on its way (to an earlier tap) would fill the
    // readout cleared here: wait for it first.
    let probe = format!("{}.querySelector('.pane-probe')", pane_js("axial"));
    wait_for(
        client,
        "the earlier probe's answer",
        &format!("return {probe}.dataset.busy === '1' ? 0 : 1;"),
        |v| v == 1.0,
    )
    .await?;
    run(
        client,
        "clearing the readout",
        &format!(
            "{}.querySelector('.pane-probe').dataset.index = '';",
            pane_js("axial")
        ),
    )
    .await?;
    point_at(client, ".slice-pane[data-pane=\"axial\"]", x, y, gesture).await?;
    // The last answer, for this position (not one asked before it).
    wait_for(
        client,
        "the value under the cursor",
        &format!("return {probe}.dataset.index && {probe}.dataset.busy !== '1' ? 1 : 0;"),
        |v| v == 1.0,
    )
    .await?;
    let index = text(
        client,
        "the voxel",
        &format!("return {probe}.dataset.index;"),
    )
    .await?;
    let value = number(
        client,
        "the value",
        &format!("return Number({probe}.dataset.value);"),
    )
    .await?;
    let index: Vec<u32> = index.split(',').filter_map(|v| v.parse().ok()).collect();
    let [i, j, k] = index[..] else {
        return Err(format!("the voxel index {index:?}"));
    };
    Ok(([i, j, k], value))
}

/// Presses `key` with the focus where it is, and waits for `plane`'s
/// view to draw again.
async fn layout_key(client: &Client, key: &str, planes: &[&str]) -> Result<(), String> {
    let before: Vec<f64> = {
        let mut v = Vec::new();
        for plane in planes {
            v.push(pane_frames(client, plane).await?);
        }
        v
    };
    press(client, key).await?;
    for (plane, before) in planes.iter().zip(before) {
        wait_for(
            client,
            &format!("the {plane} view after key {key}"),
            &frames_js(plane),
            |n| n > before,
        )
        .await?;
        pane_settled(client, plane).await?;
    }
    Ok(())
}

/// The slice views on `volume` (the dataset served): the 2×2 layout shows
/// three slices and 3D, oriented as radiologists read them; scrolling the
/// axial view moves its slice and the crosshair in the coronal one; the
/// value under the cursor is the voxel's; a distance between two voxels is
/// their distance within one voxel; a click on the 3D view moves the
/// crosshair to what it shows there; every layout is kept as a screenshot.
async fn slice_views(
    client: &Client,
    server: &TestServer,
    volume: &blocks::Volume,
    name: &str,
) -> Result<(), String> {
    open_page(client, &server.url("/")).await?;
    wait_for(client, "the 3D view finished", FINISHED, |v| v == 1.0).await?;
    keep_screenshot(client, &format!("slices-{name}-layout-1x1")).await?;
    layout_key(client, "2", &["axial", "coronal", "sagittal"]).await?;
    keep_screenshot(client, &format!("slices-{name}-layout-2x2")).await?;
    // The crosshair shows in the 3D view too, within it.
    let marked = number(
        client,
        "the crosshair in 3D",
        "const m = document.getElementById('crosshair-3d'); const v = document.getElementById('view').getBoundingClientRect();
         const r = m.getBoundingClientRect(); const x = r.left + r.width / 2, y = r.top + r.height / 2;
         return !m.hidden && x > v.left && x < v.right && y > v.top && y < v.bottom ? 1 : 0;",
    )
    .await?;
    if marked != 1.0 {
        return Err("the 2×2 layout's 3D view does not mark the crosshair".into());
    }
    let letters = |plane: &str| {
        format!(
            "const p = {}; return ['top','bottom','left','right'].map((e) => p.querySelector('.pane-orient-' + e).textContent).join('');",
            pane_js(plane)
        )
    };
    for (plane, expected) in [("axial", "APRL"), ("coronal", "SIRL"), ("sagittal", "SIAP")] {
        let got = text(client, "orientation letters", &letters(plane)).await?;
        if got != expected {
            return Err(format!(
                "the {plane} view's edges read {got} (top, bottom, left, right): expected {expected}"
            ));
        }
    }
    // Scrolling the axial view: its slice moves, and so does the crosshair's
    // axial line in the coronal view (superior is up there).
    let line = format!(
        "return Number({}.querySelector('svg').dataset.crosshair.split(',')[1]);",
        pane_js("coronal")
    );
    let y0 = number(client, "the coronal crosshair", &line).await?;
    let cz0 = hash_number(client, "cz", 0.0).await?;
    let frames = pane_frames(client, "axial").await?;
    run(
        client,
        "scrolling the axial view",
        &format!(
            "const p = {}; for (let i = 0; i < 5; i += 1) p.dispatchEvent(new WheelEvent('wheel', {{ deltaY: -100, cancelable: true, bubbles: true }}));",
            pane_js("axial")
        ),
    )
    .await?;
    wait_for(
        client,
        "the axial view after scrolling",
        &frames_js("axial"),
        |n| n > frames,
    )
    .await?;
    pane_settled(client, "axial").await?;
    pane_settled(client, "coronal").await?;
    let cz1 = hash_number(client, "cz", 0.0).await?;
    let y1 = number(client, "the coronal crosshair", &line).await?;
    let spacing = volume.geometry.spacing;
    println!("scrolled: cz {cz0} → {cz1} mm, coronal line y {y0} → {y1}");
    if ((cz0 - cz1).abs() - 5.0 * spacing[2]).abs() > 1e-3 || y1 >= y0 {
        return Err(format!(
            "five wheel steps moved the axial slice from {cz0} to {cz1} mm (expected 5 × {} mm) \
             and the coronal view's line from y {y0} to {y1}",
            spacing[2]
        ));
    }
    // The value under the cursor is the voxel's, in the slice shown.
    let (a, va) = probed(client, Gesture::Hover, -60.0, 10.0).await?;
    let expected = volume.physical_at(a[0], a[1], a[2]);
    let centre_k = (f64::from(volume.geometry.dims[2]) - 1.0) / 2.0;
    let k_expected = (centre_k + cz1 / spacing[2]).round();
    println!("under the cursor: voxel {a:?} = {va}, the volume has {expected}");
    if va != expected || f64::from(a[2]) != k_expected {
        return Err(format!(
            "the readout says voxel {a:?} = {va}; the volume holds {expected} there, and the slice is k = {k_expected}"
        ));
    }
    // A distance between two voxels: their distance within one voxel.
    let (b, _) = probed(client, Gesture::Hover, 70.0, -40.0).await?;
    let known = (0..3)
        .map(|i| ((f64::from(a[i]) - f64::from(b[i])) * spacing[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    run(
        client,
        "measure mode",
        "const m = document.getElementById('measure'); m.value = 'distance'; m.dispatchEvent(new Event('change'));",
    )
    .await?;
    point_at(
        client,
        ".slice-pane[data-pane=\"axial\"]",
        -60.0,
        10.0,
        Gesture::Click,
    )
    .await?;
    point_at(
        client,
        ".slice-pane[data-pane=\"axial\"]",
        70.0,
        -40.0,
        Gesture::Click,
    )
    .await?;
    let measured = wait_for(
        client,
        "the distance listed",
        "const li = document.querySelector('#measurements li'); return li ? Number(li.dataset.value) : -1;",
        |v| v >= 0.0,
    )
    .await?;
    let voxel = spacing.iter().copied().fold(0.0, f64::max);
    println!("distance {measured:.2} mm between voxels {a:?} and {b:?}, {known:.2} mm apart");
    if (measured - known).abs() > voxel {
        return Err(format!(
            "the distance measured is {measured} mm; the voxels are {known} mm apart"
        ));
    }
    let drawn = number(
        client,
        "the measurement drawn",
        &format!(
            "return {}.querySelectorAll('svg .measure-label').length;",
            pane_js("axial")
        ),
    )
    .await?;
    if drawn != 1.0 {
        return Err(format!("{drawn} measurement labels on the axial view"));
    }
    // An angle at the second of three voxels: their angle within 2°.
    let (c, _) = probed(client, Gesture::Hover, -60.0, -60.0).await?;
    run(
        client,
        "angle mode",
        "const m = document.getElementById('measure'); m.value = 'angle'; m.dispatchEvent(new Event('change'));",
    )
    .await?;
    for (x, y) in [(-60.0, 10.0), (70.0, -40.0), (-60.0, -60.0)] {
        point_at(
            client,
            ".slice-pane[data-pane=\"axial\"]",
            x,
            y,
            Gesture::Click,
        )
        .await?;
    }
    let measured = wait_for(
        client,
        "the angle listed",
        "const li = document.querySelectorAll('#measurements li')[1]; return li ? Number(li.dataset.value) : -1;",
        |v| v >= 0.0,
    )
    .await?;
    let mm = |v: [u32; 3]| {
        glam::DVec3::new(
            f64::from(v[0]) * spacing[0],
            f64::from(v[1]) * spacing[1],
            f64::from(v[2]) * spacing[2],
        )
    };
    let known = (mm(a) - mm(b)).angle_between(mm(c) - mm(b)).to_degrees();
    println!("angle {measured:.2}° at voxel {b:?}; the voxels make {known:.2}°");
    if (measured - known).abs() > 2.0 {
        return Err(format!(
            "the angle measured is {measured}°; the voxels make {known}°"
        ));
    }
    run(
        client,
        "crosshair mode",
        "const m = document.getElementById('measure'); m.value = 'off'; m.dispatchEvent(new Event('change'));",
    )
    .await?;
    // A click on the 3D view's forehead (a quarter of its height above the
    // middle) puts the crosshair on the bone it shows there.
    let frames = pane_frames(client, "axial").await?;
    let height = number(
        client,
        "the 3D view's height",
        "return document.getElementById('view').clientHeight;",
    )
    .await?;
    point_at(client, "#view", 0.0, -0.25 * height, Gesture::Click).await?;
    wait_for(
        client,
        "the slices after a pick",
        &frames_js("axial"),
        |n| n > frames,
    )
    .await?;
    pane_settled(client, "axial").await?;
    let picked: Vec<f64> = {
        let mut v = Vec::new();
        for name in ["cx", "cy", "cz"] {
            v.push(hash_number(client, name, 0.0).await?);
        }
        v
    };
    // The voxels within one of the point: bone among them.
    let g = &volume.geometry;
    let index: Vec<f64> = (0..3)
        .map(|a| {
            let along: f64 = (0..3).map(|r| g.direction[a][r] * picked[r]).sum();
            along / g.spacing[a] + (f64::from(g.dims[a]) - 1.0) / 2.0
        })
        .collect();
    let mut value = f64::MIN;
    for dz in -1i64..=1 {
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                let v: Vec<u32> = [dx, dy, dz]
                    .iter()
                    .zip(&index)
                    .zip(g.dims)
                    .map(|((d, &i), n)| (i.round() as i64 + d).clamp(0, i64::from(n) - 1) as u32)
                    .collect();
                value = value.max(volume.physical_at(v[0], v[1], v[2]));
            }
        }
    }
    println!("picked {picked:?} mm, voxel {index:?}; the most within a voxel is {value}");
    // Looking from the front, the bone shown is in front of the centre and above it.
    if picked[1] >= 0.0 || picked[2] <= 0.0 || value < 150.0 {
        return Err(format!(
            "a click on the 3D view's forehead put the crosshair at {picked:?} mm, on a voxel of {value}"
        ));
    }
    oblique(client).await?;
    layout_key(client, "3", &["axial", "coronal", "sagittal"]).await?;
    keep_screenshot(client, &format!("slices-{name}-layout-1+3")).await?;
    layout_key(client, "4", &["axial"]).await?;
    keep_screenshot(client, &format!("slices-{name}-layout-axial")).await?;
    // Save image saves the view shown: the axial slice's lossless frame.
    save_image(client).await?;
    let saved = client
        .execute_async(
            "const done = arguments[arguments.length - 1];
             const link = document.getElementById('download');
             createImageBitmap(link.saved).then((b) => done([link.download, b.width, b.height]));",
            vec![],
        )
        .await
        .map_err(|e| format!("reading the saved image: {e}"))?;
    let size = number(
        client,
        "the axial frame",
        &format!(
            "const c = {}.querySelector('canvas'); return c.width * 1e5 + c.height;",
            pane_js("axial")
        ),
    )
    .await?;
    let (w, h) = ((size / 1e5).floor(), size % 1e5);
    println!("saved {saved}");
    if !saved[0].as_str().is_some_and(|n| n.contains("-axial-"))
        || saved[1].as_f64() != Some(w)
        || saved[2].as_f64() != Some(h)
    {
        return Err(format!(
            "Save image with the axial view alone saved {saved}, not its {w}×{h} frame"
        ));
    }
    // The address reproduces the slice view, pixel for pixel, in a fresh page.
    let canvas_hash = format!(
        "const c = {}.querySelector('canvas'); const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
         let h = 0; for (let i = 0; i < d.length; i += 1) h = (h * 31 + d[i]) % 1000000007; return h;",
        pane_js("axial")
    );
    let before = number(client, "the axial image", &canvas_hash).await?;
    let href = text(client, "the address", "return location.href;").await?;
    println!("slice link: {href}");
    client
        .goto("about:blank")
        .await
        .map_err(|e| format!("leaving the page: {e}"))?;
    client
        .goto(&href)
        .await
        .map_err(|e| format!("loading {href}: {e}"))?;
    wait_for(client, "the linked axial view", &frames_js("axial"), |n| {
        n >= 1.0
    })
    .await?;
    pane_settled(client, "axial").await?;
    let after = number(client, "the linked axial image", &canvas_hash).await?;
    if after != before {
        return Err(format!(
            "the link {href} shows another axial image ({after} against {before})"
        ));
    }
    Ok(())
}

/// A drag along the axial view's vertical crosshair line, from 80 px above
/// its centre 60 px to the right, turns the coronal and sagittal planes
/// about the axial normal: they stay perpendicular to it and each other,
/// the axial plane stays, and its crosshair lines turn.
async fn oblique(client: &Client) -> Result<(), String> {
    let centre = text(
        client,
        "the axial crosshair",
        &format!(
            "return {}.querySelector('svg').dataset.crosshair;",
            pane_js("axial")
        ),
    )
    .await?;
    let c: Vec<f64> = centre.split(',').filter_map(|v| v.parse().ok()).collect();
    let size = number(
        client,
        "the axial view's size",
        &format!(
            "const p = {}; return p.clientWidth * 1e5 + p.clientHeight;",
            pane_js("axial")
        ),
    )
    .await?;
    let (w, h) = ((size / 1e5).floor(), size % 1e5);
    let frames = pane_frames(client, "coronal").await?;
    let axial_frames = pane_frames(client, "axial").await?;
    let axial = client
        .find(Locator::Css(".slice-pane[data-pane=\"axial\"]"))
        .await
        .map_err(|e| format!("the axial view: {e}"))?;
    let mut drag = MouseActions::new("mouse".into())
        .then(PointerAction::MoveToElement {
            element: axial,
            duration: None,
            x: c[0] - w / 2.0,
            y: c[1] - h / 2.0 - 80.0,
        })
        .then(PointerAction::Down { button: 0 });
    for _ in 0..6 {
        drag = drag.then(PointerAction::MoveBy {
            duration: Some(Duration::from_millis(30)),
            x: 10.0,
            y: 0.0,
        });
    }
    drag = drag.then(PointerAction::Up { button: 0 });
    client
        .perform_actions(drag)
        .await
        .map_err(|e| format!("turning the crosshair: {e}"))?;
    wait_for(
        client,
        "the coronal view turned",
        &frames_js("coronal"),
        |n| n > frames,
    )
    .await?;
    // The axial view draws again too: its crosshair lines are the others' planes.
    wait_for(client, "the axial view's lines", &frames_js("axial"), |n| {
        n > axial_frames
    })
    .await?;
    for plane in ["axial", "coronal", "sagittal"] {
        pane_settled(client, plane).await?;
    }
    let orient = |plane: &'static str| async move {
        let text = text(
            client,
            "an orientation",
            &format!("return new URLSearchParams(location.hash.slice(1)).get('{plane}_orient') || '1,0,0,0';"),
        )
        .await?;
        let parsed =
            <shaders::slice::Orientation as shaders::settings::TextSetting>::parse_text(&text)
                .map_err(|e| format!("{plane}_orient {text}: {}", e.0))?;
        let plane_of = match plane {
            "axial" => shaders::slice::Plane::Axial,
            "coronal" => shaders::slice::Plane::Coronal,
            _ => shaders::slice::Plane::Sagittal,
        };
        Ok::<_, String>(
            shaders::slice::SliceRequest {
                plane: plane_of,
                orient: parsed,
                ..Default::default()
            }
            .axes()[2],
        )
    };
    let (a, c, s) = (
        orient("axial").await?,
        orient("coronal").await?,
        orient("sagittal").await?,
    );
    let turned = c.dot(glam::Vec3::NEG_Y).acos().to_degrees();
    println!("turned the crosshair {turned:.1}°: normals {a}, {c}, {s}");
    if a != glam::Vec3::NEG_Z
        || a.dot(c).abs() > 1e-4
        || a.dot(s).abs() > 1e-4
        || c.dot(s).abs() > 1e-4
        || turned < 5.0
    {
        return Err(format!(
            "after turning the crosshair the normals are {a}, {c}, {s} (coronal turned {turned}°)"
        ));
    }
    let lines = text(
        client,
        "the axial view's lines",
        &format!(
            "return [...{}.querySelectorAll('svg line')].map((l) => l.getAttribute('x1') + ':' + l.getAttribute('x2')).join(' ');",
            pane_js("axial")
        ),
    )
    .await?;
    let vertical = lines.split(' ').any(|l| {
        let x: Vec<f64> = l.split(':').filter_map(|v| v.parse().ok()).collect();
        x.len() == 2 && (x[0] - x[1]).abs() < 1.0
    });
    if vertical {
        return Err(format!(
            "the axial view's crosshair lines did not turn: {lines}"
        ));
    }
    Ok(())
}

/// The dataset of the slice tests and its voxels: the VHF head when the
/// shared datasets are there, else the phantom.
fn slice_dataset(test: &str) -> (server::Dataset, blocks::Volume, &'static str) {
    if let Some(data) = voxserve_tests::data::shared_data(test) {
        let path = data.join("dicom/vhf_head");
        let mut source = blocks::ingest::open(&path, &Default::default()).expect("the VHF head");
        let volume = blocks::ingest::load(source.as_mut()).expect("its voxels");
        let dataset = server::Dataset::load(&path, &Default::default(), 256 << 20)
            .expect("the VHF head's store");
        return (dataset, volume, "vhf");
    }
    let volume = blocks::phantom::head(64).expect("phantom");
    let dataset = server::Dataset::phantom(64, 64 << 20).expect("phantom");
    (dataset, volume, "phantom")
}

#[tokio::test]
async fn slice_views_scroll_probe_measure_and_follow_a_pick_in_every_layout() {
    let test = "slice_views_scroll_probe_measure_and_follow_a_pick_in_every_layout";
    let Some((_driver, client)) = open_browser_as(test, 1400, 900, false).await else {
        return;
    };
    let (dataset, volume, name) = slice_dataset(test);
    let server = TestServer::with_backend(
        shaders::Backend::Cpu,
        vec![dataset],
        1,
        StreamSettings::default(),
    )
    .await;
    let result = slice_views(&client, &server, &volume, name).await;
    finish(test, client, result).await;
}

/// The Tab key, Shift, and the keys that scroll (WebDriver's codes).
const TAB: &str = "\u{E004}";
const SHIFT_TAB: &str = "\u{E008}\u{E004}\u{E000}";
const ARROW_DOWN: &str = "\u{E015}";
const PAGE_UP: &str = "\u{E00E}";

/// Presses `key` until the focused element answers `script` with 1 (at most 40 times).
async fn tab_to(client: &Client, key: &str, what: &str, script: &str) -> Result<(), String> {
    for _ in 0..40 {
        if number(client, what, script).await? == 1.0 {
            return Ok(());
        }
        press(client, key).await?;
    }
    Err(format!(
        "{what}: not reached with the keyboard in 40 presses"
    ))
}

/// From the keyboard alone: choose the second dataset, the 2×2 layout,
/// scroll the axial slice ten slices up, and reset.
async fn keyboard_path(client: &Client, server: &TestServer) -> Result<(), String> {
    open_page(client, &server.url("/")).await?;
    wait_for(client, "the first view finished", FINISHED, |v| v == 1.0).await?;
    tab_to(
        client,
        TAB,
        "the dataset picker focused",
        "return document.activeElement.id === 'dataset' ? 1 : 0;",
    )
    .await?;
    let frames = number(client, "frames", FRAMES).await?;
    press(client, ARROW_DOWN).await?;
    wait_for(client, "a frame of the second dataset", FRAMES, |n| {
        n > frames
    })
    .await?;
    let chosen = text(
        client,
        "the dataset",
        "return new URLSearchParams(location.hash.slice(1)).get('dataset');",
    )
    .await?;
    if chosen != "small" {
        return Err(format!("the arrow key chose dataset {chosen:?}, not small"));
    }
    tab_to(
        client,
        SHIFT_TAB,
        "the 3D view focused",
        "return document.activeElement.id === 'view' ? 1 : 0;",
    )
    .await?;
    layout_key(client, "2", &["axial", "coronal", "sagittal"]).await?;
    press(client, TAB).await?;
    let focused = text(
        client,
        "the focused view",
        "return document.activeElement.dataset.pane || document.activeElement.id;",
    )
    .await?;
    if focused != "axial" {
        return Err(format!(
            "Tab from the 3D view went to {focused:?}, not the axial view"
        ));
    }
    let frames = pane_frames(client, "axial").await?;
    press(client, PAGE_UP).await?;
    wait_for(
        client,
        "the axial view after Page Up",
        &frames_js("axial"),
        |n| n > frames,
    )
    .await?;
    let cz = hash_number(client, "cz", 0.0).await?;
    let spacing = datasets_json(server).await?[1]["spacing"][2]
        .as_f64()
        .unwrap_or(f64::NAN);
    if (cz - 10.0 * spacing).abs() > 0.02 {
        return Err(format!(
            "Page Up put the axial slice at {cz} mm: expected 10 × {spacing} mm"
        ));
    }
    // Shift+1: the first of the dataset's named windows (brain for CT).
    let first = datasets_json(server).await?[1]["windows"][0].clone();
    press(client, "\u{E008}1\u{E000}").await?;
    let window = text(
        client,
        "the slices' window",
        "return new URLSearchParams(location.hash.slice(1)).get('swindow') || '';",
    )
    .await?;
    let number_text = |v: &serde_json::Value| v.as_f64().map(|x| x.to_string()).unwrap_or_default();
    if window
        != format!(
            "{},{}",
            number_text(&first["centre"]),
            number_text(&first["width"])
        )
    {
        return Err(format!(
            "Shift+1 set the window {window:?}; the first is {first}"
        ));
    }
    press(client, "r").await?;
    wait_for(
        client,
        "the crosshair back at the centre",
        "return new URLSearchParams(location.hash.slice(1)).get('cz') === null ? 1 : 0;",
        |v| v == 1.0,
    )
    .await?;
    pane_settled(client, "axial").await?;
    Ok(())
}

#[tokio::test]
async fn the_main_path_works_from_the_keyboard_alone() {
    let test = "the_main_path_works_from_the_keyboard_alone";
    let Some((_driver, client)) = open_browser_as(test, 1400, 900, false).await else {
        return;
    };
    let phantom = server::Dataset::phantom(32, 64 << 20).expect("phantom");
    let volume = std::sync::Arc::new(blocks::phantom::head(24).expect("small phantom"));
    let mut source = blocks::ingest::MemorySource::new(volume, "small");
    let store = blocks::store::ingest_in_memory(&mut source, &Default::default()).expect("store");
    let small = server::Dataset::new("small".into(), store, 64 << 20).expect("small");
    let server = TestServer::with_backend(
        shaders::Backend::Cpu,
        vec![phantom, small],
        2,
        StreamSettings::default(),
    )
    .await;
    let result = keyboard_path(&client, &server).await;
    finish(test, client, result).await;
}

/// On a phone (390×844, touch) the 2×2 layout shows three slices and 3D,
/// each within the screen and drawn; a swipe scrolls the axial view and
/// moves the coronal view's line; taps read voxels out and measure their
/// distance; a tap on the 3D view's forehead moves the crosshair up there.
async fn phone_slices(
    client: &Client,
    server: &TestServer,
    volume: &blocks::Volume,
) -> Result<(), String> {
    open_page(client, &server.url("/")).await?;
    run(
        client,
        "choosing the 2×2 layout",
        "const s = document.getElementById('layout'); s.value = '2'; s.dispatchEvent(new Event('change'));",
    )
    .await?;
    for plane in ["axial", "coronal", "sagittal"] {
        wait_for(
            client,
            &format!("the {plane} view"),
            &frames_js(plane),
            |n| n >= 1.0,
        )
        .await?;
        pane_settled(client, plane).await?;
    }
    let inside = number(
        client,
        "the views' places",
        "const views = [document.getElementById('view'), ...document.querySelectorAll('.slice-pane')];
         return views.every((v) => { const r = v.getBoundingClientRect();
           return r.width > 100 && r.height > 100 && r.left >= 0 && r.top >= 0 && r.right <= innerWidth + 1 && r.bottom <= innerHeight + 1; }) ? 1 : 0;",
    )
    .await?;
    if inside != 1.0 {
        return Err("a view of the 2×2 layout is outside the phone's screen or tiny".into());
    }
    keep_screenshot(client, "slices-phone-layout-2x2").await?;
    wait_for(client, "the 3D view finished", FINISHED, |v| v == 1.0).await?;
    // One finger 60 px up the axial view: six slices up (10 px a slice),
    // and the coronal view's axial line moves up.
    let line = format!(
        "return Number({}.querySelector('svg').dataset.crosshair.split(',')[1]);",
        pane_js("coronal")
    );
    let y0 = number(client, "the coronal crosshair", &line).await?;
    let axial = client
        .find(Locator::Css(".slice-pane[data-pane=\"axial\"]"))
        .await
        .map_err(|e| format!("the axial view: {e}"))?;
    // Away from the crosshair's lines (a drag from a line turns them).
    let mut swipe = TouchActions::new("finger".into())
        .then(PointerAction::MoveToElement {
            element: axial,
            duration: None,
            x: -40.0,
            y: 30.0,
        })
        .then(PointerAction::Down { button: 0 });
    for _ in 0..6 {
        swipe = swipe.then(PointerAction::MoveBy {
            duration: Some(Duration::from_millis(40)),
            x: 0.0,
            y: -10.0,
        });
    }
    swipe = swipe.then(PointerAction::Up { button: 0 });
    client
        .perform_actions(swipe)
        .await
        .map_err(|e| format!("swiping: {e}"))?;
    let spacing = datasets_json(server).await?[0]["spacing"][2]
        .as_f64()
        .unwrap_or(f64::NAN);
    let cz = wait_for(
        client,
        "the axial slice after a swipe",
        &hash_js("cz", 0.0),
        |v| v != 0.0,
    )
    .await?;
    let y1 = number(client, "the coronal crosshair", &line).await?;
    println!(
        "a 60 px swipe moved the axial slice {cz} mm ({spacing} mm slices), the coronal line from y {y0} to {y1}"
    );
    if (cz - 6.0 * spacing).abs() > 0.02 || y1 >= y0 {
        return Err(format!(
            "a 60 px swipe up moved the axial slice to {cz} mm (expected 6 × {spacing} mm) and the coronal line from y {y0} to {y1}"
        ));
    }
    // A tap reads the voxel out (no hover on a touch screen) and measures.
    let mut taps = Vec::new();
    for (x, y) in [(-40.0, 20.0), (30.0, -30.0)] {
        let (v, value) = probed(client, Gesture::Tap, x, y).await?;
        if value != volume.physical_at(v[0], v[1], v[2]) {
            return Err(format!(
                "a tap read voxel {v:?} = {value}; the volume disagrees"
            ));
        }
        taps.push(v);
        if taps.len() == 1 {
            run(
                client,
                "measure mode",
                "const m = document.getElementById('measure'); m.value = 'distance'; m.dispatchEvent(new Event('change'));",
            )
            .await?;
            // The first tap set the crosshair; measure from the same point.
            point_at(
                client,
                ".slice-pane[data-pane=\"axial\"]",
                x,
                y,
                Gesture::Tap,
            )
            .await?;
        }
    }
    let g = &volume.geometry;
    let known = (0..3)
        .map(|i| ((f64::from(taps[0][i]) - f64::from(taps[1][i])) * g.spacing[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    let measured = wait_for(
        client,
        "the distance tapped",
        "const li = document.querySelector('#measurements li'); return li ? Number(li.dataset.value) : -1;",
        |v| v >= 0.0,
    )
    .await?;
    println!(
        "tapped {:?} and {:?}: {measured:.2} mm, {known:.2} mm apart",
        taps[0], taps[1]
    );
    if (measured - known).abs() > g.spacing.iter().copied().fold(0.0, f64::max) {
        return Err(format!(
            "a distance tapped is {measured} mm; the voxels are {known} mm apart"
        ));
    }
    run(
        client,
        "crosshair mode",
        "const m = document.getElementById('measure'); m.value = 'off'; m.dispatchEvent(new Event('change'));",
    )
    .await?;
    // A tap on the 3D view's forehead moves the crosshair up there.
    let before = hash_number(client, "cz", 0.0).await?;
    let height = number(
        client,
        "the 3D view",
        "return document.getElementById('view').clientHeight;",
    )
    .await?;
    // The skull is smaller here than at 1400×900: an eighth of the height up.
    point_at(client, "#view", 0.0, -0.125 * height, Gesture::Tap).await?;
    let cz = wait_for(
        client,
        "the crosshair after a tap in 3D",
        &hash_js("cz", 0.0),
        |v| v > before + 10.0,
    )
    .await?;
    println!("a tap on the 3D forehead put the crosshair at z {cz} mm (from {before})");
    Ok(())
}

#[tokio::test]
async fn on_a_phone_the_two_by_two_layout_shows_three_slices_and_3d() {
    let test = "on_a_phone_the_two_by_two_layout_shows_three_slices_and_3d";
    let Some((_driver, client)) = open_browser_as(test, 390, 844, true).await else {
        return;
    };
    let (dataset, volume, _) = slice_dataset(test);
    let server = TestServer::with_backend(
        shaders::Backend::Cpu,
        vec![dataset],
        1,
        StreamSettings::default(),
    )
    .await;
    let result = phone_slices(&client, &server, &volume).await;
    finish(test, client, result).await;
}

/// IHE Invoke Image Display against a real Orthanc holding the VHF head:
/// the launch URL with its StudyInstanceUID opens the viewer on that
/// study's volume (fetched over WADO-RS, bricked, shown at 512×512×234);
/// an unknown study gives a page saying so, not a blank viewer; a
/// malformed request a readable page naming the parameter.
async fn iid_launch(
    client: &Client,
    server: &TestServer,
    study: &str,
    series: &str,
    cache: &std::path::Path,
) -> Result<(), String> {
    let launched = Instant::now();
    client
        .goto(&server.url(&format!(
            "/IHEInvokeImageDisplay?requestType=STUDY&studyUID={study}&viewerType=IHE_BIR&diagnosticQuality=true"
        )))
        .await
        .map_err(|e| format!("opening the launch URL: {e}"))?;
    // The whole series (its preview, a sample of the images, shown first
    // while the rest arrives, is gone).
    let shown = format!(
        "return document.getElementById('dataset').value === '{series}' && document.getElementById('opening').hidden
           && document.getElementById('preview-note').hidden ? 1 : 0;"
    );
    // While the preview shows, a look at it (kept, not required: a fast
    // fetch may show it only briefly).
    let mut looked = false;
    while number(client, "the whole series shown", &shown).await? != 1.0
        && launched.elapsed() < PATIENCE
    {
        let previewing = number(
            client,
            "the preview",
            "return document.getElementById('preview-note').hidden ? 0 : Number(document.getElementById('view').dataset.frames || 0);",
        )
        .await?;
        if !looked && previewing > 1.0 {
            looked = true;
            println!(
                "the preview's first frame after {:.1} s",
                launched.elapsed().as_secs_f64()
            );
            keep_screenshot(client, "iid-preview").await?;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    wait_for(client, "the study's series shown", &shown, |v| v == 1.0).await?;
    let frames = number(client, "frames", FRAMES).await?;
    wait_for(client, "a frame of the study", FRAMES, |n| n > frames).await?;
    println!(
        "IHE Invoke Image Display to the first frame of the study (fetched, bricked, drawn): {:.1} s",
        launched.elapsed().as_secs_f64()
    );
    wait_for(client, "the study's view finished", FINISHED, |v| v == 1.0).await?;
    keep_screenshot(client, "iid-study").await?;
    if !cache
        .join(".preview")
        .join(format!("{series}.zarr"))
        .is_dir()
    {
        return Err("no preview was made of the 234-image series".into());
    }
    let list = datasets_json(server).await?;
    let offered = list
        .as_array()
        .and_then(|l| l.iter().find(|d| d["id"] == series))
        .ok_or_else(|| format!("series {series} not offered: {list}"))?;
    if offered["dims"] != serde_json::json!([512, 512, 234]) {
        return Err(format!("the series is offered as {offered}"));
    }
    let corners = text(
        client,
        "the corners",
        "return document.getElementById('context').textContent;",
    )
    .await?;
    if corners.trim().is_empty() {
        return Err(format!("the corners name no patient or study: {corners:?}"));
    }

    // The study browser finds the study by PatientID through the server
    // and lists its series; the one opened is offered already (Show).
    run(
        client,
        "a search",
        "const p = document.getElementById('studies-panel'); p.open = true;
         const f = p.querySelector('form'); f.elements.PatientID.value = '000-000-001';
         f.requestSubmit();",
    )
    .await?;
    wait_for(
        client,
        "the studies found",
        "return document.querySelectorAll('#study-list button').length;",
        |n| n == 1.0,
    )
    .await?;
    run(
        client,
        "a study",
        "document.querySelector('#study-list button').click();",
    )
    .await?;
    let listed = format!(
        "const li = document.querySelector('#series-list li[data-series=\"{series}\"]');
         return li && li.querySelector('button') && li.querySelector('button').textContent === 'Show' ? 1 : 0;"
    );
    wait_for(client, "the study's series listed", &listed, |v| v == 1.0).await?;
    let thumbnail = format!(
        "const img = document.querySelector('#series-list li[data-series=\"{series}\"] img');
         return img && img.dataset.loaded === '1' && img.complete && img.naturalWidth > 0 ? 1 : 0;"
    );
    wait_for(client, "the series' thumbnail", &thumbnail, |v| v == 1.0).await?;
    keep_screenshot(client, "study-browser").await?;

    // An unknown study: the reason over the whole page.
    client
        .goto(&server.url(
            "/IHEInvokeImageDisplay?requestType=STUDY&studyUID=1.2.826.0.1.3680043.2.1125.99.1",
        ))
        .await
        .map_err(|e| format!("opening the launch URL: {e}"))?;
    let failed = "const o = document.getElementById('opening');
        return !o.hidden && o.classList.contains('failed') ? 1 : 0;";
    wait_for(client, "the unknown study's page", failed, |v| v == 1.0).await?;
    let words = text(
        client,
        "the page's words",
        "return document.getElementById('opening').innerText;",
    )
    .await?;
    println!("an unknown study: {words:?}");
    if !words.contains("not found") || !words.contains("1.2.826.0.1.3680043.2.1125.99.1") {
        return Err(format!(
            "the page for an unknown study says {words:?}: expected that it was not found, naming it"
        ));
    }
    keep_screenshot(client, "iid-unknown").await?;

    // A malformed request: a readable page naming the parameter.
    client
        .goto(&server.url("/IHEInvokeImageDisplay?requestType=SERIES&studyUID=1.2.3"))
        .await
        .map_err(|e| format!("opening the launch URL: {e}"))?;
    let words = text(
        client,
        "the page's words",
        "return document.body.innerText;",
    )
    .await?;
    if !words.contains("requestType") || !words.contains("STUDY or PATIENT") {
        return Err(format!(
            "the page for requestType=SERIES says {words:?}: expected the parameter named"
        ));
    }
    Ok(())
}

#[tokio::test]
async fn an_iid_launch_opens_the_study_from_the_pacs_and_an_unknown_one_says_so() {
    let test = "an_iid_launch_opens_the_study_from_the_pacs_and_an_unknown_one_says_so";
    let Some(data) = voxserve_tests::data::shared_data(test) else {
        return;
    };
    let Some(orthanc) = voxserve_tests::orthanc::Orthanc::start_or_skip(test) else {
        return;
    };
    let Some((_driver, client)) = open_browser_as(test, 1000, 700, false).await else {
        return;
    };
    let http = reqwest::Client::new();
    let mut files: Vec<PathBuf> = std::fs::read_dir(data.join("dicom/vhf_head"))
        .expect("the VHF head")
        .map(|e| e.expect("entry").path())
        .collect();
    files.sort();
    for f in &files {
        orthanc.upload(&http, f).await;
    }
    let uids = blocks::ingest::dicom::instance_uids(&files[0]).expect("UIDs");
    let cache = tempfile::tempdir().expect("tempdir");
    let endpoint =
        server::pacs::endpoint::parse_pacs(&format!("orthanc={}/dicom-web", orthanc.url))
            .expect("endpoint");
    let web = server::pacs::DicomWeb::new(endpoint, Duration::from_secs(30)).expect("client");
    let studies =
        server::studies::Studies::new(vec![web], cache.path(), 1 << 30, 256 << 20).expect("cache");
    let renderer =
        server::RenderService::start(shaders::Backend::Cpu, 512 << 20, 2).expect("render worker");
    let phantom = server::Dataset::phantom(32, 64 << 20).expect("phantom");
    let mut state = server::AppState::new(vec![phantom], renderer, StreamSettings::default());
    state.studies = Some(studies);
    let server = TestServer::serving(state).await;
    let result = iid_launch(&client, &server, &uids.study, &uids.series, cache.path()).await;
    finish(test, client, result).await;
}
