//! Streaming of row kernels (one output row per input row, any [`KernelSource`] with the row
//! bindings: uniform 0, input 1, output 2, status 3): a batch cut into chunks that run
//! through a ring of [`RING`] buffer sets, so that while the device runs chunk k the host reads
//! back chunk k − 1 and writes chunk k + 1. The host converts straight into and out of mapped
//! memory (the kernels' own buffers where the adapter shares the host's memory, staging buffers
//! otherwise), in f32 or f64 on either side ([`HostReal`]); the buffers are kept across calls.
//! Indexing, chunking and buffers only.

use std::ops::Range;

use rayon::prelude::*;
use wgpu::WriteOnly;

use super::buffers::{CONVERT_ROWS, Slot, SlotPair};
use super::compose::{KernelSource, Precision};
use super::context::{GpuContext, GpuError};
use super::dispatch::Dispatch;
use super::layout::Params;
use crate::model::NoSolution;

/// Buffer sets in flight: chunk k runs while k − 1 is read back and k + 1 written.
pub const RING: usize = 2;

/// Most rows per streamed chunk on a hardware adapter: a batch of more rows streams through the
/// ring in several chunks, so that its upload and read-back overlap the kernel (a 4 M-row batch
/// in 8 chunks). A software adapter runs a batch in as few chunks as the bindings allow
/// ([`default_stream_chunk_rows`]).
pub const STREAM_CHUNK_ROWS: usize = 1 << 19;

/// The most rows per streamed chunk for `context`: [`STREAM_CHUNK_ROWS`], so that a large
/// batch's upload and read-back overlap its kernel, except on a software adapter (lavapipe),
/// where batches run in as few chunks as the bindings allow (`usize::MAX`). There the kernel
/// already runs on every core of the host, so the overlap leaves no core idle for the
/// conversions, and each further chunk costs a submission and a wait: `flatport bench --items
/// 4000000` puts forward projection in 8 chunks through the ring at 0.68–0.81 of its rate in one
/// chunk (three runs on lavapipe; docs/performance.md). The cost is
/// memory: the buffers, kept across calls, then hold the largest batch up to the binding limit
/// (128 MiB per binding on lavapipe; two sets where a batch needs more than one chunk) instead
/// of 2¹⁹ rows per set. `flatport`'s CSV commands pass batches of at most 2²⁰ rows.
pub fn default_stream_chunk_rows(context: &GpuContext) -> usize {
    if context.is_software() {
        usize::MAX
    } else {
        STREAM_CHUNK_ROWS
    }
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for f64 {}
}

/// A host real type the row kernels take and give: `f64` or `f32`. Where it is the kernels'
/// precision, rows go to and from the device without any conversion.
pub trait HostReal: bytemuck::Pod + Send + Sync + sealed::Sealed {
    /// The precision of this type.
    const PRECISION: Precision;
    /// Not a number.
    const NAN: Self;
    /// `v` rounded to this type (f64 → f32 rounds to nearest; beyond f32's range: ±∞).
    fn from_f64(v: f64) -> Self;
    /// The value as f64 (exact).
    fn to_f64(self) -> f64;
}

impl HostReal for f64 {
    const PRECISION: Precision = Precision::F64;
    const NAN: Self = f64::NAN;
    #[inline]
    fn from_f64(v: f64) -> Self {
        v
    }
    #[inline]
    fn to_f64(self) -> f64 {
        self
    }
}

impl HostReal for f32 {
    const PRECISION: Precision = Precision::F32;
    const NAN: Self = f32::NAN;
    #[inline]
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    #[inline]
    fn to_f64(self) -> f64 {
        self as f64
    }
}

/// One buffer set of the ring: what one chunk needs, kept across chunks and calls.
#[derive(Default)]
struct Lane {
    uniform: Slot,
    /// The rows the kernel reads, and where the host writes them.
    input: SlotPair,
    output: SlotPair,
    status: SlotPair,
}

/// The buffer sets the row kernels stream their chunks through, kept across calls.
#[derive(Default)]
pub(crate) struct Ring([Lane; RING]);

impl Ring {
    /// The first lane's (uniform, input, output, status) buffers, where the last one-chunk
    /// [`map`](Self::map) left its data.
    pub(crate) fn first_lane(&self) -> Option<[wgpu::Buffer; 4]> {
        let lane = &self.0[0];
        Some([
            lane.uniform.buffer()?.clone(),
            lane.input.buffer()?.clone(),
            lane.output.buffer()?.clone(),
            lane.status.buffer()?.clone(),
        ])
    }
}

