//! Shared fixtures and independent oracles for `oracle_projection`, `proptest_model` and
//! `golden_values` (kept apart from `tests/common`, which serves `tests/oracle.rs`).
//!
//! The oracles here never call flatport's math: they use its types only to build rigs. They keep
//! their own copy of every parameter (`Stack`, `CamParams`) and implement, from first principles:
//! - Snell's law in angle form on the tangential component (not the crate's vector formula),
//! - plane-by-plane tracing through the stack,
//! - forward projection by bisection on the angle of incidence in the plane of refraction,
//! - the OpenCV pinhole + Brown–Conrady distortion,
//! - the Virtual Object Point by intersecting the air ray's extension with the object axis.
#![allow(dead_code)]

pub mod random_rig;

use flatport::model::{Interface, Layer, PinholeCamera, RefractiveCamera, Rig, RigCamera};
use nalgebra::{Matrix3, Point2, Point3, Rotation3, Vector3};

/// Deterministic SplitMix64 generator (no dependency, same sequence on every machine).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let unit = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * unit
    }
}

/// The interface stack as the oracle sees it (its own copy, never read back from the crate).
#[derive(Clone, Debug)]
pub struct Stack {
    /// Unit system axis, master frame.
    pub normal: Vector3<f64>,
    /// Air layer of the master camera, metres.
    pub air_distance: f64,
    /// Layer thicknesses, metres.
    pub thicknesses: Vec<f64>,
    /// [μ_air, μ_layer_1, …, μ_layer_N, μ_water].
    pub indices: Vec<f64>,
}

impl Stack {
    pub fn index_air(&self) -> f64 {
        self.indices[0]
    }

    pub fn index_water(&self) -> f64 {
        *self.indices.last().unwrap()
    }

    /// d_k = d − n·C_k.
    pub fn air_distance_of(&self, centre: &Point3<f64>) -> f64 {
        self.air_distance - self.normal.dot(&centre.coords)
    }

    /// Σ tᵢ.
    pub fn layers_thickness(&self) -> f64 {
        self.thicknesses.iter().sum()
    }

    /// Depth x of a point beyond the outer interface, seen from camera centre `centre`.
    pub fn depth(&self, centre: &Point3<f64>, point: &Point3<f64>) -> f64 {
        self.normal.dot(&(point - centre)) - self.air_distance_of(centre) - self.layers_thickness()
    }

    pub fn layers(&self) -> Vec<Layer> {
        self.thicknesses
            .iter()
            .zip(&self.indices[1..])
            .map(|(&thickness, &index)| Layer { thickness, index })
            .collect()
    }
}

/// One camera as the oracle sees it.
#[derive(Clone, Debug)]
pub struct CamParams {
    /// R_k: X_cam = R_k · X_master + t_k.
    pub rotation: Matrix3<f64>,
    /// C_k, master frame.
    pub centre: Point3<f64>,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// OpenCV [k1, k2, p1, p2, k3].
    pub distortion: [f64; 5],
}

impl CamParams {
    pub fn has_distortion(&self) -> bool {
        self.distortion.iter().any(|&k| k != 0.0)
    }

    /// True when the pixel lies inside the image (with `margin` pixels to spare on each side).
    pub fn in_image(&self, px: &Point2<f64>, margin: f64) -> bool {
        px.x >= -margin
            && px.y >= -margin
            && px.x <= self.width as f64 - 1.0 + margin
            && px.y <= self.height as f64 - 1.0 + margin
    }

    /// Master-frame unit direction of undistorted normalised coordinates (x, y).
    pub fn dir_from_normalized(&self, x: f64, y: f64) -> Vector3<f64> {
        let d = Vector3::new(x, y, 1.0);
        self.rotation.transpose() * (d / d.norm())
    }
}

/// A rig in both forms: the oracle's parameters and the crate's `Rig` built from them.
#[derive(Clone, Debug)]
pub struct Fixture {
    pub name: String,
    pub stack: Stack,
    pub cams: Vec<CamParams>,
    pub rig: Rig,
}

