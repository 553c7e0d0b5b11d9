//! The HTTP application: routes, shared state, and [`run`].
//!
//! | route | answer |
//! |---|---|
//! | `GET /` and other paths | the web client (`web/`) |
//! | `GET /api/render?…` | a PNG of one frame; the query's parameters are the view settings ([`crate::view`], listed by `GET /api/settings`); headers `X-Render-Ms`, `X-Queue-Ms` (waited for the render worker), `X-Encode-Ms`, `X-Reduction` (data reduction rendered at), `X-Levels` (blocks per level 0..4), `X-Pending-Blocks` (blocks still shown coarser: 0 unless reading them took too long), and for `shading=global` `X-Refinement` (in-scattering directions in, j/J) and `X-Light-Ms` |
//! | `HEAD /api/render?…`, `HEAD /api/datasets/{id}/render?…` | the `GET`'s checks and content type; never renders |
//! | `GET /api/stream` | a WebSocket view session: [`crate::protocol`], [`crate::stream`] |
//! | `GET /api/settings` | every view setting (name, flag, group, kind, range or choices, unit, default, doc, what it takes), as JSON: the web client builds its controls from it |
//! | `GET /api/datasets` | the datasets offered, as JSON, each with the `renderer` serving it (`{"kind":…,"device":…}`, kind `gpu` or `cpu`) |
//! | `GET /api/datasets/{id}` | one dataset's description; 404 for an unknown id |
//! | `GET /api/datasets/{id}/render?…` | `GET /api/render` for that dataset (thumbnails, embedding) |
//! | `GET /metrics` | OpenMetrics text: [`crate::metrics`] |
//! | `GET /healthz` | `{"status":"ok","adapter":…}` |
//!
//! Every request's `Host` is checked first ([`crate::access`]: 421 for a
//! name that is not the server's).

use std::future::Future;
use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::extract::rejection::QueryRejection;
use axum::extract::{ConnectInfo, Path, Query, State};
use axum::http::{HeaderValue, Uri, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

use crate::access::Access;
use crate::dataset::DatasetInfo;
use crate::metrics::{Format, FrameTimes, Metrics, Quality, Source};
use crate::stream::{Sessions, StreamSettings};
use crate::{AppError, Dataset, RenderService, View, encode, web};

/// What every handler shares.
#[derive(Debug, Clone)]
pub struct AppState {
    /// The datasets offered, the default first (never empty).
    pub datasets: Arc<[Dataset]>,
    /// The render worker.
    pub renderer: RenderService,
    /// How view sessions trade quality for speed.
    pub stream: StreamSettings,
    /// The view sessions' places (at most `stream.max_sessions`).
    pub sessions: Sessions,
    /// Cancelled when the server shuts down ([`run`] does it): every view
    /// session then closes (1001, going away).
    pub shutdown: CancellationToken,
    /// What the server has done, for `GET /metrics`.
    pub metrics: Arc<Metrics>,
    /// Who may reach the server, and how many connections it keeps.
    pub access: Arc<Access>,
}

impl AppState {
    /// The state of a server offering `datasets` (the first is the default)
    /// through `renderer`.
    ///
    /// # Panics
    /// When `datasets` is empty.
    pub fn new(
        datasets: Vec<Dataset>,
        renderer: RenderService,
        stream: StreamSettings,
    ) -> AppState {
        assert!(!datasets.is_empty(), "a server offers at least one dataset");
        let mut metrics = Metrics::default();
        metrics.set_renderer(renderer.kind(), renderer.adapter());
        AppState {
            datasets: datasets.into(),
            renderer,
            stream,
            sessions: Sessions::new(stream.max_sessions, stream.sessions_per_client),
            shutdown: CancellationToken::new(),
            metrics: Arc::new(metrics),
            access: Arc::new(Access::default()),
        }
    }

    /// This state with `access` in place of the default (loopback names and
    /// same-origin only, [`crate::listen::ConnectionLimits::DEFAULT`]).
    pub fn with_access(mut self, access: Access) -> AppState {
        self.access = Arc::new(access);
        self
    }
}

/// The router over `state`.
pub fn router(state: AppState) -> Router {
    let host_guard = axum::middleware::from_fn_with_state(state.clone(), crate::access::host_guard);
    Router::new()
        .route("/api/render", get(render).head(render_head))
        .route("/api/stream", get(crate::stream::handler))
        .route("/api/settings", get(settings))
        .route("/api/datasets", get(datasets))
        .route("/api/datasets/{id}", get(dataset))
        .route(
            "/api/datasets/{id}/render",
            get(dataset_render).head(dataset_render_head),
        )
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .fallback(get(static_file))
        .layer(host_guard)
        .with_state(state)
}

/// Serves the application on `listener` under `state.access`'s connection
/// limits ([`crate::listen`]) until `shutdown` resolves, then finishes the
/// requests in flight, closes the view sessions (cancelling
/// `state.shutdown`) and returns once every session has ended.
pub async fn run(
    listener: TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let sessions = state.sessions.clone();
    let token = state.shutdown.clone();
    let limits = state.access.connections;
    let stop = CancellationToken::new();
    let stopping = stop.clone();
    tokio::spawn(async move {
        shutdown.await;
        stopping.cancel();
        token.cancel();
    });
    let served = crate::listen::serve(listener, router(state), limits, stop.clone()).await;
    stop.cancel();
    // Upgraded connections are no longer the listener's: it does not wait
    // for them, so wait for the sessions here.
    sessions.all_closed().await;
    served
}

async fn static_file(uri: Uri) -> Result<Response, AppError> {
    web::asset(&uri)
}

async fn healthz(State(state): State<AppState>) -> Json<serde_json::Value> {
    Json(serde_json::json!({ "status": "ok", "adapter": state.renderer.adapter() }))
}

async fn settings(State(state): State<AppState>) -> Json<serde_json::Value> {
    Json(crate::view::describe(&state.datasets))
}

async fn datasets(State(state): State<AppState>) -> Json<Vec<serde_json::Value>> {
    Json(
        state
            .datasets
            .iter()
            .map(|d| with_renderer(&state, d.info()))
            .collect(),
    )
}

/// A dataset's description with the renderer that serves it.
fn with_renderer(state: &AppState, info: DatasetInfo) -> serde_json::Value {
    let mut value = serde_json::to_value(info).unwrap_or_default();
    if let Some(fields) = value.as_object_mut() {
        fields.insert("renderer".into(), state.renderer.describe());
    }
    value
}

/// The dataset `id`, or a 404 naming the ones there are.
fn find_dataset<'a>(state: &'a AppState, id: &str) -> Result<&'a Dataset, AppError> {
    state.datasets.iter().find(|d| d.id == id).ok_or_else(|| {
        let known: Vec<&str> = state.datasets.iter().map(|d| d.id.as_str()).collect();
        AppError::NotFound(format!(
            "dataset '{id}': expected one of {}",
            known.join(", ")
        ))
    })
}

