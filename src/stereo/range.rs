//! The sweep's sampling chosen from the rig and the images (DESIGN.md §3c): the hypothesis count
//! from the rig's geometry, the depth range from a coarse sweep of the images.
//!
//! **The step rule (hypothesis count).** The hypotheses are uniform in q = 1/z. Hypothesis q of
//! reference pixel p is the point X_p(q) of p's water ray; voter k sees it at π_k(X_p(q)) (exact
//! forward projection through k's port). One step Δq moves that by |∂π_k(X_p(q))/∂q|·Δq pixels
//! (to first order), and the count D is the least with
//!
//!   M · (q_near − q_far) / (D − 1) ≤ [`STEP_PX`],  M = max over p, k, q of |∂π_k(X_p(q))/∂q|,
//!
//! M in pixels per unit of 1/z (px·m). The maximum runs over a grid of reference pixels (about
//! [`GRID_ACROSS`] across, the last row and column included), the voters whose image holds the
//! point, and [`RULE_DEPTHS`] inverse depths from end to end of the range (both ends among them);
//! each derivative is a central difference of two exact projections. For a rectified pinhole pair
//! M is f·B (disparity f·B·q); behind a flat port it is about f·(μ_w/μ_air)·B near the axis and
//! varies over the image, largest where the baseline is seen most across. D is kept within
//! [`MIN_HYPOTHESES`] … [`MAX_HYPOTHESES`]; a count clamped at the maximum is reported
//! ([`StepRule::clamped`]) with the step it gives.
//!
//! Why 0.8 px: the correlation peak of a texture with detail down to two pixels is about two
//! pixels wide; steps of 1.7 px over the housings scene of issue 39 returned a point for 57 % of
//! the seen pixels, steps of 0.85 px for 92 %. A step under a pixel everywhere in every voter
//! keeps the peak sampled by two or more hypotheses, so the parabola refines it.
//!
//! **The coarse sweep (depth range).** Without a range, every image is box-filtered by k × k,
//! k = ⌈w / [`COARSE_MAX_WIDTH`]⌉ for each camera, and its intrinsics scaled to match: f/k, and
//! c′ = (c − (k − 1)/2)/k for the pixel centres ((0, 0) the centre of the top-left pixel; a coarse
//! pixel averages k × k fine ones whose centre is at k·u′ + (k − 1)/2). The OpenCV distortion acts
//! on normalised coordinates, (u − c)/f, which this scaling leaves unchanged, so the coefficients
//! stay (tested: the coarse camera projects every point to (u − (k − 1)/2)/k). The coarse rig is
//! swept, with every check of the full pipeline (consistency with the other cameras' maps, depth
//! edges, confidence), over the search range: from the nearest depth at which a voter's image
//! overlaps the reference's (on the same grid of pixels, depths 2 % apart from the port out) to
//! [`FAR_LIMIT_M`], with the step rule at the coarse scale. The range is then the
//! [`TRIM`] and 1 − [`TRIM`] quantiles of the confident coarse depths, padded in 1/z by
//! [`PAD_STEPS`] coarse steps (a coarse depth is good to about a coarse step) plus
//! [`PAD_FRACTION`] of the span (the trimmed tails: a surface's nearest and farthest pixels are
//! few), clamped to the search range. Where fewer than [`MIN_CONFIDENT_FRACTION`] of the coarse
//! reference pixels have a point, the default range ([`super::default_depth_range`]) is taken
//! and the choice says so ([`RangeChoice::Fallback`]).

use std::fmt;
use std::time::Instant;

use nalgebra::Point3;
use rayon::prelude::*;

use super::rays::RayGrid;
use super::{Backend, GreyImage, StereoError, StereoOptions};
use crate::model::{RefractiveCamera, Rig, RigCamera};

/// The step rule's target: one hypothesis step moves the hypothesis's projection by at most this
/// many pixels in every voting camera.
pub const STEP_PX: f64 = 0.8;
/// Fewest hypotheses the rule chooses.
pub const MIN_HYPOTHESES: usize = 16;
/// Most hypotheses the rule chooses (the cost volume is W·H·D u16, two of them at once: 1.3 GB
/// each at 1280 × 1024 × 512); past it the step is coarser than [`STEP_PX`] and the rule says so.
pub const MAX_HYPOTHESES: usize = 512;
/// Reference pixels across the image (and down, in proportion) where the rule is evaluated.
pub const GRID_ACROSS: usize = 64;
/// Inverse depths, end to end of the range, where the rule is evaluated.
pub const RULE_DEPTHS: usize = 33;
/// The far end of the coarse sweep, metres: beyond the visibility of all but the clearest water,
/// where backscatter leaves no texture to match.
pub const FAR_LIMIT_M: f64 = 20.0;
/// Widest coarse image, pixels.
pub const COARSE_MAX_WIDTH: u32 = 160;
/// Fraction of the confident coarse depths trimmed at each end (stray matches).
pub const TRIM: f64 = 0.005;
/// Padding of the found range in 1/z at each end, in coarse hypothesis steps.
pub const PAD_STEPS: f64 = 3.0;
/// Padding of the found range in 1/z at each end, as a fraction of its span in 1/z.
pub const PAD_FRACTION: f64 = 0.05;
/// Least fraction of the coarse reference pixels with a confident depth for a range to be found.
pub const MIN_CONFIDENT_FRACTION: f64 = 0.01;

