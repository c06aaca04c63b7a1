//! `flatport render`: images of a board (a chessboard or a ChArUco board) seen through the port by
//! every camera of a rig.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::Context;
use clap::Args;
use nalgebra::{Isometry3, Point2};

use flatport::calib::{SceneSpec, Target, simulate};
use flatport::detect::BoardSpec;
use flatport::engine::Engine;
use flatport::io::{
    DetectedView, Truth, read_rig, read_truth, write_detections, write_grey_png, write_grey16_png,
    write_rig, write_truth,
};
use flatport::model::Rig;
use flatport::render::{Imaging, RenderOptions, render_board_spec};

use super::progress::Progress;

/// `flatport render`
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Rig file: the cameras, and the port (unless --truth gives it); with --scene, in place of
    /// the scene file's rig
    #[arg(long, value_name = "RIG.json", required_unless_present = "scene")]
    rig: Option<PathBuf>,
    /// Scene file: textured planes, height fields and spheres (and the rig, unless --rig);
    /// renders CAMERA/frame_NNN.png and the exact depth CAMERA/depth_NNN.npy instead of a board
    #[arg(long, value_name = "SCENE.json", conflicts_with_all = ["truth", "views", "board", "margin_px", "border"])]
    scene: Option<PathBuf>,
    /// Truth file of a simulated scene (`flatport simulate`): its port and board poses
    #[arg(long, value_name = "TRUTH.json", conflicts_with_all = ["views", "seed"])]
    truth: Option<PathBuf>,
    /// Board: COLSxROWS@SQUARE, a chessboard by its inner corners per row × per column (OpenCV's
    /// patternSize) and the square in metres, or a BOARD.json (a chessboard or a ChArUco board,
    /// counted in squares: docs/images.md)
    #[arg(long, value_name = "COLSxROWS@M|BOARD.json", default_value = "9x6@0.04", value_parser = super::detect::parse_board_spec)]
    board: BoardSpec,
    /// Render a set for `flatport calibrate --images`: OUTPUT/water/CAMERA/view_NNN.png (the
    /// rig's cameras under water, synchronized, the board at random places, distances and angles,
    /// often partly outside an image) and OUTPUT/air/CAMERA/view_NNN.png (each camera alone in
    /// air, --air-views poses); the truths in OUTPUT/water/ and OUTPUT/air-truth/CAMERA/
    #[arg(long, conflicts_with_all = ["truth", "scene"])]
    calibration_set: bool,
    /// In-air views per camera of --calibration-set
    #[arg(long, value_name = "N", default_value_t = 15)]
    air_views: usize,
    /// Number of random board poses (as `flatport simulate` draws them), without --truth
    #[arg(long, default_value_t = 15)]
    views: usize,
    /// Distances of the board from the master camera under water, metres along its axis, for
    /// --calibration-set (default: where the board fills 90 % to 35 % of the image width)
    #[arg(long, value_name = "NEAR:FAR", value_parser = parse_distances, requires = "calibration_set")]
    distance: Option<(f64, f64)>,
    /// Seed of the poses (and of the noise)
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The board's corners keep this many pixels from the image border (poses drawn without --truth)
    #[arg(long, value_name = "PX", default_value_t = 40.0, value_parser = super::values::non_negative)]
    margin_px: f64,
    /// Sub-samples per axis of every pixel that crosses an edge of the pattern (1 = no
    /// anti-aliasing; default 8); with --scene, of every pixel (default 3)
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=32))]
    supersample: Option<u32>,
    /// Standard deviation of the Gaussian image noise, grey levels of 255
    #[arg(long, value_name = "GREY", default_value_t = 0.0, value_parser = super::values::non_negative)]
    noise: f64,
    /// Standard deviation of a Gaussian blur, pixels
    #[arg(long, value_name = "PX", default_value_t = 0.0, value_parser = super::values::non_negative)]
    blur: f64,
    /// White border around the board's outer squares, in squares
    #[arg(long, value_name = "SQUARES", default_value_t = 1.0, value_parser = super::values::non_negative)]
    border: f64,
    /// Bits per pixel of the PNG files
    #[arg(long, default_value_t = 8, value_parser = parse_bits)]
    bits: u8,
    /// Output folder (created if missing): CAMERA/view_NNN.png per camera, truth.json, rig.json,
    /// corners.json (the exact corners: the board's corners projected through the port; for a
    /// ChArUco board every corner inside the image, `null` for the others)
    #[arg(long, short, value_name = "DIR")]
    output: PathBuf,
    /// No progress bar
    #[arg(long, short)]
    quiet: bool,
    #[command(flatten)]
    engine: super::EngineArgs,
    #[command(flatten)]
    imaging: ImagingArgs,
}

