//! What the views determine and which view to add: each estimated parameter's σ from the fit's
//! information matrix, what it trades off with (its largest correlations), and the next view
//! chosen by an optimal-design step over synthetic candidate views.
//!
//! The fit's information over the global parameters g (the board poses eliminated by the Schur
//! complement, unit residual variance) is I = S = U − Σ W_v V_v⁻¹ W_vᵀ
//! ([`BlockNormalEquations::global_information`]), and Σ_g = σ̂² I⁻¹. A view c, added, brings its
//! own share I_c (its Jacobian rows at the calibrated rig, its pose eliminated the same way), so
//! its σ would be σ̂·√((I + I_c)⁻¹)_jj. Each parameter j is weighed against what a good
//! calibration needs of it (its tolerance τ_j: issue 38's bounds over 3 for the ports), the worst
//! is j* = argmax σ_j/τ_j, and of the candidate views (the board at a few distances × tilts ×
//! places in each camera's image, posed from the rig just calibrated) the one that shrinks σ_j*
//! most is advised: an A-optimal design step on the worst-determined parameter.

use nalgebra::{
    DMatrix, Isometry3, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};

use rayon::prelude::*;

use crate::calib::pipeline::bundle::{Bundle, Estimate, Parameter, State};
use crate::calib::pipeline::report::{parameter_name, port_names};
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::screen::screen;
use crate::calib::problem::target::Target;
use crate::calib::solvers::lm::LeastSquares;
use crate::calib::targetless::{PointsProblem, PointsState, TargetlessCalibration, Track};
use crate::model::Rig;

/// Tolerance of a port's axis (each tangent direction): a third of issue 38's 0.1°, radians.
pub const AXIS_TOLERANCE_RAD: f64 = 0.1 / 3.0 * std::f64::consts::PI / 180.0;
/// Tolerance of a port's air distance and of a layer's thickness: a third of 1.5 mm, metres.
pub const DISTANCE_TOLERANCE_M: f64 = 0.5e-3;
/// Tolerance of a bare water surface's height: a third of 0.3 mm, metres.
pub const SURFACE_TOLERANCE_M: f64 = 0.1e-3;
/// Tolerance of a camera's rotation about each axis, radians (0.02°: 0.35 mm at 1 m).
pub const ROTATION_TOLERANCE_RAD: f64 = 0.02 * std::f64::consts::PI / 180.0;
/// Tolerance of a camera's translation along each axis, metres.
pub const TRANSLATION_TOLERANCE_M: f64 = 0.5e-3;
/// The board distances tried, as multiples of the nearest and farthest fitted board distance of
/// a camera: closer than any, the near end, the middle, the far end, farther than any.
const DISTANCE_FACTORS: [(f64, f64); 5] =
    [(0.6, 0.0), (1.0, 0.0), (0.5, 0.5), (0.0, 1.0), (0.0, 1.5)];
/// The tilts tried (degrees) about the camera's x and y axes.
const TILTS_DEG: [f64; 3] = [0.0, 35.0, -35.0];
/// Places in the image tried: the centres of a 3 × 3 grid.
const REGIONS: usize = 3;
/// A candidate's corners keep this many pixels from the image border.
const MARGIN_PX: f64 = 10.0;

/// One estimated parameter with its σ and what it trades off with.
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterSigma {
    /// The parameter in the fit.
    pub parameter: Parameter,
    /// Its name in words (`shared air distance`, `right rotation y`).
    pub name: String,
    /// The unit σ is shown in (`mm`, `°`, `px`, or empty).
    pub unit: &'static str,
    /// Factor from the fit's unit (m, rad, px, 1) to `unit`.
    pub scale: f64,
    /// σ in the fit's unit.
    pub sigma: f64,
    /// What a good calibration needs of it, the fit's unit.
    pub tolerance: f64,
    /// The largest correlations with the other parameters (name, ρ), largest |ρ| first.
    pub correlations: Vec<(String, f64)>,
}

impl ParameterSigma {
    /// σ over its tolerance.
    pub fn relative(&self) -> f64 {
        self.sigma / self.tolerance
    }
}

