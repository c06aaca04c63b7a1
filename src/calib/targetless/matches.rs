//! Matches between two cameras' images that assume nothing of the port: Shi–Tomasi corners spread
//! over the image by a grid, matched over the **whole** other image by mutual-best ZNCC of their
//! patches with a ratio test, then moved to sub-pixel by Gauss–Newton on the ZNCC of the patch
//! (position, an affine distortion of the patch, gain and offset; bilinear interpolation). Nothing here reads the rig: the
//! matches are the same whatever port is guessed, so a wrong guess cannot bias them.
//!
//! Written here rather than taken from a crate: `imageproc` offers FAST corners and BRIEF
//! (binary, integer-pixel) but no sub-pixel ZNCC refinement, which sets the calibration's
//! accuracy; the whole matcher is ~300 lines over the [`GreyImage`] the stereo code already has.

use nalgebra::{Point2, SMatrix, SVector};
use rayon::prelude::*;

use crate::base::GreyImage;

/// How corners are found and matched.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchOptions {
    /// Patch half-size in pixels (the patch is (2r + 1)²) for matching and refinement.
    pub patch_radius: usize,
    /// Most corners kept per image (one per grid cell; the cell grows with the image so that at
    /// most this many cells exist). Matching is brute force over pairs, O(corners²).
    pub max_corners: usize,
    /// Smallest grid cell, pixels.
    pub min_cell_px: usize,
    /// Lowe's ratio: the best patch distance must be below this fraction of the second best.
    pub ratio: f64,
    /// Smallest ZNCC of an accepted match.
    pub min_zncc: f64,
    /// Both images smoothed by a Gaussian of this σ (pixels) before anything else; 0: as they
    /// are. Noise, JPEG blocks and backscatter specks give corners that no other camera sees,
    /// and blur leaves small patches too alike to pass the ratio test (see [`ladder`]).
    pub smooth_px: f64,
}

impl Default for MatchOptions {
    fn default() -> Self {
        Self {
            patch_radius: 6,
            max_corners: 5000,
            min_cell_px: 4,
            ratio: 0.8,
            min_zncc: 0.8,
            smooth_px: 0.0,
        }
    }
}

/// Enough matches of a camera pair in one frame that the matching is kept as it is.
pub const ENOUGH_MATCHES: usize = 500;

/// The matchings tried in turn on footage that gives fewer than [`ENOUGH_MATCHES`]: `options`
/// itself, then smoothed images (σ 1 px) with 19 px patches, then σ 1.5 px with 25 px patches.
/// On a rendered seabed at `--imaging 2` (defocus 1–2.4 px, motion blur, JPEG 50) the first
/// found 23 matches, the second 424, the third 597; at `--imaging 1`, 744, 1443, 1519.
pub fn ladder(options: &MatchOptions) -> [MatchOptions; 3] {
    [
        *options,
        MatchOptions {
            smooth_px: options.smooth_px.max(1.0),
            patch_radius: options.patch_radius.max(9),
            ..*options
        },
        MatchOptions {
            smooth_px: options.smooth_px.max(1.5),
            patch_radius: options.patch_radius.max(12),
            ..*options
        },
    ]
}

/// One match: a corner of image A (integer pixel) and its sub-pixel position in image B.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelMatch {
    /// The corner in image A, pixels.
    pub in_a: Point2<f64>,
    /// Its match in image B, pixels (sub-pixel).
    pub in_b: Point2<f64>,
    /// ZNCC of the two patches after refinement.
    pub zncc: f64,
}

