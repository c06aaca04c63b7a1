//! Stage 3 tabulated: the projection of one depth hypothesis into a voting camera, exact on a
//! grid of nodes every [`TABLE_STEP`] reference pixels and bilinear in between, wherever a bound
//! on the interpolation error that the grid itself gives is within [`TABLE_TOLERANCE_PX`]; every
//! other pixel takes the exact projection ([`project_hypotheses`]).
//!
//! **Why it holds.** For a hypothesis at depth z, the voter's pixel p(x, y) of the point at depth
//! z on reference pixel (x, y)'s water ray is a smooth function of (x, y) wherever it has an
//! answer (back-projection, the point on the ray and the forward projection are smooth there).
//! On a cell [0, Δ]² the bilinear interpolant I·p of the corners' values errs by
//!
//!   |p − I·p| ≤ (Δ²/8)·(max |∂²p/∂x²| + max |∂²p/∂y²|)
//!
//! per component (linear interpolation along x errs by ≤ Δ²/8·max|p_xx| on each edge, then along
//! y by ≤ Δ²/8·max|p_yy|; the mixed term x·y is interpolated exactly). The central second
//! difference of the nodes, δ²ₓp = p(x − Δ) − 2p(x) + p(x + Δ), equals Δ²·p_xx(ξ) for some ξ
//! within a node of x, so with the largest |δ²| of the cell's four corners (each spanning the
//! cell and its neighbours) the bound is estimated as
//!
//!   e ≈ S/8·(max |δ²ₓp| + max |δ²ᵧp|),   S = [`BOUND_SAFETY`] = 2,
//!
//! the factor S for the second derivative's change within the three cells a difference spans.
//! A cell is interpolated when its four corners and the nodes of their differences have an
//! answer and √(e_u² + e_v²) ≤ [`TABLE_TOLERANCE_PX`]; `tests/stereo_table.rs` checks the
//! interpolated pixels against the exact projection over whole images.
//!
//! **The tolerance**, 0.02 px: hypotheses are spaced so that a step moves the projection by
//! about a pixel, so 0.02 px is 2 % of a step, under the parabola's own refinement (0.06 of a
//! step at the median on a noise-free plane). A sample's value moves by at most 0.02 px times the
//! image's gradient (bilinear sampling), a change that the ZNCC of a 7 × 7 window averages.
//!
//! **Where there is no answer.** The exact projection has none where the pixel has no water ray,
//! where the depth is not beyond the ray's origin (the point would be in the port) and where the
//! point is not beyond the voter's own port (in its air or glass); these are tested per pixel,
//! exactly enough: a pixel whose hypothesis lies within 1 µm (+1e-9 relative) of that limit, or
//! past it, takes the exact projection, which answers as it always does. Its other refusals
//! (behind the voter, beyond its lens's fold) lie where the projection runs off to infinity or
//! folds: second differences there exceed any tolerance, so those cells are projected exactly.

#[cfg(doc)]
use super::project::warp_bilinear;
use super::project::{air_ray_starts, project_hypotheses, sample_bilinear};
use super::rays::{RayGrid, rays_on_grid};
use super::sample::sample_row;
use crate::base::GreyImage;
use crate::model::RefractiveCamera;

/// Node spacing of the projection table, reference pixels: the exact projection runs on 1/64 of
/// the pixels (plus a node row above and below each band for the second differences).
pub const TABLE_STEP: usize = 8;
/// Largest estimated interpolation error of an interpolated cell, pixels of the voting camera.
pub const TABLE_TOLERANCE_PX: f64 = 0.02;
/// Safety factor S on the error bound estimated from the nodes' second differences.
pub const BOUND_SAFETY: f64 = 2.0;
/// Depth margin (metres, plus 1e-9 relative) beyond the limit where a point enters the voter's
/// water, within which the exact projection runs.
const WATER_MARGIN_M: f64 = 1e-6;

/// How stage 3 projects the hypothesis points into the voting cameras.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Projection {
    /// The exact forward projection of every pixel's point (Newton on the refraction equation).
    Exact,
    /// Exact on nodes every [`TABLE_STEP`] pixels, bilinear in between within
    /// [`TABLE_TOLERANCE_PX`], exact elsewhere (see the [module docs](self)).
    #[default]
    Tabulated,
}

