//! Lane twin of [`RefractiveCamera`]: back-projection (pixel → ray in the water) and forward
//! projection (point in the water → pixel) for [`LANES`](super::f64s::LANES) rows at once.
//!
//! Each function follows its scalar twin line by line, in the same order of operations, so a lane
//! rounds as the scalar code does. Where the scalar code branches, every lane computes and a
//! [`Mask`] selects. Branches that only rare rows take (a second undistortion run, a point more
//! than 1e150 times farther to the side than the air layer is thick, an iterate at a critical angle
//! within rounding) are not repeated here: such a lane is returned in `scalar`, and the caller
//! runs the scalar model for that row, which is then the answer by definition.

use super::camera::Distortion;
use super::f64s::{F64s, Mask, Vec3s, scaled};
use crate::model::refractive_camera::{AIR, Medium, SCALE_ABOVE, WATER};
use crate::model::refractive_camera::{PROJECT_MAX_ITERATIONS, PROJECT_TOLERANCE, SWITCH_MAX_Q};
use crate::model::{MAX_INPUT, NoSolution, RefractiveCamera};

/// A status code per lane: 0 = an answer, else the [`NoSolution`] code of the first reason found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Status(pub [u32; super::f64s::LANES]);

impl Status {
    /// Every lane answered so far.
    #[inline(always)]
    pub fn ok() -> Self {
        Self([0; super::f64s::LANES])
    }

    /// Records `reason` in the lanes of `mask` that have no reason yet: the scalar code returns at
    /// its first failing test, so the first reason set is the one it reports.
    #[inline(always)]
    pub fn fail(&mut self, mask: Mask, reason: NoSolution) {
        for (s, &m) in self.0.iter_mut().zip(&mask.0) {
            if m && *s == 0 {
                *s = reason.code();
            }
        }
    }

    /// Lanes still without a reason.
    #[inline(always)]
    pub fn answered(&self) -> Mask {
        Mask(self.0.map(|s| s == 0))
    }
}

/// Rays in the water for a block of pixels.
#[derive(Debug, Clone, Copy)]
pub struct Rays {
    /// Origins on the outer interface, master frame.
    pub origin: Vec3s,
    /// Unit directions in the water, master frame.
    pub dir: Vec3s,
    /// The reason per lane (0: an answer).
    pub status: Status,
    /// Lanes whose answer must come from the scalar model.
    pub scalar: Mask,
}

/// Pixels for a block of points.
#[derive(Debug, Clone, Copy)]
pub struct Pixels {
    /// u, pixels.
    pub u: F64s,
    /// v, pixels.
    pub v: F64s,
    /// The reason per lane (0: an answer).
    pub status: Status,
    /// Lanes whose answer must come from the scalar model.
    pub scalar: Mask,
}

/// VOPs for a block of points.
#[derive(Debug, Clone, Copy)]
pub struct Vops {
    /// depth, vop_distance, vop x, y, z, incidence (radians), as the batch rows of `vop`.
    pub values: [F64s; 6],
    /// The reason per lane (0: an answer).
    pub status: Status,
    /// Lanes whose answer must come from the scalar model.
    pub scalar: Mask,
}

/// A block of rays in the water with the incidence they left the air at.
#[derive(Debug, Clone, Copy)]
pub struct WaterRay {
    /// Origins on the outer interface, master frame.
    pub origin: Vec3s,
    /// Unit directions in the water, master frame.
    pub dir: Vec3s,
    /// 1 / cos a, a the angle of incidence from the air.
    pub inv_cos_a: F64s,
}

/// Most Newton steps of [`CameraLanes::project_near`] before it leaves a lane to
/// [`CameraLanes::project`]; `NEAR_MAX_ITERATIONS` in `shaders/lib/air_path.wgsl`.
pub const NEAR_MAX_ITERATIONS: u32 = 16;

