//! The view-session protocol of `GET /api/stream` (a WebSocket), in one place.
//! keep in sync with web/stream.js
//!
//! # Client → server: JSON text messages
//!
//! | message | meaning |
//! |---|---|
//! | `{"type":"view","id":N,"pane":P,"set":{…},"dpr":D}` | change a view. `pane` (optional, default `3d`) is the view: `3d`, or a slice view `axial`, `coronal` or `sagittal` ([`Pane`]), each with settings of its own. `id` (a whole number the client increases) names the message; the frames rendered from it carry it back. `set` holds settings, for the 3D view those of `GET /api/render` (as `GET /api/settings` lists them: [`crate::view`]), for a slice view those `GET /api/settings` lists under `slice` (`shaders::slice::SliceRequest`: the crosshair `cx`, `cy`, `cz`, `orient`, `zoom`, `px`, `py`, `window`, `slab`, `slab_mode`, `w`, `h`; the dataset is the 3D view's), typed: numbers as JSON numbers, switches as `true`/`false`, choices and text forms (`clip`, `light`, `tf`, …) as strings; they are merged into the view, so a camera move sends only `az` and `el`. A setting given as `null` goes back to its default (e.g. `"preset":null` with a `tf`). `w` and `h` are the viewport in CSS pixels and `dpr` (optional, 0.25 to 4, default 1) the device pixel ratio of every view: frames are `w·dpr` × `h·dpr`. |
//! | `{"type":"layout","panes":[P,…]}` | the views shown (1 to 4 different ones; `["3d"]` until said): only they are rendered, one render at a time for the session, the view changed last first. |
//! | `{"type":"probe","id":N,"at":[X,Y,Z]}` | the level-0 voxel at a point (model mm, from the volume's centre, within ±[`MAX_PROBE_MM`]): answered by a `probe` message. |
//! | `{"type":"pick","id":N,"xy":[X,Y]}` | the first point along the 3D view's ray through CSS pixel (X, Y) where what the transfer function shows turns half opaque ([`shaders::slice::pick`]): answered by a `pick` message. |
//! | `{"type":"ack","frame":F}` | the client has drawn frame `F`; the server sends at most [`crate::stream::StreamSettings::frames_in_flight`] frames ahead of the last acknowledged one. |
//! | `{"type":"status","id":N}` | asks where the session stands (`id` optional, echoed); answered by a `status` message, in order with everything else the server sends. |
//!
//! A message that is not JSON, has an unknown type or field, or sets a value
//! out of range is answered with an `error` message and changes nothing; the
//! session goes on with the view it had.
//!
//! # Server → client
//!
//! JSON text: `{"type":"hello","protocol":3,"datasets":[…],"renderer":{"kind":…,"device":…},"settings":{…},"notice":…}` once
//! at the start (the datasets' descriptions as `GET /api/datasets` gives them,
//! the stream settings, and the line every viewer shows over the image,
//! `--notice`, or `null`), `{"type":"error","id":N,"message":"…"}` for a
//! refused message (`id`: the message's, when it had one) or a view that
//! cannot be rendered, `{"type":"camera","set":{"az":…,"el":…,"dist":…,"tx":…,"ty":…,"tz":…,"fit":false,…}}`
//! when the view asked for a fit (`"fit":true`): the camera the server chose
//! (the target at the centre of what the transfer function shows, the
//! distance framing it), now the session's view, sent before the frame drawn
//! with it; `{"type":"slice","pane":P,"frame":F,"placement":{…},"window":[C,W]}`
//! before each slice view's frame F (where its pixels lie: pixel (x, y)'s
//! centre is `corner + x·right + y·down`, model mm; the unit `normal`
//! towards the viewer, the `level` sampled, the `crosshair` and the
//! `normals` of its three planes; the window drawn through);
//! `{"type":"probe","id":N,"voxel":{"index":[I,J,K],"at":[X,Y,Z],"value":V}|null,"unit":U}`
//! and `{"type":"pick","id":N,"at":[X,Y,Z]|null}` answering those
//! messages (`null`: outside the volume, nothing visible); and a [`Status`]
//! for each `status` message (`converged`: every view shown is):
//!
//! | field | meaning |
//! |---|---|
//! | `type` | `"status"` |
//! | `id` | the `status` message's id, when it had one |
//! | `view_id` | the id of the last `view` message applied (0: none yet) |
//! | `sent` | the id of the last frame sent (0: none yet) |
//! | `acked` | the id of the last frame acknowledged |
//! | `rendering` | a frame is being rendered |
//! | `waiting` | what the session waits for before it renders again: `"message"` (nothing more to send until the view changes), `"still"` (the view to be still for `idle_ms`: the full frame follows), `"ack"` (a frame is due but `frames_in_flight` frames are unacknowledged), `"render"` (the frame being rendered), `"blocks"` (blocks being read in the background: the last full frame showed some coarser, and the next follows when they have arrived) |
//! | `converged` | the current view's last frame was converged: nothing more will be sent for it |
//!
//! Replies come in order with frames, so a status after a frame describes the
//! session after that frame: `"waiting":"message"`, not `rendering` and `sent`
//! the last frame received mean nothing more will come until the view changes.
//!
//! Binary: one frame, a [`FrameHeader`] of [`HEADER_LEN`] bytes (little
//! endian) followed by the encoded image:
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | 4 bytes | magic `VXF1` |
//! | 4 | u8 | encoding: 1 JPEG, 2 PNG, 3 WebP (lossless) |
//! | 5 | u8 | flags: 1 lossless full resolution, 2 converged (nothing more will come for this view: every block at its level, the light complete), 4 memory-limited (the renderer's memory cannot hold the detail asked for: the reduction is coarser) |
//! | 6 | u16 | width, pixels |
//! | 8 | u16 | height, pixels |
//! | 10 | u16 | refinement step j (in-scattering directions in; 0 without global light) |
//! | 12 | u16 | refinement steps J |
//! | 14 | u16 | blocks shown coarser than selected while their data is read (at most 65535; 0: every block at its level) |
//! | 16 | u32 | frame id (1, 2, … per session) |
//! | 20 | u32 | id of the last view message this frame reflects |
//! | 24 | f32 | render milliseconds |
//! | 28 | f32 | encode milliseconds |
//! | 32 | f32 | data reduction rendered at, among the blocks the transfer function shows (their full-resolution voxels per voxel kept) |
//! | 36 | f32 | milliseconds the render waited for the GPU behind other sessions |
//! | 40 | f32 | share of the volume's blocks the transfer function leaves empty (0 to 1; skipped, not counted in the reduction) |
//!
//! When the server shuts down (drains) it sends each session the frame it
//! is rendering, then closes it with code 1001 (going away), on which the
//! client reconnects and sends its whole view again. A session without a message from the client for
//! [`crate::stream::StreamSettings::session_idle_s`] is closed with
//! [`CLOSE_IDLE`] (the client reconnects when the user acts again); one
//! whose peer has not answered a ping for [`PEER_PATIENCE`] seconds is
//! dropped. A session authenticated by a token that expires is closed then
//! with [`CLOSE_EXPIRED`]. A message longer than [`MAX_MESSAGE_BYTES`], or a socket that
//! breaks the protocol, closes the session with 1009 (too big) or 1002
//! (protocol error) and the reason.

