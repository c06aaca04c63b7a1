//! Calibration of any rig: one camera or many, a shared port or a port per camera, a board or a
//! 3-D target. Small named stages, composed by [`calibrate_views`] (and
//! [`calibrate_rig`](super::calibrate::calibrate_rig), which adds the diagnosis of a misfit):
//!
//! 1. [`initial_poses`]: each view's target pose from the camera that saw most of it, pinhole
//!    first (a homography for a planar target, the DLT for a 3-D one), then through the start
//!    port (the pose alone by Levenberg–Marquardt).
//! 2. The start of the ports: with two or more cameras behind a shared port and a board, the
//!    thesis' consecutive method (`consecutive_start`) over every pair of cameras, the pair
//!    whose result explains the corners best winning; otherwise a global search over each port's
//!    axis ([`search_axis`]), each cell's air distance and poses fitted by a few LM steps.
//! 3. Maximum likelihood over everything estimated and every pose ([`RigBundle`]), with a
//!    standard deviation for every estimated quantity from the covariance.

use std::time::Instant;

use nalgebra::{
    DMatrix, Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3,
};

use super::bundle::BlockNormalEquations;
use super::rig_bundle::{Estimate, Parameter, RigBundle, RigState, distance_unobservable};
use super::thesis;
use super::thesis::{CalibrationOptions, DEFAULT_MAX_RMS_PX, Method};
use crate::calib::backends::CpuBackend;
use crate::calib::costs::invariants::plane_basis;
use crate::calib::error::CalibError;
use crate::calib::problem::data::StereoData;
use crate::calib::problem::observations::Observations;
use crate::calib::problem::rig_observations::{RigObservations, SeenView, stereo_pair};
use crate::calib::problem::screen::board_noise_px;
use crate::calib::problem::target::Target;
use crate::calib::solvers::lm::{LeastSquares, LmOptions, levenberg_marquardt};
use crate::calib::solvers::search::cap_grid;
use crate::model::{Interface, Ports, Rig};

/// How to calibrate a rig.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigCalibrationOptions {
    /// What is estimated.
    pub estimate: Estimate,
    /// The method: `Consecutive` needs two cameras behind a shared port and a board;
    /// `Simultaneous` and `Auto` work on every rig (`Auto` says what it chose).
    pub method: Method,
    /// Largest axis tilt (from the port's camera's z axis) the global search covers, radians.
    pub max_tilt: f64,
    /// Huber threshold on each corner's residual, pixels.
    pub huber: Option<f64>,
    /// Iteration bound of the maximum-likelihood refinement.
    pub max_iterations: usize,
    /// Largest RMS reprojection error (any camera), pixels, accepted as a fit.
    pub max_rms_px: f64,
}

impl Default for RigCalibrationOptions {
    fn default() -> Self {
        Self {
            estimate: Estimate::default(),
            method: Method::Auto,
            max_tilt: 30f64.to_radians(),
            huber: None,
            max_iterations: 200,
            max_rms_px: DEFAULT_MAX_RMS_PX,
        }
    }
}

/// A calibrated quantity with its standard deviation (`None` when known, not estimated, or when
/// the covariance is singular).
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
    /// RMS reprojection error, pixels.
    pub rms_px: f64,
    /// Standard deviations of its rotation (about the x, y, z axes, radians) and translation (m),
    /// when its extrinsics were estimated.
    pub extrinsics_std: Option<([f64; 3], [f64; 3])>,
}