/// What a candidate view shows.
#[derive(Debug, Clone, PartialEq)]
pub enum CandidateKind {
    /// The calibration's board, posed in front of a camera.
    Board,
    /// Texture (a targetless scene) over one cell of the master's image at one distance: a
    /// [`TEXTURE_GRID`] × [`TEXTURE_GRID`] grid of points, weighed as `matches` matches.
    Texture {
        /// The grid's points, master frame, row by row.
        points: Vec<Point3<f64>>,
        /// The matches one frame of such texture gives, as the fit found them per cell.
        matches: f64,
    },
}

/// A view the advice may propose: the board posed in front of one camera, or texture at one
/// distance over a part of the master's image (the targetless route).
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateView {
    /// Board or texture.
    pub kind: CandidateKind,
    /// The camera it is posed for (rig index).
    pub camera: usize,
    /// Distance of the board's centre from that camera's centre, metres.
    pub distance_m: f64,
    /// Tilt of the board from facing the camera, degrees.
    pub tilt_deg: f64,
    /// The camera axis the board is turned about (`x`: top/bottom away, `y`: left/right away).
    pub tilt_axis: char,
    /// The 3 × 3 image cell (column, row) the board's centre falls in.
    pub region: (usize, usize),
    /// The pixel the board's centre is on, in that camera.
    pub pixel: Point2<f64>,
    /// X_master = R·X_target + t (texture: the translation to the grid's centre).
    pub master_from_target: Isometry3<f64>,
    /// The cameras that see the whole board, with its exact corners (texture: each camera's
    /// pixels of the grid's points it sees, by point index).
    pub view: SeenView,
}

impl CandidateView {
    /// Where in the image, in words (`upper left`, `centre`).
    pub fn place(&self) -> String {
        let column = ["left", "centre", "right"][self.region.0];
        let row = ["upper", "middle", "lower"][self.region.1];
        match (row, column) {
            ("middle", "centre") => "centre".into(),
            ("middle", c) => format!("middle {c}"),
            (r, "centre") => format!("{r} centre"),
            (r, c) => format!("{r} {c}"),
        }
    }

    /// The tilt in words.
    pub fn tilt_words(&self) -> String {
        if let CandidateKind::Texture { .. } = self.kind {
            "texture, as it faces the camera".into()
        } else if self.tilt_deg == 0.0 {
            "facing the camera".into()
        } else {
            // The board turned by +θ about the camera's x axis moves its lower edge (+y, down
            // in the image) to +z, away; by +θ about y its right edge (+x) comes nearer.
            let towards = match (self.tilt_axis, self.tilt_deg > 0.0) {
                ('x', true) => "its bottom edge away from the camera",
                ('x', false) => "its top edge away from the camera",
                (_, true) => "its left edge away from the camera",
                (_, false) => "its right edge away from the camera",
            };
            format!("tilted {:.0}° ({towards})", self.tilt_deg.abs())
        }
    }
}

/// What the advice found.
#[derive(Debug, Clone, PartialEq)]
pub struct Advice {
    /// Every estimated parameter, in the fit's order.
    pub parameters: Vec<ParameterSigma>,
    /// The worst-determined parameter (largest σ over tolerance), an index into `parameters`.
    pub worst: Option<usize>,
    /// The view that shrinks the worst parameter's σ most, with that σ after one such view and
    /// after [`REPEATS`] of them.
    pub best: Option<(CandidateView, f64, f64)>,
    /// The candidates tried.
    pub candidates: usize,
    /// The advice in plain words, one sentence a line.
    pub text: Vec<String>,
}

/// Views of the advised kind whose effect is also given (a person films a few, not one).
pub const REPEATS: usize = 5;

/// The information of the global parameters (unit residual variance, board poses eliminated) of
/// `seen` under `rig` with the board poses `poses`: (the parameters, I). `None` where the views
/// and poses do not match or a pose block is singular.
pub fn information(
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
    poses: &[Isometry3<f64>],
    estimate: Estimate,
    huber: Option<f64>,
) -> Option<(Vec<Parameter>, DMatrix<f64>)> {
    if seen.len() != poses.len() || seen.is_empty() {
        return None;
    }
    let bundle = Bundle::new(rig, target, seen, estimate, huber);
    let state = State::of(rig, poses.to_vec());
    let information = bundle
        .normal_equations(&state)
        .and_then(|n| n.global_information())?;
    Some((bundle.globals().to_vec(), information))
}

