//! The GPU backend: WGSL compute kernels (`shaders/`) run through wgpu over batches of any size,
//! checked against the f64 CPU reference. This module holds no geometry beyond indexing and
//! buffer layout; every kernel function has a CPU twin of the same name in [`crate::model`].
//!
//! - [`context`]: adapter choice, device, read-back (all version-sensitive wgpu calls);
//! - [`compose`]: composition of the WGSL sources per kernel and precision (also compiled by
//!   `build.rs`, which validates every kernel with naga);
//! - [`layout`]: the `#[repr(C)]` host mirrors of the kernels' uniform;
//! - [`engine`]: chunked batches, buffer reuse, f32/f64 conversion.

pub(crate) mod buffers;
pub mod compose;
pub mod context;
pub mod dispatch;
pub mod engine;
pub mod layout;

pub use compose::{CpuBounds, KernelSource, Precision, Rows};
pub use context::{AdapterSummary, CPU_BOUNDS, GpuContext, GpuError, adapters, source};
pub use dispatch::{KernelTimer, MAX_CHUNK_ITEMS};
pub use engine::{GpuEngine, HostReal, ResidentRows};
