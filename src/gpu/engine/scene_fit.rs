//! The triangulating calibration costs reduced on the device
//! (`shaders/kernels/calib_scene_fit.wgsl`): candidate interfaces × views, four numbers per pair
//! (a view's gap-line sums, or its rigid board fit's sum of squares) instead of a row per corner.
//! Indexing, chunking and buffers only; the geometry is in the kernel and its CPU twin
//! [`crate::calib::costs::scene`].

use super::{GROUP, GpuEngine, extend_reals, rows_from};
use crate::gpu::context::GpuError;
use crate::gpu::layout::Params;
use crate::gpu::shaders::Kernel;
use crate::model::Rig;

/// Reals per corner row of [`SceneFitInput`]: v_l xyz, v_r xyz, board point x y, pixels
/// u_l v_l u_r v_r.
pub const SCENE_ROW: usize = 12;

/// What [`GpuEngine::calib_scene_fit`] sums per (candidate, view).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneSum {
    /// (Σa², Σab, Σb², 0) of the view's gap lines g(d) = a·d + b under the axis (the candidate's
    /// air layer is ignored): the least-squares air layer's normal equation.
    GapLines,
    /// (Σ|R·P + t − X|², corners, 0, 0): the rigid board fit's 3-D sum of squares.
    Scene,
    /// (Σ|observed − projected|² over both images, corners, 0, 0) of the fitted board.
    Reprojection,
}

impl SceneSum {
    fn mode(self) -> u32 {
        match self {
            Self::GapLines => 0,
            Self::Scene => 1,
            Self::Reprojection => 2,
        }
    }
}

/// The scene-fit kernel's input, packed once per data set and kept for every call: (first vec4,
/// count, 0, 0) per view, then [`SCENE_ROW`] reals per corner.
#[derive(Debug, Clone)]
pub struct SceneFitInput {
    reals: Vec<f64>,
    views: usize,
}

impl SceneFitInput {
    /// Packs the corner `rows` (view by view) and each view's (first row, row count).
    pub fn new(rows: &[[f64; SCENE_ROW]], views: &[(usize, usize)]) -> Self {
        let mut reals = Vec::with_capacity(rows.len() * SCENE_ROW + 4 * views.len());
        let per_row = SCENE_ROW / 4;
        for &(first, count) in views {
            let at = views.len() + per_row * first;
            reals.extend_from_slice(&[at as f64, count as f64, 0.0, 0.0]);
        }
        for row in rows {
            reals.extend_from_slice(row);
        }
        Self {
            reals,
            views: views.len(),
        }
    }

    /// Number of views.
    pub fn views(&self) -> usize {
        self.views
    }
}

impl GpuEngine {
    /// The sums `what` of every view of `input` under every candidate interface (n unit, d;
    /// master frame), in the engine's precision: `sums[c · views + v]` gets view v under
    /// candidate c; `status` is 0 or the [`NoSolution`](crate::model::NoSolution) code of the
    /// first corner without an answer (2 where the candidate puts a camera outside the air, 6
    /// for a view whose corners are collinear or a corner whose water rays are parallel), the
    /// sums NaN where not 0.
    ///
    /// Panics if `sums` and `status` are not `candidates.len() · views` long.
    #[allow(clippy::too_many_arguments)]
    pub fn calib_scene_fit(
        &self,
        rig: &Rig,
        cameras: [usize; 2],
        input: &SceneFitInput,
        what: SceneSum,
        candidates: &[[f64; 4]],
        sums: &mut [[f64; 4]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        let view_count = input.views;
        assert!(
            sums.len() == candidates.len() * view_count && status.len() == sums.len(),
            "sums and status of candidates · views"
        );
        if sums.is_empty() {
            return Ok(());
        }
        let (a, b) = (
            rig.refractive_camera(cameras[0]),
            rig.refractive_camera(cameras[1]),
        );
        Self::check_layers(&a)?;
        Self::check_layers(&b)?;
        let precision = self.precision;
        let real = precision.size();
        let capacity = self.chunk_items(4 * real);
        let views_per_chunk = view_count.min((capacity / GROUP).max(1));
        // Candidates per view a multiple of the workgroup size: a workgroup's invocations share their view.
        let per_view = ((capacity / views_per_chunk) / GROUP * GROUP)
            .max(GROUP)
            .min(candidates.len().next_multiple_of(GROUP));
        let cap = self.context.max_storage_binding() as usize;
        if input.reals.len() * real > cap {
            return Err(GpuError::Unsupported(format!(
                "{} corner rows do not fit one binding of {cap} bytes",
                (input.reals.len() - 4 * view_count) / SCENE_ROW
            )));
        }
        let kernel = Kernel::CalibSceneFit;
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
            items * 4 * real,
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
        self.upload_reals(&mut buffers.scratch, &in_buf, &input.reals)?;
        let mut chunk = vec![[0.0; 4]; per_view];
        let mut values = vec![[0.0; 4]; items];
        let mut codes = vec![0u32; items];
        for first in (0..candidates.len()).step_by(per_view) {
            let last = (first + per_view).min(candidates.len());
            // Pad the chunk with its last candidate: every workgroup then shares one view.
            for (k, slot) in chunk.iter_mut().enumerate() {
                *slot = candidates[(first + k).min(last - 1)];
            }
            buffers.scratch.clear();
            extend_reals(
                &mut buffers.scratch,
                precision,
                bytemuck::cast_slice(&chunk),
            );
            self.upload(&cand_buf, &buffers.scratch)?;
            for view_first in (0..view_count).step_by(views_per_chunk) {
                let view_last = (view_first + views_per_chunk).min(view_count);
                let count = per_view * (view_last - view_first);
                params.set_info([
                    count as u32,
                    per_view as u32,
                    what.mode(),
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
                    (&out_buf, &out_staging, (count * 4 * real) as u64),
                    (&status_buf, &status_staging, (count * 4) as u64),
                ];
                let (values, codes) = (&mut values[..count], &mut codes[..count]);
                self.context.read_back(encoder, &copies, |data| {
                    codes.copy_from_slice(bytemuck::cast_slice(data[1]));
                    rows_from(data[0], precision, codes, values);
                })?;
                for v in view_first..view_last {
                    for c in first..last {
                        let item = (v - view_first) * per_view + (c - first);
                        let out = c * view_count + v;
                        status[out] = codes[item];
                        sums[out] = values[item];
                    }
                }
            }
        }
        Ok(())
    }
}
