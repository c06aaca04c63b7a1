//! What a calibration found and how well the data fit it: one [`Report`] for every rig, with the
//! ports and cameras and their standard deviations, the residuals per camera and view, the corner
//! images far above the rest, the stages that ran and, when the result does not fit, what the data
//! look like.

use std::collections::{BTreeSet, HashSet};

use nalgebra::{DMatrix, Isometry3, Matrix3, Vector2, Vector3};

use super::bundle::{Bundle, Estimate, INTRINSICS, Parameter, State};
use super::consecutive::no_solution;
/// The stages are recorded as the estimate runs (`calib::pipeline::estimate`) and reported here.
pub use super::estimate::Stage;
use super::estimate::{Fit, Outcome};
use super::{MIN_VIEWS, Method, Options, WEAK_AIR_STD_M, WEAK_TILT_STD_DEG};
use crate::calib::costs::SceneFit;
use crate::calib::costs::invariants::plane_basis;
use crate::calib::error::CalibError;
use crate::calib::problem::data::{CameraPair, StereoData};
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::screen::Screening;
use crate::calib::problem::target::Target;
use crate::calib::solvers::block::{BlockNormalEquations, POSE_PARAMETERS};
use crate::calib::solvers::lm::{LeastSquares, LmReport, Termination};
use crate::model::{Interface, Ports, Rig};

/// A calibrated quantity with its standard deviation (`None` when known, not estimated, not
/// refined by maximum likelihood, or when the covariance is singular).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimated {
    /// The value.
    pub value: f64,
    /// Its standard deviation.
    pub std: Option<f64>,
}

/// One calibrated port.
#[derive(Debug, Clone, PartialEq)]
pub struct PortReport {
    /// `shared`, or the name of the camera whose port it is.
    pub name: String,
    /// Unit axis in the port's frame (the master's when shared, its camera's otherwise).
    pub normal: [f64; 3],
    /// Tilt from that frame's z axis, radians.
    pub tilt: Estimated,
    /// Azimuth atan2(n_y, n_x), radians.
    pub azimuth: Estimated,
    /// Air distance, metres.
    pub distance: Estimated,
    /// Layer thicknesses, metres.
    pub thicknesses: Vec<Estimated>,
}

/// One camera's share of the result.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraReport {
    /// Its name.
    pub name: String,
    /// Corners it saw.
    pub observations: usize,
    /// Views it saw.
    pub views: usize,
    /// RMS reprojection error over every corner it saw, pixels (NaN when it saw none).
    pub rms_px: f64,
    /// RMS reprojection error over its corner images that are not outliers, pixels.
    pub inlier_rms_px: f64,
    /// RMS reprojection error per view, pixels (NaN for a view it did not see).
    pub rms_px_per_view: Vec<f64>,
    /// Standard deviations of its rotation (about the x, y, z axes, radians) and translation (m),
    /// when its extrinsics were estimated.
    pub extrinsics_std: Option<([f64; 3], [f64; 3])>,
    /// Standard deviations of its intrinsics in the order of
    /// [`INTRINSICS`] (fx, fy, cx, cy in pixels; k1, k2, p1, p2, k3),
    /// when they were estimated; `None` for a lens term held at 0.
    pub intrinsics_std: Option<[Option<f64>; 9]>,
}

/// A corner image whose reprojection residual is far above the rest, or that the screening
/// found off the board's shape in its image.
#[derive(Debug, Clone, PartialEq)]
pub struct Outlier {
    /// 0-based view.
    pub view: usize,
    /// The image's key in the observations (`left`, or the camera's name).
    pub image: String,
    /// The rig camera that took that image.
    pub camera: String,
    /// Corner index on the target.
    pub corner: usize,
    /// Its reprojection residual under the result, pixels.
    pub residual_px: f64,
    /// Whether the screening of the images ([`screen`](crate::calib::problem::screen)) found it
    /// before any fit; such corners are left out of the estimate.
    pub screened: bool,
}

/// The 3-D errors of one camera pair's triangulated corners under the result.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneErrors {
    /// The pair's camera names.
    pub cameras: [String; 2],
    /// RMS residual of the rigid target fit to the triangulated corners, metres.
    pub rms_m: f64,
    /// RMS deviation of adjacent triangulated corners' distances from the board's square, metres.
    pub square_deviation_rms_m: f64,
}

