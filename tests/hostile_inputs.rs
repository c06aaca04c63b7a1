//! A campaign of bad and hostile input through the `flatport` binary, as a new user or a script
//! gone wrong would give it. Every case must end in a clear error (exit 1, or 2 for a usage error
//! from the argument parser) whose message names what is wrong, in a message of bounded length,
//! without a panic, a hang or a file left behind; the few valid edge cases must succeed.

use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Runs `flatport args` in `dir` with a time limit; (exit code, stdout, stderr).
fn run(dir: &Path, args: &[&str]) -> (i32, String, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .current_dir(dir)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("binary runs");
    let (mut out, mut err) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = out.read_to_string(&mut text);
        text
    });
    let err_reader = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = err.read_to_string(&mut text);
        text
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("flatport {args:?} hangs (over 120 s)");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    (
        status.code().unwrap_or(-1),
        reader.join().unwrap(),
        err_reader.join().unwrap(),
    )
}

fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

const RIG_OK: &str = r#"{"cameras": [{"name": "a", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240}],
 "interface": {"normal": [0, 0, 1], "distance": 0.02}}"#;

/// Two cameras 6 cm apart behind one port whose normal is `NORMAL`.
const TWO_CAMERAS: &str = r#"{"cameras": [
 {"name": "left", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240},
 {"name": "right", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240, "translation": [-0.06, 0, 0]}],
 "interface": {"normal": NORMAL, "distance": 0.02}}"#;

/// Two cameras with a port each, the second's normal underflowing.
const PORT_PER_CAMERA: &str = r#"{"cameras": [
 {"name": "left", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240,
  "interface": {"normal": [0, 0, 1], "distance": 0.02}},
 {"name": "right", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240, "translation": [-0.06, 0, 0],
  "interface": {"normal": [1e-320, 0, 1e-320], "distance": 0.02}}]}"#;

/// A rig file with `interface` replaced.
fn rig_with(interface: &str) -> String {
    format!(
        r#"{{"cameras": [{{"name": "a", "width": 640, "height": 480, "fx": 500, "fy": 500, "cx": 320, "cy": 240}}], "interface": {interface}}}"#
    )
}

