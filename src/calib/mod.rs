//! Calibration of flat refractive ports (DESIGN.md §3): the ports (axis, air distance, layer
//! thicknesses) and, optionally, the extrinsics of any rig from views of a board or a 3-D target,
//! through one entry, [`calibrate`].
//!
//! The folders read as the flow, each depending only on those before it:
//! - [`problem`]: the target, the observations and their checks, the screening of the images,
//!   and the prepared air rays of a camera pair's corners;
//! - [`costs`]: the costs of one candidate port over a camera pair in f64 (reprojection, 3-D
//!   scene, ray gap, the invariants, the fused affine-grid invariant), their lane twins, and the
//!   linear air layer;
//! - [`backends`]: where batches of candidates are evaluated, the CPU reference or the GPU;
//! - [`solvers`]: Levenberg–Marquardt with the block normal equations of a bundle, and the
//!   searches over the axis;
//! - [`pipeline`]: the one calibration pipeline (checks, screening, poses, the thesis'
//!   consecutive start or the axis search, the maximum-likelihood bundle, the report and the
//!   diagnosis of a misfit).
//!
//! [`sweep`](mod@sweep) evaluates a cost over grids of candidate ports; [`simulate`](mod@simulate)
//! makes scenes with known truth; [`targetless`] calibrates ports from matches of any textured
//! scene, no board; [`error`] is every calibration error. No I/O here.

pub mod backends;
pub mod costs;
pub mod error;
pub mod pipeline;
pub mod problem;
pub mod simulate;
pub mod solvers;
pub mod sweep;
pub mod targetless;

pub use crate::base::Board;
#[cfg(feature = "gpu")]
pub use backends::gpu::GpuBackend;
pub use backends::{CostBackend, CpuBackend};
pub use costs::CostKind;
pub use error::CalibError;
pub use pipeline::bundle::Estimate;
pub use pipeline::report::{
    CameraReport, Estimated, Outlier, PortReport, Report, SceneErrors, Stage,
};
pub use pipeline::{
    Backend, Calibration, DEFAULT_MAX_RMS_PX, Method, Options, Progress, calibrate,
    calibrate_with_progress,
};
pub use problem::board::{RigidFit, fit_rigid};
pub use problem::data::{CameraPair, Candidate, StereoData};
pub use problem::observations::{CameraKey, Image, Observations, SeenView, View};
pub use problem::target::Target;
pub use simulate::{Cameras, Scene, SceneSpec, simulate};
