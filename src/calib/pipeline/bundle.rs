//! The maximum-likelihood bundle of every rig: Levenberg–Marquardt over what is estimated (each
//! port's axis, air distance and layer thicknesses; the extrinsics of every camera but the
//! master; where asked, every camera's intrinsics) and every target pose, minimising the
//! reprojection error of every corner in every camera that saw it (optionally under a Huber
//! loss). One camera, two or N, a shared port or a port per camera, a board or a 3-D target are
//! the same problem.
//!
//! The normal equations are the block form of [`block`](crate::calib::solvers::block) (Schur
//! complement on the poses), with as many global parameters as are estimated. Derivatives are
//! central differences; a global parameter only moves the residuals of the cameras it belongs to.
//! The corners of a view are projected together, in the lanes of the CPU engine's vector path.
//!
//! On a [`ResidualBackend`] ([`Bundle::on`]) the bundle instead hands each whole stencil (the
//! state and its ± steps along every parameter) to the backend in one call
//! ([`Bundle::stencil`]) and assembles the same normal equations from the residuals it returns.

use nalgebra::{DMatrix, DVector, Isometry3, Translation3, Unit, UnitQuaternion, Vector2, Vector3};
use rayon::prelude::*;

use crate::calib::backends::residuals::{
    Evaluation, ObservedCorner, ResidualBackend, StencilBatch,
};
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::target::Target;
use crate::calib::solvers::block::{
    BlockNormalEquations, POSE_PARAMETERS, move_pose, robust, view_share,
};
use crate::calib::solvers::lm::{LeastSquares, LmOptions, levenberg_marquardt};
use crate::calib::solvers::search::tangent_step;
use crate::engine::cpu::lanes;
use crate::model::{Interface, PinholeCamera, Ports, RefractiveCamera, Rig};

/// What a calibration estimates (`--estimate`); the rest is known.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Estimate {
    /// The axis of every port (2 degrees of freedom each).
    pub axis: bool,
    /// The air distance of every port.
    pub distance: bool,
    /// The layer thicknesses estimated in every port, as a set of layer indices (bit i: layer i,
    /// as in the rig file's `layers[i]`); [`Estimate::ALL_LAYERS`] for every layer, 0 for none.
    /// Indices stay known.
    pub layers: u32,
    /// R, t of every camera but the master.
    pub extrinsics: bool,
    /// Every camera's intrinsics ([`INTRINSICS`]: fx, fy, cx, cy and the lens terms that are
    /// not exactly 0 in the start camera; a term the in-air fit left out stays out).
    pub intrinsics: bool,
}

impl Default for Estimate {
    fn default() -> Self {
        Self {
            axis: true,
            distance: true,
            layers: 0,
            extrinsics: false,
            intrinsics: false,
        }
    }
}

impl Estimate {
    /// Nothing but the target poses (the fits of the initialisation).
    pub const NOTHING: Self = Self {
        axis: false,
        distance: false,
        layers: 0,
        extrinsics: false,
        intrinsics: false,
    };
    /// Every layer thickness ([`Estimate::layers`]).
    pub const ALL_LAYERS: u32 = u32::MAX;
    /// Layers `layer:K` can name (0-based).
    const MAX_LAYER: usize = 31;

    /// Whether layer `i`'s thickness is estimated.
    pub fn layer(&self, i: usize) -> bool {
        i <= Self::MAX_LAYER && self.layers & (1 << i) != 0
    }

    /// Parses a comma-separated list of `axis`, `distance`, `layers` (every layer's thickness),
    /// `layer:K` (layer K's thickness only, 0-based as in the rig file; repeatable),
    /// `extrinsics` and `intrinsics`.
    pub fn parse(list: &str) -> Result<Self, String> {
        let mut estimate = Self::NOTHING;
        for word in list.split(',').map(str::trim) {
            match word {
                "axis" => estimate.axis = true,
                "distance" => estimate.distance = true,
                "layers" => estimate.layers = Self::ALL_LAYERS,
                "extrinsics" => estimate.extrinsics = true,
                "intrinsics" => estimate.intrinsics = true,
                other => match other.strip_prefix("layer:").map(str::parse::<usize>) {
                    Some(Ok(k)) if k <= Self::MAX_LAYER => estimate.layers |= 1 << k,
                    Some(_) => {
                        return Err(format!(
                            "'{other}': layer:K takes a layer index from 0 to {} (as in the rig file's layers[K])",
                            Self::MAX_LAYER
                        ));
                    }
                    None => {
                        return Err(format!(
                            "'{other}' is not something to estimate: choose from axis, distance, layers, layer:K, extrinsics, intrinsics (comma-separated)"
                        ));
                    }
                },
            }
        }
        Ok(estimate)
    }

    /// The list as `--estimate` takes it.
    pub fn name(&self) -> String {
        let mut words = Vec::new();
        if self.axis {
            words.push("axis".to_string());
        }
        if self.distance {
            words.push("distance".into());
        }
        if self.layers == Self::ALL_LAYERS {
            words.push("layers".into());
        } else {
            words.extend(
                (0..=Self::MAX_LAYER)
                    .filter(|&i| self.layer(i))
                    .map(|i| format!("layer:{i}")),
            );
        }
        if self.extrinsics {
            words.push("extrinsics".into());
        }
        if self.intrinsics {
            words.push("intrinsics".into());
        }
        words.join(",")
    }
}

/// One port's pose: its axis and air distance in the frame it is given in (the master's for a
/// shared port, its camera's own otherwise) and its layer thicknesses.
#[derive(Debug, Clone, PartialEq)]
pub struct PortPose {
    /// Unit axis, into the water.
    pub normal: Unit<Vector3<f64>>,
    /// Air distance, metres.
    pub distance: f64,
    /// Layer thicknesses, metres.
    pub thicknesses: Vec<f64>,
}

impl PortPose {
    fn of(interface: &Interface) -> Self {
        Self {
            normal: *interface.normal(),
            distance: interface.air_distance(),
            thicknesses: interface.layers().iter().map(|l| l.thickness).collect(),
        }
    }
}

/// The rig and target poses being refined.
#[derive(Debug, Clone, PartialEq)]
pub struct State {
    /// The ports (one when shared), in rig camera order.
    pub ports: Vec<PortPose>,
    /// cam_from_master of every camera (the master's is the identity).
    pub extrinsics: Vec<Isometry3<f64>>,
    /// X_master = R·X_target + t per view.
    pub poses: Vec<Isometry3<f64>>,
    /// The intrinsics of every camera, in rig camera order.
    pub intrinsics: Vec<PinholeCamera>,
}

impl State {
    /// The state of `rig` with target poses `poses`.
    pub fn of(rig: &Rig, poses: Vec<Isometry3<f64>>) -> Self {
        let ports = match rig.ports() {
            Ports::Shared(interface) => vec![PortPose::of(interface)],
            Ports::PerCamera(ports) => ports.iter().map(PortPose::of).collect(),
        };
        Self {
            ports,
            extrinsics: rig.cameras().iter().map(|c| c.cam_from_master).collect(),
            poses,
            intrinsics: rig.cameras().iter().map(|c| c.intrinsics).collect(),
        }
    }

    /// The rig this state describes (`base` gives names, indices, media); `None` when it is
    /// not a valid rig (a camera outside the air, a thickness ≤ 0, an axis away from the water,
    /// a focal length ≤ 0 or a value that is not finite).
    pub fn rig(&self, base: &Rig) -> Option<Rig> {
        let port = |template: &Interface, pose: &PortPose| {
            template
                .with_thicknesses(&pose.thicknesses)
                .ok()?
                .with_pose(pose.normal.into_inner(), pose.distance)
                .ok()
        };
        let ports = match base.ports() {
            Ports::Shared(interface) => Ports::Shared(port(interface, &self.ports[0])?),
            Ports::PerCamera(ports) => Ports::PerCamera(
                ports
                    .iter()
                    .zip(&self.ports)
                    .map(|(t, p)| port(t, p))
                    .collect::<Option<_>>()?,
            ),
        };
        let mut cameras = base.cameras().to_vec();
        for (camera, extrinsics) in cameras.iter_mut().zip(&self.extrinsics) {
            camera.cam_from_master = *extrinsics;
        }
        for (camera, intrinsics) in cameras.iter_mut().zip(&self.intrinsics) {
            let values = intrinsic_values(intrinsics);
            if !(intrinsics.fx > 0.0 && intrinsics.fy > 0.0 && values.iter().all(|v| v.is_finite()))
            {
                return None;
            }
            camera.intrinsics = *intrinsics;
        }
        Rig::with_ports(cameras, ports).ok()
    }