/// The constants of one [`RefractiveCamera`] in the form the lanes use.
#[derive(Debug, Clone)]
pub struct CameraLanes<'a> {
    cx: f64,
    cy: f64,
    fx: f64,
    fy: f64,
    inv_fx: f64,
    inv_fy: f64,
    distortion: Distortion,
    distorts: bool,
    fold_radius2: f64,
    /// Columns of R_kᵀ.
    master_from_cam: [[f64; 3]; 3],
    /// Rows of R_k.
    cam_from_master: [[f64; 3]; 3],
    centre: [f64; 3],
    normal: [f64; 3],
    normal_in_cam: [f64; 3],
    air_distance: f64,
    layers_thickness: f64,
    rho_water: f64,
    inv_rho_water: f64,
    media: &'a [Medium],
    slowest: usize,
    /// No medium is less dense than the air (every ρ ≥ 1): [`project_near`](Self::project_near)'s
    /// iteration holds.
    dense: bool,
}

impl<'a> CameraLanes<'a> {
    /// The constants of `camera`.
    pub fn new(camera: &'a RefractiveCamera) -> Self {
        let i = camera.intrinsics();
        let m = camera.master_from_cam();
        let r = camera.cam_from_master();
        let (media, slowest) = camera.path_media();
        Self {
            cx: i.cx,
            cy: i.cy,
            fx: i.fx,
            fy: i.fy,
            inv_fx: 1.0 / i.fx,
            inv_fy: 1.0 / i.fy,
            distortion: Distortion::new(i),
            distorts: i.has_distortion(),
            fold_radius2: camera.fold_radius2(),
            master_from_cam: [0, 1, 2].map(|c| [m[(0, c)], m[(1, c)], m[(2, c)]]),
            cam_from_master: [0, 1, 2].map(|row| [r[(row, 0)], r[(row, 1)], r[(row, 2)]]),
            centre: camera.centre().coords.into(),
            normal: camera.normal().into_inner().into(),
            normal_in_cam: (*camera.normal_in_cam()).into(),
            air_distance: camera.air_distance(),
            layers_thickness: camera.layers_thickness(),
            rho_water: camera.relative_index_water(),
            inv_rho_water: 1.0 / camera.relative_index_water(),
            media,
            slowest,
            dense: media.iter().all(|m| m.rho >= 1.0),
        }
    }

    /// Newton steps of the undistortion for a block of raw pixels (0 without distortion): what
    /// `flatport bench` counts for the back-projection's floor.
    pub fn undistortion_steps(&self, u: F64s, v: F64s) -> u32 {
        if !self.distorts {
            return 0;
        }
        let (xd, yd) = self.normalized_distorted(u, v);
        self.distortion
            .undistort_in_fold(xd, yd, self.fold_radius2)
            .3
    }

    /// The distorted normalised coordinates ((u − c_x)/f_x, (v − c_y)/f_y) of raw pixels.
    #[inline(always)]
    fn normalized_distorted(&self, u: F64s, v: F64s) -> (F64s, F64s) {
        ((u - self.cx) * self.inv_fx, (v - self.cy) * self.inv_fy)
    }

    /// [`RefractiveCamera::backproject`] (with the row checks of the CPU engine: an input beyond
    /// ±[`MAX_INPUT`] is [`NoSolution::OutOfRange`]) for a block of raw pixels.
    #[inline(always)]
    pub fn backproject(&self, u: F64s, v: F64s) -> Rays {
        let mut status = Status::ok();
        status.fail(
            !(u.within(MAX_INPUT) & v.within(MAX_INPUT)),
            NoSolution::OutOfRange,
        );
        // dir_in_air_from_img
        let (xd, yd) = self.normalized_distorted(u, v);
        let (x, y, scalar) = if self.distorts {
            let (x, y, ok, _) = self.distortion.undistort_in_fold(xd, yd, self.fold_radius2);
            (x, y, status.answered().and_not(ok))
        } else {
            (xd, yd, Mask::splat(false))
        };
        let radius2 = x * x + y * y;
        status.fail(
            !radius2.lt(F64s::splat(self.fold_radius2)),
            NoSolution::OutsideLens,
        );
        let [c0, c1, c2] = self.master_from_cam;
        let scale = 1.0 / (radius2 + 1.0).sqrt();
        let dir_in_air = Vec3s {
            x: (c0[0] * x + c1[0] * y + c2[0]) * scale,
            y: (c0[1] * x + c1[1] * y + c2[1]) * scale,
            z: (c0[2] * x + c1[2] * y + c2[2]) * scale,
        };
        let (origin, dir) = self.ray_in_water(dir_in_air, &mut status);
        Rays {
            origin,
            dir,
            status,
            scalar,
        }
    }

