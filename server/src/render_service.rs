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
//! than on the async runtime.
//!
//! **Fair by cost.** Each job belongs to a client (its address) and costs its
//! pixels. The worker serves the clients with jobs waiting in turn, by deficit
//! round robin ([`Queue::next`]): each turn credits a client [`QUANTUM`]
//! pixels, and its next job runs once its credit covers the job. A client
//! asking for huge frames thus waits several turns for each, while the
//! others' small frames go by: it slows itself, not them. A job whose
//! requester has gone (a closed connection, a dropped session) is dropped
//! when its turn comes, not rendered. `GET /api/render` is refused at once
//! when [`QUEUE_CAPACITY`] jobs wait (503) or its client has
//! [`PER_CLIENT_QUEUE`] waiting (429), instead of waiting behind work that
//! will be stale by the time it runs; view sessions have one job each at
//! most and always queue.

use std::collections::VecDeque;
use std::net::IpAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::Instant;

use shaders::{AnyRenderer, Backend, Frame, FrameRequest, GpuError, RenderStats};
use tokio::sync::oneshot;

use crate::{AppError, Dataset};

/// `GET /api/render` jobs that may wait for the worker; more are refused.
pub const QUEUE_CAPACITY: usize = 8;
/// `GET /api/render` jobs of one client that may wait; more are refused.
pub const PER_CLIENT_QUEUE: usize = 2;
/// The credit, in pixels, a client gets per turn: one 512² frame.
pub const QUANTUM: u64 = 512 * 512;

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

impl Job {
    /// What the job costs: its pixels.
    fn cost(&self) -> u64 {
        u64::from(self.request.width) * u64::from(self.request.height)
    }
}

/// A client's waiting jobs and its credit.
#[derive(Debug)]
struct Waiting {
    client: IpAddr,
    jobs: VecDeque<Job>,
    credit: u64,
}

/// The jobs waiting for the worker, by client, in turn order.
#[derive(Debug, Default)]
struct Queue {
    turns: VecDeque<Waiting>,
    /// `GET /api/render` jobs waiting.
    http_jobs: usize,
    /// Set when the last [`RenderService`] handle is gone: the worker ends.
    closed: bool,
}

impl Queue {
    fn push(&mut self, client: IpAddr, job: Job) {
        match self.turns.iter_mut().find(|w| w.client == client) {
            Some(waiting) => waiting.jobs.push_back(job),
            None => self.turns.push_back(Waiting {
                client,
                jobs: VecDeque::from([job]),
                credit: 0,
            }),
        }
    }

    /// The next job by deficit round robin: the client whose turn it is is
    /// credited [`QUANTUM`]; if that covers its first job, the job is taken
    /// (and the client keeps its turn while credit remains), else the turn
    /// passes with the credit kept. A client with no jobs left leaves the
    /// rotation and its credit lapses.
    fn next(&mut self) -> Option<Job> {
        loop {
            let waiting = self.turns.front_mut()?;
            let cost = waiting.jobs.front().map_or(0, Job::cost);
            if waiting.credit < cost {
                waiting.credit += QUANTUM;
                if waiting.credit < cost {
                    self.turns.rotate_left(1);
                    continue;
                }
            }
            waiting.credit -= cost;
            let job = waiting.jobs.pop_front();
            if waiting.jobs.is_empty() {
                self.turns.pop_front();
            } else if waiting.credit < waiting.jobs.front().map_or(0, Job::cost) {
                self.turns.rotate_left(1);
            }
            return job;
        }
    }

    fn waiting_of(&self, client: IpAddr) -> usize {
        self.turns
            .iter()
            .find(|w| w.client == client)
            .map_or(0, |w| w.jobs.len())
    }
}

/// An HTTP job counted in [`Queue::http_jobs`] until it is answered or its
/// requester goes.
#[derive(Debug)]
struct HttpJob<'a>(&'a Shared);

impl Drop for HttpJob<'_> {
    fn drop(&mut self) {
        self.0.lock().http_jobs -= 1;
    }
}

