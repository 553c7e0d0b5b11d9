//! Studies from a PACS over DICOMweb: search with QIDO-RS, read a series'
//! metadata and retrieve its instances with WADO-RS, and brick the series
//! into a store that equals the one made from the same files on disk.
//!
//! # Layout
//! - [`endpoint`]: [`Endpoint`], a configured PACS (`--pacs NAME=URL`, its
//!   authorization from `--pacs-auth NAME=FILE`), and [`Endpoints`], the set.
//! - [`query`]: [`StudyQuery`], the QIDO-RS search keys, checked.
//! - [`dicomweb`]: [`DicomWeb`], the client: QIDO-RS searches, WADO-RS
//!   series metadata and instances (multipart, any transfer syntax),
//!   bounded sizes, timeouts and retries; [`PacsError`].
//! - [`fetch`]: [`fetch::fetch_series`], a series' instances into a spool
//!   folder with bounded concurrency, then read by the DICOM folder reader
//!   (the same grouping, sorting and geometry checks as files on disk).

pub mod dicomweb;
pub mod endpoint;
pub mod fetch;
pub mod query;

pub use dicomweb::{DicomWeb, InstanceRecord, PacsError, SeriesRecord, StudyRecord};
pub use endpoint::{Endpoint, Endpoints};
pub use query::{DateRange, StudyQuery};
