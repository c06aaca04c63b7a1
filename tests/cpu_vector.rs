//! The CPU engine's vector path against the scalar model it twins (back-projection, forward
//! projection, VOPs, triangulation): every row must get the same
//! status and, where there is an answer, the same numbers within 1e-12 relative (the issue's
//! bound; the lanes compute the scalar expressions in the same order, so most rows agree bit for
//! bit and the test reports how many do not).
//!
//! Inputs: the oracle configurations (single interface, one to three layers, a tank, an immersed
//! camera, each with and without distortion, both cameras), and proptest's random rigs; pixels
//! over and far beyond the image; points at every depth, inside the air and the glass, behind the
//! camera, on the camera's axis line, far to the side and out to 1e299 m; NaN and ±∞; batch
//! lengths that are not multiples of the lane count.

mod oracle_common;

use flatport::engine::{CpuEngine, CpuPath};
use flatport::model::{NoSolution, RefractiveCamera};
use nalgebra::{Point2, Point3};
use oracle_common::random_rig::{build, rig_spec};
use oracle_common::{Fixture, Rng, all_fixtures};
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

/// The bound: the vector path within 1e-12 relative of the scalar model.
const RELATIVE: f64 = 1e-12;

fn engines() -> [(CpuEngine, CpuEngine); 2] {
    [
        (
            CpuEngine::with_path(Some(1), CpuPath::Scalar),
            CpuEngine::with_path(Some(1), CpuPath::Vector),
        ),
        (
            CpuEngine::with_path(Some(2), CpuPath::Scalar),
            CpuEngine::with_path(Some(2), CpuPath::Vector),
        ),
    ]
}

/// Rows that differ between the two paths, as messages; and the number of rows not bit for bit equal.
fn compare<const M: usize>(
    what: &str,
    input: &[impl std::fmt::Debug],
    scalar: (&[[f64; M]], &[u32]),
    vector: (&[[f64; M]], &[u32]),
) -> (Vec<String>, usize) {
    let mut wrong = Vec::new();
    let mut inexact = 0;
    for (i, row) in input.iter().enumerate() {
        let (a, b) = ((scalar.0[i], scalar.1[i]), (vector.0[i], vector.1[i]));
        if a.1 != b.1 {
            wrong.push(format!(
                "{what} row {i} {row:?}: status {} (scalar) vs {} (vector)",
                a.1, b.1
            ));
            continue;
        }
        if a.1 != 0 {
            if !b.0.iter().all(|x| x.is_nan()) {
                wrong.push(format!(
                    "{what} row {i} {row:?}: status {} with numbers {:?}",
                    b.1, b.0
                ));
            }
            continue;
        }
        if a.0
            .iter()
            .zip(&b.0)
            .any(|(x, y)| x.to_bits() != y.to_bits())
        {
            inexact += 1;
        }
        for (x, y) in a.0.iter().zip(&b.0) {
            // Written so that a NaN on either side fails.
            if (x - y).abs().partial_cmp(&(RELATIVE * x.abs().max(1.0)))
                != Some(std::cmp::Ordering::Less)
                && x != y
            {
                wrong.push(format!(
                    "{what} row {i} {row:?}: {:?} (scalar) vs {:?} (vector)",
                    a.0, b.0
                ));
                break;
            }
        }
    }
    (wrong, inexact)
}

/// Pixels over the image and far beyond it, with special values.
fn pixels_for(camera: &RefractiveCamera, rng: &mut Rng, random: usize) -> Vec<[f64; 2]> {
    let (w, h) = (
        camera.intrinsics().width as f64,
        camera.intrinsics().height as f64,
    );
    let mut pixels = Vec::new();
    for i in 0..=40 {
        for j in 0..=32 {
            pixels.push([
                -0.6 * w + 2.2 * w * i as f64 / 40.0,
                -0.6 * h + 2.2 * h * j as f64 / 32.0,
            ]);
        }
    }
    for _ in 0..random {
        pixels.push([rng.uniform(-w, 2.0 * w), rng.uniform(-h, 2.0 * h)]);
    }
    pixels.extend([
        [f64::NAN, 10.0],
        [10.0, f64::NAN],
        [f64::INFINITY, 0.0],
        [0.0, f64::NEG_INFINITY],
        [1e301, 5.0],
        [640.0, 1e300],
        [1e6, 1e6],
        [-1e12, 3e11],
        [camera.intrinsics().cx, camera.intrinsics().cy],
    ]);
    pixels
}