/// Everything a calibration found and how well the data fit it.
#[derive(Debug, Clone, PartialEq)]
pub struct Report {
    /// The method asked for.
    pub method: Method,
    /// What ran, in words (`auto: consecutive (thesis) over 1 camera pair(s), best pair
    /// left–right, maximum likelihood from 3 starts`).
    pub strategy: String,
    /// What was estimated.
    pub estimate: Estimate,
    /// The ports, in rig order (one when shared).
    pub ports: Vec<PortReport>,
    /// The cameras, in rig order.
    pub cameras: Vec<CameraReport>,
    /// Estimated pixel noise σ̂ from the residuals of a maximum-likelihood fit (`None` for the
    /// consecutive method).
    pub sigma_px: Option<f64>,
    /// Where the views scatter more than σ̂ says (the corners of a view err together: blur, a
    /// lens or board a little off; some views noisier than others), every σ of the report is
    /// raised to what the scatter says ([`clustered_covariance`](crate::calib::solvers::block::BlockNormalEquations::clustered_covariance)): the
    /// parameter raised most and by how much. `None` where none was raised, or without a fit.
    pub sigma_from_scatter: Option<(String, f64)>,
    /// The corner noise σ per coordinate seen in the images themselves (the scatter of each
    /// board corner about the board's smooth shape), pixels: what the reprojection RMS of a fit
    /// comes close to. `None` for a 3-D target or a board under 3 × 3.
    pub noise_px: Option<f64>,
    /// RMS reprojection error over every corner image, pixels.
    pub rms_px: f64,
    /// The 3-D errors of a camera pair's triangulated corners (the pair the consecutive method
    /// ran on, else the first pair that saw three views of a board together), if any.
    pub scene: Option<SceneErrors>,
    /// Target poses X_master = R·X_target + t per view.
    pub poses: Vec<Isometry3<f64>>,
    /// Whether the target is a board.
    pub board: bool,
    /// The stages that ran, in order.
    pub stages: Vec<Stage>,
    /// Iterations of the final refinement.
    pub iterations: usize,
    /// Why it stopped.
    pub termination: String,
    /// Corner images with residuals far above the rest (or that the screening found), worst first.
    pub outliers: Vec<Outlier>,
    /// Whether the result fits: every camera's RMS over its images that are not outliers is at
    /// most the bound of [`Options::max_rms_px`](super::Options::max_rms_px) (by default also
    /// within a few times the corner noise seen in the images). The CLI writes no rig otherwise.
    pub fits: bool,
    /// What the data look like, when the RMS is far above the noise or above the bound; empty
    /// otherwise.
    pub diagnosis: Vec<String>,
    /// Everything worth a second look.
    pub warnings: Vec<String>,
    /// Wall-clock seconds of the whole calibration.
    pub seconds: f64,
    /// What evaluated the cost batches and the bundle's residual stencils: the device, and on a
    /// GPU which stages ran there ([`Backend::describe_stages`](super::Backend::describe_stages)).
    pub backend: String,
    /// Views used.
    pub views: usize,
    /// Distinct corners used (a corner seen by several cameras in a view counts once).
    pub corners: usize,
    /// Corner observations (one per corner per camera that saw it).
    pub observations: usize,
}

impl Report {
    /// The largest RMS over a camera's images that are not outliers, pixels (0 when no camera saw
    /// anything).
    pub fn worst_inlier_rms_px(&self) -> f64 {
        self.cameras
            .iter()
            .map(|c| c.inlier_rms_px)
            .filter(|r| !r.is_nan())
            .fold(0.0, f64::max)
    }

    /// The first port (the shared one, or the master's own): what a stereo calibration reports.
    pub fn port(&self) -> &PortReport {
        &self.ports[0]
    }
}

/// Residuals of every corner image: per view, (camera, corner, residual) in the bundle's order.
pub type Residuals = Vec<Vec<(usize, usize, Vector2<f64>)>>;

/// The residuals of `views` as the bundle gives them (per view, camera by camera, corners in
/// target order) labelled with their camera and corner.
pub fn label_residuals(views: &[SeenView], residuals: &[Vec<Vector2<f64>>]) -> Residuals {
    views
        .iter()
        .zip(residuals)
        .map(|(view, r)| {
            view.cameras
                .iter()
                .flat_map(|(k, corners)| corners.iter().map(move |(i, _)| (*k, *i)))
                .zip(r)
                .map(|((k, i), r)| (k, i, *r))
                .collect()
        })
        .collect()
}

/// Corner images whose residual exceeds max(1 px, 5 × the robust σ: 1.4826 × the median over
/// the corners of each corner's largest image residual), and the images the screening found,
/// marked (a screened image the result explains is not an outlier); worst first.
pub fn find_outliers(
    rig: &Rig,
    views: &[SeenView],
    residuals: &Residuals,
    screening: Option<&Screening>,
) -> Vec<Outlier> {
    let mut largest: std::collections::BTreeMap<(usize, usize), f64> = Default::default();
    for (v, view) in residuals.iter().enumerate() {
        for &(_, i, r) in view {
            let e = largest.entry((v, i)).or_insert(0.0);
            *e = e.max(r.norm());
        }
    }
    let mut sorted: Vec<f64> = largest.values().copied().collect();
    if sorted.is_empty() {
        return Vec::new();
    }
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let threshold = (5.0 * 1.4826 * median).max(1.0);
    let mut outliers = Vec::new();
    for (v, view) in residuals.iter().enumerate() {
        for &(k, i, r) in view {
            let length = r.norm();
            if length > threshold {
                let key = views[v]
                    .cameras
                    .iter()
                    .position(|(c, _)| *c == k)
                    .map_or_else(
                        || rig.cameras()[k].name.clone(),
                        |p| views[v].keys[p].clone(),
                    );
                outliers.push(Outlier {
                    view: v,
                    image: key,
                    camera: rig.cameras()[k].name.clone(),
                    corner: i,
                    residual_px: length,
                    screened: screening.is_some_and(|s| s.is_suspect(v, k, i)),
                });
            }
        }
    }
    outliers.sort_by(|a, b| b.residual_px.total_cmp(&a.residual_px));
    outliers
}

