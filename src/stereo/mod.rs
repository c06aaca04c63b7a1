//! Dense multi-view stereo through flat ports, refraction-exact: a plane sweep along each
//! reference pixel's refracted water ray, never a rectification.
//!
//! ## The method
//! For the reference camera (the master unless asked otherwise) and D hypotheses uniform in
//! inverse depth between z_min and z_max (z in the reference camera's frame):
//!
//! 1. `reference_rays`: every reference pixel is back-projected exactly through its port to its
//!    water ray o + s·w ([`rays::reference_rays`]).
//! 2. `hypothesis_points`: hypothesis h is the point of that ray at depth z_h = 1/q_h,
//!    q_h = 1/z_max + h·(1/z_min − 1/z_max)/(D − 1) (uniform in 1/z, as disparity is).
//! 3. `project_hypotheses`: each hypothesis point is projected exactly into every other camera
//!    through that camera's own port (forward projection: Newton on the refraction equation, the
//!    engine's vector path).
//! 4. `warp_bilinear` + `window_zncc`: each other image is sampled bilinearly at the projections
//!    of all reference pixels (a warped image per hypothesis), and compared with the reference by
//!    windowed zero-mean normalised cross-correlation over (2r + 1)² windows from separable box
//!    sums ([`cost`]). ZNCC ignores a gain and an offset between the two windows: the attenuation
//!    and backscatter that differ between an underwater rig's viewpoints.
//! 5. `combine_views`: the cameras that see the hypothesis vote; their costs min(1 − ZNCC, 1) are
//!    averaged (all of them for one or two votes, the best ⌈k/2⌉ of k > 2).
//! 6. `sgm_aggregate`: semi-global matching over 8 (or 4) paths, P2 lowered at image edges
//!    ([`sgm`]).
//! 7. `winner_take_all`: the least aggregated cost, refined by a parabola in 1/z ([`select`]).
//! 8. `consistency`: every other camera computes its own depth map the same way (as reference
//!    against all the others); a reference pixel's point must reproject within τ through one
//!    of them ([`check`]), τ = max(1, 0.002·f) reference pixels ([`consistency_px_for`]: the
//!    same angle at any resolution).
//! 9. `depth_edges`: pixels within a window radius of a depth jump (over 3 %) are dropped: the
//!    window straddles two surfaces there and follows the nearer (foreground fattening,
//!    [`edges`]).
//! 10. `confidence`: c = ZNCC_winner · min(1, distinctness / δ₀) ∈ [0, 1], distinctness =
//!     (S₂ − S₁)/S₂ of the aggregated costs (the winner against the best rival two or more
//!     hypotheses away).
//! 11. `points_from_depth`: z = 1/q at the refined hypothesis, the point X = o + ((z − z₀)/ż)·w on
//!     the pixel's water ray, in the master frame.
//!
//! A pixel gets NaN, never a guess, when its reference window is untextured (standard deviation
//! below `min_texture`), when no camera voted for its winner, when the winner is at either end of
//! the depth range, when no other camera confirms it, when it lies next to a depth edge, or when
//! its confidence is below `min_confidence`.
//!
//! **Sampling limit.** With hypotheses Δq apart in 1/z, one hypothesis step at depth z is
//! Δz ≈ z²·Δq; the parabola refines to a fraction of it (a tenth on a noise-free textured plane,
//! `tests/stereo.rs`).
//!
//! **Stages for the GPU.** Every stage is a function over whole arrays of f32/f64/u16 with simple
//! arithmetic, named as its future WGSL twin: `reference_rays` (the ray map kernel),
//! `hypothesis_points`, `project_hypotheses` (the forward projection kernel), `warp_bilinear`,
//! `window_zncc`, `combine_views`, `sgm_aggregate`, `winner_take_all`, `consistency`.
//!
//! ## Example
//! ```no_run
//! use flatport::stereo::{StereoOptions, stereo};
//! # let rig: flatport::model::Rig = unimplemented!();
//! # let images: Vec<flatport::stereo::GreyImage> = unimplemented!();
//! let options = StereoOptions { depth_range: Some((0.8, 2.5)), ..StereoOptions::default() };
//! let map = stereo(&rig, &images, &options)?;
//! println!("{} of {} pixels have a depth", map.valid, map.depth.len());
//! # Ok::<(), flatport::stereo::StereoError>(())
//! ```

pub mod check;
pub mod cost;
pub mod edges;
#[cfg(feature = "images")]
pub mod fuse;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod project;
pub mod range;
pub mod rays;
mod sample;
pub mod select;
pub mod sgm;
pub mod table;
mod volume;

pub use crate::base::GreyImage;
pub use table::Projection;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use thiserror::Error;

use crate::model::{RefractiveCamera, Rig};
use check::{Check, CheckView, consistency};
use cost::{COST_SCALE, Voter, cost_volume_into, reference_windows};
use edges::{depth_edges, near_mask};
use range::{
    CountChoice, RangeChoice, Sampling, StepRule, find_depth_range, largest_motion, step_rule,
};
use rays::{RayGrid, inverse_depths, reference_rays};
use sgm::{SgmParams, sgm_winners};
use volume::Volumes;

