//! Images of a board (a chessboard or a ChArUco board, [`BoardSpec`]) in the water as a camera
//! sees it through the port: every pixel is
//! back-projected through the interface by the [`Engine`] (on the GPU the pixel grid is made in
//! the shader, [`backproject_rows`]), the water ray meets the board's plane, and the board's
//! albedo there is the pixel's value. Anti-aliasing by supersampling, optional Gaussian blur and
//! noise. Lens distortion comes with the back-projection (pixels are undistorted first).
//!
//! Supersampling: the board coordinates of a pixel's sub-samples come from the affine map of that
//! pixel (its centre's board point and the central differences to its neighbours' centres); the
//! map from pixels to the board is smooth (perspective, refraction, distortion), so over one pixel
//! this is exact to about 10⁻⁴ px (second derivative ≈ tan(board tilt)/f per pixel). Only pixels
//! whose footprint crosses an edge of the pattern are supersampled; the others are uniform. A
//! pixel whose centre and four neighbours' centres all see the water is water: the board's outer
//! edge may clip a corner of such a pixel's footprint (less than an eighth of it), never an edge
//! of the pattern, so the corners are unaffected.
//!
//! ChArUco boards are drawn in OpenCV's layout ([`crate::detect::board`]): the same squares, a
//! marker centred in every white square from the dictionary's bits (the bits calib-targets decodes),
//! and the white margin of `border_squares` around them as OpenCV's `generateImage` leaves its
//! margin (tests/charuco.rs compares the pattern with OpenCV's image pixel for pixel). Every marker
//! cell and every white strip around a marker is its own uniform cell for the supersampling.
//!
//! What real cameras add (defocus, motion blur, vignetting, uneven light, low contrast,
//! backscatter, sensor noise, JPEG and H.264): [`imaging`], applied after the blur and noise.
//!
//! Textured scenes (planes, height fields and spheres with procedural or image textures) and
//! their exact depth maps: [`scene`], [`textured`].

pub mod imaging;
pub use crate::base::noise;
pub mod scene;
pub mod textured;

/// The images rendered here are the stereo matcher's input.
pub use crate::base::GreyImage;
pub use imaging::Imaging;
pub use scene::{
    Extent, Hit, ImageTexture, Relief, Shape, Sphere, Surface, SurfaceFrame, Texture,
    TexturedScene, Wave,
};
pub use textured::{RenderedView, render_textured};

use nalgebra::{Isometry3, Point3, Vector3};
use thiserror::Error;

use crate::base::Board;
use crate::base::Rng;
use crate::base::board_spec::{BoardSpec, CharucoSpec};
use crate::engine::raymap::{backproject_rows, rows_per_band};
use crate::engine::{Engine, EngineError};
use crate::model::RefractiveCamera;

/// Grey levels (0 … 1) of the rendered scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shades {
    /// The board's black squares.
    pub black: f64,
    /// The board's white squares and its white border.
    pub white: f64,
    /// Everything that is not the board (the water).
    pub background: f64,
}

impl Default for Shades {
    /// Black 0.12, white 0.85, water 0.40: a printed board under water, not a perfect one.
    fn default() -> Self {
        Self {
            black: 0.12,
            white: 0.85,
            background: 0.40,
        }
    }
}

/// How to render.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    /// Sub-samples per axis of a pixel that crosses an edge of the pattern (1 = no anti-aliasing).
    pub supersample: u32,
    /// Standard deviation of the Gaussian blur, pixels (0 = none).
    pub blur_px: f64,
    /// Standard deviation of the Gaussian noise, grey levels of 255 (0 = none).
    pub noise: f64,
    /// Seed of the noise.
    pub seed: u64,
    /// White border around the outer squares, in squares.
    pub border_squares: f64,
    /// Grey levels.
    pub shades: Shades,
    /// What a real camera adds, after the blur and the noise ([`Imaging::apply`] with the seed
    /// above as the image's index; H.264 is a sequence's, not applied here). Default: nothing.
    pub imaging: Imaging,
}

impl Default for RenderOptions {
    /// 8 × 8 sub-samples on edges, no blur, no noise, a white border of one square, no imaging
    /// effects.
    fn default() -> Self {
        Self {
            supersample: 8,
            blur_px: 0.0,
            noise: 0.0,
            seed: 1,
            border_squares: 1.0,
            shades: Shades::default(),
            imaging: Imaging::default(),
        }
    }
}

