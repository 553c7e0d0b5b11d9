//! View sessions over WebSocket (`GET /api/stream`): one per open viewer,
//! speaking [`crate::protocol`].
//!
//! A session keeps its view (the `GET /api/render` parameters merged from
//! every `view` message) and renders from it with **latest state wins**: at
//! most one render of its own at a time, messages that arrive meanwhile only
//! update the view, and at most [`StreamSettings::frames_in_flight`] frames
//! sent and not yet acknowledged, so a slow link drops frames instead of
//! building lag.
//!
//! **Adaptive quality**: while view messages keep coming (less than
//! [`StreamSettings::idle_ms`] apart) frames are rendered at
//! [`StreamSettings::interactive_scale`] of the size, at
//! [`StreamSettings::interactive_reduction`] times the data reduction (not
//! with global light or extinction shading, whose light a data change would
//! recompute), and sent as JPEG; once the view has been still for `idle_ms`
//! the full-resolution frame follows losslessly (WebP, or PNG with
//! [`StreamSettings::lossless`]), then, with global light, one lossless frame per
//! in-scattering refinement until all J directions are in. Then nothing more
//! is sent until the view changes.
//!
//! All sessions share the one render worker ([`RenderService::render_waiting`]):
//! each has at most one job queued, so the worker serves them in turn. A
//! session's view is its own; when the socket closes the session ends and
//! frees its place ([`StreamSettings::max_sessions`]).

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use axum::extract::State;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::response::Response;
use shaders::frame::MAX_IMAGE_EDGE;
use shaders::{FrameRequest, Shading};

use crate::protocol::{self, ClientMessage, Encoding, FrameHeader};
use crate::{AppError, AppState, Dataset, encode, metrics};

/// How view sessions trade quality for speed; see the module docs.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct StreamSettings {
    /// Milliseconds without a view message after which the view counts as
    /// still and the full-quality frame is rendered.
    pub idle_ms: u64,
    /// Image size while interacting, as a fraction of the full size.
    pub interactive_scale: f32,
    /// Data reduction while interacting, as a multiple of the view's.
    pub interactive_reduction: f32,
    /// JPEG quality (1–100) of frames while interacting.
    pub jpeg_quality: u8,
    /// The format of lossless frames.
    pub lossless: encode::Lossless,
    /// Frames sent ahead of the client's last acknowledgement.
    pub frames_in_flight: u32,
    /// Open sessions at most; more are refused with 503.
    pub max_sessions: usize,
}

impl Default for StreamSettings {
    fn default() -> StreamSettings {
        StreamSettings {
            idle_ms: 150,
            interactive_scale: 0.5,
            interactive_reduction: 4.0,
            jpeg_quality: 80,
            // 27–29 % fewer bytes than PNG for 0.3–1 ms more encoding (bench
            // stream, 512² and 1024², llvmpipe machine).
            lossless: encode::Lossless::Webp,
            frames_in_flight: 1,
            max_sessions: 16,
        }
    }
}

/// Counts open sessions; a [`SessionSlot`] frees its place when dropped.
#[derive(Debug, Clone, Default)]
pub struct SessionCounter(Arc<AtomicUsize>);

impl SessionCounter {
    /// Sessions open now.
    pub fn open(&self) -> usize {
        self.0.load(Ordering::Relaxed)
    }

    fn take(&self, max: usize) -> Option<SessionSlot> {
        self.0
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < max).then_some(n + 1)
            })
            .ok()
            .map(|_| SessionSlot(self.0.clone()))
    }
}

/// One session's place.
#[derive(Debug)]
struct SessionSlot(Arc<AtomicUsize>);

impl Drop for SessionSlot {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// `GET /api/stream`: upgrades to a view session, or answers 503 when
/// [`StreamSettings::max_sessions`] are open.
pub async fn handler(
    ws: WebSocketUpgrade,
    State(state): State<AppState>,
) -> Result<Response, AppError> {
    let max = state.stream.max_sessions;
    let slot = state.sessions.take(max).ok_or_else(|| {
        AppError::Busy(format!(
            "{max} view sessions are open, the most this server allows: retry later"
        ))
    })?;
    Ok(ws.on_upgrade(move |socket| async move {
        run_session(socket, state).await;
        drop(slot);
    }))
}

/// How a frame is rendered and sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Quality {
    /// Smaller, coarser, JPEG.
    Interactive,
    /// Full size and detail, lossless.
    Full,
}

/// A frame ready to send, or why there is none.
type Job = Pin<Box<dyn Future<Output = Result<(FrameHeader, Vec<u8>), String>> + Send>>;

/// The session's view and where its frames stand.
#[derive(Debug)]
struct View {
    /// The settings merged so far (`w` and `h` in CSS pixels).
    settings: crate::View,
    dpr: f64,
    /// The last view message applied.
    message_id: u32,
    changed_at: Instant,
    /// The view changed since the last render started.
    dirty: bool,
    /// A full-quality frame of the current view was sent.
    full_sent: bool,
    /// Nothing more to send for the current view.
    converged: bool,
}

