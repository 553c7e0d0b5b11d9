//! Whether this node can serve viewers now, for `GET /healthz`: a load
//! balancer or an orchestrator sends them only to a ready node.
//!
//! A node is ready when it is not draining ([`crate::app::run`]) and its
//! last probe succeeded. A probe reads the default dataset's root metadata
//! again from its store (an object store that stopped answering makes the
//! node unready even while the blocks it shows are cached) and renders a
//! [`PROBE_EDGE`]² frame of it through the render worker, in turn with
//! every other frame: of the last view drawn of it, so its viewers' blocks
//! and light stay as they are ([`crate::RenderService::probe`]), else at
//! the largest data reduction. The first probe starts
//! with the server, and `/healthz` waits up to [`FIRST_PROBE_PATIENCE`]
//! for it; later ones start when `/healthz` finds the last result older
//! than [`PROBE_EVERY`] ([`PROBE_AGAIN`] after a failure), and it answers
//! with that result meanwhile, so a
//! request never waits behind a busy render worker, and at most one probe
//! runs at a time however often `/healthz` is asked.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use shaders::FrameRequest;

use crate::AppState;
use crate::client::Client;

/// How old a probe's success may be before `/healthz` starts another.
pub const PROBE_EVERY: Duration = Duration::from_secs(10);
/// How old a probe's failure may be before `/healthz` starts another: a
/// node that recovers (its store answers again) is ready again soon.
pub const PROBE_AGAIN: Duration = Duration::from_secs(2);
/// How long `/healthz` waits for the first probe's result.
pub const FIRST_PROBE_PATIENCE: Duration = Duration::from_secs(30);
/// A probe that has not finished after this long failed.
pub const PROBE_PATIENCE: Duration = Duration::from_secs(60);
/// The probe frame's width and height, in pixels.
pub const PROBE_EDGE: u32 = 16;

/// What `/healthz` answers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Readiness {
    /// The last probe succeeded: send viewers here.
    Ready,
    /// The first probe has not finished.
    Starting,
    /// The last probe failed, and why.
    Unready(String),
    /// The node is shutting down: its sessions finish their frames and
    /// close; new ones go elsewhere.
    Draining,
}

/// The probes' results.
#[derive(Debug)]
pub struct Health {
    /// When the last probe finished, and how.
    last: tokio::sync::watch::Sender<Option<(Instant, Result<(), String>)>>,
    probing: AtomicBool,
}

impl Default for Health {
    fn default() -> Health {
        Health {
            last: tokio::sync::watch::Sender::new(None),
            probing: AtomicBool::new(false),
        }
    }
}

impl Health {
    /// Starts a probe of `state`'s node unless one runs or the last result
    /// is younger than [`PROBE_EVERY`]. Needs a tokio runtime.
    pub fn refresh(state: &AppState) {
        let health = &state.health;
        let fresh = health.last.borrow().as_ref().is_some_and(|(at, result)| {
            at.elapsed()
                < if result.is_ok() {
                    PROBE_EVERY
                } else {
                    PROBE_AGAIN
                }
        });
        if fresh || health.probing.swap(true, Ordering::AcqRel) {
            return;
        }
        let state = state.clone();
        tokio::spawn(async move {
            let result = tokio::time::timeout(PROBE_PATIENCE, probe(&state))
                .await
                .unwrap_or_else(|_| {
                    Err(format!(
                        "the probe frame did not render within {} s",
                        PROBE_PATIENCE.as_secs()
                    ))
                });
            if let Err(e) = &result {
                tracing::warn!("health probe failed: {e}");
            }
            state
                .health
                .last
                .send_replace(Some((Instant::now(), result)));
            state.health.probing.store(false, Ordering::Release);
        });
    }

    /// Whether `state`'s node is ready, from the last probe's result
    /// (starting another when it is stale; the first is waited for).
    pub async fn readiness(state: &AppState) -> Readiness {
        if state.draining.is_cancelled() {
            return Readiness::Draining;
        }
        Health::refresh(state);
        let mut last = state.health.last.subscribe();
        if last.borrow().is_none() {
            let _ =
                tokio::time::timeout(FIRST_PROBE_PATIENCE, last.wait_for(Option::is_some)).await;
        }
        if state.draining.is_cancelled() {
            return Readiness::Draining;
        }
        match &*last.borrow() {
            None => Readiness::Starting,
            Some((_, Ok(()))) => Readiness::Ready,
            Some((_, Err(e))) => Readiness::Unready(e.clone()),
        }
    }
}

/// One probe: the default dataset's store answers, and a frame of it
/// renders.
async fn probe(state: &AppState) -> Result<(), String> {
    let dataset = state
        .datasets
        .snapshot()
        .first()
        .cloned()
        .ok_or("the server offers no dataset")?;
    let store = dataset.store.clone();
    tokio::task::spawn_blocking(move || store.check_readable())
        .await
        .map_err(|e| format!("the store check failed: {e}"))?
        .map_err(|e| format!("dataset '{}': {e}", dataset.id))?;
    let request = FrameRequest {
        width: PROBE_EDGE,
        height: PROBE_EDGE,
        reduction: shaders::frame::MAX_REDUCTION as f32,
        ..FrameRequest::default()
    };
    let client = Client::User("voxserve health probe".into());
    state
        .renderer
        .probe(&client, &dataset, request)
        .await
        .map(|_| ())
        .map_err(|e| format!("dataset '{}': the probe frame failed: {e}", dataset.id))
}
