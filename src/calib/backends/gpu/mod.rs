//! The calibration costs on the GPU: a [`CostBackend`] whose per-(candidate, corner) work runs in
//! WGSL kernels over the whole batch, in f32 or f64, on a [`GpuEngine`]'s device. The kernels'
//! pipelines are compiled in the engine's context (shared with every other user of it); the
//! backend keeps its own buffers. The host code of the calibration kernels is here, one file per
//! kind of dispatch (`runner.rs` their shared state: the backend's buffers): `candidates.rs` (per candidate × corner), `views.rs` (per candidate × view,
//! the corner rows in uniform windows or one storage block), `affine_grid.rs` and `scene_fit.rs`
//! (the two per-view kernels' inputs); [`kernels`] is their catalogue.
//!
//! Per cost: [`CostKind::Scene`] and [`CostKind::Reprojection`] are reduced on the device per
//! (candidate, view) (the scene-fit kernel: triangulation, the rigid board fit and the view's sum
//! of squares), and the views are added on the device too (`calib_view_sum`, in view order, so
//! one row per candidate comes back); the profile's air layers come from the same kernel's
//! gap-line sums per (axis, view), added alike. [`CostKind::RayGap`] triangulates per corner on
//! the device (`calib_triangulate`) and sums on the host ([`ray_gap_rms`]). The affine-grid
//! invariant is fused per (axis, view) (`calib_affine_grid`) and added over the views on the
//! device; the plane errors run one dispatch of projected
//! VOPs (`calib_projected_vop`), then the per-view fits on the host ([`plane_cost`]). A candidate
//! that puts a camera outside the air, or under which a corner has no answer, costs +∞ as on the
//! CPU.

mod affine_grid;
mod bundle;
mod candidates;
pub mod kernels;
mod runner;
mod scene_fit;
mod views;

use std::ops::Deref;
use std::sync::Arc;

use nalgebra::{Unit, Vector3};
use rayon::prelude::*;

use crate::calib::backends::CostBackend;
use crate::calib::costs::affine_grid::affine_rows;
use crate::calib::costs::air_layer::sample_cameras;
use crate::calib::costs::cost_prepared;
use crate::calib::costs::invariants::ProjectedVop;
use crate::calib::costs::{CostKind, plane_cost, ray_gap_rms};
use crate::calib::error::CalibError;
use crate::calib::problem::data::{Candidate, StereoData};
use crate::engine::GpuEngine;
use crate::gpu::{ResidentRows, Rows};
use affine_grid::AffineGridInput;
pub use bundle::GpuResiduals;
use runner::KernelRunner;
use scene_fit::{SCENE_ROW, SceneFitInput, SceneSum};

/// The costs of candidate batches evaluated by a [`GpuEngine`] (any adapter, f32 or f64).
///
/// `D` and `E` are how it holds the data and the engine: borrows (`GpuBackend::new(&data,
/// &engine)`) or shared ownership (`Arc`, the default types), for holders that outlive a scope,
/// such as a Python object.
pub struct GpuBackend<D = Arc<StereoData>, E = Arc<GpuEngine>> {
    data: D,
    engine: E,
    /// v_l, v_r of every corner (master frame).
    air_rays: ResidentRows,
    /// v_l, v_r, ∂v_l/∂u, ∂v_l/∂v, ∂v_r/∂u, ∂v_r/∂v of every corner.
    vop_rows: ResidentRows,
    /// The affine-grid rows and view table, packed for the fused kernel.
    affine_input: AffineGridInput,
    /// Air rays, board points and pixels of every corner with the view table, packed for the
    /// scene-fit kernel (gap lines, 3-D scene and reprojection costs reduced per view).
    scene_input: SceneFitInput,
    /// The kernels' buffers and row binding.
    kernels: KernelRunner,
}