/// Shi–Tomasi corners: the pixel of largest min-eigenvalue of the structure tensor (5 × 5 window)
/// in each cell of a grid, kept where it exceeds 1 % of the image's largest, at least `margin`
/// pixels from the border. Integer pixels, row-major cell order.
pub fn corners(image: &GreyImage, options: &MatchOptions) -> Vec<Point2<usize>> {
    let (w, h) = (image.width as usize, image.height as usize);
    let margin = options.patch_radius + 3;
    if w <= 2 * margin + 1 || h <= 2 * margin + 1 {
        return Vec::new();
    }
    let area = ((w - 2 * margin) * (h - 2 * margin)) as f64;
    let cell = (area / options.max_corners.max(1) as f64)
        .sqrt()
        .ceil()
        .max(options.min_cell_px as f64) as usize;
    let px = |x: usize, y: usize| image.pixels[y * w + x];
    // Structure tensor entries of central-difference gradients.
    let mut gxx = vec![0.0f32; w * h];
    let mut gyy = vec![0.0f32; w * h];
    let mut gxy = vec![0.0f32; w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let gx = 0.5 * (px(x + 1, y) - px(x - 1, y));
            let gy = 0.5 * (px(x, y + 1) - px(x, y - 1));
            gxx[y * w + x] = gx * gx;
            gyy[y * w + x] = gy * gy;
            gxy[y * w + x] = gx * gy;
        }
    }
    let response = |x: usize, y: usize| -> f32 {
        let (mut a, mut b, mut c) = (0.0f32, 0.0f32, 0.0f32);
        for yy in y - 2..=y + 2 {
            for xx in x - 2..=x + 2 {
                a += gxx[yy * w + xx];
                b += gyy[yy * w + xx];
                c += gxy[yy * w + xx];
            }
        }
        // Smaller eigenvalue of [[a, c], [c, b]].
        0.5 * (a + b - ((a - b) * (a - b) + 4.0 * c * c).sqrt())
    };
    let cells_x = (w - 2 * margin) / cell;
    let cells_y = (h - 2 * margin) / cell;
    let best: Vec<(f32, Point2<usize>)> = (0..cells_x * cells_y)
        .into_par_iter()
        .map(|i| {
            let (cx, cy) = (i % cells_x, i / cells_x);
            let mut best = (0.0f32, Point2::new(0, 0));
            for y in margin + cy * cell..margin + (cy + 1) * cell {
                for x in margin + cx * cell..margin + (cx + 1) * cell {
                    let r = response(x, y);
                    if r > best.0 {
                        best = (r, Point2::new(x, y));
                    }
                }
            }
            best
        })
        .collect();
    let strongest = best.iter().map(|b| b.0).fold(0.0f32, f32::max);
    best.into_iter()
        .filter(|(r, _)| *r > 0.01 * strongest && *r > 0.0)
        .map(|(_, p)| p)
        .collect()
}

/// The zero-mean, unit-norm patch of radius `r` at integer pixel `p`; `None` where the patch is
/// flat (no texture to match) or leaves the image.
fn descriptor(image: &GreyImage, p: Point2<usize>, r: usize) -> Option<Vec<f32>> {
    let w = image.width as usize;
    if p.x < r || p.y < r || p.x + r >= w || p.y + r >= image.height as usize {
        return None;
    }
    let mut values = Vec::with_capacity((2 * r + 1) * (2 * r + 1));
    for y in p.y - r..=p.y + r {
        values.extend_from_slice(&image.pixels[y * w + p.x - r..=y * w + p.x + r]);
    }
    let mean = values.iter().sum::<f32>() / values.len() as f32;
    values.iter_mut().for_each(|v| *v -= mean);
    let norm = values.iter().map(|v| v * v).sum::<f32>().sqrt();
    // A patch whose grey levels vary by less than ~1/255 RMS carries no position.
    if !(norm > 1.0 / 255.0 * (values.len() as f32).sqrt()) {
        return None;
    }
    values.iter_mut().for_each(|v| *v /= norm);
    Some(values)
}

/// Bilinear value of `image` at (x, y); `None` outside the pixel centres.
fn bilinear(image: &GreyImage, x: f64, y: f64) -> Option<f64> {
    let (w, h) = (image.width as usize, image.height as usize);
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
        return None;
    }
    let (x0, y0) = (
        (x.floor() as usize).min(w - 2),
        (y.floor() as usize).min(h - 2),
    );
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let p = |xx: usize, yy: usize| f64::from(image.pixels[yy * w + xx]);
    Some(
        (1.0 - fy) * ((1.0 - fx) * p(x0, y0) + fx * p(x0 + 1, y0))
            + fy * ((1.0 - fx) * p(x0, y0 + 1) + fx * p(x0 + 1, y0 + 1)),
    )
}

