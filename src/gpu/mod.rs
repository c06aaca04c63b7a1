//! The GPU engine: wgpu compute kernels (WGSL in `shaders/`) over batches, checked against the f64
//! CPU reference. This module holds no geometry beyond indexing and buffer layout; every kernel
//! has a CPU twin of the same name in [`crate::model`].
//!
//! Version-sensitive wgpu calls live in [`context`].

pub mod backproject;
pub mod context;
pub mod layout;
pub mod shaders;

pub use backproject::GpuBackproject;
pub use context::{AdapterSummary, GpuContext, GpuError, adapters};