impl<D: Deref<Target = StereoData>, E: Deref<Target = GpuEngine>> GpuBackend<D, E> {
    /// A backend over `data` running on `engine` (whose device and pipelines it uses; its buffers
    /// are its own, reused across its calls). The per-corner rows are packed here once and go to the device at the first call that needs
    /// them; they stay there for every later call of this backend (the data never change under
    /// it: other data make another backend, [`CostBackend::over`]).
    pub fn new(data: D, engine: E) -> Self {
        let air_rays: Vec<[f64; 6]> = data
            .corners
            .iter()
            .map(|c| std::array::from_fn(|i| c.dirs[i / 3][i % 3]))
            .collect();
        let vop_rows: Vec<[f64; 18]> = data
            .corners
            .iter()
            .map(|c| {
                std::array::from_fn(|i| match i {
                    0..6 => c.dirs[i / 3][i % 3],
                    _ => {
                        // Columns ∂/∂u, ∂/∂v of the left, then the right Jacobian.
                        let k = (i - 6) / 6;
                        let col = (i - 6) % 6 / 3;
                        c.dir_jacobians[k][(i % 3, col)]
                    }
                })
            })
            .collect();
        let views: Vec<(usize, usize)> = data.views.iter().map(|r| (r.start, r.len())).collect();
        let affine_input = AffineGridInput::new(&affine_rows(&data), &views);
        let scene_rows: Vec<[f64; SCENE_ROW]> = data
            .corners
            .iter()
            .map(|c| {
                let p = data.board.point_in_board(c.index);
                let (v, px) = (c.dirs, c.pixels);
                [
                    v[0].x, v[0].y, v[0].z, v[1].x, v[1].y, v[1].z, p.x, p.y, px[0].x, px[0].y,
                    px[1].x, px[1].y,
                ]
            })
            .collect();
        let scene_input = SceneFitInput::new(&scene_rows, &views);
        Self {
            data,
            engine,
            air_rays: ResidentRows::new(&air_rays),
            vop_rows: ResidentRows::new(&vop_rows),
            affine_input,
            scene_input,
            kernels: KernelRunner::default(),
        }
    }

    /// Fixes where the per-(candidate, view) kernels read their corner rows: `Some(Rows::Uniform)`
    /// in uniform windows wherever every view fits one, `Some(Rows::Storage)` in one storage
    /// block, `None` (the default) chosen per call (windows on a software adapter for calls large
    /// enough to pay for a dispatch per window; one storage block, one dispatch per batch of
    /// views, on a hardware GPU). For tests of the two bindings; a backend
    /// [`over`](CostBackend::over) other data keeps the choice.
    pub fn set_rows(&mut self, rows: Option<Rows>) {
        self.kernels.rows = rows;
    }

    /// The engine the kernels run on.
    pub fn engine(&self) -> &GpuEngine {
        &self.engine
    }

    /// Drops the device copies of the per-corner data (freeing their memory): the next call
    /// that needs them uploads them again. For measuring what keeping them saves.
    pub fn evict(&self) {
        self.air_rays.evict();
        self.vop_rows.evict();
        self.affine_input.resident().evict();
        self.scene_input.resident().evict();
    }

    /// Uploads of the per-corner data to the device so far, over every input kept there (one
    /// per input a cost has used, however many calls used it).
    pub fn uploads(&self) -> usize {
        self.air_rays.uploads()
            + self.vop_rows.uploads()
            + self.affine_input.resident().uploads()
            + self.scene_input.resident().uploads()
    }

