//! `flatport render` with what real cameras add (`--imaging`, `--h264`, …): the images change,
//! the truth files do not, the board stays detectable, and without the options nothing changes.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn flatport(args: &[&str]) -> Output {
    flatport_with_path(args, None)
}

/// The binary, with PATH replaced when `path` is given.
fn flatport_with_path(args: &[&str], path: Option<&Path>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_flatport"));
    command.args(args);
    if let Some(path) = path {
        command.env("PATH", path);
    }
    command.output().expect("binary runs")
}

fn ok(output: &Output) {
    assert!(
        output.status.success(),
        "flatport failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
}

fn rig() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data/example_rig.json")
        .display()
        .to_string()
}

/// A small calibration set (3 views under water, 2 in air per camera, seed 3) with `extra`
/// options, into `dir`.
fn calibration_set(dir: &Path, extra: &[&str]) {
    let rig = rig();
    let out = dir.display().to_string();
    let mut args = vec![
        "render",
        "--rig",
        &rig,
        "--calibration-set",
        "--views",
        "3",
        "--air-views",
        "2",
        "--seed",
        "3",
        "--device",
        "cpu",
        "-q",
        "-o",
        &out,
    ];
    args.extend_from_slice(extra);
    ok(&flatport(&args));
}

/// Every file under `dir`, relative to it, sorted.
fn files(dir: &Path) -> Vec<PathBuf> {
    fn walk(dir: &Path, root: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(&path, root, out);
            } else {
                out.push(path.strip_prefix(root).unwrap().to_path_buf());
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

fn grey(path: &Path) -> Vec<u8> {
    image::open(path).unwrap().to_luma8().into_raw()
}

/// Mean absolute difference of two 8-bit images, grey levels.
fn mean_difference(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (f64::from(x) - f64::from(y)).abs())
        .sum::<f64>()
        / a.len() as f64
}

#[test]
fn imaging_1_changes_every_image_and_no_truth_file() {
    let dir = tempfile::tempdir().unwrap();
    let (clean, real) = (dir.path().join("clean"), dir.path().join("real"));
    calibration_set(&clean, &[]);
    calibration_set(&real, &["--imaging", "1"]);
    let names = files(&clean);
    assert_eq!(names, files(&real), "the same files");
    let mut images = 0;
    for name in &names {
        let (a, b) = (clean.join(name), real.join(name));
        if name.extension().is_some_and(|e| e == "png") {
            images += 1;
            let change = mean_difference(&grey(&a), &grey(&b));
            // Contrast −40 % alone moves black and white by 0.2 · 255 · 0.73 ≈ 37 levels.
            assert!(
                change > 10.0,
                "{}: changed by {change} grey levels only",
                name.display()
            );
        } else {
            assert_eq!(
                std::fs::read(&a).unwrap(),
                std::fs::read(&b).unwrap(),
                "{} is the geometric truth and must not change",
                name.display()
            );
        }
    }
    assert_eq!(
        images,
        3 * 2 + 2 * 2,
        "water and air images of both cameras"
    );

    // The board stays detectable, where the clean images show it, at its true corners: every
    // corner found within 0.5 px of corners.json (the detector's own error on the clean images
    // is below 0.1 px; defocus and noise add a little).
    let water = real.join("water");
    let obs = dir.path().join("obs.json");
    let glob = |camera: &str| format!("{camera}={}/{camera}/*.png", water.display());
    let (left, right) = (glob("left"), glob("right"));
    let output = flatport(&[
        "detect",
        "--board",
        "9x6@0.04",
        "--images",
        &left,
        "--images",
        &right,
        "-o",
        &obs.display().to_string(),
    ]);
    ok(&output);
    let read = |path: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
    };
    let (found, truth) = (read(&obs), read(&water.join("corners.json")));
    let points = |view: &serde_json::Value| -> Vec<[f64; 2]> {
        view.as_array()
            .unwrap()
            .iter()
            .map(|p| [p[0].as_f64().unwrap(), p[1].as_f64().unwrap()])
            .collect()
    };
    let found_views = found["views"].as_array().unwrap();
    assert!(
        !found_views.is_empty(),
        "no view found in the degraded images: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    for view in found_views {
        for camera in ["left", "right"] {
            let seen = points(&view[camera]);
            // The truth view it is: the one nearest in its worst corner.
            let worst = truth["views"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|t| t[camera].is_array())
                .map(|t| {
                    points(&t[camera])
                        .iter()
                        .zip(&seen)
                        .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
                        .fold(0.0, f64::max)
                })
                .fold(f64::INFINITY, f64::min);
            assert!(worst < 0.5, "{camera}: a corner {worst} px off the truth");
        }
    }
}