use serde_json::{Map, Value};
use shaders::frame::Window;
use shaders::slice::{Plane, SlicePlacement};

/// The protocol's version, sent in `hello`.
pub const PROTOCOL: u32 = 3;
/// The longest message a client may send, in bytes: views, acknowledgements
/// and status requests are far shorter.
pub const MAX_MESSAGE_BYTES: usize = 64 << 10;

/// The close code of a session closed for want of messages from the client
/// (an application code: 4000 + HTTP's 408, request timeout).
pub const CLOSE_IDLE: u16 = 4408;

/// The close code of a session whose access token has expired (4000 +
/// HTTP's 401): the client reconnects with a fresh token.
pub const CLOSE_EXPIRED: u16 = 4401;

/// Seconds between the server's pings; a peer that has sent nothing (a pong
/// included) for [`PEER_PATIENCE`] seconds is gone.
pub const PING_INTERVAL: u64 = 20;
/// See [`PING_INTERVAL`].
pub const PEER_PATIENCE: u64 = 3 * PING_INTERVAL;

/// Bytes of a [`FrameHeader`].
pub const HEADER_LEN: usize = 48;
/// The first four bytes of every frame.
pub const MAGIC: [u8; 4] = *b"VXF1";
/// Device pixel ratios accepted.
pub const DPR_RANGE: (f64, f64) = (0.25, 4.0);