/// The name, display unit, display factor and tolerance of `parameter` of `rig`.
pub fn describe(rig: &Rig, parameter: Parameter) -> (String, &'static str, f64, f64) {
    let name = parameter_name(rig, parameter);
    let degrees = 180.0 / std::f64::consts::PI;
    match parameter {
        Parameter::Axis(..) => (name, "°", degrees, AXIS_TOLERANCE_RAD),
        Parameter::Distance(p) => {
            let surface = port_names(rig)[p].1.layers().is_empty();
            let tolerance = if surface {
                SURFACE_TOLERANCE_M
            } else {
                DISTANCE_TOLERANCE_M
            };
            (name, "mm", 1e3, tolerance)
        }
        Parameter::Thickness(..) => (name, "mm", 1e3, DISTANCE_TOLERANCE_M),
        Parameter::Rotation(..) => (name, "°", degrees, ROTATION_TOLERANCE_RAD),
        Parameter::Translation(..) => (name, "mm", 1e3, TRANSLATION_TOLERANCE_M),
        Parameter::Intrinsic(k, j) => {
            let c = &rig.cameras()[k].intrinsics;
            let tolerance = match j {
                0 => 1e-3 * c.fx,
                1 => 1e-3 * c.fy,
                2 | 3 => 1.0,
                6 | 7 => 5e-4,
                _ => 5e-3,
            };
            (name, if j < 4 { "px" } else { "" }, 1.0, tolerance)
        }
    }
}

/// Every parameter's σ (σ̂ = `sigma_px`) and largest correlations from the information `info`;
/// `None` when it is singular.
pub fn sigmas(
    rig: &Rig,
    globals: &[Parameter],
    info: &DMatrix<f64>,
    sigma_px: f64,
) -> Option<Vec<ParameterSigma>> {
    let covariance = info.clone().cholesky()?.inverse();
    let names: Vec<_> = globals.iter().map(|&p| describe(rig, p)).collect();
    Some(
        globals
            .iter()
            .enumerate()
            .map(|(i, &parameter)| {
                let (name, unit, scale, tolerance) = names[i].clone();
                let mut correlations: Vec<(String, f64)> = (0..globals.len())
                    .filter(|&j| j != i)
                    .map(|j| {
                        let rho = covariance[(i, j)]
                            / (covariance[(i, i)] * covariance[(j, j)]).sqrt().max(1e-300);
                        (names[j].0.clone(), rho)
                    })
                    .collect();
                correlations.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
                correlations.truncate(3);
                ParameterSigma {
                    parameter,
                    name,
                    unit,
                    scale,
                    sigma: sigma_px * covariance[(i, i)].max(0.0).sqrt(),
                    tolerance,
                    correlations,
                }
            })
            .collect(),
    )
}

/// The candidate views of `target` for every camera of `rig`: distances from those of the fitted
/// board poses `poses` ([`DISTANCE_FACTORS`]), tilts about the camera's x and y axes
/// ([`TILTS_DEG`]) and the centres of a 3 × 3 grid over the image, each kept where the whole board
/// projects into the camera it is posed for (with a margin), with every camera that sees the
/// whole board.
pub fn candidate_views(rig: &Rig, target: &Target, poses: &[Isometry3<f64>]) -> Vec<CandidateView> {
    let points: Vec<Point3<f64>> = (0..target.len()).map(|i| target.point(i)).collect();
    if points.is_empty() {
        return Vec::new();
    }
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / points.len() as f64;
    let cameras: Vec<_> = (0..rig.cameras().len())
        .map(|k| rig.refractive_camera(k))
        .collect();
    let mut out = Vec::new();
    for (k, rig_camera) in rig.cameras().iter().enumerate() {
        let centre = rig_camera.centre_in_master();
        let distances: Vec<f64> = poses
            .iter()
            .map(|pose| (pose * Point3::from(centroid) - centre).norm())
            .filter(|d| d.is_finite())
            .collect();
        let near = distances.iter().copied().fold(f64::INFINITY, f64::min);
        let far = distances.iter().copied().fold(0.0, f64::max);
        if !near.is_finite() || far <= 0.0 {
            continue;
        }
        let master_from_cam = rig_camera.cam_from_master.rotation.inverse();
        let (w, h) = (
            f64::from(rig_camera.intrinsics.width),
            f64::from(rig_camera.intrinsics.height),
        );
        for &(a, b) in &DISTANCE_FACTORS {
            let distance = a * near + b * far;
            for (axis, tilt) in [('x', 0.0)].into_iter().chain(
                TILTS_DEG
                    .iter()
                    .filter(|t| **t != 0.0)
                    .flat_map(|&t| [('x', t), ('y', t)]),
            ) {
                for row in 0..REGIONS {
                    for column in 0..REGIONS {
                        let pixel = Point2::new(
                            (column as f64 + 0.5) / REGIONS as f64 * w,
                            (row as f64 + 0.5) / REGIONS as f64 * h,
                        );
                        let Ok(ray) = cameras[k].backproject(&pixel) else {
                            continue;
                        };
                        let along = distance - (ray.origin - centre).norm();
                        if along <= 0.0 {
                            continue;
                        }
                        let at = ray.origin + ray.dir.into_inner() * along;
                        let turn = match axis {
                            'x' => {
                                Rotation3::from_axis_angle(&Vector3::x_axis(), tilt.to_radians())
                            }
                            _ => Rotation3::from_axis_angle(&Vector3::y_axis(), tilt.to_radians()),
                        };
                        let rotation =
                            master_from_cam * UnitQuaternion::from_rotation_matrix(&turn);
                        let translation = at.coords - rotation * centroid;
                        let pose = Isometry3::from_parts(Translation3::from(translation), rotation);
                        let view =
                            as_fitted(rig, target, exact_view(rig, &cameras, &points, &pose));
                        if view.corners_of(k).is_none() {
                            continue;
                        }
                        out.push(CandidateView {
                            kind: CandidateKind::Board,
                            camera: k,
                            distance_m: distance,
                            tilt_deg: tilt,
                            tilt_axis: axis,
                            region: (column, row),
                            pixel,
                            master_from_target: pose,
                            view,
                        });
                    }
                }
            }
        }
    }
    out
}