struct Case {
    /// Files to write first: (name, content).
    files: Vec<(&'static str, String)>,
    args: Vec<&'static str>,
    /// Every one of these must appear in stderr.
    says: Vec<&'static str>,
}

fn case(files: Vec<(&'static str, String)>, args: &[&'static str], says: &[&'static str]) -> Case {
    Case {
        files,
        args: args.to_vec(),
        says: says.to_vec(),
    }
}

#[test]
fn hostile_input_gets_a_clear_error_and_leaves_nothing_behind() {
    let rig = || ("rig.json", RIG_OK.to_string());
    let example = || {
        (
            "example.json",
            std::fs::read_to_string(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/data/example_rig.json"
            ))
            .unwrap(),
        )
    };
    let points = |text: &str| ("p.csv", text.to_string());
    let cases = vec![
        // Rig files.
        case(
            vec![("rig.json", String::new()), points("x,y,z\n0,0,1\n")],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["rig.json"],
        ),
        case(
            vec![("rig.json", "\u{feff}[]".into()), points("x,y,z\n0,0,1\n")],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["rig.json"],
        ),
        case(
            vec![
                (
                    "rig.json",
                    rig_with(r#"{"normal": [0, 0, -1], "distance": 0.02}"#),
                ),
                points("x,y,z\n0,0,1\n"),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["rig.json", "normal"],
        ),
        case(
            vec![
                (
                    "rig.json",
                    rig_with(r#"{"normal": [0, 0, 0], "distance": 0.02}"#),
                ),
                points("x,y,z\n0,0,1\n"),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["rig.json", "normal"],
        ),
        case(
            vec![
                (
                    "rig.json",
                    rig_with(
                        r#"{"normal": [0, 0, 1], "distance": 0.02, "layers": [{"thickness": 0.01, "index": 0.5}]}"#,
                    ),
                ),
                points("x,y,z\n0,0,1\n"),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["rig.json", "layers[0]"],
        ),
        case(
            vec![
                (
                    "rig.json",
                    rig_with(r#"{"normal": [0, 0, 1], "distance": 0.02, "colour": 3}"#),
                ),
                points("x,y,z\n0,0,1\n"),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["rig.json", "colour"],
        ),
        case(
            vec![("rig.json", "[".repeat(100_000)), points("x,y,z\n0,0,1\n")],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["rig.json"],
        ),
        // A normal whose length underflows: named as the normal, not as a camera "not in the
        // air" (the direction such a normal gave put the second camera in the water). Through
        // project, rig show and calibrate's start rig, with a shared port and a port per camera.
        case(
            vec![
                (
                    "rig.json",
                    TWO_CAMERAS.replace("NORMAL", "[1e-320, 0, 1e-320]"),
                ),
                points("x,y,z\n0,0,1\n"),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &[
                "rig.json",
                "interface.normal",
                "not representable",
                "underflows",
            ],
        ),
        case(
            vec![("rig.json", TWO_CAMERAS.replace("NORMAL", "[0, 0, 1e-310]"))],
            &["rig", "show", "rig.json"],
            &["rig.json", "interface.normal", "not representable"],
        ),
        case(
            vec![
                (
                    "rig.json",
                    TWO_CAMERAS.replace("NORMAL", "[1e-320, 0, 1e-320]"),
                ),
                (
                    "obs.json",
                    r#"{"board": {"rows": 2, "cols": 2, "square": 0.04}, "views": []}"#.into(),
                ),
            ],
            &[
                "calibrate",
                "--rig",
                "rig.json",
                "--observations",
                "obs.json",
                "-o",
                "c.json",
            ],
            &["rig.json", "interface.normal", "not representable"],
        ),
        case(
            vec![("rig.json", PORT_PER_CAMERA.to_string())],
            &["rig", "show", "rig.json"],
            &[
                "rig.json",
                "cameras[1].interface.normal",
                "not representable",
            ],
        ),
        // User text echoed in errors is cut to its start and its size: a header of 20 million
        // columns (40 MB), a 1 MB key or value in JSON, observations and OpenCV YAML, a 1 MB
        // camera name (every message naming the camera would carry it).
        case(
            vec![
                rig(),
                ("p.csv", format!("{}x\n0,0,1\n", "x,".repeat(19_999_999))),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &[
                "p.csv:1",
                "column '2'",
                "header is 'x,x,x",
                "(20000000 columns, 39999999 bytes), expected 'x,y,z'",
            ],
        ),
        case(
            vec![
                (
                    "rig.json",
                    rig_with(&format!(
                        r#"{{"normal": [0, 0, 1], "distance": 0.02, "{}": 3}}"#,
                        "k".repeat(1 << 20)
                    )),
                ),
                points("x,y,z\n0,0,1\n"),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["rig.json:1:", "unknown field `kkkk", "(1048576 bytes)"],
        ),
        case(
            vec![
                (
                    "rig.json",
                    RIG_OK.replace(
                        "\"fx\": 500",
                        &format!("\"fx\": \"{}\"", "5".repeat(1 << 20)),
                    ),
                ),
                points("x,y,z\n0,0,1\n"),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &[
                "rig.json:1:",
                "cameras[0].fx",
                "invalid type: string \"5555",
                "(1048576 bytes)",
            ],
        ),
        case(
            vec![
                (
                    "rig.json",
                    RIG_OK.replace(
                        "\"name\": \"a\"",
                        &format!("\"name\": \"{}\"", "a".repeat(1 << 20)),
                    ),
                ),
                points("x,y,z\n0,0,1\n"),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["rig.json", "cameras[0].name", "1048576 bytes"],
        ),
        case(
            vec![
                rig(),
                (
                    "obs.json",
                    format!(
                        r#"{{"board": {{"rows": 2, "cols": 2, "square": 0.04}}, "views": [{{"{}": [[1, 1], [2, 2], [3, 3], [4, 4]]}}]}}"#,
                        "k".repeat(1 << 20)
                    ),
                ),
            ],
            &[
                "calibrate",
                "--rig",
                "rig.json",
                "--observations",
                "obs.json",
                "-o",
                "c.json",
            ],
            &["obs.json", "views[0]", "kkkk", "1048576 bytes"],
        ),
        case(
            vec![(
                "s.yml",
                format!("%YAML:1.0\n---\n{k}: 1\n{k}: 2\n", k = "k".repeat(1 << 20)),
            )],
            &["rig", "from-opencv", "s.yml", "--distance", "0.02"],
            &[
                "s.yml:3:",
                "key 'kkkk",
                "(1048576 bytes)' is longer than YAML allows",
            ],
        ),
        // CSV files.
        case(
            vec![rig(), points("")],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["p.csv", "empty"],
        ),
        case(
            vec![rig(), points("x,y\n0,0\n")],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["p.csv:1", "header"],
        ),
        case(
            vec![rig(), points("x,y,z\n0,0,1\n0,0,nan\n")],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["p.csv:3", "z"],
        ),
        case(
            vec![rig(), points("x,y,z\n0,0,1\n\u{0}\u{1},0,1\n")],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["p.csv:3"],
        ),
        case(
            vec![
                rig(),
                ("p.csv", format!("x,y,z\n{},0,1\n", "7".repeat(5_000_000))),
            ],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "-o", "out.csv",
            ],
            &["p.csv:2"],
        ),
        case(
            vec![rig(), points("x,y,z\n0,0,1\n")],
            &[
                "project",
                "--rig",
                "rig.json",
                "--points",
                "missing.csv",
                "-o",
                "out.csv",
            ],
            &["missing.csv"],
        ),
        case(
            vec![rig(), points("x,y,z\n0,0,1\n")],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "--camera", "-1",
            ],
            &["-1"],
        ),
        case(
            vec![rig(), points("x,y,z\n0,0,1\n")],
            &[
                "project", "--rig", "rig.json", "--points", "p.csv", "--camera", "9",
            ],
            &["9"],
        ),
        case(
            vec![rig(), points("x,y,z\n0,0,1\n")],
            &[
                "project",
                "--rig",
                "rig.json",
                "--points",
                "p.csv",
                "--device",
                "gpu",
                "--adapter",
                "no-such-gpu",
            ],
            &["no-such-gpu"],
        ),
        // Simulation sizes and values.
        case(
            vec![example()],
            &[
                "simulate",
                "--rig",
                "example.json",
                "--views",
                "18446744073709551615",
                "-o",
                "scene",
            ],
            &["--views"],
        ),
        case(
            vec![example()],
            &[
                "simulate",
                "--rig",
                "example.json",
                "--board",
                "100000x100000@0.04",
                "-o",
                "scene",
            ],
            &["100000"],
        ),
        case(
            vec![example()],
            &[
                "simulate",
                "--rig",
                "example.json",
                "--board",
                "9x6@1e300",
                "-o",
                "scene",
            ],
            &["metres"],
        ),
        case(
            vec![example()],
            &[
                "simulate",
                "--rig",
                "example.json",
                "--noise",
                "1e300",
                "-o",
                "scene",
            ],
            &["noise"],
        ),
        case(
            vec![example()],
            &[
                "simulate",
                "--rig",
                "example.json",
                "--noise",
                "-1",
                "-o",
                "scene",
            ],
            &["--noise"],
        ),
        case(
            vec![example()],
            &[
                "simulate",
                "--rig",
                "example.json",
                "--max-board-tilt-deg",
                "180",
                "-o",
                "scene",
            ],
            &["--max-board-tilt-deg"],
        ),
        // Bench sizes.
        case(vec![], &["bench", "--items", "0", "--no-gpu"], &["--items"]),
        case(
            vec![],
            &["bench", "--items", "10000000000", "--no-gpu"],
            &["--items"],
        ),
    ];
    for (k, c) in cases.iter().enumerate() {
        let dir = tempfile::tempdir().unwrap();
        for (name, content) in &c.files {
            std::fs::write(dir.path().join(name), content).unwrap();
        }
        let before = names(dir.path());
        let (code, stdout, stderr) = run(dir.path(), &c.args);
        let what = format!("case {k}: flatport {:?}", c.args);
        assert!(!stderr.contains("panicked"), "{what} panicked: {stderr}");
        assert!(
            code == 1 || code == 2,
            "{what}: exit {code}, stderr {stderr}"
        );
        assert!(stdout.is_empty(), "{what} wrote to stdout: {stdout}");
        assert!(stderr.contains("error"), "{what}: {stderr}");
        assert!(
            stderr.len() < 3000,
            "{what}: a message of {} bytes",
            stderr.len()
        );
        for word in &c.says {
            assert!(
                stderr.contains(word),
                "{what}: the message does not name '{word}': {stderr}"
            );
        }
        assert_eq!(names(dir.path()), before, "{what} left files behind");
    }
}

#[test]
fn edge_cases_that_are_valid_succeed() {
    let dir = tempfile::tempdir().unwrap();
    // A normal given with huge or tiny components keeps its direction, as long as its length is
    // an ordinary f64 (1e-320 components, whose length underflows, are refused above).
    for normal in ["[1e308, 0, 1e308]", "[1e-300, 0, 1e-300]"] {
        std::fs::write(
            dir.path().join("rig.json"),
            rig_with(&format!(r#"{{"normal": {normal}, "distance": 0.02}}"#)),
        )
        .unwrap();
        let (code, stdout, stderr) = run(dir.path(), &["rig", "show", "rig.json"]);
        assert_eq!(code, 0, "{normal}: {stderr}");
        assert!(stdout.contains("tilt 45.0000°"), "{normal}: {stdout}");
    }
    // Large simulated noise still keeps every corner in the images, so calibrate accepts the file
    // (it may then find no axis, but never calls a corner outside the image).
    std::fs::copy(
        concat!(env!("CARGO_MANIFEST_DIR"), "/data/example_rig.json"),
        dir.path().join("example.json"),
    )
    .unwrap();
    let (code, _, stderr) = run(
        dir.path(),
        &[
            "simulate",
            "--rig",
            "example.json",
            "--views",
            "4",
            "--noise",
            "30",
            "-o",
            "noisy",
        ],
    );
    assert_eq!(code, 0, "{stderr}");
    let (_, _, stderr) = run(
        dir.path(),
        &[
            "calibrate",
            "--rig",
            "noisy/start_rig.json",
            "--observations",
            "noisy/observations.json",
            "-o",
            "c.json",
        ],
    );
    assert!(
        !stderr.contains("outside the") && !stderr.contains("panicked"),
        "{stderr}"
    );
}