    /// [`RefractiveCamera::ray_in_water`] for a block of unit air directions (master frame):
    /// origin on the outer interface and unit direction in the water, the reasons recorded in
    /// `status` (with the CPU engine's check that the results are finite).
    #[inline(always)]
    pub fn ray_in_water(&self, dir_in_air: Vec3s, status: &mut Status) -> (Vec3s, Vec3s) {
        let ray = self.ray_in_water_at_incidence(dir_in_air, status);
        (ray.origin, ray.dir)
    }

    /// [`ray_in_water`](Self::ray_in_water) with the incidence it computed on the way.
    #[inline(always)]
    pub fn ray_in_water_at_incidence(&self, dir_in_air: Vec3s, status: &mut Status) -> WaterRay {
        let n = Vec3s::splat(self.normal);
        let cos_a = n.dot(dir_in_air);
        status.fail(!cos_a.gt(F64s::splat(0.0)), NoSolution::MissesInterface);
        let sin2_a = (1.0 - cos_a * cos_a).max(F64s::splat(0.0));
        let water_radicand = self.rho_water * self.rho_water - sin2_a;
        status.fail(
            !water_radicand.gt(F64s::splat(0.0)),
            NoSolution::TotalInternalReflection,
        );
        let inv_cos_a = 1.0 / cos_a;
        let cos_lambda1 = water_radicand.sqrt();
        let lambda1 = cos_lambda1 * inv_cos_a;
        let mut axis_shift = self.air_distance * (1.0 - lambda1);
        let mut lateral_length = F64s::splat(self.air_distance);
        for &Medium {
            length: thickness,
            rho,
            ..
        } in &self.media[WATER + 1..]
        {
            let radicand = rho * rho - sin2_a;
            status.fail(
                !radicand.gt(F64s::splat(0.0)),
                NoSolution::TotalInternalReflection,
            );
            let lambda2 = cos_a / radicand.sqrt();
            axis_shift += thickness * (1.0 - lambda1 * lambda2);
            lateral_length += thickness * lambda2;
        }
        let bent = dir_in_air + scaled(self.normal, cos_lambda1 - cos_a);
        let axis_point = Vec3s::splat(self.centre) + scaled(self.normal, axis_shift);
        let origin = axis_point + bent.scale(lateral_length * inv_cos_a);
        let y = self.inv_rho_water;
        let scale = y * (1.5 - 0.5 * bent.norm_squared() * y * y);
        let dir = bent.scale(scale);
        status.fail(
            !(origin.is_finite() & dir.is_finite()),
            NoSolution::OutOfRange,
        );
        WaterRay {
            origin,
            dir,
            inv_cos_a,
        }
    }