/// What a rig calibration found and how well the data fit it.
#[derive(Debug, Clone, PartialEq)]
pub struct RigReport {
    /// What ran, in words (`auto: one camera — pose per view, axis search, maximum likelihood`).
    pub method: String,
    /// What was estimated.
    pub estimate: Estimate,
    /// The ports, in rig order (one when shared).
    pub ports: Vec<PortReport>,
    /// The cameras, in rig order.
    pub cameras: Vec<CameraReport>,
    /// Estimated pixel noise σ̂ from the residuals.
    pub sigma_px: f64,
    /// The corner noise σ per coordinate seen in the images themselves (the scatter of each
    /// board corner about the board's smooth shape), pixels; `None` for a 3-D target or a board
    /// under 3 × 3. A fit that the model explains comes down to it.
    pub corner_noise_px: Option<f64>,
    /// RMS reprojection error over every corner and camera, pixels.
    pub rms_px: f64,
    /// Target poses X_master = R·X_target + t per view.
    pub poses: Vec<Isometry3<f64>>,
    /// The stages that ran: (name, cost or RMS reached, seconds).
    pub stages: Vec<(String, f64, f64)>,
    /// Iterations of the final refinement.
    pub iterations: usize,
    /// Why it stopped.
    pub termination: String,
    /// Whether every camera's RMS is at most the accepted bound.
    pub fits: bool,
    /// What the data look like when it does not fit.
    pub diagnosis: Vec<String>,
    /// Everything worth a second look.
    pub warnings: Vec<String>,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Views and corner observations used.
    pub views: usize,
    /// Corner observations (one per corner per camera).
    pub observations: usize,
}

impl RigReport {
    /// The RMS reprojection error of the worst camera (that saw anything), pixels.
    pub fn worst_rms_px(&self) -> f64 {
        self.cameras
            .iter()
            .map(|c| c.rms_px)
            .filter(|r| !r.is_nan())
            .fold(0.0, f64::max)
    }
}

/// A calibrated rig and its report.
#[derive(Debug, Clone, PartialEq)]
pub struct RigCalibration {
    /// The input rig with everything estimated replaced by its estimate.
    pub rig: Rig,
    /// How it was found and how well it fits.
    pub report: RigReport,
}

/// Pose-only refinement steps for one view, and the short refinements of a search cell.
const POSE_ITERATIONS: usize = 30;
const CELL_ITERATIONS: usize = 30;
/// Spacing of the global axis search, radians.
const SEARCH_SPACING_DEG: f64 = 4.0;

/// Whether the thesis' stereo pipeline ([`calibrate`](super::calibrate::calibrate)) serves: two cameras behind one shared
/// port, a board, the axis and the air distance estimated, every view seen by both cameras.
/// `flatport calibrate` and the Python package run it then, exactly as before the general
/// calibration existed; every other problem goes to
/// [`calibrate_rig`](super::calibrate::calibrate_rig).
pub fn is_thesis_stereo_case(
    rig: &Rig,
    observations: &RigObservations,
    estimate: &Estimate,
) -> bool {
    rig.shared_interface().is_some()
        && rig.cameras().len() == 2
        && observations.target.board().is_some()
        && *estimate == Estimate::default()
        && observations.views.iter().all(|v| v.images.len() == 2)
}