/// Default near end of the depth range, metres (moved out when the port is farther): the
/// fallback when the coarse sweep finds no range ([`range`]).
pub const DEFAULT_MIN_DEPTH: f64 = 0.3;
/// Default far end of the depth range, metres.
pub const DEFAULT_MAX_DEPTH: f64 = 3.0;
/// The consistency tolerance's angle, radians: τ = CONSISTENCY_RAD · f pixels (1 px at
/// f = 500 px, the 640 × 512 images the check was tuned on), at least [`MIN_CONSISTENCY_PX`].
pub const CONSISTENCY_RAD: f64 = 0.002;
/// The least consistency tolerance chosen, pixels.
pub const MIN_CONSISTENCY_PX: f64 = 1.0;

/// The consistency tolerance chosen for a reference camera of focal length `focal_px` (pixels,
/// the mean of fx and fy): τ = max([`MIN_CONSISTENCY_PX`], [`CONSISTENCY_RAD`] · f), the same
/// angle at any resolution (a fixed 1 px is half the angle at f = 1000 px that it is at
/// f = 500 px, where it was tuned). Measured at 1280 × 1024 (f = 1000 px) on issue 39's
/// housings scene: 1 px contradicted right pixels side by side often enough that the occlusion
/// margin took 9.0 % of the seen pixels (0.1 % of them wrong), 85.1 % kept a point; 2 px kept
/// 91.6 %, median error 0.029 → 0.031 % (docs/stereo.md, `rejections_at_full_size`).
pub fn consistency_px_for(focal_px: f64) -> f64 {
    let tau = CONSISTENCY_RAD * focal_px;
    if tau.is_finite() {
        tau.max(MIN_CONSISTENCY_PX)
    } else {
        MIN_CONSISTENCY_PX
    }
}

/// How to match.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoOptions {
    /// The reference camera (index in the rig; 0 = master).
    pub reference: usize,
    /// z range in the reference camera's frame, metres; `None`: found from the images by a
    /// coarse sweep ([`range`]; [`default_depth_range`] where it finds nothing).
    pub depth_range: Option<(f64, f64)>,
    /// Number of hypotheses D (uniform in 1/z); `None`: the step rule's count for each depth
    /// map ([`range::step_rule`]: one step moves a hypothesis by at most 0.8 px in every voter).
    pub hypotheses: Option<usize>,
    /// ZNCC window radius r: (2r + 1)² pixels.
    pub window_radius: usize,
    /// SGM's P1 as a fraction of the cost range (1 = ZNCC 0).
    pub penalty_step: f64,
    /// SGM's P2 as a fraction of the cost range, before the image's gradient lowers it.
    pub penalty_jump: f64,
    /// Grey-level change (0 … 1) along a path that halves P2.
    pub penalty_gradient: f64,
    /// SGM paths: 8 or 4.
    pub paths: usize,
    /// Least standard deviation (grey levels 0 … 1) of a reference window that is matched.
    pub min_texture: f64,
    /// Distinctness (S₂ − S₁)/S₂ that counts fully in the confidence.
    pub full_distinctness: f64,
    /// Least confidence of a returned point.
    pub min_confidence: f64,
    /// Largest reprojection disagreement with another camera's depth map, reference pixels;
    /// `None`: from the reference camera's focal length ([`consistency_px_for`]: 1 px up to
    /// f = 500 px, 2 px at f = 1000 px).
    pub consistency_px: Option<f64>,
    /// Relative depth jump within a window radius that marks a depth edge, whose pixels are
    /// returned as NaN (the window straddles two surfaces there); `None`: no such test.
    pub edge_jump: Option<f64>,
    /// Pixels within this many pixels of two or more neighbouring pixels whose depths the other
    /// cameras contradict are returned as NaN (0: none): at an occlusion's border the
    /// foreground's fattened depth is confirmed by the other camera's own fattened map.
    pub occlusion_margin: usize,
    /// How many other cameras compute their depth maps for the consistency check (the nearest
    /// first; `None`: all). 0 turns the check off (every match is returned unchecked).
    pub check_cameras: Option<usize>,
    /// How the CPU path projects the hypotheses into the voting cameras: tabulated (exact on a
    /// grid of nodes, bilinear within 0.02 px in between) or exact at every pixel.
    pub projection: Projection,
}

impl Default for StereoOptions {
    /// The depth range found from the images and the hypotheses by the step rule ([`range`]),
    /// 7 × 7 windows, P1 0.03, P2 0.5 halved at a change of 0.05 in grey, 8 paths,
    /// texture ≥ 0.01, confidence ≥ 0.25 (distinctness 0.05 counting fully), consistency within
    /// max(1, 0.002·f) px against every other camera ([`consistency_px_for`]), no point within
    /// a window radius of a 3 % depth jump.
    fn default() -> Self {
        Self {
            reference: 0,
            depth_range: None,
            hypotheses: None,
            window_radius: 3,
            penalty_step: 0.03,
            penalty_jump: 0.5,
            penalty_gradient: 0.05,
            paths: 8,
            min_texture: 0.01,
            full_distinctness: 0.05,
            min_confidence: 0.25,
            consistency_px: None,
            edge_jump: Some(0.03),
            occlusion_margin: 3,
            check_cameras: None,
            projection: Projection::Tabulated,
        }
    }
}

