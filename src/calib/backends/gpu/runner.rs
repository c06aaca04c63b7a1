//! What the calibration kernels' host code shares within one GPU backend: its own buffers
//! (reused across its calls), the view-row binding it was asked for, the chunk size on the
//! engine it runs on, and the uniform of the candidate kernels.

use std::sync::{Mutex, MutexGuard};

use crate::calib::problem::data::CameraPair;
use crate::engine::GpuEngine;
use crate::gpu::buffers::{Slot, SlotPair};
use crate::gpu::context::GpuError;
use crate::gpu::dispatch::chunk_items;
use crate::gpu::layout::{Params, check_layers};
use crate::gpu::{Precision, Rows};
use crate::model::{Ports, Rig};

/// The calibration kernels' buffers, reused across the calls of one backend.
#[derive(Default)]
pub(super) struct Buffers {
    pub(super) uniform: Slot,
    pub(super) candidates: Slot,
    /// The per-(candidate, view) items and their statuses, which stay on the device.
    pub(super) items: Slot,
    pub(super) item_status: Slot,
    pub(super) output: SlotPair,
    pub(super) status: SlotPair,
}

/// The host side of the calibration kernels for one backend: its buffers and where the per-view
/// kernels read their corner rows; the device, the pipelines and the item limit are the engine's
/// (each call names it).
#[derive(Default)]
pub(super) struct KernelRunner {
    buffers: Mutex<Buffers>,
    /// The corner-row binding of the per-view kernels, if fixed (else chosen per call).
    pub(super) rows: Option<Rows>,
}

impl KernelRunner {
    pub(super) fn buffers(&self) -> MutexGuard<'_, Buffers> {
        self.buffers.lock().expect("buffer cache")
    }

    /// Items per chunk on `engine` when each item needs at most `bytes_per_item` of one binding.
    pub(super) fn chunk_items(&self, engine: &GpuEngine, bytes_per_item: usize) -> usize {
        chunk_items(
            engine.context().max_storage_binding(),
            bytes_per_item,
            engine.max_chunk_items(),
        )
    }
}

/// The uniform of a candidate kernel over the pair `cameras` of `rig`: behind a port per camera,
/// the candidates move the first camera's port and the second keeps its own
/// ([`Params::hold_port`]); behind a shared port they move both.
pub(super) fn candidate_params(
    precision: Precision,
    rig: &Rig,
    cameras: CameraPair,
) -> Result<Params, GpuError> {
    let [a, b] = cameras.map(|k| rig.refractive_camera(k));
    check_layers(&a)?;
    check_layers(&b)?;
    let mut params = Params::new(precision, &a, &b, [0; 4]);
    if matches!(rig.ports(), Ports::PerCamera(_)) {
        params.hold_port(1);
    }
    Ok(params)
}