/// What a real camera adds to the images (`flatport::render::imaging`): a preset by severity,
/// and each effect's size (which replaces the preset's).
#[derive(Debug, Args)]
#[command(next_help_heading = "Imaging (what real cameras add; the corners files stay exact)")]
pub struct ImagingArgs {
    /// Every effect at this severity: 0 none, 1 as real underwater cameras give it (defocus
    /// 0.6-1.6 px, vignetting 35 %, light gradient ±20 %, contrast -40 %, backscatter, noise,
    /// JPEG 75), 2 harsher (defocus 1.0-2.4 px, motion blur 2 px, JPEG 50, stronger noise);
    /// linear in between. The options below replace single values
    #[arg(long, value_name = "SEVERITY", value_parser = parse_severity)]
    imaging: Option<f64>,
    /// Defocus: radius of the blur disc at the image centre, pixels (mean over the images)
    #[arg(long, value_name = "PX", value_parser = super::values::non_negative)]
    defocus: Option<f64>,
    /// Defocus: the centre's radius varies by ± this much from image to image, pixels
    #[arg(long, value_name = "PX", value_parser = super::values::non_negative)]
    defocus_variation: Option<f64>,
    /// Defocus: radius added at the image corners (field curvature), pixels
    #[arg(long, value_name = "PX", value_parser = super::values::non_negative)]
    defocus_corner: Option<f64>,
    /// Motion blur: length of the streak, pixels, at a random angle per image
    #[arg(long, value_name = "PX", value_parser = super::values::non_negative)]
    motion_blur: Option<f64>,
    /// Vignetting: fraction of the centre's light lost at the corners (0.35: corners at 65 %)
    #[arg(long, value_name = "F", value_parser = fraction)]
    vignetting: Option<f64>,
    /// Light gradient: ± this fraction of the light across the image, at a random direction
    #[arg(long, value_name = "F", value_parser = fraction)]
    gradient: Option<f64>,
    /// Contrast lost: grey levels scaled by 1 - F about mid-grey (0.4: black 0.2, white 0.8)
    #[arg(long, value_name = "F", value_parser = fraction)]
    contrast: Option<f64>,
    /// Backscatter: mean number of bright specks per megapixel (Gaussian blobs of 0.5-3 px)
    #[arg(long, value_name = "PER_MPX", value_parser = super::values::non_negative)]
    backscatter: Option<f64>,
    /// Backscatter: peak brightness of the brightest specks, grey 0-1 (default 0.5)
    #[arg(long, value_name = "GREY", value_parser = fraction)]
    speck_brightness: Option<f64>,
    /// Backscatter: veil (haze) added everywhere, grey 0-1
    #[arg(long, value_name = "GREY", value_parser = fraction)]
    veil: Option<f64>,
    /// Shot noise: the sensor's full well, electrons at white (noise variance = grey / E; 0 = none)
    #[arg(long, value_name = "ELECTRONS", value_parser = super::values::non_negative)]
    shot_noise: Option<f64>,
    /// Read noise: standard deviation, grey levels of 255
    #[arg(long, value_name = "GREY", value_parser = super::values::non_negative)]
    read_noise: Option<f64>,
    /// JPEG compression at this quality, 1-100 (0 = none)
    #[arg(long, value_name = "Q", value_parser = clap::value_parser!(u8).range(0..=100))]
    jpeg: Option<u8>,
    /// H.264 compression of each camera's sequence (libx264 through the ffmpeg tool) at this
    /// constant rate factor, 0-51 (23 is x264's default; higher is worse); the PNG files hold
    /// the decoded frames
    #[arg(long, value_name = "CRF", value_parser = clap::value_parser!(u8).range(0..=51))]
    h264: Option<u8>,
}

