//! One kernel dispatch from bind group to results in host memory, the sequence every host module
//! runs: bind the buffers (whole, or ranges of them) → encode the compute pass (optionally
//! between GPU timestamps) → submit → read the results back; and the chunking arithmetic around
//! it (items per chunk under the binding cap, workgroup grids past the per-dimension limit).
//! Indexing and encoding only.

use super::compose::WORKGROUP_SIZE;
use super::context::{GpuContext, GpuError};

/// Largest number of items per dispatch whatever the binding cap: bounds the device and staging
/// memory (4 Mi items: 96 MiB of f32 rays, 192 MiB in f64 split over two chunks by the cap).
pub const MAX_CHUNK_ITEMS: usize = 1 << 22;

/// Largest workgroup count per dispatch dimension every Vulkan adapter supports.
pub(crate) const MAX_GROUPS_PER_DIMENSION: usize = 65_535;

/// Items per workgroup ([`WORKGROUP_SIZE`]) as a host count.
pub(crate) const GROUP: usize = WORKGROUP_SIZE as usize;

/// The clock behind a kernel time (`GpuEngine::kernel_seconds`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KernelTimer {
    /// GPU timestamps at the start and end of the compute pass: the kernel alone.
    GpuTimestamp,
    /// Host clocks around submit and wait: the kernel plus the driver's latency.
    Host,
}

impl KernelTimer {
    /// `gpu_timestamp` or `host`, as `flatport bench --json` writes it.
    pub fn name(self) -> &'static str {
        match self {
            Self::GpuTimestamp => "gpu_timestamp",
            Self::Host => "host",
        }
    }
}

/// Items per chunk when each item needs at most `bytes_per_item` of one binding: what a binding
/// of `binding_bytes` (the adapter's largest storage binding) holds, at most `max_items`, in
/// whole workgroups (at least one).
pub(crate) fn chunk_items(binding_bytes: u64, bytes_per_item: usize, max_items: usize) -> usize {
    let cap = (binding_bytes as usize / bytes_per_item.max(1)).min(max_items);
    (cap / GROUP * GROUP).max(GROUP)
}

/// Workgroup counts (x, y) for `items` items in [`WORKGROUP_SIZE`]-wide workgroups, at most
/// `max_per_dimension` per dimension: 1-D while it fits, else y rows of x groups with x·y as close
/// above the needed count as the rows allow (fewer than y spare groups), since the kernels index
/// items as `gid.x + gid.y · groups.x · WORKGROUP_SIZE` and guard the tail. A full 2²² chunk is
/// 65 536 groups of 64: 2 rows of 32 768, not 2 rows of 65 535 (twice the work).
pub(crate) fn dispatch_grid(items: u32, max_per_dimension: u32) -> (u32, u32) {
    let groups = items.div_ceil(WORKGROUP_SIZE).max(1);
    let max = max_per_dimension.max(1);
    if groups <= max {
        return (groups, 1);
    }
    let rows = groups.div_ceil(max);
    (groups.div_ceil(rows), rows)
}

/// A pair of GPU timestamps and the buffers that bring them to the host: the clock of every
/// kernel time (one dispatch's, or a chain's).
pub(crate) struct Timestamps {
    queries: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    staging: wgpu::Buffer,
    /// Seconds per tick.
    tick: f64,
}