    /// Reprojection and scene costs reduced per (candidate, view) and summed over the views on
    /// the device; the ray gap triangulated per corner on the device and summed on the host.
    fn scene_costs(
        &self,
        kind: CostKind,
        candidates: &[Candidate],
    ) -> Result<Vec<f64>, CalibError> {
        let data: &StereoData = &self.data;
        let corners = data.corners.len();
        let mut costs = vec![f64::INFINITY; candidates.len()];
        // Candidates that keep both cameras in the air, as planes of the master frame.
        let (valid, interfaces): (Vec<usize>, Vec<[f64; 4]>) = candidates
            .par_iter()
            .enumerate()
            .filter_map(|(i, c)| Some((i, data.master_plane(c)?)))
            .unzip();
        if valid.is_empty() || corners == 0 {
            return Ok(costs);
        }
        if kind != CostKind::RayGap {
            // Triangulation, rigid fit and sums per (candidate, view) on the device.
            let what = if kind == CostKind::Scene {
                SceneSum::Scene
            } else {
                SceneSum::Reprojection
            };
            let mut sums = vec![[0.0; 4]; interfaces.len()];
            let mut status = vec![0; sums.len()];
            self.kernels.scene_fit(
                &self.engine,
                &data.rig,
                data.cameras,
                &self.scene_input,
                what,
                &interfaces,
                &mut sums,
                &mut status,
            )?;
            // scene_rms: √(Σ/N); reprojection_rms: √(Σ/2N).
            let per_value = if kind == CostKind::Scene { 1 } else { 2 };
            for (c, &i) in valid.iter().enumerate() {
                if status[c] == 0 {
                    costs[i] = (sums[c][0] / (per_value * corners) as f64).sqrt();
                }
            }
            return Ok(costs);
        }
        let mut rows = vec![[0.0; 4]; interfaces.len() * corners];
        let mut status = vec![0; rows.len()];
        self.kernels.triangulate(
            &self.engine,
            &data.rig,
            data.cameras,
            &self.air_rays,
            &interfaces,
            &mut rows,
            &mut status,
        )?;
        let answered = |c: usize| {
            status[c * corners..(c + 1) * corners]
                .iter()
                .all(|&s| s == 0)
        };
        // The ray gap: per corner on the device, summed here.
        let values: Vec<f64> = (0..valid.len())
            .into_par_iter()
            .map(|c| {
                let gaps: Vec<f64> = rows[c * corners..(c + 1) * corners]
                    .iter()
                    .map(|r| r[3])
                    .collect();
                if answered(c) {
                    ray_gap_rms(&gaps)
                } else {
                    f64::INFINITY
                }
            })
            .collect();
        valid.iter().zip(values).for_each(|(&i, v)| costs[i] = v);
        Ok(costs)
    }

    /// The affine-grid invariant: the fused kernel per (axis, view) in f64 on the device, and
    /// the sum over views there too; on adapters without SHADER_F64 the CPU twin runs instead.
    fn affine_grid_costs(&self, candidates: &[Candidate]) -> Result<Vec<f64>, CalibError> {
        let data: &StereoData = &self.data;
        if !self.engine.context().adapter().f64 {
            let rows = affine_rows(data);
            return Ok(candidates
                .par_iter()
                .map(|c| cost_prepared(data, &rows, CostKind::AffineGrid, c))
                .collect());
        }
        let axes: Vec<[f64; 4]> = candidates
            .iter()
            .map(|c| [c.normal.x, c.normal.y, c.normal.z, 0.0])
            .collect();
        let mut fits = vec![[0.0; 2]; axes.len()];
        let mut status = vec![0; fits.len()];
        self.kernels.affine_grid(
            &self.engine,
            &data.rig,
            data.cameras,
            &self.affine_input,
            &axes,
            &mut fits,
            &mut status,
        )?;
        Ok(candidates
            .iter()
            .enumerate()
            .map(|(c, candidate)| {
                let fitted = status[c] == 0 && candidate.normal.z > 0.0;
                let [chi2, dof] = fits[c];
                if fitted && dof > 0.0 {
                    chi2 / dof
                } else {
                    f64::INFINITY
                }
            })
            .collect())
    }

    /// The plane errors: projected VOPs on the device, per-view line fits on the host.
    fn plane_costs(
        &self,
        kind: CostKind,
        candidates: &[Candidate],
    ) -> Result<Vec<f64>, CalibError> {
        let data: &StereoData = &self.data;
        let corners = data.corners.len();
        let axes: Vec<[f64; 4]> = candidates
            .iter()
            .map(|c| [c.normal.x, c.normal.y, c.normal.z, 0.0])
            .collect();
        let mut rows = vec![[0.0; 10]; axes.len() * corners];
        let mut status = vec![0; rows.len()];
        self.kernels.projected_vop(
            &self.engine,
            &data.rig,
            data.cameras,
            &self.vop_rows,
            &axes,
            &mut rows,
            &mut status,
        )?;
        Ok((0..candidates.len())
            .into_par_iter()
            .map(|c| {
                let (rows, status) = (
                    &rows[c * corners..(c + 1) * corners],
                    &status[c * corners..(c + 1) * corners],
                );
                // Corners whose binocular VOP is undetermined are left out, as on the CPU.
                let views = data.views.iter().map(|range| {
                    range
                        .clone()
                        .filter(|&j| status[j] == 0)
                        .map(|j| ProjectedVop::from_packed(data.corners[j].index, &rows[j]))
                        .collect()
                });
                plane_cost(data, kind, views).unwrap_or(f64::INFINITY)
            })
            .collect())
    }
}