    /// This state with every port's air distance raised where a camera has less than
    /// [`MIN_START_AIR_M`] of air in front of it (a shared port: to [`MIN_START_AIR_M`] past the
    /// camera farthest along its axis; a port per camera: to [`MIN_START_AIR_M`]), and whether
    /// anything moved. A start made of guesses (naive ports, pose-graph extrinsics, an axis
    /// search cell, a consecutive pair's air layer) may place a camera under the water; the
    /// maximum-likelihood fit must begin where its cost and its central differences are defined.
    pub fn feasible(mut self) -> (Self, bool) {
        let mut moved = false;
        // One port for every camera (with one camera, the two rules agree).
        if self.ports.len() == 1 {
            let floor = shared_distance_floor(&self.ports[0].normal, &self.extrinsics);
            if !(self.ports[0].distance >= floor) {
                self.ports[0].distance = floor;
                moved = true;
            }
        } else {
            for port in &mut self.ports {
                if !(port.distance >= MIN_START_AIR_M) {
                    port.distance = MIN_START_AIR_M;
                    moved = true;
                }
            }
        }
        (self, moved)
    }

    /// The refractive cameras of the rig this state describes ([`State::rig`]), `None` when it
    /// is not a valid rig.
    pub fn cameras(&self, base: &Rig) -> Option<Vec<RefractiveCamera>> {
        let rig = self.rig(base)?;
        Some(
            (0..rig.cameras().len())
                .map(|k| rig.refractive_camera(k))
                .collect(),
        )
    }
}

/// Levenberg–Marquardt for at most `iterations` steps: the short fits of the poses and the search.
pub fn fit_briefly(bundle: &Bundle, state: State, iterations: usize) -> State {
    let options = LmOptions {
        max_iterations: iterations,
        ..LmOptions::default()
    };
    levenberg_marquardt(bundle, state, &options).0
}

/// RMS reprojection error (the residual vector's length) of `state` under `bundle`, pixels (+∞
/// when it has none).
pub fn rms(bundle: &Bundle, state: &State) -> f64 {
    bundle.cost(state).map_or(f64::INFINITY, |c| {
        (2.0 * c / bundle.residuals() as f64).sqrt()
    })
}

/// Fewest metres of air that a start leaves between a camera and its port
/// ([`State::feasible`]): far above the central-difference step of the distance (1 µm), so that
/// both sides of every difference are rigs, and below any real port's air (2 mm and more).
pub const MIN_START_AIR_M: f64 = 1e-3;

/// The least air distance of one port with unit axis `normal` (in the master frame) shared by
/// cameras at `cam_from_master` that leaves each of them at least [`MIN_START_AIR_M`] of air:
/// d ≥ n·C_k + [`MIN_START_AIR_M`] for every centre C_k = −R_kᵀ t_k (DESIGN.md §1: d_k = d − n·C_k).
pub fn shared_distance_floor(normal: &Vector3<f64>, cam_from_master: &[Isometry3<f64>]) -> f64 {
    cam_from_master
        .iter()
        .map(|pose| normal.dot(&pose.inverse().translation.vector))
        .fold(0.0, f64::max)
        + MIN_START_AIR_M
}

/// Whether a port's air distance changes no ray: with the same medium on both sides of its
/// parallel interfaces (a tank with air behind the water), a ray leaves in its own direction,
/// moved sideways by an amount that its angle and the thicknesses fix wherever the port sits.
pub fn distance_unobservable(port: &Interface) -> bool {
    port.index_air() == port.index_water()
}

/// One global parameter of the step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parameter {
    /// Port p's axis moved in its tangent plane along direction 0 or 1, radians.
    Axis(usize, usize),
    /// Port p's air distance, metres.
    Distance(usize),
    /// Port p's layer i thickness, metres.
    Thickness(usize, usize),
    /// Camera k's rotation about axis 0..3 (applied on the left of cam_from_master), radians.
    Rotation(usize, usize),
    /// Camera k's translation along axis 0..3 (of cam_from_master), metres.
    Translation(usize, usize),
    /// Camera k's calibration value j of [`INTRINSICS`] (fx, fy, cx, cy in pixels; k1, k2, p1,
    /// p2, k3 dimensionless).
    Intrinsic(usize, usize),
}

impl Parameter {
    /// The camera this parameter moves in rig `base` (`None`: every camera, a shared port).
    pub fn camera(self, base: &Rig) -> Option<usize> {
        match self {
            Parameter::Axis(p, _) | Parameter::Distance(p) | Parameter::Thickness(p, _) => {
                match base.ports() {
                    Ports::Shared(_) => None,
                    Ports::PerCamera(_) => Some(p),
                }
            }
            Parameter::Rotation(k, _)
            | Parameter::Translation(k, _)
            | Parameter::Intrinsic(k, _) => Some(k),
        }
    }
}

/// The intrinsics [`Parameter::Intrinsic`] indexes, in order: the pinhole's and OpenCV's
/// distortion `[k1, k2, p1, p2, k3]`.
pub const INTRINSICS: [&str; 9] = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"];

/// The values of [`INTRINSICS`] of `camera`.
pub fn intrinsic_values(camera: &PinholeCamera) -> [f64; 9] {
    let [k1, k2, p1, p2, k3] = camera.distortion;
    [
        camera.fx, camera.fy, camera.cx, camera.cy, k1, k2, p1, p2, k3,
    ]
}

/// `camera` with value j of [`INTRINSICS`] moved by `delta`.
fn move_intrinsic(camera: &mut PinholeCamera, j: usize, delta: f64) {
    match j {
        0 => camera.fx += delta,
        1 => camera.fy += delta,
        2 => camera.cx += delta,
        3 => camera.cy += delta,
        _ => camera.distortion[j - 4] += delta,
    }
}

/// Central-difference step of the geometric parameters (rad or m) and of the poses: pixels are
/// exact to ~1e-10 px and a step moves a corner by ~1e-3 px (1e-6 rad at a focal length of
/// ~1000 px), so the derivatives keep ~7 digits, and the truncation error (h²) is far below that.
const DIFFERENCE_STEP: f64 = 1e-6;
/// Central-difference step of fx, fy, cx, cy, pixels: a pixel is linear in them (the refraction
/// happens before the lens: u = fx·x_d + cx), so the difference has no truncation error at all,
/// and a step of 1e-3 px moves a corner by ≤ 1e-3 px, as the geometric steps do (the same ~7
/// digits against rounding).
const FOCAL_STEP_PX: f64 = 1e-3;
/// Central-difference step of the distortion terms: a pixel is linear in each of them too (for a
/// fixed normalised point), and 1e-6 moves a corner by fx·r²ⁿ·1e-6 ≲ 1e-3 px at the image's
/// edge, as the other steps do.
const LENS_STEP: f64 = 1e-6;

/// The central-difference step of `parameter`.
pub fn difference_step(parameter: Parameter) -> f64 {
    match parameter {
        Parameter::Intrinsic(_, j) if j < 4 => FOCAL_STEP_PX,
        Parameter::Intrinsic(..) => LENS_STEP,
        _ => DIFFERENCE_STEP,
    }
}

