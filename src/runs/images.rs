//! `calibrate --images` after the footage is read ([`super::board_footage`]): where each camera's
//! lens comes from (a rig file, its in-air views, or the underwater frames themselves), the glass
//! of each port, and the one calibration of the extrinsics and ports (DESIGN.md §3c). The command
//! line (`src/cli/calib_images.rs`) and Python's `calibrate_images` both run these steps, showing
//! their progress each in its own way.

use std::path::Path;

use thiserror::Error;

use super::board_footage::Footage;
use crate::base::Board;
use crate::calib::CalibError;
use crate::calib::Options;
use crate::calib::pipeline::boards::{
    BoardsCalibration, BoardsOptions, PortKind, RefineIntrinsics, RigSetup, calibrate_from_boards,
};
use crate::calib::pipeline::intrinsics::{IntrinsicsFit, IntrinsicsOptions, calibrate_intrinsics};
use crate::calib::pipeline::water_lenses::{calibrate_lenses_under_water, water_lens_start};
use crate::calib::pipeline::{Backend, Progress};
use crate::io::IoError;
use crate::model::{Layer, PinholeCamera, Rig};

/// Why the images route cannot go on: what the caller asked for does not match the footage, or
/// a file or a fit failed. Each message names the camera, the file or the value.
#[derive(Debug, Error)]
pub enum ImagesError {
    /// A file could not be read or written.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A calibration step failed.
    #[error(transparent)]
    Calib(#[from] CalibError),
    /// Glass given for a port that has none, or for one camera of a shared port.
    #[error("{0}")]
    Glass(String),
    /// Glass given for a camera the footage does not have.
    #[error("glass for camera '{camera}': no such camera (cameras: {cameras})")]
    GlassCamera {
        /// The camera named.
        camera: String,
        /// The footage's cameras, comma-separated.
        cameras: String,
    },
    /// A camera of the footage that the rig file lacks, or of another size.
    #[error("{rig}: {why}")]
    RigCamera {
        /// The rig file (or how the caller names the rig).
        rig: String,
        /// What does not match.
        why: String,
    },
    /// A camera's in-air calibration failed.
    #[error("the in-air calibration of camera '{camera}': {source}")]
    AirLens {
        /// The camera.
        camera: String,
        /// Why.
        source: CalibError,
    },
}

/// The glass of a port as the caller gives it: `camera` None for every port (a camera's own
/// glass wins over it), thickness in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct Glass {
    /// The camera it is for; `None`: every port.
    pub camera: Option<String>,
    /// Thickness, metres.
    pub thickness: f64,
    /// Refractive index.
    pub index: f64,
}

/// Where the lenses come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LensSource {
    /// A rig file's intrinsics (`--rig`).
    Rig,
    /// Each camera's own views in `air/`.
    Air,
    /// The underwater frames themselves: no `air/` folder and no rig.
    Water,
}

impl LensSource {
    /// A rig's lenses when one is given; else `air/` when `dir` has one; else the water.
    pub fn choose(dir: &Path, rig_given: bool) -> Self {
        if rig_given {
            Self::Rig
        } else if dir.join("air").is_dir() {
            Self::Air
        } else {
            Self::Water
        }
    }
}

/// Checks what can be checked of `glass` before the footage is read: a thickness between 0 and
/// 1 m, an index from 1 to 4; a bare surface has no glass, a shared port one for all.
pub fn check_glass(glass: &[Glass], port: PortKind) -> Result<(), ImagesError> {
    for g in glass {
        let label = g
            .camera
            .as_ref()
            .map_or(String::new(), |c| format!(" for camera '{c}'"));
        if !(g.thickness > 0.0 && g.thickness < 1.0) {
            return Err(ImagesError::Glass(format!(
                "glass{label} ({} m, index {}): a glass thickness between 0 and 1 m (in metres: 10 mm is 0.01)",
                g.thickness, g.index
            )));
        }
        if !(1.0..=4.0).contains(&g.index) {
            return Err(ImagesError::Glass(format!(
                "glass{label} ({} m, index {}): a refractive index from 1 to 4",
                g.thickness, g.index
            )));
        }
        match (&g.camera, port) {
            (_, PortKind::Surface) => {
                return Err(ImagesError::Glass(
                    "glass: the port 'surface' is a bare water surface, without glass (a window in front of every camera is the port 'shared')".into(),
                ));
            }
            (Some(camera), PortKind::Shared) => {
                return Err(ImagesError::Glass(format!(
                    "glass for camera '{camera}': with the port 'shared' one port is in front of every camera; give its glass for all"
                )));
            }
            _ => {}
        }
    }
    Ok(())
}

