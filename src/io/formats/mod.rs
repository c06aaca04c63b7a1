//! The files of a calibration and its tools: text formats that name cameras, boards and ports.

pub mod aquacal;
#[cfg(feature = "images")]
pub mod board_json;
pub mod calib_json;
pub mod detections;
pub mod export;
pub mod opencv;
pub mod rig_json;
#[cfg(feature = "images")]
pub mod scene_json;
pub mod sweep_shard;
pub mod tabular;
