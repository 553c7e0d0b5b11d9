//! [`Session`]: a view session's state and its rules, as plain data: what
//! to render next, and when, from the messages, acknowledgements and frames
//! that have come (see [`super`]'s docs for the rules). No I/O and no clock:
//! every event brings its `now`, so the rules are tested with explicit
//! instants; [`super::socket`] feeds it a socket and runs its actions.
//!
//! A session has four views ([`Pane`]): the 3D view and three slice views,
//! each with its own settings, message id and progress, rendered under the
//! same rules; the layout says which are shown. One render at a time for the
//! whole session: the view changed last goes first.

use std::sync::Arc;
use std::time::Duration;

use serde_json::{Map, Value};
use shaders::frame::{MAX_IMAGE_EDGE, Window};
use shaders::illumination::Mode;
use shaders::settings::{Raw, Settings};
use shaders::slice::{Plane, SliceRequest};
use shaders::{Camera, FrameRequest};
use tokio::time::Instant;

use super::StreamSettings;
use crate::Dataset;
use crate::protocol::{self, ClientMessage, Pane, Reply, Status, Waiting};
use crate::view::{Origin, ViewError};

/// How a frame is rendered and sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quality {
    /// Smaller, coarser, JPEG (slices: full size and detail, JPEG).
    Interactive,
    /// Full size and detail, lossless.
    Full,
}

/// A frame to render: of `message_id`'s view, to be sent as `frame_id`.
#[derive(Debug, Clone)]
pub struct Render {
    /// How to render and encode it.
    pub quality: Quality,
    /// The dataset.
    pub dataset: Dataset,
    /// The view it is of.
    pub pane: Pane,
    /// The 3D frame, in device pixels, scaled and reduced for `quality`
    /// (for a slice view, only its size counts).
    pub request: FrameRequest,
    /// A slice view's frame, in device pixels, and its window.
    pub slice: Option<(SliceRequest, Window)>,
    /// The id the frame is sent with.
    pub frame_id: u32,
    /// The last view message the frame reflects.
    pub message_id: u32,
}

/// What the session's loop should do next.
#[derive(Debug, Clone)]
pub enum Action {
    /// Render (and then send) this frame; report how it went with
    /// [`Session::on_frame_sent`] or [`Session::on_render_failed`].
    Render(Box<Render>),
    /// Send this reply, then ask again.
    Send(Reply),
    /// Nothing until this instant (when the view turns still) or an event
    /// before it.
    WaitUntil(Instant),
    /// Nothing until a message, an acknowledgement or the frame being rendered.
    WaitForInput,
    /// Nothing until `dataset`'s blocks read in the background have arrived
    /// since `seen` (or a message comes); then report
    /// [`Session::on_blocks_arrived`].
    WaitForBlocks {
        /// The dataset being read.
        dataset: Dataset,
        /// Its arrivals when the last frame was planned.
        seen: u64,
    },
    /// Close the session: the server is shutting down.
    Close,
}

/// Where the frames of a view stand.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Progress {
    /// No view yet.
    Empty,
    /// The view changed at `at` and no render of it has begun.
    Changed { at: Instant },
    /// Frames of the view (changed at `changed_at`) have been or are being
    /// rendered, none full yet: the full one follows once the view is still.
    Interactive { changed_at: Instant },
    /// The full frame was sent; global light's refinements follow.
    Refining,
    /// The full frame was sent showing some blocks coarser while their data
    /// is read; a frame follows when blocks have arrived since `seen`.
    Loading { seen: u64 },
    /// The last frame sent was converged: nothing more for this view.
    Converged,
    /// An error was sent for this view: nothing more for it.
    Failed,
}

/// What a view asks for next, before the window and the render in flight
/// are considered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Want {
    Nothing,
    StillAt(Instant),
    Blocks(u64),
    Frame(Quality),
}

/// One view's progress.
#[derive(Debug, Clone, Copy)]
struct PaneState {
    /// The last view message applied to it.
    message_id: u32,
    progress: Progress,
    /// In the layout.
    shown: bool,
    /// When it last changed (the view changed last renders first).
    changed: Option<Instant>,
}

impl PaneState {
    const NEW: PaneState = PaneState {
        message_id: 0,
        progress: Progress::Empty,
        shown: false,
        changed: None,
    };

    fn change(&mut self, now: Instant) {
        self.progress = Progress::Changed { at: now };
        self.changed = Some(now);
    }

    /// Changes those of `panes` that have a view.
    fn change_all(panes: &mut [PaneState], now: Instant) {
        for pane in panes.iter_mut().filter(|p| p.progress != Progress::Empty) {
            pane.change(now);
        }
    }
}

