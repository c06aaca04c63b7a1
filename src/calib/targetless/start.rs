//! The start of a targetless fit: a search over each port's axis (a cap of 20° around the guess)
//! and air distance (a factor of 1/4 … 8 of the guess) by the maximum-likelihood profile cost
//! (every track's point fitted alone under the candidate port, its reprojection error summed,
//! truncated at a few pixels so that outliers do not steer it).
//!
//! Why: the joint fit from a naive guess far from the truth (8° of tilt, 40 mm of air off) slides
//! down a valley toward a zero air layer, where the cameras leave the air; the profile is defined
//! for every candidate and its grid minimum lies in the right basin. A rig with a port per camera
//! is searched port by port, twice (coordinate descent).

use nalgebra::{Matrix3, Point3, Vector2, Vector3};
use rayon::prelude::*;

use crate::calib::pipeline::bundle::{Estimate, MIN_START_AIR_M};
use crate::calib::solvers::search::tangent_step;
use crate::calib::targetless::fit::Track;
use crate::model::{Interface, Ports, RefractiveCamera, Rig, triangulate_rays};

/// Squared residual (px²) at which a track's profile cost is truncated.
const TRUNCATE_PX2: f64 = 16.0;
/// Tracks the search evaluates (spread evenly over the tracks).
pub const SEARCH_TRACKS: usize = 300;
/// Whether every camera of `rig` is at least [`MIN_START_AIR_M`] (1 mm) from its port: a start
/// closer than a difference step (1 µm) leaves the fit's derivatives undefined.
pub fn clear_of_the_port(rig: &Rig) -> bool {
    (0..rig.cameras().len()).all(|k| rig.refractive_camera(k).air_distance() >= MIN_START_AIR_M)
}

/// Track `t`'s least reprojection cost (px², truncated) over its point under `cameras`: the
/// point triangulated from its first two rays, then four Gauss–Newton steps.
fn track_profile(cameras: &[RefractiveCamera], track: &Track) -> f64 {
    let cap = TRUNCATE_PX2 * track.pixels.len() as f64;
    let residuals = |x: &Point3<f64>| -> Option<Vec<Vector2<f64>>> {
        track
            .pixels
            .iter()
            .map(|(k, p)| Some(cameras[*k].project(x).ok()? - p))
            .collect()
    };
    let start = (|| {
        let (ka, pa) = track.pixels[0];
        let (kb, pb) = track.pixels[1];
        let a = cameras[ka].backproject(&pa).ok()?;
        let b = cameras[kb].backproject(&pb).ok()?;
        Some(triangulate_rays(&a, &b).ok()?.point)
    })();
    let Some(mut x) = start else {
        return cap;
    };
    let cost = |r: &[Vector2<f64>]| r.iter().map(|e| e.norm_squared()).sum::<f64>();
    let Some(mut r) = residuals(&x) else {
        return cap;
    };
    let h = 1e-6;
    for _ in 0..4 {
        let columns: Option<Vec<Vec<Vector2<f64>>>> = (0..3)
            .map(|axis| {
                let mut step = Vector3::zeros();
                step[axis] = h;
                let plus = residuals(&(x + step))?;
                let minus = residuals(&(x - step))?;
                Some(
                    plus.iter()
                        .zip(&minus)
                        .map(|(p, m)| (p - m) / (2.0 * h))
                        .collect(),
                )
            })
            .collect();
        let Some(columns) = columns else {
            return cost(&r).min(cap);
        };
        let mut jtj = Matrix3::zeros();
        let mut jtr = Vector3::zeros();
        for a in 0..3 {
            jtr[a] = columns[a].iter().zip(&r).map(|(u, e)| u.dot(e)).sum();
            for b in 0..3 {
                jtj[(a, b)] = columns[a]
                    .iter()
                    .zip(&columns[b])
                    .map(|(u, v)| u.dot(v))
                    .sum();
            }
        }
        let Some(step) = jtj.cholesky().map(|c| c.solve(&(-jtr))) else {
            break;
        };
        let moved = x + step;
        match residuals(&moved) {
            Some(next) if cost(&next) <= cost(&r) => {
                x = moved;
                r = next;
            }
            _ => break,
        }
    }
    cost(&r).min(cap)
}

/// Every track's least reprojection cost (px²) with its point fitted alone under `rig`,
/// truncated at 16 px² per observation, in track order.
pub fn track_costs(rig: &Rig, tracks: &[Track]) -> Vec<f64> {
    let cameras: Vec<RefractiveCamera> = (0..rig.cameras().len())
        .map(|k| rig.refractive_camera(k))
        .collect();
    tracks
        .par_iter()
        .map(|t| track_profile(&cameras, t))
        .collect()
}

/// The profile cost of `rig` over `tracks`: the sum of their [`track_costs`] (px²).
pub fn profile(rig: &Rig, tracks: &[Track]) -> f64 {
    track_costs(rig, tracks).iter().sum()
}

fn ports_of(rig: &Rig) -> Vec<Interface> {
    match rig.ports() {
        Ports::Shared(p) => vec![p.clone()],
        Ports::PerCamera(p) => p.clone(),
    }
}

