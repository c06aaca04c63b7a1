//! The GPU figures of `flatport bench`, on one adapter: its roofs (the host link both ways, the
//! device memory by a copy kernel); per precision each relation's kernel alone and end to end
//! (host rows in f64 and in f32, forward projection streamed and in one chunk); and in f64 the
//! affine-grid sweep, the reprojection and scene sweeps and the calibration backend's stencil
//! calls.

use std::time::Instant;

use anyhow::Context;

use flatport::calib::{Candidate, CostBackend, CostKind, GpuBackend};
use flatport::engine::GpuEngine;
use flatport::engine::gpu::kernels;
use flatport::gpu::roofs::{device_bandwidth, link_bandwidth};
use flatport::gpu::{GpuContext, KernelSource, Precision, STREAM_CHUNK_ROWS};
use flatport::model::RefractiveCamera;

use super::record::{Measure, Recorder, Roofs};
use super::{Setup, fastest};

/// Candidates per call of the stencil figures (a finite-difference stencil's size) and calls timed.
pub(super) const STENCIL: usize = 7;
const STENCIL_CALLS: usize = 20;

/// Every GPU figure on the adapter `adapter` names (else the best); returns the adapter's
/// description and its roofs.
pub(super) fn figures(
    setup: &Setup,
    adapter: Option<&str>,
    repeats: usize,
    recorder: &mut Recorder,
) -> anyhow::Result<(String, Roofs)> {
    let context = GpuContext::new(adapter)
        .context("the GPU paths need a Vulkan adapter (or pass --no-gpu)")?;
    let summary = context.adapter();
    let name = format!("{} ({})", summary.name, summary.driver);
    eprintln!("GPU adapter: {name}");
    let roofs = measure_roofs(&context, repeats)?;
    recorder.gpu = Some((name.clone(), roofs));
    let has_f64 = summary.f64;
    relation_figures(
        setup,
        GpuEngine::new(context, Precision::F32)?,
        repeats,
        recorder,
    )?;
    if !has_f64 {
        eprintln!("the adapter has no SHADER_F64: no f64 figures");
        return Ok((name, roofs));
    }
    let gpu = GpuEngine::new(GpuContext::new(adapter)?, Precision::F64)?;
    let gpu = relation_figures(setup, gpu, repeats, recorder)?;
    // The fused affine-grid kernel runs in f64 whatever the engine's precision: one figure.
    cost_figures(setup, &gpu, repeats, recorder)?;
    Ok((name, roofs))
}

/// The host link's and the device memory's bandwidths, printed.
fn measure_roofs(context: &GpuContext, repeats: usize) -> anyhow::Result<Roofs> {
    let link = link_bandwidth(context, repeats).context("measuring the host link")?;
    let device = device_bandwidth(context, repeats).context("measuring the device memory")?;
    outln!(
        "host link ({} MiB through wgpu): upload {:.2} GB/s, download {:.2} GB/s",
        link.bytes >> 20,
        link.upload / 1e9,
        link.download / 1e9
    );
    outln!(
        "device memory (copy kernel over {} MiB, read + write, {}): {:.1} GB/s",
        device.bytes >> 20,
        device.timer.name(),
        device.bytes_per_s / 1e9
    );
    Ok(Roofs { link, device })
}