/// Points: along back-projected rays at depths from 0.1 mm to 50 m, inside the air and the
/// layers, behind the camera, on the camera's axis line, far to the side and far away, specials.
fn points_for(camera: &RefractiveCamera, pixels: &[[f64; 2]], rng: &mut Rng) -> Vec<[f64; 3]> {
    let mut points = Vec::new();
    let c = camera.centre();
    let n = camera.normal().into_inner();
    for p in pixels {
        if let Ok(ray) = camera.backproject(&Point2::new(p[0], p[1])) {
            let s = 10f64.powf(rng.uniform(-4.0, 1.7));
            points.push(ray.point_at(s).coords.into());
            // Before the outer interface: in the glass or the air.
            points.push(ray.point_at(-rng.uniform(0.0, 0.05)).coords.into());
        }
    }
    for k in 0..40 {
        let s = 0.01 * 1.6f64.powi(k);
        points.push((c + n * s).coords.into());
        points.push((c - n * s).coords.into());
        points.push([c.x + s * 30.0, c.y - s, c.z + s * 0.2]);
    }
    for e in [10, 20, 50, 100, 154, 155, 200, 299] {
        let s = 10f64.powi(e);
        points.push([0.1 * s, 0.05 * s, s]);
        points.push([100.0 * s, 0.0, s]);
        points.push([0.0, 0.0, s]);
    }
    points.extend([
        [f64::NAN, 0.0, 1.0],
        [0.0, 0.0, f64::INFINITY],
        [2e300, 0.0, 1.0],
        [0.0, 0.0, -1.0],
        [1e-300, 0.0, 2.0],
    ]);
    points
}

/// Matches between the two cameras of `fixture`: projections of water points, with noise.
fn matches_for(fixture: &Fixture, points: &[[f64; 3]], rng: &mut Rng) -> Vec<[f64; 4]> {
    let (a, b) = (fixture.camera(0), fixture.camera(1));
    let mut matches: Vec<[f64; 4]> = points
        .iter()
        .filter_map(|p| {
            let p = Point3::from(*p);
            let (pa, pb) = (a.project(&p).ok()?, b.project(&p).ok()?);
            Some([
                pa.x + rng.uniform(-0.3, 0.3),
                pa.y,
                pb.x,
                pb.y + rng.uniform(-0.3, 0.3),
            ])
        })
        .collect();
    // Each pixel with a random partner (no common point: rays that diverge or miss), and specials.
    for i in 0..matches.len().min(200) {
        let j = (i * 7 + 3) % matches.len();
        matches.push([matches[i][0], matches[i][1], matches[j][2], matches[j][3]]);
    }
    matches.extend([
        [640.0, 512.0, 640.0, 512.0],
        [f64::NAN, 1.0, 2.0, 3.0],
        [1.0, 2.0, 3.0, 1e301],
        [1e6, 0.0, 600.0, 500.0],
        [500.0, 400.0, -1e7, 0.0],
    ]);
    matches
}

/// Runs back-projection, projection and triangulation on both paths for the cameras of
/// `fixture`; returns the differences and counts of rows compared and rows not bit-identical.
fn check_fixture(fixture: &Fixture, seed: u64, random: usize) -> (Vec<String>, usize, usize) {
    let mut rng = Rng::new(seed);
    let (mut wrong, mut rows, mut inexact) = (Vec::new(), 0, 0);
    let mut record = |(w, i): (Vec<String>, usize), n: usize| {
        wrong.extend(w);
        inexact += i;
        rows += n;
    };
    let cameras = [fixture.camera(0), fixture.camera(1)];
    for (scalar, vector) in engines() {
        for (k, camera) in cameras.iter().enumerate() {
            let pixels = pixels_for(camera, &mut rng, random);
            let n = pixels.len();
            let (mut r0, mut s0, mut r1, mut s1) =
                (vec![[0.0; 6]; n], vec![0; n], vec![[0.0; 6]; n], vec![0; n]);
            scalar.backproject(camera, &pixels, &mut r0, &mut s0);
            vector.backproject(camera, &pixels, &mut r1, &mut s1);
            record(
                compare(
                    &format!("{} camera {k} backproject", fixture.name),
                    &pixels,
                    (&r0, &s0),
                    (&r1, &s1),
                ),
                n,
            );

            let points = points_for(camera, &pixels, &mut rng);
            let n = points.len();
            let (mut p0, mut s0, mut p1, mut s1) =
                (vec![[0.0; 2]; n], vec![0; n], vec![[0.0; 2]; n], vec![0; n]);
            scalar.project(camera, &points, &mut p0, &mut s0);
            vector.project(camera, &points, &mut p1, &mut s1);
            record(
                compare(
                    &format!("{} camera {k} project", fixture.name),
                    &points,
                    (&p0, &s0),
                    (&p1, &s1),
                ),
                n,
            );

            let (mut v0, mut s0, mut v1, mut s1) =
                (vec![[0.0; 6]; n], vec![0; n], vec![[0.0; 6]; n], vec![0; n]);
            scalar.vop(camera, &points, &mut v0, &mut s0);
            vector.vop(camera, &points, &mut v1, &mut s1);
            record(
                compare(
                    &format!("{} camera {k} vop", fixture.name),
                    &points,
                    (&v0, &s0),
                    (&v1, &s1),
                ),
                n,
            );

            if k == 0 {
                let matches = matches_for(fixture, &points, &mut rng);
                let n = matches.len();
                let (mut t0, mut s0, mut t1, mut s1) =
                    (vec![[0.0; 4]; n], vec![0; n], vec![[0.0; 4]; n], vec![0; n]);
                scalar.triangulate(&cameras[0], &cameras[1], &matches, &mut t0, &mut s0);
                vector.triangulate(&cameras[0], &cameras[1], &matches, &mut t1, &mut s1);
                record(
                    compare(
                        &format!("{} triangulate", fixture.name),
                        &matches,
                        (&t0, &s0),
                        (&t1, &s1),
                    ),
                    n,
                );
            }
        }
    }
    (wrong, rows, inexact)
}