/// The calibration of views already resolved against `rig`, without the diagnosis of a misfit
/// ([`calibrate_rig`](super::calibrate::calibrate_rig) adds it).
pub fn calibrate_views(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    options: &RigCalibrationOptions,
) -> Result<RigCalibration, CalibError> {
    let started = Instant::now();
    check_method(rig, target, options)?;
    let mut stages = Vec::new();
    let mut warnings = Vec::new();
    let planar = target.is_planar();
    if options.estimate.distance {
        for (name, port) in port_names(rig) {
            if distance_unobservable(&port) {
                warnings.push(format!(
                    "port {name}: the same medium (index {}) on both sides of the port, so where it sits changes no ray: its air distance is not observable and stays at its start ({:.1} mm)",
                    port.index_air(),
                    port.air_distance() * 1e3
                ));
            }
        }
    }
    if planar && views.len() < 3 {
        warnings.push(format!("{} view(s) of a planar target: the port is weakly determined below 3 (a 3-D target fixes it from one)", views.len()));
    }
    // 1. Poses.
    let clock = Instant::now();
    let poses = initial_poses(rig, target, &views)?;
    let mut state = RigState::of(rig, poses);
    let pose_only = Estimate::NOTHING;
    let bundle = RigBundle::new(rig, target, &views, pose_only, options.huber);
    state = short_fit(&bundle, state, POSE_ITERATIONS);
    stages.push((
        "target poses (pinhole, then through the start port)".into(),
        rms(&bundle, &state),
        clock.elapsed().as_secs_f64(),
    ));
    // 2. The ports' start.
    let shared_pairs = shared_board_pairs(rig, target, &views);
    let consecutive = match options.method {
        Method::Consecutive => true,
        Method::Simultaneous => false,
        Method::Auto => !shared_pairs.is_empty(),
    };
    let mut method = format!("{}: ", options.method.name());
    if options.estimate.axis || options.estimate.distance {
        let clock = Instant::now();
        // `auto` falls back to the axis search when the consecutive start fails (in-air
        // extrinsics a few mm off can leave its linear air layer without a solution).
        let start = match consecutive
            .then(|| consecutive_start(rig, target, &views, &state, &shared_pairs, options))
        {
            Some(Err(e)) if options.method == Method::Auto && options.estimate.axis => {
                warnings.push(format!(
                    "the consecutive start failed ({e}); the global axis search replaced it"
                ));
                None
            }
            other => other.transpose()?,
        };
        if let Some((candidate_state, pair)) = start {
            state = candidate_state;
            method += &format!(
                "consecutive (thesis) over {} camera pair(s), best pair {}",
                shared_pairs.len(),
                pair
            );
            stages.push((
                format!("consecutive start (pair {pair})"),
                rms(&bundle, &state),
                clock.elapsed().as_secs_f64(),
            ));
        } else if options.estimate.axis {
            for p in 0..state.ports.len() {
                state = search_axis(rig, target, &views, state, p, options)?;
            }
            state = short_fit(&bundle, state, POSE_ITERATIONS);
            method += "pose per view, global search over each port's axis";
            stages.push((
                "global axis search".into(),
                rms(&bundle, &state),
                clock.elapsed().as_secs_f64(),
            ));
        } else {
            method += "pose per view";
        }
    } else {
        method += "pose per view";
    }
    // 3. Maximum likelihood.
    let clock = Instant::now();
    let full = RigBundle::new(rig, target, &views, options.estimate, options.huber);
    let lm = LmOptions {
        max_iterations: options.max_iterations,
        ..LmOptions::default()
    };
    let (state, lm_report, normal) = levenberg_marquardt(&full, state, &lm);
    method += ", maximum likelihood";
    let residual_count = full.residuals();
    let cost = full.cost(&state).unwrap_or(f64::INFINITY);
    let total_rms = (cost / residual_count as f64).sqrt();
    stages.push((
        "maximum likelihood".into(),
        total_rms,
        clock.elapsed().as_secs_f64(),
    ));
    let calibrated = state.rig(rig).ok_or_else(|| {
        CalibError::Options("the refinement left the rig invalid (a camera outside the air)".into())
    })?;
    let dof = residual_count.saturating_sub(full.dimension(&state));
    let sigma2 = if dof > 0 { cost / dof as f64 } else { f64::NAN };
    let covariance = normal
        .as_ref()
        .and_then(BlockNormalEquations::global_covariance)
        .map(|c| c * sigma2);
    let rms_per_camera = full.rms_per_camera(&state).unwrap_or_default();
    let fits = rms_per_camera
        .iter()
        .all(|r| r.is_nan() || *r <= options.max_rms_px);
    let mut report = RigReport {
        method,
        estimate: options.estimate,
        ports: port_reports(rig, &state, full.globals(), covariance.as_ref()),
        cameras: camera_reports(
            rig,
            &views,
            &rms_per_camera,
            full.globals(),
            covariance.as_ref(),
            &state.extrinsics,
        ),
        sigma_px: sigma2.sqrt(),
        corner_noise_px: corner_noise_px(rig, target, views),
        rms_px: total_rms,
        poses: state.poses.clone(),
        stages,
        iterations: lm_report.iterations,
        termination: format!("{:?}", lm_report.termination),
        fits,
        diagnosis: Vec::new(),
        warnings,
        seconds: 0.0,
        views: views.len(),
        observations: residual_count / 2,
    };
    report.seconds = started.elapsed().as_secs_f64();
    Ok(RigCalibration {
        rig: calibrated,
        report,
    })
}

