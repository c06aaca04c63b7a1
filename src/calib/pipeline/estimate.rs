//! Steps 3 to 5 of the pipeline ([`super`]): the target poses, the start of the ports, and the
//! maximum-likelihood refinement from one start or several.

use std::time::Instant;

use nalgebra::Isometry3;

use super::bundle::{Bundle, Estimate, Parameter, State, fit_briefly, rms};
use super::{MIN_VIEWS, Method, Options, Progress, consecutive, poses, search};
use crate::calib::backends::residuals::ResidualBackend;
use crate::calib::costs::SceneFit;
use crate::calib::error::CalibError;
use crate::calib::problem::data::{CameraPair, Candidate, StereoData};
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::target::Target;
use crate::calib::solvers::block::BlockNormalEquations;
use crate::calib::solvers::lm::{LeastSquares, LmOptions, LmReport, levenberg_marquardt_observed};
use crate::model::{Ports, Rig};

/// One stage of a calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Stage {
    /// What ran (`target poses`, `global search (affine-grid, 1262 axes)`, `refine axis
    /// (affine-grid)`, `air layer (linear least squares on the ray gaps)`, `maximum likelihood
    /// from …`).
    pub name: String,
    /// The first port's axis and air distance at its end (its frame), when the stage moves it.
    pub port: Option<Candidate>,
    /// The cost it minimised, at its end.
    pub cost: f64,
    /// The cost's unit.
    pub unit: &'static str,
    /// Iterations (or grid cells).
    pub iterations: usize,
    /// Seconds spent.
    pub seconds: f64,
}

impl Stage {
    /// A stage that ended at `port` with `cost`, started at `since`.
    pub fn at(
        name: &str,
        port: Candidate,
        cost: f64,
        unit: &'static str,
        iterations: usize,
        since: Instant,
    ) -> Self {
        Self {
            name: name.into(),
            port: Some(port),
            cost,
            unit,
            iterations,
            seconds: since.elapsed().as_secs_f64(),
        }
    }
}

/// The camera pairs behind the shared port that saw the board together in [`MIN_VIEWS`] or more
/// views, prepared for the pair costs: none for a 3-D target or a port per camera.
pub(super) fn shared_board_pairs(
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
) -> Result<Vec<StereoData>, CalibError> {
    let (Ports::Shared(_), Some(board)) = (rig.ports(), target.board()) else {
        return Ok(Vec::new());
    };
    let n = rig.cameras().len();
    let mut pairs = Vec::new();
    for a in 0..n {
        for b in a + 1..n {
            let data = StereoData::new(rig, CameraPair::new(a, b), board, seen)?;
            if data.views.len() >= MIN_VIEWS {
                pairs.push(data);
            }
        }
    }
    Ok(pairs)
}

/// The maximum-likelihood fit that ended a method: the optimiser's report, the normal equations
/// at the result (for the covariance) and the global parameters they are over.
pub(super) struct Fit {
    pub report: LmReport,
    pub normal: Option<BlockNormalEquations>,
    pub globals: Vec<Parameter>,
}

/// The outcome of the estimate: the state reached, the maximum-likelihood fit if one ran, what ran in words,
/// and the camera pair whose consecutive result started it.
pub(super) struct Outcome {
    pub state: State,
    pub fit: Option<Fit>,
    pub strategy: String,
    pub pair: Option<CameraPair>,
}

/// What the steps share: the problem, the options, and where the stages, warnings and progress
/// go.
pub(super) struct Steps<'a> {
    pub rig: &'a Rig,
    pub target: &'a Target,
    pub views: &'a [SeenView],
    /// Where the residual stencils of bundles over `views` run (`None`: the bundle's CPU code).
    pub residuals: Option<&'a dyn ResidualBackend>,
    pub options: &'a Options,
    pub stages: &'a mut Vec<Stage>,
    pub warnings: &'a mut Vec<String>,
    pub progress: &'a mut dyn FnMut(&Progress),
}