impl Fixture {
    /// Builds the crate rig from the oracle's parameters (t_k = −R_k C_k).
    pub fn build(name: &str, stack: Stack, cams: Vec<CamParams>) -> Self {
        let interface = Interface::new(
            stack.normal,
            stack.air_distance,
            stack.layers(),
            stack.index_air(),
            stack.index_water(),
        )
        .expect("valid interface");
        let rig_cams = cams
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let intrinsics = PinholeCamera::new(
                    &format!("cam{k}"),
                    c.width,
                    c.height,
                    c.fx,
                    c.fy,
                    c.cx,
                    c.cy,
                    c.distortion,
                )
                .expect("valid intrinsics");
                let translation = -(c.rotation * c.centre.coords);
                RigCamera::new(&format!("cam{k}"), intrinsics, c.rotation, translation)
                    .expect("valid extrinsics")
            })
            .collect();
        let rig = Rig::new(rig_cams, interface).expect("valid rig");
        Self {
            name: name.to_string(),
            stack,
            cams,
            rig,
        }
    }

    pub fn camera(&self, k: usize) -> RefractiveCamera {
        self.rig.refractive_camera(k)
    }

    pub fn d_k(&self, k: usize) -> f64 {
        self.stack.air_distance_of(&self.cams[k].centre)
    }

    /// Oracle: water ray of camera k for a master-frame air direction.
    pub fn trace(&self, k: usize, dir_in_air: &Vector3<f64>) -> Result<Path, Fail> {
        trace_path(
            &self.cams[k].centre,
            dir_in_air,
            &self.stack.normal,
            self.d_k(k),
            &self.stack.thicknesses,
            &self.stack.indices,
        )
    }

    /// Oracle: air direction and angle of incidence from camera k to a point, by bisection.
    pub fn air_dir(&self, k: usize, point: &Point3<f64>) -> Result<(Vector3<f64>, f64), Fail> {
        air_dir_by_bisection(
            &self.cams[k].centre,
            point,
            &self.stack.normal,
            self.d_k(k),
            &self.stack.thicknesses,
            &self.stack.indices,
        )
    }

    /// Oracle: forward projection of a point into camera k.
    pub fn project(&self, k: usize, point: &Point3<f64>) -> Result<Point2<f64>, Fail> {
        let (dir, _) = self.air_dir(k, point)?;
        pixel_from_dir_checked(&self.cams[k], &dir)
    }

    /// Oracle: (x̌, Ǒ) of a point for camera k, by intersecting the air ray's extension with the
    /// object axis. `None` when the point is on the camera's axis line (the lines coincide in
    /// direction there; use [`apparent_depth`]).
    pub fn traced_vop(&self, k: usize, point: &Point3<f64>) -> Option<(f64, Point3<f64>)> {
        let (dir, a) = self.air_dir(k, point).ok()?;
        if a < 1e-6 {
            return None;
        }
        let x = self.stack.depth(&self.cams[k].centre, point);
        Some(vop_by_tracing(
            &self.cams[k].centre,
            &dir,
            point,
            &self.stack.normal,
            x,
        ))
    }
}

/// Why an oracle has no answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fail {
    /// The ray does not travel toward the next plane.
    Misses,
    /// sin θ₂ ≥ 1 at some interface.
    Tir,
    /// The point is not beyond the outer interface.
    NotInWater,
    /// The air ray points behind the camera's image plane.
    BehindCamera,
    /// Beyond the fold of the lens distortion.
    OutsideLens,
}

/// A traced path: `points[i]` is where the ray meets interface i; `dirs[0]` is the air direction and
/// `dirs[i + 1]` the direction after interface i (the last one is in the water).
#[derive(Clone, Debug, PartialEq)]
pub struct Path {
    pub points: Vec<Point3<f64>>,
    pub dirs: Vec<Vector3<f64>>,
}

