//! Rows that live on the device (`DeviceRows`, `src/engine/gpu/device.rs`) on lavapipe, f32 and
//! f64: the chain matched pixels → back-projection → triangulation with the rays never on the
//! host, against the f64 CPU reference (DESIGN.md §5: f32 rays within 2e-6, pixels within
//! 1e-3 px, f64 within 1e-9 relative; the f32 triangulation bound of `tests/gpu.rs` derived from
//! the ray bound) and against the host-row call; the same chain fused in one kernel
//! (`triangulate_pixels`) against the CPU on rigs with a shared port and a port per camera (its
//! points within the bounds that §5's 2e-6 (f32) and 1e-12 (f64) on the rays give them) and
//! against the three-kernel chain; projection into many cameras against the CPU;
//! pixel grids against their closed form; the caller's own buffers in and out; and the typed
//! errors of rows that do not fit a call. Skipped without a Vulkan adapter outside CI, as
//! `tests/gpu.rs`.

mod common;
mod gpu_harness;

use common::configurations;
use flatport::engine::CpuEngine;
use flatport::engine::gpu::{Pixels, Points, Rays, Triangulated};
use flatport::gpu::{DeviceRows, GpuContext, GpuError, Precision};
use flatport::model::{NoSolution, RefractiveCamera, Rig};
use gpu_harness::{Random, engine, rig_with_layer_stacks};
use nalgebra::{Point2, Point3};

const N: usize = 3000;

/// Matches: the projections of random points in the water in both cameras, `noise` px added to
/// the left u; one row in 50 a pixel pair that need not see one point, one in 97 NaN, row 7
/// beyond f32's range.
fn random_matches(
    random: &mut Random,
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    n: usize,
    noise: f64,
) -> Vec<[f64; 4]> {
    let mut matches = Vec::with_capacity(n);
    while matches.len() < n {
        let k = matches.len();
        if k % 97 == 5 {
            matches.push([f64::NAN, 100.0, 200.0, 300.0]);
            continue;
        }
        if k == 7 {
            matches.push([400.0, 300.0, 1e40, 300.0]);
            continue;
        }
        let pixel = Point2::new(random.range(0.0, 1280.0), random.range(0.0, 1024.0));
        let point = match a.backproject(&pixel) {
            Ok(ray) => ray.point_at(random.range(0.05, 6.0)),
            Err(_) => continue,
        };
        if let (Ok(pa), Ok(pb)) = (a.project(&point), b.project(&point)) {
            matches.push([pa.x + noise * random.range(-1.0, 1.0), pa.y, pb.x, pb.y]);
        } else if k % 50 == 0 {
            matches.push([
                random.range(-500.0, 1800.0),
                random.range(-500.0, 1500.0),
                600.0,
                500.0,
            ]);
        }
    }
    matches
}

fn split(matches: &[[f64; 4]]) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    (
        matches.iter().map(|m| [m[0], m[1]]).collect(),
        matches.iter().map(|m| [m[2], m[3]]).collect(),
    )
}

/// Allowed status disagreements: none in f64, rounding at boundaries in f32 (0.2 %).
fn allowed(precision: Precision, n: usize) -> usize {
    match precision {
        Precision::F64 => 0,
        Precision::F32 => n / 500,
    }
}

/// Rows both answered, as (index) after checking the statuses: at most `allowed` differ, rows
/// without an answer are NaN on the device side, and the batch has answers and non-answers.
fn answered_by_both<const M: usize>(
    what: &str,
    reference: (&[[f64; M]], &[u32]),
    device: (&[[f64; M]], &[u32]),
    allowed: usize,
) -> Vec<usize> {
    let (r, rs) = reference;
    let (d, ds) = device;
    assert_eq!(r.len(), d.len(), "{what}: row counts");
    assert_eq!(ds.len(), d.len(), "{what}: a status per row");
    let differ = (0..r.len()).filter(|&i| rs[i] != ds[i]).count();
    assert!(
        differ <= allowed,
        "{what}: {differ} statuses differ (allowed {allowed})"
    );
    for i in (0..d.len()).filter(|&i| ds[i] != 0) {
        assert!(
            d[i].iter().all(|v| v.is_nan()),
            "{what}: row {i} without an answer is NaN"
        );
    }
    let both: Vec<usize> = (0..r.len()).filter(|&i| rs[i] == 0 && ds[i] == 0).collect();
    assert!(
        both.len() > r.len() / 2,
        "{what}: {} of {} answered",
        both.len(),
        r.len()
    );
    assert!(
        rs.iter().any(|&s| s != 0),
        "{what}: the batch must have rows without an answer"
    );
    both
}

