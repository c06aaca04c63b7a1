//! The fused affine-grid kernel (`shaders/calib/affine_grid.wgsl`): candidate axes ×
//! views, one (χ², dof) per pair, always in f64, added over the views on the device: one
//! (Σχ², Σdof) per axis comes back. Indexing, chunking and buffers only; the
//! formulation is in [`crate::calib::costs::affine_grid`].

use super::kernels;
use super::runner::KernelRunner;
use super::views::{ViewKernel, ViewRows};
use crate::calib::problem::data::CameraPair;
use crate::engine::GpuEngine;
use crate::gpu::compose::Precision;
use crate::gpu::context::GpuError;
use crate::model::Rig;

/// The fused affine-grid kernel's input: N reals per corner (a multiple of 4: the kernel reads
/// vec4), view by view, kept on the device across calls ([`ViewRows`]).
#[derive(Debug)]
pub struct AffineGridInput {
    rows: ViewRows,
}

impl AffineGridInput {
    /// The corner `rows` (view by view) and each view's (first row, row count).
    pub fn new<const N: usize>(rows: &[[f64; N]], views: &[(usize, usize)]) -> Self {
        Self {
            rows: ViewRows::new(rows.as_flattened(), N, views),
        }
    }

    /// The rows as kept on the device.
    pub fn resident(&self) -> &ViewRows {
        &self.rows
    }
}

impl KernelRunner {
    /// The weighted affine-grid χ² and degrees of freedom of `input` under every axis (unit,
    /// fourth value ignored), per view on the device and added over the views there in view
    /// order: `fits[c]` gets (Σχ², Σdof) of axis c; `status[c]` is 0, or 6 (degenerate) where a
    /// view has fewer than 4 weighted corners or a singular fit, the fit NaN where not 0. Runs in
    /// f64 whatever the engine's precision; errors on adapters without SHADER_F64. The input is
    /// uploaded at the first call and kept on the device for the later ones.
    ///
    /// Panics if `fits` and `status` are not `axes.len()` long.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn affine_grid(
        &self,
        engine: &GpuEngine,
        rig: &Rig,
        cameras: CameraPair,
        input: &AffineGridInput,
        axes: &[[f64; 4]],
        fits: &mut [[f64; 2]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        if !engine.context().adapter().f64 {
            return Err(GpuError::Unsupported(format!(
                "the affine-grid kernel runs in f64 and adapter '{}' has no SHADER_F64",
                engine.context().adapter().name
            )));
        }
        let job = ViewKernel {
            kernel: &kernels::AFFINE_GRID,
            precision: Precision::F64,
            input: &input.rows,
        };
        self.run_views(engine, job, rig, cameras, axes, fits, status)
    }
}