/// Why stereo cannot run on its input.
#[derive(Debug, Error)]
pub enum StereoError {
    /// The rig has fewer than two cameras.
    #[error("stereo needs at least two cameras; the rig has {0}")]
    TooFewCameras(usize),
    /// Not one image per camera.
    #[error("{got} images for the rig's {expected} cameras: one image per camera, in rig order")]
    ImageCount {
        /// Cameras.
        expected: usize,
        /// Images.
        got: usize,
    },
    /// An image whose size is not its camera's.
    #[error(
        "camera '{camera}': the image is {width} × {height} pixels, the rig says {expected_width} × {expected_height}"
    )]
    ImageSize {
        /// The camera.
        camera: String,
        /// The image's width.
        width: u32,
        /// The image's height.
        height: u32,
        /// The rig's width.
        expected_width: u32,
        /// The rig's height.
        expected_height: u32,
    },
    /// An image with a pixel that is not a number.
    #[error("camera '{camera}': pixel ({u}, {v}) of the image is not a finite number")]
    ImageValue {
        /// The camera.
        camera: String,
        /// Column.
        u: usize,
        /// Row.
        v: usize,
    },
    /// A depth range that cannot be swept.
    #[error("depth range {min}:{max} m (z in the frame of camera '{camera}'): {reason}")]
    DepthRange {
        /// The reference camera.
        camera: String,
        /// Near end.
        min: f64,
        /// Far end.
        max: f64,
        /// What is wrong.
        reason: String,
    },
    /// The GPU could not run the stages (no adapter, a volume over its limits, a device fault).
    #[error("stereo on the GPU: {0}")]
    Gpu(String),
    /// An option out of range.
    #[error("stereo option {option}: {reason}")]
    Option {
        /// The option.
        option: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// Where a long computation stands, for a progress display.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoProgress {
    /// The depth map being computed (0: the reference's; then the check cameras').
    pub run: usize,
    /// How many depth maps are computed.
    pub runs: usize,
    /// Its reference camera's name.
    pub camera: String,
    /// Work units done in this run (a hypothesis of a band of rows each).
    pub done: usize,
    /// Work units of this run.
    pub total: usize,
}

/// A depth map of the reference camera.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    /// Width of the reference image.
    pub width: usize,
    /// Height of the reference image.
    pub height: usize,
    /// The reference camera (index in the rig).
    pub reference: usize,
    /// z of each pixel's surface point in the reference camera's frame, metres; NaN where no
    /// confident depth.
    pub depth: Vec<f32>,
    /// Each pixel's surface point in the rig's master frame, metres; NaN where no confident depth.
    pub points: Vec<[f32; 3]>,
    /// Confidence 0 … 1 of each returned point (0 where NaN).
    pub confidence: Vec<f32>,
    /// Pixels with a point.
    pub valid: usize,
    /// The depth range swept, metres.
    pub depth_range: (f64, f64),
    /// Hypotheses swept (the reference's depth map).
    pub hypotheses: usize,
    /// How the depth range and the hypotheses were chosen.
    pub sampling: Sampling,
    /// The consistency tolerance used, reference pixels (given, or [`consistency_px_for`]).
    pub consistency_px: f64,
    /// Depth maps computed (1 + the check cameras').
    pub runs: usize,
    /// Seconds per stage, summed over the runs: rays, cost volume, aggregation, selection,
    /// consistency.
    pub stage_seconds: Vec<(&'static str, f64)>,
}

/// The default depth range for a reference camera whose port's outer surface reaches
/// `farthest_port` metres (z in its frame): [`DEFAULT_MIN_DEPTH`]:[`DEFAULT_MAX_DEPTH`], the near
/// end moved out to 5 cm beyond the port when the port is farther than 25 cm, the far end to
/// twice the near end when that is farther.
pub fn default_depth_range(farthest_port: f64) -> (f64, f64) {
    let min = DEFAULT_MIN_DEPTH.max(farthest_port + 0.05);
    (min, DEFAULT_MAX_DEPTH.max(2.0 * min))
}

/// The depth range `options` give for `rig`, checked as [`stereo`] checks it, with the options
/// themselves: for a caller that must refuse bad input before it writes anything. `None` when
/// the options give no range (it is then found from the images).
///
/// Errors: [`StereoError::Option`] for an option out of range or a reference the rig does not
/// have, [`StereoError::TooFewCameras`], [`StereoError::DepthRange`] for a range that is not in
/// the water in front of the reference camera.
pub fn resolve_depth_range(
    rig: &Rig,
    options: &StereoOptions,
) -> Result<Option<(f64, f64)>, StereoError> {
    check_options(options)?;
    let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
    if names.len() < 2 {
        return Err(StereoError::TooFewCameras(names.len()));
    }
    let reference = options.reference;
    if reference >= names.len() {
        return Err(StereoError::Option {
            option: "reference",
            reason: format!("camera {reference} asked for, the rig has {}", names.len()),
        });
    }
    let Some(range) = options.depth_range else {
        return Ok(None);
    };
    let rays = reference_rays(&rig.refractive_camera(reference));
    let farthest = farthest_port(&rays, names[reference])?;
    check_range(range, farthest, names[reference])?;
    Ok(Some(range))
}

