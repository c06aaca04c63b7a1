//! Parses and validates every composed WGSL kernel of every catalogue with naga, in both
//! precisions and both view-row bindings, so that a WGSL mistake is a build error naming the
//! kernel, never a panic or a `GpuError::Kernel` at pipeline creation. The composition is the
//! crate's own (`src/gpu/compose.rs`, with a copy of the CPU's stopping rules that `tests/gpu.rs`
//! holds equal to the context's), the catalogues are the crate's (`src/engine/gpu/kernels.rs`,
//! `src/calib/backends/gpu/kernels.rs`), the validation is `build/wgsl.rs`, which `tests/gpu.rs`
//! also runs.

//!
//! Without the `gpu` feature there are no kernels, and nothing to check.

#[cfg(feature = "gpu")]
#[allow(dead_code)]
#[path = "src/gpu/compose.rs"]
pub mod compose;
/// The catalogues name `crate::gpu::compose::KernelSource`, as in the crate.
#[cfg(feature = "gpu")]
mod gpu {
    pub use super::compose;
}
#[cfg(feature = "gpu")]
#[allow(dead_code)]
#[path = "src/calib/backends/gpu/kernels.rs"]
mod calibration_kernels;
#[cfg(feature = "gpu")]
#[allow(dead_code)]
#[path = "src/engine/gpu/kernels.rs"]
mod relation_kernels;
#[cfg(feature = "gpu")]
#[allow(dead_code)]
#[path = "src/stereo/gpu/kernels.rs"]
mod stereo_kernels;
#[cfg(feature = "gpu")]
#[path = "build/wgsl.rs"]
mod wgsl;

// `CpuBounds` is named by build/wgsl.rs as `super::CpuBounds`.
#[cfg(feature = "gpu")]
use compose::{CpuBounds, KernelSource, Precision, Rows};

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    #[cfg(feature = "gpu")]
    validate();
}

/// Composes and validates every kernel; exits with the errors.
#[cfg(feature = "gpu")]
fn validate() {
    use std::collections::HashSet;
    use wgsl::CPU_BOUNDS_COPY;

    for path in [
        "shaders",
        "src/gpu/compose.rs",
        "src/engine/gpu/kernels.rs",
        "src/calib/backends/gpu/kernels.rs",
        "src/stereo/gpu/kernels.rs",
        "build/wgsl.rs",
        "build.rs",
    ] {
        println!("cargo:rerun-if-changed={path}");
    }
    let kernels: Vec<&KernelSource> = relation_kernels::ALL
        .iter()
        .chain(&calibration_kernels::ALL)
        .chain(&stereo_kernels::ALL)
        .copied()
        .collect();
    let mut errors = Vec::new();
    // The pipeline cache keys kernels by name.
    let mut names = HashSet::new();
    for kernel in &kernels {
        if !names.insert(kernel.name) {
            errors.push(format!(
                "kernel {}: the name is taken by another kernel of a catalogue",
                kernel.name
            ));
        }
    }
    for kernel in kernels {
        for precision in [Precision::F32, Precision::F64] {
            // A kernel of fixed precision is composed once, as the pipeline cache composes it.
            if kernel.precision(precision) != precision {
                continue;
            }
            let bindings: &[Rows] = if kernel.reads_view_rows {
                &Rows::ALL
            } else {
                &[Rows::Storage]
            };
            for &rows in bindings {
                let source = compose::compose(kernel, precision, rows, &CPU_BOUNDS_COPY);
                let label = format!("kernel {} {precision}", kernel.label(rows));
                let capabilities = wgsl::capabilities(precision == Precision::F64);
                if let Err(error) = wgsl::check(&label, &source, capabilities) {
                    errors.push(error);
                }
            }
        }
    }
    if !errors.is_empty() {
        // Cargo prints a failed build script's stderr.
        eprintln!(
            "{} composed WGSL kernel(s) failed the build's checks (line numbers count in the composed module: \
             prelude, shaders/common.wgsl, shaders/lib/, then the kernel's parts; src/gpu/compose.rs):\n\n{}",
            errors.len(),
            errors.join("\n")
        );
        std::process::exit(1);
    }
}
