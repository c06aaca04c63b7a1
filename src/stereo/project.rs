//! Stages 3 and 4a of the sweep, shared by the exact path ([`super::cost`]) and the tabulated
//! one ([`super::table`]): the exact forward projection of the hypothesis points into a voting
//! camera, where its Newton iterations start, and the bilinear samples of the voter's image.

use super::rays::RayGrid;
use crate::base::GreyImage;
use crate::engine::cpu::lanes;
use crate::model::RefractiveCamera;

/// Stage 3, `project_hypotheses`: the exact forward projection of `points` into `camera` by the
/// engine's vector path, each from `tan_starts` (the tan a of an air ray near the point's, from
/// [`air_ray_starts`]): Newton from there settles in two or three steps, and a point it does not
/// settle takes the safeguarded projection (`lanes::project_near_all`).
pub fn project_hypotheses(
    camera: &RefractiveCamera,
    points: &[[f64; 3]],
    tan_starts: &[f64],
    pixels: &mut [[f64; 2]],
    status: &mut [u32],
) {
    lanes::project_near_all(camera, points, tan_starts, pixels, status);
}

/// Where [`project_hypotheses`] starts for the points on the reference rays of rows
/// `first_row ..` (as many as `starts` holds): the tan a, in `camera`'s air, of a ray that leaves
/// its port in the direction of the reference ray in the water (Snell across the parallel layers:
/// sin a = ρ_w·|w × n|). The camera sees a point of that ray from a viewpoint a baseline away, so
/// its own ray is within the parallax angle of it. 0 where the pixel has no ray or the angle is
/// past the critical one.
pub fn air_ray_starts(
    rays: &RayGrid,
    first_row: usize,
    camera: &RefractiveCamera,
    starts: &mut [f64],
) {
    let n = camera.normal().into_inner();
    let rho = camera.relative_index_water();
    let first = first_row * rays.width;
    for (j, start) in starts.iter_mut().enumerate() {
        let w = rays.dir[first + j];
        let cos = (w[0] * n.x + w[1] * n.y + w[2] * n.z).abs().min(1.0);
        let sin = rho * (1.0 - cos * cos).sqrt();
        // A NaN direction (no ray) gives cos 1 (`min` drops the NaN): start 0.
        *start = if sin < 1.0 {
            sin / (1.0 - sin * sin).sqrt()
        } else {
            0.0
        };
    }
}

/// Stage 4a, `warp_bilinear`: the image sampled bilinearly at `pixels` ((0, 0) the centre of the
/// top-left pixel); NaN where the projection has no answer or falls outside [0, w − 1] × [0, h − 1].
pub fn warp_bilinear(image: &GreyImage, pixels: &[[f64; 2]], status: &[u32], warped: &mut [f32]) {
    let (w, h) = (image.width as usize, image.height as usize);
    for ((p, s), out) in pixels.iter().zip(status).zip(warped.iter_mut()) {
        *out = if *s == 0 {
            sample_bilinear(&image.pixels, w, h, p[0], p[1])
        } else {
            f32::NAN
        };
    }
}

/// One bilinear sample of the `w` × `h` image `pixels` at (u, v), (0, 0) the centre of the
/// top-left pixel; NaN outside [0, w − 1] × [0, h − 1].
///
/// Scalar on purpose: a branch-free version written for the vector units (the four samples
/// gathered) compiled to scalar code all the same and was no faster; what costs here is the wait
/// for the image's cache lines, which `table::warp_tabulated` keeps short by sampling where it
/// interpolates instead of storing the projections first.
#[inline(always)]
pub(crate) fn sample_bilinear(pixels: &[f32], w: usize, h: usize, u: f64, v: f64) -> f32 {
    if !(u >= 0.0 && u <= (w - 1) as f64 && v >= 0.0 && v <= (h - 1) as f64) {
        return f32::NAN;
    }
    // The cell's top-left corner, kept one short of the last row/column so that its neighbours
    // exist (u = w − 1 is then the cell's right edge, fx = 1); a single row or column is its own
    // neighbour. u, v ≥ 0 here, so truncation is the floor (an instruction, where `floor` is a
    // libm call on the baseline x86-64 target).
    let x0 = (u as usize).min(w.saturating_sub(2));
    let y0 = (v as usize).min(h.saturating_sub(2));
    let (fx, fy) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let at = |x: usize, y: usize| pixels[y * w + x];
    let top = at(x0, y0) + fx * (at(x1, y0) - at(x0, y0));
    let bottom = at(x0, y1) + fx * (at(x1, y1) - at(x0, y1));
    top + fy * (bottom - top)
}
