//! The embedding API of issue 12: ray maps against `Engine::backproject` on every pixel, the f32
//! entry points against the f64 ones, a GPU context on a caller's device, owned calibration
//! backends, and `flatport export` on the command line.
//!
//! Tolerances: the CPU ray map runs the same f64 reference as `backproject`, so 1e-12 (the issue's
//! bound) holds with room; the GPU f64 kernels agree with the CPU to 1e-12 relative (DESIGN §5:
//! |Δ| ≤ 1e-12 · max(1, |cpu|)), f32 within 2e-6 (directions) and 1e-6 m (origins, about 30 mm
//! from the camera at f32's 6e-8 relative resolution, with the kernels' rounding).

mod gpu_harness;

use std::process::Command;
use std::sync::Arc;

use flatport::calib::{CostBackend, CostKind, CpuBackend, SceneSpec, StereoData, simulate};
use flatport::engine::raymap::{backproject_rows, rows_per_band};
use flatport::engine::{CpuEngine, Engine, GpuEngine};
use flatport::gpu::{GpuContext, Precision};
use flatport::io::npy::read_npy;
use flatport::io::read_rig;
use flatport::model::Rig;

fn example_rig() -> Rig {
    read_rig(concat!(env!("CARGO_MANIFEST_DIR"), "/data/example_rig.json").as_ref()).unwrap()
}

/// Every pixel (u, v) = (column, row) of the camera, row-major.
fn all_pixels(width: u32, height: u32) -> Vec<[f64; 2]> {
    (0..height)
        .flat_map(|v| (0..width).map(move |u| [f64::from(u), f64::from(v)]))
        .collect()
}

fn reference(engine: &Engine, rig: &Rig, k: usize) -> (Vec<[f64; 6]>, Vec<u32>) {
    let camera = rig.refractive_camera(k);
    let (w, h) = (camera.intrinsics().width, camera.intrinsics().height);
    let pixels = all_pixels(w, h);
    let (mut rays, mut status) = (vec![[0.0; 6]; pixels.len()], vec![0; pixels.len()]);
    engine
        .backproject(&camera, &pixels, &mut rays, &mut status)
        .unwrap();
    (rays, status)
}

/// The ray map of camera `k` in bands of `band` rows.
fn raymap(engine: &Engine, rig: &Rig, k: usize, band: u32) -> (Vec<[f64; 6]>, Vec<u32>) {
    let camera = rig.refractive_camera(k);
    let (w, h) = (camera.intrinsics().width, camera.intrinsics().height);
    let (mut rays, mut status) = (vec![[0.0; 6]; (w * h) as usize], vec![0; (w * h) as usize]);
    for first in (0..h).step_by(band as usize) {
        let rows = band.min(h - first);
        let range = (first * w) as usize..((first + rows) * w) as usize;
        backproject_rows(
            engine,
            &camera,
            first,
            rows,
            &mut rays[range.clone()],
            &mut status[range],
        )
        .unwrap();
    }
    (rays, status)
}

#[test]
fn cpu_raymap_equals_backproject_on_every_pixel_of_a_1280x1024_camera() {
    let rig = example_rig();
    let engine = Engine::Cpu(CpuEngine::new(None));
    for k in 0..2 {
        let (expected, expected_status) = reference(&engine, &rig, k);
        assert_eq!(expected.len(), 1280 * 1024);
        // A band that does not divide the height, so the last band is short.
        let (rays, status) = raymap(&engine, &rig, k, 300);
        assert_eq!(status, expected_status);
        let answered = status.iter().filter(|&&s| s == 0).count();
        assert!(answered > 1280 * 1000, "{answered} pixels with a ray");
        let worst = rays
            .iter()
            .zip(&expected)
            .zip(&status)
            .filter(|(_, s)| **s == 0)
            .flat_map(|((a, b), _)| (0..6).map(move |i| (a[i] - b[i]).abs()))
            .fold(0.0, f64::max);
        assert!(worst <= 1e-12, "camera {k}: {worst}");
    }
    assert_eq!(rows_per_band(1280, 1 << 20), 819);
    assert_eq!(rows_per_band(5_000_000, 1 << 20), 1);
}