/// The buffers of one lane for one call (handles: cheap clones).
struct LaneBuffers {
    uniform: wgpu::Buffer,
    input: wgpu::Buffer,
    input_host: wgpu::Buffer,
    output: wgpu::Buffer,
    output_host: wgpu::Buffer,
    status: wgpu::Buffer,
    status_host: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

/// A chunk submitted and not yet read back.
struct InFlight {
    lane: usize,
    rows: Range<usize>,
    submission: wgpu::SubmissionIndex,
    mapped: std::sync::mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
}

/// Mapped bytes as values of `T` (mappings are aligned far beyond 8 bytes; an error otherwise).
fn reals<T: HostReal>(bytes: &[u8]) -> Result<&[T], GpuError> {
    bytemuck::try_cast_slice(bytes)
        .map_err(|e| GpuError::Readback(format!("mapped memory not aligned for reals: {e}")))
}

/// Bytes per parallel piece of [`write_rows`].
const PIECE: usize = 1 << 16;

/// Writes `rows` into mapped memory `target` (exactly their size in `precision`) on all cores:
/// a plain copy where the host type is the kernel precision, else converted through a small
/// block that stays in the cache.
fn write_rows<H: HostReal, const N: usize>(
    target: WriteOnly<'_, [u8]>,
    precision: Precision,
    rows: &[[H; N]],
) {
    let values: &[H] = rows.as_flattened();
    let per_piece = PIECE / precision.size();
    // Whole pieces in parallel (a fixed-size piece can move to another thread), the tail here.
    let (pieces, tail) = target.into_chunks::<PIECE>();
    let whole = pieces.len() * per_piece;
    let pieces: Vec<WriteOnly<'_, [u8; PIECE]>> = pieces.into_iter().collect();
    let write = |target: WriteOnly<'_, [u8]>, values: &[H]| match precision {
        Precision::F32 => put::<H, f32>(target, values),
        Precision::F64 => put::<H, f64>(target, values),
    };
    pieces
        .into_par_iter()
        .zip(values[..whole].par_chunks(per_piece))
        .for_each(|(target, values)| write(target.into(), values));
    write(tail, &values[whole..]);
}

/// Writes `values` as `T` into `target`.
fn put<S: HostReal, T: HostReal>(mut target: WriteOnly<'_, [u8]>, values: &[S]) {
    if S::PRECISION == T::PRECISION {
        target.copy_from_slice(bytemuck::cast_slice(values));
        return;
    }
    const BLOCK: usize = 512;
    let mut block = [T::zeroed(); BLOCK];
    let bytes = BLOCK * std::mem::size_of::<T>();
    for (k, values) in values.chunks(BLOCK).enumerate() {
        for (b, v) in block.iter_mut().zip(values) {
            *b = T::from_f64(v.to_f64());
        }
        let converted: &[u8] = bytemuck::cast_slice(&block[..values.len()]);
        target
            .slice(k * bytes..k * bytes + converted.len())
            .copy_from_slice(converted);
    }
}

/// Copies mapped kernel rows into `output` where `status` is 0, NaN elsewhere, then applies the
/// CPU engine's guard (`CpuEngine::map`): every row all numbers or all NaN, and inputs beyond
/// the kernel precision's range (f32 would read them as infinity) rejected as out of range.
fn read_rows<K: HostReal, H: HostReal, const N: usize, const M: usize>(
    values: &[K],
    limit: f64,
    input: &[[H; N]],
    status: &mut [u32],
    output: &mut [[H; M]],
) {
    let values = &values[..output.len() * M];
    output
        .par_chunks_mut(CONVERT_ROWS)
        .zip(status.par_chunks_mut(CONVERT_ROWS))
        .zip(values.par_chunks(CONVERT_ROWS * M))
        .zip(input.par_chunks(CONVERT_ROWS))
        .for_each(|(((output, status), values), input)| {
            for (((row, s), chunk), x) in output
                .iter_mut()
                .zip(status.iter_mut())
                .zip(values.chunks_exact(M))
                .zip(input)
            {
                if *s == 0 {
                    *row = std::array::from_fn(|k| H::from_f64(chunk[k].to_f64()));
                }
                let beyond = !x.iter().all(|v| v.to_f64().abs() <= limit);
                let unfinished = *s == 0 && !row.iter().all(|v| v.to_f64().is_finite());
                if beyond || unfinished {
                    *s = NoSolution::OutOfRange.code();
                }
                if *s != 0 {
                    *row = [H::NAN; M];
                }
            }
        });
}

