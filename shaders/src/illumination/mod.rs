//! The illumination modes behind one interface: global light propagation
//! ([`crate::global_light`]) and extinction-based illumination
//! ([`crate::extinction`]) each compute light from the resident blocks in a
//! declared list of stages before the ray caster reads it.
//!
//! - [`Mode`]: which modes there are, what each declares (its stages in the
//!   order they run, whether frames refine it, which ray-caster variant reads
//!   it and how) and its GPU state, made on first use.
//! - [`Illumination`]: what the renderer asks of a mode's GPU state.
//! - [`StageCache`]: the update policy both modes share: each stage is
//!   recomputed when the data, the transfer function or a setting that
//!   `affects` it or an earlier stage changed (the settings say which), from
//!   the first such stage on.
//! - [`masks`]: the slots and blocks the stages work on; [`textures`]: the
//!   textures they write and their readback.

pub mod masks;
pub mod textures;

use std::any::Any;
use std::fmt;

use blocks::TransferFunction;
use glam::{Mat4, Vec3};

use crate::extinction::{Extinction, ExtinctionTimings};
use crate::global_light::{GlobalLight, LightTimings};
use crate::packed::GpuAtlas;
use crate::raycast::{self, VolumePlacement};
use crate::settings::{Json, Settings, stage_key};
use crate::volume_texture::VolumeTexture;
use crate::{FrameRequest, GpuContext, GpuError, Shading};

pub use masks::{near_blocks, slot_blocks};
pub use textures::{StageTexture, read_texture_bytes};

/// Invocations per workgroup along each axis of the per-texel and per-cell
/// illumination stages.
pub const WORKGROUP_EDGE: u32 = 4;

/// Workgroups covering `dims` invocations, one per texel or cell.
pub fn workgroups(dims: [u32; 3]) -> [u32; 3] {
    dims.map(|d| d.div_ceil(WORKGROUP_EDGE))
}

/// The affine maps between texture space and model space of a volume:
/// (model from texture, texture from model).
pub fn texture_transforms(texture: &VolumeTexture) -> (Mat4, Mat4) {
    let placement = VolumePlacement::of(texture);
    let m = placement.model_from_texture;
    let model_from_texture = Mat4::from_cols(
        m.x_axis.extend(0.0),
        m.y_axis.extend(0.0),
        m.z_axis.extend(0.0),
        (-(m * Vec3::splat(0.5))).extend(1.0),
    );
    (model_from_texture, model_from_texture.inverse())
}

/// A lighting mode computed ahead of the ray caster.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Mode {
    /// Global light propagation by local piecewise integration (Hernell,
    /// Ljung, Ynnerman 2008): `shading=global`.
    GlobalLight,
    /// Extinction-based illumination from a summed-area table (Schlegel,
    /// Makhinya, Pajarola 2011): `shading=extinction`.
    Extinction,
}

/// How far towards the eye global light's stored light is read, in voxels
/// of the smallest spacing. Read at the sample, a surface blends the lit
/// texels outside it with those inside that its own opacity shadows, in
/// proportions that change with where the surface cuts the texel grid: one
/// ring per voxel on every smooth surface (the VHF skull at 1:1 under
/// `ct-bone`). Two voxels out, the light is the light just outside the
/// surface: the rings go. One voxel left them faint; the offset moves
/// shadow edges by as much. Scaled by each block's level instead, the
/// offset jumps at level borders and draws the blocks as patches.
pub const LIGHT_READ_VOXELS: f32 = 2.0;

/// How the ray caster reads a mode's light: flags, light colour and bias,
/// and the offset towards the eye the light is read at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RaycastLight {
    /// `FLAG_*` bits to set.
    pub flags: u32,
    /// Light colour times intensity (rgb) and I_bias (a).
    pub light: [f32; 4],
    /// How far towards the eye the light is read (mm).
    pub light_offset: f32,
}

impl Mode {
    /// Every mode.
    pub const ALL: [Mode; 2] = [Mode::GlobalLight, Mode::Extinction];

    /// The mode of `shading`, if it is lit by one.
    pub fn of(shading: Shading) -> Option<Mode> {
        match shading {
            Shading::GlobalLight => Some(Mode::GlobalLight),
            Shading::Extinction => Some(Mode::Extinction),
            Shading::Unshaded | Shading::Gradient | Shading::Mip | Shading::MinIp => None,
        }
    }

