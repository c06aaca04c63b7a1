//! Calibration of flat refractive ports (DESIGN.md §3): the system axis and the air layer of
//! cameras behind a flat port, from views of a chessboard.
//!
//! The folders read as the flow, each depending only on those before it:
//! - [`problem`]: the board, the observations, the screening of the views, and the prepared air
//!   rays of every corner;
//! - [`costs`]: the costs of one candidate interface in f64 (reprojection, 3-D scene, ray gap,
//!   the invariants, the fused affine-grid invariant) and the linear air layer;
//! - [`backends`]: where batches of candidates are evaluated, the CPU reference or the GPU;
//! - [`solvers`]: Levenberg–Marquardt and the searches over the axis;
//! - [`methods`]: the calibration methods, the maximum-likelihood bundle, the diagnosis of
//!   misfits and the cost sweeps.
//!
//! [`simulate`](mod@simulate) makes scenes with known truth; [`error`] is every calibration
//! error. No I/O here.

pub mod backends;
pub mod costs;
pub mod error;
pub mod methods;
pub mod problem;
pub mod simulate;
pub mod solvers;

pub use backends::gpu::GpuBackend;
pub use backends::{CostBackend, CpuBackend};
pub use costs::CostKind;
pub use error::{CalibError, Side};
pub use methods::calibrate::{
    Calibration, CalibrationOptions, CalibrationProgress, CalibrationReport, Method, Outlier,
    calibrate, calibrate_with_progress,
};
pub use problem::board::{Board, RigidFit, fit_rigid};
pub use problem::data::{Candidate, StereoData};
pub use problem::observations::{Observations, StereoView, ViewGroups, compare_views};
pub use problem::rig_observations::{CameraKey, Image, RigObservations, RigView, SeenView};
pub use problem::target::Target;
pub use simulate::{RigScene, RigSceneSpec, simulate_rig};
pub use simulate::{Scene, SceneSpec, simulate};