#[test]
fn vector_path_equals_the_scalar_model_on_every_oracle_configuration() {
    let (mut wrong, mut rows, mut inexact) = (Vec::new(), 0, 0);
    let mut statuses = std::collections::BTreeSet::new();
    for (i, fixture) in all_fixtures().iter().enumerate() {
        let (w, n, x) = check_fixture(fixture, 1000 + i as u64, 2001);
        wrong.extend(w);
        rows += n;
        inexact += x;
        // Which reasons the inputs reached, so that the test shows it covers them.
        let camera = fixture.camera(0);
        let mut rng = Rng::new(7);
        let pixels = pixels_for(&camera, &mut rng, 0);
        let points = points_for(&camera, &pixels, &mut rng);
        for p in &points {
            statuses.insert(
                camera
                    .project(&Point3::from(*p))
                    .err()
                    .map_or(0, NoSolution::code),
            );
        }
        for p in &pixels {
            statuses.insert(
                camera
                    .backproject(&Point2::new(p[0], p[1]))
                    .err()
                    .map_or(0, NoSolution::code),
            );
        }
    }
    eprintln!(
        "{rows} rows compared, {inexact} not bit for bit equal; statuses reached: {statuses:?}"
    );
    assert!(
        wrong.is_empty(),
        "{} of {rows} rows differ, e.g.:\n{}",
        wrong.len(),
        wrong
            .iter()
            .take(20)
            .cloned()
            .collect::<Vec<_>>()
            .join("\n")
    );
    // Stronger than the bound, and what the lanes are written for: the same IEEE operations in the
    // same order round the same way, so every answer is bit for bit the scalar one. (Should a
    // faster formulation ever reorder them, this line goes and the 1e-12 bound above stays.)
    assert_eq!(inexact, 0, "rows not bit for bit equal to the scalar model");
    // The inputs must reach every reason a single camera can give (6 and 7 are stereo/rare).
    for code in [0, 1, 2, 3, 4, 5, 8] {
        assert!(
            statuses.contains(&code),
            "no input reached status {code}: {statuses:?}"
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn vector_path_equals_the_scalar_model_on_random_rigs(spec in rig_spec(), seed in any::<u64>()) {
        let (wrong, rows, _) = check_fixture(&build(&spec), seed, 97);
        if !wrong.is_empty() {
            return Err(TestCaseError::fail(format!("{} of {rows} rows differ, e.g.:\n{}", wrong.len(), wrong.iter().take(10).cloned().collect::<Vec<_>>().join("\n"))));
        }
    }
}

/// The equality above is not bought by handing rows back to the scalar model: on ordinary
/// batches (the bench workload: pixels over the image, points 0.2–5 m into the water, matches)
/// the lanes answer every row themselves.
#[test]
fn the_lanes_answer_ordinary_rows_themselves() {
    use flatport::engine::{cpu::lanes, workload::Workload};
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/example_rig.json"
    ))
    .unwrap();
    let rig =
        flatport::io::rig_from_json_str(&text, std::path::Path::new("example_rig.json")).unwrap();
    let n = 20_000;
    let work = Workload::new(&rig, n);
    let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
    let mut status = vec![0; n];
    assert_eq!(
        lanes::backproject(&a, &work.pixels, &mut vec![[0.0; 6]; n], &mut status),
        0
    );
    assert_eq!(
        lanes::project(&a, &work.points, &mut vec![[0.0; 2]; n], &mut status),
        0
    );
    assert_eq!(
        lanes::triangulate(&a, &b, &work.matches, &mut vec![[0.0; 4]; n], &mut status),
        0
    );
    assert_eq!(
        lanes::vop(&a, &work.points, &mut vec![[0.0; 6]; n], &mut status),
        0
    );
}