fn farthest_port(rays: &RayGrid, camera: &str) -> Result<f64, StereoError> {
    rays.farthest_origin()
        .ok_or_else(|| StereoError::DepthRange {
            camera: camera.to_string(),
            min: f64::NAN,
            max: f64::NAN,
            reason: "no pixel of the reference camera sees the water".into(),
        })
}

/// Where stages 1–7 of every depth map run; the consistency check, the depths and points and
/// the confidence run on the CPU after either (the same code).
#[derive(Clone, Copy)]
pub enum Backend<'a> {
    /// The f64 CPU stages (rayon over the cores).
    Cpu,
    /// The WGSL stages on a GPU adapter (f32; the cost volume stays on the device).
    #[cfg(feature = "gpu")]
    Gpu(&'a gpu::GpuStereo),
    #[doc(hidden)]
    #[cfg(not(feature = "gpu"))]
    _Unused(std::marker::PhantomData<&'a ()>),
}

impl Backend<'_> {
    /// `cpu`, or the GPU adapter's name.
    pub fn describe(&self) -> String {
        match self {
            Self::Cpu => "cpu".to_string(),
            #[cfg(feature = "gpu")]
            Self::Gpu(g) => format!("gpu: {}", g.context().adapter().name),
            #[cfg(not(feature = "gpu"))]
            Self::_Unused(_) => unreachable!(),
        }
    }
}

/// Stereo with the reference `options.reference` on one image per rig camera (rig order, grey
/// 0 … 1). See the [module docs](self).
pub fn stereo(
    rig: &Rig,
    images: &[GreyImage],
    options: &StereoOptions,
) -> Result<DepthMap, StereoError> {
    stereo_with_progress(rig, images, options, &|_| {})
}

/// [`stereo`], calling `progress` as the work goes on (from worker threads).
pub fn stereo_with_progress(
    rig: &Rig,
    images: &[GreyImage],
    options: &StereoOptions,
    progress: &(dyn Fn(&StereoProgress) + Sync),
) -> Result<DepthMap, StereoError> {
    stereo_on(rig, images, options, Backend::Cpu, progress)
}

/// [`stereo_with_progress`] with stages 1–7 on `backend`.
pub fn stereo_on(
    rig: &Rig,
    images: &[GreyImage],
    options: &StereoOptions,
    backend: Backend,
    progress: &(dyn Fn(&StereoProgress) + Sync),
) -> Result<DepthMap, StereoError> {
    let names = check_inputs(rig, images, options)?;
    let cameras: Vec<RefractiveCamera> =
        (0..names.len()).map(|k| rig.refractive_camera(k)).collect();
    let reference = options.reference;
    let mut seconds = Timings::default();
    let started = Instant::now();
    let rays = reference_rays(&cameras[reference]);
    let farthest = farthest_port(&rays, &names[reference])?;
    seconds.add("rays", started);
    let started = Instant::now();
    let sampling = sampling_for(
        rig, images, options, &cameras, &rays, farthest, &names, backend,
    )?;
    if options.depth_range.is_none() {
        seconds.add("range search", started);
    }
    let range = sampling.depth_range;

    // The check cameras: every other camera, the nearest first.
    let mut others: Vec<usize> = (0..names.len()).filter(|&k| k != reference).collect();
    let centre = cameras[reference].centre();
    others.sort_by(|&a, &b| {
        (cameras[a].centre() - centre)
            .norm()
            .total_cmp(&(cameras[b].centre() - centre).norm())
    });
    others.truncate(options.check_cameras.unwrap_or(usize::MAX));
    let runs = 1 + others.len();

    let mut volumes = Volumes::default();
    let main = depth_run(
        &cameras,
        images,
        reference,
        &rays,
        range,
        sampling.hypotheses,
        options,
        (0, runs, &names[reference]),
        progress,
        backend,
        &mut volumes,
        &mut seconds,
    )?;
    let mut check_maps = Vec::with_capacity(others.len());
    for (run, &c) in others.iter().enumerate() {
        let started = Instant::now();
        let rays_c = reference_rays(&cameras[c]);
        seconds.add("rays", started);
        let Some(range_c) = check_range_for(&rays, range, &cameras[c], &rays_c) else {
            continue;
        };
        let hypotheses_c = match options.hypotheses {
            Some(d) => d,
            None => step_rule(largest_motion(&cameras, c, &rays_c, range_c), range_c).count,
        };
        let map = depth_run(
            &cameras,
            images,
            c,
            &rays_c,
            range_c,
            hypotheses_c,
            options,
            (run + 1, runs, &names[c]),
            progress,
            backend,
            &mut volumes,
            &mut seconds,
        )?;
        check_maps.push((c, map));
    }
    finish(
        &cameras,
        reference,
        &rays,
        &main,
        &check_maps,
        options,
        sampling,
        runs,
        seconds,
    )
}

