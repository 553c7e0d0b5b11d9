//! The HTTP application: routes, shared state, and [`run`].
//!
//! | route | answer |
//! |---|---|
//! | `GET /` and other paths | the web client (`web/`) |
//! | `GET /api/render?…` | a PNG of one frame; the query's parameters are the view settings ([`crate::view`], listed by `GET /api/settings`); headers `X-Render-Ms`, `X-Queue-Ms` (waited for the render worker), `X-Encode-Ms`, `X-Reduction` (data reduction rendered at), `X-Levels` (blocks per level 0..4), `X-Pending-Blocks` (blocks still shown coarser: 0 unless reading them took too long), with `fit=true` `X-Camera` (the camera the fit chose, as query parameters), and for `shading=global` `X-Refinement` (in-scattering directions in, j/J) and `X-Light-Ms` |
//! | `HEAD /api/render?…`, `HEAD /api/datasets/{id}/render?…` | the `GET`'s checks and content type; never renders |
//! | `GET /api/stream` | a WebSocket view session: [`crate::protocol`], [`crate::stream`] |
//! | `GET /api/settings` | every view setting (name, flag, group, kind, range or choices, unit, default, doc, what it takes), as JSON: the web client builds its controls from it |
//! | `GET /api/datasets` | the datasets offered, as JSON, each with the `renderer` serving it (`{"kind":…,"device":…}`, kind `gpu` or `cpu`) |
//! | `GET /api/datasets/{id}` | one dataset's description; 404 for an unknown id |
//! | `GET /api/datasets/{id}/render?…` | `GET /api/render` for that dataset (thumbnails, embedding) |
//! | `GET /metrics` | OpenMetrics text: [`crate::metrics`] |
//! | `GET /healthz` | `{"status":"ok"}` when the node can render ([`crate::health`]); 503 with `status` `starting`, `unavailable` or `draining` when not (with the `adapter`, and the `error`, when the server has no authentication) |
//! | `POST /dicom-web/studies`, `POST /dicom-web/studies/{study}` | STOW-RS: [`crate::receive`] (with `--receive`; a store role) |
//! | `GET /api/auth` | how to log in: `{"required":…,"oidc":{"issuer","client_id","scopes","authorization_endpoint","token_endpoint"}|null,"api_tokens":…}` |
//!
//! Every request's `Host` is checked first ([`crate::access`]: 421 for a
//! name that is not the server's), and every response has the security
//! headers of [`crate::access`]. The API routes (`/api/…` but `/api/auth`,
//! and `/metrics`) need a token when the server has authentication
//! ([`crate::auth`]: 401 without a valid one); the web client's files,
//! `/healthz` and `/api/auth` do not. Lists show only the datasets the
//! caller may see; another dataset answers 403, or 404 when the policy
//! hides denied ones. `/metrics` needs a metrics role, STOW-RS a store
//! role. Each access is
//! recorded in the audit trail ([`crate::audit`]).

