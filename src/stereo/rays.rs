//! Stage 1 and 2 of the sweep: the water ray of every reference pixel (exact back-projection),
//! the hypotheses (uniform in inverse depth) and the hypothesis points on the rays.
//!
//! A reference pixel's water ray is o + s·w (master frame, o on the outer interface, |w| = 1).
//! Its depth in the reference camera's frame is z(s) = r₃·(o + s·w − C) = z₀ + s·ż with r₃ the
//! third row of R_ref, z₀ = r₃·(o − C) and ż = r₃·w, so the point at depth z is
//! X(z) = o + ((z − z₀)/ż)·w, in the water when z ≥ z₀ (and ż > 0).

use rayon::prelude::*;

use crate::engine::cpu::lanes;
use crate::model::RefractiveCamera;

/// Pixels per task of the batch stages.
pub(crate) const TASK_PIXELS: usize = 4096;

/// The water ray of every pixel of a camera, row-major, master frame.
#[derive(Debug, Clone)]
pub struct RayGrid {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// o: where the ray leaves the outer interface (NaN where the pixel has no ray).
    pub origin: Vec<[f64; 3]>,
    /// w: unit direction in the water.
    pub dir: Vec<[f64; 3]>,
    /// z₀: depth of o in the camera's frame (NaN where the pixel has no ray).
    pub z0: Vec<f64>,
    /// ż = dz/ds along the ray (NaN where the ray does not go deeper).
    pub dz: Vec<f64>,
}

impl RayGrid {
    /// X(z) of pixel `i`, or `None` when the pixel has no ray or z is not beyond its origin.
    #[inline]
    pub fn point_at_depth(&self, i: usize, z: f64) -> Option<[f64; 3]> {
        let s = (z - self.z0[i]) / self.dz[i];
        if !(s >= 0.0 && s.is_finite()) {
            return None;
        }
        let (o, w) = (self.origin[i], self.dir[i]);
        Some([o[0] + s * w[0], o[1] + s * w[1], o[2] + s * w[2]])
    }

    /// The largest z₀ over the pixels that have a ray: the port's farthest point in this camera's
    /// image, depth in its frame.
    pub fn farthest_origin(&self) -> Option<f64> {
        self.z0
            .iter()
            .copied()
            .filter(|z| z.is_finite())
            .reduce(f64::max)
    }
}

/// Stage 1, `reference_rays`: the water ray of every pixel centre (u, v) = (column, row) of
/// `camera`, by the engine's vector back-projection (exact, lens distortion included).
pub fn reference_rays(camera: &RefractiveCamera) -> RayGrid {
    let (width, height) = (
        camera.intrinsics().width as usize,
        camera.intrinsics().height as usize,
    );
    rays_on_grid(camera, width, height, 1)
}

/// The water rays of the pixels (u, v) = (`step`·column, `step`·row) for `width` × `height` grid
/// points, row-major (step 1: every pixel, [`reference_rays`]; the tabulated projection's nodes
/// otherwise, which may lie past the image's last pixel). The same back-projection for every
/// step: a node at a pixel has that pixel's ray, bit for bit.
pub fn rays_on_grid(
    camera: &RefractiveCamera,
    width: usize,
    height: usize,
    step: usize,
) -> RayGrid {
    let count = width * height;
    let mut rays = vec![[0.0; 6]; count];
    let mut status = vec![0u32; count];
    let z_row = camera.cam_from_master().row(2).transpose();
    let centre = camera.centre().coords;
    rays.par_chunks_mut(TASK_PIXELS)
        .zip(status.par_chunks_mut(TASK_PIXELS))
        .enumerate()
        .for_each(|(task, (rays, status))| {
            let pixels: Vec<[f64; 2]> = (0..rays.len())
                .map(|j| {
                    let i = task * TASK_PIXELS + j;
                    [((i % width) * step) as f64, ((i / width) * step) as f64]
                })
                .collect();
            lanes::backproject(camera, &pixels, rays, status);
        });
    let mut grid = RayGrid {
        width,
        height,
        origin: Vec::with_capacity(count),
        dir: Vec::with_capacity(count),
        z0: Vec::with_capacity(count),
        dz: Vec::with_capacity(count),
    };
    for (r, s) in rays.iter().zip(&status) {
        let (o, w) = ([r[0], r[1], r[2]], [r[3], r[4], r[5]]);
        let ok = *s == 0;
        let z0 = z_row[0] * (o[0] - centre.x)
            + z_row[1] * (o[1] - centre.y)
            + z_row[2] * (o[2] - centre.z);
        let dz = z_row[0] * w[0] + z_row[1] * w[1] + z_row[2] * w[2];
        grid.origin.push(if ok { o } else { [f64::NAN; 3] });
        grid.dir.push(if ok { w } else { [f64::NAN; 3] });
        grid.z0.push(if ok { z0 } else { f64::NAN });
        grid.dz.push(if ok && dz > 0.0 { dz } else { f64::NAN });
    }
    grid
}

/// The hypotheses' inverse depths q_h = 1/z_max + h·(1/z_min − 1/z_max)/(N − 1), h = 0 … N − 1:
/// uniform in 1/z (uniform in disparity for a rectified pinhole pair), h = 0 the farthest.
pub fn inverse_depths(min_depth: f64, max_depth: f64, count: usize) -> Vec<f64> {
    let (far, near) = (1.0 / max_depth, 1.0 / min_depth);
    let step = (near - far) / (count.max(2) - 1) as f64;
    (0..count).map(|h| far + h as f64 * step).collect()
}

/// Stage 2, `hypothesis_points`: X(1/q) on the ray of every pixel of rows `first_row ..` (as many
/// as `points` holds), master frame; `placeholder` where the pixel has no ray or the depth is not
/// in the water along it (a point the projection rejects at once: the projecting camera's centre).
pub fn hypothesis_points(
    rays: &RayGrid,
    first_row: usize,
    inverse_depth: f64,
    placeholder: [f64; 3],
    points: &mut [[f64; 3]],
) {
    let z = 1.0 / inverse_depth;
    let first = first_row * rays.width;
    for (j, point) in points.iter_mut().enumerate() {
        *point = rays.point_at_depth(first + j, z).unwrap_or(placeholder);
    }
}
