//! The WGSL source of each stage: shared files first, then the stage's own file.
//! WGSL has no include directive; concatenation at compile time stands in for it.

/// A ray-marching stage: the shared uniforms, hash and march, then `$stage`.
macro_rules! march_stage {
    ($stage:literal) => {
        concat!(
            include_str!("../wgsl/shared/raycast_params.wgsl"),
            "\n",
            include_str!("../wgsl/shared/hash.wgsl"),
            "\n",
            include_str!("../wgsl/shared/march.wgsl"),
            "\n",
            include_str!($stage),
        )
    };
}

/// The `raycast` stage over packed blocks (`shaders/wgsl/raycast.wgsl`).
pub const RAYCAST: &str = march_stage!("../wgsl/raycast.wgsl");

/// The `reference` stage over one plain texture (`shaders/wgsl/reference.wgsl`).
pub const REFERENCE: &str = march_stage!("../wgsl/reference.wgsl");
