//! Dense stereo's figures for `flatport bench`: one frame of the example seabed scene through the
//! small example pair (320 × 256, 128 hypotheses, both depth maps for the consistency check), per
//! device: frames per second and pixel·hypothesis·view per second (reference pixels × hypotheses
//! × voting cameras, summed over the depth maps). The 1280 × 1024 figures are in
//! docs/performance.md.

use std::path::Path;
use std::time::Instant;

use flatport::engine::{CpuEngine, Engine};
use flatport::io::rig_from_json_str;
use flatport::io::scene_json::scene_from_json_str;
use flatport::render::{RenderOptions, render_textured};
use flatport::stereo::gpu::GpuStereo;
use flatport::stereo::{Backend, StereoOptions, stereo_on};

const SCENE: &str = include_str!("../../data/scenes/seabed.json");
const RIG: &str = include_str!("../../data/rigs/small_stereo.json");

/// Renders the scene, then times stereo on the CPU and (unless `no_gpu`) on the GPU `adapter`,
/// the fastest of `repeats` runs each, and prints a line per device.
pub fn stereo_figures(adapter: Option<&str>, no_gpu: bool, repeats: usize) -> anyhow::Result<()> {
    let rig = rig_from_json_str(RIG, Path::new("data/rigs/small_stereo.json"))?;
    let scene = scene_from_json_str(SCENE, Path::new("data/scenes/seabed.json"))?.scene;
    let engine = Engine::Cpu(CpuEngine::new(None));
    let images = (0..rig.cameras().len())
        .map(|k| {
            let options = RenderOptions {
                noise: 2.0,
                seed: k as u64,
                ..RenderOptions::default()
            };
            Ok(render_textured(&engine, &rig.refractive_camera(k), &scene, 0, &options)?.image)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let options = StereoOptions {
        depth_range: Some((1.0, 2.2)),
        ..StereoOptions::default()
    };
    let gpu = if no_gpu {
        None
    } else {
        match GpuStereo::new(adapter) {
            Ok(gpu) => Some(gpu),
            Err(e) => {
                eprintln!("no GPU stereo figure: {e}");
                None
            }
        }
    };
    let mut backends = vec![Backend::Cpu];
    if let Some(gpu) = &gpu {
        backends.push(Backend::Gpu(gpu));
    }
    let intrinsics = &rig.cameras()[0].intrinsics;
    let pixels = (intrinsics.width * intrinsics.height) as f64;
    let views = (rig.cameras().len() - 1) as f64;
    for backend in backends {
        let mut best = f64::INFINITY;
        let mut maps = 1;
        for _ in 0..repeats.max(1) {
            let started = Instant::now();
            let map = stereo_on(&rig, &images, &options, backend, &|_| {})?;
            best = best.min(started.elapsed().as_secs_f64());
            maps = map.runs;
        }
        let work = pixels * options.hypotheses as f64 * views * maps as f64;
        outln!(
            "stereo 320x256x{} {:36} {:8.3} frames/s  {:8.1} M pixel·hypothesis·view/s  ({:.2} s a frame, {maps} depth maps)",
            options.hypotheses,
            backend.describe(),
            1.0 / best,
            work / best / 1e6,
            best
        );
    }
    Ok(())
}
