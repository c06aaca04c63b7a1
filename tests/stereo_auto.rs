//! Dense stereo with no options (DESIGN.md §3c): the depth range found from the images and the
//! hypotheses chosen by the step rule (src/stereo/range.rs), against the renderer's exact depth
//! (tests/stereo_common). The step rule is checked against exact projections of every step; the
//! coarse rig against the box filter's closed form; the acceptance levels on its three
//! scene kinds and two more (a far scene, a near one), each with `StereoOptions::default()`; the
//! chosen range must hold the true depths of every pixel another camera sees. Release mode:
//! `cargo test --release --test stereo_auto`.

mod stereo_common;

use std::process::Command;

use flatport::model::Rig;
use flatport::render::{Extent, Shape, TexturedScene};
use flatport::stereo::range::{
    CountChoice, RangeChoice, STEP_PX, downsampled_rig, largest_motion, step_rule,
};
use flatport::stereo::rays::{inverse_depths, reference_rays};
use flatport::stereo::{StereoOptions, stereo};
use nalgebra::{Point2, Point3};
use stereo_common::*;

/// The rig `json` with every camera's size, focal lengths and principal point times `scale`
/// (the same field of view at another resolution).
fn scaled(json: &str, scale: u32) -> Rig {
    let text = json
        .replace(
            "\"width\": 320, \"height\": 256, \"fx\": 260, \"fy\": 260, \"cx\": 159.5, \"cy\": 127.5",
            &format!(
                "\"width\": {}, \"height\": {}, \"fx\": {}, \"fy\": {}, \"cx\": {}, \"cy\": {}",
                320 * scale,
                256 * scale,
                260 * scale,
                260 * scale,
                160.0 * f64::from(scale) - 0.5,
                128.0 * f64::from(scale) - 0.5
            ),
        )
        .replace(
            "\"width\": 320, \"height\": 256, \"fx\": 250, \"fy\": 250, \"cx\": 159.5, \"cy\": 127.5",
            &format!(
                "\"width\": {}, \"height\": {}, \"fx\": {}, \"fy\": {}, \"cx\": {}, \"cy\": {}",
                320 * scale,
                256 * scale,
                250 * scale,
                250 * scale,
                160.0 * f64::from(scale) - 0.5,
                128.0 * f64::from(scale) - 0.5
            ),
        );
    assert!(scale == 1 || text != json, "the rig was scaled");
    rig(&text)
}

/// Steps of every reference pixel (every `stride`-th in both directions) between consecutive
/// hypotheses of `count` over `range`, in every other camera where both ends fall in its image:
/// the largest, by the model's own exact back-projection and projection (not the stereo code's).
fn largest_step_px(rig: &Rig, range: (f64, f64), count: usize, stride: usize) -> f64 {
    let reference = rig.refractive_camera(0);
    let (w, h) = (
        reference.intrinsics().width as usize,
        reference.intrinsics().height as usize,
    );
    let z_row = reference.cam_from_master().row(2).transpose();
    let q = inverse_depths(range.0, range.1, count);
    let others: Vec<_> = (1..rig.cameras().len())
        .map(|k| rig.refractive_camera(k))
        .collect();
    let mut largest = 0f64;
    for v in (0..h).step_by(stride) {
        for u in (0..w).step_by(stride) {
            let Ok(ray) = reference.backproject(&Point2::new(u as f64, v as f64)) else {
                continue;
            };
            let z0 = z_row.dot(&(ray.origin - reference.centre()));
            let dz = z_row.dot(&ray.dir);
            let at = |q: f64| ray.point_at((1.0 / q - z0) / dz);
            for camera in &others {
                let (cw, ch) = (
                    f64::from(camera.intrinsics().width),
                    f64::from(camera.intrinsics().height),
                );
                let inside = |p: &Point2<f64>| {
                    p.x >= 0.0 && p.y >= 0.0 && p.x <= cw - 1.0 && p.y <= ch - 1.0
                };
                let mut previous: Option<Point2<f64>> = None;
                for &qh in &q {
                    let p = camera.project(&at(qh)).ok().filter(inside);
                    if let (Some(a), Some(b)) = (previous, p) {
                        largest = largest.max((b - a).norm());
                    }
                    previous = p;
                }
            }
        }
    }
    largest
}

