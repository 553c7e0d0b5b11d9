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
//! 503 beyond it) and at [`StreamSettings::sessions_per_client`] per client
//! address (429); a browser page of another site is refused (403,
//! [`crate::access`]). A session ends, and frees its place, when the client
//! closes the socket, the socket breaks, the client sent nothing for
//! [`StreamSettings::session_idle_s`] (close [`protocol::CLOSE_IDLE`]), the
//! peer answered no ping for [`protocol::PEER_PATIENCE`] seconds, a message
//! exceeded [`protocol::MAX_MESSAGE_BYTES`] (close 1009), or the server
//! shuts down (`AppState::shutdown`): then it sends a close with code 1001
//! (going away).
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

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex, PoisonError};

use axum::Extension;
use axum::Json;
use axum::extract::ws::{WebSocketUpgrade, rejection::WebSocketUpgradeRejection};
use axum::extract::{ConnectInfo, State};
use axum::http::{HeaderMap, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use futures_util::StreamExt;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

pub use session::{Action, Session};

use crate::auth::Principal;
use crate::client::Client;
use crate::{AppError, AppState, encode, protocol};

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
    /// Open sessions of one client (a signed-in user, else an address) at
    /// most; more are refused with 429.
    pub sessions_per_client: usize,
    /// Seconds without a message from the client (a view change, an
    /// acknowledgement, a status request) after which its session is closed
    /// (code [`protocol::CLOSE_IDLE`]), so that viewers left open do not
    /// hold places.
    pub session_idle_s: u64,
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
        sessions_per_client: 4,
        session_idle_s: 600,
    };
}

impl Default for StreamSettings {
    fn default() -> StreamSettings {
        StreamSettings::DEFAULT
    }
}

/// The open sessions' places: a semaphore of [`StreamSettings::max_sessions`]
/// permits, one held by each session until it ends, and the count of each
/// client's sessions (at most [`StreamSettings::sessions_per_client`]; a
/// [`Client`] is a signed-in user, else an address).
#[derive(Debug, Clone)]
pub struct Sessions {
    places: Arc<Semaphore>,
    max: u32,
    per_client: usize,
    by_client: Arc<Mutex<HashMap<Client, usize>>>,
}

/// A session's place: freed when dropped.
#[derive(Debug)]
pub struct Place {
    _permit: OwnedSemaphorePermit,
    client: Client,
    address: IpAddr,
    by_client: Arc<Mutex<HashMap<Client, usize>>>,
}

impl Drop for Place {
    fn drop(&mut self) {
        let mut by_client = lock(&self.by_client);
        if let Some(count) = by_client.get_mut(&self.client) {
            *count -= 1;
            if *count == 0 {
                by_client.remove(&self.client);
            }
        }
    }
}

impl Place {
    /// The client holding the place.
    pub fn client(&self) -> &Client {
        &self.client
    }

    /// The address the session comes from.
    pub fn address(&self) -> IpAddr {
        self.address
    }
}

/// The counts, whatever a panic elsewhere left: each change is one step.
fn lock(
    by_client: &Mutex<HashMap<Client, usize>>,
) -> std::sync::MutexGuard<'_, HashMap<Client, usize>> {
    by_client.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Sessions {
    /// Places for `max` sessions at once, at most `per_client` of one client
    /// address.
    pub fn new(max: usize, per_client: usize) -> Sessions {
        let max = u32::try_from(max).unwrap_or(u32::MAX);
        Sessions {
            places: Arc::new(Semaphore::new(max as usize)),
            max,
            per_client,
            by_client: Arc::default(),
        }
    }

    /// Sessions open now.
    pub fn open(&self) -> usize {
        (self.max as usize).saturating_sub(self.places.available_permits())
    }

    /// A place for one more session of `client`, or why there is none.
    fn try_open(&self, client: Client, address: IpAddr) -> Result<Place, AppError> {
        let mut by_client = lock(&self.by_client);
        let count = by_client.entry(client.clone()).or_insert(0);
        if *count >= self.per_client {
            return Err(AppError::TooMany(format!(
                "{} view sessions from {client} are open, the most this server allows one \
                 client: close one, or retry later",
                self.per_client
            )));
        }
        let permit = self.places.clone().try_acquire_owned().map_err(|_| {
            AppError::Busy(format!(
                "{} view sessions are open, the most this server allows: retry later",
                self.max
            ))
        })?;
        *count += 1;
        Ok(Place {
            _permit: permit,
            client,
            address,
            by_client: self.by_client.clone(),
        })
    }

    /// Resolves when every session has ended; no session opens after.
    pub async fn all_closed(&self) {
        let all = self.places.acquire_many(self.max).await;
        self.places.close();
        drop(all);
    }
}

/// `GET /api/stream`: upgrades to a view session, or answers 403 to a page
/// of another site ([`crate::access`]), 429 when the client has
/// [`StreamSettings::sessions_per_client`] open and 503 when
/// [`StreamSettings::max_sessions`] are (both with `Retry-After`). A GET
/// that asks no upgrade is answered the same way, and 426 (upgrade
/// required) where a session could open now: a browser, whose WebSocket
/// hides why an upgrade failed, asks so to tell its user why.
pub async fn handler(
    ws: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
    State(state): State<AppState>,
    ConnectInfo(address): ConnectInfo<SocketAddr>,
    Extension(principal): Extension<Principal>,
    Extension(client): Extension<Client>,
    uri: Uri,
    headers: HeaderMap,
) -> Result<Response, Response> {
    state
        .access
        .check_origin(&uri, &headers)
        .map_err(IntoResponse::into_response)?;
    if state.draining.is_cancelled() {
        return Err(AppError::Busy(
            "this server is shutting down: open the session again (through a load balancer, \
             on another node)"
                .into(),
        )
        .into_response());
    }
    let place = state
        .sessions
        .try_open(client, address.ip())
        .map_err(IntoResponse::into_response)?;
    let Ok(ws) = ws else {
        drop(place);
        let message =
            "GET /api/stream opens a view session over WebSocket (a session could open now)";
        return Err((
            StatusCode::UPGRADE_REQUIRED,
            Json(serde_json::json!({ "error": message })),
        )
            .into_response());
    };
    let caller = socket::Caller {
        datasets: state.visible(&principal),
        principal,
    };
    Ok(ws
        .protocols([crate::auth::SUBPROTOCOL])
        .max_message_size(protocol::MAX_MESSAGE_BYTES)
        .max_frame_size(protocol::MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| async move {
            let (sink, stream) = socket.split();
            socket::run(sink, stream, &state, place, caller).await;
        }))
}
