//! One camera of a rig prepared for refraction: back-projection (pixel → ray in the water) and
//! forward projection (point in the water → pixel), both in the master frame.

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Unit, Vector2, Vector3};

use super::camera::PinholeCamera;
use super::interface::{Interface, Layer};
use super::snell::refract;
use super::{MAX_INPUT, NoSolution};

/// A ray `origin + s·dir`, s ≥ 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Start point.
    pub origin: Point3<f64>,
    /// Unit direction.
    pub dir: Unit<Vector3<f64>>,
}

impl Ray {
    /// The point `origin + s·dir`.
    #[inline]
    pub fn point_at(&self, s: f64) -> Point3<f64> {
        self.origin + self.dir.into_inner() * s
    }
}

/// Largest number of iterations of the forward-projection root finder before it reports
/// [`NoSolution::NoConvergence`]. Newton from the paraxial start needs 2–6; the bound only matters
/// if rounding forces bisection steps, each of which halves the bracket.
pub const PROJECT_MAX_ITERATIONS: u32 = 100;

/// Relative step size |Δτ|/τ at which the forward-projection Newton iteration stops. The
/// convergence is quadratic, so the error after that last step is far below it.
pub const PROJECT_TOLERANCE: f64 = 1e-13;

/// How light from a point in the water reaches a camera: the solution of the forward projection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AirPath {
    /// Unit direction of the ray in the air, from the camera centre toward the interface, master frame.
    pub dir_in_air: Unit<Vector3<f64>>,
    /// tan a, a the angle of incidence in the air.
    pub tan_incidence: f64,
    /// x: distance of the point from the outer interface along the axis, metres.
    pub depth: f64,
    /// r: distance of the point from the camera's axis line C_k + s·n, metres.
    pub lateral_distance: f64,
    /// Root-finder iterations used (0 for a point on the camera's axis line).
    pub iterations: u32,
}

/// The Virtual Object Point of a point in the water as seen from one camera (thesis ch. 4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vop {
    /// x: distance of the real point from the outer interface along the axis, metres (> 0).
    pub depth: f64,
    /// x̌: signed distance from A1 (object axis ∩ outer interface) to the VOP, positive toward the
    /// water, negative inside the layers, metres.
    pub vop_distance: f64,
    /// The VOP Ǒ = A1 + x̌·n, master frame.
    pub vop: Point3<f64>,
    /// Angle of incidence in the air, radians.
    pub incidence: f64,
}

/// Camera k of a rig with the interface expressed in its terms: centre C_k, own air layer
/// d_k = d − n·C_k, and the index ratios ρ = μ/μ_air. Build it once with
/// [`Rig::refractive_camera`](super::Rig::refractive_camera) and reuse it for every point.
#[derive(Debug, Clone)]
pub struct RefractiveCamera {
    intrinsics: PinholeCamera,
    cam_from_master: Matrix3<f64>,
    master_from_cam: Matrix3<f64>,
    centre: Point3<f64>,
    normal: Unit<Vector3<f64>>,
    /// R_k·n: the system axis in this camera's frame.
    normal_in_cam: Vector3<f64>,
    air_distance: f64,
    layers: Vec<Layer>,
    /// The media of a forward-projection path: air, water, then the layers ([`AIR`], [`WATER`]).
    media: Vec<Medium>,
    /// Index in `media` of the slowest medium (smallest ρ; the first of equals).
    slowest: usize,
    layers_thickness: f64,
    index_air: f64,
    index_water: f64,
    /// ρ_w = μ_w/μ_air.
    rho_water: f64,
    /// 1/ρ_w.
    inv_rho_water: f64,
    /// Squared normalised radius of the lens model's fold ([`PinholeCamera::fold_radius2`]).
    fold_radius2: f64,
    /// (1/f_x, 1/f_y).
    inv_focal: Vector2<f64>,
    /// Whether the intrinsics distort.
    distorts: bool,
}

impl RefractiveCamera {
    /// Prepares a camera with OpenCV extrinsics `cam_from_master` behind `interface`.
    pub fn new(
        intrinsics: PinholeCamera,
        cam_from_master: &Isometry3<f64>,
        interface: &Interface,
    ) -> Self {
        let rotation = cam_from_master.rotation.to_rotation_matrix().into_inner();
        let centre = cam_from_master.inverse_transform_point(&Point3::origin());
        let normal = *interface.normal();
        let index_air = interface.index_air();
        let air_distance = interface.air_distance() - normal.dot(&centre.coords);
        let rho_water = interface.index_water() / index_air;
        let mut media: Vec<Medium> = [(air_distance, 1.0, 1.0), (0.0, rho_water, 1.0 / rho_water)]
            .into_iter()
            .chain(
                interface
                    .layers()
                    .iter()
                    .map(|l| (l.thickness, l.index / index_air, index_air / l.index)),
            )
            .map(|(length, rho, inv_rho)| Medium {
                length,
                rho,
                inv_rho,
                critical_top: f64::INFINITY,
            })
            .collect();
        let rhos: Vec<f64> = media.iter().map(|m| m.rho).collect();
        for medium in &mut media {
            for &rho in &rhos {
                let k = medium.rho / rho;
                if k > 1.0 {
                    medium.critical_top = medium.critical_top.min(1.0 / (k * k - 1.0).sqrt());
                }
            }
        }
        let slowest =
            (0..media.len()).fold(AIR, |a, i| if media[i].rho < media[a].rho { i } else { a });
        Self {
            intrinsics,
            cam_from_master: rotation,
            master_from_cam: rotation.transpose(),
            centre,
            normal,
            normal_in_cam: rotation * normal.into_inner(),
            air_distance,
            layers: interface.layers().to_vec(),
            media,
            slowest,
            layers_thickness: interface.layers_thickness(),
            index_air,
            index_water: interface.index_water(),
            rho_water,
            inv_rho_water: 1.0 / rho_water,
            fold_radius2: intrinsics.fold_radius2(),
            inv_focal: Vector2::new(1.0 / intrinsics.fx, 1.0 / intrinsics.fy),
            distorts: intrinsics.has_distortion(),
        }
    }

