//! Global light propagation with local piecewise integration and first-order
//! scattering (Hernell, Ljung, Ynnerman 2008), computed in the packed block
//! coordinates of the multiresolution structure: one illumination mode
//! ([`crate::illumination::Mode::GlobalLight`]).
//!
//! Its [`Stage`]s, in the order they run, each a WGSL compute shader with a
//! CPU twin of the same name in [`crate::cpu::global_light`]:
//! - `local_opacity`: α_lp (eq. 6), per stored voxel, atlas-shaped;
//! - `global_opacity`: α_g (eq. 7), the shadow volume representation (SVR), a
//!   regular grid at 1:1 … 1:8 of the volume's resolution;
//! - `direct_light`: I_d (eq. 8), per stored voxel (or, with
//!   `light_method=reference`, `direct_light_reference`: every stored voxel
//!   marched to the light at full step, what the piecewise method is
//!   measured against);
//! - `in_scatter`: I_s (eqs. 10, 11), one direction per refinement, blended
//!   into the light volume (eq. 13), then `light_seams` ([`SEAM_PASSES`]):
//!   the aprons of blocks beside coarser ones take the coarser block's light
//!   on their border, so level borders show no step in the light.
//!
//! The ray caster reads the light volume with one extra lookup per sample
//! (eq. 12).
//!
//! # Layout
//! - [`settings`](mod@settings): [`LightSettings`], each setting with the
//!   stage its change recomputes from; [`LightSource`].
//! - [`params`]: [`LightParams`], the stages' uniforms.
//! - [`directions`]: the in-scattering directions and their weights.
//! - [`pipelines`]: [`LightPipelines`], the compiled stages.
//! - [`resources`]: [`LightVolumes`], the textures and buffers.
//! - [`update`]: [`GlobalLight`], the GPU state and its update policy.

pub mod directions;
pub mod params;
pub mod pipelines;
pub mod resources;
pub mod settings;
pub mod update;

pub use directions::{ScatterDirection, scatter_directions, subdivided_octahedron};
pub use params::{LightParams, LightSetup, svr_dims};
pub use pipelines::LightPipelines;
pub use resources::LightVolumes;
pub use settings::{
    DirectLightMethod, LightSettings, LightSource, MAX_DIRECTIONS, MAX_INTENSITY,
    MAX_LIGHT_DISTANCE,
};
pub(crate) use settings::{check_direction, check_position, parse_vec3};
pub use update::{GlobalLight, LightTimings};

/// The light volumes' texel format: one f32 per texel.
pub const LIGHT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;

/// The stages of global light propagation, in the order they run: a change
/// of a setting recomputes from the stage it `affects` on; `in_scatter` is
/// then refined one direction per frame. The GPU path, the CPU twin
/// ([`crate::cpu::global_light::compute_light`]) and the tests run this list.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// α_lp (eq. 6).
    LocalOpacity,
    /// α_g, the SVR (eq. 7).
    GlobalOpacity,
    /// I_d (eq. 8).
    DirectLight,
    /// I_s (eqs. 10, 11, 13).
    InScatter,
}

impl Stage {
    /// Every stage, in the order they run.
    pub const ALL: [Stage; 4] = [
        Stage::LocalOpacity,
        Stage::GlobalOpacity,
        Stage::DirectLight,
        Stage::InScatter,
    ];

    /// Their names, in the same order (what settings say they affect).
    pub const NAMES: [&'static str; 4] = [
        "local_opacity",
        "global_opacity",
        "direct_light",
        "in_scatter",
    ];

    /// The stage's name.
    pub fn name(self) -> &'static str {
        Stage::NAMES[self as usize]
    }

    /// The WGSL stage it runs under `method` (the direct light has a reference).
    pub fn shader(self, method: DirectLightMethod) -> &'static str {
        match (self, method) {
            (Stage::DirectLight, DirectLightMethod::Reference) => "direct_light_reference",
            _ => self.name(),
        }
    }
}