impl ImagingArgs {
    /// The preset (or nothing) with the options given replacing its values, seeded by `seed`.
    fn imaging(&self, seed: u64) -> anyhow::Result<Imaging> {
        let mut imaging = Imaging::preset(self.imaging.unwrap_or(0.0), seed)?;
        let set = |field: &mut f64, value: Option<f64>| {
            if let Some(value) = value {
                *field = value;
            }
        };
        set(&mut imaging.defocus.radius_px, self.defocus);
        set(&mut imaging.defocus.variation_px, self.defocus_variation);
        set(&mut imaging.defocus.corner_px, self.defocus_corner);
        set(&mut imaging.motion_blur_px, self.motion_blur);
        set(&mut imaging.vignetting, self.vignetting);
        set(&mut imaging.gradient, self.gradient);
        set(&mut imaging.contrast, self.contrast);
        set(&mut imaging.backscatter.specks_per_mpx, self.backscatter);
        set(
            &mut imaging.backscatter.speck_brightness,
            self.speck_brightness,
        );
        if self.backscatter.is_some_and(|b| b > 0.0) && imaging.backscatter.speck_brightness == 0.0
        {
            imaging.backscatter.speck_brightness = 0.5;
        }
        set(&mut imaging.backscatter.veil, self.veil);
        set(&mut imaging.noise.full_well_e, self.shot_noise);
        set(&mut imaging.noise.read_noise, self.read_noise);
        if let Some(q) = self.jpeg {
            imaging.jpeg_quality = (q > 0).then_some(q);
        }
        if self.h264.is_some() {
            imaging.h264_crf = self.h264;
            flatport::render::imaging::check_h264_tool()?;
        }
        imaging.check()?;
        Ok(imaging)
    }
}

/// A severity from 0 to 2.
fn parse_severity(text: &str) -> Result<f64, String> {
    let value = super::values::non_negative(text)?;
    if value <= 2.0 {
        Ok(value)
    } else {
        Err(format!(
            "a severity from 0 (none) to 2 (harsh), got {value}"
        ))
    }
}

/// A fraction from 0 to 1 (below 1 where the effect needs it: the range check says).
fn fraction(text: &str) -> Result<f64, String> {
    let value = super::values::non_negative(text)?;
    if value <= 1.0 {
        Ok(value)
    } else {
        Err(format!("a fraction from 0 to 1, got {value}"))
    }
}

/// `NEAR:FAR` in metres, 0 < NEAR < FAR.
fn parse_distances(text: &str) -> Result<(f64, f64), String> {
    let (near, far) = text
        .split_once(':')
        .ok_or_else(|| format!("'{text}': give NEAR:FAR in metres, e.g. 0.8:2.2"))?;
    let value = |v: &str| {
        v.trim()
            .parse::<f64>()
            .map_err(|_| format!("'{text}': '{v}' is not a number of metres"))
    };
    let (near, far) = (value(near)?, value(far)?);
    if !(near > 0.0 && far > near && far.is_finite()) {
        return Err(format!("'{text}': NEAR and FAR must be 0 < NEAR < FAR"));
    }
    Ok((near, far))
}

fn parse_bits(text: &str) -> Result<u8, String> {
    match text {
        "8" => Ok(8),
        "16" => Ok(16),
        _ => Err(format!("8 or 16 bits per pixel, got '{text}'")),
    }
}

/// What to render: the rig with the true port, the board, the poses.
pub struct Scene {
    pub rig: Rig,
    pub board: BoardSpec,
    pub poses: Vec<Isometry3<f64>>,
}