    /// Camera centre C_k in the master frame.
    pub fn centre(&self) -> &Point3<f64> {
        &self.centre
    }

    /// This camera's air layer d_k = d − n·C_k, metres.
    pub fn air_distance(&self) -> f64 {
        self.air_distance
    }

    /// The intrinsics.
    pub fn intrinsics(&self) -> &PinholeCamera {
        &self.intrinsics
    }

    /// R_kᵀ: rotation from this camera's frame to the master frame.
    pub fn master_from_cam(&self) -> &Matrix3<f64> {
        &self.master_from_cam
    }

    /// The system axis n, master frame.
    pub fn normal(&self) -> &Unit<Vector3<f64>> {
        &self.normal
    }

    /// The layers, in the order light from the camera crosses them.
    pub fn layers(&self) -> &[Layer] {
        &self.layers
    }

    /// ρ_w = μ_w/μ_air.
    pub fn relative_index_water(&self) -> f64 {
        self.rho_water
    }

    /// Index of the medium around the cameras.
    pub fn index_air(&self) -> f64 {
        self.index_air
    }

    /// Squared normalised radius of the lens model's fold ([`PinholeCamera::fold_radius2`]).
    pub fn fold_radius2(&self) -> f64 {
        self.fold_radius2
    }

    /// R_k: rotation from the master frame to this camera's frame.
    pub fn cam_from_master(&self) -> &Matrix3<f64> {
        &self.cam_from_master
    }

    /// R_k·n: the system axis in this camera's frame.
    pub fn normal_in_cam(&self) -> &Vector3<f64> {
        &self.normal_in_cam
    }

    /// Σ tᵢ: the thickness of all layers, metres.
    pub fn layers_thickness(&self) -> f64 {
        self.layers_thickness
    }

    /// The forward-projection root finder's media, for the vector twin in
    /// [`engine::cpu::lanes`](crate::engine::cpu::lanes): (air, water, then the layers; the index of the
    /// slowest).
    pub(crate) fn path_media(&self) -> (&[Medium], usize) {
        (&self.media, self.slowest)
    }

    /// Unit viewing direction of a (distorted) pixel in the master frame.
    ///
    /// Errors: [`NoSolution::OutsideLens`] when undistortion fails or lands beyond the fold of the
    /// radial distortion ([`PinholeCamera::fold_radius2`]), where the pixel has several preimages.
    #[inline]
    pub fn dir_in_air_from_img(
        &self,
        pixel: &Point2<f64>,
    ) -> Result<Unit<Vector3<f64>>, NoSolution> {
        let i = &self.intrinsics;
        let distorted = Vector2::new(
            (pixel.x - i.cx) * self.inv_focal.x,
            (pixel.y - i.cy) * self.inv_focal.y,
        );
        let normalized = if self.distorts {
            i.undistort_normalized_in_fold(&distorted, self.fold_radius2)
                .ok_or(NoSolution::OutsideLens)?
        } else {
            distorted
        };
        let radius2 = normalized.norm_squared();
        if !(radius2 < self.fold_radius2) {
            return Err(NoSolution::OutsideLens);
        }
        // R_kᵀ·(x, y, 1)/√(x² + y² + 1): rotate, then scale once.
        let m = &self.master_from_cam;
        let dir = m.column(0) * normalized.x + m.column(1) * normalized.y + m.column(2);
        Ok(Unit::new_unchecked(dir * (1.0 / (radius2 + 1.0).sqrt())))
    }

    /// Back-projects a (distorted) pixel into the water with the closed form of
    /// [`ray_in_water`](Self::ray_in_water).
    #[inline]
    pub fn backproject(&self, pixel: &Point2<f64>) -> Result<Ray, NoSolution> {
        self.ray_in_water(&self.dir_in_air_from_img(pixel)?)
    }

    /// Back-projects a (distorted) pixel by tracing, see [`trace_ray_in_water`](Self::trace_ray_in_water).
    pub fn backproject_traced(&self, pixel: &Point2<f64>) -> Result<Ray, NoSolution> {
        self.trace_ray_in_water(&self.dir_in_air_from_img(pixel)?)
    }

