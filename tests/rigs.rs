//! Any rig through the `flatport` binary (issue 10): `simulate` for every rig kind and target,
//! `rig from-opencv --unit`, and a rig with a port per camera through every geometry command,
//! checked against the same physical rig written with one shared port.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use flatport::calib::Target;
use flatport::io::{read_observations, read_rig, read_target, read_truth};
use flatport::model::{Ports, Rig};
use nalgebra::{Matrix3, Rotation3, Vector3};

fn flatport(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .output()
        .expect("binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn run_ok(args: &[&str]) -> String {
    let o = flatport(args);
    assert!(
        o.status.success(),
        "flatport {args:?} failed: {}",
        stderr(&o)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn run_err(args: &[&str]) -> String {
    let o = flatport(args);
    assert!(!o.status.success(), "flatport {args:?} should fail");
    assert!(
        o.stdout.is_empty(),
        "a failing command writes nothing to stdout"
    );
    stderr(&o)
}

fn data(name: &str) -> String {
    format!("{}/data/rigs/{name}", env!("CARGO_MANIFEST_DIR"))
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// The same rig to rounding: a rotation written as a matrix and read back through a quaternion
/// moves by ~1e-16, so equality is per value within 1e-12.
fn assert_same_rig(a: &Rig, b: &Rig, what: &str) {
    assert_eq!(a.cameras().len(), b.cameras().len(), "{what}");
    for (k, (ca, cb)) in a.cameras().iter().zip(b.cameras()).enumerate() {
        assert_eq!(
            (&ca.name, &ca.intrinsics),
            (&cb.name, &cb.intrinsics),
            "{what}"
        );
        let gap =
            (ca.cam_from_master.to_homogeneous() - cb.cam_from_master.to_homogeneous()).norm();
        assert!(gap < 1e-12, "{what}: camera {k} moved by {gap}");
        let (pa, pb) = (a.port_in_master(k), b.port_in_master(k));
        assert!(
            (pa.normal().into_inner() - pb.normal().into_inner()).norm() < 1e-12,
            "{what}"
        );
        assert!(
            (pa.air_distance() - pb.air_distance()).abs() < 1e-12,
            "{what}"
        );
        assert_eq!(pa.layers(), pb.layers(), "{what}");
        assert_eq!(
            (pa.index_air(), pa.index_water()),
            (pb.index_air(), pb.index_water())
        );
    }
    assert_eq!(
        matches!(a.ports(), Ports::Shared(_)),
        matches!(b.ports(), Ports::Shared(_)),
        "{what}: the kind of ports"
    );
}

/// Parses a CSV output into rows of numbers (header dropped).
fn table(text: &str) -> Vec<Vec<f64>> {
    text.lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .map(|v| v.trim().parse::<f64>().unwrap())
                .collect()
        })
        .collect()
}

/// The stereo form is what `simulate` wrote before the general form existed: the golden files
/// are the output of the binary built from 25fa429 with the same arguments.
#[test]
fn stereo_simulation_is_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let rig = format!("{}/data/example_rig.json", env!("CARGO_MANIFEST_DIR"));
    for (args, golden) in [
        (
            vec!["--views", "3", "--seed", "5", "--board", "4x3@0.05"],
            "simulate_stereo_4x3_seed5.json",
        ),
        (
            vec![
                "--views",
                "2",
                "--seed",
                "11",
                "--cameras",
                "right,left",
                "--board",
                "3x3@0.06",
                "--noise",
                "0.3",
            ],
            "simulate_stereo_right_left_3x3_seed11.json",
        ),
    ] {
        let out = dir.path().join(golden);
        let mut all = vec!["simulate", "--rig", &rig, "--output", p(&out)];
        all.extend(args);
        run_ok(&all);
        let expected = std::fs::read(format!(
            "{}/tests/golden/{golden}",
            env!("CARGO_MANIFEST_DIR")
        ))
        .unwrap();
        assert!(
            std::fs::read(out.join("observations.json")).unwrap() == expected,
            "{golden} differs"
        );
        // The truth now holds the whole rig, and reads back.
        let truth = read_truth(&out.join("truth.json")).unwrap();
        let expected = read_rig(Path::new(&rig)).unwrap();
        assert_same_rig(truth.rig.as_ref().unwrap(), &expected, golden);
    }
}

/// Every example rig simulates; without noise every corner is the exact projection of the true
/// pose through its camera's port, every view is seen by the master, start_rig.json is the naive
/// start of each port.
#[test]
fn every_example_rig_simulates_in_the_general_form() {
    let dir = tempfile::tempdir().unwrap();
    let target = data("target_v.json");
    let cases: Vec<(&str, Vec<&str>, usize)> = vec![
        ("single_housing.json", vec![], 1),
        ("array_2x2.json", vec!["--min-cameras", "2"], 2),
        ("housings.json", vec![], 1),
        ("housings.json", vec!["--target", &target], 1),
        ("tank.json", vec!["--board", "7x5@0.03"], 1),
        ("tank.json", vec!["--target", &target], 1),
        ("single_housing.json", vec!["--target", &target], 1),
    ];
    for (n, (file, extra, least)) in cases.iter().enumerate() {
        let out = dir.path().join(format!("case{n}"));
        let rig_path = data(file);
        let mut args = vec![
            "simulate",
            "--rig",
            &rig_path,
            "--views",
            "6",
            "--noise",
            "0",
            "--seed",
            "3",
            "--output",
            p(&out),
        ];
        args.extend(extra.iter().copied());
        let printed = run_ok(&args);
        assert!(printed.contains("general form"), "{file}: {printed}");
        let rig = read_rig(Path::new(&rig_path)).unwrap();
        assert_same_rig(&read_rig(&out.join("rig.json")).unwrap(), &rig, file);
        let truth = read_truth(&out.join("truth.json")).unwrap();
        assert_same_rig(truth.rig.as_ref().unwrap(), &rig, file);
        let master = rig.port_in_master(0);
        let normal_gap =
            (truth.interface.normal().into_inner() - master.normal().into_inner()).norm();
        assert!(normal_gap < 1e-15, "{file}");
        assert_eq!(truth.interface.air_distance(), master.air_distance());
        let observations = read_observations(&out.join("observations.json")).unwrap();
        if extra.contains(&"--target") {
            assert_eq!(
                observations.target,
                read_target(Path::new(&target)).unwrap()
            );
        } else {
            assert!(matches!(observations.target, Target::Board(_)));
        }
        let seen = observations.resolve(&rig).unwrap();
        assert_eq!(seen.len(), 6);
        assert_eq!(truth.master_from_board.len(), 6);
        for (v, view) in seen.iter().enumerate() {
            assert_eq!(view.cameras[0].0, 0, "{file} view {v}: the master sees it");
            assert!(view.cameras.len() >= *least, "{file} view {v}");
            for (k, corners) in &view.cameras {
                assert_eq!(corners.len(), observations.target.len(), "the whole target");
                let camera = rig.refractive_camera(*k);
                for &(i, pixel) in corners {
                    let point = truth.master_from_board[v] * observations.target.point(i);
                    let exact = camera.project(&point).unwrap();
                    // The file holds the pixels at full precision; the pose is written as a
                    // rotation matrix and read back through a quaternion.
                    assert!(
                        (pixel - exact).norm() < 1e-6,
                        "{file} view {v} camera {k} corner {i}"
                    );
                }
            }
        }
        let start = read_rig(&out.join("start_rig.json")).unwrap();
        let naive = |port: &flatport::model::Interface| {
            port.normal().into_inner() == Vector3::z() && port.air_distance() == 0.01
        };
        match (start.ports(), rig.ports()) {
            (Ports::Shared(s), Ports::Shared(t)) => {
                assert!(naive(s) && s.layers() == t.layers(), "{file}")
            }
            (Ports::PerCamera(s), Ports::PerCamera(t)) => {
                assert!(
                    s.iter()
                        .zip(t)
                        .all(|(s, t)| naive(s) && s.layers() == t.layers())
                )
            }
            _ => panic!("{file}: start_rig.json changed the kind of ports"),
        }
    }
    // The array: more than one camera sees views, and the seed reproduces the scene.
    let again = dir.path().join("again");
    run_ok(&[
        "simulate",
        "--rig",
        &data("array_2x2.json"),
        "--views",
        "6",
        "--noise",
        "0",
        "--seed",
        "3",
        "--min-cameras",
        "2",
        "--output",
        p(&again),
    ]);
    assert_eq!(
        std::fs::read(again.join("observations.json")).unwrap(),
        std::fs::read(dir.path().join("case1/observations.json")).unwrap()
    );
}

#[test]
fn simulate_refuses_what_it_cannot_do_and_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let target = data("target_v.json");
    let housings = data("housings.json");
    let err = run_err(&[
        "simulate",
        "--rig",
        &housings,
        "--target",
        &target,
        "--board",
        "4x4@0.04",
        "-o",
        p(&out),
    ]);
    assert!(err.contains("--target") && err.contains("--board"), "{err}");
    let err = run_err(&[
        "simulate",
        "--rig",
        &housings,
        "--cameras",
        "left,right",
        "-o",
        p(&out),
    ]);
    assert!(
        err.contains("--cameras") && err.contains("a port per camera"),
        "{err}"
    );
    let err = run_err(&[
        "simulate",
        "--rig",
        &data("array_2x2.json"),
        "--min-cameras",
        "5",
        "-o",
        p(&out),
    ]);
    assert!(
        err.contains("--min-cameras 5") && err.contains("1 to 4"),
        "{err}"
    );
    let err = run_err(&[
        "simulate",
        "--rig",
        &data("array_2x2.json"),
        "--views",
        "50000",
        "-o",
        p(&out),
    ]);
    // 10⁷ corners / (54 corners × 4 cameras) = 46 296 views.
    assert!(
        err.contains("--views 50000") && err.contains("1 to 46296"),
        "{err}"
    );
    // Target files: unknown keys, too few points, all points in one place, not finite.
    for (text, words) in [
        (
            r#"{"points": [[0,0,0],[1,0,0],[0,1,0],[1,1,0]], "unit": "m"}"#,
            vec!["unit"],
        ),
        (
            r#"{"points": [[0,0,0],[1,0,0],[0,1,0]]}"#,
            vec!["points", "at least 4"],
        ),
        (
            r#"{"points": [[0,0,0],[0,0,0],[0,0,0],[0,0,0]]}"#,
            vec!["points", "same point"],
        ),
        (
            r#"{"points": [[0,0,0],[1,0,0],[0,1,0],[1,1,1e999]]}"#,
            vec!["points"],
        ),
    ] {
        let path = dir.path().join("target.json");
        std::fs::write(&path, text).unwrap();
        let err = run_err(&[
            "simulate",
            "--rig",
            &housings,
            "--target",
            p(&path),
            "-o",
            p(&out),
        ]);
        assert!(err.contains("target.json"), "{err}");
        for word in words {
            assert!(err.contains(word), "{text}: {err}");
        }
    }
    // 100 px of noise keeps every corner 500 px from the border: no pose fits the target in.
    let err = run_err(&[
        "simulate",
        "--rig",
        &housings,
        "--target",
        &target,
        "--noise",
        "100",
        "-o",
        p(&out),
    ]);
    assert!(
        err.contains("target_v.json") && err.contains("found no pose"),
        "{err}"
    );
    assert!(!out.exists(), "nothing written");
    let help = run_ok(&["simulate", "--help"]);
    assert!(
        help.contains("--target") && help.contains("Examples:"),
        "{help}"
    );
}

