//! The methods, each composed of the problem, the costs, a backend and the solvers: the
//! calibration ([`calibrate`](mod@calibrate): consecutive, simultaneous, auto), its
//! maximum-likelihood refinement ([`bundle`]), what the data look like when nothing fits
//! ([`diagnose`]), and cost surfaces ([`sweep`](mod@sweep)).

pub mod bundle;
pub mod calibrate;
pub mod diagnose;
pub mod misfit;
pub mod rig_bundle;
pub mod rig_calibrate;
pub mod sweep;