use std::future::Future;
use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::Extension;
use axum::extract::rejection::QueryRejection;
use axum::extract::{ConnectInfo, Path, Query, State};
use axum::http::{HeaderValue, Uri, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

use crate::access::Access;
use crate::audit::{Audit, Event, Outcome};
use crate::auth::{Auth, Principal};
use crate::client::{Client, RequestRates};
use crate::dataset::DatasetInfo;
use crate::metrics::{Format, FrameTimes, Metrics, Quality, Source};
use crate::stream::{Sessions, StreamSettings};
use crate::{AppError, Dataset, RenderService, View, encode, web};

/// How long sessions may take to finish their frames when the server
/// drains, unless `serve --drain-s` says otherwise.
pub const DEFAULT_DRAIN: Duration = Duration::from_secs(30);

/// What every handler shares.
#[derive(Debug, Clone)]
pub struct AppState {
    /// The datasets offered, the default first (never empty); more may
    /// arrive while the server runs (studies received).
    pub datasets: Datasets,
    /// The render worker.
    pub renderer: RenderService,
    /// How view sessions trade quality for speed.
    pub stream: StreamSettings,
    /// The view sessions' places (at most `stream.max_sessions`).
    pub sessions: Sessions,
    /// Cancelled when the server shuts down ([`run`] does it): every view
    /// session then closes (1001, going away).
    pub shutdown: CancellationToken,
    /// Cancelled when the server starts draining ([`run`]): `/healthz`
    /// answers 503, new sessions are refused, and each session finishes
    /// the frame it renders, then closes (1001, on which the web client
    /// reconnects, through a load balancer to another node).
    pub draining: CancellationToken,
    /// How long [`run`] lets sessions finish their frames before it closes
    /// them (`serve --drain-s`).
    pub drain_timeout: Duration,
    /// The health probes' results, for `/healthz` ([`crate::health`]).
    pub health: Arc<crate::health::Health>,
    /// What the server has done, for `GET /metrics`.
    pub metrics: Arc<Metrics>,
    /// Who may reach the server, and how many connections it keeps.
    pub access: Arc<Access>,
    /// Who is asking, and what they may see.
    pub auth: Arc<Auth>,
    /// Where access events are recorded.
    pub audit: Arc<Audit>,
    /// The certificate when served over TLS.
    pub tls: Option<Arc<crate::tls::Tls>>,
    /// Each client's API requests a second (at most `access.requests`).
    pub rates: Arc<RequestRates>,
    /// A line every viewer shows over the image (`--notice`), if any.
    pub notice: Option<Arc<str>>,
    /// Where studies pushed to the server go (`--receive`), if anywhere.
    pub receiver: Option<Arc<crate::receive::Receiver>>,
    /// The PACS the study browser searches (`--pacs`), if any.
    pub studies: Option<Arc<crate::studies::Studies>>,
}

/// The datasets a server offers: a list read as a whole (a request works
/// on the list as it was when it began, a view session on the list as it
/// was at its last message) and added to, or taken from, while the server
/// runs.
#[derive(Debug, Clone)]
pub struct Datasets(Arc<std::sync::RwLock<Arc<[Dataset]>>>);

impl Datasets {
    /// `list`, the default first.
    pub fn new(list: Vec<Dataset>) -> Datasets {
        Datasets(Arc::new(std::sync::RwLock::new(list.into())))
    }

    /// The datasets now.
    pub fn snapshot(&self) -> Arc<[Dataset]> {
        self.0
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Whether a dataset has the id `id`.
    pub fn contains(&self, id: &str) -> bool {
        self.snapshot().iter().any(|d| d.id == id)
    }

    /// Offers `dataset` too, in place of one with its id.
    pub fn add(&self, dataset: Dataset) {
        let mut list = self
            .0
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut next: Vec<Dataset> = list
            .iter()
            .filter(|d| d.id != dataset.id)
            .cloned()
            .collect();
        next.push(dataset);
        *list = next.into();
    }

    /// No longer offers dataset `id` (sessions showing it keep what they
    /// hold); never the last one.
    pub fn remove(&self, id: &str) {
        let mut list = self
            .0
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if list.len() > 1 && list.iter().any(|d| d.id == id) {
            let next: Vec<Dataset> = list.iter().filter(|d| d.id != id).cloned().collect();
            *list = next.into();
        }
    }
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
            datasets: Datasets::new(datasets),
            renderer,
            stream,
            sessions: Sessions::new(stream.max_sessions, stream.sessions_per_client),
            shutdown: CancellationToken::new(),
            draining: CancellationToken::new(),
            drain_timeout: DEFAULT_DRAIN,
            health: Arc::default(),
            metrics: Arc::new(metrics),
            access: Arc::new(Access::default()),
            auth: Arc::new(Auth::default()),
            audit: Arc::new(Audit::default()),
            tls: None,
            rates: Arc::new(RequestRates::new(Access::default().requests)),
            notice: None,
            receiver: None,
            studies: None,
        }
    }

    /// This state with `notice` shown by every viewer (e.g. "Not for
    /// diagnostic use").
    pub fn with_notice(mut self, notice: Option<String>) -> AppState {
        self.notice = notice.filter(|n| !n.is_empty()).map(Arc::from);
        self
    }

    /// This state served over `tls` (and sending HSTS).
    pub fn with_tls(mut self, tls: Arc<crate::tls::Tls>) -> AppState {
        self.tls = Some(tls);
        self
    }

    /// This state with `auth` in place of none (everyone anonymous) and
    /// events recorded to `audit`.
    pub fn with_auth(mut self, auth: Auth, audit: Audit) -> AppState {
        self.auth = Arc::new(auth);
        self.audit = Arc::new(audit);
        self
    }

    /// The datasets `principal` may see, in order.
    pub fn visible(&self, principal: &Principal) -> Arc<[Dataset]> {
        let all = self.datasets.snapshot();
        if !self.auth.required() {
            return all;
        }
        all.iter()
            .filter(|d| self.auth.may_see(principal, &d.id))
            .cloned()
            .collect()
    }

    /// The dataset `id` if `principal` may see it.
    ///
    /// # Errors
    /// 404 for an unknown id (naming the ones the principal may see); 403
    /// for a denied one, or the same 404 when the policy hides denied
    /// datasets.
    pub fn find_dataset(&self, principal: &Principal, id: &str) -> Result<Dataset, AppError> {
        let all = self.datasets.snapshot();
        let found = all.iter().find(|d| d.id == id);
        match found {
            Some(dataset) if self.auth.may_see(principal, id) => Ok(dataset.clone()),
            Some(_) if !self.auth.hides_denied() => Err(AppError::Forbidden(format!(
                "dataset '{id}': {} may not see it",
                principal.user
            ))),
            _ => {
                let visible = self.visible(principal);
                let known: Vec<&str> = visible.iter().map(|d| d.id.as_str()).collect();
                Err(AppError::NotFound(format!(
                    "dataset '{id}': expected one of {}",
                    known.join(", ")
                )))
            }
        }
    }

    /// Records `event` in the audit trail.
    pub fn audit(&self, event: &Event) {
        self.audit.record(event);
    }

    /// This state with `access` in place of the default (loopback names and
    /// same-origin only, [`crate::listen::ConnectionLimits::DEFAULT`]).
    pub fn with_access(mut self, access: Access) -> AppState {
        self.rates = Arc::new(RequestRates::new(access.requests));
        self.access = Arc::new(access);
        self
    }
}

