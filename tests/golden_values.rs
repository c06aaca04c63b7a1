//! Golden values from 50-digit arithmetic (scripts/golden.py, mpmath): forward projection,
//! back-projection and traced VOP distances for five fixed rigs (tests/golden/rigs.json: single
//! interface; glass with distortion; three layers with distortion; a tank air → glass → water →
//! glass → air; an immersed camera looking into air, with total internal reflection). Both the
//! model and the f64 oracles of tests/oracle_common are held to them.

mod oracle_common;

use std::collections::BTreeMap;
use std::path::Path as FsPath;

use flatport::model::vop::{real_from_virtual, virtual_from_real};
use flatport::model::{NoSolution, RefractiveCamera};
use nalgebra::{Matrix3, Point2, Point3, Vector3};
use oracle_common::*;
use serde_json::Value;

/// Issue "Done when": forward projection to 1e-6 px. The golden pixels carry 20 significant digits.
const PIXEL_TOL: f64 = 1e-6;
/// Issue "Done when": back-projection to 1e-9 (unit direction; origin in metres).
const RAY_TOL: f64 = 1e-9;
/// Issue "Done when": VOP relations to 1e-9 m.
const VOP_TOL: f64 = 1e-9;
/// Where the water ray grazes the interface (cos θw below this) eq 4.8 is ill-conditioned in the
/// angle (condition number ~1/cos²θw); those rows are checked in `golden_vop_where_the_water_ray_grazes`.
const GRAZING_COS: f64 = 0.01;

fn golden_dir() -> std::path::PathBuf {
    FsPath::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("golden")
}

fn number(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn vector3(v: &Value) -> Vector3<f64> {
    Vector3::new(number(&v[0]), number(&v[1]), number(&v[2]))
}

/// The golden rigs as oracle fixtures (which build the model's `Rig` from the same numbers).
fn rigs() -> BTreeMap<String, Fixture> {
    let text =
        std::fs::read_to_string(golden_dir().join("rigs.json")).expect("tests/golden/rigs.json");
    let json: Value = serde_json::from_str(&text).expect("valid JSON");
    let mut rigs = BTreeMap::new();
    for (name, rig) in json.as_object().unwrap() {
        let interface = &rig["interface"];
        let layers = interface["layers"].as_array().unwrap();
        let normal = vector3(&interface["normal"]);
        let stack = Stack {
            normal: normal / normal.norm(),
            air_distance: number(&interface["distance"]),
            thicknesses: layers.iter().map(|l| number(&l["thickness"])).collect(),
            indices: std::iter::once(number(&interface["index_air"]))
                .chain(layers.iter().map(|l| number(&l["index"])))
                .chain(std::iter::once(number(&interface["index_water"])))
                .collect(),
        };
        let cams = rig["cameras"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| {
                let rotation = match c.get("rotation") {
                    Some(r) => Matrix3::from_fn(|i, j| number(&r[i][j])),
                    None => Matrix3::identity(),
                };
                let translation = c.get("translation").map_or(Vector3::zeros(), vector3);
                let d = c["distortion"].as_array().unwrap();
                CamParams {
                    rotation,
                    centre: Point3::from(-(rotation.transpose() * translation)),
                    width: c["width"].as_u64().unwrap() as u32,
                    height: c["height"].as_u64().unwrap() as u32,
                    fx: number(&c["fx"]),
                    fy: number(&c["fy"]),
                    cx: number(&c["cx"]),
                    cy: number(&c["cy"]),
                    distortion: [
                        number(&d[0]),
                        number(&d[1]),
                        number(&d[2]),
                        number(&d[3]),
                        number(&d[4]),
                    ],
                }
            })
            .collect();
        rigs.insert(name.clone(), Fixture::build(name, stack, cams));
    }
    rigs
}

/// Rows of a golden CSV as column → text maps (comment lines start with '#').
fn csv(name: &str) -> Vec<BTreeMap<String, String>> {
    let text =
        std::fs::read_to_string(golden_dir().join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows: Vec<_> = lines
        .map(|line| {
            let cells: Vec<&str> = line.split(',').collect();
            assert_eq!(cells.len(), header.len(), "{name}: {line}");
            header
                .iter()
                .cloned()
                .zip(cells.iter().map(|c| c.to_string()))
                .collect()
        })
        .collect();
    assert!(!rows.is_empty(), "{name} is empty");
    rows
}

fn f(row: &BTreeMap<String, String>, column: &str) -> f64 {
    row[column]
        .parse()
        .unwrap_or_else(|_| panic!("{column} = {:?}", row[column]))
}

fn status_of(error: NoSolution) -> &'static str {
    match error {
        NoSolution::NotInWater => "not_in_water",
        NoSolution::BehindCamera => "behind_camera",
        NoSolution::OutsideLens => "outside_lens",
        NoSolution::TotalInternalReflection => "tir",
        NoSolution::MissesInterface => "misses",
        _ => "other",
    }
}

fn oracle_status(error: Fail) -> &'static str {
    match error {
        Fail::NotInWater => "not_in_water",
        Fail::BehindCamera => "behind_camera",
        Fail::OutsideLens => "outside_lens",
        Fail::Tir => "tir",
        Fail::Misses => "misses",
    }
}

