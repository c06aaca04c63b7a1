//! The physical limits a GPU figure is read against, measured on the context's own device:
//! the host link (how fast rows cross between host memory and the device, through wgpu as the
//! engine moves them) and the device's memory bandwidth (a copy kernel, timed like the relation
//! kernels). A kernel that reads and writes `b` bytes per item at `r` items/s uses `b·r` of the
//! second; an end-to-end call that moves `b` bytes per item over the link uses `b·r` of the first.

use std::time::Instant;

use super::context::{GpuContext, GpuError};
use super::dispatch::{Dispatch, GROUP, KernelTimer};

/// Largest buffer the roofs move: 256 MiB, large enough that a data-centre GPU's launch and
/// driver latencies are a few per cent of a transfer, capped by the adapter's storage binding.
pub const ROOF_BYTES: u64 = 256 << 20;

/// The host link's bandwidths, bytes per second.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkBandwidth {
    /// Host memory → device buffer (`Queue::write_buffer` and a wait), the fastest of the repeats.
    pub upload: f64,
    /// Device buffer → host memory (copy to a mappable buffer, map, copy into a `Vec`).
    pub download: f64,
    /// Bytes moved per transfer.
    pub bytes: u64,
}

/// The device memory's bandwidth as a copy kernel sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceBandwidth {
    /// Bytes read plus bytes written per second.
    pub bytes_per_s: f64,
    /// The clock that timed the kernel.
    pub timer: KernelTimer,
    /// Bytes copied per dispatch (read once and written once).
    pub bytes: u64,
}

/// The copy kernel: 16-byte words from `source` to `target`. Not composed from `shaders/`: it
/// uses nothing of the geometry, only the overrides every pipeline of the context sets.
const COPY_KERNEL: &str = "
override WORKGROUP_SIZE: u32 = 64u;
override RIG_LAYERS: u32 = 1u;
@group(0) @binding(0) var<storage, read> copy_in: array<vec4<u32>>;
@group(0) @binding(1) var<storage, read_write> copy_out: array<vec4<u32>>;
@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gid.x + gid.y * groups.x * WORKGROUP_SIZE;
    if (i < arrayLength(&copy_out)) {
        copy_out[i] = copy_in[i];
    }
}
";

/// Bytes the roofs move on `context`: [`ROOF_BYTES`] or the adapter's largest storage binding,
/// in whole workgroups of 16-byte words.
fn roof_bytes(context: &GpuContext) -> u64 {
    let word_group = 16 * GROUP as u64;
    (ROOF_BYTES.min(context.max_storage_binding()) / word_group * word_group).max(word_group)
}

/// A host pattern of `bytes` bytes, different in every word, so a copy that drops or repeats
/// words is seen.
fn pattern(bytes: u64) -> Vec<u8> {
    (0..bytes / 4)
        .flat_map(|k| (k as u32).wrapping_mul(2_654_435_761).to_le_bytes())
        .collect()
}

/// Measures the host link on `context`: the fastest of `repeats` uploads and of `repeats`
/// downloads of `roof_bytes` after one warm-up each, host clocks around each.
///
/// Errors: [`GpuError`] from the allocation or a transfer, and [`GpuError::Readback`] if the
/// bytes read back differ from those written.
pub fn link_bandwidth(context: &GpuContext, repeats: usize) -> Result<LinkBandwidth, GpuError> {
    let bytes = roof_bytes(context);
    let host = pattern(bytes);
    let usage =
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC;
    let device_buffer = context.buffer("link roof", bytes, usage)?;
    let staging = context.buffer(
        "link roof staging",
        bytes,
        wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
    )?;
    let (mut upload, mut download) = (f64::INFINITY, f64::INFINITY);
    let mut back = vec![0u8; bytes as usize];
    for round in 0..=repeats.max(1) {
        let started = Instant::now();
        context.queue().write_buffer(&device_buffer, 0, &host);
        context.wait()?;
        let seconds = started.elapsed().as_secs_f64();
        let started = Instant::now();
        let encoder = context
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("link roof"),
            });
        context.read_back(encoder, &[(&device_buffer, &staging, bytes)], |data| {
            back.copy_from_slice(data[0])
        })?;
        if round > 0 {
            upload = upload.min(seconds);
            download = download.min(started.elapsed().as_secs_f64());
        }
    }
    if back != host {
        return Err(GpuError::Readback(
            "the link roof read back other bytes than it wrote".into(),
        ));
    }
    Ok(LinkBandwidth {
        upload: bytes as f64 / upload,
        download: bytes as f64 / download,
        bytes,
    })
}

/// Measures the device memory's bandwidth on `context`: a copy kernel over `roof_bytes`, the
/// fastest of `repeats` dispatches after one warm-up (GPU timestamps where the adapter has them),
/// counting each byte read and each byte written. The copy is checked once against its source.
///
/// Errors: [`GpuError`] from the pipeline, an allocation or a dispatch, and
/// [`GpuError::Readback`] if the copy differs from its source.
pub fn device_bandwidth(context: &GpuContext, repeats: usize) -> Result<DeviceBandwidth, GpuError> {
    let bytes = roof_bytes(context);
    let pipeline = context.pipeline("device memory roof", COPY_KERNEL, 1)?;
    let source = context.buffer(
        "device roof source",
        bytes,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
    )?;
    let target = context.buffer(
        "device roof target",
        bytes,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
    )?;
    let staging = context.buffer(
        "device roof staging",
        bytes,
        wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
    )?;
    let host = pattern(bytes);
    context.queue().write_buffer(&source, 0, &host);
    let dispatch = Dispatch::new(context, &pipeline, "device memory roof");
    let bind_group = dispatch.bind(&[(0, &source), (1, &target)]);
    let groups = dispatch.grid((bytes / 16) as usize);
    let copied = dispatch.run(
        &[(&bind_group, groups)],
        &[(&target, &staging, bytes)],
        |data| data[0] == host.as_slice(),
    )?;
    if !copied {
        return Err(GpuError::Readback(
            "the copy kernel of the device memory roof wrote other bytes than it read".into(),
        ));
    }
    let (seconds, timer) = dispatch.seconds(&bind_group, groups, repeats.max(1))?;
    Ok(DeviceBandwidth {
        bytes_per_s: 2.0 * bytes as f64 / seconds,
        timer,
        bytes,
    })
}
