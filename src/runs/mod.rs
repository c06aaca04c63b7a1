//! Whole jobs over files, above `io` and the algorithms: each reads with [`crate::io`], computes
//! with [`crate::calib`], [`crate::detect`] or [`crate::stereo`] (which take arrays and return
//! arrays), and hands back what the command line and Python write or show.
//!
//! - [`board_footage`]: `calibrate --images`' footage: `air/` and `water/` folders of images or
//!   videos read, the board found in every frame, the frames to use chosen;
//! - [`images`]: the rest of that route: every camera's lens (in air, from a rig file, or from
//!   the underwater frames), then the extrinsics and ports;
//! - [`sequence`]: `stereo --images`' synchronized frames of a rig, one frame at a time.

pub mod board_footage;
pub mod images;
pub mod sequence;