    /// The ray in the water for a ray leaving the camera centre with `dir_in_air` (master frame),
    /// closed form (thesis 5.2.2).
    ///
    /// With c = n·v = cos a, λ1 and λ2,ᵢ at that angle, the backward extension of the water ray
    /// crosses the line C_k + s·n at
    /// c_axis = C_k + [d_k (1 − λ1) + Σ tᵢ (1 − λ1 λ2,ᵢ)]·n,
    /// and its direction is w = (μa/μw)·(v + cos a (λ1 − 1)·n) (Snell across the whole stack). The
    /// returned origin is where c_axis + λ·w meets the outer interface,
    /// c_axis + (d_k + Σ tᵢ λ2,ᵢ)/cos a · (v + cos a (λ1 − 1)·n). Master frame, metres.
    ///
    /// Errors: [`NoSolution::MissesInterface`] when n·v ≤ 0, [`NoSolution::TotalInternalReflection`]
    /// when the light cannot enter a layer or the water.
    #[inline]
    pub fn ray_in_water(&self, dir_in_air: &Unit<Vector3<f64>>) -> Result<Ray, NoSolution> {
        let v = dir_in_air.into_inner();
        let n = self.normal.into_inner();
        let cos_a = n.dot(&v);
        if !(cos_a > 0.0) {
            return Err(NoSolution::MissesInterface);
        }
        let sin2_a = (1.0 - cos_a * cos_a).max(0.0);
        let water_radicand = self.rho_water * self.rho_water - sin2_a;
        if !(water_radicand > 0.0) {
            return Err(NoSolution::TotalInternalReflection);
        }
        let inv_cos_a = 1.0 / cos_a;
        // cos a·λ1 = √(ρ_w² − sin²a) = ρ_w cos θ_w.
        let cos_lambda1 = water_radicand.sqrt();
        let lambda1 = cos_lambda1 * inv_cos_a;
        let mut axis_shift = self.air_distance * (1.0 - lambda1);
        let mut lateral_length = self.air_distance;
        for &Medium {
            length: thickness,
            rho,
            ..
        } in &self.media[WATER + 1..]
        {
            let radicand = rho * rho - sin2_a;
            if !(radicand > 0.0) {
                return Err(NoSolution::TotalInternalReflection);
            }
            let lambda2 = cos_a / radicand.sqrt();
            axis_shift += thickness * (1.0 - lambda1 * lambda2);
            lateral_length += thickness * lambda2;
        }
        let bent = v + n * (cos_lambda1 - cos_a);
        let axis_point = self.centre + n * axis_shift;
        let origin = axis_point + bent * (lateral_length * inv_cos_a);
        // |bent|² = |v|² − cos²a + ρ_w² − sin²a = ρ_w²: normalise by 1/ρ_w with one Newton step of
        // 1/√ from there (y ← y(3 − |bent|² y²)/2), which removes the rounding as a division would.
        let y = self.inv_rho_water;
        let scale = y * (1.5 - 0.5 * bent.norm_squared() * y * y);
        Ok(Ray {
            origin,
            dir: Unit::new_unchecked(bent * scale),
        })
    }

    /// The ray in the water by tracing: intersect each plane in turn and apply vector Snell
    /// ([`refract`]). Independent of the λ relations; same result and errors as
    /// [`ray_in_water`](Self::ray_in_water).
    pub fn trace_ray_in_water(&self, dir_in_air: &Unit<Vector3<f64>>) -> Result<Ray, NoSolution> {
        let n = &self.normal;
        if !(n.dot(dir_in_air) > 0.0) {
            return Err(NoSolution::MissesInterface);
        }
        let mut point = self.centre;
        let mut dir = *dir_in_air;
        let mut index = self.index_air;
        let mut plane = self.air_distance; // offset of the next plane along n, from C_k
        let media = self
            .layers
            .iter()
            .map(|l| (l.thickness, l.index))
            .chain(std::iter::once((0.0, self.index_water)));
        for (thickness, next_index) in media {
            // Refraction keeps n·dir > 0, so every later plane is reached.
            point += dir.into_inner() * ((plane - n.dot(&(point - self.centre))) / n.dot(&dir));
            dir =
                refract(&dir, n, index / next_index).ok_or(NoSolution::TotalInternalReflection)?;
            index = next_index;
            plane += thickness;
        }
        Ok(Ray { origin: point, dir })
    }

    /// Solves how light from `point_in_master` reaches the camera centre.
    ///
    /// With z = n·(O − C_k), x = z − d_k − Σ tᵢ (the depth, must be > 0), r the distance of O from
    /// the line C_k + s·n and e the unit vector toward O across it, the path crosses the media
    /// m ∈ {air (d_k), layers (tᵢ), water (x)} and its lateral offsets add up to r. This is
    /// DESIGN.md's monotone equation f(u) = 0, u = sin a, written in the tangent v = tan θ_ref of the
    /// angle in one *reference* medium: with kₘ = μ_ref/μₘ (so sin θₘ = kₘ sin θ_ref),
    ///
    /// f(v) = Σₘ Lₘ T(v; kₘ) − r = 0,  T(v; k) = tan θₘ = k v / √(1 + (1 − k²) v²).
    ///
    /// Every T is increasing, so the root is unique. The reference is the medium whose term
    /// dominates f′, re-chosen at every iterate: its term is linear in v, so f is close to linear
    /// around the root. (With a fixed tan a, deep points seen at steep incidence need tens of
    /// Newton steps because the water term saturates; with a fixed water angle, near-grazing air
    /// rays do, because the air term blows up.) f is the lateral miss in metres whatever the
    /// variable, so switching only rescales f′ and the bracket. Bracket: [0, min(r / L_ref, v_max)]
    /// (f(r / L_ref) ≥ 0; v_max = 1/√(k² − 1) over media with k > 1, the critical angle). Start:
    /// the paraxial root, in the medium of largest L/μ. Newton keeps the bracket and bisects
    /// whenever a step would leave it, stops when |Δv| ≤ [`PROJECT_TOLERANCE`]·v, and gives up after
    /// [`PROJECT_MAX_ITERATIONS`]. r = 0 gives a = 0. Finally tan a = T(v; k_air).
    ///
    /// Errors: [`NoSolution::NotInWater`] when x ≤ 0 (the point is in the air or a layer, or behind
    /// the camera); [`NoSolution::NoConvergence`] if the iteration bound is hit;
    /// [`NoSolution::OutOfRange`] for a coordinate beyond ±[`MAX_INPUT`] or an overflow.
    pub fn air_path_to(&self, point_in_master: &Point3<f64>) -> Result<AirPath, NoSolution> {
        let (depth, lateral, r) = self.split(point_in_master)?;
        if r == 0.0 {
            return Ok(AirPath {
                dir_in_air: self.normal,
                tan_incidence: 0.0,
                depth,
                lateral_distance: r,
                iterations: 0,
            });
        }
        let (v, rho_ref, iterations) = self.solve_incidence(depth, r)?;
        let tau = tan_incidence_from(v, rho_ref);
        let dir = if tau > SCALE_ABOVE {
            // Near grazing, where τ² would overflow: the same direction divided by τ.
            let inv_tau = 1.0 / tau;
            (self.normal.into_inner() * inv_tau + lateral * (1.0 / r))
                / (1.0 + inv_tau * inv_tau).sqrt()
        } else {
            (self.normal.into_inner() + lateral * (tau / r)) / (1.0 + tau * tau).sqrt()
        };
        Ok(AirPath {
            dir_in_air: Unit::new_unchecked(dir),
            tan_incidence: tau,
            depth,
            lateral_distance: r,
            iterations,
        })
    }

