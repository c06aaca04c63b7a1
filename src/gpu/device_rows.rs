//! Rows that live on the device: [`DeviceRows`], a batch of rows in a storage buffer with one
//! status per row, made by uploading host rows once, by a kernel, or from a `wgpu::Buffer` of the
//! caller's, and read back once (or never). Where [`ResidentRows`](super::ResidentRows) are host
//! data the toolkit copies to the device on demand, `DeviceRows` are device data the host sees
//! only when asked. Layout and buffers only: what the rows mean is their [`RowKind`]'s.
//!
//! # Layout
//!
//! - **rows** ([`buffer`](DeviceRows::buffer)): row i is `WIDTH` reals at byte offset
//!   `i · WIDTH · size`, tightly packed, no padding; reals are little-endian IEEE `f32`
//!   (`size` 4) or `f64` (`size` 8) as the rows' [`Precision`] says (the engine's);
//!   [`stride_bytes`](DeviceRows::stride_bytes) is `WIDTH · size`.
//! - **status** ([`status_buffer`](DeviceRows::status_buffer)): one `u32` per row; 0 where the
//!   row holds an answer, else the [`NoSolution`] code of the CPU path.
//!   The reals of a row whose status is not 0 are unspecified (a kernel leaves them as they
//!   were); [`read`](DeviceRows::read) gives NaN for them.
//! - Both buffers have the usage `STORAGE | COPY_SRC | COPY_DST` ([`DeviceRows::USAGE`]) and at
//!   least 16 bytes; they may be longer than the rows.

use std::marker::PhantomData;

use super::buffers::extend_reals;
use super::compose::Precision;
use super::context::{GpuContext, GpuError};
use crate::model::NoSolution;

/// What the rows of a [`DeviceRows`] hold: their width in reals and the names of their columns
/// (as the CSV files of DESIGN.md §1 name them). The engine's kinds are in
/// [`crate::engine::gpu`] (`Pixels`, `Points`, `Rays`, `Triangulated`); another crate may
/// define its own for its kernels.
pub trait RowKind: 'static {
    /// Reals per row.
    const WIDTH: usize;
    /// The columns' names, `WIDTH` of them.
    const COLUMNS: &'static [&'static str];
    /// One row on the host: `[f64; WIDTH]`.
    type Row: bytemuck::Pod + Send + Sync;
}

/// A batch of rows of kind `K` on one device, in one precision, with a status per row (the
/// [module](self) documents the layout). Cloning shares the buffers.
///
/// The relations that take and give them are [`GpuEngine`](crate::engine::GpuEngine)'s
/// `*_rows` calls and `triangulate_pixels`; [`crate::engine::gpu::device`] has the chain matched
/// pixels → points (one fused kernel, and back-project → triangulate through the rays) as a
/// compiled example.
pub struct DeviceRows<K: RowKind> {
    rows: wgpu::Buffer,
    status: wgpu::Buffer,
    len: usize,
    precision: Precision,
    /// The [`GpuContext::id`] of the context whose device holds the buffers.
    context: u64,
    kind: PhantomData<fn() -> K>,
}

impl<K: RowKind> Clone for DeviceRows<K> {
    fn clone(&self) -> Self {
        Self {
            rows: self.rows.clone(),
            status: self.status.clone(),
            len: self.len,
            precision: self.precision,
            context: self.context,
            kind: PhantomData,
        }
    }
}

impl<K: RowKind> std::fmt::Debug for DeviceRows<K> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceRows")
            .field("columns", &K::COLUMNS)
            .field("rows", &self.len)
            .field("precision", &self.precision)
            .finish()
    }
}

/// Bytes of a buffer of `bytes` payload: at least 16, a multiple of 16.
fn padded(bytes: usize) -> u64 {
    (bytes.max(16) as u64).next_multiple_of(16)
}

impl<K: RowKind> DeviceRows<K> {
    /// The usage of both buffers: bound as storage by the kernels, copied to and from.
    pub const USAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE
        .union(wgpu::BufferUsages::COPY_SRC)
        .union(wgpu::BufferUsages::COPY_DST);