const YAML_MM: &str = "%YAML:1.0
---
image_width: 1280
image_height: 1024
M1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 864.91, 0., 640., 0., 864.91, 512., 0., 0., 1. ]
D1: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.1, 0.01, 0., 0., 0. ]
M2: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 870., 0., 630., 0., 870., 500., 0., 0., 1. ]
D2: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.09, 0.011, 0., 0., 0. ]
R: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]
T: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ -60., 3., 1.5 ]
";

#[test]
fn from_opencv_refuses_millimetres_and_converts_them_with_unit_mm() {
    let dir = tempfile::tempdir().unwrap();
    let yaml = dir.path().join("stereo_mm.yml");
    std::fs::write(&yaml, YAML_MM).unwrap();
    let out = dir.path().join("rig.json");
    let err = run_err(&[
        "rig",
        "from-opencv",
        p(&yaml),
        "--distance",
        "0.02",
        "--output",
        p(&out),
    ]);
    assert!(
        err.contains("stereo_mm.yml") && err.contains("--unit mm"),
        "{err}"
    );
    assert!(!out.exists());
    run_ok(&[
        "rig",
        "from-opencv",
        p(&yaml),
        "--distance",
        "0.02",
        "--unit",
        "mm",
        "--output",
        p(&out),
    ]);
    let rig = read_rig(&out).unwrap();
    let t = rig.cameras()[1].cam_from_master.translation.vector;
    assert_eq!(t, Vector3::new(-0.06, 0.003, 0.0015));
    // Metres stay as they are with the default and with --unit m.
    let metres = dir.path().join("stereo_m.yml");
    std::fs::write(
        &metres,
        YAML_MM.replace("-60., 3., 1.5", "-0.06, 0.003, 0.0015"),
    )
    .unwrap();
    for unit in [&[][..], &["--unit", "m"][..]] {
        let mut args = vec!["rig", "from-opencv", p(&metres), "--distance", "0.02"];
        args.extend(unit);
        let text = run_ok(&args);
        let back = flatport::io::rig_from_json_str(&text, Path::new("stdout")).unwrap();
        assert_eq!(back, rig);
    }
    let err = run_err(&[
        "rig",
        "from-opencv",
        p(&yaml),
        "--distance",
        "0.02",
        "--unit",
        "km",
    ]);
    assert!(err.contains("--unit"), "{err}");
}

