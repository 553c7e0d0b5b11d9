//! The voxserve server: HTTP API, the web client, the render worker that owns the
//! GPU, frame encoding, and the command-line subcommands.
//!
//! # Layout
//! - [`app`]: the axum router, [`AppState`], and [`run`](app::run), which serves on
//!   a listener until a shutdown future resolves, then drains (the view
//!   sessions finish their frames and close) and returns when they have ended
//!   (tests use port 0); [`health`]: what `/healthz` answers (probes).
//! - [`access`]: [`access::Access`], who may reach the server: the `Host`
//!   names it answers to, the web origins that may open view sessions.
//! - [`auth`]: [`auth::Auth`], who is asking (OpenID Connect access tokens,
//!   static API tokens) and which datasets they may see (a policy file);
//!   [`audit`]: one JSON line per access event.
//! - [`listen`]: the accept loop: connection caps (overall and per client,
//!   the quietest connection closed to make room), header and idle timeouts.
//! - [`tls`]: [`tls::Tls`], the certificate and key, read again on `SIGHUP`.
//! - [`error`]: [`AppError`]: client errors become 4xx with a message naming the
//!   field; internal errors become a generic 500 and are logged once.
//! - [`view`]: [`View`], what a client asks to see (a dataset and a frame
//!   request), read from `GET /api/render`'s query or merged from view-session
//!   patches, every setting checked as the schema (`shaders::settings`)
//!   declares it; `GET /api/settings` describes them.
//! - [`render_service`]: [`RenderService`], one worker thread that owns the GPU
//!   renderer and serves render jobs from all requests in arrival order.
//! - [`stream`]: view sessions over WebSocket (`GET /api/stream`): latest state
//!   wins, adaptive quality, one render worker shared in turn; a state machine
//!   without I/O or clock, and a thin loop on the socket that closes it on
//!   shutdown;
//!   [`protocol`]: their messages and the binary frame header, in one place.
//! - [`dataset`]: [`Dataset`], a brick store the server offers (on disk, or bricked
//!   in memory at start), and its public description.
//! - [`encode`]: frame → PNG or JPEG.
//! - [`metrics`]: `GET /metrics`, OpenMetrics text (sessions, frames, render,
//!   encode and queue time histograms, block cache hits).
//! - [`web`]: the static web client from `web/`, compiled into the binary.
//! - [`cli`]: the command line's subcommands and flags (`render`'s view flags
//!   from the settings schema).
//! - [`pacs`]: studies from a PACS over DICOMweb (QIDO-RS, WADO-RS), fetched
//!   into a spool folder and bricked as the same files on disk are.
//! - [`receive`]: studies pushed to the server (STOW-RS), kept series by
//!   series and bricked into datasets once complete.
//! - [`studies`]: the study browser's PACS search and opening of series
//!   (fetched, bricked and cached), and IHE Invoke Image Display.
//! - [`dimse`]: the DICOM C-STORE and C-ECHO service class provider, keeping
//!   what it receives as [`receive`] does.
//! - [`commands`]: what `serve`, `render`, `info`, `ingest`, `pacs` and
//!   `settings` do.
//!
//! The benchmarks (`voxserve bench`) are in the binary's module tree
//! (`server/src/bench/`), not in this library.

pub mod access;
pub mod app;
pub mod audit;
pub mod auth;
pub mod cli;
pub mod client;
pub mod commands;
pub mod dataset;
pub mod dimse;
pub mod encode;
pub mod error;
pub mod health;
pub mod listen;
pub mod metrics;
pub mod pacs;
pub mod protocol;
pub mod receive;
pub mod render_service;
pub mod stream;
pub mod studies;
pub mod tls;
pub mod view;
pub mod web;

pub use app::{AppState, run};
pub use dataset::Dataset;
pub use error::AppError;
pub use render_service::RenderService;
pub use view::View;