/// The passes of `light_seams` (`shaders/wgsl/light_seams.wgsl`) in the
/// order they run after every in-scattering step, as (level, outward): the
/// levels coarsest first, so the coarser slots a pass reads are final (level
/// 4 has no coarser neighbour), and per level the texels outside their block
/// along 1, 2, then 3 axes (faces, edges, corners), since each blends texels
/// the earlier ones set. The GPU update and the CPU twin run this list.
pub const SEAM_PASSES: [(u32, u32); 12] = [
    (3, 1),
    (3, 2),
    (3, 3),
    (2, 1),
    (2, 2),
    (2, 3),
    (1, 1),
    (1, 2),
    (1, 3),
    (0, 1),
    (0, 2),
    (0, 3),
];

/// The passes of [`SEAM_PASSES`] with work to do for blocks shown at levels
/// `lod` (per block of a grid of `grid`, x fastest; [`blocks::lod::EMPTY`]
/// where none is shown), in order: those of the levels that hold a block with
/// a neighbour shown coarser. The others would change no texel (at 1:1, none
/// has any), so both implementations leave them out.
pub fn seam_passes(lod: &[u8], grid: [u32; 3]) -> Vec<(u32, u32)> {
    let mut beside_coarser = [false; blocks::store::LEVELS];
    for (b, &level) in lod.iter().enumerate() {
        let Some(found) = beside_coarser.get_mut(usize::from(level)) else {
            continue;
        };
        if *found {
            continue;
        }
        let block = blocks::store::grid_position(grid, b);
        let around = blocks::seams::neighbourhood(lod, grid, block);
        *found = around
            .iter()
            .any(|&n| n > level && usize::from(n) < blocks::store::LEVELS);
    }
    SEAM_PASSES
        .into_iter()
        .filter(|&(level, _)| beside_coarser[level as usize])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn seam_passes_run_only_for_levels_beside_a_coarser_block() {
        let grid = [3, 1, 1];
        assert!(
            seam_passes(&[0, 0, 0], grid).is_empty(),
            "one level: no seams"
        );
        let empty = blocks::lod::EMPTY;
        assert!(
            seam_passes(&[0, empty, 2], grid).is_empty(),
            "not neighbours"
        );
        let passes = seam_passes(&[0, 2, 3], grid);
        assert_eq!(
            passes,
            SEAM_PASSES
                .into_iter()
                .filter(|&(l, _)| l == 2 || l == 0)
                .collect::<Vec<_>>(),
            "level 2 beside 3 and level 0 beside 2, in SEAM_PASSES' order"
        );
    }

    #[test]
    fn near_blocks_mark_exactly_the_blocks_within_the_margin_of_a_kept_one() {
        use crate::illumination::near_blocks;
        use blocks::packing::Packing;
        use blocks::store::LEVELS;
        let grid = [7u32, 5, 4];
        let n = (grid[0] * grid[1] * grid[2]) as usize;
        let mut lod = vec![blocks::lod::EMPTY; n];
        let kept = [(1u32, 1u32, 0u32), (6, 4, 3)];
        for &(x, y, z) in &kept {
            lod[(x + grid[0] * (y + grid[1] * z)) as usize] = 0;
        }
        let packing = Packing {
            atlas_dims: [18; 3],
            regions: [blocks::packing::Region {
                z0: 0,
                slots: [0; 3],
            }; LEVELS],
            lod,
            slot: vec![0; n],
        };
        for margin in 0..4u32 {
            let mask = near_blocks(&packing, grid, margin);
            for z in 0..grid[2] {
                for y in 0..grid[1] {
                    for x in 0..grid[0] {
                        let near = kept.iter().any(|&(kx, ky, kz)| {
                            kx.abs_diff(x) <= margin
                                && ky.abs_diff(y) <= margin
                                && kz.abs_diff(z) <= margin
                        });
                        let got = mask[(x + grid[0] * (y + grid[1] * z)) as usize];
                        assert_eq!(
                            got,
                            u32::from(near),
                            "margin {margin}, block ({x}, {y}, {z})"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn octahedron_subdivisions_have_the_known_vertex_counts_on_the_sphere() {
        for (level, count) in [(0, 6), (1, 18), (2, 66), (3, 258)] {
            let v = subdivided_octahedron(level);
            assert_eq!(v.len(), count);
            assert!(v.iter().all(|p| (p.length() - 1.0).abs() < 1e-5));
        }
    }

    #[test]
    fn scattering_starts_at_the_light_and_spreads_with_weights_that_blend_to_a_mean() {
        let to_light = Vec3::new(0.3, -0.5, 0.8);
        let d = scatter_directions(18, 0.0, to_light);
        assert_eq!(d.len(), 18);
        assert!(d[0].to_light && !d[1].to_light);
        assert!((Vec3::from(d[0].towards) - to_light.normalize()).length() < 1e-5);
        // The second direction is the farthest from the light's: opposite it.
        assert!(Vec3::from(d[1].towards).dot(to_light.normalize()) < -0.99);
        // Isotropic: blend = 1/j (eq. 13).
        for (j, s) in d.iter().enumerate() {
            assert!((s.blend - 1.0 / (j + 1) as f32).abs() < 1e-6);
        }
        // Forward scattering weighs directions near the light's more.
        let f = scatter_directions(6, 0.6, to_light);
        assert!(f[0].weight > f[2].weight && f[2].weight > f[1].weight);
        assert_eq!(scatter_directions(1, 0.0, to_light).len(), 1);
        assert_eq!(scatter_directions(7, 0.0, to_light).len(), 7);
    }

    #[test]
    fn settings_are_checked_field_by_field() {
        use crate::settings::Settings;
        assert!(LightSettings::default().validate_fields().is_ok());
        let bad = [
            (
                LightSettings {
                    segment_voxels: 2,
                    ..Default::default()
                },
                "segment=2",
            ),
            (
                LightSettings {
                    svr_scale: 3,
                    ..Default::default()
                },
                "svr=3: expected 1, 2, 4 or 8",
            ),
            (
                LightSettings {
                    scatter_radius_voxels: f32::NAN,
                    ..Default::default()
                },
                "scatter_radius",
            ),
            (
                LightSettings {
                    directions: 0,
                    ..Default::default()
                },
                "directions=0",
            ),
            (
                LightSettings {
                    bias: 1.5,
                    ..Default::default()
                },
                "bias=1.5",
            ),
            (
                LightSettings {
                    phase_g: 1.0,
                    ..Default::default()
                },
                "phase_g",
            ),
            (
                LightSettings {
                    source: LightSource::Directional([0.0; 3]),
                    ..Default::default()
                },
                "zero",
            ),
            (
                LightSettings {
                    source: LightSource::Point([f32::INFINITY, 0.0, 0.0]),
                    ..Default::default()
                },
                "position",
            ),
        ];
        for (settings, want) in bad {
            let e = settings.validate_fields().expect_err(want).to_string();
            assert!(e.contains(want), "{e}");
        }
        use crate::settings::TextSetting;
        assert_eq!(
            LightSource::parse_text("point:0.5,0.5,0.5"),
            Ok(LightSource::Point([0.5; 3]))
        );
        assert_eq!(
            LightSource::parse_text("directional:0,0,1"),
            Ok(LightSource::Directional([0.0, 0.0, 1.0]))
        );
        for bad in ["sun:0,0,1", "point:1,2", "point", "directional:a,b,c"] {
            assert!(
                LightSource::parse_text(bad)
                    .expect_err(bad)
                    .0
                    .contains("point:x,y,z"),
                "{bad}"
            );
        }
    }
}