/// The pixel of `point` in `camera` (its lens `intrinsics`), where it is at least [`MARGIN_PX`]
/// inside the image.
fn pixel_inside(
    camera: &crate::model::RefractiveCamera,
    intrinsics: &crate::model::PinholeCamera,
    point: &Point3<f64>,
) -> Option<Point2<f64>> {
    let pixel = camera.project(point).ok()?;
    let (w, h) = (f64::from(intrinsics.width), f64::from(intrinsics.height));
    let inside = pixel.x >= MARGIN_PX
        && pixel.y >= MARGIN_PX
        && pixel.x <= w - MARGIN_PX
        && pixel.y <= h - MARGIN_PX;
    inside.then_some(pixel)
}

/// The exact corners of `points` at `pose` in every camera that sees all of them ([`MARGIN_PX`]
/// inside its image).
fn exact_view(
    rig: &Rig,
    cameras: &[crate::model::RefractiveCamera],
    points: &[Point3<f64>],
    pose: &Isometry3<f64>,
) -> SeenView {
    let mut view = SeenView::default();
    for (k, camera) in cameras.iter().enumerate() {
        let intrinsics = &rig.cameras()[k].intrinsics;
        let corners: Option<Vec<(usize, Point2<f64>)>> = points
            .iter()
            .enumerate()
            .map(|(i, p)| Some((i, pixel_inside(camera, intrinsics, &(pose * p))?)))
            .collect();
        if let Some(corners) = corners {
            view.cameras.push((k, corners));
            view.keys.push(rig.cameras()[k].name.clone());
        }
    }
    view
}

/// `seen` as the calibration fits it: for a board, without the corner images the screening of
/// gross errors leaves out of every estimate ([`screen`]: a strongly tilted board seen through the
/// port can stray from the board's smooth shape by more than its threshold).
pub fn as_fitted_views(rig: &Rig, target: &Target, seen: &[SeenView]) -> Vec<SeenView> {
    match target.board() {
        Some(board) => screen(rig, board, seen)
            .without_suspects(seen)
            .unwrap_or_else(|| seen.to_vec()),
        None => seen.to_vec(),
    }
}

fn as_fitted(rig: &Rig, target: &Target, view: SeenView) -> SeenView {
    if view.cameras.is_empty() {
        return view;
    }
    as_fitted_views(rig, target, std::slice::from_ref(&view))
        .pop()
        .unwrap_or(view)
}