/// Why an image could not be rendered.
#[derive(Debug, Error)]
pub enum RenderError {
    /// The engine failed (GPU lost, …).
    #[error(transparent)]
    Engine(#[from] EngineError),
    /// An option out of range.
    #[error("render option {option}: {reason}")]
    Option {
        /// The option.
        option: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// An imaging effect failed (JPEG, H.264: `ffmpeg` missing or failing).
    #[error("{effect}: {reason}")]
    Imaging {
        /// The effect.
        effect: &'static str,
        /// What went wrong, and what to install where a tool is missing.
        reason: String,
    },
}

/// Pixels per band of the back-projection: bounds memory (48 bytes a ray) whatever the image.
const BAND_PIXELS: usize = 1 << 18;

/// The pattern drawn on the board's plane.
#[derive(Debug, Clone, Copy)]
enum Pattern<'a> {
    Chessboard(&'a Board),
    Charuco(&'a CharucoSpec),
}

impl Pattern<'_> {
    /// The inner corner grid: the outer squares span [−1, cols] × [−1, rows] in squares.
    fn grid(&self) -> Board {
        match self {
            Pattern::Chessboard(board) => **board,
            Pattern::Charuco(spec) => spec.corner_grid(),
        }
    }
}

/// Where (fx, fy) ∈ [0, 1)² of white square (a, b) lies along each axis: 0 before the marker,
/// 1 … bits + 2 its cells, bits + 3 after it; `None` for a square without a marker.
fn marker_cell(
    spec: &CharucoSpec,
    a: i64,
    b: i64,
    fx: f64,
    fy: f64,
) -> Option<(usize, usize, usize)> {
    let id = spec.marker_at_square(usize::try_from(a).ok()?, usize::try_from(b).ok()?)?;
    let relative = spec.marker_size_m / spec.square_size_m;
    let start = 0.5 * (1.0 - relative);
    let cells = spec.marker_bits() + 2;
    let along = |f: f64| {
        let t = (f - start) / relative;
        if t < 0.0 {
            0
        } else if t >= 1.0 {
            cells + 1
        } else {
            ((t * cells as f64) as usize).min(cells - 1) + 1
        }
    };
    Some((id, along(fx), along(fy)))
}

/// What lies at board point (x, y) in squares (corner `(c, r)` at (c, r)): 0 black, 1 white
/// (squares, markers' white bits and the border), 2 background. The outer squares span
/// [−1, cols] × [−1, rows]; square (a, b) = (⌊x⌋ + 1, ⌊y⌋ + 1) is black when a + b is even, so
/// the square at corner 0's outer diagonal is black (OpenCV's top-left ChArUco square too).
fn region(pattern: &Pattern, border: f64, x: f64, y: f64) -> u8 {
    let grid = pattern.grid();
    let (cols, rows) = (grid.cols as f64, grid.rows as f64);
    if !(x >= -1.0 - border && x <= cols + border && y >= -1.0 - border && y <= rows + border) {
        return 2; // also NaN: a ray that does not reach the board
    }
    if x < -1.0 || x >= cols || y < -1.0 || y >= rows {
        return 1;
    }
    let (a, b) = ((x.floor() as i64) + 1, (y.floor() as i64) + 1);
    if (a + b) % 2 == 0 {
        return 0;
    }
    match pattern {
        Pattern::Chessboard(_) => 1,
        Pattern::Charuco(spec) => match marker_cell(spec, a, b, x - x.floor(), y - y.floor()) {
            // Inside the marker (cells 1 … bits + 2 along both axes) and black there.
            Some((id, i, j))
                if (1..=spec.marker_bits() + 2).contains(&i)
                    && (1..=spec.marker_bits() + 2).contains(&j)
                    && spec.marker_cell_is_black(id, i - 1, j - 1) =>
            {
                0
            }
            _ => 1,
        },
    }
}

/// Which cell of the pattern a board point lies in: equal cells have equal shade and are convex
/// (a square; in a ChArUco white square, a marker cell or one of the rectangles of the white
/// strip around the marker), so a pixel whose footprint's four corners share a cell is uniform.
fn cell(pattern: &Pattern, border: f64, x: f64, y: f64) -> (u8, i64, i64, usize, usize) {
    let grid = pattern.grid();
    match region(pattern, border, x, y) {
        0 | 1 if x >= -1.0 && x < grid.cols as f64 && y >= -1.0 && y < grid.rows as f64 => {
            let (i, j) = (x.floor() as i64, y.floor() as i64);
            let sub = match pattern {
                Pattern::Charuco(spec) => {
                    marker_cell(spec, i + 1, j + 1, x - x.floor(), y - y.floor())
                        .map_or((0, 0), |(_, u, v)| (u, v))
                }
                Pattern::Chessboard(_) => (0, 0),
            };
            (0, i, j, sub.0, sub.1)
        }
        r => (r + 1, 0, 0, 0, 0),
    }
}

/// Renders `camera`'s image of the chessboard `board` at `master_from_board` (X_master =
/// R·X_board + t).
pub fn render_board(
    engine: &Engine,
    camera: &RefractiveCamera,
    board: &Board,
    master_from_board: &Isometry3<f64>,
    options: &RenderOptions,
) -> Result<GreyImage, RenderError> {
    render_pattern(
        engine,
        camera,
        Pattern::Chessboard(board),
        master_from_board,
        options,
    )
}

/// Renders `camera`'s image of the board `spec` describes (a chessboard or a ChArUco board) at
/// `master_from_board` (X_master = R·X_board + t, the board frame of its corner grid: corner 0 at
/// the origin, [`BoardSpec::corner_grid`]).
pub fn render_board_spec(
    engine: &Engine,
    camera: &RefractiveCamera,
    spec: &BoardSpec,
    master_from_board: &Isometry3<f64>,
    options: &RenderOptions,
) -> Result<GreyImage, RenderError> {
    let pattern = match spec {
        BoardSpec::Chessboard(board) => Pattern::Chessboard(board),
        BoardSpec::Charuco(charuco) => Pattern::Charuco(charuco),
    };
    render_pattern(engine, camera, pattern, master_from_board, options)
}

fn render_pattern(
    engine: &Engine,
    camera: &RefractiveCamera,
    pattern: Pattern,
    master_from_board: &Isometry3<f64>,
    options: &RenderOptions,
) -> Result<GreyImage, RenderError> {
    check_options(options)?;
    let board = &pattern.grid();
    let pattern = &pattern;
    let intrinsics = camera.intrinsics();
    let (width, height) = (intrinsics.width, intrinsics.height);
    let board_points = board_points(engine, camera, board, master_from_board)?;
    let (w, h) = (width as usize, height as usize);
    let shades = options.shades;
    let shade = |r: u8| match r {
        0 => shades.black,
        1 => shades.white,
        _ => shades.background,
    };
    let n = options.supersample.max(1) as usize;
    let border = options.border_squares;
    let mut pixels = vec![0f32; w * h];
    use rayon::prelude::*;
    pixels.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        for (u, out) in row.iter_mut().enumerate() {
            let p = board_points[v * w + u];
            if !(p[0].is_finite() && p[1].is_finite()) {
                *out = shades.background as f32;
                continue;
            }
            let at = |uu: usize, vv: usize| board_points[vv * w + uu];
            // Water all round: the pixel's centre and its four neighbours' centres see the water
            // (most pixels; the pattern's features are many pixels wide, the white border too).
            let water = |q: [f64; 2]| region(pattern, border, q[0], q[1]) == 2;
            if water(p)
                && (u == 0 || water(at(u - 1, v)))
                && (u + 1 == w || water(at(u + 1, v)))
                && (v == 0 || water(at(u, v - 1)))
                && (v + 1 == h || water(at(u, v + 1)))
            {
                *out = shades.background as f32;
                continue;
            }
            // Central differences (one-sided at the border or next to a pixel without a ray).
            let diff = |a: Option<[f64; 2]>, b: Option<[f64; 2]>, scale: f64| match (a, b) {
                (Some(a), Some(b)) if a[0].is_finite() && b[0].is_finite() => {
                    Some([(b[0] - a[0]) * scale, (b[1] - a[1]) * scale])
                }
                _ => None,
            };
            let left = (u > 0).then(|| at(u - 1, v));
            let right = (u + 1 < w).then(|| at(u + 1, v));
            let up = (v > 0).then(|| at(u, v - 1));
            let down = (v + 1 < h).then(|| at(u, v + 1));
            let du = diff(left, right, 0.5)
                .or_else(|| diff(Some(p), right, 1.0))
                .or_else(|| diff(left, Some(p), 1.0));
            let dv = diff(up, down, 0.5)
                .or_else(|| diff(Some(p), down, 1.0))
                .or_else(|| diff(up, Some(p), 1.0));
            let (Some(du), Some(dv)) = (du, dv) else {
                *out = shade(region(pattern, border, p[0], p[1])) as f32;
                continue;
            };
            let sample =
                |a: f64, b: f64| [p[0] + a * du[0] + b * dv[0], p[1] + a * du[1] + b * dv[1]];
            let corners = [
                sample(-0.5, -0.5),
                sample(0.5, -0.5),
                sample(-0.5, 0.5),
                sample(0.5, 0.5),
            ];
            let first = cell(pattern, border, corners[0][0], corners[0][1]);
            if n == 1
                || corners[1..]
                    .iter()
                    .all(|c| cell(pattern, border, c[0], c[1]) == first)
            {
                *out = shade(region(pattern, border, p[0], p[1])) as f32;
                continue;
            }
            let mut sum = 0.0;
            for i in 0..n {
                for j in 0..n {
                    let (a, b) = (
                        (i as f64 + 0.5) / n as f64 - 0.5,
                        (j as f64 + 0.5) / n as f64 - 0.5,
                    );
                    let q = sample(a, b);
                    sum += shade(region(pattern, border, q[0], q[1]));
                }
            }
            *out = (sum / (n * n) as f64) as f32;
        }
    });
    let image = GreyImage {
        width,
        height,
        pixels,
    };
    finish_image(image, options)
}

