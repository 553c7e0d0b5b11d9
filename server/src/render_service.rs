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
//! **Fair by cost.** Each job belongs to a [`Client`] (a signed-in user, else
//! an address) and costs its
//! pixels times the samples a ray may take ([`shaders::raycast::samples_per_ray`]):
//! pixel-samples. A frame costing more than [`TURN_COST`] is drawn in bands of
//! rows, one band per turn, so no turn holds the worker longer than a
//! [`TURN_COST`] frame does. The worker serves the clients with work waiting in
//! turn, by deficit round robin ([`Queue::next`]): each turn credits a client
//! [`QUANTUM`], and its next band runs once its credit covers it. A client
//! asking for huge frames thus gets one band per round while the others' small
//! frames go by: it slows itself, not them. A frame whose requester has gone
//! (a closed connection, a dropped session) is dropped when its next turn
//! comes, before any band or between two. A frame costing more than the
//! service's limit ([`RenderService::set_max_frame_cost`]) is refused before it
//! queues. `GET /api/render` is refused at once
//! when [`QUEUE_CAPACITY`] jobs wait (503) or its client has
//! [`PER_CLIENT_QUEUE`] waiting (429), instead of waiting behind work that
//! will be stale by the time it runs; view sessions have one job each at
//! most and always queue.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::Instant;

use blocks::cache::BlockCache;
use shaders::frame::Window;
use shaders::raycast::samples_per_ray;
use shaders::slice::{SlicePlacement, SliceRequest};
use shaders::{AnyRenderer, Backend, Frame, FrameRequest, GpuError, RenderStats, Rows};
use tokio::sync::oneshot;

use crate::client::Client;
use crate::{AppError, Dataset};

/// `GET /api/render` jobs that may wait for the worker; more are refused.
pub const QUEUE_CAPACITY: usize = 8;
/// `GET /api/render` jobs of one client that may wait; more are refused.
pub const PER_CLIENT_QUEUE: usize = 2;
/// The pixel-samples one turn draws at most: a 512² frame of up to 256
/// samples a ray (a 256² frame of 1024). A frame costing more is drawn in
/// bands of rows, one per turn. Smaller turns keep others' frames waiting
/// less and cost more bands: with 512² × 1024, sixteen 256² sessions beside
/// a client asking for 4096² frames kept 0.82 of their frame rate, with this
/// 0.94; a 1024² frame of the 256³ phantom takes 14 bands, 309 ms against
/// 272 ms whole (`bench stream`, CPU renderer, 2 cores).
pub const TURN_COST: u64 = 512 * 512 * 256;
/// The credit, in pixel-samples, a client gets per turn: one turn's cost.
pub const QUANTUM: u64 = TURN_COST;
/// The pixel-samples one frame may cost by default: a 4096² frame of up to
/// 2048 samples a ray (a 512³ volume's diagonal at a step of 0.45 voxels).
pub const MAX_FRAME_COST: u64 = 4096 * 4096 * 2048;

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
    /// Bands of rows it was drawn in: 1 unless it cost more than a turn
    /// ([`TURN_COST`]).
    pub bands: u32,
    /// Milliseconds the longest band took (`render_ms` for one band): the
    /// longest another client's frame waited for this one at a time.
    pub longest_band_ms: f64,
    /// The dataset's chunk arrivals when the frame was planned: a frame with
    /// pending blocks can wait for arrivals after these
    /// ([`Dataset::settle`]).
    pub arrivals: u64,
    /// For a slice view's frame: where it lies and its window.
    pub slice: Option<(SlicePlacement, Window)>,
}

struct Job {
    dataset: Dataset,
    /// The frame; for a slice, only its size counts.
    request: FrameRequest,
    /// A slice view's frame and its window.
    slice: Option<(SliceRequest, Window)>,
    queued: Instant,
    reply: Reply,
    /// Samples a ray may take ([`samples_per_ray`]).
    samples: u64,
    /// Rows drawn per turn: the whole frame unless it costs more than
    /// [`TURN_COST`].
    rows_per_turn: u32,
    /// The bands drawn so far.
    drawn: Option<Drawn>,
    /// A health probe's frame: drawn with the settings of the last view
    /// the dataset's renderer drew, if any ([`RenderService::probe`]).
    probe: bool,
}

