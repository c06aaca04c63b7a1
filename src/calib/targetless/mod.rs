//! Targetless port calibration (issue 40): a rig calibrated in air (lenses, extrinsics) and a
//! guess of its port(s) calibrated from synchronized frames of any textured scene, no board.
//!
//! 1. [`matches`](mod@matches): corners of the master's image matched in every other camera's image by a rule
//!    that reads no rig (mutual-best ZNCC over the whole image, ratio test, sub-pixel
//!    Gauss–Newton); a corner matched in several cameras is one [`Track`]. Frames are pooled.
//! 2. Outliers: each track triangulated under the guessed port; tracks without a triangulation
//!    or whose water rays miss each other by a gross angle (above max(0.02 rad, median + 8 MAD))
//!    are dropped.
//! 3. [`fit`]: maximum likelihood over the ports (what [`Estimate`] names) and every track's
//!    point, under a Huber loss of [`TargetlessOptions::huber_px`]; after each fit the tracks
//!    whose RMS reprojection error exceeds median + f·1.4826·MAD are dropped, f tightening
//!    8 → 5 → 3.5; the last fit is plain least squares. Where the fit from the rig's guess ends
//!    above [`TargetlessOptions::max_rms_px`], more starts are tried (axes over a cap of 20°)
//!    and the best kept.
//! 4. σ of every parameter from JᵀJ scaled by the residual variance and by the patches' overlap
//!    (matches whose patches share pixels share their errors); a parameter the scene
//!    cannot pin (σ above its limit) is reported in [`TargetlessCalibration::unpinned`] with the
//!    parameter it trades off against, and [`TargetlessCalibration::confident_rig`] refuses it.
//!
//! [`sweep`] evaluates the start's profile cost over a grid of ports (`flatport sweep
//! --targetless`), to see the well a scene gives before trusting a fit.
//!
//! **How many matches.** The Fisher information of the port grows with the matches and their
//! spread in image and depth: on the rendered scenes of issue 40, 3 000 exact matches at 0.3 px
//! give σ 0.03–0.09° for the axis and 0.4–1.9 mm for the air layer. The sub-pixel matcher here is
//! good to ~0.05 px on rendered texture, so ~1 000 matches spread over the image (one corner per
//! grid cell) already give σ a few times below the 0.1° / 1.5 mm goals; more frames add more.

pub mod fit;
pub mod matches;
pub mod start;
pub mod sweep;

use std::collections::BTreeMap;

use nalgebra::{DMatrix, Point3, SymmetricEigen, Unit, Vector3};

use crate::base::GreyImage;
use crate::calib::pipeline::bundle::{Estimate, Parameter, State};
use crate::calib::pipeline::report::{parameter_name, port_names};
use crate::calib::solvers::lm::{LmOptions, Termination, levenberg_marquardt};
use crate::calib::solvers::search::tangent_step;
use crate::model::{Interface, Ports, Rig, triangulate_rays};

pub use fit::{PointsProblem, PointsState, Track};
pub use matches::{MatchOptions, PixelMatch, match_pair};

/// Frames used from footage when no selection is given: at most this many, spread evenly over it
/// (`calibrate --targetless` without `--frames`, `flatport.calibrate_targetless`).
pub const DEFAULT_FRAMES: usize = 8;

/// Settings of a targetless calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetlessOptions {
    /// What is estimated (axis and distance of every port by default).
    pub estimate: Estimate,
    /// How corners are found and matched.
    pub matching: MatchOptions,
    /// Huber threshold of the robust fits, pixels.
    pub huber_px: f64,
    /// A fit ending above this RMS reprojection error (px) tries more starts, and is refused
    /// when none ends below it.
    pub max_rms_px: f64,
    /// Largest σ of an axis (degrees, along its worst direction) that counts as pinned.
    pub max_axis_sigma_deg: f64,
    /// Largest σ of an air distance or layer thickness (metres) that counts as pinned.
    pub max_distance_sigma_m: f64,
    /// Fewest inlier tracks to fit from.
    pub min_tracks: usize,
}

impl Default for TargetlessOptions {
    fn default() -> Self {
        Self {
            estimate: Estimate::default(),
            matching: MatchOptions::default(),
            huber_px: 1.0,
            max_rms_px: 1.0,
            max_axis_sigma_deg: 0.1,
            max_distance_sigma_m: 0.002,
            min_tracks: 50,
        }
    }
}

