//! The skeleton the per-(candidate, view) kernels share ([`calib_affine_grid`] and
//! [`calib_scene_fit`]): one item per (candidate, view), M reals out each, the corner rows
//! resident on the device, chunked over candidates and views. Indexing, chunking and buffers
//! only.
//!
//! [`calib_affine_grid`]: GpuEngine::calib_affine_grid
//! [`calib_scene_fit`]: GpuEngine::calib_scene_fit

use super::{GROUP, GpuEngine, rows_from};
use crate::gpu::context::GpuError;
use crate::gpu::engine::ResidentRows;
use crate::gpu::layout::Params;
use crate::gpu::shaders::{Kernel, Precision};
use crate::model::Rig;

/// What a per-(candidate, view) dispatch needs besides its candidates.
pub(super) struct ViewKernel<'a> {
    pub kernel: Kernel,
    pub precision: Precision,
    /// The corner rows and view table, as the kernel reads them (binding 1).
    pub input: &'a ResidentRows,
    /// Rows of corners, for the message when they do not fit one binding.
    pub corners: usize,
    pub views: usize,
    /// The kernel's third info word (`params.info.z`).
    pub info_z: u32,
}

impl GpuEngine {
    /// Runs `job` over every (candidate, view): `output[c · views + v]` and `status[c · views +
    /// v]` get the kernel's item for candidate c and view v, the row NaN where the status is not
    /// 0. A chunk holds `per_view` candidates for each of its views, view-major: every candidate
    /// where they fit one chunk (a stencil's few candidates cost a few items per view, not a
    /// workgroup), else a multiple of the workgroup size, so that each workgroup's items share
    /// one view, the last chunk padded with its last candidate.
    ///
    /// Panics if `output` and `status` are not `candidates.len() · views` long.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn run_views<const M: usize>(
        &self,
        job: ViewKernel<'_>,
        rig: &Rig,
        cameras: [usize; 2],
        candidates: &[[f64; 4]],
        output: &mut [[f64; M]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        let view_count = job.views;
        assert!(
            output.len() == candidates.len() * view_count && status.len() == output.len(),
            "output and status of candidates · views"
        );
        if output.is_empty() {
            return Ok(());
        }
        let (a, b) = (
            rig.refractive_camera(cameras[0]),
            rig.refractive_camera(cameras[1]),
        );
        Self::check_layers(&a)?;
        Self::check_layers(&b)?;
        let precision = job.precision;
        let real = precision.size();
        let capacity = self.chunk_items(M * real);
        let views_per_chunk = view_count.min((capacity / GROUP).max(1));
        let fit = ((capacity / views_per_chunk) / GROUP * GROUP).max(GROUP);
        let per_view = if candidates.len() <= fit {
            candidates.len()
        } else {
            fit
        };
        let cap = self.context.max_storage_binding() as usize;
        if job.input.reals() * real > cap {
            return Err(GpuError::Unsupported(format!(
                "{} corner rows do not fit one binding of {cap} bytes",
                job.corners
            )));
        }
        let pipeline = self.pipeline(job.kernel)?;
        let in_buf = job.input.on_device(self, precision)?;
        let mut params = Params::new(precision, &a, &b, [0; 4]);
        let mut guard = self.buffers();
        let buffers = &mut *guard;
        let uniform = self.uniform(&mut buffers.uniform, &params)?;
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
            items * M * real,
        )?;
        let (status_buf, status_staging) = self.readable(
            &mut buffers.status,
            &mut buffers.status_staging,
            "status",
            items * 4,
        )?;
        let bind_group = self.bind_group(
            &pipeline,
            job.kernel.name(),
            &[
                (0, &uniform),
                (1, &in_buf),
                (2, &out_buf),
                (3, &status_buf),
                (4, &cand_buf),
            ],
        );
        let mut chunk = vec![[0.0; 4]; per_view];
        let mut values = vec![[0.0; M]; items];
        let mut codes = vec![0u32; items];
        for first in (0..candidates.len()).step_by(per_view) {
            let last = (first + per_view).min(candidates.len());
            // Pad the last of several chunks with its last candidate: every workgroup then
            // shares one view.
            for (k, slot) in chunk.iter_mut().enumerate() {
                *slot = candidates[(first + k).min(last - 1)];
            }
            self.upload_reals_as(precision, &cand_buf, chunk.as_flattened())?;
            for view_first in (0..view_count).step_by(views_per_chunk) {
                let view_last = (view_first + views_per_chunk).min(view_count);
                let count = per_view * (view_last - view_first);
                params.set_info([count as u32, per_view as u32, job.info_z, view_first as u32]);
                self.context.queue.write_buffer(&uniform, 0, params.bytes());
                let encoder = self.encode_dispatch(
                    &pipeline,
                    &bind_group,
                    job.kernel.name(),
                    self.context.dispatch_size(count as u32),
                );
                let copies = [
                    (&out_buf, &out_staging, (count * M * real) as u64),
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
                        output[out] = values[item];
                    }
                }
            }
        }
        Ok(())
    }
}