/// The bands of a frame drawn so far, and what drawing them took.
#[derive(Debug)]
struct Drawn {
    rgba: Vec<u8>,
    rows: u32,
    render_ms: f64,
    queue_ms: f64,
    bands: u32,
    longest_band_ms: f64,
    stats: RenderStats,
    arrivals: u64,
    /// A slice's placement and window.
    placed: Option<(SlicePlacement, Window)>,
}

impl Job {
    /// The frame's cost in pixel-samples.
    fn frame_cost(request: &FrameRequest, samples: u64) -> u64 {
        u64::from(request.width) * u64::from(request.height) * samples
    }

    /// The rows one turn draws of `request` at `samples` a ray: as many as
    /// [`TURN_COST`] covers, at least one however wide.
    fn rows_per_turn(request: &FrameRequest, samples: u64) -> u32 {
        let row_cost = u64::from(request.width) * samples;
        u32::try_from((TURN_COST / row_cost.max(1)).max(1))
            .unwrap_or(u32::MAX)
            .min(request.height.max(1))
    }

    /// The rows its next band draws.
    fn next_rows(&self) -> Rows {
        let first = self.drawn.as_ref().map_or(0, |d| d.rows);
        Rows {
            first,
            count: self.rows_per_turn.min(self.request.height - first),
        }
    }

    /// What its next turn costs: the next band's pixel-samples.
    fn cost(&self) -> u64 {
        u64::from(self.request.width) * u64::from(self.next_rows().count) * self.samples
    }
}

/// A client's waiting jobs and its credit.
#[derive(Debug)]
struct Waiting {
    client: Client,
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
    fn push(&mut self, client: Client, job: Job) {
        match self.turns.iter_mut().find(|w| w.client == client) {
            Some(waiting) => waiting.jobs.push_back(job),
            None => self.turns.push_back(Waiting {
                client,
                jobs: VecDeque::from([job]),
                credit: 0,
            }),
        }
    }

    /// Puts a frame with bands left back before its client's other jobs (the
    /// client joins the rotation at its end if it had left it).
    fn resume(&mut self, client: Client, job: Job) {
        match self.turns.iter_mut().find(|w| w.client == client) {
            Some(waiting) => waiting.jobs.push_front(job),
            None => self.turns.push_back(Waiting {
                client,
                jobs: VecDeque::from([job]),
                credit: 0,
            }),
        }
    }

    /// The next job by deficit round robin: the client whose turn it is is
    /// credited [`QUANTUM`] (holding at most a quantum, or its next band's
    /// cost if more); if that covers its first job's next band, the job is
    /// taken (and the client keeps its turn while credit remains), else the
    /// turn passes with the credit kept. A client with no jobs left
    /// leaves the rotation and its credit lapses.
    fn next(&mut self) -> Option<(Client, Job)> {
        loop {
            let waiting = self.turns.front_mut()?;
            let cost = waiting.jobs.front().map_or(0, Job::cost);
            if waiting.credit < cost {
                // Credit beyond a quantum (or the job, if it costs more) is
                // not kept: a turn draws a band at most, however long the
                // client waited.
                waiting.credit = (waiting.credit + QUANTUM).min(QUANTUM.max(cost));
                if waiting.credit < cost {
                    self.turns.rotate_left(1);
                    continue;
                }
            }
            waiting.credit -= cost;
            let client = waiting.client.clone();
            let job = waiting.jobs.pop_front();
            if waiting.jobs.is_empty() {
                self.turns.pop_front();
            } else if waiting.credit < waiting.jobs.front().map_or(0, Job::cost) {
                self.turns.rotate_left(1);
            }
            return job.map(|job| (client, job));
        }
    }

