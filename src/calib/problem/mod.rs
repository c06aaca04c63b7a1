//! What a calibration is given: the target ([`target`], [`board`]), the observations and their
//! checks ([`observations`]), the screening of each image for gross corner errors ([`screen`]),
//! and a camera pair's corners prepared for the pair costs ([`data`]).

pub mod board;
pub mod data;
pub mod observations;
pub mod screen;
pub mod target;
