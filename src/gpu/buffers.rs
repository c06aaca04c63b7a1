//! Device buffers reused across chunks and calls, and the host-side conversions of rows to and
//! from a kernel precision. A [`Slot`] keeps one buffer and replaces it only when a call needs
//! more bytes or another usage; a [`SlotPair`] pairs a buffer the kernels write or read with the
//! one the host maps: the same buffer where the adapter shares the host's memory
//! ([`GpuContext::maps_storage`]), a staging copy otherwise. Layout and bytes only.

use rayon::prelude::*;

use super::compose::Precision;
use super::context::{GpuContext, GpuError};

/// Rows per parallel task of the host-side conversions.
pub(crate) const CONVERT_ROWS: usize = 1 << 14;

/// A buffer that is replaced when a call needs more bytes or another usage.
#[derive(Default)]
pub(crate) struct Slot(Option<wgpu::Buffer>);

impl Slot {
    /// The slot's buffer, replaced first when it holds fewer than `bytes` (rounded up to 16, at
    /// least 16) or another usage.
    pub(crate) fn get(
        &mut self,
        context: &GpuContext,
        label: &str,
        bytes: usize,
        usage: wgpu::BufferUsages,
    ) -> Result<&wgpu::Buffer, GpuError> {
        let bytes = (bytes.max(16) as u64).next_multiple_of(16);
        match &mut self.0 {
            Some(buffer) if buffer.size() >= bytes && buffer.usage() == usage => {}
            slot => {
                // The old buffer goes first, so that both never hold device memory at once.
                *slot = None;
                *slot = Some(context.buffer(label, bytes, usage)?);
            }
        }
        Ok(self.0.as_ref().expect("just set"))
    }

    /// A uniform buffer (`params`) of at least `bytes`, written through the queue.
    pub(crate) fn uniform(
        &mut self,
        context: &GpuContext,
        bytes: usize,
    ) -> Result<wgpu::Buffer, GpuError> {
        Ok(self
            .get(
                context,
                "params",
                bytes,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            )?
            .clone())
    }

    /// The buffer the slot holds now, if any.
    pub(crate) fn buffer(&self) -> Option<&wgpu::Buffer> {
        self.0.as_ref()
    }
}

/// A kernel's buffer and the buffer the host maps to reach it: one buffer where the adapter shares
/// the host's memory ([`GpuContext::maps_storage`]), a storage buffer and a staging copy
/// otherwise; [`readable`](Self::readable) for what the kernels write, [`writable`](Self::writable)
/// for what they read.
#[derive(Default)]
pub(crate) struct SlotPair {
    device: Slot,
    host: Slot,
}

impl SlotPair {
    /// (the kernels' buffer, the host's) of at least `bytes` that the kernels write and the host
    /// reads.
    pub(crate) fn readable(
        &mut self,
        context: &GpuContext,
        label: &str,
        bytes: usize,
    ) -> Result<(wgpu::Buffer, wgpu::Buffer), GpuError> {
        use wgpu::BufferUsages as U;
        self.get(
            context,
            label,
            bytes,
            [U::MAP_READ, U::COPY_SRC, U::COPY_DST],
        )
    }

    /// (the kernels' buffer, the host's) of at least `bytes` that the host writes and the
    /// kernels read (mapped: of usage [`input_usage`]).
    pub(crate) fn writable(
        &mut self,
        context: &GpuContext,
        label: &str,
        bytes: usize,
    ) -> Result<(wgpu::Buffer, wgpu::Buffer), GpuError> {
        use wgpu::BufferUsages as U;
        self.get(
            context,
            label,
            bytes,
            [U::MAP_WRITE, U::COPY_DST, U::COPY_SRC],
        )
    }

    /// One buffer of usage `STORAGE | map` where the context maps storage, else a buffer of
    /// `STORAGE | copy` and a staging buffer of `map | staged`.
    fn get(
        &mut self,
        context: &GpuContext,
        label: &str,
        bytes: usize,
        [map, copy, staged]: [wgpu::BufferUsages; 3],
    ) -> Result<(wgpu::Buffer, wgpu::Buffer), GpuError> {
        use wgpu::BufferUsages as U;
        if context.maps_storage() {
            let buffer = self.device.get(context, label, bytes, U::STORAGE | map)?;
            Ok((buffer.clone(), buffer.clone()))
        } else {
            let buffer = self
                .device
                .get(context, label, bytes, U::STORAGE | copy)?
                .clone();
            let host = self.host.get(context, label, bytes, map | staged)?.clone();
            Ok((buffer, host))
        }
    }

    /// The kernels' buffer now, if any.
    pub(crate) fn buffer(&self) -> Option<&wgpu::Buffer> {
        self.device.buffer()
    }
}

/// Usage of a buffer the kernels read and the host fills with [`upload`]: mapped directly where
/// the adapter shares the host's memory, written through the queue otherwise.
pub(crate) fn input_usage(context: &GpuContext) -> wgpu::BufferUsages {
    use wgpu::BufferUsages as U;
    if context.maps_storage() {
        U::STORAGE | U::MAP_WRITE
    } else {
        U::STORAGE | U::COPY_DST
    }
}

