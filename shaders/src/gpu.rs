//! [`GpuContext`]: the adapter, device and queue every stage runs on.
//!
//! Adapter selection honours `WGPU_BACKEND` (a comma list: vulkan, gl, metal, dx12)
//! and `WGPU_ADAPTER_NAME` (part of an adapter's name), then prefers hardware over
//! software: discrete, integrated, virtual, other, and last the CPU adapter (Mesa's
//! lavapipe on machines without a GPU). The device is requested with the adapter's
//! own limits, because wgpu's defaults cap 3D textures at 2048 and buffers at 256 MiB.
//!
//! wgpu reports validation and out-of-memory errors asynchronously; [`GpuContext::scoped`]
//! wraps an operation in error scopes and turns what they catch into a [`GpuError`].

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::GpuError;

/// How long [`GpuContext::wait`] keeps polling before it gives up. A 4096² frame of
/// a large volume on a software adapter takes tens of seconds, so this is generous.
const WAIT_LIMIT: Duration = Duration::from_secs(600);
/// One poll's timeout; the GL backend gives up after about 2 s whatever it is asked,
/// so timeouts are retried until [`WAIT_LIMIT`].
const POLL_TIMEOUT: Duration = Duration::from_secs(2);

/// The adapter, device and queue, and what was learnt about them. Cloning is
/// cheap and shares the device.
#[derive(Debug, Clone)]
pub struct GpuContext {
    /// The adapter the device was created on.
    pub adapter: wgpu::Adapter,
    /// The device.
    pub device: wgpu::Device,
    /// The device's queue.
    pub queue: wgpu::Queue,
    /// Name, backend, device type and driver of the adapter.
    pub info: wgpu::AdapterInfo,
}