/// The global parameters `estimate` names for `base`, in step order: per port its axis (2),
/// air distance (where observable) and the layers named; then the extrinsics of every camera
/// but the master; then the intrinsics.
pub(crate) fn global_parameters(base: &Rig, estimate: Estimate) -> Vec<Parameter> {
    let mut globals = Vec::new();
    let ports = match base.ports() {
        Ports::Shared(interface) => vec![interface],
        Ports::PerCamera(ports) => ports.iter().collect(),
    };
    for (p, port) in ports.into_iter().enumerate() {
        if estimate.axis {
            globals.extend([Parameter::Axis(p, 0), Parameter::Axis(p, 1)]);
        }
        if estimate.distance && !distance_unobservable(port) {
            globals.push(Parameter::Distance(p));
        }
        let layers = port.layers().len();
        globals.extend(
            (0..layers)
                .filter(|&i| estimate.layer(i))
                .map(|i| Parameter::Thickness(p, i)),
        );
    }
    if estimate.extrinsics {
        for k in 1..base.cameras().len() {
            globals.extend((0..3).map(|a| Parameter::Rotation(k, a)));
            globals.extend((0..3).map(|a| Parameter::Translation(k, a)));
        }
    }
    if estimate.intrinsics {
        for (k, camera) in base.cameras().iter().enumerate() {
            let values = intrinsic_values(&camera.intrinsics);
            globals.extend(
                (0..INTRINSICS.len())
                    .filter(|&j| j < 4 || values[j] != 0.0)
                    .map(|j| Parameter::Intrinsic(k, j)),
            );
        }
    }
    globals
}

/// The reprojection problem of any rig.
pub struct Bundle<'a> {
    base: &'a Rig,
    views: &'a [SeenView],
    globals: Vec<Parameter>,
    huber: Option<f64>,
    /// Every target corner, target frame.
    points: Vec<[f64; 3]>,
    /// Where whole stencils are evaluated; `None`: the bundle's own CPU code.
    backend: Option<&'a dyn ResidualBackend>,
    /// A prior on the estimated intrinsics ([`Bundle::with_lens_prior`]).
    lens_prior: Option<&'a LensPrior>,
}

/// A Gaussian prior on every camera's intrinsics: the lenses calibrated in air, with their σ,
/// for a fit that estimates the intrinsics again under water ([`Bundle::with_lens_prior`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LensPrior {
    /// Per rig camera, the prior's mean of each value of [`INTRINSICS`].
    pub means: Vec<[f64; 9]>,
    /// Per rig camera, the prior's σ of each value (0 or not finite: no prior on it).
    pub std: Vec<[f64; 9]>,
    /// σ of a corner, pixels: the prior's terms are weighed against the corners' residuals
    /// (pixels, unit weight) by it, (σ_px/σ_j)·(θ_j − μ_j), which makes the least squares the
    /// maximum a posteriori estimate under both.
    pub corner_sigma_px: f64,
}

impl LensPrior {
    /// The weight σ_px/σ_j of camera `k`'s value `j`, 0 without a prior on it.
    fn weight(&self, k: usize, j: usize) -> f64 {
        let std = self.std.get(k).map_or(0.0, |s| s[j]);
        if std > 0.0 && std.is_finite() && self.corner_sigma_px > 0.0 {
            self.corner_sigma_px / std
        } else {
            0.0
        }
    }
}

impl<'a> Bundle<'a> {
    /// The problem of `views` of `target` by `base` (which gives everything known), estimating
    /// `estimate`, with an optional Huber threshold (pixels).
    pub fn new(
        base: &'a Rig,
        target: &Target,
        views: &'a [SeenView],
        estimate: Estimate,
        huber: Option<f64>,
    ) -> Self {
        let globals = global_parameters(base, estimate);
        let points = (0..target.len())
            .map(|i| target.point(i).coords.into())
            .collect();
        Self {
            base,
            views,
            globals,
            huber,
            points,
            backend: None,
            lens_prior: None,
        }
    }

    /// The same problem with a Gaussian prior on the estimated intrinsics (`None`: none): its
    /// terms join the cost and the normal equations (unit weight: they are already in pixels).
    pub fn with_lens_prior(mut self, prior: Option<&'a LensPrior>) -> Self {
        self.lens_prior = prior;
        self
    }

    /// The prior's terms: (global index, residual r = w·(θ − μ), weight w) for every estimated
    /// intrinsic with a prior.
    fn prior_terms(&self, state: &State) -> Vec<(usize, f64, f64)> {
        let Some(prior) = self.lens_prior else {
            return Vec::new();
        };
        self.globals
            .iter()
            .enumerate()
            .filter_map(|(g, &parameter)| {
                let Parameter::Intrinsic(k, j) = parameter else {
                    return None;
                };
                let w = prior.weight(k, j);
                let mean = prior.means.get(k)?[j];
                let value = intrinsic_values(state.intrinsics.get(k)?)[j];
                (w > 0.0).then_some((g, w * (value - mean), w))
            })
            .collect()
    }

    /// `normal` with the prior's terms added: each adds r² to the cost, w² to its diagonal and
    /// w·r to its gradient (J = w).
    fn with_prior(&self, state: &State, mut normal: BlockNormalEquations) -> BlockNormalEquations {
        for (g, r, w) in self.prior_terms(state) {
            normal.cost += r * r;
            normal.global[(g, g)] += w * w;
            normal.prior_information[g] += w * w;
            normal.global_gradient[g] += w * r;
        }
        normal
    }

    /// The same problem with its residuals evaluated by `backend` (made for
    /// [`observed_corners`](Self::observed_corners) of these views), or by the bundle's own CPU
    /// code where `None`.
    ///
    /// Panics if the backend was made for another number of corners.
    pub fn on(mut self, backend: Option<&'a dyn ResidualBackend>) -> Self {
        if let Some(b) = backend {
            assert_eq!(
                b.observations(),
                self.residuals() / 2,
                "a residual backend made for these views"
            );
        }
        self.backend = backend;
        self
    }

    /// Every observed corner in the order of the residuals: views in order, camera by camera in
    /// the view's order, corners in target order.
    pub fn observed_corners(&self) -> Vec<ObservedCorner> {
        let mut out = Vec::with_capacity(self.residuals() / 2);
        for (v, view) in self.views.iter().enumerate() {
            for (k, corners) in &view.cameras {
                out.extend(corners.iter().map(|(i, observed)| ObservedCorner {
                    view: v,
                    camera: *k,
                    point_in_target: self.points[*i],
                    observed: observed.coords.into(),
                }));
            }
        }
        out
    }

    /// The same problem estimating only the global parameters `keep` accepts (a search over one
    /// port leaves the others' parameters out: no image it uses depends on them).
    pub fn keeping(mut self, keep: impl Fn(Parameter) -> bool) -> Self {
        self.globals.retain(|&g| keep(g));
        self
    }

    /// The global parameters, in step order.
    pub fn globals(&self) -> &[Parameter] {
        &self.globals
    }

    /// The residual count: two per corner per camera that saw it.
    pub fn residuals(&self) -> usize {
        2 * self.views.iter().map(SeenView::observations).sum::<usize>()
    }

    /// The camera parameter `parameter` moves (`None`: every camera, a shared port).
    fn camera_of(&self, parameter: Parameter) -> Option<usize> {
        parameter.camera(self.base)
    }

    /// The refractive cameras of `state`, `None` when it is not a valid rig.
    pub fn cameras(&self, state: &State) -> Option<Vec<RefractiveCamera>> {
        state.cameras(self.base)
    }

    /// Residuals (projected − observed, px) of view `v` under target pose `pose`, camera by
    /// camera in the view's order, corners in target order; only camera `only` when given.
    fn view_residuals(
        &self,
        cameras: &[RefractiveCamera],
        v: usize,
        pose: &Isometry3<f64>,
        only: Option<usize>,
        out: &mut Vec<Vector2<f64>>,
    ) -> Option<()> {
        for (k, corners) in &self.views[v].cameras {
            if only.is_some_and(|o| o != *k) {
                continue;
            }
            let points: Vec<[f64; 3]> = corners
                .iter()
                .map(|(i, _)| {
                    (pose * nalgebra::Point3::from(self.points[*i]))
                        .coords
                        .into()
                })
                .collect();
            let pixels = lanes::project_all(&cameras[*k], &points)?;
            out.extend(
                corners
                    .iter()
                    .zip(&pixels)
                    .map(|((_, observed), p)| Vector2::new(p[0], p[1]) - observed.coords),
            );
        }
        Some(())
    }