/// A session's views: the 3D view and the three slice views, each with its
/// own settings and frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Pane {
    /// The volume rendering.
    Volume,
    /// A slice view of this plane.
    Slice(Plane),
}

impl Pane {
    /// Every pane, in the order of their numbers in frame headers.
    pub const ALL: [Pane; 4] = [
        Pane::Volume,
        Pane::Slice(Plane::Axial),
        Pane::Slice(Plane::Coronal),
        Pane::Slice(Plane::Sagittal),
    ];

    /// The name in messages: `3d`, `axial`, `coronal`, `sagittal`.
    pub fn name(self) -> &'static str {
        match self {
            Pane::Volume => "3d",
            Pane::Slice(plane) => shaders::settings::Choice::name(plane),
        }
    }

    /// The pane of a name.
    pub fn named(name: &str) -> Option<Pane> {
        Pane::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Its number in frame headers (0 to 3), and its place in [`Pane::ALL`].
    pub fn index(self) -> usize {
        match self {
            Pane::Volume => 0,
            Pane::Slice(Plane::Axial) => 1,
            Pane::Slice(Plane::Coronal) => 2,
            Pane::Slice(Plane::Sagittal) => 3,
        }
    }

    fn expected() -> String {
        let names: Vec<&str> = Pane::ALL.iter().map(|p| p.name()).collect();
        format!("one of {}", names.join(", "))
    }
}

impl serde::Serialize for Pane {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// How a frame's image is encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// Lossy, for frames while the user interacts.
    Jpeg = 1,
    /// Lossless, PNG.
    Png = 2,
    /// Lossless, WebP.
    Webp = 3,
}

/// The header in front of every binary frame; see the module docs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameHeader {
    /// How the image is encoded.
    pub encoding: Encoding,
    /// Lossless at full resolution.
    pub lossless: bool,
    /// Nothing more will be sent for this view.
    pub converged: bool,
    /// The renderer's memory cannot hold the detail asked for.
    pub memory_limited: bool,
    /// Blocks shown coarser than selected while their data is read.
    pub pending_blocks: u16,
    /// Image width.
    pub width: u16,
    /// Image height.
    pub height: u16,
    /// In-scattering directions in (j).
    pub refined: u16,
    /// In-scattering directions in all (J).
    pub directions: u16,
    /// This frame's id.
    pub frame_id: u32,
    /// The id of the last view message the frame reflects.
    pub message_id: u32,
    /// Render milliseconds.
    pub render_ms: f32,
    /// Encode milliseconds.
    pub encode_ms: f32,
    /// The data reduction rendered at, among the blocks the transfer
    /// function shows.
    pub reduction: f32,
    /// Milliseconds the job waited for the render worker.
    pub queue_ms: f32,
    /// The share of blocks the transfer function leaves empty (0 to 1).
    pub empty_share: f32,
    /// The view it is of.
    pub pane: Pane,
}

/// A frame header [`FrameHeader::parse`] refuses.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HeaderError {
    /// Fewer bytes than a header.
    #[error("a frame of {0} bytes: expected at least the {HEADER_LEN}-byte header")]
    Short(usize),
    /// Not a voxserve frame.
    #[error("frame magic {0:?}: expected {MAGIC:?}")]
    Magic([u8; 4]),
    /// An encoding this version does not know.
    #[error("frame encoding {0}: expected 1 (JPEG), 2 (PNG) or 3 (WebP)")]
    Encoding(u8),
    /// A pane this version does not know.
    #[error("frame pane {0}: expected 0 (3d), 1 (axial), 2 (coronal) or 3 (sagittal)")]
    Pane(u8),
}