/// The hypothesis count the step rule gives for a range.
#[derive(Debug, Clone, PartialEq)]
pub struct StepRule {
    /// The count chosen (within [`MIN_HYPOTHESES`] … [`MAX_HYPOTHESES`]).
    pub count: usize,
    /// The count the rule asks for before the clamp.
    pub needed: usize,
    /// M: the largest motion of a hypothesis's projection per unit of 1/z, pixels·m (NaN when no
    /// voter sees the range).
    pub motion_px_m: f64,
    /// The largest step in pixels at `count` hypotheses: M·(q_near − q_far)/(count − 1).
    pub step_px: f64,
    /// The rule's target, pixels ([`STEP_PX`]).
    pub target_px: f64,
}

impl StepRule {
    /// Whether the count was held at [`MAX_HYPOTHESES`] (the step is then over the target).
    pub fn clamped(&self) -> bool {
        self.needed > self.count
    }
}

/// The coarse sweep that found a depth range.
#[derive(Debug, Clone, PartialEq)]
pub struct CoarseSweep {
    /// Box filter (and intrinsics scale) of the reference camera's image.
    pub factor: usize,
    /// Coarse reference image width.
    pub width: usize,
    /// Coarse reference image height.
    pub height: usize,
    /// The depths searched, metres (z in the reference camera's frame).
    pub searched_m: (f64, f64),
    /// The step rule at the coarse scale.
    pub rule: StepRule,
    /// Coarse reference pixels with a confident depth.
    pub confident: usize,
    /// The [`TRIM`] and 1 − [`TRIM`] quantiles of the confident depths, metres (NaN when none).
    pub quantiles_m: (f64, f64),
    /// Seconds the coarse sweep took.
    pub seconds: f64,
}

/// Where a depth range came from.
#[derive(Debug, Clone, PartialEq)]
pub enum RangeChoice {
    /// Given in the options (`--depth`).
    Given,
    /// Found by the coarse sweep.
    Found(CoarseSweep),
    /// The coarse sweep found too few confident depths: the default range.
    Fallback(CoarseSweep),
}

/// Where a hypothesis count came from.
#[derive(Debug, Clone, PartialEq)]
pub enum CountChoice {
    /// Given in the options (`--hypotheses`).
    Given,
    /// The step rule.
    Rule(StepRule),
}

/// The depth range and hypothesis count of a depth map, and how each was chosen.
#[derive(Debug, Clone, PartialEq)]
pub struct Sampling {
    /// z range in the reference camera's frame, metres.
    pub depth_range: (f64, f64),
    /// How the range was chosen.
    pub range: RangeChoice,
    /// Hypotheses of the reference's depth map.
    pub hypotheses: usize,
    /// How the count was chosen.
    pub count: CountChoice,
}

