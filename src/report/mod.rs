//! A calibration's report for a person (`flatport calibrate … --report-dir DIR`): one
//! self-contained HTML page (`DIR/index.html`, no script from the network, no framework) with
//! its pictures as PNG files beside it and the numbers as JSON and CSV.
//!
//! What it shows: the rig in 3-D from the top and the side (cameras with their axes, the ports,
//! the board poses or the targetless points); per camera the residual quiver, a spatial error
//! map and the coverage (where the corners fell in air and under water, over the image and over
//! distance and tilt); RMS per camera and frame with outliers and left-out frames named; the
//! error histogram; the held-out frames by depth; every estimated parameter with σ and its
//! largest correlations; the verdict; and the advice ([`advice`]): the worst-determined
//! parameter and the view that shrinks its σ most, marked on the coverage pictures.
//!
//! It uses `model`, `calib` and `io` (files, the plot font); the CLI parses `--report-dir` and
//! calls [`write_report`].

pub mod advice;
mod html;
mod pictures;
pub mod stereo;

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point2, Point3, Vector2, Vector3};

use crate::base::Board;
use crate::calib::pipeline::acceptance::{Grade, Verdict};
use crate::calib::pipeline::boards::{
    BoardsCalibration, WaterFrame, square_errors, triangulate_view, validate,
};
use crate::calib::pipeline::report::Report;
use crate::calib::problem::observations::{CameraKey, Image, Observations, View};
use crate::calib::problem::target::Target;
use crate::calib::targetless::TargetlessCalibration;
use crate::io::IoError;
use crate::model::Rig;
use advice::Advice;

/// What can go wrong writing a report.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// A file or folder could not be written.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A picture could not be drawn.
    #[error("{}: drawing failed: {reason}", path.display())]
    Draw {
        /// The picture.
        path: PathBuf,
        /// What plotters said.
        reason: String,
    },
}

/// Everything a report is made from. Routes fill what they have; the rest stays empty and the
/// page says so.
#[derive(Debug, Clone)]
pub struct Input<'a> {
    /// The page's title.
    pub title: String,
    /// The command that ran, shown on the page.
    pub command: String,
    /// The calibrated rig.
    pub rig: &'a Rig,
    /// The calibration's report (`None`: the targetless route).
    pub report: Option<&'a Report>,
    /// The target of a board route.
    pub target: Option<Target>,
    /// The fitted frames, labelled, in the report's view order.
    pub fitted: Vec<(String, View)>,
    /// The frames held out of the fit, labelled.
    pub held_out: Vec<(String, View)>,
    /// Per camera (rig order), the corners of its in-air views.
    pub air: Vec<Vec<Point2<f64>>>,
    /// The verdict (good, usable, poor) where the route judges one.
    pub verdict: Option<Verdict>,
    /// Frames, images and corners left out of the fit: (what, why).
    pub left_out: Vec<(String, String)>,
    /// Targetless: the scene points, master frame.
    pub points: Vec<Point3<f64>>,
    /// Rows of σ the route computed itself (name, value, σ) where there is no information matrix
    /// here (the targetless route).
    pub sigma_rows: Vec<(String, String, String)>,
    /// Lines worth reading (warnings, the route's own notes).
    pub notes: Vec<String>,
    /// The Huber threshold of the fit, pixels.
    pub huber: Option<f64>,
    /// The targetless route's result (its tracks, points and information).
    pub targetless: Option<&'a TargetlessCalibration>,
}

impl<'a> Input<'a> {
    /// An input with only the rig: fill the rest.
    pub fn new(title: &str, command: &str, rig: &'a Rig) -> Self {
        Self {
            title: title.into(),
            command: command.into(),
            rig,
            report: None,
            target: None,
            fitted: Vec::new(),
            held_out: Vec::new(),
            air: Vec::new(),
            verdict: None,
            left_out: Vec::new(),
            points: Vec::new(),
            sigma_rows: Vec::new(),
            notes: Vec::new(),
            huber: None,
            targetless: None,
        }
    }

