//! Cost-surface sweeps: a cost over a grid of axes (tilt × azimuth) and optionally air layers,
//! evaluated in chunks of candidates through a [`CostBackend`], streamed to a sink so memory stays
//! bounded whatever the grid size.
//!
//! Cell order is row-major over [tilt, azimuth] or [tilt, azimuth, distance]. Without a distance
//! grid each axis cell takes the air layer of the profile ([`CostBackend::profile`]): the linear
//! least-squares air layer for costs that need one, none for the axis-only invariants.

use std::time::Instant;

use super::backend::CostBackend;
use super::costs::CostKind;
use super::data::Candidate;
use super::error::CalibError;
use crate::model::normal_from_tilt_azimuth;

/// `count` values from `start` to `stop`, both included (numpy's `linspace`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Linspace {
    /// First value.
    pub start: f64,
    /// Last value (equal to `start` when `count` is 1).
    pub stop: f64,
    /// Number of values (≥ 1).
    pub count: usize,
}

impl Linspace {
    /// Value `i`: start + i·(stop − start)/(count − 1).
    pub fn value(&self, i: usize) -> f64 {
        if self.count <= 1 { self.start } else { self.start + (self.stop - self.start) * i as f64 / (self.count - 1) as f64 }
    }

    /// Every value.
    pub fn values(&self) -> Vec<f64> {
        (0..self.count).map(|i| self.value(i)).collect()
    }

    /// Spacing between neighbours (0 for a single value).
    pub fn step(&self) -> f64 {
        if self.count <= 1 { 0.0 } else { (self.stop - self.start) / (self.count - 1) as f64 }
    }
}

/// What to sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepSpec {
    /// The cost.
    pub kind: CostKind,
    /// Tilt of the axis from the master camera's z axis, degrees.
    pub tilt_deg: Linspace,
    /// Azimuth atan2(n_y, n_x), degrees.
    pub azimuth_deg: Linspace,
    /// Air layers (metres); `None` for the profile.
    pub distance: Option<Linspace>,
}

impl SweepSpec {
    /// Checks the grid: counts ≥ 1, tilts in [0°, 80°), positive air layers.
    pub fn validate(&self) -> Result<(), CalibError> {
        let bad = |what: &str| Err(CalibError::Options(what.to_string()));
        if self.tilt_deg.count == 0 || self.azimuth_deg.count == 0 || self.distance.is_some_and(|d| d.count == 0) {
            return bad("every grid needs at least one value (COUNT ≥ 1)");
        }
        for t in [self.tilt_deg.start, self.tilt_deg.stop] {
            if !(0.0..80.0).contains(&t) {
                return bad(&format!("tilts must lie in [0°, 80°): got {t}°"));
            }
        }
        if !(self.azimuth_deg.start.is_finite() && self.azimuth_deg.stop.is_finite()) {
            return bad("azimuths must be finite");
        }
        if let Some(d) = self.distance {
            if !(d.start > 0.0 && d.stop > 0.0 && d.start.is_finite() && d.stop.is_finite()) {
                return bad(&format!("air layers must be positive: got {}:{}", d.start, d.stop));
            }
        }
        Ok(())
    }

    /// Grid shape: [tilt, azimuth] or [tilt, azimuth, distance].
    pub fn shape(&self) -> Vec<usize> {
        let mut shape = vec![self.tilt_deg.count, self.azimuth_deg.count];
        if let Some(d) = self.distance {
            shape.push(d.count);
        }
        shape
    }

    /// Number of cells.
    pub fn cells(&self) -> usize {
        self.shape().iter().product()
    }

    /// Number of axis cells (tilt × azimuth).
    pub fn axes(&self) -> usize {
        self.tilt_deg.count * self.azimuth_deg.count
    }
}

/// The best cell of a sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepMinimum {
    /// Index of the cell in row-major order.
    pub cell: usize,
    /// Its tilt, degrees.
    pub tilt_deg: f64,
    /// Its azimuth, degrees.
    pub azimuth_deg: f64,
    /// Its air layer (the grid's, or the profile's; NaN for axis-only costs without a grid).
    pub distance: f64,
    /// Its cost.
    pub cost: f64,
}