    /// The views of `state` some of whose corners its rig cannot project (a target pose the
    /// port carries outside the lens, or behind a camera); `None` when the state is not a valid
    /// rig.
    pub fn undefined_views(&self, state: &State) -> Option<Vec<usize>> {
        let cameras = self.cameras(state)?;
        let mut scratch = Vec::new();
        Some(
            state
                .poses
                .iter()
                .enumerate()
                .filter(|(v, pose)| {
                    scratch.clear();
                    self.view_residuals(&cameras, *v, pose, None, &mut scratch)
                        .is_none()
                })
                .map(|(v, _)| v)
                .collect(),
        )
    }

    /// Every residual at `state`, views in order.
    pub fn all_residuals(&self, state: &State) -> Option<Vec<Vec<Vector2<f64>>>> {
        if let Some(backend) = self.backend {
            return self.all_residuals_on(backend, state);
        }
        let cameras = self.cameras(state)?;
        state
            .poses
            .par_iter()
            .enumerate()
            .map(|(v, pose)| {
                let mut out = Vec::new();
                self.view_residuals(&cameras, v, pose, None, &mut out)
                    .map(|()| out)
            })
            .collect()
    }

    /// RMS reprojection error of every camera (NaN for a camera that saw nothing), pixels.
    pub fn rms_per_camera(&self, state: &State) -> Option<Vec<f64>> {
        let residuals = self.all_residuals(state)?;
        let mut sums = vec![(0.0, 0usize); self.base.cameras().len()];
        for (view, r) in self.views.iter().zip(&residuals) {
            let mut offset = 0;
            for (k, corners) in &view.cameras {
                for r in &r[offset..offset + corners.len()] {
                    sums[*k].0 += r.norm_squared();
                    sums[*k].1 += 1;
                }
                offset += corners.len();
            }
        }
        Some(
            sums.iter()
                .map(|&(s, n)| {
                    if n == 0 {
                        f64::NAN
                    } else {
                        (s / (2 * n) as f64).sqrt()
                    }
                })
                .collect(),
        )
    }

    /// The range of the observed corners ([`observed_corners`](Self::observed_corners)) of
    /// every view.
    fn view_ranges(&self) -> Vec<std::ops::Range<usize>> {
        let mut start = 0;
        self.views
            .iter()
            .map(|view| {
                let range = start..start + view.observations();
                start = range.end;
                range
            })
            .collect()
    }

    /// [`all_residuals`](Self::all_residuals) by `backend`: one evaluation.
    fn all_residuals_on(
        &self,
        backend: &dyn ResidualBackend,
        state: &State,
    ) -> Option<Vec<Vec<Vector2<f64>>>> {
        let batch = StencilBatch {
            cameras: vec![self.cameras(state)?],
            poses: vec![state.poses.clone()],
            evaluations: vec![Evaluation {
                cameras: 0,
                poses: 0,
                only: None,
            }],
        };
        let residuals = backend.residuals(&batch).swap_remove(0)?;
        Some(
            self.view_ranges()
                .into_iter()
                .map(|range| residuals[range].to_vec())
                .collect(),
        )
    }

    /// The central-difference stencil at `state`, `None` when a step leaves the valid rigs:
    /// evaluation 0 is the state itself; evaluations 1 + 2c and 2 + 2c are the state moved by
    /// +h and −h along column c of the step (h: [`difference_step`]; the global parameters in
    /// order, only the camera a parameter moves evaluated; then the six pose parameters, every view's pose moved at once:
    /// a corner depends on its own view's pose alone).
    pub fn stencil(&self, state: &State) -> Option<StencilBatch> {
        let mut batch = StencilBatch {
            cameras: vec![self.cameras(state)?],
            poses: vec![state.poses.clone()],
            evaluations: vec![Evaluation {
                cameras: 0,
                poses: 0,
                only: None,
            }],
        };
        for &parameter in &self.globals {
            let h = difference_step(parameter);
            for step in [h, -h] {
                batch
                    .cameras
                    .push(self.cameras(&self.moved(state, parameter, step))?);
                batch.evaluations.push(Evaluation {
                    cameras: batch.cameras.len() - 1,
                    poses: 0,
                    only: self.camera_of(parameter),
                });
            }
        }
        for q in 0..POSE_PARAMETERS {
            for step in [DIFFERENCE_STEP, -DIFFERENCE_STEP] {
                let mut delta = [0.0; POSE_PARAMETERS];
                delta[q] = step;
                batch
                    .poses
                    .push(state.poses.iter().map(|p| move_pose(p, &delta)).collect());
                batch.evaluations.push(Evaluation {
                    cameras: 0,
                    poses: batch.poses.len() - 1,
                    only: None,
                });
            }
        }
        Some(batch)
    }

    /// [`normal_equations`](LeastSquares::normal_equations) from the residuals of the whole
    /// [`stencil`](Self::stencil) evaluated by `backend` in one call: each view's Jacobian by
    /// central differences of its rows, then its share as on the CPU path.
    fn normal_equations_on(
        &self,
        backend: &dyn ResidualBackend,
        state: &State,
    ) -> Option<BlockNormalEquations> {
        let globals = self.globals.len();
        let columns = globals + POSE_PARAMETERS;
        // Every evaluation answered, or no normal equations (as on the CPU path).
        let residuals: Vec<Vec<Vector2<f64>>> = backend
            .residuals(&self.stencil(state)?)
            .into_iter()
            .collect::<Option<_>>()?;
        let shares = self
            .view_ranges()
            .into_par_iter()
            .map(|range| {
                let count = range.len();
                // jacobian[c * count + i] = ∂r_i/∂(parameter c), globals first.
                let mut jacobian = vec![Vector2::zeros(); columns * count];
                for c in 0..columns {
                    let plus = &residuals[1 + 2 * c][range.clone()];
                    let minus = &residuals[2 + 2 * c][range.clone()];
                    let h = self
                        .globals
                        .get(c)
                        .map_or(DIFFERENCE_STEP, |&g| difference_step(g));
                    for (i, (a, b)) in plus.iter().zip(minus).enumerate() {
                        jacobian[c * count + i] = (a - b) / (2.0 * h);
                    }
                }
                view_share(&residuals[0][range], &jacobian, columns, self.huber)
            })
            .collect();
        Some(self.with_prior(state, BlockNormalEquations::from_shares(globals, shares)))
    }

    fn moved(&self, state: &State, parameter: Parameter, delta: f64) -> State {
        moved(state, parameter, delta)
    }
}

/// `state` moved by `delta` along the global parameter `parameter`.
pub(crate) fn moved(state: &State, parameter: Parameter, delta: f64) -> State {
    let mut state = state.clone();
    match parameter {
        Parameter::Axis(p, a) => {
            let mut offset = Vector2::zeros();
            offset[a] = delta;
            state.ports[p].normal = tangent_step(&state.ports[p].normal, &offset);
        }
        Parameter::Distance(p) => state.ports[p].distance += delta,
        Parameter::Thickness(p, i) => state.ports[p].thicknesses[i] += delta,
        Parameter::Rotation(k, a) => {
            let mut w = Vector3::zeros();
            w[a] = delta;
            state.extrinsics[k] = Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_scaled_axis(w),
            ) * state.extrinsics[k];
        }
        Parameter::Translation(k, a) => state.extrinsics[k].translation.vector[a] += delta,
        Parameter::Intrinsic(k, j) => move_intrinsic(&mut state.intrinsics[k], j, delta),
    }
    state
}

