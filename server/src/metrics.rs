//! `GET /metrics`: what the server has done, in the OpenMetrics text format
//! Prometheus scrapes (through `prometheus-client`).
//!
//! | metric | meaning |
//! |---|---|
//! | `voxserve_sessions_open` | view sessions open now |
//! | `voxserve_sessions_total` | view sessions opened |
//! | `voxserve_frames_total{source,quality}` | frames sent: `source` `stream` or `http`, `quality` `interactive` or `full` |
//! | `voxserve_render_seconds` | render time per frame (histogram) |
//! | `voxserve_encode_seconds{format}` | encode time per frame, `jpeg` or `png` (histogram) |
//! | `voxserve_queue_seconds` | time a frame waited for the render worker (histogram) |
//! | `voxserve_block_cache_hits` / `_misses` | decoded-block reads served from memory / read from the store, so far |
//! | `voxserve_block_cache_bytes` | decoded blocks held in memory under the cache budget |
//! | `voxserve_store_cache_hits` / `_misses` | object-store reads answered from the disk cache (`--store-cache`) / not held there, so far |
//! | `voxserve_render_abandoned` | frames dropped unrendered (or partly rendered) because their requester had gone, so far |
//! | `voxserve_render_bands` | bands drawn of frames too costly for one turn of the render worker, so far |

use std::sync::atomic::AtomicU64;

use prometheus_client::encoding::{EncodeLabelSet, EncodeLabelValue, LabelValueEncoder};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::metrics::info::Info;
use prometheus_client::registry::Registry;

/// Where a frame went.
#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
pub enum Source {
    /// A view session.
    Stream,
    /// `GET /api/render`.
    Http,
}

/// How a frame was rendered and encoded.
#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
pub enum Quality {
    /// Smaller and lossy, while the user interacts.
    Interactive,
    /// Full size, lossless.
    Full,
}

/// The image format.
#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
pub enum Format {
    /// JPEG.
    Jpeg,
    /// PNG.
    Png,
    /// WebP (lossless).
    Webp,
}

/// Label values in lower case, as Prometheus labels are usually written.
macro_rules! label_values {
    ($($ty:ty { $($variant:ident => $text:literal),+ })+) => {$(
        impl EncodeLabelValue for $ty {
            fn encode(&self, encoder: &mut LabelValueEncoder<'_>) -> Result<(), std::fmt::Error> {
                let text = match self { $(Self::$variant => $text),+ };
                std::fmt::Write::write_str(encoder, text)
            }
        }
    )+};
}

label_values! {
    Source { Stream => "stream", Http => "http" }
    Quality { Interactive => "interactive", Full => "full" }
    Format { Jpeg => "jpeg", Png => "png", Webp => "webp" }
}

#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
struct FrameLabels {
    source: Source,
    quality: Quality,
}

#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
struct FormatLabels {
    format: Format,
}

/// The server's metrics; shared by every handler and session.
#[derive(Debug)]
pub struct Metrics {
    registry: Registry,
    sessions_open: Gauge,
    sessions_total: Counter,
    frames: Family<FrameLabels, Counter>,
    render_seconds: Histogram,
    encode_seconds: Family<FormatLabels, Histogram>,
    queue_seconds: Histogram,
    cache_hits: Gauge<u64, AtomicU64>,
    cache_misses: Gauge<u64, AtomicU64>,
    store_cache_hits: Gauge<u64, AtomicU64>,
    store_cache_misses: Gauge<u64, AtomicU64>,
    cache_bytes: Gauge<u64, AtomicU64>,
    render_abandoned: Gauge<u64, AtomicU64>,
    render_bands: Gauge<u64, AtomicU64>,
}