/// Sub-pixel position in `b` of the patch of `a` at integer pixel `p`, starting at `start`:
/// Gauss–Newton on Σ (T(x) − (α·B(q + (I + A)·x) + β))² over the position q, a 2 × 2 affine
/// distortion A of the patch (the two views see a slanted surface at different scales and
/// shears: a translation-only fit would move the centre toward the patch's strongest texture),
/// α (gain) and β (offset); B bilinear, its gradient by central differences of the interpolated
/// image. Returns (q, ZNCC after the fit), `None` when the patch leaves `b`, the distortion grows
/// past 30 % or the iteration does not settle.
pub fn refine(
    a: &GreyImage,
    b: &GreyImage,
    p: Point2<usize>,
    start: Point2<f64>,
    r: usize,
) -> Option<(Point2<f64>, f64)> {
    let wa = a.width as usize;
    let template: Vec<(f64, f64, f64)> = (p.y - r..=p.y + r)
        .flat_map(|y| (p.x - r..=p.x + r).map(move |x| (x, y)))
        .map(|(x, y)| {
            (
                x as f64 - p.x as f64,
                y as f64 - p.y as f64,
                f64::from(a.pixels[y * wa + x]),
            )
        })
        .collect();
    // State: q (2), A row-major (4), gain, offset.
    let mut q = start;
    let mut affine = [0.0f64; 4];
    let (mut gain, mut offset) = (1.0, 0.0);
    let warp = |q: &Point2<f64>, affine: &[f64; 4], dx: f64, dy: f64| {
        (
            q.x + dx + affine[0] * dx + affine[1] * dy,
            q.y + dy + affine[2] * dx + affine[3] * dy,
        )
    };
    let mut settled = false;
    for _ in 0..30 {
        let mut jtj = SMatrix::<f64, 8, 8>::zeros();
        let mut jtr = SVector::<f64, 8>::zeros();
        for &(dx, dy, t) in &template {
            let (x, y) = warp(&q, &affine, dx, dy);
            let v = bilinear(b, x, y)?;
            let gx = bilinear(b, x + 0.5, y)? - bilinear(b, x - 0.5, y)?;
            let gy = bilinear(b, x, y + 0.5)? - bilinear(b, x, y - 0.5)?;
            let residual = gain * v + offset - t;
            let (ggx, ggy) = (gain * gx, gain * gy);
            let j =
                SVector::<f64, 8>::from([ggx, ggy, ggx * dx, ggx * dy, ggy * dx, ggy * dy, v, 1.0]);
            jtj += j * j.transpose();
            jtr += j * residual;
        }
        let step = jtj.cholesky()?.solve(&(-jtr));
        // A step over half a pixel is the iteration walking away from its basin: clamp it.
        let move_px = step[0].hypot(step[1]);
        let scale = if move_px > 0.5 { 0.5 / move_px } else { 1.0 };
        q.x += scale * step[0];
        q.y += scale * step[1];
        for (k, value) in affine.iter_mut().enumerate() {
            *value += scale * step[2 + k];
        }
        gain += scale * step[6];
        offset += scale * step[7];
        if (q - start).norm() > 2.0 || affine.iter().any(|v| v.abs() > 0.3) {
            return None;
        }
        if move_px < 1e-4 {
            settled = true;
            break;
        }
    }
    if !settled {
        return None;
    }
    let values: Vec<f64> = template
        .iter()
        .map(|&(dx, dy, _)| {
            let (x, y) = warp(&q, &affine, dx, dy);
            bilinear(b, x, y)
        })
        .collect::<Option<_>>()?;
    let ts: Vec<f64> = template.iter().map(|t| t.2).collect();
    Some((q, zncc(&ts, &values)))
}

/// Zero-mean normalised cross-correlation of two equal-length sequences.
fn zncc(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        ab += (x - ma) * (y - mb);
        aa += (x - ma) * (x - ma);
        bb += (y - mb) * (y - mb);
    }
    ab / (aa * bb).sqrt().max(f64::MIN_POSITIVE)
}

/// The integer position of best ZNCC in `b` within ±`reach` of `around`, for the patch of `a`
/// at `p` (its descriptor `template`), and the 3 × 3 scores around it for a parabola.
fn best_integer(
    b: &GreyImage,
    template: &[f32],
    around: Point2<usize>,
    reach: usize,
    r: usize,
) -> Option<(Point2<usize>, f32)> {
    let mut best: Option<(Point2<usize>, f32)> = None;
    for y in around.y.saturating_sub(reach)..=around.y + reach {
        for x in around.x.saturating_sub(reach)..=around.x + reach {
            if let Some(d) = descriptor(b, Point2::new(x, y), r) {
                let score: f32 = d.iter().zip(template).map(|(u, v)| u * v).sum();
                if best.is_none_or(|(_, s)| score > s) {
                    best = Some((Point2::new(x, y), score));
                }
            }
        }
    }
    best
}