    /// The mode's stages in the order they run: the names its settings'
    /// `affects` use, and what the GPU path, the CPU twin and the tests run.
    pub fn stages(self) -> &'static [&'static str] {
        match self {
            Mode::GlobalLight => &crate::global_light::Stage::NAMES,
            Mode::Extinction => &crate::extinction::Stage::NAMES,
        }
    }

    /// Whether frames after a change refine the light (global light's
    /// in-scattering, one direction per frame) rather than it being complete
    /// at once.
    pub fn refines(self) -> bool {
        self == Mode::GlobalLight
    }

    /// The ray-caster variant that reads the mode's light.
    pub fn raycast_stage(self) -> raycast::Stage {
        match self {
            Mode::GlobalLight => raycast::Stage::RaycastLit,
            Mode::Extinction => raycast::Stage::RaycastExtinction,
        }
    }

    /// How the ray caster reads the mode's light for `request` of `texture`.
    pub fn raycast_light(self, request: &FrameRequest, texture: &VolumeTexture) -> RaycastLight {
        match self {
            Mode::GlobalLight => {
                let settings = &request.light;
                let [r, g, b] = settings.colour.map(|c| c * settings.intensity);
                RaycastLight {
                    flags: raycast::FLAG_LIT,
                    light: [r, g, b, settings.bias],
                    light_offset: LIGHT_READ_VOXELS * texture.geometry.min_spacing_f32(),
                }
            }
            // The light cache holds the coloured light: white, no bias; the
            // gradient factor k of eq. 8 keeps gradient shading; the cache is
            // read `LIGHT_READ_CELLS` cells towards the eye (see
            // `RaycastParams::light_offset`).
            Mode::Extinction => RaycastLight {
                flags: raycast::FLAG_LIT | raycast::FLAG_SHADED,
                light: [1.0, 1.0, 1.0, 0.0],
                light_offset: crate::extinction::LIGHT_READ_CELLS
                    * crate::extinction::cell_mm(texture, request.extinction.sat_size),
            },
        }
    }

    /// The mode's GPU state, its stages compiled.
    pub fn create(self, gpu: &GpuContext) -> Result<Box<dyn Illumination>, GpuError> {
        Ok(match self {
            Mode::GlobalLight => Box::new(GlobalLight::new(gpu)?),
            Mode::Extinction => Box::new(Extinction::new(gpu)?),
        })
    }
}

/// What a mode's stages read: the resident blocks, the frame's
/// transfer-function table, and what identifies them.
#[derive(Debug, Clone, Copy)]
pub struct Inputs<'a> {
    /// The packed data and its index.
    pub atlas: &'a GpuAtlas,
    /// The transfer-function table, `array<vec4<f32>>`.
    pub transfer_function: &'a wgpu::Buffer,
    /// How texels map to the transfer function.
    pub texture: &'a VolumeTexture,
    /// Entries in the table.
    pub tf_len: u32,
    /// The transfer function the table holds.
    pub tf: &'a TransferFunction,
    /// Bumped whenever the resident blocks change.
    pub data_version: u64,
}

/// What a mode's stages took this frame.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum Timings {
    /// Global light propagation's stages.
    GlobalLight(LightTimings),
    /// Extinction-based illumination's stages.
    Extinction(ExtinctionTimings),
}

impl Timings {
    /// The whole update, ms.
    pub fn total_ms(&self) -> f64 {
        match self {
            Timings::GlobalLight(t) => t.total_ms,
            Timings::Extinction(t) => t.total_ms,
        }
    }

    /// Refinement steps in and in all (j, J), for modes that refine.
    pub fn refinement(&self) -> Option<(u32, u32)> {
        match self {
            Timings::GlobalLight(t) => Some((t.refined, t.directions)),
            Timings::Extinction(_) => None,
        }
    }

    /// Whether the light is complete: nothing more will refine it.
    pub fn converged(&self) -> bool {
        self.refinement().is_none_or(|(j, n)| j >= n)
    }
}

/// How far one frame refines a mode's light once its stages are up to date.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refine {
    /// Not at all: a later band of a frame shows the light its first band did.
    Hold,
    /// One refinement step (an interactive frame).
    Step,
    /// Every step left (a still image, a test).
    Converge,
}

/// What the renderer asks of a mode's GPU state.
pub trait Illumination: fmt::Debug + Send {
    /// Brings the mode's stages up to date for `request`: from the first stage
    /// whose inputs changed on, then (for a mode that refines) as far as
    /// `refine` says; nothing for a camera move.
    fn update(
        &mut self,
        gpu: &GpuContext,
        inputs: Inputs<'_>,
        request: &FrameRequest,
        refine: Refine,
    ) -> Result<Timings, GpuError>;