/// A method that does not apply to the rig is an error that says why.
fn check_method(
    rig: &Rig,
    target: &Target,
    options: &RigCalibrationOptions,
) -> Result<(), CalibError> {
    if options.method == Method::Consecutive {
        let shared = matches!(rig.ports(), Ports::Shared(_)) && rig.cameras().len() >= 2;
        if !shared || target.board().is_none() {
            return Err(CalibError::Options(
                "the consecutive method (the thesis' invariants) needs two or more cameras behind one shared port and a board; use --method simultaneous or auto".into(),
            ));
        }
        if options.estimate.layers != 0 || options.estimate.extrinsics {
            return Err(CalibError::Options(
                "the consecutive method estimates the axis and the air distance only; --estimate layers or extrinsics needs --method simultaneous or auto".into(),
            ));
        }
    }
    if !(options.estimate.axis
        || options.estimate.distance
        || options.estimate.layers != 0
        || options.estimate.extrinsics)
    {
        return Err(CalibError::Options(
            "--estimate names nothing to estimate".into(),
        ));
    }
    let layers = match rig.ports() {
        Ports::Shared(port) => port.layers().len(),
        Ports::PerCamera(ports) => ports.iter().map(|p| p.layers().len()).min().unwrap_or(0),
    };
    if options.estimate.layers != Estimate::ALL_LAYERS
        && let Some(k) = (layers..32).find(|&k| options.estimate.layer(k))
    {
        return Err(CalibError::Options(format!(
            "--estimate layer:{k}: the rig's port(s) have {layers} layer(s), layer:0 to layer:{}",
            layers.saturating_sub(1)
        )));
    }
    if options.estimate.extrinsics && rig.cameras().len() < 2 {
        return Err(CalibError::Options("--estimate extrinsics needs two or more cameras (the master's extrinsics define the frame)".into()));
    }
    Ok(())
}

fn short_fit(bundle: &RigBundle, state: RigState, iterations: usize) -> RigState {
    let options = LmOptions {
        max_iterations: iterations,
        ..LmOptions::default()
    };
    levenberg_marquardt(bundle, state, &options).0
}

/// RMS reprojection error of `state` under `bundle`, pixels (+∞ when it has none).
fn rms(bundle: &RigBundle, state: &RigState) -> f64 {
    bundle
        .cost(state)
        .map_or(f64::INFINITY, |c| (c / bundle.residuals() as f64).sqrt())
}

/// Each view's target pose (master frame) from the camera that saw most of it: the pinhole pose of
/// its undistorted corners (homography for a planar target, DLT for a 3-D one).
pub fn initial_poses(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
) -> Result<Vec<Isometry3<f64>>, CalibError> {
    views
        .iter()
        .enumerate()
        .map(|(v, view)| {
            let (k, corners) = view.cameras.iter().max_by_key(|(_, c)| c.len()).expect("a resolved view has a camera");
            let camera = &rig.cameras()[*k];
            let mut object = Vec::with_capacity(corners.len());
            let mut image = Vec::with_capacity(corners.len());
            for (i, pixel) in corners {
                let Some(x) = camera.intrinsics.normalized_from_img(pixel) else { continue };
                object.push(target.point(*i));
                image.push(x);
            }
            let cam_from_target = pinhole_pose(&object, &image).ok_or_else(|| CalibError::UnusableView {
                view: v,
                reason: format!("no pose of the target fits camera '{}''s corners (are they in target order?)", camera.name),
            })?;
            Ok(camera.cam_from_master.inverse() * cam_from_target)
        })
        .collect()
}

