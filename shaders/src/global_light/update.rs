//! [`GlobalLight`]: the light of one renderer on the GPU, what it was computed
//! for, and the refinement reached. Each frame it recomputes from the first
//! [`Stage`] whose inputs changed (the paper's update A when that is the
//! first), else adds one in-scattering direction (B) until all J are in; a
//! camera change recomputes nothing. Every stage's time is reported apart.

use std::any::Any;
use std::time::Instant;

use super::{
    DirectLightMethod, LightParams, LightPipelines, LightSettings, LightSetup, LightVolumes,
    ScatterDirection, Stage, seam_passes,
};
use crate::illumination::{Illumination, Inputs, Refine, StageCache, Timings, workgroups};
use crate::pipeline::run;
use crate::settings::Settings;
use crate::{FrameRequest, GpuContext, GpuError};

/// What the light stages of one frame took, in milliseconds (0 for stages
/// that did not run).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct LightTimings {
    /// `local_opacity`.
    pub local_opacity_ms: f64,
    /// `global_opacity`.
    pub global_opacity_ms: f64,
    /// `direct_light` (or `direct_light_reference`).
    pub direct_light_ms: f64,
    /// `in_scatter`, all steps this frame.
    pub in_scatter_ms: f64,
    /// The whole light update of this frame.
    pub total_ms: f64,
    /// True when stages were recomputed (from the first whose inputs changed;
    /// all of them is the paper's update A), not refined.
    pub recomputed: bool,
    /// In-scattering directions blended so far (j).
    pub refined: u32,
    /// Directions in all (J).
    pub directions: u32,
}

impl LightTimings {
    /// Adds `ms` to `stage`'s time.
    fn add(&mut self, stage: Stage, ms: f64) {
        *match stage {
            Stage::LocalOpacity => &mut self.local_opacity_ms,
            Stage::GlobalOpacity => &mut self.global_opacity_ms,
            Stage::DirectLight => &mut self.direct_light_ms,
            Stage::InScatter => &mut self.in_scatter_ms,
        } += ms;
    }
}

/// The light of one renderer: GPU resources, what each stage was computed
/// for, and the refinement reached. See the module docs.
#[derive(Debug)]
pub struct GlobalLight {
    pipelines: LightPipelines,
    volumes: Option<LightVolumes>,
    cache: StageCache,
    directions: Vec<ScatterDirection>,
    params: Option<LightParams>,
    method: DirectLightMethod,
    refined: usize,
    /// The `light_seams` passes the packing needs.
    seam_passes: Vec<(u32, u32)>,
}

/// What the update policy of global light drives: the stages of one
/// implementation, [`GlobalLight`] on the GPU or
/// [`crate::cpu::global_light::CpuGlobalLight`] for the CPU renderer.
pub(crate) trait LightStages {
    /// What the stages read besides the settings.
    type Inputs<'a>: Copy;

    /// What each stage was computed for.
    fn cache(&mut self) -> &mut StageCache;

    /// Builds what the stages need for `settings`; true when the light's
    /// textures were made anew (so every stage must run).
    fn prepare(
        &mut self,
        inputs: Self::Inputs<'_>,
        settings: &LightSettings,
    ) -> Result<bool, GpuError>;

