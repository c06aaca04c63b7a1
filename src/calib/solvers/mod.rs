//! The solvers the methods compose: Levenberg–Marquardt over any least-squares problem
//! ([`lm`]), and the searches over the axis (a global grid over the tilt cap, a stencil
//! refinement, the air layer's one-dimensional fit) that ask a backend for whole batches ([`search`]).

pub mod lm;
pub mod search;
