//! Parses and validates every composed WGSL kernel with naga, in both precisions and both
//! corner-row bindings, so that a WGSL mistake is a build error naming the
//! kernel, never a panic or a `GpuError::Kernel` at pipeline creation. The composition is the crate's own
//! (`src/gpu/shaders/compose.rs`, with a copy of the CPU's stopping rules that `tests/gpu.rs` holds
//! equal to the engine's); the validation is `build/wgsl.rs`, which `tests/gpu.rs` also runs.

#[allow(dead_code)]
#[path = "src/gpu/shaders/compose.rs"]
mod compose;
#[path = "build/wgsl.rs"]
mod wgsl;

// `CpuBounds` is named by build/wgsl.rs as `super::CpuBounds`.
use compose::{CpuBounds, Kernel, Precision, Rows};
use wgsl::CPU_BOUNDS_COPY;

fn main() {
    println!("cargo:rerun-if-changed=shaders");
    println!("cargo:rerun-if-changed=src/gpu/shaders/compose.rs");
    println!("cargo:rerun-if-changed=build/wgsl.rs");
    println!("cargo:rerun-if-changed=build.rs");
    let mut errors = Vec::new();
    for kernel in Kernel::ALL {
        for precision in [Precision::F32, Precision::F64] {
            // A kernel of fixed precision is composed once, as the engine composes it.
            if kernel
                .fixed_precision()
                .is_some_and(|fixed| fixed != precision)
            {
                continue;
            }
            let bindings: &[Rows] = if kernel.reads_view_rows() {
                &Rows::ALL
            } else {
                &[Rows::Storage]
            };
            for &rows in bindings {
                let source = compose::source(kernel, precision, rows, &CPU_BOUNDS_COPY);
                let rows_name = if kernel.reads_view_rows() {
                    format!(" {} rows", rows.name())
                } else {
                    String::new()
                };
                let label = format!("kernel {} {precision}{rows_name}", kernel.name());
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
            "{} composed WGSL kernel(s) failed naga's checks (line numbers count in the composed module: prelude, \
             shaders/common.wgsl, shaders/lib/, then the kernel; src/gpu/shaders/compose.rs):\n\n{}",
            errors.len(),
            errors.join("\n")
        );
        std::process::exit(1);
    }
}