/// The start and the refinement of the method (steps 3 to 5 of the pipeline): the pinhole poses,
/// the ports' starts (the consecutive method over `pairs`, else the axis search), then maximum
/// likelihood from each start (none for the consecutive method).
pub(super) fn estimate(steps: &mut Steps, pairs: &[StereoData]) -> Result<Outcome, CalibError> {
    let (pinhole, rig_start) = target_poses(steps)?;
    let options = steps.options;
    let mut strategy = format!("{}: ", options.method.name());
    let (mut starts, pair) = port_starts(steps, pairs, &pinhole, &rig_start, &mut strategy)?;
    if options.method == Method::Consecutive {
        let (_, state) = starts.swap_remove(0);
        return Ok(Outcome {
            state,
            fit: None,
            strategy,
            pair,
        });
    }
    if starts.is_empty() {
        starts.push(("the rig's start guess".into(), rig_start));
    }
    let count = starts.len();
    let (state, fit) = maximum_likelihood(steps, &starts)?;
    strategy += &if count > 1 {
        format!(", maximum likelihood from {count} starts")
    } else {
        ", maximum likelihood".to_string()
    };
    Ok(Outcome {
        state,
        fit: Some(fit),
        strategy,
        pair,
    })
}

/// Step 3: each view's target pose by the pinhole model, and the same poses fitted through the
/// rig's start ports: (pinhole, rig start).
fn target_poses(steps: &mut Steps) -> Result<(State, State), CalibError> {
    let clock = Instant::now();
    let (rig, target, views) = (steps.rig, steps.target, steps.views);
    let pinhole = State::of(rig, poses::initial_poses(rig, target, views)?);
    let pose_only =
        Bundle::new(rig, target, views, Estimate::NOTHING, steps.options.huber).on(steps.residuals);
    let rig_start = fit_briefly(&pose_only, pinhole.clone(), poses::POSE_ITERATIONS);
    steps.stages.push(Stage {
        name: "target poses (pinhole, then through the start port)".into(),
        port: None,
        cost: rms(&pose_only, &rig_start),
        unit: "px",
        iterations: poses::POSE_ITERATIONS,
        seconds: clock.elapsed().as_secs_f64(),
    });
    Ok((pinhole, rig_start))
}

/// Named states the maximum-likelihood fit may start from, and the pair of cameras the
/// consecutive method chose.
type Starts = (Vec<(String, State)>, Option<CameraPair>);

/// Step 4: the named starts of the ports. The consecutive method over the pairs behind a shared
/// port (and for `auto` its pair's reprojection profile minimum and the rig's start too), else
/// the global axis search over each port; nothing when no port is estimated. Returns the starts
/// and the pair the consecutive method chose; `strategy` gets what ran.
fn port_starts(
    steps: &mut Steps,
    pairs: &[StereoData],
    pinhole: &State,
    rig_start: &State,
    strategy: &mut String,
) -> Result<Starts, CalibError> {
    let options = steps.options;
    let moves_ports = options.estimate.axis || options.estimate.distance;
    let use_pairs = !pairs.is_empty() && moves_ports;
    let mut starts: Vec<(String, State)> = Vec::new();
    let mut chosen = None;
    if use_pairs {
        match consecutive_start(steps, pinhole, pairs) {
            Ok((state, pair, profile)) => {
                chosen = Some(pair);
                let names = pair.map(|k| steps.rig.cameras()[k].name.as_str());
                *strategy += &format!(
                    "consecutive (thesis) over {} camera pair(s), best pair {}–{}",
                    pairs.len(),
                    names[0],
                    names[1]
                );
                starts.push(("the consecutive result".into(), state));
                if let Some(profile) = profile {
                    starts.push(("the reprojection profile's minimum".into(), profile));
                }
            }
            // The consecutive method takes the in-air extrinsics as given: a few mm off can leave
            // its linear air layer without a solution. Where they are estimated too, its failure
            // is no verdict on the data, and `auto` goes on from the axis search instead.
            Err(e)
                if options.method == Method::Auto
                    && options.estimate.axis
                    && options.estimate.extrinsics =>
            {
                // A fallback, not a finding: a stage of the report, not a warning.
                steps.stages.push(Stage {
                    name: format!(
                        "consecutive start: failed ({e}); the global axis search replaces it"
                    ),
                    port: None,
                    cost: f64::NAN,
                    unit: "px",
                    iterations: 0,
                    seconds: 0.0,
                });
            }
            Err(e) => return Err(e),
        }
    }
    if starts.is_empty() {
        if options.estimate.axis {
            starts.push((
                "the axis search's result".into(),
                axis_search(steps, rig_start.clone())?,
            ));
            *strategy += "pose per view, global search over each port's axis";
        } else {
            *strategy += "pose per view";
        }
    }
    // `auto` also starts from the rig's own guess: where the pairs' or the search's start is
    // poor (a port per camera searched one camera at a time, extrinsics estimated), the guess
    // itself may lead to the minimum, and the lowest cost wins anyway.
    if options.method == Method::Auto && (use_pairs || options.estimate.axis) {
        starts.push(("the rig's start guess".into(), rig_start.clone()));
    }
    Ok((starts, chosen))
}

