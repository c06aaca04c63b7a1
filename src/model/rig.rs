//! Rigs: a master camera that defines the world frame, more cameras with OpenCV `stereoCalibrate`
//! extrinsics, and the flat interface they all look through.

use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

use super::camera::PinholeCamera;
use super::error::{ModelError, check_finite};
use super::interface::Interface;
use super::refractive_camera::RefractiveCamera;

/// Largest ‖RᵀR − I‖ accepted for a rotation read from a file (OpenCV writes ~1e-15; hand-typed
/// matrices with 6–8 digits stay well under this).
pub const ROTATION_TOLERANCE: f64 = 1e-5;

/// One camera of a rig: its intrinsics and where it sits relative to the master.
#[derive(Debug, Clone, PartialEq)]
pub struct RigCamera {
    /// Unique name (`left`, `right`, …).
    pub name: String,
    /// Pinhole intrinsics and distortion.
    pub intrinsics: PinholeCamera,
    /// (R_k, t_k) with X_k = R_k · X_master + t_k, as OpenCV `stereoCalibrate` gives them.
    pub cam_from_master: Isometry3<f64>,
}

impl RigCamera {
    /// Builds a camera from OpenCV extrinsics: `rotation` R_k and `translation` t_k with
    /// X_k = R_k · X_master + t_k. R_k must be orthonormal to [`ROTATION_TOLERANCE`] with det = +1; it
    /// is projected onto the nearest rotation.
    pub fn new(
        name: &str,
        intrinsics: PinholeCamera,
        rotation: Matrix3<f64>,
        translation: Vector3<f64>,
    ) -> Result<Self, ModelError> {
        for (i, v) in rotation.iter().enumerate() {
            check_finite(
                &format!("camera '{name}' rotation[{}][{}]", i % 3, i / 3),
                *v,
            )?;
        }
        for (i, v) in translation.iter().enumerate() {
            check_finite(&format!("camera '{name}' translation[{i}]"), *v)?;
        }
        let orthogonality_error = (rotation.transpose() * rotation - Matrix3::identity()).norm();
        let determinant = rotation.determinant();
        if orthogonality_error > ROTATION_TOLERANCE || determinant <= 0.0 {
            return Err(ModelError::NotARotation {
                camera: name.to_string(),
                orthogonality_error,
                determinant,
            });
        }
        let rotation =
            UnitQuaternion::from_matrix_eps(&rotation, 1e-15, 100, UnitQuaternion::identity());
        Ok(Self {
            name: name.to_string(),
            intrinsics,
            cam_from_master: Isometry3::from_parts(Translation3::from(translation), rotation),
        })
    }

    /// Camera centre in the master frame, C_k = −R_kᵀ t_k.
    pub fn centre_in_master(&self) -> Point3<f64> {
        self.cam_from_master
            .inverse_transform_point(&Point3::origin())
    }
}

/// Cameras behind one shared flat interface. The first camera is the master: its frame is the
/// world frame, so its extrinsics are the identity.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    cameras: Vec<RigCamera>,
    interface: Interface,
}

impl Rig {
    /// Builds and validates a rig: at least one camera, unique names, identity master extrinsics,
    /// every camera centre on the air side of the first interface (d_k = d − n·C_k > 0).
    pub fn new(cameras: Vec<RigCamera>, interface: Interface) -> Result<Self, ModelError> {
        let master = cameras.first().ok_or(ModelError::NoCameras)?;
        let iso = &master.cam_from_master;
        if iso.translation.vector.norm() > 1e-12 || iso.rotation.angle() > 1e-9 {
            return Err(ModelError::MasterNotIdentity {
                camera: master.name.clone(),
            });
        }
        for (i, camera) in cameras.iter().enumerate() {
            if cameras[..i].iter().any(|c| c.name == camera.name) {
                return Err(ModelError::DuplicateCameraName {
                    name: camera.name.clone(),
                });
            }
        }
        let rig = Self { cameras, interface };
        rig.check_cameras_in_air(&rig.interface)?;
        Ok(rig)
    }

    fn check_cameras_in_air(&self, interface: &Interface) -> Result<(), ModelError> {
        for camera in &self.cameras {
            let air_distance = interface.air_distance()
                - interface.normal().dot(&camera.centre_in_master().coords);
            if !(air_distance > 0.0) {
                return Err(ModelError::CameraNotInAir {
                    camera: camera.name.clone(),
                    air_distance,
                });
            }
        }
        Ok(())
    }