/// Per camera: (RMS over every corner image, RMS over those that are not `outliers`, RMS per
/// view), pixels; NaN where a camera saw nothing.
pub fn camera_rms(
    rig: &Rig,
    residuals: &Residuals,
    outliers: &[Outlier],
) -> Vec<(f64, f64, Vec<f64>)> {
    let flagged: HashSet<(usize, &str, usize)> = outliers
        .iter()
        .map(|o| (o.view, o.camera.as_str(), o.corner))
        .collect();
    let rms = |sum: f64, n: usize| {
        if n == 0 {
            f64::NAN
        } else {
            (sum / n as f64).sqrt()
        }
    };
    rig.cameras()
        .iter()
        .enumerate()
        .map(|(k, camera)| {
            let (mut all, mut inliers, mut per_view) = ((0.0, 0), (0.0, 0), Vec::new());
            for (v, view) in residuals.iter().enumerate() {
                let mut this = (0.0, 0);
                for &(_, i, r) in view.iter().filter(|(c, _, _)| *c == k) {
                    let r2 = r.norm_squared();
                    this.0 += r2;
                    this.1 += 1;
                    if !flagged.contains(&(v, camera.name.as_str(), i)) {
                        inliers.0 += r2;
                        inliers.1 += 1;
                    }
                }
                all.0 += this.0;
                all.1 += this.1;
                per_view.push(rms(this.0, this.1));
            }
            (rms(all.0, all.1), rms(inliers.0, inliers.1), per_view)
        })
        .collect()
}

/// The standard deviation of global parameter `parameter`, from the covariance.
fn std_of(
    globals: &[Parameter],
    covariance: Option<&DMatrix<f64>>,
    parameter: Parameter,
) -> Option<f64> {
    let i = globals.iter().position(|&g| g == parameter)?;
    covariance.map(|c| c[(i, i)].max(0.0).sqrt())
}

/// Every port of `state` with its standard deviations from `covariance` (of the global
/// parameters `globals`, σ̂² applied): tilt and azimuth carried from the tangent-plane parameters.
pub fn port_reports(
    rig: &Rig,
    state: &State,
    globals: &[Parameter],
    covariance: Option<&DMatrix<f64>>,
) -> Vec<PortReport> {
    state
        .ports
        .iter()
        .enumerate()
        .map(|(p, port)| {
            let name = port_names(rig).swap_remove(p).0;
            let n = port.normal;
            // (tilt, azimuth) from the tangent-plane parameters by their derivatives at n.
            let (tilt_std, azimuth_std) = match (
                globals.iter().position(|&g| g == Parameter::Axis(p, 0)),
                globals.iter().position(|&g| g == Parameter::Axis(p, 1)),
                covariance,
            ) {
                (Some(i), Some(j), Some(c)) => {
                    let [e1, e2] = plane_basis(&n);
                    let sin_tilt = (n.x * n.x + n.y * n.y).sqrt();
                    // d tilt = −d n_z / sin t; d azimuth = (n_x d n_y − n_y d n_x) / sin² t.
                    let d_tilt = |e: &Vector3<f64>| -e.z / sin_tilt.max(1e-12);
                    let d_azimuth = |e: &Vector3<f64>| {
                        (n.x * e.y - n.y * e.x) / (sin_tilt * sin_tilt).max(1e-24)
                    };
                    let jt = Vector2::new(d_tilt(&e1), d_tilt(&e2));
                    let ja = Vector2::new(d_azimuth(&e1), d_azimuth(&e2));
                    let cov = nalgebra::Matrix2::new(c[(i, i)], c[(i, j)], c[(j, i)], c[(j, j)]);
                    // At zero tilt the angles are singular: report the axis σ as the tilt's.
                    if sin_tilt < 1e-9 {
                        (Some(cov.trace().sqrt()), None)
                    } else {
                        (
                            Some(jt.dot(&(cov * jt)).max(0.0).sqrt()),
                            Some(ja.dot(&(cov * ja)).max(0.0).sqrt()),
                        )
                    }
                }
                _ => (None, None),
            };
            PortReport {
                name,
                normal: [n.x, n.y, n.z],
                tilt: Estimated {
                    value: n.z.clamp(-1.0, 1.0).acos(),
                    std: tilt_std,
                },
                azimuth: Estimated {
                    value: n.y.atan2(n.x),
                    std: azimuth_std,
                },
                distance: Estimated {
                    value: port.distance,
                    std: std_of(globals, covariance, Parameter::Distance(p)),
                },
                thicknesses: port
                    .thicknesses
                    .iter()
                    .enumerate()
                    .map(|(i, &t)| Estimated {
                        value: t,
                        std: std_of(globals, covariance, Parameter::Thickness(p, i)),
                    })
                    .collect(),
            }
        })
        .collect()
}