/// The glass of each camera's port, in `names`' order.
pub fn glass_per_camera(
    glass: &[Glass],
    names: &[String],
    port: PortKind,
) -> Result<Vec<Vec<Layer>>, ImagesError> {
    check_glass(glass, port)?;
    let mut per_camera = vec![Vec::new(); names.len()];
    for g in glass {
        let layer = Layer {
            thickness: g.thickness,
            index: g.index,
        };
        match &g.camera {
            Some(camera) => {
                let k = names.iter().position(|n| n == camera).ok_or_else(|| {
                    ImagesError::GlassCamera {
                        camera: camera.clone(),
                        cameras: names.join(", "),
                    }
                })?;
                per_camera[k] = vec![layer];
            }
            None => {
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

/// The intrinsics of the footage's cameras from `rig` (by name, of the same size); `label`
/// names the rig in errors (its file).
pub fn cameras_from_rig(
    rig: &Rig,
    label: &str,
    footage: &Footage,
) -> Result<Vec<PinholeCamera>, ImagesError> {
    let error = |why: String| ImagesError::RigCamera {
        rig: label.to_string(),
        why,
    };
    footage
        .cameras
        .iter()
        .map(|camera| {
            let k = rig.camera_index(&camera.name).ok_or_else(|| {
                let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
                error(format!(
                    "no camera '{}' (the camera folders name the cameras; the rig has {})",
                    camera.name,
                    names.join(", ")
                ))
            })?;
            let intrinsics = rig.cameras()[k].intrinsics;
            if (intrinsics.width, intrinsics.height) != (camera.width, camera.height) {
                return Err(error(format!(
                    "camera '{}' is {}x{} pixels, its frames {}x{}",
                    camera.name, intrinsics.width, intrinsics.height, camera.width, camera.height
                )));
            }
            Ok(intrinsics)
        })
        .collect()
}

/// Every camera's start lens from its underwater frames (their magnification n_water/n_air
/// divided out), in the footage's camera order.
pub fn water_lens_starts(
    footage: &Footage,
    board: &Board,
    index_air: f64,
    index_water: f64,
) -> Result<Vec<PinholeCamera>, ImagesError> {
    footage
        .cameras
        .iter()
        .enumerate()
        .map(|(k, camera)| {
            Ok(water_lens_start(
                &camera.name,
                (camera.width, camera.height),
                board,
                &footage.water,
                k,
                index_air,
                index_water,
            )?)
        })
        .collect()
}

/// Camera `k`'s lens from its in-air views.
pub fn air_lens(footage: &Footage, k: usize, board: &Board) -> Result<IntrinsicsFit, ImagesError> {
    let camera = &footage.cameras[k];
    calibrate_intrinsics(
        &camera.name,
        camera.width,
        camera.height,
        board,
        &camera.air,
        &IntrinsicsOptions::default(),
    )
    .map_err(|source| ImagesError::AirLens {
        camera: camera.name.clone(),
        source,
    })
}

/// The fit's settings as `calibrate --images` and `calibrate_images` take them.
#[derive(Debug, Clone, PartialEq)]
pub struct FitSettings {
    /// Huber threshold, pixels (`None`: the default).
    pub huber: Option<f64>,
    /// Most iterations of each fit.
    pub max_iterations: usize,
    /// The RMS above which the fit is refused (`None`: the default bound).
    pub max_rms_px: Option<f64>,
    /// Largest port tilt the searches consider, degrees.
    pub max_tilt_deg: f64,
    /// Share of the frames held out.
    pub holdout: f64,
    /// Whether the lenses are refined under water.
    pub refine_intrinsics: RefineIntrinsics,
}

/// The options of the calibration: `settings` on `backend`, with the in-air lenses' σ (`fits`,
/// empty where the lenses did not come from air) as their uncertainty.
pub fn boards_options(
    settings: &FitSettings,
    backend: Backend,
    fits: &[(String, IntrinsicsFit)],
) -> BoardsOptions {
    let defaults = BoardsOptions::default();
    BoardsOptions {
        calibration: Options {
            huber: settings.huber.or(defaults.calibration.huber),
            max_iterations: settings.max_iterations,
            max_rms_px: settings.max_rms_px,
            max_tilt: settings.max_tilt_deg.to_radians(),
            backend,
            ..Options::default()
        },
        holdout: settings.holdout,
        lens_std: fits.iter().map(|(_, fit)| fit.std).collect(),
        refine_intrinsics: settings.refine_intrinsics,
        ..defaults
    }
}

/// The calibration of the extrinsics and ports (and, with [`LensSource::Water`], the lenses):
/// the result, and with the lenses from the water why their terms were chosen.
pub fn calibrate(
    source: LensSource,
    names: &[String],
    setup: &RigSetup,
    board: &Board,
    footage: &Footage,
    options: &BoardsOptions,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(BoardsCalibration, Option<String>), ImagesError> {
    let frames = &footage.water;
    let options = &BoardsOptions {
        turnable: footage.turnable,
        ..options.clone()
    };
    Ok(match source {
        LensSource::Water => {
            let w = calibrate_lenses_under_water(names, setup, board, frames, options, progress)?;
            (w.calibration, Some(w.reason))
        }
        LensSource::Rig | LensSource::Air => (
            calibrate_from_boards(names, setup, board, frames, options, progress)?,
            None,
        ),
    })
}

/// Why a calibration that does not fit is refused: the verdict's reasons and what the data
/// look like.
pub fn refusal(result: &BoardsCalibration) -> String {
    format!(
        "the calibration does not fit: {}. What the data look like: {}.",
        result.verdict.why.join("; "),
        result.calibration.report.diagnosis.join("; ")
    )
}
