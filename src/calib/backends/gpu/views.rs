//! The skeleton the per-(candidate, view) kernels share (the fused affine grid and the scene
//! fit): one item per (candidate, view), M reals out each, the corner rows resident on the device
//! ([`ViewRows`]), chunked over candidates and views, the items summed over views on the device
//! (`calib_view_sum`) so that one row per candidate comes back. Indexing, chunking and buffers
//! only.

use std::num::NonZeroU64;
use std::ops::Range;
use std::sync::OnceLock;

use super::kernels;
use super::runner::{KernelRunner, candidate_params};
use crate::calib::problem::data::CameraPair;
use crate::engine::GpuEngine;
use crate::gpu::ResidentRows;
use crate::gpu::buffers::{input_usage, rows_from, upload_reals};
use crate::gpu::compose::{KernelSource, Precision, Rows, UNIFORM_WINDOW_BYTES};
use crate::gpu::context::GpuError;
use crate::gpu::dispatch::{Dispatch, GROUP};
use crate::model::Rig;

/// Byte alignment of every bound range of a uniform buffer: the largest value WebGPU allows for
/// `min_uniform_buffer_offset_alignment`, so a multiple of every adapter's.
const UNIFORM_ALIGNMENT: usize = 256;

/// Corner rows grouped by view, as the per-(candidate, view) kernels read them (binding 1), packed
/// once per precision and kept on the device across calls (the hundreds of small calls of a
/// stencil refinement upload nothing).
///
/// Packed into blocks, each a table of (first vec4, corners, 0, 0) per view followed by those
/// views' rows: where every view fits a [`UNIFORM_WINDOW_BYTES`] window, as consecutive views per
/// window, bound as a uniform buffer one window per dispatch ([`Rows::Uniform`], which lavapipe
/// loads with a gather, not a loop over the lanes); otherwise all views in one storage block.
#[derive(Debug)]
pub struct ViewRows {
    /// Every corner row, view by view.
    rows: Vec<f64>,
    /// Reals per corner row (a multiple of 4: the kernels read vec4).
    row_reals: usize,
    /// (first row, rows) per view.
    views: Vec<(usize, usize)>,
    /// The packing per precision, in one storage block and in uniform windows.
    packed: [OnceLock<Packed>; 4],
}

/// [`ViewRows`] packed for one precision.
#[derive(Debug)]
pub(super) struct Packed {
    /// How the kernels bind the blocks.
    rows: Rows,
    blocks: Vec<Block>,
    /// Every block, at its offset.
    resident: ResidentRows,
}

/// Consecutive views whose table and rows are one bound range of the packed buffer.
#[derive(Debug)]
struct Block {
    /// The views, numbered as in [`ViewRows`].
    views: Range<usize>,
    /// Start and length in bytes of the bound range.
    offset: u64,
    bytes: u64,
}

impl ViewRows {
    /// `rows` (`row_reals` reals per corner row, view by view) and each view's (first row, row
    /// count). Nothing is packed or uploaded until a kernel reads them.
    ///
    /// Panics if `row_reals` is not a positive multiple of 4, `rows` not whole rows, or a view
    /// outside the rows.
    pub fn new(rows: &[f64], row_reals: usize, views: &[(usize, usize)]) -> Self {
        assert!(
            row_reals > 0 && row_reals.is_multiple_of(4),
            "rows of whole vec4"
        );
        assert!(rows.len().is_multiple_of(row_reals), "whole rows");
        let count = rows.len() / row_reals;
        assert!(
            views.iter().all(|&(first, n)| first + n <= count),
            "views within the rows"
        );
        Self {
            rows: rows.to_vec(),
            row_reals,
            views: views.to_vec(),
            packed: Default::default(),
        }
    }

    /// Number of views.
    pub fn views(&self) -> usize {
        self.views.len()
    }

    /// Number of corner rows.
    pub fn corners(&self) -> usize {
        self.rows.len() / self.row_reals
    }

    /// How many times the rows went to a device (1 after any number of calls on one engine and
    /// precision).
    pub fn uploads(&self) -> usize {
        self.packed
            .iter()
            .filter_map(OnceLock::get)
            .map(|p| p.resident.uploads())
            .sum()
    }

    /// Drops the device copies (freeing their memory): the next kernel that reads the rows
    /// uploads them again.
    pub fn evict(&self) {
        for packed in self.packed.iter().filter_map(OnceLock::get) {
            packed.resident.evict();
        }
    }