impl Path {
    pub fn origin(&self) -> Point3<f64> {
        *self.points.last().unwrap()
    }

    pub fn dir_in_water(&self) -> Vector3<f64> {
        *self.dirs.last().unwrap()
    }
}

/// Snell's law in angle form: θ₁ from the tangential component of the unit `dir` relative to the unit
/// `normal`, sin θ₂ = (μ1/μ2)·sin θ₁, and the refracted direction cos θ₂·n + sin θ₂·ê, with ê the
/// unit tangential direction of incidence.
pub fn snell_angle_form(
    dir: &Vector3<f64>,
    normal: &Vector3<f64>,
    mu1: f64,
    mu2: f64,
) -> Result<Vector3<f64>, Fail> {
    let cos1 = normal.dot(dir);
    if !(cos1 > 0.0) {
        return Err(Fail::Misses);
    }
    let tangential = dir - normal * cos1;
    let sin1 = tangential.norm();
    let sin2 = mu1 / mu2 * sin1;
    if sin2 >= 1.0 {
        return Err(Fail::Tir);
    }
    let cos2 = ((1.0 - sin2) * (1.0 + sin2)).sqrt();
    if sin1 == 0.0 {
        return Ok(*normal);
    }
    Ok(normal * cos2 + tangential * (sin2 / sin1))
}

/// Brute-force tracing: from `centre` along the unit `dir_in_air`, meet each plane
/// n·(X − C) = d_k + t₁ + … in turn and refract with [`snell_angle_form`].
/// `indices` = [μ_air, μ_1, …, μ_N, μ_water], `layers` = [t₁, …, t_N].
pub fn trace_path(
    centre: &Point3<f64>,
    dir_in_air: &Vector3<f64>,
    normal: &Vector3<f64>,
    d_k: f64,
    layers: &[f64],
    indices: &[f64],
) -> Result<Path, Fail> {
    assert_eq!(indices.len(), layers.len() + 2);
    let mut point = *centre;
    let mut dir = dir_in_air / dir_in_air.norm();
    let mut plane = d_k;
    let mut path = Path {
        points: Vec::with_capacity(layers.len() + 1),
        dirs: vec![dir],
    };
    for i in 0..=layers.len() {
        let cos = normal.dot(&dir);
        if !(cos > 0.0) {
            return Err(Fail::Misses);
        }
        point += dir * ((plane - normal.dot(&(point - centre))) / cos);
        dir = snell_angle_form(&dir, normal, indices[i], indices[i + 1])?;
        path.points.push(point);
        path.dirs.push(dir);
        if i < layers.len() {
            plane += layers[i];
        }
    }
    Ok(path)
}

/// [`trace_path`] reduced to (origin on the outer interface, unit direction in the water).
pub fn trace(
    centre: &Point3<f64>,
    dir_in_air: &Vector3<f64>,
    normal: &Vector3<f64>,
    d_k: f64,
    layers: &[f64],
    indices: &[f64],
) -> Option<(Point3<f64>, Vector3<f64>)> {
    trace_path(centre, dir_in_air, normal, d_k, layers, indices)
        .ok()
        .map(|p| (p.origin(), p.dir_in_water()))
}

/// OpenCV distortion of normalised coordinates, written out from the OpenCV documentation.
pub fn distort(k: &[f64; 5], x: f64, y: f64) -> (f64, f64) {
    let [k1, k2, p1, p2, k3] = *k;
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    (
        x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
        y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
    )
}