#[test]
fn the_step_rule_bounds_every_step_by_exact_projections() {
    for (name, rig, range) in [
        ("shared port", rig(SHARED_PORT_PAIR), (0.8, 2.5)),
        ("housings", rig(PORT_PER_CAMERA), (0.86, 1.97)),
        ("housings 640 x 512", scaled(PORT_PER_CAMERA, 2), (0.6, 3.0)),
        ("above water", rig(ABOVE_WATER_TRIO), (0.9, 2.2)),
    ] {
        let cameras: Vec<_> = (0..rig.cameras().len())
            .map(|k| rig.refractive_camera(k))
            .collect();
        let rays = reference_rays(&cameras[0]);
        let rule = step_rule(largest_motion(&cameras, 0, &rays, range), range);
        assert!(!rule.clamped(), "{name}: {rule:?}");
        // Every second pixel, every step, every other camera.
        let exact = largest_step_px(&rig, range, rule.count, 2);
        // With one hypothesis fewer the rule's bound would be broken somewhere: the count is the
        // least that keeps it (up to the rule's rounding to a whole step).
        let fewer = largest_step_px(&rig, range, rule.count - 1, 2);
        eprintln!(
            "{name}: {} hypotheses over {range:?}, M = {:.1} px·m, rule's largest step {:.4} px; exact over every 2nd pixel: {exact:.4} px ({fewer:.4} px with one fewer)",
            rule.count, rule.motion_px_m, rule.step_px
        );
        // The rule samples a grid of pixels and 9 depths of a smooth function; the exact steps
        // are differences, not derivatives: within 1 % of the rule's own largest step.
        assert!(exact <= STEP_PX * 1.01, "{name}: {exact} px");
        assert!(
            (exact - rule.step_px).abs() <= 0.01 * rule.step_px,
            "{name}: exact {exact} against the rule's {}",
            rule.step_px
        );
        assert!(
            fewer > STEP_PX,
            "{name}: {fewer} px with one hypothesis fewer: the rule's count is not the least"
        );
    }
}

#[test]
fn a_coarse_camera_projects_where_the_box_filter_puts_the_point() {
    // A coarse pixel (u′, v′) averages the fine pixels k·u′ … k·u′ + k − 1, whose centre is
    // k·u′ + (k − 1)/2: a point the fine camera sees at u the coarse one sees at
    // (u − (k − 1)/2)/k, distortion included.
    for (json, k) in [
        (SHARED_PORT_PAIR, 4usize),
        (PORT_PER_CAMERA, 3),
        (ABOVE_WATER_TRIO, 2),
    ] {
        let fine = scaled(json, 4);
        let coarse = downsampled_rig(&fine, &vec![k; fine.cameras().len()]).unwrap();
        for c in 0..fine.cameras().len() {
            let (a, b) = (fine.refractive_camera(c), coarse.refractive_camera(c));
            assert_eq!(
                b.intrinsics().width as usize,
                a.intrinsics().width as usize / k
            );
            let mut checked = 0;
            for i in 0..200 {
                let t = i as f64 / 200.0;
                let x = Point3::new(
                    -0.6 + 1.2 * ((7.0 * t).fract()),
                    -0.5 + 1.0 * ((13.0 * t).fract()),
                    0.7 + 2.0 * t,
                );
                let (Ok(p), Ok(q)) = (a.project(&x), b.project(&x)) else {
                    continue;
                };
                let half = (k as f64 - 1.0) / 2.0;
                assert!(
                    ((p.x - half) / k as f64 - q.x).abs() < 1e-9
                        && ((p.y - half) / k as f64 - q.y).abs() < 1e-9,
                    "camera {c}: fine {p}, coarse {q}"
                );
                checked += 1;
            }
            assert!(checked > 100, "{checked}");
        }
    }
}

/// An acceptance scene.
struct Case {
    name: &'static str,
    rig: Rig,
    scene: TexturedScene,
}