/// Writes a rig with a shared port and the same physical rig with a port per camera, each port
/// written by hand in its camera's frame from DESIGN.md §1: n_k = R_k n, d_k = d − n·C_k.
fn shared_and_own_ports(dir: &Path) -> (PathBuf, PathBuf) {
    let normal = Vector3::new(0.1, 0.1, 1.0).normalize();
    let distance = 0.03;
    let rotation: Matrix3<f64> =
        (Rotation3::from_euler_angles(-2f64.to_radians(), 5f64.to_radians(), 0.7f64.to_radians()))
            .into_inner();
    let translation = Vector3::new(-0.08, 0.004, 0.01);
    let centre = -(rotation.transpose() * translation);
    let media = r#""layers": [{"thickness": 0.014, "index": 1.473}], "index_air": 1.003, "index_water": 1.333"#;
    let port = |n: Vector3<f64>, d: f64| {
        format!(
            r#"{{"normal": [{:?}, {:?}, {:?}], "distance": {d:?}, {media}}}"#,
            n.x, n.y, n.z
        )
    };
    let left = r#""name": "left", "width": 1280, "height": 1024, "fx": 864.91, "fy": 870.2, "cx": 640.5, "cy": 511.0, "distortion": [-0.08, 0.012, 0.0004, -0.0003, 0.001]"#;
    let r = rotation;
    let right = format!(
        r#""name": "right", "width": 1024, "height": 768, "fx": 700.0, "fy": 700.0, "cx": 512.0, "cy": 384.0, "distortion": [-0.05, 0.01, 0, 0, 0], "rotation": [[{:?}, {:?}, {:?}], [{:?}, {:?}, {:?}], [{:?}, {:?}, {:?}]], "translation": [{:?}, {:?}, {:?}]"#,
        r[(0, 0)],
        r[(0, 1)],
        r[(0, 2)],
        r[(1, 0)],
        r[(1, 1)],
        r[(1, 2)],
        r[(2, 0)],
        r[(2, 1)],
        r[(2, 2)],
        translation.x,
        translation.y,
        translation.z
    );
    let shared = format!(
        "{{\"cameras\": [{{{left}}}, {{{right}}}], \"interface\": {}}}",
        port(normal, distance)
    );
    let own = format!(
        "{{\"cameras\": [{{{left}, \"interface\": {}}}, {{{right}, \"interface\": {}}}]}}",
        port(normal, distance),
        port(rotation * normal, distance - normal.dot(&centre))
    );
    let (a, b) = (dir.join("shared.json"), dir.join("own.json"));
    std::fs::write(&a, shared).unwrap();
    std::fs::write(&b, own).unwrap();
    let (rig_a, rig_b): (Rig, Rig) = (read_rig(&a).unwrap(), read_rig(&b).unwrap());
    assert!(rig_a.shared_interface().is_some() && rig_b.shared_interface().is_none());
    (a, b)
}

