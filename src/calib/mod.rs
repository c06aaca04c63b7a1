//! Calibration of a shared flat refractive stereo system (DESIGN.md §3): the system axis and the
//! air layer of a stereo camera behind one flat port, from stereo views of a planar chessboard.
//!
//! Dependency order: [`board`], [`observations`] (data) → [`data`] (prepared air rays) →
//! [`costs`], [`invariants`], [`affine_grid`], [`air_layer`] (pure f64 costs of one candidate)
//! → [`backend`], [`gpu_backend`] (batches of candidates, CPU or GPU) → [`search`], [`lm`],
//! [`bundle`] (optimisers) → [`calibrate()`] (the methods), [`sweep`](mod@sweep) (cost
//! surfaces). [`screen`] finds gross corner errors from the board's shape in each image and
//! [`diagnose`] tests the usual mistakes (swapped images, reversed corner order, wrong square)
//! when nothing fits. [`simulate`](mod@simulate) makes scenes with known truth. No I/O here.

pub mod affine_grid;
pub mod air_layer;
pub mod backend;
pub mod board;
pub mod bundle;
pub mod calibrate;
pub mod costs;
pub mod data;
pub mod diagnose;
pub mod error;
pub mod gpu_backend;
pub mod invariants;
pub mod lm;
pub mod observations;
pub mod rng;
pub mod screen;
pub mod search;
pub mod simulate;
pub mod sweep;

pub use backend::{CostBackend, CpuBackend};
pub use board::{Board, RigidFit, fit_rigid};
pub use costs::CostKind;
pub use data::{Candidate, StereoData};
pub use error::{CalibError, Side};
pub use gpu_backend::GpuBackend;
pub use observations::{Observations, StereoView, ViewGroups, compare_views};
pub use simulate::{Scene, SceneSpec, simulate};
pub use calibrate::{Calibration, CalibrationOptions, CalibrationProgress, CalibrationReport, Method, Outlier, calibrate, calibrate_with_progress};