/// The router over `state`.
pub fn router(state: AppState) -> Router {
    let host_guard = axum::middleware::from_fn_with_state(state.clone(), crate::access::host_guard);
    let headers =
        axum::middleware::from_fn_with_state(state.clone(), crate::access::security_headers);
    let authenticated = axum::middleware::from_fn_with_state(state.clone(), crate::auth::require);
    let rate_limited =
        axum::middleware::from_fn_with_state(state.clone(), crate::client::limit_rate);
    let api = Router::new()
        .route("/api/render", get(render).head(render_head))
        // HTTP/2 opens WebSockets with CONNECT (RFC 8441).
        .route(
            "/api/stream",
            get(crate::stream::handler).connect(crate::stream::handler),
        )
        .route("/api/settings", get(settings))
        .route("/dicom-web/studies", post(crate::receive::stow))
        .route(
            "/dicom-web/studies/{study}",
            post(crate::receive::stow_study),
        )
        .route("/api/pacs", get(crate::studies::list))
        .route("/api/pacs/studies", get(crate::studies::search))
        .route("/api/pacs/series", get(crate::studies::series))
        .route(
            "/api/pacs/open",
            post(crate::studies::open).get(crate::studies::progress),
        )
        .route("/api/pacs/iid", get(crate::studies::resolve))
        .route("/api/pacs/thumbnail", get(crate::studies::thumbnail))
        .route("/api/datasets", get(datasets))
        .route("/api/datasets/{id}", get(dataset))
        .route(
            "/api/datasets/{id}/render",
            get(dataset_render).head(dataset_render_head),
        )
        .route("/metrics", get(metrics))
        // Authenticated first: the rate is the user's.
        .layer(rate_limited)
        .layer(authenticated);
    Router::new()
        .merge(api)
        .route("/api/auth", get(auth_config))
        .route("/healthz", get(healthz))
        .route("/IHEInvokeImageDisplay", get(crate::studies::invoke))
        .fallback(get(static_file))
        .layer(host_guard)
        .layer(headers)
        .with_state(state)
}