/// Inputs for the geometry commands: points in the water (some that one camera cannot see,
/// one in the air), pixels over the images, matches of the points in both cameras.
fn inputs(dir: &Path, shared: &Path) -> [PathBuf; 3] {
    let mut points = String::from("x,y,z\n");
    // Inside both cameras' views: |x/z| ≤ 0.45, |y/z| ≤ 0.35, depths 0.3 to 4 m.
    for i in 0..300 {
        let z = 0.3 + (i % 11) as f64 * 0.37;
        let (x, y) = (
            ((i % 15) as f64 / 14.0 - 0.5) * 0.9 * z,
            ((i / 15) as f64 / 19.0 - 0.5) * 0.7 * z,
        );
        points.push_str(&format!("{x},{y},{z}\n"));
    }
    points.push_str("0,0,0.01\n");
    let mut pixels = String::from("u,v\n");
    for i in 0..200 {
        pixels.push_str(&format!(
            "{},{}\n",
            (i % 20) as f64 * 50.3 + 3.0,
            (i / 20) as f64 * 75.1 + 4.0
        ));
    }
    let points_path = dir.join("points.csv");
    std::fs::write(&points_path, &points).unwrap();
    let project = |camera: &str| {
        table(&run_ok(&[
            "project",
            "--rig",
            p(shared),
            "--points",
            p(&points_path),
            "--camera",
            camera,
            "--device",
            "cpu",
        ]))
    };
    let (l, r) = (project("left"), project("right"));
    let mut matches = String::from("ul,vl,ur,vr\n");
    let mut swapped = matches.clone();
    for (a, b) in l.iter().zip(&r) {
        if a[0].is_finite() && b[0].is_finite() {
            matches.push_str(&format!("{:?},{:?},{:?},{:?}\n", a[0], a[1], b[0], b[1]));
            swapped.push_str(&format!("{:?},{:?},{:?},{:?}\n", b[0], b[1], a[0], a[1]));
        }
    }
    assert!(
        matches.lines().count() > 250,
        "the points are seen by both cameras"
    );
    std::fs::write(dir.join("matches_right_left.csv"), swapped).unwrap();
    let (pixels_path, matches_path) = (dir.join("pixels.csv"), dir.join("matches.csv"));
    std::fs::write(&pixels_path, pixels).unwrap();
    std::fs::write(&matches_path, matches).unwrap();
    [points_path, pixels_path, matches_path]
}

