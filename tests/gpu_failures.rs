//! The GPU backend made to fail: a kernel the adapter refuses, an impossible allocation, a
//! refused buffer descriptor, an error raised outside any scope. Each must come back as a
//! `GpuError`, never as a panic (wgpu's default error handler panics) or a hang.

mod gpu_harness;

use flatport::gpu::{GpuError, Precision};

#[test]
fn a_kernel_the_adapter_refuses_is_an_error_naming_it() {
    let Some(engine) = gpu_harness::engine(Precision::F32) else {
        return;
    };
    let source = "@compute @workgroup_size(64) fn main() { let x: f32 = no_such_value; }";
    let error = engine
        .context()
        .pipeline("broken_kernel", source, 1)
        .unwrap_err();
    assert!(matches!(error, GpuError::Kernel { .. }), "{error:?}");
    assert!(error.to_string().contains("broken_kernel"), "{error}");
    // The engine still works afterwards (a kernel declares the overrides the context sets).
    let sum = "override WORKGROUP_SIZE: u32;\n\
               override RIG_LAYERS: u32;\n\
               @group(0) @binding(0) var<storage, read_write> out: array<u32>;\n\
               @compute @workgroup_size(WORKGROUP_SIZE) fn main() { out[0] = 1u; }";
    engine.context().pipeline("fine_kernel", sum, 1).unwrap();
    engine.context().check("after the refused kernel").unwrap();
}

#[test]
fn an_impossible_allocation_is_an_error() {
    let Some(engine) = gpu_harness::engine(Precision::F32) else {
        return;
    };
    let bytes = u64::MAX / 4;
    let error = engine
        .context()
        .buffer("huge", bytes, wgpu::BufferUsages::STORAGE)
        .unwrap_err();
    assert!(
        matches!(error, GpuError::OutOfMemory { bytes: b, .. } if b == bytes),
        "{error:?}"
    );
    assert!(error.to_string().contains("huge"), "{error}");
}

#[test]
fn a_refused_buffer_descriptor_is_an_error() {
    // Without MAPPABLE_PRIMARY_BUFFERS (the discrete-GPU path) a storage buffer cannot be mapped.
    let Some(engine) = gpu_harness::engine_with(Precision::F32, false) else {
        return;
    };
    let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::MAP_READ;
    let error = engine
        .context()
        .buffer("mapped_storage", 256, usage)
        .unwrap_err();
    assert!(matches!(error, GpuError::Validation { .. }), "{error:?}");
    assert!(error.to_string().contains("mapped_storage"), "{error}");
}

#[test]
fn an_error_outside_a_scope_is_reported_not_a_panic() {
    let Some(engine) = gpu_harness::engine_with(Precision::F32, false) else {
        return;
    };
    let device = engine.context().device();
    // Invalid: a mapped storage buffer without MAPPABLE_PRIMARY_BUFFERS, with no error scope.
    let _buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("unscoped"),
        size: 256,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let error = engine.context().check("a test's own buffer").unwrap_err();
    assert!(matches!(error, GpuError::Validation { .. }), "{error:?}");
    assert!(error.to_string().contains("a test's own buffer"), "{error}");
    // Reported once: the next check is clean.
    engine.context().check("the next call").unwrap();
}