impl Timestamps {
    /// Timestamps on `context`, labelled `label`; `None` where the device has no TIMESTAMP_QUERY.
    pub(crate) fn new(context: &GpuContext, label: &str) -> Result<Option<Self>, GpuError> {
        let device = context.device();
        if !device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return Ok(None);
        }
        let queries = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some(label),
            ty: wgpu::QueryType::Timestamp,
            count: 2,
        });
        let resolve = context.buffer(
            label,
            16,
            wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
        )?;
        let staging = context.buffer(
            label,
            16,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )?;
        let tick = context.queue().get_timestamp_period() as f64 * 1e-9;
        Ok(Some(Self {
            queries,
            resolve,
            staging,
            tick,
        }))
    }

    /// Writes of timestamp `start` at a compute pass's beginning (where given) and `end` at its
    /// end (where given).
    pub(crate) fn writes(
        &self,
        start: Option<u32>,
        end: Option<u32>,
    ) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: start,
            end_of_pass_write_index: end,
        }
    }

    /// Submits `encoder` (whose passes wrote both timestamps), waits, and returns the seconds
    /// between them.
    pub(crate) fn seconds(
        &self,
        context: &GpuContext,
        mut encoder: wgpu::CommandEncoder,
    ) -> Result<f64, GpuError> {
        encoder.resolve_query_set(&self.queries, 0..2, &self.resolve, 0);
        let ticks = context.read_back(encoder, &[(&self.resolve, &self.staging, 16)], |data| {
            let stamps: &[u64] = bytemuck::cast_slice(data[0]);
            stamps[1].saturating_sub(stamps[0])
        })?;
        Ok(ticks as f64 * self.tick)
    }
}

/// Dispatches of one compiled kernel on one context: its bind groups, its compute passes, their
/// submission and the read-back of their results. `label` names the encoder, the pass and the
/// bind groups (the kernel's name).
pub(crate) struct Dispatch<'a> {
    context: &'a GpuContext,
    pipeline: &'a wgpu::ComputePipeline,
    label: &'a str,
}

impl<'a> Dispatch<'a> {
    /// Dispatches of `pipeline` on `context`.
    pub(crate) fn new(
        context: &'a GpuContext,
        pipeline: &'a wgpu::ComputePipeline,
        label: &'a str,
    ) -> Self {
        Self {
            context,
            pipeline,
            label,
        }
    }

    /// A bind group of the pipeline with each `(binding, buffer)` bound whole.
    pub(crate) fn bind(&self, entries: &[(u32, &wgpu::Buffer)]) -> wgpu::BindGroup {
        self.bind_resources(
            entries
                .iter()
                .map(|&(binding, buffer)| (binding, buffer.as_entire_binding())),
        )
    }

