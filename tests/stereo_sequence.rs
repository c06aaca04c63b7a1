//! `flatport stereo` over sequences: a rendered sequence as images and as lossless videos (the
//! same depth maps, byte for byte), `--frames`, `--resume` (complete frames skipped, a frame with
//! a missing or cut output computed again), `--shard` (the shards' outputs equal one run's, and
//! the job examples of docs/jobs/ run as written), `--fuse` (the fused cloud, read back by
//! ply-rs-bw's parser, lies on the scene's analytic surfaces with the plane's normal), and bad
//! sequences refused with nothing written.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod stereo_common;
use stereo_common::SHARED_PORT_PAIR;

fn flatport(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("flatport runs")
}

fn ok(args: &[&str]) -> String {
    let out = flatport(args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// The shared-port pair at 160 × 128.
fn small_rig() -> String {
    SHARED_PORT_PAIR.replace(
        "\"width\": 320, \"height\": 256, \"fx\": 260, \"fy\": 260, \"cx\": 159.5, \"cy\": 127.5",
        "\"width\": 160, \"height\": 128, \"fx\": 130, \"fy\": 130, \"cx\": 79.5, \"cy\": 63.5",
    )
}

/// Renders `surfaces` seen by the small rig in `frames` (offsets along x) into `dir`/shots.
fn render(dir: &Path, frames: usize, surfaces: &str) -> PathBuf {
    let offsets: Vec<String> = (0..frames)
        .map(|f| format!("{{\"offset\": [{}, 0, 0]}}", 0.02 * f as f64))
        .collect();
    let scene = dir.join("scene.json");
    std::fs::write(
        &scene,
        format!(
            "{{\"rig\": {}, \"frames\": [{}], \"surfaces\": {surfaces}}}",
            small_rig(),
            offsets.join(", ")
        ),
    )
    .unwrap();
    let shots = dir.join("shots");
    ok(&[
        "render",
        "--scene",
        p(&scene),
        "--noise",
        "1",
        "--device",
        "cpu",
        "--quiet",
        "-o",
        p(&shots),
    ]);
    shots
}

/// A seabed and a rock (the stereo tests' small scene).
const SEABED: &str = r#"[
    {"height_field": {"origin": [0, 0, 1.6], "normal": [0, 0, -1],
       "relief": {"amplitude": 0.05, "wavelength": 0.7, "seed": 3},
       "texture": {"noise": {"scale": 0.3, "octaves": 4, "seed": 4}}}},
    {"sphere": {"centre": [0.1, 0.05, 1.3], "radius": 0.15,
       "texture": {"noise": {"scale": 0.12, "octaves": 4, "seed": 5}}}}]"#;

/// Whether the ffmpeg tools are installed; says so when they are not.
fn have_ffmpeg() -> bool {
    let found = ["ffmpeg", "ffprobe"].iter().all(|tool| {
        Command::new(tool)
            .arg("-version")
            .output()
            .is_ok_and(|o| o.status.success())
    });
    if !found {
        eprintln!("SKIPPED: ffmpeg/ffprobe are not installed (apt-get install ffmpeg)");
    }
    found
}

/// Each camera's frames of `shots` as one lossless video (FFV1 in Matroska, 8-bit grey) in
/// `videos`/CAMERA/CAMERA.mkv, written by the ffmpeg tool.
fn write_videos(shots: &Path, videos: &Path) {
    for camera in ["left", "right"] {
        std::fs::create_dir_all(videos.join(camera)).unwrap();
        let out = Command::new("ffmpeg")
            .args(["-v", "error", "-y", "-framerate", "10", "-i"])
            .arg(shots.join(camera).join("frame_%03d.png"))
            .args(["-c:v", "ffv1", "-pix_fmt", "gray"])
            .arg(videos.join(camera).join(format!("{camera}.mkv")))
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn folders(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

fn summary(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&read(path)).unwrap()
}

const ARRAYS: [&str; 3] = ["points.npy", "depth.npy", "confidence.npy"];

#[test]
fn a_lossless_video_gives_the_depth_maps_of_its_frames_as_images() {
    if !have_ffmpeg() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let shots = render(dir.path(), 3, SEABED);
    let videos = dir.path().join("videos");
    write_videos(&shots, &videos);
    let rig = shots.join("rig.json");
    let run = |images: &Path, out: &Path, frames: &str| {
        ok(&[
            "stereo",
            "--rig",
            p(&rig),
            "--images",
            p(images),
            "--output",
            p(out),
            "--depth",
            "0.8:2.5",
            "--hypotheses",
            "32",
            "--device",
            "cpu",
            "--quiet",
            "--frames",
            frames,
        ])
    };
    let (from_images, from_videos) = (dir.path().join("a"), dir.path().join("b"));
    run(&shots, &from_images, "1:");
    run(&videos, &from_videos, "1:");
    // --frames 1: is frames 1 and 2, named as the images are, and by index for videos.
    assert_eq!(folders(&from_images), ["frame_001", "frame_002"]);
    assert_eq!(folders(&from_videos), ["frame_000001", "frame_000002"]);
    for (image, video) in [("frame_001", "frame_000001"), ("frame_002", "frame_000002")] {
        for file in ARRAYS {
            assert!(
                read(&from_images.join(image).join(file))
                    == read(&from_videos.join(video).join(file)),
                "{image}/{file} differs from {video}/{file}"
            );
        }
        // The clouds' vertices (their headers name the frame).
        let body = |path: PathBuf| {
            let bytes = read(&path);
            let end = b"end_header\n";
            let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
            bytes[at..].to_vec()
        };
        assert!(
            body(from_images.join(image).join("cloud.ply"))
                == body(from_videos.join(video).join("cloud.ply")),
            "{image}/cloud.ply"
        );
    }
    let s = summary(&from_videos.join("summary.json"));
    assert_eq!(s["frames_in_sequence"], 3);
    let indices: Vec<u64> = s["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["index"].as_u64().unwrap())
        .collect();
    assert_eq!(indices, [1, 2]);
    // A step: frames 0 and 2.
    let stepped = dir.path().join("c");
    run(&videos, &stepped, "::2");
    assert_eq!(folders(&stepped), ["frame_000000", "frame_000002"]);
    assert!(
        read(&stepped.join("frame_000002/depth.npy"))
            == read(&from_images.join("frame_002/depth.npy"))
    );
}

#[test]
fn resume_skips_complete_frames_and_computes_broken_ones_again() {
    let dir = tempfile::tempdir().unwrap();
    let shots = render(dir.path(), 3, SEABED);
    let rig = shots.join("rig.json");
    let out = dir.path().join("out");
    let run = |extra: &[&str]| {
        let mut args = vec![
            "stereo",
            "--rig",
            p(&rig),
            "--images",
            p(&shots),
            "--output",
            p(&out),
            "--depth",
            "0.8:2.5",
            "--hypotheses",
            "32",
            "--device",
            "cpu",
            "--quiet",
        ];
        args.extend_from_slice(extra);
        ok(&args)
    };
    run(&[]);
    let original: Vec<Vec<u8>> = ["frame_001/cloud.ply", "frame_002/depth.npy"]
        .iter()
        .map(|f| read(&out.join(f)))
        .collect();
    let record = read(&out.join("frame_000/frame.json"));
    // Frame 1 loses a file, frame 2 gets a cut one (as a copy stopped halfway would leave).
    std::fs::remove_file(out.join("frame_001/cloud.ply")).unwrap();
    std::fs::write(out.join("frame_002/depth.npy"), &original[1][..100]).unwrap();
    let said = run(&["--resume"]);
    assert!(said.contains("2 to compute, 1 complete"), "{said}");
    // Frame 0 was not computed again: its record (with its seconds) is the same, byte for byte.
    assert!(read(&out.join("frame_000/frame.json")) == record);
    assert!(read(&out.join("frame_001/cloud.ply")) == original[0]);
    assert!(read(&out.join("frame_002/depth.npy")) == original[1]);
    let s = summary(&out.join("summary.json"));
    assert_eq!(s["frames"].as_array().unwrap().len(), 3);
    assert_eq!(
        (s["computed"].as_u64(), s["skipped_complete"].as_u64()),
        (Some(2), Some(1))
    );
    // Everything complete: nothing computed; other settings: everything computed again.
    let said = run(&["--resume"]);
    assert!(said.contains("0 to compute, 3 complete"), "{said}");
    let said = run(&["--resume", "--window", "2", "--frames", "0"]);
    assert!(said.contains("1 to compute, 0 complete"), "{said}");
}

#[test]
fn shards_write_what_one_run_writes_and_the_job_examples_run_as_written() {
    let dir = tempfile::tempdir().unwrap();
    let shots = render(dir.path(), 3, SEABED);
    let rig = shots.join("rig.json");
    let run = |out: &Path, extra: &[&str]| {
        let mut args = vec![
            "stereo",
            "--rig",
            p(&rig),
            "--images",
            p(&shots),
            "--output",
            p(out),
            "--depth",
            "0.8:2.5",
            "--hypotheses",
            "32",
            "--device",
            "cpu",
            "--quiet",
        ];
        args.extend_from_slice(extra);
        ok(&args)
    };
    let whole = dir.path().join("whole");
    run(&whole, &[]);
    let sharded = dir.path().join("sharded");
    // Contiguous blocks: 3 frames over 2 shards are frame 0, then frames 1 and 2.
    let said = run(&sharded, &["--shard", "0/2"]);
    assert!(
        said.contains("1 frame(s) of 3 selected, shard 0/2"),
        "{said}"
    );
    assert_eq!(folders(&sharded), ["frame_000"]);
    run(&sharded, &["--shard", "1/2"]);
    for frame in ["frame_000", "frame_001", "frame_002"] {
        for file in ARRAYS.iter().chain(&["cloud.ply", "depth.png"]) {
            assert!(
                read(&whole.join(frame).join(file)) == read(&sharded.join(frame).join(file)),
                "{frame}/{file}"
            );
        }
    }
    let names = |s: &serde_json::Value| -> Vec<String> {
        s["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["frame"].as_str().unwrap().to_string())
            .collect()
    };
    assert_eq!(
        names(&summary(&sharded.join("summary-shard-0-of-2.json"))),
        ["frame_000"]
    );
    assert_eq!(
        names(&summary(&sharded.join("summary-shard-1-of-2.json"))),
        ["frame_001", "frame_002"]
    );
    assert!(!sharded.join("summary.json").exists());
    // The merge: the whole command with --resume computes nothing and writes summary.json.
    let said = run(&sharded, &["--resume"]);
    assert!(said.contains("0 to compute, 3 complete"), "{said}");
    let merged = summary(&sharded.join("summary.json"));
    assert_eq!(names(&merged), names(&summary(&whole.join("summary.json"))));
    for (a, b) in merged["frames"].as_array().unwrap().iter().zip(
        summary(&whole.join("summary.json"))["frames"]
            .as_array()
            .unwrap(),
    ) {
        assert_eq!(a["valid_points"], b["valid_points"]);
    }

    // The job examples, as SLURM and Kubernetes run them, in a folder laid out as they say
    // (rig.json, footage/), with flatport on the PATH.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let site = dir.path().join("site");
    std::fs::create_dir_all(&site).unwrap();
    std::fs::copy(&rig, site.join("rig.json")).unwrap();
    for camera in ["left", "right"] {
        std::fs::create_dir_all(site.join("footage").join(camera)).unwrap();
        for f in std::fs::read_dir(shots.join(camera)).unwrap().flatten() {
            if f.path().extension().is_some_and(|e| e == "png") {
                std::fs::copy(
                    f.path(),
                    site.join("footage").join(camera).join(f.file_name()),
                )
                .unwrap();
            }
        }
    }
    let bin = Path::new(env!("CARGO_BIN_EXE_flatport")).parent().unwrap();
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let script = |file: &str, variable: &str, index: usize| {
        let out = Command::new("bash")
            .arg(root.join("docs/jobs").join(file))
            .current_dir(&site)
            .env("PATH", &path)
            .env(variable, index.to_string())
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{file} ({variable}={index}): {}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    let text = String::from_utf8(read(&root.join("docs/jobs/stereo.sbatch"))).unwrap();
    let tasks: usize = text
        .lines()
        .find_map(|l| l.strip_prefix("#SBATCH --array=0-"))
        .expect("an --array line")
        .trim()
        .parse::<usize>()
        .unwrap()
        + 1;
    assert!(
        text.contains(&format!("\"$SLURM_ARRAY_TASK_ID/{tasks}\"")),
        "--array and --shard agree"
    );
    for task in 0..tasks {
        script("stereo.sbatch", "SLURM_ARRAY_TASK_ID", task);
    }
    script("stereo-merge.sbatch", "UNUSED", 0);
    let merged = summary(&site.join("out/summary.json"));
    assert_eq!(names(&merged), ["frame_000", "frame_001", "frame_002"]);
    assert_eq!(merged["computed"], 0);
    // The Indexed Job's command, with /data the site: pod 0 finds its frames complete.
    let yaml = String::from_utf8(read(&root.join("docs/jobs/stereo-job.yaml"))).unwrap();
    let command: Vec<&str> = yaml
        .lines()
        .skip_while(|l| !l.trim_start().starts_with("- >-"))
        .skip(1)
        .take_while(|l| !l.trim_start().starts_with("volumeMounts"))
        .map(str::trim)
        .collect();
    let command = command.join(" ").replace("/data", p(&site));
    assert!(command.starts_with("flatport stereo"), "{command}");
    let out = Command::new("sh")
        .args(["-c", &command])
        .env("PATH", &path)
        .env("JOB_COMPLETION_INDEX", "0")
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{command}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("0 to compute"));
}

#[test]
fn bad_sequences_are_refused_naming_the_problem_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let shots = render(dir.path(), 2, SEABED);
    let rig = shots.join("rig.json");
    let refused = |images: &Path, extra: &[&str]| -> String {
        let out_dir = dir.path().join("result");
        let mut args = vec![
            "stereo",
            "--rig",
            p(&rig),
            "--images",
            p(images),
            "--output",
            p(&out_dir),
            "--depth",
            "0.8:2.5",
            "--hypotheses",
            "16",
            "--device",
            "cpu",
            "--quiet",
        ];
        args.extend_from_slice(extra);
        let out = flatport(&args);
        assert!(!out.status.success(), "{extra:?} should fail");
        assert!(!out_dir.exists(), "{extra:?}: nothing written");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    // --frames beyond the sequence, and a shard index out of range.
    let error = refused(&shots, &["--frames", "5:"]);
    assert!(
        error.contains("--frames '5:'") && error.contains("has 2 frames"),
        "{error}"
    );
    let error = refused(&shots, &["--shard", "2/2"]);
    assert!(
        error.contains("--shard") && error.contains("2/2"),
        "{error}"
    );
    if !have_ffmpeg() {
        return;
    }
    let videos = dir.path().join("videos");
    write_videos(&shots, &videos);
    // A video that does not decode.
    let broken = dir.path().join("broken");
    std::fs::create_dir_all(broken.join("right")).unwrap();
    std::fs::create_dir_all(broken.join("left")).unwrap();
    std::fs::copy(videos.join("left/left.mkv"), broken.join("left/left.mkv")).unwrap();
    std::fs::write(broken.join("right/right.mkv"), b"not a video at all").unwrap();
    let error = refused(&broken, &[]);
    assert!(
        error.contains("right.mkv") && error.contains("cannot read the video"),
        "{error}"
    );
    // Frame counts that differ: a video of one frame against one of two.
    let short = dir.path().join("short");
    std::fs::create_dir_all(short.join("left")).unwrap();
    std::fs::copy(videos.join("left/left.mkv"), short.join("left/left.mkv")).unwrap();
    let shorter = short.join("right");
    std::fs::create_dir_all(&shorter).unwrap();
    let out = Command::new("ffmpeg")
        .args(["-v", "error", "-y", "-i"])
        .arg(shots.join("right/frame_000.png"))
        .args(["-c:v", "ffv1", "-pix_fmt", "gray"])
        .arg(shorter.join("right.mkv"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let error = refused(&short, &[]);
    assert!(
        error.contains("frames do not match") && error.contains("left 2, right 1"),
        "{error}"
    );
    // --frames outside the video.
    let error = refused(&videos, &["--frames", "2"]);
    assert!(
        error.contains("left.mkv")
            && error.contains("--frames '2'")
            && error.contains("has 2 frames"),
        "{error}"
    );
}

/// The vertices of a PLY file, read by ply-rs-bw's parser (not the crate's writer): each
/// vertex's float and uchar properties by name, and the property names in header order.
fn read_ply(path: &Path) -> (Vec<String>, Vec<std::collections::HashMap<String, f64>>) {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Property};
    let mut file = std::fs::File::open(path).unwrap();
    let ply = Parser::<DefaultElement>::new().read_ply(&mut file).unwrap();
    let names = ply.header.elements["vertex"]
        .properties
        .keys()
        .cloned()
        .collect();
    let vertices = ply.payload["vertex"]
        .iter()
        .map(|v| {
            v.iter()
                .map(|(name, value)| {
                    let x = match value {
                        Property::Float(x) => f64::from(*x),
                        Property::UChar(x) => f64::from(*x),
                        other => panic!("{name}: {other:?}"),
                    };
                    (name.clone(), x)
                })
                .collect()
        })
        .collect();
    (names, vertices)
}

#[test]
fn a_fused_cloud_lies_on_the_scene_with_the_planes_normal() {
    // A plane z = 1.6 and a sphere, both analytic: a point's distance to the scene is
    // min(|z − 1.6|, ||p − c| − r|), in the master frame the scene is given in.
    let dir = tempfile::tempdir().unwrap();
    let shots = render(
        dir.path(),
        1,
        r#"[{"plane": {"point": [0, 0, 1.6], "normal": [0, 0, -1],
               "texture": {"noise": {"scale": 0.3, "octaves": 4, "seed": 4}}}},
            {"sphere": {"centre": [0.1, 0.05, 1.3], "radius": 0.15,
               "texture": {"noise": {"scale": 0.12, "octaves": 4, "seed": 5}}}}]"#,
    );
    let out = dir.path().join("out");
    let said = ok(&[
        "stereo",
        "--rig",
        p(&shots.join("rig.json")),
        "--images",
        p(&shots),
        "--output",
        p(&out),
        "--depth",
        "1.0:2.0",
        "--hypotheses",
        "256",
        "--device",
        "cpu",
        "--quiet",
        "--fuse",
    ]);
    assert!(said.contains("fused points"), "{said}");
    let (names, vertices) = read_ply(&out.join("frame_000/fused.ply"));
    assert_eq!(
        names,
        ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]
    );
    let header = read(&out.join("frame_000/fused.ply"));
    assert!(header.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
    let record = summary(&out.join("frame_000/frame.json"));
    assert_eq!(
        record["fused_points"].as_u64().unwrap() as usize,
        vertices.len()
    );
    let (centre, radius, plane_z) = ([0.1, 0.05, 1.3], 0.15, 1.6);
    let mut relative = Vec::new();
    let mut plane_angles = Vec::new();
    for v in &vertices {
        let p = [v["x"], v["y"], v["z"]];
        let n = [v["nx"], v["ny"], v["nz"]];
        let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((norm - 1.0).abs() < 1e-5, "unit normals: {v:?}");
        let to_plane = (p[2] - plane_z).abs();
        let from_centre =
            ((p[0] - centre[0]).powi(2) + (p[1] - centre[1]).powi(2) + (p[2] - centre[2]).powi(2))
                .sqrt();
        let to_sphere = (from_centre - radius).abs();
        relative.push(to_plane.min(to_sphere) / p[2]);
        // On the plane, clear of the sphere's outline: the normal faces the cameras, −z.
        if to_plane < 0.005 && to_sphere > 0.03 && from_centre > radius + 0.05 {
            plane_angles.push((-n[2] / norm).clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let quantile = |v: &Vec<f64>, q: f64| v[((v.len() - 1) as f64 * q) as usize];
    assert!(vertices.len() > 10_000, "{} points", vertices.len());
    let m = median(&mut relative);
    eprintln!(
        "fused: {} points, median distance {:.3} % of depth, 95th percentile {:.3} %",
        vertices.len(),
        100.0 * m,
        100.0 * quantile(&relative, 0.95)
    );
    assert!(
        m <= 0.003,
        "median distance to the scene {:.3} % of depth",
        100.0 * m
    );
    assert!(
        plane_angles.len() > 5000,
        "{} plane points",
        plane_angles.len()
    );
    let a = median(&mut plane_angles);
    let a90 = quantile(&plane_angles, 0.9);
    eprintln!("plane normals: median {a:.2}°, 90th percentile {a90:.2}°");
    assert!(
        a <= 3.0 && a90 <= 6.0,
        "plane normals: median {a:.2}°, 90th percentile {a90:.2}°"
    );
}
