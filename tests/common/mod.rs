//! Independent oracles for the refractive model. Nothing here calls flatport's math: Snell in
//! angle form, plane-by-plane tracing, forward projection by bisection over the tracer, the
//! OpenCV lens model written out again. flatport types are used only to build rigs.
#![allow(dead_code)]

use flatport::model::{Interface, Layer, PinholeCamera, Rig, RigCamera};
use nalgebra::{Matrix3, Point2, Point3, Rotation3, Unit, Vector3};

/// The stack seen by one camera: its centre, the planes' offsets along n from it, the indices.
pub struct Stack {
    pub centre: Vector3<f64>,
    pub normal: Vector3<f64>,
    /// Offset along n from the camera centre to each interface.
    pub planes: Vec<f64>,
    /// Indices: air, layers…, water (planes.len() + 1 entries).
    pub indices: Vec<f64>,
    pub cam_from_master: Matrix3<f64>,
    pub camera: PinholeCamera,
}

impl Stack {
    pub fn of(rig: &Rig, k: usize) -> Self {
        let i = rig.shared_interface().unwrap();
        let cam = &rig.cameras()[k];
        let r = cam
            .cam_from_master
            .rotation
            .to_rotation_matrix()
            .into_inner();
        let t = cam.cam_from_master.translation.vector;
        let centre = -(r.transpose() * t);
        let normal = i.normal().into_inner();
        let mut planes = vec![i.air_distance() - normal.dot(&centre)];
        let mut indices = vec![i.index_air()];
        for l in i.layers() {
            planes.push(planes.last().unwrap() + l.thickness);
            indices.push(l.index);
        }
        indices.push(i.index_water());
        Stack {
            centre,
            normal,
            planes,
            indices,
            cam_from_master: r,
            camera: cam.intrinsics,
        }
    }

    pub fn outer(&self) -> f64 {
        *self.planes.last().unwrap()
    }
}

/// Snell in angle form: split `dir` into normal and tangential parts, sin θ₂ = μ1/μ2 · sin θ₁.
pub fn snell_angle_form(
    dir: Vector3<f64>,
    n: Vector3<f64>,
    mu1: f64,
    mu2: f64,
) -> Option<Vector3<f64>> {
    let cos1 = dir.dot(&n);
    if cos1 <= 0.0 {
        return None;
    }
    let tangential = dir - n * cos1;
    let sin1 = tangential.norm();
    if sin1 == 0.0 {
        return Some(n);
    }
    let sin2 = mu1 / mu2 * sin1;
    if sin2 >= 1.0 {
        return None;
    }
    let cos2 = (1.0 - sin2 * sin2).sqrt();
    Some(n * cos2 + tangential * (sin2 / sin1))
}

/// Traces a ray from the camera centre through every plane. Returns (origin on the outer
/// interface, unit direction in the water, every direction along the way).
pub fn trace(
    stack: &Stack,
    dir_in_air: Vector3<f64>,
) -> Option<(Vector3<f64>, Vector3<f64>, Vec<Vector3<f64>>)> {
    let n = stack.normal;
    let mut p = stack.centre;
    let mut d = dir_in_air.normalize();
    let mut dirs = vec![d];
    for (j, &plane) in stack.planes.iter().enumerate() {
        let along = d.dot(&n);
        if along <= 0.0 {
            return None;
        }
        p += d * ((plane - n.dot(&(p - stack.centre))) / along);
        d = snell_angle_form(d, n, stack.indices[j], stack.indices[j + 1])?;
        dirs.push(d);
    }
    Some((p, d, dirs))
}

