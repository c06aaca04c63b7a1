//! The refractive model in f64: pure functions of parameters and inputs. No I/O, no GPU.
//!
//! Dependency order: [`snell`] and [`vop`] (formulas) → [`interface`], [`camera`] (parameters) →
//! [`rig`] → [`RefractiveCamera`] (back-projection, forward projection, VOPs) → [`stereo`]
//! (binocular VOPs, triangulation).

pub mod camera;
pub mod error;
pub mod interface;
pub mod refractive_camera;
pub mod rig;
pub mod snell;
pub mod stereo;
pub mod vop;

pub use camera::PinholeCamera;
pub use error::ModelError;
pub use interface::{Interface, Layer, normal_from_tilt_azimuth};
pub use refractive_camera::{AirPath, Ray, RefractiveCamera, Vop};
pub use rig::{Ports, Rig, RigCamera};
pub use stereo::{BinocularVop, Triangulation, binocular_vop, triangulate_rays};

/// Why a point, pixel or ray has no answer. Not an error: batches report these per element (as a
/// NaN row in CSV output, as a status code on the GPU).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum NoSolution {
    /// Outside the lens model's valid region: beyond the first fold of the radial distortion, where
    /// the polynomial stops being one-to-one (or undistortion did not converge).
    OutsideLens = 1,
    /// The air ray travels parallel to or away from the interface.
    MissesInterface = 2,
    /// Light cannot pass into a layer or the water at this angle.
    TotalInternalReflection = 3,
    /// The point is not beyond the outer interface (it is in the air, in a layer, or behind).
    NotInWater = 4,
    /// The light from the point would reach the camera from behind its image plane (more than 90°
    /// off the optical axis): the point is behind the camera, or in front of it but so far to the
    /// side that only a near-grazing air ray, beyond the camera's field of view, reaches it.
    BehindCamera = 5,
    /// Nearly parallel rays or a point in the degenerate plane of a stereo pair.
    Degenerate = 6,
    /// The forward-projection root finder hit its iteration bound.
    NoConvergence = 7,
    /// An input beyond ±[`MAX_INPUT`], or a result that overflows the floating-point range: no
    /// number can be given (never a row of wrong finite numbers).
    OutOfRange = 8,
}

/// Largest magnitude of an input coordinate (metres or pixels) that the f64 paths accept; a row
/// with a larger one is [`NoSolution::OutOfRange`]. (The GPU's f32 kernels stop at 1e30.) Up to
/// it, lengths are computed without overflow: squares are taken only after scaling.
pub const MAX_INPUT: f64 = 1e300;

/// Whether a batch row breaks "every number or none": an input beyond ±`limit` (or NaN) or a
/// result that is not finite. Both engines reject such a row as [`NoSolution::OutOfRange`]
/// (`limit` is [`MAX_INPUT`] in f64; the f32 kernels' inputs stop at 1e30).
#[inline]
pub fn out_of_range(input: &[f64], limit: f64, output: &[f64]) -> bool {
    !input.iter().all(|x| x.abs() <= limit) || !output.iter().all(|y| y.is_finite())
}

impl NoSolution {
    /// Every variant, in code order.
    pub const ALL: [NoSolution; 8] = [
        Self::OutsideLens,
        Self::MissesInterface,
        Self::TotalInternalReflection,
        Self::NotInWater,
        Self::BehindCamera,
        Self::Degenerate,
        Self::NoConvergence,
        Self::OutOfRange,
    ];

    /// Stable status code (non-zero; 0 means success in per-element status buffers).
    pub fn code(self) -> u32 {
        self as u32
    }

    /// The variant with this status code.
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|v| v.code() == code)
    }

    /// Short human description.
    pub fn describe(self) -> &'static str {
        match self {
            Self::OutsideLens => "outside the lens model's one-to-one region",
            Self::MissesInterface => "ray misses the interface",
            Self::TotalInternalReflection => "total internal reflection",
            Self::NotInWater => "point not in the water (in the air or a layer)",
            Self::BehindCamera => {
                "beyond the camera's field of view (light would arrive from behind its image plane)"
            }
            Self::Degenerate => "degenerate geometry (parallel rays)",
            Self::NoConvergence => "root finder did not converge",
            Self::OutOfRange => {
                "beyond the floating-point range (a coordinate past ±1e300, ±1e30 on f32 kernels, or an overflow)"
            }
        }
    }
}

impl std::fmt::Display for NoSolution {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.describe())
    }
}

/// So that `?` carries a `NoSolution` into `Box<dyn Error>` and `anyhow` (as the README's examples do).
impl std::error::Error for NoSolution {}
