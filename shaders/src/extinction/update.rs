//! [`Extinction`]: the extinction-based illumination of one renderer on the
//! GPU and what each [`Stage`] was computed for. It follows the paper's
//! algorithm 1: each frame recomputes from the first stage whose inputs
//! changed (the data or transfer function rebuild the SAT and everything
//! after it; ambient-occlusion settings the ambient term and the shadows;
//! lights, ambient light and cone the shadows alone); a camera change
//! recomputes nothing.

use std::any::Any;
use std::time::Instant;

use super::{
    AoMethod, ExtinctionParams, ExtinctionPipelines, ExtinctionSettings, ExtinctionVolumes,
    ShadowMethod, Stage, near_cells_mask, scan_workgroups,
};
use crate::illumination::{
    Illumination, Inputs, Refine, StageCache, StageKey, Timings, workgroups,
};
use crate::pipeline::run;
use crate::{FrameRequest, GpuContext, GpuError};

/// What the extinction stages of one frame took, in milliseconds (0 for
/// stages that did not run).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ExtinctionTimings {
    /// `extinction_sat`: reconstruction and the three scans.
    pub sat_ms: f64,
    /// `ambient_occlusion` (or its reference).
    pub ambient_occlusion_ms: f64,
    /// `soft_shadow` (or `shadow_ray`), all lights.
    pub soft_shadow_ms: f64,
    /// The whole update of this frame.
    pub total_ms: f64,
    /// Grid cells along x, y, z.
    pub grid: [u32; 3],
}

impl ExtinctionTimings {
    /// Adds `ms` to `stage`'s time.
    fn add(&mut self, stage: Stage, ms: f64) {
        *match stage {
            Stage::ExtinctionSat => &mut self.sat_ms,
            Stage::AmbientOcclusion => &mut self.ambient_occlusion_ms,
            Stage::SoftShadow => &mut self.soft_shadow_ms,
        } += ms;
    }
}

/// The extinction-based illumination of one renderer: GPU resources and what
/// each stage was computed for. See the module docs.
#[derive(Debug)]
pub struct Extinction {
    pipelines: ExtinctionPipelines,
    volumes: Option<ExtinctionVolumes>,
    cache: StageCache,
    params: Option<ExtinctionParams>,
    methods: (AoMethod, ShadowMethod),
}

/// What the update policy of extinction-based illumination drives: the
/// stages of one implementation, [`Extinction`] on the GPU or
/// [`crate::cpu::extinction::CpuExtinction`] for the CPU renderer.
pub(crate) trait ExtinctionStages {
    /// What the stages read besides the settings.
    type Inputs<'a>: Copy;

    /// What each stage was computed for.
    fn cache(&mut self) -> &mut StageCache;

    /// Builds what the stages need for `params` and `settings`; true when
    /// the SAT and textures were made anew (so every stage must run).
    fn prepare(
        &mut self,
        inputs: Self::Inputs<'_>,
        params: &ExtinctionParams,
        settings: &ExtinctionSettings,
    ) -> Result<bool, GpuError>;

    /// Runs `stage` by the methods of the prepared settings; returns its
    /// milliseconds.
    fn run(&mut self, inputs: Self::Inputs<'_>, stage: Stage) -> Result<f64, GpuError>;
}

/// Brings `stages` up to date for one frame whose stages have `keys`
/// (algorithm 1): from the first stale stage on; nothing when none is.
pub(crate) fn update_extinction<S: ExtinctionStages>(
    stages: &mut S,
    inputs: S::Inputs<'_>,
    keys: Vec<StageKey>,
    params: &ExtinctionParams,
    settings: &ExtinctionSettings,
) -> Result<ExtinctionTimings, GpuError> {
    let start = Instant::now();
    let mut timings = ExtinctionTimings {
        grid: params.grid,
        ..ExtinctionTimings::default()
    };
    if let Some(stale) = stages.cache().first_stale(&keys) {
        // New buffers hold nothing: everything is recomputed into them.
        let first = if stages.prepare(inputs, params, settings)? {
            0
        } else {
            stale
        };
        for &stage in &Stage::ALL[first..] {
            let ms = stages.run(inputs, stage)?;
            timings.add(stage, ms);
        }
        stages.cache().computed(first, keys);
    }
    timings.total_ms = start.elapsed().as_secs_f64() * 1e3;
    Ok(timings)
}

impl Extinction {
    /// Compiles the stages.
    pub fn new(gpu: &GpuContext) -> Result<Extinction, GpuError> {
        Ok(Extinction {
            pipelines: ExtinctionPipelines::new(gpu)?,
            volumes: None,
            cache: StageCache::default(),
            params: None,
            methods: Default::default(),
        })
    }