/// The depth range and hypothesis count of the reference's depth map that [`stereo`] sweeps
/// with `options` on `images` (the range found by a coarse sweep on `backend` where the options
/// give none, the count by the step rule where they give none; see [`range`]), with the inputs
/// checked as [`stereo`] checks them: for a caller that prints the choice before the sweep.
/// Passing `options` with the range set to the one returned sweeps the same hypotheses.
pub fn choose_sampling(
    rig: &Rig,
    images: &[GreyImage],
    options: &StereoOptions,
    backend: Backend,
) -> Result<Sampling, StereoError> {
    let names = check_inputs(rig, images, options)?;
    let cameras: Vec<RefractiveCamera> =
        (0..names.len()).map(|k| rig.refractive_camera(k)).collect();
    let rays = reference_rays(&cameras[options.reference]);
    let farthest = farthest_port(&rays, &names[options.reference])?;
    sampling_for(
        rig, images, options, &cameras, &rays, farthest, &names, backend,
    )
}

/// [`choose_sampling`] on checked inputs, with the reference's rays.
#[allow(clippy::too_many_arguments)]
fn sampling_for(
    rig: &Rig,
    images: &[GreyImage],
    options: &StereoOptions,
    cameras: &[RefractiveCamera],
    rays: &RayGrid,
    farthest: f64,
    names: &[String],
    backend: Backend,
) -> Result<Sampling, StereoError> {
    let reference = options.reference;
    let (depth_range, range) = match options.depth_range {
        Some(range) => (range, RangeChoice::Given),
        None => find_depth_range(rig, images, options, cameras, rays, farthest, backend)?,
    };
    check_range(depth_range, farthest, &names[reference])?;
    let (hypotheses, count) = match options.hypotheses {
        Some(d) => (d, CountChoice::Given),
        None => {
            let rule: StepRule = step_rule(
                largest_motion(cameras, reference, rays, depth_range),
                depth_range,
            );
            (rule.count, CountChoice::Rule(rule))
        }
    };
    Ok(Sampling {
        depth_range,
        range,
        hypotheses,
        count,
    })
}

/// The checks of [`stereo`]'s inputs; the camera names.
fn check_inputs(
    rig: &Rig,
    images: &[GreyImage],
    options: &StereoOptions,
) -> Result<Vec<String>, StereoError> {
    check_options(options)?;
    let names: Vec<String> = rig.cameras().iter().map(|c| c.name.clone()).collect();
    if names.len() < 2 {
        return Err(StereoError::TooFewCameras(names.len()));
    }
    if images.len() != names.len() {
        return Err(StereoError::ImageCount {
            expected: names.len(),
            got: images.len(),
        });
    }
    if options.reference >= names.len() {
        return Err(StereoError::Option {
            option: "reference",
            reason: format!(
                "camera {} asked for, the rig has {}",
                options.reference,
                names.len()
            ),
        });
    }
    for (k, (camera, image)) in rig.cameras().iter().zip(images).enumerate() {
        let i = &camera.intrinsics;
        if image.width != i.width
            || image.height != i.height
            || image.pixels.len() != i.width as usize * i.height as usize
        {
            return Err(StereoError::ImageSize {
                camera: names[k].clone(),
                width: image.width,
                height: image.height,
                expected_width: i.width,
                expected_height: i.height,
            });
        }
        if let Some(at) = image.pixels.iter().position(|p| !p.is_finite()) {
            return Err(StereoError::ImageValue {
                camera: names[k].clone(),
                u: at % image.width as usize,
                v: at / image.width as usize,
            });
        }
    }
    Ok(names)
}

