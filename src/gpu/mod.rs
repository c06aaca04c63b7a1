//! The wgpu toolkit: WGSL compute kernels (`shaders/`) composed, compiled once per context and
//! run over batches of any size, headless, on a Vulkan adapter. It holds no geometry beyond
//! indexing and buffer layout, and knows no kernel by name: each user keeps a catalogue of
//! [`KernelSource`]s beside its host code (the batch engine's relation kernels in
//! [`crate::engine::gpu`], the cost kernels beside the GPU cost backend).
//!
//! - [`compose`]: the pure-string composition of a kernel in a precision (also compiled by
//!   `build.rs`, which validates every kernel of every catalogue with naga);
//! - [`context`]: adapter choice, device, the pipeline cache every user of a context shares,
//!   waits and read-back (all version-sensitive wgpu calls);
//! - [`layout`]: the `#[repr(C)]` host mirrors of the kernels' uniform;
//! - `buffers`: buffers reused across chunks and calls, mapped or staged, and the host-side
//!   conversions to and from a kernel precision;
//! - [`dispatch`]: one dispatch from bind group to results in host memory, kernel timing, the
//!   chunking arithmetic;
//! - [`stream`]: row kernels streamed through a ring of buffer sets, f32 or f64 host rows
//!   ([`HostReal`]);
//! - [`resident`]: rows kept on the device across calls ([`ResidentRows`]);
//! - [`device_rows`]: rows that live on the device ([`DeviceRows`]): uploaded once, made and
//!   read by chains of kernels, read back once or never; the caller's own `wgpu::Buffer`s;
//! - [`roofs`]: the host link's and the device memory's bandwidths, which GPU figures are read
//!   against (`flatport bench`).
//!
//! Without the crate's `gpu` feature only [`compose`] is here (a kernel precision names what the
//! options ask for, whichever device runs).

#[cfg(feature = "gpu")]
pub(crate) mod buffers;
pub mod compose;
#[cfg(feature = "gpu")]
pub mod context;
#[cfg(feature = "gpu")]
pub mod device_rows;
#[cfg(feature = "gpu")]
pub mod dispatch;
#[cfg(feature = "gpu")]
pub mod layout;
#[cfg(feature = "gpu")]
pub mod resident;
#[cfg(feature = "gpu")]
pub mod roofs;
#[cfg(feature = "gpu")]
pub mod stream;

pub use compose::{CpuBounds, KernelSource, Precision, Rows};
#[cfg(feature = "gpu")]
pub use context::{AdapterSummary, CPU_BOUNDS, GpuContext, GpuError, adapters, source};
#[cfg(feature = "gpu")]
pub use device_rows::{DeviceRows, RowKind};
#[cfg(feature = "gpu")]
pub use dispatch::{KernelTimer, MAX_CHUNK_ITEMS};
#[cfg(feature = "gpu")]
pub use resident::ResidentRows;
#[cfg(feature = "gpu")]
pub use stream::{HostReal, STREAM_CHUNK_ROWS, default_stream_chunk_rows};
