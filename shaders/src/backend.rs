//! Which renderer draws: the GPU ([`Renderer`]) or the CPU ([`CpuRenderer`]),
//! chosen once per process by [`Backend::choose`] from `--renderer`
//! ([`RendererChoice`]), and [`AnyRenderer`], either one behind the same calls.

use std::sync::Arc;

use blocks::cache::BlockCache;
use blocks::lod::LodSelection;
use blocks::packing::Packing;

use crate::cpu::CpuRenderer;
use crate::volume_texture::VolumeTexture;
use crate::{Frame, FrameRequest, GpuContext, GpuError, RenderStats, Renderer};

/// `--renderer`: which renderer to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RendererChoice {
    /// The GPU when there is a hardware adapter; the CPU when the only one
    /// is a software rasterizer (lavapipe, llvmpipe, WARP, SwiftShader) or
    /// there is none. The default.
    #[default]
    Auto,
    /// The GPU adapter (a software one too); an error when there is none.
    Gpu,
    /// The CPU renderer.
    Cpu,
}

impl RendererChoice {
    /// Every choice, for command-line parsing.
    pub const ALL: [RendererChoice; 3] = [Self::Auto, Self::Gpu, Self::Cpu];

    /// The name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Gpu => "gpu",
            Self::Cpu => "cpu",
        }
    }
}

impl std::fmt::Display for RendererChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The renderer a process uses.
#[derive(Debug, Clone)]
#[expect(
    clippy::large_enum_variant,
    reason = "one per process, made once: boxing the GPU context buys nothing"
)]
pub enum Backend {
    /// Frames ray-cast by the GPU stages.
    Gpu(GpuContext),
    /// Frames ray-cast by the CPU twins, on every core.
    Cpu,
}

impl Backend {
    /// The backend `choice` names; see [`RendererChoice`].
    pub fn choose(choice: RendererChoice) -> Result<Backend, GpuError> {
        match choice {
            RendererChoice::Cpu => Ok(Backend::Cpu),
            RendererChoice::Gpu => Ok(Backend::Gpu(GpuContext::new()?)),
            RendererChoice::Auto => match GpuContext::new() {
                Ok(gpu) if !gpu.is_software() => Ok(Backend::Gpu(gpu)),
                Ok(gpu) => {
                    tracing::info!(
                        "the only GPU adapter is a software one ({}): rendering on the CPU",
                        gpu.info.name
                    );
                    Ok(Backend::Cpu)
                }
                Err(e) => {
                    tracing::info!("no GPU adapter ({e}): rendering on the CPU");
                    Ok(Backend::Cpu)
                }
            },
        }
    }

    /// `gpu` or `cpu`.
    pub fn kind(&self) -> &'static str {
        match self {
            Backend::Gpu(_) => "gpu",
            Backend::Cpu => "cpu",
        }
    }

    /// What renders, in words: the adapter, or the CPU and its threads.
    pub fn describe(&self) -> String {
        match self {
            Backend::Gpu(gpu) => gpu.describe(),
            Backend::Cpu => format!(
                "CPU renderer, {} threads, {}",
                rayon::current_num_threads(),
                crate::cpu::march::Isa::best().name()
            ),
        }
    }

    /// A renderer of the store behind `cache` keeping at most `budget_bytes`
    /// of blocks in its atlas (GPU memory, or memory).
    pub fn renderer(
        &self,
        cache: Arc<BlockCache>,
        budget_bytes: u64,
    ) -> Result<AnyRenderer, GpuError> {
        Ok(match self {
            Backend::Gpu(gpu) => {
                AnyRenderer::Gpu(Box::new(Renderer::new(gpu.clone(), cache, budget_bytes)?))
            }
            Backend::Cpu => AnyRenderer::Cpu(Box::new(CpuRenderer::new(cache, budget_bytes))),
        })
    }
}

/// A [`Renderer`] or a [`CpuRenderer`]: the calls they share.
#[derive(Debug)]
pub enum AnyRenderer {
    /// On the GPU (both boxed: each is kilobytes, of sizes that change).
    Gpu(Box<Renderer>),
    /// On the CPU.
    Cpu(Box<CpuRenderer>),
}

impl AnyRenderer {
    /// See [`Renderer::render`].
    pub fn render(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        match self {
            AnyRenderer::Gpu(r) => r.render(request),
            AnyRenderer::Cpu(r) => r.render(request),
        }
    }

    /// See [`Renderer::render_now`].
    pub fn render_now(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        match self {
            AnyRenderer::Gpu(r) => r.render_now(request),
            AnyRenderer::Cpu(r) => r.render_now(request),
        }
    }

    /// See [`Renderer::render_probe`].
    pub fn render_probe(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        match self {
            AnyRenderer::Gpu(r) => r.render_probe(request),
            AnyRenderer::Cpu(r) => r.render_probe(request),
        }
    }

    /// See [`Renderer::render_converged`].
    pub fn render_converged(&mut self, request: &FrameRequest) -> Result<Frame, GpuError> {
        match self {
            AnyRenderer::Gpu(r) => r.render_converged(request),
            AnyRenderer::Cpu(r) => r.render_converged(request),
        }
    }

    /// What the last frame took and showed.
    pub fn last_stats(&self) -> &RenderStats {
        match self {
            AnyRenderer::Gpu(r) => r.last_stats(),
            AnyRenderer::Cpu(r) => r.last_stats(),
        }
    }

    /// The level-of-detail selection in use, once a frame was rendered.
    pub fn selection(&self) -> Option<&LodSelection> {
        match self {
            AnyRenderer::Gpu(r) => r.selection(),
            AnyRenderer::Cpu(r) => r.selection(),
        }
    }

    /// The packing in use, once a frame was rendered.
    pub fn packing(&self) -> Option<&Packing> {
        match self {
            AnyRenderer::Gpu(r) => r.packing(),
            AnyRenderer::Cpu(r) => r.packing(),
        }
    }

    /// How voxels become texels.
    pub fn volume_texture(&self) -> &VolumeTexture {
        match self {
            AnyRenderer::Gpu(r) => r.volume_texture(),
            AnyRenderer::Cpu(r) => r.volume_texture(),
        }
    }
}