/// Every geometry command's invocations: (name, arguments after --rig RIG).
fn commands(inputs: &[PathBuf; 3]) -> Vec<(String, Vec<String>)> {
    let [points, pixels, matches] = inputs.clone().map(|p| p.to_str().unwrap().to_string());
    let mut all = Vec::new();
    for camera in ["left", "right"] {
        for (command, flag, file) in [
            ("project", "--points", &points),
            ("backproject", "--pixels", &pixels),
            ("vop", "--points", &points),
        ] {
            all.push((
                format!("{command} {camera}"),
                vec![
                    command.into(),
                    flag.into(),
                    file.clone(),
                    "--camera".into(),
                    camera.into(),
                ],
            ));
        }
    }
    all.push((
        "triangulate".into(),
        vec!["triangulate".into(), "--matches".into(), matches.clone()],
    ));
    all.push((
        "triangulate right,left".into(),
        vec![
            "triangulate".into(),
            "--matches".into(),
            matches.replace("matches.csv", "matches_right_left.csv"),
            "--cameras".into(),
            "right,left".into(),
        ],
    ));
    all
}

fn with_rig(command: &[String], rig: &Path, device: &[&str]) -> Vec<String> {
    let mut args = vec![command[0].clone(), "--rig".into(), p(rig).into()];
    args.extend(command[1..].iter().cloned());
    args.extend(device.iter().map(|s| s.to_string()));
    args
}

