//! The `flatport` binary on files: the CSV contract, every malformed-input case, help texts.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn flatport(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .output()
        .expect("binary runs")
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

const RIG: &str = r#"{
  "cameras": [
    {"name": "left",  "width": 1280, "height": 1024, "fx": 864.91, "fy": 864.91, "cx": 640.0, "cy": 512.0,
     "distortion": [0, 0, 0, 0, 0]},
    {"name": "right", "width": 1280, "height": 1024, "fx": 864.91, "fy": 864.91, "cx": 640.0, "cy": 512.0,
     "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation": [-0.06, 0, 0]}
  ],
  "interface": {"normal": [0.1, 0.1, 1.0], "distance": 0.02,
                "layers": [{"thickness": 0.014, "index": 1.473}],
                "index_air": 1.003, "index_water": 1.333}
}"#;

/// Parses a CSV output into its header and rows of numbers.
fn table(text: &str) -> (String, Vec<Vec<f64>>) {
    let mut lines = text.lines();
    let header = lines.next().expect("header").to_string();
    let rows = lines
        .map(|l| {
            l.split(',')
                .map(|v| v.trim().parse::<f64>().unwrap())
                .collect()
        })
        .collect();
    (header, rows)
}

fn run_ok(args: &[&str]) -> String {
    let o = flatport(args);
    assert!(
        o.status.success(),
        "flatport {args:?} failed: {}",
        stderr(&o)
    );
    stdout(&o)
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

#[test]
fn project_backproject_and_triangulate_agree_with_the_points() {
    let dir = tempfile::tempdir().unwrap();
    let rig = write(dir.path(), "rig.json", RIG);
    let rig = rig.to_str().unwrap();
    let truth = [
        [0.2, -0.1, 1.5],
        [-0.3, 0.25, 0.8],
        [0.0, 0.0, 3.0],
        [0.5, 0.4, 2.2],
    ];
    let mut text = String::from("x,y,z\n");
    for p in &truth {
        text += &format!("{},{},{}\n", p[0], p[1], p[2]);
    }
    let points = write(dir.path(), "points.csv", &text);
    let points = points.to_str().unwrap();

    let left = run_ok(&["project", "--rig", rig, "--points", points]);
    let right = run_ok(&[
        "project", "--rig", rig, "--points", points, "--camera", "right",
    ]);
    let (header, left) = table(&left);
    assert_eq!(header, "u,v");
    let (_, right) = table(&right);
    assert_eq!(left.len(), truth.len());

    // Back-projected rays pass through their points.
    let mut pixels = String::from("u,v\n");
    for p in &left {
        pixels += &format!("{},{}\n", p[0], p[1]);
    }
    let pixels = write(dir.path(), "pixels.csv", &pixels);
    let rays = run_ok(&[
        "backproject",
        "--rig",
        rig,
        "--pixels",
        pixels.to_str().unwrap(),
    ]);
    let (header, rays) = table(&rays);
    assert_eq!(header, "ox,oy,oz,dx,dy,dz");
    for (ray, p) in rays.iter().zip(&truth) {
        let (o, d) = ([ray[0], ray[1], ray[2]], [ray[3], ray[4], ray[5]]);
        let w = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
        let cross = [
            w[1] * d[2] - w[2] * d[1],
            w[2] * d[0] - w[0] * d[2],
            w[0] * d[1] - w[1] * d[0],
        ];
        let miss = cross.iter().map(|c| c * c).sum::<f64>().sqrt();
        // CSV carries shortest round-trip f64 text, so only model rounding remains.
        assert!(miss < 1e-9, "ray misses its point by {miss} m");
        // Origin on the outer interface: n·o = d + t = 0.034 with n = (0.1, 0.1, 1)/|n|.
        let n_dot_o = (0.1 * o[0] + 0.1 * o[1] + o[2]) / 1.02f64.sqrt();
        assert!((n_dot_o - 0.034).abs() < 1e-12);
    }

    // Triangulation returns the points.
    let mut matches = String::from("ul,vl,ur,vr\n");
    for (l, r) in left.iter().zip(&right) {
        matches += &format!("{},{},{},{}\n", l[0], l[1], r[0], r[1]);
    }
    let matches = write(dir.path(), "matches.csv", &matches);
    let out = dir.path().join("tri.csv");
    let o = flatport(&[
        "triangulate",
        "--rig",
        rig,
        "--matches",
        matches.to_str().unwrap(),
        "--output",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(o.stdout.is_empty(), "with --output nothing goes to stdout");
    let (header, tri) = table(&std::fs::read_to_string(&out).unwrap());
    assert_eq!(header, "x,y,z,residual");
    for (t, p) in tri.iter().zip(&truth) {
        let err = ((t[0] - p[0]).powi(2) + (t[1] - p[1]).powi(2) + (t[2] - p[2]).powi(2)).sqrt();
        assert!(err < 1e-7, "triangulated {t:?} vs {p:?}");
        assert!(t[3] < 1e-9);
    }
}

#[test]
fn rows_without_answer_are_nan_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let rig = write(dir.path(), "rig.json", RIG);
    // Row 2 lies inside the glass (z ≈ 0.025 m), row 3 in the air.
    let points = write(
        dir.path(),
        "p.csv",
        "x,y,z\n0.1,0.1,1.0\n0,0,0.025\n0,0,0.01\n0.2,0,2\n",
    );
    let o = flatport(&[
        "project",
        "--rig",
        rig.to_str().unwrap(),
        "--points",
        points.to_str().unwrap(),
    ]);
    assert!(o.status.success());
    let lines: Vec<&str> = std::str::from_utf8(&o.stdout).unwrap().lines().collect();
    assert_eq!(lines.len(), 5, "one row per input row");
    assert_eq!(lines[2], "NaN,NaN");
    assert_eq!(lines[3], "NaN,NaN");
    assert!(!lines[1].contains("NaN") && !lines[4].contains("NaN"));
    let err = stderr(&o);
    assert!(err.contains("2 of 4 rows"), "{err}");
    assert!(err.contains("not in the water"), "{err}");

    let vops = run_ok(&[
        "vop",
        "--rig",
        rig.to_str().unwrap(),
        "--points",
        points.to_str().unwrap(),
    ]);
    let lines: Vec<&str> = vops.lines().collect();
    assert_eq!(lines[0], "depth,vop_distance,vop_x,vop_y,vop_z,incidence");
    assert_eq!(lines[2], "NaN,NaN,NaN,NaN,NaN,NaN");
}

#[test]
fn malformed_csv_names_file_line_and_column_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let rig = write(dir.path(), "rig.json", RIG);
    let rig = rig.to_str().unwrap();
    let out = dir.path().join("out.csv");
    let cases = [
        ("header.csv", "x,y,w\n1,2,3\n", vec!["header.csv", "x,y,z"]),
        (
            "text.csv",
            "x,y,z\n0,0,1\n0.1,abc,2\n",
            vec!["text.csv", ":3", "y", "abc"],
        ),
        ("count.csv", "x,y,z\n0,0,1\n0,0\n", vec!["count.csv", ":3"]),
        ("nan.csv", "x,y,z\n0,0,NaN\n", vec!["nan.csv", ":2", "z"]),
        ("empty.csv", "", vec!["empty.csv"]),
    ];
    for (name, text, needles) in cases {
        let path = write(dir.path(), name, text);
        let err = run_err(&[
            "project",
            "--rig",
            rig,
            "--points",
            path.to_str().unwrap(),
            "--output",
            out.to_str().unwrap(),
        ]);
        for needle in needles {
            assert!(
                err.contains(needle),
                "error for {name} should mention {needle:?}: {err}"
            );
        }
        assert!(
            !out.exists(),
            "nothing is written on malformed input ({name})"
        );
    }
}

#[test]
fn bad_rigs_and_arguments_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let points = write(dir.path(), "p.csv", "x,y,z\n0,0,1\n");
    let points = points.to_str().unwrap();
    let cases = [
        (
            "typo.json",
            RIG.replace("\"index_water\"", "\"index_watr\""),
            vec!["index_watr"],
        ),
        (
            "fx.json",
            RIG.replacen("\"fx\": 864.91, ", "", 1),
            vec!["fx"],
        ),
        (
            "back.json",
            RIG.replace("[0.1, 0.1, 1.0]", "[0.1, 0.1, -1.0]"),
            vec!["normal"],
        ),
        (
            "zero.json",
            RIG.replace("[0.1, 0.1, 1.0]", "[0, 0, 0]"),
            vec!["normal"],
        ),
        (
            "notair.json",
            RIG.replace("[-0.06, 0, 0]", "[0, 0, -0.5]"),
            vec!["right", "air"],
        ),
        (
            "syntax.json",
            RIG.replace("\"cameras\": [", "\"cameras\": [,"),
            vec!["syntax.json"],
        ),
    ];
    for (name, text, needles) in cases {
        let rig = write(dir.path(), name, &text);
        let err = run_err(&[
            "project",
            "--rig",
            rig.to_str().unwrap(),
            "--points",
            points,
        ]);
        for needle in needles {
            assert!(
                err.contains(needle),
                "error for {name} should mention {needle:?}: {err}"
            );
        }
    }
    let rig = write(dir.path(), "rig.json", RIG);
    let rig = rig.to_str().unwrap();
    let err = run_err(&[
        "project", "--rig", rig, "--points", points, "--camera", "middle",
    ]);
    assert!(
        err.contains("middle") && err.contains("left, right"),
        "{err}"
    );
    let err = run_err(&["project", "--rig", rig, "--points", "missing.csv"]);
    assert!(err.contains("missing.csv"), "{err}");
    let err = run_err(&["project", "--rig", "nope.json", "--points", points]);
    assert!(err.contains("nope.json"), "{err}");
    let mono = write(dir.path(), "mono.json", &RIG.replace(
        r#",
    {"name": "right", "width": 1280, "height": 1024, "fx": 864.91, "fy": 864.91, "cx": 640.0, "cy": 512.0,
     "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation": [-0.06, 0, 0]}"#, ""));
    let matches = write(dir.path(), "m.csv", "ul,vl,ur,vr\n1,2,3,4\n");
    let err = run_err(&[
        "triangulate",
        "--rig",
        mono.to_str().unwrap(),
        "--matches",
        matches.to_str().unwrap(),
    ]);
    assert!(err.contains("two cameras"), "{err}");
}

#[test]
fn every_command_has_help_with_an_example() {
    for command in [
        "project",
        "backproject",
        "triangulate",
        "vop",
        "demo",
        "detect",
        "render",
    ] {
        let help = run_ok(&[command, "--help"]);
        assert!(
            help.contains("Example"),
            "{command} --help has no example:\n{help}"
        );
        assert!(help.contains("flatport"), "{command}");
    }
    let help = run_ok(&["rig", "from-opencv", "--help"]);
    assert!(help.contains("Example") && help.contains("--distance"));
    let help = run_ok(&["rig", "from-aquacal", "--help"]);
    assert!(help.contains("Example") && help.contains("--master"));
    for format in ["colmap", "opencv", "aquacal", "raymap"] {
        let help = run_ok(&["export", format, "--help"]);
        assert!(
            help.contains("Example") && help.contains("flatport export"),
            "export {format}"
        );
    }
    let info = run_ok(&["info"]);
    assert!(info.contains(env!("CARGO_PKG_VERSION")) && info.contains("cpu"));
}

/// `export aquacal` and `rig from-aquacal` through the binary: a bare-surface rig comes back with
/// the same numbers (the library's tests check the geometry), a rig with glass is refused saying
/// why, and nothing is written then.
#[test]
fn aquacal_export_and_import() {
    let dir = tempfile::tempdir().unwrap();
    let rig = write(
        dir.path(),
        "rig.json",
        r#"{"cameras": [
            {"name": "cam0", "width": 1280, "height": 960, "fx": 1000, "fy": 1000, "cx": 640, "cy": 480},
            {"name": "cam1", "width": 1280, "height": 960, "fx": 1000, "fy": 1000, "cx": 640, "cy": 480,
             "translation": [-0.1, 0, 0]}],
           "interface": {"normal": [0, 0, 1], "distance": 0.25, "index_water": 1.333}}"#,
    );
    let calibration = dir.path().join("calibration.json");
    run_ok(&[
        "export",
        "aquacal",
        "--rig",
        rig.to_str().unwrap(),
        "-o",
        calibration.to_str().unwrap(),
    ]);
    let text = std::fs::read_to_string(&calibration).unwrap();
    assert!(text.contains("\"water_z\": 0.25") && text.contains("\"version\": \"1.0\""));
    let back = run_ok(&["rig", "from-aquacal", calibration.to_str().unwrap()]);
    let back: serde_json::Value = serde_json::from_str(&back).unwrap();
    assert_eq!(back["interface"]["distance"], 0.25);
    assert_eq!(
        back["interface"]["normal"],
        serde_json::json!([0.0, 0.0, 1.0])
    );
    assert_eq!(
        back["cameras"][1]["translation"],
        serde_json::json!([-0.1, 0.0, 0.0])
    );
    let swapped = run_ok(&[
        "rig",
        "from-aquacal",
        calibration.to_str().unwrap(),
        "--master",
        "cam1",
    ]);
    assert!(swapped.find("cam1").unwrap() < swapped.find("cam0").unwrap());

    let glass = write(
        dir.path(),
        "glass.json",
        &std::fs::read_to_string(&rig).unwrap().replace(
            r#""distance": 0.25,"#,
            r#""distance": 0.25, "layers": [{"thickness": 0.01, "index": 1.49}],"#,
        ),
    );
    let refused = dir.path().join("refused.json");
    let message = run_err(&[
        "export",
        "aquacal",
        "--rig",
        glass.to_str().unwrap(),
        "-o",
        refused.to_str().unwrap(),
    ]);
    assert!(
        message.contains("glass.json") && message.contains("bare water surface"),
        "{message}"
    );
    assert!(!refused.exists());
}