fn bounded_plane(
    z: f64,
    tilt: f64,
    seed: u64,
    scale: f64,
    s: [f64; 2],
) -> flatport::render::Surface {
    let mut plane = plane_at(z, tilt, noise(seed, scale));
    if let Shape::Plane { extent, .. } = &mut plane.shape {
        *extent = Some(Extent { s, t: [-5.0, 5.0] });
    }
    plane
}

/// Runs `case` with `StereoOptions::default()` and checks the levels and the range.
fn accept(case: &Case) {
    let rendered = render_all(&case.rig, &case.scene, 2.0);
    let started = std::time::Instant::now();
    let map = stereo(&case.rig, &rendered.images, &StereoOptions::default()).unwrap();
    let seconds = started.elapsed().as_secs_f64();
    let seen = seen_by_another(&case.rig, 0, &rendered);
    let a = accuracy(&map, &rendered.depths[0], &seen);
    let truth = &rendered.depths[0];
    let (low, high) = (0..truth.len())
        .filter(|&i| seen[i])
        .map(|i| f64::from(truth[i]))
        .fold((f64::INFINITY, 0f64), |(a, b), z| (a.min(z), b.max(z)));
    eprintln!(
        "{}: {}\n  true depths seen {low:.3}:{high:.3} m; {} seen pixels, {:.1} % with a point, median {:.3} %, {:.1} % within 2 %, periphery median {:.3} % ({} points), {} points unseen, {:.1} % of them gross; {seconds:.1} s {:?}",
        case.name,
        map.sampling,
        a.seen,
        100.0 * a.valid_fraction,
        100.0 * a.median,
        100.0 * a.within_2,
        100.0 * a.periphery_median,
        a.periphery_points,
        a.unseen_points,
        100.0 * a.unseen_gross,
        map.stage_seconds
    );
    let name = case.name;
    assert!(
        matches!(map.sampling.range, RangeChoice::Found(_)),
        "{name}"
    );
    assert!(matches!(map.sampling.count, CountChoice::Rule(_)), "{name}");
    let (min, max) = map.depth_range;
    assert!(
        min < low && high < max,
        "{name}: the range {min}:{max} misses true depths {low}:{high}"
    );
    assert!(a.seen > 15_000, "{name}: only {} pixels seen", a.seen);
    assert!(a.valid_fraction >= 0.85, "{name}: {a:?}");
    assert!(a.median <= 0.003, "{name}: {a:?}");
    assert!(a.within_2 >= 0.93, "{name}: {a:?}");
    assert!(a.periphery_points > 1000, "{name}: {a:?}");
    assert!(a.periphery_median <= 0.005, "{name}: {a:?}");
    assert!(a.unseen_gross <= 0.05, "{name}: {a:?}");
}

#[test]
fn defaults_shared_port_seabed_and_rock() {
    accept(&Case {
        name: "shared port: seabed and a rock",
        rig: rig(SHARED_PORT_PAIR),
        scene: scene(vec![seabed(1.6, 3), sphere([0.12, 0.05, 1.3], 0.15, 12)]),
    });
}

#[test]
fn defaults_housings_plane_and_sphere() {
    // The third scene: two housings 25 cm apart, a tilted plane and a sphere, true depths
    // about 0.88 … 1.82 m, at 640 × 512 (steps of 128 hypotheses over that range would be 1.1 px
    // here; over the old default 0.3 … 3 m, 5.5 px). Texture with detail down to 3 px, as the
    // 320 × 256 scenes have (with detail down to 7 px only, 80 % have a point at the rule's
    // 0.8 px steps, 84 % at 0.4 px: smooth texture, not the sampling, limits that).
    accept(&Case {
        name: "housings 640 x 512: plane and sphere",
        rig: scaled(PORT_PER_CAMERA, 2),
        scene: scene(vec![
            plane_at(1.5, 0.35, noise(41, 0.06)),
            sphere([0.1, 0.02, 1.1], 0.22, 42),
        ]),
    });
}

#[test]
fn defaults_three_cameras_above_a_bare_water_surface() {
    accept(&Case {
        name: "three cameras above water: seabed and a rock",
        rig: rig(ABOVE_WATER_TRIO),
        scene: scene(vec![seabed(1.5, 5), sphere([0.1, 0.08, 1.3], 0.12, 32)]),
    });
}

