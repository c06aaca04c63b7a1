//! `flatport demo`: the built-in example end to end. The calibration story from pixels (render the
//! documented rig's views of a board, detect the corners, calibrate from a naive start, sweep the
//! invariant around the result) in DIR, and the geometry tour (project, back-project,
//! triangulate, VOPs) in DIR/geometry.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use nalgebra::{Point2, Point3};

use flatport::io::{rig_from_json_str, write_rig, write_table, write_truth};
use flatport::model::{NoSolution, Rig, triangulate_rays};

use super::rig::describe;

/// The example stereo rig: docs/DESIGN.md §1's rig with mild lens distortion and the right camera
/// turned 1° toward the left one.
pub const EXAMPLE_RIG: &str = include_str!("../../data/example_rig.json");

/// `flatport demo`
#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Folder to write the example files into (created if missing)
    #[arg(long, short, value_name = "DIR", default_value = "flatport-demo")]
    output: PathBuf,
    /// Where the calibration's and the sweeps' cost batches run
    #[command(flatten)]
    engine: super::EngineArgs,
}

/// A grid of points in the water: 21 × 15 per depth plane, spanning a bit more than the view.
fn example_points() -> Vec<[f64; 3]> {
    let mut points = Vec::new();
    for &z in &[0.3, 1.0, 2.5, 6.0] {
        for j in 0..15 {
            for i in 0..21 {
                let x = z * (-0.75 + 1.5 * i as f64 / 20.0);
                let y = z * (-0.6 + 1.2 * j as f64 / 14.0);
                points.push([x, y, z]);
            }
        }
    }
    points
}

fn inside(rig: &Rig, camera: usize, pixel: &Point2<f64>) -> bool {
    let i = &rig.cameras()[camera].intrinsics;
    (-0.5..i.width as f64 - 0.5).contains(&pixel.x)
        && (-0.5..i.height as f64 - 0.5).contains(&pixel.y)
}

fn write(
    dir: &Path,
    name: &str,
    header: [&str; 2],
    rows: &[Result<Point2<f64>, NoSolution>],
) -> anyhow::Result<()> {
    write_table(
        Some(&dir.join(name)),
        header,
        rows.iter().map(|r| r.ok().map(|p| [p.x, p.y])),
    )?;
    Ok(())
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    let dir = &args.output;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let rig = rig_from_json_str(EXAMPLE_RIG, Path::new("<built-in example rig>"))?;
    outln!("flatport demo: a stereo camera behind a 14 mm glass port, looking into water\n");
    out!("{}", describe(&rig));
    footage_story(&rig, dir, &args.engine)?;
    calibration_story(&rig, dir, &args.engine)?;
    geometry_tour(&rig, &dir.join("geometry"))?;
    stereo_story(&dir.join("stereo"))
}

/// The small example pair (320 × 256), which the demo's and the bench's stereo run on.
pub(super) const SMALL_PAIR: &str = include_str!("../../data/rigs/small_stereo.json");

/// The example seabed with a rock (data/scenes/seabed.json) through every camera of `rig`, on the
/// CPU, with `options` (camera k's noise seeded with k).
pub(super) fn render_seabed(
    rig: &Rig,
    options: &flatport::render::RenderOptions,
) -> anyhow::Result<Vec<flatport::stereo::GreyImage>> {
    use flatport::io::scene_json::scene_without_rig_from_json_str;
    // Built into the binary, so the demo runs from any folder: the scene's own `rig` key names a
    // file of the checkout, and `rig` is given here instead.
    const SCENE: &str = include_str!("../../data/scenes/seabed.json");
    let scene = scene_without_rig_from_json_str(SCENE, Path::new("data/scenes/seabed.json"))?;
    let engine = flatport::engine::Engine::Cpu(flatport::engine::CpuEngine::new(None));
    (0..rig.cameras().len())
        .map(|k| {
            let options = flatport::render::RenderOptions {
                seed: k as u64,
                ..options.clone()
            };
            let camera = rig.refractive_camera(k);
            Ok(flatport::render::render_textured(&engine, &camera, &scene, 0, &options)?.image)
        })
        .collect()
}

