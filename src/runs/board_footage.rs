//! Footage of a board for `calibrate --images` (DESIGN.md §3c): `DIR/air/<camera>/` (each camera's
//! own views in air) and `DIR/water/<camera>/` (synchronized frames under water), each folder
//! images or one video ([`frames`](crate::io::frames)); the board found in every frame read
//! ([`find_corners`]), in parallel batches, and the frames to use chosen for spread over the image
//! and the board's poses ([`spread`]).

use std::path::Path;

use image::GrayImage;
use nalgebra::Point2;
use rayon::prelude::*;

use crate::base::board_spec::BoardSpec;
use crate::calib::Board;
use crate::calib::pipeline::boards::WaterFrame;
use crate::calib::pipeline::intrinsics::AirView;
use crate::calib::pipeline::selection::{describe_image, spread};
use crate::detect::{BoardCorners, Found, find_corners, resolve_view};
use crate::io::IoError;
use crate::io::frames::{FrameSelection, FrameSource, check_synchronized, open_cameras};

/// Largest number of in-air views per camera used by default; more add little to a lens and
/// cost time.
pub const DEFAULT_MAX_AIR_VIEWS: usize = 40;
/// Largest number of underwater frames used by default.
pub const DEFAULT_MAX_WATER_FRAMES: usize = 60;
/// Without a frame step, the step keeps the frames read to about this many times the cap.
pub const READ_PER_KEPT: usize = 4;

/// How to read the footage.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FootageOptions {
    /// The master camera's folder name (`None`: the first by name).
    pub master: Option<String>,
    /// Read every n-th frame (`None`: 1, or as many as keep about [`READ_PER_KEPT`] × the cap).
    pub frame_step: Option<usize>,
    /// Most in-air views used per camera.
    pub max_air_views: usize,
    /// Most underwater frames used.
    pub max_water_frames: usize,
    /// Read `air/` (false: the cameras' in-air calibration comes from elsewhere).
    pub air: bool,
}

impl Default for FootageOptions {
    fn default() -> Self {
        Self {
            master: None,
            frame_step: None,
            max_air_views: DEFAULT_MAX_AIR_VIEWS,
            max_water_frames: DEFAULT_MAX_WATER_FRAMES,
            air: true,
        }
    }
}

/// One camera's footage.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFootage {
    /// Its name (the folder's).
    pub name: String,
    /// Image size, pixels.
    pub width: u32,
    /// Image size, pixels.
    pub height: u32,
    /// The in-air views chosen (empty without `air/`).
    pub air: Vec<AirView>,
    /// In-air images read, and in how many the board was found.
    pub air_read: (usize, usize),
}

/// The footage of a rig, its board found.
#[derive(Debug, Clone, PartialEq)]
pub struct Footage {
    /// The cameras, the master first.
    pub cameras: Vec<CameraFootage>,
    /// The underwater frames chosen, corners per camera in [`Footage::cameras`]' order.
    pub water: Vec<WaterFrame>,
    /// Underwater frames read, with the board in some camera, and in two or more.
    pub water_read: (usize, usize, usize),
    /// What was chosen and why, a line each (frame steps, caps), for the caller to show.
    pub notes: Vec<String>,
    /// Whether each image numbered the board's corners on its own, so that the cameras of a
    /// frame may start from different ends (a chessboard; ChArUco corners carry their ids):
    /// [`BoardsOptions::turnable`](crate::calib::pipeline::boards::BoardsOptions::turnable).
    pub turnable: bool,
}

impl Footage {
    /// The camera names, the master first.
    pub fn names(&self) -> Vec<String> {
        self.cameras.iter().map(|c| c.name.clone()).collect()
    }

    /// Every camera's in-air corners (pixels), in [`Footage::cameras`]' order: where the board
    /// fell in air, for the report's coverage pictures.
    pub fn air_corners(&self) -> Vec<Vec<Point2<f64>>> {
        self.cameras
            .iter()
            .map(|c| {
                c.air
                    .iter()
                    .flat_map(|v| v.corners.iter().map(|(_, p)| *p))
                    .collect()
            })
            .collect()
    }
}