#[test]
fn gpu_raymap_from_the_in_shader_grid_agrees_with_the_cpu() {
    let rig = example_rig();
    let cpu = Engine::Cpu(CpuEngine::new(None));
    let (expected, expected_status) = reference(&cpu, &rig, 1);
    for (precision, bound) in [(Precision::F64, 1e-12), (Precision::F32, 2e-6)] {
        let Some(gpu) = gpu_harness::engine(precision) else {
            return;
        };
        if precision == Precision::F64 && !gpu.context().adapter().f64 {
            continue;
        }
        let (rays, status) = raymap(&Engine::Gpu(gpu), &rig, 1, 500);
        let mut worst = 0.0f64;
        for ((a, b), (s, t)) in rays
            .iter()
            .zip(&expected)
            .zip(status.iter().zip(&expected_status))
        {
            if *s == 0 && *t == 0 {
                for i in 0..6 {
                    worst = worst.max((a[i] - b[i]).abs() / b[i].abs().max(1.0));
                }
            }
        }
        // Statuses agree except, in f32, at the rounding edge of the lens model's region.
        let differing = status
            .iter()
            .zip(&expected_status)
            .filter(|(a, b)| a != b)
            .count();
        assert!(
            differing <= if precision == Precision::F64 { 0 } else { 64 },
            "{precision}: {differing} statuses differ"
        );
        assert!(worst <= bound, "{precision}: {worst}");
    }
}

#[test]
fn f32_entry_points_are_the_f64_answers_rounded() {
    let rig = example_rig();
    let engine = Engine::Cpu(CpuEngine::new(None));
    let (left, right) = (rig.refractive_camera(0), rig.refractive_camera(1));
    // More rows than one block of the widening, so blocks join up.
    let n = flatport::engine::F32_BLOCK_ROWS + 1000;
    let points: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let t = i as f32 / n as f32;
            [0.6 * (t - 0.5), 0.4 * (0.5 - t * t), 0.5 + 2.5 * t]
        })
        .collect();
    let wide: Vec<[f64; 3]> = points.iter().map(|p| p.map(f64::from)).collect();
    let (mut px32, mut px64, mut s32, mut s64) = (
        vec![[0f32; 2]; n],
        vec![[0.0; 2]; n],
        vec![0; n],
        vec![0; n],
    );
    engine
        .project_f32(&left, &points, &mut px32, &mut s32)
        .unwrap();
    engine.project(&left, &wide, &mut px64, &mut s64).unwrap();
    assert_eq!(s32, s64);
    assert!(
        px32.iter()
            .zip(&px64)
            .all(|(a, b)| a[0] == b[0] as f32 && a[1] == b[1] as f32)
    );
    let mut px_r = vec![[0f32; 2]; n];
    engine
        .project_f32(&right, &points, &mut px_r, &mut s32)
        .unwrap();
    let matches: Vec<[f32; 4]> = px32
        .iter()
        .zip(&px_r)
        .map(|(l, r)| [l[0], l[1], r[0], r[1]])
        .collect();
    let mut found = vec![[0f32; 4]; n];
    engine
        .triangulate_f32(&left, &right, &matches, &mut found, &mut s32)
        .unwrap();
    // Pixels rounded to f32 (~3e-5 px at 1000 px) move the point by well under a millimetre.
    assert!(
        found
            .iter()
            .zip(&points)
            .zip(&s32)
            .all(|((f, p), &s)| s == 0 && (0..3).all(|i| (f[i] - p[i]).abs() < 1e-3))
    );
    let mut rays = vec![[0f32; 6]; n];
    engine
        .backproject_f32(&left, &px32, &mut rays, &mut s32)
        .unwrap();
    assert!(
        rays.iter()
            .all(|r| ((r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt() - 1.0).abs() < 1e-6)
    );
    let mut vops = vec![[0f32; 6]; n];
    engine.vop_f32(&left, &points, &mut vops, &mut s32).unwrap();
    assert!(s32.iter().all(|&s| s == 0));
}

#[test]
fn a_gpu_context_on_the_callers_device() {
    if gpu_harness::engine(Precision::F32).is_none() {
        return;
    }
    // The caller's own instance, adapter, device and queue.
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::VULKAN;
    let instance = wgpu::Instance::new(desc);
    let adapter =
        pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions::default()))
            .unwrap();
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        required_features: adapter.features() & wgpu::Features::SHADER_F64,
        required_limits: adapter.limits(),
        ..Default::default()
    }))
    .unwrap();
    let context = GpuContext::from_device(&adapter, device.clone(), queue.clone());
    assert_eq!(context.adapter().name, adapter.get_info().name);
    let gpu = GpuEngine::new(context, Precision::F32).unwrap();
    let rig = example_rig();
    let camera = rig.refractive_camera(0);
    let pixels = vec![[640.0, 512.0], [100.0, 900.0]];
    let (mut rays, mut status) = (vec![[0.0; 6]; 2], vec![0; 2]);
    gpu.backproject(&camera, &pixels, &mut rays, &mut status)
        .unwrap();
    let mut expected = vec![[0.0; 6]; 2];
    CpuEngine::new(Some(1)).backproject(&camera, &pixels, &mut expected, &mut status);
    for (a, b) in rays.iter().zip(&expected) {
        assert!((0..6).all(|i| (a[i] - b[i]).abs() < 2e-6), "{a:?} vs {b:?}");
    }
    // The caller's device still works beside flatport's kernels.
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("caller"),
        size: 16,
        usage: wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    queue.write_buffer(&buffer, 0, &[0; 16]);
    queue.submit([]);
}

