//! Dense stereo on rendered scenes against the renderer's exact depth (tests/stereo_common): an
//! exact noise-free plane to the sampling limit, the issue's acceptance levels on a shared port,
//! a port per camera and three cameras above a bare water surface, the pinhole approximation's
//! failure in the periphery, bad input, and the CLI end to end. Release mode: `cargo test
//! --release --test stereo`.

mod stereo_common;

use std::path::Path;
use std::process::Command;

use flatport::render::GreyImage;
use flatport::stereo::{StereoError, StereoOptions, stereo};
use stereo_common::*;

fn env_f64(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The options of the tests: the defaults with the scene's depth range (the tuning run reads
/// overrides from the environment).
fn options(range: (f64, f64)) -> StereoOptions {
    let d = StereoOptions::default();
    StereoOptions {
        reference: d.reference,
        depth_range: Some(range),
        hypotheses: std::env::var("FP_HYP")
            .ok()
            .and_then(|v| v.parse().ok())
            .or(d.hypotheses),
        window_radius: env_f64("FP_R", d.window_radius as f64) as usize,
        penalty_step: env_f64("FP_P1", d.penalty_step),
        penalty_jump: env_f64("FP_P2", d.penalty_jump),
        penalty_gradient: env_f64("FP_G", d.penalty_gradient),
        paths: env_f64("FP_PATHS", d.paths as f64) as usize,
        min_texture: env_f64("FP_TEX", d.min_texture),
        full_distinctness: env_f64("FP_DIST", d.full_distinctness),
        min_confidence: env_f64("FP_CONF", d.min_confidence),
        consistency_px: std::env::var("FP_LR")
            .ok()
            .and_then(|v| v.parse().ok())
            .or(d.consistency_px),
        edge_jump: match env_f64("FP_JUMP", d.edge_jump.unwrap_or(0.0)) {
            j if j > 0.0 => Some(j),
            _ => None,
        },
        occlusion_margin: env_f64("FP_MARGIN", d.occlusion_margin as f64) as usize,
        check_cameras: std::env::var("FP_CHECK").ok().and_then(|v| v.parse().ok()),
        projection: match std::env::var("FP_PROJECTION").as_deref() {
            Ok("exact") => flatport::stereo::Projection::Exact,
            _ => d.projection,
        },
    }
}

/// One acceptance scene: its rig, surfaces, depth range.
struct Case {
    name: &'static str,
    rig: flatport::model::Rig,
    scene: flatport::render::TexturedScene,
    range: (f64, f64),
}

fn shared_port_seabed() -> Case {
    Case {
        name: "shared port: seabed and a rock",
        rig: rig(SHARED_PORT_PAIR),
        scene: scene(vec![seabed(1.6, 3), sphere([0.12, 0.05, 1.3], 0.15, 12)]),
        range: (0.8, 2.5),
    }
}

fn port_per_camera_step() -> Case {
    let mut near = plane_at(1.45, 0.0, noise(21, 0.12));
    if let flatport::render::Shape::Plane { extent, .. } = &mut near.shape {
        *extent = Some(flatport::render::Extent {
            s: [-3.0, 0.1],
            t: [-3.0, 3.0],
        });
    }
    Case {
        name: "port per camera: a depth step",
        rig: rig(PORT_PER_CAMERA),
        scene: scene(vec![near, plane_at(1.9, 0.08, noise(22, 0.15))]),
        range: (1.0, 2.6),
    }
}

fn above_water_trio() -> Case {
    Case {
        name: "three cameras above water: seabed and a rock",
        rig: rig(ABOVE_WATER_TRIO),
        scene: scene(vec![seabed(1.5, 5), sphere([0.1, 0.08, 1.3], 0.12, 32)]),
        range: (0.9, 2.2),
    }
}

fn run_case(case: &Case) -> (Accuracy, flatport::stereo::DepthMap, Rendered) {
    let rendered = render_all(&case.rig, &case.scene, 2.0);
    let started = std::time::Instant::now();
    let map = stereo(&case.rig, &rendered.images, &options(case.range)).unwrap();
    let seen = seen_by_another(&case.rig, 0, &rendered);
    let a = accuracy(&map, &rendered.depths[0], &seen);
    eprintln!(
        "{}: {} seen pixels, {:.1} % with a point, median {:.3} %, {:.1} % within 2 %, periphery median {:.3} % ({} points), {} points unseen, {:.1} % of them gross; {:.2} s {:?}",
        case.name,
        a.seen,
        100.0 * a.valid_fraction,
        100.0 * a.median,
        100.0 * a.within_2,
        100.0 * a.periphery_median,
        a.periphery_points,
        a.unseen_points,
        100.0 * a.unseen_gross,
        started.elapsed().as_secs_f64(),
        map.stage_seconds
    );
    (a, map, rendered)
}

fn assert_acceptance(case: &Case, a: &Accuracy) {
    let name = case.name;
    assert!(
        a.seen > 20_000,
        "{name}: only {} pixels seen by another camera",
        a.seen
    );
    assert!(a.valid_fraction >= 0.85, "{name}: {a:?}");
    assert!(a.median <= 0.003, "{name}: {a:?}");
    assert!(a.within_2 >= 0.93, "{name}: {a:?}");
    assert!(a.periphery_points > 2000, "{name}: {a:?}");
    assert!(a.periphery_median <= 0.005, "{name}: {a:?}");
    assert!(a.unseen_gross <= 0.05, "{name}: {a:?}");
}

#[test]
fn a_noise_free_plane_is_recovered_to_a_fraction_of_a_hypothesis_step() {
    // A textured plane 1.2 m in front of the left camera, seen through the tilted shared port
    // with distortion, no noise. One hypothesis step at z is Δz = z²·Δq with Δq the spacing of
    // the inverse depths; the sub-hypothesis parabola must land within a fraction of it.
    let rig = rig(SHARED_PORT_PAIR);
    let case_scene = scene(vec![plane_at(1.2, 0.0, noise(5, 0.12))]);
    let rendered = render_all(&rig, &case_scene, 0.0);
    let range = (0.8, 2.0);
    let o = options(range);
    let map = stereo(&rig, &rendered.images, &o).unwrap();
    let truth = &rendered.depths[0];
    let seen = seen_by_another(&rig, 0, &rendered);
    let step_q = (1.0 / range.0 - 1.0 / range.1) / (map.hypotheses - 1) as f64;
    let mut errors_in_steps: Vec<f64> = (0..truth.len())
        .filter(|&i| seen[i] && map.depth[i].is_finite())
        .map(|i| {
            let z = f64::from(truth[i]);
            let step_z = z * z * step_q;
            (f64::from(map.depth[i]) - z).abs() / step_z
        })
        .collect();
    errors_in_steps.sort_by(f64::total_cmp);
    let seen_count = seen.iter().filter(|s| **s).count();
    let n = errors_in_steps.len();
    let (median, p95) = (errors_in_steps[n / 2], errors_in_steps[n * 95 / 100]);
    eprintln!(
        "noise-free plane at 1.2 m: {n} of {seen_count} seen pixels with a point; error median {median:.4} steps, 95th percentile {p95:.4} steps (a step is {:.2} mm here)",
        1.2 * 1.2 * step_q * 1000.0
    );
    assert!(n as f64 >= 0.95 * seen_count as f64, "{n} of {seen_count}");
    // The sampling limit: a tenth of a step at the median, a quarter for 95 % of the pixels.
    assert!(median <= 0.1, "median {median} steps");
    assert!(p95 <= 0.25, "95th percentile {p95} steps");
}

#[test]
fn acceptance_shared_port_seabed_and_rock() {
    let case = shared_port_seabed();
    let (a, _, _) = run_case(&case);
    assert_acceptance(&case, &a);
}

#[test]
fn acceptance_port_per_camera_depth_step() {
    let case = port_per_camera_step();
    let (a, _, _) = run_case(&case);
    assert_acceptance(&case, &a);
}

#[test]
fn acceptance_three_cameras_above_a_bare_water_surface() {
    let case = above_water_trio();
    let (a, _, _) = run_case(&case);
    assert_acceptance(&case, &a);
}

#[test]
fn a_pinhole_approximation_is_worse_in_the_periphery() {
    // The same images matched as if the cameras were pinholes with the in-water focal length
    // f·μ_w/μ_air (refraction's geometry ignored). Parallel cameras behind a port that faces
    // them squarely here, the case the approximation is made for (a convergent or tilted camera
    // meets the port obliquely even at its image centre, and the approximation fails there too): near the image centre the rays cross the port almost
    // at right angles and the approximation holds to within a few per cent; toward the edges the
    // incidence grows and so does its error. The exact model holds everywhere.
    let parallel_square = SHARED_PORT_PAIR
        .replace("\"normal\": [0.1, 0.1, 1.0]", "\"normal\": [0.0, 0.0, 1.0]")
        .replace(
            "\"rotation\": [[0.9975640502598242, 0.0, 0.0697564737441253], [0.0, 1.0, 0.0], [-0.0697564737441253, 0.0, 0.9975640502598242]]",
            "\"rotation\": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]",
        )
        .replace(
            "\"translation\": [-0.19951281005196484, 0.0, 0.013951294748825061]",
            "\"translation\": [-0.2, 0.0, 0.0]",
        );
    assert!(parallel_square.contains("[0, 0, 1]]") && parallel_square.contains("[-0.2, 0.0, 0.0]"));
    let case = Case {
        name: "parallel pair, square port: seabed and a rock",
        rig: rig(&parallel_square),
        ..shared_port_seabed()
    };
    let (exact, _, rendered) = run_case(&case);
    let pinhole = pinhole_rig(&case.rig);
    let map = stereo(&pinhole, &rendered.images, &options(case.range)).unwrap();
    let seen = seen_by_another(&case.rig, 0, &rendered);
    let approx = accuracy(&map, &rendered.depths[0], &seen);
    eprintln!(
        "pinhole approximation: {:.1} % with a point, median {:.3} %, {:.1} % within 2 %, centre median {:.3} %, periphery median {:.3} % ({} points); exact: centre {:.3} %, periphery {:.3} %",
        100.0 * approx.valid_fraction,
        100.0 * approx.median,
        100.0 * approx.within_2,
        100.0 * approx.centre_median,
        100.0 * approx.periphery_median,
        approx.periphery_points,
        100.0 * exact.centre_median,
        100.0 * exact.periphery_median
    );
    assert!(exact.periphery_median <= 0.005, "{exact:?}");
    assert!(
        approx.periphery_median >= 3.0 * exact.periphery_median
            && approx.periphery_median >= 1.5 * approx.centre_median,
        "pinhole {approx:?} against exact {exact:?}"
    );
}

#[test]
fn bad_input_is_refused_with_what_is_wrong() {
    let rig = rig(SHARED_PORT_PAIR);
    let image = |w: u32, h: u32| GreyImage {
        width: w,
        height: h,
        pixels: vec![0.5; (w * h) as usize],
    };
    let good = vec![image(320, 256), image(320, 256)];
    let o = options((0.8, 2.5));
    let error = stereo(&rig, &[image(320, 256), image(300, 256)], &o).unwrap_err();
    assert!(matches!(error, StereoError::ImageSize { .. }));
    let text = error.to_string();
    assert!(
        text.contains("'right'") && text.contains("300") && text.contains("320"),
        "{text}"
    );
    let error = stereo(&rig, &good[..1], &o).unwrap_err().to_string();
    assert!(
        error.contains("1 images for the rig's 2 cameras"),
        "{error}"
    );
    // Depth ranges behind the camera, in the air or glass of the port, upside down.
    for (range, says) in [
        ((-0.5, 2.0), "behind the camera"),
        ((0.03, 2.0), "in the air or in the port's layers"),
        ((0.06, 2.0), "in the air or in the port's layers"),
        ((1.5, 1.0), "beyond the near end"),
    ] {
        let error = stereo(&rig, &good, &options(range)).unwrap_err();
        let text = error.to_string();
        assert!(matches!(error, StereoError::DepthRange { .. }), "{text}");
        assert!(
            text.contains(says) && text.contains(&format!("{}:{}", range.0, range.1)),
            "{text}"
        );
    }
    let mut nan = image(320, 256);
    nan.pixels[3 * 320 + 7] = f32::NAN;
    let error = stereo(&rig, &[good[0].clone(), nan], &o)
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("'right'") && error.contains("(7, 3)"),
        "{error}"
    );
}

