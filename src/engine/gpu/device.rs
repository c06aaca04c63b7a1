//! The relations over rows that live on the device ([`DeviceRows`]): upload once, run any chain
//! of relations on the device (back-project → triangulate, one point set into many cameras,
//! pixel grids made on the device), read back once or never. Each call records its kernels into
//! one submission and returns at once; the queue keeps them in order, and
//! [`read`](GpuEngine::read) waits for them.
//!
//! The row kinds and their layouts (in the engine's precision, f32 or f64; the layout of the
//! buffers is [`crate::gpu::device_rows`]'s):
//!
//! | kind             | reals per row | columns                         |
//! |------------------|---------------|---------------------------------|
//! | [`Pixels`]       | 2             | u, v (raw pixels)               |
//! | [`Points`]       | 3             | x, y, z (master frame, metres)  |
//! | [`Rays`]         | 6             | ox, oy, oz, dx, dy, dz          |
//! | [`Triangulated`] | 4             | x, y, z, residual (metres)      |
//!
//! A row with no answer carries its status through the chain: a ray whose pixel missed the
//! port gives a triangulated row with that ray's status, as the host-row calls and the CPU do.
//!
//! Matched pixels → 3-D points, rows never on the host between, in one fused kernel
//! ([`triangulate_pixels`](GpuEngine::triangulate_pixels): both back-projections and the
//! triangulation in one pass, no rays in device memory); where the rays themselves are wanted,
//! [`backproject_rows`](GpuEngine::backproject_rows) of each camera and then
//! [`triangulate_rows`](GpuEngine::triangulate_rows) give the same rows in three kernels:
//!
//! ```
//! use flatport::engine::gpu::Pixels;
//! use flatport::engine::{CpuEngine, GpuEngine};
//! use flatport::gpu::{GpuContext, Precision};
//! use nalgebra::Point3;
//!
//! let rig = flatport::io::read_rig(std::path::Path::new("data/example_rig.json"))?;
//! let (left, right) = (rig.refractive_camera(0), rig.refractive_camera(1));
//! # let Ok(context) = GpuContext::new(None) else { return Ok(()) }; // no Vulkan adapter
//! let engine = GpuEngine::new(context, Precision::F32)?;
//!
//! // Matched pixels (ul, vl, ur, vr): here the projections of points 1-2 m deep.
//! let truth = [Point3::new(0.1, -0.05, 1.2), Point3::new(-0.2, 0.1, 2.0)];
//! let matches: Vec<[f64; 4]> = truth
//!     .iter()
//!     .map(|p| {
//!         let (l, r) = (left.project(p).unwrap(), right.project(p).unwrap());
//!         [l.x, l.y, r.x, r.y]
//!     })
//!     .collect();
//! let pixels_l: Vec<[f64; 2]> = matches.iter().map(|m| [m[0], m[1]]).collect();
//! let pixels_r: Vec<[f64; 2]> = matches.iter().map(|m| [m[2], m[3]]).collect();
//!
//! let on_l = engine.upload::<Pixels>(&pixels_l)?; // the one copy to the device
//! let on_r = engine.upload::<Pixels>(&pixels_r)?;
//! let points = engine.triangulate_pixels(&left, &right, &on_l, &on_r)?; // one kernel
//! let (xyzr, status) = engine.read(&points)?; // the one copy back
//!
//! // The same points through the rays, which stay on the device.
//! let rays_l = engine.backproject_rows(&left, &on_l)?;
//! let rays_r = engine.backproject_rows(&right, &on_r)?;
//! let (chained, _) = engine.read(&engine.triangulate_rows(&rays_l, &rays_r)?)?;
//!
//! // The points again, and as the f64 CPU reference triangulates the same matches.
//! let mut cpu = vec![[0.0; 4]; matches.len()];
//! let mut cpu_status = vec![0; matches.len()];
//! CpuEngine::new(None).triangulate(&left, &right, &matches, &mut cpu, &mut cpu_status);
//! assert_eq!(status, [0, 0]);
//! assert_eq!(cpu_status, [0, 0]);
//! for (((g, h), c), p) in xyzr.iter().zip(&chained).zip(&cpu).zip(&truth) {
//!     assert!((0..3).all(|k| (g[k] - c[k]).abs() < 1e-4 && (g[k] - p[k]).abs() < 1e-4));
//!     assert!((0..3).all(|k| (g[k] - h[k]).abs() < 1e-4));
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use bytemuck::Zeroable;