    /// The input of a calibration from board frames (`calibrate --images`): `frames` are the
    /// underwater frames given to [`calibrate_from_boards`](crate::calib::pipeline::boards::calibrate_from_boards),
    /// `names` the cameras in rig order.
    pub fn from_boards(
        command: &str,
        result: &'a BoardsCalibration,
        names: &[String],
        board: &Board,
        frames: &[WaterFrame],
        huber: Option<f64>,
    ) -> Self {
        let view_of = |label: &str| -> Option<(String, View)> {
            let frame = frames.iter().find(|f| f.label == label)?;
            Some((label.to_string(), water_view(frame, names, board)))
        };
        let mut input = Self::new(
            "flatport calibration from board frames",
            command,
            &result.calibration.rig,
        );
        input.report = Some(&result.calibration.report);
        input.target = Some(Target::Board(*board));
        input.fitted = result.fitted.iter().filter_map(|l| view_of(l)).collect();
        input.held_out = result
            .validation
            .iter()
            .flat_map(|v| &v.frames)
            .filter_map(|l| view_of(l))
            .collect();
        input.verdict = Some(result.verdict.clone());
        input.left_out = result
            .dropped
            .iter()
            .map(|(f, why)| (format!("frame {f}"), why.clone()))
            .chain(result.left_out.iter().map(|l| (l.clone(), String::new())))
            .chain(result.dropped_corners.iter().map(|c| {
                (
                    c.clone(),
                    "corner far above the rest after the first fit".into(),
                )
            }))
            .collect();
        input.notes = result
            .turned
            .iter()
            .chain(&result.calibration.report.warnings)
            .cloned()
            .collect();
        input.huber = huber;
        input
    }

    /// The input of a calibration from an observations file (`calibrate --observations`).
    pub fn from_observations(
        command: &str,
        rig: &'a Rig,
        report: &'a Report,
        observations: &Observations,
        huber: Option<f64>,
    ) -> Self {
        let mut input = Self::new("flatport calibration from observations", command, rig);
        input.report = Some(report);
        input.target = Some(observations.target.clone());
        input.fitted = observations
            .views
            .iter()
            .enumerate()
            .map(|(v, view)| (format!("view {v}"), view.clone()))
            .collect();
        input.notes = report.warnings.clone();
        input.huber = huber;
        input
    }
}

impl<'a> Input<'a> {
    /// The input of a targetless calibration (`calibrate --targetless`): the rig, the scene's
    /// points and each port's σ.
    pub fn from_targetless(command: &str, result: &'a TargetlessCalibration) -> Self {
        let mut input = Self::new("flatport targetless calibration", command, &result.rig);
        input.points = result.points.clone();
        for port in &result.ports {
            let p = &port.port;
            input.sigma_rows.push((
                format!("{} tilt (°) / azimuth (°)", port.name),
                format!(
                    "{:.3} / {:.2}",
                    p.tilt().to_degrees(),
                    p.azimuth().to_degrees()
                ),
                port.axis_sigma_deg
                    .map_or("known".into(), |s| format!("{s:.4}° (worst direction)")),
            ));
            input.sigma_rows.push((
                format!("{} air distance (mm)", port.name),
                format!("{:.3}", p.air_distance() * 1e3),
                port.distance_sigma_m
                    .map_or("known".into(), |s| format!("{:.3} mm", s * 1e3)),
            ));
        }
        input.notes = result.unpinned.iter().map(|u| u.reason.clone()).collect();
        input.notes.push(format!(
            "{} of {} tracks kept ({} observations), RMS {:.4} px",
            result.inliers, result.candidates, result.observations, result.rms_px
        ));
        input.verdict = Some(if result.unpinned.is_empty() {
            Verdict {
                grade: Grade::Good,
                why: vec![format!(
                    "every port parameter's σ is within its limit; {} tracks fit to {:.3} px RMS",
                    result.inliers, result.rms_px
                )],
            }
        } else {
            Verdict {
                grade: Grade::Poor,
                why: result
                    .unpinned
                    .iter()
                    .map(|u| format!("not pinned down, no rig written: {}", u.reason))
                    .collect(),
            }
        });
        input.targetless = Some(result);
        input
    }
}

/// Where the report's air-layer σ, which carries the in-air lenses' own σ (the fit held them
/// fixed: `calib::pipeline::report::add_lens_uncertainty`), is well above the advice's (the
/// views' information alone), a sentence saying so: more views under water shrink only the
/// views' part.
fn lens_share(advice: &mut Advice, report: &Report) {
    let larger: Vec<String> = advice
        .parameters
        .iter()
        .filter_map(|p| {
            let crate::calib::pipeline::bundle::Parameter::Distance(port) = p.parameter else {
                return None;
            };
            let reported = report.ports.get(port)?.distance.std?;
            (reported > 1.5 * p.sigma).then(|| {
                format!(
                    "the {}'s σ is {:.3} mm with the lenses' σ, {:.3} mm from the views alone",
                    p.name,
                    reported * 1e3,
                    p.sigma * 1e3
                )
            })
        })
        .collect();
    if !larger.is_empty() {
        advice.text.push(format!(
            "The fit holds the lenses at their in-air calibration, and their own σ dominates: {}. More views under water shrink only the second figure; more in-air views of the board (sharper lenses), or --refine-intrinsics always, shrink the first.",
            larger.join("; ")
        ));
    }
}