// ---- The CLI end to end ----------------------------------------------------------------------

fn flatport(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("flatport runs")
}

/// A small scene file: the shared-port pair at 160 × 128 looking at a seabed and a rock, two
/// frames.
fn small_scene_file(dir: &Path) -> std::path::PathBuf {
    let rig = SHARED_PORT_PAIR.replace(
        "\"width\": 320, \"height\": 256, \"fx\": 260, \"fy\": 260, \"cx\": 159.5, \"cy\": 127.5",
        "\"width\": 160, \"height\": 128, \"fx\": 130, \"fy\": 130, \"cx\": 79.5, \"cy\": 63.5",
    );
    let text = format!(
        r#"{{"rig": {rig},
  "frames": [{{"offset": [0, 0, 0]}}, {{"offset": [0.02, 0, 0]}}],
  "surfaces": [
    {{"height_field": {{"origin": [0, 0, 1.6], "normal": [0, 0, -1],
       "relief": {{"amplitude": 0.05, "wavelength": 0.7, "seed": 3}},
       "texture": {{"noise": {{"scale": 0.3, "octaves": 4, "seed": 4}}}}}}}},
    {{"sphere": {{"centre": [0.1, 0.05, 1.3], "radius": 0.15,
       "texture": {{"noise": {{"scale": 0.12, "octaves": 4, "seed": 5}}}}}}}}
  ]}}"#
    );
    let path = dir.join("scene.json");
    std::fs::write(&path, text).unwrap();
    path
}