#[test]
fn rig_from_opencv_yaml() {
    let dir = tempfile::tempdir().unwrap();
    let yaml = write(
        dir.path(),
        "stereo.yml",
        "%YAML:1.0
---
image_width: 1280
image_height: 1024
M1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 8.6491000000000003e+02, 0., 640., 0., 8.6491000000000003e+02,
       512., 0., 0., 1. ]
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
   data: [ -0.06, 0., 0. ]
",
    );
    let out = dir.path().join("rig.json");
    let o = flatport(&[
        "rig",
        "from-opencv",
        yaml.to_str().unwrap(),
        "--distance",
        "0.02",
        "--layer",
        "0.014:1.473",
        "--normal",
        "0.1,0.1,1",
        "--output",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let shown = run_ok(&["rig", "show", out.to_str().unwrap()]);
    assert!(
        shown.contains("'right'") && shown.contains("fx 870"),
        "{shown}"
    );
    assert!(shown.contains("azimuth 45.0000°"), "{shown}");
    // Camera right sits 0.06 m to the +x side of the master: C = −Rᵀt.
    assert!(
        shown.contains("centre [0.060000, 0.000000, 0.000000]"),
        "{shown}"
    );
    let err = run_err(&[
        "rig",
        "from-opencv",
        yaml.to_str().unwrap(),
        "--distance",
        "-1",
    ]);
    assert!(err.contains("distance"), "{err}");
}

#[test]
fn demo_runs_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    // Run from a folder outside the checkout, as after `cargo install`: the demo's data are in
    // the binary (the seabed scene named its rig by a path of the checkout once).
    let o = Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(["demo", "--output", "demo", "--device", "cpu"])
        .current_dir(dir.path())
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "demo outside the checkout failed: {}",
        stderr(&o)
    );
    let text = stdout(&o);
    // The calibration story: rendered images, detected corners, calibration from the naive start,
    // two sweeps.
    // From footage alone: the lenses, the extrinsics and the port, against the rendered truth.
    assert!(out.join("footage/water/left").is_dir() && out.join("footage/air/right").is_dir());
    let footage_rig = flatport::io::read_rig(&out.join("footage_rig.json")).unwrap();
    let truth = flatport::io::read_rig("data/example_rig.json".as_ref()).unwrap();
    let (found, want) = (
        footage_rig.shared_interface().unwrap(),
        truth.shared_interface().unwrap(),
    );
    let axis = found.normal().angle(want.normal()).to_degrees();
    let air = (found.air_distance() - want.air_distance()).abs() * 1e3;
    assert!(
        axis < 0.1 && air < 1.5,
        "from footage: axis {axis}°, air {air} mm"
    );
    assert!(out.join("footage_report.json").is_file());
    for file in [
        "rig.json",
        "truth.json",
        "observations.json",
        "start_rig.json",
        "calibrated_rig.json",
        "report.json",
    ] {
        assert!(out.join(file).exists(), "demo wrote no {file}");
    }
    for sweep in ["sweep_wide", "sweep_close"] {
        for file in [
            "heatmap.png",
            "polar.png",
            "cost.npy",
            "cost.csv",
            "summary.json",
        ] {
            assert!(
                out.join(sweep).join(file).exists(),
                "demo wrote no {sweep}/{file}"
            );
        }
    }
    assert!(
        text.contains("against the truth: axis off by 0.0"),
        "{text}"
    );
    // The geometry tour.
    let geometry = out.join("geometry");
    for file in [
        "rig.json",
        "points.csv",
        "pixels_left.csv",
        "pixels_right.csv",
        "rays_left.csv",
        "matches.csv",
        "triangulated.csv",
        "vops_left.csv",
    ] {
        assert!(
            geometry.join(file).exists(),
            "demo wrote no geometry/{file}"
        );
    }
    assert!(text.contains("triangulation"), "{text}");
    // It ends with dense stereo: a point cloud and a depth picture of a rendered scene.
    let stereo = out.join("stereo");
    for file in ["cloud.ply", "depth.png"] {
        assert!(stereo.join(file).is_file(), "demo wrote no stereo/{file}");
    }
    let ply = std::fs::read(stereo.join("cloud.ply")).unwrap();
    let header = String::from_utf8_lossy(&ply[..ply.len().min(400)]).to_string();
    let vertices: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or(0);
    assert!(vertices > 30_000, "{vertices} points: {header}");
    assert!(text.contains("dense stereo"), "{text}");
    // The demo's own files feed the other commands.
    let rig = geometry.join("rig.json");
    let tri = run_ok(&[
        "triangulate",
        "--rig",
        rig.to_str().unwrap(),
        "--matches",
        geometry.join("matches.csv").to_str().unwrap(),
    ]);
    assert_eq!(
        tri.lines().count(),
        std::fs::read_to_string(geometry.join("points.csv"))
            .unwrap()
            .lines()
            .count()
    );
}

