//! The voxserve server: HTTP API, the web client, the render worker that owns the
//! GPU, frame encoding, and the command-line subcommands.
//!
//! # Layout
//! - [`app`]: the axum router, [`AppState`], and [`run`](app::run), which serves on
//!   a listener until a shutdown future resolves (tests use port 0).
//! - [`error`]: [`AppError`]: client errors become 4xx with a message naming the
//!   field; internal errors become a generic 500 and are logged once.
//! - [`frame_query`]: the query string of `GET /api/render` → a [`shaders::FrameRequest`].
//! - [`render_service`]: [`RenderService`], one worker thread that owns the GPU
//!   renderer and serves render jobs from all requests in arrival order.
//! - [`stream`]: view sessions over WebSocket (`GET /api/stream`): latest state
//!   wins, adaptive quality, one render worker shared in turn;
//!   [`protocol`]: their messages and the binary frame header, in one place.
//! - [`dataset`]: [`Dataset`], a brick store the server offers (on disk, or bricked
//!   in memory at start), and its public description.
//! - [`encode`]: frame → PNG or JPEG.
//! - [`metrics`]: `GET /metrics`, OpenMetrics text (sessions, frames, render,
//!   encode and queue time histograms, block cache hits).
//! - [`web`]: the static web client from `web/`, compiled into the binary.
//! - [`cli`]: the command line's subcommands and flags.
//! - [`commands`]: what `serve`, `render`, `info` and `ingest` do.
//! - [`bench`]: `voxserve bench render | read | blocks | light`, JSON lines.
//! - [`reference_data`]: the real datasets of `../shared/data` that tests and
//!   benchmarks use, with how to read them and a transfer function for each.

pub mod app;
pub mod bench;
pub mod cli;
pub mod commands;
pub mod dataset;
pub mod encode;
pub mod error;
pub mod frame_query;
pub mod metrics;
pub mod protocol;
pub mod reference_data;
pub mod render_service;
pub mod stream;
pub mod web;

pub use app::{AppState, run};
pub use dataset::Dataset;
pub use error::AppError;
pub use render_service::RenderService;