/// One view session's state; see the module docs.
#[derive(Debug)]
pub struct Session {
    datasets: Arc<[Dataset]>,
    settings: StreamSettings,
    /// The 3D view's settings and the dataset (`w` and `h` in CSS pixels).
    view: crate::View,
    /// The slice views' settings (`w` and `h` in CSS pixels), by plane as
    /// in [`Pane::ALL`]'s slices.
    slices: [SliceRequest; 3],
    dpr: f64,
    /// The last view message applied, to any view.
    message_id: u32,
    panes: [PaneState; 4],
    /// The view and quality of the render in flight, if one is.
    rendering: Option<(Pane, Quality)>,
    /// The last frame id handed out (frame ids start at 1).
    last_id: u32,
    /// The last frame sent.
    sent: u32,
    /// The last frame the client acknowledged (at most `sent`).
    acked: u32,
    /// The server is shutting down.
    closing: bool,
    /// The server drains: the render in flight finishes, then the session
    /// closes.
    draining: bool,
}

impl Session {
    /// Offers `datasets` from now on (the list the server offers now).
    pub fn offer(&mut self, datasets: Arc<[Dataset]>) {
        self.datasets = datasets;
    }

    /// A session without a view yet, offering `datasets`; the layout shows
    /// the 3D view alone.
    pub fn new(datasets: Arc<[Dataset]>, settings: StreamSettings) -> Session {
        let mut panes = [PaneState::NEW; 4];
        panes[Pane::Volume.index()].shown = true;
        Session {
            datasets,
            settings,
            view: crate::View::default(),
            slices: [Plane::Axial, Plane::Coronal, Plane::Sagittal].map(|plane| SliceRequest {
                plane,
                ..SliceRequest::default()
            }),
            dpr: 1.0,
            message_id: 0,
            panes,
            rendering: None,
            last_id: 0,
            sent: 0,
            acked: 0,
            closing: false,
            draining: false,
        }
    }

    /// A text message arrived at `now`; the reply to send, if any. Probes
    /// and picks are answered by the loop ([`Session::probe_target`],
    /// [`Session::pick_target`]).
    pub fn on_text(&mut self, now: Instant, text: &str) -> Option<Reply> {
        match protocol::parse_client_message(text) {
            Ok(message) => self.on_message(now, message),
            Err(refusal) => Some(Reply::error(refusal.id, refusal.message)),
        }
    }

    /// A message read; the reply to send, if any.
    pub fn on_message(&mut self, now: Instant, message: ClientMessage) -> Option<Reply> {
        match message {
            ClientMessage::View { id, pane, set, dpr } => self.on_view(now, id, pane, &set, dpr),
            ClientMessage::Ack { frame } => {
                self.on_ack(frame);
                None
            }
            ClientMessage::Status { id } => Some(Reply::Status(self.status(now, id))),
            ClientMessage::Layout { panes } => {
                self.on_layout(now, &panes);
                None
            }
            ClientMessage::Probe { id, .. } | ClientMessage::Pick { id, .. } => Some(Reply::error(
                Some(id),
                "probes and picks are answered by the session's loop",
            )),
        }
    }

    /// View message `id` for `pane` arrived at `now`: `set` and `dpr` are
    /// merged into that view, or, when any is refused, the view stays and
    /// the error is the reply.
    pub fn on_view(
        &mut self,
        now: Instant,
        id: u32,
        pane: Pane,
        set: &Map<String, Value>,
        dpr: Option<f64>,
    ) -> Option<Reply> {
        let dpr = dpr.unwrap_or(self.dpr);
        let dataset_before = self.view.dataset.clone();
        let orients_before = self.slices.each_ref().map(|s| s.orient);
        let checked = match pane {
            Pane::Volume => {
                let mut view = self.view.clone();
                view.patch(set, &self.datasets)
                    .and_then(|()| device_size(view.frame.width, view.frame.height, dpr))
                    .map(|_| self.view = view)
            }
            Pane::Slice(_) => {
                let slot = pane.index() - 1;
                let mut slice = self.slices[slot].clone();
                patch_slice(&mut slice, set)
                    .and_then(|()| device_size(slice.width, slice.height, dpr))
                    .map(|_| self.slices[slot] = slice)
            }
        };
        if let Err(error) = checked {
            return Some(Reply::error(Some(id), error.to_string()));
        }
        let rescaled = dpr != self.dpr;
        self.dpr = dpr;
        self.message_id = id;
        let state = &mut self.panes[pane.index()];
        state.message_id = id;
        state.change(now);
        // Every view shows the dataset and is drawn at the pixel ratio; a
        // slice view's crosshair lines are the other views' planes.
        if rescaled || self.view.dataset != dataset_before {
            PaneState::change_all(&mut self.panes, now);
        } else if self.slices.each_ref().map(|s| s.orient) != orients_before {
            PaneState::change_all(&mut self.panes[1..], now);
        }
        None
    }

