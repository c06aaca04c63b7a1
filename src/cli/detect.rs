//! `flatport detect`: board corners (a chessboard or a ChArUco board) in every camera's images →
//! the observations file.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, bail};
use clap::Args;
use rayon::prelude::*;

use flatport::calib::Board;
use flatport::detect::{
    BoardSpec, CharucoSpec, Found, Miss, Rule, corners_by_id, detect_board, detect_charuco,
    resolve_view,
};
use flatport::io::overlay::{overlay, overlay_ids};
use flatport::io::{DetectedView, read_grey_image, read_rig, write_detections, write_rgb_jpeg};
use flatport::model::Rig;

use super::progress::Progress;

/// `flatport detect`
#[derive(Debug, Args)]
pub struct DetectArgs {
    /// Board: COLSxROWS@SQUARE, a chessboard by its inner corners per row × per column (OpenCV's
    /// patternSize) and the square in metres, or a BOARD.json (a chessboard or a ChArUco board,
    /// counted in squares: docs/images.md). A ChArUco board's corners carry OpenCV's ids, so
    /// partial views are kept (a corner not seen is null)
    #[arg(long, value_name = "COLSxROWS@M|BOARD.json", value_parser = parse_board_spec)]
    pub board: BoardSpec,
    /// A camera's images as CAMERA=GLOB (quote the glob), once per camera; the images of each
    /// camera are taken in sorted file-name order and the n-th images of all cameras form view n
    #[arg(long = "images", value_name = "CAMERA=GLOB", required = true, value_parser = parse_images)]
    pub images: Vec<(String, String)>,
    /// The observations file to write (JSON; the calibration's input)
    #[arg(long, short, value_name = "OBS.json")]
    pub output: PathBuf,
    /// Rig file (cameras calibrated in air, a guess of the port): the camera names must be the
    /// rig's, every image must have its camera's size, and on colour-symmetric boards the cameras
    /// of a view are paired by their rays
    #[arg(long, value_name = "RIG.json")]
    pub rig: Option<PathBuf>,
    /// Folder for overlays: every image with its corners, corner 0 and the row direction drawn
    #[arg(long, value_name = "DIR")]
    pub overlay: Option<PathBuf>,
    /// Replaced by --board BOARD.json, which gives the dictionary with the marker size (says so)
    #[arg(long, value_name = "DICT", hide = true)]
    pub charuco: Option<String>,
    /// No progress bar
    #[arg(long, short)]
    pub quiet: bool,
}

fn parse_images(text: &str) -> Result<(String, String), String> {
    match text.split_once('=') {
        Some((camera, glob)) if !camera.trim().is_empty() && !glob.is_empty() => {
            Ok((camera.trim().to_string(), glob.to_string()))
        }
        _ => Err(format!(
            "expected CAMERA=GLOB such as left='images/left/*.png', got '{text}'"
        )),
    }
}

/// The files of each camera, sorted by file name (then by path).
fn list_images(images: &[(String, String)]) -> anyhow::Result<Vec<Vec<PathBuf>>> {
    let mut lists = Vec::new();
    for (i, (camera, pattern)) in images.iter().enumerate() {
        if images[..i].iter().any(|(c, _)| c == camera) {
            bail!("--images names camera '{camera}' twice");
        }
        let paths = glob::glob(pattern)
            .with_context(|| format!("--images {camera}={pattern}: not a valid glob"))?;
        let mut files = Vec::new();
        for path in paths {
            let path = path.with_context(|| format!("--images {camera}={pattern}"))?;
            if path.is_file() {
                files.push(path);
            }
        }
        if files.is_empty() {
            bail!("--images {camera}={pattern}: no file matches");
        }
        files.sort_by(|a, b| a.file_name().cmp(&b.file_name()).then_with(|| a.cmp(b)));
        lists.push(files);
    }
    for (k, files) in lists.iter().enumerate().skip(1) {
        if files.len() != lists[0].len() {
            bail!(
                "camera '{}' has {} images and camera '{}' has {}: the images are paired by position, so every camera needs as many",
                images[0].0,
                lists[0].len(),
                images[k].0,
                files.len()
            );
        }
    }
    Ok(lists)
}

