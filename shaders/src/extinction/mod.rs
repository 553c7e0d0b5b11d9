//! Extinction-based illumination (Schlegel, Makhinya, Pajarola 2011): ambient
//! occlusion, colour bleeding and cone soft shadows from a 3D summed-area
//! table (SAT) of extinction coefficients, computed on a regular grid over the
//! volume reconstructed from the packed blocks: one illumination mode
//! ([`crate::illumination::Mode::Extinction`]).
//!
//! Its [`Stage`]s, in the order they run, each a WGSL compute shader with a
//! CPU twin of the same name in [`crate::cpu::extinction`]:
//! - `extinction_sat`: Δt·τ per grid cell from the packed blocks (empty blocks
//!   read nothing), then the SAT by three in-place prefix scans (x, y, z), with
//!   Δt·τ·RGB in the same passes for colour bleeding; 64-bit fixed-point sums
//!   keep every cuboid query exact (see the shader's header);
//! - `ambient_occlusion`: I_AO (eq. 4) and I_AO_RGB (eq. 5) from cuboid shells
//!   weighted by 1/r² (fig. 5), or with `ao_method=sampled` its reference
//!   `ambient_occlusion_reference` (explicit sampling of the sphere);
//! - `soft_shadow`: per light, the cone towards it as cuboid queries along the
//!   main axis (eq. 7, fig. 7), summed with ambient light into the light
//!   cache, or with `shadow_method=ray` its reference `shadow_ray` (one
//!   classic shadow ray per light).
//!
//! The ray caster reads the light cache with one lookup per sample.
//!
//! # Layout
//! - [`settings`](mod@settings): [`ExtinctionSettings`], each setting with the
//!   stage its change recomputes from; [`ExtinctionLight`].
//! - [`params`]: [`ExtinctionParams`], the stages' uniforms, the grid and
//!   the ambient-occlusion shells.
//! - [`pipelines`]: [`ExtinctionPipelines`], the compiled stages.
//! - [`resources`]: [`ExtinctionVolumes`], the SAT and textures.
//! - [`update`]: [`Extinction`], the GPU state and its update policy
//!   (algorithm 1).

pub mod params;
pub mod pipelines;
pub mod resources;
pub mod settings;
pub mod update;

pub use params::{
    AoShells, ExtinctionParams, LIGHT_READ_CELLS, LightUniform, cell_mm, grid_dims,
    near_cells_mask, scan_workgroups, sphere_norm,
};
pub use pipelines::ExtinctionPipelines;
pub use resources::ExtinctionVolumes;
pub use settings::{
    AoMethod, ExtinctionLight, ExtinctionLightKind, ExtinctionSettings, MAX_AO_SHELLS, MAX_LIGHTS,
    ShadowMethod,
};
pub use update::{Extinction, ExtinctionTimings};

/// Samples per grid side of the reference shadow ray (the paper's 250 per unit).
pub const SHADOW_RAY_SAMPLES: f32 = 250.0;
/// Fixed-point scale of SAT cells: one unit of Δt·τ.
pub const FIXED_ONE: f32 = 16_777_216.0;
/// The largest Δt·τ a cell holds (an opaque cell passes e^−4 ≈ 2 % of the light).
pub const MAX_CELL_DEPTH: f32 = 4.0;
/// The most cuboids per cone.
pub const MAX_CONE_CUBOIDS: u32 = 256;
/// The light cache's and ambient term's texel format.
pub const CACHE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// The extinction texture's texel format (Δt·τ per cell).
pub const EXTINCTION_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
/// Invocations per workgroup along each axis of the scan (per line).
pub const SCAN_WORKGROUP_EDGE: u32 = 8;

/// The stages of extinction-based illumination, in the order they run (the
/// paper's algorithm 1): a change of a setting recomputes from the stage it
/// `affects` on. The GPU path, the CPU twin
/// ([`crate::cpu::extinction::compute_extinction`]) and the tests run this list.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// The SAT of Δt·τ (and Δt·τ·RGB), and Δt·τ per cell.
    ExtinctionSat,
    /// I_AO and I_AO_RGB (eqs. 4, 5).
    AmbientOcclusion,
    /// The light cache: ambient light and every light through its cone (eq. 7).
    SoftShadow,
}

impl Stage {
    /// Every stage, in the order they run.
    pub const ALL: [Stage; 3] = [
        Stage::ExtinctionSat,
        Stage::AmbientOcclusion,
        Stage::SoftShadow,
    ];

    /// Their names, in the same order (what settings say they affect).
    pub const NAMES: [&'static str; 3] = ["extinction_sat", "ambient_occlusion", "soft_shadow"];

    /// The stage's name.
    pub fn name(self) -> &'static str {
        Stage::NAMES[self as usize]
    }