/// Every camera's share: what it saw in `views`, its RMS values (from [`camera_rms`]) and, when
/// its extrinsics or intrinsics were estimated, their standard deviations.
pub fn camera_reports(
    rig: &Rig,
    views: &[SeenView],
    rms: Vec<(f64, f64, Vec<f64>)>,
    globals: &[Parameter],
    covariance: Option<&DMatrix<f64>>,
    extrinsics: &[Isometry3<f64>],
) -> Vec<CameraReport> {
    rig.cameras()
        .iter()
        .zip(rms)
        .enumerate()
        .map(|(k, (camera, (rms_px, inlier_rms_px, rms_px_per_view)))| {
            let seen: Vec<usize> = views
                .iter()
                .filter_map(|v| v.corners_of(k).map(<[_]>::len))
                .collect();
            CameraReport {
                name: camera.name.clone(),
                observations: seen.iter().sum(),
                views: seen.len(),
                rms_px,
                inlier_rms_px,
                rms_px_per_view,
                extrinsics_std: extrinsics_std(globals, covariance, k, &extrinsics[k]),
                intrinsics_std: intrinsics_std(globals, covariance, k),
            }
        })
        .collect()
}

/// The report's port and extrinsic σ with every camera's lens as uncertain as `lens_std` says
/// (per camera, σ of [`INTRINSICS`]: its in-air calibration's) instead
/// of exact. The fit held the lenses fixed at their in-air values, so a lens off by δl moves the
/// fitted ports and extrinsics p by δp = −S_pp⁻¹ S_pl δl (S the information of the fitted views
/// over p and the lenses l at the result, board poses eliminated): their covariance is the
/// "consider" covariance Σ_pp = σ̂² S_pp⁻¹ + A Σ_l Aᵀ with A = S_pp⁻¹ S_pl and Σ_l = diag(σ_lens²),
/// not the posterior of a fit that re-estimates the lenses (which the underwater views would
/// pin further, and which `tests/lens_uncertainty.rs` found 20× too small in variance against a
/// Monte Carlo of the lenses). A principal point known to 0.06 px turns a camera by 0.004°, ten
/// times such a rotation's σ. Returns false, the report unchanged, where that system cannot be
/// formed (no σ̂, views that are not the report's, a singular S_pp).
pub fn add_lens_uncertainty(
    report: &mut Report,
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
    estimate: Estimate,
    huber: Option<f64>,
    lens_std: &[[f64; 9]],
) -> bool {
    let Some(sigma) = report.sigma_px.filter(|s| *s > 0.0 && s.is_finite()) else {
        return false;
    };
    if lens_std.len() != rig.cameras().len() || report.poses.len() != seen.len() {
        return false;
    }
    let estimate = Estimate {
        intrinsics: true,
        ..estimate
    };
    let bundle = Bundle::new(rig, target, seen, estimate, huber);
    let state = State::of(rig, report.poses.clone());
    let Some(normal) = bundle.normal_equations(&state) else {
        return false;
    };
    let Some(information) = normal.global_information() else {
        return false;
    };
    let globals = bundle.globals().to_vec();
    // The lenses (l) and the rest (p), with each lens parameter's prior σ.
    let mut lenses = Vec::new();
    let mut priors = Vec::new();
    let mut rest = Vec::new();
    for (i, parameter) in globals.iter().enumerate() {
        if let Parameter::Intrinsic(k, j) = *parameter {
            let prior = lens_std[k][j];
            if !(prior > 0.0 && prior.is_finite()) {
                return false;
            }
            lenses.push(i);
            priors.push(prior);
        } else {
            rest.push(i);
        }
    }
    let s_pl = information.select_rows(&rest).select_columns(&lenses);
    // The fitted views' own share with the lenses held (S_pp⁻¹ σ̂²), each σ raised where the views
    // scatter more than σ̂ says (as the fit's report did).
    let Some(data) = covariances(&normal.restricted(&rest), sigma * sigma) else {
        return false;
    };
    let inverse = &data.classical / (sigma * sigma);
    let a = &inverse * s_pl;
    let lens_covariance = DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
        priors.len(),
        priors.iter().map(|s| s * s),
    ));
    let cov_pp = data.raised + &a * &lens_covariance * a.transpose();
    let cov_pl = -(&a * &lens_covariance);
    let mut covariance = DMatrix::zeros(globals.len(), globals.len());
    for (r, &i) in rest.iter().enumerate() {
        for (c, &j) in rest.iter().enumerate() {
            covariance[(i, j)] = cov_pp[(r, c)];
        }
        for (c, &j) in lenses.iter().enumerate() {
            covariance[(i, j)] = cov_pl[(r, c)];
            covariance[(j, i)] = cov_pl[(r, c)];
        }
    }
    for (c, &j) in lenses.iter().enumerate() {
        covariance[(j, j)] = lens_covariance[(c, c)];
    }
    let ports = port_reports(rig, &state, &globals, Some(&covariance));
    for (old, new) in report.ports.iter_mut().zip(ports) {
        old.tilt.std = new.tilt.std;
        old.azimuth.std = new.azimuth.std;
        old.distance.std = new.distance.std;
        for (t, n) in old.thicknesses.iter_mut().zip(new.thicknesses) {
            t.std = n.std;
        }
    }
    for (k, camera) in report.cameras.iter_mut().enumerate() {
        if camera.extrinsics_std.is_some() {
            camera.extrinsics_std =
                extrinsics_std(&globals, Some(&covariance), k, &state.extrinsics[k]);
        }
    }
    true
}