/// The options' Gaussian blur, then their Gaussian noise (one generator per image row, seeded
/// from the seed and the row: the same image whatever the number of threads), then their imaging
/// effects (the seed as the image's index).
pub(crate) fn finish_image(
    mut image: GreyImage,
    options: &RenderOptions,
) -> Result<GreyImage, RenderError> {
    use rayon::prelude::*;
    let w = image.width as usize;
    if options.blur_px > 0.0 {
        image = blur(&image, options.blur_px);
    }
    if options.noise > 0.0 {
        let sigma = (options.noise / 255.0) as f32;
        let seed = options.seed;
        image
            .pixels
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(v, row)| {
                let mut rng = Rng::new(
                    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
                        .wrapping_add(v as u64),
                );
                // Marsaglia's polar method: two normal deviates per accepted point, no trigonometry.
                for pair in row.chunks_mut(2) {
                    let (x, y, s) = loop {
                        let (x, y) = (2.0 * rng.uniform() - 1.0, 2.0 * rng.uniform() - 1.0);
                        let s = x * x + y * y;
                        if s > 0.0 && s < 1.0 {
                            break (x, y, s);
                        }
                    };
                    let scale = sigma * (-2.0 * s.ln() / s).sqrt() as f32;
                    pair[0] += scale * x as f32;
                    if let Some(p) = pair.get_mut(1) {
                        *p += scale * y as f32;
                    }
                }
            });
    }
    options.imaging.apply(&mut image, options.seed)?;
    Ok(image)
}

