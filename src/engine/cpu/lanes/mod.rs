//! The CPU engine's vector path: the relations of [`crate::model`] over blocks of
//! [`LANES`] rows held as structures of arrays, so that one vector instruction serves 4–8 rays.
//!
//! Layout (each file but the first the twin of the scalar module of the same name):
//! - [`f64s`]: the vocabulary, [`F64s`] (16 f64), [`Mask`], 3-vectors ([`Vec3s`]);
//! - [`camera`]: distortion and the undistortion Newton iteration;
//! - [`refractive_camera`]: back-projection and forward projection (its safeguarded Newton
//!   iteration, every lane until the slowest converges);
//! - [`stereo`]: midpoint triangulation;
//! - this file: the batch functions over slices, compiled once per instruction set and chosen at
//!   run time (`multiversion`: AVX-512, else AVX2 + FMA, else NEON, else the baseline), and the
//!   scalar fallback for the rows the lanes leave to the model.
//!
//! **One definition.** The scalar model stays the reference. A lane computes the same expressions
//! in the same order (so it rounds as the scalar code does), and where the scalar code takes a
//! branch that only rare rows reach, the lane is handed back and the scalar model answers it.
//! `tests/cpu_vector.rs` holds the two together on the oracle configurations and proptest's random
//! rigs: equal statuses, values within 1e-12 relative (in practice bit for bit).

/// Applies the `multiversion` attribute with the one list of instruction sets every kernel is
/// compiled for; [`instruction_set`] names the one the machine runs, in the same order. Also used
/// by the calibration costs' lane twin (`calib::costs::lanes`).
macro_rules! dispatched {
    ($($item:item)*) => {$(
        #[multiversion::multiversion(targets(
            "x86_64+avx512f+avx512vl+avx512dq+avx2+fma",
            "x86_64+avx2+fma",
            "aarch64+neon",
        ))]
        $item
    )*};
}
pub(crate) use dispatched;

pub mod camera;
pub mod f64s;
pub mod refractive_camera;
pub mod stereo;

pub use f64s::{F64s, LANES, Mask, Vec3s};
use refractive_camera::CameraLanes;

use crate::model::{MAX_INPUT, NoSolution, RefractiveCamera, triangulate_rays};
use nalgebra::{Point2, Point3};

/// The instruction set the vector path runs on this machine: `avx512`, `avx2`, `neon` or
/// `baseline` (the build's own target features: SSE2 on x86-64), as the kernels' dispatch
/// chooses it.
pub fn instruction_set() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::is_x86_feature_detected as has;
        if has!("avx512f") && has!("avx512vl") && has!("avx512dq") && has!("avx2") && has!("fma") {
            return "avx512";
        }
        if has!("avx2") && has!("fma") {
            return "avx2";
        }
    }
    #[cfg(target_arch = "aarch64")]
    {
        if std::arch::is_aarch64_feature_detected!("neon") {
            return "neon";
        }
    }
    "baseline"
}

/// One row of a batch through the scalar model, with the CPU engine's row checks: an input beyond
/// ±[`MAX_INPUT`] or a result that is not finite is [`NoSolution::OutOfRange`]; a row without an
/// answer is NaN. The CPU engine's scalar path and the vector path's fallback are both this.
#[inline]
pub fn scalar_row<const N: usize, const M: usize>(
    input: &[f64; N],
    f: impl Fn(&[f64; N]) -> Result<[f64; M], NoSolution>,
) -> ([f64; M], u32) {
    let result = if input.iter().all(|x| x.abs() <= MAX_INPUT) {
        f(input)
    } else {
        Err(NoSolution::OutOfRange)
    };
    match result {
        Ok(value) if value.iter().all(|y| y.is_finite()) => (value, 0),
        Ok(_) => ([f64::NAN; M], NoSolution::OutOfRange.code()),
        Err(reason) => ([f64::NAN; M], reason.code()),
    }
}

/// [`RefractiveCamera::backproject`] as a batch row: origin xyz, direction xyz.
#[inline]
pub fn backproject_row(
    camera: &RefractiveCamera,
    &[u, v]: &[f64; 2],
) -> Result<[f64; 6], NoSolution> {
    let ray = camera.backproject(&Point2::new(u, v))?;
    let (o, d) = (ray.origin, ray.dir);
    Ok([o.x, o.y, o.z, d.x, d.y, d.z])
}

