//! The triangulating calibration costs reduced on the device
//! (`shaders/calib/scene_fit.wgsl`): candidate interfaces × views, four numbers per pair
//! (a view's gap-line sums, or its rigid board fit's sum of squares) instead of a row per corner,
//! added over the views on the device (`shaders/calib/view_sum.wgsl`): four numbers per candidate
//! come back.
//! Indexing, chunking and buffers only; the geometry is in the kernel and its CPU twin
//! [`crate::calib::costs::scene`].

use super::kernels;
use super::runner::KernelRunner;
use super::views::{ViewKernel, ViewRows};
use crate::calib::problem::data::CameraPair;
use crate::engine::GpuEngine;
use crate::gpu::compose::{KernelSource, STATUS_RETRY};
use crate::gpu::context::GpuError;
use crate::model::Rig;

/// Reals per corner row of [`SceneFitInput`]: v_l xyz, v_r xyz, board point x y, pixels
/// u_l v_l u_r v_r.
pub const SCENE_ROW: usize = 12;

/// What the scene-fit kernel sums per (candidate, view).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneSum {
    /// (Σa², Σab, Σb², 0) of the view's gap lines g(d) = a·d + b under the axis (the candidate's
    /// air layer is ignored): the least-squares air layer's normal equation.
    GapLines,
    /// (Σ|R·P + t − X|², corners, 0, 0): the rigid board fit's 3-D sum of squares.
    Scene,
    /// (Σ|observed − projected|² over both images, corners, 0, 0) of the fitted board: each
    /// fitted corner is projected from its observed air ray by an unbracketed Newton iteration
    /// where no medium is less dense than air (`project_near_pair` in `shaders/lib/air_path.wgsl`);
    /// a view where that leaves a corner unsettled is summed again with every corner by the full
    /// forward projection (`project`), by a second kernel that only those (candidate, view) pairs
    /// run.
    Reprojection,
}

impl SceneSum {
    /// The kernel that sums it (one WGSL file, its mode a constant).
    fn kernel(self) -> &'static KernelSource {
        match self {
            Self::GapLines => &kernels::SCENE_GAP,
            Self::Scene => &kernels::SCENE_FIT,
            Self::Reprojection => &kernels::SCENE_REPROJECTION,
        }
    }
}

/// The scene-fit kernel's input: [`SCENE_ROW`] reals per corner, view by view, kept on the
/// device across calls ([`ViewRows`]).
#[derive(Debug)]
pub struct SceneFitInput {
    rows: ViewRows,
}

impl SceneFitInput {
    /// The corner `rows` (view by view) and each view's (first row, row count).
    pub fn new(rows: &[[f64; SCENE_ROW]], views: &[(usize, usize)]) -> Self {
        Self {
            rows: ViewRows::new(rows.as_flattened(), SCENE_ROW, views),
        }
    }

    /// The rows as kept on the device.
    pub fn resident(&self) -> &ViewRows {
        &self.rows
    }
}

impl KernelRunner {
    /// The sums `what` over the views of `input` under every candidate interface (n unit, d: the
    /// plane n·x = d of the master frame; behind a port per camera it moves the port of
    /// `cameras[0]` and `cameras[1]` keeps its own), in the engine's precision, added over the
    /// views on the device in view order: `sums[c]` gets candidate c's; `status[c]` is 0 or the
    /// [`NoSolution`](crate::model::NoSolution) code of the first view with a corner without an
    /// answer (2 where the candidate puts a camera outside the air, 6 for a view whose corners
    /// are collinear or a corner whose water rays are parallel), the sums NaN where not 0. The
    /// input is uploaded at the first call and kept on the device for the later ones.
    ///
    /// Panics if `sums` and `status` are not `candidates.len()` long.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn scene_fit(
        &self,
        engine: &GpuEngine,
        rig: &Rig,
        cameras: CameraPair,
        input: &SceneFitInput,
        what: SceneSum,
        candidates: &[[f64; 4]],
        sums: &mut [[f64; 4]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        let job = ViewKernel {
            kernel: what.kernel(),
            precision: engine.precision(),
            input: &input.rows,
        };
        self.run_views(engine, job, rig, cameras, candidates, sums, status)?;
        if what != SceneSum::Reprojection {
            return Ok(());
        }
        // The candidates with a view the fast kernel left unsettled (their combined status is
        // STATUS_RETRY whatever their other views gave), summed again by the safeguarded one
        // (every view of them: a whole candidate is one batch row).
        let unsettled: Vec<usize> = (0..candidates.len())
            .filter(|&c| status[c] == STATUS_RETRY)
            .collect();
        if unsettled.is_empty() {
            return Ok(());
        }
        let again: Vec<[f64; 4]> = unsettled.iter().map(|&c| candidates[c]).collect();
        let mut again_sums = vec![[0.0; 4]; again.len()];
        let mut again_status = vec![0; again_sums.len()];
        let job = ViewKernel {
            kernel: &kernels::SCENE_REPROJECTION_SAFEGUARDED,
            precision: engine.precision(),
            input: &input.rows,
        };
        self.run_views(
            engine,
            job,
            rig,
            cameras,
            &again,
            &mut again_sums,
            &mut again_status,
        )?;
        for (k, &c) in unsettled.iter().enumerate() {
            sums[c] = again_sums[k];
            status[c] = again_status[k];
        }
        Ok(())
    }
}