    /// `split` and `solve_incidence` of [`RefractiveCamera::air_path_to`] for a block of points in
    /// the master frame, with the CPU engine's check of the inputs' range.
    #[inline(always)]
    fn air_path(&self, point: Vec3s) -> AirPathLanes {
        let zero = F64s::splat(0.0);
        let mut status = Status::ok();
        status.fail(
            !(point.x.within(MAX_INPUT) & point.y.within(MAX_INPUT) & point.z.within(MAX_INPUT)),
            NoSolution::OutOfRange,
        );
        let n = Vec3s::splat(self.normal);
        let offset = point - Vec3s::splat(self.centre);
        let z = n.dot(offset);
        let depth = z - self.air_distance - self.layers_thickness;
        status.fail(!depth.gt(zero), NoSolution::NotInWater);
        let lateral = offset - scaled(self.normal, z);
        let largest = lateral.x.abs().max(lateral.y.abs()).max(lateral.z.abs());
        // Lengths beyond 1e150 (scaled before squaring) and tan a beyond 1e150 take the scalar path.
        let scalar = status.answered()
            & (largest.gt(F64s::splat(SCALE_ABOVE))
                | (largest / self.air_distance).gt(F64s::splat(SCALE_ABOVE * 0.5)));
        let r = lateral.norm_squared().sqrt();
        let on_axis = r.eq(zero);
        // Solve where a lane still needs it; lanes already decided get a harmless r.
        let solving = status.answered().and_not(scalar).and_not(on_axis);
        let root = PathLanes {
            media: self.media,
            depth: solving.select(depth, F64s::splat(1.0)),
        }
        .solve(self.slowest, solving.select(r, F64s::splat(1.0)), solving);
        let scalar = scalar | (solving & root.scalar);
        AirPathLanes {
            depth,
            lateral,
            r,
            on_axis,
            v: root.v,
            k: root.rho_ref,
            solving,
            status,
            scalar,
        }
    }

    /// [`RefractiveCamera::vop`] (with the CPU engine's row checks) for a block of points in the
    /// master frame: depth, x̌, the VOP's xyz and the angle of incidence, per lane. A point on the
    /// camera's axis line (tan a = 0, where x̌ is eq 4.8's apparent depth) is left to the scalar
    /// model.
    #[inline(always)]
    pub fn vop(&self, point: Vec3s) -> Vops {
        let zero = F64s::splat(0.0);
        let AirPathLanes {
            depth,
            r,
            on_axis,
            v,
            k,
            mut status,
            mut scalar,
            ..
        } = self.air_path(point);
        let tau = k * v / (1.0 + (1.0 - k * k) * v * v).sqrt();
        scalar = scalar | (status.answered() & (on_axis | !tau.gt(zero)));
        let vop_distance = r / tau - self.air_distance - self.layers_thickness;
        let shift = vop_distance - depth;
        let vop = point + scaled(self.normal, shift);
        let incidence = F64s(tau.0.map(f64::atan));
        let values = [depth, vop_distance, vop.x, vop.y, vop.z, incidence];
        let finite = values
            .iter()
            .fold(Mask::splat(true), |all, v| all & v.is_finite());
        status.fail(!finite, NoSolution::OutOfRange);
        Vops {
            values,
            status,
            scalar,
        }
    }

    /// [`RefractiveCamera::project`] (with the CPU engine's row checks) for a block of points in
    /// the master frame.
    #[inline(always)]
    pub fn project(&self, point: Vec3s) -> Pixels {
        let AirPathLanes {
            depth: _,
            lateral,
            r,
            on_axis,
            v,
            k,
            solving,
            mut status,
            mut scalar,
        } = self.air_path(point);
        let lateral_in_cam = self.in_cam(lateral);
        let root_q = (1.0 + (1.0 - k * k) * v * v).sqrt();
        let solved = scaled(self.normal_in_cam, r * root_q) + lateral_in_cam.scale(k * v);
        // r·√q overflowing (a point ~1e300 m away) takes the scalar path.
        scalar = scalar | (solving & !solved.is_finite());
        let dir = Vec3s::select(on_axis, Vec3s::splat(self.normal_in_cam), solved);
        let (u, v) = self.pixel_along(dir, &mut status);
        Pixels {
            u,
            v,
            status,
            scalar,
        }
    }

    /// R_k·v: a master-frame vector in the camera frame.
    #[inline(always)]
    fn in_cam(&self, v: Vec3s) -> Vec3s {
        let [r0, r1, r2] = self.cam_from_master;
        Vec3s {
            x: r0[0] * v.x + r0[1] * v.y + r0[2] * v.z,
            y: r1[0] * v.x + r1[1] * v.y + r1[2] * v.z,
            z: r2[0] * v.x + r2[1] * v.y + r2[2] * v.z,
        }
    }

