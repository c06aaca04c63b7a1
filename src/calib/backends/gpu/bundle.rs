//! The bundle's residuals on the GPU ([`GpuResiduals`], a [`ResidualBackend`]): one dispatch of
//! `calib_bundle_residuals` (`shaders/calib/bundle_residuals.wgsl`) per chunk of a stencil batch,
//! evaluations × observed corners, in f64. The corners go to the device once, at the first call,
//! and stay there for every later call of the backend; a call uploads only its camera sets, pose
//! sets and evaluation table and reads back two reals and a status per (evaluation, corner).
//! Indexing, chunking and buffers only; the geometry is the kernel's and its CPU twin's,
//! [`CpuResiduals`].

use std::ops::Deref;
use std::sync::{Arc, Mutex};

use bytemuck::{Pod, Zeroable};
use nalgebra::Vector2;

use super::kernels;
use crate::calib::backends::residuals::{
    CpuResiduals, ObservedCorner, ResidualBackend, Residuals, StencilBatch,
};
use crate::engine::GpuEngine;
use crate::gpu::buffers::{Slot, SlotPair, input_usage, upload};
use crate::gpu::context::GpuError;
use crate::gpu::dispatch::{Dispatch, chunk_items};
use crate::gpu::layout::{CameraF64, Params, check_layers};
use crate::gpu::{Precision, ResidentRows, Rows};
use crate::model::RefractiveCamera;

/// Reals per corner row: target point x, y, z, observed u, v, view, camera, 0.
const CORNER_ROW: usize = 8;
/// `ALL_CAMERAS` in the kernel: an evaluation that projects every camera's corners.
const ALL_CAMERAS: u32 = u32::MAX;
/// Bytes each item needs of its largest binding (the two f64 residual values).
const ITEM_BYTES: usize = 2 * 8;

/// Mirrors `struct BundleInfo` in `shaders/calib/bundle_residuals.wgsl` — keep in sync.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
struct BundleInfo {
    /// Items in the chunk, observed corners, cameras per set, views per pose set.
    sizes: [u32; 4],
    /// First evaluation of the chunk, 0, 0, 0.
    chunk: [u32; 4],
}

/// The kernel's buffers, reused across calls.
#[derive(Default)]
struct Buffers {
    uniform: Slot,
    cameras: Slot,
    poses: Slot,
    evaluations: Slot,
    output: SlotPair,
    status: SlotPair,
}

/// The bundle's residuals evaluated by a [`GpuEngine`] in f64.
///
/// `E` is how it holds the engine: a borrow or shared ownership (`Arc`, the default).
/// A device error does not end a calibration: the call and every later one run on the CPU
/// ([`CpuResiduals`]) and [`failure`](ResidualBackend::failure) says why.
pub struct GpuResiduals<E = Arc<GpuEngine>> {
    engine: E,
    /// The corner rows ([`CORNER_ROW`] reals each), kept on the device.
    corners: ResidentRows,
    buffers: Mutex<Buffers>,
    /// The CPU twin, for the calls after a device error.
    fallback: CpuResiduals,
    failure: Mutex<Option<String>>,
}

impl<E: Deref<Target = GpuEngine>> GpuResiduals<E> {
    /// A backend for `corners` on `engine`. Errors ([`GpuError::Unsupported`]) where the
    /// engine's kernels are not f64: the bundle's finite differences need f64 residuals, and it
    /// stays on the CPU then.
    pub fn new(engine: E, corners: &[ObservedCorner]) -> Result<Self, GpuError> {
        if engine.precision() != Precision::F64 {
            return Err(GpuError::Unsupported(format!(
                "the bundle's residuals need f64 kernels, the engine runs {}",
                engine.precision()
            )));
        }
        let rows: Vec<[f64; CORNER_ROW]> = corners
            .iter()
            .map(|c| {
                let [x, y, z] = c.point_in_target;
                let [u, v] = c.observed;
                [x, y, z, u, v, c.view as f64, c.camera as f64, 0.0]
            })
            .collect();
        Ok(Self {
            engine,
            corners: ResidentRows::new(&rows),
            buffers: Mutex::default(),
            fallback: CpuResiduals::new(corners),
            failure: Mutex::new(None),
        })
    }