    /// (x, O − C_k − z·n, r) of [`air_path_to`](Self::air_path_to): depth, lateral offset and its
    /// length. Errors: [`NoSolution::NotInWater`] when x ≤ 0.
    /// Errors: [`NoSolution::OutOfRange`] when a coordinate of the point is beyond ±[`MAX_INPUT`]
    /// (or NaN).
    #[inline]
    fn split(&self, point_in_master: &Point3<f64>) -> Result<(f64, Vector3<f64>, f64), NoSolution> {
        if !point_in_master.coords.iter().all(|c| c.abs() <= MAX_INPUT) {
            return Err(NoSolution::OutOfRange);
        }
        let n = self.normal.into_inner();
        let offset = point_in_master - self.centre;
        let z = n.dot(&offset);
        let depth = z - self.air_distance - self.layers_thickness;
        if !(depth > 0.0) {
            return Err(NoSolution::NotInWater);
        }
        let lateral = offset - n * z;
        Ok((depth, lateral, length(&lateral)))
    }

    /// The root of [`air_path_to`](Self::air_path_to)'s f for a point at `depth` and lateral
    /// distance `r` > 0, as (v, ρ_ref, iterations): v the tangent of the angle in the final
    /// reference medium, ρ_ref that medium's relative index (tan a = T(v; ρ_ref)).
    #[inline]
    fn solve_incidence(&self, depth: f64, r: f64) -> Result<(f64, f64, u32), NoSolution> {
        // The same code at a length known to the compiler for the common stacks (one layer, a
        // single interface), so that the loops over the media unroll.
        let media = self.media.as_slice();
        let root = if let Ok(media) = <&[Medium; 3]>::try_from(media) {
            PathMedia { media, depth }.solve(self.slowest, r)
        } else if let Ok(media) = <&[Medium; 2]>::try_from(media) {
            PathMedia { media, depth }.solve(self.slowest, r)
        } else {
            PathMedia { media, depth }.solve(self.slowest, r)
        }?;
        if r / self.air_distance > SCALE_ABOVE {
            // tan a may be beyond 1e150, where the iteration's squares overflow: accept the root
            // only if the lateral offsets, summed without squares of tan a, give r.
            let tau = tan_incidence_from(root.0, root.1);
            let others: f64 = self.media[WATER..]
                .iter()
                .enumerate()
                .map(|(i, m)| if i == 0 { depth } else { m.length } * m.inv_rho / ((1.0 / tau) * (1.0 / tau) + 1.0 - m.inv_rho * m.inv_rho).sqrt())
                .sum();
            let residual = self.air_distance * tau + others - r;
            if !(residual.abs() <= 1e-6 * r) {
                return Err(NoSolution::OutOfRange);
            }
        }
        Ok(root)
    }

    /// Forward projection: the (distorted) pixel at which `point_in_master` appears through the
    /// interface. Solves [`air_path_to`](Self::air_path_to), rotates the air ray into the camera,
    /// then pinhole and distortion.
    ///
    /// Errors: those of `air_path_to`; [`NoSolution::BehindCamera`] when the air ray points behind
    /// the image plane (a point behind the camera, or one so far to the side of a tilted port that
    /// only a near-grazing air ray reaches it); [`NoSolution::OutsideLens`] beyond the fold of the
    /// radial distortion, where the pixel would back-project to another ray;
    /// [`NoSolution::OutOfRange`] when the pixel overflows.
    #[inline]
    pub fn project(&self, point_in_master: &Point3<f64>) -> Result<Point2<f64>, NoSolution> {
        let (depth, lateral, r) = self.split(point_in_master)?;
        // Any positive multiple of the air direction gives the same pixel: with tan a = k v / √q,
        // q = 1 + (1 − k²) v², take r·√q·(n + lateral·tan a / r) = r√q·n + k v·lateral, rotated
        // term by term so that only the two scalars wait for the root finder.
        let dir_in_cam = if r == 0.0 {
            self.normal_in_cam
        } else {
            let lateral_in_cam = self.cam_from_master * lateral;
            let (v, k, _) = self.solve_incidence(depth, r)?;
            let root_q = (1.0 + (1.0 - k * k) * v * v).sqrt();
            let dir = self.normal_in_cam * (r * root_q) + lateral_in_cam * (k * v);
            if dir.iter().all(|c| c.is_finite()) {
                dir
            } else {
                // r·√q overflowed (a point ~1e300 m away): the same direction divided by r.
                self.normal_in_cam * root_q + lateral_in_cam * (k * v / r)
            }
        };
        if !dir_in_cam.iter().all(|c| c.is_finite()) {
            return Err(NoSolution::OutOfRange);
        }
        if !(dir_in_cam.z > 0.0) {
            return Err(NoSolution::BehindCamera);
        }
        let inv_z = 1.0 / dir_in_cam.z;
        let normalized = Vector2::new(dir_in_cam.x * inv_z, dir_in_cam.y * inv_z);
        if !(normalized.norm_squared() < self.fold_radius2) {
            return Err(NoSolution::OutsideLens);
        }
        let pixel = self.intrinsics.img_from_normalized(&normalized);
        if !(pixel.x.is_finite() && pixel.y.is_finite()) {
            return Err(NoSolution::OutOfRange);
        }
        Ok(pixel)
    }

