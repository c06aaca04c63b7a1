//! The flat refractive interface stack: system axis, air layer, layers, media.

use nalgebra::{Unit, Vector3};

use super::error::{ModelError, check_finite};

/// One parallel layer of the port (glass, acrylic, …): its thickness along the normal and its index.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Layer {
    /// Thickness along the system axis, metres (> 0).
    pub thickness: f64,
    /// Refractive index (≥ 1).
    pub index: f64,
}

/// A flat port: parallel planes with a common unit normal n (the *system axis*), in the master frame.
///
/// Interface i (0-based) lies on the plane n·X = d + t₀ + … + t_(i−1), with d the air layer
/// thickness ([`air_distance`](Self::air_distance)). The cameras sit in a medium of index
/// `index_air`; after the last layer comes the medium of index `index_water`. Zero layers is a single
/// interface air → water; a tank seen from outside is air → glass → water → glass → air.
#[derive(Debug, Clone, PartialEq)]
pub struct Interface {
    normal: Unit<Vector3<f64>>,
    air_distance: f64,
    layers: Vec<Layer>,
    index_air: f64,
    index_water: f64,
}

/// Default index of the medium around the cameras.
pub const DEFAULT_INDEX_AIR: f64 = 1.0;
/// Default index of the last medium.
pub const DEFAULT_INDEX_WATER: f64 = 1.333;

impl Interface {
    /// Builds and validates an interface stack.
    ///
    /// `normal` may be unnormalised; it is normalised here. Errors: a zero or non-finite normal, a
    /// normal with n·z ≤ 0 (pointing away from the water for a forward-looking master camera),
    /// `air_distance` ≤ 0, a thickness ≤ 0, an index < 1.
    pub fn new(
        normal: Vector3<f64>,
        air_distance: f64,
        layers: Vec<Layer>,
        index_air: f64,
        index_water: f64,
    ) -> Result<Self, ModelError> {
        for (axis, v) in ["normal[0]", "normal[1]", "normal[2]"]
            .iter()
            .zip(normal.iter())
        {
            check_finite(axis, *v)?;
        }
        // Scaled by its largest component before squaring: |n|² of a normal given as
        // [1e308, 1e308, 1e308] overflows, and the unit vector would come out zero.
        // Only outside [1e-150, 1e150], so that every ordinary normal normalises to the same bits.
        let largest = normal.amax();
        if largest == 0.0 {
            return Err(ModelError::ZeroNormal);
        }
        // Its true length |n| = largest · |n / largest|. A length below the smallest normal f64
        // (a normal given as [1e-320, 0, 1e-320]) or past the largest is no length f64 holds: such
        // a normal is refused here, naming it, rather than normalised through a subnormal scale
        // into a direction that then fails elsewhere (a camera "not in the air").
        let length = largest * (normal / largest).norm();
        let unrepresentable = ModelError::NormalLength {
            x: normal.x,
            y: normal.y,
            z: normal.z,
            length,
        };
        if !(f64::MIN_POSITIVE..=f64::MAX).contains(&length) {
            return Err(unrepresentable);
        }
        let normal = if (1e-150..=1e150).contains(&largest) {
            normal
        } else {
            normal / largest
        };
        let unit = Unit::new_normalize(normal);
        if (unit.norm() - 1.0).abs() > 1e-12 {
            return Err(unrepresentable);
        }
        if normal.z <= 0.0 {
            return Err(ModelError::NormalAwayFromWater {
                x: normal.x,
                y: normal.y,
                z: normal.z,
            });
        }
        check_finite("interface distance", air_distance)?;
        if air_distance <= 0.0 {
            return Err(ModelError::NonPositiveAirDistance {
                value: air_distance,
            });
        }
        check_index("index_air", index_air)?;
        check_index("index_water", index_water)?;
        for (i, layer) in layers.iter().enumerate() {
            check_finite(&format!("layer {i} thickness"), layer.thickness)?;
            if layer.thickness <= 0.0 {
                return Err(ModelError::NonPositiveThickness {
                    layer: i,
                    value: layer.thickness,
                });
            }
            check_index(&format!("layer {i}"), layer.index)?;
        }
        Ok(Self {
            normal: unit,
            air_distance,
            layers,
            index_air,
            index_water,
        })
    }