/// What one image gave (the image itself is read again for its overlay: memory stays bounded
/// whatever the number of images).
struct ImageResult {
    found: Result<Found, Miss>,
}

pub fn run(args: DetectArgs) -> anyhow::Result<()> {
    if let Some(dictionary) = &args.charuco {
        bail!(
            "--charuco {dictionary}: give the ChArUco board as a file instead, --board BOARD.json with \
             {{\"type\": \"charuco\", \"squares_x\": 7, \"squares_y\": 5, \"square_size\": 0.04, \"marker_size\": 0.03, \"dictionary\": \"{dictionary}\"}} \
             (squares, not inner corners; metres; docs/images.md)"
        );
    }
    let board = match &args.board {
        BoardSpec::Chessboard(board) => *board,
        BoardSpec::Charuco(spec) => return run_charuco(&args, spec),
    };
    let names: Vec<String> = args.images.iter().map(|(c, _)| c.clone()).collect();
    let rig: Option<Rig> = args.rig.as_deref().map(read_rig).transpose()?;
    let rig_cameras = rig
        .as_ref()
        .map(|rig| cameras_in_rig(rig, &names))
        .transpose()?;
    let files = list_images(&args.images)?;
    let views = files[0].len();
    // Sizes first, from the headers: a wrong image fails before any detection runs.
    check_sizes(&files, &names, rig.as_ref().zip(rig_cameras.as_deref()))?;
    let results: Vec<ImageResult> = detect_all(&files, args.quiet, |image| ImageResult {
        found: detect_board(image, &board).map(|d| Found::new(image, &board, d)),
    })?;
    let pair = rig.as_ref().zip(rig_cameras.as_deref());
    let resolved = resolve_views(&board, &names, &files, pair, &results);
    let left_out = write_detections(&args.output, &board, &names, &resolved.detected)?;
    let left_out: Vec<String> = left_out
        .iter()
        .map(|&i| {
            let v = resolved.kept_views[i];
            let saw: Vec<&str> = (0..names.len())
                .filter(|&k| resolved.detected[i][k].is_some())
                .map(|k| names[k].as_str())
                .collect();
            format!(
                "view {v} ({}): only {} found the board, and today's stereo observations file holds views both cameras saw",
                file_list(&files, v),
                saw.join(", ")
            )
        })
        .collect();
    if let Some(dir) = &args.overlay {
        write_overlays(
            dir,
            &board,
            &names,
            &files,
            &results,
            &resolved.chosen_per_image,
            &resolved.view_notes,
        )?;
    }
    for line in &resolved.misses {
        eprintln!("no board: {line}");
    }
    for line in &resolved.dropped {
        eprintln!("dropped: {line}");
    }
    for line in &resolved.unresolved {
        eprintln!("warning: corner 0 unresolved, view left out: {line}");
    }
    for line in &left_out {
        eprintln!("left out: {line}");
    }
    // Corners the grid missed (a speck on a corner), filled in from their neighbours.
    for v in 0..views {
        for (k, name) in names.iter().enumerate() {
            let Ok(found) = &results[v * names.len() + k].found else {
                continue;
            };
            let filled = &found.detection.filled;
            if filled.is_empty() {
                continue;
            }
            let unrefined = filled.iter().filter(|f| f.unrefined.is_some()).count();
            eprintln!(
                "filled: {} ({name}): {} corner(s) the grid missed, filled in from their neighbours{}",
                files[k][v].display(),
                filled.len(),
                if unrefined > 0 {
                    format!(
                        " ({unrefined} the image did not place: left out of the view, its other corners kept)"
                    )
                } else {
                    " and placed on the image".to_string()
                }
            );
        }
    }
    let per_camera: Vec<String> = names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let count = (0..views)
                .filter(|&v| results[v * names.len() + k].found.is_ok())
                .count();
            format!("{name} {count}/{views}")
        })
        .collect();
    let written = resolved.detected.len() - left_out.len();
    outln!(
        "boards found: {}; wrote {} of {views} views to {}{}",
        per_camera.join(", "),
        written,
        args.output.display(),
        if let Some(dir) = &args.overlay {
            format!(", overlays in {}", dir.display())
        } else {
            String::new()
        }
    );
    if written == 0 {
        bail!(
            "no view of the board in any camera could be used: {} holds no views",
            args.output.display()
        );
    }
    Ok(())
}