/// σ of parameter `j` (σ̂ = `sigma_px`) from the information `info`, `None` when singular.
fn sigma_of(info: &DMatrix<f64>, j: usize, sigma_px: f64) -> Option<f64> {
    // (I⁻¹)_jj = e_jᵀ I⁻¹ e_j: one solve, not the whole inverse.
    let mut unit = nalgebra::DVector::zeros(info.nrows());
    unit[j] = 1.0;
    let column = info.clone().cholesky()?.solve(&unit);
    Some(sigma_px * column[j].max(0.0).sqrt())
}

/// An advice with no parameter yet, saying `line`.
fn bare(line: &str) -> Advice {
    Advice {
        parameters: Vec::new(),
        worst: None,
        best: None,
        candidates: 0,
        text: vec![line.into()],
    }
}

/// The advice's parameters (their σ from `info`, σ̂ = `sigma_px`), the worst of them and the
/// sentence that names it; a bare advice saying why (no worst parameter) where `info` is
/// singular or empty.
fn weighed(
    rig: &Rig,
    globals: &[Parameter],
    info: &DMatrix<f64>,
    sigma_px: f64,
    singular: &str,
) -> Advice {
    let Some(parameters) = sigmas(rig, globals, info, sigma_px) else {
        return bare(singular);
    };
    let Some(worst) = parameters
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.relative().total_cmp(&b.1.relative()))
        .map(|(i, _)| i)
    else {
        return bare("Nothing was estimated.");
    };
    let w = &parameters[worst];
    let line = format!(
        "The worst-determined parameter is the {}: σ {:.4} {} against the {:.4} {} a good calibration needs ({:.1}×){}.",
        w.name,
        w.sigma * w.scale,
        w.unit,
        w.tolerance * w.scale,
        w.unit,
        w.relative(),
        w.correlations
            .first()
            .map_or(String::new(), |(n, r)| format!(
                "; it trades off with the {n} (ρ = {r:+.2})"
            ))
    );
    Advice {
        parameters,
        worst: Some(worst),
        best: None,
        candidates: 0,
        text: vec![line],
    }
}

/// Of `candidates`, the one whose information (`extra`, computed on every core) shrinks the σ of
/// parameter `worst` most when added to `info`, with that σ after one such view and after
/// [`REPEATS`] of them; the first of the smallest wins.
fn best_of(
    candidates: Vec<CandidateView>,
    extra: impl Fn(&CandidateView) -> Option<DMatrix<f64>> + Sync,
    info: &DMatrix<f64>,
    worst: usize,
    sigma_px: f64,
) -> Option<(CandidateView, f64, f64)> {
    let scored: Vec<Option<(f64, DMatrix<f64>)>> = candidates
        .par_iter()
        .map(|candidate| {
            let extra = extra(candidate)?;
            Some((sigma_of(&(info + &extra), worst, sigma_px)?, extra))
        })
        .collect();
    candidates
        .into_iter()
        .zip(scored)
        .filter_map(|(c, s)| s.map(|(after, extra)| (c, after, extra)))
        .fold(
            None::<(CandidateView, f64, DMatrix<f64>)>,
            |best, next| match best {
                Some(b) if b.1 <= next.1 => Some(b),
                _ => Some(next),
            },
        )
        .map(|(candidate, after, extra)| {
            let repeated =
                sigma_of(&(info + &extra * REPEATS as f64), worst, sigma_px).unwrap_or(after);
            (candidate, after, repeated)
        })
}

/// The closing sentence when the worst parameter already meets its tolerance.
fn already_good(advice: &mut Advice) {
    if let Some(w) = advice.worst
        && advice.parameters[w].relative() <= 1.0
    {
        advice.text.push(
            "Every parameter is already within what a good calibration needs; more views only refine it."
                .into(),
        );
    }
}