/// The GPU path gives the CPU's answers within the f32 and f64 tolerances, NaN rows at the same
/// places, and says which device ran. Needs a Vulkan adapter (lavapipe in CI).
#[test]
fn gpu_device_agrees_with_cpu_device() {
    let dir = tempfile::tempdir().unwrap();
    let rig = write(dir.path(), "rig.json", RIG);
    let mut points = String::from("x,y,z\n");
    for i in 0..400 {
        let (x, y, z) = (
            (i % 20) as f64 * 0.07 - 0.7,
            (i / 20) as f64 * 0.06 - 0.6,
            0.2 + (i % 7) as f64 * 0.8,
        );
        points.push_str(&format!("{x},{y},{z}\n"));
    }
    points.push_str("0,0,0.01\n"); // in the air: NaN row
    let points = write(dir.path(), "points.csv", &points);
    let rig = rig.to_str().unwrap();
    let points = points.to_str().unwrap();
    let cpu = flatport(&[
        "project", "--rig", rig, "--points", points, "--device", "cpu",
    ]);
    assert!(stderr(&cpu).contains("device: cpu"), "{}", stderr(&cpu));
    let (_, expected) = table(&stdout(&cpu));
    for (precision, tolerance) in [("f32", 1e-3), ("f64", 1e-9)] {
        let gpu = flatport(&[
            "project",
            "--rig",
            rig,
            "--points",
            points,
            "--device",
            "gpu",
            "--precision",
            precision,
        ]);
        if !gpu.status.success()
            && std::env::var_os("CI").is_none()
            && stderr(&gpu).contains("no GPU adapter")
        {
            eprintln!("SKIPPED (no Vulkan adapter; CI fails here instead)");
            return;
        }
        assert!(gpu.status.success(), "{}", stderr(&gpu));
        assert!(
            stderr(&gpu).contains("device: gpu: ") && stderr(&gpu).contains(precision),
            "{}",
            stderr(&gpu)
        );
        assert!(
            stderr(&gpu).contains("1 of 401 rows have no answer"),
            "{}",
            stderr(&gpu)
        );
        let (_, rows) = table(&stdout(&gpu));
        assert_eq!(rows.len(), expected.len());
        for (g, c) in rows.iter().zip(&expected) {
            for (a, b) in g.iter().zip(c) {
                assert!(
                    a.is_nan() == b.is_nan()
                        && (a.is_nan() || (a - b).abs() <= tolerance * b.abs().max(1.0)),
                    "{precision}: {g:?} vs {c:?}"
                );
            }
        }
    }
    let refused = run_err(&[
        "project",
        "--rig",
        rig,
        "--points",
        points,
        "--device",
        "cpu",
        "--precision",
        "f32",
    ]);
    assert!(refused.contains("f64 only"), "{refused}");
}