/// Why a targetless calibration could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TargetlessError {
    /// No frames given.
    #[error(
        "no frames: targetless calibration needs at least one synchronized frame of every camera"
    )]
    NoFrames,
    /// A frame without one image per rig camera.
    #[error("frame {frame}: {got} images for a rig of {expected} cameras")]
    CameraCount {
        /// 0-based frame.
        frame: usize,
        /// Images given.
        got: usize,
        /// Rig cameras.
        expected: usize,
    },
    /// An image whose size is not its camera's.
    #[error(
        "frame {frame}, camera '{camera}': the image is {width}×{height} px, the rig says {expected_width}×{expected_height}"
    )]
    ImageSize {
        /// 0-based frame.
        frame: usize,
        /// Camera name.
        camera: String,
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
        /// Rig width.
        expected_width: u32,
        /// Rig height.
        expected_height: u32,
    },
    /// A rig of one camera: nothing to match.
    #[error("the rig has one camera: targetless calibration matches the scene between cameras")]
    OneCamera,
    /// Nothing to estimate.
    #[error("--estimate names no port parameter: nothing to calibrate")]
    NothingToEstimate,
    /// Too few matches survive.
    #[error(
        "{found} usable matches ({candidates} before outlier rejection); at least {needed} are needed: film more texture, more frames, or check that the images belong to these cameras"
    )]
    TooFewMatches {
        /// Inlier tracks.
        found: usize,
        /// Tracks matched.
        candidates: usize,
        /// The minimum.
        needed: usize,
    },
    /// No start converged to a fit within the RMS bound.
    #[error(
        "no fit: the best start ended at {rms_px:.3} px RMS (bound {bound_px} px) after trying {starts} starts ({termination}); the matches or the rig's cameras do not fit any port"
    )]
    NoFit {
        /// Best RMS reprojection error, pixels.
        rms_px: f64,
        /// The bound.
        bound_px: f64,
        /// Starts tried.
        starts: usize,
        /// Why the solver stopped.
        termination: String,
    },
    /// The fit is made but some parameter is not pinned down by the scene.
    #[error("{}", describe_unpinned(.0))]
    Unpinned(Vec<Unpinned>),
}

fn describe_unpinned(unpinned: &[Unpinned]) -> String {
    let lines: Vec<String> = unpinned.iter().map(|u| u.reason.clone()).collect();
    format!(
        "the scene does not pin the port down, no rig written:\n  {}\n  (film a scene with more depth and texture toward the image's edges, or fix the parameter: restrict --estimate)",
        lines.join("\n  ")
    )
}

/// A parameter the scene does not pin down.
#[derive(Debug, Clone, PartialEq)]
pub struct Unpinned {
    /// The parameter, as reports name it (`shared axis`, `left distance`).
    pub parameter: String,
    /// Its σ (degrees for an axis, metres otherwise).
    pub sigma: f64,
    /// The limit it exceeds, same unit.
    pub limit: f64,
    /// One line: which parameter, its σ, the limit and what it trades off against.
    pub reason: String,
}

/// One port's estimate, in the frame the rig file gives it in.
#[derive(Debug, Clone, PartialEq)]
pub struct PortEstimate {
    /// `shared` or the camera's name.
    pub name: String,
    /// The fitted port.
    pub port: Interface,
    /// σ of the axis along its worst direction, degrees (`None`: not estimated).
    pub axis_sigma_deg: Option<f64>,
    /// σ of the air distance, metres (`None`: not estimated).
    pub distance_sigma_m: Option<f64>,
    /// σ of each layer thickness, metres (`None`: not estimated).
    pub thickness_sigma_m: Vec<Option<f64>>,
}