/// One underwater frame as a view of `board` (every camera that saw corners).
fn water_view(frame: &WaterFrame, names: &[String], board: &Board) -> View {
    View {
        images: frame
            .corners
            .iter()
            .enumerate()
            .filter(|(_, c)| !c.is_empty())
            .map(|(k, corners)| {
                let mut full = vec![None; board.corners()];
                for (i, p) in corners {
                    if let Some(slot) = full.get_mut(*i) {
                        *slot = Some(*p);
                    }
                }
                Image {
                    camera: CameraKey::Name(names[k].clone()),
                    key: names[k].clone(),
                    corners: full,
                }
            })
            .collect(),
    }
}

/// One corner image of a fitted frame under the calibrated rig.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Corner {
    pub camera: usize,
    pub frame: usize,
    pub corner: usize,
    pub observed: Point2<f64>,
    /// Projected − observed, pixels.
    pub residual: Vector2<f64>,
    /// Distance of the corner from the camera's centre, metres.
    pub depth_m: f64,
    /// Angle between the board's normal and the camera's optical axis, degrees (`None`: no
    /// board, the targetless route).
    pub tilt_deg: Option<f64>,
    pub outlier: bool,
}

/// One held-out frame through the calibrated rig.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct HeldOutFrame {
    pub label: String,
    /// Mean distance of its triangulated corners from the master camera, metres.
    pub depth_m: Option<f64>,
    /// Reprojection RMS with only its board pose fitted, pixels.
    pub rms_px: Option<f64>,
    /// Neighbouring corners' distance − square, metres.
    pub square_errors: Vec<f64>,
}

/// What the page is drawn from.
pub(crate) struct Facts<'a> {
    pub input: &'a Input<'a>,
    pub corners: Vec<Corner>,
    /// Per fitted frame, per camera: its RMS (`None`: not seen).
    pub frame_rms: Vec<Vec<Option<f64>>>,
    pub held_out: Vec<HeldOutFrame>,
    /// Why there are no held-out figures, if there are none.
    pub held_out_note: Option<String>,
    pub advice: Option<Advice>,
    /// Board poses of the fitted frames (master frame).
    pub poses: Vec<Isometry3<f64>>,
    /// The label of each fitted frame, as `frame_rms`.
    pub frame_labels: Vec<String>,
}

/// What was written.
#[derive(Debug, Clone)]
pub struct Written {
    /// `DIR/index.html`.
    pub index: PathBuf,
    /// Every file written.
    pub files: Vec<PathBuf>,
    /// The advice, where the route allows one.
    pub advice: Option<Advice>,
}