use super::{GpuEngine, kernels};
use crate::gpu::compose::{KernelSource, Precision, Rows};
use crate::gpu::context::GpuError;
use crate::gpu::device_rows::{DeviceRows, RowKind};
use crate::gpu::dispatch::{Dispatch, KernelTimer, Timestamps, chunk_items};
use crate::gpu::layout::{Params, check_layers};
use crate::model::RefractiveCamera;

/// Raw pixels: u, v.
#[derive(Debug)]
pub enum Pixels {}

/// Points in the master frame: x, y, z (metres).
#[derive(Debug)]
pub enum Points {}

/// Rays in the water, master frame: origin on the outer interface (ox, oy, oz), unit direction
/// (dx, dy, dz).
#[derive(Debug)]
pub enum Rays {}

/// Triangulated points: x, y, z and the distance between the two rays there (metres).
#[derive(Debug)]
pub enum Triangulated {}

impl RowKind for Pixels {
    const WIDTH: usize = 2;
    const COLUMNS: &'static [&'static str] = &["u", "v"];
    type Row = [f64; 2];
}

impl RowKind for Points {
    const WIDTH: usize = 3;
    const COLUMNS: &'static [&'static str] = &["x", "y", "z"];
    type Row = [f64; 3];
}

impl RowKind for Rays {
    const WIDTH: usize = 6;
    const COLUMNS: &'static [&'static str] = &["ox", "oy", "oz", "dx", "dy", "dz"];
    type Row = [f64; 6];
}

impl RowKind for Triangulated {
    const WIDTH: usize = 4;
    const COLUMNS: &'static [&'static str] = &["x", "y", "z", "residual"];
    type Row = [f64; 4];
}

/// A buffer a kernel binds, `item_bytes` per row: a range of it per chunk.
struct Bound<'a> {
    binding: u32,
    buffer: &'a wgpu::Buffer,
    item_bytes: usize,
}

impl<'a> Bound<'a> {
    /// The rows' reals at `binding`.
    fn rows<K: RowKind>(binding: u32, rows: &'a DeviceRows<K>) -> Self {
        Self {
            binding,
            buffer: rows.buffer(),
            item_bytes: rows.stride_bytes(),
        }
    }

    /// The rows' statuses at `binding`.
    fn status<K: RowKind>(binding: u32, rows: &'a DeviceRows<K>) -> Self {
        Self {
            binding,
            buffer: rows.status_buffer(),
            item_bytes: 4,
        }
    }
}

impl GpuEngine {
    /// Uploads host rows of kind `K` to the device in the engine's precision: the one copy from
    /// the host. Rows beyond what the precision holds, or not finite, get status
    /// [`OutOfRange`](crate::model::NoSolution::OutOfRange) as in the host-row calls.
    pub fn upload<K: RowKind>(&self, rows: &[K::Row]) -> Result<DeviceRows<K>, GpuError> {
        DeviceRows::upload(&self.context, self.precision, rows)
    }

    /// The rows and statuses of `rows`, read back after every kernel submitted before: NaN rows
    /// where the status is not 0 ([`DeviceRows::read`]).
    pub fn read<K: RowKind>(
        &self,
        rows: &DeviceRows<K>,
    ) -> Result<(Vec<K::Row>, Vec<u32>), GpuError> {
        rows.read(&self.context)
    }

    /// [`read`](Self::read) with the rows flat, `K::WIDTH` reals per row
    /// ([`DeviceRows::read_reals`]).
    pub fn read_reals<K: RowKind>(
        &self,
        rows: &DeviceRows<K>,
    ) -> Result<(Vec<f64>, Vec<u32>), GpuError> {
        rows.read_reals(&self.context)
    }

    /// Rows of kind `K` in the caller's own buffers on this engine's device and precision
    /// ([`DeviceRows::from_buffers`]): flatport's kernels read and write them in place.
    pub fn rows_from_buffers<K: RowKind>(
        &self,
        rows: wgpu::Buffer,
        status: Option<wgpu::Buffer>,
        len: usize,
    ) -> Result<DeviceRows<K>, GpuError> {
        DeviceRows::from_buffers(&self.context, self.precision, rows, status, len)
    }

