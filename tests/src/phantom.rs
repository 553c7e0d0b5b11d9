//! The phantom at the sizes tests use, generated once per test binary.

use std::sync::OnceLock;

use blocks::Volume;

/// The edge length GPU tests use: 64³ keeps a software frame well under a second.
pub const TEST_SIZE: u32 = 64;

/// The head phantom at [`TEST_SIZE`]³.
pub fn phantom_64() -> &'static Volume {
    static PHANTOM: OnceLock<Volume> = OnceLock::new();
    PHANTOM
        .get_or_init(|| blocks::phantom::head(TEST_SIZE).unwrap_or_else(|e| panic!("phantom: {e}")))
}
