//! Data that stays on the device: rows uploaded at the first call that needs them and kept for
//! every later call on the same device and precision (per-item rows read by the hundreds of
//! small calls of a stencil refinement, say). Buffers only.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::gpu::buffers::{input_usage, upload_reals};
use crate::gpu::compose::Precision;
use crate::gpu::context::{GpuContext, GpuError};

/// Rows of `width` reals, kept on the host and, once a kernel has read them, on the device.
///
/// The rows never change: data that change make a new `ResidentRows` (a cost backend builds its
/// own from its data set), so a device copy is never stale. The copy is made again
/// only for another device or precision.
pub struct ResidentRows {
    reals: Vec<f64>,
    width: usize,
    /// Also bound as a uniform buffer (windows of view rows, [`Rows::Uniform`](super::Rows)).
    uniform: bool,
    device: Mutex<Option<DeviceCopy>>,
    uploads: AtomicUsize,
}

/// The device copy of [`ResidentRows`].
struct DeviceCopy {
    /// The [`GpuContext::id`] of the context whose device holds the copy.
    context: u64,
    precision: Precision,
    buffer: wgpu::Buffer,
}

impl ResidentRows {
    /// Rows of N reals (nothing is uploaded until a kernel reads them).
    pub fn new<const N: usize>(rows: &[[f64; N]]) -> Self {
        Self::from_reals(rows.as_flattened().to_vec(), N)
    }

    /// `reals` as rows of `width` (a multiple of `width` long).
    pub(crate) fn from_reals(reals: Vec<f64>, width: usize) -> Self {
        assert!(
            width > 0 && reals.len().is_multiple_of(width),
            "whole rows of {width} reals"
        );
        Self {
            reals,
            width,
            uniform: false,
            device: Mutex::new(None),
            uploads: AtomicUsize::new(0),
        }
    }

    /// The same rows, to be bound as uniform windows as well as storage.
    pub(crate) fn bound_as_uniform(mut self) -> Self {
        self.uniform = true;
        self
    }

    /// The reals as the device gets them (before rounding to the precision).
    #[cfg(test)]
    pub(crate) fn reals_for_tests(&self) -> &[f64] {
        &self.reals
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.reals.len() / self.width
    }

    /// True without rows.
    pub fn is_empty(&self) -> bool {
        self.reals.is_empty()
    }

    /// Reals per row.
    pub fn width(&self) -> usize {
        self.width
    }

    /// How many times the rows went to a device (1 after any number of calls on one engine).
    pub fn uploads(&self) -> usize {
        self.uploads.load(Ordering::Relaxed)
    }

    /// Drops the device copy (freeing its memory): the next kernel that reads the rows uploads
    /// them again.
    pub fn evict(&self) {
        *self.device.lock().unwrap_or_else(|p| p.into_inner()) = None;
    }

    /// The rows on `context`'s device in `precision`: the kept copy, or a new one uploaded now.
    pub(crate) fn on_device(
        &self,
        context: &GpuContext,
        precision: Precision,
    ) -> Result<wgpu::Buffer, GpuError> {
        let mut copy = self.device.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(kept) = copy.as_ref()
            && kept.context == context.id()
            && kept.precision == precision
        {
            return Ok(kept.buffer.clone());
        }
        // The old copy goes first, so that both never hold device memory at once.
        *copy = None;
        let bytes = (self.reals.len().max(4) * precision.size()) as u64;
        let usage = if self.uniform {
            input_usage(context) | wgpu::BufferUsages::UNIFORM
        } else {
            input_usage(context)
        };
        let buffer = context.buffer("resident rows", bytes.next_multiple_of(16), usage)?;
        upload_reals(context, precision, &buffer, &self.reals)?;
        self.uploads.fetch_add(1, Ordering::Relaxed);
        *copy = Some(DeviceCopy {
            context: context.id(),
            precision,
            buffer: buffer.clone(),
        });
        Ok(buffer)
    }
}

impl std::fmt::Debug for ResidentRows {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ResidentRows")
            .field("rows", &self.len())
            .field("width", &self.width)
            .field("uploads", &self.uploads())
            .finish()
    }
}