    /// The SAT and textures, once computed (tests read them back).
    pub fn volumes(&self) -> Option<&ExtinctionVolumes> {
        self.volumes.as_ref()
    }

    /// The params of the last computation.
    pub fn params(&self) -> Option<&ExtinctionParams> {
        self.params.as_ref()
    }

    /// The SAT and every texture read back into the CPU twins' state (tests
    /// compare each stage's twin, fed the GPU's own inputs, with it).
    pub fn read_state(
        &self,
        gpu: &GpuContext,
    ) -> Result<crate::cpu::extinction::ExtinctionState, GpuError> {
        let (Some(v), Some(params)) = (&self.volumes, &self.params) else {
            return Err(GpuError::InvalidRequest(
                "no extinction terms have been computed".into(),
            ));
        };
        let mut state = crate::cpu::extinction::ExtinctionState::empty(params);
        for ch in 0..params.channels as usize {
            state.sat.data[ch] = v.read_sat(gpu, ch)?;
        }
        state.extinction = v.extinction.read(gpu)?;
        state.ambient = v.ambient.read_rgba(gpu)?;
        state.light_cache = v.light_cache.read_rgba(gpu)?;
        Ok(state)
    }

    /// Brings the light cache up to date (algorithm 1): from the first stage
    /// whose inputs changed on; nothing for a camera move.
    pub fn update_cache(
        &mut self,
        gpu: &GpuContext,
        inputs: Inputs<'_>,
        settings: &ExtinctionSettings,
    ) -> Result<ExtinctionTimings, GpuError> {
        settings.validate()?;
        let params =
            ExtinctionParams::new(inputs.texture, settings, inputs.atlas.layout, inputs.tf_len);
        let keys = StageCache::keys(&Stage::NAMES, settings, &inputs);
        update_extinction(self, (gpu, inputs), keys, &params, settings)
    }

    /// Writes `params` and the near-cells mask, and (re)allocates the SAT and
    /// textures when the grid or the channels changed: true when they were.
    fn prepare_volumes(
        &mut self,
        gpu: &GpuContext,
        inputs: Inputs<'_>,
        params: &ExtinctionParams,
    ) -> Result<bool, GpuError> {
        let mask = near_cells_mask(&inputs.atlas.packing, params);
        let fits = self
            .volumes
            .as_ref()
            .is_some_and(|v| v.fits(params.grid, params.channels, mask.len()));
        if !fits {
            // The old buffers go before the new ones are made.
            self.volumes = None;
            self.volumes = Some(ExtinctionVolumes::new(
                gpu,
                params.grid,
                params.channels,
                mask.len(),
            )?);
        }
        if let Some(v) = &self.volumes {
            gpu.queue
                .write_buffer(&v.near_blocks, 0, bytemuck::cast_slice(&mask));
            gpu.queue
                .write_buffer(&v.params, 0, bytemuck::bytes_of(params));
            for (axis, buffer) in v.scan_params.iter().enumerate() {
                let scanning = params.scanning(axis as u32);
                gpu.queue
                    .write_buffer(buffer, 0, bytemuck::bytes_of(&scanning));
            }
        }
        self.params = Some(*params);
        Ok(!fits)
    }

