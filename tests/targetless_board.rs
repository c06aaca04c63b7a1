//! The targetless estimate of a port against a board calibration of the same rig (issue 40: "the
//! estimate agrees with a board calibration of the same rig within their σ"). The shared-port
//! pair of tests/stereo_common at 640 × 512 (the same field of view; a ChArUco square is then
//! 30–80 px wide) renders (1) a calibration set of a ChArUco board under water
//! (`flatport render --calibration-set`), calibrated by `flatport calibrate --images --board
//! --rig` (the lenses known, the extrinsics and the port fitted), and (2) a seabed with a rock,
//! calibrated by the library's targetless route with the true in-air rig; both start from the
//! naive port. The two ports must agree within 3·√(σ_targetless² + σ_board²) and both lie near
//! the truth the images were rendered with.

mod stereo_common;

use std::path::Path;
use std::process::Command;

use flatport::calib::targetless::{TargetlessOptions, calibrate_targetless};
use flatport::io::frames::read_camera_frames;
use flatport::model::Rig;
use stereo_common::*;

const BOARD: &str = "data/boards/charuco_7x5.json";

fn flatport(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("flatport runs")
}

/// SHARED_PORT_PAIR at 640 × 512 (focal lengths and principal point doubled), its port reset to
/// the naive guess when `naive`.
fn pair_json(naive: bool) -> String {
    let text = SHARED_PORT_PAIR.replace(
        "\"width\": 320, \"height\": 256, \"fx\": 260, \"fy\": 260, \"cx\": 159.5, \"cy\": 127.5",
        "\"width\": 640, \"height\": 512, \"fx\": 520, \"fy\": 520, \"cx\": 319.5, \"cy\": 255.5",
    );
    assert_ne!(text, SHARED_PORT_PAIR);
    if naive {
        let reset = text.replace(
            "\"normal\": [0.1, 0.1, 1.0], \"distance\": 0.05",
            "\"normal\": [0, 0, 1], \"distance\": 0.01",
        );
        assert_ne!(reset, text);
        reset
    } else {
        text
    }
}

fn angle_deg(
    a: &nalgebra::Unit<nalgebra::Vector3<f64>>,
    b: &nalgebra::Unit<nalgebra::Vector3<f64>>,
) -> f64 {
    a.dot(b).clamp(-1.0, 1.0).acos().to_degrees()
}

