//! Kernels over batches of candidate interfaces × corners (`calib_triangulate`,
//! `calib_projected_vop`): one item per (candidate, corner), candidate-major, in one dispatch per
//! chunk of candidates. The calibration geometry lives in the kernels and their CPU twins in
//! [`crate::calib::costs`]; here only indexing, chunking and buffers.

use super::kernels;
use super::runner::{KernelRunner, candidate_params};
use crate::calib::problem::data::CameraPair;
use crate::engine::GpuEngine;
use crate::gpu::ResidentRows;
use crate::gpu::buffers::{input_usage, rows_from, upload_reals};
use crate::gpu::compose::{KernelSource, Rows};
use crate::gpu::context::GpuError;
use crate::gpu::dispatch::Dispatch;
use crate::model::Rig;

impl KernelRunner {
    /// Triangulates every corner under every candidate interface (n unit, d: the plane n·x = d of
    /// the master frame; behind a port per camera it moves the port of `cameras[0]` and
    /// `cameras[1]` keeps its own):
    /// `air_rays` holds the two unit air directions v_l, v_r of each corner (cameras `cameras`
    /// of `rig`; rows of 6, kept on the device across calls), `points[c · corners + j]` gets x, y, z, gap of corner j under candidate c,
    /// as [`calib::costs::triangulate_corner`](crate::calib::costs::triangulate_corner).
    /// `status` is 0 or the [`NoSolution`](crate::model::NoSolution) code, the row NaN where not 0.
    ///
    /// Panics if `points` and `status` are not `candidates.len() · air_rays.len()` long.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn triangulate(
        &self,
        engine: &GpuEngine,
        rig: &Rig,
        cameras: CameraPair,
        air_rays: &ResidentRows,
        candidates: &[[f64; 4]],
        points: &mut [[f64; 4]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.run_candidates::<6, 4>(
            engine,
            &kernels::TRIANGULATE,
            rig,
            cameras,
            air_rays,
            candidates,
            points,
            status,
        )
    }

    /// The binocular VOP of every corner under every candidate axis (unit, master frame; the
    /// fourth value is ignored), projected along n into the plane ⟂ n, and its Jacobian for
    /// pixel noise, as [`costs::invariants::projected_vop`](crate::calib::costs::invariants::projected_vop):
    /// `corners` holds v_l, v_r, ∂v_l/∂u, ∂v_l/∂v, ∂v_r/∂u, ∂v_r/∂v (xyz each; rows of 18, kept
    /// on the device across calls); `vops` gets
    /// q₁, q₂ and J = ∂q/∂(u_l, v_l, u_r, v_r) column by column. Status 6 (degenerate) where the
    /// VOP is undetermined.
    ///
    /// Panics if `vops` and `status` are not `axes.len() · corners.len()` long.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn projected_vop(
        &self,
        engine: &GpuEngine,
        rig: &Rig,
        cameras: CameraPair,
        corners: &ResidentRows,
        axes: &[[f64; 4]],
        vops: &mut [[f64; 10]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.run_candidates::<18, 10>(
            engine,
            &kernels::PROJECTED_VOP,
            rig,
            cameras,
            corners,
            axes,
            vops,
            status,
        )
    }

    /// Runs a candidate kernel over `candidates` × `corners` items, chunked over candidates so
    /// that every binding stays under the adapter's cap and a chunk holds at most the engine's
    /// item limit.
    #[allow(clippy::too_many_arguments)]
    fn run_candidates<const N: usize, const M: usize>(
        &self,
        engine: &GpuEngine,
        kernel: &KernelSource,
        rig: &Rig,
        cameras: CameraPair,
        input: &ResidentRows,
        candidates: &[[f64; 4]],
        output: &mut [[f64; M]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        let corners = input.len();
        let items = candidates.len() * corners;
        assert!(
            output.len() == items && status.len() == items,
            "output and status of candidates · corners"
        );
        assert_eq!(input.width(), N, "one input row of {N} per corner");
        let (context, precision) = (engine.context(), engine.precision());
        let mut params = candidate_params(precision, rig, cameras)?;
        if items == 0 {
            return Ok(());
        }
        let s = precision.size();
        let item_bytes = M * s;
        let per_chunk = self.chunk_items(engine, item_bytes.max(4)) / corners;
        let cap = context.max_storage_binding() as usize;
        if per_chunk == 0 || corners * N * s > cap {
            return Err(GpuError::Unsupported(format!(
                "{corners} corners per candidate do not fit one dispatch ({} items, {cap} bytes per binding)",
                self.chunk_items(engine, item_bytes.max(4))
            )));
        }
        let per_chunk = per_chunk.min(candidates.len());
        let pipeline =
            context.kernel_pipeline(kernel, precision, Rows::Storage, params.layers())?;
        let dispatch = Dispatch::new(context, &pipeline, kernel.name);
        let mut guard = self.buffers();
        let buffers = &mut *guard;

        let uniform = buffers.uniform.uniform(context, params.bytes().len())?;
        let in_buf = input.on_device(context, precision)?;
        let cand_buf = buffers
            .candidates
            .get(
                context,
                "candidates",
                per_chunk * 4 * s,
                input_usage(context),
            )?
            .clone();
        let (out_buf, out_staging) =
            buffers
                .output
                .readable(context, "output", per_chunk * corners * M * s)?;
        let (status_buf, status_staging) =
            buffers
                .status
                .readable(context, "status", per_chunk * corners * 4)?;
        let bind_group = dispatch.bind(&[
            (0, &uniform),
            (1, &in_buf),
            (2, &out_buf),
            (3, &status_buf),
            (4, &cand_buf),
        ]);
        for first in (0..candidates.len()).step_by(per_chunk) {
            let last = (first + per_chunk).min(candidates.len());
            let range = first * corners..last * corners;
            let count = range.len();
            params.set_info([count as u32, corners as u32, 0, 0]);
            context.queue().write_buffer(&uniform, 0, params.bytes());
            upload_reals(
                context,
                precision,
                &cand_buf,
                bytemuck::cast_slice(&candidates[first..last]),
            )?;
            let copies = [
                (&out_buf, &out_staging, (count * M * s) as u64),
                (&status_buf, &status_staging, (count * 4) as u64),
            ];
            let (out_rows, out_status) = (&mut output[range.clone()], &mut status[range]);
            dispatch.run(&[(&bind_group, dispatch.grid(count))], &copies, |data| {
                out_status.copy_from_slice(bytemuck::cast_slice(data[1]));
                rows_from(data[0], precision, out_status, out_rows);
            })?;
        }
        Ok(())
    }
}
