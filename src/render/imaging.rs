//! What a real camera adds to the rendered image: defocus, motion blur, vignetting, an uneven
//! light, low contrast, backscatter, sensor noise, JPEG and H.264 compression. Each effect has a
//! physical size ([`Imaging`]'s fields, zero or `None` for none), and [`Imaging::preset`] sets
//! them all from one severity (0 none, 1 as real underwater cameras give it, 2 harsher), so that
//! calibration can be tested on degraded footage whose corners are still known exactly.
//!
//! Images are grey levels 0 … 1 ([`GreyImage`]). [`Imaging::apply`] works on one image, in the
//! order light meets them: the scene's contrast c (I ↦ ½ + (1 − c)(I − ½)), the light's linear
//! gradient, the backscatter (an additive veil and bright specks), the lens's defocus and the
//! motion blur, the lens's vignetting, the sensor's shot and read noise, clamping to 0 … 1, and
//! the camera's JPEG compression. The quantisation to 8 (or 16) bits is the PNG writer's. H.264
//! compresses a camera's whole sequence of frames: [`h264_round_trip`] (the `ffmpeg` tool), which
//! `flatport render` runs on every camera's folder.
//!
//! Everything random (the defocus and the gradient of each image, the motion's direction, the
//! specks, the noise) is drawn from [`Rng`] streams seeded by [`Imaging::seed`] and the image's
//! index, one stream per effect and one per image row for the noise: the same image whatever the
//! number of threads, and different frames differ.

use std::path::Path;
use std::process::{Command, Stdio};

use rayon::prelude::*;

use super::{GreyImage, RenderError};
use crate::base::Rng;

/// Defocus: a disc (pillbox) point spread of radius R pixels,
/// R(r) = max(0, R₀ + `corner_px` · r²/r_c²) at distance r from the image centre (r_c: the
/// corner pixels'), where R₀ = `radius_px` + `variation_px` · u is drawn per image, u uniform in
/// [−1, 1): a focus that varies from frame to frame and a field curvature that blurs the corners
/// more.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Defocus {
    /// Mean radius of the blur disc at the image centre, pixels.
    pub radius_px: f64,
    /// Half the range of the centre's radius over the images, pixels (R₀ ∈ radius ± variation).
    pub variation_px: f64,
    /// Radius added at the corners (field curvature), pixels; R grows with r².
    pub corner_px: f64,
}

/// Backscatter: light scattered back by particles between the port and the board.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Backscatter {
    /// Mean number of specks per megapixel (the count per image is Poisson distributed).
    pub specks_per_mpx: f64,
    /// Peak brightness of the brightest specks, grey levels 0 … 1 added at the speck's centre
    /// (each speck's peak is uniform in [0.3, 1] of it; its radius σ uniform in 0.5 … 3 px:
    /// a Gaussian blob).
    pub speck_brightness: f64,
    /// The veil: grey level added everywhere (haze), 0 … 1.
    pub veil: f64,
}

/// The sensor's noise: shot noise (Poisson: variance ∝ signal) and read noise (signal-free),
/// both drawn as Gaussians (the Poisson count is ≥ 100 electrons on every grey that matters).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SensorNoise {
    /// Electrons at full scale (grey 1): the shot noise's standard deviation at grey I is
    /// √(I / full_well); 0 = no shot noise.
    pub full_well_e: f64,
    /// Standard deviation of the read noise, grey levels of 255.
    pub read_noise: f64,
}

/// What a real camera adds to the image, each effect with its physical size; the default adds
/// nothing. Set the fields, or take [`Imaging::preset`] and change some.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Imaging {
    /// Seed of everything random (with each image's index).
    pub seed: u64,
    /// Defocus blur.
    pub defocus: Defocus,
    /// Length of the motion blur, pixels: a line point spread at a random angle per image.
    pub motion_blur_px: f64,
    /// Fraction of the centre's light lost at the image corners, 0 … 1 (0.35: the corners get
    /// 65 %): cos⁴-like falloff, the light at distance r from the centre is cos⁴θ with
    /// tan θ = (r/r_c)·tan θ_c and cos⁴θ_c = 1 − vignetting (r_c: the corner pixels').
    pub vignetting: f64,
    /// Linear light gradient across the image, ± this fraction (0.2: from 80 % to 120 % of the
    /// light between the image's extreme corners) along a random direction per image.
    pub gradient: f64,
    /// Contrast lost, 0 … 1: grey I ↦ ½ + (1 − c)(I − ½) (0.4: black 0.2, white 0.8).
    pub contrast: f64,
    /// Backscatter: specks and veil.
    pub backscatter: Backscatter,
    /// Shot and read noise.
    pub noise: SensorNoise,
    /// JPEG compression at this quality (1 … 100), encoded and decoded again; `None` = none.
    pub jpeg_quality: Option<u8>,
    /// H.264 (libx264) compression of a camera's sequence at this constant rate factor
    /// (0 … 51, higher is worse; 23 is x264's default); `None` = none. Not applied by
    /// [`Imaging::apply`], which sees one image: by [`h264_round_trip`] on the sequence.
    pub h264_crf: Option<u8>,
}

/// A linear interpolation of the preset's values at severities 0, 1, 2.
fn ramp(severity: f64, at0: f64, at1: f64, at2: f64) -> f64 {
    if severity <= 1.0 {
        at0 + (at1 - at0) * severity
    } else {
        at1 + (at2 - at1) * (severity - 1.0)
    }
}