    /// Uploads of the corner rows so far (1 after any number of calls).
    pub fn uploads(&self) -> usize {
        self.corners.uploads()
    }

    /// The residuals of every evaluation of `batch` on the device.
    pub fn evaluate(&self, batch: &StencilBatch) -> Result<Vec<Residuals>, GpuError> {
        let corners = self.corners.len();
        let evaluations = batch.evaluations.len();
        if corners == 0 || evaluations == 0 {
            return Ok(vec![Some(vec![Vector2::zeros(); corners]); evaluations]);
        }
        let per_chunk = self.chunk_items() / corners;
        if per_chunk == 0 {
            return Err(GpuError::Unsupported(format!(
                "{corners} corners do not fit one dispatch"
            )));
        }
        let mut values = vec![[0.0; 2]; evaluations * corners];
        let mut status = vec![0u32; evaluations * corners];
        self.run(batch, per_chunk, &mut values, &mut status)?;
        Ok(values
            .chunks_exact(corners)
            .zip(status.chunks_exact(corners))
            .map(|(values, status)| {
                status
                    .iter()
                    .all(|&s| s == 0)
                    .then(|| values.iter().map(|v| Vector2::new(v[0], v[1])).collect())
            })
            .collect())
    }

    /// Items per chunk: what one binding holds, at most the engine's item limit.
    fn chunk_items(&self) -> usize {
        chunk_items(
            self.engine.context().max_storage_binding(),
            ITEM_BYTES,
            self.engine.max_chunk_items(),
        )
    }

