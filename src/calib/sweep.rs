//! Cost-surface sweeps: a cost over a grid of axes (tilt × azimuth) and optionally air layers,
//! evaluated in chunks of candidates through a [`CostBackend`], streamed to a sink so memory stays
//! bounded whatever the grid size.
//!
//! Cell order is row-major over [tilt, azimuth] or [tilt, azimuth, distance]. Without a distance
//! grid each axis cell takes the air layer of the profile ([`CostBackend::profile`]): the linear
//! least-squares air layer for costs that need one, none for the axis-only invariants.

use std::ops::Range;
use std::time::Instant;

use crate::calib::backends::CostBackend;
use crate::calib::costs::CostKind;
use crate::calib::error::CalibError;
use crate::calib::problem::data::Candidate;
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
        if self.count <= 1 {
            self.start
        } else {
            self.start + (self.stop - self.start) * i as f64 / (self.count - 1) as f64
        }
    }

    /// Every value.
    pub fn values(&self) -> Vec<f64> {
        (0..self.count).map(|i| self.value(i)).collect()
    }

    /// Spacing between neighbours (0 for a single value).
    pub fn step(&self) -> f64 {
        if self.count <= 1 {
            0.0
        } else {
            (self.stop - self.start) / (self.count - 1) as f64
        }
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
    /// Checks the grid: counts ≥ 1, at most [`MAX_SWEEP_CELLS`] cells, tilts in [0°, 80°),
    /// positive air layers.
    pub fn validate(&self) -> Result<(), CalibError> {
        let bad = |what: &str| Err(CalibError::Options(what.to_string()));
        if self.tilt_deg.count == 0
            || self.azimuth_deg.count == 0
            || self.distance.is_some_and(|d| d.count == 0)
        {
            return bad("every grid needs at least one value (COUNT ≥ 1)");
        }
        if self
            .checked_cells()
            .is_none_or(|cells| cells > MAX_SWEEP_CELLS)
        {
            return bad(&too_many_cells(&self.shape()));
        }
        for t in [self.tilt_deg.start, self.tilt_deg.stop] {
            if !(0.0..80.0).contains(&t) {
                return bad(&format!("tilts must lie in [0°, 80°): got {t}°"));
            }
        }
        if !(self.azimuth_deg.start.is_finite() && self.azimuth_deg.stop.is_finite()) {
            return bad("azimuths must be finite");
        }
        if let Some(d) = self.distance
            && !(d.start > 0.0 && d.stop > 0.0 && d.start.is_finite() && d.stop.is_finite())
        {
            return bad(&format!(
                "air layers must be positive: got {}:{}",
                d.start, d.stop
            ));
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

    /// Number of cells (saturating at `usize::MAX`; [`validate`](Self::validate) refuses more
    /// than [`MAX_SWEEP_CELLS`]).
    pub fn cells(&self) -> usize {
        self.checked_cells().unwrap_or(usize::MAX)
    }

    /// Number of cells, `None` when it overflows.
    pub fn checked_cells(&self) -> Option<usize> {
        self.shape()
            .iter()
            .try_fold(1usize, |a, &b| a.checked_mul(b))
    }

    /// Whether every axis takes its own least-squares air layer (no `--distance` grid, and a cost
    /// that depends on the air layer): those air layers are an output of the sweep
    /// (`distance.npy`).
    pub fn profiles_air_distance(&self) -> bool {
        self.distance.is_none() && !self.kind.axis_only()
    }

    /// Tilt and azimuth (degrees) of cell `cell` (row-major: tilt, azimuth, then air layer).
    pub fn cell_angles_deg(&self, cell: usize) -> (f64, f64) {
        let axis = cell / self.distance.map_or(1, |d| d.count);
        (
            self.tilt_deg.value(axis / self.azimuth_deg.count),
            self.azimuth_deg.value(axis % self.azimuth_deg.count),
        )
    }

    /// Number of axis cells (tilt × azimuth), saturating.
    pub fn axes(&self) -> usize {
        self.tilt_deg.count.saturating_mul(self.azimuth_deg.count)
    }
}

/// Most cells a sweep evaluates. The outputs stream, so memory does not grow with the grid, but
/// the files do: cost.npy takes 8 bytes a cell and cost.csv up to [`CSV_BYTES_PER_CELL`], so 10⁹
/// cells write up to about 8 GB + 80 GB (and take hours at 10⁹ cell·corners per second).
pub const MAX_SWEEP_CELLS: usize = 1_000_000_000;

/// Upper estimate of one cost.csv row (four numbers at full precision, commas, newline), bytes.
pub const CSV_BYTES_PER_CELL: usize = 80;

/// Most cells handed to the backend in one call, whatever `--chunk` and the distance grid are:
/// a batch holds a candidate (32 bytes) and two results (16 bytes) per cell, so about 12 MiB.
pub const MAX_BATCH_CELLS: usize = 1 << 18;

/// Why a grid of `shape` is refused (more than [`MAX_SWEEP_CELLS`] cells).
pub fn too_many_cells(shape: &[usize]) -> String {
    let dims = shape
        .iter()
        .map(|s| s.to_string())
        .collect::<Vec<_>>()
        .join(" × ");
    let cells = shape
        .iter()
        .try_fold(1u128, |a, &b| a.checked_mul(b as u128));
    let size = cells.map_or("more than 10³⁸".into(), |c| format!("{c}"));
    let disk = cells.map_or(String::new(), |c| {
        format!(
            " (cost.npy {:.3e} bytes and cost.csv up to {:.3e} bytes)",
            (8 * c) as f64,
            (CSV_BYTES_PER_CELL as u128 * c) as f64
        )
    });
    format!(
        "the grid {dims} has {size} cells{disk}; a sweep evaluates at most {MAX_SWEEP_CELLS} cells (cost.npy takes 8 bytes a cell, cost.csv up to {CSV_BYTES_PER_CELL}): use fewer values"
    )
}

/// The lowest cost of each axis cell, pooled into a picture of at most `max_side` × `max_side`
/// blocks (each the minimum over a block of f_t × f_a adjacent axis cells, f = ⌈count / max_side⌉):
/// the heat map and polar plot of any grid in memory bounded by the picture, not the grid. Grids
/// of at most `max_side` values per axis are kept cell for cell (f = 1).
#[derive(Debug, Clone, PartialEq)]
pub struct MinPool {
    tilts: Linspace,
    azimuths: Linspace,
    tilt_factor: usize,
    azimuth_factor: usize,
    columns: usize,
    /// values[block row · columns + block column]; +∞ where no cell of the block is finite.
    values: Vec<f64>,
}

impl MinPool {
    /// An empty picture of the tilt × azimuth grid.
    pub fn new(tilts: Linspace, azimuths: Linspace, max_side: usize) -> Self {
        let max_side = max_side.max(1);
        let tilt_factor = tilts.count.div_ceil(max_side).max(1);
        let azimuth_factor = azimuths.count.div_ceil(max_side).max(1);
        let rows = tilts.count.div_ceil(tilt_factor);
        let columns = azimuths.count.div_ceil(azimuth_factor);
        Self {
            tilts,
            azimuths,
            tilt_factor,
            azimuth_factor,
            columns,
            values: vec![f64::INFINITY; rows * columns],
        }
    }

    /// Takes the cost of axis cell `axis` (row-major over tilt × azimuth); NaN is ignored.
    pub fn add(&mut self, axis: usize, cost: f64) {
        let (t, a) = (axis / self.azimuths.count, axis % self.azimuths.count);
        let k = (t / self.tilt_factor) * self.columns + a / self.azimuth_factor;
        if cost < self.values[k] {
            self.values[k] = cost;
        }
    }

    /// Cells of the grid per picture block, (tilts, azimuths).
    pub fn factors(&self) -> (usize, usize) {
        (self.tilt_factor, self.azimuth_factor)
    }

    /// The pooled values, row-major over (tilt block, azimuth block).
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// The tilt of each block row: the middle of its first and last cell's tilts.
    pub fn tilts_deg(&self) -> Vec<f64> {
        block_centres(&self.tilts, self.tilt_factor)
    }

    /// The azimuth of each block column: the middle of its first and last cell's azimuths.
    pub fn azimuths_deg(&self) -> Vec<f64> {
        block_centres(&self.azimuths, self.azimuth_factor)
    }
}

fn block_centres(grid: &Linspace, factor: usize) -> Vec<f64> {
    (0..grid.count.div_ceil(factor))
        .map(|b| {
            let (first, last) = (b * factor, ((b + 1) * factor).min(grid.count) - 1);
            if first == last {
                grid.value(first)
            } else {
                0.5 * (grid.value(first) + grid.value(last))
            }
        })
        .collect()
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

/// One of `count` contiguous slices of a grid's cells in row-major (C) order, `index` in
/// 0..count: `--shard INDEX/COUNT`, for a job array that runs one sweep over several machines.
/// The slices differ in size by at most one cell and together cover the grid once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// This slice, 0-based (SLURM's `$SLURM_ARRAY_TASK_ID` with `--array=0-(N-1)`, Kubernetes'
    /// `$JOB_COMPLETION_INDEX`).
    pub index: usize,
    /// Number of slices.
    pub count: usize,
}

/// Most shards of one sweep.
pub const MAX_SHARDS: usize = 100_000;

impl Shard {
    /// Parses `INDEX/COUNT` with 0 ≤ INDEX < COUNT ≤ [`MAX_SHARDS`].
    pub fn parse(text: &str) -> Result<Self, String> {
        let error = || {
            format!(
                "expected INDEX/COUNT with 0 ≤ INDEX < COUNT (0-based, such as 0/4 … 3/4), got '{text}'"
            )
        };
        let (index, count) = text.split_once('/').ok_or_else(error)?;
        let index: usize = index.trim().parse().map_err(|_| error())?;
        let count: usize = count.trim().parse().map_err(|_| error())?;
        if count == 0 || index >= count {
            return Err(error());
        }
        if count > MAX_SHARDS {
            return Err(format!("at most {MAX_SHARDS} shards, got {count}"));
        }
        Ok(Self { index, count })
    }

    /// The cells of this slice of a grid of `total` cells: ⌊index·total/count⌋ up to
    /// ⌊(index+1)·total/count⌋ (exact in 128-bit arithmetic).
    pub fn cells(&self, total: usize) -> Range<usize> {
        let bound = |i: usize| (i as u128 * total as u128 / self.count as u128) as usize;
        bound(self.index)..bound(self.index + 1)
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// Sweeps `spec` over `backend` in batches of `chunk` axis cells (all their air layers), at most
/// [`MAX_BATCH_CELLS`] cells each: candidates are generated batch by batch, never for the whole
/// grid, so memory is bounded by the batch whatever the grid. Calls `sink` with every batch in
/// cell order and `progress(done, total)` after each, on the calling thread, while the backend
/// evaluates the next batch on another.
pub fn sweep(
    backend: &dyn CostBackend,
    spec: &SweepSpec,
    chunk: usize,
    sink: &mut dyn FnMut(SweepChunk) -> Result<(), CalibError>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SweepSummary, CalibError> {
    sweep_cells(backend, spec, chunk, 0..spec.cells(), sink, progress)
}

/// [`sweep`] over the cells `cells` of the grid only (row-major indices, as a [`Shard`] gives
/// them): the same batches' candidates, so every cell's cost is the one a whole sweep computes.
/// [`SweepChunk::first`] and [`SweepMinimum::cell`] are indices into the whole grid;
/// `progress(done, total)` counts within `cells`.
pub fn sweep_cells(
    backend: &dyn CostBackend,
    spec: &SweepSpec,
    chunk: usize,
    cells: Range<usize>,
    sink: &mut dyn FnMut(SweepChunk) -> Result<(), CalibError>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SweepSummary, CalibError> {
    spec.validate()?;
    let started = Instant::now();
    let (tilts, azimuths) = (spec.tilt_deg, spec.azimuth_deg);
    let depth = spec.distance.map_or(1, |d| d.count);
    if cells.start > cells.end || cells.end > spec.cells() {
        return Err(CalibError::Options(format!(
            "cells {}..{} are not within the grid's {} cells",
            cells.start,
            cells.end,
            spec.cells()
        )));
    }
    let total = cells.end;
    let per_batch = chunk.max(1).saturating_mul(depth).min(MAX_BATCH_CELLS);
    let normal_of = |a: usize| {
        normal_from_tilt_azimuth(
            tilts.value(a / azimuths.count).to_radians(),
            azimuths.value(a % azimuths.count).to_radians(),
        )
    };
    // One batch's costs and air layers, from the backend.
    let evaluate = |first: usize, end: usize| -> Result<(Vec<f64>, Vec<f64>), CalibError> {
        // The axis cells this batch touches (a batch may start or end inside an axis's air layers).
        let first_axis = first / depth;
        let normals: Vec<_> = (first_axis..=(end - 1) / depth).map(normal_of).collect();
        Ok(match spec.distance {
            None => {
                let (candidates, costs) = backend.profile(spec.kind, &normals)?;
                (
                    costs,
                    candidates
                        .iter()
                        .map(|c| c.air_distance)
                        .collect::<Vec<_>>(),
                )
            }
            Some(grid) if spec.kind.axis_only() => {
                // The air layer does not enter: one evaluation per axis, repeated along d.
                let candidates: Vec<Candidate> = normals
                    .iter()
                    .map(|n| Candidate {
                        normal: *n,
                        air_distance: f64::NAN,
                    })
                    .collect();
                let per_axis = backend.costs(spec.kind, &candidates)?;
                (
                    (first..end)
                        .map(|c| per_axis[c / depth - first_axis])
                        .collect(),
                    (first..end).map(|c| grid.value(c % depth)).collect(),
                )
            }
            Some(grid) => {
                let candidates: Vec<Candidate> = (first..end)
                    .map(|c| Candidate {
                        normal: normals[c / depth - first_axis],
                        air_distance: grid.value(c % depth),
                    })
                    .collect();
                let costs = backend.costs(spec.kind, &candidates)?;
                (costs, candidates.iter().map(|c| c.air_distance).collect())
            }
        })
    };
    let mut minimum: Option<SweepMinimum> = None;
    let mut finite = 0;
    // The backend evaluates the next batch on a thread of its own while this one hands the
    // last to the sink (the files' rows, the picture's minima): on a GPU the device then never
    // waits for the host's writing. At most two batches wait between them, so memory stays
    // bounded by the batch. A failure on either side stops both.
    std::thread::scope(|scope| -> Result<(), CalibError> {
        let (sender, batches) = std::sync::mpsc::sync_channel(1);
        scope.spawn(move || {
            let mut first = cells.start;
            while first < total {
                let end = first.saturating_add(per_batch).min(total);
                let result = evaluate(first, end).map(|values| (first, values));
                let failed = result.is_err();
                if sender.send(result).is_err() || failed {
                    return;
                }
                first = end;
            }
        });
        for batch in batches {
            let (first, (costs, distances)) = batch?;
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
            sink(SweepChunk {
                first,
                costs: &costs,
                distances: &distances,
            })?;
            progress(first + costs.len() - cells.start, cells.len());
        }
        Ok(())
    })?;
    Ok(SweepSummary {
        minimum,
        cells: cells.len(),
        finite,
        seconds: started.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_cover_the_grid_once_in_order() {
        for total in [0usize, 1, 7, 64, 4096, 1_000_000_007] {
            for count in [1usize, 2, 3, 4, 7, 64] {
                let mut next = 0;
                for index in 0..count {
                    let cells = Shard { index, count }.cells(total);
                    assert_eq!(cells.start, next, "{index}/{count} of {total}");
                    assert!(cells.len() <= total / count + 1);
                    next = cells.end;
                }
                assert_eq!(next, total);
            }
        }
        assert_eq!(Shard::parse("2/4"), Ok(Shard { index: 2, count: 4 }));
        for bad in ["4/4", "-1/4", "1/0", "1", "a/b", "1/4/2", "0/1000000"] {
            assert!(Shard::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn linspace_includes_both_ends() {
        let l = Linspace {
            start: -180.0,
            stop: 180.0,
            count: 5,
        };
        assert_eq!(l.values(), vec![-180.0, -90.0, 0.0, 90.0, 180.0]);
        assert_eq!(
            Linspace {
                start: 3.0,
                stop: 9.0,
                count: 1
            }
            .values(),
            vec![3.0]
        );
    }

    #[test]
    fn min_pool_keeps_small_grids_and_takes_block_minima_of_large_ones() {
        let tilts = Linspace {
            start: 0.0,
            stop: 4.0,
            count: 5,
        };
        let azimuths = Linspace {
            start: 0.0,
            stop: 6.0,
            count: 7,
        };
        let value = |axis: usize| ((axis * 37) % 11) as f64;
        // Cell for cell when the grid fits.
        let mut exact = MinPool::new(tilts, azimuths, 7);
        (0..35).for_each(|a| exact.add(a, value(a)));
        assert_eq!(exact.factors(), (1, 1));
        assert_eq!(exact.values(), (0..35).map(value).collect::<Vec<_>>());
        assert_eq!(exact.tilts_deg(), tilts.values());
        // At most 2 blocks a side: 3 tilts and 4 azimuths per block (the last blocks smaller).
        let mut pooled = MinPool::new(tilts, azimuths, 2);
        (0..35).for_each(|a| pooled.add(a, value(a)));
        pooled.add(0, f64::NAN);
        assert_eq!(pooled.factors(), (3, 4));
        let brute = |rows: std::ops::Range<usize>, cols: std::ops::Range<usize>| {
            rows.flat_map(|t| cols.clone().map(move |a| value(t * 7 + a)))
                .fold(f64::INFINITY, f64::min)
        };
        assert_eq!(
            pooled.values(),
            [
                brute(0..3, 0..4),
                brute(0..3, 4..7),
                brute(3..5, 0..4),
                brute(3..5, 4..7)
            ]
        );
        assert_eq!(pooled.tilts_deg(), vec![1.0, 3.5]);
        assert_eq!(pooled.azimuths_deg(), vec![1.5, 5.0]);
    }

    #[test]
    fn grids_too_large_are_refused_without_overflow() {
        let huge = Linspace {
            start: 0.0,
            stop: 1.0,
            count: usize::MAX,
        };
        let small = Linspace {
            start: 0.0,
            stop: 1.0,
            count: 3,
        };
        for spec in [
            SweepSpec {
                kind: CostKind::AffineGrid,
                tilt_deg: huge,
                azimuth_deg: huge,
                distance: None,
            },
            SweepSpec {
                kind: CostKind::AffineGrid,
                tilt_deg: small,
                azimuth_deg: small,
                distance: Some(Linspace {
                    start: 0.01,
                    stop: 0.02,
                    count: MAX_SWEEP_CELLS,
                }),
            },
        ] {
            let message = spec.validate().unwrap_err().to_string();
            assert!(message.contains("at most 1000000000 cells"), "{message}");
        }
    }
}