/// The pinhole pose cam_from_target of `object` points seen at undistorted normalised `image`
/// coordinates: a homography when the points are coplanar, the DLT otherwise. `None` when
/// degenerate.
pub fn pinhole_pose(object: &[Point3<f64>], image: &[Vector2<f64>]) -> Option<Isometry3<f64>> {
    if object.len() < 4 {
        return None;
    }
    // The points' own frame: centroid and principal axes; a plane has a vanishing third axis.
    let n = object.len() as f64;
    let centre = object.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let scatter = object.iter().fold(Matrix3::zeros(), |a, p| {
        let d = p.coords - centre;
        a + d * d.transpose()
    });
    let eigen = scatter.symmetric_eigen();
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let mut axes = Matrix3::from_columns(&order.map(|i| eigen.eigenvectors.column(i).into_owned()));
    if axes.determinant() < 0.0 {
        axes.column_mut(2).neg_mut();
    }
    let scale = (eigen.eigenvalues[order[0]] / n).sqrt().max(1e-12);
    // local = axesᵀ (X − c) / scale; X = c + scale · axes · local.
    let local: Vec<Vector3<f64>> = object
        .iter()
        .map(|p| axes.transpose() * (p.coords - centre) / scale)
        .collect();
    let planar = eigen.eigenvalues[order[2]] <= 1e-12 * eigen.eigenvalues[order[0]];
    let (rotation, translation) = if planar {
        homography_pose(&local, image)?
    } else {
        dlt_pose(&local, image)?
    };
    // x ~ R_l·local + t_l, and scaling the right side by `scale` changes no image point:
    // X_cam = R_l·axesᵀ·(X − c) + scale·t_l, a rigid pose.
    let r = rotation * axes.transpose();
    let t = translation * scale - r * centre;
    Some(Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    ))
}

/// Pose (R, t) of points on z = 0 of their (scaled) local frame from a homography.
fn homography_pose(
    local: &[Vector3<f64>],
    image: &[Vector2<f64>],
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let mut a = DMatrix::zeros(2 * local.len(), 9);
    for (i, (p, x)) in local.iter().zip(image).enumerate() {
        let (u, v) = (x.x, x.y);
        let row = [p.x, p.y, 1.0];
        for j in 0..3 {
            a[(2 * i, j)] = row[j];
            a[(2 * i, 6 + j)] = -u * row[j];
            a[(2 * i + 1, 3 + j)] = row[j];
            a[(2 * i + 1, 6 + j)] = -v * row[j];
        }
    }
    let h = smallest_right_singular_vector(&a)?;
    let mut hm = Matrix3::from_row_slice(h.as_slice());
    let (h1, h2) = (hm.column(0).norm(), hm.column(1).norm());
    let lambda = 2.0 / (h1 + h2);
    hm *= lambda;
    if hm[(2, 2)] < 0.0 {
        hm = -hm;
    }
    let r1 = hm.column(0).into_owned();
    let r2 = hm.column(1).into_owned();
    let r = orthonormal(&Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]))?;
    Some((r, hm.column(2).into_owned()))
}

/// Pose (R, t) of non-coplanar points (local frame) by the direct linear transform.
fn dlt_pose(
    local: &[Vector3<f64>],
    image: &[Vector2<f64>],
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    if local.len() < 6 {
        return None;
    }
    let mut a = DMatrix::zeros(2 * local.len(), 12);
    for (i, (p, x)) in local.iter().zip(image).enumerate() {
        let row = [p.x, p.y, p.z, 1.0];
        for j in 0..4 {
            a[(2 * i, j)] = row[j];
            a[(2 * i, 8 + j)] = -x.x * row[j];
            a[(2 * i + 1, 4 + j)] = row[j];
            a[(2 * i + 1, 8 + j)] = -x.y * row[j];
        }
    }
    let p = smallest_right_singular_vector(&a)?;
    let mut m = Matrix3::new(p[0], p[1], p[2], p[4], p[5], p[6], p[8], p[9], p[10]);
    let mut t = Vector3::new(p[3], p[7], p[11]);
    if m.determinant() < 0.0 {
        m = -m;
        t = -t;
    }
    let scale = m.singular_values().mean();
    Some((orthonormal(&m)?, t / scale))
}

fn smallest_right_singular_vector(a: &DMatrix<f64>) -> Option<nalgebra::DVector<f64>> {
    // Of AᵀA: its eigenvector of the smallest eigenvalue (A has ≥ 8 rows and 9 or 12 columns).
    let ata = a.transpose() * a;
    let eigen = ata.symmetric_eigen();
    let i = eigen.eigenvalues.imin();
    let v = eigen.eigenvectors.column(i).into_owned();
    v.iter().all(|x| x.is_finite()).then_some(v)
}