/// What the handles and the worker share.
#[derive(Debug, Default)]
struct Shared {
    queue: Mutex<Queue>,
    ready: Condvar,
    abandoned: AtomicU64,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Queue> {
        // Every change to the queue is one step: nothing half done to see.
        self.queue.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The next job, waiting for one; `None` once closed.
    fn take(&self) -> Option<Job> {
        let mut queue = self.lock();
        loop {
            if queue.closed {
                return None;
            }
            if let Some(job) = queue.next() {
                return Some(job);
            }
            queue = self
                .ready
                .wait(queue)
                .unwrap_or_else(PoisonError::into_inner);
        }
    }
}

/// A handle to the render worker; cloning shares the worker.
#[derive(Debug, Clone)]
pub struct RenderService {
    shared: Arc<Shared>,
    adapter: Arc<str>,
    kind: &'static str,
    _worker: Arc<WorkerThread>,
}

/// The worker thread: when the last handle is dropped the queue closes and
/// the thread is joined, so the GPU device is released before the process
/// exits rather than racing its exit.
#[derive(Debug)]
struct WorkerThread {
    shared: Arc<Shared>,
    handle: Option<std::thread::JoinHandle<()>>,
}

impl Drop for WorkerThread {
    fn drop(&mut self) {
        self.shared.lock().closed = true;
        self.shared.ready.notify_all();
        if let Some(handle) = self.handle.take()
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
        let shared = Arc::new(Shared::default());
        let queue = shared.clone();
        let handle = std::thread::Builder::new()
            .name("render-worker".into())
            .spawn(move || {
                // Ends when the last RenderService handle is gone.
                while let Some(job) = queue.take() {
                    if job.reply.is_closed() {
                        // The requester has gone: nobody would see the frame.
                        queue.abandoned.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
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
            shared: shared.clone(),
            adapter,
            kind,
            _worker: Arc::new(WorkerThread {
                shared,
                handle: Some(handle),
            }),
        })
    }

    /// Jobs dropped unrendered because their requester had gone, so far.
    pub fn abandoned(&self) -> u64 {
        self.shared.abandoned.load(Ordering::Relaxed)
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

    /// Renders `request` for `client`, or refuses at once when
    /// [`QUEUE_CAPACITY`] HTTP jobs wait (503) or the client has
    /// [`PER_CLIENT_QUEUE`] waiting (429): single HTTP frames, whose client
    /// retries rather than waiting behind stale work.
    pub async fn render(
        &self,
        client: IpAddr,
        dataset: &Dataset,
        request: FrameRequest,
    ) -> Result<RenderedFrame, AppError> {
        let (job, answer) = Job::new(dataset, request);
        {
            let mut queue = self.shared.lock();
            if queue.http_jobs >= QUEUE_CAPACITY {
                return Err(AppError::Busy(format!(
                    "the renderer has {QUEUE_CAPACITY} frames waiting: retry shortly"
                )));
            }
            if queue.waiting_of(client) >= PER_CLIENT_QUEUE {
                return Err(AppError::TooMany(format!(
                    "{PER_CLIENT_QUEUE} frames of {client} are waiting for the renderer, the \
                     most one client may have: retry once they are done"
                )));
            }
            queue.http_jobs += 1;
            queue.push(client, job);
        }
        let _counted = HttpJob(&self.shared);
        self.shared.ready.notify_one();
        Self::answer(answer).await
    }

    /// Renders `request` for `client`, always queued. View sessions use
    /// this: each has at most one job queued.
    pub async fn render_waiting(
        &self,
        client: IpAddr,
        dataset: &Dataset,
        request: FrameRequest,
    ) -> Result<RenderedFrame, AppError> {
        let (job, answer) = Job::new(dataset, request);
        self.shared.lock().push(client, job);
        self.shared.ready.notify_one();
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

#[cfg(test)]
mod tests {
    use super::*;

    /// `count` jobs of `width` × `height` pixels.
    fn jobs(dataset: &Dataset, (width, height): (u32, u32), count: usize) -> Vec<Job> {
        (0..count)
            .map(|_| {
                let request = FrameRequest {
                    width,
                    height,
                    ..FrameRequest::default()
                };
                Job::new(dataset, request).0
            })
            .collect()
    }

    /// The widths of the jobs `queue` gives, in order, until it is empty.
    fn widths(queue: &mut Queue) -> Vec<u32> {
        std::iter::from_fn(|| queue.next())
            .map(|job| job.request.width)
            .collect()
    }

    #[test]
    fn clients_take_turns_by_cost() {
        let dataset = Dataset::phantom(16, 1 << 20).expect("phantom");
        let (a, b): (IpAddr, IpAddr) = ([127, 0, 0, 2].into(), [127, 0, 0, 3].into());
        // Frames of equal cost alternate (a's are 512 wide, b's 256).
        let mut queue = Queue::default();
        for job in jobs(&dataset, (512, 512), 3) {
            queue.push(a, job);
        }
        for job in jobs(&dataset, (256, 1024), 3) {
            queue.push(b, job);
        }
        assert_eq!(widths(&mut queue), [512, 256, 512, 256, 512, 256]);
        // Big frames of one client wait while another's small ones go by,
        // though they came first.
        for job in jobs(&dataset, (1024, 1024), 2) {
            queue.push(a, job);
        }
        for job in jobs(&dataset, (64, 64), 3) {
            queue.push(b, job);
        }
        assert_eq!(widths(&mut queue), [64, 64, 64, 1024, 1024]);
        assert!(queue.turns.is_empty());
    }
}