    /// The pixel of the air ray along `dir` (camera frame, any length), the reasons recorded in
    /// `status`: the tail of [`RefractiveCamera::project`].
    #[inline(always)]
    fn pixel_along(&self, dir: Vec3s, status: &mut Status) -> (F64s, F64s) {
        status.fail(!dir.is_finite(), NoSolution::OutOfRange);
        status.fail(!dir.z.gt(F64s::splat(0.0)), NoSolution::BehindCamera);
        let inv_z = 1.0 / dir.z;
        let (x, y) = (dir.x * inv_z, dir.y * inv_z);
        status.fail(
            !(x * x + y * y).lt(F64s::splat(self.fold_radius2)),
            NoSolution::OutsideLens,
        );
        let (xd, yd) = if self.distorts {
            let d = self.distortion.distort_with_jacobian(x, y);
            (d.x, d.y)
        } else {
            (x, y)
        };
        let (u, v) = (self.fx * xd + self.cx, self.fy * yd + self.cy);
        status.fail(!(u.is_finite() & v.is_finite()), NoSolution::OutOfRange);
        (u, v)
    }

    /// The forward projection of points seen near known air rays (a fitted board corner near its
    /// observed ray), without [`project`](Self::project)'s safeguards: Newton's iteration on
    /// f(x) = d_k x + Σₘ Lₘ T(x; 1/ρₘ) − r in x = tan a (the water as deep as the point, then the
    /// layers), from `tan_start`, the tan a of the ray each point is seen near. Where no medium is
    /// less dense than air every term is increasing and concave in x, so after the first step the
    /// iterates approach the root from below, with no bracket to keep; from a start within a few
    /// pixels two or three steps reach [`PROJECT_TOLERANCE`]. The twin of `project_near_pair` in
    /// `shaders/lib/air_path.wgsl`: the same start, iteration and stop on the step; its
    /// quadratic-model stop is tighter (within rounding, where the shader's f32 rule allows half
    /// the tolerance), it evaluates T with a square root and a division where the shader
    /// uses 1/√q, and it leaves a point not in the water to `project` where the shader answers it
    /// (`project`'s first test; here a settled lane has a pixel, which its callers rely on).
    ///
    /// Returns the pixels and the lanes it `settled`; every other lane (a medium less dense than
    /// air, a point out of range or not in the water, a grazing ray, an iteration that does not
    /// settle within [`NEAR_MAX_ITERATIONS`], a pixel with a reason) must take
    /// [`project`](Self::project), which decides. A settled lane's pixel is `project`'s up to
    /// rounding (the same root, by another path).
    #[inline(always)]
    pub fn project_near(&self, point: Vec3s, tan_start: F64s) -> (Pixels, Mask) {
        let zero = F64s::splat(0.0);
        let n = Vec3s::splat(self.normal);
        let offset = point - Vec3s::splat(self.centre);
        let z = n.dot(offset);
        let depth = z - self.air_distance - self.layers_thickness;
        let lateral = offset - scaled(self.normal, z);
        let r = lateral.norm_squared().sqrt();
        let in_range =
            point.x.within(MAX_INPUT) & point.y.within(MAX_INPUT) & point.z.within(MAX_INPUT);
        // Beyond SCALE_ABOVE the squares of r and tan a overflow: `project` scales them.
        let moderate = r.lt(F64s::splat(SCALE_ABOVE))
            & (r / self.air_distance).lt(F64s::splat(SCALE_ABOVE * 0.5));
        let mut active = Mask::splat(self.dense) & in_range & depth.gt(zero) & moderate;
        let mut settled = Mask::splat(false);
        let mut x = tan_start.max(zero);
        let mut tau = zero;
        for _ in 0..NEAR_MAX_ITERATIONS {
            if !active.any() {
                break;
            }
            // T(x; k) = k x / √q, T′ = k / √q³, T″ = −3 (1 − k²) x T′ / q, q = 1 + (1 − k²) x².
            let mut f = self.air_distance * x - r;
            let mut df = F64s::splat(self.air_distance);
            let mut d2f = zero;
            for (i, medium) in self.media.iter().enumerate().skip(WATER) {
                let length = if i == WATER {
                    depth
                } else {
                    F64s::splat(medium.length)
                };
                let k = medium.inv_rho;
                let q = 1.0 + (1.0 - k * k) * x * x;
                let root_q = q.sqrt();
                let inv_q_root_q = 1.0 / (q * root_q);
                let slope = length * k * inv_q_root_q;
                f += slope * q * x;
                df += slope;
                d2f += slope * ((k * k - 1.0) * 3.0) * x * (inv_q_root_q * root_q);
            }
            let step = f / df;
            // Done when the step is within the tolerance (as `project`), or when the error left
            // after the step, by the quadratic model |f″| step² / 2f′, is within rounding (ε x:
            // `project`'s last step, under the tolerance, leaves an error of that order; the
            // shader's f32 rule allows half the tolerance). The model holds where f″ barely
            // changes over the step (|f″| grows with x from 0): steps under 1 % of x.
            let modelled =
                step.abs().le(0.01 * x) & (d2f.abs() * step * step).le(2.0 * f64::EPSILON * x * df);
            let done = active & (step.abs().le(PROJECT_TOLERANCE * x) | modelled);
            tau = done.select(x - step, tau);
            settled = settled | done;
            active = active.and_not(done);
            x = (x - step).max(zero);
        }
        // n·r + lateral·tan a: the air direction times r√(1 + tan² a); n itself on the axis.
        let on_axis = r.eq(zero);
        let along = Vec3s::select(on_axis, n, n.scale(r) + lateral.scale(tau));
        let mut status = Status::ok();
        let (u, v) = self.pixel_along(self.in_cam(along), &mut status);
        let settled = settled & status.answered();
        let pixels = Pixels {
            u,
            v,
            status,
            scalar: Mask::splat(false),
        };
        (pixels, settled)
    }
}

