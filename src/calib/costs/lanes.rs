//! The lane twin of the triangulating costs: their passes under one axis
//! ([`crate::calib::costs::scene`]) on the CPU engine's vector path
//! ([`crate::engine::cpu::lanes`]), over [`Columns`]: the water rays of every corner with their gap-line sums, the
//! triangulation at an air layer, and the reprojection of the fitted board corners.
//!
//! A sweep evaluates these for thousands of axes over every corner, so the data is held as
//! columns (one `Vec<f64>` per coordinate, padded to whole blocks of [`LANES`]): a block is one
//! contiguous load or store per coordinate, where rows would take [`LANES`] scalar moves each.

use crate::engine::cpu::lanes::refractive_camera::{CameraLanes, Rays, Status};
use crate::engine::cpu::lanes::{
    F64s, LANES, Mask, Vec3s, dispatched, project_row, scalar_row, stereo,
};
use crate::model::RefractiveCamera;

/// `N` columns of f64 over `len` rows, each padded to a whole number of blocks of [`LANES`]; the
/// padding repeats the last row, so that every lane of a block computes on a real row and the
/// passes need only mask the padding out of their sums.
#[derive(Debug, Clone)]
pub struct Columns<const N: usize> {
    len: usize,
    values: [Vec<f64>; N],
}

impl<const N: usize> Default for Columns<N> {
    fn default() -> Self {
        Self {
            len: 0,
            values: std::array::from_fn(|_| Vec::new()),
        }
    }
}

impl<const N: usize> Columns<N> {
    /// The columns of `rows`, padded.
    pub fn from_rows(rows: impl IntoIterator<Item = [f64; N]>) -> Self {
        let mut columns = Self::default();
        for row in rows {
            for (column, value) in columns.values.iter_mut().zip(row) {
                column.push(value);
            }
            columns.len += 1;
        }
        columns.pad();
        columns
    }

    /// `len` rows (the buffers reused; the values left to be [`set`](Self::set) and then
    /// [`pad`](Self::pad)ded, or written by whole blocks).
    pub fn resize(&mut self, len: usize) {
        self.len = len;
        for column in &mut self.values {
            column.resize(len.div_ceil(LANES) * LANES, 0.0);
        }
    }

    /// Rows (without the padding).
    pub fn len(&self) -> usize {
        self.len
    }

    /// No rows.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Column `c` (with the padding).
    pub fn column(&self, c: usize) -> &[f64] {
        &self.values[c]
    }

    /// Row `i`, coordinate `c`.
    pub fn get(&self, c: usize, i: usize) -> f64 {
        self.values[c][i]
    }

    /// Sets row `i`, coordinate `c`.
    pub fn set(&mut self, c: usize, i: usize, value: f64) {
        self.values[c][i] = value;
    }

    /// Repeats the last row into the padding.
    pub fn pad(&mut self) {
        let len = self.len;
        for column in &mut self.values {
            column.resize(len.div_ceil(LANES) * LANES, 0.0);
            if let Some(&last) = len.checked_sub(1).and_then(|i| column.get(i)) {
                column[len..].fill(last);
            }
        }
    }

    /// The blocks' first rows.
    fn blocks(&self) -> impl Iterator<Item = usize> + use<N> {
        (0..self.len).step_by(LANES)
    }

    /// Lanes of the block at `start` that hold real rows, not padding.
    #[inline(always)]
    fn real(&self, start: usize) -> Mask {
        let rows = self.len - start;
        let mut mask = [false; LANES];
        for (l, m) in mask.iter_mut().enumerate() {
            *m = l < rows;
        }
        Mask(mask)
    }

    #[inline(always)]
    fn lanes(&self, c: usize, start: usize) -> F64s {
        let mut lanes = [0.0; LANES];
        lanes.copy_from_slice(&self.values[c][start..start + LANES]);
        F64s(lanes)
    }

