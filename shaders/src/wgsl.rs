//! The WGSL source of each stage: shared files first, then the stage's own file.
//! WGSL has no include directive; concatenation at compile time stands in for it.

/// The `raycast` stage (`shaders/wgsl/raycast.wgsl`).
pub const RAYCAST: &str = concat!(
    include_str!("../wgsl/shared/raycast_params.wgsl"),
    "\n",
    include_str!("../wgsl/shared/hash.wgsl"),
    "\n",
    include_str!("../wgsl/raycast.wgsl"),
);
