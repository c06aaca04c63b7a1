//! The stereo kernels' catalogue: the WGSL of each stage the GPU stereo dispatches
//! (`shaders/stereo/`), composed after the shared files by [`compose`](crate::gpu::compose), the
//! uniform `Sweep` (`shaders/stereo/sweep.wgsl`) in front of each. Pure data: `build.rs` includes
//! this file to validate every kernel with naga at build time. Names carry the `stereo_` prefix
//! (unique across the catalogues: the pipeline cache's key). All run in f32.

use crate::gpu::compose::{KernelSource, Precision};

const SWEEP: &str = include_str!("../../../shaders/stereo/sweep.wgsl");

/// Stage 1: the reference pixel grid → water rays (o, z₀, w, ż).
pub static RAYS: KernelSource = KernelSource::new(
    "stereo_rays",
    &[SWEEP, include_str!("../../../shaders/stereo/rays.wgsl")],
)
.in_precision(Precision::F32);

/// Stages 2–4a: hypothesis points projected into one voter, its image sampled there.
pub static WARP: KernelSource = KernelSource::new(
    "stereo_warp",
    &[SWEEP, include_str!("../../../shaders/stereo/warp.wgsl")],
)
.in_precision(Precision::F32);

/// Stage 4b: windowed ZNCC per voter, from separable running sums down a strip of rows.
pub static ZNCC: KernelSource = KernelSource::new(
    "stereo_zncc",
    &[SWEEP, include_str!("../../../shaders/stereo/zncc.wgsl")],
)
.in_precision(Precision::F32);

/// Stage 5: the voters' ZNCC combined into the cost volume.
pub static COST: KernelSource = KernelSource::new(
    "stereo_cost",
    &[SWEEP, include_str!("../../../shaders/stereo/cost.wgsl")],
)
.in_precision(Precision::F32);

/// Stage 6: SGM along every path direction, in one dispatch.
pub static SGM: KernelSource = KernelSource::new(
    "stereo_sgm",
    &[SWEEP, include_str!("../../../shaders/stereo/sgm.wgsl")],
)
.in_precision(Precision::F32);

/// Stage 7: winner-take-all, sub-hypothesis refinement, confidence's ingredients.
pub static SELECT: KernelSource = KernelSource::new(
    "stereo_select",
    &[SWEEP, include_str!("../../../shaders/stereo/select.wgsl")],
)
.in_precision(Precision::F32);

/// Every stereo kernel.
pub static ALL: [&KernelSource; 6] = [&RAYS, &WARP, &ZNCC, &COST, &SGM, &SELECT];