/// The largest f32 triangulation error over its bound (as `tests/gpu.rs`): direction and origin
/// errors ≤ 2e-6 move each ray by δ·range + δo at the point, the midpoint by that over sin θ
/// (factor 2: both rays).
fn f32_triangulation_error(
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    matches: &[[f64; 4]],
    reference: &[[f64; 4]],
    device: &[[f64; 4]],
    rows: &[usize],
) -> f64 {
    triangulation_error(2e-6, a, b, matches, reference, device, rows)
}

/// The largest triangulation error over the bound its rays' errors give: direction errors ≤ δ
/// and origin errors ≤ δ·max(1, |origin|) move each ray by δ·range + δ·max(1, |origin|) at the
/// point, the midpoint by that over sin θ (factor 2: both rays). δ = 2e-6 for f32 rays, 1e-12 for
/// f64 (DESIGN.md §5).
fn triangulation_error(
    delta: f64,
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    matches: &[[f64; 4]],
    reference: &[[f64; 4]],
    device: &[[f64; 4]],
    rows: &[usize],
) -> f64 {
    let mut worst: f64 = 0.0;
    for &i in rows {
        let m = matches[i];
        let ra = a.backproject(&Point2::new(m[0], m[1])).unwrap();
        let rb = b.backproject(&Point2::new(m[2], m[3])).unwrap();
        let c = reference[i];
        let p = Point3::new(c[0], c[1], c[2]);
        let sin = ra.dir.cross(&rb.dir).norm();
        let origins = ra.origin.coords.norm().max(1.0) + rb.origin.coords.norm().max(1.0);
        let bound = 2.0 * delta * ((p - ra.origin).norm() + (p - rb.origin).norm() + origins) / sin;
        let error = (0..4)
            .map(|k| (device[i][k] - c[k]).abs())
            .fold(0.0, f64::max);
        worst = worst.max(error / bound);
    }
    worst
}

/// Largest |Δ| / max(1, |reference|) over the given rows.
fn relative<const M: usize>(reference: &[[f64; M]], device: &[[f64; M]], rows: &[usize]) -> f64 {
    rows.iter()
        .flat_map(|&i| {
            (0..M).map(move |k| {
                (device[i][k] - reference[i][k]).abs() / reference[i][k].abs().max(1.0)
            })
        })
        .fold(0.0, f64::max)
}

/// The headline: matched pixels of two cameras → 3-D points, the rays never on the host, equal
/// to the f64 CPU reference within §5's bounds, statuses included (a NaN pixel and one beyond
/// f32's range are out of range, a pixel pair that sees no one point is not in the water or
/// degenerate, as on the CPU). With small chunks too, so that every kernel binds ranges at
/// offsets.
#[test]
fn chain_backproject_triangulate_on_the_device_matches_the_cpu() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(mut gpu) = engine(precision) else {
            return;
        };
        let mut random = Random(0x9E37_79B9_7F4A_7C15);
        for chunk in [usize::MAX, 64 * 7] {
            gpu.set_max_chunk_items(chunk);
            for (name, rig) in configurations() {
                let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
                let matches = random_matches(&mut random, &a, &b, N, 0.3);
                let (pixels_a, pixels_b) = split(&matches);
                let rays_a = gpu
                    .backproject_rows(&a, &gpu.upload::<Pixels>(&pixels_a).unwrap())
                    .unwrap();
                let rays_b = gpu
                    .backproject_rows(&b, &gpu.upload::<Pixels>(&pixels_b).unwrap())
                    .unwrap();
                let points = gpu.triangulate_rows(&rays_a, &rays_b).unwrap();
                let (g, gs) = gpu.read(&points).unwrap();

                let (mut c, mut cs) = (vec![[0.0; 4]; N], vec![0; N]);
                cpu.triangulate(&a, &b, &matches, &mut c, &mut cs);
                let what = format!(
                    "device chain {precision} {name}, chunks of {}",
                    gpu.max_chunk_items()
                );
                let out_of_range = NoSolution::OutOfRange.code();
                assert_eq!(gs[5], out_of_range, "{what}: a NaN pixel");
                if precision == Precision::F32 {
                    assert_eq!(gs[7], out_of_range, "{what}: a pixel beyond f32");
                }
                let rows = answered_by_both(&what, (&c, &cs), (&g, &gs), allowed(precision, N));
                match precision {
                    Precision::F32 => {
                        let worst = f32_triangulation_error(&a, &b, &matches, &c, &g, &rows);
                        println!("{what:60} max |Δ| / bound {worst:.2}");
                        assert!(worst < 1.0, "{what}: |Δ| / bound {worst:.2}");
                    }
                    Precision::F64 => {
                        let rel = relative(&c, &g, &rows);
                        println!("{what:60} relative {rel:.1e}");
                        assert!(rel < 1e-9, "{what}: relative {rel:.1e}");
                    }
                }
            }
        }
    }
}

