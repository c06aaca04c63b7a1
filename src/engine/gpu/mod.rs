//! The GPU engine's kernels: [`kernels`], the catalogue of the relation kernels.

pub mod kernels;