impl FrameHeader {
    /// The header's bytes.
    pub fn to_bytes(&self) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        b[0..4].copy_from_slice(&MAGIC);
        b[4] = self.encoding as u8;
        b[5] = u8::from(self.lossless)
            | (u8::from(self.converged) << 1)
            | (u8::from(self.memory_limited) << 2);
        b[6..8].copy_from_slice(&self.width.to_le_bytes());
        b[8..10].copy_from_slice(&self.height.to_le_bytes());
        b[10..12].copy_from_slice(&self.refined.to_le_bytes());
        b[12..14].copy_from_slice(&self.directions.to_le_bytes());
        b[14..16].copy_from_slice(&self.pending_blocks.to_le_bytes());
        b[16..20].copy_from_slice(&self.frame_id.to_le_bytes());
        b[20..24].copy_from_slice(&self.message_id.to_le_bytes());
        b[24..28].copy_from_slice(&self.render_ms.to_le_bytes());
        b[28..32].copy_from_slice(&self.encode_ms.to_le_bytes());
        b[32..36].copy_from_slice(&self.reduction.to_le_bytes());
        b[36..40].copy_from_slice(&self.queue_ms.to_le_bytes());
        b[40..44].copy_from_slice(&self.empty_share.to_le_bytes());
        b[44] = self.pane.index() as u8;
        b
    }

    /// Reads a header from the start of `bytes` (clients and tests).
    ///
    /// # Errors
    /// When `bytes` is too short, the magic is wrong or the encoding unknown.
    pub fn parse(bytes: &[u8]) -> Result<FrameHeader, HeaderError> {
        if bytes.len() < HEADER_LEN {
            return Err(HeaderError::Short(bytes.len()));
        }
        if bytes[0..4] != MAGIC {
            return Err(HeaderError::Magic([bytes[0], bytes[1], bytes[2], bytes[3]]));
        }
        let u16_at = |i: usize| u16::from_le_bytes([bytes[i], bytes[i + 1]]);
        let u32_at =
            |i: usize| u32::from_le_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
        let f32_at = |i: usize| f32::from_bits(u32_at(i));
        let encoding = match bytes[4] {
            1 => Encoding::Jpeg,
            2 => Encoding::Png,
            3 => Encoding::Webp,
            other => return Err(HeaderError::Encoding(other)),
        };
        let pane = *Pane::ALL
            .get(usize::from(bytes[44]))
            .ok_or(HeaderError::Pane(bytes[44]))?;
        Ok(FrameHeader {
            encoding,
            lossless: bytes[5] & 1 != 0,
            converged: bytes[5] & 2 != 0,
            memory_limited: bytes[5] & 4 != 0,
            pending_blocks: u16_at(14),
            width: u16_at(6),
            height: u16_at(8),
            refined: u16_at(10),
            directions: u16_at(12),
            frame_id: u32_at(16),
            message_id: u32_at(20),
            render_ms: f32_at(24),
            encode_ms: f32_at(28),
            reduction: f32_at(32),
            queue_ms: f32_at(36),
            empty_share: f32_at(40),
            pane,
        })
    }
}

/// A client message, checked.
#[derive(Debug, Clone, PartialEq)]
pub enum ClientMessage {
    /// Change the view: `set` holds view settings as JSON; `null` sets one
    /// back to its default.
    View {
        /// The message's id.
        id: u32,
        /// The view it changes.
        pane: Pane,
        /// Settings to merge into the view (checked when merged).
        set: Map<String, Value>,
        /// Device pixel ratio, if given.
        dpr: Option<f64>,
    },
    /// The client has drawn `frame`.
    Ack {
        /// The frame's id.
        frame: u32,
    },
    /// Where does the session stand? Answered by a [`Status`].
    Status {
        /// The message's id, echoed in the reply.
        id: Option<u32>,
    },
    /// Show these views (and render only them).
    Layout {
        /// The views shown, at least one, each once.
        panes: Vec<Pane>,
    },
    /// The voxel at a point: answered by a [`Reply::Probe`].
    Probe {
        /// The message's id, echoed.
        id: u32,
        /// Model mm (from the volume's centre).
        at: [f32; 3],
    },
    /// The first visible point under a pixel of the 3D view: answered by a
    /// [`Reply::Pick`].
    Pick {
        /// The message's id, echoed.
        id: u32,
        /// CSS pixels from the 3D view's top left.
        x: f32,
        /// See `x`.
        y: f32,
    },
}

