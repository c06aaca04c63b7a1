//! `flatport sweep --shard I/N` and `flatport sweep merge`: the merged shards write the same
//! files as the unsharded sweep (cost.npy byte for byte), in any order of the shard folders; a
//! missing, repeated, foreign or damaged shard is refused by name.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn flatport(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("binary runs")
}

fn ok(args: &[&str]) -> String {
    let out = flatport(args);
    assert!(
        out.status.success(),
        "flatport {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn refused(args: &[&str]) -> String {
    let out = flatport(args);
    assert!(!out.status.success(), "flatport {args:?} should fail");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!stderr.contains("panicked"), "{stderr}");
    stderr
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// A simulated scene of the example rig: (rig, observations, truth).
fn scene(dir: &Path, seed: &str) -> (PathBuf, PathBuf, PathBuf) {
    let out = dir.join(format!("scene{seed}"));
    ok(&[
        "simulate",
        "--rig",
        "data/example_rig.json",
        "--views",
        "5",
        "--noise",
        "0.2",
        "--seed",
        seed,
        "--output",
        p(&out),
    ]);
    (
        out.join("rig.json"),
        out.join("observations.json"),
        out.join("truth.json"),
    )
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Runs the sweep whole and in `count` shards, merges the shards (folders in reverse order), and
/// compares the files.
fn sharded_equals_whole(grid: &[&str], count: usize, files: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let (rig, observations, truth) = scene(dir.path(), "3");
    let mut base = vec![
        "sweep",
        "--device",
        "cpu",
        "--quiet",
        "--rig",
        p(&rig),
        "--observations",
        p(&observations),
    ];
    base.extend_from_slice(grid);
    let whole = dir.path().join("whole");
    let mut args = base.clone();
    args.extend(["--truth", p(&truth), "--output", p(&whole)]);
    ok(&args);
    let mut shards = Vec::new();
    for index in 0..count {
        let folder = dir.path().join(format!("shard{index}"));
        let shard = format!("{index}/{count}");
        let mut args = base.clone();
        // A small batch, so that batches and shard boundaries fall inside axes' air layers.
        args.extend(["--chunk", "3", "--shard", &shard, "--output", p(&folder)]);
        ok(&args);
        assert!(folder.join("shard.json").exists());
        shards.push(folder);
    }
    let merged = dir.path().join("merged");
    let mut args = vec!["sweep", "merge"];
    args.extend(shards.iter().rev().map(|s| p(s)));
    args.extend(["--truth", p(&truth), "--output", p(&merged)]);
    ok(&args);
    for file in files {
        assert!(
            read(&whole.join(file)) == read(&merged.join(file)),
            "{file} differs between the whole and the merged sweep"
        );
    }
    // The summaries agree but for the timing.
    let summary = |d: &Path| {
        let mut v: serde_json::Value =
            serde_json::from_slice(&read(&d.join("summary.json"))).unwrap();
        for key in ["seconds", "cells_per_s", "cell_correspondences_per_s"] {
            v.as_object_mut().unwrap().remove(key);
        }
        v
    };
    assert_eq!(summary(&whole), summary(&merged));
    for picture in ["heatmap.png", "polar.png"] {
        assert!(merged.join(picture).exists());
    }
}

#[test]
fn four_merged_shards_of_a_profile_sweep_equal_the_whole_sweep() {
    sharded_equals_whole(
        &[
            "--cost",
            "reprojection",
            "--tilt-deg",
            "0:20:7",
            "--azimuth-deg",
            "-180:180:9",
        ],
        4,
        &["cost.npy", "distance.npy", "cost.csv"],
    );
}

#[test]
fn merged_shards_of_a_distance_grid_equal_the_whole_sweep() {
    // 5 × 3 × 4 = 60 cells in 7 shards: boundaries inside axes' air layers.
    sharded_equals_whole(
        &[
            "--cost",
            "scene",
            "--tilt-deg",
            "4:12:5",
            "--azimuth-deg",
            "30:60:3",
            "--distance",
            "0.015:0.025:4",
        ],
        7,
        &["cost.npy", "cost.csv"],
    );
    sharded_equals_whole(
        &[
            "--cost",
            "affine-grid",
            "--tilt-deg",
            "0:20:6",
            "--azimuth-deg",
            "-180:180:6",
        ],
        4,
        &["cost.npy", "cost.csv"],
    );
}

#[test]
fn shards_that_do_not_belong_together_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (rig, observations, _) = scene(dir.path(), "3");
    let (_, other_observations, _) = scene(dir.path(), "4");
    let shard = |index: usize, count: usize, observations: &Path, tilts: &str, name: &str| {
        let folder = dir.path().join(name);
        let s = format!("{index}/{count}");
        ok(&[
            "sweep",
            "--device",
            "cpu",
            "--quiet",
            "--rig",
            p(&rig),
            "--observations",
            p(observations),
            "--cost",
            "affine-grid",
            "--tilt-deg",
            tilts,
            "--azimuth-deg",
            "0:90:4",
            "--shard",
            &s,
            "--output",
            p(&folder),
        ]);
        folder
    };
    let a = [0, 1, 2].map(|i| shard(i, 3, &observations, "0:10:5", &format!("a{i}")));
    let merged = dir.path().join("merged");
    let merge = |dirs: &[&PathBuf]| {
        let mut args = vec!["sweep", "merge"];
        args.extend(dirs.iter().map(|d| p(d)));
        args.extend(["--output", p(&merged)]);
        refused(&args)
    };
    // A shard missing.
    let error = merge(&[&a[0], &a[2]]);
    assert!(
        error.contains("1/3") && error.contains("missing"),
        "{error}"
    );
    // A shard twice.
    let error = merge(&[&a[0], &a[1], &a[1], &a[2]]);
    assert!(error.contains("both shard 1/3"), "{error}");
    // A shard of another scene's observations.
    let foreign = shard(1, 3, &other_observations, "0:10:5", "foreign");
    let error = merge(&[&a[0], &foreign, &a[2]]);
    assert!(
        error.contains("different sweeps")
            && error.contains("observations")
            && error.contains("foreign"),
        "{error}"
    );
    // A shard of another grid.
    let other_grid = shard(1, 3, &observations, "0:12:5", "grid");
    let error = merge(&[&a[0], &other_grid, &a[2]]);
    assert!(error.contains("grids"), "{error}");
    // A shard of another split.
    let quarter = shard(1, 4, &observations, "0:10:5", "quarter");
    let error = merge(&[&a[0], &quarter, &a[2]]);
    assert!(error.contains("shard counts"), "{error}");
    // A folder that is no shard, and a shard whose cost.npy lost values.
    let error = merge(&[&a[0], &dir.path().join("scene3"), &a[2]]);
    assert!(
        error.contains("scene3") && error.contains("not a sweep shard"),
        "{error}"
    );
    let npy = a[1].join("cost.npy");
    let bytes = read(&npy);
    std::fs::write(&npy, &bytes[..bytes.len() - 8]).unwrap();
    let error = merge(&[&a[0], &a[1], &a[2]]);
    assert!(error.contains("cost.npy"), "{error}");
    // Nothing was written by the refused merges.
    assert!(!merged.join("cost.npy").exists());
    // A bad --shard is refused by clap, naming the form.
    let error = refused(&[
        "sweep",
        "--rig",
        p(&rig),
        "--observations",
        p(&observations),
        "--tilt-deg",
        "0:1:2",
        "--azimuth-deg",
        "0:1:2",
        "-o",
        p(&merged),
        "--shard",
        "3/3",
    ]);
    assert!(error.contains("INDEX/COUNT"), "{error}");
}