/// A chunk of results handed to the sink: cells `first..first + costs.len()` in row-major order.
#[derive(Debug)]
pub struct SweepChunk<'a> {
    /// Index of the first cell.
    pub first: usize,
    /// Cost per cell (+∞ where the candidate explains no corner).
    pub costs: &'a [f64],
    /// Air layer per cell: the grid value, the profile's, or NaN for axis-only costs.
    pub distances: &'a [f64],
}

/// What a sweep measured.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepSummary {
    /// The lowest finite cost, `None` when no cell has one.
    pub minimum: Option<SweepMinimum>,
    /// Cells evaluated.
    pub cells: usize,
    /// Cells with a finite cost.
    pub finite: usize,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Sweeps `spec` over `backend`, `chunk` axis cells per backend call (the backend chunks further
/// for the device). Calls `sink` with every chunk in order and `progress(done, total)` after each.
pub fn sweep(
    backend: &dyn CostBackend,
    spec: &SweepSpec,
    chunk: usize,
    sink: &mut dyn FnMut(SweepChunk) -> Result<(), CalibError>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SweepSummary, CalibError> {
    spec.validate()?;
    let started = Instant::now();
    let (tilts, azimuths) = (spec.tilt_deg, spec.azimuth_deg);
    let depth = spec.distance.map_or(1, |d| d.count);
    let total = spec.cells();
    let axes = spec.axes();
    let chunk = chunk.max(1);
    let mut minimum: Option<SweepMinimum> = None;
    let mut finite = 0;
    let mut axis = 0;
    while axis < axes {
        let end = (axis + chunk).min(axes);
        let normals: Vec<_> = (axis..end)
            .map(|a| normal_from_tilt_azimuth(tilts.value(a / azimuths.count).to_radians(), azimuths.value(a % azimuths.count).to_radians()))
            .collect();
        let (costs, distances) = match spec.distance {
            None => {
                let (candidates, costs) = backend.profile(spec.kind, &normals)?;
                (costs, candidates.iter().map(|c| c.air_distance).collect::<Vec<_>>())
            }
            Some(grid) if spec.kind.axis_only() => {
                // The air layer does not enter: one evaluation per axis, repeated along d.
                let candidates: Vec<Candidate> = normals.iter().map(|n| Candidate { normal: *n, air_distance: f64::NAN }).collect();
                let per_axis = backend.costs(spec.kind, &candidates)?;
                let costs = per_axis.iter().flat_map(|&c| std::iter::repeat_n(c, depth)).collect();
                (costs, normals.iter().flat_map(|_| grid.values()).collect())
            }
            Some(grid) => {
                let candidates: Vec<Candidate> =
                    normals.iter().flat_map(|n| grid.values().into_iter().map(move |d| Candidate { normal: *n, air_distance: d })).collect();
                let costs = backend.costs(spec.kind, &candidates)?;
                (costs, candidates.iter().map(|c| c.air_distance).collect())
            }
        };
        let first = axis * depth;
        for (k, &cost) in costs.iter().enumerate() {
            if cost.is_finite() {
                finite += 1;
                if minimum.is_none_or(|m| cost < m.cost) {
                    let cell = first + k;
                    let a = cell / depth;
                    minimum = Some(SweepMinimum {
                        cell,
                        tilt_deg: tilts.value(a / azimuths.count),
                        azimuth_deg: azimuths.value(a % azimuths.count),
                        distance: distances[k],
                        cost,
                    });
                }
            }
        }
        sink(SweepChunk { first, costs: &costs, distances: &distances })?;
        axis = end;
        progress(axis * depth, total);
    }
    Ok(SweepSummary { minimum, cells: total, finite, seconds: started.elapsed().as_secs_f64() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linspace_includes_both_ends() {
        let l = Linspace { start: -180.0, stop: 180.0, count: 5 };
        assert_eq!(l.values(), vec![-180.0, -90.0, 0.0, 90.0, 180.0]);
        assert_eq!(Linspace { start: 3.0, stop: 9.0, count: 1 }.values(), vec![3.0]);
    }
}