/// The last step: the small example pair (320 × 256) renders the example seabed with a rock,
/// dense stereo turns the pair into depths (64 hypotheses: a second or two on the CPU), and the
/// point cloud and a depth picture are written.
fn stereo_story(dir: &Path) -> anyhow::Result<()> {
    use flatport::io::stereo_files::{CloudPoint, write_depth_png, write_point_cloud_ply};
    use flatport::render::RenderOptions;
    use flatport::stereo::{Backend, StereoOptions, stereo_on};
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let rig = rig_from_json_str(SMALL_PAIR, Path::new("data/rigs/small_stereo.json"))?;
    let started = std::time::Instant::now();
    let options = RenderOptions {
        supersample: 1,
        noise: 2.0,
        ..RenderOptions::default()
    };
    let images = render_seabed(&rig, &options)?;
    let options = StereoOptions {
        depth_range: Some((1.0, 2.2)),
        hypotheses: Some(64),
        ..StereoOptions::default()
    };
    let map = stereo_on(&rig, &images, &options, Backend::Cpu, &|_| {})?;
    let cloud: Vec<CloudPoint> = map
        .points
        .iter()
        .zip(&images[0].pixels)
        .filter(|(p, _)| p[0].is_finite())
        .map(|(p, g)| {
            let grey = (g.clamp(0.0, 1.0) * 255.0).round() as u8;
            CloudPoint {
                position: *p,
                colour: [grey; 3],
            }
        })
        .collect();
    write_point_cloud_ply(
        &dir.join("cloud.ply"),
        &cloud,
        &["flatport demo: the example seabed, left camera".into()],
    )?;
    write_depth_png(
        &dir.join("depth.png"),
        map.width as u32,
        map.height as u32,
        &map.depth,
        "flatport demo: depth z in camera 'left'",
    )?;
    outln!(
        "\n7. dense stereo: the small pair (320 x 256) renders a seabed with a rock and matches it (64 hypotheses, {:.1} s): {:.1} % of the pixels with a point",
        started.elapsed().as_secs_f64(),
        100.0 * map.valid as f64 / (map.width * map.height) as f64
    );
    outln!(
        "wrote {0}/: cloud.ply depth.png   (more: flatport stereo --help, docs/stereo.md)",
        dir.display()
    );
    Ok(())
}

/// Scene of the story: 15 views of a 9×6 board of 40 mm squares, rendered with mild noise and
/// blur.
const VIEWS: usize = 15;
const NOISE_GREY: f64 = 2.0;
const BLUR_PX: f64 = 0.6;

/// Render, detect, calibrate from the naive start, sweep the invariant around the result.
/// Footage views of the example rig: under water (synchronized) and per camera in air.
const FOOTAGE_WATER_VIEWS: usize = 16;
const FOOTAGE_AIR_VIEWS: usize = 10;