/// The global search over each port's axis ([`search::search_axis`]), the poses refitted after.
/// With a port per camera and the extrinsics estimated, the extrinsics are linked again from
/// each camera's board poses through its own port found ([`relinked`]), where that explains the
/// corners better than the start's.
fn axis_search(steps: &mut Steps, start: State) -> Result<State, CalibError> {
    let clock = Instant::now();
    let (rig, target, views, options) = (steps.rig, steps.target, steps.views, steps.options);
    let mut state = start;
    // cam_from_target of every (view, camera), each camera's images fitted through its own port.
    let mut own_poses = vec![vec![None; rig.cameras().len()]; views.len()];
    for p in 0..state.ports.len() {
        let (next, poses) = search::search_axis(rig, target, views, state, p, options)?;
        state = next;
        for (row, pose) in own_poses.iter_mut().zip(poses) {
            row[p] = pose;
        }
    }
    let pose_only =
        Bundle::new(rig, target, views, Estimate::NOTHING, options.huber).on(steps.residuals);
    let mut state = fit_briefly(&pose_only, state, poses::POSE_ITERATIONS);
    let searched = rms(&pose_only, &state);
    steps.stages.push(Stage {
        name: "global axis search".into(),
        port: Some(first_port(&state)),
        cost: searched,
        unit: "px",
        iterations: 0,
        seconds: clock.elapsed().as_secs_f64(),
    });
    if matches!(rig.ports(), Ports::PerCamera(_))
        && options.estimate.extrinsics
        && let Some(relinked) = relinked(&state, &own_poses)
    {
        let clock = Instant::now();
        let relinked = fit_briefly(&pose_only, relinked, poses::POSE_ITERATIONS);
        let cost = rms(&pose_only, &relinked);
        // Kept where it explains the corners better than the start's extrinsics.
        if cost < searched || (cost.is_finite() && !searched.is_finite()) {
            steps.stages.push(Stage {
                name: "extrinsics linked again through the ports found".into(),
                port: Some(first_port(&relinked)),
                cost,
                unit: "px",
                iterations: poses::POSE_ITERATIONS,
                seconds: clock.elapsed().as_secs_f64(),
            });
            state = relinked;
        }
    }
    Ok(state)
}

/// `state` with the extrinsics linked again ([`link_poses`]) from `cam_from_target[view][camera]`,
/// each camera's board poses fitted to its own images through its own port, and every view's
/// target pose placed by the first camera of that view with a pose (the master where it saw the
/// view); cameras left unlinked keep their extrinsics. `None` when no camera but the master
/// links.
///
/// The start's extrinsics come from the pinhole poses of the *apparent* boards
/// ([`extrinsics_start`](super::extrinsics::extrinsics_start)); behind a port per camera each
/// camera's apparent board is compressed along its own axis, so cameras turned from each other
/// start degrees and centimetres off (zoo seed 7: 2–6°, 2–9 cm), and the maximum likelihood from
/// there stops at a wrong minimum. Through the ports the search found, the poses are near the
/// truth.
///
/// [`link_poses`]: super::extrinsics::link_poses
fn relinked(state: &State, cam_from_target: &[Vec<Option<Isometry3<f64>>>]) -> Option<State> {
    let n = state.extrinsics.len();
    let (cam_from_master, links) = super::extrinsics::link_poses(cam_from_target, n);
    if links.iter().skip(1).all(Option::is_none) {
        return None;
    }
    let mut next = state.clone();
    for (k, link) in links.iter().enumerate().skip(1) {
        if link.is_some() {
            next.extrinsics[k] = cam_from_master[k];
        }
    }
    for (pose, row) in next.poses.iter_mut().zip(cam_from_target) {
        let seen = (0..n).find(|&k| links[k].is_some() && row.get(k).copied().flatten().is_some());
        if let Some(k) = seen
            && let Some(cam_from_target) = row[k]
        {
            *pose = next.extrinsics[k].inverse() * cam_from_target;
        }
    }
    Some(next)
}