/// [`RefractiveCamera::project`] as a batch row: u, v.
#[inline]
pub fn project_row(
    camera: &RefractiveCamera,
    &[x, y, z]: &[f64; 3],
) -> Result<[f64; 2], NoSolution> {
    camera.project(&Point3::new(x, y, z)).map(|p| [p.x, p.y])
}

/// [`RefractiveCamera::vop`] as a batch row: depth, vop_distance, vop xyz, incidence.
#[inline]
pub fn vop_row(camera: &RefractiveCamera, &[x, y, z]: &[f64; 3]) -> Result<[f64; 6], NoSolution> {
    let v = camera.vop(&Point3::new(x, y, z))?;
    Ok([
        v.depth,
        v.vop_distance,
        v.vop.x,
        v.vop.y,
        v.vop.z,
        v.incidence,
    ])
}

/// Triangulation of a match (ul, vl, ur, vr) as a batch row: x, y, z, residual.
#[inline]
pub fn triangulate_row(
    a: &RefractiveCamera,
    b: &RefractiveCamera,
    &[ul, vl, ur, vr]: &[f64; 4],
) -> Result<[f64; 4], NoSolution> {
    let ray_a = a.backproject(&Point2::new(ul, vl))?;
    let ray_b = b.backproject(&Point2::new(ur, vr))?;
    let t = triangulate_rays(&ray_a, &ray_b)?;
    Ok([t.point.x, t.point.y, t.point.z, t.residual])
}

/// Pixels of `points` (master frame) in `camera` on the vector path, or `None` when one of them
/// has no answer: the calibration's per-corner projections (bundle residuals and Jacobians, the
/// reprojection cost) in lanes, bit for bit [`RefractiveCamera::project`].
pub fn project_all(camera: &RefractiveCamera, points: &[[f64; 3]]) -> Option<Vec<[f64; 2]>> {
    let mut pixels = vec![[0.0; 2]; points.len()];
    let mut status = vec![0; points.len()];
    project(camera, points, &mut pixels, &mut status);
    status.iter().all(|&s| s == 0).then_some(pixels)
}

/// Column `c` of a block of rows as lanes; a short last block repeats its last row (those lanes
/// are computed and dropped).
#[inline(always)]
fn column<const N: usize>(rows: &[[f64; N]], c: usize) -> F64s {
    let last = rows.len() - 1;
    // A plain loop rather than `array::from_fn`, which the compiler left out of line (a scalar
    // call per column) in the batch functions compiled for a wider instruction set.
    let mut lanes = [0.0; LANES];
    for (l, lane) in lanes.iter_mut().enumerate() {
        *lane = rows[l.min(last)][c];
    }
    F64s(lanes)
}

/// Writes lane `l` of a block: the lane's values, or NaN and its status code.
#[inline(always)]
fn store<const M: usize>(row: &mut [f64; M], status: &mut u32, code: u32, values: [f64; M]) {
    (*row, *status) = if code == 0 {
        (values, 0)
    } else {
        ([f64::NAN; M], code)
    };
}