impl View {
    /// The dataset and frame request of this view at `quality`, checked.
    fn request(
        &self,
        state: &AppState,
        quality: Quality,
    ) -> Result<(Dataset, FrameRequest), String> {
        let dataset = self
            .settings
            .dataset(&state.datasets)
            .map_err(|e| format!("view setting {e}"))?;
        let mut request = self.settings.frame.clone();
        (request.width, request.height) = device_size(&request, self.dpr)?;
        if quality == Quality::Interactive {
            let s = state.stream.interactive_scale;
            request.width = ((request.width as f32 * s).round() as u32).max(1);
            request.height = ((request.height as f32 * s).round() as u32).max(1);
            // Lit modes keep their data: other blocks would recompute the light
            // (global light) or the summed-area table (extinction) twice a gesture.
            if !matches!(request.shading, Shading::GlobalLight | Shading::Extinction) {
                request.reduction = (request.reduction * state.stream.interactive_reduction)
                    .min(shaders::frame::MAX_REDUCTION as f32);
            }
        }
        Ok((dataset.clone(), request))
    }
}

/// The frame size in device pixels of a viewport of `request.width` ×
/// `request.height` CSS pixels at device pixel ratio `dpr`.
fn device_size(request: &FrameRequest, dpr: f64) -> Result<(u32, u32), String> {
    let (w, h) = (f64::from(request.width), f64::from(request.height));
    let (pw, ph) = ((w * dpr).round(), (h * dpr).round());
    let max = f64::from(MAX_IMAGE_EDGE);
    if pw > max || ph > max {
        return Err(format!(
            "viewport {w}×{h} at device pixel ratio {dpr} is {pw}×{ph} pixels: expected at most \
             {MAX_IMAGE_EDGE} per side"
        ));
    }
    Ok((pw.max(1.0) as u32, ph.max(1.0) as u32))
}

/// Sends one JSON text message; false when the socket is gone.
async fn send_json(socket: &mut WebSocket, value: &serde_json::Value) -> bool {
    socket
        .send(Message::Text(value.to_string().into()))
        .await
        .is_ok()
}

/// Runs one session until the client goes away.
async fn run_session(mut socket: WebSocket, state: AppState) {
    let hello = serde_json::json!({
        "type": "hello",
        "protocol": protocol::PROTOCOL,
        "datasets": state.datasets.iter().map(Dataset::info).collect::<Vec<_>>(),
        "settings": state.stream,
    });
    if !send_json(&mut socket, &hello).await {
        return;
    }
    state.metrics.session_opened();
    let mut view = View {
        settings: crate::View::default(),
        dpr: 1.0,
        message_id: 0,
        changed_at: Instant::now(),
        dirty: false,
        full_sent: false,
        converged: false,
    };
    let mut have_view = false;
    let mut job: Option<(Quality, Job)> = None;
    // Frame ids are handed out when a render starts; `sent` is the last one
    // sent, `acked` the last one the client drew.
    let mut next_id: u32 = 0;
    let mut sent: u32 = 0;
    let mut acked: u32 = 0;
    let idle = Duration::from_millis(state.stream.idle_ms);
    loop {
        // Start a render when the last is done and the client keeps up.
        if job.is_none() && have_view && sent - acked < state.stream.frames_in_flight {
            let still = view.changed_at.elapsed() >= idle;
            let quality = if view.dirty {
                Some(if still {
                    Quality::Full
                } else {
                    Quality::Interactive
                })
            } else if (!view.full_sent && still) || (view.full_sent && !view.converged) {
                // The still view's full frame, then its light refinements.
                Some(Quality::Full)
            } else {
                None
            };
            if let Some(quality) = quality {
                if view.dirty {
                    view.dirty = false;
                    view.full_sent = false;
                    view.converged = false;
                }
                match view.request(&state, quality) {
                    Ok((dataset, request)) => {
                        next_id += 1;
                        job = Some((
                            quality,
                            render_job(&state, dataset, request, quality, next_id, view.message_id),
                        ));
                    }
                    Err(message) => {
                        // Checked when the message came; only the dataset can change this.
                        view.converged = true;
                        view.full_sent = true;
                        if !send_json(
                            &mut socket,
                            &serde_json::json!({"type": "error", "message": message}),
                        )
                        .await
                        {
                            return;
                        }
                    }
                }
            }
        }
        // Wake when the view turns still, unless frames wait for an ack (the
        // ack wakes the loop then; waking earlier would only spin).
        let window_open = sent - acked < state.stream.frames_in_flight;
        let wait_for_still =
            job.is_none() && have_view && !view.full_sent && !view.dirty && window_open;
        let still_at = tokio::time::Instant::from_std(view.changed_at + idle);
        tokio::select! {
            incoming = socket.recv() => {
                let Some(Ok(message)) = incoming else { return };
                let text = match message {
                    Message::Text(text) => text,
                    Message::Close(_) => return,
                    Message::Ping(_) | Message::Pong(_) => continue,
                    Message::Binary(_) => {
                        let error = serde_json::json!({"type": "error", "message": "binary message: expected JSON text"});
                        if !send_json(&mut socket, &error).await {
                            return;
                        }
                        continue;
                    }
                };
                match protocol::parse_client_message(text.as_str()) {
                    Ok(ClientMessage::Ack { frame }) => acked = acked.max(frame.min(sent)),
                    Ok(ClientMessage::View { id, set, dpr }) => {
                        match apply(&view, &state, &set, dpr) {
                            Ok((settings, dpr)) => {
                                view.settings = settings;
                                view.dpr = dpr;
                                view.message_id = id;
                                view.changed_at = Instant::now();
                                view.dirty = true;
                                have_view = true;
                            }
                            Err(message) => {
                                let error = serde_json::json!({"type": "error", "id": id, "message": message});
                                if !send_json(&mut socket, &error).await {
                                    return;
                                }
                            }
                        }
                    }
                    Err(refusal) => {
                        let error = serde_json::json!({"type": "error", "id": refusal.id, "message": refusal.message});
                        if !send_json(&mut socket, &error).await {
                            return;
                        }
                    }
                }
            }
            done = async { match job.as_mut() { Some((_, j)) => j.await, None => std::future::pending().await } }, if job.is_some() => {
                let Some((quality, _)) = job.take() else { continue };
                match done {
                    Ok((header, bytes)) => {
                        if quality == Quality::Full {
                            view.full_sent = true;
                            view.converged = view.converged || header.converged;
                        }
                        if socket.send(Message::Binary(bytes.into())).await.is_err() {
                            return;
                        }
                        sent = header.frame_id;
                        let (metric_quality, format) = match header.encoding {
                            Encoding::Jpeg => (metrics::Quality::Interactive, metrics::Format::Jpeg),
                            Encoding::Png => (metrics::Quality::Full, metrics::Format::Png),
                            Encoding::Webp => (metrics::Quality::Full, metrics::Format::Webp),
                        };
                        state.metrics.frame(
                            metrics::Source::Stream,
                            metric_quality,
                            format,
                            metrics::FrameTimes {
                                render_ms: f64::from(header.render_ms),
                                queue_ms: f64::from(header.queue_ms),
                                encode_ms: f64::from(header.encode_ms),
                            },
                        );
                    }
                    Err(message) => {
                        view.full_sent = true;
                        view.converged = true;
                        if !send_json(&mut socket, &serde_json::json!({"type": "error", "message": message})).await {
                            return;
                        }
                    }
                }
            }
            () = tokio::time::sleep_until(still_at), if wait_for_still => {}
        }
    }
}