impl Imaging {
    /// The effects at `severity` (0 … 2), seeded by `seed`:
    ///
    /// | effect                         | 0    | 1 (as real cameras give it) | 2 (harsh)  |
    /// |--------------------------------|------|-----------------------------|------------|
    /// | defocus radius at the centre   | 0    | 0.6 … 1.6 px                | 1.0 … 2.4 px |
    /// | defocus added at the corners   | 0    | 0.2 px                      | 0.4 px     |
    /// | motion blur                    | 0    | 0                           | 2 px       |
    /// | vignetting (light lost)        | 0    | 35 %                        | 50 %       |
    /// | light gradient                 | 0    | ±20 %                       | ±30 %      |
    /// | contrast lost                  | 0    | 40 %                        | 55 %       |
    /// | specks per megapixel           | 0    | 30                          | 100        |
    /// | speck brightness               | 0    | 0.5                         | 0.7        |
    /// | veil                           | 0    | 0.04                        | 0.08       |
    /// | shot noise: full well          | ∞    | 4000 e⁻                     | 1000 e⁻    |
    /// | read noise                     | 0    | 1 grey level                | 2.5        |
    /// | JPEG quality                   | none | 75                          | 50         |
    ///
    /// In between every value is linear in the severity (the shot noise's variance 1/full_well
    /// too; the JPEG quality from 100 at severity 0+). No H.264 (a sequence's effect: set
    /// [`Imaging::h264_crf`]). A severity outside 0 … 2 or not finite is an error.
    pub fn preset(severity: f64, seed: u64) -> Result<Self, RenderError> {
        if !(0.0..=2.0).contains(&severity) {
            return Err(RenderError::Option {
                option: "imaging",
                reason: format!("a severity from 0 (none) to 2 (harsh), got {severity}"),
            });
        }
        if severity == 0.0 {
            return Ok(Self {
                seed,
                ..Self::default()
            });
        }
        let s = severity;
        let inverse_well = ramp(s, 0.0, 1.0 / 4000.0, 1.0 / 1000.0);
        Ok(Self {
            seed,
            defocus: Defocus {
                radius_px: ramp(s, 0.0, 1.1, 1.7),
                variation_px: ramp(s, 0.0, 0.5, 0.7),
                corner_px: ramp(s, 0.0, 0.2, 0.4),
            },
            motion_blur_px: ramp(s, 0.0, 0.0, 2.0),
            vignetting: ramp(s, 0.0, 0.35, 0.5),
            gradient: ramp(s, 0.0, 0.2, 0.3),
            contrast: ramp(s, 0.0, 0.4, 0.55),
            backscatter: Backscatter {
                specks_per_mpx: ramp(s, 0.0, 30.0, 100.0),
                speck_brightness: ramp(s, 0.0, 0.5, 0.7),
                veil: ramp(s, 0.0, 0.04, 0.08),
            },
            noise: SensorNoise {
                full_well_e: 1.0 / inverse_well,
                read_noise: ramp(s, 0.0, 1.0, 2.5),
            },
            jpeg_quality: Some(ramp(s, 100.0, 75.0, 50.0).round() as u8),
            h264_crf: None,
        })
    }

    /// Whether [`Imaging::apply`] leaves every image as it is.
    pub fn is_identity(&self) -> bool {
        let d = &self.defocus;
        d.radius_px == 0.0
            && d.variation_px == 0.0
            && d.corner_px == 0.0
            && self.motion_blur_px == 0.0
            && self.vignetting == 0.0
            && self.gradient == 0.0
            && self.contrast == 0.0
            && self.backscatter.specks_per_mpx == 0.0
            && self.backscatter.veil == 0.0
            && self.noise.full_well_e == 0.0
            && self.noise.read_noise == 0.0
            && self.jpeg_quality.is_none()
    }