/// The advice for the fit of `seen` (screened as the calibration screens them: [`as_fitted_views`]) (board poses `poses`) under the calibrated `rig`, estimating
/// `estimate` with noise σ̂ = `sigma_px`: see the module documentation.
pub fn advise(
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
    poses: &[Isometry3<f64>],
    estimate: Estimate,
    huber: Option<f64>,
    sigma_px: f64,
) -> Advice {
    let fitted = as_fitted_views(rig, target, seen);
    let Some((globals, info)) = information(rig, target, &fitted, poses, estimate, huber) else {
        return bare(
            "No information matrix: the fitted views and their board poses are not at hand for this route.",
        );
    };
    let mut advice = weighed(
        rig,
        &globals,
        &info,
        sigma_px,
        "The information matrix is singular: the views do not determine every estimated parameter (vary the board's distance and tilt).",
    );
    let Some(worst) = advice.worst else {
        return advice;
    };
    let candidates = candidate_views(rig, target, poses);
    advice.candidates = candidates.len();
    let extra = |candidate: &CandidateView| {
        information(
            rig,
            target,
            std::slice::from_ref(&candidate.view),
            std::slice::from_ref(&candidate.master_from_target),
            estimate,
            None,
        )
        .map(|(_, extra)| extra)
    };
    advice.best = best_of(candidates, extra, &info, worst, sigma_px);
    let w = &advice.parameters[worst];
    let line = match &advice.best {
        Some((c, after, repeated)) => {
            let name = &rig.cameras()[c.camera].name;
            format!(
                "Add views with the board {:.2} m from camera {name}, {}, its centre in the {} of {name}'s image (marked on the coverage pictures): one such view takes the {}'s σ from {:.4} to {:.4} {}, {REPEATS} such views to {:.4} {}.",
                c.distance_m,
                c.tilt_words(),
                c.place(),
                w.name,
                w.sigma * w.scale,
                after * w.scale,
                w.unit,
                repeated * w.scale,
                w.unit,
            )
        }
        None => "No candidate view fits the board whole into a camera's image at the distances filmed; film the board farther away or use a ChArUco board.".into(),
    };
    advice.text.push(line);
    if advice.best.is_some() {
        already_good(&mut advice);
    }
    advice
}

/// Points on a side of a texture candidate's grid.
pub const TEXTURE_GRID: usize = 5;
/// The texture distances tried, as multiples of the nearest and farthest matched point's
/// distance (5th and 95th percentile): well in front of the scene, in front of it, its near end,
/// its middle, its far end. Nearer texture is what pins an air layer down.
const TEXTURE_DISTANCE_FACTORS: [(f64, f64); 5] =
    [(0.3, 0.0), (0.6, 0.0), (1.0, 0.0), (0.5, 0.5), (0.0, 1.0)];

/// The matches one frame gives over a cell of a 3 × 3 grid of the master's image: the median
/// over the (frame, cell) pairs that hold any of the fit's tracks (at least 1).
fn matches_per_cell(result: &TargetlessCalibration) -> f64 {
    let i = &result.rig.cameras()[0].intrinsics;
    let (w, h) = (f64::from(i.width), f64::from(i.height));
    let mut counts: std::collections::BTreeMap<(usize, usize, usize), usize> = Default::default();
    for t in &result.tracks {
        let Some((_, p)) = t.pixels.iter().find(|(k, _)| *k == 0) else {
            continue;
        };
        let cell = |x: f64, size: f64| ((x / size * REGIONS as f64) as usize).min(REGIONS - 1);
        *counts
            .entry((t.frame, cell(p.x.max(0.0), w), cell(p.y.max(0.0), h)))
            .or_default() += 1;
    }
    let mut values: Vec<usize> = counts.into_values().collect();
    values.sort_unstable();
    values
        .get(values.len() / 2)
        .map_or(1.0, |m| (*m).max(1) as f64)
}

