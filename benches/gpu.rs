//! GPU kernels on the first Vulkan adapter (lavapipe without a GPU), f32 and f64, batch sizes
//! 10⁴–10⁷: `end_to_end` (upload, dispatch, results in host memory) and `kernel` (dispatch only,
//! data resident; up to one chunk). Run: `cargo bench --bench gpu`. Without an adapter the bench
//! says so and measures nothing.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};

use flatport::engine::GpuEngine;
use flatport::engine::gpu::kernels;
use flatport::engine::workload::Workload;
use flatport::gpu::MAX_CHUNK_ITEMS;
use flatport::gpu::{GpuContext, Precision};
use flatport::io::rig_from_json_str;

const RIG: &str = include_str!("../data/example_rig.json");
const SIZES: [usize; 4] = [10_000, 100_000, 1_000_000, 10_000_000];

fn kernels(c: &mut Criterion) {
    let rig = rig_from_json_str(RIG, std::path::Path::new("example_rig.json"))
        .expect("example rig parses");
    let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
    let work = Workload::new(&rig, *SIZES.last().unwrap());
    for precision in [Precision::F32, Precision::F64] {
        let gpu = match GpuContext::new(None)
            .map_err(|e| e.to_string())
            .and_then(|c| GpuEngine::new(c, precision).map_err(|e| e.to_string()))
        {
            Ok(gpu) => gpu,
            Err(e) => {
                eprintln!("no GPU bench ({precision}): {e}");
                return;
            }
        };
        let mut group = c.benchmark_group(format!("gpu_{precision}"));
        group.sample_size(10);
        for &n in &SIZES {
            group.throughput(Throughput::Elements(n as u64));
            let mut out6 = vec![[0.0; 6]; n];
            let mut out4 = vec![[0.0; 4]; n];
            let mut out2 = vec![[0.0; 2]; n];
            let mut status = vec![0; n];
            group.bench_function(BenchmarkId::new("backproject/end_to_end", n), |bench| {
                bench.iter(|| {
                    gpu.backproject(&a, &work.pixels[..n], &mut out6, &mut status)
                        .unwrap()
                })
            });
            group.bench_function(BenchmarkId::new("project/end_to_end", n), |bench| {
                bench.iter(|| {
                    gpu.project(&a, &work.points[..n], &mut out2, &mut status)
                        .unwrap()
                })
            });
            group.bench_function(BenchmarkId::new("triangulate/end_to_end", n), |bench| {
                bench.iter(|| {
                    gpu.triangulate(&a, &b, &work.matches[..n], &mut out4, &mut status)
                        .unwrap()
                })
            });
            if n <= MAX_CHUNK_ITEMS / 2 {
                // kernel_seconds times its own dispatches; criterion reports their sum per iteration.
                group.bench_function(BenchmarkId::new("backproject/kernel", n), |bench| {
                    bench.iter_custom(|iters| {
                        let (s, _) = gpu
                            .kernel_seconds::<2, 6>(
                                &kernels::BACKPROJECT,
                                &a,
                                &a,
                                &work.pixels[..n],
                                1,
                            )
                            .unwrap();
                        std::time::Duration::from_secs_f64(s * iters as f64)
                    })
                });
            }
        }
        group.finish();
    }
}

criterion_group!(benches, kernels);
criterion_main!(benches);