/// The rotation nearest `m` (polar decomposition); `None` when `m` is degenerate.
fn orthonormal(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut r = u * v_t;
    if r.determinant() < 0.0 {
        let mut u = u;
        u.column_mut(2).neg_mut();
        r = u * v_t;
    }
    r.iter().all(|x| x.is_finite()).then_some(r)
}

/// Pairs of cameras behind the shared port that both saw the board in three or more views, with
/// their stereo observations (for the consecutive method): none for a 3-D target or per-camera
/// ports.
fn shared_board_pairs(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
) -> Vec<((usize, usize), Observations)> {
    if !matches!(rig.ports(), Ports::Shared(_)) {
        return Vec::new();
    }
    let n = rig.cameras().len();
    let mut pairs = Vec::new();
    for a in 0..n {
        for b in a + 1..n {
            if let Some(pair) = stereo_pair(target, views, rig, a, b)
                && pair.views.len() >= 3
            {
                pairs.push(((a, b), pair));
            }
        }
    }
    pairs
}

/// The thesis' consecutive method on every pair of cameras that share the port; each pair's axis
/// and air distance is tried as the start of the whole rig (poses refitted) and the one that
/// explains every corner best wins. Returns the state and the pair, named.
fn consecutive_start(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    state: &RigState,
    pairs: &[((usize, usize), Observations)],
    options: &RigCalibrationOptions,
) -> Result<(RigState, String), CalibError> {
    let pose_only = Estimate::NOTHING;
    let mut best: Option<(f64, RigState, String)> = None;
    let mut last_error = None;
    for ((a, b), pair) in pairs {
        let (a, b) = (*a, *b);
        let stereo = match StereoData::new(rig, [a, b], pair) {
            Ok(data) => data,
            Err(e) => {
                last_error = Some(e);
                continue;
            }
        };
        let backend = CpuBackend::new(&stereo);
        // No bound on the RMS: the consecutive result is a start, not a fit of the images, and a
        // misfit here must not diagnose (the diagnosis refits through this very function).
        let stereo_options = CalibrationOptions {
            method: Method::Consecutive,
            max_tilt: options.max_tilt,
            max_rms_px: f64::INFINITY,
            ..CalibrationOptions::default()
        };
        let calibration = match thesis::run(
            &backend,
            &stereo_options,
            Vec::new(),
            &mut |_| {},
            &|_, _| Vec::new(),
        ) {
            Ok(c) => c,
            Err(e) => {
                last_error = Some(e);
                continue;
            }
        };
        let mut start = state.clone();
        start.ports[0].normal = *calibration.interface.normal();
        start.ports[0].distance = calibration.interface.air_distance();
        let bundle = RigBundle::new(rig, target, views, pose_only, options.huber);
        let start = short_fit(&bundle, start, POSE_ITERATIONS);
        let cost = rms(&bundle, &start);
        let name = format!("{}–{}", rig.cameras()[a].name, rig.cameras()[b].name);
        if best.as_ref().is_none_or(|(c, _, _)| cost < *c) {
            best = Some((cost, start, name));
        }
    }
    match best {
        Some((_, state, name)) => Ok((state, name)),
        None => Err(last_error.unwrap_or_else(|| {
            CalibError::Options(
                "no pair of cameras shares enough views of the board for the consecutive method"
                    .into(),
            )
        })),
    }
}

