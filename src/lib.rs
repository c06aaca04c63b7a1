//! # flatport
//!
//! Refraction through flat ports: cameras in air looking through one or more parallel flat
//! interfaces (air → glass → water). Exact forward projection, back-projection, Virtual Object
//! Points (VOP) and triangulation, in f64 on the CPU.
//!
//! ## Conventions
//! - Units: metres and radians.
//! - Camera frame: OpenCV — x right, y down, z forward; pixel (0, 0) is the centre of the top-left
//!   pixel. Distortion `[k1, k2, p1, p2, k3]`, applied after projection and removed before
//!   back-projection.
//! - The first camera of a rig (the *master*) defines the world frame. Camera k has OpenCV
//!   extrinsics X_k = R_k · X_master + t_k; its centre is C_k = −R_kᵀ t_k.
//! - The system axis n is the unit interface normal in the master frame, pointing into the water.
//!   The air layer d is the distance along n from the master centre to the first interface;
//!   interface i lies on n·X = d + t₀ + … + t_(i−1). Camera k's own air layer is d_k = d − n·C_k.
//! - Precision: everything here is f64.
//!
//! The conventions and relations in full, with the thesis' equation numbers (T. Dolereit's thesis
//! on Virtual Object Points for flat refractive systems), are in `docs/DESIGN.md`.
//!
//! ## Example
//! ```
//! use flatport::model::{Interface, Layer, PinholeCamera, Rig, RigCamera};
//! use nalgebra::{Matrix3, Point3, Vector3};
//!
//! let intrinsics = PinholeCamera::new("left", 1280, 1024, 864.91, 864.91, 640.0, 512.0, [0.0; 5])?;
//! let camera = RigCamera::new("left", intrinsics, Matrix3::identity(), Vector3::zeros())?;
//! let interface = Interface::new(Vector3::new(0.1, 0.1, 1.0), 0.02,
//!     vec![Layer { thickness: 0.014, index: 1.473 }], 1.0, 1.333)?;
//! let rig = Rig::new(vec![camera], interface)?;
//!
//! let left = rig.refractive_camera(0);
//! let pixel = left.project(&Point3::new(0.2, -0.1, 1.5)).expect("point is in the water");
//! let ray_in_water = left.backproject(&pixel).expect("pixel sees the water");
//! // The water ray passes through the point again.
//! let to_point = Point3::new(0.2, -0.1, 1.5) - ray_in_water.origin;
//! assert!(to_point.cross(&ray_in_water.dir).norm() < 1e-9);
//! # Ok::<(), flatport::model::ModelError>(())
//! ```

#![deny(missing_docs)]
// `!(x > 0.0)` is deliberate throughout: unlike `x <= 0.0` it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

/// The README's Rust examples, compiled and run by `cargo test --doc` so that they stay true.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;

/// The guides' Rust examples (docs/*.md), compiled and run by `cargo test --doc` as the README's
/// are; their shell and Python blocks are run by `scripts/check-docs.sh`.
#[cfg(doctest)]
pub mod guides {
    macro_rules! guide {
        ($name:ident, $path:literal) => {
            #[doc = include_str!($path)]
            pub struct $name;
        };
    }
    guide!(Architecture, "../docs/architecture.md");
    guide!(Accuracy, "../docs/accuracy.md");
    guide!(Calibration, "../docs/calibration.md");
    guide!(Design, "../docs/DESIGN.md");
    guide!(Export, "../docs/export.md");
    guide!(Geometry, "../docs/geometry.md");
    guide!(Images, "../docs/images.md");
    guide!(Library, "../docs/library.md");
    guide!(Performance, "../docs/performance.md");
    guide!(Python, "../docs/python.md");
    guide!(Rigs, "../docs/rigs.md");
    guide!(Sweeps, "../docs/sweeps.md");
    guide!(Testing, "../docs/testing.md");
}

pub mod base;
pub mod calib;
#[cfg(feature = "images")]
pub mod detect;
pub mod engine;
pub mod gpu;
pub mod io;
pub mod model;
#[cfg(feature = "images")]
pub mod render;
#[cfg(feature = "images")]
pub mod report;
#[cfg(feature = "images")]
pub mod runs;
pub mod stereo;