    /// Uploads the batch's tables and runs the kernel over chunks of `per_chunk` evaluations,
    /// writing `values` and `status` (evaluation-major).
    fn run(
        &self,
        batch: &StencilBatch,
        per_chunk: usize,
        values: &mut [[f64; 2]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        let context = self.engine.context();
        let corners = self.corners.len();
        let tables = Tables::of(batch)?;
        let pipeline = context.kernel_pipeline(
            &kernels::BUNDLE_RESIDUALS,
            Precision::F64,
            Rows::Storage,
            tables.layers,
        )?;
        let dispatch = Dispatch::new(context, &pipeline, kernels::BUNDLE_RESIDUALS.name);
        let mut guard = self.buffers.lock().unwrap_or_else(|p| p.into_inner());
        let buffers = &mut *guard;
        let usage = input_usage(context);
        let uniform = buffers.uniform.uniform(context, size_of::<BundleInfo>())?;
        let corner_buffer = self.corners.on_device(context, Precision::F64)?;
        let input = |slot: &mut Slot, label: &str, bytes: &[u8]| {
            let buffer = slot.get(context, label, bytes.len(), usage)?.clone();
            upload(context, &buffer, bytes)?;
            Ok::<_, GpuError>(buffer)
        };
        let cameras = input(&mut buffers.cameras, "camera sets", &tables.cameras)?;
        let poses = input(
            &mut buffers.poses,
            "pose sets",
            bytemuck::cast_slice(&tables.poses),
        )?;
        let evaluation_table = input(
            &mut buffers.evaluations,
            "evaluations",
            bytemuck::cast_slice(&tables.evaluations),
        )?;
        let chunk_bytes = per_chunk.min(batch.evaluations.len()) * corners;
        let (out_buf, out_staging) =
            buffers
                .output
                .readable(context, "residuals", chunk_bytes * ITEM_BYTES)?;
        let (status_buf, status_staging) =
            buffers
                .status
                .readable(context, "status", chunk_bytes * 4)?;
        let bind_group = dispatch.bind(&[
            (0, &uniform),
            (1, &corner_buffer),
            (2, &out_buf),
            (3, &status_buf),
            (4, &cameras),
            (5, &poses),
            (6, &evaluation_table),
        ]);
        for first in (0..batch.evaluations.len()).step_by(per_chunk) {
            let last = (first + per_chunk).min(batch.evaluations.len());
            let range = first * corners..last * corners;
            let count = range.len();
            let info = BundleInfo {
                sizes: [
                    count as u32,
                    corners as u32,
                    tables.cameras_per_set,
                    tables.views,
                ],
                chunk: [first as u32, 0, 0, 0],
            };
            context
                .queue()
                .write_buffer(&uniform, 0, bytemuck::bytes_of(&info));
            let copies = [
                (&out_buf, &out_staging, (count * ITEM_BYTES) as u64),
                (&status_buf, &status_staging, (count * 4) as u64),
            ];
            let (values, status) = (&mut values[range.clone()], &mut status[range]);
            dispatch.run(&[(&bind_group, dispatch.grid(count))], &copies, |data| {
                status.copy_from_slice(bytemuck::cast_slice(&data[1][..count * 4]));
                values.copy_from_slice(bytemuck::cast_slice(&data[0][..count * ITEM_BYTES]));
            })?;
        }
        Ok(())
    }
}

/// A batch as the kernel reads it.
struct Tables {
    /// Every camera set's cameras, [`CameraF64`] after [`CameraF64`].
    cameras: Vec<u8>,
    cameras_per_set: u32,
    /// Rows of [R | t] of every pose set's views.
    poses: Vec<[f64; 4]>,
    views: u32,
    /// (camera set, pose set, only camera or [`ALL_CAMERAS`], 0) per evaluation.
    evaluations: Vec<[u32; 4]>,
    /// The most layers of a camera (the pipeline's `RIG_LAYERS`).
    layers: u32,
}

impl Tables {
    /// The tables of `batch`. Errors where a camera has more layers than the kernels take.
    fn of(batch: &StencilBatch) -> Result<Self, GpuError> {
        let mut cameras = Vec::new();
        let mut layers = 0;
        for camera in batch.cameras.iter().flatten() {
            check_layers(camera)?;
            layers = layers.max(camera.layers().len() as u32);
            cameras.extend_from_slice(bytemuck::bytes_of(&camera_f64(camera)));
        }
        let poses = batch
            .poses
            .iter()
            .flatten()
            .flat_map(|pose| {
                let m = pose.to_homogeneous();
                (0..3).map(move |r| [m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]])
            })
            .collect();
        let evaluations = batch
            .evaluations
            .iter()
            .map(|e| {
                let only = e.only.map_or(ALL_CAMERAS, |k| k as u32);
                [e.cameras as u32, e.poses as u32, only, 0]
            })
            .collect();
        Ok(Self {
            cameras,
            cameras_per_set: batch.cameras.first().map_or(0, |set| set.len() as u32),
            poses,
            views: batch.poses.first().map_or(0, |set| set.len() as u32),
            evaluations,
            layers,
        })
    }
}

/// `camera` as the kernels' `Camera` in f64 (the uniform's mirror; the layer count checked).
fn camera_f64(camera: &RefractiveCamera) -> CameraF64 {
    match Params::new(Precision::F64, camera, camera, [0; 4]) {
        Params::F64(params) => params.cams[0],
        Params::F32(_) => unreachable!("asked for f64"),
    }
}

impl<E: Deref<Target = GpuEngine> + Sync> ResidualBackend for GpuResiduals<E> {
    fn describe(&self) -> String {
        let a = self.engine.context().adapter();
        format!("gpu: {} ({}, {}), f64", a.name, a.backend, a.driver)
    }

    fn observations(&self) -> usize {
        self.corners.len()
    }

    /// The batch on the device; after a device error, on the CPU (this call and every later one).
    fn residuals(&self, batch: &StencilBatch) -> Vec<Residuals> {
        if self.failure().is_none() {
            match self.evaluate(batch) {
                Ok(residuals) => return residuals,
                Err(e) => {
                    *self.failure.lock().unwrap_or_else(|p| p.into_inner()) = Some(e.to_string())
                }
            }
        }
        self.fallback.residuals(batch)
    }

    fn failure(&self) -> Option<String> {
        self.failure
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }
}