/// The device chain gives what the host-row call `triangulate` gives for the same matches (its
/// one fused kernel): the same statuses, points within the same bounds.
#[test]
fn chain_on_the_device_agrees_with_the_host_row_call() {
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let mut random = Random(0x2545_F491_4F6C_DD1D);
        for (name, rig) in configurations() {
            let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
            let matches = random_matches(&mut random, &a, &b, N, 0.3);
            let (pixels_a, pixels_b) = split(&matches);
            let rays_a = gpu
                .backproject_rows(&a, &gpu.upload::<Pixels>(&pixels_a).unwrap())
                .unwrap();
            let rays_b = gpu
                .backproject_rows(&b, &gpu.upload::<Pixels>(&pixels_b).unwrap())
                .unwrap();
            let (g, gs) = gpu
                .read(&gpu.triangulate_rows(&rays_a, &rays_b).unwrap())
                .unwrap();
            let (mut h, mut hs) = (vec![[0.0; 4]; N], vec![0; N]);
            gpu.triangulate(&a, &b, &matches, &mut h, &mut hs).unwrap();
            let what = format!("device chain vs host rows {precision} {name}");
            let rows = answered_by_both(&what, (&h, &hs), (&g, &gs), allowed(precision, N));
            match precision {
                Precision::F32 => {
                    let worst = f32_triangulation_error(&a, &b, &matches, &h, &g, &rows);
                    assert!(worst < 1.0, "{what}: |Δ| / bound {worst:.2}");
                }
                Precision::F64 => {
                    let rel = relative(&h, &g, &rows);
                    assert!(rel < 1e-9, "{what}: relative {rel:.1e}");
                }
            }
            // And the rays read back are the host call's back-projection.
            let (r, rs) = gpu.read(&rays_a).unwrap();
            let (mut hr, mut hrs) = (vec![[0.0; 6]; N], vec![0; N]);
            gpu.backproject(&a, &pixels_a, &mut hr, &mut hrs).unwrap();
            let rows = answered_by_both(&format!("{what} rays"), (&hr, &hrs), (&r, &rs), 0);
            let bound = match precision {
                Precision::F32 => 2e-6,
                Precision::F64 => 1e-9,
            };
            let rel = relative(&hr, &r, &rows);
            assert!(rel < bound, "{what}: rays relative {rel:.1e}");
        }
    }
}

/// The rigs of the fused chain: every configuration of `configurations` (one port shared by both
/// cameras: a bare water surface, distorted lenses, one to three layers, a tank) and two housings
/// with a port each (a bare interface and three layers, either camera first).
fn fused_rigs() -> Vec<(String, Rig)> {
    let mut rigs: Vec<(String, Rig)> = configurations()
        .into_iter()
        .map(|(name, rig)| (format!("shared port, {name}"), rig))
        .collect();
    for bare_first in [true, false] {
        rigs.push((
            format!("a port per camera, bare first: {bare_first}"),
            rig_with_layer_stacks(bare_first),
        ));
    }
    rigs
}

/// A pixel whose back-projection in `camera` fails on the CPU (far outside the image: the lens
/// folds, or the air ray misses the port or is reflected), searched over directions and radii.
fn failing_pixel(camera: &RefractiveCamera) -> [f64; 2] {
    for radius in [1e4, 1e5, 1e6, 1e7] {
        for k in 0..16 {
            let angle = k as f64 * std::f64::consts::PI / 8.0;
            let pixel = [640.0 + radius * angle.cos(), 512.0 + radius * angle.sin()];
            if camera
                .backproject(&Point2::new(pixel[0], pixel[1]))
                .is_err()
            {
                return pixel;
            }
        }
    }
    panic!("no pixel without a back-projection found")
}