/// [`RefractiveCamera::air_path_to`] for a block of points, up to the root of its equation.
struct AirPathLanes {
    /// x, the depth beyond the outer interface.
    depth: F64s,
    /// O − C_k − z·n and its length r.
    lateral: Vec3s,
    r: F64s,
    /// Lanes with r = 0 (no root to find: the path runs along n).
    on_axis: Mask,
    /// The root v in the variable of the medium of relative index k (lanes of `solving`).
    v: F64s,
    k: F64s,
    /// Lanes whose root was found here.
    solving: Mask,
    status: Status,
    /// Lanes whose answer must come from the scalar model.
    scalar: Mask,
}

/// The root of the forward projection for a block: v per lane in the variable of medium ρ_ref.
#[derive(Debug, Clone, Copy)]
struct Root {
    v: F64s,
    rho_ref: F64s,
    /// Lanes the scalar solver must take (a NaN equation, an iterate at a critical angle within
    /// rounding, or the iteration bound: the scalar code decides what they are).
    scalar: Mask,
}

/// Lane twin of the scalar `PathMedia`: a camera's media with the water as deep as each lane's point.
struct PathLanes<'a> {
    media: &'a [Medium],
    depth: F64s,
}

/// The lane of `table[index[l]]` per lane, `index` holding small whole numbers.
#[inline(always)]
fn pick(index: F64s, table: impl Iterator<Item = F64s>) -> F64s {
    let mut out = F64s::splat(f64::NAN);
    for (i, value) in table.enumerate() {
        out = index.eq(F64s::splat(i as f64)).select(value, out);
    }
    out
}