// The four batch loops below share their shape on purpose. Folded into one generic loop (the
// lanes of a relation as a closure, or as a trait with `#[inline(always)]` methods, returning the
// output columns), back-projection ran at 56–64 M rows/s instead of 87 on one thread (machine B,
// `flatport bench --no-gpu`), while projection and triangulation did not change.
dispatched! {
    /// [`Engine::backproject`](crate::engine::Engine::backproject) on the vector path, one thread;
    /// returns how many rows the scalar model answered. Panics if the slices differ in length.
    pub fn backproject(camera: &RefractiveCamera, pixels: &[[f64; 2]], rays: &mut [[f64; 6]], status: &mut [u32]) -> usize {
        assert!(pixels.len() == rays.len() && pixels.len() == status.len(), "input, output and status of equal length");
        let lanes = CameraLanes::new(camera);
        let mut by_scalar = 0;
        for ((pixels, rays), status) in pixels.chunks(LANES).zip(rays.chunks_mut(LANES)).zip(status.chunks_mut(LANES)) {
            let out = lanes.backproject(column(pixels, 0), column(pixels, 1));
            let (o, d) = (out.origin, out.dir);
            for l in 0..pixels.len() {
                if out.scalar.0[l] {
                    (rays[l], status[l]) = scalar_row(&pixels[l], |p| backproject_row(camera, p));
                    by_scalar += 1;
                } else {
                    let values = [o.x.0[l], o.y.0[l], o.z.0[l], d.x.0[l], d.y.0[l], d.z.0[l]];
                    store(&mut rays[l], &mut status[l], out.status.0[l], values);
                }
            }
        }
        by_scalar
    }

    /// [`Engine::project`](crate::engine::Engine::project) on the vector path, one thread; returns
    /// how many rows the scalar model answered. Panics if the slices differ in length.
    pub fn project(camera: &RefractiveCamera, points: &[[f64; 3]], pixels: &mut [[f64; 2]], status: &mut [u32]) -> usize {
        assert!(points.len() == pixels.len() && points.len() == status.len(), "input, output and status of equal length");
        let lanes = CameraLanes::new(camera);
        let mut by_scalar = 0;
        for ((points, pixels), status) in points.chunks(LANES).zip(pixels.chunks_mut(LANES)).zip(status.chunks_mut(LANES)) {
            let out = lanes.project(Vec3s { x: column(points, 0), y: column(points, 1), z: column(points, 2) });
            for l in 0..points.len() {
                if out.scalar.0[l] {
                    (pixels[l], status[l]) = scalar_row(&points[l], |p| project_row(camera, p));
                    by_scalar += 1;
                } else {
                    store(&mut pixels[l], &mut status[l], out.status.0[l], [out.u.0[l], out.v.0[l]]);
                }
            }
        }
        by_scalar
    }

    /// [`project`] for points seen near known air rays: each lane from the tan a of its air ray
    /// (`tan_starts`, one a point; a start within a few pixels settles in two or three steps) by
    /// [`CameraLanes::project_near`], the lanes it leaves by [`CameraLanes::project`] and their
    /// rare rows by the scalar model, as the calibration's reprojection does. A settled lane's
    /// pixel is `project`'s up to rounding (the same root, by another path), and its status is
    /// `project`'s. Dense stereo's hypotheses take it (`stereo::cost::project_hypotheses`).
    /// Returns how many rows the scalar model answered. Panics if the slices differ in length.
    pub fn project_near_all(camera: &RefractiveCamera, points: &[[f64; 3]], tan_starts: &[f64], pixels: &mut [[f64; 2]], status: &mut [u32]) -> usize {
        assert!(
            points.len() == pixels.len() && points.len() == status.len() && points.len() == tan_starts.len(),
            "input, starts, output and status of equal length"
        );
        let lanes = CameraLanes::new(camera);
        let mut by_scalar = 0;
        for (((points, tans), pixels), status) in points.chunks(LANES).zip(tan_starts.chunks(LANES)).zip(pixels.chunks_mut(LANES)).zip(status.chunks_mut(LANES)) {
            let point = Vec3s { x: column(points, 0), y: column(points, 1), z: column(points, 2) };
            let mut tan = [0.0; LANES];
            tan[..tans.len()].copy_from_slice(tans);
            let (near, settled) = lanes.project_near(point, F64s(tan));
            let full = (!settled.all()).then(|| lanes.project(point));
            for l in 0..points.len() {
                match &full {
                    Some(full) if !settled.0[l] => {
                        if full.scalar.0[l] {
                            (pixels[l], status[l]) = scalar_row(&points[l], |p| project_row(camera, p));
                            by_scalar += 1;
                        } else {
                            store(&mut pixels[l], &mut status[l], full.status.0[l], [full.u.0[l], full.v.0[l]]);
                        }
                    }
                    _ => store(&mut pixels[l], &mut status[l], near.status.0[l], [near.u.0[l], near.v.0[l]]),
                }
            }
        }
        by_scalar
    }

    /// [`Engine::vop`](crate::engine::Engine::vop) on the vector path, one thread; returns how
    /// many rows the scalar model answered. Panics if the slices differ in length.
    pub fn vop(camera: &RefractiveCamera, points: &[[f64; 3]], vops: &mut [[f64; 6]], status: &mut [u32]) -> usize {
        assert!(points.len() == vops.len() && points.len() == status.len(), "input, output and status of equal length");
        let lanes = CameraLanes::new(camera);
        let mut by_scalar = 0;
        for ((points, vops), status) in points.chunks(LANES).zip(vops.chunks_mut(LANES)).zip(status.chunks_mut(LANES)) {
            let out = lanes.vop(Vec3s { x: column(points, 0), y: column(points, 1), z: column(points, 2) });
            for l in 0..points.len() {
                if out.scalar.0[l] {
                    (vops[l], status[l]) = scalar_row(&points[l], |p| vop_row(camera, p));
                    by_scalar += 1;
                } else {
                    store(&mut vops[l], &mut status[l], out.status.0[l], out.values.map(|v| v.0[l]));
                }
            }
        }
        by_scalar
    }

    /// [`Engine::triangulate`](crate::engine::Engine::triangulate) on the vector path, one
    /// thread; returns how many rows the scalar model answered. Panics if the slices differ in
    /// length.
    pub fn triangulate(a: &RefractiveCamera, b: &RefractiveCamera, matches: &[[f64; 4]], points: &mut [[f64; 4]], status: &mut [u32]) -> usize {
        assert!(matches.len() == points.len() && matches.len() == status.len(), "input, output and status of equal length");
        let (lanes_a, lanes_b) = (CameraLanes::new(a), CameraLanes::new(b));
        let mut by_scalar = 0;
        for ((matches, points), status) in matches.chunks(LANES).zip(points.chunks_mut(LANES)).zip(status.chunks_mut(LANES)) {
            let [ul, vl, ur, vr] = [0, 1, 2, 3].map(|c| column(matches, c));
            let in_range = ul.within(MAX_INPUT) & vl.within(MAX_INPUT) & ur.within(MAX_INPUT) & vr.within(MAX_INPUT);
            let (ray_a, ray_b) = (lanes_a.backproject(ul, vl), lanes_b.backproject(ur, vr));
            let out = stereo::triangulate(&ray_a, &ray_b, in_range);
            let scalar: Mask = in_range & (ray_a.scalar | ray_b.scalar);
            let p = out.point;
            for l in 0..matches.len() {
                if scalar.0[l] {
                    (points[l], status[l]) = scalar_row(&matches[l], |m| triangulate_row(a, b, m));
                    by_scalar += 1;
                } else {
                    store(&mut points[l], &mut status[l], out.status.0[l], [p.x.0[l], p.y.0[l], p.z.0[l], out.residual.0[l]]);
                }
            }
        }
        by_scalar
    }
}