/// Serves the application on `listener` under `state.access`'s connection
/// limits ([`crate::listen`]) until `shutdown` resolves, then drains: stops
/// accepting connections (a load balancer sends new ones to another node),
/// answers `/healthz` with 503 `draining` on connections still open,
/// finishes the requests in flight, lets each view session finish the
/// frame it renders and close (`state.draining`), closes those still open
/// and the connections still answering a request after
/// `state.drain_timeout` (`state.shutdown`), and returns once every
/// session has ended. The first health probe starts here.
pub async fn run(
    listener: TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let sessions = state.sessions.clone();
    let token = state.shutdown.clone();
    let draining = state.draining.clone();
    let drain = state.drain_timeout;
    let limits = state.access.connections;
    let tls = state.tls.clone();
    let starting = draining.clone();
    tokio::spawn(async move {
        shutdown.await;
        starting.cancel();
    });
    // The drain's deadline counts from when it begins, whatever the
    // requests in flight take.
    let (begun, closing, open) = (draining.clone(), token.clone(), sessions.clone());
    tokio::spawn(async move {
        begun.cancelled().await;
        let at_start = open.open();
        tokio::time::sleep(drain).await;
        if open.open() > 0 {
            tracing::warn!(
                "{} of {at_start} view sessions still open after {} s of draining: closing them",
                open.open(),
                drain.as_secs_f64()
            );
        }
        closing.cancel();
    });
    crate::health::Health::refresh(&state);
    let trusted: Arc<[ipnet::IpNet]> = state.access.trusted_proxies.clone().into();
    let served = crate::listen::serve(
        listener,
        router(state),
        limits,
        trusted,
        tls,
        draining.clone(),
        token.clone(),
    )
    .await;
    draining.cancel();
    // Upgraded connections are no longer the listener's: it does not wait
    // for them, so wait for the sessions here.
    sessions.all_closed().await;
    token.cancel();
    served
}

async fn static_file(uri: Uri) -> Result<Response, AppError> {
    web::asset(&uri)
}

/// 200 `{"status":"ok"}` when the node can render ([`crate::health`]),
/// else 503 with `status` `starting`, `unavailable` or `draining`; without
/// authentication also the `adapter`, and why an unavailable node is.
async fn healthz(State(state): State<AppState>) -> Response {
    use crate::health::{Health, Readiness};
    let readiness = Health::readiness(&state).await;
    let (code, status, why) = match readiness {
        Readiness::Ready => (axum::http::StatusCode::OK, "ok", None),
        Readiness::Starting => (
            axum::http::StatusCode::SERVICE_UNAVAILABLE,
            "starting",
            Some("the first probe frame has not rendered yet".to_owned()),
        ),
        Readiness::Unready(why) => (
            axum::http::StatusCode::SERVICE_UNAVAILABLE,
            "unavailable",
            Some(why),
        ),
        Readiness::Draining => (
            axum::http::StatusCode::SERVICE_UNAVAILABLE,
            "draining",
            Some("the server is shutting down".to_owned()),
        ),
    };
    let mut body = serde_json::json!({ "status": status });
    // Strangers learn nothing more of a server with authentication.
    if !state.auth.required() {
        body["adapter"] = state.renderer.adapter().into();
        if let Some(why) = why {
            body["error"] = why.into();
        }
    }
    (code, Json(body)).into_response()
}

async fn auth_config(State(state): State<AppState>) -> Json<serde_json::Value> {
    Json(state.auth.describe())
}

