//! What every algorithm shares, below all of them: the grey image (and the procedural texture
//! that fills rendered scenes), the calibration board's description, the seeded random
//! generator, and the cutting of user input in error messages.
//!
//! `detect`, `render`, `stereo` and `calib` each use these and none of the others: an image
//! drawn by `render` is matched by `stereo` and `calib::targetless` as the same [`GreyImage`];
//! a board read from `BOARD.json` is drawn by `render`, found by `detect` and fitted by `calib`
//! as the same [`Board`] and [`BoardSpec`].

pub mod board;
#[cfg(feature = "images")]
pub mod board_spec;
pub mod image;
pub mod noise;
pub mod rng;
pub(crate) mod text;

pub use board::Board;
#[cfg(feature = "images")]
pub use board_spec::{BoardError, BoardSpec, CharucoSpec};
pub use image::GreyImage;
pub use rng::Rng;