#[test]
fn defaults_far_scene() {
    // A wall 4 … 9 m away (a plane tilted 42°), seen by the housings 25 cm apart at 640 × 512,
    // texture detail down to about 2 px.
    accept(&Case {
        name: "housings 640 x 512: a far tilted wall",
        rig: scaled(PORT_PER_CAMERA, 2),
        scene: scene(vec![plane_at(5.5, 0.9, noise(51, 0.15))]),
    });
}

#[test]
fn defaults_near_scene() {
    // A seabed 0.45 m below the shared-port pair with a stone on it: the frustums overlap from
    // about 0.25 m.
    accept(&Case {
        name: "shared port: a near seabed and a stone",
        rig: rig(SHARED_PORT_PAIR),
        scene: scene(vec![
            bounded_plane(0.5, 0.1, 61, 0.04, [-5.0, 5.0]),
            sphere([0.1, 0.02, 0.43], 0.05, 62),
        ]),
    });
}

#[test]
fn cli_without_options_writes_the_chosen_sampling() {
    let dir = tempfile::tempdir().unwrap();
    let rig_path = dir.path().join("rig.json");
    let json = SHARED_PORT_PAIR.replace(
        "\"width\": 320, \"height\": 256, \"fx\": 260, \"fy\": 260, \"cx\": 159.5, \"cy\": 127.5",
        "\"width\": 160, \"height\": 128, \"fx\": 130, \"fy\": 130, \"cx\": 79.5, \"cy\": 63.5",
    );
    std::fs::write(&rig_path, &json).unwrap();
    let small = rig(&json);
    let rendered = render_all(
        &small,
        &scene(vec![seabed(1.6, 3), sphere([0.1, 0.05, 1.3], 0.15, 5)]),
        1.0,
    );
    let images = dir.path().join("shots");
    for (k, camera) in small.cameras().iter().enumerate() {
        let folder = images.join(&camera.name);
        std::fs::create_dir_all(&folder).unwrap();
        image::GrayImage::from_raw(160, 128, rendered.images[k].to_u8())
            .unwrap()
            .save(folder.join("frame_000.png"))
            .unwrap();
    }
    let result = dir.path().join("result");
    let out = Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args([
            "stereo",
            "--rig",
            rig_path.to_str().unwrap(),
            "--images",
            images.to_str().unwrap(),
            "--output",
            result.to_str().unwrap(),
            "--device",
            "cpu",
            "--quiet",
        ])
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("depth range") && stderr.contains("(found: a coarse sweep"),
        "{stderr}"
    );
    assert!(
        stderr.contains("hypotheses uniform in 1/z (rule:"),
        "{stderr}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(result.join("summary.json")).unwrap())
            .unwrap();
    let range = summary["depth_range_m"].as_array().unwrap();
    let (min, max) = (range[0].as_f64().unwrap(), range[1].as_f64().unwrap());
    // The true depths of the seabed (1.6 ± 0.05 m, tilted port) and the rock's front (1.15 m).
    assert!(
        min < 1.1 && min > 0.5 && max > 1.8 && max < 4.0,
        "{min}:{max}"
    );
    let hypotheses = summary["hypotheses"].as_u64().unwrap();
    assert!((16..=512).contains(&hypotheses), "{hypotheses}");
    assert_eq!(summary["hypotheses_chosen"], "step rule");
    let frame = &summary["frames"][0];
    assert_eq!(frame["hypotheses"], summary["hypotheses"]);
    assert_eq!(frame["sampling"]["depth_range"]["how"], "found");
    assert_eq!(frame["sampling"]["hypotheses"]["how"], "step rule");
    let step = frame["sampling"]["hypotheses"]["rule"]["largest_step_px"]
        .as_f64()
        .unwrap();
    assert!(step <= STEP_PX && step > 0.5, "{step}");
}

/// The housings scene at 1280 × 1024 (f = 1000 px) with no options, timed: the step rule's count
/// at the size of issue 39's scenes. `cargo test --release --test stereo_auto -- --ignored
/// --nocapture full_size`.
#[test]
#[ignore]
fn full_size_housings_with_no_options() {
    accept(&Case {
        name: "housings 1280 x 1024: plane and sphere",
        rig: scaled(PORT_PER_CAMERA, 4),
        scene: scene(vec![
            plane_at(1.5, 0.35, noise(41, 0.03)),
            sphere([0.1, 0.02, 1.1], 0.22, 42),
        ]),
    });
}