/// The first step: ChArUco footage of the example rig rendered (each camera alone in air, the
/// rig under water), then the whole rig calibrated from it alone (`calibrate --images`): the
/// lenses, the extrinsics and the port.
fn footage_story(rig: &Rig, dir: &Path, engine_args: &super::EngineArgs) -> anyhow::Result<()> {
    use flatport::render::RenderOptions;
    const BOARD: &str = include_str!("../../data/boards/charuco_7x5.json");
    let board_path = dir.join("board.json");
    std::fs::write(&board_path, BOARD)
        .with_context(|| format!("cannot write {}", board_path.display()))?;
    let board = flatport::io::read_board(&board_path)?;
    outln!(
        "\n1. from footage alone: a 7x5 ChArUco board (40 mm squares) filmed by each camera in air ({FOOTAGE_AIR_VIEWS} views) and by the rig under water ({FOOTAGE_WATER_VIEWS} frames, often partly outside an image), rendered into footage/;\n   \
         then every camera's lens, the extrinsics and the port from those images alone (flatport calibrate --images):"
    );
    let footage = dir.join("footage");
    let started = Instant::now();
    let engine = flatport::engine::Engine::Cpu(flatport::engine::CpuEngine::new(None));
    super::render::render_set(
        rig,
        &board,
        &super::render::CalibrationSet {
            water_views: FOOTAGE_WATER_VIEWS,
            air_views: FOOTAGE_AIR_VIEWS,
            seed: 3,
            water_distance: None,
        },
        &RenderOptions {
            blur_px: BLUR_PX,
            noise: NOISE_GREY,
            seed: 3,
            ..RenderOptions::default()
        },
        8,
        &engine,
        &footage,
        true,
    )?;
    outln!(
        "   rendered {} images in {:.1} s",
        (FOOTAGE_WATER_VIEWS + FOOTAGE_AIR_VIEWS) * rig.cameras().len(),
        started.elapsed().as_secs_f64()
    );
    let glass = rig.port_in_master(0).layers()[0];
    let args = super::calib::CalibrateArgs {
        rig: None,
        observations: None,
        output: dir.join("footage_rig.json"),
        report: Some(dir.join("footage_report.json")),
        report_dir: None,
        images: Some(footage.clone()),
        board: Some(board_path),
        port: Some(super::calib::PortArg::Shared),
        glass: vec![flatport::runs::images::Glass {
            camera: None,
            thickness: glass.thickness,
            index: glass.index,
        }],
        index_water: Some(rig.port_in_master(0).index_water()),
        index_air: Some(rig.port_in_master(0).index_air()),
        master: None,
        frame_step: None,
        max_frames: None,
        holdout: flatport::calib::pipeline::boards::DEFAULT_HOLDOUT,
        refine_intrinsics: "auto".into(),
        quiet: true,
        targetless: false,
        frames: None,
        max_sigma_axis_deg: 0.1,
        max_sigma_distance_mm: 2.0,
        method: super::calib::MethodArg::Auto,
        estimate: flatport::calib::Estimate::default(),
        max_tilt_deg: 30.0,
        grid_step_deg: None,
        huber: None,
        max_iterations: 200,
        max_rms_px: None,
        truth: Some(footage.join("water").join("truth.json")),
        engine: super::EngineArgs {
            device: engine_args.device,
            precision: engine_args.precision,
            adapter: engine_args.adapter.clone(),
        },
    };
    super::calib_images::run(&args, &footage)?;
    Ok(())
}

