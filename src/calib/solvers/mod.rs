//! The solvers the pipeline composes: Levenberg–Marquardt over any least-squares problem
//! ([`lm`]) with the block normal equations of a bundle adjustment ([`block`]: global parameters
//! and one pose per view, Schur complement on the poses), and the searches over the axis (a global
//! grid over the tilt cap, a stencil refinement, the air layer's one-dimensional fit) that ask a
//! backend for whole batches ([`search`]).

pub mod block;
pub mod lm;
pub mod search;