/// Matches of image `a` in image `b`: corners of both, mutual best ZNCC over the whole images
/// with Lowe's ratio test on the patch distance √(2 − 2·ZNCC), the best integer position within
/// ±2 px of B's corner, then [`refine`]. Every corner of `a` is matched independently, so the
/// result does not depend on any port or extrinsics.
pub fn match_pair(a: &GreyImage, b: &GreyImage, options: &MatchOptions) -> Vec<PixelMatch> {
    if options.smooth_px > 0.0 {
        let plain = MatchOptions {
            smooth_px: 0.0,
            ..*options
        };
        return match_pair(
            &a.smoothed(options.smooth_px),
            &b.smoothed(options.smooth_px),
            &plain,
        );
    }
    let r = options.patch_radius;
    let describe = |image: &GreyImage| -> (Vec<Point2<usize>>, Vec<Vec<f32>>) {
        corners(image, options)
            .into_iter()
            .filter_map(|p| descriptor(image, p, r).map(|d| (p, d)))
            .unzip()
    };
    let (corners_a, desc_a) = describe(a);
    let (corners_b, desc_b) = describe(b);
    if corners_a.is_empty() || corners_b.is_empty() {
        return Vec::new();
    }
    // Best and second-best ZNCC of every row (A → B) and the best of every column (B → A).
    let scores = |from: &[Vec<f32>], to: &[Vec<f32>]| -> Vec<(usize, f32, f32)> {
        from.par_iter()
            .map(|d| {
                let (mut best, mut first, mut second) = (0, f32::MIN, f32::MIN);
                for (j, e) in to.iter().enumerate() {
                    let s: f32 = d.iter().zip(e).map(|(u, v)| u * v).sum();
                    if s > first {
                        second = first;
                        first = s;
                        best = j;
                    } else if s > second {
                        second = s;
                    }
                }
                (best, first, second)
            })
            .collect()
    };
    let forward = scores(&desc_a, &desc_b);
    let backward = scores(&desc_b, &desc_a);
    let distance = |zncc: f32| (2.0 - 2.0 * f64::from(zncc)).max(0.0).sqrt();
    forward
        .par_iter()
        .enumerate()
        .filter_map(|(i, &(j, first, second))| {
            if backward[j].0 != i || f64::from(first) < options.min_zncc {
                return None;
            }
            if distance(first) >= options.ratio * distance(second) {
                return None;
            }
            let p = corners_a[i];
            let (q, _) = best_integer(b, &desc_a[i], corners_b[j], 2, r)?;
            let (q, score) = refine(a, b, p, Point2::new(q.x as f64, q.y as f64), r)?;
            (score >= options.min_zncc).then_some(PixelMatch {
                in_a: Point2::new(p.x as f64, p.y as f64),
                in_b: q,
                zncc: score,
            })
        })
        .collect()
}

#[cfg(all(test, feature = "images"))]
mod tests {
    use super::*;
    use crate::base::noise::texture_grey;

    /// A smooth random texture sampled at (x + dx, y + dy): the same scene moved by a known
    /// sub-pixel shift, the oracle of the refinement.
    fn textured(w: u32, h: u32, dx: f64, dy: f64) -> GreyImage {
        let pixels = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                texture_grey(
                    [(x as f64 + dx) * 0.01, (y as f64 + dy) * 0.01, 0.0],
                    0.08,
                    2,
                    1.0,
                    9,
                ) as f32
            })
            .collect();
        GreyImage {
            width: w,
            height: h,
            pixels,
        }
    }

    #[test]
    fn a_known_sub_pixel_shift_is_recovered() {
        // B(x) = A(x + s): a corner p of A lies at p − s in B.
        let (sx, sy) = (7.37, -3.61);
        let a = textured(160, 128, 0.0, 0.0);
        let b = textured(160, 128, sx, sy);
        let matches = match_pair(&a, &b, &MatchOptions::default());
        assert!(matches.len() > 100, "{} matches", matches.len());
        let errors: Vec<f64> = matches
            .iter()
            .map(|m| (m.in_b - (m.in_a - nalgebra::Vector2::new(sx, sy))).norm())
            .collect();
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        let worst = errors.iter().copied().fold(0.0, f64::max);
        eprintln!(
            "shift: RMS {rms} px, worst {worst} px over {} matches",
            matches.len()
        );
        // The images are point samples of a texture whose finest octave has a 4 px wavelength
        // (2 octaves from 8 px, a soft tanh): bilinear interpolation of such content errs by a
        // few hundredths of a pixel, depending on the sub-pixel phase (the shift's 0.37, 0.39).
        // Measured: RMS 0.0201 px, worst 0.052 px over 562 matches. With 4 octaves and contrast
        // 3 (1 px wavelengths and hard edges: aliased point samples) the RMS was 0.038 px and
        // the worst match 0.09 px off; the bounds sit between the two.
        assert!(rms < 0.03, "RMS {rms} px");
        assert!(worst < 0.075, "worst {worst} px");
    }

    #[test]
    fn a_flat_image_gives_no_corners_and_no_matches() {
        let flat = GreyImage {
            width: 64,
            height: 64,
            pixels: vec![0.5; 64 * 64],
        };
        assert!(corners(&flat, &MatchOptions::default()).is_empty());
        assert!(match_pair(&flat, &flat, &MatchOptions::default()).is_empty());
    }
}