/// Six million rows through the CLI on the GPU: streamed in chunks, every row written in order.
#[test]
fn six_million_rows_through_the_cli() {
    use std::io::{BufRead, Write};
    let dir = tempfile::tempdir().unwrap();
    let rig = write(dir.path(), "rig.json", RIG);
    let pixels = dir.path().join("pixels.csv");
    let n = 6_000_000usize;
    {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&pixels).unwrap());
        writeln!(f, "u,v").unwrap();
        for i in 0..n {
            writeln!(
                f,
                "{},{}",
                (i % 1280) as f64 + 0.5,
                ((i / 1280) % 1024) as f64
            )
            .unwrap();
        }
    }
    let out = dir.path().join("rays.csv");
    let o = flatport(&[
        "backproject",
        "--rig",
        rig.to_str().unwrap(),
        "--pixels",
        pixels.to_str().unwrap(),
        "--device",
        "gpu",
        "-o",
        out.to_str().unwrap(),
    ]);
    if !o.status.success()
        && std::env::var_os("CI").is_none()
        && stderr(&o).contains("no GPU adapter")
    {
        eprintln!("SKIPPED (no Vulkan adapter; CI fails here instead)");
        return;
    }
    assert!(o.status.success(), "{}", stderr(&o));
    let camera = flatport::io::rig_from_json_str(RIG, Path::new("rig.json"))
        .unwrap()
        .refractive_camera(0);
    let file = std::io::BufReader::new(std::fs::File::open(&out).unwrap());
    let mut lines = 0usize;
    for (k, line) in file.lines().enumerate() {
        let line = line.unwrap();
        if k == 0 {
            assert_eq!(line, "ox,oy,oz,dx,dy,dz");
            continue;
        }
        let i = k - 1;
        if i % 100_003 == 0 || i == n - 1 {
            // Row i is pixel i, in order: its direction is the CPU's within the f32 tolerance.
            let v: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
            let pixel = nalgebra::Point2::new((i % 1280) as f64 + 0.5, ((i / 1280) % 1024) as f64);
            let cpu = camera.backproject(&pixel).unwrap();
            let dir = nalgebra::Vector3::new(v[3], v[4], v[5]);
            assert!(
                (dir - cpu.dir.into_inner()).norm() < 2e-6,
                "row {i}: {line}"
            );
        }
        lines += 1;
    }
    assert_eq!(lines, n, "every row, none lost or added");
}