/// `state` with the target pose of every view whose corners it cannot project placed again:
/// the pinhole pose of the corners' directions bent into the water at the state's own ports
/// ([`poses::water_poses`]), then every pose fitted briefly; with how many views were placed.
///
/// A view's pose comes from the pinhole pose of its pixels (the *apparent* board, nearer and
/// wider than the board in the water), fitted through the start port; where that port carries a
/// corner outside the lens (a wide lens seeing the board near its edge: zoo seed 41, k1 = −0.21)
/// no fit can start, and every start of the maximum likelihood would be undefined. The state is
/// returned as it was when every view is defined, or when placing them again does not make the
/// cost defined.
fn with_defined_poses(steps: &Steps, state: State) -> (State, usize) {
    let pose_only = Bundle::new(
        steps.rig,
        steps.target,
        steps.views,
        Estimate::NOTHING,
        steps.options.huber,
    )
    .on(steps.residuals);
    poses::place_undefined_views(&pose_only, steps.rig, steps.target, steps.views, state)
}

/// Step 5: maximum likelihood from each named start; the lowest cost wins. A start that does not
/// explain every corner is skipped with a warning; one that ends nearly as low far away, and a
/// fit that stops early, are warnings.
fn maximum_likelihood(
    steps: &mut Steps,
    starts: &[(String, State)],
) -> Result<(State, Fit), CalibError> {
    let options = steps.options;
    let full = Bundle::new(
        steps.rig,
        steps.target,
        steps.views,
        options.estimate,
        options.huber,
    )
    .on(steps.residuals)
    .with_lens_prior(options.lens_prior.as_ref());
    let lm = LmOptions {
        max_iterations: options.max_iterations,
        ..LmOptions::default()
    };
    let residuals = full.residuals();
    let report_rms = |cost: f64| (2.0 * cost / residuals as f64).sqrt();
    let mut best: Option<(State, LmReport, Option<BlockNormalEquations>)> = None;
    let mut finals = Vec::new();
    for (name, start) in starts {
        // A start is a guess: where it leaves a camera without air, the port moves out to it.
        let (raised, _) = start.clone().feasible();
        let moved: Vec<String> = (raised.ports.iter().zip(&start.ports).enumerate())
            .filter(|(_, (a, b))| a.distance != b.distance)
            .map(|(p, (a, _))| {
                let port = match steps.rig.ports() {
                    Ports::Shared(_) => "its port".to_string(),
                    Ports::PerCamera(_) => format!("port {}", steps.rig.cameras()[p].name),
                };
                format!("{port} moved out to {:.1} mm of air", a.distance * 1e3)
            })
            .collect();
        let start = raised;
        let name = if moved.is_empty() {
            name.clone()
        } else {
            format!(
                "{name} ({}, to leave every camera in the air)",
                moved.join(", ")
            )
        };
        let defined = |state: &State| full.cost(state).is_some_and(f64::is_finite);
        // Only an undefined start has views to place again (one residual pass otherwise).
        let (start, name) = if defined(&start) {
            (start, name)
        } else {
            match with_defined_poses(steps, start) {
                (start, 0) => (start, name),
                (start, placed) => (
                    start,
                    format!(
                        "{name} ({placed} view(s) placed again by their corners' directions in the water)"
                    ),
                ),
            }
        };
        let start = &start;
        if !defined(start) {
            // Other starts follow (and no start at all is an error below): a stage, not a warning.
            let port = first_port(start);
            steps.stages.push(Stage {
                name: format!(
                    "{name}: does not explain every corner (a target behind the port, or a camera outside the air), not used as a start"
                ),
                port: Some(port),
                cost: f64::NAN,
                unit: "px",
                iterations: 0,
                seconds: 0.0,
            });
            continue;
        }
        let clock = Instant::now();
        let stage_name = format!("maximum likelihood from {name}");
        let progress = &mut *steps.progress;
        let (state, report, normal) =
            levenberg_marquardt_observed(&full, start.clone(), &lm, &mut |i| {
                progress(&Progress {
                    stage: &stage_name,
                    done: i.iteration,
                    total: None,
                    cost: report_rms(i.cost),
                    unit: "px",
                })
            });
        steps.stages.push(Stage {
            name: format!("{stage_name} ({})", report.termination.describe()),
            port: Some(first_port(&state)),
            cost: report_rms(report.final_cost),
            unit: "px",
            iterations: report.iterations,
            seconds: clock.elapsed().as_secs_f64(),
        });
        finals.push((name.clone(), first_port(&state), report.final_cost));
        if best
            .as_ref()
            .is_none_or(|(_, r, _)| report.final_cost < r.final_cost)
        {
            best = Some((state, report, normal));
        }
    }
    let (state, report, normal) =
        best.ok_or_else(|| consecutive::no_solution(options, "no start explains every corner"))?;
    let best_port = first_port(&state);
    for (name, port, cost) in &finals {
        let apart = port.normal.angle(&best_port.normal).to_degrees();
        // A start that ends in a clearly worse minimum only shows the cost has several; one
        // that ends nearly as low elsewhere makes the answer ambiguous.
        if *cost < report.final_cost * 1.5 && apart > 0.5 {
            steps.warnings.push(format!(
                "the refinement from {name} ended {apart:.2}° away at a cost only ×{:.2} higher: the data hardly tell the two axes apart",
                cost / report.final_cost.max(f64::MIN_POSITIVE)
            ));
        }
    }
    if !report.termination.converged() {
        steps.warnings.push(format!(
            "the maximum-likelihood refinement stopped early: {}",
            report.termination.describe()
        ));
    }
    let globals = full.globals().to_vec();
    Ok((
        state,
        Fit {
            report,
            normal,
            globals,
        },
    ))
}