impl LeastSquares for Bundle<'_> {
    type State = State;
    type Normal = BlockNormalEquations;

    fn dimension(&self, state: &State) -> usize {
        self.globals.len() + POSE_PARAMETERS * state.poses.len()
    }

    fn cost(&self, state: &State) -> Option<f64> {
        let residuals = self.all_residuals(state)?;
        let prior: f64 = self.prior_terms(state).iter().map(|(_, r, _)| r * r).sum();
        Some(
            residuals
                .iter()
                .flatten()
                .map(|r| robust(self.huber, r.norm_squared()).0)
                .sum::<f64>()
                + prior,
        )
    }

    fn normal_equations(&self, state: &State) -> Option<BlockNormalEquations> {
        if let Some(backend) = self.backend {
            return self.normal_equations_on(backend, state);
        }
        let globals = self.globals.len();
        let cameras = self.cameras(state)?;
        // The cameras of the state moved by ±h along each global parameter.
        let shifted: Vec<[Vec<RefractiveCamera>; 2]> = self
            .globals
            .iter()
            .map(|&p| {
                let h = difference_step(p);
                Some([
                    self.cameras(&self.moved(state, p, h))?,
                    self.cameras(&self.moved(state, p, -h))?,
                ])
            })
            .collect::<Option<_>>()?;
        let shares: Vec<(DMatrix<f64>, DVector<f64>, f64)> = state
            .poses
            .par_iter()
            .enumerate()
            .map(|(v, pose)| {
                let mut base = Vec::new();
                self.view_residuals(&cameras, v, pose, None, &mut base)?;
                let count = base.len();
                let columns = globals + POSE_PARAMETERS;
                // jacobian[p * count + i] = ∂r_i/∂(parameter p), globals first.
                let mut jacobian = vec![Vector2::zeros(); columns * count];
                // Where each camera's residuals start in this view.
                let mut offsets = Vec::with_capacity(self.views[v].cameras.len());
                let mut offset = 0;
                for (k, corners) in &self.views[v].cameras {
                    offsets.push((*k, offset));
                    offset += corners.len();
                }
                let (mut plus, mut minus) = (Vec::with_capacity(count), Vec::with_capacity(count));
                for p in 0..columns {
                    plus.clear();
                    minus.clear();
                    // Rows this column fills: a camera's block, or the whole view.
                    let h = if p < globals {
                        difference_step(self.globals[p])
                    } else {
                        DIFFERENCE_STEP
                    };
                    let start = if p < globals {
                        let only = self.camera_of(self.globals[p]);
                        if only.is_some_and(|k| !offsets.iter().any(|(c, _)| *c == k)) {
                            continue;
                        }
                        self.view_residuals(&shifted[p][0], v, pose, only, &mut plus)?;
                        self.view_residuals(&shifted[p][1], v, pose, only, &mut minus)?;
                        only.map_or(0, |k| {
                            offsets.iter().find(|(c, _)| *c == k).expect("seen").1
                        })
                    } else {
                        let mut delta = [0.0; POSE_PARAMETERS];
                        delta[p - globals] = DIFFERENCE_STEP;
                        self.view_residuals(
                            &cameras,
                            v,
                            &move_pose(pose, &delta),
                            None,
                            &mut plus,
                        )?;
                        delta[p - globals] = -DIFFERENCE_STEP;
                        self.view_residuals(
                            &cameras,
                            v,
                            &move_pose(pose, &delta),
                            None,
                            &mut minus,
                        )?;
                        0
                    };
                    for (i, (a, b)) in plus.iter().zip(&minus).enumerate() {
                        jacobian[p * count + start + i] = (a - b) / (2.0 * h);
                    }
                }
                Some(view_share(&base, &jacobian, columns, self.huber))
            })
            .collect::<Option<_>>()?;
        Some(self.with_prior(state, BlockNormalEquations::from_shares(globals, shares)))
    }

    fn retract(&self, state: &State, delta: &DVector<f64>) -> State {
        let d = delta.as_slice();
        let mut moved = state.clone();
        // A port's two axis steps move its axis together, in the tangent basis of the axis the
        // derivatives were taken at.
        let mut axis_steps = vec![Vector2::zeros(); state.ports.len()];
        for (p, &parameter) in self.globals.iter().enumerate() {
            match parameter {
                Parameter::Axis(port, a) => axis_steps[port][a] = d[p],
                _ => moved = self.moved(&moved, parameter, d[p]),
            }
        }
        for (port, step) in moved.ports.iter_mut().zip(&axis_steps) {
            port.normal = tangent_step(&port.normal, step);
        }
        let g = self.globals.len();
        moved.poses = state
            .poses
            .iter()
            .enumerate()
            .map(|(v, pose)| {
                move_pose(
                    pose,
                    &d[g + POSE_PARAMETERS * v..g + POSE_PARAMETERS * (v + 1)],
                )
            })
            .collect();
        moved
    }
}

#[cfg(test)]
mod tests {
    use super::rms;
    use super::*;
    use crate::base::Board;
    use crate::model::{Layer, PinholeCamera, RigCamera};
    use nalgebra::{Matrix3, Point2};

    fn camera(name: &str, x: f64) -> RigCamera {
        let intrinsics =
            PinholeCamera::new(name, 640, 480, 500.0, 500.0, 320.0, 240.0, [0.0; 5]).unwrap();
        RigCamera::new(
            name,
            intrinsics,
            Matrix3::identity(),
            Vector3::new(-x, 0.0, 0.0),
        )
        .unwrap()
    }

    fn port(distance: f64) -> Interface {
        let glass = vec![
            Layer {
                thickness: 0.01,
                index: 1.49,
            },
            Layer {
                thickness: 0.004,
                index: 1.5,
            },
        ];
        Interface::new(Vector3::new(0.05, 0.0, 1.0), distance, glass, 1.0, 1.333).unwrap()
    }

    #[test]
    fn estimates_parse_and_name_each_other() {
        for text in [
            "axis,distance",
            "axis,layers,extrinsics",
            "distance,layer:0,layer:3",
        ] {
            assert_eq!(Estimate::parse(text).unwrap().name(), text);
        }
        assert_eq!(
            Estimate::parse("axis,distance").unwrap(),
            Estimate::default()
        );
        let error = Estimate::parse("axis,tilt").unwrap_err();
        assert!(
            error.contains("'tilt' is not something to estimate"),
            "{error}"
        );
        assert!(Estimate::parse("layer:32").unwrap_err().contains("0 to 31"));
        let layers = Estimate::parse("layer:1").unwrap();
        assert!(layers.layer(1) && !layers.layer(0) && !layers.layer(40));
    }

    #[test]
    fn the_global_parameters_follow_what_is_estimated_and_whose_port_it_is() {
        let target = Target::Board(Board {
            rows: 3,
            cols: 3,
            square: 0.05,
        });
        let views: Vec<SeenView> = Vec::new();
        let shared = Rig::new(vec![camera("a", 0.0), camera("b", 0.1)], port(0.02)).unwrap();
        let all = Estimate::parse("axis,distance,layers,extrinsics").unwrap();
        let bundle = Bundle::new(&shared, &target, &views, all, None);
        assert_eq!(
            bundle.globals(),
            &[
                Parameter::Axis(0, 0),
                Parameter::Axis(0, 1),
                Parameter::Distance(0),
                Parameter::Thickness(0, 0),
                Parameter::Thickness(0, 1),
                Parameter::Rotation(1, 0),
                Parameter::Rotation(1, 1),
                Parameter::Rotation(1, 2),
                Parameter::Translation(1, 0),
                Parameter::Translation(1, 1),
                Parameter::Translation(1, 2),
            ]
        );
        // A shared port moves every camera; a camera's own port moves that camera only.
        assert_eq!(bundle.camera_of(Parameter::Axis(0, 1)), None);
        let housings = Rig::with_ports(
            vec![camera("a", 0.0), camera("b", 0.2)],
            Ports::PerCamera(vec![port(0.02), port(0.03)]),
        )
        .unwrap();
        let bundle = Bundle::new(&housings, &target, &views, Estimate::default(), None);
        assert_eq!(bundle.globals().len(), 6);
        assert_eq!(bundle.camera_of(Parameter::Distance(1)), Some(1));
        // Air on both sides of a slab: its place changes no ray, its distance is not estimated.
        let tank = Interface::new(
            Vector3::z(),
            0.05,
            vec![Layer {
                thickness: 0.1,
                index: 1.333,
            }],
            1.0,
            1.0,
        )
        .unwrap();
        assert!(distance_unobservable(&tank));
        let rig = Rig::new(vec![camera("a", 0.0)], tank).unwrap();
        let bundle = Bundle::new(&rig, &target, &views, Estimate::default(), None);
        assert_eq!(
            bundle.globals(),
            &[Parameter::Axis(0, 0), Parameter::Axis(0, 1)]
        );
    }