/// Back-projection, forward projection and triangulation on `gpu`: kernel alone, end to end
/// from f64 and f32 host rows, and forward projection streamed and in one chunk. Hands the
/// engine back.
fn relation_figures(
    setup: &Setup,
    mut gpu: GpuEngine,
    repeats: usize,
    recorder: &mut Recorder,
) -> anyhow::Result<GpuEngine> {
    let (a, b, work) = (&setup.a, &setup.b, &setup.work);
    let n = work.pixels.len();
    let p = gpu.precision().name();
    let mut status = vec![0u32; n];
    let (mut out6, mut out4, mut out2) = (vec![[0.0; 6]; n], vec![[0.0; 4]; n], vec![[0.0; 2]; n]);
    // The workload as a pipeline with f32 data holds it (converted before timing).
    let points_f32: Vec<[f32; 3]> = work.points.iter().map(|r| r.map(|v| v as f32)).collect();
    let pixels_f32: Vec<[f32; 2]> = work.pixels.iter().map(|r| r.map(|v| v as f32)).collect();
    let (mut out2_f32, mut out6_f32) = (vec![[0.0f32; 2]; n], vec![[0.0f32; 6]; n]);

    kernel_figure(setup, &gpu, &kernels::BACKPROJECT, a, a, repeats, recorder)?;
    let t = fastest(repeats, || {
        Ok(gpu.backproject(a, &work.pixels, &mut out6, &mut status)?)
    })?;
    recorder.record(Measure::gpu("backproject", p, "end_to_end"), t);
    let t = fastest(repeats, || {
        Ok(gpu.backproject(a, &pixels_f32, &mut out6_f32, &mut status)?)
    })?;
    recorder.record(Measure::gpu("backproject", p, "end_to_end_f32_host"), t);

    kernel_figure(setup, &gpu, &kernels::PROJECT, a, a, repeats, recorder)?;
    let [streamed, one_chunk] = stream_figures(setup, &mut gpu, repeats, &mut out2, &mut status)?;
    // `end_to_end` is the chunking the engine chooses for this adapter (`default_stream_chunk_rows`:
    // one chunk on lavapipe, the ring on a hardware GPU).
    let chosen = if gpu.stream_chunk_rows() == STREAM_CHUNK_ROWS {
        streamed
    } else {
        one_chunk
    };
    recorder.record(Measure::gpu("project", p, "end_to_end"), chosen);
    recorder.record(Measure::gpu("project", p, "end_to_end_streamed"), streamed);
    recorder.record(
        Measure::gpu("project", p, "end_to_end_one_chunk"),
        one_chunk,
    );
    // The same with the host's data in f32 (no conversion where the kernel is f32).
    let t = fastest(repeats, || {
        Ok(gpu.project(a, &points_f32, &mut out2_f32, &mut status)?)
    })?;
    recorder.record(Measure::gpu("project", p, "end_to_end_f32_host"), t);

    kernel_figure(setup, &gpu, &kernels::TRIANGULATE, a, b, repeats, recorder)?;
    let t = fastest(repeats, || {
        Ok(gpu.triangulate(a, b, &work.matches, &mut out4, &mut status)?)
    })?;
    recorder.record(Measure::gpu("triangulate", p, "end_to_end"), t);

    let chains = super::device::chains(&gpu, a, b, &work.matches, repeats)?;
    for (label, chain) in [
        (super::device::LABEL, &chains.fused),
        (super::device::LABEL_UNFUSED, &chains.unfused),
    ] {
        let kernel = Measure::gpu(label, p, "kernel").over(n, chain.timer);
        recorder.record(kernel, chain.kernel);
        recorder.record(Measure::gpu(label, p, "end_to_end"), chain.end_to_end);
    }
    Ok(gpu)
}

/// One relation's kernel alone over the batch's first rows (one chunk at most), the data already
/// on the device.
fn kernel_figure(
    setup: &Setup,
    gpu: &GpuEngine,
    kernel: &KernelSource,
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    repeats: usize,
    recorder: &mut Recorder,
) -> anyhow::Result<()> {
    let work = &setup.work;
    let n = work.pixels.len();
    let (name, (seconds, timer), items) = match kernel.name {
        name if name == kernels::BACKPROJECT.name => {
            let rows = &work.pixels[..n.min(gpu.chunk_rows::<2, 6>())];
            let time = gpu.kernel_seconds::<2, 6>(kernel, a, b, rows, repeats)?;
            ("backproject", time, rows.len())
        }
        name if name == kernels::PROJECT.name => {
            let rows = &work.points[..n.min(gpu.chunk_rows::<3, 2>())];
            let time = gpu.kernel_seconds::<3, 2>(kernel, a, b, rows, repeats)?;
            ("project", time, rows.len())
        }
        _ => {
            let rows = &work.matches[..n.min(gpu.chunk_rows::<4, 4>())];
            let time = gpu.kernel_seconds::<4, 4>(kernel, a, b, rows, repeats)?;
            ("triangulate", time, rows.len())
        }
    };
    let measure = Measure::gpu(name, gpu.precision().name(), "kernel").over(items, timer.name());
    recorder.record(measure, seconds);
    Ok(())
}

