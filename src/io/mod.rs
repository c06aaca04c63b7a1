//! File formats: rig JSON, OpenCV FileStorage YAML, CSV tables. No geometry here.

pub mod aquacal;
#[cfg(feature = "images")]
pub mod board_footage;
#[cfg(feature = "images")]
pub mod board_json;
pub mod calib_json;
pub mod detections;
pub mod error;
pub mod export;
#[cfg(feature = "images")]
pub mod frames;
#[cfg(feature = "images")]
pub mod image;
pub mod npy;
pub mod opencv;
pub mod output;
#[cfg(feature = "images")]
pub mod overlay;
#[cfg(feature = "images")]
pub mod plot;
pub mod rig_json;
#[cfg(feature = "images")]
pub mod scene_json;
#[cfg(feature = "images")]
pub mod stereo_files;
pub mod sweep_shard;
pub mod tabular;

use std::path::Path;

#[cfg(feature = "images")]
pub use self::image::{
    image_size, read_grey_image, write_grey_png, write_grey16_png, write_rgb_jpeg,
};
pub use aquacal::{
    AquaCalBoard, AquaCalExportError, aquacal_json, read_aquacal, rig_from_aquacal_str,
};
#[cfg(feature = "images")]
pub use board_json::{board_from_json_str, read_board};
pub use calib_json::{
    Truth, observations_from_json_str, observations_to_json_string, read_observations, read_target,
    read_truth, report_to_json_string, stereo_observations_to_json_string, target_from_json_str,
    targetless_report_to_json_string, write_boards_report, write_observations, write_report,
    write_stereo_observations, write_truth,
};
pub use detections::{DetectedView, detections_to_json_string, write_detections};
pub use error::IoError;
pub use export::{
    ColmapDialect, ExportError, colmap_cameras_txt, colmap_cameras_txt_as, colmap_rig_config,
    colmap_rigs_txt, opencv_yaml,
};
pub use opencv::{MAX_BASELINE_M, OpenCvStereo, parse_opencv_stereo, read_opencv_stereo};
pub use output::{OutputFile, remove_temporaries, write_atomic};
pub use rig_json::{read_rig, rig_from_json_str, rig_to_json_string, write_rig};
pub use tabular::{
    TableReader, TableSource, TableWriteSummary, TableWriter, read_table, read_table_from,
    validate_table, write_table,
};

/// Reads a whole file (`-` = standard input) into a string.
pub(crate) fn read_text(path: &Path) -> Result<String, IoError> {
    let err = |source| IoError::Read {
        path: path.to_path_buf(),
        source,
    };
    if path.as_os_str() == "-" {
        let mut text = String::new();
        std::io::Read::read_to_string(&mut std::io::stdin(), &mut text).map_err(err)?;
        Ok(text)
    } else {
        std::fs::read_to_string(path).map_err(err)
    }
}