    /// `len` rows in `precision` on `context`'s device, their values and statuses not yet
    /// written (zero): for a kernel to fill.
    pub fn allocate(
        context: &GpuContext,
        precision: Precision,
        len: usize,
    ) -> Result<Self, GpuError> {
        let bytes = len
            .checked_mul(K::WIDTH * precision.size())
            .ok_or_else(|| {
                GpuError::Rows(format!(
                    "{len} rows of {} reals overflow a buffer",
                    K::WIDTH
                ))
            })?;
        let rows = context.buffer("device rows", padded(bytes), Self::USAGE)?;
        let status = context.buffer("device rows status", padded(4 * len), Self::USAGE)?;
        Ok(Self {
            rows,
            status,
            len,
            precision,
            context: context.id(),
            kind: PhantomData,
        })
    }

    /// Uploads host rows (f64, rounded to `precision`) to `context`'s device: the one copy from
    /// the host. A row with a value beyond what `precision` holds
    /// ([`Precision::huge`]) or not finite gets the status of
    /// [`NoSolution::OutOfRange`], as in the engine's host-row calls.
    pub fn upload(
        context: &GpuContext,
        precision: Precision,
        rows: &[K::Row],
    ) -> Result<Self, GpuError> {
        let reals: &[f64] = bytemuck::cast_slice(rows);
        let this = Self::allocate(context, precision, rows.len())?;
        if rows.is_empty() {
            return Ok(this);
        }
        let mut bytes = Vec::with_capacity(reals.len() * precision.size());
        extend_reals(&mut bytes, precision, reals);
        context.queue().write_buffer(&this.rows, 0, &bytes);
        let limit = precision.huge();
        let status: Vec<u32> = reals
            .chunks_exact(K::WIDTH)
            .map(|row| {
                if row.iter().all(|v| v.abs() <= limit) {
                    0
                } else {
                    NoSolution::OutOfRange.code()
                }
            })
            .collect();
        if status.iter().any(|&s| s != 0) {
            context
                .queue()
                .write_buffer(&this.status, 0, bytemuck::cast_slice(&status));
        }
        Ok(this)
    }

    /// Rows of the caller's own buffers on `context`'s device: `rows` holds `len` rows in
    /// `precision` laid out as the [module](self) says, from byte 0; `status` one `u32` per row
    /// (`None`: a new status buffer, every row an answer). Nothing is copied: kernels read and
    /// write the caller's buffers.
    ///
    /// Errors ([`GpuError::Rows`]): a buffer shorter than the rows, or without the usage
    /// `STORAGE` (and `COPY_SRC` to [`read`](Self::read) it). The buffers must come from
    /// `context`'s device (wgpu does not say which device made a buffer: one from another device
    /// fails at its first use with [`GpuError::Validation`]).
    pub fn from_buffers(
        context: &GpuContext,
        precision: Precision,
        rows: wgpu::Buffer,
        status: Option<wgpu::Buffer>,
        len: usize,
    ) -> Result<Self, GpuError> {
        let need = (len as u64).saturating_mul((K::WIDTH * precision.size()) as u64);
        if rows.size() < need {
            return Err(GpuError::Rows(format!(
                "a buffer of {} bytes cannot hold {len} rows of {} {precision} reals ({need} bytes)",
                rows.size(),
                K::WIDTH
            )));
        }
        let status = match status {
            Some(status) if status.size() < 4 * len as u64 => {
                return Err(GpuError::Rows(format!(
                    "a status buffer of {} bytes cannot hold {len} statuses ({} bytes)",
                    status.size(),
                    4 * len
                )));
            }
            Some(status) => status,
            None => context.buffer("device rows status", padded(4 * len), Self::USAGE)?,
        };
        for (name, buffer) in [("rows", &rows), ("status", &status)] {
            if !buffer.usage().contains(wgpu::BufferUsages::STORAGE) {
                return Err(GpuError::Rows(format!(
                    "the {name} buffer has the usage {:?}, without STORAGE",
                    buffer.usage()
                )));
            }
        }
        Ok(Self {
            rows,
            status,
            len,
            precision,
            context: context.id(),
            kind: PhantomData,
        })
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True without rows.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The precision of the reals.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Bytes from one row to the next: `WIDTH · 4` in f32, `WIDTH · 8` in f64.
    pub fn stride_bytes(&self) -> usize {
        K::WIDTH * self.precision.size()
    }

    /// The rows' buffer (a handle: the rows stay valid while either lives).
    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.rows
    }