    #[test]
    fn a_state_is_the_rig_it_describes_and_moves_one_parameter_at_a_time() {
        let rig = Rig::new(vec![camera("a", 0.0), camera("b", 0.1)], port(0.02)).unwrap();
        let state = State::of(&rig, vec![Isometry3::identity()]);
        // The same rig, its normal normalised again (to the last bit).
        let again = state.rig(&rig).unwrap();
        assert_eq!(again.cameras(), rig.cameras());
        let (a, b) = (
            again.shared_interface().unwrap(),
            rig.shared_interface().unwrap(),
        );
        assert!(a.normal().angle(b.normal()) < 1e-15);
        assert_eq!(
            (a.air_distance(), a.layers()),
            (b.air_distance(), b.layers())
        );
        let target = Target::Board(Board {
            rows: 3,
            cols: 3,
            square: 0.05,
        });
        let views = vec![SeenView {
            cameras: vec![(0, vec![(0, Point2::new(1.0, 1.0))])],
            keys: vec!["a".into()],
        }];
        let all = Estimate::parse("axis,distance,layers,extrinsics").unwrap();
        let bundle = Bundle::new(&rig, &target, &views, all, None);
        let moved = bundle.moved(&state, Parameter::Distance(0), 1e-3);
        assert!((moved.ports[0].distance - 0.021).abs() < 1e-15);
        let moved = bundle.moved(&state, Parameter::Thickness(0, 1), -1e-3);
        assert!((moved.ports[0].thicknesses[1] - 0.003).abs() < 1e-15);
        let moved = bundle.moved(&state, Parameter::Translation(1, 2), 0.01);
        assert!((moved.extrinsics[1].translation.vector.z - 0.01).abs() < 1e-15);
        // A tangent step of 0.01 turns the axis by atan(0.01) (normalise(n + 0.01 e₁)).
        let moved = bundle.moved(&state, Parameter::Axis(0, 0), 0.01);
        let turned = moved.ports[0].normal.angle(&state.ports[0].normal);
        assert!((turned - 0.01f64.atan()).abs() < 1e-12, "{turned}");
        // A distance that puts a camera outside the air is no rig.
        let outside = bundle.moved(&state, Parameter::Distance(0), -0.03);
        assert!(outside.rig(&rig).is_none());
    }

    /// The rig, views and state (the true poses, a port moved off the truth) of a simulated scene
    /// of `rig` with 0.1 px noise.
    fn simulated(rig: &Rig, views: usize) -> (Target, Vec<SeenView>, State) {
        use crate::calib::simulate::{SceneSpec, simulate};
        let target = Target::Board(Board {
            rows: 4,
            cols: 5,
            square: 0.04,
        });
        let scene = simulate(rig, &SceneSpec::new(target.clone(), views, 0.1, 5)).unwrap();
        let seen = scene.observations.resolve(rig).unwrap();
        let mut state = State::of(rig, scene.master_from_target);
        state.ports[0].distance += 2e-3;
        state.ports[0].normal = tangent_step(&state.ports[0].normal, &Vector2::new(0.01, -0.02));
        (target, seen, state)
    }

    /// The stencil evaluated by the CPU residual backend gives the bundle's own normal
    /// equations bit for bit: the batch's evaluations are the columns' ± steps in order, a
    /// parameter of one camera leaves the others' rows zero, and a pose set moving every view at
    /// once gives each view's pose columns. Over a shared port with every layer and the
    /// extrinsics and intrinsics estimated (global columns of every camera and of one camera,
    /// steps of several sizes), and over a port
    /// per camera (each port's columns only its camera's rows).
    #[test]
    fn the_stencil_on_the_cpu_backend_gives_the_same_normal_equations_bit_for_bit() {
        let shared = Rig::new(vec![camera("a", 0.0), camera("b", 0.1)], port(0.02)).unwrap();
        let housings = Rig::with_ports(
            vec![camera("a", 0.0), camera("b", 0.1)],
            Ports::PerCamera(vec![port(0.02), port(0.025)]),
        )
        .unwrap();
        let all = Estimate::parse("axis,distance,layers,extrinsics,intrinsics").unwrap();
        for rig in [&shared, &housings] {
            let (target, seen, state) = simulated(rig, 5);
            for huber in [None, Some(0.2)] {
                let cpu = Bundle::new(rig, &target, &seen, all, huber);
                let backend =
                    crate::calib::backends::residuals::CpuResiduals::new(&cpu.observed_corners());
                let batched = Bundle::new(rig, &target, &seen, all, huber).on(Some(&backend));
                let stencil = batched.stencil(&state).unwrap();
                assert_eq!(
                    stencil.evaluations.len(),
                    1 + 2 * (cpu.globals().len() + POSE_PARAMETERS)
                );
                assert_eq!(
                    batched.normal_equations(&state).unwrap(),
                    cpu.normal_equations(&state).unwrap()
                );
                assert_eq!(batched.cost(&state), cpu.cost(&state));
                assert_eq!(batched.rms_per_camera(&state), cpu.rms_per_camera(&state));
            }
        }
    }

    /// A 640×480 camera with a lens (k3 left out, as an in-air fit may leave it).
    fn lens_camera(name: &str, x: f64) -> RigCamera {
        let intrinsics = PinholeCamera::new(
            name,
            640,
            480,
            520.0,
            515.0,
            318.0,
            243.0,
            [-0.12, 0.05, 4e-4, -3e-4, 0.0],
        )
        .unwrap();
        RigCamera::new(
            name,
            intrinsics,
            Matrix3::identity(),
            Vector3::new(-x, 0.0, 0.0),
        )
        .unwrap()
    }

    fn lens_rig() -> Rig {
        Rig::new(
            vec![lens_camera("a", 0.0), lens_camera("b", 0.12)],
            port(0.02),
        )
        .unwrap()
    }

    fn lens_views(
        rig: &Rig,
        noise_px: f64,
        seed: u64,
    ) -> (Target, Vec<SeenView>, Vec<Isometry3<f64>>) {
        use crate::calib::simulate::{SceneSpec, simulate};
        let target = Target::Board(Board {
            rows: 6,
            cols: 8,
            square: 0.03,
        });
        let scene = simulate(rig, &SceneSpec::new(target.clone(), 16, noise_px, seed)).unwrap();
        let seen = scene.observations.resolve(rig).unwrap();
        (target, seen, scene.master_from_target)
    }