fn calibration_story(rig: &Rig, dir: &Path, engine_args: &super::EngineArgs) -> anyhow::Result<()> {
    use flatport::calib::sweep::Linspace;
    use flatport::calib::{Board, Options, SceneSpec, Target, calibrate, simulate};
    use flatport::engine::Engine;
    use flatport::io::{Truth, read_observations, write_report};
    use flatport::render::RenderOptions;

    let board = Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    };
    outln!(
        "\n2. the port alone, from a chessboard: render {VIEWS} views of a 9x6 chessboard (40 mm squares) in the water, as both cameras see it through the port\n   \
         (every pixel back-projected, edges supersampled 8×8, lens distortion, blur {BLUR_PX} px, noise {NOISE_GREY} grey levels)"
    );
    let mut spec = SceneSpec::pair(Target::Board(board), VIEWS, 0.0, 1, 0, 1);
    spec.margin_px = 40.0;
    let poses = simulate(rig, &spec)?.master_from_target;
    let scene = super::render::Scene {
        rig: rig.clone(),
        board: flatport::detect::BoardSpec::Chessboard(board),
        poses,
    };
    let options = RenderOptions {
        blur_px: BLUR_PX,
        noise: NOISE_GREY,
        seed: 1,
        ..RenderOptions::default()
    };
    let engine: Engine = super::calib::calibration_engine(engine_args)?;
    let images = dir.join("images");
    let started = Instant::now();
    super::render::render_scene(&scene, &options, 8, &engine, &images, false)?;
    outln!(
        "   {} images in {:.2} s: {}/left/ and right/",
        2 * VIEWS,
        started.elapsed().as_secs_f64(),
        images.display()
    );
    write_rig(&dir.join("rig.json"), rig)?;
    let truth = Truth {
        interface: rig.port_in_master(0),
        master_from_board: scene.poses.clone(),
        noise_px: 0.0,
        seed: 1,
        rig: Some(rig.clone()),
    };

    outln!(
        "3. detect the corners (calib-targets, corner 0 by the board's colours), overlays in overlays/:"
    );
    let started = Instant::now();
    let glob = |camera: &str| {
        (
            camera.to_string(),
            format!("{}/{camera}/*.png", glob_escape(&images)),
        )
    };
    super::detect::run(super::detect::DetectArgs {
        board: flatport::detect::BoardSpec::Chessboard(board),
        images: vec![glob("left"), glob("right")],
        output: dir.join("observations.json"),
        rig: Some(dir.join("rig.json")),
        overlay: Some(dir.join("overlays")),
        charuco: None,
        quiet: false,
    })?;
    let observations = read_observations(&dir.join("observations.json"))?;
    let exact = read_observations(&images.join("corners.json"))?;
    let seconds = started.elapsed().as_secs_f64();
    match corner_errors(&observations, &exact) {
        Some((rms, max)) => {
            outln!(
                "   in {seconds:.2} s; against the exact corners (projected through the port): RMS {rms:.4} px, largest {max:.4} px"
            )
        }
        None => outln!(
            "   in {seconds:.2} s; some views were left out (see above), so the corners are not compared with the exact ones"
        ),
    }
    write_truth(&dir.join("truth.json"), &truth)?;

    let start = super::calib::naive_start(rig)?;
    write_rig(&dir.join("start_rig.json"), &start)?;
    outln!("4. calibrate from a naive start (axis on the camera's z axis, 10 mm air layer):");
    let options = Options {
        backend: super::calib::backend(engine),
        ..Options::default()
    };
    let calibration = calibrate(&start, &observations, &options)?;
    write_rig(&dir.join("calibrated_rig.json"), &calibration.rig)?;
    write_report(&dir.join("report.json"), &calibration.report)?;
    for line in super::calib::summary(&calibration.report).lines() {
        outln!("   {line}");
    }
    let truth_path = dir.join("truth.json");
    for line in super::calib::truth_errors(&calibration.rig, &truth, &truth_path)?.lines() {
        outln!("   {line}");
    }

    outln!(
        "5. sweep the affine-grid cost over the axis (a wide view, and a close one around the result):"
    );
    let found = calibration.report.port();
    let (tilt, azimuth) = (
        found.tilt.value.to_degrees(),
        found.azimuth.value.to_degrees(),
    );
    // Close view: ±1° of tilt, and azimuths spanning about ±1° of arc at this tilt.
    let arc = (1.0 / tilt.to_radians().sin().max(0.05)).min(180.0);
    let sweeps = [
        (
            "sweep_wide",
            Linspace {
                start: 0.0,
                stop: 20.0,
                count: 96,
            },
            Linspace {
                start: -180.0,
                stop: 180.0,
                count: 96,
            },
        ),
        (
            "sweep_close",
            Linspace {
                start: (tilt - 1.0).max(0.0),
                stop: tilt + 1.0,
                count: 64,
            },
            Linspace {
                start: azimuth - arc,
                stop: azimuth + arc,
                count: 64,
            },
        ),
    ];
    for (name, tilt_deg, azimuth_deg) in sweeps {
        let args = super::sweep::SweepArgs {
            rig: Some(dir.join("start_rig.json")),
            observations: Some(dir.join("observations.json")),
            targetless: false,
            images: None,
            frames: None,
            cost: super::sweep::CostArg::Invariant,
            tilt_deg: Some(tilt_deg),
            azimuth_deg: Some(azimuth_deg),
            distance: None,
            output: Some(dir.join(name)),
            truth: Some(dir.join("truth.json")),
            chunk: 4096,
            quiet: false,
            shard: None,
            engine: super::EngineArgs {
                device: engine_args.device,
                precision: engine_args.precision,
                adapter: engine_args.adapter.clone(),
            },
        };
        let summary = super::sweep::run_sweep(&args)?;
        let m = &summary["argmin"];
        outln!(
            "   {name}: {} × {} axes, minimum at tilt {:.3}°, azimuth {:.3}° in {:.2} s",
            tilt_deg.count,
            azimuth_deg.count,
            m["tilt_deg"].as_f64().unwrap_or(f64::NAN),
            m["azimuth_deg"].as_f64().unwrap_or(f64::NAN),
            summary["seconds"].as_f64().unwrap_or(f64::NAN)
        );
    }
    outln!(
        "\nwrote {0}/: rig.json (the truth) truth.json observations.json start_rig.json calibrated_rig.json report.json\n       {0}/images/ (the rendered images, corners.json the exact corners), {0}/overlays/ (the detections drawn)\n       {0}/sweep_wide/ and {0}/sweep_close/: heatmap.png polar.png cost.npy cost.csv summary.json",
        dir.display()
    );
    Ok(())
}

