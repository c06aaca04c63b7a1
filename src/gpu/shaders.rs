//! WGSL sources and their composition. A kernel module is: a precision prelude (generated from the
//! crate's constants, so the CPU and GPU stop at the same bounds), `shaders/common.wgsl`, the
//! relations in `shaders/lib/`, and one kernel from `shaders/kernels/`. The composition itself is in [`compose`], which
//! `build.rs` also compiles to validate every kernel with naga at build time.

use crate::model::camera::UNDISTORT_MAX_ITERATIONS;
use crate::model::refractive_camera::{PROJECT_MAX_ITERATIONS, PROJECT_TOLERANCE};
use crate::model::stereo::{MIN_BINOCULAR_CONDITIONING, MIN_RAY_ANGLE_SIN2};

pub mod compose;

pub use compose::{CpuBounds, Kernel, Precision, Rows, STATUS_RETRY, UNIFORM_WINDOW_BYTES};

/// Invocations per workgroup of every kernel: the value of WGSL's `override WORKGROUP_SIZE`
/// (`shaders/common.wgsl`, no default there), set at pipeline creation by
/// [`GpuContext::pipeline`](super::GpuContext::pipeline), and the width of every host dispatch
/// computation.
pub const WORKGROUP_SIZE: u32 = 64;

/// The CPU path's stopping rules, as the kernels get them.
pub const CPU_BOUNDS: CpuBounds = CpuBounds {
    undistort_max_iterations: UNDISTORT_MAX_ITERATIONS,
    project_tolerance: PROJECT_TOLERANCE,
    project_max_iterations: PROJECT_MAX_ITERATIONS,
    min_ray_angle_sin2: MIN_RAY_ANGLE_SIN2,
    min_binocular_conditioning: MIN_BINOCULAR_CONDITIONING,
};

/// The precision prelude with the CPU's stopping rules: see [`compose::prelude`].
pub fn prelude(precision: Precision) -> String {
    compose::prelude(precision, &CPU_BOUNDS)
}

/// The composed WGSL module of `kernel` at `precision` with the CPU's stopping rules; `rows` the
/// corner-row binding of per-view kernels (ignored by the others).
pub fn source(kernel: Kernel, precision: Precision, rows: Rows) -> String {
    compose::source(kernel, precision, rows, &CPU_BOUNDS)
}