#[test]
fn imaging_0_writes_what_no_imaging_option_writes() {
    let dir = tempfile::tempdir().unwrap();
    let (plain, zero) = (dir.path().join("plain"), dir.path().join("zero"));
    let rig = rig();
    let render = |out: &Path, extra: &[&str]| {
        let out = out.display().to_string();
        let mut args = vec![
            "render", "--rig", &rig, "--views", "2", "--seed", "5", "--noise", "2", "--device",
            "cpu", "-q", "-o", &out,
        ];
        args.extend_from_slice(extra);
        ok(&flatport(&args));
    };
    render(&plain, &[]);
    render(&zero, &["--imaging", "0"]);
    for name in files(&plain) {
        assert_eq!(
            std::fs::read(plain.join(&name)).unwrap(),
            std::fs::read(zero.join(&name)).unwrap(),
            "{}",
            name.display()
        );
    }
}

#[test]
fn imaging_options_out_of_range_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let rig = rig();
    let out = dir.path().display().to_string();
    for (option, value, says) in [
        ("--imaging", "2.5", "severity"),
        ("--vignetting", "1", "vignetting"),
        ("--contrast", "1.5", "fraction"),
        ("--jpeg", "101", "101"),
        ("--h264", "52", "52"),
    ] {
        let output = flatport(&[
            "render", "--rig", &rig, "--views", "1", "-q", "-o", &out, option, value,
        ]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(
            !output.status.success() && stderr.contains(says),
            "{option} {value}: {stderr}"
        );
    }
}

fn have_ffmpeg() -> bool {
    Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success())
}

#[test]
fn h264_rewrites_each_cameras_frames_with_the_decoded_video() {
    if !have_ffmpeg() {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI needs the ffmpeg tool with libx264 for --h264 (apt-get install ffmpeg)"
        );
        eprintln!("SKIPPED: ffmpeg is not on PATH (apt-get install ffmpeg); CI fails here instead");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (clean, video) = (dir.path().join("clean"), dir.path().join("video"));
    calibration_set(&clean, &[]);
    calibration_set(&video, &["--h264", "30"]);
    let mut changed = 0;
    for name in files(&clean) {
        let (a, b) = (clean.join(&name), video.join(&name));
        if name.extension().is_some_and(|e| e == "png") {
            let change = mean_difference(&grey(&a), &grey(&b));
            // x264 at CRF 30 on a sharp board: changed, by a grey level or two on average.
            assert!(
                change > 0.05 && change < 4.0,
                "{}: changed by {change} grey levels",
                name.display()
            );
            changed += 1;
        } else {
            assert_eq!(
                std::fs::read(&a).unwrap(),
                std::fs::read(&b).unwrap(),
                "{}",
                name.display()
            );
        }
    }
    assert_eq!(changed, 10);
}

#[test]
fn h264_without_ffmpeg_says_what_to_install() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("no-programs");
    std::fs::create_dir(&empty).unwrap();
    let rig = rig();
    let out = dir.path().join("out").display().to_string();
    let output = flatport_with_path(
        &[
            "render", "--rig", &rig, "--views", "1", "--device", "cpu", "-q", "--h264", "23", "-o",
            &out,
        ],
        Some(&empty),
    );
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        !output.status.success() && stderr.contains("apt-get install ffmpeg"),
        "{stderr}"
    );
}
