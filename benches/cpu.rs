//! CPU f64 back-projection and forward projection, single thread, batch sizes 10³–10⁶.
//!
//! Run: `cargo bench --bench cpu`. Throughput is reported in elements per second.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::{Point2, Point3};

use flatport::io::rig_from_json_str;
use flatport::model::Rig;

const RIG: &str = include_str!("../data/example_rig.json");

fn rig() -> Rig {
    rig_from_json_str(RIG, std::path::Path::new("example_rig.json")).expect("example rig parses")
}

/// The example rig without lens distortion: isolates the refraction from the undistortion.
fn pinhole_rig() -> Rig {
    let rig = rig();
    let mut cameras = rig.cameras().to_vec();
    for camera in &mut cameras {
        camera.intrinsics.distortion = [0.0; 5];
    }
    Rig::new(cameras, rig.interface().clone()).expect("still valid")
}

/// Deterministic pseudo-random pixels over the image (a fixed LCG keeps the bench dependency-free).
fn pixels(count: usize) -> Vec<Point2<f64>> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..count).map(|_| Point2::new(next() * 1279.0, next() * 1023.0)).collect()
}

fn points(rig: &Rig, count: usize) -> Vec<Point3<f64>> {
    let camera = rig.refractive_camera(0);
    pixels(count)
        .iter()
        .enumerate()
        .map(|(i, p)| camera.backproject(p).expect("example pixels see the water").point_at(0.2 + (i % 50) as f64 * 0.1))
        .collect()
}

fn backproject(c: &mut Criterion) {
    let mut group = c.benchmark_group("cpu_f64_backproject");
    group.sample_size(10);
    for (variant, rig) in [("pinhole", pinhole_rig()), ("distorted", rig())] {
    let camera = rig.refractive_camera(0);
    for &count in &[1_000usize, 10_000, 100_000, 1_000_000] {
        let input = pixels(count);
        let mut out = vec![[0.0f64; 6]; count];
        group.throughput(Throughput::Elements(count as u64));
        group.bench_with_input(BenchmarkId::new(variant, count), &input, |b, input| {
            b.iter(|| {
                for (pixel, row) in input.iter().zip(out.iter_mut()) {
                    if let Ok(r) = camera.backproject(pixel) {
                        *row = [r.origin.x, r.origin.y, r.origin.z, r.dir.x, r.dir.y, r.dir.z];
                    }
                }
            })
        });
    }
    }
    group.finish();
}

fn project(c: &mut Criterion) {
    let mut group = c.benchmark_group("cpu_f64_project");
    group.sample_size(10);
    for (variant, rig) in [("pinhole", pinhole_rig()), ("distorted", rig())] {
    let camera = rig.refractive_camera(0);
    for &count in &[1_000usize, 10_000, 100_000, 1_000_000] {
        let input = points(&rig, count);
        let mut out = vec![[0.0f64; 2]; count];
        group.throughput(Throughput::Elements(count as u64));
        group.bench_with_input(BenchmarkId::new(variant, count), &input, |b, input| {
            b.iter(|| {
                for (point, row) in input.iter().zip(out.iter_mut()) {
                    if let Ok(p) = camera.project(point) {
                        *row = [p.x, p.y];
                    }
                }
            })
        });
    }
    }
    group.finish();
}

criterion_group!(benches, backproject, project);
criterion_main!(benches);