/// The board route through the binary: (its rig, σ of the axis in degrees (tilt and azimuth
/// combined into an angle), σ of the air distance in metres).
fn board_calibration(dir: &Path, truth: &Path, naive: &Path) -> (Rig, f64, f64) {
    let set = dir.join("set");
    let started = std::time::Instant::now();
    let out = flatport(&[
        "render",
        "--rig",
        truth.to_str().unwrap(),
        "--board",
        BOARD,
        "--calibration-set",
        "--views",
        "12",
        "--air-views",
        "3",
        "--noise",
        "1",
        "--device",
        "cpu",
        "-q",
        "-o",
        set.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "render: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rendered_s = started.elapsed().as_secs_f64();
    let (rig_path, report_path) = (dir.join("board_rig.json"), dir.join("board_report.json"));
    let out = flatport(&[
        "calibrate",
        "--images",
        set.to_str().unwrap(),
        "--board",
        BOARD,
        "--port",
        "shared",
        "--glass",
        "0.014:1.473",
        "--index-air",
        "1.003",
        "--rig",
        naive.to_str().unwrap(),
        "--device",
        "cpu",
        "-q",
        "-o",
        rig_path.to_str().unwrap(),
        "--report",
        report_path.to_str().unwrap(),
    ]);
    eprintln!(
        "board route: rendered in {rendered_s:.1} s, calibrated in {:.1} s\n{}{}",
        started.elapsed().as_secs_f64() - rendered_s,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report_path).unwrap()).unwrap();
    let port = &report["ports"][0];
    let std = |key: &str| {
        port[key]["std"]
            .as_f64()
            .unwrap_or_else(|| panic!("σ of {key}: {port}"))
    };
    let tilt = port["tilt_deg"]["value"].as_f64().unwrap().to_radians();
    // The axis moves by σ_tilt along the tilt and by σ_azimuth · sin(tilt) across it.
    let axis_sigma = std("tilt_deg").hypot(std("azimuth_deg") * tilt.sin());
    (
        flatport::io::read_rig(&rig_path).unwrap(),
        axis_sigma,
        std("distance"),
    )
}

#[test]
fn the_targetless_port_agrees_with_a_board_calibration_within_their_sigma() {
    let dir = tempfile::tempdir().unwrap();
    let (truth_path, naive_path) = (dir.path().join("truth.json"), dir.path().join("naive.json"));
    std::fs::write(&truth_path, pair_json(false)).unwrap();
    std::fs::write(&naive_path, pair_json(true)).unwrap();
    let truth = rig(&pair_json(false));
    let true_port = truth.port_in_master(0);
    let started = std::time::Instant::now();
    let (board_rig, board_axis_sigma, board_distance_sigma) =
        board_calibration(dir.path(), &truth_path, &naive_path);
    let board_s = started.elapsed().as_secs_f64();

    // The targetless route: the scene rendered with the truth, through the files (as the CLI
    // reads them), calibrated from the naive port.
    let scene_path = dir.path().join("scene.json");
    std::fs::write(
        &scene_path,
        format!(
            r#"{{"rig": {}, "background": 0.35, "surfaces": [
    {{"height_field": {{"origin": [0, 0, 1.6], "normal": [0, 0, -1],
       "relief": {{"amplitude": 0.05, "wavelength": 0.7, "waves": 6, "seed": 3}},
       "texture": {{"noise": {{"scale": 0.15, "octaves": 4, "contrast": 3.0, "seed": 103}}}}}}}},
    {{"sphere": {{"centre": [0.12, 0.05, 1.3], "radius": 0.15,
       "texture": {{"noise": {{"scale": 0.06, "octaves": 4, "contrast": 3.0, "seed": 12}}}}}}}}]}}"#,
            pair_json(false)
        ),
    )
    .unwrap();
    let shots = dir.path().join("shots");
    let out = flatport(&[
        "render",
        "--scene",
        scene_path.to_str().unwrap(),
        "--device",
        "cpu",
        "--noise",
        "1",
        "-q",
        "-o",
        shots.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "render: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let naive = rig(&pair_json(true));
    let frames = read_camera_frames(&shots, &["left", "right"], None, 8).unwrap();
    let result = calibrate_targetless(
        &naive,
        &frames.frames,
        &TargetlessOptions::default(),
        &mut |line| eprintln!("  {line}"),
    )
    .unwrap();
    let targetless_s = started.elapsed().as_secs_f64() - board_s;
    let port = &result.ports[0];
    let (tl_axis_sigma, tl_distance_sigma) =
        (port.axis_sigma_deg.unwrap(), port.distance_sigma_m.unwrap());

    let (tl, board) = (result.rig.port_in_master(0), board_rig.port_in_master(0));
    let axis_apart = angle_deg(tl.normal(), board.normal());
    let distance_apart = tl.air_distance() - board.air_distance();
    let axis_bound = 3.0 * tl_axis_sigma.hypot(board_axis_sigma);
    let distance_bound = 3.0 * tl_distance_sigma.hypot(board_distance_sigma);
    eprintln!(
        "board: axis {:.4}° off the truth (σ {board_axis_sigma:.4}°), air {:+.3} mm (σ {:.3} mm), {board_s:.1} s\n\
         targetless: axis {:.4}° off (σ {tl_axis_sigma:.4}°), air {:+.3} mm (σ {:.3} mm), {} tracks, {targetless_s:.1} s\n\
         apart: axis {axis_apart:.4}° (bound {axis_bound:.4}°), air {:+.3} mm (bound {:.3} mm)",
        angle_deg(board.normal(), true_port.normal()),
        (board.air_distance() - true_port.air_distance()) * 1e3,
        board_distance_sigma * 1e3,
        angle_deg(tl.normal(), true_port.normal()),
        (tl.air_distance() - true_port.air_distance()) * 1e3,
        tl_distance_sigma * 1e3,
        result.inliers,
        distance_apart * 1e3,
        distance_bound * 1e3,
    );
    assert!(result.unpinned.is_empty(), "{:?}", result.unpinned);
    assert!(
        axis_apart <= axis_bound,
        "axes {axis_apart}° apart, bound {axis_bound}°"
    );
    assert!(
        distance_apart.abs() <= distance_bound,
        "air distances {distance_apart} m apart, bound {distance_bound} m"
    );
    for (route, port) in [("board", &board), ("targetless", &tl)] {
        let axis = angle_deg(port.normal(), true_port.normal());
        let air = port.air_distance() - true_port.air_distance();
        assert!(axis < 0.1, "{route}: axis off by {axis}°");
        assert!(air.abs() < 1.5e-3, "{route}: air off by {air} m");
    }
}