    /// The cameras, master first.
    pub fn cameras(&self) -> &[RigCamera] {
        &self.cameras
    }

    /// The shared interface.
    pub fn interface(&self) -> &Interface {
        &self.interface
    }

    /// The same rig behind another interface (validated: every camera must stay in the air).
    pub fn with_interface(&self, interface: Interface) -> Result<Self, ModelError> {
        self.check_cameras_in_air(&interface)?;
        Ok(Self {
            cameras: self.cameras.clone(),
            interface,
        })
    }

    /// Index of a camera given by name, or by its position as a decimal number (`0` = master).
    pub fn camera_index(&self, name_or_index: &str) -> Option<usize> {
        if let Some(i) = self.cameras.iter().position(|c| c.name == name_or_index) {
            return Some(i);
        }
        name_or_index
            .parse::<usize>()
            .ok()
            .filter(|&i| i < self.cameras.len())
    }

    /// Camera `index` prepared for refractive projection and back-projection.
    ///
    /// # Panics
    /// When `index` is out of range.
    pub fn refractive_camera(&self, index: usize) -> RefractiveCamera {
        let camera = &self.cameras[index];
        RefractiveCamera::new(camera.intrinsics, &camera.cam_from_master, &self.interface)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::interface::Layer;

    fn intrinsics() -> PinholeCamera {
        PinholeCamera::new("c", 1280, 1024, 864.91, 864.91, 640.0, 512.0, [0.0; 5]).unwrap()
    }

    fn interface(distance: f64) -> Interface {
        Interface::new(
            Vector3::new(0.1, 0.1, 1.0),
            distance,
            vec![Layer {
                thickness: 0.014,
                index: 1.473,
            }],
            1.0,
            1.333,
        )
        .unwrap()
    }

    fn stereo(distance: f64) -> Result<Rig, ModelError> {
        let left =
            RigCamera::new("left", intrinsics(), Matrix3::identity(), Vector3::zeros()).unwrap();
        let right = RigCamera::new(
            "right",
            intrinsics(),
            Matrix3::identity(),
            Vector3::new(-0.06, 0.0, 0.0),
        )
        .unwrap();
        Rig::new(vec![left, right], interface(distance))
    }

    #[test]
    fn centre_follows_opencv_convention() {
        let rig = stereo(0.02).unwrap();
        // t = −R C  ⇒  C = (0.06, 0, 0) for t = (−0.06, 0, 0).
        assert!((rig.cameras()[1].centre_in_master() - Point3::new(0.06, 0.0, 0.0)).norm() < 1e-15);
        assert_eq!(rig.camera_index("right"), Some(1));
        assert_eq!(rig.camera_index("0"), Some(0));
        assert_eq!(rig.camera_index("2"), None);
    }

    #[test]
    fn camera_outside_the_air_is_rejected() {
        // n·C_right = 0.06·0.1/|n| ≈ 0.00594 > d = 0.005.
        assert!(matches!(
            stereo(0.005),
            Err(ModelError::CameraNotInAir { .. })
        ));
        assert!(stereo(0.007).is_ok());
    }

    #[test]
    fn non_rotations_are_rejected() {
        let skew = Matrix3::new(1.0, 0.1, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(matches!(
            RigCamera::new("r", intrinsics(), skew, Vector3::zeros()),
            Err(ModelError::NotARotation { .. })
        ));
        let mirror = Matrix3::new(-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(RigCamera::new("r", intrinsics(), mirror, Vector3::zeros()).is_err());
    }

    #[test]
    fn master_must_be_identity_and_names_unique() {
        let moved = RigCamera::new(
            "m",
            intrinsics(),
            Matrix3::identity(),
            Vector3::new(0.1, 0.0, 0.0),
        )
        .unwrap();
        assert!(matches!(
            Rig::new(vec![moved], interface(0.02)),
            Err(ModelError::MasterNotIdentity { .. })
        ));
        let a = RigCamera::new("a", intrinsics(), Matrix3::identity(), Vector3::zeros()).unwrap();
        assert!(matches!(
            Rig::new(vec![a.clone(), a], interface(0.02)),
            Err(ModelError::DuplicateCameraName { .. })
        ));
        assert_eq!(
            Rig::new(vec![], interface(0.02)),
            Err(ModelError::NoCameras)
        );
    }
}