/// Stages 9–11 after the depth maps: the consistency check, depth edges, the confidence.
#[allow(clippy::too_many_arguments)]
fn finish(
    cameras: &[RefractiveCamera],
    reference: usize,
    rays: &RayGrid,
    main: &RawDepth,
    check_maps: &[(usize, RawDepth)],
    options: &StereoOptions,
    sampling: Sampling,
    runs: usize,
    mut seconds: Timings,
) -> Result<DepthMap, StereoError> {
    let started = Instant::now();
    let (w, h) = (rays.width, rays.height);
    let reference_camera = cameras[reference].intrinsics();
    let consistency_px = options
        .consistency_px
        .unwrap_or_else(|| consistency_px_for(0.5 * (reference_camera.fx + reference_camera.fy)));
    let checks = if options.check_cameras == Some(0) {
        vec![Check::Confirmed; w * h]
    } else {
        let views: Vec<CheckView> = check_maps
            .iter()
            .map(|(c, map)| CheckView {
                camera: &cameras[*c],
                width: cameras[*c].intrinsics().width as usize,
                height: cameras[*c].intrinsics().height as usize,
                points: &map.points,
            })
            .collect();
        consistency(&cameras[reference], w, &main.points, &views, consistency_px)
    };
    // Depth edges among the confirmed depths, and the pixels next to a depth that the other
    // cameras contradict (an occlusion's border, where the foreground's fattened depth is
    // confirmed by the other camera's own fattened map).
    let confirmed: Vec<bool> = checks.iter().map(|c| *c == Check::Confirmed).collect();
    let confirmed_depth: Vec<f32> = (0..w * h)
        .map(|i| {
            if confirmed[i] {
                main.depth[i]
            } else {
                f32::NAN
            }
        })
        .collect();
    let mut near_edge = match options.edge_jump {
        Some(jump) => depth_edges(&confirmed_depth, w, h, options.window_radius, jump as f32),
        None => vec![false; w * h],
    };
    if options.occlusion_margin > 0 && options.check_cameras != Some(0) {
        // The contradicted pixels that have a contradicted neighbour: a lone one in a textured
        // surface does not cut a hole, while an occlusion's band, however thin, runs along its
        // edge.
        let refused: Vec<bool> = checks.iter().map(|c| *c == Check::Contradicted).collect();
        let grouped: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                refused[i]
                    && (y.saturating_sub(1)..=(y + 1).min(h - 1)).any(|yy| {
                        (x.saturating_sub(1)..=(x + 1).min(w - 1))
                            .any(|xx| (xx, yy) != (x, y) && refused[yy * w + xx])
                    })
            })
            .collect();
        let near = near_mask(&grouped, w, h, options.occlusion_margin);
        for (edge, near) in near_edge.iter_mut().zip(near) {
            *edge |= near;
        }
    }
    let mut depth = vec![f32::NAN; w * h];
    let mut points = vec![[f32::NAN; 3]; w * h];
    let mut confidence = vec![0f32; w * h];
    let mut valid = 0;
    for i in 0..w * h {
        let c = main.confidence[i];
        if confirmed[i]
            && !near_edge[i]
            && main.depth[i].is_finite()
            && f64::from(c) >= options.min_confidence
        {
            depth[i] = main.depth[i];
            points[i] = main.points[i].map(|v| v as f32);
            confidence[i] = c;
            valid += 1;
        }
    }
    seconds.add("consistency", started);
    Ok(DepthMap {
        width: w,
        height: h,
        reference,
        depth,
        points,
        confidence,
        valid,
        depth_range: sampling.depth_range,
        hypotheses: sampling.hypotheses,
        sampling,
        consistency_px,
        runs,
        stage_seconds: seconds.0,
    })
}