/// `random_matches` with rows whose answer depends on the order of the failures, as the CPU
/// orders them (an input out of range first, then camera a's back-projection, then b's): a good
/// pixel a with a pixel b that has no back-projection, a pixel a without one and pixel b NaN
/// (out of range, not a's failure), both without one (a's failure), a pixel a without one and a
/// good pixel b. Returns the matches and those rows.
fn matches_with_failures(
    random: &mut Random,
    a: &RefractiveCamera,
    b: &RefractiveCamera,
) -> (Vec<[f64; 4]>, [usize; 4]) {
    let mut matches = random_matches(random, a, b, N, 0.3);
    let point = a
        .backproject(&Point2::new(640.0, 512.0))
        .unwrap()
        .point_at(1.5);
    let (good_a, good_b) = (a.project(&point).unwrap(), b.project(&point).unwrap());
    let (bad_a, bad_b) = (failing_pixel(a), failing_pixel(b));
    let rows = [11, 13, 17, 19];
    matches[rows[0]] = [good_a.x, good_a.y, bad_b[0], bad_b[1]];
    matches[rows[1]] = [bad_a[0], bad_a[1], f64::NAN, 100.0];
    matches[rows[2]] = [bad_a[0], bad_a[1], bad_b[0], bad_b[1]];
    matches[rows[3]] = [bad_a[0], bad_a[1], good_b.x, good_b.y];
    (matches, rows)
}

/// Issue 31's chain, fused: matched pixels of two cameras → 3-D points in one kernel
/// (`triangulate_pixels`), the rays never in memory, against the f64 CPU reference on every rig
/// of `fused_rigs`: statuses equal (f32: but for rounding at boundaries, as above), f64 points
/// within the bound that DESIGN.md §5's 1e-12 on the rays gives them, f32 within the one its
/// 2e-6 gives; rows where either pixel has no answer (out of range, missing the port, outside
/// the lens) get the CPU's status in the CPU's order. With small chunks too, so that the pixels'
/// statuses are bound at offsets.
#[test]
fn fused_chain_on_the_device_matches_the_cpu() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(mut gpu) = engine(precision) else {
            return;
        };
        let mut random = Random(0x6A09_E667_F3BC_C908);
        for chunk in [usize::MAX, 64 * 7] {
            gpu.set_max_chunk_items(chunk);
            for (name, rig) in fused_rigs() {
                let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
                let (matches, ordered) = matches_with_failures(&mut random, &a, &b);
                let (pixels_a, pixels_b) = split(&matches);
                let on_a = gpu.upload::<Pixels>(&pixels_a).unwrap();
                let on_b = gpu.upload::<Pixels>(&pixels_b).unwrap();
                let points = gpu.triangulate_pixels(&a, &b, &on_a, &on_b).unwrap();
                assert_eq!(points.len(), N);
                let (g, gs) = gpu.read(&points).unwrap();

                let (mut c, mut cs) = (vec![[0.0; 4]; N], vec![0; N]);
                cpu.triangulate(&a, &b, &matches, &mut c, &mut cs);
                let what = format!(
                    "fused chain {precision} {name}, chunks of {}",
                    gpu.max_chunk_items()
                );
                let out_of_range = NoSolution::OutOfRange.code();
                assert_eq!(gs[5], out_of_range, "{what}: a NaN pixel a");
                if precision == Precision::F32 {
                    assert_eq!(gs[7], out_of_range, "{what}: a pixel b beyond f32");
                }
                // The rows of mixed failures: the CPU's statuses, which are failures of the kind
                // each row was built for.
                let [b_fails, a_fails_b_nan, both_fail, a_fails] = ordered;
                assert_eq!(cs[a_fails_b_nan], out_of_range, "{what}: CPU, NaN pixel b");
                for i in [b_fails, both_fail, a_fails] {
                    assert!(![0, out_of_range].contains(&cs[i]), "{what}: CPU row {i}");
                }
                for i in ordered {
                    assert_eq!(gs[i], cs[i], "{what}: row {i}, the CPU's order of failures");
                }
                let rows = answered_by_both(&what, (&c, &cs), (&g, &gs), allowed(precision, N));
                let delta = match precision {
                    Precision::F32 => 2e-6,
                    Precision::F64 => 1e-12,
                };
                let worst = triangulation_error(delta, &a, &b, &matches, &c, &g, &rows);
                println!("{what:70} max |Δ| / bound {worst:.1e}");
                assert!(worst < 1.0, "{what}: |Δ| / bound {worst:.2}");
            }
        }
    }
}