/// `flatport bench --json` writes the issue's shape with a figure for every path (GPU ones where a
/// Vulkan adapter exists; CI requires one).
#[test]
fn bench_json_has_every_path() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bench.json");
    let json_arg = json.to_str().unwrap();
    let mut o = flatport(&[
        "bench",
        "--items",
        "3000",
        "--repeats",
        "1",
        "--sweep-cells",
        "64",
        "--json",
        json_arg,
    ]);
    let gpu = o.status.success()
        || std::env::var_os("CI").is_some()
        || !stderr(&o).contains("Vulkan adapter");
    if !gpu {
        eprintln!("no Vulkan adapter: checking the CPU paths only (CI fails instead)");
        o = flatport(&[
            "bench",
            "--items",
            "3000",
            "--repeats",
            "1",
            "--sweep-cells",
            "64",
            "--json",
            json_arg,
            "--no-gpu",
        ]);
    }
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("ratios from this run") && !stdout(&o).contains("NOT MET"),
        "{}",
        stdout(&o)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(report["memory_stream_bytes_per_s"].as_f64().unwrap() > 1e8);
    let results = report["results"].as_array().unwrap();
    let has = |kernel: &str, path: &str, precision: &str, stage: &str, one_thread: Option<bool>| {
        results.iter().any(|r| {
            r["kernel"] == kernel
                && r["path"] == path
                && r["precision"] == precision
                && r["stage"] == stage
                && r["items"] == 3000
                && r["items_per_s"]
                    .as_f64()
                    .is_some_and(|x| x.is_finite() && x > 0.0)
                && one_thread.is_none_or(|one| (r["threads"] == 1) == one)
        })
    };
    // The sweep: 64 axis cells × 9 990 correspondences, on the CPU and (f64 kernel) the GPU.
    let sweep = |path: &str| {
        results.iter().any(|r| {
            r["kernel"] == "sweep"
                && r["path"] == path
                && r["precision"] == "f64"
                && r["items"] == 64 * 9990
                && r["items_per_s"].as_f64().is_some_and(|x| x > 0.0)
        })
    };
    assert!(sweep("cpu"), "sweep cpu");
    assert!(!gpu || sweep("gpu"), "sweep gpu");
    // Every figure names what ran it; every GPU relation figure is read against its roof, the
    // device memory for a kernel, the host link end to end, both measured in this run.
    for r in results {
        assert!(r["device"].as_str().is_some_and(|d| !d.is_empty()), "{r}");
    }
    if gpu {
        for key in [
            "host_link_upload_bytes_per_s",
            "host_link_download_bytes_per_s",
            "device_memory_bytes_per_s",
        ] {
            assert!(report[key].as_f64().is_some_and(|x| x > 1e7), "{key}");
        }
        let relations = [
            "backproject",
            "project",
            "triangulate",
            "chain_triangulate",
            "chain_triangulate_unfused",
        ];
        for r in results
            .iter()
            .filter(|r| r["path"] == "gpu" && relations.iter().any(|k| r["kernel"] == *k))
        {
            let roof = if r["stage"] == "kernel" {
                "device_memory"
            } else {
                "host_link"
            };
            assert_eq!(r["roof"], roof, "{r}");
            assert!(
                r["roof_fraction"]
                    .as_f64()
                    .is_some_and(|f| f.is_finite() && f > 0.0),
                "{r}"
            );
        }
    }
    for kernel in ["backproject", "project", "triangulate"] {
        assert!(
            has(kernel, "cpu", "f64", "end_to_end", Some(true)),
            "{kernel} cpu 1 thread"
        );
        assert!(
            has(kernel, "cpu", "f64", "end_to_end", None),
            "{kernel} cpu all threads"
        );
        if gpu {
            for precision in ["f32", "f64"] {
                for stage in ["kernel", "end_to_end"] {
                    assert!(
                        has(kernel, "gpu", precision, stage, None),
                        "{kernel} gpu {precision} {stage}"
                    );
                }
            }
        }
    }
    // The device-resident chain, matched pixels → points: one fused kernel and three kernels.
    if gpu {
        for kernel in ["chain_triangulate", "chain_triangulate_unfused"] {
            for precision in ["f32", "f64"] {
                for stage in ["kernel", "end_to_end"] {
                    assert!(
                        has(kernel, "gpu", precision, stage, None),
                        "{kernel} gpu {precision} {stage}"
                    );
                }
            }
        }
    }
    // Forward projection's end-to-end variants; `end_to_end` is the figure of the chunking the
    // engine chose for the adapter, one of the two measured.
    if gpu {
        for precision in ["f32", "f64"] {
            for stage in [
                "end_to_end_streamed",
                "end_to_end_one_chunk",
                "end_to_end_f32_host",
            ] {
                assert!(
                    has("project", "gpu", precision, stage, None),
                    "project gpu {precision} {stage}"
                );
            }
            let rate = |stage: &str| {
                results
                    .iter()
                    .find(|r| {
                        r["kernel"] == "project"
                            && r["path"] == "gpu"
                            && r["precision"] == precision
                            && r["stage"] == stage
                    })
                    .and_then(|r| r["items_per_s"].as_f64())
            };
            let chosen = rate("end_to_end");
            assert!(
                chosen == rate("end_to_end_streamed") || chosen == rate("end_to_end_one_chunk"),
                "project gpu {precision}: end_to_end {chosen:?} is neither measured variant"
            );
        }
    }
    // The CPU on both paths, one thread and all, with the pinhole back-projection beside the rig's.
    for kernel in [
        "backproject",
        "backproject_pinhole",
        "project",
        "triangulate",
    ] {
        for cpu_path in ["scalar", "vector"] {
            for one in [true, false] {
                let found = results.iter().find(|r| {
                    r["kernel"] == kernel
                        && r["path"] == "cpu"
                        && r["cpu_path"] == cpu_path
                        && (r["threads"] == 1) == one
                });
                let r =
                    found.unwrap_or_else(|| panic!("{kernel} cpu {cpu_path} one thread: {one}"));
                assert!(r["items_per_s"].as_f64().is_some_and(|x| x > 0.0), "{r}");
                // Cycles per item for one thread wherever the OS reports a clock.
                if one && report["cpu_clock_hz"].is_f64() {
                    assert!(
                        r["cycles_per_item"].as_f64().is_some_and(|c| c > 0.0),
                        "{r}"
                    );
                }
            }
        }
    }
    let isa = report["cpu_instruction_set"].as_str().unwrap();
    assert!(
        ["avx512", "avx2", "neon", "baseline"].contains(&isa),
        "{isa}"
    );
    if report["cpu_clock_hz"].is_f64() {
        let floors = report["floors"]["kernels"].as_array().unwrap();
        assert_eq!(floors.len(), 4);
        for f in floors {
            assert!(
                f["floor_cycles_per_item"].as_f64().is_some_and(|c| c > 0.0)
                    && f["sqrt_per_item"].as_f64().unwrap() >= 3.0,
                "{f}"
            );
        }
    }
    // The clock of every figure: GPU timestamps for the GPU kernel stage where the adapter has
    // TIMESTAMP_QUERY (lavapipe does, DESIGN.md §6: so in CI), host clocks for everything else.
    for r in results {
        let gpu_kernel = r["path"] == "gpu" && r["stage"] == "kernel";
        let timer = r["timer"]
            .as_str()
            .unwrap_or_else(|| panic!("no timer in {r}"));
        if gpu_kernel {
            assert!(
                timer == "gpu_timestamp" || (timer == "host" && std::env::var_os("CI").is_none()),
                "{r}"
            );
        } else {
            assert_eq!(timer, "host", "{r}");
        }
    }
}