impl fmt::Display for Sampling {
    /// Two lines: the range and how it was chosen, the count and how it was chosen.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (min, max) = self.depth_range;
        write!(f, "depth range {min:.3}:{max:.3} m")?;
        match &self.range {
            RangeChoice::Given => write!(f, " (given)")?,
            RangeChoice::Found(c) => write!(
                f,
                " (found: a coarse sweep at {} x {} over {:.3}:{:.1} m, {} hypotheses, {} confident pixels, their {:.1}-{:.1} % quantiles {:.3}:{:.3} m padded by {PAD_STEPS} coarse steps + {:.0} % of the span in 1/z; {:.1} s)",
                c.width,
                c.height,
                c.searched_m.0,
                c.searched_m.1,
                c.rule.count,
                c.confident,
                100.0 * TRIM,
                100.0 * (1.0 - TRIM),
                c.quantiles_m.0,
                c.quantiles_m.1,
                100.0 * PAD_FRACTION,
                c.seconds
            )?,
            RangeChoice::Fallback(c) => write!(
                f,
                " (WARNING: the default range; a coarse sweep at {} x {} over {:.3}:{:.1} m found only {} confident pixels of {}, fewer than {:.0} %: give --depth MIN:MAX)",
                c.width,
                c.height,
                c.searched_m.0,
                c.searched_m.1,
                c.confident,
                c.width * c.height,
                100.0 * MIN_CONFIDENT_FRACTION
            )?,
        }
        write!(f, "\n{} hypotheses uniform in 1/z", self.hypotheses)?;
        match &self.count {
            CountChoice::Given => write!(f, " (given)"),
            CountChoice::Rule(rule) => {
                write!(
                    f,
                    " (rule: one step moves a hypothesis by at most {} px in every voting camera; {:.0} px per 1/m here, largest step {:.2} px",
                    rule.target_px, rule.motion_px_m, rule.step_px
                )?;
                if rule.clamped() {
                    write!(
                        f,
                        "; WARNING: {} needed, held at the maximum {MAX_HYPOTHESES}",
                        rule.needed
                    )?;
                }
                write!(f, ")")
            }
        }
    }
}

/// The sample pixels of the rules: about `across` columns and rows in proportion, the last
/// column and row included.
fn sample_pixels(width: usize, height: usize, across: usize) -> Vec<usize> {
    let step = (width / across).max(1);
    let mut samples = Vec::new();
    let columns = (0..width).step_by(step).chain([width - 1]);
    for u in columns {
        for v in (0..height).step_by(step).chain([height - 1]) {
            samples.push(v * width + u);
        }
    }
    samples.sort_unstable();
    samples.dedup();
    samples
}

/// Whether `pixel` lies in `camera`'s image, [0, w − 1] × [0, h − 1].
fn inside(camera: &RefractiveCamera, u: f64, v: f64) -> bool {
    let i = camera.intrinsics();
    u >= 0.0 && v >= 0.0 && u <= f64::from(i.width) - 1.0 && v <= f64::from(i.height) - 1.0
}

/// M of the step rule: the largest |∂π_k(X_p(q))/∂q| over the grid of reference pixels, the
/// voters (every camera but `reference`) whose image holds the point, and [`RULE_DEPTHS`]
/// inverse depths over `range` (central differences of exact projections, ±10⁻⁴ of the range in
/// 1/z). Pixels per unit of 1/z (px·m); `None` when no voter sees a sample.
pub fn largest_motion(
    cameras: &[RefractiveCamera],
    reference: usize,
    rays: &RayGrid,
    (min_depth, max_depth): (f64, f64),
) -> Option<f64> {
    let (q_far, q_near) = (1.0 / max_depth, 1.0 / min_depth);
    let h = 1e-4 * (q_near - q_far);
    let samples = sample_pixels(rays.width, rays.height, GRID_ACROSS);
    let motion_at = |camera: &RefractiveCamera, i: usize| -> Option<f64> {
        let mut largest: Option<f64> = None;
        for j in 0..RULE_DEPTHS {
            let q = q_far + (q_near - q_far) * j as f64 / (RULE_DEPTHS - 1) as f64;
            let at = |q: f64| {
                let x = rays.point_at_depth(i, 1.0 / q)?;
                let p = camera.project(&Point3::from(x)).ok()?;
                inside(camera, p.x, p.y).then_some(p)
            };
            let (Some(a), Some(b)) = (at(q - h), at(q + h)) else {
                continue;
            };
            let motion = (b - a).norm() / (2.0 * h);
            if motion.is_finite() {
                largest = Some(largest.map_or(motion, |m| m.max(motion)));
            }
        }
        largest
    };
    cameras
        .iter()
        .enumerate()
        .filter(|(k, _)| *k != reference)
        .flat_map(|(_, camera)| {
            samples
                .par_iter()
                .filter_map(|&i| motion_at(camera, i))
                .collect::<Vec<f64>>()
        })
        .reduce(f64::max)
}

/// The step rule's count for `range` given M (`motion_px_m`, from [`largest_motion`]; `None`:
/// no voter sees the range, [`MIN_HYPOTHESES`]).
pub fn step_rule(motion_px_m: Option<f64>, (min_depth, max_depth): (f64, f64)) -> StepRule {
    let span = 1.0 / min_depth - 1.0 / max_depth;
    let Some(m) = motion_px_m else {
        return StepRule {
            count: MIN_HYPOTHESES,
            needed: MIN_HYPOTHESES,
            motion_px_m: f64::NAN,
            step_px: f64::NAN,
            target_px: STEP_PX,
        };
    };
    let steps = (m * span / STEP_PX).ceil();
    let needed = if steps.is_finite() && steps < 1e9 {
        steps as usize + 1
    } else {
        usize::MAX
    };
    let count = needed.clamp(MIN_HYPOTHESES, MAX_HYPOTHESES);
    StepRule {
        count,
        needed,
        motion_px_m: m,
        step_px: m * span / (count - 1) as f64,
        target_px: STEP_PX,
    }
}