/// Renders every camera's image of every pose into `dir`/CAMERA/view_NNN.png, writes rig.json,
/// truth.json and corners.json (the exact corners, whatever the imaging effects). With H.264
/// (`options.imaging.h264_crf`) each camera's sequence is then encoded and decoded and its PNG
/// files rewritten. Returns the image paths per camera.
pub fn render_scene(
    scene: &Scene,
    options: &RenderOptions,
    bits: u8,
    engine: &Engine,
    dir: &Path,
    quiet: bool,
) -> anyhow::Result<Vec<Vec<PathBuf>>> {
    let names: Vec<String> = scene.rig.cameras().iter().map(|c| c.name.clone()).collect();
    for name in &names {
        std::fs::create_dir_all(dir.join(name))
            .with_context(|| format!("cannot create {}", dir.join(name).display()))?;
    }
    write_rig(&dir.join("rig.json"), &scene.rig)?;
    let truth = Truth {
        interface: scene.rig.port_in_master(0),
        master_from_board: scene.poses.clone(),
        noise_px: 0.0,
        seed: options.seed,
        rig: Some(scene.rig.clone()),
    };
    write_truth(&dir.join("truth.json"), &truth)?;
    // The exact corners: every board corner projected through the port by the model. A
    // chessboard's view holds all of them or none (its detector takes whole boards only); a
    // ChArUco board's holds those inside the image (ids say which).
    let grid = scene.board.corner_grid();
    let partial = matches!(scene.board, BoardSpec::Charuco(_));
    let cameras: Vec<_> = (0..names.len())
        .map(|k| scene.rig.refractive_camera(k))
        .collect();
    let exact: Vec<DetectedView> = scene
        .poses
        .iter()
        .map(|pose| {
            cameras
                .iter()
                .map(|camera| {
                    let i = camera.intrinsics();
                    let corners: Vec<Option<Point2<f64>>> = (0..grid.corners())
                        .map(|c| {
                            camera
                                .project(&(pose * grid.point_in_board(c)))
                                .ok()
                                .filter(|p: &Point2<f64>| {
                                    p.x >= -0.5
                                        && p.y >= -0.5
                                        && p.x < i.width as f64 - 0.5
                                        && p.y < i.height as f64 - 0.5
                                })
                        })
                        .collect();
                    let seen = corners.iter().filter(|c| c.is_some()).count();
                    let usable = if partial {
                        seen > 0
                    } else {
                        seen == corners.len()
                    };
                    usable.then_some(corners)
                })
                .collect()
        })
        .collect();
    write_detections(&dir.join("corners.json"), &grid, &names, &exact)?;

    let total = scene.poses.len() * names.len();
    let progress = Mutex::new(Progress::new("render", "images", quiet));
    let done = AtomicUsize::new(0);
    let mut paths = vec![Vec::new(); names.len()];
    // Images one after the other (each one is parallel inside), PNG encoding beside the next one.
    let (sender, receiver) =
        std::sync::mpsc::sync_channel::<(PathBuf, flatport::render::GreyImage)>(2);
    std::thread::scope(|s| -> anyhow::Result<()> {
        let writer = s.spawn(move || -> anyhow::Result<()> {
            for (path, image) in receiver {
                if bits == 16 {
                    write_grey16_png(&path, &image.to_u16(), image.width, image.height)?;
                } else {
                    write_grey_png(&path, &image.to_u8(), image.width, image.height)?;
                }
                let n = done.fetch_add(1, Ordering::Relaxed) + 1;
                if let Ok(mut p) = progress.lock() {
                    p.update(n, total);
                }
            }
            Ok(())
        });
        let mut result = Ok(());
        'views: for (v, pose) in scene.poses.iter().enumerate() {
            for (k, camera) in cameras.iter().enumerate() {
                let seed = options
                    .seed
                    .wrapping_mul(1_000_003)
                    .wrapping_add((v * names.len() + k) as u64);
                let image = match render_board_spec(
                    engine,
                    camera,
                    &scene.board,
                    pose,
                    &RenderOptions {
                        seed,
                        ..options.clone()
                    },
                ) {
                    Ok(image) => image,
                    Err(e) => {
                        result = Err(anyhow::Error::from(e));
                        break 'views;
                    }
                };
                let path = dir.join(&names[k]).join(format!("view_{v:03}.png"));
                paths[k].push(path.clone());
                if sender.send((path, image)).is_err() {
                    break 'views;
                }
            }
        }
        drop(sender);
        writer.join().expect("the PNG writer does not panic")?;
        result
    })?;
    if let Some(crf) = options.imaging.h264_crf {
        for camera in &paths {
            super::render_scene::h264_sequence(camera, crf, bits)?;
        }
    }
    Ok(paths)
}

pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    if let Some(scene) = &args.scene {
        return super::render_scene::run(super::render_scene::SceneRun {
            scene,
            rig: args.rig.as_deref(),
            options: RenderOptions {
                supersample: args.supersample.unwrap_or(3),
                blur_px: args.blur,
                noise: args.noise,
                seed: args.seed,
                imaging: args.imaging.imaging(args.seed)?,
                ..RenderOptions::default()
            },
            bits: args.bits,
            output: &args.output,
            quiet: args.quiet,
            engine: &args.engine,
        });
    }
    let Some(rig_path) = &args.rig else {
        anyhow::bail!("--rig RIG.json is needed to render a board (or give --scene)");
    };
    let rig = read_rig(rig_path)?;
    let board = args.board.clone();
    if args.calibration_set {
        return render_calibration_set(&args, &rig, &board);
    }
    let scene = match &args.truth {
        Some(path) => {
            let truth = read_truth(path)?;
            let rig = rig
                .with_interface(truth.interface.clone())
                .with_context(|| format!("{}: its port does not fit the rig", path.display()))?;
            Scene {
                rig,
                board,
                poses: truth.master_from_board,
            }
        }
        None => {
            if rig.cameras().len() < 2 {
                anyhow::bail!(
                    "poses are drawn as `flatport simulate` draws them, for a stereo pair: the rig has one camera (give --truth)"
                );
            }
            let mut spec = SceneSpec::pair(
                Target::Board(board.corner_grid()),
                args.views,
                0.0,
                args.seed,
                0,
                1,
            );
            spec.margin_px = args.margin_px;
            let simulated = simulate(&rig, &spec)?;
            Scene {
                rig,
                board,
                poses: simulated.master_from_target,
            }
        }
    };
    let options = RenderOptions {
        supersample: args.supersample.unwrap_or(8),
        blur_px: args.blur,
        noise: args.noise,
        seed: args.seed,
        border_squares: args.border,
        imaging: args.imaging.imaging(args.seed)?,
        ..RenderOptions::default()
    };
    let engine = args.engine.engine()?;
    let started = std::time::Instant::now();
    let paths = render_scene(
        &scene,
        &options,
        args.bits,
        &engine,
        &args.output,
        args.quiet,
    )?;
    outln!(
        "rendered {} images ({} views × {} cameras) in {:.2} s into {}/: {}/view_NNN.png, rig.json, truth.json, corners.json",
        paths.iter().map(Vec::len).sum::<usize>(),
        scene.poses.len(),
        paths.len(),
        started.elapsed().as_secs_f64(),
        args.output.display(),
        scene
            .rig
            .cameras()
            .iter()
            .map(|c| c.name.as_str())
            .collect::<Vec<_>>()
            .join("/, ")
    );
    Ok(())
}

/// `render --calibration-set`: the layout `calibrate --images` reads (see [`RenderArgs`]).
fn render_calibration_set(args: &RenderArgs, rig: &Rig, board: &BoardSpec) -> anyhow::Result<()> {
    let options = RenderOptions {
        supersample: args.supersample.unwrap_or(8),
        blur_px: args.blur,
        noise: args.noise,
        seed: args.seed,
        border_squares: args.border,
        imaging: args.imaging.imaging(args.seed)?,
        ..RenderOptions::default()
    };
    let engine = args.engine.engine()?;
    let started = std::time::Instant::now();
    let set = CalibrationSet {
        water_views: args.views,
        air_views: args.air_views,
        seed: args.seed,
        water_distance: args.distance,
    };
    render_set(
        rig,
        board,
        &set,
        &options,
        args.bits,
        &engine,
        &args.output,
        args.quiet,
    )?;
    outln!(
        "rendered a calibration set in {:.1} s into {}/: water/CAMERA/ ({} synchronized views), air/CAMERA/ ({} views each), the truths in water/ and air-truth/",
        started.elapsed().as_secs_f64(),
        args.output.display(),
        args.views,
        args.air_views
    );
    Ok(())
}

