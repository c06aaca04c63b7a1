//! WGSL sources, composed at build time: `shaders/common.wgsl` in front of each kernel file.

/// Back-projection kernel (f32), composed.
pub const BACKPROJECT: &str = concat!(include_str!("../../shaders/common.wgsl"), include_str!("../../shaders/backproject.wgsl"));

/// Every composed kernel with its name, for validation.
pub const ALL: &[(&str, &str)] = &[("backproject", BACKPROJECT)];