/// Forward projection by bisection on the angle of incidence in the plane of refraction. Returns
/// the unit air direction (master frame).
pub fn air_dir_by_bisection(stack: &Stack, point: Vector3<f64>) -> Option<Vector3<f64>> {
    let n = stack.normal;
    let delta = point - stack.centre;
    let z = n.dot(&delta);
    if z <= stack.outer() {
        return None;
    }
    let lateral = delta - n * z;
    let r = lateral.norm();
    if r <= 1e-12 * z {
        // On the axis line (up to rounding, which would give e a spurious component along n).
        return Some(n);
    }
    let e = lateral / r;
    // Lateral position reached at the point's depth by the ray leaving at angle a (increasing in a).
    let reach = |a: f64| -> f64 {
        let dir = n * a.cos() + e * a.sin();
        match trace(stack, dir) {
            Some((p, w, _)) => {
                let s = (z - n.dot(&(p - stack.centre))) / w.dot(&n);
                e.dot(&(p + w * s - stack.centre))
            }
            None => f64::INFINITY, // beyond the critical angle nothing reaches the water
        }
    };
    let (mut lo, mut hi) = (0.0f64, std::f64::consts::FRAC_PI_2);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if reach(mid) < r {
            lo = mid
        } else {
            hi = mid
        }
        if hi - lo < 1e-17 {
            break;
        }
    }
    let a = 0.5 * (lo + hi);
    Some(n * a.cos() + e * a.sin())
}

/// OpenCV distortion, written out.
pub fn distort(c: &PinholeCamera, x: f64, y: f64) -> (f64, f64) {
    let [k1, k2, p1, p2, k3] = c.distortion;
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    (
        x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
        y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
    )
}

/// Pixel of a master-frame direction from the camera centre.
pub fn pixel_of_dir(stack: &Stack, dir: Vector3<f64>) -> Option<Point2<f64>> {
    let p = stack.cam_from_master * dir;
    if p.z <= 0.0 {
        return None;
    }
    let (xd, yd) = distort(&stack.camera, p.x / p.z, p.y / p.z);
    Some(Point2::new(
        stack.camera.fx * xd + stack.camera.cx,
        stack.camera.fy * yd + stack.camera.cy,
    ))
}

/// Undistortion by OpenCV's fixed-point iteration, run to convergence.
pub fn undistort(c: &PinholeCamera, pixel: Point2<f64>) -> (f64, f64) {
    let (xd, yd) = ((pixel.x - c.cx) / c.fx, (pixel.y - c.cy) / c.fy);
    let [k1, k2, p1, p2, k3] = c.distortion;
    let (mut x, mut y) = (xd, yd);
    for _ in 0..2000 {
        let r2 = x * x + y * y;
        let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
        let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        (x, y) = ((xd - dx) / radial, (yd - dy) / radial);
    }
    (x, y)
}

/// Master-frame unit direction of a pixel.
pub fn dir_of_pixel(stack: &Stack, pixel: Point2<f64>) -> Vector3<f64> {
    let (x, y) = undistort(&stack.camera, pixel);
    (stack.cam_from_master.transpose() * Vector3::new(x, y, 1.0)).normalize()
}

/// Closest point on line (p, u) to line (q, w): the traced VOP is the closest point of the air
/// ray's backward extension to the object axis.
pub fn closest_on_first(
    p: Vector3<f64>,
    u: Vector3<f64>,
    q: Vector3<f64>,
    w: Vector3<f64>,
) -> Vector3<f64> {
    let w0 = p - q;
    let (a, b, c, d, e) = (u.dot(&u), u.dot(&w), w.dot(&w), u.dot(&w0), w.dot(&w0));
    let s = (b * e - c * d) / (a * c - b * b);
    p + u * s
}

pub fn unit(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z).normalize()
}

/// A stereo rig: master plus a second camera 0.08 m to the right, turned 3° about y and 1° about x.
pub fn stereo_rig(
    normal: Vector3<f64>,
    distance: f64,
    layers: Vec<Layer>,
    index_air: f64,
    index_water: f64,
    distortion: bool,
) -> Rig {
    let d = if distortion {
        [-0.12, 0.03, 0.0008, -0.0005, -0.002]
    } else {
        [0.0; 5]
    };
    let left = PinholeCamera::new("left", 1280, 1024, 864.91, 866.2, 641.3, 509.8, d).unwrap();
    let right = PinholeCamera::new("right", 1280, 1024, 870.0, 870.0, 630.0, 515.0, d).unwrap();
    let r = Rotation3::from_euler_angles(1f64.to_radians(), -3f64.to_radians(), 0.0).into_inner();
    let centre = Vector3::new(0.08, 0.002, -0.001);
    let t = -(r * centre);
    Rig::new(
        vec![
            RigCamera::new("left", left, Matrix3::identity(), Vector3::zeros()).unwrap(),
            RigCamera::new("right", right, r, t).unwrap(),
        ],
        Interface::new(normal, distance, layers, index_air, index_water).unwrap(),
    )
    .unwrap()
}

