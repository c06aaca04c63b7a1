//! The problem: what was observed and what is known. The board ([`board`]), the views of it in
//! the images ([`observations`]), the screening of each view by the board's shape ([`screen`]),
//! and the observations prepared for cost evaluation: every corner's air rays, which do not
//! depend on the interface, computed once ([`data`]).

pub mod board;
pub mod data;
pub mod observations;
pub mod rig_observations;
pub mod screen;
pub mod target;