/// σ of camera `k`'s rotation (about the master's axes) and of the translation t of its
/// cam_from_master, from the covariance of its step parameters (ω, τ): a step turns the whole
/// transform, t ← exp(ω)·t + τ, so δt = ω × t + τ = −[t]× ω + τ and Σ_t = A Σ Aᵀ with
/// A = [−[t]×  I]. (The τ block alone is not t's covariance: ω moves t as well.)
fn extrinsics_std(
    globals: &[Parameter],
    covariance: Option<&DMatrix<f64>>,
    k: usize,
    cam_from_master: &Isometry3<f64>,
) -> Option<([f64; 3], [f64; 3])> {
    let c = covariance?;
    let index: Vec<usize> = (0..3)
        .map(|a| Parameter::Rotation(k, a))
        .chain((0..3).map(|a| Parameter::Translation(k, a)))
        .map(|p| globals.iter().position(|&g| g == p))
        .collect::<Option<_>>()?;
    let block = nalgebra::Matrix6::from_fn(|i, j| c[(index[i], index[j])]);
    let mut a = nalgebra::Matrix3x6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-cam_from_master.translation.vector.cross_matrix()));
    a.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    let translation = a * block * a.transpose();
    let std = |m: f64| m.max(0.0).sqrt();
    Some((
        [std(block[(0, 0)]), std(block[(1, 1)]), std(block[(2, 2)])],
        [
            std(translation[(0, 0)]),
            std(translation[(1, 1)]),
            std(translation[(2, 2)]),
        ],
    ))
}

/// σ of camera `k`'s intrinsics ([`INTRINSICS`](super::bundle::INTRINSICS) order) from the
/// covariance, when any were estimated; `None` for a term held fixed.
fn intrinsics_std(
    globals: &[Parameter],
    covariance: Option<&DMatrix<f64>>,
    k: usize,
) -> Option<[Option<f64>; 9]> {
    covariance?;
    let std: [Option<f64>; 9] =
        std::array::from_fn(|j| std_of(globals, covariance, Parameter::Intrinsic(k, j)));
    std.iter().any(Option::is_some).then_some(std)
}

/// Each port with its name in reports: `shared`, or its camera's name.
pub fn port_names(rig: &Rig) -> Vec<(String, Interface)> {
    match rig.ports() {
        Ports::Shared(port) => vec![("shared".into(), port.clone())],
        Ports::PerCamera(ports) => rig
            .cameras()
            .iter()
            .map(|c| c.name.clone())
            .zip(ports.iter().cloned())
            .collect(),
    }
}

/// `parameter` of `rig` in words: `shared air distance`, `cam2 rotation x`, `cam0 fx`.
pub fn parameter_name(rig: &Rig, parameter: Parameter) -> String {
    let ports = port_names(rig);
    let cameras = rig.cameras();
    let axis = ["x", "y", "z"];
    match parameter {
        Parameter::Axis(p, a) => format!("{} axis (tangent {})", ports[p].0, a + 1),
        Parameter::Distance(p) => format!("{} air distance", ports[p].0),
        Parameter::Thickness(p, i) => format!("{} layer {i} thickness", ports[p].0),
        Parameter::Rotation(k, a) => format!("{} rotation {}", cameras[k].name, axis[a]),
        Parameter::Translation(k, a) => format!("{} translation {}", cameras[k].name, axis[a]),
        Parameter::Intrinsic(k, j) => format!("{} {}", cameras[k].name, INTRINSICS[j]),
    }
}