    /// The rows packed for `precision`, in uniform windows where `uniform` allows and every view
    /// fits one, else in one storage block (one packing, and one device copy, for both cases).
    fn packed(&self, precision: Precision, uniform: bool) -> &Packed {
        let storage = 2 * usize::from(precision == Precision::F64);
        let window = Rows::uniform_window_vec4(precision);
        let row_vec4 = self.row_reals / 4;
        // A view needs its table entry and its rows in one window.
        let fits = |&(_, n): &(usize, usize)| n * row_vec4 < window;
        if uniform && self.views.iter().all(fits) {
            self.packed[storage + 1].get_or_init(|| self.pack_windows(precision))
        } else {
            self.packed[storage].get_or_init(|| self.pack_storage(precision))
        }
    }

    /// One block of every view, bound as storage.
    fn pack_storage(&self, precision: Precision) -> Packed {
        let mut reals = Vec::with_capacity(4 * self.views.len() + self.rows.len());
        self.push_block(&mut reals, 0..self.views.len());
        let bytes = (reals.len() * precision.size()) as u64;
        Packed {
            rows: Rows::Storage,
            blocks: vec![Block {
                views: 0..self.views.len(),
                offset: 0,
                bytes,
            }],
            resident: ResidentRows::from_reals(reals, 4),
        }
    }

    /// Consecutive views per uniform window, each window's block at an aligned offset; the buffer
    /// extends a whole window past the last block's start, since each binding is a whole window.
    fn pack_windows(&self, precision: Precision) -> Packed {
        let window = Rows::uniform_window_vec4(precision);
        let vec4_bytes = 4 * precision.size();
        let row_vec4 = self.row_reals / 4;
        let mut reals = Vec::new();
        let mut blocks = Vec::new();
        let mut start = 0;
        while start < self.views.len() {
            // As many views as fit (at least one: `packed` checked each fits alone).
            let mut end = start;
            let mut used = 0;
            while end < self.views.len() && used + 1 + self.views[end].1 * row_vec4 <= window {
                used += 1 + self.views[end].1 * row_vec4;
                end += 1;
            }
            let offset = (reals.len() * precision.size()).next_multiple_of(UNIFORM_ALIGNMENT);
            reals.resize(offset / precision.size(), 0.0);
            self.push_block(&mut reals, start..end);
            blocks.push(Block {
                views: start..end,
                offset: offset as u64,
                bytes: UNIFORM_WINDOW_BYTES as u64,
            });
            start = end;
        }
        let last = blocks.last().map_or(0, |b| b.offset as usize);
        reals.resize((last + UNIFORM_WINDOW_BYTES) / precision.size(), 0.0);
        debug_assert!(reals.len().is_multiple_of(vec4_bytes / precision.size()));
        Packed {
            rows: Rows::Uniform,
            blocks,
            resident: ResidentRows::from_reals(reals, 4).bound_as_uniform(),
        }
    }

    /// Appends the block of `views`: their table, then their rows; a table entry's first vec4
    /// counts from the block's start.
    fn push_block(&self, reals: &mut Vec<f64>, views: Range<usize>) {
        let row_vec4 = self.row_reals / 4;
        let mut first = views.len();
        for &(_, n) in &self.views[views.clone()] {
            reals.extend_from_slice(&[first as f64, n as f64, 0.0, 0.0]);
            first += n * row_vec4;
        }
        for &(row, n) in &self.views[views] {
            reals.extend_from_slice(&self.rows[row * self.row_reals..(row + n) * self.row_reals]);
        }
    }
}

/// Fewest items per dispatch, on average over the windows, for which a call on a software adapter
/// reads its rows from uniform windows: a dispatch costs lavapipe about 50 µs besides its items, and a few workgroups
/// leave some of its threads idle (7-candidate stencil calls over 185 views ran at 8.6 ms in
/// windows, 5.4 ms in one storage block; machine A). 64 workgroups of 54-corner views gain far
/// more than that from the faster loads.
const MIN_WINDOW_ITEMS: usize = 64 * GROUP;

/// Whether a call of `per_view` candidates for each of `views` views reads its rows from
/// `windows` uniform windows (one dispatch each) rather than one storage block.
fn large_enough_for_windows(per_view: usize, views: usize, windows: usize) -> bool {
    per_view * views >= MIN_WINDOW_ITEMS * windows.max(1)
}