    /// The layout shows `panes` (a view shown again goes on where it was).
    pub fn on_layout(&mut self, now: Instant, panes: &[Pane]) {
        for pane in Pane::ALL {
            let state = &mut self.panes[pane.index()];
            let shown = panes.contains(&pane);
            if shown && !state.shown && state.progress != Progress::Empty {
                state.change(now);
            }
            state.shown = shown;
        }
    }

    /// The client has drawn `frame` (and so every frame before it).
    pub fn on_ack(&mut self, frame: u32) {
        self.acked = self.acked.max(frame.min(self.sent));
    }

    /// The frame being rendered was sent; `converged` as its header says,
    /// `loading`: some blocks were shown coarser, their data read since the
    /// dataset's arrivals were `seen`.
    pub fn on_frame_sent(&mut self, converged: bool, loading: Option<u64>) {
        let Some((pane, quality)) = self.rendering.take() else {
            return;
        };
        self.sent = self.last_id;
        let state = &mut self.panes[pane.index()];
        // A view that changed meanwhile starts over; this frame was of the old one.
        if quality == Quality::Full
            && matches!(
                state.progress,
                Progress::Interactive { .. } | Progress::Refining
            )
        {
            state.progress = match (converged, loading) {
                (true, _) => Progress::Converged,
                (false, Some(seen)) => Progress::Loading { seen },
                (false, None) => Progress::Refining,
            };
        }
    }

    /// The frame being rendered was drawn with `camera`, the one a fit chose:
    /// the view takes it (so later frames keep it) and the client is told.
    /// Nothing when the view no longer asks for a fit (a later message set
    /// the camera itself).
    pub fn on_fitted(&mut self, camera: Camera) -> Option<Reply> {
        if !self.view.frame.camera.fit {
            return None;
        }
        let current = &mut self.view.frame.camera;
        // The angles may have moved since the fit began: they stay.
        *current = Camera {
            azimuth_deg: current.azimuth_deg,
            elevation_deg: current.elevation_deg,
            roll_deg: current.roll_deg,
            ..camera
        };
        Some(Reply::Camera {
            set: current.to_json(),
        })
    }

    /// The frame being rendered failed; the error to send. Nothing more is
    /// rendered for its view until it changes.
    pub fn on_render_failed(&mut self, message: String) -> Reply {
        if let Some((pane, _)) = self.rendering.take() {
            let state = &mut self.panes[pane.index()];
            if !matches!(state.progress, Progress::Changed { .. }) {
                state.progress = Progress::Failed;
            }
        }
        Reply::error(None, message)
    }

    /// Blocks the last frames waited for have arrived: the next full frames
    /// show them.
    pub fn on_blocks_arrived(&mut self) {
        for state in &mut self.panes {
            if matches!(state.progress, Progress::Loading { .. }) {
                state.progress = Progress::Refining;
            }
        }
    }

    /// The server is shutting down: the next action is [`Action::Close`].
    pub fn shut_down(&mut self) {
        self.closing = true;
    }

    /// The server drains (SIGTERM): the render in flight, if any, finishes
    /// and its frame goes out; then the next action is [`Action::Close`],
    /// and no other render begins.
    pub fn drain(&mut self) {
        self.draining = true;
    }

    /// Whether [`Session::drain`] was called.
    pub fn is_draining(&self) -> bool {
        self.draining
    }

    /// What to do at `now`. A [`Action::Render`] counts as begun.
    pub fn next_action(&mut self, now: Instant) -> Action {
        if self.closing || (self.draining && self.rendering.is_none()) {
            return Action::Close;
        }
        if self.rendering.is_some() {
            return Action::WaitForInput;
        }
        match self.want(now) {
            (_, Want::Nothing) => Action::WaitForInput,
            // The ack wakes the loop; waking at the still instant would only spin.
            _ if self.window_full() => Action::WaitForInput,
            (_, Want::StillAt(at)) => Action::WaitUntil(at),
            (_, Want::Blocks(seen)) => match self.view.dataset(&self.datasets) {
                Ok(dataset) => Action::WaitForBlocks {
                    dataset: dataset.clone(),
                    seen,
                },
                Err(_) => Action::WaitForInput,
            },
            (pane, Want::Frame(quality)) => self.begin(pane, quality),
        }
    }

    /// Where the session stands at `now`, the answer to status message `id`.
    pub fn status(&self, now: Instant, id: Option<u32>) -> Status {
        let waiting = match self.want(now).1 {
            _ if self.rendering.is_some() => Waiting::Render,
            Want::Nothing => Waiting::Message,
            _ if self.window_full() => Waiting::Ack,
            Want::StillAt(_) => Waiting::Still,
            Want::Blocks(_) => Waiting::Blocks,
            // Only seen between an event and the loop's next action, which begins it.
            Want::Frame(_) => Waiting::Render,
        };
        let shown = self.panes.iter().filter(|p| p.shown);
        Status {
            id,
            view_id: self.message_id,
            sent: self.sent,
            acked: self.acked,
            rendering: self.rendering.is_some(),
            waiting,
            converged: shown.clone().any(|p| p.progress == Progress::Converged)
                && shown
                    .clone()
                    .all(|p| matches!(p.progress, Progress::Converged | Progress::Empty)),
        }
    }