fn run_table(args: &[String]) -> Vec<Vec<f64>> {
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    table(&run_ok(&args))
}

/// `absolute` + `relative`·|b| per value, NaN where the other is NaN.
fn assert_close(what: &str, a: &[Vec<f64>], b: &[Vec<f64>], absolute: f64, relative: f64) {
    assert_eq!(a.len(), b.len(), "{what}: row count");
    let mut answered = 0;
    for (row, (ra, rb)) in a.iter().zip(b).enumerate() {
        assert_eq!(ra.len(), rb.len());
        answered += usize::from(!ra[0].is_nan());
        for (x, y) in ra.iter().zip(rb) {
            assert!(
                x.is_nan() == y.is_nan()
                    && (x.is_nan() || (x - y).abs() <= absolute + relative * y.abs()),
                "{what}, row {row}: {ra:?} vs {rb:?}"
            );
        }
    }
    assert!(answered * 2 > a.len(), "{what}: most rows have an answer");
}

/// A port per camera goes through project, backproject, vop, triangulate, export raymap and
/// export colmap as the shared port it describes: the same numbers to 1e-9 px and 1e-12 relative.
#[test]
fn a_port_per_camera_matches_the_shared_port_in_every_command() {
    let dir = tempfile::tempdir().unwrap();
    let (shared, own) = shared_and_own_ports(dir.path());
    let inputs = inputs(dir.path(), &shared);
    for (what, command) in commands(&inputs) {
        let a = run_table(&with_rig(&command, &own, &["--device", "cpu"]));
        let b = run_table(&with_rig(&command, &shared, &["--device", "cpu"]));
        let absolute = if command[0] == "project" { 1e-9 } else { 1e-13 };
        assert_close(&what, &a, &b, absolute, 1e-12);
    }
    // export raymap: every pixel's ray in the water, the same from both files.
    for camera in ["left", "right"] {
        let (ra, rb) = (
            dir.path().join(format!("own-{camera}.npy")),
            dir.path().join(format!("shared-{camera}.npy")),
        );
        for (rig, out) in [(&own, &ra), (&shared, &rb)] {
            run_ok(&[
                "export",
                "raymap",
                "--rig",
                p(rig),
                "--camera",
                camera,
                "--device",
                "cpu",
                "--output",
                p(out),
            ]);
        }
        let (shape_a, a) = flatport::io::npy::read_npy(&ra).unwrap();
        let (shape_b, b) = flatport::io::npy::read_npy(&rb).unwrap();
        assert_eq!(shape_a, shape_b);
        assert!(a.len() > 1_000_000 && a.len() == b.len());
        let answered = a.iter().filter(|x| !x.is_nan()).count();
        assert!(
            answered * 2 > a.len(),
            "raymap {camera}: most pixels have a ray"
        );
        for (i, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!(
                x.is_nan() == y.is_nan()
                    && (x.is_nan() || (x - y).abs() <= 1e-13 + 1e-12 * y.abs()),
                "raymap {camera}, value {i}: {x} vs {y}"
            );
        }
    }
    // export colmap writes each camera's own port: the same numbers from both files.
    let (ca, cb) = (
        dir.path().join("colmap-own"),
        dir.path().join("colmap-shared"),
    );
    run_ok(&["export", "colmap", "--rig", p(&own), "--output", p(&ca)]);
    run_ok(&["export", "colmap", "--rig", p(&shared), "--output", p(&cb)]);
    for file in ["cameras.txt", "rig_config.json", "rigs.txt"] {
        let tokens = |dir: &Path| -> Vec<String> {
            std::fs::read_to_string(dir.join(file))
                .unwrap()
                .split(|c: char| c.is_whitespace() || "[]{},:\"".contains(c))
                .filter(|t| !t.is_empty())
                .map(str::to_string)
                .collect()
        };
        let (ta, tb) = (tokens(&ca), tokens(&cb));
        assert_eq!(ta.len(), tb.len(), "{file}");
        for (x, y) in ta.iter().zip(&tb) {
            match (x.parse::<f64>(), y.parse::<f64>()) {
                (Ok(x), Ok(y)) => assert!(
                    (x - y).abs() <= 1e-15 + 1e-12 * y.abs(),
                    "{file}: {x} vs {y}"
                ),
                _ => assert_eq!(x, y, "{file}"),
            }
        }
    }
}