    /// Back-projects pixels on the device into rays in the water (as
    /// [`backproject`](Self::backproject)); a pixel row without an answer gives its status.
    ///
    /// Errors: rows of another device or precision ([`GpuError::Rows`]), a camera with more
    /// layers than the kernels take.
    pub fn backproject_rows(
        &self,
        camera: &RefractiveCamera,
        pixels: &DeviceRows<Pixels>,
    ) -> Result<DeviceRows<Rays>, GpuError> {
        pixels.check_on(&self.context, self.precision, "the pixels")?;
        check_layers(camera)?;
        let rays = DeviceRows::allocate(&self.context, self.precision, pixels.len())?;
        let params = Params::new(self.precision, camera, camera, [0; 4]);
        let mut encoder = self.encoder("backproject rows");
        let bindings = [
            Bound::rows(1, pixels),
            Bound::rows(2, &rays),
            Bound::status(3, &rays),
        ];
        self.encode(
            &mut encoder,
            &kernels::BACKPROJECT,
            params,
            pixels.len(),
            &bindings,
            no_info,
        )?;
        self.carry_status(&mut encoder, &rays, &[pixels.status_buffer()])?;
        self.submit(encoder, "backproject rows")?;
        Ok(rays)
    }

    /// Projects points on the device into `camera`'s raw pixels (as [`project`](Self::project):
    /// the fast kernel, then the safeguarded one on the rows it leaves, on the device); a point
    /// row without an answer gives its status.
    ///
    /// Errors as [`backproject_rows`](Self::backproject_rows).
    pub fn project_rows(
        &self,
        camera: &RefractiveCamera,
        points: &DeviceRows<Points>,
    ) -> Result<DeviceRows<Pixels>, GpuError> {
        Ok(self
            .project_many(points, std::slice::from_ref(camera))?
            .remove(0))
    }

    /// Projects one point set on the device into each of `cameras` (one submission, the points
    /// uploaded once): the pixels of camera k are the k-th rows returned.
    ///
    /// Errors as [`backproject_rows`](Self::backproject_rows).
    pub fn project_many(
        &self,
        points: &DeviceRows<Points>,
        cameras: &[RefractiveCamera],
    ) -> Result<Vec<DeviceRows<Pixels>>, GpuError> {
        points.check_on(&self.context, self.precision, "the points")?;
        for camera in cameras {
            check_layers(camera)?;
        }
        let mut encoder = self.encoder("project rows");
        let mut all = Vec::with_capacity(cameras.len());
        for camera in cameras {
            let pixels = DeviceRows::allocate(&self.context, self.precision, points.len())?;
            let params = Params::new(self.precision, camera, camera, [0; 4]);
            let bindings = [
                Bound::rows(1, points),
                Bound::rows(2, &pixels),
                Bound::status(3, &pixels),
            ];
            self.encode(
                &mut encoder,
                &kernels::PROJECT,
                params,
                points.len(),
                &bindings,
                no_info,
            )?;
            self.encode(
                &mut encoder,
                &kernels::PROJECT_RETRY,
                params,
                points.len(),
                &bindings,
                no_info,
            )?;
            self.carry_status(&mut encoder, &pixels, &[points.status_buffer()])?;
            all.push(pixels);
        }
        self.submit(encoder, "project rows")?;
        Ok(all)
    }

    /// Triangulates row i of `a` with row i of `b` (water rays of two cameras, as
    /// [`backproject_rows`](Self::backproject_rows) gives them): the midpoint of their closest
    /// approach and their distance there, as [`triangulate`](Self::triangulate) after its
    /// back-projections. A row whose ray in `a` has no answer gets that ray's status, else one
    /// whose ray in `b` has none gets that one's (the CPU's order).
    ///
    /// Errors: rows of unequal lengths, of another device or precision ([`GpuError::Rows`]).
    pub fn triangulate_rows(
        &self,
        a: &DeviceRows<Rays>,
        b: &DeviceRows<Rays>,
    ) -> Result<DeviceRows<Triangulated>, GpuError> {
        a.check_on(&self.context, self.precision, "the rays a")?;
        b.check_on(&self.context, self.precision, "the rays b")?;
        if a.len() != b.len() {
            return Err(GpuError::Rows(format!(
                "triangulation pairs row i of the rays a with row i of the rays b: {} rows a, {} rows b",
                a.len(),
                b.len()
            )));
        }
        let points = DeviceRows::allocate(&self.context, self.precision, a.len())?;
        let mut encoder = self.encoder("triangulate rows");
        let bindings = [
            Bound::rows(1, a),
            Bound::rows(2, &points),
            Bound::status(3, &points),
            Bound::rows(4, b),
        ];
        let params = self.camera_free_params();
        self.encode(
            &mut encoder,
            &kernels::TRIANGULATE_RAYS,
            params,
            a.len(),
            &bindings,
            no_info,
        )?;
        // b first: a's status, carried last, wins where both rays have none.
        self.carry_status(
            &mut encoder,
            &points,
            &[b.status_buffer(), a.status_buffer()],
        )?;
        self.submit(encoder, "triangulate rows")?;
        Ok(points)
    }