/// The texture candidates of a targetless fit: for each cell of a 3 × 3 grid over the master's
/// image and each distance from those of the fit's points ([`TEXTURE_DISTANCE_FACTORS`]), a [`TEXTURE_GRID`]² grid of points over the cell's middle at that distance
/// from the master, kept where at least half of them are seen by the master and another camera.
pub fn texture_candidates(rig: &Rig, points: &[Point3<f64>], matches: f64) -> Vec<CandidateView> {
    let cameras: Vec<_> = (0..rig.cameras().len())
        .map(|k| rig.refractive_camera(k))
        .collect();
    let master = &rig.cameras()[0];
    let centre = master.centre_in_master();
    let mut distances: Vec<f64> = points
        .iter()
        .map(|p| (p - centre).norm())
        .filter(|d| d.is_finite())
        .collect();
    if distances.is_empty() {
        return Vec::new();
    }
    distances.sort_by(f64::total_cmp);
    let near = distances[distances.len() / 20];
    let far = distances[distances.len() - 1 - distances.len() / 20];
    let (w, h) = (
        f64::from(master.intrinsics.width),
        f64::from(master.intrinsics.height),
    );
    let mut out = Vec::new();
    for &(a, b) in &TEXTURE_DISTANCE_FACTORS {
        let distance = a * near + b * far;
        for row in 0..REGIONS {
            for column in 0..REGIONS {
                let cell = |i: usize, across: usize, size: f64, index: usize| {
                    // The middle 60 % of the cell.
                    let t = 0.2 + 0.6 * i as f64 / (across - 1) as f64;
                    (index as f64 + t) / REGIONS as f64 * size
                };
                let grid: Vec<Point3<f64>> = (0..TEXTURE_GRID * TEXTURE_GRID)
                    .filter_map(|g| {
                        let pixel = Point2::new(
                            cell(g % TEXTURE_GRID, TEXTURE_GRID, w, column),
                            cell(g / TEXTURE_GRID, TEXTURE_GRID, h, row),
                        );
                        let ray = cameras[0].backproject(&pixel).ok()?;
                        let along = distance - (ray.origin - centre).norm();
                        (along > 0.0).then(|| ray.origin + ray.dir.into_inner() * along)
                    })
                    .collect();
                if grid.len() < TEXTURE_GRID * TEXTURE_GRID {
                    continue;
                }
                let mut view = SeenView::default();
                for (k, camera) in cameras.iter().enumerate() {
                    let intrinsics = &rig.cameras()[k].intrinsics;
                    let seen: Vec<(usize, Point2<f64>)> = grid
                        .iter()
                        .enumerate()
                        .filter_map(|(i, p)| Some((i, pixel_inside(camera, intrinsics, p)?)))
                        .collect();
                    if !seen.is_empty() {
                        view.cameras.push((k, seen));
                        view.keys.push(rig.cameras()[k].name.clone());
                    }
                }
                let tracked = texture_tracks(&view, &grid).0.len();
                if 2 * tracked < grid.len() {
                    continue;
                }
                let middle =
                    grid.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / grid.len() as f64;
                let pixel = Point2::new(
                    (column as f64 + 0.5) / REGIONS as f64 * w,
                    (row as f64 + 0.5) / REGIONS as f64 * h,
                );
                out.push(CandidateView {
                    kind: CandidateKind::Texture {
                        points: grid,
                        matches,
                    },
                    camera: 0,
                    distance_m: distance,
                    tilt_deg: 0.0,
                    tilt_axis: 'x',
                    region: (column, row),
                    pixel,
                    master_from_target: Isometry3::translation(middle.x, middle.y, middle.z),
                    view,
                });
            }
        }
    }
    out
}

/// The tracks of a texture candidate: each grid point the master and at least one other camera
/// see, with its point.
fn texture_tracks(view: &SeenView, grid: &[Point3<f64>]) -> (Vec<Track>, Vec<Point3<f64>>) {
    grid.iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let pixels: Vec<(usize, Point2<f64>)> = view
                .cameras
                .iter()
                .filter_map(|(k, seen)| seen.iter().find(|(j, _)| *j == i).map(|(_, x)| (*k, *x)))
                .collect();
            (pixels.first().is_some_and(|(k, _)| *k == 0) && pixels.len() >= 2)
                .then_some((Track { frame: 0, pixels }, *p))
        })
        .unzip()
}

/// The information a texture candidate adds to a targetless fit of `rig` estimating `estimate`:
/// its grid's tracks' JᵀJ (points eliminated) scaled to the matches one frame of it gives.
fn texture_information(
    rig: &Rig,
    estimate: Estimate,
    candidate: &CandidateView,
) -> Option<DMatrix<f64>> {
    let CandidateKind::Texture { points, matches } = &candidate.kind else {
        return None;
    };
    let (tracks, points) = texture_tracks(&candidate.view, points);
    if tracks.is_empty() {
        return None;
    }
    let problem = PointsProblem::new(rig, &tracks, estimate, None);
    let state = PointsState {
        rig: State::of(rig, Vec::new()),
        points,
    };
    let information = problem.normal_equations(&state)?.global_information()?;
    Some(information * (matches / tracks.len() as f64))
}

