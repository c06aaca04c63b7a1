//! The relation kernels' catalogue: the WGSL of each kernel the GPU engine dispatches
//! (`shaders/kernels/`), composed after the shared files by [`compose`](crate::gpu::compose).
//! Pure data: `build.rs` includes this file to validate every kernel with naga at build time.

use crate::gpu::compose::KernelSource;

/// The bindings of the row-mapping kernels: N input reals and M output reals per row, one status
/// per row.
const MAP_BINDINGS: &str = include_str!("../../../shaders/kernels/map_bindings.wgsl");

/// u,v → ray in the water.
pub static BACKPROJECT: KernelSource = KernelSource::new(
    "backproject",
    &[
        MAP_BINDINGS,
        include_str!("../../../shaders/kernels/backproject.wgsl"),
    ],
);

/// Every pixel of an image → ray in the water, pixels generated in the shader (its own
/// bindings: no input rows).
pub static BACKPROJECT_GRID: KernelSource = KernelSource::new(
    "backproject_grid",
    &[include_str!(
        "../../../shaders/kernels/backproject_grid.wgsl"
    )],
);

/// x,y,z → u,v by the unbracketed Newton iteration, two rows per invocation (their iterations
/// overlap on a CPU driver); the rows it does not settle come back with status
/// [`STATUS_RETRY`](crate::gpu::compose::STATUS_RETRY) for [`PROJECT_SAFEGUARDED`].
pub static PROJECT: KernelSource = KernelSource::new(
    "project",
    &[
        MAP_BINDINGS,
        include_str!("../../../shaders/kernels/project.wgsl"),
    ],
)
.with_rows_per_invocation(2);

/// x,y,z → u,v with every safeguard of the forward projection.
pub static PROJECT_SAFEGUARDED: KernelSource = KernelSource::new(
    "project_safeguarded",
    &[
        MAP_BINDINGS,
        include_str!("../../../shaders/kernels/project_safeguarded.wgsl"),
    ],
);

/// x,y,z → depth, VOP distance, VOP, tan a.
pub static VOP: KernelSource = KernelSource::new(
    "vop",
    &[
        MAP_BINDINGS,
        include_str!("../../../shaders/kernels/vop.wgsl"),
    ],
);

/// ul,vl,ur,vr → x,y,z, residual.
pub static TRIANGULATE: KernelSource = KernelSource::new(
    "triangulate",
    &[
        MAP_BINDINGS,
        include_str!("../../../shaders/kernels/triangulate.wgsl"),
    ],
);

/// ul,vl,ur,vr → both VOPs, axis offset, conditioning.
pub static BINOCULAR_VOP: KernelSource = KernelSource::new(
    "binocular_vop",
    &[
        MAP_BINDINGS,
        include_str!("../../../shaders/kernels/binocular_vop.wgsl"),
    ],
);

/// The safeguarded projection of the rows [`PROJECT`] left with
/// [`STATUS_RETRY`](crate::gpu::compose::STATUS_RETRY), in place (rows on the device).
pub static PROJECT_RETRY: KernelSource = KernelSource::new(
    "project_retry",
    &[
        MAP_BINDINGS,
        include_str!("../../../shaders/kernels/project_retry.wgsl"),
    ],
);

/// Two water rays of a row (device rows a and b) → x,y,z, residual (its own bindings).
pub static TRIANGULATE_RAYS: KernelSource = KernelSource::new(
    "triangulate_rays",
    &[include_str!(
        "../../../shaders/kernels/triangulate_rays.wgsl"
    )],
);

/// Matched pixels of two cameras (device rows a and b, with their statuses) → x,y,z, residual:
/// both back-projections and the triangulation fused, the device-resident twin of [`TRIANGULATE`]
/// (its own bindings).
pub static TRIANGULATE_PIXELS: KernelSource = KernelSource::new(
    "triangulate_pixels",
    &[include_str!(
        "../../../shaders/kernels/triangulate_pixels.wgsl"
    )],
);

/// An input row's status carried to its output row (its own bindings).
pub static MERGE_STATUS: KernelSource = KernelSource::new(
    "merge_status",
    &[include_str!("../../../shaders/kernels/merge_status.wgsl")],
);

/// Pixels of a grid, generated on the device (its own bindings: no input rows).
pub static PIXEL_GRID: KernelSource = KernelSource::new(
    "pixel_grid",
    &[include_str!("../../../shaders/kernels/pixel_grid.wgsl")],
);

/// Every kernel of the catalogue.
pub static ALL: [&KernelSource; 12] = [
    &BACKPROJECT,
    &BACKPROJECT_GRID,
    &PROJECT,
    &PROJECT_SAFEGUARDED,
    &VOP,
    &TRIANGULATE,
    &BINOCULAR_VOP,
    &PROJECT_RETRY,
    &TRIANGULATE_RAYS,
    &TRIANGULATE_PIXELS,
    &MERGE_STATUS,
    &PIXEL_GRID,
];