/// Rows both device chains answered whose pixels the f64 CPU back-projects in both cameras (the
/// rays the bound of `triangulation_error` needs): all but `allowed` of them, the f32 pixels at
/// the lens's or the port's boundary.
fn with_cpu_rays(
    what: &str,
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    matches: &[[f64; 4]],
    rows: Vec<usize>,
    allowed: usize,
) -> Vec<usize> {
    let count = rows.len();
    let kept: Vec<usize> = rows
        .into_iter()
        .filter(|&i| {
            let m = matches[i];
            a.backproject(&Point2::new(m[0], m[1])).is_ok()
                && b.backproject(&Point2::new(m[2], m[3])).is_ok()
        })
        .collect();
    assert!(
        count - kept.len() <= allowed,
        "{what}: {} rows without CPU rays",
        count - kept.len()
    );
    kept
}

/// The fused chain and the three-kernel chain (`backproject_rows` of both cameras, then
/// `triangulate_rows`) give the same rows for the same pixels on the device: the same statuses
/// (f32: but for rounding at boundaries), points within the bounds of the rays' errors. Also
/// through rows the device made: pixels that `project_many` gives for points in the water, with
/// the statuses of the points that have none.
#[test]
fn fused_and_three_kernel_chains_agree() {
    for precision in [Precision::F32, Precision::F64] {
        let Some(gpu) = engine(precision) else { return };
        let mut random = Random(0xBB67_AE85_84CA_A73B);
        let delta = match precision {
            Precision::F32 => 2e-6,
            Precision::F64 => 1e-12,
        };
        for (name, rig) in fused_rigs() {
            let (a, b) = (rig.refractive_camera(0), rig.refractive_camera(1));
            let matches = random_matches(&mut random, &a, &b, N, 0.3);
            let (pixels_a, pixels_b) = split(&matches);
            let on_a = gpu.upload::<Pixels>(&pixels_a).unwrap();
            let on_b = gpu.upload::<Pixels>(&pixels_b).unwrap();
            let (f, fs) = gpu
                .read(&gpu.triangulate_pixels(&a, &b, &on_a, &on_b).unwrap())
                .unwrap();
            let rays_a = gpu.backproject_rows(&a, &on_a).unwrap();
            let rays_b = gpu.backproject_rows(&b, &on_b).unwrap();
            let (t, ts) = gpu
                .read(&gpu.triangulate_rows(&rays_a, &rays_b).unwrap())
                .unwrap();
            let what = format!("fused vs three kernels {precision} {name}");
            let rows = answered_by_both(&what, (&t, &ts), (&f, &fs), allowed(precision, N));
            let rows = with_cpu_rays(&what, &a, &b, &matches, rows, allowed(precision, N));
            let worst = triangulation_error(delta, &a, &b, &matches, &t, &f, &rows);
            assert!(worst < 1.0, "{what}: |Δ| / bound {worst:.2}");

            // Pixels made on the device: points along the rays of random pixels of camera a,
            // one in 10 in the air (no pixel), projected into both cameras.
            let points: Vec<[f64; 3]> = (0..N)
                .map(|k| {
                    let pixel = Point2::new(random.range(0.0, 1280.0), random.range(0.0, 1024.0));
                    match a.backproject(&pixel) {
                        Ok(ray) if k % 10 != 0 => {
                            ray.point_at(random.range(0.05, 6.0)).coords.into()
                        }
                        _ => [0.0, 0.0, 1e-3],
                    }
                })
                .collect();
            let projected = gpu
                .project_many(
                    &gpu.upload::<Points>(&points).unwrap(),
                    &[a.clone(), b.clone()],
                )
                .unwrap();
            let (on_a, on_b) = (&projected[0], &projected[1]);
            let (f, fs) = gpu
                .read(&gpu.triangulate_pixels(&a, &b, on_a, on_b).unwrap())
                .unwrap();
            let rays_a = gpu.backproject_rows(&a, on_a).unwrap();
            let rays_b = gpu.backproject_rows(&b, on_b).unwrap();
            let (t, ts) = gpu
                .read(&gpu.triangulate_rows(&rays_a, &rays_b).unwrap())
                .unwrap();
            let what = format!("{what}, projected pixels");
            let (pa, _) = gpu.read(on_a).unwrap();
            let (pb, _) = gpu.read(on_b).unwrap();
            let projected_matches: Vec<[f64; 4]> = pa
                .iter()
                .zip(&pb)
                .map(|(p, q)| [p[0], p[1], q[0], q[1]])
                .collect();
            let rows = answered_by_both(&what, (&t, &ts), (&f, &fs), allowed(precision, N));
            let rows = with_cpu_rays(
                &what,
                &a,
                &b,
                &projected_matches,
                rows,
                allowed(precision, N),
            );
            let worst = triangulation_error(delta, &a, &b, &projected_matches, &t, &f, &rows);
            assert!(worst < 1.0, "{what}: |Δ| / bound {worst:.2}");
            for i in (0..N).filter(|i| i % 10 == 0) {
                assert_ne!(fs[i], 0, "{what}: row {i}, a point in the air has no pixel");
            }
        }
    }
}