/// What step 6 of the pipeline reports on: the problem, the screening, the pairs, the estimate
/// and the stages and warnings so far.
pub(super) struct Input<'a> {
    pub rig: &'a Rig,
    pub target: &'a Target,
    pub seen: &'a [SeenView],
    pub screening: Option<&'a Screening>,
    pub pairs: &'a [StereoData],
    pub options: &'a Options,
}

/// Step 6: the report of `estimate` over every corner of `input.seen` (the screened ones
/// included), and the calibrated rig.
pub(super) fn make_report(
    input: &Input,
    estimate: Outcome,
    stages: Vec<Stage>,
    mut warnings: Vec<String>,
) -> Result<(Report, Rig), CalibError> {
    let Input {
        rig,
        target,
        seen,
        screening,
        pairs,
        options,
    } = *input;
    let Outcome {
        state,
        fit,
        strategy,
        pair,
    } = estimate;
    let calibrated = state
        .rig(rig)
        .ok_or_else(|| no_solution(options, "the result puts a camera outside the air"))?;
    // The residuals under the result over every corner (the screened ones too).
    let every = Bundle::new(rig, target, seen, Estimate::NOTHING, options.huber);
    let residuals = every
        .all_residuals(&state)
        .ok_or_else(|| no_solution(options, "a fitted corner does not project under the result"))?;
    let labelled = label_residuals(seen, &residuals);
    let outliers = find_outliers(rig, seen, &labelled, screening);
    warnings.extend(outlier_warning(&outliers, options, fit.is_some()));
    let (covariance, sigma_px, iterations, termination, globals, raised) =
        uncertainty(&state, fit.as_ref(), seen, screening, &stages);
    let sigma_from_scatter = raised.map(|(i, factor)| (parameter_name(rig, globals[i]), factor));
    let ports = port_reports(rig, &state, &globals, covariance.as_ref());
    warnings.extend(uncertainty_warnings(
        &ports,
        fit.as_ref().map(|f| &f.report),
        &covariance,
    ));
    let cameras = camera_reports(
        rig,
        seen,
        camera_rms(rig, &labelled, &outliers),
        &globals,
        covariance.as_ref(),
        &state.extrinsics,
    );
    let fits = cameras
        .iter()
        .all(|c| c.inlier_rms_px.is_nan() || c.inlier_rms_px <= options.rms_bound());
    let squares: Vec<f64> = residuals
        .iter()
        .flatten()
        .map(|r| r.norm_squared())
        .collect();
    let report = Report {
        method: options.method,
        strategy,
        estimate: options.estimate,
        ports,
        cameras,
        sigma_px,
        sigma_from_scatter,
        noise_px: screening.and_then(|s| s.noise_px),
        rms_px: (squares.iter().sum::<f64>() / squares.len().max(1) as f64).sqrt(),
        scene: scene_errors(&calibrated, target, seen, pairs, pair),
        poses: state.poses.clone(),
        board: target.board().is_some(),
        stages,
        iterations,
        termination,
        outliers,
        fits,
        diagnosis: Vec::new(),
        warnings,
        seconds: 0.0,
        backend: options.backend.describe_stages(),
        views: seen.len(),
        corners: distinct_corners(seen),
        observations: seen.iter().map(SeenView::observations).sum(),
    };
    Ok((report, calibrated))
}

/// Distinct corners of `seen` (a corner seen by several cameras in a view counts once).
fn distinct_corners(seen: &[SeenView]) -> usize {
    seen.iter()
        .map(|v| {
            let set: BTreeSet<usize> = v
                .cameras
                .iter()
                .flat_map(|(_, c)| c.iter().map(|(i, _)| *i))
                .collect();
            set.len()
        })
        .sum()
}

/// The warning for corner images far above the rest, if any.
fn outlier_warning(outliers: &[Outlier], options: &Options, fitted: bool) -> Option<String> {
    let worst = outliers.first()?;
    let corners: BTreeSet<(usize, usize)> = outliers.iter().map(|o| (o.view, o.corner)).collect();
    let huber = options.huber.is_none() && fitted && outliers.iter().any(|o| !o.screened);
    Some(format!(
        "{} corner(s) have residuals far above the rest (largest {:.2} px at view {} corner {}, {} image): check the detections{}",
        corners.len(),
        worst.residual_px,
        worst.view,
        worst.corner,
        worst.image,
        if huber { ", or use the Huber loss" } else { "" }
    ))
}