/// The reference camera's water rays at the table's nodes: pixel (`step`·i, `step`·j) for
/// i = 0 … ⌊(w − 1)/step⌋ + 1 and j likewise (one node past the image's last pixel, so every
/// pixel's cell has four corners).
#[derive(Debug, Clone)]
pub struct ProjectionTable {
    step: usize,
    nodes: RayGrid,
}

impl ProjectionTable {
    /// The nodes of a `width` × `height` reference image of `camera`, every [`TABLE_STEP`] pixels.
    pub fn new(camera: &RefractiveCamera, width: usize, height: usize) -> Self {
        Self::with_step(camera, width, height, TABLE_STEP)
    }

    /// The nodes every `step` pixels (≥ 1).
    pub fn with_step(camera: &RefractiveCamera, width: usize, height: usize, step: usize) -> Self {
        let step = step.max(1);
        let columns = width.saturating_sub(1) / step + 2;
        let rows = height.saturating_sub(1) / step + 2;
        Self {
            step,
            nodes: rays_on_grid(camera, columns, rows, step),
        }
    }

    /// The node spacing, pixels.
    pub fn step(&self) -> usize {
        self.step
    }
}

/// What one call of [`project_tabulated`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TableCounts {
    /// Pixels interpolated.
    pub interpolated: usize,
    /// Pixels projected exactly (no answer nearby, or a cell over the tolerance).
    pub exact: usize,
    /// Nodes projected exactly.
    pub nodes: usize,
}

/// The tabulated projection's state for one band of reference rows and one voting camera: what
/// does not change with the hypothesis, and reused buffers.
#[derive(Debug, Clone)]
pub struct TableBand {
    width: usize,
    ext_first: usize,
    /// The band's node rows: `node_first ..` (`node_rows` of them).
    node_first: usize,
    node_rows: usize,
    node_starts: Vec<f64>,
    /// Per pixel of the band: the depth at or below which the exact projection runs (NaN: always).
    exact_below: Vec<f64>,
    /// Per band row and cell (`columns` a row): the largest `exact_below` of the cell's pixels
    /// in that row (∞ where one has no ray), so that a whole run of a cell's pixels is tested
    /// at once.
    cell_below: Vec<f64>,
    node_points: Vec<[f64; 3]>,
    node_pixels: Vec<[f64; 2]>,
    node_status: Vec<u32>,
    /// |δ²ₓ|, |δ²ᵧ| of u and v per node (∞ where a node of the difference has no answer).
    second: Vec<[f64; 4]>,
    /// Per cell of the band's node rows: interpolate?
    cell_ok: Vec<bool>,
    row_u: Vec<f64>,
    row_v: Vec<f64>,
    /// One band row's interpolated projections (NaN where the pixel is projected exactly).
    pixel_u: Vec<f64>,
    pixel_v: Vec<f64>,
    exact: Vec<usize>,
    exact_points: Vec<[f64; 3]>,
    exact_starts: Vec<f64>,
    exact_pixels: Vec<[f64; 2]>,
    exact_status: Vec<u32>,
}

