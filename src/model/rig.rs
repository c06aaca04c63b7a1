//! Rigs: a master camera that defines the world frame, more cameras with OpenCV `stereoCalibrate`
//! extrinsics, and the flat ports they look through: one shared by all, or one per camera.

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

/// The ports of a rig: one flat port shared by every camera, or a port per camera (a housing
/// each, DESIGN.md §3b).
#[derive(Debug, Clone, PartialEq)]
pub enum Ports {
    /// One port in front of every camera, in the master frame.
    Shared(Interface),
    /// Each camera's own port, in rig camera order, each in *that camera's* frame: its centre at the
    /// origin, the normal into the water, the distance from the centre to the first interface
    /// (colmap_underwater's FLATPORT convention).
    PerCamera(Vec<Interface>),
}

/// Cameras behind flat ports. The first camera is the master: its frame is the world frame, so
/// its extrinsics are the identity.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    cameras: Vec<RigCamera>,
    ports: Ports,
}

impl Rig {
    /// Builds and validates a rig behind one shared port: at least one camera, unique names,
    /// identity master extrinsics, every camera centre on the air side of the first interface
    /// (d_k = d − n·C_k > 0).
    pub fn new(cameras: Vec<RigCamera>, interface: Interface) -> Result<Self, ModelError> {
        Self::with_ports(cameras, Ports::Shared(interface))
    }

    /// Builds and validates a rig with the given ports ([`Rig::new`]'s checks; per-camera ports:
    /// exactly one per camera).
    pub fn with_ports(cameras: Vec<RigCamera>, ports: Ports) -> Result<Self, ModelError> {
        let master = cameras.first().ok_or(ModelError::NoCameras)?;
        let iso = &master.cam_from_master;
        if iso.translation.vector.norm() > 1e-12 || iso.rotation.angle() > 1e-9 {
            return Err(ModelError::MasterNotIdentity {
                camera: master.name.clone(),
            });
        }
        // A set of the names seen: linear in the cameras (a scan of the earlier names for each
        // took 24-36 s for a rig of 100 002 cameras).
        let mut names = std::collections::HashSet::with_capacity(cameras.len());
        for camera in &cameras {
            if !names.insert(camera.name.as_str()) {
                return Err(ModelError::DuplicateCameraName {
                    name: camera.name.clone(),
                });
            }
        }
        if let Ports::PerCamera(ports) = &ports
            && ports.len() != cameras.len()
        {
            return Err(ModelError::MixedPorts(format!(
                "{} ports for {} cameras: with per-camera ports every camera has its own",
                ports.len(),
                cameras.len()
            )));
        }
        let rig = Self { cameras, ports };
        rig.check_cameras_in_air()?;
        Ok(rig)
    }

