//! The fused affine-grid kernel (`shaders/kernels/calib_affine_grid.wgsl`): candidate axes ×
//! views, one (χ², dof) per pair, always in f64. Indexing, chunking and buffers only; the
//! formulation is in [`crate::calib::costs::affine_grid`].

use super::GpuEngine;
use super::views::ViewKernel;
use crate::gpu::context::GpuError;
use crate::gpu::engine::ResidentRows;
use crate::gpu::shaders::{Kernel, Precision};
use crate::model::Rig;

/// The fused affine-grid kernel's input, packed once per data set and kept on the device across
/// calls ([`ResidentRows`]): every corner row (N reals, a multiple of 4: the kernel reads vec4),
/// then (first row, row count, 0, 0) per view.
#[derive(Debug)]
pub struct AffineGridInput {
    packed: ResidentRows,
    rows: usize,
    views: usize,
}

impl AffineGridInput {
    /// Packs `rows` (view by view) and each view's (first row, row count).
    pub fn new<const N: usize>(rows: &[[f64; N]], views: &[(usize, usize)]) -> Self {
        assert_eq!(N % 4, 0, "rows are read as vec4");
        let mut reals = Vec::with_capacity(rows.len() * N + 4 * views.len());
        for row in rows {
            reals.extend_from_slice(row);
        }
        for &(first, count) in views {
            reals.extend_from_slice(&[first as f64, count as f64, 0.0, 0.0]);
        }
        Self {
            packed: ResidentRows::from_reals(reals, 4),
            rows: rows.len(),
            views: views.len(),
        }
    }

    /// Number of views.
    pub fn views(&self) -> usize {
        self.views
    }

    /// The packed rows as kept on the device.
    pub fn resident(&self) -> &ResidentRows {
        &self.packed
    }
}

impl GpuEngine {
    /// The weighted affine-grid χ² and degrees of freedom of every view of `input` under every
    /// axis (unit, fourth value ignored). `fits[c · views + v]` gets
    /// (χ², dof) of view v under axis c; `status` is 0, or 6 (degenerate) where the view has
    /// fewer than 4 weighted corners or a singular fit, the fit NaN where not 0. Runs in f64
    /// whatever the engine's precision; errors on adapters without SHADER_F64. The input is
    /// uploaded at the first call and kept on the device for the later ones.
    ///
    /// Panics if `fits` and `status` are not `axes.len() · views.len()` long.
    pub fn calib_affine_grid(
        &self,
        rig: &Rig,
        cameras: [usize; 2],
        input: &AffineGridInput,
        axes: &[[f64; 4]],
        fits: &mut [[f64; 2]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        if !self.context.adapter().f64 {
            return Err(GpuError::Unsupported(format!(
                "the affine-grid kernel runs in f64 and adapter '{}' has no SHADER_F64",
                self.context.adapter().name
            )));
        }
        let job = ViewKernel {
            kernel: Kernel::CalibAffineGrid,
            precision: Precision::F64,
            input: &input.packed,
            corners: input.rows,
            views: input.views,
            info_z: input.rows as u32,
        };
        self.run_views(job, rig, cameras, axes, fits, status)
    }
}
