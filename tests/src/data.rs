//! The real datasets in `../shared/data` (beside the repository; never copied
//! into it). Tests that need them skip with a printed reason when the folder is
//! absent, unless `VOXSERVE_REQUIRE_DATA=1` (set by `.ci/run`), which makes a
//! missing folder a failure.

use std::path::PathBuf;

use crate::gpu::report_skip;

/// `../shared/data` beside the repository, or `None` (after saying why `test` is
/// skipped).
///
/// # Panics
/// When the folder is missing and `VOXSERVE_REQUIRE_DATA=1`.
pub fn shared_data(test: &str) -> Option<PathBuf> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    if dir.join("README.md").is_file() {
        return Some(dir);
    }
    if std::env::var("VOXSERVE_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!(
            "{test}: VOXSERVE_REQUIRE_DATA=1 but {} is missing",
            dir.display()
        );
    }
    report_skip(test, &format!("no shared datasets at {}", dir.display()));
    None
}