    /// Checks every value's range: an error names the effect and the range.
    pub fn check(&self) -> Result<(), RenderError> {
        let within = |option: &'static str, value: f64, low: f64, high: f64, unit: &str| {
            if value >= low && value <= high {
                Ok(())
            } else {
                Err(RenderError::Option {
                    option,
                    reason: format!("{low} to {high}{unit}, got {value}"),
                })
            }
        };
        let d = &self.defocus;
        within("defocus", d.radius_px, 0.0, 20.0, " px")?;
        within("defocus variation", d.variation_px, 0.0, 20.0, " px")?;
        within("defocus at the corners", d.corner_px, 0.0, 20.0, " px")?;
        within("motion blur", self.motion_blur_px, 0.0, 50.0, " px")?;
        within(
            "vignetting",
            self.vignetting,
            0.0,
            0.99,
            " of the light lost",
        )?;
        within("gradient", self.gradient, 0.0, 0.99, " of the light")?;
        within("contrast", self.contrast, 0.0, 1.0, " of the contrast lost")?;
        let b = &self.backscatter;
        within(
            "backscatter",
            b.specks_per_mpx,
            0.0,
            1e5,
            " specks per megapixel",
        )?;
        within("speck brightness", b.speck_brightness, 0.0, 1.0, " grey")?;
        within("veil", b.veil, 0.0, 1.0, " grey")?;
        if self.noise.full_well_e != 0.0 {
            within("shot noise", self.noise.full_well_e, 1.0, 1e9, " electrons")?;
        }
        within(
            "read noise",
            self.noise.read_noise,
            0.0,
            100.0,
            " grey levels",
        )?;
        if let Some(q) = self.jpeg_quality {
            within("jpeg", f64::from(q), 1.0, 100.0, " quality")?;
        }
        if let Some(crf) = self.h264_crf {
            within("h264", f64::from(crf), 0.0, 51.0, " (x264's CRF)")?;
        }
        Ok(())
    }

    /// Adds the effects to `image`, the `index`th of a sequence (frames with different indices
    /// get different draws). The image is left as it is when [`Imaging::is_identity`]; else
    /// its values end in 0 … 1. Errors: a value out of range ([`Imaging::check`]), an image too
    /// large for JPEG (65 535 px a side).
    pub fn apply(&self, image: &mut GreyImage, index: u64) -> Result<(), RenderError> {
        self.check()?;
        if self.is_identity() || image.pixels.is_empty() {
            return Ok(());
        }
        let stream = |effect: u64| {
            Rng::new(
                self.seed
                    .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                    .wrapping_add(index.wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
                    .wrapping_add(effect.wrapping_mul(0x1656_67B1_9E37_79F9)),
            )
        };
        let geometry = Geometry::of(image);
        if self.contrast > 0.0 {
            let k = (1.0 - self.contrast) as f32;
            image
                .pixels
                .par_iter_mut()
                .for_each(|p| *p = 0.5 + k * (*p - 0.5));
        }
        if self.gradient > 0.0 {
            let angle = stream(1).range(0.0, std::f64::consts::TAU);
            let direction = [angle.cos(), angle.sin()];
            // The ramp is ± gradient at the extreme corners along the direction.
            let reach =
                direction[0].abs() * geometry.half[0] + direction[1].abs() * geometry.half[1];
            let g = self.gradient / reach.max(f64::MIN_POSITIVE);
            geometry.scale(image, |x, y| {
                1.0 + g * (direction[0] * x + direction[1] * y)
            });
        }
        let b = &self.backscatter;
        if b.veil > 0.0 {
            let veil = b.veil as f32;
            image.pixels.par_iter_mut().for_each(|p| *p += veil);
        }
        if b.specks_per_mpx > 0.0 && b.speck_brightness > 0.0 {
            add_specks(image, b, &mut stream(2));
        }
        let d = &self.defocus;
        if d.radius_px > 0.0 || d.variation_px > 0.0 || d.corner_px > 0.0 {
            let centre = (d.radius_px + d.variation_px * stream(3).range(-1.0, 1.0)).max(0.0);
            defocus(image, &geometry, centre, d.corner_px);
        }
        if self.motion_blur_px > 0.0 {
            let angle = stream(4).range(0.0, std::f64::consts::PI);
            let kernel = Kernel::line(self.motion_blur_px, angle);
            image.pixels = kernel.convolve(image);
        }
        if self.vignetting > 0.0 {
            let tan_corner = (1.0 - self.vignetting).powf(0.25).acos().tan();
            let scale = tan_corner / geometry.corner.max(f64::MIN_POSITIVE);
            geometry.scale(image, |x, y| {
                let t = scale * x.hypot(y);
                let cos2 = 1.0 / (1.0 + t * t);
                cos2 * cos2
            });
        }
        let n = &self.noise;
        if n.full_well_e > 0.0 || n.read_noise > 0.0 {
            add_noise(image, n, stream(5).next_u64());
        }
        image
            .pixels
            .par_iter_mut()
            .for_each(|p| *p = p.clamp(0.0, 1.0));
        if let Some(quality) = self.jpeg_quality {
            jpeg_round_trip(image, quality)?;
        }
        Ok(())
    }
}

/// Pixel coordinates about the image centre.
struct Geometry {
    width: usize,
    /// ((w − 1)/2, (h − 1)/2): the centre, and the corner pixels' offsets from it.
    half: [f64; 2],
    /// The corner pixels' distance from the centre, r_c.
    corner: f64,
}

impl Geometry {
    fn of(image: &GreyImage) -> Self {
        let half = [
            (f64::from(image.width) - 1.0) / 2.0,
            (f64::from(image.height) - 1.0) / 2.0,
        ];
        Self {
            width: image.width as usize,
            half,
            corner: half[0].hypot(half[1]),
        }
    }

    /// Multiplies each pixel by `factor(x, y)` of its offset from the centre.
    fn scale(&self, image: &mut GreyImage, factor: impl Fn(f64, f64) -> f64 + Sync) {
        image
            .pixels
            .par_chunks_mut(self.width)
            .enumerate()
            .for_each(|(v, row)| {
                let y = v as f64 - self.half[1];
                for (u, p) in row.iter_mut().enumerate() {
                    *p *= factor(u as f64 - self.half[0], y) as f32;
                }
            });
    }
}

/// A point spread function on the pixel grid: `(2·half + 1)²` weights summing to 1.
struct Kernel {
    half: usize,
    weights: Vec<f32>,
}

impl Kernel {
    /// Sub-samples per pixel axis when the disc's overlap with a pixel is measured.
    const DISC_SAMPLES: usize = 32;

    /// The disc of radius `radius` px: each weight is the area of the pixel inside the disc
    /// (measured on 32 × 32 sub-samples), over their sum. A disc smaller than a sub-sample is
    /// the identity.
    fn disc(radius: f64) -> Self {
        let half = (radius + 0.5).ceil() as usize;
        let size = 2 * half + 1;
        let n = Self::DISC_SAMPLES;
        let mut weights = vec![0f32; size * size];
        let mut sum = 0.0;
        for j in 0..size {
            for i in 0..size {
                let (cx, cy) = (i as f64 - half as f64, j as f64 - half as f64);
                let mut inside = 0usize;
                for b in 0..n {
                    let y = cy - 0.5 + (b as f64 + 0.5) / n as f64;
                    for a in 0..n {
                        let x = cx - 0.5 + (a as f64 + 0.5) / n as f64;
                        if x * x + y * y <= radius * radius {
                            inside += 1;
                        }
                    }
                }
                weights[j * size + i] = inside as f32;
                sum += inside as f64;
            }
        }
        if sum == 0.0 {
            return Self {
                half: 0,
                weights: vec![1.0],
            };
        }
        for w in &mut weights {
            *w = (f64::from(*w) / sum) as f32;
        }
        Self { half, weights }
    }