impl PathLanes<'_> {
    #[inline(always)]
    fn length(&self, i: usize) -> F64s {
        if i == WATER {
            self.depth
        } else {
            F64s::splat(self.media[i].length)
        }
    }

    #[inline(always)]
    fn lengths(&self) -> impl Iterator<Item = F64s> + '_ {
        (0..self.media.len()).map(|i| self.length(i))
    }

    #[inline(always)]
    fn constants(&self, f: fn(&Medium) -> f64) -> impl Iterator<Item = F64s> + '_ {
        self.media.iter().map(move |m| F64s::splat(f(m)))
    }

    /// `PathMedia::bracket_top` per lane: min(r / L_ref, critical top of ref).
    #[inline(always)]
    fn bracket_top(&self, reference: F64s, r: F64s) -> F64s {
        (r / pick(reference, self.lengths()))
            .min(pick(reference, self.constants(|m| m.critical_top)))
    }

    /// `PathMedia::solve` for the lanes of `active`: the same start, Newton steps, bracket,
    /// re-parametrisations and stopping rules, every lane until the slowest is done.
    #[inline(always)]
    fn solve(&self, slowest: usize, r: F64s, mut active: Mask) -> Root {
        let zero = F64s::splat(0.0);
        let mut reference = F64s::splat(AIR as f64);
        let mut reference_weight = self.length(AIR) * self.media[AIR].inv_rho;
        let mut paraxial_slope = zero;
        for (i, medium) in self.media.iter().enumerate() {
            let weight = self.length(i) * medium.inv_rho;
            paraxial_slope += weight;
            let heavier = weight.gt(reference_weight);
            reference = heavier.select(F64s::splat(i as f64), reference);
            reference_weight = heavier.select(weight, reference_weight);
        }
        let mut rho_ref = pick(reference, self.constants(|m| m.rho));
        let mut v = r * (1.0 / (paraxial_slope * rho_ref));
        let mut lo = zero;
        let mut hi = self.bracket_top(reference, r);
        v = (v.gt(lo) & v.lt(hi)).select(v, 0.5 * (lo + hi));
        let slowest_rho = self.media[slowest].rho;
        let (mut root, mut root_rho) = (v, rho_ref);
        let mut scalar = Mask::splat(false);
        for _ in 1..=PROJECT_MAX_ITERATIONS {
            if !active.any() {
                break;
            }
            let (f, mut df, dominant) = self.incidence_equation(v, reference, rho_ref, r);
            lo = (active & f.lt(zero)).select(v, lo);
            hi = (active & f.gt(zero)).select(v, hi);
            let exact = active & f.eq(zero);
            (root, root_rho) = (exact.select(v, root), exact.select(rho_ref, root_rho));
            let nan = active & !f.eq(f);
            scalar = scalar | nan;
            active = active.and_not(exact | nan);
            let rho_dominant = pick(dominant, self.constants(|m| m.rho));
            let switch = active & !rho_dominant.eq(rho_ref) & self.resolves(rho_ref, dominant, v);
            if switch.any() {
                self.reparametrise(
                    switch,
                    [&mut reference, &mut rho_ref],
                    dominant,
                    [&mut v, &mut lo, &mut hi],
                    &mut df,
                    r,
                );
            }
            let mut step = f / df;
            let leaving = active & (v - step).ge(hi) & !F64s::splat(slowest_rho).eq(rho_ref);
            if leaving.any() {
                let to = F64s::splat(slowest as f64);
                self.reparametrise(
                    leaving,
                    [&mut reference, &mut rho_ref],
                    to,
                    [&mut v, &mut lo, &mut hi],
                    &mut df,
                    r,
                );
                step = f / df;
            }
            // An iterate mapped to infinity (at a critical angle within rounding): the scalar
            // code bisects from there.
            let infinite = active & v.eq(F64s::splat(f64::INFINITY));
            scalar = scalar | infinite;
            active = active.and_not(infinite);
            let converged = active & step.abs().le(PROJECT_TOLERANCE * v);
            (root, root_rho) = (
                converged.select(v - step, root),
                converged.select(rho_ref, root_rho),
            );
            active = active.and_not(converged);
            let mut next = v - step;
            next = (next.gt(lo) & next.lt(hi)).select(next, 0.5 * (lo + hi));
            let narrow = active & (hi - lo).le(PROJECT_TOLERANCE * hi);
            (root, root_rho) = (narrow.select(next, root), narrow.select(rho_ref, root_rho));
            active = active.and_not(narrow);
            v = active.select(next, v);
        }
        Root {
            v: root,
            rho_ref: root_rho,
            scalar: scalar | active,
        }
    }

    /// `PathMedia::incidence_equation`: f(v), f′(v) in the variable of each lane's reference
    /// medium, and the medium whose term contributes most to f′.
    #[inline(always)]
    fn incidence_equation(
        &self,
        v: F64s,
        reference: F64s,
        rho_ref: F64s,
        r: F64s,
    ) -> (F64s, F64s, F64s) {
        let v2 = v * v;
        let (mut f, mut df) = (-r, F64s::splat(0.0));
        let (mut dominant, mut dominant_slope) = (F64s::splat(AIR as f64), F64s::splat(0.0));
        for (i, medium) in self.media.iter().enumerate() {
            let length = self.length(i);
            let is_reference = reference.eq(F64s::splat(i as f64));
            let k = rho_ref * medium.inv_rho;
            let q = 1.0 + (1.0 - k * k) * v2;
            let inv_q = 1.0 / q;
            let lk = length * k * (q.sqrt() * inv_q);
            let (lk, slope) = (
                is_reference.select(length, lk),
                is_reference.select(length, lk * inv_q),
            );
            f += lk * v;
            df += slope;
            let steeper = slope.gt(dominant_slope);
            dominant = steeper.select(F64s::splat(i as f64), dominant);
            dominant_slope = steeper.select(slope, dominant_slope);
        }
        (f, df, dominant)
    }

    /// `PathMedia::resolves` per lane: the map into medium `to`'s angle keeps the iterate
    /// (0 < q ≤ `SWITCH_MAX_Q`).
    #[inline(always)]
    fn resolves(&self, rho_ref: F64s, to: F64s, v: F64s) -> Mask {
        let k = rho_ref / pick(to, self.constants(|m| m.rho));
        let q = 1.0 + (1.0 - k * k) * v * v;
        q.gt(F64s::splat(0.0)) & q.le(F64s::splat(SWITCH_MAX_Q))
    }

    /// `PathMedia::reparametrise` for the lanes of `mask`: v and the bracket map through
    /// T(·; ρ_ref/ρ_to), f′ is divided by T′, the top is capped by the new medium's bound (and is
    /// that bound where no evaluation has lowered the old top).
    #[inline(always)]
    fn reparametrise(
        &self,
        mask: Mask,
        [reference, rho_ref]: [&mut F64s; 2],
        to: F64s,
        [v, lo, hi]: [&mut F64s; 3],
        df: &mut F64s,
        r: F64s,
    ) {
        let rho_to = pick(to, self.constants(|m| m.rho));
        let k = *rho_ref / rho_to;
        let map = |x: F64s| {
            let q = 1.0 + (1.0 - k * k) * x * x;
            q.gt(F64s::splat(0.0))
                .select(k * x / q.sqrt(), F64s::splat(f64::INFINITY))
        };
        let q = 1.0 + (1.0 - k * k) * *v * *v;
        *df = mask.select(*df / (k / (q * q.sqrt())), *df);
        let (v_to, lo_to) = (map(*v), map(*lo));
        // A top no evaluation has lowered becomes the new medium's own bound (see the scalar code).
        let top_to = self.bracket_top(to, r);
        let hi_to = (*hi)
            .ge(self.bracket_top(*reference, r))
            .select(top_to, map(*hi).min(top_to));
        (*v, *lo, *hi) = (
            mask.select(v_to, *v),
            mask.select(lo_to, *lo),
            mask.select(hi_to, *hi),
        );
        *reference = mask.select(to, *reference);
        *rho_ref = mask.select(rho_to, *rho_ref);
    }
}