/// The view with `set` and `dpr` applied, checked; the old view stays when
/// it fails.
fn apply(
    view: &View,
    state: &AppState,
    set: &serde_json::Map<String, serde_json::Value>,
    dpr: Option<f64>,
) -> Result<(crate::View, f64), String> {
    let mut settings = view.settings.clone();
    settings.patch(set, &state.datasets)?;
    let dpr = dpr.unwrap_or(view.dpr);
    device_size(&settings.frame, dpr)?;
    Ok((settings, dpr))
}

/// Renders and encodes one frame.
fn render_job(
    state: &AppState,
    dataset: Dataset,
    request: FrameRequest,
    quality: Quality,
    frame_id: u32,
    message_id: u32,
) -> Job {
    let renderer = state.renderer.clone();
    let jpeg_quality = state.stream.jpeg_quality;
    let lossless = state.stream.lossless;
    Box::pin(async move {
        let rendered = renderer
            .render_waiting(&dataset, request)
            .await
            .map_err(|e| e.to_string())?;
        let converged = rendered.stats.converged();
        let light = rendered.stats.light().copied();
        let frame = rendered.frame;
        let (width, height) = (frame.width, frame.height);
        let start = Instant::now();
        let (encoding, image) = tokio::task::spawn_blocking(move || match quality {
            Quality::Interactive => encode::jpeg(&frame, jpeg_quality).map(|b| (Encoding::Jpeg, b)),
            Quality::Full => match lossless {
                encode::Lossless::Png => encode::png(&frame).map(|b| (Encoding::Png, b)),
                encode::Lossless::Webp => encode::webp(&frame).map(|b| (Encoding::Webp, b)),
            },
        })
        .await
        .map_err(|e| format!("the encoder task failed: {e}"))?
        .map_err(|e| format!("encoding the frame failed: {e}"))?;
        let header = FrameHeader {
            encoding,
            lossless: quality == Quality::Full,
            converged: quality == Quality::Full && converged,
            width: width as u16,
            height: height as u16,
            refined: light.map_or(0, |l| l.refined as u16),
            directions: light.map_or(0, |l| l.directions as u16),
            frame_id,
            message_id,
            render_ms: rendered.render_ms as f32,
            encode_ms: (start.elapsed().as_secs_f64() * 1e3) as f32,
            reduction: rendered.stats.reduction as f32,
            queue_ms: rendered.queue_ms as f32,
        };
        let mut bytes = Vec::with_capacity(protocol::HEADER_LEN + image.len());
        bytes.extend_from_slice(&header.to_bytes());
        bytes.extend_from_slice(&image);
        Ok((header, bytes))
    })
}