    /// The texture the ray caster reads, once computed.
    fn light_view(&self) -> Option<&wgpu::TextureView>;

    /// Forgets what was computed, so the next update recomputes everything.
    fn invalidate(&mut self);

    /// The state itself, for tests that read its textures back.
    fn as_any(&self) -> &dyn Any;
}

/// What one cached stage was computed for: the resident data's version, the
/// transfer function, and the values of the settings whose change recomputes
/// it ([`stage_key`]).
pub type StageKey = (u64, TransferFunction, Vec<Json>);

/// The update policy of a mode's stages: what each was computed for, and
/// from which stage a frame must recompute.
#[derive(Debug, Clone, Default)]
pub struct StageCache {
    computed_for: Vec<Option<StageKey>>,
}

impl StageCache {
    /// The keys of `stages` (in the order they run) for `settings` over
    /// `inputs`' data and transfer function.
    pub fn keys<S: Settings>(stages: &[&str], settings: &S, inputs: &Inputs<'_>) -> Vec<StageKey> {
        StageCache::keys_of(stages, settings, inputs.data_version, inputs.tf)
    }

    /// The keys of `stages` for `settings` over the resident data's
    /// `data_version` and transfer function `tf` (any renderer's).
    pub fn keys_of<S: Settings>(
        stages: &[&str],
        settings: &S,
        data_version: u64,
        tf: &TransferFunction,
    ) -> Vec<StageKey> {
        stages
            .iter()
            .map(|stage| (data_version, tf.clone(), stage_key(settings, stages, stage)))
            .collect()
    }

    /// The first stage whose key differs from what it was computed for, if any.
    pub fn first_stale(&self, keys: &[StageKey]) -> Option<usize> {
        keys.iter()
            .enumerate()
            .position(|(i, key)| self.computed_for.get(i).and_then(Option::as_ref) != Some(key))
    }

    /// Records that the stages from `first` on were computed for `keys`.
    pub fn computed(&mut self, first: usize, keys: Vec<StageKey>) {
        self.computed_for.resize(keys.len(), None);
        for (i, key) in keys.into_iter().enumerate().skip(first) {
            self.computed_for[i] = Some(key);
        }
    }

    /// Whether every stage has been computed.
    pub fn is_complete(&self) -> bool {
        !self.computed_for.is_empty() && self.computed_for.iter().all(Option::is_some)
    }

    /// Forgets every stage.
    pub fn invalidate(&mut self) {
        self.computed_for.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::Settings;

    #[test]
    fn every_affected_stage_is_a_stage_of_its_mode() {
        let check = |mode: Mode, specs: Vec<&crate::settings::Spec>| {
            for spec in specs {
                if let Some(stage) = spec.affects {
                    assert!(
                        mode.stages().contains(&stage),
                        "{}: affects '{stage}', not a stage of {mode:?}: {:?}",
                        spec.name,
                        mode.stages()
                    );
                }
            }
        };
        check(
            Mode::GlobalLight,
            crate::LightSettings::settings()
                .iter()
                .map(|s| s.spec())
                .collect(),
        );
        check(
            Mode::Extinction,
            crate::extinction::ExtinctionSettings::settings()
                .iter()
                .map(|s| s.spec())
                .collect(),
        );
    }

    #[test]
    fn the_first_stale_stage_is_the_first_whose_key_changed() {
        let tf = TransferFunction::parse("0:000000:0,1:ffffff:1").expect("tf");
        let key = |v: u64, s: i64| (v, tf.clone(), vec![Json::from(s)]);
        let mut cache = StageCache::default();
        let keys = vec![key(1, 0), key(1, 0), key(1, 0)];
        assert_eq!(cache.first_stale(&keys), Some(0));
        cache.computed(0, keys.clone());
        assert!(cache.is_complete());
        assert_eq!(cache.first_stale(&keys), None);
        assert_eq!(
            cache.first_stale(&[key(1, 0), key(1, 5), key(1, 5)]),
            Some(1)
        );
        assert_eq!(
            cache.first_stale(&[key(2, 0), key(2, 0), key(2, 0)]),
            Some(0)
        );
        cache.invalidate();
        assert_eq!(cache.first_stale(&keys), Some(0));
    }
}