    /// The Virtual Object Point of `point_in_master` for this camera (thesis ch. 4): where the
    /// backward extension of the air ray meets the object axis O + s·n. With a the angle of
    /// incidence found by [`air_path_to`](Self::air_path_to) and r the distance of O from the line
    /// C_k + s·n, the air ray reaches that axis at r / tan a along n from C_k, so
    /// x̌ = r / tan a − d_k − Σ tᵢ and Ǒ = A1 + x̌·n with A1 = O − x·n.
    ///
    /// This equals eq 4.8, x̌ = x/λ1 − Σ tᵢ (1 − λ2,ᵢ) (tested against it), but stays exact where
    /// the water ray grazes the port, where eq 4.8 amplifies the rounding of a; eq 4.8 is used on
    /// the axis line (r = 0), where it is the apparent depth.
    pub fn vop(&self, point_in_master: &Point3<f64>) -> Result<Vop, NoSolution> {
        let path = self.air_path_to(point_in_master)?;
        let tau = path.tan_incidence;
        let vop_distance = if tau > 0.0 {
            path.lateral_distance / tau - self.air_distance - self.layers_thickness
        } else {
            super::vop::virtual_from_real(
                path.depth,
                0.0,
                &self.layers,
                self.index_air,
                self.index_water,
            )
            .ok_or(NoSolution::TotalInternalReflection)?
        };
        let n = self.normal.into_inner();
        let vop = point_in_master + n * (vop_distance - path.depth);
        let result = Vop {
            depth: path.depth,
            vop_distance,
            vop,
            incidence: tau.atan(),
        };
        // Every number or none: an overflow anywhere is a rejection, never a partly NaN row.
        let all_finite = [
            result.depth,
            result.vop_distance,
            vop.x,
            vop.y,
            vop.z,
            result.incidence,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !all_finite {
            return Err(NoSolution::OutOfRange);
        }
        Ok(result)
    }
}

/// Index of the air in [`RefractiveCamera`]'s media.
pub(crate) const AIR: usize = 0;
/// Index of the water in [`RefractiveCamera`]'s media; the layers follow it.
pub(crate) const WATER: usize = 1;

/// A medium that a forward-projection path crosses, with the constants its root finder needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Medium {
    /// Length along the axis: d_k for the air, tᵢ for a layer; unused for the water, whose length
    /// is the depth of the point.
    pub(crate) length: f64,
    /// ρ = μ/μ_air.
    pub(crate) rho: f64,
    /// 1/ρ.
    pub(crate) inv_rho: f64,
    /// Critical-angle top of the bracket in this medium's variable: light must enter every medium,
    /// v < 1/√(k² − 1) for every k = ρ/ρₘ > 1 (∞ when there is none).
    pub(crate) critical_top: f64,
}

/// The media of the path to one point: a camera's media with the water as deep as the point.
#[derive(Debug, Clone, Copy)]
struct PathMedia<'a> {
    media: &'a [Medium],
    depth: f64,
}