/// One point set into both cameras of every configuration (one upload): the pixels of the f64
/// CPU projection within 1e-3 px over the image in f32 and 1e-9 relative anywhere in f64,
/// statuses as the CPU's (points in the air or behind a camera, a NaN point).
#[test]
fn project_many_matches_the_cpu_in_every_camera() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(mut gpu) = engine(precision) else {
            return;
        };
        gpu.set_max_chunk_items(64 * 5);
        let mut random = Random(0xD1B5_4A32_D192_ED03);
        for (name, rig) in configurations() {
            let cameras = [rig.refractive_camera(0), rig.refractive_camera(1)];
            let points: Vec<[f64; 3]> = (0..N)
                .map(|k| {
                    let pixel = Point2::new(random.range(0.0, 1280.0), random.range(0.0, 1024.0));
                    match cameras[0].backproject(&pixel) {
                        Ok(ray) if k % 10 != 0 => {
                            ray.point_at(random.range(1e-3, 6.0)).coords.into()
                        }
                        _ if k % 10 == 3 => [f64::NAN, 0.0, 1.0],
                        _ => [
                            random.range(-2.0, 2.0),
                            random.range(-2.0, 2.0),
                            random.range(-0.5, 4.0),
                        ],
                    }
                })
                .collect();
            let on_device = gpu.upload::<Points>(&points).unwrap();
            let all = gpu.project_many(&on_device, &cameras).unwrap();
            assert_eq!(all.len(), 2);
            for (k, (camera, pixels)) in cameras.iter().zip(&all).enumerate() {
                let (g, gs) = gpu.read(pixels).unwrap();
                let (mut c, mut cs) = (vec![[0.0; 2]; N], vec![0; N]);
                cpu.project(camera, &points, &mut c, &mut cs);
                let what = format!("project_many {precision} {name} camera {k}");
                let rows = answered_by_both(&what, (&c, &cs), (&g, &gs), allowed(precision, N));
                match precision {
                    Precision::F32 => {
                        // Over the image (1280 × 1024), as tests/gpu.rs: points seen at
                        // steeper angles project far outside it, where the refraction amplifies
                        // the rounding of f32 inputs.
                        let near_image = |p: &[f64; 2]| {
                            p[0] > 0.0 && p[0] < 1280.0 && p[1] > 0.0 && p[1] < 1024.0
                        };
                        let in_view: Vec<usize> = rows
                            .iter()
                            .copied()
                            .filter(|&i| near_image(&c[i]))
                            .collect();
                        assert!(in_view.len() > N / 2, "{what}: most points in view");
                        let worst = in_view
                            .iter()
                            .flat_map(|&i| [(g[i][0] - c[i][0]).abs(), (g[i][1] - c[i][1]).abs()])
                            .fold(0.0, f64::max);
                        assert!(worst < 1e-3, "{what}: {worst:.1e} px");
                    }
                    Precision::F64 => {
                        let rel = relative(&c, &g, &rows);
                        assert!(rel < 1e-9, "{what}: relative {rel:.1e}");
                    }
                }
            }
        }
    }
}