fn check_options(options: &RenderOptions) -> Result<(), RenderError> {
    let bad = |option, reason: String| Err(RenderError::Option { option, reason });
    if !(1..=32).contains(&options.supersample) {
        return bad(
            "supersample",
            format!("1 to 32 sub-samples per axis, got {}", options.supersample),
        );
    }
    if !(options.blur_px >= 0.0 && options.blur_px <= 20.0) {
        return bad("blur", format!("0 to 20 px, got {}", options.blur_px));
    }
    if !(options.noise >= 0.0 && options.noise <= 100.0) {
        return bad(
            "noise",
            format!("0 to 100 grey levels, got {}", options.noise),
        );
    }
    if !(options.border_squares >= 0.0 && options.border_squares <= 100.0) {
        return bad(
            "border",
            format!("0 to 100 squares, got {}", options.border_squares),
        );
    }
    options.imaging.check()
}

/// The board point (in squares) each pixel centre sees, NaN where its ray has no answer or does
/// not meet the board's plane in front of the port.
fn board_points(
    engine: &Engine,
    camera: &RefractiveCamera,
    board: &Board,
    master_from_board: &Isometry3<f64>,
) -> Result<Vec<[f64; 2]>, RenderError> {
    let (width, height) = (camera.intrinsics().width, camera.intrinsics().height);
    let normal: Vector3<f64> = master_from_board.rotation * Vector3::z();
    let origin: Point3<f64> = master_from_board * Point3::origin();
    let board_from_master = master_from_board.inverse();
    let band = rows_per_band(width, BAND_PIXELS);
    let mut points = Vec::with_capacity(width as usize * height as usize);
    let mut rays = Vec::new();
    let mut status = Vec::new();
    let mut first = 0;
    while first < height {
        let rows = band.min(height - first);
        let count = rows as usize * width as usize;
        rays.resize(count, [0.0; 6]);
        status.resize(count, 0);
        backproject_rows(engine, camera, first, rows, &mut rays, &mut status)?;
        points.extend(rays.iter().zip(&status).map(|(r, &s)| {
            if s != 0 {
                return [f64::NAN; 2];
            }
            let (o, d) = (
                Point3::new(r[0], r[1], r[2]),
                Vector3::new(r[3], r[4], r[5]),
            );
            // o + s·d on the plane n·(X − origin) = 0, in front of the port.
            let s = normal.dot(&(origin - o)) / normal.dot(&d);
            if !(s > 0.0 && s.is_finite()) {
                return [f64::NAN; 2];
            }
            let p = board_from_master * (o + s * d);
            [p.x / board.square, p.y / board.square]
        }));
        first += rows;
    }
    Ok(points)
}