/// How many views a calibration set has ([`render_set`]).
pub struct CalibrationSet {
    /// Synchronized views of the rig under water.
    pub water_views: usize,
    /// Views per camera in air.
    pub air_views: usize,
    /// Seed of the poses (and the noise).
    pub seed: u64,
    /// Distances of the board under water, metres along the master's axis (`None`: where it
    /// fills 90 % to 35 % of the master's image width).
    pub water_distance: Option<(f64, f64)>,
}

/// Renders the layout `calibrate --images` reads into `dir`: water/CAMERA/view_NNN.png of `rig`
/// (with rig.json, truth.json, corners.json), and air/CAMERA/view_NNN.png of each camera alone in
/// air (its truths in air-truth/CAMERA/).
#[allow(clippy::too_many_arguments)]
pub fn render_set(
    rig: &Rig,
    board: &BoardSpec,
    set: &CalibrationSet,
    options: &RenderOptions,
    bits: u8,
    engine: &Engine,
    dir: &Path,
    quiet: bool,
) -> anyhow::Result<()> {
    use flatport::calib::simulate::spread::{board_poses, depth_range};
    let grid = board.corner_grid();
    let outer = ((grid.cols + 1).max(grid.rows + 1)) as f64 * grid.square;
    let inside = |rig: &Rig| {
        let cameras: Vec<_> = (0..rig.cameras().len())
            .map(|k| rig.refractive_camera(k))
            .collect();
        move |k: usize, point: &nalgebra::Point3<f64>| {
            let i = cameras[k].intrinsics();
            cameras[k].project(point).is_ok_and(|p| {
                p.x >= 0.0
                    && p.y >= 0.0
                    && p.x < i.width as f64 - 1.0
                    && p.y < i.height as f64 - 1.0
            })
        }
    };
    let index_water = rig.port_in_master(0).index_water();
    let poses = board_poses(
        rig,
        &grid,
        set.water_views,
        set.water_distance
            .unwrap_or_else(|| depth_range(rig, outer, index_water)),
        set.seed,
        &inside(rig),
    );
    let water = dir.join("water");
    let scene = Scene {
        rig: rig.clone(),
        board: board.clone(),
        poses,
    };
    render_scene(&scene, options, bits, engine, &water, quiet)?;
    for (k, camera) in rig.cameras().iter().enumerate() {
        let dry = Rig::new(
            vec![flatport::model::RigCamera::new(
                &camera.name,
                camera.intrinsics,
                nalgebra::Matrix3::identity(),
                nalgebra::Vector3::zeros(),
            )?],
            flatport::model::Interface::new(nalgebra::Vector3::z(), 0.01, vec![], 1.0, 1.0)?,
        )?;
        let poses = board_poses(
            &dry,
            &grid,
            set.air_views,
            depth_range(&dry, outer, 1.0),
            set.seed.wrapping_add(1 + k as u64),
            &inside(&dry),
        );
        let truth_dir = dir.join("air-truth").join(&camera.name);
        let scene = Scene {
            rig: dry,
            board: board.clone(),
            poses,
        };
        // The imaging effects' own draws for each camera's in-air views (their image indices
        // repeat the water views' and the other cameras'); nothing changes without them.
        let air_options = RenderOptions {
            imaging: Imaging {
                seed: options
                    .imaging
                    .seed
                    .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                    .wrapping_add(1 + k as u64),
                ..options.imaging
            },
            ..options.clone()
        };
        render_scene(&scene, &air_options, bits, engine, &truth_dir, quiet)?;
        let air = dir.join("air");
        std::fs::create_dir_all(&air)
            .with_context(|| format!("cannot create {}", air.display()))?;
        let target = air.join(&camera.name);
        if target.exists() {
            std::fs::remove_dir_all(&target)
                .with_context(|| format!("cannot replace {}", target.display()))?;
        }
        std::fs::rename(truth_dir.join(&camera.name), &target)
            .with_context(|| format!("cannot move the in-air views to {}", target.display()))?;
    }
    Ok(())
}