    /// A bind group of the pipeline with each binding's resource given (a range of a buffer, say).
    pub(crate) fn bind_resources<'b>(
        &self,
        entries: impl IntoIterator<Item = (u32, wgpu::BindingResource<'b>)>,
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .into_iter()
            .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource })
            .collect();
        self.context
            .device()
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(self.label),
                layout: &self.pipeline.get_bind_group_layout(0),
                entries: &entries,
            })
    }

    /// The workgroup grid of `items` invocations on this adapter ([`dispatch_grid`]).
    pub(crate) fn grid(&self, items: usize) -> (u32, u32) {
        dispatch_grid(
            items as u32,
            self.context.adapter().max_workgroups_per_dimension,
        )
    }

    /// An empty command encoder, labelled.
    pub(crate) fn encoder(&self) -> wgpu::CommandEncoder {
        self.context
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some(self.label),
            })
    }

    /// Records one compute pass into `encoder`: the pipeline, then each `(bind group, (x, y)
    /// workgroups)` in order, with GPU timestamps written around the pass where asked.
    pub(crate) fn record(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        dispatches: &[(&wgpu::BindGroup, (u32, u32))],
        timestamp_writes: Option<wgpu::ComputePassTimestampWrites>,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(self.label),
            timestamp_writes,
        });
        pass.set_pipeline(self.pipeline);
        for &(bind_group, (x, y)) in dispatches {
            pass.set_bind_group(0, bind_group, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
    }

    /// Runs `dispatches` in one pass and submission, then copies each `(source, staging, bytes)`
    /// into its staging buffer (nothing to copy where `staging` is `source`), waits, and hands
    /// the mapped bytes of every staging buffer, in order, to `read`.
    pub(crate) fn run<T>(
        &self,
        dispatches: &[(&wgpu::BindGroup, (u32, u32))],
        copies: &[(&wgpu::Buffer, &wgpu::Buffer, u64)],
        read: impl FnOnce(&[&[u8]]) -> T,
    ) -> Result<T, GpuError> {
        let mut encoder = self.encoder();
        self.record(&mut encoder, dispatches, None);
        self.context.read_back(encoder, copies, read)
    }

    /// Seconds of one dispatch of `groups` workgroups over `bind_group` (the data already on the
    /// device): the fastest of `repeats` dispatches after one warm-up, with the clock that
    /// measured it: GPU timestamps written at the start and end of the compute pass where the
    /// device has TIMESTAMP_QUERY (the kernel's own time), else host clocks around submit and
    /// wait (which add the driver's latency).
    pub(crate) fn seconds(
        &self,
        bind_group: &wgpu::BindGroup,
        groups: (u32, u32),
        repeats: usize,
    ) -> Result<(f64, KernelTimer), GpuError> {
        let mut best = f64::INFINITY;
        let Some(stamps) = Timestamps::new(self.context, "kernel time")? else {
            for _ in 0..=repeats {
                let mut encoder = self.encoder();
                self.record(&mut encoder, &[(bind_group, groups)], None);
                let started = std::time::Instant::now();
                self.context.submit(encoder.finish());
                self.context.wait()?;
                best = best.min(started.elapsed().as_secs_f64());
            }
            return Ok((best, KernelTimer::Host));
        };
        for _ in 0..=repeats {
            let mut encoder = self.encoder();
            let writes = stamps.writes(Some(0), Some(1));
            self.record(&mut encoder, &[(bind_group, groups)], Some(writes));
            best = best.min(stamps.seconds(self.context, encoder)?);
        }
        Ok((best, KernelTimer::GpuTimestamp))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dispatch_grids_cover_every_item_with_fewer_spare_groups_than_rows() {
        for items in [
            1u32,
            63,
            64,
            65,
            65_535 * 64,
            65_535 * 64 + 1,
            1 << 22,
            (1 << 22) + 17,
            u32::MAX,
        ] {
            let (x, y) = dispatch_grid(items, 65_535);
            let needed = items.div_ceil(WORKGROUP_SIZE) as u64;
            assert!(x <= 65_535 && y <= 65_535, "{items}: {x} × {y}");
            assert!(
                x as u64 * y as u64 >= needed,
                "{items}: {x} × {y} misses items"
            );
            assert!(
                x as u64 * y as u64 - needed < y as u64,
                "{items}: {x} × {y} for {needed} groups"
            );
        }
        assert_eq!(dispatch_grid(1 << 22, 65_535), (32_768, 2));
        assert_eq!(dispatch_grid(0, 65_535), (1, 1));
    }

    /// Chunks are whole workgroups within the binding and the item limit, and at least one
    /// workgroup even where one item would not fit.
    #[test]
    fn chunks_are_whole_workgroups_within_the_binding() {
        let lavapipe = 128 << 20;
        assert_eq!(
            chunk_items(lavapipe, 24, 1 << 23),
            5_592_405 / GROUP * GROUP
        );
        assert_eq!(chunk_items(lavapipe, 16, MAX_CHUNK_ITEMS), MAX_CHUNK_ITEMS);
        assert_eq!(chunk_items(lavapipe, 24, 1000), 960);
        assert_eq!(chunk_items(1000, 24, MAX_CHUNK_ITEMS), GROUP);
        assert_eq!(
            chunk_items(lavapipe, 0, 100),
            GROUP,
            "zero bytes per item counts as one"
        );
        for (binding, bytes, max) in [(lavapipe, 48, 1 << 20), (1 << 30, 36, 777_777)] {
            let items = chunk_items(binding, bytes, max);
            assert!(items.is_multiple_of(GROUP) && items <= max, "{items}");
            assert!((items * bytes) as u64 <= binding, "{items} × {bytes}");
        }
    }

    /// A small per-dimension limit (as a test adapter might report) still covers every item.
    #[test]
    fn dispatch_grids_cover_every_item_under_a_small_limit() {
        for max in [1u32, 2, 7, 1000] {
            for items in [1u32, 64, 65, 64 * 7 + 1, 100_000] {
                let (x, y) = dispatch_grid(items, max);
                assert!(x <= max, "{items} under {max}: x = {x}");
                assert!(
                    u64::from(x) * u64::from(y) * u64::from(WORKGROUP_SIZE) >= u64::from(items),
                    "{items} under {max}: {x} × {y}"
                );
            }
        }
    }
}