/// What a targetless calibration found.
#[derive(Debug, Clone)]
pub struct TargetlessCalibration {
    /// The calibrated rig (the input's cameras with the fitted ports).
    pub rig: Rig,
    /// Every port with σ.
    pub ports: Vec<PortEstimate>,
    /// Matched tracks before outlier rejection.
    pub candidates: usize,
    /// Tracks kept in the final fit.
    pub inliers: usize,
    /// Observations (camera pixels) in the final fit.
    pub observations: usize,
    /// Matches found per camera (index ≥ 1) against the master, summed over frames.
    pub matches_per_camera: Vec<usize>,
    /// RMS reprojection error of the final fit, pixels.
    pub rms_px: f64,
    /// Starts tried.
    pub starts: usize,
    /// Why the final fit stopped.
    pub termination: Termination,
    /// The parameters the scene does not pin down (empty: every σ within its limit).
    pub unpinned: Vec<Unpinned>,
    /// Every track's final point, master frame (for a look at the scene).
    pub points: Vec<Point3<f64>>,
    /// The tracks of the final fit, one per point of `points`.
    pub tracks: Vec<Track>,
    /// What was estimated.
    pub estimate: Estimate,
    /// The estimated parameters, in the order of `information`'s rows.
    pub globals: Vec<Parameter>,
    /// The information of `globals` at the fit (JᵀJ with the points eliminated, unit residual
    /// variance); `None` where it is singular. The covariance is `sigma_px²`·`information`⁻¹.
    pub information: Option<DMatrix<f64>>,
    /// The σ of one residual the covariance is scaled by, pixels: the fit's residual σ times
    /// √`overlap`.
    pub sigma_px: f64,
    /// Mean count of matched patches covering a covered pixel of the master's image: the σ are
    /// scaled by its square root (overlapping patches share their matching errors).
    pub overlap: f64,
}

impl TargetlessCalibration {
    /// The rig when every parameter is pinned down, else [`TargetlessError::Unpinned`].
    pub fn confident_rig(&self) -> Result<&Rig, TargetlessError> {
        if self.unpinned.is_empty() {
            Ok(&self.rig)
        } else {
            Err(TargetlessError::Unpinned(self.unpinned.clone()))
        }
    }
}

/// Matches of every frame pooled into tracks (the master's corner, its match in each other
/// camera), and the match count per camera.
pub fn tracks_of(
    frames: &[Vec<GreyImage>],
    options: &MatchOptions,
    progress: &mut dyn FnMut(&str),
) -> (Vec<Track>, Vec<usize>) {
    let (options, mut chosen) = choose_matching(frames, options, progress);
    let options = &options;
    let cameras = frames.first().map_or(0, Vec::len);
    let mut per_camera = vec![0; cameras];
    let mut tracks = Vec::new();
    for (f, frame) in frames.iter().enumerate() {
        let mut by_corner: BTreeMap<(u64, u64), Track> = BTreeMap::new();
        for k in 1..frame.len() {
            // The pair the choice matched already is not matched again.
            let found = match chosen.take_if(|_| (f, k) == (frames.len() / 2, 1)) {
                Some(found) => found,
                None => match_pair(&frame[0], &frame[k], options),
            };
            per_camera[k] += found.len();
            progress(&format!(
                "frame {}/{}: camera {k}: {} matches with the master",
                f + 1,
                frames.len(),
                found.len()
            ));
            for m in found {
                let key = (m.in_a.x as u64, m.in_a.y as u64);
                by_corner
                    .entry(key)
                    .or_insert_with(|| Track {
                        frame: f,
                        pixels: vec![(0, m.in_a)],
                    })
                    .pixels
                    .push((k, m.in_b));
            }
        }
        tracks.extend(by_corner.into_values());
    }
    (tracks, per_camera)
}

/// The matching for `frames`: the first of [`matches::ladder`] that finds at least
/// [`matches::ENOUGH_MATCHES`] between the master and the next camera in the middle frame, else
/// the one that finds most. One matching for every frame and camera, so that a corner of the
/// master is the same corner in each camera's matches (the tracks join on it). Returns the
/// matching and what it found in that pair (none without a frame of two cameras).
pub fn choose_matching(
    frames: &[Vec<GreyImage>],
    options: &MatchOptions,
    progress: &mut dyn FnMut(&str),
) -> (MatchOptions, Option<Vec<PixelMatch>>) {
    let Some(frame) = frames.get(frames.len() / 2).filter(|f| f.len() >= 2) else {
        return (*options, None);
    };
    let mut best: Option<(Vec<PixelMatch>, MatchOptions)> = None;
    for (i, candidate) in matches::ladder(options).into_iter().enumerate() {
        let pairs = match_pair(&frame[0], &frame[1], &candidate);
        let found = pairs.len();
        if i > 0 {
            progress(&format!(
                "  matching again on images smoothed by σ {:.1} px with {} px patches: {found} matches",
                candidate.smooth_px,
                2 * candidate.patch_radius + 1
            ));
        }
        if best.as_ref().is_none_or(|(b, _)| found > b.len()) {
            best = Some((pairs, candidate));
        }
        if found >= matches::ENOUGH_MATCHES {
            break;
        }
        if i == 0 {
            progress(&format!(
                "  {found} matches in frame {} with {} px patches (fewer than {}): the footage may be blurred, noisy or low in contrast",
                frames.len() / 2 + 1,
                2 * candidate.patch_radius + 1,
                matches::ENOUGH_MATCHES
            ));
        }
    }
    best.map_or((*options, None), |(pairs, o)| (o, Some(pairs)))
}

fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        f64::NAN
    } else {
        v[v.len() / 2]
    }
}

/// median + `factor`·1.4826·MAD of `values`.
fn mad_bound(values: &[f64], factor: f64) -> f64 {
    let m = median(values);
    let deviations: Vec<f64> = values.iter().map(|v| (v - m).abs()).collect();
    m + factor * 1.4826 * median(&deviations)
}

/// Each track's point triangulated under `rig` from its first two cameras, and the angle by which
/// the two water rays miss each other (gap / distance, radians); `None` without a triangulation.
fn triangulate(rig: &Rig, tracks: &[Track]) -> Vec<Option<(Point3<f64>, f64)>> {
    let cameras: Vec<_> = (0..rig.cameras().len())
        .map(|k| rig.refractive_camera(k))
        .collect();
    tracks
        .iter()
        .map(|t| {
            let (ka, pa) = t.pixels[0];
            let (kb, pb) = t.pixels[1];
            let a = cameras[ka].backproject(&pa).ok()?;
            let b = cameras[kb].backproject(&pb).ok()?;
            let x = triangulate_rays(&a, &b).ok()?;
            let range = (x.point - cameras[ka].centre()).norm();
            // Every camera must see the point: a projection for each.
            for (k, _) in &t.pixels {
                cameras[*k].project(&x.point).ok()?;
            }
            Some((x.point, x.residual / range))
        })
        .collect()
}

/// The fit of `tracks` from `start`: rounds of Huber fits with tracks dropped by a tightening MAD
/// bound, then a plain least-squares fit. Returns the kept tracks, the state, the final normal
/// equations and the termination.
struct Fitted {
    tracks: Vec<Track>,
    state: PointsState,
    normal: Option<fit::PointNormalEquations>,
    termination: Termination,
    rms_px: f64,
    cost: f64,
    globals: Vec<Parameter>,
}

fn fit_rounds(
    rig: &Rig,
    mut tracks: Vec<Track>,
    mut state: PointsState,
    options: &TargetlessOptions,
    brief: bool,
    progress: &mut dyn FnMut(&str),
) -> Fitted {
    let lm = |iterations| LmOptions {
        max_iterations: iterations,
        cost_tolerance: 1e-12,
        ..LmOptions::default()
    };
    let factors: &[f64] = if brief { &[] } else { &[8.0, 5.0, 3.5] };
    let first = if brief { 15 } else { 100 };
    (tracks, state) = without_undefined(rig, tracks, state, options, progress);
    {
        let problem = PointsProblem::new(rig, &tracks, options.estimate, Some(options.huber_px));
        let (s, _, _) = levenberg_marquardt(&problem, state, &lm(first));
        state = s;
    }
    for &factor in factors {
        let problem = PointsProblem::new(rig, &tracks, options.estimate, Some(options.huber_px));
        let Some(residuals) = problem.all_residuals(&state) else {
            break;
        };
        let errors: Vec<f64> = residuals
            .iter()
            .map(|r| (r.iter().map(|e| e.norm_squared()).sum::<f64>() / r.len() as f64).sqrt())
            .collect();
        let bound = mad_bound(&errors, factor);
        let keep: Vec<bool> = errors.iter().map(|e| *e <= bound).collect();
        let dropped = keep.iter().filter(|k| !**k).count();
        progress(&format!(
            "  dropped {dropped} of {} tracks above {bound:.3} px (median + {factor}·MAD)",
            tracks.len()
        ));
        let (t, p): (Vec<Track>, Vec<Point3<f64>>) = tracks
            .into_iter()
            .zip(state.points)
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(x, _)| x)
            .unzip();
        tracks = t;
        state.points = p;
        (tracks, state) = without_undefined(rig, tracks, state, options, progress);
        let problem = PointsProblem::new(rig, &tracks, options.estimate, Some(options.huber_px));
        let (s, _, _) = levenberg_marquardt(&problem, state, &lm(100));
        state = s;
    }
    let huber = if brief { Some(options.huber_px) } else { None };
    let problem = PointsProblem::new(rig, &tracks, options.estimate, huber);
    let (state, report, normal) =
        levenberg_marquardt(&problem, state, &lm(if brief { 1 } else { 100 }));
    let observations = problem.residuals() / 2;
    let rms_px = problem
        .all_residuals(&state)
        .map(|r| {
            (r.iter().flatten().map(|e| e.norm_squared()).sum::<f64>() / (2 * observations) as f64)
                .sqrt()
        })
        .unwrap_or(f64::INFINITY);
    let globals = problem.globals().to_vec();
    Fitted {
        tracks,
        state,
        normal,
        termination: report.termination,
        rms_px,
        cost: report.final_cost,
        globals,
    }
}

