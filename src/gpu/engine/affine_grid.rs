//! The fused affine-grid kernel (`shaders/kernels/calib_affine_grid.wgsl`): candidate axes ×
//! views, one (χ², dof) per pair, always in f64. Indexing, chunking and buffers only; the
//! formulation is in [`crate::calib::costs::affine_grid`].

use super::{GROUP, GpuEngine};
use crate::gpu::context::GpuError;
use crate::gpu::layout::Params;
use crate::gpu::shaders::{Kernel, Precision};
use crate::model::Rig;

/// The fused affine-grid kernel's input, packed once per data set: every corner row (N reals, a
/// multiple of 4: the kernel reads vec4), then (first row, row count, 0, 0) per view.
#[derive(Debug, Clone)]
pub struct AffineGridInput {
    reals: Vec<f64>,
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
            reals,
            rows: rows.len(),
            views: views.len(),
        }
    }

    /// Number of views.
    pub fn views(&self) -> usize {
        self.views
    }
}

impl GpuEngine {
    /// The weighted affine-grid χ² and degrees of freedom of every view of `input` under every
    /// axis (unit, fourth value ignored). `fits[c · views + v]` gets
    /// (χ², dof) of view v under axis c; `status` is 0, or 6 (degenerate) where the view has
    /// fewer than 4 weighted corners or a singular fit. Runs in f64 whatever the engine's
    /// precision; errors on adapters without SHADER_F64.
    ///
    /// Panics if `fits` and `status` are not `axes.len() · views.len()` long.
    #[allow(clippy::too_many_arguments)]
    pub fn calib_affine_grid(
        &self,
        rig: &Rig,
        cameras: [usize; 2],
        input: &AffineGridInput,
        axes: &[[f64; 4]],
        fits: &mut [[f64; 2]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        let view_count = input.views;
        assert!(
            fits.len() == axes.len() * view_count && status.len() == fits.len(),
            "fits and status of axes · views"
        );
        if !self.context.adapter().f64 {
            return Err(GpuError::Unsupported(format!(
                "the affine-grid kernel runs in f64 and adapter '{}' has no SHADER_F64",
                self.context.adapter().name
            )));
        }
        if fits.is_empty() {
            return Ok(());
        }
        let (a, b) = (
            rig.refractive_camera(cameras[0]),
            rig.refractive_camera(cameras[1]),
        );
        Self::check_layers(&a)?;
        Self::check_layers(&b)?;
        let precision = Precision::F64;
        let real = precision.size();
        // Items per dispatch: (χ², dof) and a status each.
        let capacity = self.chunk_items(2 * real);
        let views_per_chunk = view_count.min((capacity / GROUP).max(1));
        // Candidates per view a multiple of the workgroup size: a workgroup's invocations share their view.
        let per_view = ((capacity / views_per_chunk) / GROUP * GROUP)
            .max(GROUP)
            .min(axes.len().next_multiple_of(GROUP));
        let cap = self.context.max_storage_binding() as usize;
        if input.reals.len() * real > cap {
            return Err(GpuError::Unsupported(format!(
                "{} corner rows do not fit one binding of {cap} bytes",
                input.rows
            )));
        }
        let kernel = Kernel::CalibAffineGrid;
        let pipeline = self.pipeline(kernel)?;
        let mut params = Params::new(precision, &a, &b, [0; 4]);
        let mut guard = self.buffers();
        let buffers = &mut *guard;
        let uniform = buffers
            .uniform
            .get(
                &self.context,
                "params",
                params.bytes().len(),
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            )?
            .clone();
        let in_buf = buffers
            .input
            .get(
                &self.context,
                "input",
                input.reals.len() * real,
                self.input_usage(),
            )?
            .clone();
        let cand_buf = buffers
            .candidates
            .get(
                &self.context,
                "candidates",
                per_view * 4 * real,
                self.input_usage(),
            )?
            .clone();
        let items = per_view * views_per_chunk;
        let (out_buf, out_staging) = self.readable(
            &mut buffers.output,
            &mut buffers.output_staging,
            "output",
            items * 2 * real,
        )?;
        let (status_buf, status_staging) = self.readable(
            &mut buffers.status,
            &mut buffers.status_staging,
            "status",
            items * 4,
        )?;
        let bind_group = self.bind_group(
            &pipeline,
            kernel.name(),
            &[
                (0, &uniform),
                (1, &in_buf),
                (2, &out_buf),
                (3, &status_buf),
                (4, &cand_buf),
            ],
        );
        self.upload(&in_buf, bytemuck::cast_slice(&input.reals))?;
        let mut chunk_axes = vec![[0.0; 4]; per_view];
        for first in (0..axes.len()).step_by(per_view) {
            let last = (first + per_view).min(axes.len());
            // Pad the chunk with its last axis: every workgroup then shares one view.
            for (k, slot) in chunk_axes.iter_mut().enumerate() {
                *slot = axes[(first + k).min(last - 1)];
            }
            self.upload(&cand_buf, bytemuck::cast_slice(&chunk_axes))?;
            for view_first in (0..view_count).step_by(views_per_chunk) {
                let view_last = (view_first + views_per_chunk).min(view_count);
                let count = per_view * (view_last - view_first);
                params.set_info([
                    count as u32,
                    per_view as u32,
                    input.rows as u32,
                    view_first as u32,
                ]);
                self.context.queue.write_buffer(&uniform, 0, params.bytes());
                let encoder = self.encode_dispatch(
                    &pipeline,
                    &bind_group,
                    kernel.name(),
                    self.context.dispatch_size(count as u32),
                );
                let copies = [
                    (&out_buf, &out_staging, (count * 2 * real) as u64),
                    (&status_buf, &status_staging, (count * 4) as u64),
                ];
                self.context.read_back(encoder, &copies, |data| {
                    let values: &[f64] = bytemuck::cast_slice(data[0]);
                    let codes: &[u32] = bytemuck::cast_slice(data[1]);
                    for v in view_first..view_last {
                        for c in first..last {
                            let item = (v - view_first) * per_view + (c - first);
                            let out = c * view_count + v;
                            status[out] = codes[item];
                            fits[out] = if codes[item] == 0 {
                                [values[2 * item], values[2 * item + 1]]
                            } else {
                                [f64::NAN; 2]
                            };
                        }
                    }
                })?;
            }
        }
        Ok(())
    }
}