    /// A line segment of length `length` px through the centre at `angle` (radians from the
    /// image's x axis): 16 points per pixel along it, each spread bilinearly over the grid.
    fn line(length: f64, angle: f64) -> Self {
        let half = (length / 2.0 + 1.0).ceil() as usize;
        let size = 2 * half + 1;
        let mut weights = vec![0f32; size * size];
        let points = ((length * 16.0).ceil() as usize).max(1);
        let (c, s) = (angle.cos(), angle.sin());
        for k in 0..points {
            let t = length * ((k as f64 + 0.5) / points as f64 - 0.5);
            let (x, y) = (t * c + half as f64, t * s + half as f64);
            let (x0, y0) = (x.floor(), y.floor());
            let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
            let (x0, y0) = (x0 as usize, y0 as usize);
            let w = 1.0 / points as f32;
            weights[y0 * size + x0] += w * (1.0 - fx) * (1.0 - fy);
            weights[y0 * size + x0 + 1] += w * fx * (1.0 - fy);
            weights[(y0 + 1) * size + x0] += w * (1.0 - fx) * fy;
            weights[(y0 + 1) * size + x0 + 1] += w * fx * fy;
        }
        Self { half, weights }
    }

    /// The kernel's weighted sum around pixel (u, v), the image's edge pixels repeated beyond it.
    fn at(&self, image: &GreyImage, u: usize, v: usize) -> f32 {
        let (w, h) = (image.width as usize, image.height as usize);
        let size = 2 * self.half + 1;
        let mut sum = 0.0;
        for j in 0..size {
            let y = (v + j).saturating_sub(self.half).min(h - 1);
            let row = &image.pixels[y * w..(y + 1) * w];
            let weights = &self.weights[j * size..(j + 1) * size];
            for (i, &k) in weights.iter().enumerate() {
                if k != 0.0 {
                    sum += k * row[(u + i).saturating_sub(self.half).min(w - 1)];
                }
            }
        }
        sum
    }

    /// The image convolved with the kernel.
    fn convolve(&self, image: &GreyImage) -> Vec<f32> {
        let w = image.width as usize;
        let mut out = vec![0f32; image.pixels.len()];
        out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, p) in row.iter_mut().enumerate() {
                *p = self.at(image, u, v);
            }
        });
        out
    }
}

/// Radius step between the discs a varying defocus blends, pixels.
const DEFOCUS_STEP_PX: f64 = 0.25;

/// Disc blur of radius R = `centre` + `corner`·r²/r_c²: discs at radii `DEFOCUS_STEP_PX` apart
/// from the centre's to the corners', each pixel linear between the two that bracket its R.
fn defocus(image: &mut GreyImage, geometry: &Geometry, centre: f64, corner: f64) {
    let steps = (corner / DEFOCUS_STEP_PX).ceil() as usize;
    let step = if steps == 0 {
        0.0
    } else {
        corner / steps as f64
    };
    let kernels: Vec<Kernel> = (0..=steps)
        .map(|k| Kernel::disc(centre + k as f64 * step))
        .collect();
    let source = &*image;
    let w = geometry.width;
    let mut out = vec![0f32; source.pixels.len()];
    out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        let y = v as f64 - geometry.half[1];
        for (u, p) in row.iter_mut().enumerate() {
            if steps == 0 {
                *p = kernels[0].at(source, u, v);
                continue;
            }
            let x = u as f64 - geometry.half[0];
            let r2 = (x * x + y * y) / (geometry.corner * geometry.corner).max(f64::MIN_POSITIVE);
            let level = (r2.min(1.0) * steps as f64).min(steps as f64);
            let k = (level.floor() as usize).min(steps - 1);
            let f = (level - k as f64) as f32;
            let a = kernels[k].at(source, u, v);
            *p = if f > 0.0 {
                a + f * (kernels[k + 1].at(source, u, v) - a)
            } else {
                a
            };
        }
    });
    image.pixels = out;
}

/// Poisson-distributed count of mean `mean` (Knuth's product below 30, a rounded normal above).
fn poisson(mean: f64, rng: &mut Rng) -> usize {
    if mean < 30.0 {
        let limit = (-mean).exp();
        let (mut count, mut product) = (0, rng.uniform());
        while product > limit {
            count += 1;
            product *= rng.uniform();
        }
        count
    } else {
        (mean + mean.sqrt() * rng.normal()).round().max(0.0) as usize
    }
}

/// Bright specks: Gaussian blobs of σ uniform in 0.5 … 3 px and peak uniform in [0.3, 1] of the
/// brightness, at uniform places (centres anywhere on the image), a Poisson count of them.
fn add_specks(image: &mut GreyImage, backscatter: &Backscatter, rng: &mut Rng) {
    let (w, h) = (image.width as usize, image.height as usize);
    let mean = backscatter.specks_per_mpx * (w * h) as f64 / 1e6;
    for _ in 0..poisson(mean, rng) {
        let (cx, cy) = (
            rng.range(-0.5, w as f64 - 0.5),
            rng.range(-0.5, h as f64 - 0.5),
        );
        let sigma = rng.range(0.5, 3.0);
        let peak = backscatter.speck_brightness * rng.range(0.3, 1.0);
        let reach = (3.5 * sigma).ceil();
        let (u0, u1) = (
            (cx - reach).max(0.0) as usize,
            ((cx + reach) as usize).min(w - 1),
        );
        let (v0, v1) = (
            (cy - reach).max(0.0) as usize,
            ((cy + reach) as usize).min(h - 1),
        );
        for v in v0..=v1 {
            for u in u0..=u1 {
                let r2 = (u as f64 - cx).powi(2) + (v as f64 - cy).powi(2);
                image.pixels[v * w + u] += (peak * (-r2 / (2.0 * sigma * sigma)).exp()) as f32;
            }
        }
    }
}

