//! Dense stereo per device: one frame of the example seabed scene through the small example pair
//! (320 × 256, 128 hypotheses, both depth maps), on the CPU and on the first GPU adapter.
//! Criterion's throughput is pixel·hypothesis·view (reference pixels × hypotheses × voting
//! cameras over both maps); frames per second are 1 / time. Lavapipe runs these kernels far
//! slower than the CPU path, so a software adapter is measured only with
//! `FLATPORT_BENCH_LAVAPIPE=1`. Run: `cargo bench --bench stereo`.

use std::path::Path;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};

use flatport::engine::{CpuEngine, Engine};
use flatport::io::rig_from_json_str;
use flatport::io::scene_json::scene_from_json_str;
use flatport::render::{RenderOptions, render_textured};
use flatport::stereo::gpu::GpuStereo;
use flatport::stereo::{Backend, StereoOptions, stereo_on};

const SCENE: &str = include_str!("../data/scenes/seabed.json");
const RIG: &str = include_str!("../data/rigs/small_stereo.json");

fn stereo(c: &mut Criterion) {
    let rig = rig_from_json_str(RIG, Path::new("small_stereo.json")).expect("example rig");
    let scene = scene_from_json_str(SCENE, Path::new("data/scenes/seabed.json"))
        .expect("example scene")
        .scene;
    let engine = Engine::Cpu(CpuEngine::new(None));
    let images: Vec<_> = (0..rig.cameras().len())
        .map(|k| {
            let options = RenderOptions {
                noise: 2.0,
                seed: k as u64,
                ..RenderOptions::default()
            };
            render_textured(&engine, &rig.refractive_camera(k), &scene, 0, &options)
                .expect("renders")
                .image
        })
        .collect();
    let options = StereoOptions {
        depth_range: Some((1.0, 2.2)),
        hypotheses: Some(128),
        ..StereoOptions::default()
    };
    let gpu = match GpuStereo::new(None) {
        Ok(gpu)
            if !gpu.context().is_software()
                || std::env::var_os("FLATPORT_BENCH_LAVAPIPE").is_some() =>
        {
            Some(gpu)
        }
        Ok(gpu) => {
            eprintln!(
                "{}: a software adapter, not measured (FLATPORT_BENCH_LAVAPIPE=1 to measure it)",
                gpu.context().adapter().name
            );
            None
        }
        Err(e) => {
            eprintln!("no GPU stereo bench: {e}");
            None
        }
    };
    let i = &rig.cameras()[0].intrinsics;
    let maps = rig.cameras().len() as u64;
    let work = u64::from(i.width * i.height) * 128u64 * maps * (maps - 1);
    let mut group = c.benchmark_group("stereo_320x256x128");
    group.sample_size(10);
    group.throughput(Throughput::Elements(work));
    group.bench_function("cpu", |b| {
        b.iter(|| stereo_on(&rig, &images, &options, Backend::Cpu, &|_| {}).unwrap())
    });
    if let Some(gpu) = &gpu {
        group.bench_function("gpu", |b| {
            b.iter(|| stereo_on(&rig, &images, &options, Backend::Gpu(gpu), &|_| {}).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, stereo);
criterion_main!(benches);