/// The coarse factor k of an image `width` pixels wide: ⌈width / [`COARSE_MAX_WIDTH`]⌉.
pub fn coarse_factor(width: u32) -> usize {
    width.div_ceil(COARSE_MAX_WIDTH).max(1) as usize
}

/// `image` box-filtered by `factor` × `factor`: ⌊w/k⌋ × ⌊h/k⌋ pixels, each the mean of its k × k
/// block (the last columns and rows that make no whole block are dropped).
pub fn downsample(image: &GreyImage, factor: usize) -> GreyImage {
    let k = factor.max(1);
    let (w, h) = (image.width as usize, image.height as usize);
    let (cw, ch) = ((w / k).max(1), (h / k).max(1));
    let mut pixels = vec![0f32; cw * ch];
    for (y, row) in pixels.chunks_mut(cw).enumerate() {
        for (x, out) in row.iter_mut().enumerate() {
            let mut sum = 0f64;
            let mut n = 0u32;
            for yy in y * k..((y + 1) * k).min(h) {
                for xx in x * k..((x + 1) * k).min(w) {
                    sum += f64::from(image.pixels[yy * w + xx]);
                    n += 1;
                }
            }
            *out = (sum / f64::from(n.max(1))) as f32;
        }
    }
    GreyImage {
        width: cw as u32,
        height: ch as u32,
        pixels,
    }
}

/// `rig` with every camera's intrinsics scaled for its image box-filtered by `factors[k]`
/// (see the module docs), its ports and extrinsics unchanged.
pub fn downsampled_rig(rig: &Rig, factors: &[usize]) -> Result<Rig, StereoError> {
    let cameras: Vec<RigCamera> = rig
        .cameras()
        .iter()
        .zip(factors)
        .map(|(camera, &k)| {
            let i = camera.intrinsics;
            let s = k.max(1) as f64;
            let half = (s - 1.0) / 2.0;
            let mut intrinsics = i;
            intrinsics.width = (i.width / k.max(1) as u32).max(1);
            intrinsics.height = (i.height / k.max(1) as u32).max(1);
            intrinsics.fx = i.fx / s;
            intrinsics.fy = i.fy / s;
            intrinsics.cx = (i.cx - half) / s;
            intrinsics.cy = (i.cy - half) / s;
            RigCamera {
                intrinsics,
                ..camera.clone()
            }
        })
        .collect();
    Rig::with_ports(cameras, rig.ports().clone()).map_err(|e| StereoError::Option {
        option: "depth_range",
        reason: format!("the coarse rig of the range search: {e}"),
    })
}

/// The nearest depth (z in the reference's frame, from `start` out by 2 % a step to
/// `far`) at which a reference pixel of the grid has its point inside a voter's image, one step
/// nearer; `None` when no voter sees any.
fn overlap_near(
    cameras: &[RefractiveCamera],
    reference: usize,
    rays: &RayGrid,
    start: f64,
    far: f64,
) -> Option<f64> {
    let samples = sample_pixels(rays.width, rays.height, GRID_ACROSS / 2);
    let mut z = start;
    let mut previous = start;
    while z <= far {
        let seen = samples.iter().any(|&i| {
            let Some(x) = rays.point_at_depth(i, z) else {
                return false;
            };
            cameras.iter().enumerate().any(|(k, c)| {
                k != reference
                    && c.project(&Point3::from(x))
                        .is_ok_and(|p| inside(c, p.x, p.y))
            })
        });
        if seen {
            return Some(previous);
        }
        previous = z;
        z *= 1.02;
    }
    None
}