#[test]
fn calibration_backends_can_own_their_data() {
    let rig = example_rig();
    let board = flatport::calib::Target::Board(flatport::calib::Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    });
    let scene = simulate(&rig, &SceneSpec::pair(board, 6, 0.1, 9, 0, 1)).unwrap();
    let data = StereoData::from_observations(&rig, [0, 1], &scene.observations).unwrap();
    let borrowed = CpuBackend::new(&data);
    let candidate = flatport::calib::Candidate {
        normal: *rig.shared_interface().unwrap().normal(),
        air_distance: rig.shared_interface().unwrap().air_distance(),
    };
    let expected = borrowed
        .costs(CostKind::Reprojection, &[candidate])
        .unwrap();
    // An owned backend outlives the scope that made it: 'static, Send and Sync.
    let owned: Box<dyn CostBackend + Send + 'static> =
        Box::new(CpuBackend::new(Arc::new(data.clone())));
    let handle =
        std::thread::spawn(move || owned.costs(CostKind::Reprojection, &[candidate]).unwrap());
    assert_eq!(handle.join().unwrap(), expected);
}

fn flatport_cli(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .unwrap()
}

#[test]
fn export_raymap_on_the_command_line_is_backproject() {
    let dir = tempfile::tempdir().unwrap();
    let rig_path = concat!(env!("CARGO_MANIFEST_DIR"), "/data/example_rig.json");
    let out = dir.path().join("rays.npy");
    let run = flatport_cli(&[
        "export",
        "raymap",
        "--rig",
        rig_path,
        "--camera",
        "right",
        "--device",
        "cpu",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let (shape, values) = read_npy(&out).unwrap();
    assert_eq!(shape, [1024, 1280, 6]);
    let (expected, status) = reference(&Engine::Cpu(CpuEngine::new(None)), &example_rig(), 1);
    for ((row, e), s) in values.chunks(6).zip(&expected).zip(&status) {
        if *s == 0 {
            assert_eq!(row, e);
        } else {
            assert!(row.iter().all(|v| v.is_nan()));
        }
    }
    // Onto a device node the file is written in place, and the node stays a device.
    let run = flatport_cli(&[
        "export",
        "raymap",
        "--rig",
        rig_path,
        "--device",
        "cpu",
        "--precision",
        "f32",
        "-o",
        "/dev/null",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    use std::os::unix::fs::FileTypeExt;
    assert!(
        std::fs::metadata("/dev/null")
            .unwrap()
            .file_type()
            .is_char_device()
    );
}

#[test]
fn export_colmap_and_opencv_on_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let rig_path = concat!(env!("CARGO_MANIFEST_DIR"), "/data/example_rig.json");
    let folder = dir.path().join("colmap");
    let run = flatport_cli(&[
        "export",
        "colmap",
        "--rig",
        rig_path,
        "--output",
        folder.to_str().unwrap(),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let cameras = std::fs::read_to_string(folder.join("cameras.txt")).unwrap();
    assert_eq!(
        cameras,
        flatport::io::colmap_cameras_txt(&example_rig()).unwrap()
    );
    assert!(folder.join("rig_config.json").is_file());
    assert_eq!(
        std::fs::read_to_string(folder.join("rigs.txt")).unwrap(),
        flatport::io::colmap_rigs_txt(&example_rig())
    );
    // A port of two layers is refused, naming the file and why.
    let mut two = std::fs::read_to_string(rig_path).unwrap();
    two = two.replace(
        r#""layers": [{"thickness": 0.014, "index": 1.473}]"#,
        r#""layers": [{"thickness": 0.014, "index": 1.473}, {"thickness": 0.002, "index": 1.4}]"#,
    );
    let two_path = dir.path().join("two.json");
    std::fs::write(&two_path, two).unwrap();
    let run = flatport_cli(&[
        "export",
        "colmap",
        "--rig",
        two_path.to_str().unwrap(),
        "--output",
        folder.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && stderr.contains("two.json") && stderr.contains("one glass layer"),
        "{stderr}"
    );
    let run = flatport_cli(&["export", "opencv", "--rig", rig_path]);
    assert!(run.status.success());
    let yaml = String::from_utf8(run.stdout).unwrap();
    assert!(yaml.starts_with("%YAML:1.0\n---\n") && yaml.contains("R: !!opencv-matrix"));
    let run = flatport_cli(&["export", "opencv", "--rig", rig_path, "--camera", "nope"]);
    assert!(!run.status.success() && String::from_utf8_lossy(&run.stderr).contains("nope"));
}