/// What a per-(candidate, view) dispatch needs besides its candidates.
pub(super) struct ViewKernel<'a> {
    pub kernel: &'static KernelSource,
    pub precision: Precision,
    /// The corner rows, as the kernel reads them (binding 1).
    pub input: &'a ViewRows,
}

/// Views of one block that one dispatch covers.
struct Piece {
    block: usize,
    views: Range<usize>,
}

/// Most (candidate, view) items of one submission, in items of one chunk's binding: the chunks
/// of a call go to the device in one submission (one read-back) up to this many bindings' worth,
/// so that a software adapter still answers a huge call well within the context's wait limit
/// (16 M items of the 185-view scene's affine grid take lavapipe about 10 s).
const ROUND_CHUNK_ITEMS: usize = 4;

impl KernelRunner {
    /// Runs `job` over every (candidate, view) and sums over the views on the device:
    /// `output[c]` gets the sums over views 0, 1, … (in that order and in f64, as an f64 fold on
    /// the host would add them; f32 items in f32 with Neumaier's compensation where the adapter
    /// has no SHADER_F64) of the kernel's M reals for
    /// candidate c, and `status[c]` combines the views' statuses: 0 where every view's is 0,
    /// [`STATUS_RETRY`](crate::gpu::compose::STATUS_RETRY) where any view's is, else the first
    /// non-zero one in view order; the row NaN where the status is not 0. Without views the sums
    /// are 0 and the status 0.
    ///
    /// A chunk holds `per_view` candidates for each of its views, view-major: every candidate
    /// where they fit one chunk (a stencil's few candidates cost a few items per view, not a
    /// workgroup), else a multiple of the workgroup size, so that each workgroup's items share
    /// one view, the last chunk padded with its last candidate. The views are dispatched block by
    /// block of [`ViewRows`] (one dispatch per uniform window), as many views per batch as the
    /// items' binding holds, each batch followed by the view-sum kernel (`calib_view_sum`),
    /// which adds the batch to the chunk's sums on the device. Every chunk and batch of a call
    /// is one submission and one read-back of M reals and a status per candidate (up to
    /// [`ROUND_CHUNK_ITEMS`] chunks' items a submission).
    ///
    /// Panics if `output` and `status` are not `candidates.len()` long.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn run_views<const M: usize>(
        &self,
        engine: &GpuEngine,
        job: ViewKernel<'_>,
        rig: &Rig,
        cameras: CameraPair,
        candidates: &[[f64; 4]],
        output: &mut [[f64; M]],
        status: &mut [u32],
    ) -> Result<(), GpuError> {
        assert!(M <= 4, "at most 4 reals per item");
        let view_count = job.input.views();
        assert!(
            output.len() == candidates.len() && status.len() == output.len(),
            "output and status of every candidate"
        );
        if output.is_empty() {
            return Ok(());
        }
        if view_count == 0 {
            output.fill([0.0; M]);
            status.fill(0);
            return Ok(());
        }
        let precision = job.precision;
        let context = engine.context();
        let mut params = candidate_params(precision, rig, cameras)?;
        let real = precision.size();
        let capacity = self.chunk_items(engine, M * real);
        let views_per_chunk = view_count.min((capacity / GROUP).max(1));
        let fit = ((capacity / views_per_chunk) / GROUP * GROUP).max(GROUP);
        let per_view = if candidates.len() <= fit {
            candidates.len()
        } else {
            fit
        };
        // Uniform windows are lavapipe's gather (one dispatch each, a barrier between them); a
        // hardware GPU reads one storage block in one dispatch over every view of a batch.
        let windows = context.adapter().max_uniform_binding >= UNIFORM_WINDOW_BYTES as u64
            && match self.rows {
                Some(rows) => rows == Rows::Uniform,
                None if context.is_software() => {
                    let windowed = job.input.packed(precision, true);
                    windowed.rows == Rows::Uniform
                        && large_enough_for_windows(per_view, view_count, windowed.blocks.len())
                }
                None => false,
            };
        let packed = job.input.packed(precision, windows);
        let cap = context.max_storage_binding();
        if packed.rows == Rows::Storage && packed.blocks[0].bytes > cap {
            return Err(GpuError::Unsupported(format!(
                "{} corner rows do not fit one binding of {cap} bytes",
                job.input.corners()
            )));
        }
        // Each block cut into dispatches of at most `views_per_chunk` views, and the dispatches
        // into batches of at most `views_per_chunk` views together.
        let mut pieces = Vec::new();
        for (k, block) in packed.blocks.iter().enumerate() {
            for start in block.views.clone().step_by(views_per_chunk) {
                let end = (start + views_per_chunk).min(block.views.end);
                pieces.push(Piece {
                    block: k,
                    views: start..end,
                });
            }
        }
        let mut batches: Vec<Range<usize>> = Vec::new();
        let mut batch_views = 0;
        for (k, piece) in pieces.iter().enumerate() {
            match batches.last_mut() {
                Some(batch) if batch_views + piece.views.len() <= views_per_chunk => {
                    batch.end = k + 1;
                    batch_views += piece.views.len();
                }
                _ => {
                    batches.push(k..k + 1);
                    batch_views = piece.views.len();
                }
            }
        }
        let chunks = candidates.len().div_ceil(per_view);
        let round_chunks =
            (ROUND_CHUNK_ITEMS * capacity / (per_view * view_count)).clamp(1, chunks);

        let pipeline =
            context.kernel_pipeline(job.kernel, precision, packed.rows, params.layers())?;
        let dispatch = Dispatch::new(context, &pipeline, job.kernel.name);
        // The sums in f64 wherever the adapter has it (f32 items too: the host's f64 sums).
        let (sum_kernel, sum_precision) = match precision {
            Precision::F64 => (&kernels::VIEW_SUM, Precision::F64),
            Precision::F32 if context.adapter().f64 => {
                (&kernels::VIEW_SUM_F32_ITEMS, Precision::F64)
            }
            Precision::F32 => (&kernels::VIEW_SUM_F32, Precision::F32),
        };
        let sum_real = sum_precision.size();
        let sum_pipeline =
            context.kernel_pipeline(sum_kernel, sum_precision, Rows::Storage, params.layers())?;
        let summing = Dispatch::new(context, &sum_pipeline, sum_kernel.name);
        let rows_buf = packed.resident.on_device(context, precision)?;

        // The uniform: a slot per piece (the kernel's), then one per batch (the view sum's), each
        // at an aligned offset; the same for every chunk.
        // The view sum's Params are of its own precision (f64 sums of an f32 kernel's items).
        let mut sum_params = candidate_params(sum_precision, rig, cameras)?;
        let params_bytes = params.bytes().len();
        let sum_params_bytes = sum_params.bytes().len();
        let stride = params_bytes
            .max(sum_params_bytes)
            .next_multiple_of(UNIFORM_ALIGNMENT);
        let sum_base = pieces.len() * stride;
        let mut slots = vec![0u8; sum_base + batches.len() * stride];
        for batch in &batches {
            // Item base of each piece within its batch.
            let mut count = 0;
            for k in batch.clone() {
                let piece = &pieces[k];
                let block = &packed.blocks[piece.block];
                let n = per_view * piece.views.len();
                params.set_info([
                    n as u32,
                    per_view as u32,
                    count as u32,
                    (piece.views.start - block.views.start) as u32,
                ]);
                slots[k * stride..k * stride + params_bytes].copy_from_slice(params.bytes());
                count += n;
            }
        }
        for (b, batch) in batches.iter().enumerate() {
            let views: usize = pieces[batch.clone()].iter().map(|p| p.views.len()).sum();
            // The view sum's (calib_view_sum): candidates, views, adding, reals per item.
            sum_params.set_info([per_view as u32, views as u32, u32::from(b > 0), M as u32]);
            let at = sum_base + b * stride;
            slots[at..at + sum_params_bytes].copy_from_slice(sum_params.bytes());
        }

        let mut guard = self.buffers();
        let buffers = &mut *guard;
        let uniform_buf = buffers.uniform.uniform(context, slots.len())?;
        context.queue().write_buffer(&uniform_buf, 0, &slots);
        let round_candidates = round_chunks * per_view;
        let cand_buf = buffers
            .candidates
            .get(
                context,
                "candidates",
                round_candidates * 4 * real,
                input_usage(context),
            )?
            .clone();
        let items = per_view * views_per_chunk;
        let storage = wgpu::BufferUsages::STORAGE;
        let items_buf = buffers
            .items
            .get(context, "view items", items * M * real, storage)?
            .clone();
        let item_status_buf = buffers
            .item_status
            .get(context, "view item status", items * 4, storage)?
            .clone();
        let (sums_buf, sums_staging) =
            buffers
                .output
                .readable(context, "view sums", round_candidates * M * sum_real)?;
        let (codes_buf, codes_staging) =
            buffers
                .status
                .readable(context, "view sum status", round_candidates * 4)?;
        let range = |buffer, offset: usize, bytes: usize| {
            wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer,
                offset: offset as u64,
                size: NonZeroU64::new(bytes as u64),
            })
        };
        // Per chunk of a round: the kernel's bind group per piece (its slot, its block, the
        // chunk's candidates), the view sum's per batch (its slot, the chunk's sums).
        let mut kernel_groups = Vec::with_capacity(round_chunks * pieces.len());
        let mut sum_groups = Vec::with_capacity(round_chunks * batches.len());
        for chunk in 0..round_chunks {
            let candidate_bytes = per_view * 4 * real;
            for (k, piece) in pieces.iter().enumerate() {
                let block = &packed.blocks[piece.block];
                kernel_groups.push(dispatch.bind_resources([
                    (0, range(&uniform_buf, k * stride, params_bytes)),
                    (
                        1,
                        range(&rows_buf, block.offset as usize, block.bytes as usize),
                    ),
                    (2, items_buf.as_entire_binding()),
                    (3, item_status_buf.as_entire_binding()),
                    (
                        4,
                        range(&cand_buf, chunk * candidate_bytes, candidate_bytes),
                    ),
                ]));
            }
            for b in 0..batches.len() {
                sum_groups.push(summing.bind_resources([
                    (
                        0,
                        range(&uniform_buf, sum_base + b * stride, sum_params_bytes),
                    ),
                    (1, items_buf.as_entire_binding()),
                    (2, item_status_buf.as_entire_binding()),
                    (
                        3,
                        range(
                            &sums_buf,
                            chunk * per_view * M * sum_real,
                            per_view * M * sum_real,
                        ),
                    ),
                    (4, range(&codes_buf, chunk * per_view * 4, per_view * 4)),
                ]));
            }
        }

        let mut padded = vec![[0.0; 4]; round_candidates];
        let mut values = vec![[0.0; M]; round_candidates];
        let mut codes = vec![0u32; round_candidates];
        for first in (0..candidates.len()).step_by(round_candidates) {
            let last = (first + round_candidates).min(candidates.len());
            let used = (last - first).div_ceil(per_view);
            // Pad the last chunk with its last candidate: every workgroup then shares one view.
            for (k, slot) in padded[..used * per_view].iter_mut().enumerate() {
                *slot = candidates[(first + k).min(last - 1)];
            }
            upload_reals(
                context,
                precision,
                &cand_buf,
                padded[..used * per_view].as_flattened(),
            )?;
            let mut encoder = dispatch.encoder();
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some(job.kernel.name),
                    timestamp_writes: None,
                });
                for chunk in 0..used {
                    for (b, batch) in batches.iter().enumerate() {
                        pass.set_pipeline(&pipeline);
                        for k in batch.clone() {
                            let n = per_view * pieces[k].views.len();
                            let (x, y) = dispatch.grid(n);
                            pass.set_bind_group(0, &kernel_groups[chunk * pieces.len() + k], &[]);
                            pass.dispatch_workgroups(x, y, 1);
                        }
                        pass.set_pipeline(&sum_pipeline);
                        let (x, y) = summing.grid(per_view);
                        pass.set_bind_group(0, &sum_groups[chunk * batches.len() + b], &[]);
                        pass.dispatch_workgroups(x, y, 1);
                    }
                }
            }
            let n = last - first;
            let copies = [
                (&sums_buf, &sums_staging, (n * M * sum_real) as u64),
                (&codes_buf, &codes_staging, (n * 4) as u64),
            ];
            let (values, codes) = (&mut values[..n], &mut codes[..n]);
            context.read_back(encoder, &copies, |data| {
                codes.copy_from_slice(bytemuck::cast_slice(data[1]));
                rows_from(data[0], sum_precision, codes, values);
            })?;
            output[first..last].copy_from_slice(values);
            status[first..last].copy_from_slice(codes);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows numbered so that every real says where it came from: view v, row j, real k.
    fn numbered(views: &[usize], row_reals: usize) -> (Vec<f64>, Vec<(usize, usize)>) {
        let mut rows = Vec::new();
        let mut table = Vec::new();
        for (v, &n) in views.iter().enumerate() {
            table.push((rows.len() / row_reals, n));
            for j in 0..n {
                for k in 0..row_reals {
                    rows.push((v * 1_000_000 + j * 100 + k) as f64);
                }
            }
        }
        (rows, table)
    }

    /// Reads back view v's rows through its block's table, as the kernels do.
    fn rows_of(packed: &Packed, precision: Precision, row_reals: usize, v: usize) -> Vec<f64> {
        let block = packed
            .blocks
            .iter()
            .find(|b| b.views.contains(&v))
            .expect("every view in a block");
        let reals = packed.resident.reals_for_tests();
        let start = block.offset as usize / precision.size();
        let entry = start + 4 * (v - block.views.start);
        let (first, n) = (reals[entry] as usize, reals[entry + 1] as usize);
        let from = start + 4 * first;
        reals[from..from + n * row_reals].to_vec()
    }

    #[test]
    fn windows_hold_whole_views_in_order_at_aligned_offsets() {
        // 54-corner views of the scene (3 vec4 a row): 25 per f32 window, 12 per f64 window.
        for (precision, per_window) in [(Precision::F32, 25), (Precision::F64, 12)] {
            let counts = vec![54; 30];
            let (rows, table) = numbered(&counts, 12);
            let view_rows = ViewRows::new(&rows, 12, &table);
            let packed = view_rows.packed(precision, true);
            assert_eq!(packed.rows, Rows::Uniform);
            let blocks: Vec<_> = packed.blocks.iter().map(|b| b.views.clone()).collect();
            let expected: Vec<_> = (0..30)
                .step_by(per_window)
                .map(|v| v..(v + per_window).min(30))
                .collect();
            assert_eq!(blocks, expected);
            for block in &packed.blocks {
                assert_eq!(block.offset as usize % UNIFORM_ALIGNMENT, 0);
                assert_eq!(block.bytes as usize, UNIFORM_WINDOW_BYTES);
                let size = packed.resident.reals_for_tests().len() * precision.size();
                assert!(
                    block.offset as usize + UNIFORM_WINDOW_BYTES <= size,
                    "window in the buffer"
                );
            }
            for (v, &(first, n)) in table.iter().enumerate() {
                assert_eq!(
                    rows_of(packed, precision, 12, v),
                    rows[first * 12..(first + n) * 12]
                );
            }
        }
    }

    #[test]
    fn calls_too_small_to_fill_the_windows_read_one_storage_block() {
        // A 7-candidate stencil call over 185 views of 54 corners: 8 f32 windows of the scene
        // kernels, 47 f64 windows of the affine grid; a 64 × 64 sweep.
        assert!(!large_enough_for_windows(7, 185, 8));
        assert!(!large_enough_for_windows(7, 185, 47));
        assert!(large_enough_for_windows(4096, 185, 8));
        assert!(large_enough_for_windows(4096, 185, 47));
    }

    #[test]
    fn a_view_larger_than_a_window_puts_every_view_in_storage() {
        // 300 corners of 36 reals (the affine grid's rows) are 2700 vec4: more than the 2048 of
        // an f64 window, fewer than the 4096 of an f32 one.
        let counts = [54, 300, 0, 54];
        let (rows, table) = numbered(&counts, 36);
        let view_rows = ViewRows::new(&rows, 36, &table);
        let f64_packed = view_rows.packed(Precision::F64, true);
        assert_eq!(f64_packed.rows, Rows::Storage);
        assert_eq!(f64_packed.blocks.len(), 1);
        // The storage packing asked for either way: one copy on the device, not two.
        assert!(std::ptr::eq(
            f64_packed,
            view_rows.packed(Precision::F64, false)
        ));
        assert_eq!(view_rows.packed(Precision::F32, true).rows, Rows::Uniform);
        assert_eq!(view_rows.packed(Precision::F32, false).rows, Rows::Storage);
        for (v, &(first, n)) in table.iter().enumerate() {
            for (packed, precision) in [
                (f64_packed, Precision::F64),
                (view_rows.packed(Precision::F32, true), Precision::F32),
            ] {
                assert_eq!(
                    rows_of(packed, precision, 36, v),
                    rows[first * 36..(first + n) * 36]
                );
            }
        }
    }
}
