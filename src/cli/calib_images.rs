//! `flatport calibrate --images DIR --board BOARD.json --port surface|shared|housings`: a whole
//! rig from images or videos of a board: every camera's lens in air, then the extrinsics and the
//! ports under water (DESIGN.md §3c).

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, bail};
use image::GrayImage;
use nalgebra::Point2;
use rayon::prelude::*;

use flatport::calib::pipeline::boards::{
    BoardsCalibration, BoardsOptions, PortKind, RigSetup, WaterFrame, calibrate_from_boards,
};
use flatport::calib::pipeline::intrinsics::{
    AirView, IntrinsicsFit, IntrinsicsOptions, calibrate_intrinsics,
};
use flatport::calib::pipeline::selection::{describe_image, spread};
use flatport::calib::{Board, Options};
use flatport::detect::board::BoardSpec;
use flatport::detect::{BoardCorners, Found, find_corners, resolve_view};
use flatport::io::frames::{FrameSelection, FrameSource, check_synchronized, open_cameras};
use flatport::io::{read_board, read_rig, write_boards_report, write_rig};
use flatport::model::{Layer, PinholeCamera};

use super::calib::{
    CalibrateArgs, CalibrationStatus, PortArg, backend, calibration_engine, summary,
};
use super::progress::Progress;

/// Largest number of in-air views per camera used by default (`--max-frames`); more add little
/// to a lens and cost time.
pub const DEFAULT_MAX_AIR_VIEWS: usize = 40;
/// Largest number of underwater frames used by default.
pub const DEFAULT_MAX_WATER_FRAMES: usize = 60;
/// Without `--frame-step`, the step keeps the frames detected to about this many times the cap.
const DETECT_PER_KEPT: usize = 4;

/// One camera's corners in one frame, ((corner index, pixel)), empty where the board was not
/// found.
type FrameCorners = Vec<(usize, Point2<f64>)>;

/// `--glass`: `T:N` for every port, or `CAMERA=T:N` for one camera's housing.
#[derive(Debug, Clone, PartialEq)]
pub struct GlassArg {
    /// The camera it is for; `None`: every port.
    pub camera: Option<String>,
    /// Thickness, metres.
    pub thickness: f64,
    /// Refractive index.
    pub index: f64,
}

/// Parses `T:N` or `CAMERA=T:N`.
pub fn parse_glass(text: &str) -> Result<GlassArg, String> {
    let (camera, rest) = match text.split_once('=') {
        Some((c, r)) => (Some(c.trim().to_string()), r),
        None => (None, text),
    };
    let error = || {
        format!(
            "expected THICKNESS:INDEX (metres, e.g. 0.01:1.49) or CAMERA=THICKNESS:INDEX, got '{text}'"
        )
    };
    let (t, n) = rest.split_once(':').ok_or_else(error)?;
    let thickness: f64 = t.trim().parse().map_err(|_| error())?;
    let index: f64 = n.trim().parse().map_err(|_| error())?;
    if !(thickness > 0.0 && thickness < 1.0) {
        return Err(format!(
            "'{text}': a glass thickness between 0 and 1 m (in metres: 10 mm is 0.01)"
        ));
    }
    if !(1.0..=4.0).contains(&index) {
        return Err(format!("'{text}': a refractive index from 1 to 4"));
    }
    if camera.as_deref() == Some("") {
        return Err(error());
    }
    Ok(GlassArg {
        camera,
        thickness,
        index,
    })
}