/// `tracks` (and their points in `state`) less those whose cost or derivatives are undefined at
/// `state` ([`PointsProblem::undefined_tracks`]): a point that a difference step of the port
/// moves out of a camera's view. Left as they are where the state's cameras are undefined.
fn without_undefined(
    rig: &Rig,
    tracks: Vec<Track>,
    mut state: PointsState,
    options: &TargetlessOptions,
    progress: &mut dyn FnMut(&str),
) -> (Vec<Track>, PointsState) {
    let problem = PointsProblem::new(rig, &tracks, options.estimate, Some(options.huber_px));
    let undefined = match problem.undefined_tracks(&state) {
        Some(u) if !u.is_empty() => u,
        _ => return (tracks, state),
    };
    progress(&format!(
        "  left out {} of {} tracks whose point does not project into each of its cameras under the port (or a difference step from it)",
        undefined.len(),
        tracks.len()
    ));
    let (t, p): (Vec<Track>, Vec<Point3<f64>>) = tracks
        .into_iter()
        .zip(state.points)
        .enumerate()
        .filter(|(i, _)| undefined.binary_search(i).is_err())
        .map(|(_, x)| x)
        .unzip();
    state.points = p;
    (t, state)
}

/// The start `rig` with every port's axis moved by `offset` (radians in its tangent plane).
fn tilted(rig: &Rig, tilt: f64, azimuth: f64) -> Option<Rig> {
    let offset = nalgebra::Vector2::new(tilt * azimuth.cos(), tilt * azimuth.sin());
    let tilt_port = |p: &Interface| {
        p.with_pose(
            tangent_step(p.normal(), &offset).into_inner(),
            p.air_distance(),
        )
        .ok()
    };
    let ports = match rig.ports() {
        Ports::Shared(p) => Ports::Shared(tilt_port(p)?),
        Ports::PerCamera(ports) => {
            Ports::PerCamera(ports.iter().map(tilt_port).collect::<Option<_>>()?)
        }
    };
    rig.with_new_ports(ports).ok()
}

/// Distinct minima of the start search refined briefly before the best is fitted in full.
const SEARCH_STARTS: usize = 4;

/// A brief fit of `tracks` from `start` (the tracks the ray-gap test keeps under it): its Huber
/// cost per track and the rig it ends at; `None` with too few tracks or no valid rig.
fn brief_fit(start: &Rig, tracks: &[Track], options: &TargetlessOptions) -> Option<(f64, Rig)> {
    let (tracks, points) = screened(start, tracks);
    if tracks.len() < options.min_tracks {
        return None;
    }
    let state = PointsState {
        rig: State::of(start, Vec::new()),
        points,
    };
    let n = tracks.len() as f64;
    let fitted = fit_rounds(start, tracks, state, options, true, &mut |_| {});
    let rig = fitted.state.rig.rig(start)?;
    Some((fitted.cost / n, rig))
}

/// Tracks kept by the loose ray-gap test under `rig`, with their starting points.
fn screened(rig: &Rig, tracks: &[Track]) -> (Vec<Track>, Vec<Point3<f64>>) {
    let triangulated = triangulate(rig, tracks);
    let gaps: Vec<f64> = triangulated.iter().flatten().map(|(_, g)| *g).collect();
    let bound = mad_bound(&gaps, 8.0).max(0.02);
    tracks
        .iter()
        .zip(triangulated)
        .filter_map(|(t, x)| x.filter(|(_, g)| *g <= bound).map(|(p, _)| (t.clone(), p)))
        .unzip()
}

