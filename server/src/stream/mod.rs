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
//! All sessions share the one render worker
//! ([`crate::RenderService::render_waiting`]): each has at most one job
//! queued, so the worker serves them in turn. A session's view is its own.
//! [`Sessions`] caps them at [`StreamSettings::max_sessions`] (a semaphore;
//! 503 beyond it); a session ends, and frees its place, when the client
//! closes the socket, the socket breaks, or the server shuts down
//! (`AppState::shutdown`): then it sends a close with code 1001 (going away).
//! A place is freed before the close handshake completes, so a client that
//! has seen its session close can open another at once.
//!
//! # Layout
//! - [`session`]: [`Session`], the rules above as plain state: messages,
//!   acknowledgements and finished frames in, with the instant they came;
//!   what to do next out ([`Action`]). No I/O, no clock.
//! - `socket`: the loop that feeds a session from a socket (generic over
//!   `Sink`/`Stream`), renders and sends what it asks for, and closes it on
//!   shutdown.

pub mod session;
mod socket;

use std::sync::Arc;

use axum::extract::State;
use axum::extract::ws::WebSocketUpgrade;
use axum::response::Response;
use futures_util::StreamExt;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

pub use session::{Action, Session};

use crate::{AppError, AppState, encode};

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

impl StreamSettings {
    /// The defaults, also `serve`'s flags' defaults.
    pub const DEFAULT: StreamSettings = StreamSettings {
        idle_ms: 150,
        interactive_scale: 0.5,
        interactive_reduction: 4.0,
        jpeg_quality: 80,
        // 27–29 % fewer bytes than PNG for 0.3–1 ms more encoding (bench
        // stream, 512² and 1024², llvmpipe machine).
        lossless: encode::Lossless::Webp,
        frames_in_flight: 1,
        max_sessions: 16,
    };
}

impl Default for StreamSettings {
    fn default() -> StreamSettings {
        StreamSettings::DEFAULT
    }
}

/// The open sessions' places: a semaphore of [`StreamSettings::max_sessions`]
/// permits, one held by each session until it ends.
#[derive(Debug, Clone)]
pub struct Sessions {
    places: Arc<Semaphore>,
    max: u32,
}

impl Sessions {
    /// Places for `max` sessions at once.
    pub fn new(max: usize) -> Sessions {
        let max = u32::try_from(max).unwrap_or(u32::MAX);
        Sessions {
            places: Arc::new(Semaphore::new(max as usize)),
            max,
        }
    }

    /// Sessions open now.
    pub fn open(&self) -> usize {
        (self.max as usize).saturating_sub(self.places.available_permits())
    }

    /// A place for one more session, if there is one.
    fn try_open(&self) -> Option<OwnedSemaphorePermit> {
        self.places.clone().try_acquire_owned().ok()
    }

    /// Resolves when every session has ended; no session opens after.
    pub async fn all_closed(&self) {
        let all = self.places.acquire_many(self.max).await;
        self.places.close();
        drop(all);
    }
}

/// `GET /api/stream`: upgrades to a view session, or answers 503 when
/// [`StreamSettings::max_sessions`] are open.
pub async fn handler(
    ws: WebSocketUpgrade,
    State(state): State<AppState>,
) -> Result<Response, AppError> {
    let place = state.sessions.try_open().ok_or_else(|| {
        AppError::Busy(format!(
            "{} view sessions are open, the most this server allows: retry later",
            state.stream.max_sessions
        ))
    })?;
    Ok(ws.on_upgrade(move |socket| async move {
        let (sink, stream) = socket.split();
        socket::run(sink, stream, &state, place).await;
    }))
}
