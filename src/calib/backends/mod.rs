//! Where batches of candidate costs are evaluated: the host optimisers hand a whole batch
//! (a search grid, a finite-difference stencil) to a [`CostBackend`] in one call.

#[cfg(feature = "gpu")]
pub mod gpu;
pub mod residuals;

use std::ops::Deref;
use std::sync::Arc;

use nalgebra::{Unit, Vector3};
use rayon::prelude::*;

use crate::calib::costs::affine_grid::{ROW, affine_rows};
use crate::calib::costs::scene::air_distance_for_axis;
use crate::calib::costs::scene::{SceneRows, axis_costs, profile_cost};
use crate::calib::costs::{CostKind, cost_prepared};
use crate::calib::error::CalibError;
use crate::calib::problem::data::{Candidate, StereoData};

/// Evaluates calibration costs for batches of candidate interfaces.
pub trait CostBackend: Sync {
    /// One line saying what evaluates (`cpu (f64, 2 threads)`, `gpu: llvmpipe …, f64`).
    fn describe(&self) -> String;

    /// What evaluates cost `kind`: [`describe`](Self::describe), unless this backend runs that
    /// cost elsewhere or in another precision (the GPU's affine-grid kernel is always f64).
    fn describe_cost(&self, kind: CostKind) -> String {
        let _ = kind;
        self.describe()
    }

    /// The data the costs are computed from.
    fn data(&self) -> &StereoData;

    /// A backend of the same kind over other data: the consecutive method runs on the corners
    /// that the screening ([`screen`](crate::calib::problem::screen)) kept. The default evaluates on the CPU.
    fn over<'b>(&'b self, data: &'b StereoData) -> Box<dyn CostBackend + 'b> {
        Box::new(CpuBackend::new(data))
    }

    /// The cost `kind` of every candidate, in order; +∞ where a candidate explains no corner.
    fn costs(&self, kind: CostKind, candidates: &[Candidate]) -> Result<Vec<f64>, CalibError>;

    /// The least-squares air layer of every axis (DESIGN.md's linear solve), in order; `None`
    /// where an axis has none.
    fn air_distances(
        &self,
        normals: &[Unit<Vector3<f64>>],
    ) -> Result<Vec<Option<f64>>, CalibError> {
        Ok(normals
            .par_iter()
            .map(|n| air_distance_for_axis(self.data(), n).map(|(d, _)| d))
            .collect())
    }

    /// The cost of each axis with the air layer solved per axis (a profile): axis-only costs
    /// ignore the air layer; the others take the least-squares air layer of that axis, and an
    /// axis without one costs +∞. Returns the candidates evaluated and their costs.
    fn profile(
        &self,
        kind: CostKind,
        normals: &[Unit<Vector3<f64>>],
    ) -> Result<(Vec<Candidate>, Vec<f64>), CalibError> {
        let distances: Vec<Option<f64>> = if kind.axis_only() {
            vec![Some(f64::NAN); normals.len()]
        } else {
            self.air_distances(normals)?
        };
        let data = self.data();
        // Axes with an air layer that keeps both cameras in the air are evaluated; the rest cost +∞.
        let valid: Vec<usize> = (0..normals.len())
            .filter(|&i| {
                distances[i].is_some_and(|d| d.is_nan() || d > data.min_air_distance(&normals[i]))
            })
            .collect();
        let candidates: Vec<Candidate> = normals
            .iter()
            .zip(&distances)
            .map(|(n, d)| Candidate {
                normal: *n,
                air_distance: d.unwrap_or(f64::NAN),
            })
            .collect();
        let batch: Vec<Candidate> = valid.iter().map(|&i| candidates[i]).collect();
        let values = self.costs(kind, &batch)?;
        let mut costs = vec![f64::INFINITY; normals.len()];
        for (&i, v) in valid.iter().zip(values) {
            costs[i] = v;
        }
        Ok((candidates, costs))
    }
}

/// Most candidates under one axis that [`CpuBackend::costs`] evaluates from one computation of the
/// axis's water rays: the rays are one of the cost's three passes over the corners and the other
/// two run per air layer, so a group of 16 spends little of its time on them, while a single axis
/// with many air layers still spreads over the threads.
pub const AXIS_GROUP: usize = 16;

/// The f64 reference on the CPU, parallel over candidates (rayon).
///
/// `D` is how it holds the data: a borrow (`CpuBackend::new(&data)`) or shared ownership
/// (`CpuBackend::new(Arc::new(data))`, the default type), for holders that outlive a scope, such
/// as a Python object.
#[derive(Debug)]
pub struct CpuBackend<D = Arc<StereoData>> {
    data: D,
    /// The affine-grid invariant's per-corner rows, prepared once.
    affine_rows: Vec<[f64; ROW]>,
    /// The triangulating costs' per-corner rows, prepared once.
    scene_rows: SceneRows,
}

impl<D: Deref<Target = StereoData>> CpuBackend<D> {
    /// A backend over `data`.
    pub fn new(data: D) -> Self {
        let affine_rows = affine_rows(&data);
        let scene_rows = SceneRows::new(&data);
        Self {
            data,
            affine_rows,
            scene_rows,
        }
    }
}

impl<D: Deref<Target = StereoData> + Sync> CostBackend for CpuBackend<D> {
    fn describe(&self) -> String {
        format!(
            "cpu (f64 reference, {} threads)",
            rayon::current_num_threads()
        )
    }

    fn data(&self) -> &StereoData {
        &self.data
    }

    /// Each candidate's cost; the triangulating costs of consecutive candidates under one axis
    /// (a sweep's air layers) from that axis's water rays computed once ([`axis_costs`]), in
    /// groups of at most [`AXIS_GROUP`] so that one axis with many air layers still spreads over
    /// the threads.
    fn costs(&self, kind: CostKind, candidates: &[Candidate]) -> Result<Vec<f64>, CalibError> {
        if kind.axis_only() {
            return Ok(candidates
                .par_iter()
                .map(|c| cost_prepared(&self.data, &self.affine_rows, kind, c))
                .collect());
        }
        let groups: Vec<&[Candidate]> = candidates
            .chunk_by(|a, b| a.normal == b.normal)
            .flat_map(|axis| axis.chunks(AXIS_GROUP))
            .collect();
        Ok(groups
            .par_iter()
            .flat_map_iter(|group| axis_costs(&self.data, &self.scene_rows, kind, group))
            .collect())
    }

    /// The default's candidates and costs, with the water rays of each axis computed once for
    /// its air-layer solve and its cost ([`profile_cost`]).
    fn profile(
        &self,
        kind: CostKind,
        normals: &[Unit<Vector3<f64>>],
    ) -> Result<(Vec<Candidate>, Vec<f64>), CalibError> {
        if kind.axis_only() {
            let candidates: Vec<Candidate> = normals
                .iter()
                .map(|n| Candidate {
                    normal: *n,
                    air_distance: f64::NAN,
                })
                .collect();
            let costs = self.costs(kind, &candidates)?;
            return Ok((candidates, costs));
        }
        Ok(normals
            .par_iter()
            .map(|n| {
                let (air_distance, cost) = profile_cost(&self.data, &self.scene_rows, kind, n);
                (
                    Candidate {
                        normal: *n,
                        air_distance,
                    },
                    cost,
                )
            })
            .unzip())
    }
}