    /// Triangulates matched pixels on the device, fused: row i of `pixels_a` (raw pixels of
    /// camera `a`) with row i of `pixels_b` (camera `b`), each back-projected through its own
    /// camera and port, then the midpoint of the two water rays' closest approach and their
    /// distance there, in one kernel: no rays in device memory between (the same rows as
    /// [`backproject_rows`](Self::backproject_rows) of both followed by
    /// [`triangulate_rows`](Self::triangulate_rows), in one pass over the pixels instead of three
    /// kernels and their status merges). A row gets the first failure in the CPU's order: pixel a's
    /// status where it is not 0 (a pixel out of range, say), else pixel b's, else that of a's
    /// back-projection, else b's, else the triangulation's, as the CPU and
    /// [`triangulate`](Self::triangulate) give for the same matches (ul, vl, ur, vr). The
    /// three-kernel chain gives the same statuses except where a's back-projection fails and
    /// pixel b has a status of its own: there its ray a's status wins.
    ///
    /// Errors: rows of unequal lengths, of another device or precision ([`GpuError::Rows`]), a
    /// camera with more layers than the kernels take.
    pub fn triangulate_pixels(
        &self,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        pixels_a: &DeviceRows<Pixels>,
        pixels_b: &DeviceRows<Pixels>,
    ) -> Result<DeviceRows<Triangulated>, GpuError> {
        pixels_a.check_on(&self.context, self.precision, "the pixels a")?;
        pixels_b.check_on(&self.context, self.precision, "the pixels b")?;
        if pixels_a.len() != pixels_b.len() {
            return Err(GpuError::Rows(format!(
                "triangulation pairs row i of the pixels a with row i of the pixels b: {} rows a, {} rows b",
                pixels_a.len(),
                pixels_b.len()
            )));
        }
        check_layers(a)?;
        check_layers(b)?;
        let points = DeviceRows::allocate(&self.context, self.precision, pixels_a.len())?;
        let params = Params::new(self.precision, a, b, [0; 4]);
        let mut encoder = self.encoder("triangulate pixels");
        let bindings = [
            Bound::rows(1, pixels_a),
            Bound::rows(2, &points),
            Bound::status(3, &points),
            Bound::rows(4, pixels_b),
            Bound::status(5, pixels_a),
            Bound::status(6, pixels_b),
        ];
        self.encode(
            &mut encoder,
            &kernels::TRIANGULATE_PIXELS,
            params,
            pixels_a.len(),
            &bindings,
            no_info,
        )?;
        self.submit(encoder, "triangulate pixels")?;
        Ok(points)
    }

    /// The pixels of a `width` × `height` grid every `step` pixels, made on the device, row-major:
    /// row i is (u, v) = step · (i mod width, i div width). `pixel_grid(w, h, 1)` is every pixel
    /// of a w × h image (as [`backproject_grid`](Self::backproject_grid) generates them).
    ///
    /// Errors ([`GpuError::Rows`]): a step of 0, more than 2³² − 1 pixels.
    pub fn pixel_grid(
        &self,
        width: u32,
        height: u32,
        step: u32,
    ) -> Result<DeviceRows<Pixels>, GpuError> {
        if step == 0 {
            return Err(GpuError::Rows(
                "a pixel grid needs a step of at least 1 pixel".into(),
            ));
        }
        let len = u64::from(width) * u64::from(height);
        if len > u64::from(u32::MAX) {
            return Err(GpuError::Rows(format!(
                "a pixel grid of {width} × {height} has more than 2³² − 1 pixels"
            )));
        }
        let pixels = DeviceRows::allocate(&self.context, self.precision, len as usize)?;
        let mut encoder = self.encoder("pixel grid");
        let bindings = [Bound::rows(2, &pixels), Bound::status(3, &pixels)];
        let params = self.camera_free_params();
        self.encode(
            &mut encoder,
            &kernels::PIXEL_GRID,
            params,
            pixels.len(),
            &bindings,
            |first, count| [count as u32, width, first as u32, step],
        )?;
        self.submit(encoder, "pixel grid")?;
        Ok(pixels)
    }