/// A global search over port `p`'s axis (within the tilt cap about its frame's z axis): each cell
/// fits the air distance and the poses by a few LM steps; the best cell (and the start, if
/// better) is kept.
/// With a port per camera only that camera's images take part (the other ports are still at
/// their start and would pull the search their way).
pub fn search_axis(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    state: RigState,
    p: usize,
    options: &RigCalibrationOptions,
) -> Result<RigState, CalibError> {
    let distance_only = Estimate {
        distance: options.estimate.distance,
        ..Estimate::NOTHING
    };
    let (own_views, own_poses): (Vec<SeenView>, Vec<Isometry3<f64>>) = match rig.ports() {
        Ports::Shared(_) => (views.to_vec(), state.poses.clone()),
        Ports::PerCamera(_) => views
            .iter()
            .zip(&state.poses)
            .filter_map(|(view, pose)| {
                let own: Vec<_> = view
                    .cameras
                    .iter()
                    .filter(|(k, _)| *k == p)
                    .cloned()
                    .collect();
                (!own.is_empty()).then(|| (SeenView { cameras: own }, *pose))
            })
            .unzip(),
    };
    if own_views.is_empty() {
        return Ok(state);
    }
    let whole = state;
    let views = &own_views[..];
    // The poses refitted to these images alone under the start port, for every cell to start from.
    let pose_only = Estimate::NOTHING;
    let state = short_fit(
        &RigBundle::new(rig, target, views, pose_only, options.huber),
        RigState {
            poses: own_poses,
            ..whole.clone()
        },
        POSE_ITERATIONS,
    );
    let bundle = RigBundle::new(rig, target, views, distance_only, options.huber)
        .keeping(|g| g == Parameter::Distance(p));
    let axes = cap_grid(options.max_tilt, SEARCH_SPACING_DEG.to_radians());
    let start_cost = rms(&bundle, &short_fit(&bundle, state.clone(), CELL_ITERATIONS));
    let cells: Vec<(f64, RigState)> = axes
        .iter()
        .map(|axis| {
            let mut cell = state.clone();
            cell.ports[p].normal = *axis;
            let cell = short_fit(&bundle, cell, CELL_ITERATIONS);
            (rms(&bundle, &cell), cell)
        })
        .collect();
    let (cost, best) = cells
        .into_iter()
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .expect("the cap grid holds the z axis");
    if cost.is_finite() || start_cost.is_finite() {
        // The port found; the poses are refitted over every camera afterwards.
        let mut result = whole;
        if cost <= start_cost {
            result.ports[p] = best.ports[p].clone();
        }
        Ok(result)
    } else {
        Err(CalibError::Options(format!(
            "no axis within a tilt of {:.1}° explains the corners of port {p}",
            options.max_tilt.to_degrees()
        )))
    }
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

fn port_reports(
    rig: &Rig,
    state: &RigState,
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

fn camera_reports(
    rig: &Rig,
    views: &[SeenView],
    rms_px: &[f64],
    globals: &[Parameter],
    covariance: Option<&DMatrix<f64>>,
    extrinsics: &[Isometry3<f64>],
) -> Vec<CameraReport> {
    rig.cameras()
        .iter()
        .enumerate()
        .map(|(k, camera)| {
            let seen: Vec<usize> = views
                .iter()
                .filter_map(|v| {
                    v.cameras
                        .iter()
                        .find(|(c, _)| *c == k)
                        .map(|(_, c)| c.len())
                })
                .collect();
            CameraReport {
                name: camera.name.clone(),
                observations: seen.iter().sum(),
                views: seen.len(),
                rms_px: rms_px.get(k).copied().unwrap_or(f64::NAN),
                extrinsics_std: extrinsics_std(globals, covariance, k, &extrinsics[k]),
            }
        })
        .collect()
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

/// The corner noise seen in the images of a board ([`board_noise_px`]): each camera's corners of
/// each view, undistorted, as offsets from the principal point in pixels.
fn corner_noise_px(rig: &Rig, target: &Target, views: &[SeenView]) -> Option<f64> {
    let board = target.board()?;
    let images: Vec<Vec<(usize, Vector2<f64>)>> = views
        .iter()
        .flat_map(|view| &view.cameras)
        .map(|(k, corners)| {
            let intrinsics = &rig.cameras()[*k].intrinsics;
            corners
                .iter()
                .filter_map(|(i, p)| {
                    let x = intrinsics.normalized_from_img(p)?;
                    Some((*i, Vector2::new(intrinsics.fx * x.x, intrinsics.fy * x.y)))
                })
                .collect()
        })
        .collect();
    board_noise_px(board, &images)
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
