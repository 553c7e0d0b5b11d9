//! The error type of the `shaders` crate.

/// Everything that can go wrong on the GPU side.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter at all: no GPU driver and no software rasterizer is installed.
    #[error(
        "no GPU adapter found (backends tried: {backends}). Install a Vulkan driver: on \
         Debian/Ubuntu `sudo apt-get install mesa-vulkan-drivers libvulkan1` provides \
         lavapipe, a software Vulkan driver that works without a GPU; set WGPU_BACKEND \
         (vulkan, gl, metal, dx12) to choose a backend"
    )]
    NoAdapter {
        /// The backends that were searched.
        backends: String,
    },
    /// Adapters exist, but `WGPU_ADAPTER_NAME` matches none of them.
    #[error("WGPU_ADAPTER_NAME={wanted:?} matches no adapter: expected part of one of {available}")]
    NoMatchingAdapter {
        /// The requested name.
        wanted: String,
        /// The adapters that exist.
        available: String,
    },
    /// The adapter refused to create a device.
    #[error("adapter '{adapter}' refused to create a device: {source}")]
    RequestDevice {
        /// The adapter's name.
        adapter: String,
        /// wgpu's reason.
        source: wgpu::RequestDeviceError,
    },
    /// wgpu reported a validation error: a bug in voxserve, named by the operation.
    #[error("GPU validation error in {operation}: {message}")]
    Validation {
        /// What voxserve was doing.
        operation: String,
        /// wgpu's description.
        message: String,
    },
    /// The device ran out of memory.
    #[error("GPU out of memory in {operation}")]
    OutOfMemory {
        /// What voxserve was doing.
        operation: String,
    },
    /// A request exceeds what this adapter can do (texture size, format).
    #[error("{what}: {limit}")]
    Unsupported {
        /// The request.
        what: String,
        /// The limit it hits.
        limit: String,
    },
    /// The device did not finish the work in time, or was lost.
    #[error("GPU did not finish {operation}: {reason}")]
    Wait {
        /// What voxserve was waiting for.
        operation: String,
        /// Why the wait ended.
        reason: String,
    },
    /// Reading a result back from the GPU failed.
    #[error("reading back {operation} from the GPU failed: {reason}")]
    Readback {
        /// What was read.
        operation: String,
        /// Why it failed.
        reason: String,
    },
    /// The request itself is invalid (image size, parameters).
    #[error("{0}")]
    InvalidRequest(String),
    /// A setting of the request is out of range: which, its value and what
    /// was expected.
    #[error(transparent)]
    Setting(#[from] crate::settings::SettingError),
    /// Volume data could not be prepared.
    #[error(transparent)]
    Data(#[from] blocks::Error),
}