/// The rig's index of each camera `--images` names.
fn cameras_in_rig(rig: &Rig, names: &[String]) -> anyhow::Result<Vec<usize>> {
    names
        .iter()
        .map(|name| {
            rig.cameras()
                .iter()
                .position(|c| &c.name == name)
                .with_context(|| {
                    let known: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
                    format!(
                        "--images names camera '{name}', which the rig does not have (it has {})",
                        known.join(", ")
                    )
                })
        })
        .collect()
}

/// Every image of a camera has the size of the first, and of the rig's camera where a rig is
/// given (read from the headers only).
fn check_sizes(
    files: &[Vec<PathBuf>],
    names: &[String],
    rig: Option<(&Rig, &[usize])>,
) -> anyhow::Result<()> {
    for (k, list) in files.iter().enumerate() {
        let expected = rig.map(|(rig, indices)| {
            let i = &rig.cameras()[indices[k]].intrinsics;
            (i.width, i.height)
        });
        let mut first: Option<(u32, u32, &Path)> = None;
        for path in list {
            let size = flatport::io::image_size(path)?;
            if let Some((w, h)) = expected
                && size != (w, h)
            {
                bail!(
                    "{}: {}×{} pixels, but the rig's camera '{}' takes {w}×{h}",
                    path.display(),
                    size.0,
                    size.1,
                    names[k]
                );
            }
            match first {
                Some((w, h, other)) if size != (w, h) => bail!(
                    "{}: {}×{} pixels, but {} of the same camera '{}' has {w}×{h}",
                    path.display(),
                    size.0,
                    size.1,
                    other.display(),
                    names[k]
                ),
                None => first = Some((size.0, size.1, path)),
                _ => {}
            }
        }
    }
    Ok(())
}

/// Runs `detect` on every image, view by view and camera by camera within a view (the order of
/// the results), on every core, with progress.
fn detect_all<T: Send>(
    files: &[Vec<PathBuf>],
    quiet: bool,
    detect: impl Fn(&image::GrayImage) -> T + Sync,
) -> anyhow::Result<Vec<T>> {
    let (cameras, views) = (files.len(), files[0].len());
    let jobs: Vec<(usize, usize)> = (0..views)
        .flat_map(|v| (0..cameras).map(move |k| (v, k)))
        .collect();
    let progress = Mutex::new(Progress::new("detect", "images", quiet));
    let done = AtomicUsize::new(0);
    jobs.par_iter()
        .map(|&(v, k)| {
            let path = &files[k][v];
            let image = read_grey_image(path)?;
            let found = detect(&image);
            let n = done.fetch_add(1, Ordering::Relaxed) + 1;
            if let Ok(mut p) = progress.lock() {
                p.update(n, jobs.len());
            }
            Ok(found)
        })
        .collect()
}

/// `--board`: COLSxROWS@SQUARE (a chessboard by its inner corners) or the path of a BOARD.json
/// (a value ending in `.json`, or an existing file).
pub fn parse_board_spec(text: &str) -> Result<BoardSpec, String> {
    let path = Path::new(text);
    if text.ends_with(".json") || path.is_file() {
        return flatport::io::read_board(path).map_err(|e| e.to_string());
    }
    super::calib::parse_board(text)
        .map(BoardSpec::Chessboard)
        .map_err(|e| format!("{e}, or the path of a BOARD.json"))
}