async fn dataset(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<DatasetInfo>, AppError> {
    Ok(Json(find_dataset(&state, &id)?.info()))
}

/// `GET /api/datasets/{id}/render?…`: `GET /api/render` with the dataset in
/// the path (thumbnails, embedding).
async fn dataset_render(
    State(state): State<AppState>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    Path(id): Path<String>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let pairs = dataset_pairs(&state, id, query)?;
    render_pairs(&state, client.ip(), &pairs).await
}

/// `HEAD /api/datasets/{id}/render?…`: [`render_head`] with the dataset in
/// the path.
async fn dataset_render_head(
    State(state): State<AppState>,
    Path(id): Path<String>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let pairs = dataset_pairs(&state, id, query)?;
    head_pairs(&state, &pairs)
}

/// The view parameters of `/api/datasets/{id}/render?…`: the query's, and
/// the dataset `id` from the path.
fn dataset_pairs(
    state: &AppState,
    id: String,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Vec<(String, String)>, AppError> {
    find_dataset(state, &id)?;
    let Query(mut pairs) = query
        .map_err(|e| AppError::BadRequest(format!("malformed query string: {}", e.body_text())))?;
    if pairs.iter().any(|(name, _)| name == "dataset") {
        return Err(AppError::BadRequest(format!(
            "query parameter dataset: the dataset is '{id}' from the path; leave it out of the query"
        )));
    }
    pairs.push(("dataset".into(), id));
    Ok(pairs)
}

async fn metrics(State(state): State<AppState>) -> Response {
    let text = state.metrics.encode(
        state.sessions.open(),
        state.datasets.iter().map(|d| &*d.cache),
    );
    let content_type = "application/openmetrics-text; version=1.0.0; charset=utf-8";
    ([(header::CONTENT_TYPE, content_type)], text).into_response()
}

async fn render(
    State(state): State<AppState>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let Query(pairs) = query
        .map_err(|e| AppError::BadRequest(format!("malformed query string: {}", e.body_text())))?;
    render_pairs(&state, client.ip(), &pairs).await
}

/// `HEAD /api/render?…`: the headers of a PNG frame once the view parameters
/// are checked (400 as for `GET`), without rendering it.
async fn render_head(
    State(state): State<AppState>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let Query(pairs) = query
        .map_err(|e| AppError::BadRequest(format!("malformed query string: {}", e.body_text())))?;
    head_pairs(&state, &pairs)
}

/// The view `pairs` (query parameters) ask for, checked.
fn checked_view<'s>(
    state: &'s AppState,
    pairs: &[(String, String)],
) -> Result<(View, &'s Dataset), AppError> {
    let view = View::from_query(pairs, &state.datasets)
        .map_err(|e| AppError::BadRequest(e.to_string()))?;
    let dataset = view
        .dataset(&state.datasets)
        .map_err(|e| AppError::BadRequest(e.to_string()))?;
    Ok((view, dataset))
}

/// The answer to `HEAD` for the frame `pairs` ask for: its checks, no frame.
fn head_pairs(state: &AppState, pairs: &[(String, String)]) -> Result<Response, AppError> {
    checked_view(state, pairs)?;
    let headers = [
        (header::CONTENT_TYPE, HeaderValue::from_static("image/png")),
        (header::CACHE_CONTROL, HeaderValue::from_static("no-store")),
    ];
    Ok(headers.into_response())
}

/// How many renders `GET /api/render` makes while blocks arrive before it
/// answers with what it has (`X-Pending-Blocks` then says how many were shown
/// coarser).
const MAX_RENDERS: usize = 16;
/// How long one wait for blocks gathers arrivals, and may last in all.
const GATHER: Duration = Duration::from_secs(2);
const PATIENCE: Duration = Duration::from_secs(30);

/// Renders `request` of `dataset` at the detail it selects: the render
/// worker never waits for storage, so while blocks are being read the frame
/// shows them coarser; this waits (here, not on the worker) for them to
/// arrive and renders again.
async fn render_complete(
    state: &AppState,
    client: IpAddr,
    dataset: &Dataset,
    request: &shaders::FrameRequest,
) -> Result<crate::render_service::RenderedFrame, AppError> {
    let mut rendered = state
        .renderer
        .render(client, dataset, request.clone())
        .await?;
    for _ in 1..MAX_RENDERS {
        if rendered.stats.pending_blocks == 0 {
            break;
        }
        dataset.settle(rendered.arrivals, GATHER, PATIENCE).await;
        rendered = state
            .renderer
            .render(client, dataset, request.clone())
            .await?;
    }
    Ok(rendered)
}

/// Renders the frame `pairs` (query parameters) ask for, for `client`, as a
/// PNG response.
async fn render_pairs(
    state: &AppState,
    client: IpAddr,
    pairs: &[(String, String)],
) -> Result<Response, AppError> {
    let (view, dataset) = checked_view(state, pairs)?;
    let rendered = render_complete(state, client, dataset, &view.frame).await?;
    let encode_start = Instant::now();
    let frame = rendered.frame;
    let png = tokio::task::spawn_blocking(move || encode::png(&frame))
        .await
        .map_err(|e| AppError::Internal(format!("PNG encoder task failed: {e}")))?
        .map_err(|e| AppError::Internal(format!("PNG encoding failed: {e}")))?;
    let encode_ms = encode_start.elapsed().as_secs_f64() * 1e3;
    state.metrics.frame(
        Source::Http,
        Quality::Full,
        Format::Png,
        FrameTimes {
            render_ms: rendered.render_ms,
            queue_ms: rendered.queue_ms,
            encode_ms,
        },
    );
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
    set("x-queue-ms", format!("{:.1}", rendered.queue_ms));
    set("x-encode-ms", format!("{encode_ms:.1}"));
    set("x-reduction", format!("{:.2}", stats.reduction));
    set("x-levels", format!("{:?}", stats.level_counts));
    set("x-pending-blocks", stats.pending_blocks.to_string());
    if let Some(light) = stats.light() {
        set(
            "x-refinement",
            format!("{}/{}", light.refined, light.directions),
        );
        set("x-light-ms", format!("{:.1}", light.total_ms));
    }
    Ok((headers, png).into_response())
}