/// Shape and data of a little-endian float32 .npy file, read here by hand (the header as numpy
/// writes it), not by the crate's own reader.
fn read_f32_npy(path: &Path) -> (Vec<usize>, Vec<f32>) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00", "{}", path.display());
    let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(&bytes[10..10 + header_len]).unwrap();
    assert!(header.contains("'descr': '<f4'"), "{header}");
    assert!(header.contains("'fortran_order': False"), "{header}");
    assert_eq!((10 + header_len) % 64, 0, "data aligned to 64 bytes");
    let shape_text = header
        .split("'shape': (")
        .nth(1)
        .unwrap()
        .split(')')
        .next()
        .unwrap();
    let shape: Vec<usize> = shape_text
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.trim().parse().unwrap())
        .collect();
    let data: Vec<f32> = bytes[10 + header_len..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(
        data.len(),
        shape.iter().product::<usize>(),
        "{}",
        path.display()
    );
    (shape, data)
}

fn files_under(dir: &Path) -> Vec<String> {
    let mut names = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for entry in entries.flatten() {
            let path = entry.path();
            if path.is_dir() {
                names.extend(files_under(&path));
            } else {
                names.push(path.display().to_string());
            }
        }
    }
    names.sort();
    names
}

#[test]
fn cli_render_then_stereo_writes_every_output() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene_file(dir.path());
    let shots = dir.path().join("shots");
    let out = flatport(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--noise",
        "1",
        "--device",
        "cpu",
        "-o",
        shots.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for name in [
        "left/frame_000.png",
        "left/frame_001.png",
        "right/depth_001.npy",
        "rig.json",
    ] {
        assert!(shots.join(name).is_file(), "{name}");
    }
    let (shape, depth) = read_f32_npy(&shots.join("left/depth_000.npy"));
    assert_eq!(shape, vec![128, 160]);
    assert!(depth.iter().filter(|d| d.is_finite()).count() > 15_000);

    // The same outputs from both devices (the GPU's on lavapipe here), in the same format.
    let mut listings = Vec::new();
    for device in ["cpu", "gpu"] {
        let result = dir.path().join(format!("result-{device}"));
        let out = flatport(&[
            "stereo",
            "--device",
            device,
            "--rig",
            shots.join("rig.json").to_str().unwrap(),
            "--images",
            shots.to_str().unwrap(),
            "--output",
            result.to_str().unwrap(),
            "--depth",
            "0.8:2.5",
            "--hypotheses",
            "64",
            "--quiet",
        ]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{stderr}");
        assert!(stderr.contains(&format!("device: {device}")), "{stderr}");
        for frame in ["frame_000", "frame_001"] {
            let folder = result.join(frame);
            let (shape, points) = read_f32_npy(&folder.join("points.npy"));
            assert_eq!(shape, vec![128, 160, 3]);
            let (shape, depth) = read_f32_npy(&folder.join("depth.npy"));
            assert_eq!(shape, vec![128, 160]);
            let (shape, confidence) = read_f32_npy(&folder.join("confidence.npy"));
            assert_eq!(shape, vec![128, 160]);
            let valid = depth.iter().filter(|d| d.is_finite()).count();
            assert!(valid > 5000, "{frame}: {valid} depths");
            for i in 0..depth.len() {
                assert_eq!(depth[i].is_finite(), points[3 * i].is_finite(), "pixel {i}");
                assert!((0.0..=1.0).contains(&confidence[i]));
                if depth[i].is_finite() {
                    assert!(depth[i] > 0.8 && depth[i] < 2.5);
                }
            }
            // The PLY: its header, then one 15-byte vertex per point.
            let bytes = std::fs::read(folder.join("cloud.ply")).unwrap();
            let end = b"end_header\n";
            let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
            let header = std::str::from_utf8(&bytes[..at]).unwrap();
            assert!(
                header.starts_with("ply\nformat binary_little_endian 1.0\n"),
                "{header}"
            );
            assert!(
                header.contains(&format!("element vertex {valid}\n")),
                "{header}"
            );
            assert!(header.contains(
            "property float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
        ), "{header}");
            assert_eq!(bytes.len() - at, valid * 15);
            // The first vertex is the first pixel with a point.
            let first = depth.iter().position(|d| d.is_finite()).unwrap();
            let x = f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
            assert_eq!(x, points[3 * first]);
            let (w, h) = image::image_dimensions(folder.join("depth.png")).unwrap();
            assert!(w > 160 && h >= 128);
        }
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(result.join("summary.json")).unwrap())
                .unwrap();
        let frames = summary["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 2);
        for f in frames {
            let fraction = f["valid_fraction"].as_f64().unwrap();
            assert!(fraction > 0.3 && fraction <= 1.0, "{f}");
            assert!(f["seconds"].as_f64().unwrap() > 0.0);
            assert_eq!(f["hypotheses"], 64);
            assert!(f["device"].as_str().unwrap().starts_with(device));
        }
        assert_eq!(summary["reference"], "left");
        let prefix = result.display().to_string();
        listings.push(
            files_under(&result)
                .iter()
                .map(|f| f.trim_start_matches(&prefix).to_string())
                .collect::<Vec<_>>(),
        );
    }
    assert_eq!(listings[0], listings[1], "the devices write the same files");
}

#[test]
fn cli_bad_input_names_the_problem_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene_file(dir.path());
    let shots = dir.path().join("shots");
    let out = flatport(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--device",
        "cpu",
        "--supersample",
        "1",
        "-o",
        shots.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rig = shots.join("rig.json");
    let copy = |name: &str| {
        let to = dir.path().join(name);
        let _ = std::fs::remove_dir_all(&to);
        for camera in ["left", "right"] {
            std::fs::create_dir_all(to.join(camera)).unwrap();
            for f in std::fs::read_dir(shots.join(camera)).unwrap().flatten() {
                std::fs::copy(f.path(), to.join(camera).join(f.file_name())).unwrap();
            }
        }
        to
    };
    let stereo_into = |images: &Path, extra: &[&str]| {
        let result = dir.path().join("result");
        let _ = std::fs::remove_dir_all(&result);
        let mut args = vec![
            "stereo",
            "--rig",
            rig.to_str().unwrap(),
            "--images",
            images.to_str().unwrap(),
            "--output",
            result.to_str().unwrap(),
            "--hypotheses",
            "16",
            "--quiet",
        ];
        args.extend_from_slice(extra);
        let out = flatport(&args);
        assert!(!out.status.success(), "{extra:?} should fail");
        assert!(
            !result.exists(),
            "nothing written: {:?}",
            files_under(&result)
        );
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    // A missing camera folder.
    let images = copy("missing");
    std::fs::remove_dir_all(images.join("right")).unwrap();
    let error = stereo_into(&images, &["--depth", "0.8:2.5"]);
    assert!(
        error.contains("right") && error.contains("missing"),
        "{error}"
    );
    // Frames that do not match: one camera has a frame fewer.
    let images = copy("unmatched");
    std::fs::remove_file(images.join("right/frame_000.png")).unwrap();
    let error = stereo_into(&images, &["--depth", "0.8:2.5"]);
    assert!(
        error.contains("frames do not match") && error.contains("left 2, right 1"),
        "{error}"
    );
    // ... or the same count under other names.
    let images = copy("renamed");
    std::fs::rename(
        images.join("right/frame_000.png"),
        images.join("right/frame_002.png"),
    )
    .unwrap();
    let error = stereo_into(&images, &["--depth", "0.8:2.5"]);
    assert!(
        error.contains("frames do not match") && error.contains("frame_001.png"),
        "{error}"
    );
    // An image of the wrong size.
    let images = copy("size");
    let small = image::GrayImage::new(100, 128);
    small.save(images.join("right/frame_001.png")).unwrap();
    let error = stereo_into(&images, &["--depth", "0.8:2.5"]);
    assert!(
        error.contains("right/frame_001.png")
            && error.contains("100x128")
            && error.contains("160x128"),
        "{error}"
    );
    // ... or every image of a camera at a size the rig does not give it.
    small.save(images.join("right/frame_000.png")).unwrap();
    let error = stereo_into(&images, &["--depth", "0.8:2.5"]);
    assert!(
        error.contains("camera 'right'")
            && error.contains("100 × 128")
            && error.contains("160 × 128"),
        "{error}"
    );
    // An unreadable file.
    let images = copy("unreadable");
    std::fs::write(images.join("left/frame_001.png"), b"not a png at all").unwrap();
    let error = stereo_into(&images, &["--depth", "0.8:2.5"]);
    assert!(error.contains("left/frame_001.png"), "{error}");
    // Depth ranges in the port's glass, behind the camera, malformed.
    let images = copy("range");
    let error = stereo_into(&images, &["--depth", "0.04:2.5"]);
    assert!(
        error.contains("0.04:2.5") && error.contains("air or in the port's layers"),
        "{error}"
    );
    let error = stereo_into(&images, &["--depth", "-1:2.5"]);
    assert!(error.contains("behind the camera"), "{error}");
    let error = stereo_into(&images, &["--depth", "1:x"]);
    assert!(error.contains("'x' is not a finite number"), "{error}");
    // An unknown reference camera, and an adapter that is not there.
    let error = stereo_into(&images, &["--reference", "middle"]);
    assert!(
        error.contains("--reference middle") && error.contains("left, right"),
        "{error}"
    );
    let error = stereo_into(
        &images,
        &["--device", "gpu", "--adapter", "no-such-adapter"],
    );
    assert!(
        error.contains("--device gpu") && error.contains("no-such-adapter"),
        "{error}"
    );
}

#[test]
fn cli_render_refuses_a_bad_scene_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bad.json");
    std::fs::write(
        &scene,
        r#"{"rig": "nowhere.json", "surfaces": [{"sphere": {"centre": [0, 0, 1], "radius": 0.2, "texture": {"noise": {"scale": 0.1, "octaves": 3, "colour": 2}}}}]}"#,
    )
    .unwrap();
    let shots = dir.path().join("shots");
    let out = flatport(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "-o",
        shots.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("surfaces[0].sphere.texture.noise") && stderr.contains("colour"),
        "{stderr}"
    );
    assert!(!shots.exists());
    // A scene without a rig, and no --rig.
    std::fs::write(
        &scene,
        r#"{"surfaces": [{"sphere": {"centre": [0, 0, 1], "radius": 0.2, "texture": {"noise": {"scale": 0.1}}}}]}"#,
    )
    .unwrap();
    let out = flatport(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "-o",
        shots.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("give --rig"),
        "{stderr}"
    );
    assert!(!shots.exists());
}

/// Full size: a 1280 × 1024 pair with 128 hypotheses, timed (the issue's target: 30 s on this
/// 2-core machine). `cargo test --release --test stereo -- --ignored --nocapture full_size`.
#[test]
#[ignore]
fn full_size_timing() {
    let json = SHARED_PORT_PAIR
        .replace("\"width\": 320, \"height\": 256, \"fx\": 260, \"fy\": 260, \"cx\": 159.5, \"cy\": 127.5",
                 "\"width\": 1280, \"height\": 1024, \"fx\": 1040, \"fy\": 1040, \"cx\": 639.5, \"cy\": 511.5");
    let rig = rig(&json);
    // Texture with detail down to two pixels (about 1.2 mm a pixel at 1.6 m here).
    let fine = |seed| flatport::render::Texture::Noise {
        seed,
        scale: 0.04,
        octaves: 5,
        contrast: 3.0,
    };
    let mut rock = sphere([0.12, 0.05, 1.3], 0.15, 12);
    rock.texture = fine(12);
    let surfaces = vec![plane_at(1.6, 0.1, fine(3)), rock];
    let started = std::time::Instant::now();
    let rendered = render_all(&rig, &scene(surfaces), 2.0);
    eprintln!("rendered in {:.1} s", started.elapsed().as_secs_f64());
    let started = std::time::Instant::now();
    // 128 hypotheses over 1.1 … 2.2 m: about a pixel of disparity a step at this resolution.
    let map = stereo(&rig, &rendered.images, &options((1.1, 2.2))).unwrap();
    let seconds = started.elapsed().as_secs_f64();
    let seen = seen_by_another(&rig, 0, &rendered);
    let a = accuracy(&map, &rendered.depths[0], &seen);
    eprintln!(
        "1280 × 1024, {} hypotheses, {} depth maps: {seconds:.1} s ({:?}); {:.1} % with a point, median {:.3} %, periphery median {:.3} %",
        map.hypotheses,
        map.runs,
        map.stage_seconds,
        100.0 * a.valid_fraction,
        100.0 * a.median,
        100.0 * a.periphery_median
    );
    assert!(a.valid_fraction > 0.85 && a.median < 0.003, "{a:?}");
}

/// Prints the accuracy of every acceptance scene (for tuning with FP_* variables).
#[test]
#[ignore]
fn tuning_report() {
    for case in [
        shared_port_seabed(),
        port_per_camera_step(),
        above_water_trio(),
    ] {
        run_case(&case);
    }
}