/// `flatport detect` with a ChArUco board: every corner comes with its id, so there is no corner 0
/// to resolve and a partial view is kept with `null` for the corners not seen.
fn run_charuco(args: &DetectArgs, spec: &CharucoSpec) -> anyhow::Result<()> {
    let grid = spec.corner_grid();
    let names: Vec<String> = args.images.iter().map(|(c, _)| c.clone()).collect();
    let rig: Option<Rig> = args.rig.as_deref().map(read_rig).transpose()?;
    let rig_cameras = rig
        .as_ref()
        .map(|rig| cameras_in_rig(rig, &names))
        .transpose()?;
    let files = list_images(&args.images)?;
    let views = files[0].len();
    check_sizes(&files, &names, rig.as_ref().zip(rig_cameras.as_deref()))?;
    let results = detect_all(&files, args.quiet, |image| detect_charuco(image, spec))?;
    let count = names.len();
    let mut detected: Vec<DetectedView> = Vec::new();
    let mut kept_views = Vec::new();
    for v in 0..views {
        for k in 0..count {
            if let Err(miss) = &results[v * count + k] {
                eprintln!("no board: {}: {miss}", files[k][v].display());
            }
        }
        let view: DetectedView = (0..count)
            .map(|k| {
                results[v * count + k]
                    .as_ref()
                    .ok()
                    .map(|corners| corners_by_id(corners, grid.corners()))
            })
            .collect();
        if view.iter().all(Option::is_none) {
            eprintln!(
                "dropped: view {v} ({}): no camera found the board",
                file_list(&files, v)
            );
            continue;
        }
        detected.push(view);
        kept_views.push(v);
    }
    let left_out = write_detections(&args.output, &grid, &names, &detected)?;
    for &i in &left_out {
        let v = kept_views[i];
        let saw: Vec<&str> = (0..count)
            .filter(|&k| detected[i][k].is_some())
            .map(|k| names[k].as_str())
            .collect();
        eprintln!(
            "left out: view {v} ({}): only {} found the board, and today's stereo observations file holds views both cameras saw",
            file_list(&files, v),
            saw.join(", ")
        );
    }
    let per_camera: Vec<String> = names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let found: Vec<usize> = (0..views)
                .filter_map(|v| results[v * count + k].as_ref().ok().map(Vec::len))
                .collect();
            format!(
                "{name} {}/{views} ({} corners)",
                found.len(),
                found.iter().sum::<usize>()
            )
        })
        .collect();
    if let Some(dir) = &args.overlay {
        write_charuco_overlays(dir, &grid, &names, &files, &results)?;
    }
    let written = detected.len() - left_out.len();
    outln!(
        "ChArUco boards found: {}; wrote {written} of {views} views to {}{}",
        per_camera.join(", "),
        args.output.display(),
        if let Some(dir) = &args.overlay {
            format!(", overlays in {}", dir.display())
        } else {
            String::new()
        }
    );
    if written == 0 {
        bail!(
            "no view of the board in any camera could be used: {} holds no views",
            args.output.display()
        );
    }
    Ok(())
}