impl TableBand {
    /// The state for the rows `ext_first .. ext_first + rows` of `rays` (the reference's rays)
    /// projected into `camera` through `table`.
    pub fn new(
        table: &ProjectionTable,
        rays: &RayGrid,
        ext_first: usize,
        rows: usize,
        camera: &RefractiveCamera,
    ) -> Self {
        let (w, step) = (rays.width, table.step);
        let node_height = table.nodes.height;
        let last_row = (ext_first + rows).max(1) - 1;
        // Cell rows of the band, their corner rows, and a node row more each side for δ²ᵧ.
        let (cell_first, cell_last) = (ext_first / step, last_row / step);
        let node_first = cell_first.saturating_sub(1);
        let node_end = (cell_last + 3).min(node_height);
        let node_rows = node_end - node_first;
        let node_count = node_rows * table.nodes.width;
        let mut node_starts = vec![0.0; node_count];
        air_ray_starts(&table.nodes, node_first, camera, &mut node_starts);
        // The voter's water begins where n·(X − C) = d_k + Σt: along o + s·w, at
        // s_k = (d_k + Σt − n·(o − C))/(n·w) when n·w > 0.
        let n = camera.normal().into_inner();
        let c = camera.centre().coords;
        let port = camera.air_distance() + camera.layers_thickness();
        let exact_below = (ext_first * w..(ext_first + rows) * w)
            .map(|i| {
                let (o, d) = (rays.origin[i], rays.dir[i]);
                let along = n.x * d[0] + n.y * d[1] + n.z * d[2];
                if !(along > 0.0) {
                    return f64::NAN;
                }
                let beyond = n.x * (o[0] - c.x) + n.y * (o[1] - c.y) + n.z * (o[2] - c.z);
                let s = ((port - beyond) / along).max(0.0);
                let z = rays.z0[i] + s * rays.dz[i];
                z + WATER_MARGIN_M + 1e-9 * z.abs()
            })
            .collect::<Vec<f64>>();
        let columns = table.nodes.width;
        let mut cell_below = vec![f64::NEG_INFINITY; rows * columns];
        for (k, row) in exact_below.chunks(w).enumerate() {
            for (x, &below) in row.iter().enumerate() {
                let cell = &mut cell_below[k * columns + x / step];
                // `max` would drop a NaN (no ray: always exact).
                *cell = if below.is_nan() {
                    f64::INFINITY
                } else {
                    cell.max(below)
                };
            }
        }
        Self {
            width: w,
            ext_first,
            node_first,
            node_rows,
            node_starts,
            exact_below,
            cell_below,
            node_points: vec![[0.0; 3]; node_count],
            node_pixels: vec![[0.0; 2]; node_count],
            node_status: vec![0; node_count],
            second: vec![[0.0; 4]; node_count],
            cell_ok: vec![false; node_count],
            row_u: vec![0.0; table.nodes.width],
            row_v: vec![0.0; table.nodes.width],
            pixel_u: vec![0.0; w],
            pixel_v: vec![0.0; w],
            exact: Vec::new(),
            exact_points: Vec::new(),
            exact_starts: Vec::new(),
            exact_pixels: Vec::new(),
            exact_status: Vec::new(),
        }
    }

    /// The band's pixels (indices from its first row) that the last [`project_tabulated`]
    /// projected exactly.
    pub fn exact_pixels(&self) -> &[usize] {
        &self.exact
    }

    /// The cells of the band's node rows with their four corners' second differences: whether
    /// each is interpolated (row-major over the table's node columns, rows from `node_first`).
    fn mark_cells(&mut self, columns: usize) {
        let rows = self.node_rows;
        let (pixels, status) = (&self.node_pixels, &self.node_status);
        let value = |i: usize| -> Option<[f64; 2]> { (status[i] == 0).then(|| pixels[i]) };
        // |p(a) − 2p(b) + p(c)| per component, ∞ without an answer.
        let difference = |a: usize, b: usize, c: usize| -> [f64; 2] {
            match (value(a), value(b), value(c)) {
                (Some(a), Some(b), Some(c)) => [
                    (a[0] - 2.0 * b[0] + c[0]).abs(),
                    (a[1] - 2.0 * b[1] + c[1]).abs(),
                ],
                _ => [f64::INFINITY; 2],
            }
        };
        let enough = columns >= 3 && rows >= 3;
        for j in 0..rows {
            for i in 0..columns {
                self.second[j * columns + i] = if enough {
                    // At the grid's border the neighbour's difference stands in.
                    let ci = i.clamp(1, columns - 2);
                    let cj = j.clamp(1, rows - 2);
                    let at = |jj: usize, ii: usize| jj * columns + ii;
                    let x = difference(at(j, ci - 1), at(j, ci), at(j, ci + 1));
                    let y = difference(at(cj - 1, i), at(cj, i), at(cj + 1, i));
                    [x[0], y[0], x[1], y[1]]
                } else {
                    [f64::INFINITY; 4]
                };
            }
        }
        let tolerance = TABLE_TOLERANCE_PX;
        for j in 0..rows.saturating_sub(1) {
            for i in 0..columns - 1 {
                let corners = [
                    j * columns + i,
                    j * columns + i + 1,
                    (j + 1) * columns + i,
                    (j + 1) * columns + i + 1,
                ];
                let answered = corners.iter().all(|&k| status[k] == 0);
                let mut largest = [0f64; 4];
                for &k in &corners {
                    for (m, s) in largest.iter_mut().zip(self.second[k]) {
                        *m = m.max(s);
                    }
                }
                let e_u = BOUND_SAFETY / 8.0 * (largest[0] + largest[1]);
                let e_v = BOUND_SAFETY / 8.0 * (largest[2] + largest[3]);
                self.cell_ok[j * columns + i] = answered && e_u.hypot(e_v) <= tolerance;
            }
        }
    }
}

