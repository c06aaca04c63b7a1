//! Dense stereo's figures for `flatport bench`: one frame of the example seabed scene through the
//! example pair, 128 hypotheses, both depth maps for the consistency check, per device: frames
//! per second and pixel·hypothesis·view per second (reference pixels × hypotheses × voting
//! cameras, summed over the depth maps). At 320 × 256 on the CPU and a hardware GPU; at the
//! issue's 1280 × 1024 on a hardware GPU only (the CPU takes 15–30 s a frame there:
//! docs/performance.md). A software adapter gets no GPU figure: lavapipe runs these kernels on
//! the same cores, about 4× slower than the CPU path. Each line ends with the fastest run's
//! seconds per stage (the cost volume, aggregation with selection, ...), summed over its maps.

use std::path::Path;
use std::time::Instant;

use flatport::io::rig_from_json_str;
use flatport::model::Rig;
use flatport::render::RenderOptions;
use flatport::stereo::gpu::GpuStereo;
use flatport::stereo::{Backend, GreyImage, StereoOptions, stereo_on};

use crate::cli::demo::{SMALL_PAIR, render_seabed};

/// The example pair with its images `scale` times wider and higher (the same field of view).
fn scaled_rig(scale: f64) -> anyhow::Result<Rig> {
    let mut json: serde_json::Value = serde_json::from_str(SMALL_PAIR)?;
    for camera in json["cameras"].as_array_mut().into_iter().flatten() {
        for key in ["width", "height"] {
            camera[key] = serde_json::json!((camera[key].as_f64().unwrap_or(0.0) * scale) as u64);
        }
        for key in ["fx", "fy", "cx", "cy"] {
            camera[key] = serde_json::json!(camera[key].as_f64().unwrap_or(0.0) * scale);
        }
    }
    Ok(rig_from_json_str(
        &json.to_string(),
        Path::new("data/rigs/small_stereo.json"),
    )?)
}

/// Times stereo on the CPU at 320 × 256 and, unless `no_gpu`, on the GPU `adapter` when it is a
/// hardware one, at 320 × 256 and 1280 × 1024 (there also with SGM walking 2 and 1 path lines a
/// workgroup); the fastest of `repeats` runs each, a line each.
pub(super) fn figures(adapter: Option<&str>, no_gpu: bool, repeats: usize) -> anyhow::Result<()> {
    let mut gpu = if no_gpu {
        None
    } else {
        match GpuStereo::new(adapter) {
            Ok(gpu) if gpu.context().is_software() => {
                eprintln!(
                    "no GPU stereo figure on the software adapter '{}' (it runs on these same cores, slower than the CPU path)",
                    gpu.context().adapter().name
                );
                None
            }
            Ok(gpu) => Some(gpu),
            Err(e) => {
                eprintln!("no GPU stereo figure: {e}");
                None
            }
        }
    };
    for scale in [1.0, 4.0] {
        let mut backends = Vec::new();
        if scale == 1.0 {
            backends.push(Backend::Cpu);
        }
        if let Some(gpu) = &gpu {
            backends.push(Backend::Gpu(gpu));
        }
        if backends.is_empty() {
            continue;
        }
        let rig = scaled_rig(scale)?;
        let noisy = RenderOptions {
            noise: 2.0,
            ..RenderOptions::default()
        };
        let images = render_seabed(&rig, &noisy)?;
        for backend in backends {
            frame_figure(&rig, &images, backend, repeats, "")?;
        }
        // At the full size on a hardware GPU, SGM's other groupings (the default walks 8 path
        // lines a workgroup): which suits the GPU is measured, not guessed.
        if scale == 4.0
            && let Some(mut regrouped) = gpu.take()
        {
            // The same device, pipelines and buffers (the last figures: the option is taken).
            for lines in [2, 1] {
                regrouped = regrouped.with_sgm_lines(lines);
                let label = format!(
                    ", SGM {lines} line{} a workgroup",
                    if lines > 1 { "s" } else { "" }
                );
                frame_figure(&rig, &images, Backend::Gpu(&regrouped), repeats, &label)?;
            }
        }
    }
    Ok(())
}

/// One device's line: frames per second and pixel·hypothesis·view per second.
fn frame_figure(
    rig: &Rig,
    images: &[GreyImage],
    backend: Backend,
    repeats: usize,
    label: &str,
) -> anyhow::Result<()> {
    // The figure: 128 hypotheses, as given (not the step rule's count).
    let hypotheses = 128;
    let options = StereoOptions {
        depth_range: Some((1.0, 2.2)),
        hypotheses: Some(hypotheses),
        ..StereoOptions::default()
    };
    let intrinsics = &rig.cameras()[0].intrinsics;
    let pixels = f64::from(intrinsics.width * intrinsics.height);
    let views = (rig.cameras().len() - 1) as f64;
    // One warm-up (pipelines, buffers), then the fastest of the repeats.
    let mut maps = stereo_on(rig, images, &options, backend, &|_| {})?.runs;
    let mut best = f64::INFINITY;
    let mut stages = Vec::new();
    for _ in 0..repeats.max(1) {
        let started = Instant::now();
        let map = stereo_on(rig, images, &options, backend, &|_| {})?;
        let seconds = started.elapsed().as_secs_f64();
        maps = map.runs;
        if seconds < best {
            best = seconds;
            stages = map.stage_seconds;
        }
    }
    let stages: Vec<String> = stages
        .iter()
        .map(|(stage, seconds)| format!("{stage} {:.1} ms", seconds * 1e3))
        .collect();
    let work = pixels * hypotheses as f64 * views * maps as f64;
    outln!(
        "stereo {}x{}x{} {:36} {:8.3} frames/s  {:8.1} M pixel·hypothesis·view/s  ({:.3} s a frame, {maps} depth maps: {})",
        intrinsics.width,
        intrinsics.height,
        hypotheses,
        format!("{}{label}", backend.describe()),
        1.0 / best,
        work / best / 1e6,
        best,
        stages.join(", ")
    );
    Ok(())
}