    #[test]
    fn intrinsics_are_global_parameters_of_their_camera_and_lens_terms_at_zero_stay_out() {
        let rig = lens_rig();
        let target = Target::Board(Board {
            rows: 3,
            cols: 3,
            square: 0.05,
        });
        let views: Vec<SeenView> = Vec::new();
        let estimate = Estimate::parse("intrinsics").unwrap();
        assert_eq!(estimate.name(), "intrinsics");
        assert_eq!(
            Estimate::parse("axis,distance,extrinsics,intrinsics")
                .unwrap()
                .name(),
            "axis,distance,extrinsics,intrinsics"
        );
        let bundle = Bundle::new(&rig, &target, &views, estimate, None);
        // fx, fy, cx, cy, k1, k2, p1, p2 of each camera; k3 is 0 in the start: left out.
        let want: Vec<Parameter> = (0..2)
            .flat_map(|k| (0..8).map(move |j| Parameter::Intrinsic(k, j)))
            .collect();
        assert_eq!(bundle.globals(), &want[..]);
        assert_eq!(bundle.camera_of(Parameter::Intrinsic(1, 4)), Some(1));
        // A moved intrinsic is that camera's, in the rig the state describes.
        let state = State::of(&rig, vec![Isometry3::identity()]);
        let moved = bundle.moved(&state, Parameter::Intrinsic(1, 2), 3.0);
        let moved = bundle.moved(&moved, Parameter::Intrinsic(1, 4), 0.01);
        let moved_rig = moved.rig(&rig).unwrap();
        let (a, b) = (
            &moved_rig.cameras()[1].intrinsics,
            &rig.cameras()[1].intrinsics,
        );
        assert_eq!(a.cx, b.cx + 3.0);
        assert_eq!(a.distortion[0], b.distortion[0] + 0.01);
        assert_eq!(moved_rig.cameras()[0], rig.cameras()[0]);
        // A focal length ≤ 0 is no rig.
        let flat = bundle.moved(&state, Parameter::Intrinsic(0, 0), -600.0);
        assert!(flat.rig(&rig).is_none());
    }