/// Stage 3 tabulated, `project_tabulated`: the projections into `camera` of the points at depth
/// 1/`inverse_depth` on the rays of the band's rows (`pixels`, `status` as
/// [`project_hypotheses`] writes them for those points, `starts` its starts from
/// [`air_ray_starts`]): exact at the nodes, bilinear within the cells whose error bound is within
/// [`TABLE_TOLERANCE_PX`], exact elsewhere (see the [module docs](self)). A pixel without an
/// answer gets the exact projection's status.
#[allow(clippy::too_many_arguments)]
pub fn project_tabulated(
    table: &ProjectionTable,
    band: &mut TableBand,
    rays: &RayGrid,
    camera: &RefractiveCamera,
    starts: &[f64],
    inverse_depth: f64,
    pixels: &mut [[f64; 2]],
    status: &mut [u32],
) -> TableCounts {
    let rows = pixels.len() / band.width;
    let counts = tabulate(
        table,
        band,
        rays,
        camera,
        starts,
        inverse_depth,
        rows,
        |k, u, v| {
            let row = k * u.len();
            for (x, (&u, &v)) in u.iter().zip(v).enumerate() {
                if !u.is_nan() {
                    pixels[row + x] = [u, v];
                    status[row + x] = 0;
                }
            }
        },
    );
    for (n, &j) in band.exact.iter().enumerate() {
        pixels[j] = band.exact_pixels[n];
        status[j] = band.exact_status[n];
    }
    counts
}

/// Stages 3 and 4a fused, `warp_tabulated`: `image` sampled bilinearly at the projections
/// [`project_tabulated`] gives (`warped`, one value per pixel of the band's rows, as
/// [`warp_bilinear`] writes them), each row's interpolated projections sampled as soon as the
/// row is made, 8 at a time where the processor gathers (`stereo/sample.rs`). The same values
/// as [`warp_bilinear`] of [`project_tabulated`]'s output, bit for bit, without the band's
/// projections ever stored: at 1280 pixels a row those were 16 bytes a pixel written and read
/// back per hypothesis, which pushed the voter's image out of the cache (`docs/performance.md`).
#[allow(clippy::too_many_arguments)]
pub fn warp_tabulated(
    table: &ProjectionTable,
    band: &mut TableBand,
    rays: &RayGrid,
    camera: &RefractiveCamera,
    starts: &[f64],
    inverse_depth: f64,
    image: &GreyImage,
    warped: &mut [f32],
) -> TableCounts {
    let (w, h) = (image.width as usize, image.height as usize);
    let rows = warped.len() / band.width;
    let counts = tabulate(
        table,
        band,
        rays,
        camera,
        starts,
        inverse_depth,
        rows,
        |k, u, v| {
            let row = &mut warped[k * u.len()..(k + 1) * u.len()];
            sample_row(&image.pixels, w, h, u, v, row);
        },
    );
    for (n, &j) in band.exact.iter().enumerate() {
        warped[j] = if band.exact_status[n] == 0 {
            let p = band.exact_pixels[n];
            sample_bilinear(&image.pixels, w, h, p[0], p[1])
        } else {
            f32::NAN
        };
    }
    counts
}

crate::engine::cpu::lanes::dispatched! {
    /// One row's projections (`u`, `v`, a value per pixel) interpolated along x within every
    /// cell of `fractions.len()` pixels from the row's values at the node columns (`row_u`,
    /// `row_v`): u₀ + f·(u₁ − u₀) with f = (x − x₀)/step, the weights `fractions`.
    fn interpolate_row(row_u: &[f64], row_v: &[f64], fractions: &[f64], u: &mut [f64], v: &mut [f64]) {
        let step = fractions.len();
        for (i, (u, v)) in u.chunks_mut(step).zip(v.chunks_mut(step)).enumerate() {
            let (u0, du) = (row_u[i], row_u[i + 1] - row_u[i]);
            let (v0, dv) = (row_v[i], row_v[i + 1] - row_v[i]);
            if let (Ok(u), Ok(v), Ok(f)) = (
                <&mut [f64; TABLE_STEP]>::try_from(&mut *u),
                <&mut [f64; TABLE_STEP]>::try_from(&mut *v),
                <&[f64; TABLE_STEP]>::try_from(fractions),
            ) {
                // A whole cell of the default step: fixed lengths, one vector operation each.
                for j in 0..TABLE_STEP {
                    u[j] = u0 + f[j] * du;
                    v[j] = v0 + f[j] * dv;
                }
            } else {
                for ((u, v), &f) in u.iter_mut().zip(v.iter_mut()).zip(fractions) {
                    *u = u0 + f * du;
                    *v = v0 + f * dv;
                }
            }
        }
    }
}