/// Rank of a device type: lower is preferred.
fn device_type_rank(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

/// Rank of a backend: native APIs before GL.
fn backend_rank(b: wgpu::Backend) -> u8 {
    match b {
        wgpu::Backend::Vulkan | wgpu::Backend::Metal | wgpu::Backend::Dx12 => 0,
        wgpu::Backend::Gl => 1,
        _ => 2,
    }
}

impl GpuContext {
    /// Finds the best adapter and creates a device on it (blocking).
    pub fn new() -> Result<GpuContext, GpuError> {
        pollster::block_on(GpuContext::new_async())
    }

    /// Finds the best adapter and creates a device on it.
    ///
    /// Without `WGPU_BACKEND`, the native backends (Vulkan, Metal, DX12) are searched
    /// first and GL only when they offer nothing: starting GL probes display servers
    /// (EGL), which is slow and noisy on a headless machine.
    pub async fn new_async() -> Result<GpuContext, GpuError> {
        let mut adapters = Vec::new();
        let mut searched = wgpu::Backends::empty();
        let choices = match wgpu::Backends::from_env() {
            Some(chosen) => vec![chosen],
            None => vec![wgpu::Backends::PRIMARY, wgpu::Backends::SECONDARY],
        };
        for backends in choices {
            let descriptor = wgpu::InstanceDescriptor {
                backends,
                ..wgpu::InstanceDescriptor::new_without_display_handle_from_env()
            };
            let instance = wgpu::Instance::new(descriptor);
            searched |= backends;
            adapters = instance.enumerate_adapters(backends).await;
            if !adapters.is_empty() {
                break;
            }
        }
        if adapters.is_empty() {
            return Err(GpuError::NoAdapter {
                backends: format!("{searched:?}"),
            });
        }
        if let Ok(wanted) = std::env::var("WGPU_ADAPTER_NAME") {
            let available = adapters
                .iter()
                .map(|a| format!("'{}'", a.get_info().name))
                .collect::<Vec<_>>()
                .join(", ");
            let needle = wanted.to_lowercase();
            adapters.retain(|a| a.get_info().name.to_lowercase().contains(&needle));
            if adapters.is_empty() {
                return Err(GpuError::NoMatchingAdapter { wanted, available });
            }
        }
        adapters.sort_by_key(|a| {
            let info = a.get_info();
            (
                device_type_rank(info.device_type),
                backend_rank(info.backend),
            )
        });
        // An adapter may list itself and still fail to open; try the next one then.
        let mut last_error = None;
        for adapter in adapters {
            match GpuContext::open(adapter).await {
                Ok(gpu) => return Ok(gpu),
                Err(e) => {
                    tracing::warn!("{e}");
                    last_error = Some(e);
                }
            }
        }
        Err(last_error.unwrap_or(GpuError::NoAdapter {
            backends: format!("{searched:?}"),
        }))
    }

    /// Creates the device on one adapter, with its own limits and the optional
    /// features voxserve can use.
    async fn open(adapter: wgpu::Adapter) -> Result<GpuContext, GpuError> {
        let info = adapter.get_info();
        let wanted = wgpu::Features::TEXTURE_FORMAT_16BIT_NORM | wgpu::Features::FLOAT32_FILTERABLE;
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("voxserve"),
                required_features: adapter.features() & wanted,
                required_limits: adapter.limits(),
                ..Default::default()
            })
            .await
            .map_err(|source| GpuError::RequestDevice {
                adapter: info.name.clone(),
                source,
            })?;
        device.on_uncaptured_error(Arc::new(|e: wgpu::Error| {
            tracing::error!("uncaptured GPU error: {e}");
        }));
        tracing::info!(
            adapter = %info.name,
            backend = %info.backend,
            device_type = ?info.device_type,
            driver = %format!("{} {}", info.driver, info.driver_info).trim(),
            "GPU adapter"
        );
        Ok(GpuContext {
            adapter,
            device,
            queue,
            info,
        })
    }

    /// A one-line description of the adapter: `name (backend, device type)`.
    pub fn describe(&self) -> String {
        format!(
            "{} ({}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }

    /// Whether the adapter runs on the CPU (lavapipe, llvmpipe, WARP).
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// Runs `f` inside validation and out-of-memory error scopes and returns what
    /// they caught as a [`GpuError`] naming `operation`.
    pub fn scoped<T>(&self, operation: &str, f: impl FnOnce() -> T) -> Result<T, GpuError> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let value = f();
        let validation = pollster::block_on(validation.pop());
        let oom = pollster::block_on(oom.pop());
        match (validation, oom) {
            (Some(e), _) => Err(GpuError::Validation {
                operation: operation.to_owned(),
                message: e.to_string(),
            }),
            (None, Some(_)) => Err(GpuError::OutOfMemory {
                operation: operation.to_owned(),
            }),
            (None, None) => Ok(value),
        }
    }

    /// Blocks until the queue's submitted work is done, retrying poll timeouts.
    pub fn wait(&self, operation: &str) -> Result<(), GpuError> {
        let start = Instant::now();
        loop {
            let poll = self.device.poll(wgpu::PollType::Wait {
                submission_index: None,
                timeout: Some(POLL_TIMEOUT),
            });
            match poll {
                Ok(_) => return Ok(()),
                Err(wgpu::PollError::Timeout) if start.elapsed() < WAIT_LIMIT => {
                    tracing::debug!("still waiting for {operation} after {:?}", start.elapsed());
                }
                Err(e) => {
                    return Err(GpuError::Wait {
                        operation: operation.to_owned(),
                        reason: format!("{e} (after {:.1} s)", start.elapsed().as_secs_f32()),
                    });
                }
            }
        }
    }

    /// Maps `buffer` for reading, waits, and hands its bytes to `read`.
    pub fn read_buffer<T>(
        &self,
        buffer: &wgpu::Buffer,
        operation: &str,
        read: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, GpuError> {
        let (sender, receiver) = std::sync::mpsc::channel();
        buffer.map_async(wgpu::MapMode::Read, .., move |result| {
            // The receiver lives until this function returns; a failed send means
            // nobody waits any more, which is fine.
            let _ = sender.send(result);
        });
        self.wait(operation)?;
        let readback_error = |reason: String| GpuError::Readback {
            operation: operation.to_owned(),
            reason,
        };
        receiver
            .recv()
            .map_err(|_| readback_error("the map callback never ran".into()))?
            .map_err(|e| readback_error(e.to_string()))?;
        let value = {
            let view = buffer
                .get_mapped_range(..)
                .map_err(|e| readback_error(e.to_string()))?;
            read(&view)
        };
        buffer.unmap();
        Ok(value)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hardware_ranks_before_software() {
        let mut types = [
            wgpu::DeviceType::Cpu,
            wgpu::DeviceType::IntegratedGpu,
            wgpu::DeviceType::Other,
            wgpu::DeviceType::DiscreteGpu,
            wgpu::DeviceType::VirtualGpu,
        ];
        types.sort_by_key(|t| device_type_rank(*t));
        assert_eq!(types[0], wgpu::DeviceType::DiscreteGpu);
        assert_eq!(types[4], wgpu::DeviceType::Cpu);
        assert!(backend_rank(wgpu::Backend::Vulkan) < backend_rank(wgpu::Backend::Gl));
    }
}
