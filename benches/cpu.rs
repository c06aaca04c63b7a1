//! The CPU engine, one thread, f64: back-projection (with and without lens distortion), forward
//! projection and triangulation on the scalar path (the model row by row) and the vector path
//! (`engine::cpu::lanes`), side by side, for batch sizes 10³–10⁶.
//!
//! Run: `cargo bench --bench cpu` (criterion; throughput in elements per second). Each group
//! holds both paths at every size, so their ratio comes from one run. `flatport bench` gives the
//! same figures without criterion, with all threads and cycles per item.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};

use flatport::engine::workload::{Workload, without_distortion};
use flatport::engine::{CpuEngine, CpuPath};
use flatport::io::rig_from_json_str;
use flatport::model::{RefractiveCamera, Rig};

const RIG: &str = include_str!("../data/example_rig.json");
const SIZES: [usize; 4] = [1_000, 10_000, 100_000, 1_000_000];

fn rig() -> Rig {
    rig_from_json_str(RIG, std::path::Path::new("example_rig.json")).expect("example rig parses")
}

/// The example rig without lens distortion: isolates the refraction from the undistortion.
fn pinhole_rig() -> Rig {
    without_distortion(&rig()).expect("still valid")
}

fn engines() -> [(&'static str, CpuEngine); 2] {
    [
        ("scalar", CpuEngine::with_path(Some(1), CpuPath::Scalar)),
        ("vector", CpuEngine::with_path(Some(1), CpuPath::Vector)),
    ]
}

/// A group per rig (pinhole, distorted) for `relation`: `run` on camera 0 on both paths at every size.
fn groups<const M: usize>(
    c: &mut Criterion,
    relation: &str,
    run: impl Fn(&CpuEngine, &RefractiveCamera, &Workload, &mut [[f64; M]], &mut [u32]),
) {
    for (variant, rig) in [("pinhole", pinhole_rig()), ("distorted", rig())] {
        let mut group = c.benchmark_group(format!("cpu_f64_{relation}_{variant}"));
        group.sample_size(10);
        let camera = rig.refractive_camera(0);
        for count in SIZES {
            let work = Workload::new(&rig, count);
            let (mut out, mut status) = (vec![[0.0; M]; count], vec![0; count]);
            group.throughput(Throughput::Elements(count as u64));
            for (path, engine) in engines() {
                group.bench_function(BenchmarkId::new(path, count), |b| {
                    b.iter(|| run(&engine, &camera, &work, &mut out, &mut status))
                });
            }
        }
        group.finish();
    }
}

fn backproject(c: &mut Criterion) {
    groups::<6>(c, "backproject", |engine, camera, work, rays, status| {
        engine.backproject(camera, &work.pixels, rays, status)
    });
}

fn project(c: &mut Criterion) {
    groups::<2>(c, "project", |engine, camera, work, pixels, status| {
        engine.project(camera, &work.points, pixels, status)
    });
}

fn triangulate(c: &mut Criterion) {
    let rig = rig();
    let mut group = c.benchmark_group("cpu_f64_triangulate");
    group.sample_size(10);
    let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
    for count in SIZES {
        let work = Workload::new(&rig, count);
        let (mut points, mut status) = (vec![[0.0; 4]; count], vec![0; count]);
        group.throughput(Throughput::Elements(count as u64));
        for (path, engine) in engines() {
            group.bench_function(BenchmarkId::new(path, count), |bench| {
                bench.iter(|| engine.triangulate(&a, &b, &work.matches, &mut points, &mut status))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, backproject, project, triangulate);
criterion_main!(benches);