    #[inline(always)]
    fn vector(&self, c: usize, start: usize) -> Vec3s {
        Vec3s {
            x: self.lanes(c, start),
            y: self.lanes(c + 1, start),
            z: self.lanes(c + 2, start),
        }
    }

    #[inline(always)]
    fn store(&mut self, c: usize, start: usize, lanes: F64s) {
        self.values[c][start..start + LANES].copy_from_slice(&lanes.0);
    }

    #[inline(always)]
    fn store_vector(&mut self, c: usize, start: usize, v: Vec3s) {
        self.store(c, start, v.x);
        self.store(c + 1, start, v.y);
        self.store(c + 2, start, v.z);
    }
}

/// Columns of [`axis_rays`]'s rows per camera: the origin on the outer interface at the air layer
/// the rays were computed at (0–2), the unit water direction (3–5), ∂origin/∂d = v/(n·v) (6–8: the
/// water ray is linear in the air layer, DESIGN.md §2).
pub type RayColumns = Columns<9>;

/// Σa², Σab, Σb² over the gap lines g(d) = a·d + b of every corner
/// ([`GapLine`](crate::calib::costs::air_layer::GapLine)), and whether every line was usable
/// (|w_l × w_r| above the caller's bound).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GapSums {
    /// Σa².
    pub aa: f64,
    /// Σab.
    pub ab: f64,
    /// Σb².
    pub bb: f64,
    /// Every line usable.
    pub usable: bool,
}

/// Lane sum in lane order.
#[inline(always)]
fn total(x: F64s) -> f64 {
    x.0.iter().sum()
}