/// Issue 14: the OS error of a missing file is printed once, not once in the message and again as
/// its source.
#[test]
fn os_errors_are_printed_once() {
    let rig = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/example_rig.json");
    let message = run_err(&[
        "vop",
        "--rig",
        rig.to_str().unwrap(),
        "--points",
        "/nonexistent/points.csv",
        "--device",
        "cpu",
    ]);
    assert_eq!(
        message.matches("No such file or directory").count(),
        1,
        "{message}"
    );
    let message = run_err(&["vop", "--rig", "/nonexistent/rig.json", "--points", "p.csv"]);
    assert_eq!(message.matches("os error 2").count(), 1, "{message}");
}

/// Issue 14: negative option values reach the option's parser (they read as unknown flags before)
/// and out-of-range values are refused with a message naming the option and the value.
#[test]
fn negative_and_out_of_range_option_values_name_the_option() {
    let rig = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/example_rig.json");
    let rig = rig.to_str().unwrap();
    let cases: [(&[&str], &[&str]); 9] = [
        (
            &[
                "calibrate",
                "--rig",
                rig,
                "--observations",
                "o.json",
                "-o",
                "c.json",
                "--huber",
                "-1",
            ],
            &["--huber", "must be > 0, got -1"],
        ),
        (
            &[
                "calibrate",
                "--rig",
                rig,
                "--observations",
                "o.json",
                "-o",
                "c.json",
                "--max-tilt-deg",
                "-5",
            ],
            &["--max-tilt-deg", "(0°, 80°), got -5"],
        ),
        (
            &[
                "calibrate",
                "--rig",
                rig,
                "--observations",
                "o.json",
                "-o",
                "c.json",
                "--grid-step-deg",
                "-1",
            ],
            &["--grid-step-deg", "must be > 0"],
        ),
        (
            &[
                "sweep",
                "--rig",
                rig,
                "--observations",
                "o.json",
                "--tilt-deg",
                "0:10:3",
                "--azimuth-deg",
                "0:90:3",
                "-o",
                "s",
                "--distance",
                "-0.01:0.03:3",
            ],
            &["--distance", "air layers must be > 0 m"],
        ),
        (
            &[
                "vop", "--rig", rig, "--points", "p.csv", "--camera", "-1", "--device", "cpu",
            ],
            &["--camera", "no camera '-1'"],
        ),
        (
            &[
                "simulate",
                "--rig",
                rig,
                "-o",
                "s",
                "--max-board-tilt-deg",
                "180",
            ],
            &["--max-board-tilt-deg", "[0°, 90°), got 180"],
        ),
        (
            &[
                "simulate",
                "--rig",
                rig,
                "-o",
                "s",
                "--max-board-tilt-deg",
                "-1",
            ],
            &["--max-board-tilt-deg", "[0°, 90°), got -1"],
        ),
        (
            &["simulate", "--rig", rig, "-o", "s", "--noise", "-0.5"],
            &["--noise", "must be ≥ 0, got -0.5"],
        ),
        (
            &["simulate", "--rig", rig, "-o", "s", "--views", "-3"],
            &["--views", "'-3'"],
        ),
    ];
    for (args, expected) in cases {
        let message = run_err(args);
        assert!(
            !message.contains("unexpected argument"),
            "{args:?}: {message}"
        );
        for part in expected {
            assert!(
                message.contains(part),
                "{args:?}: expected {part:?} in {message}"
            );
        }
    }
}