/// The covariance of the global parameters (σ̂² applied, each σ raised where the views scatter
/// more: [`widened`]), σ̂, the iterations and termination of the final stage, the global
/// parameters, and the parameter whose σ the scatter raised most with its factor, of a
/// maximum-likelihood fit; the consecutive method (no fit) has none of them and reports its
/// last refinement's iterations.
#[allow(clippy::type_complexity)]
fn uncertainty(
    state: &State,
    fit: Option<&Fit>,
    seen: &[SeenView],
    screening: Option<&Screening>,
    stages: &[Stage],
) -> (
    Option<DMatrix<f64>>,
    Option<f64>,
    usize,
    String,
    Vec<Parameter>,
    Option<(usize, f64)>,
) {
    let Some(fit) = fit else {
        let iterations = stages
            .iter()
            .rev()
            .find(|s| s.name.starts_with("refine"))
            .map_or(0, |s| s.iterations);
        return (None, None, iterations, "converged".into(), Vec::new(), None);
    };
    let dimension = fit.globals.len() + POSE_PARAMETERS * state.poses.len();
    // The fit ran on the views without the screened corner images: two residuals per image.
    let clean = screening.and_then(|s| s.without_suspects(seen));
    let views = clean.as_deref().unwrap_or(seen);
    let residuals = 2 * views.iter().map(SeenView::observations).sum::<usize>();
    let dof = residuals.saturating_sub(dimension);
    let sigma2 = if dof > 0 {
        fit.report.final_cost / dof as f64
    } else {
        f64::NAN
    };
    let (covariance, raised) = fit
        .normal
        .as_ref()
        .and_then(|normal| covariances(normal, sigma2))
        .map(|c| (c.raised, c.largest))
        .unzip();
    (
        covariance,
        Some(sigma2.sqrt()),
        fit.report.iterations,
        fit.report.termination.describe().to_string(),
        fit.globals.clone(),
        raised.flatten(),
    )
}

/// `covariance` (σ̂²·S⁻¹) with each parameter's σ raised to what `clustered` (the same
/// parameters' covariance from how the views scatter, and per parameter the number of views B_i
/// that inform it: [`clustered_covariance`](crate::calib::solvers::block::BlockNormalEquations::clustered_covariance))
/// says, where the views scatter more than chance explains: C' = D C D, D_ii = √(R_ii / C_ii)
/// where R_ii / C_ii exceeds 1 + 2√(2/(B_i − 1)) (two of the ratio's standard errors under
/// independent errors of one variance), else 1. C' keeps C's correlations and never lowers a σ.
/// Why a threshold and not max(C_ii, R_ii): R's diagonal is itself an estimate from B_i views,
/// and the larger of two estimates overstates the σ of a fit whose corners are plain noise
/// (by 10-20 % on 20-60 views: `tests/calibration_uncertainty.rs`). Also returns the largest
/// D_ii and its index (none raised: `None`).
pub fn widened(
    mut covariance: DMatrix<f64>,
    (clustered, informing): &(DMatrix<f64>, Vec<usize>),
) -> (DMatrix<f64>, Option<(usize, f64)>) {
    let n = covariance.nrows();
    let factors: Vec<f64> = (0..n)
        .map(|i| {
            let (c, r, views) = (covariance[(i, i)], clustered[(i, i)], informing[i]);
            let chance = 1.0 + 2.0 * (2.0 / (views.max(2) - 1) as f64).sqrt();
            if views >= 2 && c > 0.0 && r.is_finite() && r > chance * c {
                (r / c).sqrt()
            } else {
                1.0
            }
        })
        .collect();
    for i in 0..n {
        for j in 0..n {
            covariance[(i, j)] *= factors[i] * factors[j];
        }
    }
    let largest = factors
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, f)| *f > 1.0)
        .max_by(|a, b| a.1.total_cmp(&b.1));
    (covariance, largest)
}

/// The covariance of `normal`'s globals at residual variance `sigma2`: σ²·S⁻¹ as it stands
/// (`classical`), and with each σ raised where the views scatter more than chance explains
/// ([`widened`]; `raised`, the parameter raised most and its factor in `largest`). `None` where S
/// is singular.
pub fn covariances(normal: &BlockNormalEquations, sigma2: f64) -> Option<Covariances> {
    let classical = normal.global_covariance()? * sigma2;
    let (raised, largest) = match normal.clustered_covariance(sigma2) {
        Some(clustered) => widened(classical.clone(), &clustered),
        None => (classical.clone(), None),
    };
    Some(Covariances {
        classical,
        raised,
        largest,
    })
}

/// What [`covariances`] gives.
#[derive(Debug, Clone, PartialEq)]
pub struct Covariances {
    /// σ²·S⁻¹: every corner independent, one variance.
    pub classical: DMatrix<f64>,
    /// `classical` with each σ raised to what the views' scatter says ([`widened`]).
    pub raised: DMatrix<f64>,
    /// The parameter whose σ was raised most (index into the globals) and by how much.
    pub largest: Option<(usize, f64)>,
}

