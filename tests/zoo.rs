//! The rig zoo (issue 45): random rigs a user may bring ([`flatport::calib::simulate::zoo`]),
//! each rendered as a calibration set and calibrated by `flatport calibrate --images` with no
//! option beyond what a user knows (`--port`, `--glass`), then scored against its truth: was a rig
//! written, and is every estimate within 3σ of the truth (and within issue 38's bounds)?
//!
//! `seeded_subset` runs a fixed handful in CI. The sweep behind docs/performance.md's table:
//!
//! ```sh
//! FP_ZOO_SEEDS=1-100 FP_ZOO_IMAGING=0 cargo test --release --test zoo -- --ignored --nocapture sweep
//! ```
//!
//! writes `target/tmp/zoo/table.md` (one row a rig: what it is, the outcome and the verdict or the
//! refusal's reason, each error against its σ). `FP_ZOO_IMAGING=SEVERITY` renders with real-camera
//! degradations (`render --imaging`); `FP_ZOO_WATER_ONLY=1` removes the in-air views, so every lens
//! comes from the underwater frames.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use flatport::calib::simulate::zoo::{ZooPort, ZooRig, zoo_rig};
use flatport::io::{read_rig, write_rig};
use flatport::model::{Ports, Rig};
use serde_json::Value;

fn flatport(args: &[String]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("the flatport binary runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// One rig's outcome.
#[derive(Debug)]
struct Row {
    rig: String,
    /// `None`: a rig was written; else the refusal's last line.
    refused: Option<String>,
    /// Largest axis error of a port, degrees, and the same over its σ.
    axis: (f64, f64),
    /// Largest air-distance error of a port, mm, and over its σ.
    air: (f64, f64),
    /// Largest rotation error of a camera, degrees, and over its σ.
    rotation: (f64, f64),
    /// Largest centre error of a camera, mm.
    centre_mm: f64,
    /// Whether the kind is a surface (its air bound is 0.3 mm, else 1.5 mm).
    surface: bool,
    /// The report's verdict (`good`, `usable`), where written.
    verdict: String,
    seconds: f64,
}

impl Row {
    /// Every estimate within 3σ of the truth (an axis: of its σ over both angles).
    fn within_3_sigma(&self) -> bool {
        self.refused.is_none() && self.axis.1 <= 3.0 && self.air.1 <= 3.0 && self.rotation.1 <= 3.0
    }

    /// Within issue 38's bounds: axis 0.1°, air 1.5 mm (surface 0.3 mm), extrinsics 0.05° / 1 mm.
    fn within_bounds(&self) -> bool {
        let air = if self.surface { 0.3 } else { 1.5 };
        self.refused.is_none()
            && self.axis.0 <= 0.1
            && self.air.0 <= air
            && self.rotation.0 <= 0.05
            && self.centre_mm <= 1.0
    }

    fn markdown(&self) -> String {
        match &self.refused {
            Some(why) => format!(
                "| {} | refused: {} | | | | | {:.0} |",
                self.rig, why, self.seconds
            ),
            None => format!(
                "| {} | {} ({}) | {:.4}° ({:.1}σ) | {:.3} mm ({:.1}σ) | {:.4}° ({:.1}σ) | {:.3} mm | {:.0} |",
                self.rig,
                match (self.within_3_sigma(), self.within_bounds()) {
                    (true, true) => "ok",
                    (true, false) => "ok within 3σ, over a bound",
                    (false, true) => "within bounds, over 3σ",
                    (false, false) => "OFF",
                },
                self.verdict,
                self.axis.0,
                self.axis.1,
                self.air.0,
                self.air.1,
                self.rotation.0,
                self.rotation.1,
                self.centre_mm,
                self.seconds
            ),
        }
    }
}

/// The σ of a port's axis over both angles, degrees, from the report's tilt and azimuth σ.
fn axis_std_deg(port: &Value) -> f64 {
    let tilt = port["tilt_deg"]["value"]
        .as_f64()
        .unwrap_or(0.0)
        .to_radians();
    let st = port["tilt_deg"]["std"].as_f64().unwrap_or(f64::NAN);
    let sa = port["azimuth_deg"]["std"].as_f64().unwrap_or(f64::NAN);
    (st * st + (tilt.sin() * sa).powi(2)).sqrt()
}

/// Renders `zoo`'s calibration set into `dir` and calibrates it with default options (with
/// `water_only`, the in-air views removed first: every lens from the underwater frames).
fn run(zoo: &ZooRig, imaging: f64, water_only: bool, dir: &Path) -> Row {
    std::fs::create_dir_all(dir).unwrap();
    let rig_path = dir.join("truth_rig.json");
    let board_path = dir.join("board.json");
    write_rig(&rig_path, &zoo.rig).unwrap();
    std::fs::write(&board_path, zoo.board.json()).unwrap();
    let set = dir.join("set");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let mut render: Vec<String> = [
        "render",
        "--rig",
        &s(&rig_path),
        "--board",
        &s(&board_path),
        "--calibration-set",
        "--views",
        "24",
        "--air-views",
        "15",
        "--noise",
        "1",
        "--seed",
        &zoo.seed.to_string(),
        "--distance",
        &format!("{}:{}", zoo.water_distance().0, zoo.water_distance().1),
        "--device",
        "cpu",
        "-q",
        "-o",
        &s(&set),
    ]
    .iter()
    .map(|a| a.to_string())
    .collect();
    if imaging > 0.0 {
        render.extend(["--imaging".to_string(), imaging.to_string()]);
    }
    let out = flatport(&render);
    assert!(
        out.status.success(),
        "{}: render: {}",
        zoo.describe(),
        text(&out.stderr)
    );
    if water_only {
        std::fs::remove_dir_all(set.join("air")).unwrap();
        std::fs::remove_dir_all(set.join("air-truth")).unwrap();
    }
    let found_path = dir.join("rig.json");
    let report_path = dir.join("report.json");
    let _ = std::fs::remove_file(&found_path);
    let mut args: Vec<String> = [
        "calibrate",
        "--images",
        &s(&set),
        "--board",
        &s(&board_path),
        "--port",
        zoo.port.flag(),
        "--device",
        "cpu",
        "-q",
        "--output",
        &s(&found_path),
        "--report",
        &s(&report_path),
    ]
    .iter()
    .map(|a| a.to_string())
    .collect();
    for g in &zoo.glass {
        args.push("--glass".into());
        args.push(g.clone());
    }
    let started = std::time::Instant::now();
    let out = flatport(&args);
    let seconds = started.elapsed().as_secs_f64();
    let mut row = Row {
        rig: zoo.describe(),
        refused: None,
        axis: (0.0, 0.0),
        air: (0.0, 0.0),
        rotation: (0.0, 0.0),
        centre_mm: 0.0,
        surface: zoo.port == ZooPort::Surface,
        seconds,
        verdict: String::new(),
    };
    if !out.status.success() {
        let stderr = text(&out.stderr);
        assert!(
            !found_path.exists(),
            "a refusal wrote {}",
            found_path.display()
        );
        row.refused = Some(
            stderr
                .lines()
                .rev()
                .find(|l| l.starts_with("error"))
                .unwrap_or("(no error line)")
                .chars()
                .take(400)
                .collect(),
        );
        return row;
    }
    let found = read_rig(&found_path).unwrap();
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(&report_path).unwrap()).unwrap();
    score(&zoo.rig, &found, &report, &mut row);
    row.verdict = report["verdict"]["grade"]
        .as_str()
        .unwrap_or("no verdict")
        .into();
    row
}

fn score(truth: &Rig, found: &Rig, report: &Value, row: &mut Row) {
    let ports = |rig: &Rig| match rig.ports() {
        Ports::Shared(p) => vec![p.clone()],
        Ports::PerCamera(p) => p.clone(),
    };
    let reported = report["ports"].as_array().cloned().unwrap_or_default();
    for (p, (t, f)) in ports(truth).iter().zip(ports(found)).enumerate() {
        let axis = t.normal().angle(f.normal()).to_degrees();
        let air = (t.air_distance() - f.air_distance()).abs();
        let (sa, sd) = reported.get(p).map_or((f64::NAN, f64::NAN), |r| {
            (
                axis_std_deg(r),
                r["distance"]["std"].as_f64().unwrap_or(f64::NAN),
            )
        });
        row.axis = worst(row.axis, (axis, axis / sa));
        row.air = worst(row.air, (air * 1e3, air / sd));
    }
    let cameras = report["cameras"].as_array().cloned().unwrap_or_default();
    for t in truth.cameras().iter().skip(1) {
        let Some(j) = found.camera_index(&t.name) else {
            continue;
        };
        let f = &found.cameras()[j];
        let rotation = t
            .cam_from_master
            .rotation
            .angle_to(&f.cam_from_master.rotation)
            .to_degrees();
        let centre = (t.centre_in_master() - f.centre_in_master()).norm() * 1e3;
        // The report's camera by name (the calibrated rig's order need not be the truth's).
        let sr = cameras
            .iter()
            .find(|c| c["name"].as_str() == Some(t.name.as_str()))
            .and_then(|c| c["rotation_std_deg"].as_array())
            .map_or(f64::NAN, |s| {
                s.iter()
                    .filter_map(Value::as_f64)
                    .map(|v| v * v)
                    .sum::<f64>()
                    .sqrt()
            });
        row.rotation = worst(row.rotation, (rotation, rotation / sr));
        row.centre_mm = row.centre_mm.max(centre);
    }
}

/// The larger error, with its ratio to σ (a NaN ratio, no σ, counts as over).
fn worst(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    let ratio = |r: f64| if r.is_nan() { f64::INFINITY } else { r };
    (a.0.max(b.0), ratio(a.1).max(ratio(b.1)))
}

fn out_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("zoo")
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn table(rows: &[Row]) -> String {
    let mut t = String::from(
        "| rig | outcome | axis (worst port) | air layer | rotation | centre | s |\n|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        t += &r.markdown();
        t.push('\n');
    }
    let written = rows.iter().filter(|r| r.refused.is_none()).count();
    let sigma = rows.iter().filter(|r| r.within_3_sigma()).count();
    let bounds = rows.iter().filter(|r| r.within_bounds()).count();
    t += &format!(
        "\n{} rigs: {written} written, {sigma} within 3σ, {bounds} within issue 38's bounds, {} refused\n",
        rows.len(),
        rows.len() - written
    );
    t
}

/// Seeds from `FP_ZOO_SEEDS` (`A-B` or `A,B,C`).
fn seeds(spec: &str) -> Vec<u64> {
    if let Some((a, b)) = spec.split_once('-') {
        (a.trim().parse().unwrap()..=b.trim().parse().unwrap()).collect()
    } else {
        spec.split(',').map(|s| s.trim().parse().unwrap()).collect()
    }
}

/// A fixed handful of zoo rigs (a tank wall with one camera, six cameras above a surface, two
/// housings, eight cameras behind a shared window, three cameras 0.3 m apart converging through
/// one window, two housings and seven cameras behind a window with colour-symmetric chessboards
/// whose images number the corners from either end, one wide lens in a housing, six housings
/// with thin air layers, one wide lens behind a window) calibrate with
/// default options: a rig is written, every estimate within 3σ of the truth and within issue 38's
/// bounds. Before the images' corner orders were made to agree across the cameras
/// (calib::pipeline::turns) seed 60 was refused at 85 px, and seed 13 written with two images
/// left out, its centres 1.1 mm off; before views the start port carries outside the lens were
/// placed again (estimate.rs, `with_defined_poses`) seed 41 was refused: "no start explains
/// every corner". Seed 70 (six housings 0.87 m apart, two with 2.5 and 5 mm of air) was written
/// 3° and 84 mm off before each housing's port was refined from its search's best cells
/// (search.rs); seed 75 (a wide lens, k1 = −0.26, behind a window) was refused, "no axis within
/// a tilt of 30° explains the corners", before the search's cells placed views their port
/// cannot project again.
#[test]
fn seeded_subset() {
    let subset = [1u64, 2, 5, 8, 12, 13, 41, 60, 70, 75];
    let mut rows = Vec::new();
    for seed in subset {
        let zoo = zoo_rig(seed).unwrap();
        let row = run(&zoo, 0.0, false, &out_dir(&format!("seed_{seed}")));
        eprintln!("{}", row.markdown());
        rows.push(row);
    }
    let t = table(&rows);
    eprintln!("{t}");
    for row in &rows {
        assert!(row.refused.is_none(), "{t}");
        // Every estimate within 3σ of the truth (the extrinsics' σ carries the in-air lenses'
        // uncertainty: report::add_lens_uncertainty) and within issue 38's bounds.
        assert!(row.within_3_sigma(), "{t}");
        assert!(row.within_bounds(), "{t}");
    }
}

/// The sweep over `FP_ZOO_SEEDS` (default 1-20) at imaging severity `FP_ZOO_IMAGING` (default 0),
/// its table in target/tmp/zoo/table.md.
#[test]
#[ignore = "minutes per rig: the sweep behind docs/performance.md"]
fn sweep() {
    let spec = std::env::var("FP_ZOO_SEEDS").unwrap_or_else(|_| "1-20".into());
    let imaging: f64 = std::env::var("FP_ZOO_IMAGING")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0.0);
    let water_only = std::env::var("FP_ZOO_WATER_ONLY").is_ok_and(|v| v == "1");
    let mut rows = Vec::new();
    for seed in seeds(&spec) {
        let zoo = zoo_rig(seed).unwrap();
        let row = run(
            &zoo,
            imaging,
            water_only,
            &out_dir(&format!("sweep_{seed}")),
        );
        eprintln!("{}", row.markdown());
        rows.push(row);
    }
    let t = table(&rows);
    let path = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("zoo")
        .join("table.md");
    std::fs::write(&path, &t).unwrap();
    eprintln!("{t}\nwritten to {}", path.display());
}