/// The tabulated projection of the band's first `rows` rows: each row's interpolated pixels
/// handed to `interpolated_row(row in the band, u, v)` (a row's w values each, NaN where the
/// pixel is not interpolated), the others listed in `band.exact` with their exact projections in
/// `band.exact_pixels` and `band.exact_status`.
#[allow(clippy::too_many_arguments)]
fn tabulate(
    table: &ProjectionTable,
    band: &mut TableBand,
    rays: &RayGrid,
    camera: &RefractiveCamera,
    starts: &[f64],
    inverse_depth: f64,
    rows: usize,
    mut interpolated_row: impl FnMut(usize, &[f64], &[f64]),
) -> TableCounts {
    let (w, step) = (band.width, table.step);
    let columns = table.nodes.width;
    let z = 1.0 / inverse_depth;
    let placeholder: [f64; 3] = camera.centre().coords.into();
    // The nodes, exact.
    let first_node = band.node_first * columns;
    for (j, point) in band.node_points.iter_mut().enumerate() {
        *point = table
            .nodes
            .point_at_depth(first_node + j, z)
            .unwrap_or(placeholder);
    }
    project_hypotheses(
        camera,
        &band.node_points,
        &band.node_starts,
        &mut band.node_pixels,
        &mut band.node_status,
    );
    band.mark_cells(columns);
    // The pixels: bilinear (first along y for the row, then along x) where the cell allows and
    // the point is in the voter's water, else queued for the exact projection.
    band.exact.clear();
    let inv_step = 1.0 / step as f64;
    // (x − x0)/step within a cell, as the interpolation's weight.
    let fractions: Vec<f64> = (0..step).map(|j| j as f64 * inv_step).collect();
    let mut interpolated = 0;
    for k in 0..rows {
        let y = band.ext_first + k;
        let cell_row = y / step - band.node_first;
        let fy = (y % step) as f64 * inv_step;
        let (top, bottom) = (cell_row * columns, (cell_row + 1) * columns);
        for i in 0..columns {
            let (a, b) = (band.node_pixels[top + i], band.node_pixels[bottom + i]);
            band.row_u[i] = a[0] + fy * (b[0] - a[0]);
            band.row_v[i] = a[1] + fy * (b[1] - a[1]);
        }
        let ok = &band.cell_ok[top..top + columns];
        let below = &band.exact_below[k * w..(k + 1) * w];
        let cell_below = &band.cell_below[k * columns..(k + 1) * columns];
        // Every cell interpolated at once (vectorised), then the cells that may not be
        // interpolated everywhere: their pixels that may not are marked and queued.
        interpolate_row(
            &band.row_u,
            &band.row_v,
            &fractions,
            &mut band.pixel_u,
            &mut band.pixel_v,
        );
        interpolated += w;
        for (i, x0) in (0..w).step_by(step).enumerate() {
            // `z > NaN` is false: a pixel without a ray takes the exact path.
            if ok[i] && z > cell_below[i] {
                continue;
            }
            let x1 = (x0 + step).min(w);
            for (x, &limit) in (x0..x1).zip(&below[x0..x1]) {
                if !(ok[i] && z > limit) {
                    (band.pixel_u[x], band.pixel_v[x]) = (f64::NAN, f64::NAN);
                    band.exact.push(k * w + x);
                    interpolated -= 1;
                }
            }
        }
        interpolated_row(k, &band.pixel_u, &band.pixel_v);
    }
    // The rest, exact: the same points and starts as `project_hypotheses` on every pixel.
    let first = band.ext_first * w;
    band.exact_points.clear();
    band.exact_starts.clear();
    for &j in &band.exact {
        band.exact_points
            .push(rays.point_at_depth(first + j, z).unwrap_or(placeholder));
        band.exact_starts.push(starts[j]);
    }
    let count = band.exact.len();
    band.exact_pixels.resize(count, [0.0; 2]);
    band.exact_status.resize(count, 0);
    project_hypotheses(
        camera,
        &band.exact_points,
        &band.exact_starts,
        &mut band.exact_pixels,
        &mut band.exact_status,
    );
    TableCounts {
        interpolated,
        exact: count,
        nodes: band.node_points.len(),
    }
}
