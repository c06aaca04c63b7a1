//! The CPU backend: the f64 reference of [`crate::model`] over batches, parallel with rayon.

use rayon::prelude::*;

use crate::model::{MAX_INPUT, NoSolution, RefractiveCamera, Rig, binocular_vop, out_of_range, triangulate_rays};
use nalgebra::{Point2, Point3, Unit, Vector3};

/// Items per rayon task: large enough to amortise scheduling, small enough to balance.
const TASK_ITEMS: usize = 4096;

/// The f64 reference on a pool of threads.
pub struct CpuEngine {
    pool: rayon::ThreadPool,
}

impl CpuEngine {
    /// A backend on `threads` threads (all cores when `None`).
    pub fn new(threads: Option<usize>) -> Self {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.unwrap_or(0))
            .thread_name(|k| format!("flatport-cpu-{k}"))
            .build()
            .expect("a rayon thread pool");
        Self { pool }
    }

    /// Number of threads.
    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }

    /// Applies `f` to every row in parallel: status 0 and the row, or the reason's code and NaN. A
    /// row with an input beyond ±[`MAX_INPUT`] or a result that is not finite is
    /// [`NoSolution::OutOfRange`]: every row is all numbers or all NaN.
    pub fn map<const N: usize, const M: usize>(
        &self,
        input: &[[f64; N]],
        output: &mut [[f64; M]],
        status: &mut [u32],
        f: impl Fn(&[f64; N]) -> Result<[f64; M], NoSolution> + Sync,
    ) {
        assert!(input.len() == output.len() && input.len() == status.len(), "input, output and status of equal length");
        type Task<'a, const N: usize, const M: usize> = (&'a [[f64; N]], (&'a mut [[f64; M]], &'a mut [u32]));
        let run = |(input, (output, status)): Task<N, M>| {
            for ((x, y), s) in input.iter().zip(output.iter_mut()).zip(status.iter_mut()) {
                let result = if out_of_range(x, MAX_INPUT, &[]) { Err(NoSolution::OutOfRange) } else { f(x) };
                (*y, *s) = match result {
                    Ok(value) if !out_of_range(&[], MAX_INPUT, &value) => (value, 0),
                    Ok(_) => ([f64::NAN; M], NoSolution::OutOfRange.code()),
                    Err(reason) => ([f64::NAN; M], reason.code()),
                };
            }
        };
        if self.threads() == 1 {
            run((input, (output, status)));
            return;
        }
        self.pool.install(|| {
            input
                .par_chunks(TASK_ITEMS)
                .zip(output.par_chunks_mut(TASK_ITEMS).zip(status.par_chunks_mut(TASK_ITEMS)))
                .for_each(run);
        });
    }

    /// See [`Engine::backproject`](super::Engine::backproject).
    pub fn backproject(&self, camera: &RefractiveCamera, pixels: &[[f64; 2]], rays: &mut [[f64; 6]], status: &mut [u32]) {
        self.map(pixels, rays, status, |&[u, v]| {
            let ray = camera.backproject(&Point2::new(u, v))?;
            let (o, d) = (ray.origin, ray.dir);
            Ok([o.x, o.y, o.z, d.x, d.y, d.z])
        });
    }

    /// See [`Engine::project`](super::Engine::project).
    pub fn project(&self, camera: &RefractiveCamera, points: &[[f64; 3]], pixels: &mut [[f64; 2]], status: &mut [u32]) {
        self.map(points, pixels, status, |&[x, y, z]| camera.project(&Point3::new(x, y, z)).map(|p| [p.x, p.y]));
    }

    /// See [`Engine::vop`](super::Engine::vop).
    pub fn vop(&self, camera: &RefractiveCamera, points: &[[f64; 3]], vops: &mut [[f64; 6]], status: &mut [u32]) {
        self.map(points, vops, status, |&[x, y, z]| {
            let v = camera.vop(&Point3::new(x, y, z))?;
            Ok([v.depth, v.vop_distance, v.vop.x, v.vop.y, v.vop.z, v.incidence])
        });
    }

    /// See [`Engine::triangulate`](super::Engine::triangulate).
    pub fn triangulate(&self, a: &RefractiveCamera, b: &RefractiveCamera, matches: &[[f64; 4]], points: &mut [[f64; 4]], status: &mut [u32]) {
        self.map(matches, points, status, |&[ul, vl, ur, vr]| {
            let ray_a = a.backproject(&Point2::new(ul, vl))?;
            let ray_b = b.backproject(&Point2::new(ur, vr))?;
            let t = triangulate_rays(&ray_a, &ray_b)?;
            Ok([t.point.x, t.point.y, t.point.z, t.residual])
        });
    }

    /// See [`Engine::binocular_vop`](super::Engine::binocular_vop).
    pub fn binocular_vop(&self, a: &RefractiveCamera, b: &RefractiveCamera, matches: &[[f64; 4]], vops: &mut [[f64; 8]], status: &mut [u32]) {
        self.map(matches, vops, status, |&[ul, vl, ur, vr]| {
            let v_a = a.dir_in_air_from_img(&Point2::new(ul, vl))?;
            let v_b = b.dir_in_air_from_img(&Point2::new(ur, vr))?;
            let bv = binocular_vop(a.centre(), &v_a, b.centre(), &v_b, a.normal())?;
            let (l, r) = (bv.vop_left, bv.vop_right);
            Ok([l.x, l.y, l.z, r.x, r.y, r.z, bv.axis_offset, bv.conditioning])
        });
    }

    /// See [`Engine::ray_gap_cost`](super::Engine::ray_gap_cost).
    pub fn ray_gap_cost(&self, rig: &Rig, a: usize, b: usize, air_rays: &[[f64; 6]], candidates: &[[f64; 4]], costs: &mut [[f64; 2]]) {
        assert_eq!(candidates.len(), costs.len(), "one cost per candidate");
        let term = |a: &RefractiveCamera, b: &RefractiveCamera, r: &[f64; 6]| -> Option<f64> {
            let v_a = Unit::new_normalize(Vector3::new(r[0], r[1], r[2]));
            let v_b = Unit::new_normalize(Vector3::new(r[3], r[4], r[5]));
            let t = triangulate_rays(&a.ray_in_water(&v_a).ok()?, &b.ray_in_water(&v_b).ok()?).ok()?;
            Some(t.residual * t.residual)
        };
        self.pool.install(|| {
            candidates.par_iter().zip(costs.par_iter_mut()).for_each(|(c, cost)| {
                let moved = rig.interface().with_pose(Vector3::new(c[0], c[1], c[2]), c[3]).and_then(|i| rig.with_interface(i));
                // A candidate that puts a camera outside the air has no term.
                let Ok(moved) = moved else {
                    *cost = [0.0, 0.0];
                    return;
                };
                let (a, b) = (moved.refractive_camera(a), moved.refractive_camera(b));
                *cost = air_rays.iter().filter_map(|r| term(&a, &b, r)).fold([0.0, 0.0], |acc, x| [acc[0] + x, acc[1] + 1.0]);
            });
        });
    }
}