/// The configurations of the issue: single interface, one glass, two and three layers, a tank.
pub fn configurations() -> Vec<(&'static str, Rig)> {
    let tilt = unit(0.12, -0.08, 1.0);
    let steep = unit(0.35, 0.3, 1.0); // ≈ 25° tilt
    let glass = Layer {
        thickness: 0.014,
        index: 1.473,
    };
    vec![
        (
            "single interface",
            stereo_rig(tilt, 0.03, vec![], 1.0, 1.333, false),
        ),
        (
            "single interface, distorted",
            stereo_rig(steep, 0.045, vec![], 1.0003, 1.34, true),
        ),
        (
            "one glass layer",
            stereo_rig(tilt, 0.02, vec![glass], 1.003, 1.333, true),
        ),
        (
            "two layers",
            stereo_rig(
                steep,
                0.045,
                vec![
                    glass,
                    Layer {
                        thickness: 0.006,
                        index: 1.49,
                    },
                ],
                1.0,
                1.333,
                true,
            ),
        ),
        (
            "three layers",
            stereo_rig(
                tilt,
                0.015,
                vec![
                    Layer {
                        thickness: 0.01,
                        index: 1.52,
                    },
                    Layer {
                        thickness: 0.002,
                        index: 1.38,
                    },
                    Layer {
                        thickness: 0.02,
                        index: 1.7,
                    },
                ],
                1.0,
                1.345,
                true,
            ),
        ),
        (
            "tank (air, glass, water, glass, air)",
            stereo_rig(
                tilt,
                0.05,
                vec![
                    Layer {
                        thickness: 0.01,
                        index: 1.5,
                    },
                    Layer {
                        thickness: 0.3,
                        index: 1.333,
                    },
                    Layer {
                        thickness: 0.01,
                        index: 1.5,
                    },
                ],
                1.0,
                1.0,
                true,
            ),
        ),
    ]
}

/// Points in the water in front of the cameras: a grid over depth and lateral offset, plus points on
/// the master's axis line (r = 0) and points 0.1 mm beyond the outer interface.
pub fn points_in_water(rig: &Rig) -> Vec<Point3<f64>> {
    let n = rig.shared_interface().unwrap().normal().into_inner();
    let outer = rig.shared_interface().unwrap().outer_distance();
    let mut points = Vec::new();
    for &depth in &[0.2, 0.7, 1.5, 5.0] {
        for i in -3..=3 {
            for j in -2..=2 {
                let base = Vector3::new(i as f64 * 0.11, j as f64 * 0.1, 1.0) * (depth + outer);
                points.push(Point3::from(base));
            }
        }
        points.push(Point3::from(n * (outer + depth)));
    }
    for &(x, y) in &[(0.0, 0.0), (0.01, 0.02), (-0.03, 0.01)] {
        let base = Vector3::new(x, y, 0.0);
        let along = (outer + 1e-4 - n.dot(&base)) / n.z;
        points.push(Point3::from(base + Vector3::z() * along));
    }
    points
}

/// True when the pixel lies in the image (where a lens model is meaningful), with a margin.
pub fn in_image(stack: &Stack, pixel: &Point2<f64>, margin: f64) -> bool {
    let c = &stack.camera;
    pixel.x > -margin
        && pixel.y > -margin
        && pixel.x < c.width as f64 + margin
        && pixel.y < c.height as f64 + margin
}

pub fn as_unit(v: Vector3<f64>) -> Unit<Vector3<f64>> {
    Unit::new_normalize(v)
}