/// A path as a glob pattern that matches itself: `[`, `]`, `*`, `?` escaped.
fn glob_escape(path: &Path) -> String {
    glob::Pattern::escape(&path.to_string_lossy())
}

/// RMS and largest distance (pixels) between the corners of `found` and `exact`, view by view,
/// over the corners both hold; `None` when they hold different numbers of views (some view was
/// left out, so they no longer pair by position).
fn corner_errors(
    found: &flatport::calib::Observations,
    exact: &flatport::calib::Observations,
) -> Option<(f64, f64)> {
    if found.views.len() != exact.views.len() {
        return None;
    }
    let (mut sum, mut count, mut max) = (0.0, 0usize, 0.0f64);
    for (a, b) in found.views.iter().zip(&exact.views) {
        // The images of one camera, paired by key.
        let pairs = a.images.iter().flat_map(|i| {
            let j = b.images.iter().find(|j| j.key == i.key);
            j.into_iter()
                .flat_map(move |j| i.corners.iter().zip(&j.corners))
        });
        for (p, q) in pairs {
            if let (Some(p), Some(q)) = (p, q) {
                let e = (p - q).norm();
                sum += e * e;
                count += 1;
                max = max.max(e);
            }
        }
    }
    Some(((sum / count.max(1) as f64).sqrt(), max))
}