    /// The Jacobian columns of the intrinsics in the normal equations against the closed form of
    /// OpenCV's model: u = fx·x_d + cx, x_d = x(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y +
    /// p2 (r² + 2x²) (and v alike), (x, y) the undistorted normalised point of the projected
    /// corner. JᵀJ and Jᵀr of camera 0's nine intrinsics (k3 too, here non-zero) agree to 1e-7 of
    /// their scale; and each column agrees with a central difference 100 times finer.
    #[test]
    fn the_intrinsics_columns_match_the_closed_form_and_a_finer_difference() {
        let mut truth = lens_rig();
        let mut cameras = truth.cameras().to_vec();
        cameras[0].intrinsics.distortion[4] = 0.02;
        truth = Rig::with_ports(cameras, truth.ports().clone()).unwrap();
        let (target, seen, poses) = lens_views(&truth, 0.1, 3);
        let estimate = Estimate::parse("intrinsics").unwrap();
        let bundle = Bundle::new(&truth, &target, &seen, estimate, None)
            .keeping(|g| matches!(g, Parameter::Intrinsic(0, _)));
        assert_eq!(bundle.globals().len(), 9);
        let state = State::of(&truth, poses);
        let normal = bundle.normal_equations(&state).unwrap();
        let residuals: Vec<Vector2<f64>> = bundle
            .all_residuals(&state)
            .unwrap()
            .into_iter()
            .flatten()
            .collect();
        let corners = bundle.observed_corners();
        let c = &truth.cameras()[0].intrinsics;
        let mut jtj = DMatrix::<f64>::zeros(9, 9);
        let mut jtr = DVector::<f64>::zeros(9);
        for (corner, r) in corners.iter().zip(&residuals) {
            if corner.camera != 0 {
                continue;
            }
            let (u, v) = (corner.observed[0] + r.x, corner.observed[1] + r.y);
            let distorted = Vector2::new((u - c.cx) / c.fx, (v - c.cy) / c.fy);
            let p = c.undistort_normalized(&distorted).unwrap();
            let (x, y) = (p.x, p.y);
            let r2 = x * x + y * y;
            let columns = [
                Vector2::new(distorted.x, 0.0),
                Vector2::new(0.0, distorted.y),
                Vector2::new(1.0, 0.0),
                Vector2::new(0.0, 1.0),
                Vector2::new(c.fx * x * r2, c.fy * y * r2),
                Vector2::new(c.fx * x * r2 * r2, c.fy * y * r2 * r2),
                Vector2::new(c.fx * 2.0 * x * y, c.fy * (r2 + 2.0 * y * y)),
                Vector2::new(c.fx * (r2 + 2.0 * x * x), c.fy * 2.0 * x * y),
                Vector2::new(c.fx * x * r2 * r2 * r2, c.fy * y * r2 * r2 * r2),
            ];
            for i in 0..9 {
                jtr[i] += columns[i].dot(r);
                for j in 0..9 {
                    jtj[(i, j)] += columns[i].dot(&columns[j]);
                }
            }
        }
        for i in 0..9 {
            for j in 0..9 {
                let scale = (jtj[(i, i)] * jtj[(j, j)]).sqrt();
                let error = (normal.global[(i, j)] - jtj[(i, j)]).abs() / scale;
                assert!(
                    error < 1e-7,
                    "JᵀJ[{i}][{j}]: {} vs {} ({error:e})",
                    normal.global[(i, j)],
                    jtj[(i, j)]
                );
            }
            let scale = jtj[(i, i)].sqrt()
                * residuals
                    .iter()
                    .map(|r| r.norm_squared())
                    .sum::<f64>()
                    .sqrt();
            let error = (normal.global_gradient[i] - jtr[i]).abs() / scale;
            assert!(
                error < 1e-7,
                "Jᵀr[{i}]: {} vs {} ({error:e})",
                normal.global_gradient[i],
                jtr[i]
            );
        }
        // Each column against a central difference with a step 100 times finer (the pixels are
        // linear in the intrinsics: both are exact but for rounding).
        for &parameter in bundle.globals() {
            let fine = difference_step(parameter) / 100.0;
            let column = |h: f64| -> Vec<Vector2<f64>> {
                let plus = bundle
                    .all_residuals(&bundle.moved(&state, parameter, h))
                    .unwrap();
                let minus = bundle
                    .all_residuals(&bundle.moved(&state, parameter, -h))
                    .unwrap();
                plus.iter()
                    .flatten()
                    .zip(minus.iter().flatten())
                    .map(|(a, b)| (a - b) / (2.0 * h))
                    .collect()
            };
            let (coarse, finer) = (column(difference_step(parameter)), column(fine));
            let size = finer.iter().map(|d| d.norm()).fold(0.0, f64::max);
            let gap = coarse
                .iter()
                .zip(&finer)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max);
            assert!(gap < 1e-5 * size, "{parameter:?}: {gap:e} against {size:e}");
        }
    }

    /// Noise-free views of a lens rig, the start's intrinsics off as an in-air calibration can
    /// leave them (fx +0.5 %, cx +3 px, k1 +0.01 in each camera), the port and the extrinsics
    /// off too: maximum likelihood over the port, the extrinsics and the intrinsics comes back to
    /// the truth, to rounding.
    #[test]
    fn intrinsics_extrinsics_and_port_come_back_from_noise_free_views() {
        use crate::calib::solvers::lm::{LmOptions, levenberg_marquardt};
        let truth = lens_rig();
        let (target, seen, poses) = lens_views(&truth, 0.0, 7);
        let estimate = Estimate::parse("axis,distance,extrinsics,intrinsics").unwrap();
        let mut start = State::of(&truth, poses);
        for camera in &mut start.intrinsics {
            camera.fx *= 1.005;
            camera.cx += 3.0;
            camera.distortion[0] += 0.01;
        }
        start.ports[0].distance += 2e-3;
        start.ports[0].normal = tangent_step(&start.ports[0].normal, &Vector2::new(0.01, -0.02));
        start.extrinsics[1].translation.vector.x += 2e-3;
        // The bundle's known values (k3 = 0 stays out) are the start's.
        let start_rig = start.rig(&truth).unwrap();
        let bundle = Bundle::new(&start_rig, &target, &seen, estimate, None);
        let options = LmOptions {
            max_iterations: 500,
            ..LmOptions::default()
        };
        let (found, report, _) = levenberg_marquardt(&bundle, start, &options);
        assert!(report.termination.converged(), "{report:?}");
        let want = State::of(&truth, Vec::new());
        for (k, (a, b)) in found.intrinsics.iter().zip(&want.intrinsics).enumerate() {
            let (a, b) = (intrinsic_values(a), intrinsic_values(b));
            for j in 0..9 {
                let bound = if j < 4 { 1e-5 } else { 1e-8 };
                assert!(
                    (a[j] - b[j]).abs() < bound,
                    "camera {k} {}: {} vs {}",
                    INTRINSICS[j],
                    a[j],
                    b[j]
                );
            }
        }
        let axis = found.ports[0]
            .normal
            .angle(&want.ports[0].normal)
            .to_degrees();
        let air = (found.ports[0].distance - want.ports[0].distance).abs();
        let baseline =
            (found.extrinsics[1].translation.vector - want.extrinsics[1].translation.vector).norm();
        assert!(
            axis < 1e-7 && air < 1e-9 && baseline < 1e-9,
            "axis {axis}°, air {air} m, baseline {baseline} m"
        );
        assert!(rms(&bundle, &found) < 1e-7, "{}", rms(&bundle, &found));
    }

    /// The lens prior's terms in the normal equations are those of its cost: with the prior
    /// on (and 0.1 px of noise, the start 2 px and 0.4 % off), the gradient Jᵀr of every
    /// intrinsic equals half the central difference of the cost, and the cost grows by exactly
    /// Σ (σ_px/σ_j)²(θ_j − μ_j)² over the bundle without it.
    #[test]
    fn the_lens_priors_terms_are_its_cost_s_derivatives() {
        let truth = lens_rig();
        let (target, seen, poses) = lens_views(&truth, 0.1, 5);
        let estimate = Estimate::parse("intrinsics").unwrap();
        let prior = LensPrior {
            means: truth
                .cameras()
                .iter()
                .map(|c| intrinsic_values(&c.intrinsics))
                .collect(),
            std: vec![[0.5, 0.5, 0.4, 0.4, 1e-3, 2e-3, 1e-4, 1e-4, 0.0]; 2],
            corner_sigma_px: 0.1,
        };
        let plain = Bundle::new(&truth, &target, &seen, estimate, None);
        let bundle =
            Bundle::new(&truth, &target, &seen, estimate, None).with_lens_prior(Some(&prior));
        let mut state = State::of(&truth, poses);
        state.intrinsics[0].cx += 2.0;
        state.intrinsics[1].fx *= 1.004;
        let expected: f64 = (0..2)
            .flat_map(|k| (0..8).map(move |j| (k, j)))
            .map(|(k, j)| {
                let d = intrinsic_values(&state.intrinsics[k])[j] - prior.means[k][j];
                (0.1 / prior.std[k][j] * d).powi(2)
            })
            .sum();
        let added = bundle.cost(&state).unwrap() - plain.cost(&state).unwrap();
        assert!(
            (added - expected).abs() < 1e-9 * expected,
            "{added} vs {expected}"
        );
        let normal = bundle.normal_equations(&state).unwrap();
        assert!((normal.cost - bundle.cost(&state).unwrap()).abs() < 1e-9 * normal.cost);
        for (g, &parameter) in bundle.globals().iter().enumerate() {
            let h = if matches!(parameter, Parameter::Intrinsic(_, j) if j < 4) {
                1e-3
            } else {
                1e-7
            };
            let up = bundle.cost(&bundle.moved(&state, parameter, h)).unwrap();
            let down = bundle.cost(&bundle.moved(&state, parameter, -h)).unwrap();
            let slope = (up - down) / (2.0 * h) / 2.0;
            let scale = slope.abs().max(normal.global_gradient[g].abs()).max(1e-6);
            assert!(
                (slope - normal.global_gradient[g]).abs() < 1e-4 * scale,
                "{parameter:?}: Jᵀr {} against the cost's slope {slope}",
                normal.global_gradient[g]
            );
        }
    }

    /// A prior pulls each estimated value toward its mean as the posterior does: on noise-free
    /// views whose truth has cx 3 px above the prior's mean, a prior σ equal to the data's own
    /// σ of cx leaves it half way, a prior 100 times tighter at the mean, and without one at the
    /// truth (the other values held by the data alone, their prior σ unset).
    #[test]
    fn a_lens_prior_holds_a_value_as_its_sigma_against_the_datas_says() {
        let truth = lens_rig();
        let (target, seen, poses) = lens_views(&truth, 0.0, 9);
        let estimate = Estimate::parse("intrinsics").unwrap();
        let bundle = Bundle::new(&truth, &target, &seen, estimate, None)
            .keeping(|g| g == Parameter::Intrinsic(0, 2));
        let state = State::of(&truth, poses);
        // The data's σ of cx at unit corner σ: the inverse of the information about cx, with the
        // poses eliminated.
        let information = bundle
            .normal_equations(&state)
            .unwrap()
            .global_information()
            .unwrap();
        let data_std = information[(0, 0)].recip().sqrt();
        let options = LmOptions {
            max_iterations: 200,
            ..LmOptions::default()
        };
        let truth_cx = truth.cameras()[0].intrinsics.cx;
        let fitted_cx = |prior_std: Option<f64>| {
            let prior = LensPrior {
                means: (0..2)
                    .map(|k| {
                        let mut values = intrinsic_values(&truth.cameras()[k].intrinsics);
                        values[2] -= 3.0;
                        values
                    })
                    .collect(),
                // A σ on cx alone (0: no prior on the other values).
                std: vec![
                    std::array::from_fn(|j| if j == 2 {
                        prior_std.unwrap_or(0.0)
                    } else {
                        0.0
                    });
                    2
                ],
                corner_sigma_px: 1.0,
            };
            let with = Bundle::new(&truth, &target, &seen, estimate, None)
                .keeping(|g| g == Parameter::Intrinsic(0, 2))
                .with_lens_prior(prior_std.map(|_| &prior));
            let (found, report, _) = levenberg_marquardt(&with, state.clone(), &options);
            assert!(report.termination.converged(), "{report:?}");
            found.intrinsics[0].cx - truth_cx
        };
        let none = fitted_cx(None);
        let equal = fitted_cx(Some(data_std));
        let tight = fitted_cx(Some(data_std / 100.0));
        assert!(
            none.abs() < 1e-6,
            "without a prior: {none} px from the truth"
        );
        assert!(
            (equal + 1.5).abs() < 0.01,
            "equal σ: {equal} px (half way is -1.5)"
        );
        assert!(
            (tight + 3.0).abs() < 0.01,
            "tight prior: {tight} px (the mean is -3)"
        );
    }

    /// With 0.2 px of noise the calibration reports σ of every estimated intrinsic, and the truth
    /// lies within 3σ of each estimate; k3 (0 in the rig) has none and stays 0.
    #[test]
    fn the_report_gives_the_intrinsics_standard_deviations_and_they_cover_the_truth() {
        use crate::calib::simulate::{SceneSpec, simulate};
        use crate::calib::{Options, calibrate};
        let truth = lens_rig();
        let target = Target::Board(Board {
            rows: 6,
            cols: 8,
            square: 0.03,
        });
        let scene = simulate(&truth, &SceneSpec::new(target, 20, 0.2, 11)).unwrap();
        let mut cameras = truth.cameras().to_vec();
        for camera in &mut cameras {
            camera.intrinsics.fx *= 1.002;
            camera.intrinsics.cx += 1.0;
            camera.intrinsics.distortion[0] += 0.003;
        }
        let start = Rig::with_ports(cameras, truth.ports().clone()).unwrap();
        let options = Options {
            estimate: Estimate::parse("axis,distance,extrinsics,intrinsics").unwrap(),
            ..Options::default()
        };
        let calibration = calibrate(&start, &scene.observations, &options).unwrap();
        assert!(calibration.report.fits, "{:?}", calibration.report.warnings);
        for (k, camera) in calibration.report.cameras.iter().enumerate() {
            let std = camera.intrinsics_std.expect("estimated intrinsics have σ");
            let found = intrinsic_values(&calibration.rig.cameras()[k].intrinsics);
            let want = intrinsic_values(&truth.cameras()[k].intrinsics);
            for j in 0..8 {
                let s = std[j].expect("σ");
                assert!(
                    s > 0.0 && (found[j] - want[j]).abs() < 3.0 * s,
                    "camera {k} {}: {} vs {} ± {s}",
                    INTRINSICS[j],
                    found[j],
                    want[j]
                );
            }
            assert_eq!((std[8], found[8]), (None, 0.0));
        }
    }
}
