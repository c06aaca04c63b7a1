//! Reproducible batches for benchmarks (`flatport bench`, `cargo bench`): pixels over the image,
//! points in the water in view, and stereo matches, on a given rig.

use nalgebra::Point2;

use crate::model::{ModelError, Rig};

/// `rig` with every camera's lens distortion set to zero: the benchmarks' pinhole variant, which
/// isolates the refraction from the undistortion.
pub fn without_distortion(rig: &Rig) -> Result<Rig, ModelError> {
    let mut cameras = rig.cameras().to_vec();
    for camera in &mut cameras {
        camera.intrinsics.distortion = [0.0; 5];
    }
    Rig::with_ports(cameras, rig.ports().clone())
}

/// Batches of one size for cameras 0 and 1 of a rig.
pub struct Workload {
    /// Raw pixels of camera 0, uniform over its image.
    pub pixels: Vec<[f64; 2]>,
    /// Points in the water seen by camera 0, 0.2–5 m beyond the interface.
    pub points: Vec<[f64; 3]>,
    /// The points' pixels in cameras 0 and 1 (ul, vl, ur, vr); points camera 1 does not see are
    /// replaced by its image centre.
    pub matches: Vec<[f64; 4]>,
}

/// A fixed LCG: reproducible without a dependency.
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

impl Workload {
    /// `items` of each kind on cameras 0 and 1 of `rig` (camera 0 twice when there is one).
    pub fn new(rig: &Rig, items: usize) -> Self {
        let (a, b) = (
            rig.refractive_camera(0),
            rig.refractive_camera(1.min(rig.cameras().len() - 1)),
        );
        let (w, h) = (
            rig.cameras()[0].intrinsics.width as f64,
            rig.cameras()[0].intrinsics.height as f64,
        );
        let mut random = Lcg(0x2545_f491_4f6c_dd1d);
        let pixels: Vec<[f64; 2]> = (0..items)
            .map(|_| [random.next() * (w - 1.0), random.next() * (h - 1.0)])
            .collect();
        let mut points = Vec::with_capacity(items);
        let mut matches = Vec::with_capacity(items);
        for (i, p) in pixels.iter().enumerate() {
            let point = match a.backproject(&Point2::new(p[0], p[1])) {
                Ok(ray) => ray.point_at(0.2 + (i % 49) as f64 * 0.1),
                Err(_) => a.centre() + a.normal().into_inner() * (1.0 + a.air_distance()),
            };
            points.push([point.x, point.y, point.z]);
            let right = b
                .project(&point)
                .map(|q| [q.x, q.y])
                .unwrap_or([b.intrinsics().cx, b.intrinsics().cy]);
            matches.push([p[0], p[1], right[0], right[1]]);
        }
        Self {
            pixels,
            points,
            matches,
        }
    }
}