/// The old defaults (128 hypotheses over 0.3 … 3 m) against no options (range found, the step
/// rule), in turns, twice, on two 320 × 256 scenes: accuracy and seconds. `cargo test --release
/// --test stereo_auto -- --ignored --nocapture old_defaults`.
#[test]
#[ignore]
fn old_defaults_in_turns() {
    let old = StereoOptions {
        depth_range: Some((0.3, 3.0)),
        hypotheses: Some(128),
        ..StereoOptions::default()
    };
    for (name, rig, surfaces) in [
        (
            "shared port: seabed and a rock",
            rig(SHARED_PORT_PAIR),
            vec![seabed(1.6, 3), sphere([0.12, 0.05, 1.3], 0.15, 12)],
        ),
        (
            "housings: plane and sphere",
            rig(PORT_PER_CAMERA),
            vec![
                plane_at(1.5, 0.35, noise(41, 0.12)),
                sphere([0.1, 0.02, 1.1], 0.22, 42),
            ],
        ),
    ] {
        let rendered = render_all(&rig, &scene(surfaces), 2.0);
        let seen = seen_by_another(&rig, 0, &rendered);
        for turn in 0..2 {
            for (label, options) in [
                ("old defaults", &old),
                ("no options", &StereoOptions::default()),
            ] {
                let started = std::time::Instant::now();
                let map = stereo(&rig, &rendered.images, options).unwrap();
                let seconds = started.elapsed().as_secs_f64();
                let a = accuracy(&map, &rendered.depths[0], &seen);
                eprintln!(
                    "{name}, turn {turn}, {label}: {} hypotheses over {:.3}:{:.3} m, {:.1} % with a point, median {:.3} %, {:.1} % within 2 %; {seconds:.2} s",
                    map.hypotheses,
                    map.depth_range.0,
                    map.depth_range.1,
                    100.0 * a.valid_fraction,
                    100.0 * a.median,
                    100.0 * a.within_2
                );
            }
        }
    }
}