    /// Runs `stage` (in-scattering: its first direction, restarting the
    /// refinement); returns its milliseconds.
    fn run(&mut self, inputs: Self::Inputs<'_>, stage: Stage) -> Result<f64, GpuError>;

    /// Blends the next in-scattering direction in; returns its milliseconds.
    fn scatter_step(&mut self, inputs: Self::Inputs<'_>) -> Result<f64, GpuError>;

    /// Directions blended in so far (j) and in all (J).
    fn refinement(&self) -> (usize, usize);
}

/// Brings `light` up to date for one frame whose stages have `keys`: from
/// the first stale stage on, else (with [`Refine::Step`]) one more
/// in-scattering direction; with [`Refine::Converge`], every direction left.
pub(crate) fn update_light<S: LightStages>(
    light: &mut S,
    inputs: S::Inputs<'_>,
    keys: Vec<crate::illumination::StageKey>,
    settings: &LightSettings,
    refine: Refine,
) -> Result<LightTimings, GpuError> {
    settings.validate_fields()?;
    let start = Instant::now();
    let mut timings = LightTimings::default();
    let left = |light: &S| {
        let (j, n) = light.refinement();
        j < n
    };
    if let Some(stale) = light.cache().first_stale(&keys) {
        // New textures hold nothing: everything is recomputed into them.
        let first = if light.prepare(inputs, settings)? {
            0
        } else {
            stale
        };
        for &stage in &Stage::ALL[first..] {
            let ms = light.run(inputs, stage)?;
            timings.add(stage, ms);
        }
        light.cache().computed(first, keys);
        timings.recomputed = true;
    } else if refine == Refine::Step && left(light) {
        timings.in_scatter_ms += light.scatter_step(inputs)?;
    }
    while refine == Refine::Converge && left(light) {
        timings.in_scatter_ms += light.scatter_step(inputs)?;
    }
    timings.total_ms = start.elapsed().as_secs_f64() * 1e3;
    let (j, n) = light.refinement();
    (timings.refined, timings.directions) = (j as u32, n as u32);
    Ok(timings)
}

impl GlobalLight {
    /// Compiles the light stages.
    pub fn new(gpu: &GpuContext) -> Result<GlobalLight, GpuError> {
        Ok(GlobalLight {
            pipelines: LightPipelines::new(gpu)?,
            volumes: None,
            cache: StageCache::default(),
            directions: Vec::new(),
            params: None,
            method: DirectLightMethod::default(),
            refined: 0,
            seam_passes: Vec::new(),
        })
    }

    /// The light's textures, once computed (tests read them back).
    pub fn volumes(&self) -> Option<&LightVolumes> {
        self.volumes.as_ref()
    }

    /// The params of the last computation.
    pub fn params(&self) -> Option<&LightParams> {
        self.params.as_ref()
    }

    /// The in-scattering directions of the last computation, in order.
    pub fn directions(&self) -> &[ScatterDirection] {
        &self.directions
    }

    /// Every texture read back into the CPU twins' state (tests compare each
    /// stage's twin, fed the GPU's own inputs, with it).
    pub fn read_state(
        &self,
        gpu: &GpuContext,
    ) -> Result<crate::cpu::global_light::LightState, GpuError> {
        let v = self
            .volumes
            .as_ref()
            .ok_or_else(|| GpuError::InvalidRequest("no light has been computed".into()))?;
        Ok(crate::cpu::global_light::LightState {
            local_opacity: v.local_opacity.read(gpu)?,
            shadow_volume: v.shadow_volume.read(gpu)?,
            direct_light: v.direct_light.read(gpu)?,
            light_volume: v.light_volume.read(gpu)?,
        })
    }

    /// Whether every in-scattering direction is in.
    pub fn converged(&self) -> bool {
        self.cache.is_complete() && self.refined >= self.directions.len()
    }

    /// Brings the light up to date for one frame ([`update_light`]).
    pub fn update_light(
        &mut self,
        gpu: &GpuContext,
        inputs: Inputs<'_>,
        settings: &LightSettings,
        refine: Refine,
    ) -> Result<LightTimings, GpuError> {
        let keys = StageCache::keys(&Stage::NAMES, settings, &inputs);
        update_light(self, (gpu, inputs), keys, settings, refine)
    }

    /// Runs the `light_seams` passes with work to do ([`seam_passes`]) over
    /// the light volume, in order, as one submission (each dispatch sees the
    /// writes of those before it); returns their milliseconds.
    fn seams(&self, gpu: &GpuContext, inputs: Inputs<'_>) -> Result<f64, GpuError> {
        let (Some(volumes), Some(params)) = (&self.volumes, &self.params) else {
            return Ok(0.0);
        };
        let start = Instant::now();
        let stage = &self.pipelines.light_seams;
        let mut passes = Vec::new();
        for &(level, outward) in &self.seam_passes {
            let [_, _, sz, _] = params.regions[level as usize];
            let pass_params =
                uniform_buffer(gpu, "light seams params", &params.seam_pass(level, outward))?;
            let edge = (16 >> level) + 2;
            let [w, h, _] = params.atlas_dims();
            passes.push((pass_params, workgroups([w, h, sz * edge])));
        }
        gpu.scoped("running light_seams", || {
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("light_seams"),
                });
            for (pass_params, groups) in &passes {
                let bind_group = stage.bind_group(
                    gpu,
                    &[
                        pass_params.as_entire_binding(),
                        wgpu::BindingResource::TextureView(&inputs.atlas.index_view),
                        volumes.slot_blocks.as_entire_binding(),
                        wgpu::BindingResource::TextureView(&volumes.light_volume.view),
                    ],
                );
                stage.dispatch(&mut encoder, &bind_group, *groups);
            }
            gpu.queue.submit([encoder.finish()]);
        })?;
        gpu.wait("light_seams")?;
        Ok(start.elapsed().as_secs_f64() * 1e3)
    }
}

