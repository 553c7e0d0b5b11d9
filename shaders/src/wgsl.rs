//! The WGSL source of each stage: shared files first, then the stage's own file.
//! WGSL has no include directive; concatenation at compile time stands in for it,
//! and each stage takes only the shared files whose bindings it declares.

/// The shared files of the ray-marching stages, then `$stage` and `$more`.
macro_rules! march_stage {
    ($($file:literal),+) => {
        concat!(
            include_str!("../wgsl/shared/raycast_params.wgsl"),
            "\n",
            include_str!("../wgsl/shared/hash.wgsl"),
            "\n",
            include_str!("../wgsl/shared/ray.wgsl"),
            "\n",
            include_str!("../wgsl/shared/transfer_function.wgsl"),
            "\n",
            include_str!("../wgsl/shared/march.wgsl"),
            $("\n", include_str!($file),)+
        )
    };
}

/// The shared files of the light stages, then the listed ones.
macro_rules! light_stage {
    ($($file:literal),+) => {
        concat!(
            include_str!("../wgsl/shared/light_params.wgsl"),
            "\n",
            include_str!("../wgsl/shared/ray.wgsl"),
            "\n",
            include_str!("../wgsl/shared/blocks.wgsl"),
            "\n",
            include_str!("../wgsl/shared/light.wgsl"),
            $("\n", include_str!($file),)+
        )
    };
}

/// The `raycast` stage over packed blocks, unlit (`shaders/wgsl/raycast.wgsl`).
pub const RAYCAST: &str = march_stage!(
    "../wgsl/shared/blocks.wgsl",
    "../wgsl/shared/packed.wgsl",
    "../wgsl/raycast.wgsl",
    "../wgsl/shared/no_light.wgsl"
);

/// The `raycast` stage lit by a light volume (`shaders/wgsl/raycast.wgsl` with
/// `shared/light_volume.wgsl`).
pub const RAYCAST_LIT: &str = march_stage!(
    "../wgsl/shared/blocks.wgsl",
    "../wgsl/shared/packed.wgsl",
    "../wgsl/raycast.wgsl",
    "../wgsl/shared/light_volume.wgsl"
);

/// The `reference` stage over one plain texture (`shaders/wgsl/reference.wgsl`).
pub const REFERENCE: &str = march_stage!("../wgsl/reference.wgsl");

/// The `local_opacity` stage (`shaders/wgsl/local_opacity.wgsl`).
pub const LOCAL_OPACITY: &str = light_stage!(
    "../wgsl/shared/transfer_function.wgsl",
    "../wgsl/shared/packed.wgsl",
    "../wgsl/shared/light_data.wgsl",
    "../wgsl/shared/slot.wgsl",
    "../wgsl/shared/light_opacity.wgsl",
    "../wgsl/local_opacity.wgsl"
);

/// The `global_opacity` stage (`shaders/wgsl/global_opacity.wgsl`).
pub const GLOBAL_OPACITY: &str =
    light_stage!("../wgsl/shared/packed.wgsl", "../wgsl/global_opacity.wgsl");

/// The `direct_light` stage (`shaders/wgsl/direct_light.wgsl`).
pub const DIRECT_LIGHT: &str =
    light_stage!("../wgsl/shared/slot.wgsl", "../wgsl/direct_light.wgsl");

/// The `in_scatter` stage (`shaders/wgsl/in_scatter.wgsl`).
pub const IN_SCATTER: &str = light_stage!(
    "../wgsl/shared/transfer_function.wgsl",
    "../wgsl/shared/packed.wgsl",
    "../wgsl/shared/light_data.wgsl",
    "../wgsl/shared/slot.wgsl",
    "../wgsl/shared/light_opacity.wgsl",
    "../wgsl/in_scatter.wgsl"
);

/// The `direct_light_reference` stage (`shaders/wgsl/direct_light_reference.wgsl`).
pub const DIRECT_LIGHT_REFERENCE: &str = light_stage!(
    "../wgsl/shared/transfer_function.wgsl",
    "../wgsl/shared/packed.wgsl",
    "../wgsl/shared/light_data.wgsl",
    "../wgsl/shared/slot.wgsl",
    "../wgsl/shared/light_opacity.wgsl",
    "../wgsl/direct_light_reference.wgsl"
);

#[cfg(test)]
mod tests {
    #[test]
    fn every_stage_parses_and_validates() {
        for (name, source) in [
            ("raycast", super::RAYCAST),
            ("raycast lit", super::RAYCAST_LIT),
            ("reference", super::REFERENCE),
            ("local_opacity", super::LOCAL_OPACITY),
            ("global_opacity", super::GLOBAL_OPACITY),
            ("direct_light", super::DIRECT_LIGHT),
            ("in_scatter", super::IN_SCATTER),
            ("direct_light_reference", super::DIRECT_LIGHT_REFERENCE),
        ] {
            let module = naga::front::wgsl::parse_str(source)
                .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("{name}: {e:?}"));
        }
    }
}
