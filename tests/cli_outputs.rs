//! Where the `flatport` binary writes, and how it ends: device nodes, FIFOs and symbolic links as
//! outputs, a full device, signals in the middle of a write, pipes as inputs, a closed stdout.
//!
//! The device nodes are made with `mknod` in a temporary folder (these machines and CI run as
//! root), never the system's own `/dev/null`, which a wrong rename would destroy.

use std::io::{Read, Write};
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn bin() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_flatport"));
    command.env("XDG_RUNTIME_DIR", std::env::temp_dir());
    command
}

fn flatport(args: &[&str]) -> Output {
    bin().args(args).output().expect("binary runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

struct Scene {
    dir: tempfile::TempDir,
    rig: PathBuf,
    points: PathBuf,
}

/// The example rig and `rows` points in the water in front of it.
fn scene(rows: usize) -> Scene {
    let dir = tempfile::tempdir().unwrap();
    let rig = dir.path().join("rig.json");
    std::fs::copy(
        concat!(env!("CARGO_MANIFEST_DIR"), "/data/example_rig.json"),
        &rig,
    )
    .unwrap();
    let mut csv = String::from("x,y,z\n");
    for i in 0..rows {
        let f = i as f64 / rows.max(1) as f64;
        csv.push_str(&format!(
            "{},{},{}\n",
            0.3 * f - 0.15,
            0.1 - 0.2 * f,
            0.5 + f
        ));
    }
    let points = dir.path().join("points.csv");
    std::fs::write(&points, csv).unwrap();
    Scene { dir, rig, points }
}

impl Scene {
    fn project(&self, extra: &[&str]) -> Output {
        let mut args = vec![
            "project",
            "--device",
            "cpu",
            "--rig",
            self.rig.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        flatport(&args)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }
}

fn mknod(path: &Path, major: u32, minor: u32) -> bool {
    Command::new("mknod")
        .arg(path)
        .args(["c", &major.to_string(), &minor.to_string()])
        .status()
        .is_ok_and(|s| s.success())
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| text(&o.stdout).trim() == "0")
}

#[test]
fn a_device_node_output_is_written_in_place_not_replaced() {
    let s = scene(100);
    let null = s.path("null");
    if !mknod(&null, 1, 3) {
        assert!(!is_root(), "mknod failed as root");
        eprintln!("skipped: mknod needs root");
        return;
    }
    for flag in ["-o", "--output"] {
        let o = s.project(&[
            "--points",
            s.points.to_str().unwrap(),
            flag,
            null.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        let kind = std::fs::symlink_metadata(&null).unwrap().file_type();
        assert!(kind.is_char_device(), "the device node was replaced");
    }
    // No temporary beside it.
    assert_eq!(names(s.dir.path()), ["null", "points.csv", "rig.json"]);
    // The calibration report and rig outputs go through the same code.
    let o = flatport(&["rig", "show", s.rig.to_str().unwrap()]);
    assert!(o.status.success());
}

#[test]
fn a_full_device_is_an_error_naming_it() {
    let s = scene(200_000);
    let full = s.path("full");
    if !mknod(&full, 1, 7) {
        assert!(!is_root(), "mknod failed as root");
        return;
    }
    let o = s.project(&[
        "--points",
        s.points.to_str().unwrap(),
        "-o",
        full.to_str().unwrap(),
    ]);
    assert!(!o.status.success(), "writing onto a full device succeeded");
    let stderr = text(&o.stderr);
    assert!(stderr.contains(full.to_str().unwrap()), "{stderr}");
    assert!(stderr.contains("No space left"), "{stderr}");
    assert!(
        std::fs::symlink_metadata(&full)
            .unwrap()
            .file_type()
            .is_char_device()
    );
}

#[test]
fn a_symlink_output_keeps_the_link_and_replaces_its_file() {
    let s = scene(10);
    let real = s.path("real.csv");
    std::fs::write(&real, "old").unwrap();
    let link = s.path("link.csv");
    std::os::unix::fs::symlink("real.csv", &link).unwrap();
    let o = s.project(&[
        "--points",
        s.points.to_str().unwrap(),
        "-o",
        link.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(
        std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink()
    );
    let written = std::fs::read_to_string(&real).unwrap();
    assert!(
        written.starts_with("u,v\n") && written.lines().count() == 11,
        "{written}"
    );
    assert_eq!(
        names(s.dir.path()),
        ["link.csv", "points.csv", "real.csv", "rig.json"]
    );
}

#[test]
fn dev_stdout_as_output_goes_to_standard_output() {
    let s = scene(5);
    let o = s.project(&["--points", s.points.to_str().unwrap(), "-o", "/dev/stdout"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let stdout = text(&o.stdout);
    assert!(
        stdout.starts_with("u,v\n") && stdout.lines().count() == 6,
        "{stdout}"
    );
}

#[test]
fn a_folder_as_output_is_refused_by_name() {
    let s = scene(5);
    let folder = s.path("out");
    std::fs::create_dir(&folder).unwrap();
    let o = s.project(&[
        "--points",
        s.points.to_str().unwrap(),
        "-o",
        folder.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let stderr = text(&o.stderr);
    assert!(
        stderr.contains("folder") && stderr.contains(folder.to_str().unwrap()),
        "{stderr}"
    );
}

/// An OS error's text appears once in a message.
#[test]
fn os_error_text_is_not_repeated() {
    let s = scene(5);
    let o = s.project(&["--points", s.path("missing.csv").to_str().unwrap()]);
    let stderr = text(&o.stderr);
    assert_eq!(stderr.matches("No such file").count(), 1, "{stderr}");
}

/// Starts `flatport project` reading a FIFO that stays open, so the command is mid-write (its
/// temporary output exists) when the signal comes.
fn interrupted_by(signal: &str, expected_code: i32) {
    let s = scene(0);
    let fifo = s.path("input.fifo");
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let out = s.path("out.csv");
    let mut child = bin()
        .args([
            "project",
            "--device",
            "cpu",
            "--rig",
            s.rig.to_str().unwrap(),
        ])
        .args([
            "--points",
            fifo.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut writer = std::fs::OpenOptions::new().write(true).open(&fifo).unwrap();
    writer.write_all(b"x,y,z\n0,0,1\n0.1,0,1\n").unwrap();
    writer.flush().unwrap();
    // Wait until the command has its temporary file open.
    let start = Instant::now();
    while !names(s.dir.path()).iter().any(|n| n.ends_with(".tmp")) {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no temporary file appeared"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let pid = child.id().to_string();
    assert!(
        Command::new("kill")
            .args(["-s", signal, &pid])
            .status()
            .unwrap()
            .success()
    );
    let status = child.wait().unwrap();
    drop(writer);
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    assert_eq!(status.code(), Some(expected_code), "{signal}: {stderr}");
    assert!(stderr.contains("interrupted"), "{stderr}");
    assert_eq!(
        names(s.dir.path()),
        ["input.fifo", "points.csv", "rig.json"],
        "{signal} left files behind"
    );
}

#[test]
fn sigint_removes_the_partial_output() {
    interrupted_by("INT", 130);
}

#[test]
fn sigterm_removes_the_partial_output() {
    interrupted_by("TERM", 143);
}

#[test]
fn sighup_removes_the_partial_output() {
    interrupted_by("HUP", 129);
}

#[test]
fn standard_input_to_standard_output_is_read_once() {
    let s = scene(1000);
    let points = std::fs::read(&s.points).unwrap();
    for input in ["-", "/dev/stdin"] {
        let mut child = bin()
            .args([
                "project",
                "--device",
                "cpu",
                "--rig",
                s.rig.to_str().unwrap(),
                "--points",
                input,
            ])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut stdin = child.stdin.take().unwrap();
        let bytes = points.clone();
        let feeder = std::thread::spawn(move || stdin.write_all(&bytes));
        let o = child.wait_with_output().unwrap();
        feeder.join().unwrap().unwrap();
        assert!(o.status.success(), "{input}: {}", text(&o.stderr));
        assert_eq!(text(&o.stdout).lines().count(), 1001, "{input}");
    }
}

#[test]
fn a_fifo_input_to_standard_output_is_read_once() {
    // What `--points <(generate)` hands the command: a pipe that can be read once.
    let s = scene(1000);
    let fifo = s.path("points.fifo");
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let points = std::fs::read(&s.points).unwrap();
    let feeder = {
        let fifo = fifo.clone();
        std::thread::spawn(move || {
            std::fs::OpenOptions::new()
                .write(true)
                .open(&fifo)
                .unwrap()
                .write_all(&points)
        })
    };
    let o = s.project(&["--points", fifo.to_str().unwrap()]);
    feeder.join().unwrap().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(text(&o.stdout).lines().count(), 1001);
}

#[test]
fn a_bad_row_from_standard_input_writes_nothing_to_standard_output() {
    let s = scene(0);
    let mut child = bin()
        .args([
            "project",
            "--device",
            "cpu",
            "--rig",
            s.rig.to_str().unwrap(),
            "--points",
            "-",
        ])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(b"x,y,z\n0,0,1\n0,0,1\n0,zero,1\n")
        .unwrap();
    let o = child.wait_with_output().unwrap();
    assert!(!o.status.success());
    assert!(o.stdout.is_empty(), "wrote {:?}", text(&o.stdout));
    let stderr = text(&o.stderr);
    assert!(stderr.contains(":4") && stderr.contains("zero"), "{stderr}");
}

#[test]
fn a_closed_standard_output_ends_quietly() {
    let s = scene(300_000);
    let mut child = bin()
        .args([
            "project",
            "--device",
            "cpu",
            "--rig",
            s.rig.to_str().unwrap(),
        ])
        .args(["--points", s.points.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Read one line, then close the pipe, as `| head -1` does.
    let mut stdout = child.stdout.take().unwrap();
    let mut first = [0u8; 4];
    stdout.read_exact(&mut first).unwrap();
    drop(stdout);
    let o = child.wait_with_output().unwrap();
    let stderr = text(&o.stderr);
    assert_eq!(o.status.code(), Some(141), "{stderr}");
    assert!(
        !stderr.contains("Broken pipe") && !stderr.contains("error"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn a_closed_standard_output_of_a_summary_ends_quietly() {
    // `rig show` prints with the stdout helper (println! would panic on EPIPE).
    let s = scene(0);
    let mut child = bin()
        .args(["rig", "show", s.rig.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let stderr = text(&o.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        matches!(o.status.code(), Some(0) | Some(141)),
        "{:?} {stderr}",
        o.status
    );
}
