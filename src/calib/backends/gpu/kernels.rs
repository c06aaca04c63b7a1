//! The calibration kernels' catalogue: the WGSL of each kernel the GPU cost backend dispatches
//! (`shaders/calib/`), composed after the shared files by [`compose`](crate::gpu::compose).
//! Pure data: `build.rs` includes this file to validate every kernel with naga at build time.
//! The names keep the `calib_` prefix: they are unique across the catalogues (the pipeline
//! cache's key).

use crate::gpu::compose::{KernelSource, Precision};

/// The bindings of the candidate × corner kernels: rows per corner, candidates, M reals and a
/// status per (candidate, corner).
const CANDIDATE_BINDINGS: &str = include_str!("../../../../shaders/calib/candidate_bindings.wgsl");

/// The four modes of the per-view scene kernel (its mode a constant composed in front of it, so
/// that the compiler drops the other modes).
const SCENE_FIT_WGSL: &str = include_str!("../../../../shaders/calib/scene_fit.wgsl");

/// The sum over views of the per-view kernels' items (three kernels: f64 or f32 items summed in
/// f64, f32 items summed in f32 with compensation).
const VIEW_SUM_WGSL: &str = include_str!("../../../../shaders/calib/view_sum.wgsl");

/// Candidate interfaces × corners (two air rays) → x, y, z, gap.
pub static TRIANGULATE: KernelSource = KernelSource::new(
    "calib_triangulate",
    &[
        CANDIDATE_BINDINGS,
        include_str!("../../../../shaders/calib/triangulate.wgsl"),
    ],
);

/// Candidate axes × corners (air rays and their pixel Jacobians) → projected binocular VOP q₁,
/// q₂ in the plane ⟂ n and its Jacobian ∂q/∂(u_l, v_l, u_r, v_r).
pub static PROJECTED_VOP: KernelSource = KernelSource::new(
    "calib_projected_vop",
    &[
        CANDIDATE_BINDINGS,
        include_str!("../../../../shaders/calib/projected_vop.wgsl"),
    ],
);

/// Candidate axes × views (fused corner rows) → weighted affine-grid χ² and degrees of freedom;
/// always f64 (the one-pass χ² needs it).
pub static AFFINE_GRID: KernelSource = KernelSource::new(
    "calib_affine_grid",
    &[include_str!("../../../../shaders/calib/affine_grid.wgsl")],
)
.reading_view_rows()
.in_precision(Precision::F64);

/// Candidate axes × views (air rays) → the view's gap-line sums Σa², Σab, Σb².
pub static SCENE_GAP: KernelSource = KernelSource::new(
    "calib_scene_gap",
    &["const MODE: u32 = 0u;", SCENE_FIT_WGSL],
)
.reading_view_rows();

/// Candidate interfaces × views (air rays, board points) → the rigid board fit's 3-D sum of
/// squares.
pub static SCENE_FIT: KernelSource = KernelSource::new(
    "calib_scene_fit",
    &["const MODE: u32 = 1u;", SCENE_FIT_WGSL],
)
.reading_view_rows();

/// Candidate interfaces × views (air rays, board points, pixels) → the rigid board fit's
/// reprojection sum of squares, each corner projected from its observed air ray; the views with
/// a corner that does not settle come back with status
/// [`STATUS_RETRY`](crate::gpu::compose::STATUS_RETRY) for
/// [`SCENE_REPROJECTION_SAFEGUARDED`].
pub static SCENE_REPROJECTION: KernelSource = KernelSource::new(
    "calib_scene_reprojection",
    &["const MODE: u32 = 2u;", SCENE_FIT_WGSL],
)
.reading_view_rows();

/// The same sum with every corner by the safeguarded forward projection.
pub static SCENE_REPROJECTION_SAFEGUARDED: KernelSource = KernelSource::new(
    "calib_scene_reprojection_safeguarded",
    &["const MODE: u32 = 3u;", SCENE_FIT_WGSL],
)
.reading_view_rows();

/// The per-(candidate, view) kernels' items summed over views per candidate in view order, their
/// statuses combined (`shaders/calib/view_sum.wgsl`): f64 items plainly in f64, as the host adds
/// them.
pub static VIEW_SUM: KernelSource = KernelSource::new(
    "calib_view_sum",
    &[
        "alias item_real = real;\nconst COMPENSATED: bool = false;",
        VIEW_SUM_WGSL,
    ],
)
.in_precision(Precision::F64);

/// [`VIEW_SUM`] of f32 items, added in f64 (the host's sums of them, bit for bit): for adapters
/// with SHADER_F64.
pub static VIEW_SUM_F32_ITEMS: KernelSource = KernelSource::new(
    "calib_view_sum_f32_items",
    &[
        "alias item_real = f32;\nconst COMPENSATED: bool = false;",
        VIEW_SUM_WGSL,
    ],
)
.in_precision(Precision::F64);

/// [`VIEW_SUM`] of f32 items in f32 with Neumaier's compensation: for adapters without
/// SHADER_F64.
pub static VIEW_SUM_F32: KernelSource = KernelSource::new(
    "calib_view_sum_f32",
    &[
        "alias item_real = real;\nconst COMPENSATED: bool = true;",
        VIEW_SUM_WGSL,
    ],
)
.in_precision(Precision::F32);

/// The bundle's stencil batches: evaluations (camera set, pose set) × observed corners →
/// projected − observed pixels; always f64 (the bundle's central differences need it).
pub static BUNDLE_RESIDUALS: KernelSource = KernelSource::new(
    "calib_bundle_residuals",
    &[include_str!(
        "../../../../shaders/calib/bundle_residuals.wgsl"
    )],
)
.in_precision(Precision::F64);

/// Every kernel of the catalogue.
pub static ALL: [&KernelSource; 11] = [
    &TRIANGULATE,
    &PROJECTED_VOP,
    &AFFINE_GRID,
    &SCENE_GAP,
    &SCENE_FIT,
    &SCENE_REPROJECTION,
    &SCENE_REPROJECTION_SAFEGUARDED,
    &VIEW_SUM,
    &VIEW_SUM_F32_ITEMS,
    &VIEW_SUM_F32,
    &BUNDLE_RESIDUALS,
];