    /// Every camera in the air: d_k = d − n·C_k > 0 behind a shared port (a camera's own port
    /// has d_k = its distance, > 0 by construction).
    fn check_cameras_in_air(&self) -> Result<(), ModelError> {
        let Ports::Shared(interface) = &self.ports else {
            return Ok(());
        };
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

    /// The ports.
    pub fn ports(&self) -> &Ports {
        &self.ports
    }

    /// The shared port (master frame), or `None` when every camera has its own.
    pub fn shared_interface(&self) -> Option<&Interface> {
        match &self.ports {
            Ports::Shared(interface) => Some(interface),
            Ports::PerCamera(_) => None,
        }
    }

    /// The port camera `index` looks through, in the master frame.
    ///
    /// # Panics
    /// When `index` is out of range.
    pub fn port_in_master(&self, index: usize) -> Interface {
        match &self.ports {
            Ports::Shared(interface) => interface.clone(),
            Ports::PerCamera(ports) => {
                ports[index].transformed(&self.cameras[index].cam_from_master.inverse())
            }
        }
    }

    /// The same rig behind another shared interface (validated: every camera must stay in the air).
    pub fn with_interface(&self, interface: Interface) -> Result<Self, ModelError> {
        self.with_new_ports(Ports::Shared(interface))
    }

    /// The same cameras behind other ports (validated).
    pub fn with_new_ports(&self, ports: Ports) -> Result<Self, ModelError> {
        Self::with_ports(self.cameras.clone(), ports)
    }

    /// The same rig with its cameras in the order `order` (indices into this rig's cameras, each
    /// once), the first of them the master: every camera's `cam_from_master` and a shared port
    /// re-expressed in the new master's frame (a camera's own port stays in its frame). `None`
    /// when `order` is not a permutation of the cameras.
    pub fn reordered(&self, order: &[usize]) -> Option<Self> {
        let n = self.cameras.len();
        let mut seen = vec![false; n];
        if order.len() != n
            || order
                .iter()
                .any(|&k| k >= n || std::mem::replace(&mut seen[k], true))
        {
            return None;
        }
        // X_new = new_from_old · X_old, new_from_old = cam_from_master of the new master.
        let new_from_old = self.cameras[order[0]].cam_from_master;
        let old_from_new = new_from_old.inverse();
        let cameras = order
            .iter()
            .map(|&k| RigCamera {
                cam_from_master: self.cameras[k].cam_from_master * old_from_new,
                ..self.cameras[k].clone()
            })
            .collect();
        let ports = match &self.ports {
            Ports::Shared(port) => Ports::Shared(port.transformed(&new_from_old)),
            Ports::PerCamera(ports) => {
                Ports::PerCamera(order.iter().map(|&k| ports[k].clone()).collect())
            }
        };
        Self::with_ports(cameras, ports).ok()
    }

    /// The same rig with camera `index` (not the master) moved to `cam_from_master` (validated:
    /// behind a shared port it must stay in the air).
    ///
    /// # Panics
    /// When `index` is 0 or out of range.
    pub fn with_extrinsics(
        &self,
        index: usize,
        cam_from_master: Isometry3<f64>,
    ) -> Result<Self, ModelError> {
        assert!(index > 0, "the master camera defines the frame");
        let mut cameras = self.cameras.clone();
        cameras[index].cam_from_master = cam_from_master;
        Self::with_ports(cameras, self.ports.clone())
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
        match &self.ports {
            Ports::Shared(interface) => {
                RefractiveCamera::new(camera.intrinsics, &camera.cam_from_master, interface)
            }
            Ports::PerCamera(_) => RefractiveCamera::new(
                camera.intrinsics,
                &camera.cam_from_master,
                &self.port_in_master(index),
            ),
        }
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

    #[test]
    fn a_port_per_camera_equals_the_shared_port_it_describes() {
        // Camera 1 turned 20° about y and moved: its own port, written by hand from DESIGN.md's
        // relations (n_k = R_k n, d_k = d − n·C_k), must project and back-project as the shared
        // port does.
        let shared = interface(0.2);
        let rotation =
            nalgebra::Rotation3::from_euler_angles(0.05, 20f64.to_radians(), -0.1).into_inner();
        let right = RigCamera::new(
            "right",
            intrinsics(),
            rotation,
            Vector3::new(-0.12, 0.01, 0.004),
        )
        .unwrap();
        let left =
            RigCamera::new("left", intrinsics(), Matrix3::identity(), Vector3::zeros()).unwrap();
        let cameras = vec![left, right];
        let rig = Rig::new(cameras.clone(), shared.clone()).unwrap();
        let ports: Vec<Interface> = cameras
            .iter()
            .map(|c| {
                let n = c.cam_from_master.rotation * shared.normal().into_inner();
                let d = shared.air_distance() - shared.normal().dot(&c.centre_in_master().coords);
                shared.with_pose(n, d).unwrap()
            })
            .collect();
        let own = Rig::with_ports(cameras, Ports::PerCamera(ports)).unwrap();
        assert!(own.shared_interface().is_none());
        for k in 0..2 {
            let (a, b) = (rig.refractive_camera(k), own.refractive_camera(k));
            assert!((a.air_distance() - b.air_distance()).abs() < 1e-15);
            for point in [
                Point3::new(0.3, -0.2, 1.5),
                Point3::new(-1.0, 0.4, 3.0),
                Point3::new(0.02, 0.01, 0.4),
            ] {
                let (pa, pb) = (a.project(&point).unwrap(), b.project(&point).unwrap());
                assert!((pa - pb).norm() < 1e-9, "camera {k}: {pa} vs {pb}");
                let (ra, rb) = (a.backproject(&pa).unwrap(), b.backproject(&pa).unwrap());
                assert!((ra.dir.into_inner() - rb.dir.into_inner()).norm() < 1e-12);
                assert!((ra.origin - rb.origin).norm() < 1e-12);
            }
        }
        // As many ports as cameras.
        let one = vec![interface(0.02)];
        assert!(matches!(
            Rig::with_ports(own.cameras().to_vec(), Ports::PerCamera(one)),
            Err(ModelError::MixedPorts(_))
        ));
    }
}