/// `rig` with port `p` (its shared port, or camera `p`'s own) replaced by `port`; `None` when that
/// is not a valid rig (a camera outside the air).
pub fn with_port(rig: &Rig, p: usize, port: Interface) -> Option<Rig> {
    let ports = match rig.ports() {
        Ports::Shared(_) => Ports::Shared(port),
        Ports::PerCamera(ports) => {
            let mut ports = ports.clone();
            ports[p] = port;
            Ports::PerCamera(ports)
        }
    };
    rig.with_new_ports(ports).ok()
}

/// At most `count` of `tracks`, spread evenly over them (every ⌈len / count⌉-th).
pub fn spread(tracks: &[Track], count: usize) -> Vec<Track> {
    let stride = tracks.len().div_ceil(count.max(1)).max(1);
    tracks.iter().step_by(stride).cloned().collect()
}

/// The best start found from `rig` for `tracks`, with its profile cost per track, and the
/// candidates evaluated.
pub fn search_start(rig: &Rig, tracks: &[Track], estimate: Estimate) -> (Rig, f64, usize) {
    let (mut starts, evaluated) = search_starts(rig, tracks, estimate, 1);
    let (best, cost) = starts.swap_remove(0);
    (best, cost, evaluated)
}

/// How far apart two starts are: the largest angle between their ports' axes (radians) and the
/// largest |ln| of their air distances' ratio.
fn apart(a: &Rig, b: &Rig) -> (f64, f64) {
    ports_of(a)
        .iter()
        .zip(ports_of(b))
        .map(|(p, q)| {
            (
                p.normal().dot(q.normal()).clamp(-1.0, 1.0).acos(),
                (p.air_distance() / q.air_distance()).ln().abs(),
            )
        })
        .fold((0.0, 0.0), |(x, y), (u, v)| {
            (f64::max(x, u), f64::max(y, v))
        })
}

/// Starts that count as distinct basins of the profile: axes more than 2° apart or air distances
/// more than 1.4× apart.
fn distinct(a: &Rig, b: &Rig) -> bool {
    let (angle, ratio) = apart(a, b);
    angle > 2f64.to_radians() || ratio > 1.4f64.ln()
}

/// The `count` best distinct starts found from `rig` for `tracks` (best first, each with its
/// profile cost per track; at least one, `rig` itself when nothing better is found) and the
/// candidates evaluated. The profile's grid minimum can lie in a neighbouring basin of the
/// likelihood (a far scene with one near object makes its valley uneven): the fit refines a few
/// distinct grid minima, not only the best.
pub fn search_starts(
    rig: &Rig,
    tracks: &[Track],
    estimate: Estimate,
    count: usize,
) -> (Vec<(Rig, f64)>, usize) {
    let sample = spread(tracks, SEARCH_TRACKS);
    let n = sample.len().max(1) as f64;
    let mut best_rig = rig.clone();
    let mut best = if clear_of_the_port(rig) {
        profile(rig, &sample)
    } else {
        f64::INFINITY
    };
    let mut evaluated = 1;
    // Every candidate of the last port's last round, with its cost.
    let mut last: Vec<(Rig, f64)> = vec![(rig.clone(), best)];
    let guesses = ports_of(rig);
    let mut offsets = vec![Vector2::zeros()];
    if estimate.axis {
        for ring in 1..=8 {
            let tilt = (2.5 * f64::from(ring)).to_radians();
            let around = 4 * ring.min(4);
            for s in 0..around {
                let azimuth = std::f64::consts::TAU * f64::from(s) / f64::from(around);
                offsets.push(Vector2::new(tilt * azimuth.cos(), tilt * azimuth.sin()));
            }
        }
    }
    let factors: &[f64] = if estimate.distance {
        &[0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0]
    } else {
        &[1.0]
    };
    let rounds = if guesses.len() > 1 { 2 } else { 1 };
    for _ in 0..rounds {
        for (p, guess) in guesses.iter().enumerate() {
            let candidates: Vec<Rig> = offsets
                .iter()
                .flat_map(|o| factors.iter().map(move |f| (o, f)))
                .filter_map(|(o, f)| {
                    let port = guess
                        .with_pose(
                            tangent_step(guess.normal(), o).into_inner(),
                            guess.air_distance() * f,
                        )
                        .ok()?;
                    with_port(&best_rig, p, port).filter(clear_of_the_port)
                })
                .collect();
            evaluated += candidates.len();
            let costs: Vec<f64> = candidates.iter().map(|r| profile(r, &sample)).collect();
            if let Some((i, c)) = costs.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))
                && *c < best
            {
                best = *c;
                best_rig = candidates[i].clone();
            }
            last = candidates.into_iter().zip(costs).collect();
        }
    }
    last.retain(|(_, c)| c.is_finite());
    last.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut chosen: Vec<(Rig, f64)> = vec![(best_rig, best / n)];
    for (candidate, cost) in last {
        if chosen.len() >= count {
            break;
        }
        if chosen.iter().all(|(c, _)| distinct(c, &candidate)) {
            chosen.push((candidate, cost / n));
        }
    }
    (chosen, evaluated)
}
