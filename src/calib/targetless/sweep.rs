//! The targetless cost over a grid of ports, so a user sees the well (`flatport sweep --images DIR
//! --rig RIG.json --targetless`): each cell's port is the master's (a shared port, or the
//! master camera's own housing) with the cell's axis (tilt from the master's z, azimuth
//! atan2(n_y, n_x)) and air distance, the other cameras' ports as in the rig. Its cost is the
//! maximum-likelihood profile of the matches ([`start::track_costs`]: every track's point fitted
//! alone under that port), trimmed and written as an RMS reprojection error in px:
//! √(Σ_{best 90 % of tracks} c_t / (2 · their observations)), c_t = min_X Σ_obs |π(X) − p|².
//!
//! Why trimmed: a few per cent of the matches are wrong (the fit drops 2–3 % as outliers on the
//! rendered scenes), and each costs up to its truncation (16 px² per observation) whatever the
//! port, so a plain sum puts a floor of ~0.2 px under a well whose bottom is the matching noise
//! (~0.01 px): the well would show only a few per cent of relief. The best 90 % leave the wrong
//! matches out at every cell near the well, and the cost is still continuous in the port.

use rayon::prelude::*;

use crate::calib::error::CalibError;
use crate::calib::sweep::{SweepChunk, SweepMinimum, SweepSpec, SweepSummary};
use crate::calib::targetless::fit::Track;
use crate::calib::targetless::start::{self, with_port};
use crate::model::{Ports, Rig, normal_from_tilt_azimuth};

/// Tracks a targetless sweep evaluates (spread evenly over those matched): a cell's cost is
/// linear in them, and a thousand put the well's bottom far below the grid spacings worth
/// sweeping (a full fit on ~2 000 tracks has σ ≈ 0.004° and 0.2 mm).
pub const SWEEP_TRACKS: usize = 1000;

/// Share of the tracks (the best, by their profile cost) the sweep's cost is made of.
pub const KEPT_SHARE: f64 = 0.9;

/// The targetless cost of one port: the trimmed RMS reprojection error (px) of `tracks` with
/// every point fitted alone under `rig`, over the best [`KEPT_SHARE`] of them; +∞ without tracks.
pub fn profile_rms_px(rig: &Rig, tracks: &[Track]) -> f64 {
    let mut costs: Vec<(f64, usize)> = start::track_costs(rig, tracks)
        .into_iter()
        .zip(tracks.iter().map(|t| t.pixels.len()))
        .collect();
    costs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let kept = ((tracks.len() as f64 * KEPT_SHARE).ceil() as usize).min(costs.len());
    let (sum, observations) = costs[..kept]
        .iter()
        .fold((0.0, 0usize), |(s, n), (c, o)| (s + c, n + o));
    if observations == 0 {
        return f64::INFINITY;
    }
    (sum / (2 * observations) as f64).sqrt()
}

/// `rig` with the master's port (the shared one, or camera 0's own, in its frame: the master
/// frame) at `tilt`, `azimuth` (radians) and `distance` (metres); `None` when that is no valid
/// rig.
fn candidate(rig: &Rig, tilt: f64, azimuth: f64, distance: f64) -> Option<Rig> {
    let port = match rig.ports() {
        Ports::Shared(p) => p,
        Ports::PerCamera(ports) => ports.first()?,
    };
    let moved = port
        .with_pose(
            normal_from_tilt_azimuth(tilt, azimuth).into_inner(),
            distance,
        )
        .ok()?;
    with_port(rig, 0, moved)
}

/// Sweeps the targetless cost of `tracks` over `spec`'s grid, which must have a distance grid
/// (the cost has no linear air-layer profile): cells in row-major order [tilt, azimuth,
/// distance], handed to `sink` one axis cell (all its air distances) at a time, `progress(done,
/// total)` after each. A cell whose port is no valid rig (a camera outside the air) costs +∞.
/// `spec.kind` is not used.
pub fn sweep_targetless(
    rig: &Rig,
    tracks: &[Track],
    spec: &SweepSpec,
    sink: &mut dyn FnMut(SweepChunk) -> Result<(), CalibError>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SweepSummary, CalibError> {
    spec.validate()?;
    let Some(distances) = spec.distance else {
        return Err(CalibError::Options(
            "the targetless cost needs a distance grid (--distance START:STOP:COUNT): it has no linear air-layer profile".into(),
        ));
    };
    let started = std::time::Instant::now();
    let depth = distances.count;
    let total = spec.cells();
    let mut minimum: Option<SweepMinimum> = None;
    let mut finite = 0;
    let values = distances.values();
    for axis in 0..spec.axes() {
        let first = axis * depth;
        let (tilt_deg, azimuth_deg) = spec.cell_angles_deg(first);
        let costs: Vec<f64> = values
            .par_iter()
            .map(|&d| {
                candidate(rig, tilt_deg.to_radians(), azimuth_deg.to_radians(), d)
                    .map_or(f64::INFINITY, |r| profile_rms_px(&r, tracks))
            })
            .collect();
        for (k, &cost) in costs.iter().enumerate() {
            if cost.is_finite() {
                finite += 1;
                if minimum.is_none_or(|m| cost < m.cost) {
                    minimum = Some(SweepMinimum {
                        cell: first + k,
                        tilt_deg,
                        azimuth_deg,
                        distance: values[k],
                        cost,
                    });
                }
            }
        }
        sink(SweepChunk {
            first,
            costs: &costs,
            distances: &values,
        })?;
        progress(first + depth, total);
    }
    Ok(SweepSummary {
        minimum,
        cells: total,
        finite,
        seconds: started.elapsed().as_secs_f64(),
    })
}
