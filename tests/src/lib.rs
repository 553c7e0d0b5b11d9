//! Helpers for voxserve's end-to-end and image tests.
//!
//! # Layout
//! - [`gpu`]: the shared [`GpuContext`] of a test binary, or a printed reason to
//!   skip; with `VOXSERVE_REQUIRE_GPU=1` (set by `.ci/run`) a missing adapter fails.
//! - [`image_compare`]: compare a rendered frame with another or with a golden PNG
//!   under a tolerance, writing `*-actual.png` and `*-diff.png` on failure.
//! - [`phantom`]: the phantom at test sizes, generated once per test binary, as a
//!   volume and as a bricked dataset.
//! - [`render`]: packed and reference renders of a dataset on the GPU and the
//!   CPU twins, set up alike.
//! - [`data`]: the real datasets in `../shared/data`, or a printed reason to skip.
//! - [`reference_data`]: those datasets as the benchmarks read them (how to
//!   open each, a transfer function that shows it): the binary's own list,
//!   compiled in here too so tests and benchmarks describe the same views.
//! - [`checks`]: facts that show a volume is really in an image (coverage,
//!   left–right symmetry, centroid).
//! - [`server`]: a real server on port 0 for end-to-end tests.
//! - [`issuer`]: an OpenID Connect issuer on port 0 that signs real tokens
//!   (RS256, ES256), rotates keys, and logs browsers in (PKCE).
//! - [`orthanc`]: a real PACS (Orthanc with DICOMweb) on a loopback port,
//!   loaded through its REST API.
//! - [`s3`]: a real S3-compatible server (`s3s-fs`) on a loopback port,
//!   which can be stopped, started again and slowed.
//! - [`nginx`]: nginx on a loopback port as the load balancer in front of
//!   render nodes, with the configuration the README documents.
//! - [`malformed`]: a generated corpus of malformed and hostile volume files,
//!   as a table of cases with the words each error must contain.

pub mod checks;
pub mod data;
pub mod gpu;
pub mod image_compare;
pub mod issuer;
pub mod malformed;
pub mod nginx;
pub mod orthanc;
pub mod phantom;
#[path = "../../server/src/bench/reference_data.rs"]
pub mod reference_data;
pub mod render;
pub mod s3;
pub mod server;

pub use gpu::{gpu_or_skip, require_gpu};
pub use image_compare::{ImageDiff, Tolerance};

use shaders::GpuContext;