    /// The system axis n: unit normal of the interfaces, master frame, pointing into the water.
    pub fn normal(&self) -> &Unit<Vector3<f64>> {
        &self.normal
    }

    /// Air layer thickness d: distance along n from the master camera centre to the first interface.
    pub fn air_distance(&self) -> f64 {
        self.air_distance
    }

    /// The layers between the air and the water, in the order light from the camera crosses them.
    pub fn layers(&self) -> &[Layer] {
        &self.layers
    }

    /// Index of the medium around the cameras.
    pub fn index_air(&self) -> f64 {
        self.index_air
    }

    /// Index of the last medium.
    pub fn index_water(&self) -> f64 {
        self.index_water
    }

    /// Total thickness of the layers, Σ tᵢ.
    pub fn layers_thickness(&self) -> f64 {
        self.layers.iter().map(|l| l.thickness).sum()
    }

    /// Distance along n from the master camera centre to the outer (last) interface, d + Σ tᵢ.
    pub fn outer_distance(&self) -> f64 {
        self.air_distance + self.layers_thickness()
    }

    /// Tilt of the system axis: the angle between n and the master camera's z axis, radians.
    pub fn tilt(&self) -> f64 {
        self.normal.z.clamp(-1.0, 1.0).acos()
    }

    /// Azimuth of the system axis: atan2(n_y, n_x), radians (0 for an untilted axis).
    pub fn azimuth(&self) -> f64 {
        self.normal.y.atan2(self.normal.x)
    }

    /// The same stack seen from another frame B, with X_B = `b_from_a`·X_A (this stack given in A):
    /// n_B = R n_A and d_B = d_A + n_B·t. A camera's own port (normal and distance in that camera's
    /// frame) becomes the master frame's by its `cam_from_master` inverse. Not revalidated: the
    /// normal may point anywhere in B (n·z > 0 holds in the frame of the camera that looks through it).
    pub fn transformed(&self, b_from_a: &nalgebra::Isometry3<f64>) -> Self {
        let normal = b_from_a.rotation * self.normal;
        Self {
            normal,
            air_distance: self.air_distance + normal.dot(&b_from_a.translation.vector),
            ..self.clone()
        }
    }

    /// The same stack with other layer thicknesses (indices kept; validated as in [`new`](Self::new)).
    pub fn with_thicknesses(&self, thicknesses: &[f64]) -> Result<Self, ModelError> {
        assert_eq!(
            thicknesses.len(),
            self.layers.len(),
            "one thickness per layer"
        );
        let layers = self
            .layers
            .iter()
            .zip(thicknesses)
            .map(|(l, &thickness)| Layer {
                thickness,
                index: l.index,
            })
            .collect();
        Self::new(
            self.normal.into_inner(),
            self.air_distance,
            layers,
            self.index_air,
            self.index_water,
        )
    }

    /// The same stack with another system axis and air layer (validated as in [`new`](Self::new)).
    pub fn with_pose(&self, normal: Vector3<f64>, air_distance: f64) -> Result<Self, ModelError> {
        Self::new(
            normal,
            air_distance,
            self.layers.clone(),
            self.index_air,
            self.index_water,
        )
    }
}

/// Unit axis with the given tilt from the master z axis and azimuth atan2(n_y, n_x), radians:
/// n = (sin t cos φ, sin t sin φ, cos t).
pub fn normal_from_tilt_azimuth(tilt: f64, azimuth: f64) -> Unit<Vector3<f64>> {
    let (st, ct) = tilt.sin_cos();
    let (sa, ca) = azimuth.sin_cos();
    Unit::new_normalize(Vector3::new(st * ca, st * sa, ct))
}