/// Project a grid of points, back-project and triangulate them, VOPs: into `dir`.
fn geometry_tour(rig: &Rig, dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let rig = rig.clone();
    write_rig(&dir.join("rig.json"), &rig)?;
    outln!(
        "\n6. the geometry on its own: project, back-project, triangulate a grid of points, VOPs"
    );

    let points = example_points();
    let (left, right) = (rig.refractive_camera(0), rig.refractive_camera(1));
    write_table(
        Some(&dir.join("points.csv")),
        ["x", "y", "z"],
        points.iter().map(|&p| Some(p)),
    )?;

    // Forward projection into both cameras.
    let paths: Vec<_> = points
        .iter()
        .map(|p| left.air_path_to(&Point3::from(*p)))
        .collect();
    let started = Instant::now();
    let pixels_left: Vec<_> = points
        .iter()
        .map(|p| left.project(&Point3::from(*p)))
        .collect();
    let pixels_right: Vec<_> = points
        .iter()
        .map(|p| right.project(&Point3::from(*p)))
        .collect();
    let project_time = started.elapsed();
    write(dir, "pixels_left.csv", ["u", "v"], &pixels_left)?;
    write(dir, "pixels_right.csv", ["u", "v"], &pixels_right)?;
    let mut iterations: Vec<u32> = paths
        .iter()
        .filter_map(|p| p.ok())
        .map(|p| p.iterations)
        .collect();
    iterations.sort_unstable();

    // Back-projection of the left pixels: each ray must pass through its point.
    let started = Instant::now();
    let rays: Vec<_> = pixels_left
        .iter()
        .map(|p| p.and_then(|p| left.backproject(&p)))
        .collect();
    let backproject_time = started.elapsed();
    write_table(
        Some(&dir.join("rays_left.csv")),
        ["ox", "oy", "oz", "dx", "dy", "dz"],
        rays.iter().map(|r| {
            r.ok().map(|r| {
                [
                    r.origin.x, r.origin.y, r.origin.z, r.dir.x, r.dir.y, r.dir.z,
                ]
            })
        }),
    )?;
    let miss = points
        .iter()
        .zip(&rays)
        .filter_map(|(p, r)| {
            r.ok()
                .map(|r| (Point3::from(*p) - r.origin).cross(&r.dir).norm())
        })
        .fold(0.0, f64::max);

    // Triangulation of the matches seen by both cameras.
    let matches: Vec<Option<[f64; 4]>> = pixels_left
        .iter()
        .zip(&pixels_right)
        .map(|(l, r)| match (l, r) {
            (Ok(l), Ok(r)) => Some([l.x, l.y, r.x, r.y]),
            _ => None,
        })
        .collect();
    write_table(
        Some(&dir.join("matches.csv")),
        ["ul", "vl", "ur", "vr"],
        matches.iter().copied(),
    )?;
    let started = Instant::now();
    let triangulated: Vec<_> = matches
        .iter()
        .map(|m| {
            let [ul, vl, ur, vr] = m.ok_or(NoSolution::NotInWater)?;
            let a = left.backproject(&Point2::new(ul, vl))?;
            let b = right.backproject(&Point2::new(ur, vr))?;
            triangulate_rays(&a, &b)
        })
        .collect();
    let triangulate_time = started.elapsed();
    write_table(
        Some(&dir.join("triangulated.csv")),
        ["x", "y", "z", "residual"],
        triangulated.iter().map(|t| {
            t.ok()
                .map(|t| [t.point.x, t.point.y, t.point.z, t.residual])
        }),
    )?;
    let triangulation_error = points
        .iter()
        .zip(&triangulated)
        .filter_map(|(p, t)| t.ok().map(|t| (Point3::from(*p) - t.point).norm()))
        .fold(0.0, f64::max);

    // Virtual Object Points for the left camera.
    let vops: Vec<_> = points.iter().map(|p| left.vop(&Point3::from(*p))).collect();
    write_table(
        Some(&dir.join("vops_left.csv")),
        [
            "depth",
            "vop_distance",
            "vop_x",
            "vop_y",
            "vop_z",
            "incidence",
        ],
        vops.iter().map(|v| {
            v.ok().map(|v| {
                [
                    v.depth,
                    v.vop_distance,
                    v.vop.x,
                    v.vop.y,
                    v.vop.z,
                    v.incidence,
                ]
            })
        }),
    )?;

    let visible = pixels_left
        .iter()
        .zip(&pixels_right)
        .filter(
            |(l, r)| matches!((l, r), (Ok(l), Ok(r)) if inside(&rig, 0, l) && inside(&rig, 1, r)),
        )
        .count();
    let projected = pixels_left.iter().filter(|p| p.is_ok()).count();
    let median = iterations.get(iterations.len() / 2).copied().unwrap_or(0);
    let max = iterations.last().copied().unwrap_or(0);
    let micros = |d: std::time::Duration| d.as_secs_f64() * 1e6;

    outln!(
        "{} points on 4 planes 0.3–6 m away ({} inside both images)",
        points.len(),
        visible
    );
    outln!(
        "forward projection: {projected} of {} points, Newton iterations median {median}, max {max}, {:.0} µs for both cameras",
        points.len(),
        micros(project_time)
    );
    outln!(
        "back-projection:    largest distance from a point to its pixel's water ray {miss:.1e} m, {:.0} µs",
        micros(backproject_time)
    );
    outln!(
        "triangulation:      largest error {triangulation_error:.1e} m over {} matches, {:.0} µs",
        triangulated.iter().filter(|t| t.is_ok()).count(),
        micros(triangulate_time)
    );
    if let Some(v) = vops
        .iter()
        .filter_map(|v| v.ok())
        .min_by(|a, b| a.vop_distance.total_cmp(&b.vop_distance))
    {
        outln!(
            "virtual object points: nearest VOP {:.4} m beyond the glass for a point {:.3} m deep",
            v.vop_distance,
            v.depth
        );
    }
    outln!(
        "wrote {}/: rig.json points.csv pixels_left.csv pixels_right.csv rays_left.csv matches.csv triangulated.csv vops_left.csv",
        dir.display()
    );
    outln!(
        "try:  flatport triangulate --rig {0}/rig.json --matches {0}/matches.csv | head",
        dir.display()
    );
    Ok(())
}