    /// The statuses' buffer.
    pub fn status_buffer(&self) -> &wgpu::Buffer {
        &self.status
    }

    /// The (rows, status) buffers, for the caller's own wgpu code.
    pub fn into_buffers(self) -> (wgpu::Buffer, wgpu::Buffer) {
        (self.rows, self.status)
    }

    /// True where the rows live on `context`'s device (were made through `context`).
    pub fn is_on(&self, context: &GpuContext) -> bool {
        self.context == context.id()
    }

    /// Errors unless the rows live on `context`'s device and are in `precision`; `what` names
    /// them in the message.
    pub(crate) fn check_on(
        &self,
        context: &GpuContext,
        precision: Precision,
        what: &str,
    ) -> Result<(), GpuError> {
        if !self.is_on(context) {
            return Err(GpuError::Rows(format!(
                "{what} live on another device than this engine's ('{}')",
                context.adapter().name
            )));
        }
        if self.precision != precision {
            return Err(GpuError::Rows(format!(
                "{what} hold {} reals, this engine runs {precision}",
                self.precision
            )));
        }
        Ok(())
    }

    /// Reads the rows back to the host (after every kernel submitted before): the rows as f64
    /// and their statuses, the rows NaN where the status is not 0; a row with an answer that is
    /// not finite gets [`NoSolution::OutOfRange`] as in the engine's host-row calls.
    ///
    /// Errors: rows of another device ([`GpuError::Rows`]), or a failure of the device (a kernel
    /// of the chain that made them included).
    pub fn read(&self, context: &GpuContext) -> Result<(Vec<K::Row>, Vec<u32>), GpuError> {
        let (reals, status) = self.read_reals(context)?;
        let rows: Vec<K::Row> = bytemuck::try_cast_slice(&reals)
            .map_err(|e| GpuError::Rows(format!("{} reals per row: {e}", K::WIDTH)))?
            .to_vec();
        Ok((rows, status))
    }

    /// [`read`](Self::read) with the rows flat: `WIDTH` reals per row, row after row.
    pub fn read_reals(&self, context: &GpuContext) -> Result<(Vec<f64>, Vec<u32>), GpuError> {
        self.check_on(context, self.precision, "the rows")?;
        if self.len == 0 {
            context.check("reading device rows")?;
            return Ok((Vec::new(), Vec::new()));
        }
        let s = self.precision.size();
        let (row_bytes, status_bytes) = ((self.len * K::WIDTH * s) as u64, 4 * self.len as u64);
        use wgpu::BufferUsages as U;
        let staging_rows = context.buffer(
            "device rows read",
            padded(row_bytes as usize),
            U::MAP_READ | U::COPY_DST,
        )?;
        let staging_status = context.buffer(
            "device rows status read",
            padded(status_bytes as usize),
            U::MAP_READ | U::COPY_DST,
        )?;
        let encoder = context
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("device rows read"),
            });
        let (reals, status) = context.read_back(
            encoder,
            &[
                (&self.rows, &staging_rows, row_bytes),
                (&self.status, &staging_status, status_bytes),
            ],
            |data| -> Result<(Vec<f64>, Vec<u32>), GpuError> {
                let status: Vec<u32> = bytemuck::try_cast_slice(data[1])
                    .map_err(|e| GpuError::Readback(format!("mapped status not aligned: {e}")))?
                    .to_vec();
                let reals: Vec<f64> = match self.precision {
                    Precision::F64 => bytemuck::try_cast_slice::<u8, f64>(data[0])
                        .map_err(|e| GpuError::Readback(format!("mapped rows not aligned: {e}")))?
                        .to_vec(),
                    Precision::F32 => bytemuck::try_cast_slice::<u8, f32>(data[0])
                        .map_err(|e| GpuError::Readback(format!("mapped rows not aligned: {e}")))?
                        .iter()
                        .map(|&v| v as f64)
                        .collect(),
                };
                Ok((reals, status))
            },
        )??;
        let (mut reals, mut status) = (reals, status);
        for (row, s) in reals.chunks_exact_mut(K::WIDTH).zip(status.iter_mut()) {
            if *s == 0 && !row.iter().all(|v| v.is_finite()) {
                *s = NoSolution::OutOfRange.code();
            }
            if *s != 0 {
                row.fill(f64::NAN);
            }
        }
        Ok((reals, status))
    }
}