    /// The dataset shown, for probes.
    ///
    /// # Errors
    /// When the view's dataset is not offered.
    pub fn probe_target(&self) -> Result<Dataset, ViewError> {
        self.view
            .dataset(&self.datasets)
            .cloned()
            .map_err(|e| ViewError::setting(Origin::Session, e))
    }

    /// What a pick at CSS pixel (`x`, `y`) of the 3D view needs: the
    /// dataset, the 3D view's frame (size in CSS pixels) and its transfer
    /// function.
    ///
    /// # Errors
    /// When the view's dataset is not offered.
    pub fn pick_target(
        &self,
    ) -> Result<(Dataset, FrameRequest, blocks::TransferFunction), ViewError> {
        let dataset = self.probe_target()?;
        let frame = self.view.frame.clone();
        let tf = frame.transfer_function(dataset.value_range(), dataset.default_preset());
        Ok((dataset, frame, tf))
    }

    /// At most `frames_in_flight` frames are sent and unacknowledged.
    fn window_full(&self) -> bool {
        self.sent - self.acked >= self.settings.frames_in_flight
    }

    /// What the shown views ask for, the most pressing first: a frame (of
    /// the view changed last), the earliest still instant, blocks (the
    /// earliest arrivals count), else nothing.
    fn want(&self, now: Instant) -> (Pane, Want) {
        let mut best = (Pane::Volume, Want::Nothing);
        let mut frame_changed: Option<Option<Instant>> = None;
        for pane in Pane::ALL {
            let state = &self.panes[pane.index()];
            if !state.shown {
                continue;
            }
            let want = self.want_of(state, now);
            best = match (best.1, want) {
                (_, Want::Nothing) => best,
                (Want::Frame(_), Want::Frame(_)) => {
                    if frame_changed.is_some_and(|c| state.changed > c) {
                        frame_changed = Some(state.changed);
                        (pane, want)
                    } else {
                        best
                    }
                }
                (Want::Frame(_), _) => best,
                (_, Want::Frame(_)) => {
                    frame_changed = Some(state.changed);
                    (pane, want)
                }
                (Want::StillAt(a), Want::StillAt(b)) => (pane, Want::StillAt(a.min(b))),
                (Want::StillAt(_), _) => best,
                (_, Want::StillAt(_)) => (pane, want),
                (Want::Blocks(a), Want::Blocks(b)) => (pane, Want::Blocks(a.min(b))),
                (Want::Nothing, _) => (pane, want),
            };
        }
        best
    }

    fn want_of(&self, state: &PaneState, now: Instant) -> Want {
        let idle = Duration::from_millis(self.settings.idle_ms);
        match state.progress {
            Progress::Empty | Progress::Converged | Progress::Failed => Want::Nothing,
            Progress::Changed { at } if now >= at + idle => Want::Frame(Quality::Full),
            Progress::Changed { .. } => Want::Frame(Quality::Interactive),
            Progress::Interactive { changed_at } if now >= changed_at + idle => {
                Want::Frame(Quality::Full)
            }
            Progress::Interactive { changed_at } => Want::StillAt(changed_at + idle),
            // The next light refinement, or the blocks that arrived.
            Progress::Refining => Want::Frame(Quality::Full),
            Progress::Loading { seen } => Want::Blocks(seen),
        }
    }

    /// Begins a render of `pane` at `quality`, or gives up on a view that
    /// can no longer be rendered.
    fn begin(&mut self, pane: Pane, quality: Quality) -> Action {
        let state = &mut self.panes[pane.index()];
        if let Progress::Changed { at } = state.progress {
            state.progress = Progress::Interactive { changed_at: at };
        }
        let message_id = state.message_id;
        match self.request(pane, quality) {
            Ok((dataset, request, slice)) => {
                self.last_id += 1;
                self.rendering = Some((pane, quality));
                Action::Render(Box::new(Render {
                    quality,
                    dataset,
                    pane,
                    request,
                    slice,
                    frame_id: self.last_id,
                    message_id,
                }))
            }
            Err(error) => {
                // Checked when the message came; only the datasets can change this.
                self.panes[pane.index()].progress = Progress::Failed;
                Action::Send(Reply::error(None, error.to_string()))
            }
        }
    }

