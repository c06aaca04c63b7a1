//! The GPU engine: the relations of [`crate::model`] (back-projection, forward projection with
//! its safeguarded retry, VOPs, triangulation, binocular VOPs, image-grid back-projection) as
//! WGSL kernels over batches of any size, f32 or f64, on a [`GpuContext`]. [`kernels`] is their
//! catalogue; the wgpu toolkit underneath (composition, pipeline cache, buffers, dispatch,
//! streaming) is [`crate::gpu`].
//!
//! Batches are cut into chunks that fit the adapter's storage-binding cap (128 MiB on lavapipe)
//! and dispatch limits; buffers are kept and reused across chunks and calls, replaced only when a
//! larger chunk or another usage needs it. On adapters that share the host's memory the host maps
//! the kernels' buffers directly; elsewhere it goes through staging buffers. The row kernels
//! (back-projection, projection, VOPs, triangulation) stream their chunks through a ring of
//! buffer sets so that upload, kernel and read-back overlap, and take f64 or f32 host slices
//! ([`HostReal`]); the other calls take f64 slices and convert for f32 kernels.
//! Rows with no answer get their status code and NaN.
//!
//! [`device`] runs the same relations on rows that live on the device
//! ([`DeviceRows`](crate::gpu::DeviceRows)): upload once, chain relations, read back once.

use std::sync::{Arc, Mutex, MutexGuard};

use crate::gpu::buffers::{Slot, SlotPair, rows_from};
use crate::gpu::compose::{KernelSource, Precision, Rows, STATUS_RETRY, WORKGROUP_SIZE};
use crate::gpu::context::{GpuContext, GpuError};
use crate::gpu::dispatch::{
    Dispatch, GROUP, KernelTimer, MAX_CHUNK_ITEMS, MAX_GROUPS_PER_DIMENSION, chunk_items,
};
use crate::gpu::layout::{Params, check_layers};
use crate::gpu::stream::{HostReal, Ring, default_stream_chunk_rows};
use crate::model::RefractiveCamera;

pub mod device;
pub mod kernels;

pub use device::{Pixels, Points, Rays, Triangulated};

/// Device and staging buffers, reused across chunks and calls.
#[derive(Default)]
struct Buffers {
    uniform: Slot,
    output: SlotPair,
    status: SlotPair,
    /// The buffer sets the row kernels stream their chunks through.
    ring: Ring,
}

/// The batch engine on a GPU: the relation kernels on one adapter at one precision.
pub struct GpuEngine {
    context: GpuContext,
    precision: Precision,
    buffers: Mutex<Buffers>,
    /// Most items per dispatch ([`MAX_CHUNK_ITEMS`] unless a test lowers it).
    max_chunk_items: usize,
    /// Most rows per streamed chunk of the row kernels
    /// ([`default_stream_chunk_rows`](crate::gpu::default_stream_chunk_rows) unless changed).
    stream_chunk_rows: usize,
}

impl GpuEngine {
    /// The backend on `context` at `precision`. Errors when f64 is asked of an adapter without
    /// SHADER_F64.
    pub fn new(context: GpuContext, precision: Precision) -> Result<Self, GpuError> {
        if precision == Precision::F64 && !context.adapter().f64 {
            return Err(GpuError::Unsupported(format!(
                "adapter '{}' has no SHADER_F64: use --precision f32 or the CPU",
                context.adapter().name
            )));
        }
        let stream_chunk_rows = default_stream_chunk_rows(&context);
        Ok(Self {
            context,
            precision,
            buffers: Mutex::default(),
            max_chunk_items: MAX_CHUNK_ITEMS,
            stream_chunk_rows,
        })
    }

    /// The context (adapter, device).
    pub fn context(&self) -> &GpuContext {
        &self.context
    }

    /// The kernels' precision.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Lowers the most items per dispatch below [`MAX_CHUNK_ITEMS`] (at least one workgroup,
    /// [`WORKGROUP_SIZE`]; values above it are capped), so that small batches run over several
    /// chunks. For tests of the chunking.
    pub fn set_max_chunk_items(&mut self, items: usize) {
        self.max_chunk_items = items.clamp(GROUP, MAX_CHUNK_ITEMS);
    }