dispatched! {
    /// The machine's cost of one √ and of one ÷ per f64 lane on the vector path, in seconds, as
    /// (√, ÷): the best of 5 trials of `rounds` rounds over 8 independent blocks, so that
    /// throughput and not latency counts. `flatport bench` multiplies them by each relation's
    /// count to estimate its floor.
    pub fn sqrt_div_seconds(rounds: usize) -> (f64, f64) {
        // Two loops spelt out on purpose: folded into one generic helper taking the operation, the
        // same probe measured 0.3 cycles per ÷ and lane, below what the hardware can do, so the
        // optimiser had changed what was timed.
        const UNROLL: usize = 16;
        let mut x: [F64s; 8] = std::array::from_fn(|j| F64s::splat(1.5 + j as f64));
        let (mut sqrt, mut div) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..5 {
            let start = std::time::Instant::now();
            for _ in 0..rounds.div_ceil(UNROLL) {
                for _ in 0..UNROLL {
                    for v in &mut x {
                        *v = v.sqrt();
                    }
                }
                x = std::hint::black_box(x);
            }
            sqrt = sqrt.min(start.elapsed().as_secs_f64());
            let start = std::time::Instant::now();
            for _ in 0..rounds.div_ceil(UNROLL) {
                for _ in 0..UNROLL {
                    for v in &mut x {
                        *v = 2.5 / *v;
                    }
                }
                x = std::hint::black_box(x);
            }
            div = div.min(start.elapsed().as_secs_f64());
        }
        std::hint::black_box(x);
        let lanes = (rounds.div_ceil(UNROLL) * UNROLL * 8 * LANES) as f64;
        (sqrt / lanes, div / lanes)
    }
}

/// Mean Newton steps of the lane undistortion per block of [`LANES`] pixels of `camera` (each
/// step one ÷ per lane; 0 without distortion), for the floor estimate of `flatport bench`.
pub fn undistortion_steps(camera: &RefractiveCamera, pixels: &[[f64; 2]]) -> f64 {
    let lanes = CameraLanes::new(camera);
    let blocks = pixels.chunks(LANES);
    let count = blocks.len().max(1);
    let steps: u64 = blocks
        .map(|b| u64::from(lanes.undistortion_steps(column(b, 0), column(b, 1))))
        .sum();
    steps as f64 / count as f64
}