    /// The dataset and frame request of `pane` at `quality`, checked.
    #[expect(clippy::type_complexity, reason = "one private use")]
    fn request(
        &self,
        pane: Pane,
        quality: Quality,
    ) -> Result<(Dataset, FrameRequest, Option<(SliceRequest, Window)>), ViewError> {
        let dataset = self
            .view
            .dataset(&self.datasets)
            .map_err(|e| ViewError::setting(Origin::Session, e))?;
        if let Pane::Slice(_) = pane {
            let mut slice = self.slices[pane.index() - 1].clone();
            // The crosshair's lines: the other views' planes as they are turned.
            slice.crosshair_normals = Some(self.slices.each_ref().map(|s| s.axes()[2].to_array()));
            (slice.width, slice.height) = device_size(slice.width, slice.height, self.dpr)?;
            let window = slice.window.unwrap_or_else(|| dataset.default_window().1);
            let request = FrameRequest {
                width: slice.width,
                height: slice.height,
                ..FrameRequest::default()
            };
            return Ok((dataset.clone(), request, Some((slice, window))));
        }
        let mut request = self.view.frame.clone();
        (request.width, request.height) = device_size(request.width, request.height, self.dpr)?;
        if quality == Quality::Interactive {
            let s = self.settings.interactive_scale;
            request.width = ((request.width as f32 * s).round() as u32).max(1);
            request.height = ((request.height as f32 * s).round() as u32).max(1);
            request.cubic_gradient = false;
            // Illumination modes keep their data: other blocks would recompute
            // their stages (the light, the summed-area table) twice a gesture.
            if Mode::of(request.shading).is_none() {
                request.reduction = (request.reduction * self.settings.interactive_reduction)
                    .min(shaders::frame::MAX_REDUCTION as f32);
            }
        }
        Ok((dataset.clone(), request, None))
    }
}

/// `slice` with `set` merged in (`null` back to the default), each setting
/// checked; unchanged when any is refused.
fn patch_slice(slice: &mut SliceRequest, set: &Map<String, Value>) -> Result<(), ViewError> {
    let origin = Origin::Session;
    let mut next = slice.clone();
    for (name, value) in set {
        let applied = match value {
            Value::Null => next.reset_named(name),
            value => next.set_named(name, &Raw::Json(value)),
        };
        applied.map_err(|e| ViewError::setting(origin, e))?;
    }
    *slice = next;
    Ok(())
}