/// Where the full-size housings scene loses its pixels, for each window radius in `FP_RADII`
/// (default "3,6"): one run with every filter off (no consistency check, no edge or occlusion
/// margin, confidence 0) splits the seen pixels into no depth (untextured by the test's own
/// window statistics, or no vote / end of range), a low confidence, and wrong (> 2 %); runs with
/// the consistency check alone, then with the depth-edge margin, then the defaults (with the
/// occlusion margin) give what each of them takes of the rest; then the defaults with each
/// consistency tolerance in `FP_CONSISTENCY` (pixels, none by default). Measured (docs/stereo.md):
/// radius 3 with 1 px lost 9.0 % to the occlusion margin (0.1 % wrong), 85.1 % kept a point;
/// radius 6 kept 91.5 % but 9.4 % gross where unseen; radius 3 with 2 px (now the default at
/// f = 1000 px) kept 91.6 %. `FP_RADII=3,6 FP_CONSISTENCY=2 cargo test --release --test
/// stereo_auto -- --ignored --nocapture rejections_at_full_size`.
#[test]
#[ignore]
fn rejections_at_full_size() {
    let rig = scaled(PORT_PER_CAMERA, 4);
    let scene = scene(vec![
        plane_at(1.5, 0.35, noise(41, 0.03)),
        sphere([0.1, 0.02, 1.1], 0.22, 42),
    ]);
    let rendered = render_all(&rig, &scene, 2.0);
    let seen = seen_by_another(&rig, 0, &rendered);
    let truth = &rendered.depths[0];
    let image = &rendered.images[0];
    let (w, h) = (image.width as usize, image.height as usize);
    let radii: Vec<usize> = std::env::var("FP_RADII")
        .unwrap_or_else(|_| "3,6".into())
        .split(',')
        .map(|r| r.trim().parse().unwrap())
        .collect();
    let mut range = None;
    for r in radii {
        // The test's own texture measure: the grey standard deviation of the (2r + 1)² window.
        let untextured = |i: usize| {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            let (mut n, mut s, mut s2) = (0f64, 0f64, 0f64);
            for yy in (y - r as i64).max(0)..=(y + r as i64).min(h as i64 - 1) {
                for xx in (x - r as i64).max(0)..=(x + r as i64).min(w as i64 - 1) {
                    let g = f64::from(image.pixels[yy as usize * w + xx as usize]);
                    n += 1.0;
                    s += g;
                    s2 += g * g;
                }
            }
            (s2 / n - (s / n).powi(2)).max(0.0).sqrt() < 0.01
        };
        let defaults = StereoOptions {
            window_radius: r,
            depth_range: range,
            ..StereoOptions::default()
        };
        let started = std::time::Instant::now();
        let full = stereo(&rig, &rendered.images, &defaults).unwrap();
        let full_s = started.elapsed().as_secs_f64();
        range = Some(full.depth_range);
        let raw = stereo(
            &rig,
            &rendered.images,
            &StereoOptions {
                check_cameras: Some(0),
                edge_jump: None,
                occlusion_margin: 0,
                min_confidence: 0.0,
                ..defaults.clone()
            },
        )
        .unwrap();
        // The filters one by one: the consistency check alone, then with the depth-edge margin;
        // the defaults add the occlusion margin.
        let checked = stereo(
            &rig,
            &rendered.images,
            &StereoOptions {
                edge_jump: None,
                occlusion_margin: 0,
                ..defaults.clone()
            },
        )
        .unwrap();
        let edged = stereo(
            &rig,
            &rendered.images,
            &StereoOptions {
                occlusion_margin: 0,
                ..defaults.clone()
            },
        )
        .unwrap();
        let (mut seen_n, mut flat, mut none, mut low, mut wrong, mut kept_raw) = (0, 0, 0, 0, 0, 0);
        let (mut dropped, mut dropped_wrong) = (0, 0);
        // Of the confident raw points: dropped by the check, by the edge margin, by the
        // occlusion margin (each with how many of them were wrong).
        let mut by = [[0usize; 2]; 3];
        for i in 0..w * h {
            if !seen[i] {
                continue;
            }
            seen_n += 1;
            let z = f64::from(raw.depth[i]);
            if !z.is_finite() {
                if untextured(i) {
                    flat += 1;
                } else {
                    none += 1;
                }
                continue;
            }
            let bad = ((z - f64::from(truth[i])) / f64::from(truth[i])).abs() > 0.02;
            if f64::from(raw.confidence[i]) < 0.25 {
                low += 1;
                continue;
            }
            if bad {
                wrong += 1;
            }
            kept_raw += 1;
            if !full.depth[i].is_finite() {
                dropped += 1;
                if bad {
                    dropped_wrong += 1;
                }
                let stage = if !checked.depth[i].is_finite() {
                    0
                } else if !edged.depth[i].is_finite() {
                    1
                } else {
                    2
                };
                by[stage][0] += 1;
                by[stage][1] += usize::from(bad);
            }
        }
        let pct = |n: usize| 100.0 * n as f64 / seen_n as f64;
        let a = accuracy(&full, truth, &seen);
        eprintln!(
            "r = {r}: {seen_n} seen; no depth: {:.1} % untextured, {:.1} % no vote / end of range; confidence < 0.25: {:.1} %; confident {:.1} % ({:.1} % wrong > 2 %), of which the consistency check and margins drop {:.1} % ({:.1} % wrong); defaults: {:.1} % with a point, median {:.3} %, {:.1} % within 2 %, periphery median {:.3} %, {:.1} % of {} unseen points gross; {full_s:.0} s",
            pct(flat),
            pct(none),
            pct(low),
            pct(kept_raw),
            pct(wrong),
            pct(dropped),
            pct(dropped_wrong),
            100.0 * a.valid_fraction,
            100.0 * a.median,
            100.0 * a.within_2,
            100.0 * a.periphery_median,
            100.0 * a.unseen_gross,
            a.unseen_points,
        );
        eprintln!(
            "r = {r}: dropped by the consistency check {:.1} % ({:.1} % wrong), the depth-edge margin {:.1} % ({:.1} % wrong), the occlusion margin {:.1} % ({:.1} % wrong)",
            pct(by[0][0]),
            pct(by[0][1]),
            pct(by[1][0]),
            pct(by[1][1]),
            pct(by[2][0]),
            pct(by[2][1]),
        );
        // Other consistency tolerances (pixels), the defaults otherwise: FP_CONSISTENCY="1.5,2".
        for tol in std::env::var("FP_CONSISTENCY")
            .unwrap_or_default()
            .split(',')
            .filter_map(|t| t.trim().parse::<f64>().ok())
        {
            let map = stereo(
                &rig,
                &rendered.images,
                &StereoOptions {
                    consistency_px: Some(tol),
                    ..defaults.clone()
                },
            )
            .unwrap();
            let a = accuracy(&map, truth, &seen);
            eprintln!(
                "r = {r}, consistency within {tol} px: {:.1} % with a point, median {:.3} %, {:.1} % within 2 %, periphery median {:.3} %, {:.1} % of {} unseen points gross",
                100.0 * a.valid_fraction,
                100.0 * a.median,
                100.0 * a.within_2,
                100.0 * a.periphery_median,
                100.0 * a.unseen_gross,
                a.unseen_points,
            );
        }
    }
}