/// Gaussian blur of standard deviation `sigma` pixels (the `image` crate's).
fn blur(image: &GreyImage, sigma: f64) -> GreyImage {
    let buffer = image::ImageBuffer::<image::Luma<f32>, Vec<f32>>::from_raw(
        image.width,
        image.height,
        image.pixels.clone(),
    )
    .expect("width · height pixels");
    let blurred = image::imageops::blur(&buffer, sigma as f32);
    GreyImage {
        width: image.width,
        height: image.height,
        pixels: blurred.into_raw(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pattern_has_a_black_square_at_corner_zero_and_alternates() {
        let board = Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        };
        assert_eq!(
            region(&Pattern::Chessboard(&board), 1.0, -0.5, -0.5),
            0,
            "the outer square at corner 0 is black"
        );
        assert_eq!(region(&Pattern::Chessboard(&board), 1.0, 0.5, -0.5), 1);
        assert_eq!(region(&Pattern::Chessboard(&board), 1.0, 0.5, 0.5), 0);
        // 10 × 7 squares: the opposite corner square has the other colour.
        assert_eq!(region(&Pattern::Chessboard(&board), 1.0, 8.5, 5.5), 1);
        assert_eq!(
            region(&Pattern::Chessboard(&board), 1.0, -1.5, 2.0),
            1,
            "white border"
        );
        assert_eq!(
            region(&Pattern::Chessboard(&board), 1.0, -2.5, 2.0),
            2,
            "water beyond the border"
        );
        assert_eq!(region(&Pattern::Chessboard(&board), 1.0, f64::NAN, 0.0), 2);
    }

    /// The ChArUco pattern equals OpenCV 4.14's `CharucoBoard.generateImage` pixel for pixel
    /// (scripts/charuco_golden.py: whole pixels per marker cell, so every pixel is one colour):
    /// the squares' colours, which squares carry markers, the marker ids, their bits and their
    /// placement, the white margin.
    #[test]
    fn the_charuco_pattern_is_opencvs() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden/charuco");
        let golden: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("charuco.json")).unwrap())
                .unwrap();
        let flat = golden["flat"].as_array().unwrap();
        assert_eq!(flat.len(), 2);
        for board in flat {
            let get = |k: &str| board[k].as_u64().unwrap() as usize;
            let (px, margin) = (get("px_per_square") as f64, get("margin_px") as f64);
            let spec = CharucoSpec::new(
                get("squares_x"),
                get("squares_y"),
                px,
                get("marker_px") as f64,
                board["dictionary"].as_str().unwrap(),
                false,
            )
            .unwrap();
            let image = image::open(dir.join(board["file"].as_str().unwrap()))
                .unwrap()
                .to_luma8();
            let pattern = Pattern::Charuco(&spec);
            let mut wrong = Vec::new();
            for (u, v, p) in image.enumerate_pixels() {
                // Pixel centre → squares from corner 0 (one square in from the board's top-left).
                let x = (u as f64 + 0.5 - margin) / px - 1.0;
                let y = (v as f64 + 0.5 - margin) / px - 1.0;
                let ours = match region(&pattern, margin / px, x, y) {
                    0 => 0,
                    1 => 255,
                    _ => 128,
                };
                if ours != p.0[0] {
                    wrong.push((u, v, p.0[0], ours));
                }
            }
            assert!(
                wrong.is_empty(),
                "{}: {} pixels differ from OpenCV's, first {:?}",
                board["file"],
                wrong.len(),
                &wrong[..wrong.len().min(8)]
            );
        }
    }
}