/// A pixel grid made on the device is its closed form, u = step · (i mod w), v = step · (i div
/// w), every row an answer, in chunks too; back-projected on the device it gives the CPU's rays.
#[test]
fn pixel_grids_on_the_device_are_their_closed_form() {
    let cpu = CpuEngine::new(None);
    for precision in [Precision::F32, Precision::F64] {
        let Some(mut gpu) = engine(precision) else {
            return;
        };
        gpu.set_max_chunk_items(64 * 3);
        let (w, h, step) = (37u32, 23u32, 3u32);
        let grid = gpu.pixel_grid(w, h, step).unwrap();
        assert_eq!(grid.len(), (w * h) as usize);
        let (pixels, status) = gpu.read(&grid).unwrap();
        for (i, (p, s)) in pixels.iter().zip(&status).enumerate() {
            let i = i as u32;
            let expected = [(step * (i % w)) as f64, (step * (i / w)) as f64];
            assert_eq!((*p, *s), (expected, 0), "{precision}: pixel {i}");
        }
        let camera = configurations()[1].1.refractive_camera(1);
        let (g, gs) = gpu
            .read(&gpu.backproject_rows(&camera, &grid).unwrap())
            .unwrap();
        let (mut c, mut cs) = (vec![[0.0; 6]; pixels.len()], vec![0; pixels.len()]);
        cpu.backproject(&camera, &pixels, &mut c, &mut cs);
        assert_eq!(gs, cs, "{precision}: grid rays' statuses");
        let rows: Vec<usize> = (0..c.len()).filter(|&i| cs[i] == 0).collect();
        let bound = match precision {
            Precision::F32 => 2e-6,
            Precision::F64 => 1e-9,
        };
        let rel = relative(&c, &g, &rows);
        assert!(rel < bound, "{precision}: grid rays relative {rel:.1e}");
        assert!(gpu.pixel_grid(0, 5, 1).unwrap().is_empty());
    }
}

/// The caller's own buffers: pixels written by plain wgpu into a buffer of the engine's device
/// go through the chain in place, and the rays' buffer, copied out by plain wgpu, holds the
/// documented layout (row i at i · 6 · 4 bytes, little-endian f32) with the values `read` gives.
#[test]
fn the_callers_own_buffers_go_in_and_come_out() {
    let Some(gpu) = engine(Precision::F32) else {
        return;
    };
    let camera = configurations()[0].1.refractive_camera(0);
    let pixels: Vec<[f32; 2]> = (0..200).map(|i| [6.0 * i as f32, 5.0 * i as f32]).collect();
    let device = gpu.context().device();
    let queue = gpu.context().queue();
    let own = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("caller's pixels"),
        size: (pixels.len() * 8) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    queue.write_buffer(&own, 0, bytemuck::cast_slice(&pixels));
    let rows: DeviceRows<Pixels> = gpu.rows_from_buffers(own, None, pixels.len()).unwrap();
    assert_eq!(rows.stride_bytes(), 8);
    let rays = gpu.backproject_rows(&camera, &rows).unwrap();
    let (read, status) = gpu.read(&rays).unwrap();

    let bytes = rays.len() * rays.stride_bytes();
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("caller's staging"),
        size: bytes as u64,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(rays.buffer(), 0, &staging, 0, bytes as u64);
    queue.submit([encoder.finish()]);
    staging.map_async(wgpu::MapMode::Read, .., |r| r.expect("mapped"));
    device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
    let mapped = staging.get_mapped_range(..).unwrap();
    let own_rays: &[f32] = bytemuck::cast_slice(&mapped);
    let cpu = CpuEngine::new(None);
    let wide: Vec<[f64; 2]> = pixels.iter().map(|p| [p[0] as f64, p[1] as f64]).collect();
    let (mut c, mut cs) = (vec![[0.0; 6]; wide.len()], vec![0; wide.len()]);
    cpu.backproject(&camera, &wide, &mut c, &mut cs);
    assert_eq!(status, cs);
    assert!(cs.iter().filter(|&&s| s == 0).count() > 100);
    for i in (0..wide.len()).filter(|&i| cs[i] == 0) {
        for k in 0..6 {
            assert_eq!(own_rays[6 * i + k] as f64, read[i][k], "row {i} column {k}");
            assert!(
                (read[i][k] - c[i][k]).abs() < 2e-6 * c[i][k].abs().max(1.0),
                "row {i}"
            );
        }
    }
}