/// Reads the footage under `dir` and finds `spec` in every frame read; `progress(what, done,
/// total)` after every batch.
///
/// Errors (each naming the folder or file): no `water/` (or `air/` when asked for), a camera of
/// `water/` missing from `air/`, synchronized cameras whose frame counts differ, an unknown
/// `master`, frames of another size than the camera's in-air views, and every error of the frame
/// readers (an image that cannot be read, a video that cannot be decoded, no ffmpeg).
pub fn read_board_footage(
    dir: &Path,
    spec: &BoardSpec,
    options: &FootageOptions,
    progress: &mut dyn FnMut(&str, usize, usize),
) -> Result<Footage, IoError> {
    let invalid = |path: &Path, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field: String::new(),
        reason,
    };
    let board = spec.corner_grid();
    let water_dir = dir.join("water");
    if !water_dir.is_dir() {
        return Err(invalid(
            dir,
            "no water/ folder: the footage holds water/<camera>/ (synchronized frames under water, one folder per camera) and air/<camera>/ (each camera's in-air views)".into(),
        ));
    }
    let mut water = open_cameras(&water_dir)?;
    if let Some(master) = &options.master {
        let k = water.iter().position(|(n, _)| n == master).ok_or_else(|| {
            let names: Vec<&str> = water.iter().map(|(n, _)| n.as_str()).collect();
            invalid(
                &water_dir,
                format!(
                    "no camera folder '{master}' for the master (cameras: {})",
                    names.join(", ")
                ),
            )
        })?;
        let first = water.remove(k);
        water.insert(0, first);
    }
    let count = check_synchronized(&water_dir, &water)?;
    let mut notes = Vec::new();
    let mut cameras: Vec<CameraFootage> = water
        .iter()
        .map(|(name, source)| {
            let (width, height) = source.size();
            CameraFootage {
                name: name.clone(),
                width,
                height,
                air: Vec::new(),
                air_read: (0, 0),
            }
        })
        .collect();
    if options.air {
        read_air(
            dir,
            spec,
            &board,
            options,
            &mut cameras,
            &mut notes,
            progress,
        )?;
    }
    // Underwater frames.
    let cap = options.max_water_frames;
    let selection = frame_selection(options.frame_step, count, cap, "water", &mut notes);
    let total = selection.indices(count).map_or(0, |i| i.count()) * water.len();
    let mut done = 0;
    let mut detected = Vec::new();
    for (name, source) in &water {
        detected.push(detect_frames(
            source,
            &selection,
            spec,
            &board,
            name,
            &mut |n| {
                done += n;
                progress("water: finding the board", done, total);
            },
        )?);
    }
    let frames: Vec<WaterFrame> = detected[0]
        .iter()
        .enumerate()
        .map(|(j, (index, _))| WaterFrame {
            label: water[0].1.frame_name(*index),
            corners: detected.iter().map(|d| d[j].1.clone()).collect(),
        })
        .collect();
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
    let seen = |f: &WaterFrame, n: usize| f.corners.iter().filter(|c| !c.is_empty()).count() >= n;
    let water_read = (
        frames.len(),
        frames.iter().filter(|f| seen(f, 1)).count(),
        frames.iter().filter(|f| seen(f, 2)).count(),
    );
    let chosen = spread(&described, cap);
    if chosen.len() < water_read.1 {
        notes.push(format!(
            "water: {} of the {} frames with the board used, spread over the images and the board's poses (at most {cap})",
            chosen.len(),
            water_read.1
        ));
    }
    Ok(Footage {
        cameras,
        water: chosen.into_iter().map(|f| frames[f].clone()).collect(),
        water_read,
        notes,
        turnable: matches!(spec, BoardSpec::Chessboard(_)),
    })
}