/// A JSON message from the server other than the hello.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Reply {
    /// A refused message, or a view that cannot be rendered.
    Error {
        /// The refused message's id, when it had one.
        #[serde(skip_serializing_if = "Option::is_none")]
        id: Option<u32>,
        /// What was wrong and what was expected.
        message: String,
    },
    /// Where the session stands; see the module docs.
    Status(Status),
    /// The camera a fit chose (`fit` set in the view): every camera setting,
    /// now the session's; it comes before the frame drawn with it.
    Camera {
        /// The camera's settings by name, as a view message sets them.
        set: Map<String, Value>,
    },
    /// Where the slice frame that follows lies, and its window.
    Slice {
        /// The view.
        pane: Pane,
        /// The frame's id.
        frame: u32,
        /// Pixel (x, y)'s centre is `corner + x·right + y·down`, model mm
        /// (device pixels), and `level` the detail it wants.
        placement: SlicePlacement,
        /// Greyscale window: centre and width, physical units.
        window: [f32; 2],
    },
    /// The voxel at a probed point.
    Probe {
        /// The probe's id.
        id: u32,
        /// The voxel (index, centre and physical value), `null` outside the volume.
        voxel: Option<shaders::slice::Probe>,
        /// The unit of the value, when known.
        unit: Option<String>,
    },
    /// The first visible point under a picked pixel.
    Pick {
        /// The pick's id.
        id: u32,
        /// Model mm, `null` when the ray meets nothing the transfer function shows.
        at: Option<[f32; 3]>,
    },
}

impl Reply {
    /// The reply before a slice frame.
    pub fn slice(pane: Pane, frame: u32, placement: SlicePlacement, window: Window) -> Reply {
        Reply::Slice {
            pane,
            frame,
            placement,
            window: [window.centre, window.width],
        }
    }
}

/// Where a session stands, the answer to a `status` message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Status {
    /// The `status` message's id, when it had one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<u32>,
    /// The id of the last view message applied.
    pub view_id: u32,
    /// The id of the last frame sent.
    pub sent: u32,
    /// The id of the last frame acknowledged.
    pub acked: u32,
    /// A frame is being rendered.
    pub rendering: bool,
    /// What the session waits for before it renders again.
    pub waiting: Waiting,
    /// Nothing more will be sent for the current view.
    pub converged: bool,
}

/// What a session waits for before it renders again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Waiting {
    /// A view message: nothing is left to send for this view.
    Message,
    /// The view to be still for `idle_ms`: then the full frame.
    Still,
    /// An acknowledgement: a frame is due, the window is full.
    Ack,
    /// The frame being rendered.
    Render,
    /// Blocks being read: the last full frame showed some coarser, and the
    /// next follows when they have arrived.
    Blocks,
}

impl Reply {
    /// An error reply.
    pub fn error(id: Option<u32>, message: impl Into<String>) -> Reply {
        Reply::Error {
            id,
            message: message.into(),
        }
    }