/// The frame size in device pixels of a viewport of `width` × `height`
/// CSS pixels at device pixel ratio `dpr`.
fn device_size(width: u32, height: u32, dpr: f64) -> Result<(u32, u32), ViewError> {
    let (w, h) = (f64::from(width), f64::from(height));
    let (pw, ph) = ((w * dpr).round(), (h * dpr).round());
    let max = f64::from(MAX_IMAGE_EDGE);
    if pw > max || ph > max {
        return Err(ViewError::Viewport {
            width,
            height,
            dpr,
            pixels_wide: pw,
            pixels_high: ph,
        });
    }
    Ok((pw.max(1.0) as u32, ph.max(1.0) as u32))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn session_with(settings: StreamSettings) -> Session {
        let phantom = Dataset::phantom(16, 1 << 20).expect("phantom");
        Session::new(Arc::from(vec![phantom]), settings)
    }

    fn session() -> Session {
        session_with(StreamSettings::default())
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    /// View message `id` setting `set`, at `now`; the reply.
    fn view(session: &mut Session, now: Instant, id: u32, set: Value) -> Option<Reply> {
        let mut message = serde_json::json!({"type": "view", "id": id});
        message["set"] = set;
        session.on_text(now, &message.to_string())
    }

    fn render(action: Action) -> Render {
        match action {
            Action::Render(render) => *render,
            other => panic!("expected a render, got {other:?}"),
        }
    }

    fn waits_for_input(action: &Action) -> bool {
        matches!(action, Action::WaitForInput)
    }

    /// Sends the frame being rendered (`converged` as its header would say)
    /// and acknowledges it.
    fn sent_and_acked(session: &mut Session, converged: bool) {
        session.on_frame_sent(converged, None);
        session.on_ack(session.sent);
    }

    #[test]
    fn a_burst_during_a_render_gives_one_next_render_of_the_last_view() {
        let mut s = session();
        let t0 = Instant::now();
        assert_eq!(
            view(&mut s, t0, 1, serde_json::json!({"w": 96, "h": 96})),
            None
        );
        let first = render(s.next_action(t0));
        assert_eq!((first.frame_id, first.message_id), (1, 1));
        for id in 2..=100u32 {
            let now = t0 + ms(u64::from(id));
            let reply = view(&mut s, now, id, serde_json::json!({"az": id}));
            assert_eq!(reply, None, "message {id}");
            assert!(waits_for_input(&s.next_action(now)), "one render at a time");
        }
        let now = t0 + ms(120);
        sent_and_acked(&mut s, false);
        let next = render(s.next_action(now));
        assert_eq!((next.frame_id, next.message_id), (2, 100));
        assert_eq!(next.request.camera.azimuth_deg, 100.0);
        assert_eq!(next.quality, Quality::Interactive);
        assert!(waits_for_input(&s.next_action(now)));
    }

    #[test]
    fn no_render_beyond_the_acknowledgement_window() {
        for frames_in_flight in [1, 2] {
            let mut s = session_with(StreamSettings {
                frames_in_flight,
                ..StreamSettings::default()
            });
            let t0 = Instant::now();
            for id in 1..=frames_in_flight {
                view(&mut s, t0, id, serde_json::json!({"az": id}));
                render(s.next_action(t0));
                s.on_frame_sent(false, None);
            }
            view(&mut s, t0, 9, serde_json::json!({"az": 90}));
            // Not when the view changes, nor when it turns still.
            for now in [t0, t0 + ms(150), t0 + ms(10_000)] {
                assert!(waits_for_input(&s.next_action(now)), "{frames_in_flight}");
                let status = s.status(now, None);
                assert_eq!(status.waiting, Waiting::Ack, "{status:?}");
                assert_eq!((status.sent, status.acked), (frames_in_flight, 0));
                assert!(!status.rendering);
            }
            // An acknowledgement of a frame never sent counts as the last sent.
            s.on_ack(1000);
            assert_eq!(s.status(t0, None).acked, frames_in_flight);
            let next = render(s.next_action(t0 + ms(10_000)));
            assert_eq!((next.message_id, next.quality), (9, Quality::Full));
        }
    }

    #[test]
    fn frames_are_interactive_while_messages_come_and_full_exactly_idle_ms_after_the_last() {
        let mut s = session();
        let t0 = Instant::now();
        view(&mut s, t0, 1, serde_json::json!({"w": 64, "h": 48}));
        let first = render(s.next_action(t0));
        assert_eq!(first.quality, Quality::Interactive);
        assert_eq!((first.request.width, first.request.height), (32, 24));
        assert_eq!(first.request.reduction, 4.0, "interactive_reduction × 1");
        assert!(
            !first.request.cubic_gradient,
            "central differences while moving"
        );
        sent_and_acked(&mut s, false);
        let t1 = t0 + ms(100);
        view(&mut s, t1, 2, serde_json::json!({"az": 10}));
        assert_eq!(render(s.next_action(t1)).quality, Quality::Interactive);
        sent_and_acked(&mut s, false);
        let still = t1 + ms(150);
        for now in [t1 + ms(20), still - ms(1)] {
            match s.next_action(now) {
                Action::WaitUntil(at) => assert_eq!(at, still),
                other => panic!("expected to wait until still, got {other:?}"),
            }
            assert_eq!(s.status(now, None).waiting, Waiting::Still);
        }
        let full = render(s.next_action(still));
        assert_eq!((full.quality, full.message_id), (Quality::Full, 2));
        assert_eq!((full.request.width, full.request.height), (64, 48));
        assert_eq!(full.request.reduction, 1.0);
        assert!(full.request.cubic_gradient, "cubic normals when still");
        sent_and_acked(&mut s, true);
        assert!(waits_for_input(&s.next_action(still + ms(10_000))));
        let status = s.status(still, Some(5));
        assert_eq!(
            status,
            Status {
                id: Some(5),
                view_id: 2,
                sent: 3,
                acked: 3,
                rendering: false,
                waiting: Waiting::Message,
                converged: true,
            }
        );
    }

    #[test]
    fn a_view_changed_after_idling_renders_full_at_once_and_the_device_pixel_ratio_scales_it() {
        let mut s = session();
        let t0 = Instant::now();
        let message =
            serde_json::json!({"type": "view", "id": 1, "set": {"w": 40, "h": 30}, "dpr": 2});
        assert_eq!(s.on_text(t0, &message.to_string()), None);
        let first = render(s.next_action(t0));
        assert_eq!((first.request.width, first.request.height), (40, 30));
        // The acknowledgement comes after the view turned still: straight to full.
        s.on_frame_sent(false, None);
        s.on_ack(1);
        let full = render(s.next_action(t0 + ms(400)));
        assert_eq!(full.quality, Quality::Full);
        assert_eq!((full.request.width, full.request.height), (80, 60));
        // Too many device pixels: refused, the view stays.
        let message = serde_json::json!({"type": "view", "id": 2, "set": {"w": 3000}, "dpr": 2});
        match s.on_text(t0, &message.to_string()) {
            Some(Reply::Error { id, message }) => {
                assert_eq!(id, Some(2));
                assert!(
                    message.contains("expected at most 4096 per side"),
                    "{message}"
                );
            }
            other => panic!("expected an error, got {other:?}"),
        }
        assert_eq!(s.status(t0, None).view_id, 1);
    }

    #[test]
    fn global_light_refines_until_converged_then_waits_for_a_message() {
        let mut s = session();
        let t0 = Instant::now();
        view(
            &mut s,
            t0,
            1,
            serde_json::json!({"shading": "global", "reduction": 2}),
        );
        let first = render(s.next_action(t0));
        assert_eq!(first.quality, Quality::Interactive);
        assert_eq!(first.request.reduction, 2.0, "lit modes keep their data");
        sent_and_acked(&mut s, false);
        let still = t0 + ms(150);
        for _ in 0..3 {
            assert_eq!(render(s.next_action(still)).quality, Quality::Full);
            sent_and_acked(&mut s, false);
            assert!(!s.status(still, None).converged);
        }
        assert_eq!(render(s.next_action(still)).quality, Quality::Full);
        sent_and_acked(&mut s, true);
        assert!(waits_for_input(&s.next_action(still + ms(10_000))));
        assert!(s.status(still, None).converged);
        // A new view starts over.
        view(&mut s, still, 2, serde_json::json!({"az": 5}));
        assert_eq!(render(s.next_action(still)).quality, Quality::Interactive);
    }

    #[test]
    fn a_refused_message_changes_nothing_and_is_answered_with_an_error() {
        let mut s = session();
        let t0 = Instant::now();
        view(&mut s, t0, 1, serde_json::json!({"w": 40, "h": 40}));
        render(s.next_action(t0));
        sent_and_acked(&mut s, false);
        let before = s.status(t0, None);
        let bad = [
            (
                serde_json::json!({"type": "view", "id": 2, "set": {"zoom": 2}}).to_string(),
                Some(2),
                "unknown view setting 'zoom'",
            ),
            (
                serde_json::json!({"type": "view", "id": 3, "set": {"az": "NaN"}}).to_string(),
                Some(3),
                "view setting az=\"NaN\"",
            ),
            (
                serde_json::json!({"type": "view", "id": 4, "set": {"dataset": "lung"}})
                    .to_string(),
                Some(4),
                "view setting dataset=\"lung\"",
            ),
            ("{nope".to_owned(), None, "not JSON"),
            (
                serde_json::json!({"type": "flush"}).to_string(),
                None,
                "message type 'flush'",
            ),
        ];
        for (text, want_id, want) in bad {
            match s.on_text(t0 + ms(10), &text) {
                Some(Reply::Error { id, message }) => {
                    assert_eq!(id, want_id, "{text}");
                    assert!(message.contains(want), "{text}: {message}");
                }
                other => panic!("{text}: expected an error, got {other:?}"),
            }
            assert_eq!(s.status(t0, None), before, "{text}");
            assert_eq!(s.view.frame.width, 40);
        }
        // The refusals did not move the still instant.
        match s.next_action(t0 + ms(20)) {
            Action::WaitUntil(at) => assert_eq!(at, t0 + ms(150)),
            other => panic!("expected to wait until still, got {other:?}"),
        }
    }

    #[test]
    fn a_render_error_stops_that_view_until_it_changes() {
        let mut s = session();
        let t0 = Instant::now();
        view(&mut s, t0, 1, serde_json::json!({"w": 40, "h": 40}));
        render(s.next_action(t0));
        let reply = s.on_render_failed("the GPU is out of memory".into());
        assert_eq!(reply, Reply::error(None, "the GPU is out of memory"));
        for now in [t0, t0 + ms(150), t0 + ms(10_000)] {
            assert!(waits_for_input(&s.next_action(now)));
        }
        let status = s.status(t0 + ms(150), None);
        assert_eq!(
            (status.waiting, status.converged, status.sent),
            (Waiting::Message, false, 0)
        );
        // A view changed during the failed render is rendered still.
        view(&mut s, t0, 2, serde_json::json!({"az": 30}));
        let next = render(s.next_action(t0));
        view(&mut s, t0 + ms(1), 3, serde_json::json!({"az": 40}));
        s.on_render_failed("again".into());
        assert_eq!(render(s.next_action(t0 + ms(2))).message_id, 3, "{next:?}");
    }

    #[test]
    fn a_view_that_stopped_being_valid_sends_an_error_and_stops() {
        let mut s = session();
        let t0 = Instant::now();
        view(&mut s, t0, 1, serde_json::json!({"dataset": "phantom"}));
        // The datasets change under the session (no server does this today).
        s.datasets = Arc::from(Vec::new());
        match s.next_action(t0) {
            Action::Send(Reply::Error { id: None, message }) => {
                assert!(
                    message.starts_with("view setting dataset=\"phantom\""),
                    "{message}"
                );
            }
            other => panic!("expected an error, got {other:?}"),
        }
        assert!(waits_for_input(&s.next_action(t0 + ms(10_000))));
    }

    #[test]
    fn shutdown_closes_the_session_even_during_a_render() {
        let mut s = session();
        let t0 = Instant::now();
        assert!(
            waits_for_input(&s.next_action(t0)),
            "no view, nothing to do"
        );
        view(&mut s, t0, 1, serde_json::json!({}));
        render(s.next_action(t0));
        s.shut_down();
        assert!(matches!(s.next_action(t0), Action::Close));
        assert!(matches!(s.next_action(t0 + ms(1)), Action::Close));
    }

    #[test]
    fn draining_finishes_the_render_in_flight_then_closes() {
        let mut s = session();
        let t0 = Instant::now();
        view(&mut s, t0, 1, serde_json::json!({}));
        render(s.next_action(t0));
        s.drain();
        // The frame is still coming: nothing else to do meanwhile.
        assert!(waits_for_input(&s.next_action(t0 + ms(1))));
        // A view message changes the view but starts no render.
        view(&mut s, t0 + ms(2), 2, serde_json::json!({"az": 40}));
        assert!(waits_for_input(&s.next_action(t0 + ms(3))));
        s.on_frame_sent(false, None);
        assert!(matches!(s.next_action(t0 + ms(4)), Action::Close));
        // A session rendering nothing closes at once.
        let mut idle = session();
        idle.drain();
        assert!(matches!(idle.next_action(t0), Action::Close));
    }

    /// View message `id` for `pane` setting `set`, at `now`; the reply.
    fn pane_view(s: &mut Session, now: Instant, id: u32, pane: &str, set: Value) -> Option<Reply> {
        let mut message = serde_json::json!({"type": "view", "id": id, "pane": pane});
        message["set"] = set;
        s.on_text(now, &message.to_string())
    }

    #[test]
    fn slice_views_render_when_shown_the_view_changed_last_first() {
        let mut s = session();
        let t0 = Instant::now();
        view(&mut s, t0, 1, serde_json::json!({"w": 64, "h": 64}));
        assert_eq!(
            pane_view(
                &mut s,
                t0,
                2,
                "axial",
                serde_json::json!({"w": 32, "h": 48, "cz": 5})
            ),
            None
        );
        // Not in the layout: only the 3D view renders.
        let first = render(s.next_action(t0));
        assert_eq!((first.pane, first.slice.is_none()), (Pane::Volume, true));
        sent_and_acked(&mut s, false);
        s.on_text(t0, r#"{"type":"layout","panes":["3d","axial","coronal"]}"#);
        let axial = render(s.next_action(t0 + ms(1)));
        let (slice, window) = axial.slice.clone().expect("a slice");
        assert_eq!(axial.pane, Pane::Slice(Plane::Axial));
        assert_eq!((slice.width, slice.height, slice.cz), (32, 48, 5.0));
        assert_eq!(axial.message_id, 2);
        // The phantom is not CT in HU: the window spans its values.
        assert_eq!(window, s.datasets[0].default_window().1);
        sent_and_acked(&mut s, false);
        // The coronal view has had no message: nothing; then scrolling the
        // axial view while the 3D view waits for still renders the axial first.
        pane_view(&mut s, t0 + ms(2), 3, "axial", serde_json::json!({"cz": 6}));
        let next = render(s.next_action(t0 + ms(2)));
        assert_eq!(
            (next.pane, next.quality),
            (Pane::Slice(Plane::Axial), Quality::Interactive)
        );
        sent_and_acked(&mut s, false);
        // Still: both full frames follow, the axial (changed last) first.
        let later = t0 + ms(1000);
        let full = render(s.next_action(later));
        assert_eq!(
            (full.pane, full.quality),
            (Pane::Slice(Plane::Axial), Quality::Full)
        );
        s.on_frame_sent(true, None);
        s.on_ack(s.sent);
        let full = render(s.next_action(later));
        assert_eq!((full.pane, full.quality), (Pane::Volume, Quality::Full));
        s.on_frame_sent(true, None);
        s.on_ack(s.sent);
        assert!(waits_for_input(&s.next_action(later)));
        assert!(s.status(later, None).converged);
        // A refused slice setting names it and changes nothing.
        let refused = pane_view(
            &mut s,
            later,
            4,
            "coronal",
            serde_json::json!({"slab": 9999}),
        );
        match refused {
            Some(Reply::Error {
                id: Some(4),
                message,
            }) => {
                assert!(message.starts_with("view setting slab=9999"), "{message}");
            }
            other => panic!("expected an error, got {other:?}"),
        }
        let refused = pane_view(&mut s, later, 5, "coronal", serde_json::json!({"az": 3}));
        assert!(
            matches!(refused, Some(Reply::Error { id: Some(5), .. })),
            "{refused:?}"
        );
        assert!(waits_for_input(&s.next_action(later)));
    }
}
