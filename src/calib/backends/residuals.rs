//! Where the bundle's reprojection residuals are evaluated: the bundle adjustment
//! ([`Bundle`](crate::calib::pipeline::bundle::Bundle)) hands a whole finite-difference stencil
//! (the current state and its ± perturbations per parameter) to a [`ResidualBackend`] in one
//! call, as a [`StencilBatch`]: sets of cameras, sets of target poses, and the (camera set, pose
//! set) pairs to evaluate. Every evaluation gives the residual (projected − observed, pixels) of
//! every observed corner, in the bundle's order ([`ObservedCorner`]).
//!
//! [`CpuResiduals`] evaluates a batch with the CPU engine's vector path, corner for corner the
//! bundle's own CPU code (bit for bit); the GPU twin is
//! [`GpuResiduals`](crate::calib::backends::gpu::GpuResiduals).

use nalgebra::{Isometry3, Point3, Vector2};
use rayon::prelude::*;

use crate::engine::cpu::lanes;
use crate::model::RefractiveCamera;

/// One corner seen by one camera in one view: a row of the bundle's residuals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObservedCorner {
    /// The view (index of its target pose).
    pub view: usize,
    /// The rig camera that saw it.
    pub camera: usize,
    /// The corner in the target frame, metres.
    pub point_in_target: [f64; 3],
    /// The observed pixel.
    pub observed: [f64; 2],
}

/// One evaluation of a [`StencilBatch`]: a camera set, a pose set, and the camera whose corners
/// it projects (`None`: every camera's; the others' residuals are 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Evaluation {
    /// Index into [`StencilBatch::cameras`].
    pub cameras: usize,
    /// Index into [`StencilBatch::poses`].
    pub poses: usize,
    /// The only camera evaluated, if one.
    pub only: Option<usize>,
}

/// Parameter states to evaluate in one call.
#[derive(Debug, Clone)]
pub struct StencilBatch {
    /// Camera sets: every rig camera (in rig order) under one state of the ports and extrinsics.
    pub cameras: Vec<Vec<RefractiveCamera>>,
    /// Pose sets: X_master = R·X_target + t of every view (in view order).
    pub poses: Vec<Vec<Isometry3<f64>>>,
    /// What to evaluate, in the order of the answer.
    pub evaluations: Vec<Evaluation>,
}

/// The residuals of one evaluation, in the order of the observed corners; `None` when a corner it
/// projects has no answer under it (behind the port, outside the lens, …).
pub type Residuals = Option<Vec<Vector2<f64>>>;

/// Evaluates the bundle's residuals for batches of parameter states. A backend is made for one
/// list of observed corners (the bundle's), which it may keep on its device across calls.
pub trait ResidualBackend: Sync {
    /// One line saying what evaluates.
    fn describe(&self) -> String;

    /// Number of observed corners it was made for.
    fn observations(&self) -> usize;

    /// The residuals of every evaluation of `batch`, in order.
    fn residuals(&self, batch: &StencilBatch) -> Vec<Residuals>;

    /// Why the backend stopped using its device and evaluated on the CPU instead, if it did.
    fn failure(&self) -> Option<String> {
        None
    }
}

/// The bundle's corners grouped as it projects them: runs of one (view, camera), in order.
#[derive(Debug, Clone)]
struct Block {
    view: usize,
    camera: usize,
    /// Range of the observed corners.
    start: usize,
    end: usize,
}

/// The f64 reference: each (evaluation, view, camera) block by the CPU engine's vector path
/// ([`lanes::project_all`]), as the bundle's own CPU code projects it.
#[derive(Debug, Clone)]
pub struct CpuResiduals {
    corners: Vec<ObservedCorner>,
    blocks: Vec<Block>,
}

impl CpuResiduals {
    /// A backend for `corners`.
    pub fn new(corners: &[ObservedCorner]) -> Self {
        let mut blocks: Vec<Block> = Vec::new();
        for (j, c) in corners.iter().enumerate() {
            match blocks.last_mut() {
                Some(b) if b.view == c.view && b.camera == c.camera => b.end = j + 1,
                _ => blocks.push(Block {
                    view: c.view,
                    camera: c.camera,
                    start: j,
                    end: j + 1,
                }),
            }
        }
        Self {
            corners: corners.to_vec(),
            blocks,
        }
    }

    /// The residuals of one evaluation.
    fn evaluate(&self, batch: &StencilBatch, evaluation: &Evaluation) -> Residuals {
        let cameras = &batch.cameras[evaluation.cameras];
        let poses = &batch.poses[evaluation.poses];
        let mut out = vec![Vector2::zeros(); self.corners.len()];
        for block in &self.blocks {
            if evaluation.only.is_some_and(|o| o != block.camera) {
                continue;
            }
            let corners = &self.corners[block.start..block.end];
            let pose = &poses[block.view];
            let points: Vec<[f64; 3]> = corners
                .iter()
                .map(|c| (pose * Point3::from(c.point_in_target)).coords.into())
                .collect();
            let pixels = lanes::project_all(&cameras[block.camera], &points)?;
            for ((r, c), p) in out[block.start..block.end]
                .iter_mut()
                .zip(corners)
                .zip(&pixels)
            {
                *r = Vector2::new(p[0], p[1]) - Vector2::from(c.observed);
            }
        }
        Some(out)
    }
}

impl ResidualBackend for CpuResiduals {
    fn describe(&self) -> String {
        format!(
            "cpu (f64 reference, {} threads)",
            rayon::current_num_threads()
        )
    }

    fn observations(&self) -> usize {
        self.corners.len()
    }

    fn residuals(&self, batch: &StencilBatch) -> Vec<Residuals> {
        batch
            .evaluations
            .par_iter()
            .map(|e| self.evaluate(batch, e))
            .collect()
    }
}
