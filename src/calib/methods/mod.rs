//! The methods, each composed of the problem, the costs, a backend and the solvers. From the
//! bottom up: the thesis' stereo methods ([`thesis`]: consecutive, simultaneous, auto) and their
//! maximum likelihood ([`bundle`]); any rig ([`rig_calibrate`], its maximum likelihood
//! [`rig_bundle`]), whose consecutive start runs the thesis' method; what the data look like when
//! nothing fits ([`diagnose`], and [`misfit`]: the usual input mistakes, each undone and
//! calibrated again); the public entries with that diagnosis ([`calibrate`](mod@calibrate):
//! `calibrate` for a stereo rig, `calibrate_rig` for any); cost surfaces ([`sweep`](mod@sweep)).

pub mod bundle;
pub mod calibrate;
pub mod diagnose;
pub mod misfit;
pub mod rig_bundle;
pub mod rig_calibrate;
pub mod sweep;
pub mod thesis;
