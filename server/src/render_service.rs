//! [`RenderService`]: one worker thread owns the renderer backend (the GPU,
//! or the CPU renderer: [`Backend`]) and a renderer per dataset in use;
//! handlers and view sessions send it jobs over a bounded channel and await
//! the reply.
//!
//! A renderer keeps its dataset's blocks (and light) in its atlas (on the
//! GPU, or in memory); at most [`RenderService::start`]'s
//! `resident_datasets` renderers are kept, and the one used least recently
//! goes (its memory freed) before another is made.
//!
//! Rendering is blocking (GPU: submit, then wait for the queue; CPU: every
//! core busy until the frame is done), so it runs on its own thread rather
//! than on the async runtime. Jobs are served in arrival order; when
//! the queue is full a request is refused at once (503) instead of waiting behind
//! work that will be stale by the time it runs.

use std::sync::Arc;
use std::time::Instant;

use shaders::{AnyRenderer, Backend, Frame, FrameRequest, GpuError, RenderStats};
use tokio::sync::{mpsc, oneshot};

use crate::{AppError, Dataset};

/// Jobs that may wait for the worker; more are refused.
pub const QUEUE_CAPACITY: usize = 8;

/// A rendered frame and how long the GPU took.
#[derive(Debug)]
pub struct RenderedFrame {
    /// The pixels.
    pub frame: Frame,
    /// Milliseconds from the worker taking the job to the pixels being read back.
    pub render_ms: f64,
    /// What the frame took and showed: data reduction, levels, uploads.
    pub stats: RenderStats,
    /// Milliseconds the job waited in the queue before the worker took it.
    pub queue_ms: f64,
    /// The dataset's chunk arrivals when the frame was planned: a frame with
    /// pending blocks can wait for arrivals after these
    /// ([`Dataset::settle`]).
    pub arrivals: u64,
}

struct Job {
    dataset: Dataset,
    request: FrameRequest,
    queued: Instant,
    reply: oneshot::Sender<Result<RenderedFrame, GpuError>>,
}

/// A handle to the render worker; cloning shares the worker.
#[derive(Debug, Clone)]
pub struct RenderService {
    // Dropped before `_worker`: when the last handle goes, the queue closes
    // first, so the worker's loop ends and the join below returns.
    jobs: mpsc::Sender<Job>,
    adapter: Arc<str>,
    kind: &'static str,
    _worker: Arc<WorkerThread>,
}

/// The worker thread, joined when the last handle is dropped, so the GPU
/// device is released before the process exits rather than racing its exit.
#[derive(Debug)]
struct WorkerThread(Option<std::thread::JoinHandle<()>>);

impl Drop for WorkerThread {
    fn drop(&mut self) {
        if let Some(handle) = self.0.take()
            && handle.join().is_err()
        {
            tracing::error!("the render worker panicked");
        }
    }
}

impl Job {
    /// A job queued now, and where its frame will come.
    fn new(
        dataset: &Dataset,
        request: FrameRequest,
    ) -> (Job, oneshot::Receiver<Result<RenderedFrame, GpuError>>) {
        let (reply, answer) = oneshot::channel();
        let job = Job {
            dataset: dataset.clone(),
            request,
            queued: Instant::now(),
            reply,
        };
        (job, answer)
    }
}

/// The worker's renderers, least recently used first.
struct Renderers {
    backend: Backend,
    budget_bytes: u64,
    capacity: usize,
    by_use: Vec<(String, AnyRenderer)>,
}

impl Renderers {
    /// The renderer of `dataset`, made (after dropping the least recently used
    /// one when all places are taken) if there is none.
    fn get(&mut self, dataset: &Dataset) -> Result<&mut AnyRenderer, GpuError> {
        if let Some(i) = self.by_use.iter().position(|(id, _)| *id == dataset.id) {
            let entry = self.by_use.remove(i);
            self.by_use.push(entry);
        } else {
            if self.by_use.len() >= self.capacity {
                // Freed before the next one allocates.
                let (id, _) = self.by_use.remove(0);
                tracing::info!("released dataset '{id}' from the renderer");
            }
            let renderer = self
                .backend
                .renderer(dataset.cache.clone(), self.budget_bytes)?;
            self.by_use.push((dataset.id.clone(), renderer));
        }
        self.by_use
            .last_mut()
            .map(|(_, r)| r)
            .ok_or_else(|| GpuError::InvalidRequest("no renderer".into()))
    }
}