/// The first port's axis and air distance in `state`.
pub(super) fn first_port(state: &State) -> Candidate {
    Candidate {
        normal: state.ports[0].normal,
        air_distance: state.ports[0].distance,
    }
}

/// The thesis' consecutive method on every pair (its cost batches on the options' backend); each
/// pair's axis and air distance is tried as the start of the whole rig and the one that explains
/// every corner best wins. Returns that state, its pair and, for `auto`, the state at the minimum
/// of that pair's reprojection profile.
fn consecutive_start(
    steps: &mut Steps,
    pinhole: &State,
    pairs: &[StereoData],
) -> Result<(State, CameraPair, Option<State>), CalibError> {
    let (rig, target, views, options) = (steps.rig, steps.target, steps.views, steps.options);
    let pose_only =
        Bundle::new(rig, target, views, Estimate::NOTHING, options.huber).on(steps.residuals);
    // The rig behind a pair's candidate port, its target poses from the pair's corners
    // triangulated under it and fitted rigidly (the views the pair did not see keep the pinhole
    // poses), then fitted through the port over every camera.
    let at = |candidate: &Candidate, data: &StereoData| {
        let mut state = pinhole.clone();
        state.ports[0].normal = candidate.normal;
        state.ports[0].distance = candidate.air_distance;
        if let Some(fit) = data
            .cameras_behind(candidate)
            .and_then(|cameras| SceneFit::new(data, &cameras))
        {
            for (pose, &v) in fit.poses().into_iter().zip(&data.view_numbers) {
                state.poses[v] = pose;
            }
        }
        fit_briefly(&pose_only, state, poses::POSE_ITERATIONS)
    };
    let mut best: Option<(f64, State, usize)> = None;
    let mut last_error = None;
    let several = pairs.len() > 1;
    for (p, data) in pairs.iter().enumerate() {
        let backend = options.backend.over(data);
        let mut pair_stages = Vec::new();
        let candidate = match consecutive::consecutive_estimate(
            backend.as_ref(),
            options,
            &mut pair_stages,
            steps.progress,
        ) {
            Ok(c) => c,
            Err(e) => {
                last_error = Some(e);
                continue;
            }
        };
        if several {
            let name = data
                .cameras
                .map(|k| rig.cameras()[k].name.clone())
                .join("–");
            for stage in &mut pair_stages {
                stage.name = format!("{} [{name}]", stage.name);
            }
        }
        steps.stages.extend(pair_stages);
        let state = at(&candidate, data);
        let cost = rms(&pose_only, &state);
        if best.as_ref().is_none_or(|(c, _, _)| cost < *c) {
            best = Some((cost, state, p));
        }
    }
    let Some((_, state, p)) = best else {
        return Err(last_error.unwrap_or_else(|| {
            CalibError::Options(
                "no pair of cameras shares enough views of the board for the consecutive method"
                    .into(),
            )
        }));
    };
    let profile = if options.method == Method::Auto {
        let backend = options.backend.over(&pairs[p]);
        let candidate =
            consecutive::profile_minimum(backend.as_ref(), options, steps.stages, steps.progress)?;
        Some(at(&candidate, &pairs[p]))
    } else {
        None
    };
    Ok((state, pairs[p].cameras, profile))
}