#[test]
fn empty_and_short_batches() {
    let fixture = all_fixtures().remove(2);
    let camera = fixture.camera(0);
    let vector = CpuEngine::with_path(Some(1), CpuPath::Vector);
    vector.backproject(&camera, &[], &mut [], &mut []);
    for n in 1..=17 {
        let pixels: Vec<[f64; 2]> = (0..n)
            .map(|i| [100.0 + 50.0 * i as f64, 200.0 + 30.0 * i as f64])
            .collect();
        let (mut rays, mut status) = (vec![[0.0; 6]; n], vec![9; n]);
        vector.backproject(&camera, &pixels, &mut rays, &mut status);
        for (i, p) in pixels.iter().enumerate() {
            let ray = camera.backproject(&Point2::new(p[0], p[1])).unwrap();
            assert_eq!(status[i], 0);
            assert!(
                (ray.origin.x - rays[i][0]).abs() < 1e-15 && (ray.dir.z - rays[i][5]).abs() < 1e-15,
                "n = {n}, row {i}"
            );
        }
    }
}

/// [`CameraLanes::project_near`](flatport::engine::cpu::lanes::refractive_camera::CameraLanes::project_near)
/// (the reprojection's unsafeguarded Newton iteration from the tan a of a nearby observed ray)
/// against the scalar model's safeguarded projection: a lane it settles has the scalar pixel
/// within 1e-12 relative (times the pixel's condition |x/z| beyond the image), and where no medium is less dense than the air it settles every
/// ordinary point (along a pixel's ray, 0.1 mm to 50 m into the water, started from the ray of
/// the pixel 3 px away, or from tan a = 0); where a medium is less dense than the air it settles
/// none (its iteration needs concave terms).
#[test]
fn project_near_settles_on_the_scalar_pixel() {
    use flatport::engine::cpu::lanes::refractive_camera::CameraLanes;
    use flatport::engine::cpu::lanes::{F64s, LANES, Vec3s};
    let (mut settled, mut ordinary, mut wrong) = (0, 0, Vec::new());
    for (f, fixture) in all_fixtures().iter().enumerate() {
        let air = fixture.stack.index_air();
        let dense = fixture.stack.indices.iter().all(|&i| i >= air);
        for k in 0..fixture.cams.len() {
            let camera = fixture.camera(k);
            let lanes = CameraLanes::new(&camera);
            let mut rng = Rng::new(40 + f as u64);
            let pixels = pixels_for(&camera, &mut rng, 200);
            // (point, tan a to start from, ordinary)
            let mut cases: Vec<([f64; 3], f64, bool)> = Vec::new();
            for p in &pixels {
                let Ok(ray) = camera.backproject(&Point2::new(p[0], p[1])) else {
                    continue;
                };
                let depth = 10f64.powf(rng.uniform(-4.0, 1.7));
                let point: [f64; 3] = ray.point_at(depth).coords.into();
                let nearby = Point2::new(p[0] + 3.0, p[1] - 1.0);
                let start = camera.dir_in_air_from_img(&nearby).map_or(0.0, |d| {
                    let cos = camera.normal().dot(&d);
                    (1.0 - cos * cos).max(0.0).sqrt() / cos
                });
                cases.push((point, start, start.is_finite() && start > 0.0));
                cases.push((point, 0.0, true));
            }
            for p in points_for(&camera, &pixels, &mut rng) {
                cases.push((p, rng.uniform(0.0, 2.0), false));
            }
            for block in cases.chunks(LANES) {
                let at = |l: usize| block[l.min(block.len() - 1)];
                let coordinate = |c: usize| F64s(std::array::from_fn(|l| at(l).0[c]));
                let point = Vec3s {
                    x: coordinate(0),
                    y: coordinate(1),
                    z: coordinate(2),
                };
                let (pixels, done) =
                    lanes.project_near(point, F64s(std::array::from_fn(|l| at(l).1)));
                for (l, &(p, start, is_ordinary)) in block.iter().enumerate() {
                    let scalar = camera.project(&Point3::from(p));
                    if is_ordinary && scalar.is_ok() {
                        ordinary += 1;
                    }
                    if !done.0[l] {
                        if dense && is_ordinary && scalar.is_ok() {
                            wrong.push(format!(
                                "{}: ordinary {p:?} from {start} not settled",
                                fixture.name
                            ));
                        }
                        continue;
                    }
                    settled += 1;
                    let near = [pixels.u.0[l], pixels.v.0[l]];
                    // Far beyond the image a pixel is ill-conditioned in its ray (u = f·x/z,
                    // z → 0): the ray's rounding grows in the pixel by |x/z|, and there the two
                    // ways of writing the same ray (rounding apart) are held to the bound times it.
                    let intrinsics = camera.intrinsics();
                    let close = scalar.is_ok_and(|s| {
                        let condition = ((s.x - intrinsics.cx) / intrinsics.fx)
                            .abs()
                            .max(((s.y - intrinsics.cy) / intrinsics.fy).abs())
                            .max(1.0);
                        [s.x, s.y]
                            .iter()
                            .zip(near)
                            .all(|(x, y)| (x - y).abs() <= RELATIVE * condition * x.abs().max(1.0))
                    });
                    if !dense || !close {
                        wrong.push(format!(
                            "{}: {p:?} from {start}: {near:?} settled, the scalar model {scalar:?}",
                            fixture.name
                        ));
                    }
                }
            }
        }
    }
    eprintln!("{settled} lanes settled, {ordinary} ordinary points");
    assert!(ordinary > 10_000, "only {ordinary} ordinary points");
    assert!(
        wrong.is_empty(),
        "{} wrong, e.g.:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(20)].join("\n")
    );
}