impl std::fmt::Debug for Job {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Job")
            .field("request", &self.request)
            .finish()
    }
}

impl RenderService {
    /// Starts the worker thread rendering with `backend`, keeping at most
    /// `budget_bytes` of each dataset's blocks in its atlas and the
    /// renderers of at most `resident_datasets` datasets.
    pub fn start(
        backend: Backend,
        budget_bytes: u64,
        resident_datasets: usize,
    ) -> Result<RenderService, GpuError> {
        let adapter: Arc<str> = backend.describe().into();
        let kind = backend.kind();
        let mut renderers = Renderers {
            backend,
            budget_bytes,
            capacity: resident_datasets.max(1),
            by_use: Vec::new(),
        };
        let (jobs, mut queue) = mpsc::channel::<Job>(QUEUE_CAPACITY);
        let handle = std::thread::Builder::new()
            .name("render-worker".into())
            .spawn(move || {
                // Ends when every sender (every RenderService clone) is gone.
                while let Some(job) = queue.blocking_recv() {
                    let start = Instant::now();
                    let queue_ms = (start - job.queued).as_secs_f64() * 1e3;
                    // Never waits for storage: blocks still being read are
                    // shown coarser and later frames refine them.
                    let arrivals = job.dataset.cache.arrivals();
                    let result = renderers.get(&job.dataset).and_then(|renderer| {
                        renderer
                            .render_now(&job.request)
                            .map(|frame| RenderedFrame {
                                frame,
                                render_ms: start.elapsed().as_secs_f64() * 1e3,
                                stats: renderer.last_stats().clone(),
                                queue_ms,
                                arrivals,
                            })
                    });
                    if let Err(e) = &result {
                        tracing::warn!("render failed: {e}");
                    }
                    // The requester may have gone away; nothing to do then.
                    let _ = job.reply.send(result);
                }
            })
            .map_err(|e| GpuError::Wait {
                operation: "starting the render worker".into(),
                reason: e.to_string(),
            })?;
        Ok(RenderService {
            jobs,
            adapter,
            kind,
            _worker: Arc::new(WorkerThread(Some(handle))),
        })
    }

    /// What the worker renders on, in words: the adapter, or the CPU.
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    /// Which renderer serves: `gpu` or `cpu`.
    pub fn kind(&self) -> &'static str {
        self.kind
    }

    /// `{"kind": "gpu"|"cpu", "device": …}`, for clients.
    pub fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "kind": self.kind, "device": &*self.adapter })
    }

    /// Renders `request`, or refuses at once when the queue is full (single
    /// HTTP frames: a client retries rather than waiting behind stale work).
    pub async fn render(
        &self,
        dataset: &Dataset,
        request: FrameRequest,
    ) -> Result<RenderedFrame, AppError> {
        let (job, answer) = Job::new(dataset, request);
        self.jobs.try_send(job).map_err(|e| match e {
            mpsc::error::TrySendError::Full(_) => AppError::Busy(format!(
                "the renderer has {QUEUE_CAPACITY} frames waiting: retry shortly"
            )),
            mpsc::error::TrySendError::Closed(_) => {
                AppError::Internal("the render worker has stopped".into())
            }
        })?;
        Self::answer(answer).await
    }

    /// Renders `request`, waiting for room in the queue. View sessions use
    /// this: each has at most one job queued, so the worker, taking jobs in
    /// arrival order, serves the sessions in turn.
    pub async fn render_waiting(
        &self,
        dataset: &Dataset,
        request: FrameRequest,
    ) -> Result<RenderedFrame, AppError> {
        let (job, answer) = Job::new(dataset, request);
        self.jobs
            .send(job)
            .await
            .map_err(|_| AppError::Internal("the render worker has stopped".into()))?;
        Self::answer(answer).await
    }

    async fn answer(
        answer: oneshot::Receiver<Result<RenderedFrame, GpuError>>,
    ) -> Result<RenderedFrame, AppError> {
        let result = answer
            .await
            .map_err(|_| AppError::Internal("the render worker dropped a job".into()))?;
        result.map_err(|e| match e {
            GpuError::InvalidRequest(m) => AppError::BadRequest(m),
            GpuError::Unsupported { .. } | GpuError::Setting(_) => {
                AppError::BadRequest(e.to_string())
            }
            GpuError::Data(e) => AppError::DataUnreadable(e.to_string()),
            other => AppError::Internal(other.to_string()),
        })
    }
}