/// The depth range found by the coarse sweep (see the module docs) for reference `reference`
/// of `rig` (whose water rays at full size are `rays`, the port reaching `farthest_port` in z),
/// and how it was found. The sweep runs on `backend` with `options`' matching settings.
#[allow(clippy::too_many_arguments)]
pub fn find_depth_range(
    rig: &Rig,
    images: &[GreyImage],
    options: &StereoOptions,
    cameras: &[RefractiveCamera],
    rays: &RayGrid,
    farthest_port: f64,
    backend: Backend,
) -> Result<((f64, f64), RangeChoice), StereoError> {
    let started = Instant::now();
    let reference = options.reference;
    let start = farthest_port * 1.02 + 1e-3;
    let near = overlap_near(cameras, reference, rays, start, FAR_LIMIT_M)
        .unwrap_or(start)
        .max(start);
    let far = FAR_LIMIT_M.max(2.0 * near);
    let searched = (near, far);
    let factors: Vec<usize> = rig
        .cameras()
        .iter()
        .map(|c| coarse_factor(c.intrinsics.width))
        .collect();
    let coarse_rig = downsampled_rig(rig, &factors)?;
    let coarse_images: Vec<GreyImage> = images
        .iter()
        .zip(&factors)
        .map(|(image, &k)| downsample(image, k))
        .collect();
    let coarse_cameras: Vec<RefractiveCamera> = (0..coarse_rig.cameras().len())
        .map(|k| coarse_rig.refractive_camera(k))
        .collect();
    let coarse_rays = super::rays::reference_rays(&coarse_cameras[reference]);
    let rule = step_rule(
        largest_motion(&coarse_cameras, reference, &coarse_rays, searched),
        searched,
    );
    let coarse_options = StereoOptions {
        depth_range: Some(searched),
        hypotheses: Some(rule.count),
        ..options.clone()
    };
    let map = super::stereo_on(
        &coarse_rig,
        &coarse_images,
        &coarse_options,
        backend,
        &|_| {},
    )?;
    let mut depths: Vec<f64> = map
        .depth
        .iter()
        .filter(|z| z.is_finite())
        .map(|&z| f64::from(z))
        .collect();
    depths.sort_by(f64::total_cmp);
    let n = depths.len();
    let quantiles = if n > 0 {
        let lo = depths[((TRIM * n as f64).floor() as usize).min(n - 1)];
        let hi = depths[((((1.0 - TRIM) * n as f64).ceil() as usize).max(1) - 1).min(n - 1)];
        (lo, hi)
    } else {
        (f64::NAN, f64::NAN)
    };
    let coarse = CoarseSweep {
        factor: factors[reference],
        width: map.width,
        height: map.height,
        searched_m: searched,
        rule,
        confident: n,
        quantiles_m: quantiles,
        seconds: started.elapsed().as_secs_f64(),
    };
    if (n as f64) < MIN_CONFIDENT_FRACTION * (map.width * map.height) as f64 {
        return Ok((
            super::default_depth_range(farthest_port),
            RangeChoice::Fallback(coarse),
        ));
    }
    let (q_far, q_near) = (1.0 / quantiles.1, 1.0 / quantiles.0);
    let coarse_step = (1.0 / searched.0 - 1.0 / searched.1) / (coarse.rule.count - 1) as f64;
    let pad = PAD_STEPS * coarse_step + PAD_FRACTION * (q_near - q_far);
    let min = (1.0 / (q_near + pad)).max(searched.0);
    let far_q = q_far - pad;
    let max = if far_q > 1.0 / searched.1 {
        1.0 / far_q
    } else {
        searched.1
    };
    Ok(((min, max), RangeChoice::Found(coarse)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rule_counts_steps_of_the_largest_motion() {
        // 100 px per 1/m over 1 … 2 m (a span of 0.5 in 1/z): 50 px, 63 steps of 0.79 px.
        let rule = step_rule(Some(100.0), (1.0, 2.0));
        assert_eq!(rule.count, 64);
        assert!(rule.step_px <= STEP_PX && rule.step_px > 0.78, "{rule:?}");
        assert!(!rule.clamped());
        // Clamped both ways, and said so at the top.
        let rule = step_rule(Some(10_000.0), (0.5, 20.0));
        assert_eq!(rule.count, MAX_HYPOTHESES);
        assert!(rule.clamped() && rule.step_px > STEP_PX);
        assert_eq!(step_rule(Some(1.0), (1.0, 2.0)).count, MIN_HYPOTHESES);
        assert_eq!(step_rule(None, (1.0, 2.0)).count, MIN_HYPOTHESES);
    }

    #[test]
    fn a_box_filter_averages_whole_blocks() {
        let image = GreyImage {
            width: 5,
            height: 4,
            pixels: (0..20).map(|i| i as f32).collect(),
        };
        let small = downsample(&image, 2);
        assert_eq!((small.width, small.height), (2, 2));
        // Block (0, 0): pixels 0, 1, 5, 6.
        assert_eq!(small.pixels, vec![3.0, 5.0, 13.0, 15.0]);
        assert_eq!(downsample(&image, 1), image);
        assert_eq!(coarse_factor(160), 1);
        assert_eq!(coarse_factor(161), 2);
        assert_eq!(coarse_factor(1280), 8);
    }
}