impl Ring {
    /// Runs `kernel` (compiled as `pipeline`, in `precision`) over `input`, N reals to M reals per
    /// row, with the uniform `params` (its `info` set per chunk), in chunks of `chunk` rows
    /// streamed through the ring. On an error the ring's buffers are dropped (a later call makes
    /// new ones), so no mapping is left behind.
    ///
    /// Panics if the slices differ in length or `chunk` is 0 for a batch of rows.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn map<H: HostReal, const N: usize, const M: usize>(
        &mut self,
        context: &GpuContext,
        kernel: &KernelSource,
        pipeline: &wgpu::ComputePipeline,
        precision: Precision,
        params: Params,
        chunk: usize,
        input: &[[H; N]],
        output: &mut [[H; M]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        assert!(
            input.len() == output.len() && input.len() == status.len(),
            "input, output and status of equal length"
        );
        if input.is_empty() {
            return Ok(());
        }
        let s = precision.size();
        let dispatch = Dispatch::new(context, pipeline, kernel.name);
        // As many lanes as chunks, at most the ring (one chunk needs no second set).
        let chunks = input.len().div_ceil(chunk);
        let mut lanes = Vec::with_capacity(RING);
        for lane in self.0.iter_mut().take(chunks.min(RING)) {
            let uniform = lane.uniform.uniform(context, params.bytes().len())?;
            let (input, input_host) = lane.input.writable(context, "input", chunk * N * s)?;
            let (output, output_host) = lane.output.readable(context, "output", chunk * M * s)?;
            let (status, status_host) = lane.status.readable(context, "status", chunk * 4)?;
            let bind_group =
                dispatch.bind(&[(0, &uniform), (1, &input), (2, &output), (3, &status)]);
            lanes.push(LaneBuffers {
                uniform,
                input,
                input_host,
                output,
                output_host,
                status,
                status_host,
                bind_group,
            });
        }
        let stream = Stream {
            context,
            precision,
            kernel,
            dispatch,
        };
        let streamed = stream.run(params, &lanes, chunk, input, output, status);
        if streamed.is_err() {
            *self = Self::default();
        }
        streamed
    }
}

/// One call's streaming: what every chunk of it shares.
struct Stream<'a> {
    context: &'a GpuContext,
    precision: Precision,
    kernel: &'a KernelSource,
    dispatch: Dispatch<'a>,
}