/// Forward projection end to end streamed through the ring in chunks of [`STREAM_CHUNK_ROWS`],
/// and in as few chunks as the bindings allow (nothing overlaps), round by round in turn (a
/// shared machine's load drifts); the first round warms up. Seconds of each.
fn stream_figures(
    setup: &Setup,
    gpu: &mut GpuEngine,
    repeats: usize,
    pixels: &mut [[f64; 2]],
    status: &mut [u32],
) -> anyhow::Result<[f64; 2]> {
    let chosen = gpu.stream_chunk_rows();
    let mut best = [f64::INFINITY; 2];
    for round in 0..=repeats {
        for (k, rows) in [STREAM_CHUNK_ROWS, usize::MAX].into_iter().enumerate() {
            gpu.set_stream_chunk_rows(rows);
            let start = Instant::now();
            gpu.project(&setup.a, &setup.work.points, pixels, status)?;
            if round > 0 {
                best[k] = best[k].min(start.elapsed().as_secs_f64());
            }
        }
    }
    gpu.set_stream_chunk_rows(chosen);
    Ok(best)
}

/// The affine-grid sweep over the sweep workload, and a stencil refinement's small calls
/// ([`STENCIL`] candidates each) with the corner rows kept on the device and uploaded again
/// before every call.
fn cost_figures(
    setup: &Setup,
    gpu: &GpuEngine,
    repeats: usize,
    recorder: &mut Recorder,
) -> anyhow::Result<()> {
    let backend = GpuBackend::new(&setup.sweep_data, gpu);
    let t = fastest(repeats.min(2), || {
        Ok(backend
            .costs(CostKind::AffineGrid, &setup.sweep_candidates)
            .map(drop)?)
    })?;
    recorder.record(Measure::gpu("sweep", "f64", "end_to_end"), t);
    // The reprojection and scene sweeps (the air layer held at the rig's) over a quarter of the
    // cells (128² for the 256²), in the engine's precision.
    let cells: Vec<Candidate> = setup
        .sweep_candidates
        .iter()
        .take(setup.sweep_candidates.len().div_ceil(4))
        .map(|c| Candidate {
            normal: c.normal,
            air_distance: setup.air_distance,
        })
        .collect();
    for (kernel, kind) in [
        ("sweep_reprojection", CostKind::Reprojection),
        ("sweep_scene", CostKind::Scene),
    ] {
        let t = fastest(repeats.min(2), || {
            Ok(backend.costs(kind, &cells).map(drop)?)
        })?;
        let items = cells.len() * setup.sweep_data.corners.len();
        let precision = gpu.precision().name();
        recorder.record(
            Measure::gpu(kernel, precision, "end_to_end").over(items, "host"),
            t,
        );
    }
    let stencil: Vec<Candidate> = setup
        .sweep_candidates
        .iter()
        .take(STENCIL)
        .map(|c| Candidate {
            normal: c.normal,
            air_distance: setup.air_distance,
        })
        .collect();
    for (kernel, kind) in [
        ("stencil_reprojection", CostKind::Reprojection),
        ("stencil_affine_grid", CostKind::AffineGrid),
    ] {
        // The two ways in turn, round by round; the first round warms up.
        let mut best = [f64::INFINITY; 2];
        for round in 0..=repeats {
            for (k, evict) in [false, true].into_iter().enumerate() {
                let start = Instant::now();
                for _ in 0..STENCIL_CALLS {
                    if evict {
                        backend.evict();
                    }
                    backend.costs(kind, &stencil)?;
                }
                if round > 0 {
                    best[k] = best[k].min(start.elapsed().as_secs_f64());
                }
            }
        }
        for (stage, t) in ["resident", "uploaded_each_call"].into_iter().zip(best) {
            let items = stencil.len() * STENCIL_CALLS;
            recorder.record(Measure::gpu(kernel, "f64", stage).over(items, "host"), t);
        }
    }
    Ok(())
}
