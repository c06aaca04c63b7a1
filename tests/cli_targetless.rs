//! `flatport calibrate --images DIR --rig RIG.json --targetless` end to end through the binary:
//! `flatport render --scene` renders a scene with the TRUE rig, the rig's port is reset to the
//! naive guess (axis on the master's z, 10 mm of air), and the command must write a rig whose
//! port is the truth's within 0.1° and 1.5 mm; a scene that cannot pin the port is refused
//! with nothing written.

mod stereo_common;

use std::path::Path;
use std::process::Command;

use flatport::io::read_rig;
use stereo_common::SHARED_PORT_PAIR;

fn flatport(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("flatport runs")
}

fn scene_file(dir: &Path, surfaces: &str) -> std::path::PathBuf {
    let text =
        format!(r#"{{"rig": {SHARED_PORT_PAIR}, "background": 0.35, "surfaces": [{surfaces}]}}"#);
    let path = dir.join("scene.json");
    std::fs::write(&path, text).unwrap();
    path
}

/// Renders `surfaces` with the true shared-port pair into DIR/shots and writes the naive rig.
fn rendered(dir: &Path, surfaces: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let scene = scene_file(dir, surfaces);
    let shots = dir.join("shots");
    let out = flatport(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--device",
        "cpu",
        "--supersample",
        "3",
        "-o",
        shots.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let naive = SHARED_PORT_PAIR.replace(
        "\"normal\": [0.1, 0.1, 1.0], \"distance\": 0.05",
        "\"normal\": [0, 0, 1], \"distance\": 0.01",
    );
    assert_ne!(naive, SHARED_PORT_PAIR);
    let naive_path = dir.join("naive.json");
    std::fs::write(&naive_path, naive).unwrap();
    (shots, naive_path)
}

const SEABED_AND_ROCK: &str = r#"
    {"height_field": {"origin": [0, 0, 1.6], "normal": [0, 0, -1],
       "relief": {"amplitude": 0.05, "wavelength": 0.7, "waves": 6, "seed": 3},
       "texture": {"noise": {"scale": 0.15, "octaves": 4, "contrast": 3.0, "seed": 103}}}},
    {"sphere": {"centre": [0.12, 0.05, 1.3], "radius": 0.15,
       "texture": {"noise": {"scale": 0.06, "octaves": 4, "contrast": 3.0, "seed": 12}}}}"#;

#[test]
fn the_shared_port_pair_is_calibrated_from_a_seabed_and_a_rock() {
    let dir = tempfile::tempdir().unwrap();
    let (shots, naive) = rendered(dir.path(), SEABED_AND_ROCK);
    let output = dir.path().join("calibrated.json");
    let out = flatport(&[
        "calibrate",
        "--images",
        shots.to_str().unwrap(),
        "--rig",
        naive.to_str().unwrap(),
        "--targetless",
        "-o",
        output.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!("{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success());
    assert!(stdout.contains("σ"), "{stdout}");
    let fitted = read_rig(&output).unwrap();
    let truth = stereo_common::rig(SHARED_PORT_PAIR);
    let (f, t) = (fitted.port_in_master(0), truth.port_in_master(0));
    let axis = f
        .normal()
        .dot(t.normal())
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    let air = f.air_distance() - t.air_distance();
    eprintln!("axis off by {axis}°, air off by {} mm", air * 1e3);
    assert!(axis < 0.1, "axis off by {axis}°");
    assert!(air.abs() < 1.5e-3, "air off by {air} m");
    // The cameras are the input's (to the rounding of the written file).
    for (a, b) in fitted.cameras().iter().zip(truth.cameras()) {
        assert_eq!((&a.name, a.intrinsics), (&b.name, b.intrinsics));
        let (ta, tb) = (
            a.cam_from_master.to_homogeneous(),
            b.cam_from_master.to_homogeneous(),
        );
        assert!((ta - tb).amax() < 1e-12, "{} moved", a.name);
    }
}

#[test]
fn a_scene_that_cannot_pin_the_port_is_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let far_plane = r#"{"plane": {"point": [0, 0, 8], "normal": [0, 0, -1],
       "texture": {"noise": {"scale": 0.6, "octaves": 4, "contrast": 3.0, "seed": 31}}}}"#;
    let (shots, naive) = rendered(dir.path(), far_plane);
    let output = dir.path().join("calibrated.json");
    let out = flatport(&[
        "calibrate",
        "--images",
        shots.to_str().unwrap(),
        "--rig",
        naive.to_str().unwrap(),
        "--targetless",
        "-o",
        output.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!("{}{stderr}", String::from_utf8_lossy(&out.stdout));
    assert!(!out.status.success());
    assert!(stderr.contains("distance: σ"), "{stderr}");
    assert!(!output.exists());
    // Missing camera folder: named.
    std::fs::remove_dir_all(shots.join("right")).unwrap();
    let out = flatport(&[
        "calibrate",
        "--images",
        shots.to_str().unwrap(),
        "--rig",
        naive.to_str().unwrap(),
        "--targetless",
        "-o",
        output.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("'right'"), "{stderr}");
    assert!(!output.exists());
}