impl Stream<'_> {
    /// The chunk loop of [`Ring::map`]: chunk k is submitted from a second thread
    /// (a driver that runs the kernel inside its submit then still overlaps) while this one reads
    /// back chunk k − 1 and writes chunk k + 1 into the lane k − 1 freed.
    fn run<H: HostReal, const N: usize, const M: usize>(
        &self,
        mut params: Params,
        lanes: &[LaneBuffers],
        chunk: usize,
        input: &[[H; N]],
        output: &mut [[H; M]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        let n = input.len();
        let chunks = n.div_ceil(chunk);
        let rows = |k: usize| k * chunk..((k + 1) * chunk).min(n);
        let mut last_use: [Option<wgpu::SubmissionIndex>; RING] = Default::default();
        self.fill(&lanes[0], None, &input[rows(0)])?;
        let mut previous: Option<InFlight> = None;
        for k in 0..chunks {
            let lane = &lanes[k % RING];
            let range = rows(k);
            params.set_info([range.len() as u32, 0, 0, 0]);
            let submit = || self.submit_chunk::<N, M>(lane, range.len(), &params);
            if previous.is_none() && k + 1 == chunks {
                // One chunk: nothing to overlap.
                let (submission, mapped) = submit()?;
                let done = InFlight {
                    lane: k % RING,
                    rows: range.clone(),
                    submission,
                    mapped,
                };
                return self.finish(lane, done, input, output, status);
            }
            let (submitted, host) = std::thread::scope(|scope| {
                let submitting = scope.spawn(submit);
                let host = (|| {
                    if let Some(done) = previous.take() {
                        let rows = done.rows.clone();
                        last_use[done.lane] = Some(done.submission.clone());
                        self.finish(
                            &lanes[done.lane],
                            done,
                            &input[rows.clone()],
                            &mut output[rows.clone()],
                            &mut status[rows],
                        )?;
                    }
                    if k + 1 < chunks {
                        let next = (k + 1) % RING;
                        self.fill(&lanes[next], last_use[next].as_ref(), &input[rows(k + 1)])?;
                    }
                    Ok::<_, GpuError>(())
                })();
                let submitted = submitting.join().unwrap_or_else(|_| {
                    Err(GpuError::Readback("the submitting thread panicked".into()))
                });
                (submitted, host)
            });
            let (submission, mapped) = submitted?;
            host?;
            previous = Some(InFlight {
                lane: k % RING,
                rows: range,
                submission,
                mapped,
            });
        }
        if let Some(done) = previous.take() {
            let rows = done.rows.clone();
            self.finish(
                &lanes[done.lane],
                done,
                &input[rows.clone()],
                &mut output[rows.clone()],
                &mut status[rows],
            )?;
        }
        Ok(())
    }

    /// Maps `lane`'s host input buffer (free once submission `after` has finished) and writes
    /// `rows` into it in the kernel precision.
    fn fill<H: HostReal, const N: usize>(
        &self,
        lane: &LaneBuffers,
        after: Option<&wgpu::SubmissionIndex>,
        rows: &[[H; N]],
    ) -> Result<(), GpuError> {
        let bytes = (rows.len() * N * self.precision.size()) as u64;
        if bytes == 0 {
            return Ok(());
        }
        let mapped = self
            .context
            .map(&lane.input_host, wgpu::MapMode::Write, bytes);
        self.context.await_map(&mapped, 1, after)?;
        {
            let mut view = lane.input_host.get_mapped_range_mut(..bytes).map_err(|e| {
                lane.input_host.unmap();
                GpuError::Readback(e.to_string())
            })?;
            write_rows(view.slice(..), self.precision, rows);
        }
        lane.input_host.unmap();
        Ok(())
    }

    /// Writes the chunk's parameters, submits its copies and dispatch over `items` items, and
    /// starts mapping its results.
    #[allow(clippy::type_complexity)]
    fn submit_chunk<const N: usize, const M: usize>(
        &self,
        lane: &LaneBuffers,
        items: usize,
        params: &Params,
    ) -> Result<
        (
            wgpu::SubmissionIndex,
            std::sync::mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
        ),
        GpuError,
    > {
        let s = self.precision.size();
        let (in_bytes, out_bytes, status_bytes) = (
            (items * N * s) as u64,
            (items * M * s) as u64,
            (items * 4) as u64,
        );
        self.context
            .queue()
            .write_buffer(&lane.uniform, 0, params.bytes());
        let dispatch = &self.dispatch;
        let mut encoder = dispatch.encoder();
        if lane.input != lane.input_host {
            encoder.copy_buffer_to_buffer(&lane.input_host, 0, &lane.input, 0, in_bytes);
        }
        let groups = dispatch.grid(items.div_ceil(self.kernel.rows_per_invocation));
        dispatch.record(&mut encoder, &[(&lane.bind_group, groups)], None);
        for (source, host, bytes) in [
            (&lane.output, &lane.output_host, out_bytes),
            (&lane.status, &lane.status_host, status_bytes),
        ] {
            if source != host {
                encoder.copy_buffer_to_buffer(source, 0, host, 0, bytes);
            }
        }
        let submission = self.context.submit(encoder.finish());
        let (sender, receiver) = std::sync::mpsc::channel();
        for (host, bytes) in [
            (&lane.output_host, out_bytes),
            (&lane.status_host, status_bytes),
        ] {
            let sender = sender.clone();
            host.map_async(wgpu::MapMode::Read, ..bytes, move |r| {
                let _ = sender.send(r);
            });
        }
        Ok((submission, receiver))
    }

    /// Waits for a submitted chunk's results and converts them into `output` and `status`.
    fn finish<H: HostReal, const N: usize, const M: usize>(
        &self,
        lane: &LaneBuffers,
        done: InFlight,
        input: &[[H; N]],
        output: &mut [[H; M]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        self.context
            .await_map(&done.mapped, 2, Some(&done.submission))?;
        let s = self.precision.size();
        let items = output.len();
        let read = (|| {
            let codes = lane
                .status_host
                .get_mapped_range(..(items * 4) as u64)
                .map_err(|e| GpuError::Readback(e.to_string()))?;
            status.copy_from_slice(
                bytemuck::try_cast_slice(&codes[..])
                    .map_err(|e| GpuError::Readback(format!("mapped status not aligned: {e}")))?,
            );
            let values = lane
                .output_host
                .get_mapped_range(..(items * M * s) as u64)
                .map_err(|e| GpuError::Readback(e.to_string()))?;
            let limit = self.precision.huge();
            match self.precision {
                Precision::F32 => {
                    read_rows(reals::<f32>(&values[..])?, limit, input, status, output)
                }
                Precision::F64 => {
                    read_rows(reals::<f64>(&values[..])?, limit, input, status, output)
                }
            }
            Ok(())
        })();
        lane.status_host.unmap();
        lane.output_host.unmap();
        read
    }
}