/// Shot noise of variance I/full_well and read noise, one generator per row seeded by `seed` and
/// the row.
fn add_noise(image: &mut GreyImage, noise: &SensorNoise, seed: u64) {
    let w = image.width as usize;
    let shot = if noise.full_well_e > 0.0 {
        1.0 / noise.full_well_e
    } else {
        0.0
    };
    let read = (noise.read_noise / 255.0).powi(2);
    image
        .pixels
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(v, row)| {
            let mut rng = Rng::new(seed.wrapping_add(v as u64));
            for p in row.iter_mut() {
                let signal = f64::from(p.max(0.0));
                let sigma = (shot * signal + read).sqrt();
                *p += (sigma * rng.normal()) as f32;
            }
        });
}

/// JPEG at `quality` (the `image` crate's encoder on the 8-bit image, as [`GreyImage::to_u8`]
/// rounds it), decoded again.
fn jpeg_round_trip(image: &mut GreyImage, quality: u8) -> Result<(), RenderError> {
    use image::ImageEncoder;
    let fail = |reason: String| RenderError::Imaging {
        effect: "jpeg",
        reason,
    };
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality)
        .write_image(
            &image.to_u8(),
            image.width,
            image.height,
            image::ExtendedColorType::L8,
        )
        .map_err(|e| {
            fail(format!(
                "cannot encode a {}x{} image: {e}",
                image.width, image.height
            ))
        })?;
    let decoded = image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg)
        .map_err(|e| fail(format!("cannot decode the JPEG just encoded: {e}")))?
        .to_luma8();
    image.pixels = decoded
        .into_raw()
        .into_iter()
        .map(|p| f32::from(p) / 255.0)
        .collect();
    Ok(())
}

/// How to get the `ffmpeg` tool with libx264, for error messages.
pub const INSTALL_FFMPEG_X264: &str = "install FFmpeg with libx264 (Debian/Ubuntu: `apt-get install ffmpeg`; macOS: `brew install ffmpeg`) so that `ffmpeg` is on PATH";

/// Frame rate given to the encoder (it sets how x264 spends its bits over time only).
const H264_FPS: u32 = 25;

/// A camera's sequence through H.264 and back: the 8-bit frames ([`GreyImage::to_u8`]) are
/// encoded by the `ffmpeg` tool with libx264 at constant rate factor `crf` (preset medium,
/// 4:2:0 chroma as cameras record, the frames padded to even sizes) into an MP4 file in a
/// temporary folder, decoded again and cropped back. Returns the decoded frames, grey 0 … 1.
///
/// Errors: frames of different sizes, a CRF above 51, `ffmpeg` missing (the error says what to
/// install), ffmpeg failing (with the end of its messages), a decoded sequence of another
/// length.
pub fn h264_round_trip(frames: &[GreyImage], crf: u8) -> Result<Vec<GreyImage>, RenderError> {
    let fail = |reason: String| RenderError::Imaging {
        effect: "h264",
        reason,
    };
    let Some(first) = frames.first() else {
        return Ok(Vec::new());
    };
    if crf > 51 {
        return Err(fail(format!("a CRF from 0 to 51, got {crf}")));
    }
    let (width, height) = (first.width, first.height);
    if let Some(other) = frames
        .iter()
        .find(|f| (f.width, f.height) != (width, height))
    {
        return Err(fail(format!(
            "the frames of one sequence must have one size: {width}x{height} and {}x{}",
            other.width, other.height
        )));
    }
    let folder =
        tempfile::tempdir().map_err(|e| fail(format!("cannot make a temporary folder: {e}")))?;
    let raw_in = folder.path().join("frames.gray");
    let video = folder.path().join("frames.mp4");
    let raw_out = folder.path().join("decoded.gray");
    let mut bytes = Vec::with_capacity(frames.len() * first.pixels.len());
    for frame in frames {
        bytes.extend(frame.to_u8());
    }
    std::fs::write(&raw_in, &bytes)
        .map_err(|e| fail(format!("cannot write {}: {e}", raw_in.display())))?;
    let size = format!("{width}x{height}");
    let rate = H264_FPS.to_string();
    let crf_text = crf.to_string();
    run_ffmpeg(
        &[
            "-f", "rawvideo", "-pix_fmt", "gray", "-s", &size, "-r", &rate,
        ],
        &raw_in,
        &[
            "-vf",
            "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            "-c:v",
            "libx264",
            "-preset",
            "medium",
            "-crf",
            &crf_text,
            "-pix_fmt",
            "yuv420p",
        ],
        &video,
    )?;
    let crop = format!("format=gray,crop={width}:{height}:0:0");
    run_ffmpeg(
        &[],
        &video,
        &[
            "-vf",
            &crop,
            "-fps_mode",
            "passthrough",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "gray",
        ],
        &raw_out,
    )?;
    let decoded = std::fs::read(&raw_out)
        .map_err(|e| fail(format!("cannot read {}: {e}", raw_out.display())))?;
    let frame_bytes = first.pixels.len();
    if decoded.len() != frame_bytes * frames.len() {
        return Err(fail(format!(
            "ffmpeg decoded {} bytes, not the {} frames of {size} encoded",
            decoded.len(),
            frames.len()
        )));
    }
    Ok(decoded
        .chunks_exact(frame_bytes)
        .map(|chunk| GreyImage {
            width,
            height,
            pixels: chunk.iter().map(|&p| f32::from(p) / 255.0).collect(),
        })
        .collect())
}