dispatched! {
    /// The water rays of every corner under the cameras `cameras` (left, right; behind one axis
    /// at the air layer `d0`) from their unit air directions `dirs` (master frame), into `rays`
    /// ([`RayColumns`]), and the sums of their gap lines, usable where the sine of the angle
    /// between the water rays exceeds `min_sin_angle`; `None` when some corner's ray has no
    /// answer (it misses the interface or is totally reflected). The rays are
    /// [`RefractiveCamera::ray_in_water`]'s, bit for bit. `moved` says whose port the air layer
    /// moves: both cameras' behind one shared port; behind a port each, only the first camera's
    /// (the second's origins, and its part of the gap line's slope, stay put).
    pub fn axis_rays(cameras: &[RefractiveCamera; 2], dirs: &[Columns<3>; 2], d0: f64, moved: [bool; 2], min_sin_angle: f64, rays: &mut [RayColumns; 2]) -> Option<GapSums> {
        let lanes = cameras.each_ref().map(CameraLanes::new);
        let corners = dirs[0].len();
        assert_eq!(corners, dirs[1].len(), "both cameras' directions");
        for r in rays.iter_mut() {
            r.resize(corners);
        }
        let zero = F64s::splat(0.0);
        let (mut aa, mut ab, mut bb) = (zero, zero, zero);
        let mut failed = Mask::splat(false);
        let mut unusable = Mask::splat(false);
        let moves = moved.map(|m| F64s::splat(if m { 1.0 } else { 0.0 }));
        for start in dirs[0].blocks() {
            let [(o_l, w_l, s_l), (o_r, w_r, s_r)] = [0, 1].map(|k| {
                let v = dirs[k].vector(0, start);
                let mut status = Status::ok();
                let water = lanes[k].ray_in_water_at_incidence(v, &mut status);
                failed = failed | !status.answered();
                let slope = v.scale(water.inv_cos_a);
                rays[k].store_vector(0, start, water.origin);
                rays[k].store_vector(3, start, water.dir);
                rays[k].store_vector(6, start, slope);
                (water.origin, water.dir, slope)
            });
            // The gap line: m = unit(w_l × w_r), g(d0) = m·(o_l − o_r), a = m·(∂o_l/∂d − ∂o_r/∂d),
            // ∂o/∂d = 0 for a port the air layer does not move.
            let cross = w_l.cross(w_r);
            let sin_angle = cross.norm_squared().sqrt();
            let m = cross.scale(1.0 / sin_angle);
            let g0 = m.dot(o_l - o_r);
            let a = m.dot(s_l.scale(moves[0]) - s_r.scale(moves[1]));
            let b = g0 - a * d0;
            unusable = unusable | !sin_angle.gt(F64s::splat(min_sin_angle));
            let real = dirs[0].real(start);
            aa += real.select(a * a, zero);
            ab += real.select(a * b, zero);
            bb += real.select(b * b, zero);
        }
        (!failed.any()).then(|| GapSums {
            aa: total(aa),
            ab: total(ab),
            bb: total(bb),
            usable: !unusable.any(),
        })
    }

    /// [`triangulate_rays`](crate::model::triangulate_rays) of every corner's two rays of
    /// [`axis_rays`] with each camera's origins moved along its air rays by `shifts` metres of air
    /// layer (the new air layer less the one they were computed at; 0 for a port the air layer
    /// does not move): `points` gets x, y, z and the residual (the distance between the rays);
    /// false when some corner does not triangulate in the water.
    pub fn triangulate_shifted(rays: &[RayColumns; 2], shifts: [f64; 2], points: &mut Columns<4>) -> bool {
        points.resize(rays[0].len());
        let shifts = shifts.map(F64s::splat);
        let mut failed = Mask::splat(false);
        for start in rays[0].blocks() {
            let [a, b] = [0, 1].map(|k| Rays {
                origin: rays[k].vector(0, start) + rays[k].vector(6, start).scale(shifts[k]),
                dir: rays[k].vector(3, start),
                status: Status::ok(),
                scalar: Mask::splat(false),
            });
            let out = stereo::triangulate(&a, &b, Mask::splat(true));
            failed = failed | !out.status.answered();
            points.store_vector(0, start, out.point);
            points.store(3, start, out.residual);
        }
        !failed.any()
    }

    /// Σ over corners of the squared pixel residuals (observed − projected) of the points
    /// `fitted` in both cameras (`cameras`, left and right), `observed` the corners' pixels per
    /// camera; `None` when a fitted corner does not project. Each point is projected from the
    /// tan a of its observed ray by [`CameraLanes::project_near`], taken from `rays`' ∂origin/∂d
    /// = v/(n·v), whose squared length is 1 + tan² a (here, not in [`axis_rays`], so that the other
    /// costs do not pay for it); the lanes it leaves take [`CameraLanes::project`], and its
    /// rare rows the scalar model, as [`project`](crate::engine::cpu::lanes::project) does.
    pub fn reprojection_squares(cameras: &[RefractiveCamera; 2], fitted: &Columns<3>, rays: &[RayColumns; 2], observed: &[Columns<2>; 2]) -> Option<f64> {
        let lanes = cameras.each_ref().map(CameraLanes::new);
        let zero = F64s::splat(0.0);
        let mut sum = zero;
        for start in fitted.blocks() {
            let point = fitted.vector(0, start);
            for k in 0..2 {
                let slope = rays[k].vector(6, start);
                let tan_start = (slope.norm_squared() - 1.0).max(zero).sqrt();
                let (near, settled) = lanes[k].project_near(point, tan_start);
                let (mut u, mut v) = (near.u, near.v);
                if !settled.all() {
                    let full = lanes[k].project(point);
                    for l in (0..LANES).filter(|&l| !settled.0[l]) {
                        let (pixel, status) = if full.scalar.0[l] {
                            let row = [point.x.0[l], point.y.0[l], point.z.0[l]];
                            scalar_row(&row, |p| project_row(&cameras[k], p))
                        } else {
                            ([full.u.0[l], full.v.0[l]], full.status.0[l])
                        };
                        if status != 0 {
                            return None;
                        }
                        [u.0[l], v.0[l]] = pixel;
                    }
                }
                let du = observed[k].lanes(0, start) - u;
                let dv = observed[k].lanes(1, start) - v;
                sum += fitted.real(start).select(du * du + dv * dv, zero);
            }
        }
        Some(total(sum))
    }
}