    /// The reply as JSON text.
    pub fn to_json(&self) -> String {
        // Plain structs of numbers, flags and strings: serialising cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }
}

/// A refused message: why, and its id when it had one.
#[derive(Debug, Clone, PartialEq)]
pub struct Refusal {
    /// The message's id, if it could be read.
    pub id: Option<u32>,
    /// What was wrong and what was expected.
    pub message: String,
}

/// Parses one text message.
///
/// # Errors
/// A [`Refusal`] naming the field and what was expected.
pub fn parse_client_message(text: &str) -> Result<ClientMessage, Refusal> {
    let value: Value = serde_json::from_str(text).map_err(|e| Refusal {
        id: None,
        message: format!("message is not JSON: {e}"),
    })?;
    let Value::Object(fields) = value else {
        return Err(Refusal {
            id: None,
            message: "message: expected a JSON object".into(),
        });
    };
    let fields = Fields::check(&fields)?;
    match fields.kind {
        "view" => fields.view(),
        "ack" => Ok(ClientMessage::Ack {
            frame: fields.whole("frame")?,
        }),
        "layout" => fields.layout(),
        "probe" => Ok(ClientMessage::Probe {
            id: fields.whole("id")?,
            at: fields.numbers::<3>("at", MAX_PROBE_MM)?,
        }),
        "pick" => {
            let [x, y] = fields.numbers::<2>("xy", shaders::frame::MAX_IMAGE_EDGE as f32)?;
            Ok(ClientMessage::Pick {
                id: fields.whole("id")?,
                x,
                y,
            })
        }
        _ => Ok(ClientMessage::Status {
            id: fields.optional_whole("id")?,
        }),
    }
}

/// The farthest from the volume's centre a probe may ask, mm.
pub const MAX_PROBE_MM: f32 = shaders::slice::MAX_OFFSET_MM as f32;

/// The message types, and the fields each may have.
const FIELDS: [(&str, &[&str]); 6] = [
    ("view", &["type", "id", "pane", "set", "dpr"]),
    ("ack", &["type", "frame"]),
    ("status", &["type", "id"]),
    ("layout", &["type", "panes"]),
    ("probe", &["type", "id", "at"]),
    ("pick", &["type", "id", "xy"]),
];

/// A message's fields, its type known and every field one it may have.
struct Fields<'a> {
    fields: &'a Map<String, Value>,
    kind: &'a str,
    /// The message's id, when it has a readable one (for refusals).
    id: Option<u32>,
}