/// The consistency tolerance's rule on two more scenes at 1280 × 1024 that it was not chosen on
/// (texture detail scaled with the resolution): the defaults (τ = 2 px at f = 1000 px) against
/// τ = 1 px, on the same images; issue 39's levels asserted for the defaults. Measured: the far
/// wall 99.0 % -> 99.2 % with a point (median 0.063 % both), the shared-port seabed 95.3 % ->
/// 97.6 % (median 0.052 -> 0.053 %), all within 2 %, no gross point where no other camera sees.
/// `cargo test --release --test stereo_auto -- --ignored --nocapture
/// tolerance_on_other_full_size_scenes`.
#[test]
#[ignore]
fn tolerance_on_other_full_size_scenes() {
    let mut seabed = seabed(1.6, 3);
    seabed.texture = noise(103, 0.15 / 4.0);
    let cases = [
        (
            "housings 1280 x 1024: a far tilted wall",
            scaled(PORT_PER_CAMERA, 4),
            scene(vec![plane_at(5.5, 0.9, noise(51, 0.075))]),
        ),
        (
            "shared port 1280 x 1024: seabed and a rock",
            scaled(SHARED_PORT_PAIR, 4),
            scene(vec![seabed, sphere([0.12, 0.05, 1.3], 0.15, 12)]),
        ),
    ];
    for (name, rig, scene) in cases {
        let rendered = render_all(&rig, &scene, 2.0);
        let seen = seen_by_another(&rig, 0, &rendered);
        let mut range = None;
        for tau in [None, Some(1.0)] {
            let map = stereo(
                &rig,
                &rendered.images,
                &StereoOptions {
                    depth_range: range,
                    consistency_px: tau,
                    ..StereoOptions::default()
                },
            )
            .unwrap();
            range = Some(map.depth_range);
            let a = accuracy(&map, &rendered.depths[0], &seen);
            eprintln!(
                "{name}, τ = {} px: {} seen pixels, {:.1} % with a point, median {:.3} %, {:.1} % within 2 %, periphery median {:.3} %, {:.1} % of {} unseen points gross",
                map.consistency_px,
                a.seen,
                100.0 * a.valid_fraction,
                100.0 * a.median,
                100.0 * a.within_2,
                100.0 * a.periphery_median,
                100.0 * a.unseen_gross,
                a.unseen_points
            );
            if tau.is_none() {
                // Issue 39's levels, with the rule's tolerance.
                assert!(a.valid_fraction >= 0.85, "{name}: {a:?}");
                assert!(a.median <= 0.003, "{name}: {a:?}");
                assert!(a.within_2 >= 0.93, "{name}: {a:?}");
                assert!(a.periphery_median <= 0.005, "{name}: {a:?}");
                assert!(a.unseen_gross <= 0.05, "{name}: {a:?}");
            }
        }
    }
}