/// The run of `flatport calibrate --images`.
pub fn run(args: &CalibrateArgs, dir: &Path) -> anyhow::Result<()> {
    let board_path = args.board.as_ref().context(
        "--images needs --board BOARD.json (the board's description, see docs/images.md)",
    )?;
    let spec = read_board(board_path)?;
    let board = spec.corner_grid();
    let port = match args.port {
        Some(PortArg::Surface) => PortKind::Surface,
        Some(PortArg::Shared) => PortKind::Shared,
        Some(PortArg::Housings) => PortKind::Housings,
        None => bail!(
            "--images needs --port: surface (one bare water surface in front of every camera), shared (one port with its glass in front of every camera) or housings (a port per camera)"
        ),
    };
    // The cameras: water/<camera>/ (synchronized), and air/<camera>/ or the rig's.
    let water_dir = dir.join("water");
    if !water_dir.is_dir() {
        bail!(
            "{}: no water/ folder: --images DIR holds water/<camera>/ (synchronized frames under water, one folder per camera) and air/<camera>/ (in-air views), see docs/calibration.md",
            dir.display()
        );
    }
    let mut water = open_cameras(&water_dir)?;
    if let Some(master) = &args.master {
        let k = water
            .iter()
            .position(|(n, _)| n == master)
            .with_context(|| {
                format!(
                    "--master {master}: no camera folder of that name in {} (cameras: {})",
                    water_dir.display(),
                    water
                        .iter()
                        .map(|(n, _)| n.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            })?;
        let first = water.remove(k);
        water.insert(0, first);
    }
    let names: Vec<String> = water.iter().map(|(n, _)| n.clone()).collect();
    let count = check_synchronized(&water_dir, &water)?;
    let glass = glass_per_camera(&args.glass, &names, port)?;
    let index_water = args.index_water.unwrap_or(1.333);
    let index_air = args.index_air.unwrap_or(1.0);
    eprintln!(
        "cameras: {} (master {}); port: {}; board: {} {}x{} corners of {} mm",
        names.join(", "),
        names[0],
        port.name(),
        spec.kind(),
        board.cols,
        board.rows,
        board.square * 1e3
    );
    // In-air intrinsics, or the rig's cameras.
    let (cameras, fits) = match &args.rig {
        Some(path) => (cameras_from_rig(path, &names)?, Vec::new()),
        None => air_intrinsics(args, dir, &names, &spec, &board)?,
    };
    for ((name, source), camera) in water.iter().zip(&cameras) {
        let (w, h) = source.size();
        if (w, h) != (camera.width, camera.height) {
            bail!(
                "{}: frames of {w}x{h} pixels, but camera '{name}' was calibrated at {}x{}",
                source.folder().display(),
                camera.width,
                camera.height
            );
        }
    }
    // Underwater frames.
    let cap = args
        .max_frames
        .map_or(DEFAULT_MAX_WATER_FRAMES, |m| m as usize);
    let selection = frame_selection(
        args.frame_step.map(|s| s as usize),
        count,
        cap,
        "underwater",
    );
    let frames = water_frames(&water, &selection, &spec, &board, args.quiet)?;
    let described: Vec<_> = frames
        .iter()
        .map(|f| {
            let descriptions = f
                .corners
                .iter()
                .zip(&cameras)
                .map(|(c, cam)| describe_image(&board, c, cam.width, cam.height))
                .collect();
            (descriptions, f.corners.iter().map(Vec::len).sum())
        })
        .collect();
    let seen_by_two = frames
        .iter()
        .filter(|f| f.corners.iter().filter(|c| !c.is_empty()).count() >= 2)
        .count();
    let chosen = spread(&described, cap);
    eprintln!(
        "underwater: the board in {} of {} frames ({} seen by two or more cameras); {} frames used{}",
        frames
            .iter()
            .filter(|f| f.corners.iter().any(|c| !c.is_empty()))
            .count(),
        frames.len(),
        seen_by_two,
        chosen.len(),
        if chosen.len() < frames.len() {
            format!(" (spread over the images and the board's poses, --max-frames {cap})")
        } else {
            String::new()
        }
    );
    let frames: Vec<WaterFrame> = chosen.into_iter().map(|f| frames[f].clone()).collect();
    let setup = RigSetup {
        cameras,
        port,
        glass,
        index_air,
        index_water,
    };
    let engine = calibration_engine(&args.engine)?;
    eprintln!("device: {}", engine.describe());
    let options = BoardsOptions {
        calibration: Options {
            huber: args.huber.or(BoardsOptions::default().calibration.huber),
            max_iterations: args.max_iterations,
            max_rms_px: args.max_rms_px,
            max_tilt: args.max_tilt_deg.to_radians(),
            backend: backend(engine),
            ..Options::default()
        },
        holdout: args.holdout,
        ..BoardsOptions::default()
    };
    eprintln!(
        "calibrating the extrinsics and {} from {} frames ({} % held out)...",
        match port {
            PortKind::Surface => "the water surface".to_string(),
            PortKind::Shared => "the shared port".to_string(),
            PortKind::Housings => format!("{} housings' ports", names.len()),
        },
        frames.len(),
        (100.0 * args.holdout).round()
    );
    let mut status = CalibrationStatus::new();
    let result = calibrate_from_boards(&names, &setup, &board, &frames, &options, &mut |p| {
        status.update(p)
    });
    status.finish();
    let result = result?;
    print_result(&result, &names);
    if let Some(path) = &args.report {
        write_boards_report(path, &result, &names, &fits)?;
    }
    let report = &result.calibration.report;
    if !report.fits {
        bail!(
            "the calibration does not fit: the reprojection RMS is {:.2} px in the worst camera. What the data look like: {}. {} not written{}",
            report.worst_inlier_rms_px(),
            report.diagnosis.join("; "),
            args.output.display(),
            args.report.as_ref().map_or(String::new(), |p| format!(
                "; the report is in {}",
                p.display()
            ))
        );
    }
    if let Some(path) = &args.truth {
        let truth = flatport::io::read_truth(path)?;
        outln!(
            "{}",
            super::calib::truth_errors(&result.calibration.rig, &truth, path)?
        );
    }
    write_rig(&args.output, &result.calibration.rig)?;
    outln!(
        "wrote {}{}",
        args.output.display(),
        args.report
            .as_ref()
            .map_or(String::new(), |p| format!(", {}", p.display()))
    );
    Ok(())
}

/// The glass of each camera's port from `--glass` (`T:N` for all, `CAMERA=T:N` for one).
fn glass_per_camera(
    glass: &[GlassArg],
    names: &[String],
    port: PortKind,
) -> anyhow::Result<Vec<Vec<Layer>>> {
    let mut per_camera = vec![Vec::new(); names.len()];
    for g in glass {
        let layer = Layer {
            thickness: g.thickness,
            index: g.index,
        };
        match (&g.camera, port) {
            (_, PortKind::Surface) => bail!(
                "--glass: --port surface is a bare water surface, without glass (use --port shared for a window)"
            ),
            (Some(camera), PortKind::Shared) => bail!(
                "--glass {camera}=...: with --port shared one port is in front of every camera; give --glass THICKNESS:INDEX"
            ),
            (Some(camera), PortKind::Housings) => {
                let k = names.iter().position(|n| n == camera).with_context(|| {
                    format!(
                        "--glass {camera}=...: no camera '{camera}' (cameras: {})",
                        names.join(", ")
                    )
                })?;
                per_camera[k] = vec![layer];
            }
            (None, _) => {
                for layers in &mut per_camera {
                    if layers.is_empty() {
                        *layers = vec![layer];
                    }
                }
            }
        }
    }
    Ok(per_camera)
}

/// The intrinsics of `names` from the rig file at `path`.
fn cameras_from_rig(path: &Path, names: &[String]) -> anyhow::Result<Vec<PinholeCamera>> {
    let rig = read_rig(path)?;
    names
        .iter()
        .map(|name| {
            rig.camera_index(name)
                .map(|k| rig.cameras()[k].intrinsics.clone())
                .with_context(|| {
                    format!(
                        "{}: no camera '{name}' (the camera folders name the cameras; the rig has {})",
                        path.display(),
                        rig.cameras().iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join(", ")
                    )
                })
        })
        .collect()
}

/// The step over `count` frames: `--frame-step`, else the smallest that detects at most about
/// [`DETECT_PER_KEPT`] × `cap` frames.
fn frame_selection(step: Option<usize>, count: usize, cap: usize, what: &str) -> FrameSelection {
    let step = step.unwrap_or_else(|| {
        let step = count.div_ceil(DETECT_PER_KEPT * cap).max(1);
        if step > 1 {
            eprintln!("{what}: {count} frames, every {step}th read (--frame-step to choose)");
        }
        step
    });
    FrameSelection {
        step,
        ..FrameSelection::ALL
    }
}

/// The corners of `spec` in one grey image: (corner index, pixel), empty where it was not found.
fn corners_in(image: &GrayImage, spec: &BoardSpec, board: &Board, name: &str) -> FrameCorners {
    match find_corners(image, spec) {
        Ok(BoardCorners::Charuco(corners)) => corners,
        Ok(BoardCorners::Chessboard(detection)) => {
            let found = Found::new(image, board, detection);
            let orderings = found.detection.orderings.clone();
            match resolve_view(board, &[name.to_string()], None, &[Some(found)]) {
                Ok(chosen) => chosen[0]
                    .map(|(o, _)| orderings[o].iter().copied().enumerate().collect())
                    .unwrap_or_default(),
                Err(_) => Vec::new(),
            }
        }
        Err(_) => Vec::new(),
    }
}

/// Reads `source`'s `selection` and finds the board in each frame, in parallel batches.
fn detect_frames(
    source: &FrameSource,
    selection: &FrameSelection,
    spec: &BoardSpec,
    board: &Board,
    name: &str,
    progress: &mut Progress,
    done: &AtomicUsize,
    total: usize,
) -> anyhow::Result<Vec<(usize, FrameCorners)>> {
    let batch = 2 * rayon::current_num_threads().max(1);
    let mut out = Vec::new();
    let mut pending: Vec<(usize, GrayImage)> = Vec::with_capacity(batch);
    let mut flush = |pending: &mut Vec<(usize, GrayImage)>,
                     out: &mut Vec<(usize, FrameCorners)>| {
        let found: Vec<(usize, FrameCorners)> = pending
            .par_iter()
            .map(|(i, image)| (*i, corners_in(image, spec, board, name)))
            .collect();
        out.extend(found);
        done.fetch_add(pending.len(), Ordering::Relaxed);
        progress.update(done.load(Ordering::Relaxed), total);
        pending.clear();
    };
    for frame in source.frames(selection)? {
        let (i, image) = frame?;
        pending.push((i, image));
        if pending.len() == batch {
            flush(&mut pending, &mut out);
        }
    }
    flush(&mut pending, &mut out);
    Ok(out)
}

/// Every camera's lens from `DIR/air/<camera>/`.
fn air_intrinsics(
    args: &CalibrateArgs,
    dir: &Path,
    names: &[String],
    spec: &BoardSpec,
    board: &Board,
) -> anyhow::Result<(Vec<PinholeCamera>, Vec<(String, IntrinsicsFit)>)> {
    let air_dir = dir.join("air");
    if !air_dir.is_dir() {
        bail!(
            "{}: no air/ folder: the cameras' in-air views go in air/<camera>/ (or give --rig RIG.json with the cameras calibrated in air)",
            dir.display()
        );
    }
    let air = open_cameras(&air_dir)?;
    let missing: Vec<&str> = names
        .iter()
        .filter(|n| !air.iter().any(|(a, _)| a == *n))
        .map(String::as_str)
        .collect();
    if !missing.is_empty() {
        bail!(
            "{}: no folder for camera(s) {} (water/ has {}; air/ has {})",
            air_dir.display(),
            missing.join(", "),
            names.join(", "),
            air.iter()
                .map(|(n, _)| n.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let cap = args
        .max_frames
        .map_or(DEFAULT_MAX_AIR_VIEWS, |m| m as usize);
    let mut cameras = Vec::new();
    let mut fits = Vec::new();
    for name in names {
        let source = &air
            .iter()
            .find(|(a, _)| a == name)
            .expect("checked above")
            .1;
        let (width, height) = source.size();
        let selection = frame_selection(
            args.frame_step.map(|s| s as usize),
            source.len(),
            cap,
            &format!("air/{name}"),
        );
        let total = selection
            .indices(source.len())
            .map(|i| i.count())
            .unwrap_or(0);
        let mut progress = Progress::new(&format!("air/{name}: detecting"), "images", args.quiet);
        let done = AtomicUsize::new(0);
        let detected = detect_frames(
            source,
            &selection,
            spec,
            board,
            name,
            &mut progress,
            &done,
            total,
        )?;
        let described: Vec<_> = detected
            .iter()
            .map(|(_, c)| (vec![describe_image(board, c, width, height)], c.len()))
            .collect();
        let chosen = spread(&described, cap);
        let views: Vec<AirView> = chosen
            .iter()
            .map(|&v| AirView {
                label: source.frame_name(detected[v].0),
                corners: detected[v].1.clone(),
            })
            .collect();
        eprintln!(
            "air/{name}: the board in {} of {} images, {} used; {}",
            described.iter().filter(|d| d.0[0].is_some()).count(),
            detected.len(),
            views.len(),
            source.describe()
        );
        let fit = calibrate_intrinsics(
            name,
            width,
            height,
            board,
            &views,
            &IntrinsicsOptions::default(),
        )
        .with_context(|| {
            format!(
                "{}: the in-air calibration of camera '{name}'",
                source.folder().display()
            )
        })?;
        print_intrinsics(name, &fit);
        cameras.push(fit.camera.clone());
        fits.push((name.clone(), fit));
    }
    Ok((cameras, fits))
}

/// Every synchronized frame's corners in every camera.
fn water_frames(
    water: &[(String, FrameSource)],
    selection: &FrameSelection,
    spec: &BoardSpec,
    board: &Board,
    quiet: bool,
) -> anyhow::Result<Vec<WaterFrame>> {
    let per_camera = selection
        .indices(water[0].1.len())
        .map(|i| i.count())
        .unwrap_or(0);
    let total = per_camera * water.len();
    let mut progress = Progress::new("water: detecting", "images", quiet);
    let done = AtomicUsize::new(0);
    let mut detected = Vec::new();
    for (name, source) in water {
        detected.push(detect_frames(
            source,
            selection,
            spec,
            board,
            name,
            &mut progress,
            &done,
            total,
        )?);
    }
    let frames = detected[0]
        .iter()
        .enumerate()
        .map(|(j, (index, _))| WaterFrame {
            label: water[0].1.frame_name(*index),
            corners: detected.iter().map(|d| d[j].1.clone()).collect(),
        })
        .collect();
    Ok(frames)
}

fn print_intrinsics(name: &str, fit: &IntrinsicsFit) {
    let c = &fit.camera;
    let s = &fit.std;
    outln!(
        "{name}: fx {:.2} ± {:.2}, fy {:.2} ± {:.2}, cx {:.2} ± {:.2}, cy {:.2} ± {:.2} px; distortion [{}]; RMS {:.3} px over {} views ({})",
        c.fx,
        s[0],
        c.fy,
        s[1],
        c.cx,
        s[2],
        c.cy,
        s[3],
        c.distortion
            .iter()
            .map(|d| format!("{d:.5}"))
            .collect::<Vec<_>>()
            .join(", "),
        fit.rms_px,
        fit.view_rms_px.iter().filter(|r| r.is_some()).count(),
        fit.model.reason
    );
    for (v, why) in fit.outliers.iter().chain(&fit.excluded) {
        outln!("  {name}: view {v} left out: {why}");
    }
}

fn print_result(result: &BoardsCalibration, names: &[String]) {
    for link in &result.links {
        if link.camera != 0 {
            eprintln!(
                "extrinsics start: {} from {} ({} shared frames)",
                names[link.camera], names[link.via], link.frames
            );
        }
    }
    for line in &result.left_out {
        eprintln!("{line}");
    }
    for (label, why) in &result.dropped {
        outln!("frame {label} dropped as an outlier: {why}");
    }
    out!("{}", summary(&result.calibration.report));
    if let Some(v) = &result.validation {
        outln!(
            "held out {} frames: reprojection RMS {:.3} px; {} neighbouring corners triangulated: median error {:.3} mm ({:.3} % of the square), RMS {:.3} mm",
            v.frames.len(),
            v.rms_px,
            v.distances,
            v.median_error_m * 1e3,
            v.median_error_percent,
            v.rms_error_m * 1e3
        );
    }
    if let Some(choice) = &result.intrinsics {
        outln!("intrinsics: {}", choice.reason);
    }
}