impl<D: Deref<Target = StereoData> + Sync, E: Deref<Target = GpuEngine> + Sync> CostBackend
    for GpuBackend<D, E>
{
    fn describe(&self) -> String {
        let a = self.engine.context().adapter();
        format!(
            "gpu: {} ({}, {}), {}",
            a.name,
            a.backend,
            a.driver,
            self.engine.precision()
        )
    }

    fn describe_cost(&self, kind: CostKind) -> String {
        let a = self.engine.context().adapter();
        match kind {
            CostKind::AffineGrid if a.f64 => format!(
                "gpu: {} ({}, {}), f64 (the affine-grid kernel, whatever the engine's precision)",
                a.name, a.backend, a.driver
            ),
            CostKind::AffineGrid => format!(
                "cpu (f64 reference, {} threads): the affine-grid cost needs SHADER_F64, which {} lacks",
                rayon::current_num_threads(),
                a.name
            ),
            _ => self.describe(),
        }
    }

    fn data(&self) -> &StereoData {
        &self.data
    }

    fn over<'b>(&'b self, data: &'b StereoData) -> Box<dyn CostBackend + 'b> {
        let mut backend = GpuBackend::new(data, &*self.engine);
        backend.set_rows(self.kernels.rows);
        Box::new(backend)
    }

    fn costs(&self, kind: CostKind, candidates: &[Candidate]) -> Result<Vec<f64>, CalibError> {
        match kind {
            CostKind::AffineGrid => self.affine_grid_costs(candidates),
            _ if kind.axis_only() => self.plane_costs(kind, candidates),
            _ => self.scene_costs(kind, candidates),
        }
    }

    fn air_distances(
        &self,
        normals: &[Unit<Vector3<f64>>],
    ) -> Result<Vec<Option<f64>>, CalibError> {
        let data: &StereoData = &self.data;
        let corners = data.corners.len();
        let mut distances = vec![None; normals.len()];
        // Axes that are interface normals at all (the CPU reference samples the rays there), in
        // the master frame, with the master plane's offset from the first camera's air layer.
        let (valid, (axes, offsets)): (Vec<usize>, (Vec<_>, Vec<f64>)) = normals
            .par_iter()
            .enumerate()
            .filter_map(|(i, n)| {
                let (_, [first, _], _) = sample_cameras(data, n)?;
                let n = first.normal();
                Some((i, ([n.x, n.y, n.z, 0.0], data.master_plane_offset(&first))))
            })
            .unzip();
        if valid.is_empty() {
            return Ok(distances);
        }
        // The gap lines' normal equation per (axis, view) on the device, summed there.
        let mut sums = vec![[0.0; 4]; axes.len()];
        let mut status = vec![0; sums.len()];
        self.kernels.scene_fit(
            &self.engine,
            &data.rig,
            data.cameras,
            &self.scene_input,
            SceneSum::GapLines,
            &axes,
            &mut sums,
            &mut status,
        )?;
        let values: Vec<Option<f64>> = (0..valid.len())
            .map(|c| {
                if status[c] != 0 {
                    return None;
                }
                let [aa, ab, ..] = sums[c];
                // least_squares_air_distance's test and solution, as the first camera's air layer.
                (aa > 1e-18 * corners as f64).then(|| -ab / aa - offsets[c])
            })
            .collect();
        valid
            .iter()
            .zip(values)
            .for_each(|(&i, d)| distances[i] = d);
        Ok(distances)
    }
}