impl PathMedia<'_> {
    /// Length along the axis of medium `i`.
    #[inline(always)]
    fn length(&self, i: usize) -> f64 {
        if i == WATER {
            self.depth
        } else {
            self.media[i].length
        }
    }

    /// The safeguarded Newton iteration of [`RefractiveCamera::air_path_to`] for lateral distance
    /// `r` > 0; `slowest` indexes the medium of smallest ρ. Returns (v, ρ_ref, iterations).
    #[inline(always)]
    fn solve(&self, slowest: usize, r: f64) -> Result<(f64, f64, u32), NoSolution> {
        // Start in the medium with the largest paraxial weight L/ρ, from the paraxial root.
        let mut reference = AIR;
        let mut reference_weight = self.length(AIR) * self.media[AIR].inv_rho;
        let mut paraxial_slope = 0.0;
        for (i, medium) in self.media.iter().enumerate() {
            let weight = self.length(i) * medium.inv_rho;
            paraxial_slope += weight;
            if weight > reference_weight {
                (reference, reference_weight) = (i, weight);
            }
        }
        // r·(1/…): the division need not wait for r's square root.
        let mut v = r * (1.0 / (paraxial_slope * self.media[reference].rho));
        let mut lo = 0.0;
        let mut hi = self.bracket_top(reference, r);
        if !(v > lo && v < hi) {
            v = 0.5 * (lo + hi);
        }
        // The slowest medium (smallest index) sets the critical-angle top of every other bracket.
        let slowest_rho = self.media[slowest].rho;
        for iteration in 1..=PROJECT_MAX_ITERATIONS {
            let (f, mut df, dominant) = self.incidence_equation(v, reference, r);
            if f < 0.0 {
                lo = v;
            } else if f > 0.0 {
                hi = v;
            } else if f == 0.0 {
                return Ok((v, self.media[reference].rho, iteration));
            } else {
                // NaN: v reached a critical-angle cap within rounding, or (a point more than 1e150
                // times farther to the side than the air layer is thick, tan a > 1e150) v²
                // overflowed. Never a silent root.
                return Err(if r / self.length(AIR) > SCALE_ABOVE {
                    NoSolution::OutOfRange
                } else {
                    NoSolution::NoConvergence
                });
            }
            if self.media[dominant].rho != self.media[reference].rho
                && self.resolves(reference, dominant, v)
            {
                self.reparametrise(
                    &mut reference,
                    dominant,
                    [&mut v, &mut lo, &mut hi],
                    &mut df,
                    r,
                );
            }
            let mut step = f / df;
            if v - step >= hi && slowest_rho != self.media[reference].rho {
                // The step leaves through the critical angle of the slowest medium: its term is
                // about to dominate, so continue in its angle, where that term is linear.
                self.reparametrise(
                    &mut reference,
                    slowest,
                    [&mut v, &mut lo, &mut hi],
                    &mut df,
                    r,
                );
                step = f / df;
            }
            if v == f64::INFINITY {
                // The iterate sat at the new medium's critical angle within rounding (it maps to
                // infinity: a point far to the side, seen at grazing incidence). Bisect, and test
                // convergence only where f was evaluated: a step from there says nothing here. If
                // the bottom also mapped beyond the top, f(0) = −r < 0 is the bracket's bottom.
                if !(lo < hi) {
                    lo = 0.0;
                }
                v = 0.5 * (lo + hi);
                continue;
            }
            // Converged: test before the bracket, since a step below half an ulp leaves v unchanged
            // and would otherwise read as a step outside the open bracket.
            if step.abs() <= PROJECT_TOLERANCE * v {
                return Ok((v - step, self.media[reference].rho, iteration));
            }
            let mut next = v - step;
            if !(next > lo && next < hi) {
                next = 0.5 * (lo + hi);
            }
            if hi - lo <= PROJECT_TOLERANCE * hi {
                return Ok((next, self.media[reference].rho, iteration));
            }
            v = next;
        }
        Err(if r / self.length(AIR) > SCALE_ABOVE {
            NoSolution::OutOfRange
        } else {
            NoSolution::NoConvergence
        })
    }

    /// f(v), f′(v) of [`RefractiveCamera::air_path_to`] in the variable of medium `reference`
    /// (T′(v; k) = k / (1 + (1 − k²) v²)^(3/2)), and the medium whose term contributes most to f′.
    #[inline(always)]
    fn incidence_equation(&self, v: f64, reference: usize, r: f64) -> (f64, f64, usize) {
        let v2 = v * v;
        let rho_ref = self.media[reference].rho;
        let (mut f, mut df) = (-r, 0.0);
        let (mut dominant, mut dominant_slope) = (AIR, 0.0);
        for (i, medium) in self.media.iter().enumerate() {
            let (lk, slope) = if i == reference {
                // k = 1: T(v; 1) = v.
                (self.length(i), self.length(i))
            } else {
                let k = rho_ref * medium.inv_rho;
                let q = 1.0 + (1.0 - k * k) * v2;
                // 1/√q as √q·(1/q): the root and the division run side by side.
                let inv_q = 1.0 / q;
                let lk = self.length(i) * k * (q.sqrt() * inv_q);
                (lk, lk * inv_q)
            };
            f += lk * v;
            df += slope;
            if slope > dominant_slope {
                (dominant, dominant_slope) = (i, slope);
            }
        }
        (f, df, dominant)
    }

    /// Upper end of the bracket in the variable of medium `reference`: f(r / L_ref) ≥ 0, capped by
    /// the critical angles.
    #[inline(always)]
    fn bracket_top(&self, reference: usize, r: f64) -> f64 {
        (r / self.length(reference)).min(self.media[reference].critical_top)
    }

    /// Whether the angle of medium `to` can carry the iterate `v` of medium `reference`: the map
    /// between the two angles keeps it to [`SWITCH_MAX_Q`]·ε relative. Its logarithmic slope is
    /// 1/q, q = 1 + (1 − k²)v², so coming back multiplies a rounding of the new variable by q.
    /// Far to the side, in the air's variable, the water's term still has the steepest slope
    /// while the water's angle is at its critical cap within rounding (q ≈ 1e48): switching
    /// there went back and forth without moving until the iteration bound.
    #[inline(always)]
    fn resolves(&self, reference: usize, to: usize, v: f64) -> bool {
        let k = self.media[reference].rho / self.media[to].rho;
        let q = 1.0 + (1.0 - k * k) * v * v;
        q > 0.0 && q <= SWITCH_MAX_Q
    }

    /// Moves the iteration from the angle of medium `reference` to that of medium `to`: f is the
    /// lateral miss in every variable; v and the bracket map through T(·; ρ_ref/ρ_to), and f′ is
    /// divided by T′ (chain rule). The mapped bracket top is capped by `to`'s own bound, and is
    /// that bound when no evaluation has lowered the old top yet.
    #[inline(never)]
    fn reparametrise(
        &self,
        reference: &mut usize,
        to: usize,
        [v, lo, hi]: [&mut f64; 3],
        df: &mut f64,
        r: f64,
    ) {
        let k = self.media[*reference].rho / self.media[to].rho;
        let map = |x: f64| {
            let q = 1.0 + (1.0 - k * k) * x * x;
            if q > 0.0 {
                k * x / q.sqrt()
            } else {
                f64::INFINITY
            }
        };
        let q = 1.0 + (1.0 - k * k) * *v * *v;
        *df /= k / (q * q.sqrt());
        (*v, *lo) = (map(*v), map(*lo));
        // A top that no evaluation has lowered is the old medium's own bound, often its critical
        // angle rounded down, whose image is a finite tangent short of a grazing root (a point
        // 1e10 m to the side stopped at tan a = 1.4e8 instead of 1.3e11): take the new medium's
        // own bound instead. A top some f(v) > 0 lowered maps to a point where f > 0 still.
        *hi = if *hi >= self.bracket_top(*reference, r) {
            self.bracket_top(to, r)
        } else {
            map(*hi).min(self.bracket_top(to, r))
        };
        *reference = to;
    }
}