async fn settings(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
) -> Json<serde_json::Value> {
    Json(crate::view::describe(&state.visible(&principal)))
}

async fn datasets(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
) -> Json<Vec<serde_json::Value>> {
    let visible = state.visible(&principal);
    state.audit(
        &Event::new(
            "list",
            Some(&principal),
            Some(client.ip()),
            Outcome::Success,
        )
        .detail(format!(
            "{} of {} datasets",
            visible.len(),
            state.datasets.snapshot().len()
        )),
    );
    Json(
        visible
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

/// Records an access to `dataset` by `principal` from `client` that ended
/// in `result`.
fn audit_access<T>(
    state: &AppState,
    event: &'static str,
    principal: &Principal,
    client: IpAddr,
    dataset: Option<&str>,
    result: &Result<T, AppError>,
) {
    let (outcome, detail) = match result {
        Ok(_) => (Outcome::Success, None),
        Err(e @ (AppError::Forbidden(_) | AppError::NotFound(_))) => {
            (Outcome::Denied, Some(e.to_string()))
        }
        Err(e) => (Outcome::Failure, Some(e.to_string())),
    };
    let mut line = Event::new(event, Some(principal), Some(client), outcome);
    if let Some(id) = dataset {
        line = line.dataset(id);
    }
    if let Some(detail) = detail {
        line = line.detail(detail);
    }
    state.audit(&line);
}

async fn dataset(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    Path(id): Path<String>,
) -> Result<Json<DatasetInfo>, AppError> {
    let found = state.find_dataset(&principal, &id).map(|d| d.info());
    audit_access(
        &state,
        "describe",
        &principal,
        client.ip(),
        Some(&id),
        &found,
    );
    found.map(Json)
}

/// `GET /api/datasets/{id}/render?…`: `GET /api/render` with the dataset in
/// the path (thumbnails, embedding).
async fn dataset_render(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    Extension(asker): Extension<Client>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    Path(id): Path<String>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let rendered = match dataset_pairs(&state, &principal, id.clone(), query) {
        Ok(pairs) => render_pairs(&state, &principal, &asker, &pairs).await,
        Err(e) => Err(e),
    };
    audit_access(
        &state,
        "render",
        &principal,
        client.ip(),
        Some(&id),
        &rendered,
    );
    rendered
}

/// `HEAD /api/datasets/{id}/render?…`: [`render_head`] with the dataset in
/// the path.
async fn dataset_render_head(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    Path(id): Path<String>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let pairs = dataset_pairs(&state, &principal, id, query)?;
    head_pairs(&state, &principal, &pairs)
}

/// The view parameters of `/api/datasets/{id}/render?…`: the query's, and
/// the dataset `id` from the path.
fn dataset_pairs(
    state: &AppState,
    principal: &Principal,
    id: String,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Vec<(String, String)>, AppError> {
    state.find_dataset(principal, &id)?;
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

async fn metrics(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
) -> Result<Response, AppError> {
    let allowed = if state.auth.may_read_metrics(&principal) {
        Ok(())
    } else {
        Err(AppError::Forbidden(format!(
            "/metrics: {} has no metrics role (the policy file's metrics_roles)",
            principal.user
        )))
    };
    audit_access(&state, "metrics", &principal, client.ip(), None, &allowed);
    allowed?;
    let text = state.metrics.encode(
        state.sessions.open(),
        &state.renderer,
        state.datasets.snapshot().iter().map(|d| &*d.cache),
    );
    let content_type = "application/openmetrics-text; version=1.0.0; charset=utf-8";
    Ok(([(header::CONTENT_TYPE, content_type)], text).into_response())
}

async fn render(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    Extension(asker): Extension<Client>,
    ConnectInfo(client): ConnectInfo<SocketAddr>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let rendered = match query {
        Ok(Query(pairs)) => {
            let rendered = render_pairs(&state, &principal, &asker, &pairs).await;
            let named = named_dataset(&pairs).map(str::to_owned);
            let id = named.or_else(|| state.visible(&principal).first().map(|d| d.id.clone()));
            audit_access(
                &state,
                "render",
                &principal,
                client.ip(),
                id.as_deref(),
                &rendered,
            );
            return rendered;
        }
        Err(e) => Err(AppError::BadRequest(format!(
            "malformed query string: {}",
            e.body_text()
        ))),
    };
    audit_access(&state, "render", &principal, client.ip(), None, &rendered);
    rendered
}

/// `HEAD /api/render?…`: the headers of a PNG frame once the view parameters
/// are checked (400 as for `GET`), without rendering it.
async fn render_head(
    State(state): State<AppState>,
    Extension(principal): Extension<Principal>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Response, AppError> {
    let Query(pairs) = query
        .map_err(|e| AppError::BadRequest(format!("malformed query string: {}", e.body_text())))?;
    head_pairs(&state, &principal, &pairs)
}

/// The dataset a query names, if it names one.
fn named_dataset(pairs: &[(String, String)]) -> Option<&str> {
    pairs
        .iter()
        .find(|(name, _)| name == "dataset")
        .map(|(_, id)| id.as_str())
}

/// The view `pairs` (query parameters) ask for, checked: a dataset they name
/// must be one `principal` may see (403, or 404).
fn checked_view(
    state: &AppState,
    principal: &Principal,
    pairs: &[(String, String)],
) -> Result<(View, Dataset), AppError> {
    if let Some(id) = named_dataset(pairs)
        && state.datasets.contains(id)
    {
        state.find_dataset(principal, id)?;
    }
    let visible = state.visible(principal);
    if visible.is_empty() {
        return Err(AppError::Forbidden(format!(
            "{} may see no dataset",
            principal.user
        )));
    }
    let view =
        View::from_query(pairs, &visible).map_err(|e| AppError::BadRequest(e.to_string()))?;
    let dataset = view
        .dataset(&visible)
        .map_err(|e| AppError::BadRequest(e.to_string()))?
        .clone();
    Ok((view, dataset))
}

/// The answer to `HEAD` for the frame `pairs` ask for: its checks, no frame.
fn head_pairs(
    state: &AppState,
    principal: &Principal,
    pairs: &[(String, String)],
) -> Result<Response, AppError> {
    checked_view(state, principal, pairs)?;
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
    client: &Client,
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
        // Admitted already: not refused for the client's other frames waiting.
        rendered = state
            .renderer
            .render_waiting(client, dataset, request.clone())
            .await?;
    }
    Ok(rendered)
}

/// Renders the frame `pairs` (query parameters) ask for, for `client`, as a
/// PNG response.
async fn render_pairs(
    state: &AppState,
    principal: &Principal,
    client: &Client,
    pairs: &[(String, String)],
) -> Result<Response, AppError> {
    let (view, dataset) = checked_view(state, principal, pairs)?;
    let rendered = render_complete(state, client, &dataset, &view.frame).await?;
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
    set("x-render-bands", rendered.bands.to_string());
    set(
        "x-render-band-ms",
        format!("{:.1}", rendered.longest_band_ms),
    );
    set("x-encode-ms", format!("{encode_ms:.1}"));
    set("x-reduction", format!("{:.2}", stats.reduction));
    set("x-empty-share", format!("{:.3}", stats.empty_share));
    if stats.memory_limited {
        set("x-memory-limited", "1".to_owned());
    }
    set("x-levels", format!("{:?}", stats.level_counts));
    set("x-pending-blocks", stats.pending_blocks.to_string());
    if let Some(camera) = &stats.camera {
        // The camera a fit chose, as query parameters that draw it again.
        let query = shaders::settings::Settings::to_texts(camera)
            .iter()
            .map(|(spec, text)| format!("{}={text}", spec.name))
            .collect::<Vec<_>>()
            .join("&");
        set("x-camera", query);
    }
    if let Some(light) = stats.light() {
        set(
            "x-refinement",
            format!("{}/{}", light.refined, light.directions),
        );
        set("x-light-ms", format!("{:.1}", light.total_ms));
    }
    Ok((headers, png).into_response())
}