/// Every camera's in-air views of `board` from `dir/air/<camera>/`, chosen for spread.
fn read_air(
    dir: &Path,
    spec: &BoardSpec,
    board: &Board,
    options: &FootageOptions,
    cameras: &mut [CameraFootage],
    notes: &mut Vec<String>,
    progress: &mut dyn FnMut(&str, usize, usize),
) -> Result<(), IoError> {
    let air_dir = dir.join("air");
    let invalid = |path: &Path, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field: String::new(),
        reason,
    };
    if !air_dir.is_dir() {
        return Err(invalid(
            dir,
            "no air/ folder: each camera's in-air views of the board go in air/<camera>/ (or give the cameras' in-air calibration as a rig)".into(),
        ));
    }
    let air = open_cameras(&air_dir)?;
    let names: Vec<&str> = air.iter().map(|(n, _)| n.as_str()).collect();
    let missing: Vec<&str> = cameras
        .iter()
        .map(|c| c.name.as_str())
        .filter(|n| !names.contains(n))
        .collect();
    if !missing.is_empty() {
        return Err(invalid(
            &air_dir,
            format!(
                "no folder for camera(s) {} (water/ has {}; air/ has {})",
                missing.join(", "),
                cameras
                    .iter()
                    .map(|c| c.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
                names.join(", ")
            ),
        ));
    }
    let cap = options.max_air_views;
    for camera in cameras.iter_mut() {
        let Some((_, source)) = air.iter().find(|(a, _)| *a == camera.name) else {
            continue;
        };
        if source.size() != (camera.width, camera.height) {
            let (w, h) = source.size();
            return Err(invalid(
                source.folder(),
                format!(
                    "in-air images of {w}x{h} pixels, but the camera's underwater frames are {}x{}: a camera keeps its resolution",
                    camera.width, camera.height
                ),
            ));
        }
        let what = format!("air/{}", camera.name);
        let selection = frame_selection(options.frame_step, source.len(), cap, &what, notes);
        let total = selection.indices(source.len()).map_or(0, |i| i.count());
        let mut done = 0;
        let label = format!("{what}: finding the board");
        let detected = detect_frames(source, &selection, spec, board, &camera.name, &mut |n| {
            done += n;
            progress(&label, done, total);
        })?;
        let described: Vec<_> = detected
            .iter()
            .map(|(_, c)| {
                (
                    vec![describe_image(board, c, camera.width, camera.height)],
                    c.len(),
                )
            })
            .collect();
        let found = described.iter().filter(|d| d.0[0].is_some()).count();
        let chosen = spread(&described, cap);
        if chosen.len() < found {
            notes.push(format!(
                "{what}: {} of the {found} views with the board used, spread over the image and the board's poses (at most {cap})",
                chosen.len()
            ));
        }
        camera.air_read = (detected.len(), found);
        camera.air = chosen
            .iter()
            .map(|&v| AirView {
                label: source.frame_name(detected[v].0),
                corners: detected[v].1.clone(),
            })
            .collect();
    }
    Ok(())
}

/// The step over `count` frames: `step`, else the smallest that reads at most about
/// [`READ_PER_KEPT`] × `cap` frames (noted when above 1).
fn frame_selection(
    step: Option<usize>,
    count: usize,
    cap: usize,
    what: &str,
    notes: &mut Vec<String>,
) -> FrameSelection {
    let step = step.unwrap_or_else(|| {
        let step = count.div_ceil(READ_PER_KEPT * cap.max(1)).max(1);
        if step > 1 {
            notes.push(format!(
                "{what}: {count} frames, every {step}th read (a frame step chooses)"
            ));
        }
        step
    });
    FrameSelection {
        step,
        ..FrameSelection::ALL
    }
}

/// The corners of `spec` in one grey image: (corner index, pixel), empty where it was not found.
/// A chessboard's corner 0 by the colour and image rules of [`crate::detect`].
pub fn corners_in(
    image: &GrayImage,
    spec: &BoardSpec,
    board: &Board,
    name: &str,
) -> Vec<(usize, Point2<f64>)> {
    match find_corners(image, spec) {
        Ok(BoardCorners::Charuco(corners)) => corners,
        Ok(BoardCorners::Chessboard(detection)) => {
            let found = Found::new(image, board, detection);
            let detection = found.detection.clone();
            match resolve_view(board, &[name.to_string()], None, &[Some(found)]) {
                // The chosen ordering's corners, those the image did not place left out.
                Ok(chosen) => chosen[0]
                    .map(|(o, _)| {
                        let observed = detection.observed(o).into_iter().enumerate();
                        observed.filter_map(|(i, p)| p.map(|p| (i, p))).collect()
                    })
                    .unwrap_or_default(),
                Err(_) => Vec::new(),
            }
        }
        Err(_) => Vec::new(),
    }
}

/// A frame's index and its labelled corners (id, pixel).
type FrameCorners = (usize, Vec<(usize, Point2<f64>)>);

/// Reads `source`'s `selection` and finds the board in each frame, a batch of frames at a time
/// on every core (a video decodes in order); `done(n)` after each batch of n.
fn detect_frames(
    source: &FrameSource,
    selection: &FrameSelection,
    spec: &BoardSpec,
    board: &Board,
    name: &str,
    done: &mut dyn FnMut(usize),
) -> Result<Vec<FrameCorners>, IoError> {
    let batch = 2 * rayon::current_num_threads().max(1);
    let mut out = Vec::new();
    let mut pending: Vec<(usize, GrayImage)> = Vec::with_capacity(batch);
    let mut flush = |pending: &mut Vec<(usize, GrayImage)>, out: &mut Vec<_>| {
        let found: Vec<FrameCorners> = pending
            .par_iter()
            .map(|(i, image)| (*i, corners_in(image, spec, board, name)))
            .collect();
        out.extend(found);
        done(pending.len());
        pending.clear();
    };
    for frame in source.frames(selection)? {
        pending.push(frame?);
        if pending.len() == batch {
            flush(&mut pending, &mut out);
        }
    }
    flush(&mut pending, &mut out);
    Ok(out)
}