/// The advice for a targetless calibration: each port parameter's σ from the fit's information
/// (as the route computes it), the worst of them, and the texture — a part of the master's image
/// at one distance ([`texture_candidates`]) — that, filmed in one more frame with as many matches
/// as the fit found per cell, shrinks its σ most.
pub fn advise_targetless(result: &TargetlessCalibration) -> Advice {
    let rig = &result.rig;
    let Some(info) = &result.information else {
        return bare(
            "The information matrix is singular: the matches do not determine the port at all; film a scene with texture at several distances across the whole image.",
        );
    };
    let mut advice = weighed(
        rig,
        &result.globals,
        info,
        result.sigma_px,
        "The information matrix is singular: the matches do not determine the port at all; film a scene with texture at several distances across the whole image.",
    );
    let Some(worst) = advice.worst else {
        return advice;
    };
    let matches = matches_per_cell(result);
    let candidates = texture_candidates(rig, &result.points, matches);
    advice.candidates = candidates.len();
    let extra = |candidate: &CandidateView| texture_information(rig, result.estimate, candidate);
    advice.best = best_of(candidates, extra, info, worst, result.sigma_px);
    let w = &advice.parameters[worst];
    let master = &rig.cameras()[0].name;
    let line = match &advice.best {
        Some((c, after, repeated)) => {
            let seen_by: Vec<&str> = c
                .view
                .cameras
                .iter()
                .map(|(k, _)| rig.cameras()[*k].name.as_str())
                .collect();
            format!(
                "Film textured scene {:.2} m from camera {master}, filling the {} of its image (seen by {}; marked on the coverage pictures): one frame of it (about {matches:.0} matches there, as your footage gives per ninth of the image) takes the {}'s σ from {:.4} to {:.4} {}, {REPEATS} such frames to {:.4} {}.",
                c.distance_m,
                c.place(),
                seen_by.join(", "),
                w.name,
                w.sigma * w.scale,
                after * w.scale,
                w.unit,
                repeated * w.scale,
                w.unit,
            )
        }
        None => format!(
            "No part of {master}'s image at the distances filmed is seen by another camera: check the rig's extrinsics."
        ),
    };
    advice.text.push(line);
    if advice.best.is_some() {
        already_good(&mut advice);
    }
    advice
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn places_and_tilts_read_as_words() {
        let c = CandidateView {
            kind: CandidateKind::Board,
            camera: 0,
            distance_m: 1.0,
            tilt_deg: 35.0,
            tilt_axis: 'x',
            region: (0, 0),
            pixel: Point2::origin(),
            master_from_target: Isometry3::identity(),
            view: SeenView::default(),
        };
        assert_eq!(c.place(), "upper left");
        assert!(c.tilt_words().contains("bottom edge away"));
        let centre = CandidateView {
            region: (1, 1),
            tilt_deg: 0.0,
            ..c
        };
        assert_eq!(centre.place(), "centre");
        assert_eq!(centre.tilt_words(), "facing the camera");
    }

    #[test]
    fn the_tilt_in_words_is_the_edge_that_is_farther() {
        let rig = crate::io::read_rig(std::path::Path::new("data/example_rig.json")).unwrap();
        let target = Target::Board(crate::base::Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        });
        let poses = [
            Isometry3::translation(-0.16, -0.1, 0.5),
            Isometry3::translation(-0.16, -0.1, 0.8),
        ];
        let candidates = candidate_views(&rig, &target, &poses);
        let tilted: Vec<_> = candidates
            .iter()
            .filter(|c| c.camera == 0 && c.tilt_deg != 0.0)
            .collect();
        assert!(tilted.len() > 10, "{} tilted candidates", tilted.len());
        let cam_from_master = rig.cameras()[0].cam_from_master;
        for c in tilted {
            let corners = c.view.corners_of(0).unwrap();
            let depth = |i: usize| (cam_from_master * (c.master_from_target * target.point(i))).z;
            // The corners at the image's extremes along the turn's direction.
            let along = |p: &Point2<f64>| if c.tilt_axis == 'x' { p.y } else { p.x };
            let low = corners
                .iter()
                .min_by(|a, b| along(&a.1).total_cmp(&along(&b.1)))
                .unwrap();
            let high = corners
                .iter()
                .max_by(|a, b| along(&a.1).total_cmp(&along(&b.1)))
                .unwrap();
            let far_edge = if depth(high.0) > depth(low.0) {
                if c.tilt_axis == 'x' {
                    "bottom"
                } else {
                    "right"
                }
            } else if c.tilt_axis == 'x' {
                "top"
            } else {
                "left"
            };
            assert!(
                c.tilt_words()
                    .contains(&format!("its {far_edge} edge away")),
                "{} but the {far_edge} edge is farther",
                c.tilt_words()
            );
        }
    }
}
