//! The WGSL source of each stage: shared files first, then the stage's own file.
//! WGSL has no include directive; concatenation at compile time stands in for it,
//! and each stage takes only the shared files whose bindings it declares.

/// The shared files of the ray-marching stages, then `$stage` and `$more`.
macro_rules! march_stage {
    ($($file:literal),+) => {
        concat!(
            include_str!("../wgsl/shared/packed_volume.wgsl"),
            "\n",
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
            include_str!("../wgsl/shared/packed_volume.wgsl"),
            "\n",
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

/// The `raycast` stage lit by the light cache of extinction-based illumination
/// (`shaders/wgsl/raycast.wgsl` with `shared/light_cache.wgsl`).
pub const RAYCAST_EXTINCTION: &str = march_stage!(
    "../wgsl/shared/blocks.wgsl",
    "../wgsl/shared/packed.wgsl",
    "../wgsl/raycast.wgsl",
    "../wgsl/shared/light_cache.wgsl"
);

/// The shared files of the extinction-based illumination stages, then the listed ones.
macro_rules! extinction_stage {
    ($($file:literal),+) => {
        concat!(
            include_str!("../wgsl/shared/packed_volume.wgsl"),
            "\n",
            include_str!("../wgsl/shared/extinction_params.wgsl"),
            $("\n", include_str!($file),)+
        )
    };
}

/// The `extinction_sat` stage, entry points `reconstruct` and `scan`
/// (`shaders/wgsl/extinction_sat.wgsl`).
pub const EXTINCTION_SAT: &str = extinction_stage!(
    "../wgsl/shared/ray.wgsl",
    "../wgsl/shared/blocks.wgsl",
    "../wgsl/shared/transfer_function.wgsl",
    "../wgsl/shared/packed.wgsl",
    "../wgsl/extinction_sat.wgsl",
    "../wgsl/shared/sat.wgsl"
);

/// The `ambient_occlusion` stage (`shaders/wgsl/ambient_occlusion.wgsl`).
pub const AMBIENT_OCCLUSION: &str = extinction_stage!(
    "../wgsl/shared/blocks.wgsl",
    "../wgsl/shared/near_cells.wgsl",
    "../wgsl/ambient_occlusion.wgsl",
    "../wgsl/shared/sat.wgsl"
);

/// The `ambient_occlusion_reference` stage
/// (`shaders/wgsl/ambient_occlusion_reference.wgsl`).
pub const AMBIENT_OCCLUSION_REFERENCE: &str = extinction_stage!(
    "../wgsl/shared/blocks.wgsl",
    "../wgsl/shared/near_cells.wgsl",
    "../wgsl/ambient_occlusion_reference.wgsl"
);

/// The `soft_shadow` stage (`shaders/wgsl/soft_shadow.wgsl`).
pub const SOFT_SHADOW: &str = extinction_stage!(
    "../wgsl/shared/blocks.wgsl",
    "../wgsl/shared/near_cells.wgsl",
    "../wgsl/shared/extinction_light.wgsl",
    "../wgsl/soft_shadow.wgsl",
    "../wgsl/shared/sat.wgsl",
    "../wgsl/shared/light_cache_fill.wgsl"
);

/// The `shadow_ray` stage (`shaders/wgsl/shadow_ray.wgsl`).
pub const SHADOW_RAY: &str = extinction_stage!(
    "../wgsl/shared/blocks.wgsl",
    "../wgsl/shared/near_cells.wgsl",
    "../wgsl/shared/extinction_light.wgsl",
    "../wgsl/shadow_ray.wgsl",
    "../wgsl/shared/light_cache_fill.wgsl"
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

/// The `light_seams` stage (`shaders/wgsl/light_seams.wgsl`).
pub const LIGHT_SEAMS: &str = light_stage!("../wgsl/light_seams.wgsl");

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
            ("light_seams", super::LIGHT_SEAMS),
            ("direct_light_reference", super::DIRECT_LIGHT_REFERENCE),
            ("raycast extinction", super::RAYCAST_EXTINCTION),
            ("extinction_sat", super::EXTINCTION_SAT),
            ("ambient_occlusion", super::AMBIENT_OCCLUSION),
            (
                "ambient_occlusion_reference",
                super::AMBIENT_OCCLUSION_REFERENCE,
            ),
            ("soft_shadow", super::SOFT_SHADOW),
            ("shadow_ray", super::SHADOW_RAY),
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
