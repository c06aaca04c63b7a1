//! `flatport calibrate --device gpu` against `--device cpu` on files (issue 33: "`--device gpu`
//! serves every rig the CPU does"): a one-camera rig and a four-camera array, simulated by
//! `flatport simulate`, calibrated from the naive start on both devices. The two calibrations
//! agree within what the optimiser's stopping rule leaves open, their RMS values to 1e-6 px, and
//! the GPU's report names the GPU and the stages it ran. With `CI` set, a missing Vulkan adapter
//! fails the run; without it the tests are skipped with a note.

use std::path::Path;
use std::process::{Command, Output};

use flatport::calib::solvers::lm::LmOptions;
use nalgebra::{Matrix3, Vector3};
use serde_json::Value;

fn flatport(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("binary runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Whether a Vulkan adapter is there; `false` (with a note) outside CI, a failure in CI.
fn have_gpu() -> bool {
    match flatport::gpu::GpuContext::open(None, true) {
        Ok(_) => true,
        Err(e) if std::env::var_os("CI").is_none() => {
            eprintln!("SKIPPED (no Vulkan adapter; CI fails here instead): {e}");
            false
        }
        Err(e) => panic!("CI needs a Vulkan adapter (scripts/test.sh installs lavapipe): {e}"),
    }
}

/// The calibrated rig and the report of `flatport calibrate` of `dir`'s simulated scene from its
/// naive start on `device`.
fn calibrate(dir: &Path, device: &str, extra: &[&str]) -> (Value, Value) {
    let (rig, report) = (
        dir.join(format!("{device}.json")),
        dir.join(format!("{device}_report.json")),
    );
    let (start, observations) = (dir.join("start_rig.json"), dir.join("observations.json"));
    let mut args = vec![
        "calibrate",
        "--rig",
        p(&start),
        "--observations",
        p(&observations),
        "--output",
        p(&rig),
        "--report",
        p(&report),
        "--device",
        device,
    ];
    args.extend_from_slice(extra);
    let out = flatport(&args);
    assert!(out.status.success(), "{device}: {}", text(&out.stderr));
    (json(&rig), json(&report))
}

/// How far apart two runs of the optimiser from the same start may end, in standard deviations
/// of each estimate, for `residuals` residuals (two per corner observation).
///
/// Each run stops where an accepted step lowers the cost C by less than the cost tolerance τ of
/// [`LmOptions::default`] (1e-10) of C. Gauss–Newton on these small-residual problems contracts
/// the excess over the minimum at least twofold per step, so what remains after the last step is
/// below its gain: each end lies within ΔC ≤ τ·C of the minimum. There the cost is quadratic,
/// ΔC = δᵀJᵀJδ, so parameter i lies within √(ΔC·(JᵀJ)⁻¹ᵢᵢ) of it (Cauchy–Schwarz); the report's
/// σᵢ² = σ̂²·(JᵀJ)⁻¹ᵢᵢ with σ̂² = C/(N − P) turns that into √(τ·(N − P))·σᵢ ≤ √(τ·N)·σᵢ. Two runs:
/// twice that. (Both devices evaluate the same residuals to ~1e-15 of a pixel, tests/bundle_gpu.rs,
/// far below what the stopping rule leaves.)
fn apart_in_sigmas(residuals: usize) -> f64 {
    2.0 * (LmOptions::default().cost_tolerance * residuals as f64).sqrt()
}

/// The RMS values of both runs agree to this, pixels (the "~1e-6 px").
const RMS_PX: f64 = 1e-6;

/// Each port's tilt, azimuth and air distance of the GPU's report within [`apart_in_sigmas`]
/// of the CPU's standard deviations of the CPU's values; returns the largest gap in σ.
fn ports_agree(cpu: &Value, gpu: &Value, bound: f64) -> f64 {
    let mut worst = 0.0f64;
    let (a, b) = (
        cpu["ports"].as_array().unwrap(),
        gpu["ports"].as_array().unwrap(),
    );
    assert_eq!(a.len(), b.len());
    for (a, b) in a.iter().zip(b) {
        for key in ["tilt_deg", "azimuth_deg", "distance"] {
            let (value, std) = (
                a[key]["value"].as_f64().unwrap(),
                a[key]["std"].as_f64().unwrap(),
            );
            let gap = (b[key]["value"].as_f64().unwrap() - value).abs() / std;
            assert!(
                gap <= bound,
                "port {}: {key} {gap:e} σ apart (bound {bound:e})",
                a["name"]
            );
            worst = worst.max(gap);
        }
    }
    worst
}

/// Every camera's extrinsics (cam_from_master of the calibrated rigs) within the bound of its
/// standard deviations per axis (the rotation as the left rotation vector between the two, as
/// the bundle steps it); returns the largest gap in σ.
fn extrinsics_agree(cpu_rig: &Value, gpu_rig: &Value, cpu: &Value, bound: f64) -> f64 {
    let matrix = |v: &Value| Matrix3::from_fn(|r, c| v["rotation"][r][c].as_f64().unwrap());
    let vector = |v: &Value| [0, 1, 2].map(|i| v["translation"][i].as_f64().unwrap());
    let mut worst = 0.0f64;
    let cameras = cpu["cameras"].as_array().unwrap();
    for (k, report) in cameras.iter().enumerate().skip(1) {
        let (a, b) = (&cpu_rig["cameras"][k], &gpu_rig["cameras"][k]);
        // The rotation vector of M = R_gpu·R_cpuᵀ from its skew part (sin θ times the axis:
        // exact to O(θ³) for the tiny turns here; the angle from the trace is NaN-prone near 0).
        let m = matrix(b) * matrix(a).transpose();
        let turn = Vector3::new(
            m[(2, 1)] - m[(1, 2)],
            m[(0, 2)] - m[(2, 0)],
            m[(1, 0)] - m[(0, 1)],
        ) / 2.0;
        let (ta, tb) = (vector(a), vector(b));
        for axis in 0..3 {
            let rotation_std = report["rotation_std_deg"][axis]
                .as_f64()
                .unwrap()
                .to_radians();
            let translation_std = report["translation_std_m"][axis].as_f64().unwrap();
            for (what, gap) in [
                ("rotation", turn[axis].abs() / rotation_std),
                ("translation", (tb[axis] - ta[axis]).abs() / translation_std),
            ] {
                assert!(
                    gap <= bound,
                    "camera {k}: {what} axis {axis} {gap:e} σ apart (bound {bound:e})"
                );
                worst = worst.max(gap);
            }
        }
    }
    worst
}

/// The RMS values of both reports within [`RMS_PX`], the backends named.
fn reports_agree(cpu: &Value, gpu: &Value) {
    let gap = (gpu["rms_px_all"].as_f64().unwrap() - cpu["rms_px_all"].as_f64().unwrap()).abs();
    assert!(gap <= RMS_PX, "RMS {gap:e} px apart");
    for (a, b) in cpu["rms_px"]
        .as_array()
        .unwrap()
        .iter()
        .zip(gpu["rms_px"].as_array().unwrap())
    {
        assert!(
            (a.as_f64().unwrap() - b.as_f64().unwrap()).abs() <= RMS_PX,
            "{a} vs {b}"
        );
    }
    assert!(gpu["fits"].as_bool().unwrap() && cpu["fits"].as_bool().unwrap());
    let (cpu_backend, gpu_backend) = (
        cpu["backend"].as_str().unwrap(),
        gpu["backend"].as_str().unwrap(),
    );
    assert!(cpu_backend.starts_with("cpu"), "{cpu_backend}");
    assert!(
        gpu_backend.starts_with("gpu: ")
            && gpu_backend.contains("on the GPU: the pair costs of the consecutive method and the bundle's residual stencils"),
        "{gpu_backend}"
    );
    assert!(
        gpu["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .all(|w| !w.as_str().unwrap().contains("GPU failed")),
        "{}",
        gpu["warnings"]
    );
}

/// `flatport simulate` of `rig` into `dir`.
fn simulate(dir: &Path, rig: &str, extra: &[&str]) {
    let mut args = vec!["simulate", "--rig", rig, "--seed", "2", "--output", p(dir)];
    args.extend_from_slice(extra);
    let out = flatport(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
}

#[test]
fn one_camera_calibrates_alike_on_the_gpu_and_the_cpu() {
    if !have_gpu() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    simulate(
        dir.path(),
        "data/rigs/single_housing.json",
        &["--views", "10"],
    );
    let (cpu_rig, cpu) = calibrate(dir.path(), "cpu", &[]);
    let (gpu_rig, gpu) = calibrate(dir.path(), "gpu", &[]);
    reports_agree(&cpu, &gpu);
    let bound = apart_in_sigmas(2 * cpu["observations"].as_u64().unwrap() as usize);
    let worst = ports_agree(&cpu, &gpu, bound);
    eprintln!("one camera: ports {worst:.2e} σ apart (bound {bound:.2e} σ)");
    assert_eq!(cpu_rig["cameras"], gpu_rig["cameras"], "nothing else moves");
    // The one-camera path: the axis search, then maximum likelihood, on both.
    assert!(
        gpu["strategy"].as_str().unwrap().contains("global search"),
        "{}",
        gpu["strategy"]
    );
}

#[test]
fn a_four_camera_array_with_its_extrinsics_calibrates_alike_on_the_gpu_and_the_cpu() {
    if !have_gpu() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    simulate(
        dir.path(),
        "data/rigs/array_2x2.json",
        &["--views", "12", "--min-cameras", "2"],
    );
    let estimate = ["--estimate", "axis,distance,extrinsics"];
    let (cpu_rig, cpu) = calibrate(dir.path(), "cpu", &estimate);
    let (gpu_rig, gpu) = calibrate(dir.path(), "gpu", &estimate);
    reports_agree(&cpu, &gpu);
    let bound = apart_in_sigmas(2 * cpu["observations"].as_u64().unwrap() as usize);
    let ports = ports_agree(&cpu, &gpu, bound);
    let extrinsics = extrinsics_agree(&cpu_rig, &gpu_rig, &cpu, bound);
    eprintln!(
        "four cameras: ports {ports:.2e} σ, extrinsics {extrinsics:.2e} σ apart (bound {bound:.2e} σ)"
    );
}

/// With f32 kernels the pair costs run on the GPU and the bundle stays on the CPU (its central
/// differences need f64 residuals), and the report says so: the result is the CPU's.
#[test]
fn with_f32_kernels_the_report_says_the_bundle_stays_on_the_cpu() {
    if !have_gpu() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    simulate(
        dir.path(),
        "data/rigs/single_housing.json",
        &["--views", "6"],
    );
    let (cpu_rig, _) = calibrate(dir.path(), "cpu", &[]);
    let (gpu_rig, gpu) = calibrate(dir.path(), "gpu", &["--precision", "f32"]);
    let backend = gpu["backend"].as_str().unwrap();
    assert!(
        backend.starts_with("gpu: ")
            && backend.contains("f32")
            && backend.contains("on the CPU: the bundle"),
        "{backend}"
    );
    // One camera: no pair costs; every stage ran on the CPU, as with --device cpu.
    assert_eq!(cpu_rig, gpu_rig);
}
