//! The GPU harness: one [`GpuContext`] per test binary, created on first use.
//!
//! Without an adapter a GPU test prints why and returns early (the test passes,
//! and the output says it was skipped), unless `VOXSERVE_REQUIRE_GPU=1`: then a
//! missing adapter fails the test, so CI cannot go green without exercising the GPU.

use std::sync::OnceLock;

use crate::GpuContext;

/// Whether the environment demands a GPU (`VOXSERVE_REQUIRE_GPU=1`).
pub fn require_gpu() -> bool {
    std::env::var("VOXSERVE_REQUIRE_GPU").is_ok_and(|v| v == "1")
}

/// The test binary's GPU, or `None` after printing why `test` is skipped.
///
/// # Panics
/// When no adapter exists and `VOXSERVE_REQUIRE_GPU=1`.
pub fn gpu_or_skip(test: &str) -> Option<&'static GpuContext> {
    static GPU: OnceLock<Result<GpuContext, String>> = OnceLock::new();
    match GPU.get_or_init(|| GpuContext::new().map_err(|e| e.to_string())) {
        Ok(gpu) => Some(gpu),
        Err(reason) if require_gpu() => {
            panic!("{test}: VOXSERVE_REQUIRE_GPU=1 but there is no usable GPU: {reason}")
        }
        Err(reason) => {
            report_skip(test, &format!("no GPU adapter: {reason}"));
            None
        }
    }
}

/// Says on the terminal that `test` was skipped and why. Written to stderr
/// directly, not through `eprintln!`, which the test harness captures and hides
/// for passing tests: a skip must be visible in every test log.
pub fn report_skip(test: &str, reason: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "SKIPPED {test}: {reason}");
}