    /// The most items per dispatch now ([`MAX_CHUNK_ITEMS`] unless lowered): also the limit of
    /// the calibration backends that run on this engine.
    pub fn max_chunk_items(&self) -> usize {
        self.max_chunk_items
    }

    /// Sets the most rows per streamed chunk of the row kernels (at least 1; the default is
    /// [`default_stream_chunk_rows`]). `usize::MAX` runs a batch in as few chunks as the bindings
    /// allow, so one that fits one chunk runs without any overlap: for measuring what the
    /// streaming gains.
    pub fn set_stream_chunk_rows(&mut self, rows: usize) {
        self.stream_chunk_rows = rows.max(1);
    }

    /// The most rows per streamed chunk of the row kernels now.
    pub fn stream_chunk_rows(&self) -> usize {
        self.stream_chunk_rows
    }

    /// The compiled pipeline of `kernel` for the cameras of `params` (its `RIG_LAYERS`: their
    /// most layers), from the context's cache.
    fn pipeline(
        &self,
        kernel: &KernelSource,
        params: &Params,
    ) -> Result<Arc<wgpu::ComputePipeline>, GpuError> {
        self.context
            .kernel_pipeline(kernel, self.precision, Rows::Storage, params.layers())
    }

    fn buffers(&self) -> MutexGuard<'_, Buffers> {
        self.buffers.lock().expect("buffer cache")
    }

    /// Items per chunk when each item needs at most `bytes_per_item` of one binding, at most the
    /// engine's item limit.
    fn chunk_items(&self, bytes_per_item: usize) -> usize {
        chunk_items(
            self.context.max_storage_binding(),
            bytes_per_item,
            self.max_chunk_items,
        )
    }

    /// Runs a kernel mapping N reals to M reals per item with cameras `a` and `b`, streaming the
    /// chunks (at most [`stream_chunk_rows`](Self::stream_chunk_rows) rows each) through the
    /// ring of buffer sets.
    fn run_map<H: HostReal, const N: usize, const M: usize>(
        &self,
        kernel: &KernelSource,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        input: &[[H; N]],
        output: &mut [[H; M]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.run_map_in(kernel, a, b, input, output, status, self.stream_chunk_rows)
    }

    /// [`run_map`](Self::run_map) in chunks of at most `max_rows` rows (and what the bindings
    /// allow): [`kernel_seconds`](Self::kernel_seconds) puts a whole chunk on the first lane.
    #[allow(clippy::too_many_arguments)]
    fn run_map_in<H: HostReal, const N: usize, const M: usize>(
        &self,
        kernel: &KernelSource,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        input: &[[H; N]],
        output: &mut [[H; M]],
        status: &mut [u32],
        max_rows: usize,
    ) -> Result<(), GpuError> {
        assert!(
            input.len() == output.len() && input.len() == status.len(),
            "input, output and status of equal length"
        );
        check_layers(a)?;
        check_layers(b)?;
        if input.is_empty() {
            return Ok(());
        }
        let chunk = self
            .chunk_items(N.max(M) * self.precision.size())
            .min(max_rows.max(1))
            .min(input.len());
        let params = Params::new(self.precision, a, b, [0; 4]);
        let pipeline = self.pipeline(kernel, &params)?;
        self.buffers().ring.map(
            &self.context,
            kernel,
            &pipeline,
            self.precision,
            params,
            chunk,
            input,
            output,
            status,
        )
    }

    /// Most rows of a row kernel with N input and M output reals per dispatch (one chunk): the
    /// most [`kernel_seconds`](Self::kernel_seconds) takes.
    pub fn chunk_rows<const N: usize, const M: usize>(&self) -> usize {
        self.chunk_items(N.max(M) * self.precision.size())
    }

    /// Seconds per dispatch of `kernel` over `input` (one chunk at most), the data already on the
    /// device: the kernel-only time, without upload or read-back. Runs `repeats` dispatches after
    /// one warm-up and returns the fastest, with the clock that measured it: GPU timestamps written
    /// at the start and end of the compute pass where the device has TIMESTAMP_QUERY (the kernel's
    /// own time), else host clocks around submit and wait (which add the driver's latency).
    pub fn kernel_seconds<const N: usize, const M: usize>(
        &self,
        kernel: &KernelSource,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        input: &[[f64; N]],
        repeats: usize,
    ) -> Result<(f64, KernelTimer), GpuError> {
        let mut output = vec![[0.0f64; M]; input.len()];
        let mut status = vec![0; input.len()];
        let chunk = self.chunk_items(N.max(M) * self.precision.size());
        if input.len() > chunk {
            return Err(GpuError::Unsupported(format!(
                "kernel_seconds takes one chunk ({chunk} items) at most, got {}",
                input.len()
            )));
        }
        // Uploads the data and leaves it resident in the first lane's buffers.
        self.run_map_in(kernel, a, b, input, &mut output, &mut status, usize::MAX)?;
        let pipeline = self.pipeline(kernel, &Params::new(self.precision, a, b, [0; 4]))?;
        let [uniform, in_buf, out_buf, status_buf] = self
            .buffers()
            .ring
            .first_lane()
            .expect("allocated by run_map");
        let dispatch = Dispatch::new(&self.context, &pipeline, kernel.name);
        let bind_group =
            dispatch.bind(&[(0, &uniform), (1, &in_buf), (2, &out_buf), (3, &status_buf)]);
        let groups = dispatch.grid(input.len().div_ceil(kernel.rows_per_invocation));
        dispatch.seconds(&bind_group, groups, repeats)
    }

    /// Back-projects raw pixels of `camera` into `rays` (origin xyz on the outer interface, unit
    /// direction xyz, master frame), in f64 or f32 on the host ([`HostReal`]; a host type equal
    /// to the kernel precision goes to and from the device unconverted). `status[i]` is 0 or the [`NoSolution`](crate::model::NoSolution)
    /// code, and the row NaN, exactly where the CPU path has no answer (up to rounding at the
    /// boundaries in f32).
    ///
    /// Panics if the slices differ in length.
    pub fn backproject<H: HostReal>(
        &self,
        camera: &RefractiveCamera,
        pixels: &[[H; 2]],
        rays: &mut [[H; 6]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.run_map(&kernels::BACKPROJECT, camera, camera, pixels, rays, status)
    }

    /// Forward projection of points (master frame) to raw pixels; status as in
    /// [`backproject`](Self::backproject). One kernel runs the unbracketed Newton iteration on
    /// every row (`project_near_pair` in `shaders/lib/air_path.wgsl`); the rows it does not settle (a
    /// medium less dense than air, a point not in the water, grazing rays) run again through the
    /// safeguarded kernel, which decides them as the CPU does.
    pub fn project<H: HostReal>(
        &self,
        camera: &RefractiveCamera,
        points: &[[H; 3]],
        pixels: &mut [[H; 2]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.run_map(&kernels::PROJECT, camera, camera, points, pixels, status)?;
        // The rows the unbracketed iteration left: through every safeguard.
        let retry: Vec<usize> = (0..status.len())
            .filter(|&i| status[i] == STATUS_RETRY)
            .collect();
        if !retry.is_empty() {
            let again: Vec<[H; 3]> = retry.iter().map(|&i| points[i]).collect();
            let mut out = vec![[H::from_f64(0.0); 2]; again.len()];
            let mut codes = vec![0; again.len()];
            self.run_map(
                &kernels::PROJECT_SAFEGUARDED,
                camera,
                camera,
                &again,
                &mut out,
                &mut codes,
            )?;
            for (k, &i) in retry.iter().enumerate() {
                (pixels[i], status[i]) = (out[k], codes[k]);
            }
        }
        Ok(())
    }

    /// VOPs of points: depth, vop_distance, vop xyz, incidence (radians), as
    /// [`RefractiveCamera::vop`].
    pub fn vop<H: HostReal>(
        &self,
        camera: &RefractiveCamera,
        points: &[[H; 3]],
        vops: &mut [[H; 6]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.run_map(&kernels::VOP, camera, camera, points, vops, status)?;
        // The kernel returns tan a: WGSL has no f64 arctangent.
        for row in vops.iter_mut() {
            row[5] = H::from_f64(row[5].to_f64().atan());
        }
        Ok(())
    }

    /// Triangulates matches (ul, vl, ur, vr: raw pixels in `a` and `b`) into x, y, z, residual
    /// (master frame, metres), as [`CpuEngine::triangulate`](crate::engine::CpuEngine::triangulate):
    /// the chain back-project → triangulate runs in one kernel (both pixels back-projected to
    /// water rays, then the midpoint of closest approach), with no host round trip between.
    /// Status as in [`backproject`](Self::backproject).
    pub fn triangulate<H: HostReal>(
        &self,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        matches: &[[H; 4]],
        points: &mut [[H; 4]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.run_map(&kernels::TRIANGULATE, a, b, matches, points, status)
    }

    /// Binocular VOPs of matches (ul, vl, ur, vr): left VOP xyz, right VOP xyz, axis offset m,
    /// conditioning, as [`binocular_vop`](crate::model::binocular_vop) with `a`'s axis.
    pub fn binocular_vop<H: HostReal>(
        &self,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        matches: &[[H; 4]],
        vops: &mut [[H; 8]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.run_map(&kernels::BINOCULAR_VOP, a, b, matches, vops, status)
    }

    /// Back-projects every pixel (u, v) = (column, row) of a `width` × `height` image, pixels
    /// generated in the shader; `rays` and `status` are row-major, `width · height` long.
    pub fn backproject_grid(
        &self,
        camera: &RefractiveCamera,
        width: u32,
        height: u32,
        rays: &mut [[f64; 6]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.backproject_grid_rows(camera, width, 0, height, rays, status)
    }

    /// [`backproject_grid`](Self::backproject_grid) of the image rows `first_row ..
    /// first_row + height` only (a band of a larger image): `rays[i]` is pixel (i mod width,
    /// first_row + i div width).
    pub fn backproject_grid_rows(
        &self,
        camera: &RefractiveCamera,
        width: u32,
        first_row: u32,
        height: u32,
        rays: &mut [[f64; 6]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        let (w, h) = (width as usize, height as usize);
        assert!(
            rays.len() == w * h && status.len() == w * h,
            "rays and status of width · height"
        );
        if w == 0 || h == 0 {
            return Ok(());
        }
        check_layers(camera)?;
        let s = self.precision.size();
        let rows = (self.chunk_items(6 * s) / w).clamp(1, MAX_GROUPS_PER_DIMENSION);
        let mut params = Params::new(self.precision, camera, camera, [0; 4]);
        let pipeline = self.pipeline(&kernels::BACKPROJECT_GRID, &params)?;
        let dispatch = Dispatch::new(&self.context, &pipeline, "backproject_grid");
        let mut guard = self.buffers();
        let buffers = &mut *guard;
        let uniform = buffers
            .uniform
            .uniform(&self.context, params.bytes().len())?;
        let (out_buf, out_staging) =
            buffers
                .output
                .readable(&self.context, "output", rows * w * 6 * s)?;
        let (status_buf, status_staging) =
            buffers
                .status
                .readable(&self.context, "status", rows * w * 4)?;
        let bind_group = dispatch.bind(&[(0, &uniform), (2, &out_buf), (3, &status_buf)]);
        for first in (0..h).step_by(rows) {
            let count = rows.min(h - first);
            let items = count * w;
            params.set_info([items as u32, width, first_row + first as u32, 0]);
            self.context
                .queue()
                .write_buffer(&uniform, 0, params.bytes());
            let groups = (width.div_ceil(WORKGROUP_SIZE), count as u32);
            let copies = [
                (&out_buf, &out_staging, (items * 6 * s) as u64),
                (&status_buf, &status_staging, (items * 4) as u64),
            ];
            let range = first * w..first * w + items;
            let (out_rows, out_status) = (&mut rays[range.clone()], &mut status[range]);
            dispatch.run(&[(&bind_group, groups)], &copies, |data| {
                out_status.copy_from_slice(bytemuck::cast_slice(data[1]));
                rows_from(data[0], self.precision, out_status, out_rows);
            })?;
        }
        Ok(())
    }
}