    fn waiting_of(&self, client: &Client) -> usize {
        self.turns
            .iter()
            .find(|w| w.client == *client)
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
#[derive(Debug)]
struct Shared {
    queue: Mutex<Queue>,
    ready: Condvar,
    abandoned: AtomicU64,
    /// Bands drawn of frames drawn in more than one.
    bands: AtomicU64,
    /// The most pixel-samples a frame may cost.
    max_frame_cost: AtomicU64,
}

impl Default for Shared {
    fn default() -> Shared {
        Shared {
            queue: Mutex::default(),
            ready: Condvar::new(),
            abandoned: AtomicU64::new(0),
            bands: AtomicU64::new(0),
            max_frame_cost: AtomicU64::new(MAX_FRAME_COST),
        }
    }
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Queue> {
        // Every change to the queue is one step: nothing half done to see.
        self.queue.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The next job, waiting for one; `None` once closed.
    fn take(&self) -> Option<(Client, Job)> {
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
    /// A job queued now, and where its frame will come; refused when the
    /// frame costs more than `max_cost` pixel-samples.
    fn new(
        dataset: &Dataset,
        request: FrameRequest,
        max_cost: u64,
    ) -> Result<(Job, oneshot::Receiver<Result<RenderedFrame, GpuError>>), AppError> {
        let samples = u64::from(samples_per_ray(
            &dataset.cache.store().meta().geometry,
            &request,
        ));
        let cost = Job::frame_cost(&request, samples);
        if cost > max_cost {
            return Err(AppError::BadRequest(format!(
                "a {}x{} frame at step {} voxels of '{}' costs up to {cost} pixel-samples \
                 ({samples} samples a ray), more than this server's limit of {max_cost}: ask \
                 for fewer pixels (w, h) or a larger step",
                request.width, request.height, request.step_voxels, dataset.id
            )));
        }
        Ok(Job::queued(dataset, request, None, samples))
    }

    /// A job of `request` (with `slice`, a slice view's) at `samples` a
    /// pixel, queued now, and where its frame will come.
    fn queued(
        dataset: &Dataset,
        request: FrameRequest,
        slice: Option<(SliceRequest, Window)>,
        samples: u64,
    ) -> (Job, oneshot::Receiver<Result<RenderedFrame, GpuError>>) {
        let (reply, answer) = oneshot::channel();
        let job = Job {
            dataset: dataset.clone(),
            rows_per_turn: Job::rows_per_turn(&request, samples),
            request,
            slice,
            queued: Instant::now(),
            reply,
            samples,
            drawn: None,
            probe: false,
        };
        (job, answer)
    }

    /// A slice view's frame of `dataset` queued now, and where it will
    /// come: priced and drawn band by band as frames are (pixels × the
    /// slab's samples).
    fn slice(
        dataset: &Dataset,
        slice: SliceRequest,
        window: Window,
        max_cost: u64,
    ) -> Result<(Job, oneshot::Receiver<Result<RenderedFrame, GpuError>>), AppError> {
        let samples = u64::from(slice.slab_samples(&dataset.store.meta().geometry));
        let request = FrameRequest {
            width: slice.width,
            height: slice.height,
            ..FrameRequest::default()
        };
        let cost = Job::frame_cost(&request, samples);
        if cost > max_cost {
            return Err(AppError::BadRequest(format!(
                "a {}x{} slice of '{}' with a slab of {samples} samples costs {cost} \
                 pixel-samples, more than this server's limit of {max_cost}: ask for fewer \
                 pixels (w, h) or a thinner slab",
                slice.width, slice.height, dataset.id
            )));
        }
        Ok(Job::queued(
            dataset,
            request,
            Some((slice, window)),
            samples,
        ))
    }

    /// Draws the job's next band: the frame when it was the last (or the
    /// only) one, else the job with the band added.
    fn draw_band(mut self, renderers: &mut Renderers) -> Result<Turn, (Reply, GpuError)> {
        let start = Instant::now();
        let rows = self.next_rows();
        let whole = rows.count == self.request.height;
        let request = if whole {
            self.request.clone()
        } else {
            FrameRequest {
                rows: Some(rows),
                ..self.request.clone()
            }
        };
        // Never waits for storage: blocks still being read are shown
        // coarser and later frames refine them.
        let arrivals = self.dataset.cache.arrivals();
        let drawn_band = match &self.slice {
            // Slices are sampled on the CPU from the dataset's block cache.
            Some((slice, window)) => {
                let band = SliceRequest {
                    rows: (!whole).then_some(rows),
                    ..slice.clone()
                };
                shaders::slice::render(&self.dataset.cache, &band, *window)
                    .map(|drawn| {
                        let stats = RenderStats {
                            pending_blocks: drawn.pending_chunks,
                            draw_ms: start.elapsed().as_secs_f64() * 1e3,
                            ..RenderStats::default()
                        };
                        (drawn.frame, stats, Some((drawn.placement, drawn.window)))
                    })
                    .map_err(GpuError::Data)
            }
            None => renderers.get(&self.dataset).and_then(|(renderer, last)| {
                let band = if self.probe {
                    // The last view's frame again, at the probe's size, from
                    // the blocks and light the views see: a frame of other
                    // settings would replace them and the view's next frame
                    // would bring them back.
                    let probe = match last.as_ref() {
                        Some(last) => FrameRequest {
                            width: request.width,
                            height: request.height,
                            rows: None,
                            ..last.clone()
                        },
                        None => request,
                    };
                    renderer.render_probe(&probe)?
                } else {
                    let band = renderer.render_now(&request)?;
                    // A view probes draw once it rendered: one that fails
                    // would make every later probe fail.
                    if rows.first == 0 {
                        *last = Some(self.request.clone());
                    }
                    band
                };
                Ok((band, renderer.last_stats().clone(), None))
            }),
        };
        let (band, stats, placed) = match drawn_band {
            Ok(drawn) => drawn,
            Err(e) => return Err((self.reply, e)),
        };
        let render_ms = start.elapsed().as_secs_f64() * 1e3;
        let drawn = match self.drawn.take() {
            Some(mut drawn) => {
                drawn.rgba.extend_from_slice(&band.rgba);
                drawn.rows += rows.count;
                drawn.render_ms += render_ms;
                drawn.bands += 1;
                drawn.longest_band_ms = drawn.longest_band_ms.max(render_ms);
                drawn.stats.draw_ms += stats.draw_ms;
                // Blocks still read while any band was drawn: the frame is
                // drawn again once they are in.
                drawn.stats.pending_blocks = drawn.stats.pending_blocks.max(stats.pending_blocks);
                drawn
            }
            None => {
                let mut rgba = band.rgba;
                if !whole {
                    let frame_bytes =
                        self.request.width as usize * self.request.height as usize * 4;
                    rgba.reserve_exact(frame_bytes.saturating_sub(rgba.len()));
                }
                Drawn {
                    rgba,
                    rows: rows.count,
                    render_ms,
                    queue_ms: (start - self.queued).as_secs_f64() * 1e3,
                    bands: 1,
                    longest_band_ms: render_ms,
                    stats,
                    arrivals,
                    placed,
                }
            }
        };
        if drawn.rows < self.request.height {
            self.drawn = Some(drawn);
            return Ok(Turn::More(self));
        }
        let frame = RenderedFrame {
            frame: Frame {
                width: self.request.width,
                height: self.request.height,
                rgba: drawn.rgba,
            },
            render_ms: drawn.render_ms,
            stats: drawn.stats,
            queue_ms: drawn.queue_ms,
            bands: drawn.bands,
            longest_band_ms: drawn.longest_band_ms,
            arrivals: drawn.arrivals,
            slice: drawn.placed,
        };
        Ok(Turn::Done(self.reply, frame))
    }
}

/// Where a job's frame goes.
type Reply = oneshot::Sender<Result<RenderedFrame, GpuError>>;

/// What a turn of the worker left.
#[expect(
    clippy::large_enum_variant,
    reason = "one at a time, moved once on the worker's stack"
)]
enum Turn {
    /// The frame, for the requester.
    Done(Reply, RenderedFrame),
    /// A frame with bands left.
    More(Job),
}

/// The worker's renderers, least recently used first, each with the id
/// and the block cache of the dataset it draws.
struct Renderers {
    backend: Backend,
    budget_bytes: u64,
    capacity: usize,
    /// Per dataset: its id, its block cache, its renderer and the last
    /// frame request a view drew with it (what a health probe draws again).
    by_use: Vec<(String, Arc<BlockCache>, AnyRenderer, Option<FrameRequest>)>,
}

impl Renderers {
    /// The renderer of `dataset`, made (after dropping the least recently used
    /// one when all places are taken) if there is none. A dataset offered
    /// anew under the same id (a received series bricked again, a series
    /// opened again after it left the cache) has a new block cache: the
    /// renderer of the old one is dropped, never drawn from.
    fn get(
        &mut self,
        dataset: &Dataset,
    ) -> Result<(&mut AnyRenderer, &mut Option<FrameRequest>), GpuError> {
        if let Some(i) = self.by_use.iter().position(|(id, ..)| *id == dataset.id) {
            let entry = self.by_use.remove(i);
            if Arc::ptr_eq(&entry.1, &dataset.cache) {
                self.by_use.push(entry);
            } else {
                tracing::info!(
                    "dataset '{}' is offered anew: its old blocks are released",
                    dataset.id
                );
            }
        }
        let current = self
            .by_use
            .last()
            .is_some_and(|(id, cache, ..)| *id == dataset.id && Arc::ptr_eq(cache, &dataset.cache));
        if !current {
            if self.by_use.len() >= self.capacity {
                // Freed before the next one allocates.
                let (id, ..) = self.by_use.remove(0);
                tracing::info!("released dataset '{id}' from the renderer");
            }
            let renderer = self
                .backend
                .renderer(dataset.cache.clone(), self.budget_bytes)?;
            self.by_use
                .push((dataset.id.clone(), dataset.cache.clone(), renderer, None));
        }
        self.by_use
            .last_mut()
            .map(|(_, _, r, last)| (r, last))
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
                while let Some((client, job)) = queue.take() {
                    if job.reply.is_closed() {
                        // The requester has gone: nobody would see the frame
                        // (or the rest of it).
                        queue.abandoned.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    if job.rows_per_turn < job.request.height {
                        queue.bands.fetch_add(1, Ordering::Relaxed);
                    }
                    // Keeps the error's reply when drawing fails.
                    let (reply, result) = match job.draw_band(&mut renderers) {
                        Ok(Turn::Done(reply, frame)) => (reply, Ok(frame)),
                        Ok(Turn::More(job)) => {
                            queue.lock().resume(client, job);
                            continue;
                        }
                        Err((reply, e)) => {
                            tracing::warn!("render failed: {e}");
                            (reply, Err(e))
                        }
                    };
                    // The requester may have gone away; nothing to do then.
                    let _ = reply.send(result);
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

    /// Bands drawn so far of frames too costly for one turn ([`TURN_COST`]).
    pub fn bands(&self) -> u64 {
        self.shared.bands.load(Ordering::Relaxed)
    }

    /// The most pixel-samples a frame may cost ([`MAX_FRAME_COST`] unless
    /// set); a costlier one is refused before it queues.
    pub fn max_frame_cost(&self) -> u64 {
        self.shared.max_frame_cost.load(Ordering::Relaxed)
    }

    /// Sets [`RenderService::max_frame_cost`] (at least [`TURN_COST`]).
    pub fn set_max_frame_cost(&self, pixel_samples: u64) {
        self.shared
            .max_frame_cost
            .store(pixel_samples.max(TURN_COST), Ordering::Relaxed);
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
        client: &Client,
        dataset: &Dataset,
        request: FrameRequest,
    ) -> Result<RenderedFrame, AppError> {
        let (job, answer) = Job::new(dataset, request, self.max_frame_cost())?;
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
            queue.push(client.clone(), job);
        }
        let _counted = HttpJob(&self.shared);
        self.shared.ready.notify_one();
        Self::answer(answer).await
    }

    /// Renders `request` for `client`, always queued. View sessions use
    /// this: each has at most one job queued.
    pub async fn render_waiting(
        &self,
        client: &Client,
        dataset: &Dataset,
        request: FrameRequest,
    ) -> Result<RenderedFrame, AppError> {
        let (job, answer) = Job::new(dataset, request, self.max_frame_cost())?;
        self.wait_in_turn(client, job, answer).await
    }

    /// Renders a health probe's frame of `dataset` for `client`, always
    /// queued: `request` (one band) when the dataset's renderer has drawn
    /// no view yet, else the last view it drew at `request`'s size, so a
    /// probe never changes the blocks, light or classification the views
    /// of the dataset are drawn with.
    pub async fn probe(
        &self,
        client: &Client,
        dataset: &Dataset,
        request: FrameRequest,
    ) -> Result<RenderedFrame, AppError> {
        let (mut job, answer) = Job::new(dataset, request, self.max_frame_cost())?;
        job.probe = true;
        job.rows_per_turn = job.request.height;
        self.wait_in_turn(client, job, answer).await
    }

    /// Renders a slice view's frame of `dataset` through `window` for
    /// `client`, always queued, in turn with every frame (view sessions).
    pub async fn render_slice_waiting(
        &self,
        client: &Client,
        dataset: &Dataset,
        slice: SliceRequest,
        window: Window,
    ) -> Result<RenderedFrame, AppError> {
        let (job, answer) = Job::slice(dataset, slice, window, self.max_frame_cost())?;
        self.wait_in_turn(client, job, answer).await
    }

    /// Queues `job` for `client`, always, and awaits its frame.
    async fn wait_in_turn(
        &self,
        client: &Client,
        job: Job,
        answer: oneshot::Receiver<Result<RenderedFrame, GpuError>>,
    ) -> Result<RenderedFrame, AppError> {
        self.shared.lock().push(client.clone(), job);
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

    /// `count` jobs of `width` × `height` pixels at 256 samples a ray, so
    /// that a 512² frame costs one turn.
    fn jobs(dataset: &Dataset, (width, height): (u32, u32), count: usize) -> Vec<Job> {
        (0..count)
            .map(|_| {
                let request = FrameRequest {
                    width,
                    height,
                    ..FrameRequest::default()
                };
                let mut job = Job::new(dataset, request, u64::MAX).expect("a job").0;
                job.samples = 256;
                job.rows_per_turn = Job::rows_per_turn(&job.request, job.samples);
                job
            })
            .collect()
    }

    /// The turns `queue` gives until it is empty, as the worker takes them
    /// (a frame with bands left goes back), each as the frame's width and
    /// the band's first row; the bands are counted as drawn, not drawn.
    fn turns(queue: &mut Queue) -> Vec<(u32, u32)> {
        let mut turns = Vec::new();
        while let Some((client, mut job)) = queue.next() {
            let rows = job.next_rows();
            turns.push((job.request.width, rows.first));
            if rows.first + rows.count < job.request.height {
                job.drawn = Some(Drawn {
                    rgba: Vec::new(),
                    rows: rows.first + rows.count,
                    render_ms: 0.0,
                    queue_ms: 0.0,
                    bands: 1,
                    longest_band_ms: 0.0,
                    stats: RenderStats::default(),
                    arrivals: 0,
                    placed: None,
                });
                queue.resume(client, job);
            }
        }
        turns
    }

    #[test]
    fn a_dataset_offered_anew_under_its_id_gets_a_new_renderer() {
        let mut renderers = Renderers {
            backend: Backend::Cpu,
            budget_bytes: 64 << 20,
            capacity: 2,
            by_use: Vec::new(),
        };
        let old = Dataset::phantom(16, 1 << 20).expect("phantom");
        let new = Dataset::phantom(16, 1 << 20).expect("phantom");
        assert_eq!(old.id, new.id);
        renderers.get(&old).expect("a renderer");
        renderers.get(&old).expect("the same renderer");
        assert_eq!(renderers.by_use.len(), 1);
        renderers.get(&new).expect("a renderer");
        assert_eq!(renderers.by_use.len(), 1, "the old one is dropped");
        assert!(Arc::ptr_eq(&renderers.by_use[0].1, &new.cache));
    }

    #[test]
    fn clients_take_turns_by_cost() {
        let dataset = Dataset::phantom(16, 1 << 20).expect("phantom");
        let a = Client::Address([127, 0, 0, 2].into());
        let b = Client::User("user b".into());
        // Frames of equal cost alternate (a's are 512 wide, b's 256).
        let mut queue = Queue::default();
        for job in jobs(&dataset, (512, 512), 3) {
            queue.push(a.clone(), job);
        }
        for job in jobs(&dataset, (256, 1024), 3) {
            queue.push(b.clone(), job);
        }
        assert_eq!(
            turns(&mut queue),
            [(512, 0), (256, 0), (512, 0), (256, 0), (512, 0), (256, 0)]
        );
        // A frame costing four turns is drawn in four bands; another
        // client's small frames go by after its first, though they came
        // later, and its next frame waits for it.
        for job in jobs(&dataset, (1024, 1024), 2) {
            queue.push(a.clone(), job);
        }
        for job in jobs(&dataset, (64, 64), 3) {
            queue.push(b.clone(), job);
        }
        let big = |rows: &[u32]| rows.iter().map(|&r| (1024, r)).collect::<Vec<_>>();
        let expected = [
            big(&[0]),
            vec![(64, 0); 3],
            big(&[256, 512, 768]),
            big(&[0, 256, 512, 768]),
        ]
        .concat();
        assert_eq!(turns(&mut queue), expected);
        assert!(queue.turns.is_empty());
    }

    #[test]
    fn a_health_probe_leaves_the_views_blocks_as_they_are() {
        let dataset = Dataset::phantom(32, 16 << 20).expect("phantom");
        let service = RenderService::start(Backend::Cpu, 64 << 20, 1).expect("worker");
        let viewer = Client::Address([127, 0, 0, 2].into());
        let prober = Client::User("voxserve health probe".into());
        let range = dataset.value_range();
        let view = FrameRequest {
            reduction: 1.0,
            ..FrameRequest::new(64, 64, blocks::Preset::CtBone.transfer_function(range))
        };
        let probe = FrameRequest {
            width: 16,
            height: 16,
            reduction: shaders::frame::MAX_REDUCTION as f32,
            ..FrameRequest::default()
        };
        let runtime = tokio::runtime::Builder::new_current_thread()
            .build()
            .expect("runtime");
        // Before any view the probe's own request is drawn.
        let first = runtime
            .block_on(service.probe(&prober, &dataset, probe.clone()))
            .expect("probe before any view");
        assert_eq!((first.frame.width, first.frame.height), (16, 16));
        // The view, until every block it wants is shown.
        while runtime
            .block_on(service.render_waiting(&viewer, &dataset, view.clone()))
            .expect("view")
            .stats
            .pending_blocks
            > 0
        {
            let seen = dataset.cache.arrivals();
            if dataset.cache.loading() > 0 {
                dataset
                    .cache
                    .wait_for_arrivals(seen, std::time::Duration::from_secs(5));
            }
        }
        let probed = runtime
            .block_on(service.probe(&prober, &dataset, probe.clone()))
            .expect("probe");
        assert_eq!((probed.frame.width, probed.frame.height), (16, 16));
        assert_eq!(probed.stats.select_ms, 0.0, "{:?}", probed.stats);
        let again = runtime
            .block_on(service.render_waiting(&viewer, &dataset, view.clone()))
            .expect("view again");
        assert_eq!(
            (
                again.stats.select_ms,
                again.stats.uploaded_blocks,
                again.stats.relayout
            ),
            (0.0, 0, false),
            "the view's blocks stayed: {:?}",
            again.stats
        );
        // Nor does a probe refine the view's light, or keep the view's
        // next frame from refining it.
        let lit = FrameRequest {
            shading: shaders::Shading::GlobalLight,
            ..view
        };
        let refinement = |drawn: &RenderedFrame| {
            drawn
                .stats
                .illumination
                .and_then(|t| t.refinement())
                .expect("global light refines")
        };
        let first = runtime
            .block_on(service.render_waiting(&viewer, &dataset, lit.clone()))
            .expect("lit view");
        let probed = runtime
            .block_on(service.probe(&prober, &dataset, probe))
            .expect("probe");
        let second = runtime
            .block_on(service.render_waiting(&viewer, &dataset, lit))
            .expect("lit view again");
        assert_eq!(refinement(&probed), refinement(&first));
        assert_eq!(refinement(&second).0, refinement(&first).0 + 1);
    }

    #[test]
    fn a_costly_slab_is_drawn_band_by_band_as_one_piece() {
        let dataset = Dataset::phantom(32, 16 << 20).expect("phantom");
        let service = RenderService::start(Backend::Cpu, 64 << 20, 1).expect("worker");
        let client = Client::Address([127, 0, 0, 2].into());
        // 1024² pixels × 129 samples: 2 turns and a bit.
        let slab = SliceRequest {
            width: 1024,
            height: 1024,
            slab_mm: 128.0 * dataset.store.meta().geometry.min_spacing_f32(),
            ..SliceRequest::default()
        };
        let window = dataset.default_window().1;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .build()
            .expect("runtime");
        let banded = runtime
            .block_on(service.render_slice_waiting(&client, &dataset, slab.clone(), window))
            .expect("slab");
        assert!(banded.bands > 1, "{} bands", banded.bands);
        assert!(banded.slice.is_some());
        // Coarse data meanwhile, as the bands drew it: compare once every block is in.
        let mut whole = shaders::slice::render(&dataset.cache, &slab, window).expect("whole");
        while whole.pending_chunks > 0 {
            dataset
                .cache
                .wait_for_arrivals(dataset.cache.arrivals(), std::time::Duration::from_secs(5));
            whole = shaders::slice::render(&dataset.cache, &slab, window).expect("whole");
        }
        let banded = runtime
            .block_on(service.render_slice_waiting(&client, &dataset, slab, window))
            .expect("slab");
        assert_eq!(banded.frame.height, 1024);
        assert!(
            banded.frame.rgba == whole.frame.rgba,
            "the bands make the whole"
        );
    }
}