/// The GPU path on a rig with a port per camera gives the CPU's answers within DESIGN.md §5's
/// tolerances (f32: 1e-3 px, 2e-6 for rays as tests/gpu.rs; f64: 1e-9 relative as tests/cli.rs).
/// Needs a Vulkan adapter (lavapipe in CI).
#[test]
fn a_port_per_camera_on_the_gpu_agrees_with_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let (shared, own) = shared_and_own_ports(dir.path());
    let inputs = inputs(dir.path(), &shared);
    for (what, command) in commands(&inputs) {
        let cpu = run_table(&with_rig(&command, &own, &["--device", "cpu"]));
        for precision in ["f32", "f64"] {
            let args = with_rig(
                &command,
                &own,
                &["--device", "gpu", "--precision", precision],
            );
            let refs: Vec<&str> = args.iter().map(String::as_str).collect();
            let o = flatport(&refs);
            if !o.status.success()
                && std::env::var_os("CI").is_none()
                && stderr(&o).contains("no GPU adapter")
            {
                eprintln!("SKIPPED (no Vulkan adapter; CI fails here instead)");
                return;
            }
            assert!(o.status.success(), "{what} {precision}: {}", stderr(&o));
            let gpu = table(&String::from_utf8_lossy(&o.stdout));
            match (precision, command[0].as_str()) {
                ("f64", _) => assert_close(&format!("{what} f64"), &gpu, &cpu, 1e-12, 1e-9),
                ("f32", "project") => assert_close(&format!("{what} f32"), &gpu, &cpu, 1e-3, 0.0),
                ("f32", "backproject") => {
                    assert_close(&format!("{what} f32"), &gpu, &cpu, 2e-6, 0.0)
                }
                // Triangulated points and VOPs in f32 amplify the ray errors with depth; their
                // f32 bounds are tests/gpu.rs's business. The rows that have an answer agree.
                _ => assert_eq!(
                    gpu.iter().map(|r| r[0].is_nan()).collect::<Vec<_>>(),
                    cpu.iter().map(|r| r[0].is_nan()).collect::<Vec<_>>(),
                    "{what} f32"
                ),
            }
        }
    }
}
