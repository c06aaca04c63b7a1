//! Errors of the model layer: parameters that describe no physical rig.
//!
//! Per-point rejections (a point inside the glass, total internal reflection, …) are not errors: they
//! are [`NoSolution`](super::NoSolution) values.

/// A rig, camera or interface whose parameters are not physical.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelError {
    /// A parameter is NaN or infinite.
    #[error("{field} must be finite, got {value}")]
    NotFinite {
        /// Which parameter.
        field: String,
        /// The value given.
        value: f64,
    },
    /// The system axis has zero length.
    #[error("interface normal must not be zero")]
    ZeroNormal,
    /// The system axis' length is no ordinary f64: below the smallest normal number (it underflows,
    /// so normalising it means dividing by a subnormal or by zero) or past the largest.
    #[error(
        "interface normal [{x:e}, {y:e}, {z:e}]: its length is zero or not representable (|n| = {length:e} underflows below 2.2e-308 or overflows past 1.8e308 in f64); give it at an ordinary scale, e.g. [0.1, 0.1, 1]"
    )]
    NormalLength {
        /// x component of the normal as given.
        x: f64,
        /// y component of the normal as given.
        y: f64,
        /// z component of the normal as given.
        z: f64,
        /// Its length |n|, as f64 holds it (subnormal, zero or infinite).
        length: f64,
    },
    /// The system axis points away from the water (n·z ≤ 0 in the master frame).
    #[error(
        "interface normal [{x}, {y}, {z}] must point from the camera into the water (positive z in the master camera frame)"
    )]
    NormalAwayFromWater {
        /// x component of the normal as given.
        x: f64,
        /// y component of the normal as given.
        y: f64,
        /// z component of the normal as given.
        z: f64,
    },
    /// Air layer thickness (distance from the master camera to the first interface) is not positive.
    #[error("interface distance (air layer) must be > 0 m, got {value}")]
    NonPositiveAirDistance {
        /// The value given.
        value: f64,
    },
    /// A layer has a thickness that is not positive.
    #[error("layer {layer}: thickness must be > 0 m, got {value}")]
    NonPositiveThickness {
        /// Zero-based layer index.
        layer: usize,
        /// The value given.
        value: f64,
    },
    /// A refractive index is below 1.
    #[error("{medium}: refractive index must be >= 1.0, got {value}")]
    IndexBelowOne {
        /// Which medium (`index_air`, `index_water`, `layer 0`, …).
        medium: String,
        /// The value given.
        value: f64,
    },
    /// An intrinsic parameter is out of range.
    #[error("camera '{camera}': {field} must be {requirement}, got {value}")]
    BadIntrinsics {
        /// Camera name.
        camera: String,
        /// Parameter name (`fx`, `width`, …).
        field: &'static str,
        /// What it must be.
        requirement: &'static str,
        /// The value given.
        value: f64,
    },
    /// A rotation matrix is not a proper rotation.
    #[error(
        "camera '{camera}': rotation is not a rotation matrix (|RᵀR − I| = {orthogonality_error:.2e}, det = {determinant:.6})"
    )]
    NotARotation {
        /// Camera name.
        camera: String,
        /// Frobenius norm of RᵀR − I.
        orthogonality_error: f64,
        /// Determinant of R.
        determinant: f64,
    },
    /// The master camera has non-identity extrinsics.
    #[error(
        "camera '{camera}' is the master (first) camera and defines the world frame: its rotation must be identity and its translation zero"
    )]
    MasterNotIdentity {
        /// Camera name.
        camera: String,
    },
    /// A camera centre is not on the air side of the first interface.
    #[error(
        "camera '{camera}' is not in the air: its distance to the first interface along the normal is {air_distance} m (must be > 0)"
    )]
    CameraNotInAir {
        /// Camera name.
        camera: String,
        /// d_k = d − n·C_k.
        air_distance: f64,
    },
    /// A camera's own port was given on some cameras and not on others, or next to a shared one.
    #[error("{0}")]
    MixedPorts(String),
    /// A rig without cameras.
    #[error("a rig needs at least one camera")]
    NoCameras,
    /// Two cameras share a name.
    #[error("camera name '{name}' is used twice")]
    DuplicateCameraName {
        /// The repeated name.
        name: String,
    },
}

pub(crate) fn check_finite(field: &str, value: f64) -> Result<f64, ModelError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(ModelError::NotFinite {
            field: field.to_string(),
            value,
        })
    }
}
