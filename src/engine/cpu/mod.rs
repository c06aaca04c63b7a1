//! The batch engine's CPU backend, [`CpuEngine`]: the f64 model of [`crate::model`] over
//! batches, parallel with rayon, on the vector path of [`lanes`] (16 rows at a time) or row by
//! row through the scalar model.

use rayon::prelude::*;

pub mod lanes;

use crate::model::{NoSolution, RefractiveCamera, binocular_vop};
use lanes::{backproject_row, project_row, scalar_row, triangulate_row, vop_row};
use nalgebra::Point2;

/// Items per rayon task: large enough to amortise scheduling, small enough to balance.
const TASK_ITEMS: usize = 4096;

/// How the CPU engine evaluates back-projection, forward projection and triangulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CpuPath {
    /// Blocks of 16 rows through the lane twins in [`lanes`] (AVX-512, AVX2 or NEON, chosen at run
    /// time), rare rows through the scalar model. The default.
    #[default]
    Vector,
    /// Every row through the scalar model: the reference, and the path before the vector one.
    Scalar,
}

impl std::fmt::Display for CpuPath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Vector => write!(f, "vector {}", lanes::instruction_set()),
            Self::Scalar => f.write_str("scalar"),
        }
    }
}

/// The f64 model on a pool of threads.
pub struct CpuEngine {
    pool: rayon::ThreadPool,
    path: CpuPath,
}

impl CpuEngine {
    /// A backend on `threads` threads (all cores when `None`), on the vector path.
    pub fn new(threads: Option<usize>) -> Self {
        Self::with_path(threads, CpuPath::default())
    }

    /// A backend on `threads` threads (all cores when `None`) on `path`.
    pub fn with_path(threads: Option<usize>, path: CpuPath) -> Self {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.unwrap_or(0))
            .thread_name(|k| format!("flatport-cpu-{k}"))
            .build()
            .expect("a rayon thread pool");
        Self { pool, path }
    }

    /// Number of threads.
    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }

    /// The path batches take.
    pub fn path(&self) -> CpuPath {
        self.path
    }

    /// Runs `kernel` over tasks of [`TASK_ITEMS`] rows in parallel (in place when one thread).
    fn split<const N: usize, const M: usize>(
        &self,
        input: &[[f64; N]],
        output: &mut [[f64; M]],
        status: &mut [u32],
        kernel: impl Fn(&[[f64; N]], &mut [[f64; M]], &mut [u32]) + Sync,
    ) {
        assert!(
            input.len() == output.len() && input.len() == status.len(),
            "input, output and status of equal length"
        );
        if self.threads() == 1 {
            kernel(input, output, status);
            return;
        }
        self.pool.install(|| {
            input
                .par_chunks(TASK_ITEMS)
                .zip(
                    output
                        .par_chunks_mut(TASK_ITEMS)
                        .zip(status.par_chunks_mut(TASK_ITEMS)),
                )
                .for_each(|(input, (output, status))| kernel(input, output, status));
        });
    }

    /// Applies `f` to every row in parallel through [`scalar_row`]: status 0 and the row, or the
    /// reason's code and NaN. A row with an input beyond ±[`MAX_INPUT`](crate::model::MAX_INPUT)
    /// or a result that is not finite is [`NoSolution::OutOfRange`]: every row is all numbers or
    /// all NaN.
    pub fn map<const N: usize, const M: usize>(
        &self,
        input: &[[f64; N]],
        output: &mut [[f64; M]],
        status: &mut [u32],
        f: impl Fn(&[f64; N]) -> Result<[f64; M], NoSolution> + Sync,
    ) {
        self.split(input, output, status, |input, output, status| {
            for ((x, y), s) in input.iter().zip(output.iter_mut()).zip(status.iter_mut()) {
                (*y, *s) = scalar_row(x, &f);
            }
        });
    }

    /// See [`Engine::backproject`](super::Engine::backproject).
    pub fn backproject(
        &self,
        camera: &RefractiveCamera,
        pixels: &[[f64; 2]],
        rays: &mut [[f64; 6]],
        status: &mut [u32],
    ) {
        match self.path {
            CpuPath::Vector => self.split(pixels, rays, status, |p, r, s| {
                lanes::backproject(camera, p, r, s);
            }),
            CpuPath::Scalar => self.map(pixels, rays, status, |p| backproject_row(camera, p)),
        }
    }

    /// See [`Engine::project`](super::Engine::project).
    pub fn project(
        &self,
        camera: &RefractiveCamera,
        points: &[[f64; 3]],
        pixels: &mut [[f64; 2]],
        status: &mut [u32],
    ) {
        match self.path {
            CpuPath::Vector => self.split(points, pixels, status, |p, q, s| {
                lanes::project(camera, p, q, s);
            }),
            CpuPath::Scalar => self.map(points, pixels, status, |p| project_row(camera, p)),
        }
    }

    /// See [`Engine::vop`](super::Engine::vop).
    pub fn vop(
        &self,
        camera: &RefractiveCamera,
        points: &[[f64; 3]],
        vops: &mut [[f64; 6]],
        status: &mut [u32],
    ) {
        match self.path {
            CpuPath::Vector => self.split(points, vops, status, |p, v, s| {
                lanes::vop(camera, p, v, s);
            }),
            CpuPath::Scalar => self.map(points, vops, status, |p| vop_row(camera, p)),
        }
    }

    /// See [`Engine::triangulate`](super::Engine::triangulate).
    pub fn triangulate(
        &self,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        matches: &[[f64; 4]],
        points: &mut [[f64; 4]],
        status: &mut [u32],
    ) {
        match self.path {
            CpuPath::Vector => self.split(matches, points, status, |m, p, s| {
                lanes::triangulate(a, b, m, p, s);
            }),
            CpuPath::Scalar => self.map(matches, points, status, |m| triangulate_row(a, b, m)),
        }
    }

    /// See [`Engine::binocular_vop`](super::Engine::binocular_vop).
    pub fn binocular_vop(
        &self,
        a: &RefractiveCamera,
        b: &RefractiveCamera,
        matches: &[[f64; 4]],
        vops: &mut [[f64; 8]],
        status: &mut [u32],
    ) {
        self.map(matches, vops, status, |&[ul, vl, ur, vr]| {
            let v_a = a.dir_in_air_from_img(&Point2::new(ul, vl))?;
            let v_b = b.dir_in_air_from_img(&Point2::new(ur, vr))?;
            let bv = binocular_vop(a.centre(), &v_a, b.centre(), &v_b, a.normal())?;
            let (l, r) = (bv.vop_left, bv.vop_right);
            Ok([
                l.x,
                l.y,
                l.z,
                r.x,
                r.y,
                r.z,
                bv.axis_offset,
                bv.conditioning,
            ])
        });
    }
}
