//! Every file flatport reads or writes, and nothing else: no geometry, no algorithm. By what it
//! reads and writes:
//!
//! - [`formats`]: the files of a calibration and its tools, text that names things: the rig
//!   (JSON), the board (`BOARD.json`), observations, truth and reports, OpenCV's FileStorage YAML,
//!   AquaCal's `calibration.json`, COLMAP's and OpenCV's exports, detections, scenes, a sweep's
//!   shard manifest, CSV tables;
//! - [`media`]: pixels and arrays: image files, a camera's frames (images or a video through
//!   `ffmpeg`), `.npy` arrays, dense stereo's images, depth maps and PLY clouds;
//! - [`plots`]: pictures drawn for a person: cost-surface heat maps and polar views, corner
//!   overlays;
//! - [`output`]: files that appear whole or not at all; [`error`]: [`IoError`], naming the file
//!   and where in it.
//!
//! The functions a caller needs are re-exported here (`io::read_rig`, `io::write_report`), and
//! so are the modules (`io::frames`, `io::rig_json`), as the crate's API has always named them.

pub mod error;
pub mod formats;
pub mod media;
pub mod output;
#[cfg(feature = "images")]
pub mod plots;

pub use formats::{
    aquacal, calib_json, detections, export, opencv, rig_json, sweep_shard, tabular,
};
#[cfg(feature = "images")]
pub use formats::{board_json, scene_json};
pub use media::npy;
#[cfg(feature = "images")]
pub use media::{frames, image, stereo_files};
#[cfg(feature = "images")]
pub use plots::{overlay, plot};

use std::path::Path;

pub use error::IoError;
pub use formats::aquacal::{
    AquaCalBoard, AquaCalExportError, aquacal_json, read_aquacal, rig_from_aquacal_str,
};
#[cfg(feature = "images")]
pub use formats::board_json::{board_from_json_str, read_board};
pub use formats::calib_json::{
    Truth, observations_from_json_str, observations_to_json_string, read_observations, read_target,
    read_truth, report_to_json_string, stereo_observations_to_json_string, target_from_json_str,
    targetless_report_to_json_string, write_boards_report, write_observations, write_report,
    write_stereo_observations, write_truth,
};
pub use formats::detections::{DetectedView, detections_to_json_string, write_detections};
pub use formats::export::{
    ColmapDialect, ExportError, colmap_cameras_txt, colmap_cameras_txt_as, colmap_rig_config,
    colmap_rigs_txt, opencv_yaml,
};
pub use formats::opencv::{MAX_BASELINE_M, OpenCvStereo, parse_opencv_stereo, read_opencv_stereo};
pub use formats::rig_json::{read_rig, rig_from_json_str, rig_to_json_string, write_rig};
pub use formats::tabular::{
    TableReader, TableSource, TableWriteSummary, TableWriter, read_table, read_table_from,
    validate_table, write_table,
};
#[cfg(feature = "images")]
pub use media::image::{
    image_size, read_grey_image, write_grey_png, write_grey16_png, write_rgb_jpeg,
};
pub use output::{OutputFile, remove_temporaries, write_atomic};

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