/// Writes `bytes` at the start of a buffer made with [`input_usage`].
pub(crate) fn upload(
    context: &GpuContext,
    buffer: &wgpu::Buffer,
    bytes: &[u8],
) -> Result<(), GpuError> {
    if context.maps_storage() {
        context.write_mapped(buffer, bytes)
    } else {
        context.queue().write_buffer(buffer, 0, bytes);
        Ok(())
    }
}

/// [`upload`]s f64 `values` in `precision` (converted through a temporary for f32).
pub(crate) fn upload_reals(
    context: &GpuContext,
    precision: Precision,
    buffer: &wgpu::Buffer,
    values: &[f64],
) -> Result<(), GpuError> {
    match precision {
        Precision::F64 => upload(context, buffer, bytemuck::cast_slice(values)),
        Precision::F32 => {
            let mut bytes = Vec::with_capacity(4 * values.len());
            extend_reals(&mut bytes, precision, values);
            upload(context, buffer, &bytes)
        }
    }
}

/// Bytes of `values` in `precision`, appended to `bytes` (converted on all cores).
pub(crate) fn extend_reals(bytes: &mut Vec<u8>, precision: Precision, values: &[f64]) {
    match precision {
        Precision::F64 => bytes.extend_from_slice(bytemuck::cast_slice(values)),
        Precision::F32 => {
            let start = bytes.len();
            bytes.resize(start + 4 * values.len(), 0);
            bytes[start..]
                .par_chunks_mut(4 * CONVERT_ROWS)
                .zip(values.par_chunks(CONVERT_ROWS))
                .for_each(|(out, values)| {
                    for (o, v) in out.chunks_exact_mut(4).zip(values) {
                        o.copy_from_slice(&(*v as f32).to_le_bytes());
                    }
                });
        }
    }
}

/// Copies mapped rows of `precision` into `output` where `status` is 0, NaN elsewhere (on all
/// cores).
pub(crate) fn rows_from<const M: usize>(
    bytes: &[u8],
    precision: Precision,
    status: &[u32],
    output: &mut [[f64; M]],
) {
    let s = precision.size();
    let bytes = &bytes[..output.len() * M * s];
    output
        .par_chunks_mut(CONVERT_ROWS)
        .zip(status.par_chunks(CONVERT_ROWS))
        .zip(bytes.par_chunks(CONVERT_ROWS * M * s))
        .for_each(|((output, status), bytes)| match precision {
            Precision::F64 => {
                let values: &[f64] = bytemuck::cast_slice(bytes);
                for ((row, chunk), s) in output.iter_mut().zip(values.chunks_exact(M)).zip(status) {
                    *row = if *s == 0 {
                        chunk.try_into().expect("M values")
                    } else {
                        [f64::NAN; M]
                    };
                }
            }
            Precision::F32 => {
                let values: &[f32] = bytemuck::cast_slice(bytes);
                for ((row, chunk), s) in output.iter_mut().zip(values.chunks_exact(M)).zip(status) {
                    *row = if *s == 0 {
                        std::array::from_fn(|k| chunk[k] as f64)
                    } else {
                        [f64::NAN; M]
                    };
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f64 values survive a round trip through mapped bytes in f64 and are rounded to f32 in f32;
    /// a row whose status is not 0 comes back NaN whatever its bytes; conversions over more than
    /// one parallel task keep the order.
    #[test]
    fn reals_round_trip_through_bytes_and_statuses_blank_rows() {
        let n = 2 * CONVERT_ROWS + 5;
        let values: Vec<f64> = (0..3 * n).map(|k| k as f64 + 0.1).collect();
        let status: Vec<u32> = (0..n).map(|i| u32::from(i % 7 == 3)).collect();
        for precision in [Precision::F32, Precision::F64] {
            let mut bytes = vec![1u8; 3];
            extend_reals(&mut bytes, precision, &values);
            assert_eq!(bytes.len(), 3 + values.len() * precision.size());
            assert_eq!(
                bytes[..3],
                [1, 1, 1],
                "{precision}: appended after what was there"
            );
            // Mapped memory is aligned: the reals at the start of an f64-aligned buffer.
            let mut mapped = vec![0.0f64; values.len()];
            let reals = &mut bytemuck::cast_slice_mut::<f64, u8>(&mut mapped)[..bytes.len() - 3];
            reals.copy_from_slice(&bytes[3..]);
            let mut rows = vec![[0.0; 3]; n];
            rows_from(bytemuck::cast_slice(&mapped), precision, &status, &mut rows);
            for (i, row) in rows.iter().enumerate() {
                if status[i] != 0 {
                    assert!(row.iter().all(|v| v.is_nan()), "{precision} row {i}");
                    continue;
                }
                for (k, v) in row.iter().enumerate() {
                    let expected = values[3 * i + k];
                    let expected = match precision {
                        Precision::F32 => expected as f32 as f64,
                        Precision::F64 => expected,
                    };
                    assert_eq!(*v, expected, "{precision} row {i} value {k}");
                }
            }
        }
    }
}