#[test]
fn golden_projection() {
    let rigs = rigs();
    let rows = csv("project.csv");
    let mut worst: BTreeMap<String, (f64, f64, f64, f64)> = BTreeMap::new();
    let mut statuses = BTreeMap::new();
    for row in &rows {
        let fixture = &rigs[&row["rig"]];
        let k: usize = row["camera"].parse().unwrap();
        let camera: RefractiveCamera = fixture.camera(k);
        let point = Point3::new(f(row, "x"), f(row, "y"), f(row, "z"));
        let status = row["status"].as_str();
        *statuses.entry(status.to_string()).or_insert(0) += 1;
        let what = format!("{} cam {k} {point:?}", row["rig"]);
        let model = camera.project(&point);
        let oracle = fixture.project(k, &point);
        let entry = worst.entry(row["rig"].clone()).or_default();
        if status == "ok" {
            let golden = Point2::new(f(row, "u"), f(row, "v"));
            let model = model.unwrap_or_else(|e| panic!("{what}: model {e:?}, golden {golden:?}"));
            let oracle = oracle.unwrap_or_else(|e| panic!("{what}: oracle {e:?}"));
            // Pixels far outside the image (steep rays at 0.1 mm depth, up to ~1e4 px) are compared
            // relative to 1e4 px: there one ulp of the pixel is already ~2e-12 px.
            let scale =
                1.0 + (golden - Point2::new(fixture.cams[k].cx, fixture.cams[k].cy)).norm() / 1e4;
            let (model_error, oracle_error) = (
                (model - golden).norm() / scale,
                (oracle - golden).norm() / scale,
            );
            entry.0 = entry.0.max(model_error);
            entry.1 = entry.1.max(oracle_error);
            assert!(
                model_error <= PIXEL_TOL,
                "{what}: model {model:?} vs golden {golden:?}"
            );
            assert!(
                oracle_error <= PIXEL_TOL,
                "{what}: oracle {oracle:?} vs golden {golden:?}"
            );
        } else {
            assert_eq!(model.map_err(status_of), Err(status), "{what}: model");
            assert_eq!(oracle.map_err(oracle_status), Err(status), "{what}: oracle");
        }
        // Depth, angle of incidence and the traced VOP wherever the point is in the water.
        if row["depth"] != "nan" {
            let path = camera.air_path_to(&point).expect("point in the water");
            assert!(
                (path.depth - f(row, "depth")).abs() <= 1e-12,
                "{what}: depth {}",
                path.depth
            );
            let incidence = path.tan_incidence.atan();
            assert!(
                (incidence - f(row, "incidence")).abs() <= 1e-12,
                "{what}: incidence {incidence}"
            );
            // The f64 oracle's traced VOP holds everywhere, grazing rows included.
            if let Some((traced, _)) = fixture.traced_vop(k, &point) {
                let error = (traced - f(row, "vop_distance")).abs();
                entry.3 = entry.3.max(error);
                assert!(
                    error <= VOP_TOL,
                    "{what}: oracle's traced VOP {traced} vs golden {}",
                    row["vop_distance"]
                );
            }
            if row["vop_distance"] != "nan" && f(row, "cos_water") >= GRAZING_COS {
                let vop = camera.vop(&point).unwrap().vop_distance;
                let error = (vop - f(row, "vop_distance")).abs();
                entry.2 = entry.2.max(error);
                assert!(
                    error <= VOP_TOL,
                    "{what}: vop() {vop} vs traced {}",
                    row["vop_distance"]
                );
            }
        }
    }
    println!("golden forward projection (max |Δpixel| model, oracle; max |Δx̌| of vop(), oracle):");
    for (rig, (model, oracle, vop, traced)) in &worst {
        println!("  {rig:16} {model:.1e} px, {oracle:.1e} px; {vop:.1e} m, {traced:.1e} m");
    }
    println!("  statuses {statuses:?}");
    for status in ["ok", "not_in_water", "behind_camera", "outside_lens"] {
        assert!(
            statuses.get(status).copied().unwrap_or(0) > 0,
            "no golden row with status {status}"
        );
    }
}