    /// The WGSL stage it runs by `settings`' methods (the references).
    pub fn shader(self, settings: &ExtinctionSettings) -> &'static str {
        match (self, settings.ao_method, settings.shadow_method) {
            (Stage::AmbientOcclusion, AoMethod::Sampled, _) => "ambient_occlusion_reference",
            (Stage::SoftShadow, _, ShadowMethod::Ray) => "shadow_ray",
            _ => self.name(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shells_grow_by_at_least_one_cell_to_the_sphere_volume() {
        for radius in 1..=32 {
            for shells in 1..=radius.min(MAX_AO_SHELLS) {
                let s = AoShells::new(radius, shells);
                let r = &s.radii;
                assert_eq!(r.len(), shells as usize);
                assert!(r[0] >= 1);
                assert!(r.windows(2).all(|w| w[1] > w[0]), "{r:?}");
                // The outer cube holds about the sphere's volume.
                let last = f64::from(*r.last().unwrap_or(&0));
                if shells * 2 <= radius {
                    assert!(
                        (last - 0.806 * f64::from(radius)).abs() <= 1.0,
                        "R {radius} N {shells}: {r:?}"
                    );
                }
                // Weights fall with distance.
                assert!(s.weights.windows(2).all(|w| w[1] < w[0]), "{:?}", s.weights);
            }
        }
    }

    #[test]
    fn the_norms_count_every_neighbour_once() {
        // One shell of half-edge 1: 6 faces at 1, 12 edges at ½, 8 corners at ⅓.
        let one = AoShells::new(1, 1);
        assert_eq!(one.radii, [1]);
        assert!((one.norm - (6.0 + 6.0 + 8.0 / 3.0)).abs() < 1e-5);
        assert!((one.weights[0] * 26.0 - one.norm).abs() < 1e-5);
        // Radius 1 sphere: 6 neighbours at distance 1.
        assert_eq!(sphere_norm(1), 6.0);
    }

    #[test]
    fn lights_parse_print_and_refuse_bad_fields() {
        use crate::settings::TextSetting;
        type Lights = Vec<ExtinctionLight>;
        let lights =
            Lights::parse_text("point:0.5,0.5,1.2;spot:0,0,0:1,1,1:30:ff8000:2").expect("valid");
        assert_eq!(lights.len(), 2);
        assert_eq!(lights[0].colour, [1.0; 3]);
        assert_eq!(lights[1].intensity, 2.0);
        assert_eq!(Lights::parse_text(&lights.text()), Ok(lights));
        for (text, field) in [
            ("lamp:1,2,3", "unknown kind"),
            ("point:1,2", "three numbers"),
            ("point:0,0,0:zz0000", "zz0000"),
            ("point:0,0,0:ffffff:99", "intensity"),
            ("spot:0,0,0:0,0,0:30", "direction"),
            ("spot:0,0,0:0,0,1:120", "angle"),
            ("directional:nan,0,1", "three numbers"),
        ] {
            let e = Lights::parse_text(text).expect_err(text);
            assert!(e.0.contains(field), "{text}: {e}");
        }
        let five = ["point:0,0,0"; 5].join(";");
        assert!(
            Lights::parse_text(&five)
                .expect_err("five")
                .0
                .contains("at most 4")
        );
    }

    #[test]
    fn settings_are_checked_field_by_field() {
        let ok = ExtinctionSettings::default();
        assert_eq!(ok.validate(), Ok(()));
        let cases: Vec<(ExtinctionSettings, &str)> = vec![
            (
                ExtinctionSettings {
                    sat_size: 8,
                    ..ok.clone()
                },
                "sat_size=8",
            ),
            (
                ExtinctionSettings {
                    ao_shells: 9,
                    ..ok.clone()
                },
                "ao_shells=9",
            ),
            (
                ExtinctionSettings {
                    ao_radius: 0,
                    ..ok.clone()
                },
                "ao_radius=0",
            ),
            (
                ExtinctionSettings {
                    cone_angle: f32::NAN,
                    ..ok.clone()
                },
                "cone_angle",
            ),
            (
                ExtinctionSettings {
                    cone_frequency: 0.0,
                    ..ok.clone()
                },
                "cone_frequency=0",
            ),
            (
                ExtinctionSettings {
                    cone_growth: 2.0,
                    ..ok.clone()
                },
                "cone_growth=2",
            ),
            (
                ExtinctionSettings {
                    ambient: -1.0,
                    ..ok.clone()
                },
                "ambient=-1",
            ),
            (
                ExtinctionSettings {
                    ao_method: AoMethod::Sampled,
                    colour_bleeding: true,
                    ..ok.clone()
                },
                "grey only",
            ),
        ];
        for (settings, field) in cases {
            let e = settings.validate().expect_err(field).to_string();
            assert!(e.contains(field), "{field}: {e}");
        }
    }
}
