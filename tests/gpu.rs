//! The GPU engine: every shader validated by naga (no GPU needed), host/WGSL layouts in sync, and
//! GPU-vs-CPU parity on lavapipe. With `CI` set, a missing Vulkan adapter fails the run: GPU tests
//! are never skipped silently there.

mod common;

use common::*;
use flatport::gpu::layout::GpuCamera;
use flatport::gpu::{GpuBackproject, GpuContext, shaders};
use flatport::model::NoSolution;
use nalgebra::Point2;

fn parse(name: &str, source: &str) -> naga::Module {
    naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)))
}

#[test]
fn every_shader_parses_and_validates() {
    for (name, source) in shaders::ALL {
        let module = parse(name, source);
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
            .validate(&module)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
    }
}

#[test]
fn host_camera_mirrors_the_wgsl_struct() {
    let module = parse("common", shaders::BACKPROJECT);
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).unwrap();
    let (handle, _) = module.types.iter().find(|(_, t)| t.name.as_deref() == Some("Camera")).expect("struct Camera");
    assert_eq!(layouter[handle].size as usize, std::mem::size_of::<GpuCamera>());
}

/// The context, or `None` (with a note) when there is no adapter outside CI.
fn context() -> Option<GpuContext> {
    match GpuContext::new(None) {
        Ok(context) => {
            eprintln!("GPU adapter: {} ({})", context.adapter().name, context.adapter().driver);
            Some(context)
        }
        Err(e) if std::env::var_os("CI").is_none() => {
            eprintln!("SKIPPED (no Vulkan adapter; CI fails here instead): {e}");
            None
        }
        Err(e) => panic!("CI needs a Vulkan adapter (scripts/test.sh installs lavapipe): {e}"),
    }
}

/// Tolerances for f32 kernels against the f64 reference (issue #3): directions 2e-6; origins on
/// the outer interface within 2e-6 m (f32 carries ~7 digits of metres-scale coordinates).
const DIR_TOL: f64 = 2e-6;
const ORIGIN_TOL: f64 = 2e-6;

#[test]
fn backproject_f32_matches_cpu_f64() {
    let Some(context) = context() else { return };
    let kernel = GpuBackproject::new(&context);
    for (name, rig) in configurations() {
        for k in 0..2 {
            let camera = rig.refractive_camera(k);
            let pixels: Vec<[f32; 2]> = (0..4000).map(|i| [((i * 37) % 1280) as f32 + 0.25, ((i * 91) % 1024) as f32 + 0.5]).collect();
            let mut rays = vec![[f32::NAN; 6]; pixels.len()];
            let mut status = vec![u32::MAX; pixels.len()];
            kernel.run(&context, &camera, &pixels, &mut rays, &mut status).unwrap();
            let (mut worst_dir, mut worst_origin): (f64, f64) = (0.0, 0.0);
            for ((p, ray), s) in pixels.iter().zip(&rays).zip(&status) {
                match camera.backproject(&Point2::new(p[0] as f64, p[1] as f64)) {
                    Ok(cpu) => {
                        assert_eq!(*s, 0, "{name} camera {k} pixel {p:?}");
                        let dir = nalgebra::Vector3::new(ray[3] as f64, ray[4] as f64, ray[5] as f64);
                        let origin = nalgebra::Vector3::new(ray[0] as f64, ray[1] as f64, ray[2] as f64);
                        worst_dir = worst_dir.max((dir - cpu.dir.into_inner()).norm());
                        worst_origin = worst_origin.max((origin - cpu.origin.coords).norm());
                    }
                    Err(e) => assert_eq!(*s, e.code(), "{name} camera {k} pixel {p:?}: CPU says {e}"),
                }
            }
            println!("{name:40} camera {k}: GPU f32 vs CPU f64 max |Δdir| {worst_dir:.1e}, max |Δorigin| {worst_origin:.1e} m");
            assert!(worst_dir < DIR_TOL && worst_origin < ORIGIN_TOL, "{name} camera {k}");
        }
    }
}

#[test]
fn backproject_reports_no_answer_where_the_cpu_does() {
    let Some(context) = context() else { return };
    let kernel = GpuBackproject::new(&context);
    // Light from a denser "air" (1.333) into a thinner last medium (1.0): steep pixels are totally
    // internally reflected. Pixels far outside a strongly distorted image lie beyond the lens fold.
    let cases = [
        stereo_rig(unit(0.0, 0.0, 1.0), 0.02, vec![], 1.333, 1.0, false),
        stereo_rig(unit(0.05, 0.0, 1.0), 0.02, vec![], 1.0, 1.333, true),
    ];
    let mut seen = std::collections::BTreeSet::new();
    for rig in &cases {
        let camera = rig.refractive_camera(0);
        let pixels: Vec<[f32; 2]> = (0..60).flat_map(|i| (0..50).map(move |j| [-4000.0 + i as f32 * 157.0, -3000.0 + j as f32 * 143.0])).collect();
        let mut rays = vec![[0.0f32; 6]; pixels.len()];
        let mut status = vec![u32::MAX; pixels.len()];
        kernel.run(&context, &camera, &pixels, &mut rays, &mut status).unwrap();
        let mut disagreements = 0;
        for (p, s) in pixels.iter().zip(&status) {
            let cpu = camera.backproject(&Point2::new(p[0] as f64, p[1] as f64)).err().map_or(0, NoSolution::code);
            seen.insert(cpu);
            if cpu != *s {
                disagreements += 1;
            }
        }
        // f32 and f64 may differ only for pixels within rounding of a boundary.
        assert!(disagreements <= pixels.len() / 500, "{disagreements} of {} statuses differ", pixels.len());
    }
    for code in [0, NoSolution::OutsideLens.code(), NoSolution::TotalInternalReflection.code()] {
        assert!(seen.contains(&code), "the cases must exercise status {code}");
    }
}

#[test]
fn batch_larger_than_one_chunk() {
    let Some(context) = context() else { return };
    let kernel = GpuBackproject::new(&context);
    let (_, rig) = configurations().remove(2);
    let camera = rig.refractive_camera(0);
    let n = flatport::gpu::backproject::CHUNK_ITEMS + 12_345;
    let pixels: Vec<[f32; 2]> = (0..n).map(|i| [(i % 1280) as f32, ((i / 1280) % 1024) as f32]).collect();
    let mut rays = vec![[f32::NAN; 6]; n];
    let mut status = vec![u32::MAX; n];
    kernel.run(&context, &camera, &pixels, &mut rays, &mut status).unwrap();
    assert!(status.iter().all(|&s| s == 0), "every pixel of the image sees the water");
    for i in (0..n).step_by(997).chain([n - 1]) {
        let cpu = camera.backproject(&Point2::new(pixels[i][0] as f64, pixels[i][1] as f64)).unwrap();
        let dir = nalgebra::Vector3::new(rays[i][3] as f64, rays[i][4] as f64, rays[i][5] as f64);
        assert!((dir - cpu.dir.into_inner()).norm() < DIR_TOL, "item {i}");
    }
}