#[test]
fn golden_backprojection() {
    let rigs = rigs();
    let rows = csv("backproject.csv");
    let mut worst: BTreeMap<String, (f64, f64)> = BTreeMap::new();
    let mut tir = 0;
    for row in &rows {
        let fixture = &rigs[&row["rig"]];
        let k: usize = row["camera"].parse().unwrap();
        let camera = fixture.camera(k);
        let pixel = Point2::new(f(row, "u"), f(row, "v"));
        let what = format!("{} cam {k} {pixel:?}", row["rig"]);
        let status = row["status"].as_str();
        for ray in [
            camera.backproject(&pixel),
            camera.backproject_traced(&pixel),
        ] {
            if status == "ok" {
                let ray = ray.unwrap_or_else(|e| panic!("{what}: {e:?}"));
                let origin = Point3::new(f(row, "ox"), f(row, "oy"), f(row, "oz"));
                let dir = Vector3::new(f(row, "dx"), f(row, "dy"), f(row, "dz"));
                let (dir_error, origin_error) = (
                    (ray.dir.into_inner() - dir).norm(),
                    (ray.origin - origin).norm(),
                );
                let entry = worst.entry(row["rig"].clone()).or_default();
                entry.0 = entry.0.max(dir_error);
                entry.1 = entry.1.max(origin_error);
                assert!(
                    dir_error <= RAY_TOL,
                    "{what}: direction off by {dir_error:e}"
                );
                assert!(
                    origin_error <= RAY_TOL,
                    "{what}: origin off by {origin_error:e} m"
                );
            } else {
                assert_eq!(
                    ray.map_err(status_of).map(|r| r.origin),
                    Err(status),
                    "{what}"
                );
            }
        }
        if status == "tir" {
            tir += 1;
        }
    }
    println!("golden back-projection (max |Δdir|, max |Δorigin| m):");
    for (rig, (d, o)) in &worst {
        println!("  {rig:16} {d:.1e}, {o:.1e}");
    }
    assert!(tir > 0, "the golden rows include total internal reflection");
}

#[test]
fn golden_vop_relations() {
    let rigs = rigs();
    let rows = csv("vop.csv");
    let mut worst: BTreeMap<String, f64> = BTreeMap::new();
    let (mut negative, mut tir) = (0, 0);
    for row in &rows {
        let stack = &rigs[&row["rig"]].stack;
        let (depth, incidence) = (f(row, "depth"), f(row, "incidence"));
        let layers = stack.layers();
        let (mu_a, mu_w) = (stack.index_air(), stack.index_water());
        let formula = virtual_from_real(depth, incidence, &layers, mu_a, mu_w);
        let what = format!("{} x = {depth}, a = {incidence}", row["rig"]);
        if row["status"] == "tir" {
            assert_eq!(formula, None, "{what}");
            tir += 1;
            continue;
        }
        let golden = f(row, "vop_distance");
        let formula = formula.unwrap_or_else(|| panic!("{what}: eq 4.8 gave TIR"));
        let back = real_from_virtual(golden, incidence, &layers, mu_a, mu_w).unwrap();
        assert!(
            (back - depth).abs() <= VOP_TOL,
            "{what}: eq 4.7 gives {back}"
        );
        if f(row, "cos_water") < GRAZING_COS {
            continue;
        }
        let error = (formula - golden).abs();
        let entry = worst.entry(row["rig"].clone()).or_default();
        *entry = entry.max(error);
        assert!(
            error <= VOP_TOL,
            "{what}: eq 4.8 {formula} vs traced {golden}"
        );
        if golden < 0.0 {
            negative += 1;
        }
    }
    println!("golden VOP relation (max |x̌(eq 4.8) − x̌(traced, 50 digits)| m):");
    for (rig, e) in &worst {
        println!("  {rig:16} {e:.1e}");
    }
    assert!(
        negative > 0 && tir > 0,
        "rows with x̌ < 0 ({negative}) and TIR ({tir}) must be present"
    );
}

/// `vop()` against the 50-digit traced VOP where the water ray grazes the interface (immersed rig,
/// points 0.1 mm behind the port near the critical angle). See oracle_projection's test of the
/// same name: the model evaluates eq 4.8 there, whose condition number in the angle is ~1/cos²θw.
#[test]
fn golden_vop_where_the_water_ray_grazes() {
    let rigs = rigs();
    let mut worst: f64 = 0.0;
    let mut checked = 0;
    for row in csv("project.csv") {
        if row["vop_distance"] == "nan" || f(&row, "cos_water") >= GRAZING_COS {
            continue;
        }
        let k: usize = row["camera"].parse().unwrap();
        let point = Point3::new(f(&row, "x"), f(&row, "y"), f(&row, "z"));
        let vop = rigs[&row["rig"]]
            .camera(k)
            .vop(&point)
            .unwrap()
            .vop_distance;
        worst = worst.max((vop - f(&row, "vop_distance")).abs());
        checked += 1;
    }
    println!(
        "vop() where the water ray grazes: max |Δx̌| = {worst:.1e} m over {checked} golden rows"
    );
    assert!(checked > 0);
    assert!(worst <= VOP_TOL, "{worst:e} m");
}
