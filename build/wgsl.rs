//! Parses and validates a composed WGSL kernel with naga, no GPU: shared by `build.rs` (every
//! kernel at build time) and `tests/gpu.rs` (which feeds it broken snippets too).

use naga::valid::{Capabilities, ValidationFlags, Validator};

use super::CpuBounds;

/// A copy of the CPU's stopping rules (`gpu::CPU_BOUNDS`, from `crate::model`, which a
/// build script cannot reach), so that the build validates the very text the engine compiles;
/// `tests/gpu.rs` fails when the two differ.
pub const CPU_BOUNDS_COPY: CpuBounds = CpuBounds {
    undistort_max_iterations: 30,
    project_tolerance: 1e-13,
    project_max_iterations: 100,
    switch_max_q: 100.0,
    min_ray_angle_sin2: 1e-12,
    min_binocular_conditioning: 1e-9,
};

/// The shader capabilities a kernel needs of the adapter, and no more: `FLOAT64` for f64
/// arithmetic (the context requests SHADER_F64). An f32 kernel needs none.
pub fn capabilities(float64: bool) -> Capabilities {
    let mut capabilities = Capabilities::empty();
    capabilities.set(Capabilities::FLOAT64, float64);
    capabilities
}

/// Parses `source` with naga's WGSL front end and validates it with every check and only
/// `capabilities`; the module and an entry point `main` on success.
///
/// Errors: naga's emitted message (file `label`, line, column, source excerpt) prefixed by `label`
/// (the kernel and its precision).
pub fn check(
    label: &str,
    source: &str,
    capabilities: Capabilities,
) -> Result<naga::Module, String> {
    let module = naga::front::wgsl::parse_str(source).map_err(|e| {
        format!(
            "{label}: WGSL parse error\n{}",
            e.emit_to_string_with_path(source, label)
        )
    })?;
    Validator::new(ValidationFlags::all(), capabilities)
        .validate(&module)
        .map_err(|e| {
            format!(
                "{label}: WGSL validation error\n{}",
                e.emit_to_string_with_path(source, label)
            )
        })?;
    if !module.entry_points.iter().any(|e| e.name == "main") {
        return Err(format!("{label}: no entry point `main`"));
    }
    Ok(module)
}
