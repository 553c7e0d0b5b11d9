//! The GPU context: wgpu's asynchronous validation errors come back as typed
//! errors naming the operation, and the device has the adapter's own limits.

use shaders::GpuError;
use voxserve_tests::gpu_or_skip;

#[test]
fn validation_errors_become_typed_errors_naming_the_operation() {
    let Some(gpu) = gpu_or_skip("validation_errors_become_typed_errors_naming_the_operation")
    else {
        return;
    };
    let result = gpu.scoped("compiling a broken shader", || {
        gpu.device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("broken"),
                source: wgpu::ShaderSource::Wgsl("fn main( {".into()),
            })
    });
    match result {
        Err(GpuError::Validation { operation, message }) => {
            assert_eq!(operation, "compiling a broken shader");
            assert!(!message.is_empty());
        }
        other => panic!("expected a validation error, got {other:?}"),
    }
    // The device stays usable after a caught error.
    let ok = gpu.scoped("creating a small buffer", || {
        gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("small"),
            size: 256,
            usage: wgpu::BufferUsages::UNIFORM,
            mapped_at_creation: false,
        })
    });
    assert!(ok.is_ok(), "{ok:?}");
}

#[test]
fn the_device_has_the_adapters_own_limits() {
    let Some(gpu) = gpu_or_skip("the_device_has_the_adapters_own_limits") else {
        return;
    };
    let (adapter, device) = (gpu.adapter.limits(), gpu.device.limits());
    assert_eq!(
        device.max_texture_dimension_3d,
        adapter.max_texture_dimension_3d
    );
    assert_eq!(device.max_buffer_size, adapter.max_buffer_size);
    assert_eq!(
        device.max_storage_buffer_binding_size,
        adapter.max_storage_buffer_binding_size
    );
    assert!(!gpu.describe().is_empty());
}