/// s_fold = r²_fold: the first s = r² > 0 where the radial map r ↦ r(1 + k1 r² + k2 r⁴ + k3 r⁶)
/// stops increasing, d/dr = 1 + 3k1 s + 5k2 s² + 7k3 s³ = 0 (∞ when it increases up to s = 100).
/// Beyond it the lens model is not one-to-one and flatport rejects points and pixels
/// (`NoSolution::OutsideLens`). Found by a geometric scan for the sign change, then bisection.
pub fn fold_radius2(k: &[f64; 5]) -> f64 {
    let [k1, k2, _, _, k3] = *k;
    let slope = |s: f64| 1.0 + 3.0 * k1 * s + 5.0 * k2 * s * s + 7.0 * k3 * s * s * s;
    let (mut lo, mut hi) = (0.0, 1e-6);
    while hi < 100.0 {
        if slope(hi) <= 0.0 {
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if slope(mid) > 0.0 {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return lo;
        }
        lo = hi;
        hi *= 1.01;
    }
    f64::INFINITY
}

/// Pixel of a master-frame direction: rotate into the camera, pinhole, distortion, intrinsics.
/// Fails with `BehindCamera` when the direction points behind the image plane and `OutsideLens`
/// beyond the fold of the distortion ([`fold_radius2`]).
pub fn pixel_from_dir_checked(
    cam: &CamParams,
    dir_in_master: &Vector3<f64>,
) -> Result<Point2<f64>, Fail> {
    let p = cam.rotation * dir_in_master;
    if !(p.z > 0.0) {
        return Err(Fail::BehindCamera);
    }
    let (x, y) = (p.x / p.z, p.y / p.z);
    if !(x * x + y * y < fold_radius2(&cam.distortion)) {
        return Err(Fail::OutsideLens);
    }
    Ok(pixel_from_normalized(cam, x, y))
}

/// [`pixel_from_dir_checked`] as an `Option`.
pub fn pixel_from_dir(cam: &CamParams, dir_in_master: &Vector3<f64>) -> Option<Point2<f64>> {
    pixel_from_dir_checked(cam, dir_in_master).ok()
}

/// Pixel of undistorted normalised coordinates.
pub fn pixel_from_normalized(cam: &CamParams, x: f64, y: f64) -> Point2<f64> {
    let (xd, yd) = distort(&cam.distortion, x, y);
    Point2::new(cam.fx * xd + cam.cx, cam.fy * yd + cam.cy)
}

/// Largest number of bisection steps of [`air_dir_by_bisection`].
pub const BISECTION_ITERATIONS: usize = 200;

/// Forward projection by bisection on the angle of incidence a in the plane of refraction (spanned
/// by n and the lateral offset of the point): the air direction cos a·n + sin a·ê is traced with
/// [`trace_path`] to the point's plane, and a is bisected on the sign of the lateral miss there.
/// The miss is increasing in a; a TIR counts as overshooting. Bisection runs until the bracket is
/// below 1e-15 rad *and* stops shrinking (one ulp of a), at most [`BISECTION_ITERATIONS`] steps.
/// Returns the air direction and a.
pub fn air_dir_by_bisection(
    centre: &Point3<f64>,
    point: &Point3<f64>,
    normal: &Vector3<f64>,
    d_k: f64,
    layers: &[f64],
    indices: &[f64],
) -> Result<(Vector3<f64>, f64), Fail> {
    let offset = point - centre;
    let z = normal.dot(&offset);
    let depth = z - d_k - layers.iter().sum::<f64>();
    if !(depth > 0.0) {
        return Err(Fail::NotInWater);
    }
    let mut lateral = offset - normal * z;
    // Second Gram–Schmidt pass: for a point on the axis line `lateral` is rounding noise whose
    // component along n is as large as the rest; ê must be perpendicular to n.
    lateral -= normal * normal.dot(&lateral);
    let r = lateral.norm();
    if r == 0.0 {
        return Ok((*normal, 0.0));
    }
    let e = lateral / r;
    let miss = |a: f64| -> f64 {
        let dir = normal * a.cos() + e * a.sin();
        match trace_path(centre, &dir, normal, d_k, layers, indices) {
            Ok(path) => {
                let (q, w) = (path.origin(), path.dir_in_water());
                let at_depth = q + w * ((z - normal.dot(&(q - centre))) / normal.dot(&w));
                e.dot(&(at_depth - centre)) - r
            }
            Err(_) => f64::INFINITY,
        }
    };
    let (mut lo, mut hi) = (0.0_f64, std::f64::consts::FRAC_PI_2);
    for _ in 0..BISECTION_ITERATIONS {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if miss(mid) < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    assert!(
        hi - lo < 1e-15,
        "bisection bracket {lo}..{hi} did not close"
    );
    let a = 0.5 * (lo + hi);
    Ok((normal * a.cos() + e * a.sin(), a))
}

/// The VOP by geometry: where the air line C + s·v meets the object axis O + t·n. Both lie in the
/// plane of refraction; across the axis s·(v × n) = (O − C) × n fixes s (cross products avoid
/// the cancellation of 1 − (n·v)² at small angles), then along the axis t = n·(C + s·v − O).
/// Returns x̌ = x + t, the signed distance from A1 = O − x·n to the VOP along n, and Ǒ = O + t·n.
pub fn vop_by_tracing(
    centre: &Point3<f64>,
    dir_in_air: &Vector3<f64>,
    point: &Point3<f64>,
    normal: &Vector3<f64>,
    depth: f64,
) -> (f64, Point3<f64>) {
    let across = dir_in_air.cross(normal);
    let s = (point - centre).cross(normal).dot(&across) / across.norm_squared();
    let t = normal.dot(&(centre + dir_in_air * s - point));
    (depth + t, point + normal * t)
}

/// Apparent depth at normal incidence: x̌ = (μa/μw)·x − Σ tᵢ(1 − μa/μᵢ).
pub fn apparent_depth(depth: f64, stack: &Stack) -> f64 {
    let ma = stack.index_air();
    let shift: f64 = stack
        .thicknesses
        .iter()
        .zip(&stack.indices[1..])
        .map(|(t, mu)| t * (1.0 - ma / mu))
        .sum();
    ma / stack.index_water() * depth - shift
}

/// Distance of a point from the line origin + s·dir (dir need not be unit).
pub fn point_line_distance(p: &Point3<f64>, origin: &Point3<f64>, dir: &Vector3<f64>) -> f64 {
    let u = dir / dir.norm();
    let v = p - origin;
    (v - u * u.dot(&v)).norm()
}

/// Unit normal with tilt from the master z axis and azimuth atan2(n_y, n_x).
pub fn normal_from_angles(tilt: f64, azimuth: f64) -> Vector3<f64> {
    Vector3::new(
        tilt.sin() * azimuth.cos(),
        tilt.sin() * azimuth.sin(),
        tilt.cos(),
    )
}

/// Two unit vectors completing n to an orthonormal basis.
pub fn lateral_basis(n: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let u = (helper - n * n.dot(&helper)).normalize();
    (u, n.cross(&u))
}

/// Points for camera k: a grid over depth beyond the outer interface (0.1 mm, then 0.2–5 m) and
/// lateral offset (up to 1 m) around the camera's own axis line C_k + s·n, including the axis
/// line itself (r = 0) and offsets of 1 cm.
pub fn grid_points(fixture: &Fixture, k: usize) -> Vec<Point3<f64>> {
    let n = fixture.stack.normal;
    let (u, v) = lateral_basis(&n);
    let outer = fixture.d_k(k) + fixture.stack.layers_thickness();
    let centre = fixture.cams[k].centre;
    let mut points = Vec::new();
    for &depth in &[1e-4, 0.2, 0.5, 1.0, 2.0, 5.0] {
        for &a in &[-1.0, -0.5, -0.1, -0.01, 0.0, 0.01, 0.1, 0.5, 1.0] {
            for &b in &[-0.7, -0.05, 0.0, 0.3, 1.0] {
                points.push(centre + n * (outer + depth) + u * a + v * b);
            }
        }
    }
    points
}

/// The configurations of the oracle tests.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Air → water, no layer.
    Single,
    /// Air → glass → water.
    OneGlass,
    /// Air → glass → acrylic → water.
    TwoLayers,
    /// Air → glass → thin coating → glass → water.
    ThreeLayers,
    /// A tank seen from outside: air → glass(0.01, 1.5) → water(0.3, 1.333) → glass(0.01, 1.5) → air.
    Tank,
    /// Camera immersed (μa = 1.333) behind glass, looking into air: TIR at steep angles.
    Immersed,
}

impl Kind {
    pub const ALL: [Kind; 6] = [
        Kind::Single,
        Kind::OneGlass,
        Kind::TwoLayers,
        Kind::ThreeLayers,
        Kind::Tank,
        Kind::Immersed,
    ];
}

/// Moderate barrel distortion that stays invertible over a 1280×1024 image at f ≈ 900 px.
pub const DISTORTION: [f64; 5] = [-0.12, 0.05, 0.0008, -0.0005, -0.01];

fn intrinsics(fx: f64, distortion: bool) -> (u32, u32, f64, f64, f64, f64, [f64; 5]) {
    (
        1280,
        1024,
        fx,
        fx * 1.002,
        639.5,
        511.5,
        if distortion { DISTORTION } else { [0.0; 5] },
    )
}

fn camera(rotation: Matrix3<f64>, centre: Point3<f64>, fx: f64, distortion: bool) -> CamParams {
    let (width, height, fx, fy, cx, cy, distortion) = intrinsics(fx, distortion);
    CamParams {
        rotation,
        centre,
        width,
        height,
        fx,
        fy,
        cx,
        cy,
        distortion,
    }
}

/// A stereo rig for `kind`: master at the origin, right camera 0.12 m to the right, 5 mm back, and
/// rotated (≈ 7° toward the master, 2° of pitch and roll). The normals are tilted by 5–30° at
/// various azimuths.
pub fn fixture(kind: Kind, distortion: bool) -> Fixture {
    let (tilt_deg, azimuth_deg, d, layers, index_air, index_water): (
        f64,
        f64,
        f64,
        Vec<(f64, f64)>,
        f64,
        f64,
    ) = match kind {
        Kind::Single => (12.0, 40.0, 0.03, vec![], 1.0, 1.333),
        Kind::OneGlass => (30.0, 200.0, 0.02, vec![(0.014, 1.473)], 1.003, 1.333),
        Kind::TwoLayers => (
            20.0,
            -70.0,
            0.05,
            vec![(0.012, 1.49), (0.006, 1.58)],
            1.003,
            1.34,
        ),
        Kind::ThreeLayers => (
            8.0,
            120.0,
            0.025,
            vec![(0.004, 1.52), (0.0001, 1.38), (0.02, 1.473)],
            1.0,
            1.333,
        ),
        Kind::Tank => (
            5.0,
            0.0,
            0.1,
            vec![(0.01, 1.5), (0.3, 1.333), (0.01, 1.5)],
            1.0,
            1.0,
        ),
        Kind::Immersed => (25.0, 180.0, 0.04, vec![(0.012, 1.5)], 1.333, 1.0),
    };
    let stack = Stack {
        normal: normal_from_angles(tilt_deg.to_radians(), azimuth_deg.to_radians()),
        air_distance: d,
        thicknesses: layers.iter().map(|l| l.0).collect(),
        indices: std::iter::once(index_air)
            .chain(layers.iter().map(|l| l.1))
            .chain(std::iter::once(index_water))
            .collect(),
    };
    let right_rotation = Rotation3::from_euler_angles(0.035, -0.12, 0.02).into_inner();
    let cams = vec![
        camera(Matrix3::identity(), Point3::origin(), 900.0, distortion),
        camera(
            right_rotation,
            Point3::new(0.12, 0.004, -0.005),
            880.0,
            distortion,
        ),
    ];
    let name = format!("{kind:?}{}", if distortion { "+dist" } else { "" });
    Fixture::build(&name, stack, cams)
}

/// Every configuration, without and with distortion.
pub fn all_fixtures() -> Vec<Fixture> {
    Kind::ALL
        .iter()
        .flat_map(|&k| [fixture(k, false), fixture(k, true)])
        .collect()
}