    /// Seconds the device spends on the kernels `work` submits (a chain of the calls above, its
    /// rows already on the device): the fastest of `repeats` runs after one warm-up, with the
    /// clock that measured it. Where the device has TIMESTAMP_QUERY, GPU timestamps written by an
    /// empty compute pass submitted before `work` and another after it (the queue runs them in
    /// order: the kernels' own time); else host clocks around `work` and the wait for it (which
    /// add the driver's latency).
    pub fn seconds_on_device(
        &self,
        repeats: usize,
        mut work: impl FnMut() -> Result<(), GpuError>,
    ) -> Result<(f64, KernelTimer), GpuError> {
        let mut best = f64::INFINITY;
        let Some(stamps) = Timestamps::new(&self.context, "device rows time")? else {
            for _ in 0..=repeats {
                let started = std::time::Instant::now();
                work()?;
                self.context.wait()?;
                best = best.min(started.elapsed().as_secs_f64());
            }
            return Ok((best, KernelTimer::Host));
        };
        // An empty compute pass that writes timestamp `index` at its beginning.
        let stamp = |index: u32| {
            let mut encoder = self.encoder("device rows time");
            encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("device rows time"),
                timestamp_writes: Some(stamps.writes(Some(index), None)),
            });
            encoder
        };
        for _ in 0..=repeats {
            self.context.submit(stamp(0).finish());
            work()?;
            best = best.min(stamps.seconds(&self.context, stamp(1))?);
        }
        Ok((best, KernelTimer::GpuTimestamp))
    }

    /// The uniform of a kernel that reads no camera (only `info`).
    fn camera_free_params(&self) -> Params {
        match self.precision {
            Precision::F32 => Params::F32(Zeroable::zeroed()),
            Precision::F64 => Params::F64(Zeroable::zeroed()),
        }
    }

    fn encoder(&self, label: &str) -> wgpu::CommandEncoder {
        self.context
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
    }

    /// Submits `encoder` without waiting, and reports what wgpu refused while recording it.
    fn submit(&self, encoder: wgpu::CommandEncoder, what: &str) -> Result<(), GpuError> {
        self.context.submit(encoder.finish());
        self.context.check(what)
    }

    /// Records the merge of each of `inputs` (status buffers, one `u32` per row of `output`, in
    /// order: a later one wins) into `output`'s statuses.
    fn carry_status<K: RowKind>(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        output: &DeviceRows<K>,
        inputs: &[&wgpu::Buffer],
    ) -> Result<(), GpuError> {
        for input in inputs {
            let bindings = [
                Bound::status(3, output),
                Bound {
                    binding: 4,
                    buffer: input,
                    item_bytes: 4,
                },
            ];
            let params = self.camera_free_params();
            self.encode(
                encoder,
                &kernels::MERGE_STATUS,
                params,
                output.len(),
                &bindings,
                no_info,
            )?;
        }
        Ok(())
    }

    /// Records `kernel` over `items` rows into `encoder`: chunks within the binding cap (whole
    /// workgroups, so every range starts aligned), each with its own uniform (`params` with
    /// `info(first row, rows)`) and ranges of `bindings`.
    fn encode(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        kernel: &KernelSource,
        mut params: Params,
        items: usize,
        bindings: &[Bound<'_>],
        info: impl Fn(usize, usize) -> [u32; 4],
    ) -> Result<(), GpuError> {
        if items == 0 {
            return Ok(());
        }
        let widest = bindings.iter().map(|b| b.item_bytes).max().unwrap_or(4);
        let chunk = chunk_items(
            self.context.max_storage_binding(),
            widest,
            self.max_chunk_items,
        );
        let pipeline =
            self.context
                .kernel_pipeline(kernel, self.precision, Rows::Storage, params.layers())?;
        let dispatch = Dispatch::new(&self.context, &pipeline, kernel.name);
        let mut groups = Vec::new();
        for first in (0..items).step_by(chunk) {
            let count = chunk.min(items - first);
            params.set_info(info(first, count));
            let uniform = self.context.buffer(
                "params",
                (params.bytes().len() as u64).next_multiple_of(16),
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            )?;
            self.context
                .queue()
                .write_buffer(&uniform, 0, params.bytes());
            let mut resources = vec![(0, uniform.as_entire_binding())];
            for bound in bindings {
                let size = std::num::NonZeroU64::new((count * bound.item_bytes) as u64);
                resources.push((
                    bound.binding,
                    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: bound.buffer,
                        offset: (first * bound.item_bytes) as u64,
                        size,
                    }),
                ));
            }
            let bind_group = dispatch.bind_resources(resources);
            let grid = dispatch.grid(count.div_ceil(kernel.rows_per_invocation));
            groups.push((bind_group, grid));
        }
        let passes: Vec<_> = groups.iter().map(|(g, grid)| (g, *grid)).collect();
        dispatch.record(encoder, &passes, None);
        Ok(())
    }
}

/// `info` of a kernel that needs only its row count.
fn no_info(_first: usize, count: usize) -> [u32; 4] {
    [count as u32, 0, 0, 0]
}