/// Checks that the `ffmpeg` tool runs and has the libx264 encoder ([`h264_round_trip`]'s
/// needs), so that a missing tool is reported before the images are rendered.
pub fn check_h264_tool() -> Result<(), RenderError> {
    let output = Command::new("ffmpeg")
        .args(["-hide_banner", "-h", "encoder=libx264"])
        .stdin(Stdio::null())
        .output()
        .map_err(|e| RenderError::Imaging {
            effect: "h264",
            reason: format!("the `ffmpeg` command cannot be started ({e}): {INSTALL_FFMPEG_X264}"),
        })?;
    if !String::from_utf8_lossy(&output.stdout).contains("Encoder libx264") {
        return Err(RenderError::Imaging {
            effect: "h264",
            reason: format!("this ffmpeg has no libx264 encoder: {INSTALL_FFMPEG_X264}"),
        });
    }
    Ok(())
}

/// Runs `ffmpeg [before] -i file:INPUT [after] file:OUTPUT`, quiet but for errors.
fn run_ffmpeg(
    before: &[&str],
    input: &Path,
    after: &[&str],
    output: &Path,
) -> Result<(), RenderError> {
    let file = |path: &Path| {
        let mut text = std::ffi::OsString::from("file:");
        text.push(path.as_os_str());
        text
    };
    let result = Command::new("ffmpeg")
        .args(["-nostdin", "-hide_banner", "-v", "error", "-y"])
        .args(before)
        .arg("-i")
        .arg(file(input))
        .args(after)
        .arg(file(output))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output()
        .map_err(|e| RenderError::Imaging {
            effect: "h264",
            reason: format!("the `ffmpeg` command cannot be started ({e}): {INSTALL_FFMPEG_X264}"),
        })?;
    if !result.status.success() {
        let text = String::from_utf8_lossy(&result.stderr);
        let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
        let tail = lines[lines.len().saturating_sub(6)..].join(" | ");
        let hint = if tail.contains("libx264") || tail.contains("Unknown encoder") {
            format!(" ({INSTALL_FFMPEG_X264})")
        } else {
            String::new()
        };
        return Err(RenderError::Imaging {
            effect: "h264",
            reason: format!("ffmpeg failed ({}): {tail}{hint}", result.status),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn uniform(width: u32, height: u32, grey: f32) -> GreyImage {
        GreyImage {
            width,
            height,
            pixels: vec![grey; (width * height) as usize],
        }
    }

    /// A blurred chessboard of 16 px squares with some texture: what the effects meet.
    fn board(width: u32, height: u32) -> GreyImage {
        let mut pixels = Vec::new();
        for v in 0..height {
            for u in 0..width {
                let black = ((u / 16) + (v / 16)) % 2 == 0;
                pixels.push(if black { 0.12 } else { 0.85 } + 0.01 * ((u * 7 + v * 3) % 5) as f32);
            }
        }
        GreyImage {
            width,
            height,
            pixels,
        }
    }

    /// The share of a disc of radius R beyond a line at distance d from its centre:
    /// (R² acos(d/R) − d √(R² − d²)) / (π R²), the circular segment's area.
    fn disc_beyond(d: f64, radius: f64) -> f64 {
        if d >= radius {
            0.0
        } else if d <= -radius {
            1.0
        } else {
            (radius * radius * (d / radius).acos() - d * (radius * radius - d * d).sqrt())
                / (std::f64::consts::PI * radius * radius)
        }
    }

    #[test]
    fn a_disc_blur_of_a_step_edge_has_the_circular_segments_profile() {
        // A vertical step between pixel 19 and 20 (at x = 19.5), blurred by a disc of R = 3.3 px:
        // pixel u sees the share of the disc beyond x = 19.5 − u. Tolerance: the disc's overlap
        // with each pixel is counted on 32 × 32 sub-samples (≈ 10⁻³ of the disc's area).
        let radius = 3.3;
        let (w, h) = (40u32, 9u32);
        let mut image = uniform(w, h, 0.0);
        for v in 0..h as usize {
            for u in 20..w as usize {
                image.pixels[v * w as usize + u] = 1.0;
            }
        }
        let imaging = Imaging {
            defocus: Defocus {
                radius_px: radius,
                ..Defocus::default()
            },
            ..Imaging::default()
        };
        imaging.apply(&mut image, 0).unwrap();
        let row = &image.pixels[4 * w as usize..5 * w as usize];
        for (u, &value) in row.iter().enumerate() {
            let expected = disc_beyond(19.5 - u as f64, radius);
            assert!(
                (f64::from(value) - expected).abs() < 3e-3,
                "pixel {u}: {value}, the segment's share is {expected}"
            );
        }
        // The 10 %–90 % width of the edge: closed form (bisection of the segment's share) and as
        // measured (linear between pixels).
        let crossing = |level: f64| {
            let (mut low, mut high) = (-radius, radius);
            for _ in 0..60 {
                let mid = 0.5 * (low + high);
                if disc_beyond(mid, radius) > level {
                    low = mid;
                } else {
                    high = mid;
                }
            }
            0.5 * (low + high)
        };
        let width = crossing(0.1) - crossing(0.9);
        let measured_at = |level: f32| {
            let u = row.iter().position(|&p| p >= level).unwrap();
            (u - 1) as f64 + f64::from((level - row[u - 1]) / (row[u] - row[u - 1]))
        };
        let measured = measured_at(0.9) - measured_at(0.1);
        // The closed-form profile sampled at the pixel centres and interpolated alike: the
        // curved tails make linear interpolation read 0.06 px wide of the true width.
        let sampled: Vec<f32> = (0..w)
            .map(|u| disc_beyond(19.5 - f64::from(u), radius) as f32)
            .collect();
        let sampled_at = |level: f32| {
            let u = sampled.iter().position(|&p| p >= level).unwrap();
            (u - 1) as f64 + f64::from((level - sampled[u - 1]) / (sampled[u] - sampled[u - 1]))
        };
        let interpolated = sampled_at(0.9) - sampled_at(0.1);
        assert!(
            (measured - interpolated).abs() < 0.01 && (measured - width).abs() < 0.1,
            "10-90 % width {measured} px; closed form {width} px, sampled alike {interpolated} px"
        );
        assert!(
            width > 3.0,
            "a 3.3 px disc spreads the edge over {width} px"
        );
    }

    #[test]
    fn vignetting_leaves_the_stated_fraction_at_the_corners_and_cos4_between() {
        let (w, h) = (65u32, 49u32);
        let mut image = uniform(w, h, 0.5);
        let imaging = Imaging {
            vignetting: 0.35,
            ..Imaging::default()
        };
        imaging.apply(&mut image, 0).unwrap();
        let at = |u: u32, v: u32| f64::from(image.pixels[(v * w + u) as usize]);
        for (u, v) in [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)] {
            assert!(
                (at(u, v) - 0.5 * 0.65).abs() < 1e-6,
                "corner {u},{v}: {}",
                at(u, v)
            );
        }
        assert!(
            (at(32, 24) - 0.5).abs() < 1e-7,
            "the centre keeps its light"
        );
        // Half-way to the corner: tan θ = tan θ_c / 2, cos⁴θ = cos⁴(atan(tan(acos(0.65^¼))/2)).
        let theta = ((0.65f64).powf(0.25).acos().tan() / 2.0).atan();
        let (u, v) = (32 + 16, 24 + 12);
        assert!(
            (at(u, v) - 0.5 * theta.cos().powi(4)).abs() < 1e-6,
            "half-way: {} not {}",
            at(u, v),
            0.5 * theta.cos().powi(4)
        );
    }

    #[test]
    fn contrast_keeps_mid_grey_and_lifts_black_and_lowers_white() {
        let mut image = GreyImage {
            width: 3,
            height: 1,
            pixels: vec![0.0, 0.5, 1.0],
        };
        let imaging = Imaging {
            contrast: 0.4,
            ..Imaging::default()
        };
        imaging.apply(&mut image, 0).unwrap();
        let expected = [0.2, 0.5, 0.8];
        for (p, e) in image.pixels.iter().zip(expected) {
            assert!((p - e).abs() < 1e-6, "{:?} not {expected:?}", image.pixels);
        }
    }

    #[test]
    fn the_gradient_spans_the_stated_fraction_between_extreme_corners() {
        let mut image = uniform(80, 60, 0.5);
        let imaging = Imaging {
            gradient: 0.3,
            seed: 4,
            ..Imaging::default()
        };
        imaging.apply(&mut image, 2).unwrap();
        let (low, high) = image
            .pixels
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &p| (a.min(p), b.max(p)));
        assert!(
            (low - 0.35).abs() < 1e-5 && (high - 0.65).abs() < 1e-5,
            "{low} … {high}"
        );
        let mean = image.pixels.iter().map(|&p| f64::from(p)).sum::<f64>() / 4800.0;
        assert!(
            (mean - 0.5).abs() < 1e-5,
            "a linear ramp about the centre: mean {mean}"
        );
    }

    #[test]
    fn motion_blur_spreads_a_point_along_a_line_of_the_stated_length() {
        // A point blurred by a segment of length L: variance L²/12 along it (uniform), plus the
        // bilinear spreading's (≤ 1/4 px² on each axis); across it the bilinear spread alone.
        let (w, h, length) = (41u32, 41u32, 10.0);
        let mut image = uniform(w, h, 0.0);
        image.pixels[(20 * w + 20) as usize] = 1.0;
        let imaging = Imaging {
            motion_blur_px: length,
            seed: 9,
            ..Imaging::default()
        };
        imaging.apply(&mut image, 0).unwrap();
        let (mut sum, mut m) = (0.0, [0.0f64; 5]);
        for v in 0..h {
            for u in 0..w {
                let p = f64::from(image.pixels[(v * w + u) as usize]);
                let (x, y) = (f64::from(u) - 20.0, f64::from(v) - 20.0);
                sum += p;
                m[0] += p * x;
                m[1] += p * y;
                m[2] += p * x * x;
                m[3] += p * y * y;
                m[4] += p * x * y;
            }
        }
        assert!((sum - 1.0).abs() < 1e-5, "the light is kept: {sum}");
        assert!(m[0].abs() < 1e-4 && m[1].abs() < 1e-4, "centred: {m:?}");
        let (a, b, c) = (m[2], m[3], m[4]);
        let root = ((a - b).powi(2) / 4.0 + c * c).sqrt();
        let (along, across) = ((a + b) / 2.0 + root, (a + b) / 2.0 - root);
        let uniform_variance = length * length / 12.0;
        assert!(
            along > uniform_variance && along < uniform_variance + 0.5,
            "variance along {along}, the segment's {uniform_variance}"
        );
        assert!(across < 0.5, "variance across {across}");
    }

    #[test]
    fn shot_noise_variance_is_proportional_to_the_signal_and_read_noise_adds() {
        // Variance grey/full_well + (read/255)²: at 0.2 and 0.8 with 1000 e⁻ and 2 grey levels.
        // 200 000 samples: the variance's standard error is √(2/n) ≈ 0.3 %.
        for grey in [0.2f32, 0.8] {
            let mut image = uniform(500, 400, grey);
            let imaging = Imaging {
                noise: SensorNoise {
                    full_well_e: 1000.0,
                    read_noise: 2.0,
                },
                seed: 3,
                ..Imaging::default()
            };
            imaging.apply(&mut image, 1).unwrap();
            let n = image.pixels.len() as f64;
            let mean = image.pixels.iter().map(|&p| f64::from(p)).sum::<f64>() / n;
            let var = image
                .pixels
                .iter()
                .map(|&p| (f64::from(p) - mean).powi(2))
                .sum::<f64>()
                / n;
            let expected = f64::from(grey) / 1000.0 + (2.0f64 / 255.0).powi(2);
            assert!(
                (var / expected - 1.0).abs() < 0.02 && (mean - f64::from(grey)).abs() < 1e-3,
                "grey {grey}: variance {var}, expected {expected}, mean {mean}"
            );
        }
    }

    #[test]
    fn specks_come_in_the_stated_number_per_megapixel() {
        // 2 Mpx at 100 specks per megapixel: 200 specks on average. Each adds peak · 2πσ² of
        // light (a Gaussian blob): E = 0.5 · 0.65 · 2π · E[σ²], E[σ²] = (3³ − 0.5³)/(3 · 2.5) for σ
        // uniform in 0.5 … 3. The total light's relative spread: the count's (7 %) and the
        // specks' sizes (≈ 6 %); 25 % is three standard deviations.
        let mut image = uniform(2000, 1000, 0.0);
        let imaging = Imaging {
            backscatter: Backscatter {
                specks_per_mpx: 100.0,
                speck_brightness: 0.5,
                veil: 0.0,
            },
            seed: 11,
            ..Imaging::default()
        };
        imaging.apply(&mut image, 0).unwrap();
        let light: f64 = image.pixels.iter().map(|&p| f64::from(p)).sum();
        let per_speck = 0.5 * 0.65 * std::f64::consts::TAU * (27.0 - 0.125) / 7.5;
        let specks = light / per_speck;
        assert!(
            (specks - 200.0).abs() < 50.0,
            "{specks} specks' worth of light"
        );
    }

    #[test]
    fn severity_zero_leaves_the_image_byte_identical() {
        let original = board(97, 61);
        let mut image = original.clone();
        let imaging = Imaging::preset(0.0, 7).unwrap();
        assert!(imaging.is_identity());
        imaging.apply(&mut image, 3).unwrap();
        assert!(
            image
                .pixels
                .iter()
                .zip(&original.pixels)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
    }

    #[test]
    fn the_same_seed_and_index_repeat_and_other_indices_or_seeds_differ() {
        let run = |seed: u64, index: u64| {
            let mut image = board(128, 96);
            Imaging::preset(1.0, seed)
                .unwrap()
                .apply(&mut image, index)
                .unwrap();
            image.pixels
        };
        let first = run(5, 3);
        assert_eq!(first, run(5, 3), "deterministic");
        let differ = |a: &[f32], b: &[f32]| a.iter().zip(b).filter(|(x, y)| x != y).count();
        assert!(
            differ(&first, &run(5, 4)) > first.len() / 4,
            "another frame gets other noise"
        );
        assert!(
            differ(&first, &run(6, 3)) > first.len() / 4,
            "another seed too"
        );
    }

    #[test]
    fn jpeg_changes_the_image_by_a_bounded_amount() {
        // The 8-bit image through JPEG at 75 and 30: changed, the mean error a few grey levels at
        // most (the test image's texture, ±5 grey levels from pixel to pixel, is what JPEG
        // smooths most), and worse at the lower quality.
        let original = board(128, 96);
        let error = |quality: u8| {
            let mut image = original.clone();
            Imaging {
                jpeg_quality: Some(quality),
                ..Imaging::default()
            }
            .apply(&mut image, 0)
            .unwrap();
            let diffs: Vec<f32> = image
                .pixels
                .iter()
                .zip(&original.pixels)
                .map(|(a, b)| (a - b).abs() * 255.0)
                .collect();
            let mean = diffs.iter().sum::<f32>() / diffs.len() as f32;
            let max = diffs.iter().fold(0f32, |m, &d| m.max(d));
            (mean, max)
        };
        let (mean75, max75) = error(75);
        let (mean30, _) = error(30);
        assert!(mean75 > 0.3, "JPEG changes the image: {mean75}");
        assert!(
            mean75 < 4.0 && max75 < 30.0,
            "mean {mean75}, max {max75} grey levels"
        );
        assert!(
            mean30 > mean75,
            "quality 30 ({mean30}) is worse than 75 ({mean75})"
        );
    }

    #[test]
    fn the_preset_interpolates_and_refuses_other_severities() {
        let one = Imaging::preset(1.0, 1).unwrap();
        let two = Imaging::preset(2.0, 1).unwrap();
        let half = Imaging::preset(0.5, 1).unwrap();
        assert_eq!(one.jpeg_quality, Some(75));
        assert_eq!(two.jpeg_quality, Some(50));
        assert_eq!(one.motion_blur_px, 0.0);
        assert_eq!(two.motion_blur_px, 2.0);
        assert!((half.contrast - one.contrast / 2.0).abs() < 1e-12);
        assert!((half.noise.full_well_e - 8000.0).abs() < 1e-6);
        for bad in [-0.1, 2.5, f64::NAN] {
            assert!(Imaging::preset(bad, 1).is_err(), "severity {bad}");
        }
        let wrong = Imaging {
            vignetting: 1.0,
            ..Imaging::default()
        };
        let message = wrong.apply(&mut board(8, 8), 0).unwrap_err().to_string();
        assert!(message.contains("vignetting"), "{message}");
    }
}