/// Rows that do not fit a call are typed errors that say what is wrong, never a panic: unequal
/// lengths, rows of another device, of another precision, buffers too short or without STORAGE,
/// a grid step of 0.
#[test]
fn rows_that_do_not_fit_are_typed_errors() {
    let Some(gpu) = engine(Precision::F32) else {
        return;
    };
    let camera = configurations()[0].1.refractive_camera(0);
    let expect_rows_error = |result: Result<(), GpuError>, words: &str| match result {
        Err(GpuError::Rows(message)) => {
            assert!(message.contains(words), "'{message}' should say '{words}'")
        }
        other => panic!("expected a rows error saying '{words}', got {other:?}"),
    };
    let three = gpu
        .upload::<Rays>(&[[0.0, 0.0, 0.0, 0.0, 0.0, 1.0]; 3])
        .unwrap();
    let four = gpu
        .upload::<Rays>(&[[0.0, 0.0, 0.0, 0.0, 0.0, 1.0]; 4])
        .unwrap();
    expect_rows_error(
        gpu.triangulate_rows(&three, &four).map(drop),
        "3 rows a, 4 rows b",
    );
    let second = configurations()[0].1.refractive_camera(1);
    let two_pixels = gpu.upload::<Pixels>(&[[1.0, 2.0]; 2]).unwrap();
    let five_pixels = gpu.upload::<Pixels>(&[[1.0, 2.0]; 5]).unwrap();
    expect_rows_error(
        gpu.triangulate_pixels(&camera, &second, &two_pixels, &five_pixels)
            .map(drop),
        "2 rows a, 5 rows b",
    );

    let other = GpuContext::new(None).unwrap();
    let elsewhere: DeviceRows<Pixels> =
        DeviceRows::upload(&other, Precision::F32, &[[1.0, 2.0]]).unwrap();
    expect_rows_error(
        gpu.backproject_rows(&camera, &elsewhere).map(drop),
        "another device",
    );
    expect_rows_error(gpu.read(&elsewhere).map(drop), "another device");
    let here = gpu.upload::<Pixels>(&[[1.0, 2.0]]).unwrap();
    expect_rows_error(
        gpu.triangulate_pixels(&camera, &second, &here, &elsewhere)
            .map(drop),
        "the pixels b live on another device",
    );

    if let Some(gpu64) = engine(Precision::F64) {
        let pixels = gpu.upload::<Pixels>(&[[1.0, 2.0]]).unwrap();
        // Same adapter, another device: the device is checked first; rows of the engine's own
        // device in another precision:
        let f64_rows: DeviceRows<Points> =
            DeviceRows::upload(gpu.context(), Precision::F64, &[[0.0, 0.0, 1.0]]).unwrap();
        expect_rows_error(gpu.project_rows(&camera, &f64_rows).map(drop), "f64 reals");
        let f64_pixels: DeviceRows<Pixels> =
            DeviceRows::upload(gpu.context(), Precision::F64, &[[1.0, 2.0]]).unwrap();
        expect_rows_error(
            gpu.triangulate_pixels(&camera, &second, &f64_pixels, &pixels)
                .map(drop),
            "the pixels a hold f64 reals",
        );
        expect_rows_error(
            gpu64.backproject_rows(&camera, &pixels).map(drop),
            "another device",
        );
    }

    let short = gpu
        .context()
        .buffer("short", 16, DeviceRows::<Rays>::USAGE)
        .unwrap();
    expect_rows_error(
        gpu.rows_from_buffers::<Rays>(short, None, 3).map(drop),
        "cannot hold 3 rows",
    );
    let unbindable = gpu
        .context()
        .buffer("copy only", 64, wgpu::BufferUsages::COPY_DST)
        .unwrap();
    expect_rows_error(
        gpu.rows_from_buffers::<Pixels>(unbindable, None, 2)
            .map(drop),
        "without STORAGE",
    );
    expect_rows_error(gpu.pixel_grid(4, 4, 0).map(drop), "step");
    expect_rows_error(gpu.pixel_grid(u32::MAX, 2, 1).map(drop), "2³² − 1");

    // An empty batch is no error and reads back empty.
    let empty = gpu.upload::<Pixels>(&[]).unwrap();
    let rays = gpu.backproject_rows(&camera, &empty).unwrap();
    let points: DeviceRows<Triangulated> = gpu.triangulate_rows(&rays, &rays).unwrap();
    assert_eq!(gpu.read(&points).unwrap(), (vec![], vec![]));
    let points = gpu
        .triangulate_pixels(&camera, &second, &empty, &empty)
        .unwrap();
    assert_eq!(gpu.read(&points).unwrap(), (vec![], vec![]));
}