/// Checks `frames` against `rig`: at least one frame, each with one image per rig camera (rig
/// order) of that camera's size.
pub fn check_frames(rig: &Rig, frames: &[Vec<GreyImage>]) -> Result<(), TargetlessError> {
    let cameras = rig.cameras().len();
    if frames.is_empty() {
        return Err(TargetlessError::NoFrames);
    }
    for (f, frame) in frames.iter().enumerate() {
        if frame.len() != cameras {
            return Err(TargetlessError::CameraCount {
                frame: f,
                got: frame.len(),
                expected: cameras,
            });
        }
        for (image, camera) in frame.iter().zip(rig.cameras()) {
            let i = &camera.intrinsics;
            if (image.width, image.height) != (i.width, i.height) {
                return Err(TargetlessError::ImageSize {
                    frame: f,
                    camera: camera.name.clone(),
                    width: image.width,
                    height: image.height,
                    expected_width: i.width,
                    expected_height: i.height,
                });
            }
        }
    }
    Ok(())
}

/// Calibrates the port(s) of `rig` from `frames` (frame by frame, one image per rig camera in rig
/// order): the rig's cameras and extrinsics are known, its ports are the start. `progress`
/// receives one line per stage.
pub fn calibrate_targetless(
    rig: &Rig,
    frames: &[Vec<GreyImage>],
    options: &TargetlessOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<TargetlessCalibration, TargetlessError> {
    let cameras = rig.cameras().len();
    if cameras < 2 {
        return Err(TargetlessError::OneCamera);
    }
    check_frames(rig, frames)?;
    let probe = PointsProblem::new(rig, &[], options.estimate, None);
    if probe.globals().is_empty() {
        return Err(TargetlessError::NothingToEstimate);
    }
    let (all_tracks, matches_per_camera) = tracks_of(frames, &options.matching, progress);
    let candidates = all_tracks.len();
    progress(&format!(
        "{candidates} tracks matched over {} frame(s)",
        frames.len()
    ));

    // Starts: the rig's own guess first; axes over a 20° cap when it does not fit.
    let mut starts: Vec<Rig> = vec![rig.clone()];
    for tilt_deg in [7.0f64, 14.0, 20.0] {
        for step in 0..8 {
            if let Some(r) = tilted(
                rig,
                tilt_deg.to_radians(),
                f64::from(step) * std::f64::consts::FRAC_PI_4,
            ) && start::clear_of_the_port(&r)
            {
                starts.push(r);
            }
        }
    }
    let mut best: Option<Fitted> = None;
    let mut tried = 0;
    // The search's best distinct nodes first; the axes over the cap only when none fits, each
    // fitted briefly and the best of them fitted in full.
    let (searched, evaluated) =
        start::search_starts(rig, &all_tracks, options.estimate, SEARCH_STARTS);
    progress(&format!(
        "start: {evaluated} candidate ports searched, best {:.3} px RMS (profile over a sample)",
        (searched[0].1 / 4.0).sqrt()
    ));
    // The search's distinct grid minima, each fitted briefly: the best of them is fitted in full.
    let searched = if searched.len() > 1 {
        // Compared by the profile cost over one sample of every track (each brief fit keeps
        // its own tracks).
        let sample = start::spread(&all_tracks, 4 * start::SEARCH_TRACKS);
        let n = sample.len().max(1) as f64;
        let briefly: Vec<(f64, Rig)> = searched
            .iter()
            .filter_map(|(start, _)| brief_fit(start, &all_tracks, options))
            .map(|(_, r)| (start::profile(&r, &sample) / n, r))
            .collect();
        progress(&format!(
            "  {} distinct minima of the search fitted briefly: profile per track {} px²",
            briefly.len(),
            briefly
                .iter()
                .map(|(c, _)| format!("{c:.2e}"))
                .collect::<Vec<_>>()
                .join(", ")
        ));
        tried += briefly.len();
        let first = searched[0].0.clone();
        briefly
            .into_iter()
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map_or(first, |(_, r)| r)
    } else {
        searched[0].0.clone()
    };
    let (tracks, points) = screened(&searched, &all_tracks);
    progress(&format!(
        "{} of {candidates} tracks pass the ray-gap test under the start",
        tracks.len()
    ));
    if tracks.len() >= options.min_tracks {
        tried += 1;
        let state = PointsState {
            rig: State::of(&searched, Vec::new()),
            points,
        };
        let fitted = fit_rounds(&searched, tracks, state, options, false, progress);
        progress(&format!(
            "fit from the start: {:.4} px RMS over {} tracks ({})",
            fitted.rms_px,
            fitted.tracks.len(),
            fitted.termination.describe()
        ));
        best = Some(fitted);
    }
    // A fit that could not take a step (its cost or derivatives undefined at its start) has not
    // been tried: other starts are.
    let stuck = |b: &Fitted| b.termination == Termination::InvalidStart;
    if best
        .as_ref()
        .is_none_or(|b| b.rms_px > options.max_rms_px || stuck(b))
    {
        progress("the guess does not fit: trying axes over a 20° cap");
        let mut brief: Vec<(f64, Rig)> = starts[1..]
            .iter()
            .filter_map(|start| brief_fit(start, &all_tracks, options))
            .collect();
        tried += brief.len();
        brief.sort_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((_, start)) = brief.into_iter().next() {
            let (tracks, points) = screened(&start, &all_tracks);
            if tracks.len() >= options.min_tracks {
                let state = PointsState {
                    rig: State::of(&start, Vec::new()),
                    points,
                };
                let fitted = fit_rounds(&start, tracks, state, options, false, progress);
                progress(&format!(
                    "fit from the best other start: {:.4} px RMS",
                    fitted.rms_px
                ));
                if best
                    .as_ref()
                    .is_none_or(|b| stuck(b) || fitted.rms_px < b.rms_px)
                {
                    best = Some(fitted);
                }
            }
        }
    }
    let Some(fitted) = best else {
        return Err(TargetlessError::TooFewMatches {
            found: 0,
            candidates,
            needed: options.min_tracks,
        });
    };
    if fitted.tracks.len() < options.min_tracks {
        return Err(TargetlessError::TooFewMatches {
            found: fitted.tracks.len(),
            candidates,
            needed: options.min_tracks,
        });
    }
    if !(fitted.rms_px <= options.max_rms_px) {
        return Err(TargetlessError::NoFit {
            rms_px: fitted.rms_px,
            bound_px: options.max_rms_px,
            starts: tried,
            termination: fitted.termination.describe().into(),
        });
    }
    let calibrated = fitted
        .state
        .rig
        .rig(rig)
        .ok_or_else(|| TargetlessError::NoFit {
            rms_px: fitted.rms_px,
            bound_px: options.max_rms_px,
            starts: tried,
            termination: "the fitted ports are not a valid rig".into(),
        })?;
    let observations: usize = fitted.tracks.iter().map(|t| t.pixels.len()).sum();
    let dimension = fitted.globals.len() + 3 * fitted.tracks.len();
    let variance = fitted.cost / (2 * observations).saturating_sub(dimension).max(1) as f64;
    let overlap = patch_overlap(rig, &fitted.tracks, options.matching.patch_radius);
    let information = fitted.normal.as_ref().and_then(|n| n.global_information());
    let covariance = fitted
        .normal
        .as_ref()
        .and_then(|n| n.global_covariance())
        .map(|c| c * (variance * overlap));
    let (ports, unpinned) = uncertainty(&calibrated, &fitted.globals, covariance.as_ref(), options);
    Ok(TargetlessCalibration {
        rig: calibrated,
        ports,
        candidates,
        inliers: fitted.tracks.len(),
        observations,
        matches_per_camera,
        rms_px: fitted.rms_px,
        starts: tried,
        termination: fitted.termination,
        unpinned,
        points: fitted.state.points,
        tracks: fitted.tracks,
        estimate: options.estimate,
        globals: fitted.globals,
        information,
        sigma_px: (variance * overlap).sqrt(),
        overlap,
    })
}

/// How many of the kept tracks' patches cover a pixel of the master's image, on average over the
/// pixels they cover (≥ 1). Matches whose patches share pixels share their matching errors, so
/// the residuals are not independent: the fit holds about (tracks / overlap) independent ones, and
/// σ from JᵀJ is scaled by √overlap.
fn patch_overlap(rig: &Rig, tracks: &[Track], radius: usize) -> f64 {
    let i = &rig.cameras()[0].intrinsics;
    let (w, h) = (i.width as usize, i.height as usize);
    let mut counts = vec![0u32; w * h];
    let (mut covered, mut total) = (0usize, 0usize);
    for t in tracks {
        let (_, p) = t.pixels[0];
        let (x, y) = (p.x.round() as isize, p.y.round() as isize);
        let r = radius as isize;
        for yy in (y - r).max(0)..=(y + r).min(h as isize - 1) {
            for xx in (x - r).max(0)..=(x + r).min(w as isize - 1) {
                let c = &mut counts[yy as usize * w + xx as usize];
                if *c == 0 {
                    covered += 1;
                }
                *c += 1;
                total += 1;
            }
        }
    }
    if covered == 0 {
        1.0
    } else {
        (total as f64 / covered as f64).max(1.0)
    }
}

/// Each port's σ and the parameters whose σ exceeds its limit, with the parameter each is most
/// correlated with (the direction along which the cost is flat). A singular JᵀJ (`covariance`
/// `None`) leaves every estimated parameter unpinned.
fn uncertainty(
    rig: &Rig,
    globals: &[Parameter],
    covariance: Option<&DMatrix<f64>>,
    options: &TargetlessOptions,
) -> (Vec<PortEstimate>, Vec<Unpinned>) {
    let names = port_names(rig);
    let index = |p: Parameter| globals.iter().position(|g| *g == p);
    let sd = |i: usize| covariance.map(|c| c[(i, i)].max(0.0).sqrt());
    let mut unpinned = Vec::new();
    // The parameter most correlated with global i (other than its own axis partner).
    let partner = |i: usize, same: &[usize]| -> String {
        let Some(c) = covariance else {
            return "JᵀJ is singular: the matches do not constrain it at all".into();
        };
        let best = (0..globals.len())
            .filter(|j| !same.contains(j))
            .map(|j| (j, c[(i, j)] / (c[(i, i)] * c[(j, j)]).sqrt()))
            .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()));
        match best {
            Some((j, r)) => format!(
                "it trades off with the {} (correlation {r:+.3}): the cost has a valley along them",
                parameter_name(rig, globals[j])
            ),
            None => "the cost is nearly flat along it".into(),
        }
    };
    let mut ports = Vec::new();
    for (p, (name, port)) in names.iter().enumerate() {
        let axis = match (index(Parameter::Axis(p, 0)), index(Parameter::Axis(p, 1))) {
            (Some(a), Some(b)) => Some(match covariance {
                Some(c) => {
                    let block = nalgebra::Matrix2::new(c[(a, a)], c[(a, b)], c[(b, a)], c[(b, b)]);
                    let eigen = SymmetricEigen::new(block);
                    (
                        eigen.eigenvalues.max().max(0.0).sqrt().to_degrees(),
                        vec![a, b],
                    )
                }
                None => (f64::INFINITY, vec![a, b]),
            }),
            _ => None,
        };
        if let Some((sigma, same)) = &axis
            && !(*sigma <= options.max_axis_sigma_deg)
        {
            {
                unpinned.push(Unpinned {
                    parameter: format!("{name} axis"),
                    sigma: *sigma,
                    limit: options.max_axis_sigma_deg,
                    reason: format!(
                        "{name} axis: σ {sigma:.3}° > {}°; {}",
                        options.max_axis_sigma_deg,
                        partner(same[0], same)
                    ),
                });
            }
        }
        let distance = index(Parameter::Distance(p)).map(|i| (sd(i).unwrap_or(f64::INFINITY), i));
        if let Some((sigma, i)) = distance
            && !(sigma <= options.max_distance_sigma_m)
        {
            {
                unpinned.push(Unpinned {
                    parameter: format!("{name} distance"),
                    sigma,
                    limit: options.max_distance_sigma_m,
                    reason: format!(
                        "{name} distance: σ {:.2} mm > {} mm; {}",
                        sigma * 1e3,
                        options.max_distance_sigma_m * 1e3,
                        partner(i, &[i])
                    ),
                });
            }
        }
        let thickness_sigma_m = (0..port.layers().len())
            .map(|l| index(Parameter::Thickness(p, l)).map(|i| sd(i).unwrap_or(f64::INFINITY)))
            .collect();
        ports.push(PortEstimate {
            name: name.clone(),
            port: port.clone(),
            axis_sigma_deg: axis.map(|a| a.0),
            distance_sigma_m: distance.map(|d| d.0),
            thickness_sigma_m,
        });
    }
    (ports, unpinned)
}

/// The angle between two axes, degrees.
pub fn axis_angle_deg(a: &Unit<Vector3<f64>>, b: &Unit<Vector3<f64>>) -> f64 {
    a.dot(b).clamp(-1.0, 1.0).acos().to_degrees()
}