/// Writes the report of `input` into `dir` (created): `index.html`, its pictures and the numbers.
pub fn write_report(dir: &Path, input: &Input) -> Result<Written, ReportError> {
    std::fs::create_dir_all(dir).map_err(|source| IoError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let facts = gather(input);
    let mut files = Vec::new();
    let pictures = pictures::draw_all(dir, &facts, &mut files)?;
    html::write_numbers(dir, &facts, &mut files)?;
    let index = dir.join("index.html");
    let page = html::page(&facts, &pictures);
    crate::io::output::write_atomic(&index, page.as_bytes())?;
    files.push(index.clone());
    Ok(Written {
        index,
        files,
        advice: facts.advice,
    })
}

/// The corners, frame RMS, held-out figures and advice of `input`.
fn gather<'a>(input: &'a Input<'a>) -> Facts<'a> {
    let rig = input.rig;
    let mut facts = Facts {
        input,
        corners: Vec::new(),
        frame_rms: Vec::new(),
        held_out: Vec::new(),
        held_out_note: None,
        advice: None,
        poses: Vec::new(),
        frame_labels: input.fitted.iter().map(|(l, _)| l.clone()).collect(),
    };
    if let Some(result) = input.targetless {
        targetless_corners(result, &mut facts);
        facts.advice = Some(advice::advise_targetless(result));
        facts.held_out_note = Some("this route holds no frames out".into());
        return facts;
    }
    let (Some(report), Some(target)) = (input.report, input.target.as_ref()) else {
        facts.held_out_note = Some("this route holds no frames out".into());
        return facts;
    };
    let observations = Observations {
        target: target.clone(),
        views: input.fitted.iter().map(|(_, v)| v.clone()).collect(),
        stereo_form: false,
    };
    let seen = observations.resolve(rig).unwrap_or_default();
    if seen.len() == report.poses.len() {
        facts.poses = report.poses.clone();
        let outliers: std::collections::HashSet<(usize, String, usize)> = report
            .outliers
            .iter()
            .map(|o| (o.view, o.camera.clone(), o.corner))
            .collect();
        let cameras: Vec<_> = (0..rig.cameras().len())
            .map(|k| rig.refractive_camera(k))
            .collect();
        for (v, (view, pose)) in seen.iter().zip(&report.poses).enumerate() {
            let mut rms = vec![None; rig.cameras().len()];
            let normal = pose.rotation * Vector3::z();
            for (k, corners) in &view.cameras {
                let camera = &rig.cameras()[*k];
                let axis = camera.cam_from_master.rotation.inverse() * Vector3::z();
                let tilt_deg = normal.dot(&axis).abs().clamp(0.0, 1.0).acos().to_degrees();
                let centre = camera.centre_in_master();
                let (mut sum, mut count) = (0.0, 0usize);
                for (i, observed) in corners {
                    let point = pose * target.point(*i);
                    let Ok(projected) = cameras[*k].project(&point) else {
                        continue;
                    };
                    let residual = projected - observed;
                    sum += residual.norm_squared();
                    count += 1;
                    facts.corners.push(Corner {
                        camera: *k,
                        frame: v,
                        corner: *i,
                        observed: *observed,
                        residual,
                        depth_m: (point - centre).norm(),
                        tilt_deg: Some(tilt_deg),
                        outlier: outliers.contains(&(v, camera.name.clone(), *i)),
                    });
                }
                if count > 0 {
                    rms[*k] = Some((sum / (2 * count) as f64).sqrt());
                }
            }
            facts.frame_rms.push(rms);
        }
        let sigma = report
            .sigma_px
            .or(report.noise_px)
            .filter(|s| *s > 0.0 && s.is_finite())
            .unwrap_or(report.rms_px.max(1e-3));
        let mut advice = advice::advise(
            rig,
            target,
            &seen,
            &report.poses,
            report.estimate,
            input.huber,
            sigma,
        );
        lens_share(&mut advice, report);
        facts.advice = Some(advice);
    } else {
        facts.advice = Some(Advice {
            parameters: Vec::new(),
            worst: None,
            best: None,
            candidates: 0,
            text: vec![format!(
                "The report's {} board poses do not match the {} frames at hand: no per-corner figures and no advice.",
                report.poses.len(),
                seen.len()
            )],
        });
    }
    facts.held_out = held_out(rig, target, &input.held_out);
    if input.held_out.is_empty() {
        facts.held_out_note = Some(
            "no frames were held out of this fit (a route from an observations file, one camera, or too few frames): nothing checks the fit beyond its own residuals"
                .into(),
        );
    }
    facts
}

/// The targetless fit's matches as corners (a track is a corner, its frame the frame it was
/// matched in; no tilt, no outlier: the fit dropped those) and each frame's RMS per camera.
fn targetless_corners(result: &TargetlessCalibration, facts: &mut Facts) {
    let rig = &result.rig;
    let cameras: Vec<_> = (0..rig.cameras().len())
        .map(|k| rig.refractive_camera(k))
        .collect();
    let centres: Vec<_> = rig.cameras().iter().map(|c| c.centre_in_master()).collect();
    let frames = result.tracks.iter().map(|t| t.frame + 1).max().unwrap_or(0);
    let mut sums = vec![vec![(0.0, 0usize); cameras.len()]; frames];
    for (t, (track, point)) in result.tracks.iter().zip(&result.points).enumerate() {
        for (k, observed) in &track.pixels {
            let Ok(projected) = cameras[*k].project(point) else {
                continue;
            };
            let residual = projected - observed;
            let sum = &mut sums[track.frame][*k];
            sum.0 += residual.norm_squared();
            sum.1 += 1;
            facts.corners.push(Corner {
                camera: *k,
                frame: track.frame,
                corner: t,
                observed: *observed,
                residual,
                depth_m: (point - centres[*k]).norm(),
                tilt_deg: None,
                outlier: false,
            });
        }
    }
    facts.frame_rms = sums
        .into_iter()
        .map(|row| {
            row.into_iter()
                .map(|(sum, n)| (n > 0).then(|| (sum / (2 * n) as f64).sqrt()))
                .collect()
        })
        .collect();
    facts.frame_labels = (1..=frames).map(|f| format!("frame {f}")).collect();
}

/// The held-out frames through the calibrated rig, frame by frame.
fn held_out(rig: &Rig, target: &Target, frames: &[(String, View)]) -> Vec<HeldOutFrame> {
    let Some(board) = target.board() else {
        return Vec::new();
    };
    frames
        .iter()
        .map(|(label, view)| {
            let observations = Observations {
                target: target.clone(),
                views: vec![view.clone()],
                stereo_form: false,
            };
            let one = [(label.clone(), view.clone())];
            let validation = validate(rig, board, &observations, &one).ok();
            let seen = observations
                .resolve(rig)
                .ok()
                .and_then(|s| s.into_iter().next());
            let (depth_m, square_errors) = match &seen {
                Some(seen) => {
                    let points: Vec<Point3<f64>> = triangulate_view(rig, board, seen)
                        .into_iter()
                        .flatten()
                        .collect();
                    let depth = (!points.is_empty()).then(|| {
                        points.iter().map(|p| p.coords.norm()).sum::<f64>() / points.len() as f64
                    });
                    (depth, square_errors(rig, board, seen))
                }
                None => (None, Vec::new()),
            };
            HeldOutFrame {
                label: label.clone(),
                depth_m,
                rms_px: validation.map(|v| v.rms_px).filter(|r| r.is_finite()),
                square_errors,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::{Options, SceneSpec, calibrate, simulate};

    fn example_rig() -> Rig {
        crate::io::read_rig(Path::new("data/example_rig.json")).unwrap()
    }

    #[test]
    fn a_rig_alone_gives_a_page_that_says_what_is_missing() {
        let rig = example_rig();
        let dir = tempfile::tempdir().unwrap();
        let written = write_report(dir.path(), &Input::new("t", "", &rig)).unwrap();
        let page = std::fs::read_to_string(&written.index).unwrap();
        assert!(page.contains("this route holds no frames out"), "{page}");
        assert!(page.contains("has no corner"));
        assert!(written.advice.is_none());
        assert!(dir.path().join("rig_top.png").is_file());
    }

    #[test]
    fn a_camera_that_saw_nothing_is_named_not_a_panic() {
        let rig = example_rig();
        let target = Target::Board(Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        });
        let scene = simulate(&rig, &SceneSpec::new(target, 8, 0.1, 3)).unwrap();
        let mut observations = scene.observations.clone();
        for view in &mut observations.views {
            view.images.retain(|i| i.key == "left");
        }
        let start = rig
            .with_interface(rig.port_in_master(0).with_pose(Vector3::z(), 0.01).unwrap())
            .unwrap();
        let calibration = calibrate(&start, &observations, &Options::default()).unwrap();
        let input = Input::from_observations(
            "t",
            &calibration.rig,
            &calibration.report,
            &observations,
            None,
        );
        let dir = tempfile::tempdir().unwrap();
        let written = write_report(dir.path(), &input).unwrap();
        let page = std::fs::read_to_string(&written.index).unwrap();
        assert!(
            page.contains("<h3>right</h3>\n<p>This camera has no corner"),
            "{page}"
        );
        assert!(page.contains("no frames were held out"));
        assert!(page.contains("Residuals by distance"));
        let advice = written.advice.unwrap();
        assert!(advice.worst.is_some(), "{:?}", advice.text);
        assert!(dir.path().join("quiver_1_right.png").is_file());
    }

    #[test]
    fn a_lens_share_that_dominates_the_air_sigma_is_said() {
        let rig = example_rig();
        let target = Target::Board(Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        });
        let scene = simulate(&rig, &SceneSpec::pair(target, 10, 0.1, 2, 0, 1)).unwrap();
        let mut report = calibrate(&rig, &scene.observations, &Options::default())
            .unwrap()
            .report;
        let parameter = advice::ParameterSigma {
            parameter: crate::calib::pipeline::bundle::Parameter::Distance(0),
            name: "shared air distance".into(),
            unit: "mm",
            scale: 1e3,
            sigma: 0.5e-3,
            tolerance: advice::DISTANCE_TOLERANCE_M,
            correlations: Vec::new(),
        };
        let mut advice_with = |reported_m: f64| {
            report.ports[0].distance.std = Some(reported_m);
            let mut a = Advice {
                parameters: vec![parameter.clone()],
                worst: Some(0),
                best: None,
                candidates: 0,
                text: Vec::new(),
            };
            lens_share(&mut a, &report);
            a.text
        };
        let said = advice_with(2e-3);
        assert_eq!(said.len(), 1, "{said:?}");
        assert!(
            said[0].contains("2.000 mm with the lenses' σ, 0.500 mm from the views alone"),
            "{said:?}"
        );
        assert!(advice_with(0.6e-3).is_empty());
    }
}