impl LightStages for GlobalLight {
    type Inputs<'a> = (&'a GpuContext, Inputs<'a>);

    fn cache(&mut self) -> &mut StageCache {
        &mut self.cache
    }

    fn refinement(&self) -> (usize, usize) {
        (self.refined, self.directions.len())
    }

    /// Builds the params, the slot and SVR masks and the directions for
    /// `settings`, and (re)allocates the textures when their sizes changed:
    /// true when they were.
    fn prepare(
        &mut self,
        (gpu, inputs): (&GpuContext, Inputs<'_>),
        settings: &LightSettings,
    ) -> Result<bool, GpuError> {
        let packing = &inputs.atlas.packing;
        let LightSetup {
            params,
            slot_blocks: slots,
            svr_blocks: svr_mask,
            directions,
        } = LightSetup::new(
            inputs.texture,
            settings,
            packing,
            inputs.atlas.layout,
            inputs.tf_len,
        );
        let atlas_dims = inputs.atlas.layout.atlas_dims;
        let fits = self
            .volumes
            .as_ref()
            .is_some_and(|v| v.fits(atlas_dims, params.svr_dims, slots.len(), svr_mask.len()));
        if !fits {
            // The old textures go before the new ones are made.
            self.volumes = None;
            self.volumes = Some(LightVolumes::new(
                gpu,
                atlas_dims,
                params.svr_dims,
                slots.len(),
                svr_mask.len(),
            )?);
        }
        if let Some(v) = &self.volumes {
            gpu.queue
                .write_buffer(&v.slot_blocks, 0, bytemuck::cast_slice(&slots));
            gpu.queue
                .write_buffer(&v.svr_blocks, 0, bytemuck::cast_slice(&svr_mask));
            gpu.queue
                .write_buffer(&v.params, 0, bytemuck::bytes_of(&params));
        }
        self.directions = directions;
        self.seam_passes = seam_passes(&packing.lod, params.volume.block_grid);
        self.params = Some(params);
        self.method = settings.method;
        Ok(!fits)
    }

    /// Runs `stage` (in-scattering: its first direction, restarting the
    /// refinement); returns its milliseconds.
    fn run(
        &mut self,
        (gpu, inputs): (&GpuContext, Inputs<'_>),
        stage: Stage,
    ) -> Result<f64, GpuError> {
        let (Some(v), Some(params)) = (&self.volumes, &self.params) else {
            return Err(GpuError::InvalidRequest("no light volumes".into()));
        };
        let p = &self.pipelines;
        let view = wgpu::BindingResource::TextureView;
        let data = [
            v.params.as_entire_binding(),
            view(&inputs.atlas.atlas_view),
            wgpu::BindingResource::Sampler(&p.sampler),
            inputs.transfer_function.as_entire_binding(),
            view(&inputs.atlas.index_view),
            v.slot_blocks.as_entire_binding(),
        ];
        let atlas_groups = workgroups(inputs.atlas.layout.atlas_dims);
        let with = |last| {
            let mut all = data.to_vec();
            all.push(last);
            all
        };
        match (stage, self.method) {
            (Stage::LocalOpacity, _) => run(
                gpu,
                &p.local_opacity,
                &with(view(&v.local_opacity.view)),
                atlas_groups,
            ),
            (Stage::GlobalOpacity, _) => run(
                gpu,
                &p.global_opacity,
                &[
                    v.params.as_entire_binding(),
                    view(&v.local_opacity.view),
                    wgpu::BindingResource::Sampler(&p.sampler),
                    view(&inputs.atlas.index_view),
                    view(&v.shadow_volume.view),
                    v.svr_blocks.as_entire_binding(),
                ],
                workgroups(params.svr_dims),
            ),
            (Stage::DirectLight, DirectLightMethod::Piecewise) => run(
                gpu,
                &p.direct_light,
                &[
                    v.params.as_entire_binding(),
                    view(&v.local_opacity.view),
                    view(&v.shadow_volume.view),
                    wgpu::BindingResource::Sampler(&p.sampler),
                    v.slot_blocks.as_entire_binding(),
                    view(&v.direct_light.view),
                ],
                atlas_groups,
            ),
            (Stage::DirectLight, DirectLightMethod::Reference) => run(
                gpu,
                &p.direct_light_reference,
                &with(view(&v.direct_light.view)),
                atlas_groups,
            ),
            (Stage::InScatter, _) => {
                self.refined = 0;
                self.scatter_step((gpu, inputs))
            }
        }
    }

    /// The next in-scattering step into the light volume (eq. 13's blend),
    /// then its level borders made seamless ([`SEAM_PASSES`]).
    fn scatter_step(&mut self, (gpu, inputs): (&GpuContext, Inputs<'_>)) -> Result<f64, GpuError> {
        let (Some(volumes), Some(params), Some(direction)) = (
            &self.volumes,
            &self.params,
            self.directions.get(self.refined),
        ) else {
            return Ok(0.0);
        };
        let step_params =
            uniform_buffer(gpu, "in-scattering params", &params.scattering(direction))?;
        let p = &self.pipelines;
        let view = wgpu::BindingResource::TextureView;
        let ms = run(
            gpu,
            &p.in_scatter,
            &[
                step_params.as_entire_binding(),
                view(&inputs.atlas.atlas_view),
                wgpu::BindingResource::Sampler(&p.sampler),
                inputs.transfer_function.as_entire_binding(),
                view(&inputs.atlas.index_view),
                volumes.slot_blocks.as_entire_binding(),
                view(&volumes.direct_light.view),
                view(&volumes.shadow_volume.view),
                view(&volumes.light_volume.view),
            ],
            workgroups(volumes.light_volume.dims),
        )?;
        self.refined += 1;
        Ok(ms + self.seams(gpu, inputs)?)
    }
}

/// A uniform buffer holding `params`. Each step and pass gets its own: queue
/// writes land before the next submit, so one shared buffer would be
/// overwritten too early.
fn uniform_buffer(
    gpu: &GpuContext,
    label: &'static str,
    params: &LightParams,
) -> Result<wgpu::Buffer, GpuError> {
    gpu.scoped(label, || {
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size_of::<LightParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        gpu.queue
            .write_buffer(&buffer, 0, bytemuck::bytes_of(params));
        buffer
    })
}

impl Illumination for GlobalLight {
    fn update(
        &mut self,
        gpu: &GpuContext,
        inputs: Inputs<'_>,
        request: &FrameRequest,
        refine: Refine,
    ) -> Result<Timings, GpuError> {
        self.update_light(gpu, inputs, &request.light, refine)
            .map(Timings::GlobalLight)
    }

    fn light_view(&self) -> Option<&wgpu::TextureView> {
        self.cache
            .is_complete()
            .then_some(self.volumes.as_ref())
            .flatten()
            .map(|v| &v.light_volume.view)
    }

    fn invalidate(&mut self) {
        self.cache.invalidate();
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}