impl Default for Metrics {
    fn default() -> Metrics {
        // 0.5 ms to about 33 s.
        let seconds = || Histogram::new(exponential_buckets(0.0005, 2.0, 17));
        let mut m = Metrics {
            registry: Registry::with_prefix("voxserve"),
            sessions_open: Gauge::default(),
            sessions_total: Counter::default(),
            frames: Family::default(),
            render_seconds: seconds(),
            encode_seconds: Family::new_with_constructor(|| {
                Histogram::new(exponential_buckets(0.0005, 2.0, 17))
            }),
            queue_seconds: seconds(),
            cache_hits: Gauge::default(),
            cache_misses: Gauge::default(),
            store_cache_hits: Gauge::default(),
            store_cache_misses: Gauge::default(),
            cache_bytes: Gauge::default(),
            render_abandoned: Gauge::default(),
            render_bands: Gauge::default(),
        };
        let r = &mut m.registry;
        r.register(
            "sessions_open",
            "View sessions open now",
            m.sessions_open.clone(),
        );
        r.register("sessions", "View sessions opened", m.sessions_total.clone());
        r.register("frames", "Frames sent", m.frames.clone());
        r.register(
            "render_seconds",
            "Render time per frame",
            m.render_seconds.clone(),
        );
        r.register(
            "encode_seconds",
            "Encode time per frame",
            m.encode_seconds.clone(),
        );
        r.register(
            "queue_seconds",
            "Time a frame waited for the render worker",
            m.queue_seconds.clone(),
        );
        r.register(
            "block_cache_hits",
            "Decoded-block reads served from memory so far",
            m.cache_hits.clone(),
        );
        r.register(
            "block_cache_misses",
            "Decoded-block reads that read the store so far",
            m.cache_misses.clone(),
        );
        r.register(
            "store_cache_hits",
            "Object-store reads answered from the disk cache so far",
            m.store_cache_hits.clone(),
        );
        r.register(
            "store_cache_misses",
            "Object-store reads the disk cache did not hold so far",
            m.store_cache_misses.clone(),
        );
        r.register(
            "block_cache_bytes",
            "Decoded blocks held in memory under the cache budget",
            m.cache_bytes.clone(),
        );
        r.register(
            "render_abandoned",
            "Frames dropped unrendered or partly rendered because their requester had gone, so far",
            m.render_abandoned.clone(),
        );
        r.register(
            "render_bands",
            "Bands drawn of frames too costly for one turn of the render worker, so far",
            m.render_bands.clone(),
        );
        m
    }
}

impl Metrics {
    /// Records which renderer serves (`gpu` or `cpu`) and on what, as
    /// `voxserve_renderer_info{kind,device}`.
    pub fn set_renderer(&mut self, kind: &str, device: &str) {
        let labels = vec![
            ("kind".to_owned(), kind.to_owned()),
            ("device".to_owned(), device.to_owned()),
        ];
        self.registry.register(
            "renderer",
            "Which renderer serves frames",
            Info::new(labels),
        );
    }

    /// A session opened.
    pub fn session_opened(&self) {
        self.sessions_total.inc();
    }

    /// A frame was sent: where, how, and what it took (milliseconds).
    pub fn frame(&self, source: Source, quality: Quality, format: Format, times: FrameTimes) {
        self.frames
            .get_or_create(&FrameLabels { source, quality })
            .inc();
        self.render_seconds.observe(times.render_ms / 1e3);
        self.queue_seconds.observe(times.queue_ms / 1e3);
        self.encode_seconds
            .get_or_create(&FormatLabels { format })
            .observe(times.encode_ms / 1e3);
    }

    /// The OpenMetrics text, with the gauges read now: `sessions_open`
    /// sessions, the render worker's counts and the block caches' counts,
    /// summed over `caches`.
    pub fn encode<'a>(
        &self,
        sessions_open: usize,
        renderer: &crate::RenderService,
        caches: impl Iterator<Item = &'a blocks::cache::BlockCache>,
    ) -> String {
        self.render_abandoned.set(renderer.abandoned());
        self.render_bands.set(renderer.bands());
        self.sessions_open
            .set(i64::try_from(sessions_open).unwrap_or(i64::MAX));
        let (mut hits, mut misses, mut bytes) = (0, 0, 0);
        for cache in caches {
            hits += cache.hits();
            misses += cache.misses();
            bytes += cache.cached_bytes();
        }
        self.cache_hits.set(hits);
        self.cache_misses.set(misses);
        self.cache_bytes.set(bytes);
        if let Some(disk) = blocks::store::disk_cache::get() {
            self.store_cache_hits.set(disk.hits());
            self.store_cache_misses.set(disk.misses());
        }
        let mut text = String::new();
        if let Err(e) = prometheus_client::encoding::text::encode(&mut text, &self.registry) {
            tracing::error!("encoding the metrics failed: {e}");
        }
        text
    }
}

/// What one frame took, milliseconds.
#[derive(Debug, Clone, Copy)]
pub struct FrameTimes {
    /// Rendering.
    pub render_ms: f64,
    /// Waiting for the render worker.
    pub queue_ms: f64,
    /// Encoding.
    pub encode_ms: f64,
}