/// `lanes::project_near_all` (dense stereo's projection: near air rays, the safeguarded lanes
/// where it does not settle) answers every row as `lanes::project` does, whatever the start: the
/// same status, and the same pixel within 1e-12 relative (times the pixel's condition beyond the
/// image) — on every oracle configuration, hostile points included (behind the port, on the
/// axis, 1e300 m away, NaN), from the ray of a pixel 3 px away, from 0, from a random tan a, from
/// a huge one and from NaN, in batches that are not a whole number of blocks.
#[test]
fn project_near_all_answers_every_row_as_project() {
    use flatport::engine::cpu::lanes;
    let mut wrong = Vec::new();
    let mut rows = 0;
    for (f, fixture) in all_fixtures().iter().enumerate() {
        for k in 0..fixture.cams.len() {
            let camera = fixture.camera(k);
            let mut rng = Rng::new(70 + f as u64);
            let pixels = pixels_for(&camera, &mut rng, 150);
            let points = points_for(&camera, &pixels, &mut rng);
            let n = points.len() - 3;
            let points = &points[..n];
            let starts: Vec<f64> = (0..n)
                .map(|i| match i % 5 {
                    0 => 0.0,
                    1 => rng.uniform(0.0, 2.0),
                    2 => 1e6,
                    3 => f64::NAN,
                    _ => {
                        let p = pixels[i % pixels.len()];
                        camera
                            .dir_in_air_from_img(&Point2::new(p[0] + 3.0, p[1] - 1.0))
                            .map_or(0.0, |d| {
                                let cos = camera.normal().dot(&d);
                                (1.0 - cos * cos).max(0.0).sqrt() / cos
                            })
                    }
                })
                .collect();
            let (mut near, mut near_status) = (vec![[0.0; 2]; n], vec![0u32; n]);
            let (mut full, mut full_status) = (vec![[0.0; 2]; n], vec![0u32; n]);
            lanes::project_near_all(&camera, points, &starts, &mut near, &mut near_status);
            lanes::project(&camera, points, &mut full, &mut full_status);
            let intrinsics = camera.intrinsics();
            for i in 0..n {
                rows += 1;
                let (a, b) = (near[i], full[i]);
                let condition = ((b[0] - intrinsics.cx) / intrinsics.fx)
                    .abs()
                    .max(((b[1] - intrinsics.cy) / intrinsics.fy).abs())
                    .max(1.0);
                let close = (0..2).all(|c| {
                    (a[c].is_nan() && b[c].is_nan())
                        || (a[c] - b[c]).abs() <= RELATIVE * condition * b[c].abs().max(1.0)
                });
                if near_status[i] != full_status[i] || !close {
                    wrong.push(format!(
                        "{} camera {k}: {:?} from {}: {a:?} status {}, project {b:?} status {}",
                        fixture.name, points[i], starts[i], near_status[i], full_status[i]
                    ));
                }
            }
        }
    }
    assert!(rows > 1000, "{rows} rows");
    assert!(
        wrong.is_empty(),
        "{} of {rows}:\n{}",
        wrong.len(),
        wrong[..wrong.len().min(10)].join("\n")
    );
}