/// Seconds per stage, in the order stages first ran.
#[derive(Debug, Default)]
struct Timings(Vec<(&'static str, f64)>);

impl Timings {
    fn add(&mut self, stage: &'static str, since: Instant) {
        self.add_seconds(stage, since.elapsed().as_secs_f64());
    }

    fn add_seconds(&mut self, stage: &'static str, s: f64) {
        match self.0.iter_mut().find(|(name, _)| *name == stage) {
            Some((_, total)) => *total += s,
            None => self.0.push((stage, s)),
        }
    }
}

/// One camera's depth map before the consistency check.
struct RawDepth {
    /// z in that camera's frame, NaN where rejected.
    depth: Vec<f32>,
    /// The points, master frame, NaN where rejected.
    points: Vec<[f64; 3]>,
    /// Confidence 0 … 1.
    confidence: Vec<f32>,
}

/// Stages 2–8 and the confidence for `reference` against every other camera.
#[allow(clippy::too_many_arguments)]
fn depth_run(
    cameras: &[RefractiveCamera],
    images: &[GreyImage],
    reference: usize,
    rays: &RayGrid,
    (min_depth, max_depth): (f64, f64),
    d: usize,
    options: &StereoOptions,
    (run, runs, name): (usize, usize, &str),
    progress: &(dyn Fn(&StereoProgress) + Sync),
    backend: Backend,
    volumes: &mut Volumes,
    seconds: &mut Timings,
) -> Result<RawDepth, StereoError> {
    let (w, h) = (rays.width, rays.height);
    let q = inverse_depths(min_depth, max_depth, d);
    let step = (q[d - 1] - q[0]) / (d - 1) as f64;
    let scale = f64::from(COST_SCALE);
    let params = SgmParams {
        p1: (options.penalty_step * scale).round() as u16,
        p2: (options.penalty_jump * scale).round() as u16,
        gradient: options.penalty_gradient as f32,
        paths: options.paths,
    };
    let winners = match backend {
        Backend::Cpu => cpu_winners(
            cameras,
            images,
            reference,
            rays,
            &q,
            &params,
            options,
            (run, runs, name),
            progress,
            volumes,
            seconds,
        ),
        #[cfg(feature = "gpu")]
        Backend::Gpu(device) => {
            let job = gpu::Job {
                cameras,
                images,
                reference,
                q0: q[0],
                dq: step,
                hypotheses: d,
                radius: options.window_radius,
                min_texture: options.min_texture,
                p1: params.p1,
                p2: params.p2,
                gradient: params.gradient,
                paths: params.paths,
            };
            let (winners, [cost, aggregation]) = device.winners(&job, &|done, total| {
                progress(&StereoProgress {
                    run,
                    runs,
                    camera: name.to_string(),
                    done,
                    total,
                })
            })?;
            seconds.add_seconds("cost volume", cost);
            seconds.add_seconds("aggregation", aggregation);
            winners
        }
        #[cfg(not(feature = "gpu"))]
        Backend::_Unused(_) => unreachable!(),
    };
    let started = Instant::now();
    let mut depth = vec![f32::NAN; w * h];
    let mut points = vec![[f64::NAN; 3]; w * h];
    let mut confidence = vec![0f32; w * h];
    for i in 0..w * h {
        // A rejected winner: NaN (an untextured window has no vote, so no winner, on both paths).
        let index = winners.index[i];
        if !index.is_finite() {
            continue;
        }
        let z = 1.0 / (q[0] + f64::from(index) * step);
        if let Some(point) = rays.point_at_depth(i, z) {
            depth[i] = z as f32;
            points[i] = point;
            confidence[i] = winners.quality[i]
                * (f64::from(winners.distinctness[i]) / options.full_distinctness).min(1.0) as f32;
        }
    }
    seconds.add("selection", started);
    Ok(RawDepth {
        depth,
        points,
        confidence,
    })
}

/// Stages 2–7 on the CPU: the winners of every reference pixel.
#[allow(clippy::too_many_arguments)]
fn cpu_winners(
    cameras: &[RefractiveCamera],
    images: &[GreyImage],
    reference: usize,
    rays: &RayGrid,
    q: &[f64],
    params: &SgmParams,
    options: &StereoOptions,
    (run, runs, name): (usize, usize, &str),
    progress: &(dyn Fn(&StereoProgress) + Sync),
    volumes: &mut Volumes,
    seconds: &mut Timings,
) -> select::Winners {
    let started = Instant::now();
    let (w, h) = (rays.width, rays.height);
    let d = q.len();
    let image = &images[reference];
    let windows = reference_windows(image, options.window_radius, options.min_texture);
    let voters: Vec<Voter> = (0..cameras.len())
        .filter(|&k| k != reference)
        .map(|k| Voter {
            camera: cameras[k].clone(),
            image: &images[k],
        })
        .collect();
    let table = (options.projection == Projection::Tabulated)
        .then(|| table::ProjectionTable::new(&cameras[reference], w, h));
    let total = h.div_ceil(cost::BAND_ROWS) * d;
    let done = AtomicUsize::new(0);
    let report = || {
        let n = done.fetch_add(1, Ordering::Relaxed) + 1;
        progress(&StereoProgress {
            run,
            runs,
            camera: name.to_string(),
            done: n,
            total,
        });
    };
    cost_volume_into(
        rays,
        image,
        &windows,
        options.min_texture,
        &voters,
        q,
        table.as_ref(),
        &report,
        &mut volumes.cost,
    );
    seconds.add("cost volume", started);
    let started = Instant::now();
    // The selection runs inside the aggregation, row by row (its time counted there).
    let winners = sgm_winners(
        &volumes.cost,
        w,
        h,
        d,
        &image.pixels,
        params,
        &mut volumes.sum,
    );
    seconds.add("aggregation", started);
    winners
}

fn check_options(o: &StereoOptions) -> Result<(), StereoError> {
    let bad = |option, reason: String| Err(StereoError::Option { option, reason });
    if let Some(d) = o.hypotheses
        && !(3..=1024).contains(&d)
    {
        return bad("hypotheses", format!("3 to 1024 hypotheses, got {d}"));
    }
    if !(1..=15).contains(&o.window_radius) {
        return bad(
            "window_radius",
            format!("1 to 15 pixels, got {}", o.window_radius),
        );
    }
    if !(o.penalty_step >= 0.0 && o.penalty_step <= 0.5) {
        return bad(
            "penalty_step",
            format!("P1 from 0 to 0.5 of the cost range, got {}", o.penalty_step),
        );
    }
    if !(o.penalty_jump > o.penalty_step && o.penalty_jump <= 1.0) {
        return bad(
            "penalty_jump",
            format!(
                "P2 above P1 ({}) and at most 1, got {}",
                o.penalty_step, o.penalty_jump
            ),
        );
    }
    if !(o.penalty_gradient > 0.0 && o.penalty_gradient.is_finite()) {
        return bad(
            "penalty_gradient",
            format!("a grey-level change > 0, got {}", o.penalty_gradient),
        );
    }
    if o.paths != 4 && o.paths != 8 {
        return bad("paths", format!("4 or 8 paths, got {}", o.paths));
    }
    if !(o.min_texture >= 0.0 && o.min_texture < 1.0) {
        return bad(
            "min_texture",
            format!("a standard deviation 0 to 1, got {}", o.min_texture),
        );
    }
    if !(o.full_distinctness > 0.0 && o.full_distinctness <= 1.0) {
        return bad(
            "full_distinctness",
            format!("0 to 1 (not 0), got {}", o.full_distinctness),
        );
    }
    if !(0.0..=1.0).contains(&o.min_confidence) {
        return bad(
            "min_confidence",
            format!("0 to 1, got {}", o.min_confidence),
        );
    }
    if let Some(jump) = o.edge_jump
        && !(jump > 0.0 && jump.is_finite())
    {
        return bad("edge_jump", format!("a relative jump > 0, got {jump}"));
    }
    if let Some(tau) = o.consistency_px
        && !(tau > 0.0 && tau.is_finite())
    {
        return bad("consistency_px", format!("> 0 pixels, got {tau}"));
    }
    Ok(())
}

/// The depth range must be in the water for every reference pixel: 0 < min < max, min beyond
/// the port's farthest point (`farthest`, z in the reference camera's frame).
fn check_range((min, max): (f64, f64), farthest: f64, camera: &str) -> Result<(), StereoError> {
    let bad = |reason: String| {
        Err(StereoError::DepthRange {
            camera: camera.to_string(),
            min,
            max,
            reason,
        })
    };
    if !(min.is_finite() && max.is_finite()) {
        return bad("both ends must be finite numbers".into());
    }
    if !(min > 0.0) {
        return bad("the near end lies behind the camera: depths are z > 0 in front of it".into());
    }
    if !(max > min) {
        return bad("the far end must be beyond the near end".into());
    }
    if !(min > farthest) {
        return bad(format!(
            "the near end lies in the air or in the port's layers: the port's outer surface reaches {farthest:.4} m (z) in this camera's image, so start beyond it"
        ));
    }
    Ok(())
}

/// The z range in camera c's frame of the reference's hypothesis volume: the reference's border
/// rays (and a grid inside) at both ends of its range, as z in c's frame, widened by 2 % and
/// kept beyond c's port. `None` when no such point lies in front of c.
fn check_range_for(
    reference_rays: &RayGrid,
    (min, max): (f64, f64),
    camera: &RefractiveCamera,
    rays_c: &RayGrid,
) -> Option<(f64, f64)> {
    let (w, h) = (reference_rays.width, reference_rays.height);
    let z_row = camera.cam_from_master().row(2).transpose();
    let centre = camera.centre().coords;
    let mut samples = Vec::new();
    let step = 8;
    for u in (0..w).step_by(step).chain([w - 1]) {
        for v in (0..h).step_by(step).chain([h - 1]) {
            samples.push(v * w + u);
        }
    }
    let (mut low, mut high) = (f64::INFINITY, f64::NEG_INFINITY);
    for i in samples {
        for z in [min, max] {
            if let Some(p) = reference_rays.point_at_depth(i, z) {
                let zc = z_row[0] * (p[0] - centre.x)
                    + z_row[1] * (p[1] - centre.y)
                    + z_row[2] * (p[2] - centre.z);
                low = low.min(zc);
                high = high.max(zc);
            }
        }
    }
    let port = rays_c.farthest_origin()?;
    let low = (low * 0.98).max(port + 1e-3);
    let high = high * 1.02;
    (low.is_finite() && high > low).then_some((low, high))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_consistency_tolerance_spans_one_angle_and_never_drops_under_a_pixel() {
        // 0.002·f: 1 px at f = 500 (the 640 × 512 scenes keep the tolerance they were tuned
        // with), 2 px at f = 1000, and 1 px for the 320 × 256 scenes and the coarse sweep.
        assert_eq!(consistency_px_for(500.0), 1.0);
        assert_eq!(consistency_px_for(1000.0), 2.0);
        assert_eq!(consistency_px_for(260.0), MIN_CONSISTENCY_PX);
        assert_eq!(consistency_px_for(f64::NAN), MIN_CONSISTENCY_PX);
        assert_eq!(consistency_px_for(f64::INFINITY), MIN_CONSISTENCY_PX);
    }

    #[test]
    fn the_default_range_keeps_clear_of_the_port() {
        assert_eq!(default_depth_range(0.04), (0.3, 3.0));
        let (min, max) = default_depth_range(0.5);
        assert!((min - 0.55).abs() < 1e-12 && max == 3.0);
        let (min, max) = default_depth_range(2.0);
        assert!((min - 2.05).abs() < 1e-12 && (max - 4.1).abs() < 1e-12);
    }

    #[test]
    fn ranges_in_the_port_or_behind_the_camera_are_refused() {
        assert!(check_range((0.5, 2.0), 0.04, "left").is_ok());
        for (range, says) in [
            ((0.02, 2.0), "in the air or in the port's layers"),
            ((-1.0, 2.0), "behind the camera"),
            ((2.0, 1.0), "beyond the near end"),
            ((f64::NAN, 1.0), "finite"),
        ] {
            let error = check_range(range, 0.04, "left").unwrap_err().to_string();
            assert!(error.contains(says) && error.contains("'left'"), "{error}");
        }
    }
}