fn check_index(medium: &str, value: f64) -> Result<(), ModelError> {
    check_finite(medium, value)?;
    if value < 1.0 {
        return Err(ModelError::IndexBelowOne {
            medium: medium.to_string(),
            value,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn glass() -> Vec<Layer> {
        vec![Layer {
            thickness: 0.014,
            index: 1.473,
        }]
    }

    #[test]
    fn normal_is_normalised() {
        let i = Interface::new(Vector3::new(0.1, 0.1, 1.0), 0.02, glass(), 1.0, 1.333).unwrap();
        assert!((i.normal().norm() - 1.0).abs() < 1e-15);
        assert!((i.outer_distance() - 0.034).abs() < 1e-15);
    }

    #[test]
    fn tilt_and_azimuth_round_trip() {
        let n = normal_from_tilt_azimuth(0.3, -2.0);
        let i = Interface::new(n.into_inner(), 0.02, vec![], 1.0, 1.333).unwrap();
        assert!((i.tilt() - 0.3).abs() < 1e-15 && (i.azimuth() + 2.0).abs() < 1e-15);
        // DESIGN.md example normal (0.1, 0.1, 1): tilt = atan(√0.02) ≈ 8.05°, azimuth 45°.
        let i = Interface::new(Vector3::new(0.1, 0.1, 1.0), 0.02, vec![], 1.0, 1.333).unwrap();
        assert!((i.tilt() - 0.02f64.sqrt().atan()).abs() < 1e-15);
        assert!((i.azimuth().to_degrees() - 45.0).abs() < 1e-12);
    }

    #[test]
    fn invalid_stacks_are_rejected() {
        let z = Vector3::z();
        assert_eq!(
            Interface::new(Vector3::zeros(), 0.02, glass(), 1.0, 1.333),
            Err(ModelError::ZeroNormal)
        );
        assert!(matches!(
            Interface::new(Vector3::new(0.0, 0.0, -1.0), 0.02, glass(), 1.0, 1.333),
            Err(ModelError::NormalAwayFromWater { .. })
        ));
        assert!(matches!(
            Interface::new(z, 0.0, glass(), 1.0, 1.333),
            Err(ModelError::NonPositiveAirDistance { .. })
        ));
        assert!(matches!(
            Interface::new(
                z,
                0.02,
                vec![Layer {
                    thickness: -1.0,
                    index: 1.5
                }],
                1.0,
                1.333
            ),
            Err(ModelError::NonPositiveThickness { layer: 0, .. })
        ));
        assert!(matches!(
            Interface::new(z, 0.02, glass(), 0.9, 1.333),
            Err(ModelError::IndexBelowOne { .. })
        ));
        assert!(matches!(
            Interface::new(z, f64::NAN, glass(), 1.0, 1.333),
            Err(ModelError::NotFinite { .. })
        ));
    }

    #[test]
    fn huge_and_tiny_normals_keep_their_direction() {
        // 1e-300: tiny, yet its length 1.4e-300 is an ordinary f64 (1e-320 is not: see below).
        for scale in [1e308, 1e-300, 1.0] {
            let i =
                Interface::new(Vector3::new(scale, 0.0, scale), 0.02, vec![], 1.0, 1.333).unwrap();
            let expected = Vector3::new(1.0, 0.0, 1.0) / 2f64.sqrt();
            assert!(
                (i.normal().into_inner() - expected).norm() < 1e-15,
                "{scale}: {:?}",
                i.normal()
            );
        }
        assert!(matches!(
            Interface::new(Vector3::zeros(), 0.02, vec![], 1.0, 1.333),
            Err(ModelError::ZeroNormal)
        ));
    }

    #[test]
    fn a_normal_whose_length_f64_does_not_hold_is_refused() {
        // |n| of [1e-320, 0, 1e-320] is subnormal; of [1.5e308, 1.5e308, 1.5e308] past f64::MAX;
        // of [5e-324, 0, 5e-324] (the smallest subnormals) it rounds to one subnormal step.
        for normal in [
            Vector3::new(1e-320, 0.0, 1e-320),
            Vector3::new(0.0, 0.0, 1e-310),
            Vector3::new(5e-324, 0.0, 5e-324),
            Vector3::new(1.5e308, 1.5e308, 1.5e308),
        ] {
            let error = Interface::new(normal, 0.02, vec![], 1.0, 1.333).unwrap_err();
            assert!(
                matches!(error, ModelError::NormalLength { .. }),
                "{normal:?}: {error:?}"
            );
            let message = error.to_string();
            assert!(
                message.contains("length is zero or not representable")
                    && message.contains("underflows"),
                "{message}"
            );
        }
        // The smallest normal f64 as the only component is still a length f64 holds.
        assert!(
            Interface::new(
                Vector3::new(0.0, 0.0, f64::MIN_POSITIVE),
                0.02,
                vec![],
                1.0,
                1.333
            )
            .is_ok()
        );
    }
}