impl<'a> Fields<'a> {
    /// The fields of a message of a known type with no unknown field.
    fn check(fields: &'a Map<String, Value>) -> Result<Fields<'a>, Refusal> {
        let id = fields
            .get("id")
            .and_then(Value::as_u64)
            .and_then(|i| u32::try_from(i).ok());
        let refuse = |message: String| Refusal { id, message };
        let types = "expected \"view\", \"ack\", \"status\", \"layout\", \"probe\" or \"pick\"";
        let kind = fields
            .get("type")
            .and_then(Value::as_str)
            .ok_or_else(|| refuse(format!("message field 'type': {types}")))?;
        let (kind, allowed) = FIELDS
            .into_iter()
            .find(|(k, _)| *k == kind)
            .ok_or_else(|| refuse(format!("message type '{kind}': {types}")))?;
        if let Some(unknown) = fields.keys().find(|k| !allowed.contains(&k.as_str())) {
            return Err(refuse(format!(
                "{kind} message field '{unknown}': unknown; expected {}",
                allowed.join(", ")
            )));
        }
        Ok(Fields { fields, kind, id })
    }

    fn refuse(&self, message: String) -> Refusal {
        Refusal {
            id: self.id,
            message,
        }
    }

    /// The whole number `name`.
    fn whole(&self, name: &str) -> Result<u32, Refusal> {
        self.optional_whole(name)?
            .ok_or_else(|| self.not_whole(name))
    }

    /// The whole number `name`, if given.
    fn optional_whole(&self, name: &str) -> Result<Option<u32>, Refusal> {
        self.fields
            .get(name)
            .map(|v| {
                v.as_u64()
                    .and_then(|v| u32::try_from(v).ok())
                    .ok_or_else(|| self.not_whole(name))
            })
            .transpose()
    }

    fn not_whole(&self, name: &str) -> Refusal {
        self.refuse(format!(
            "{} message field '{name}': expected a whole number from 0 to {}",
            self.kind,
            u32::MAX
        ))
    }

    /// `N` finite numbers within ±`limit` in the array `name`.
    fn numbers<const N: usize>(&self, name: &str, limit: f32) -> Result<[f32; N], Refusal> {
        let refuse = || {
            self.refuse(format!(
                "{} message field '{name}': expected an array of {N} numbers within ±{limit}",
                self.kind
            ))
        };
        let values = self
            .fields
            .get(name)
            .and_then(Value::as_array)
            .filter(|a| a.len() == N)
            .ok_or_else(refuse)?;
        let mut out = [0.0f32; N];
        for (o, v) in out.iter_mut().zip(values) {
            *o = v
                .as_f64()
                .map(|v| v as f32)
                .filter(|v| v.is_finite() && v.abs() <= limit)
                .ok_or_else(refuse)?;
        }
        Ok(out)
    }

    /// A `layout` message.
    fn layout(&self) -> Result<ClientMessage, Refusal> {
        let refuse = || {
            self.refuse(format!(
                "layout message field 'panes': expected an array of 1 to 4 different views, \
                 each {}",
                Pane::expected()
            ))
        };
        let names = self
            .fields
            .get("panes")
            .and_then(Value::as_array)
            .filter(|a| (1..=Pane::ALL.len()).contains(&a.len()))
            .ok_or_else(refuse)?;
        let mut panes = Vec::with_capacity(names.len());
        for name in names {
            let pane = name.as_str().and_then(Pane::named).ok_or_else(refuse)?;
            if panes.contains(&pane) {
                return Err(refuse());
            }
            panes.push(pane);
        }
        Ok(ClientMessage::Layout { panes })
    }

    /// A `view` message.
    fn view(&self) -> Result<ClientMessage, Refusal> {
        let id = self.whole("id")?;
        let pane = match self.fields.get("pane") {
            None => Pane::Volume,
            Some(v) => v.as_str().and_then(Pane::named).ok_or_else(|| {
                self.refuse(format!(
                    "view message field 'pane' = {v}: expected {}",
                    Pane::expected()
                ))
            })?,
        };
        let set = match self.fields.get("set") {
            None => Map::new(),
            Some(Value::Object(map)) => map.clone(),
            Some(_) => {
                return Err(
                    self.refuse("view message field 'set': expected an object of settings".into())
                );
            }
        };
        let dpr = match self.fields.get("dpr") {
            None => None,
            Some(v) => Some(
                v.as_f64()
                    .filter(|d| (DPR_RANGE.0..=DPR_RANGE.1).contains(d))
                    .ok_or_else(|| {
                        self.refuse(format!(
                            "view message field 'dpr' = {v}: expected a device pixel ratio \
                             from {} to {}",
                            DPR_RANGE.0, DPR_RANGE.1
                        ))
                    })?,
            ),
        };
        Ok(ClientMessage::View { id, pane, set, dpr })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_header_round_trips() {
        let header = FrameHeader {
            encoding: Encoding::Jpeg,
            lossless: false,
            converged: true,
            memory_limited: true,
            pending_blocks: 12,
            width: 640,
            height: 480,
            refined: 3,
            directions: 18,
            frame_id: 7,
            message_id: 1234,
            render_ms: 12.5,
            encode_ms: 3.25,
            reduction: 8.9,
            queue_ms: 0.5,
            empty_share: 0.625,
            pane: Pane::Slice(Plane::Coronal),
        };
        let mut bytes = header.to_bytes().to_vec();
        bytes.extend_from_slice(b"image");
        assert_eq!(FrameHeader::parse(&bytes), Ok(header));
        assert_eq!(
            FrameHeader::parse(&bytes[..10]),
            Err(HeaderError::Short(10))
        );
        bytes[4] = 9;
        assert_eq!(FrameHeader::parse(&bytes), Err(HeaderError::Encoding(9)));
        bytes[0] = b'X';
        let refused = FrameHeader::parse(&bytes).expect_err("bad magic");
        assert!(refused.to_string().contains("magic"), "{refused}");
    }

    #[test]
    fn messages_are_read_and_bad_ones_refused_with_the_field_named() {
        assert_eq!(
            parse_client_message(
                r#"{"type":"view","id":3,"set":{"az":30,"shading":"global","preset":null},"dpr":2}"#
            ),
            Ok(ClientMessage::View {
                id: 3,
                pane: Pane::Volume,
                set: serde_json::json!({"az": 30, "shading": "global", "preset": null})
                    .as_object()
                    .cloned()
                    .unwrap_or_default(),
                dpr: Some(2.0),
            })
        );
        assert_eq!(
            parse_client_message(r#"{"type":"ack","frame":9}"#),
            Ok(ClientMessage::Ack { frame: 9 })
        );
        assert_eq!(
            parse_client_message(r#"{"type":"status","id":4}"#),
            Ok(ClientMessage::Status { id: Some(4) })
        );
        assert_eq!(
            parse_client_message(r#"{"type":"status"}"#),
            Ok(ClientMessage::Status { id: None })
        );
        for (text, expected) in [
            ("{nope", "not JSON"),
            ("[1,2]", "expected a JSON object"),
            (r#"{"id":1}"#, "field 'type'"),
            (r#"{"type":"zoom","id":1}"#, "message type 'zoom'"),
            (
                r#"{"type":"view","id":1,"colour":"red"}"#,
                "field 'colour': unknown",
            ),
            (r#"{"type":"view","set":{}}"#, "field 'id'"),
            (r#"{"type":"view","id":-4}"#, "field 'id'"),
            (r#"{"type":"view","id":1,"set":[1]}"#, "field 'set'"),
            (r#"{"type":"view","id":1,"dpr":100}"#, "field 'dpr' = 100"),
            (r#"{"type":"ack","frame":"x"}"#, "field 'frame'"),
            (r#"{"type":"ack"}"#, "ack message field 'frame'"),
            (r#"{"type":"status","id":1.5}"#, "status message field 'id'"),
            (r#"{"type":"status","frame":1}"#, "field 'frame': unknown"),
            (
                r#"{"type":"view","id":1,"pane":"oblique"}"#,
                "field 'pane' = \"oblique\"",
            ),
            (r#"{"type":"layout","panes":[]}"#, "1 to 4 different views"),
            (
                r#"{"type":"layout","panes":["3d","3d"]}"#,
                "1 to 4 different views",
            ),
            (
                r#"{"type":"layout","panes":["3d","x"]}"#,
                "each one of 3d, axial",
            ),
            (
                r#"{"type":"probe","id":1,"at":[1,2]}"#,
                "field 'at': expected an array of 3",
            ),
            (
                r#"{"type":"probe","id":1,"at":[1,2,1e9]}"#,
                "within ±100000",
            ),
            (r#"{"type":"pick","id":1,"xy":[1,"a"]}"#, "field 'xy'"),
        ] {
            let refusal = parse_client_message(text).expect_err(text);
            assert!(
                refusal.message.contains(expected),
                "{text}: {}",
                refusal.message
            );
        }
        assert_eq!(
            parse_client_message(r#"{"type":"layout","panes":["axial","3d"]}"#),
            Ok(ClientMessage::Layout {
                panes: vec![Pane::Slice(Plane::Axial), Pane::Volume]
            })
        );
        assert_eq!(
            parse_client_message(r#"{"type":"pick","id":2,"xy":[10.5,20]}"#),
            Ok(ClientMessage::Pick {
                id: 2,
                x: 10.5,
                y: 20.0
            })
        );
        assert_eq!(
            parse_client_message(r#"{"type":"probe","id":4,"at":[1,-2,3.5]}"#),
            Ok(ClientMessage::Probe {
                id: 4,
                at: [1.0, -2.0, 3.5]
            })
        );
        assert_eq!(
            parse_client_message(r#"{"type":"view","id":5,"colour":1}"#)
                .expect_err("unknown field")
                .id,
            Some(5)
        );
    }

    #[test]
    fn replies_are_json_of_the_documented_shape() {
        let status = Reply::Status(Status {
            id: Some(3),
            view_id: 7,
            sent: 2,
            acked: 1,
            rendering: false,
            waiting: Waiting::Ack,
            converged: false,
        });
        assert_eq!(
            serde_json::from_str::<Value>(&status.to_json()).ok(),
            Some(
                serde_json::json!({"type": "status", "id": 3, "view_id": 7, "sent": 2,
                "acked": 1, "rendering": false, "waiting": "ack", "converged": false})
            )
        );
        assert_eq!(
            Reply::error(None, "no").to_json(),
            r#"{"type":"error","message":"no"}"#
        );
        assert_eq!(
            Reply::error(Some(2), "no").to_json(),
            r#"{"type":"error","id":2,"message":"no"}"#
        );
    }
}