/// Warnings about what the standard deviations say: an undetermined azimuth, a singular or weak
/// fit, a fit that ran out of iterations.
fn uncertainty_warnings(
    ports: &[PortReport],
    fit: Option<&LmReport>,
    covariance: &Option<DMatrix<f64>>,
) -> Vec<String> {
    let mut warnings = Vec::new();
    let port = &ports[0];
    if let Some(tilt_std) = port.tilt.std
        && port.tilt.value < 3.0 * tilt_std
    {
        warnings.push(format!(
            "the tilt ({:.3}°) is within 3 standard deviations of zero: the azimuth is undetermined",
            port.tilt.value.to_degrees()
        ));
    }
    match (fit, covariance) {
        (Some(_), None) => warnings.push("JᵀJ is singular at the result: the views do not determine what is estimated (vary the target's angle and distance)".into()),
        (Some(_), Some(_)) => {
            let weak_tilt = port.tilt.std.is_some_and(|s| s > WEAK_TILT_STD_DEG.to_radians());
            let weak_air = port.distance.std.is_some_and(|s| s > WEAK_AIR_STD_M);
            if weak_tilt || weak_air {
                warnings.push(format!(
                    "the views hardly constrain the result (σ tilt {:.2}°, σ air layer {:.1} mm): vary the target's angle and distance between views",
                    port.tilt.std.unwrap_or(f64::NAN).to_degrees(),
                    port.distance.std.unwrap_or(f64::NAN) * 1e3
                ));
            }
        }
        _ => {}
    }
    if fit.is_some_and(|r| r.termination == Termination::MaxIterations) {
        warnings.push("raise --max-iterations".into());
    }
    warnings
}

/// The 3-D errors of the triangulated corners of one camera pair under the calibrated rig: the
/// pair the consecutive start ran on, else the first pair that saw the board in three views.
fn scene_errors(
    calibrated: &Rig,
    target: &Target,
    seen: &[SeenView],
    pairs: &[StereoData],
    pair: Option<CameraPair>,
) -> Option<SceneErrors> {
    let board = target.board()?;
    let pair = pair
        .or_else(|| pairs.first().map(|d| d.cameras))
        .or_else(|| {
            let n = calibrated.cameras().len();
            (0..n)
                .flat_map(|a| (a + 1..n).map(move |b| CameraPair::new(a, b)))
                .find(|&pair| {
                    StereoData::new(calibrated, pair, board, seen)
                        .is_ok_and(|d| d.views.len() >= MIN_VIEWS)
                })
        })?;
    let cameras = pair.map(|k| calibrated.refractive_camera(k));
    // Over every corner, else (a screened corner that does not triangulate) over the kept ones.
    let every = StereoData::new(calibrated, pair, board, seen).ok()?;
    let (data, fit) = match SceneFit::new(&every, &cameras) {
        Some(fit) => (every, fit),
        None => {
            let kept = pairs.iter().find(|d| d.cameras == pair)?.clone();
            let fit = SceneFit::new(&kept, &cameras)?;
            (kept, fit)
        }
    };
    Some(SceneErrors {
        cameras: pair.map(|k| calibrated.cameras()[k].name.clone()),
        rms_m: fit.scene_rms(),
        square_deviation_rms_m: fit.square_deviation_rms(&data),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A covariance of two correlated parameters (σ 1 and 2, correlation 0.5).
    fn covariance() -> DMatrix<f64> {
        DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 1.0, 4.0])
    }

    #[test]
    fn a_scatter_within_chance_raises_no_sigma() {
        // 31 views: chance reaches 1 + 2·√(2/30) ≈ 1.52 in variance.
        let clustered = DMatrix::from_row_slice(2, 2, &[1.5, 0.0, 0.0, 2.0]);
        let (raised, largest) = widened(covariance(), &(clustered, vec![31, 31]));
        assert_eq!(raised, covariance());
        assert_eq!(largest, None);
    }

    #[test]
    fn a_scatter_beyond_chance_raises_that_sigma_and_keeps_the_correlation() {
        let clustered = DMatrix::from_row_slice(2, 2, &[2.25, 0.0, 0.0, 4.0]);
        let (raised, largest) = widened(covariance(), &(clustered.clone(), vec![31, 31]));
        assert!(
            (raised[(0, 0)] - 2.25).abs() < 1e-12,
            "σ 1.5 as the views say"
        );
        assert_eq!(raised[(1, 1)], 4.0, "the other σ as it was");
        let correlation = raised[(0, 1)] / (raised[(0, 0)] * raised[(1, 1)]).sqrt();
        assert!((correlation - 0.5).abs() < 1e-12);
        assert_eq!(largest.map(|(i, _)| i), Some(0));
        assert!((largest.unwrap().1 - 1.5).abs() < 1e-12);
        // The same ratio from 4 views is within chance there (1 + 2·√(2/3) ≈ 2.63).
        let (few, largest) = widened(covariance(), &(clustered, vec![4, 4]));
        assert_eq!(few, covariance());
        assert_eq!(largest, None);
    }

    #[test]
    fn a_parameter_informed_by_one_view_is_left_as_it_is() {
        let clustered = DMatrix::from_row_slice(2, 2, &[100.0, 0.0, 0.0, 100.0]);
        let (raised, _) = widened(covariance(), &(clustered, vec![1, 0]));
        assert_eq!(raised, covariance());
    }
}
