//! The HTTP application: routes, shared state, and [`run`].
//!
//! | route | answer |
//! |---|---|
//! | `GET /` and other paths | the web client (`web/`) |
//! | `GET /api/render?…` | a PNG of one frame; parameters in [`crate::frame_query`]; headers `X-Render-Ms`, `X-Encode-Ms`, `X-Reduction` (data reduction rendered at), `X-Levels` (blocks per level 0..4), and for `shading=global` `X-Refinement` (in-scattering directions in, j/J) and `X-Light-Ms` |
//! | `GET /api/stream` | a WebSocket view session: [`crate::protocol`], [`crate::stream`] |
//! | `GET /api/datasets` | the datasets offered, as JSON |
//! | `GET /healthz` | `{"status":"ok","adapter":…}` |

use std::future::Future;
use std::time::Instant;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::http::{HeaderValue, Uri, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use tokio::net::TcpListener;

use crate::dataset::DatasetInfo;
use crate::stream::{SessionCounter, StreamSettings};
use crate::{AppError, Dataset, RenderService, encode, frame_query, web};

/// What every handler shares.
#[derive(Debug, Clone)]
pub struct AppState {
    /// The dataset offered (the render worker holds it on the GPU).
    pub dataset: Dataset,
    /// The render worker.
    pub renderer: RenderService,
    /// How view sessions trade quality for speed.
    pub stream: StreamSettings,
    /// The view sessions open.
    pub sessions: SessionCounter,
}

impl AppState {
    /// The state of a server offering `dataset` through `renderer`.
    pub fn new(dataset: Dataset, renderer: RenderService, stream: StreamSettings) -> AppState {
        AppState {
            dataset,
            renderer,
            stream,
            sessions: SessionCounter::default(),
        }
    }
}

/// The router over `state`.
pub fn router(state: AppState) -> Router {
    Router::new()
        .route("/api/render", get(render))
        .route("/api/stream", get(crate::stream::handler))
        .route("/api/datasets", get(datasets))
        .route("/healthz", get(healthz))
        .fallback(get(static_file))
        .with_state(state)
}

/// Serves the application on `listener` until `shutdown` resolves, then finishes
/// the requests in flight.
pub async fn run(
    listener: TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    axum::serve(listener, router(state))
        .with_graceful_shutdown(shutdown)
        .await
}

async fn static_file(uri: Uri) -> Result<Response, AppError> {
    web::asset(&uri)
}

async fn healthz(State(state): State<AppState>) -> Json<serde_json::Value> {
    Json(serde_json::json!({ "status": "ok", "adapter": state.renderer.adapter() }))
}

async fn datasets(State(state): State<AppState>) -> Json<Vec<DatasetInfo>> {
    Json(vec![state.dataset.info()])
}

async fn render(
    State(state): State<AppState>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let Query(pairs) = query
        .map_err(|e| AppError::BadRequest(format!("malformed query string: {}", e.body_text())))?;
    let (_, request) = frame_query::parse(&pairs, std::slice::from_ref(&state.dataset))
        .map_err(AppError::BadRequest)?;
    let rendered = state.renderer.render(request).await?;
    let encode_start = Instant::now();
    let frame = rendered.frame;
    let png = tokio::task::spawn_blocking(move || encode::png(&frame))
        .await
        .map_err(|e| AppError::Internal(format!("PNG encoder task failed: {e}")))?
        .map_err(|e| AppError::Internal(format!("PNG encoding failed: {e}")))?;
    let encode_ms = encode_start.elapsed().as_secs_f64() * 1e3;
    let value =
        |text: String| HeaderValue::from_str(&text).unwrap_or(HeaderValue::from_static("-"));
    let stats = &rendered.stats;
    let mut headers = axum::http::HeaderMap::new();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/png"));
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    let mut set = |name: &'static str, text: String| {
        headers.insert(header::HeaderName::from_static(name), value(text));
    };
    set("x-render-ms", format!("{:.1}", rendered.render_ms));
    set("x-encode-ms", format!("{encode_ms:.1}"));
    set("x-reduction", format!("{:.2}", stats.reduction));
    set("x-levels", format!("{:?}", stats.level_counts));
    if let Some(light) = &stats.light {
        set(
            "x-refinement",
            format!("{}/{}", light.refined, light.directions),
        );
        set("x-light-ms", format!("{:.1}", light.total_ms));
    }
    Ok((headers, png).into_response())
}