/// The image files of view `v`, comma-separated.
fn file_list(files: &[Vec<PathBuf>], v: usize) -> String {
    files
        .iter()
        .map(|f| f[v].display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The views kept, with corner 0 resolved in each, and what was left out and why.
struct Resolved {
    detected: Vec<DetectedView>,
    /// The view number of each of `detected`.
    kept_views: Vec<usize>,
    dropped: Vec<String>,
    unresolved: Vec<String>,
    misses: Vec<String>,
    /// Per image (view-major): the ordering chosen and the rule that chose it.
    chosen_per_image: Vec<Option<(usize, Rule)>>,
    /// Per view: why corner 0 stayed unresolved.
    view_notes: Vec<Option<String>>,
}

/// Resolves corner 0 in every view where some camera found the board.
fn resolve_views(
    board: &Board,
    names: &[String],
    files: &[Vec<PathBuf>],
    rig: Option<(&Rig, &[usize])>,
    results: &[ImageResult],
) -> Resolved {
    let views = files[0].len();
    let mut resolved = Resolved {
        detected: Vec::new(),
        kept_views: Vec::new(),
        dropped: Vec::new(),
        unresolved: Vec::new(),
        misses: Vec::new(),
        chosen_per_image: vec![None; results.len()],
        view_notes: vec![None; views],
    };
    for v in 0..views {
        let found: Vec<Option<Found>> = (0..names.len())
            .map(|k| results[v * names.len() + k].found.clone().ok())
            .collect();
        for k in 0..names.len() {
            if let Err(miss) = &results[v * names.len() + k].found {
                resolved
                    .misses
                    .push(format!("{}: {miss}", files[k][v].display()));
            }
        }
        if found.iter().all(Option::is_none) {
            resolved.dropped.push(format!(
                "view {v} ({}): no camera found the board",
                file_list(files, v)
            ));
            continue;
        }
        match resolve_view(board, names, rig, &found) {
            Ok(chosen) => {
                let view: DetectedView = chosen
                    .iter()
                    .zip(&found)
                    .map(|(c, f)| c.and_then(|(o, _)| f.as_ref().map(|f| f.detection.observed(o))))
                    .collect();
                for (k, c) in chosen.iter().enumerate() {
                    resolved.chosen_per_image[v * names.len() + k] = *c;
                }
                resolved.detected.push(view);
                resolved.kept_views.push(v);
            }
            Err(why) => {
                resolved.view_notes[v] = Some(why.clone());
                resolved
                    .unresolved
                    .push(format!("view {v} ({}): {why}", file_list(files, v)));
            }
        }
    }
    resolved
}

/// What one image of a ChArUco board gave: its corners with their ids, or why none.
type CharucoResult = Result<Vec<(usize, nalgebra::Point2<f64>)>, Miss>;

/// One overlay per image of a ChArUco board: DIR/CAMERA/<file stem>.jpg, every corner found
/// with its id.
fn write_charuco_overlays(
    dir: &Path,
    grid: &Board,
    names: &[String],
    files: &[Vec<PathBuf>],
    results: &[CharucoResult],
) -> anyhow::Result<()> {
    for name in names {
        std::fs::create_dir_all(dir.join(name))
            .with_context(|| format!("cannot create {}", dir.join(name).display()))?;
    }
    let count = names.len();
    (0..results.len())
        .into_par_iter()
        .try_for_each(|i| -> anyhow::Result<()> {
            let (v, k) = (i / count, i % count);
            let path = &files[k][v];
            let image = read_grey_image(path)?;
            let stem = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| format!("view_{v:03}"));
            let (corners, caption, warning) = match &results[i] {
                Ok(corners) => (
                    corners.as_slice(),
                    format!(
                        "view {v}, {}: {} of {} ChArUco corners",
                        names[k],
                        corners.len(),
                        grid.corners()
                    ),
                    false,
                ),
                Err(miss) => (&[][..], format!("view {v}, {}: {miss}", names[k]), true),
            };
            let drawn = overlay_ids(&image, corners, grid.cols, &caption, warning);
            write_rgb_jpeg(&dir.join(&names[k]).join(format!("{stem}.jpg")), &drawn)?;
            Ok(())
        })
}

/// One overlay per image: DIR/CAMERA/<file stem>.jpg.
fn write_overlays(
    dir: &Path,
    board: &Board,
    names: &[String],
    files: &[Vec<PathBuf>],
    results: &[ImageResult],
    chosen: &[Option<(usize, Rule)>],
    notes: &[Option<String>],
) -> anyhow::Result<()> {
    for name in names {
        std::fs::create_dir_all(dir.join(name))
            .with_context(|| format!("cannot create {}", dir.join(name).display()))?;
    }
    let count = names.len();
    (0..results.len())
        .into_par_iter()
        .try_for_each(|i| -> anyhow::Result<()> {
            let (v, k) = (i / count, i % count);
            let path = &files[k][v];
            let image = read_grey_image(path)?;
            let stem = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| format!("view_{v:03}"));
            let (corners, caption, warning) = match (&results[i].found, chosen[i], &notes[v]) {
                (Ok(found), Some((o, rule)), _) => (
                    found.detection.orderings[o].clone(),
                    format!(
                        "view {v}, {}: {} corners, corner 0 by {}",
                        names[k],
                        board.corners(),
                        rule.name()
                    ),
                    false,
                ),
                (Ok(found), None, Some(why)) => (
                    found.detection.orderings[0].clone(),
                    format!("view {v}, {}: UNRESOLVED, left out: {why}", names[k]),
                    true,
                ),
                (Ok(found), None, None) => (
                    found.detection.orderings[0].clone(),
                    format!("view {v}, {}", names[k]),
                    true,
                ),
                (Err(miss), ..) => (Vec::new(), format!("view {v}, {}: {miss}", names[k]), true),
            };
            let drawn = overlay(&image, &corners, board.cols, &caption, warning);
            write_rgb_jpeg(&dir.join(&names[k]).join(format!("{stem}.jpg")), &drawn)?;
            Ok(())
        })
}