/// The largest q = 1 + (1 − k²)v² at which the root finder moves from one medium's angle to
/// another's for a steeper term (`PathMedia::resolves`): coming back, a rounding of the new
/// variable grows by q, here to 1.1e-14, a tenth of [`PROJECT_TOLERANCE`].
pub(crate) const SWITCH_MAX_Q: f64 = 100.0;

/// Lengths above this are scaled by their largest component before squaring (three squares of
/// 1e150 stay far below f64's 1.8e308). Below it the plain Euclidean norm runs, bit for bit.
pub(crate) const SCALE_ABOVE: f64 = 1e150;

/// |v| without overflow of the squares for any finite v (hypot-like: scaled by the largest
/// component when that exceeds [`SCALE_ABOVE`]). Twin of `length_scaled` in shaders/lib/air_path.wgsl.
#[inline]
fn length(v: &Vector3<f64>) -> f64 {
    let largest = v.amax();
    if largest > SCALE_ABOVE {
        largest * (v * (1.0 / largest)).norm()
    } else {
        v.norm()
    }
}

/// tan a = T(v; k_air) from the tangent v of the angle in the reference medium of index ρ_ref.
#[inline]
fn tan_incidence_from(v: f64, rho_ref: f64) -> f64 {
    let k = rho_ref;
    k * v / (1.0 + (1.0 - k * k) * v * v).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Interface, Layer, PinholeCamera, Rig, RigCamera};

    /// The example rig's port (8° tilt, glass), an undistorted master camera.
    fn camera() -> RefractiveCamera {
        let intrinsics =
            PinholeCamera::new("left", 1280, 1024, 864.91, 864.91, 640.0, 512.0, [0.0; 5]).unwrap();
        let master =
            RigCamera::new("left", intrinsics, Matrix3::identity(), Vector3::zeros()).unwrap();
        let layers = vec![Layer {
            thickness: 0.014,
            index: 1.473,
        }];
        let interface =
            Interface::new(Vector3::new(0.1, 0.1, 1.0), 0.02, layers, 1.003, 1.333).unwrap();
        Rig::new(vec![master], interface)
            .unwrap()
            .refractive_camera(0)
    }

    /// Far from the port (depth ≫ d_k + Σtᵢ) the path is the water ray alone: with θw the angle
    /// of the point from the axis, sin a = ρw sin θw, and the VOP distance is r / tan a. This
    /// limit is the oracle for points 1e20…1e299 m away, where the air and glass (0.034 m) change
    /// the angle by less than 1e-20 relative; it needs no squares of huge numbers.
    #[test]
    fn huge_coordinates_give_every_number_or_out_of_range() {
        let camera = camera();
        let n = camera.normal().into_inner();
        let direction = Vector3::new(0.1, 0.05, 1.0);
        let z = n.dot(&direction);
        let lateral = (direction - n * z).norm(); // per unit of scale: r / s
        let theta_w = (lateral / z).atan();
        let sin_a = camera.relative_index_water() * theta_w.sin();
        let (a, tan_a) = (sin_a.asin(), sin_a / (1.0 - sin_a * sin_a).sqrt());
        for exponent in [20, 100, 154, 155, 160, 200, 250, 299] {
            let s = 10f64.powi(exponent);
            let vop = camera
                .vop(&Point3::from(direction * s))
                .unwrap_or_else(|e| panic!("1e{exponent}: {e}"));
            assert!(
                (vop.incidence - a).abs() < 1e-12,
                "1e{exponent}: incidence {} vs {a}",
                vop.incidence
            );
            assert!(
                (vop.depth / (z * s) - 1.0).abs() < 1e-12,
                "1e{exponent}: depth {}",
                vop.depth
            );
            let expected = lateral * s / tan_a;
            assert!(
                (vop.vop_distance / expected - 1.0).abs() < 1e-12,
                "1e{exponent}: x̌ {} vs {expected}",
                vop.vop_distance
            );
            let pixel = camera
                .project(&Point3::from(direction * s))
                .unwrap_or_else(|e| panic!("1e{exponent}: {e}"));
            let reference = camera.project(&Point3::from(direction * 1e20)).unwrap();
            assert!(
                (pixel - reference).norm() < 1e-6,
                "1e{exponent}: pixel {pixel} vs {reference}"
            );
        }
        // Far down the optical axis: a finite pixel, not "behind the camera".
        let far = camera.project(&Point3::new(0.0, 0.0, 1e300)).unwrap();
        let reference = camera.project(&Point3::new(0.0, 0.0, 1e20)).unwrap();
        assert!((far - reference).norm() < 1e-6, "{far} vs {reference}");
    }

    #[test]
    fn inputs_beyond_the_range_are_out_of_range() {
        let camera = camera();
        for point in [
            [0.0, 0.0, 2e300],
            [-1e301, 0.0, 1.0],
            [f64::MAX, f64::MAX, f64::MAX],
            [f64::NAN, 0.0, 1.0],
            [0.0, 0.0, f64::INFINITY],
        ] {
            let point = Point3::from(point);
            assert_eq!(camera.vop(&point), Err(NoSolution::OutOfRange), "{point}");
            assert_eq!(
                camera.project(&point),
                Err(NoSolution::OutOfRange),
                "{point}"
            );
            assert_eq!(
                camera.air_path_to(&point),
                Err(NoSolution::OutOfRange),
                "{point}"
            );
        }
    }

    /// A point far to the side of a tilted port is seen at grazing incidence; its VOP distance
    /// tends to a limit as the point recedes along a fixed direction (here 0.0051781 m). From 1e10
    /// to 1e40 m every scale gives that limit: the root finder's iterate sits at the water's
    /// critical angle within rounding and must continue in the air's variable (it gave up, or
    /// returned τ = ∞ and a wrong x̌ = −d_k, before).
    #[test]
    fn far_to_the_side_points_reach_the_grazing_limit() {
        let intrinsics =
            PinholeCamera::new("left", 1280, 1024, 864.91, 864.91, 640.0, 512.0, [0.0; 5]).unwrap();
        let master =
            RigCamera::new("left", intrinsics, Matrix3::identity(), Vector3::zeros()).unwrap();
        let interface =
            Interface::new(Vector3::new(0.12, -0.08, 1.0), 0.03, vec![], 1.0, 1.333).unwrap();
        let camera = Rig::new(vec![master], interface)
            .unwrap()
            .refractive_camera(0);
        let limit = camera
            .vop(&Point3::new(1e10, 0.0, 1e8))
            .unwrap()
            .vop_distance;
        for exponent in [12, 20, 30, 38, 40, 60, 100, 140] {
            let s = 10f64.powi(exponent);
            let vop = camera
                .vop(&Point3::new(100.0 * s, 0.0, s))
                .unwrap_or_else(|e| panic!("1e{exponent}: {e}"));
            assert!(
                (vop.vop_distance - limit).abs() < 1e-9 * limit,
                "1e{exponent}: x̌ {} vs {limit}",
                vop.vop_distance
            );
            assert!(
                (vop.incidence - std::f64::consts::FRAC_PI_2).abs() < 1e-9,
                "1e{exponent}"
            );
        }
        // tan a beyond 1e150 (r / d_k): the limit, or no number at all (never another number).
        for exponent in [160, 200, 290] {
            let point = Point3::new(100.0 * 10f64.powi(exponent), 0.0, 10f64.powi(exponent));
            match camera.vop(&point) {
                Ok(vop) => assert!(
                    (vop.vop_distance - limit).abs() < 1e-9 * limit,
                    "1e{exponent}: x̌ {}",
                    vop.vop_distance
                ),
                Err(e) => assert_eq!(e, NoSolution::OutOfRange, "1e{exponent}"),
            }
        }
    }

    /// A point 1e10 m to the side of a steep port (25°, air index 1.0003): the water ray is at its
    /// critical angle within far less than an ulp, so the root is found in the air's variable,
    /// tan a ≈ 1.3e11. The iteration used to carry the water's critical cap, rounded down, into
    /// that variable as a finite top (tan a = 1.4e8) and stop there: x̌ = 66 m for 0.0285 m.
    /// Reference: the same equation solved by bisection in mpmath at 60 digits (n normalised
    /// exactly): x̌ = 0.028540042696398400340, tan a = 128514975477.41727555.
    /// Bound: x̌ = r/τ − d_k with r/τ = 2.6·x̌, and τ is known to the solver's stopping rule
    /// (|Δv| ≤ PROJECT_TOLERANCE·v, Newton quadratic: far below) plus rounding: 2.6 × 1e-13
    /// relative at most, so 1e-12.
    #[test]
    fn grazing_roots_beyond_the_water_cap_are_found_in_the_air_variable() {
        let intrinsics =
            PinholeCamera::new("left", 1280, 1024, 864.91, 866.2, 641.3, 509.8, [0.0; 5]).unwrap();
        let master =
            RigCamera::new("left", intrinsics, Matrix3::identity(), Vector3::zeros()).unwrap();
        let interface =
            Interface::new(Vector3::new(0.35, 0.3, 1.0), 0.045, vec![], 1.0003, 1.34).unwrap();
        let camera = Rig::new(vec![master], interface)
            .unwrap()
            .refractive_camera(0);
        let point = Point3::new(1e10, 0.0, 1e8);
        let path = camera.air_path_to(&point).unwrap();
        let tau = 128_514_975_477.417_28;
        assert!(
            (path.tan_incidence - tau).abs() <= 1e-12 * tau,
            "tan a {} vs {tau}",
            path.tan_incidence
        );
        let expected = 0.028_540_042_696_398_4;
        let vop = camera.vop(&point).unwrap().vop_distance;
        assert!(
            (vop - expected).abs() <= 1e-12 * expected,
            "x̌ {vop} vs {expected}"
        );
    }

    #[test]
    fn scaled_length_is_the_norm() {
        let v = Vector3::new(3.0, -4.0, 12.0);
        assert_eq!(length(&v), 13.0);
        for s in [1e150, 1e200, 1e300] {
            assert!((length(&(v * s)) / (13.0 * s) - 1.0).abs() < 1e-15, "{s}");
        }
    }
}
