//! What a newcomer meets in the first hour: `simulate` writes the naive start rig the README
//! calibrates from, a sweep into an old folder leaves no file of the earlier sweep behind, cells
//! without a finite cost are counted on stderr, the cost names of the CLI are the names of the
//! summary, and `info` says what `--device` accepts.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn flatport(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("binary runs")
}

fn ok(args: &[&str]) -> Output {
    let out = flatport(args);
    assert!(
        out.status.success(),
        "flatport {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// A small simulated scene of the example rig: (rig, observations).
fn scene(dir: &Path) -> (PathBuf, PathBuf) {
    let out = dir.join("scene");
    ok(&[
        "simulate",
        "--rig",
        "data/example_rig.json",
        "--views",
        "6",
        "--noise",
        "0",
        "--seed",
        "3",
        "--output",
        p(&out),
    ]);
    (out.join("rig.json"), out.join("observations.json"))
}

#[test]
fn simulate_writes_the_naive_start_rig() {
    let dir = tempfile::tempdir().unwrap();
    let (rig, _) = scene(dir.path());
    let start = json(&rig.with_file_name("start_rig.json"));
    let truth = json(&rig);
    // The naive start of the README and the demo: axis on the master camera's z, 10 mm of air,
    // everything else (cameras, layers, indices) the rig's own.
    let normal: Vec<f64> = start["interface"]["normal"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(normal, vec![0.0, 0.0, 1.0]);
    assert_eq!(start["interface"]["distance"].as_f64().unwrap(), 0.01);
    assert_eq!(start["cameras"], truth["cameras"]);
    for key in ["layers", "index_air", "index_water"] {
        assert_eq!(start["interface"][key], truth["interface"][key], "{key}");
    }
    assert_ne!(start["interface"]["normal"], truth["interface"]["normal"]);
}

#[test]
fn a_sweep_into_an_old_folder_leaves_no_stale_distance_npy() {
    let dir = tempfile::tempdir().unwrap();
    let (rig, obs) = scene(dir.path());
    let out = dir.path().join("sweep");
    let grid = [
        "--tilt-deg",
        "6:10:3",
        "--azimuth-deg",
        "40:50:3",
        "--device",
        "cpu",
        "--quiet",
    ];
    let sweep = |cost: &str, extra: &[&str]| {
        let mut args = vec![
            "sweep",
            "--rig",
            p(&rig),
            "--observations",
            p(&obs),
            "--cost",
            cost,
            "--output",
            p(&out),
        ];
        args.extend_from_slice(&grid);
        args.extend_from_slice(extra);
        ok(&args)
    };
    // A profile writes distance.npy ...
    sweep("reprojection", &[]);
    assert!(out.join("distance.npy").is_file());
    // ... an axis-only sweep into the same folder does not, and removes the old one.
    sweep("affine-grid", &[]);
    assert!(
        !out.join("distance.npy").exists(),
        "stale distance.npy of the earlier sweep"
    );
    // So does a sweep over a grid of air layers.
    sweep("scene", &[]);
    assert!(out.join("distance.npy").is_file());
    sweep("scene", &["--distance", "0.018:0.022:2"]);
    assert!(!out.join("distance.npy").exists());
    // A symbolic link under that name is removed, never the file it points to.
    let elsewhere = dir.path().join("keep.npy");
    std::fs::write(&elsewhere, b"not the sweep's").unwrap();
    std::os::unix::fs::symlink(&elsewhere, out.join("distance.npy")).unwrap();
    sweep("affine-grid", &[]);
    assert!(std::fs::symlink_metadata(out.join("distance.npy")).is_err());
    assert_eq!(std::fs::read(&elsewhere).unwrap(), b"not the sweep's");
    // A folder under that name is not the sweep's: left alone, with a warning.
    std::fs::create_dir(out.join("distance.npy")).unwrap();
    std::fs::write(out.join("distance.npy").join("mine"), b"x").unwrap();
    let o = sweep("affine-grid", &[]);
    assert!(out.join("distance.npy").join("mine").is_file());
    assert!(String::from_utf8_lossy(&o.stderr).contains("left alone"));
}

#[test]
fn cells_without_a_finite_cost_are_counted_on_stderr() {
    let dir = tempfile::tempdir().unwrap();
    let (rig, obs) = scene(dir.path());
    let out = dir.path().join("sweep");
    // The right camera sits 60 mm along x, so a port tilted 6–10° toward azimuths 40–50° is
    // 4.4–8.0 mm nearer to it than to the master: an air layer of 1 mm puts it outside the air,
    // and those cells are inf.
    let o = ok(&[
        "sweep",
        "--rig",
        p(&rig),
        "--observations",
        p(&obs),
        "--cost",
        "reprojection",
        "--tilt-deg",
        "6:10:3",
        "--azimuth-deg",
        "40:50:3",
        "--distance",
        "0.001:0.021:6",
        "--output",
        p(&out),
        "--device",
        "cpu",
        "--quiet",
    ]);
    let csv = std::fs::read_to_string(out.join("cost.csv")).unwrap();
    let inf = csv
        .lines()
        .skip(1)
        .filter(|l| l.rsplit(',').next().unwrap().trim() == "inf")
        .count();
    assert!(inf >= 9, "the cells at d = 1 mm are inf, {inf} found");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains(&format!(
            "warning: {inf} of 54 cells have no finite reprojection cost"
        )),
        "{stderr}"
    );
    // A sweep where every cell answers says nothing of the kind.
    let o = ok(&[
        "sweep",
        "--rig",
        p(&rig),
        "--observations",
        p(&obs),
        "--cost",
        "affine-grid",
        "--tilt-deg",
        "6:10:3",
        "--azimuth-deg",
        "40:50:3",
        "--output",
        p(&out),
        "--device",
        "cpu",
        "--quiet",
    ]);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("no finite"));
}

#[test]
fn cost_names_are_one_across_cli_and_summary_and_the_old_ones_still_work() {
    let dir = tempfile::tempdir().unwrap();
    let (rig, obs) = scene(dir.path());
    for (cli, old, name) in [
        ("affine-grid", "invariant", "affine-grid"),
        ("scene", "3d", "scene"),
        ("reprojection", "reprojection", "reprojection"),
    ] {
        let mut costs = Vec::new();
        for value in [cli, old] {
            let out = dir.path().join(format!("sweep-{value}"));
            ok(&[
                "sweep",
                "--rig",
                p(&rig),
                "--observations",
                p(&obs),
                "--cost",
                value,
                "--tilt-deg",
                "7:9:2",
                "--azimuth-deg",
                "44:46:2",
                "--output",
                p(&out),
                "--device",
                "cpu",
                "--quiet",
            ]);
            let summary = json(&out.join("summary.json"));
            assert_eq!(summary["cost"], name, "--cost {value}");
            costs.push(summary["argmin"]["cost"].as_f64().unwrap());
        }
        assert_eq!(costs[0], costs[1], "{cli} and {old} are the same cost");
    }
    let help = String::from_utf8_lossy(&ok(&["sweep", "--help"]).stdout).into_owned();
    assert!(
        help.contains("affine-grid") && help.contains("scene"),
        "{help}"
    );
    assert!(
        !help.contains("invariant|") && !help.contains("3d]"),
        "{help}"
    );
}

#[test]
fn info_says_what_device_accepts_today() {
    let info = String::from_utf8_lossy(&ok(&["info"]).stdout).into_owned();
    assert!(!info.contains("for now"), "{info}");
    assert!(
        info.contains("--device gpu") && info.contains("--device auto"),
        "{info}"
    );
}

#[test]
fn help_says_which_precision_each_command_runs() {
    let help = String::from_utf8_lossy(&ok(&["calibrate", "--help"]).stdout).into_owned();
    assert!(
        help.contains("f64 (where the adapter has it) for calibrate"),
        "{help}"
    );
    assert!(
        !help.contains("(default f32; the CPU is always f64)"),
        "{help}"
    );
}