    /// Runs `stage` by the methods of the settings; returns its milliseconds.
    fn run_stage<'a>(
        &'a self,
        gpu: &GpuContext,
        inputs: Inputs<'_>,
        stage: Stage,
    ) -> Result<f64, GpuError> {
        let (Some(v), Some(params)) = (&self.volumes, &self.params) else {
            return Err(GpuError::InvalidRequest("no extinction volumes".into()));
        };
        let p = &self.pipelines;
        let view = wgpu::BindingResource::TextureView;
        let groups = workgroups(params.grid);
        let (ao_method, shadow_method) = self.methods;
        let sat_and = |more: Vec<wgpu::BindingResource<'a>>| {
            let mut resources = v.sat_bindings();
            resources.extend(more);
            resources
        };
        match stage {
            Stage::ExtinctionSat => self.build_sat(gpu, inputs),
            Stage::AmbientOcclusion => match ao_method {
                AoMethod::Sat => run(
                    gpu,
                    &p.ambient_occlusion,
                    &sat_and(vec![
                        view(&v.ambient.view),
                        v.near_blocks.as_entire_binding(),
                    ]),
                    groups,
                ),
                AoMethod::Sampled => run(
                    gpu,
                    &p.ambient_occlusion_reference,
                    &[
                        v.params.as_entire_binding(),
                        view(&v.extinction.view),
                        view(&v.ambient.view),
                        v.near_blocks.as_entire_binding(),
                    ],
                    groups,
                ),
            },
            Stage::SoftShadow => match shadow_method {
                ShadowMethod::Cone => run(
                    gpu,
                    &p.soft_shadow,
                    &sat_and(vec![
                        view(&v.ambient.view),
                        view(&v.light_cache.view),
                        v.near_blocks.as_entire_binding(),
                    ]),
                    groups,
                ),
                ShadowMethod::Ray => run(
                    gpu,
                    &p.shadow_ray,
                    &[
                        v.params.as_entire_binding(),
                        view(&v.extinction.view),
                        view(&v.ambient.view),
                        view(&v.light_cache.view),
                        v.near_blocks.as_entire_binding(),
                    ],
                    groups,
                ),
            },
        }
    }

    /// `extinction_sat`: reconstruction, then the scans along x, y and z.
    fn build_sat(&self, gpu: &GpuContext, inputs: Inputs<'_>) -> Result<f64, GpuError> {
        let (Some(v), Some(params)) = (&self.volumes, &self.params) else {
            return Ok(0.0);
        };
        let p = &self.pipelines;
        let view = wgpu::BindingResource::TextureView;
        let base = vec![
            v.params.as_entire_binding(),
            view(&inputs.atlas.atlas_view),
            wgpu::BindingResource::Sampler(&p.sampler),
            inputs.transfer_function.as_entire_binding(),
            view(&inputs.atlas.index_view),
            v.sat[0].as_entire_binding(),
            v.sat[1].as_entire_binding(),
            v.sat[2].as_entire_binding(),
            v.sat[3].as_entire_binding(),
            view(&v.extinction.view),
        ];
        let mut ms = run(gpu, &p.reconstruct, &base, workgroups(params.grid))?;
        for (axis, uniforms) in v.scan_params.iter().enumerate() {
            let mut resources = base.clone();
            resources[0] = uniforms.as_entire_binding();
            ms += run(
                gpu,
                &p.scan,
                &resources,
                scan_workgroups(params.grid, axis as u32),
            )?;
        }
        Ok(ms)
    }
}

impl ExtinctionStages for Extinction {
    type Inputs<'a> = (&'a GpuContext, Inputs<'a>);

    fn cache(&mut self) -> &mut StageCache {
        &mut self.cache
    }

    fn prepare(
        &mut self,
        (gpu, inputs): Self::Inputs<'_>,
        params: &ExtinctionParams,
        settings: &ExtinctionSettings,
    ) -> Result<bool, GpuError> {
        self.methods = (settings.ao_method, settings.shadow_method);
        self.prepare_volumes(gpu, inputs, params)
    }

    fn run(&mut self, (gpu, inputs): Self::Inputs<'_>, stage: Stage) -> Result<f64, GpuError> {
        self.run_stage(gpu, inputs, stage)
    }
}

impl Illumination for Extinction {
    fn update(
        &mut self,
        gpu: &GpuContext,
        inputs: Inputs<'_>,
        request: &FrameRequest,
        _refine: Refine,
    ) -> Result<Timings, GpuError> {
        self.update_cache(gpu, inputs, &request.extinction)
            .map(Timings::Extinction)
    }

    fn light_view(&self) -> Option<&wgpu::TextureView> {
        self.cache
            .is_complete()
            .then_some(self.volumes.as_ref())
            .flatten()
            .map(|v| &v.light_cache.view)
    }

    fn invalidate(&mut self) {
        self.cache.invalidate();
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}
