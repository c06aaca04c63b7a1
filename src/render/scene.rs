//! Textured scenes in the water: planes, height fields and spheres, each with a procedural or an
//! image texture, and the exact intersection of a water ray with them (the nearest hit wins).
//!
//! Every surface has a local frame: an origin O, a unit normal n and two in-surface axes
//! e₁ = unit(x̂ − (x̂·n)n) (ŷ instead when n ∥ x̂) and e₂ = n × e₁, so a point X has surface
//! coordinates s = e₁·(X − O), t = e₂·(X − O) and height n·(X − O).
//!
//! - **Plane** {X : n·(X − O) = 0}, optionally bounded to s ∈ [s₀, s₁], t ∈ [t₀, t₁]. A ray
//!   o + λd meets it at λ = n·(O − o) / n·d (closed form).
//! - **Height field** {X : n·(X − O) = h(s, t)} with the relief h(s, t) = Σᵢ aᵢ sin(kᵢ·(s, t) + φᵢ)
//!   (seeded waves), optionally bounded like the plane. Along a ray g(λ) = n·(X(λ) − O) − h(s, t)
//!   changes sign at a hit. |g′(λ)| ≤ B = |n·d| + L·|d − (n·d)n| with the slope bound
//!   L = Σᵢ |aᵢ||kᵢ| ≥ |∇h|, so no root lies within |g|/B of the current λ: the march steps by
//!   max(|g|/B, δ) (δ = a thousandth of the shortest wavelength; only a ray that grazes a crest by
//!   less than that could skip it) from where the ray enters the slab |n·(X − O)| ≤ Σ|aᵢ|, and
//!   the first sign change is narrowed to 1e-9 m (regula falsi, Illinois variant).
//! - **Sphere** |X − c| = r: λ = −b ∓ √(b² − (|o − c|² − r²)), b = d·(o − c) (closed form).
//!
//! Textures: procedural ([`noise::texture_grey`](crate::base::noise::texture_grey), a solid texture in
//! the surface's local coordinates X − O, so it moves with the surface) or an image mapped onto a
//! plane or height field at (s, t): texture pixel (s/m + (w − 1)/2, t/m + (h − 1)/2) for m metres
//! per pixel, bilinear, repeated beyond its edges.

use nalgebra::{Point3, Unit, Vector3};

use crate::base::noise::texture_grey;

/// Precision of the height-field intersection along the ray, metres.
pub const HEIGHT_FIELD_TOLERANCE: f64 = 1e-9;

/// Largest number of march steps along one ray through a height field's slab.
const MAX_MARCH_STEPS: usize = 200_000;

/// A surface's local frame: origin O, unit normal n, in-surface axes e₁, e₂ (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceFrame {
    /// O, master frame.
    pub origin: Point3<f64>,
    /// n: the plane's normal, the height field's "up" (heights are measured along it).
    pub normal: Unit<Vector3<f64>>,
    /// e₁.
    pub e1: Vector3<f64>,
    /// e₂ = n × e₁.
    pub e2: Vector3<f64>,
}

impl SurfaceFrame {
    /// The frame at `origin` with normal `normal` (normalised here); `None` for a zero or
    /// non-finite normal.
    pub fn new(origin: Point3<f64>, normal: Vector3<f64>) -> Option<Self> {
        if !(normal.iter().all(|v| v.is_finite()) && normal.norm() > 1e-12) {
            return None;
        }
        let normal = Unit::new_normalize(normal);
        let axis = if normal.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = (axis - normal.into_inner() * normal.dot(&axis)).normalize();
        let e2 = normal.cross(&e1);
        Some(Self {
            origin,
            normal,
            e1,
            e2,
        })
    }

    /// (s, t, height) of a point.
    #[inline]
    pub fn local(&self, point: &Point3<f64>) -> [f64; 3] {
        let p = point - self.origin;
        [self.e1.dot(&p), self.e2.dot(&p), self.normal.dot(&p)]
    }
}

/// Bounds of a plane or height field in its surface coordinates, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extent {
    /// [s₀, s₁] along e₁.
    pub s: [f64; 2],
    /// [t₀, t₁] along e₂.
    pub t: [f64; 2],
}

impl Extent {
    fn contains(&self, s: f64, t: f64) -> bool {
        s >= self.s[0] && s <= self.s[1] && t >= self.t[0] && t <= self.t[1]
    }
}

/// One wave of a relief: a·sin(k·(s, t) + φ).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wave {
    /// Wave vector k (radians per metre) in surface coordinates.
    pub k: [f64; 2],
    /// Amplitude a, metres.
    pub amplitude: f64,
    /// Phase φ, radians.
    pub phase: f64,
}

/// The relief of a height field: a sum of waves, with its bounds.
#[derive(Debug, Clone, PartialEq)]
pub struct Relief {
    waves: Vec<Wave>,
    /// Σ|aᵢ| ≥ |h|.
    height_bound: f64,
    /// Σ|aᵢ||kᵢ| ≥ |∇h|.
    slope_bound: f64,
    /// The march's smallest step δ, metres.
    min_step: f64,
}

impl Relief {
    /// A relief of the given waves; `None` when one is not finite or a wave vector is zero.
    pub fn new(waves: Vec<Wave>) -> Option<Self> {
        if waves.iter().any(|w| {
            !(w.k.iter().all(|k| k.is_finite())
                && w.amplitude.is_finite()
                && w.phase.is_finite()
                && w.k[0].hypot(w.k[1]) > 0.0)
        }) {
            return None;
        }
        let height_bound = waves.iter().map(|w| w.amplitude.abs()).sum();
        let slope_bound = waves
            .iter()
            .map(|w| w.amplitude.abs() * w.k[0].hypot(w.k[1]))
            .sum();
        let shortest = waves
            .iter()
            .map(|w| std::f64::consts::TAU / w.k[0].hypot(w.k[1]))
            .fold(f64::INFINITY, f64::min);
        Some(Self {
            waves,
            height_bound,
            slope_bound,
            min_step: if shortest.is_finite() {
                shortest * 1e-3
            } else {
                1e-6
            },
        })
    }

    /// `count` seeded waves: wavelengths from `wavelength` down by a factor 0.62 per wave, amplitude
    /// `amplitude`·0.55ⁱ, random directions and phases.
    pub fn seeded(amplitude: f64, wavelength: f64, count: usize, seed: u64) -> Option<Self> {
        let mut state = seed ^ 0x5DEE_CE66_D1CE_4E5B;
        let mut uniform = || {
            // SplitMix64: enough for a few directions and phases.
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        let waves = (0..count)
            .map(|i| {
                let length = wavelength * 0.62f64.powi(i as i32);
                let angle = std::f64::consts::TAU * uniform();
                let k = std::f64::consts::TAU / length;
                Wave {
                    k: [k * angle.cos(), k * angle.sin()],
                    amplitude: amplitude * 0.55f64.powi(i as i32),
                    phase: std::f64::consts::TAU * uniform(),
                }
            })
            .collect();
        Self::new(waves)
    }

    /// h(s, t).
    #[inline]
    pub fn height(&self, s: f64, t: f64) -> f64 {
        self.waves
            .iter()
            .map(|w| w.amplitude * (w.k[0] * s + w.k[1] * t + w.phase).sin())
            .sum()
    }

    /// The waves.
    pub fn waves(&self) -> &[Wave] {
        &self.waves
    }
}

/// A sphere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    /// Centre, master frame.
    pub centre: Point3<f64>,
    /// Radius, metres (> 0).
    pub radius: f64,
}

/// The geometry of a surface.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A plane through the frame's origin, normal to its normal.
    Plane {
        /// Its frame.
        frame: SurfaceFrame,
        /// Bounds (unbounded when `None`).
        extent: Option<Extent>,
    },
    /// A height field over the frame's plane.
    HeightField {
        /// Its frame (heights along the normal).
        frame: SurfaceFrame,
        /// Bounds (unbounded when `None`).
        extent: Option<Extent>,
        /// h(s, t).
        relief: Relief,
    },
    /// A sphere.
    Sphere(Sphere),
}

/// A grey image used as a texture, repeated beyond its edges.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageTexture {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Grey levels 0 … 1, row-major.
    pub pixels: Vec<f32>,
    /// Metres per texture pixel on the surface.
    pub metres_per_pixel: f64,
}

impl ImageTexture {
    /// Bilinear grey level at surface coordinates (s, t) (see the module docs).
    pub fn grey(&self, s: f64, t: f64) -> f64 {
        let (w, h) = (self.width as i64, self.height as i64);
        let x = s / self.metres_per_pixel + (w - 1) as f64 / 2.0;
        let y = t / self.metres_per_pixel + (h - 1) as f64 / 2.0;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let at = |i: i64, j: i64| {
            let (i, j) = (i.rem_euclid(w), j.rem_euclid(h));
            f64::from(self.pixels[(j * w + i) as usize])
        };
        let (i, j) = (x0 as i64, y0 as i64);
        let top = at(i, j) * (1.0 - fx) + at(i + 1, j) * fx;
        let bottom = at(i, j + 1) * (1.0 - fx) + at(i + 1, j + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// How a surface is coloured.
#[derive(Debug, Clone, PartialEq)]
pub enum Texture {
    /// Procedural noise ([`texture_grey`]).
    Noise {
        /// Seed.
        seed: u64,
        /// Size of the largest features, metres.
        scale: f64,
        /// Octaves (each adds detail half the size of the previous one).
        octaves: u32,
        /// Gain of the tanh (higher: harder contrast).
        contrast: f64,
    },
    /// An image on a plane or height field.
    Image(ImageTexture),
}

/// A surface: geometry and texture.
#[derive(Debug, Clone, PartialEq)]
pub struct Surface {
    /// Geometry.
    pub shape: Shape,
    /// Texture.
    pub texture: Texture,
}

impl Surface {
    /// The smallest λ > 0 with o + λd on the surface (d a unit vector), `None` when the ray
    /// misses it.
    pub fn hit(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<f64> {
        match &self.shape {
            Shape::Plane { frame, extent } => {
                let denominator = frame.normal.dot(dir);
                if denominator.abs() < 1e-15 {
                    return None;
                }
                let lambda = frame.normal.dot(&(frame.origin - origin)) / denominator;
                if !(lambda > 0.0 && lambda.is_finite()) {
                    return None;
                }
                if let Some(e) = extent {
                    let [s, t, _] = frame.local(&(origin + dir * lambda));
                    if !e.contains(s, t) {
                        return None;
                    }
                }
                Some(lambda)
            }
            Shape::Sphere(sphere) => {
                let oc = origin - sphere.centre;
                let b = dir.dot(&oc);
                let c = oc.norm_squared() - sphere.radius * sphere.radius;
                let discriminant = b * b - c;
                if !(discriminant >= 0.0) {
                    return None;
                }
                let root = discriminant.sqrt();
                // The near root as c / (−b + √…) when b < 0 avoids cancellation.
                let (near, far) = if b < 0.0 {
                    (c / (-b + root), -b + root)
                } else {
                    (-b - root, c / (-b - root))
                };
                [near.min(far), near.max(far)]
                    .into_iter()
                    .find(|l| *l > 0.0 && l.is_finite())
            }
            Shape::HeightField {
                frame,
                extent,
                relief,
            } => height_field_hit(frame, extent.as_ref(), relief, origin, dir),
        }
    }

    /// Grey level (0 … 1) of the surface at `point` (on the surface).
    pub fn grey(&self, point: &Point3<f64>) -> f64 {
        match &self.texture {
            Texture::Noise {
                seed,
                scale,
                octaves,
                contrast,
            } => {
                let local = match &self.shape {
                    Shape::Plane { frame, .. } | Shape::HeightField { frame, .. } => {
                        frame.local(point)
                    }
                    Shape::Sphere(s) => (point - s.centre).into(),
                };
                texture_grey(local, *scale, *octaves, *contrast, *seed)
            }
            Texture::Image(image) => match &self.shape {
                Shape::Plane { frame, .. } | Shape::HeightField { frame, .. } => {
                    let [s, t, _] = frame.local(point);
                    image.grey(s, t)
                }
                // Refused when the scene is read; a sphere has no (s, t).
                Shape::Sphere(_) => 0.5,
            },
        }
    }
}

/// The interval of λ ≥ 0 where a + λ·b lies in [low, high] (all λ ≥ 0 when b = 0 and a inside).
fn slab(a: f64, b: f64, low: f64, high: f64) -> Option<(f64, f64)> {
    if b.abs() < 1e-300 {
        return (a >= low && a <= high).then_some((0.0, f64::INFINITY));
    }
    let (l0, l1) = ((low - a) / b, (high - a) / b);
    let (start, end) = (l0.min(l1).max(0.0), l0.max(l1));
    (start <= end).then_some((start, end))
}

fn height_field_hit(
    frame: &SurfaceFrame,
    extent: Option<&Extent>,
    relief: &Relief,
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
) -> Option<f64> {
    let [s0, t0, h0] = frame.local(origin);
    let (ds, dt, dh) = (frame.e1.dot(dir), frame.e2.dot(dir), frame.normal.dot(dir));
    let bound = relief.height_bound;
    let (mut start, mut end) = slab(h0, dh, -bound, bound)?;
    if let Some(e) = extent {
        let (a, b) = slab(s0, ds, e.s[0], e.s[1])?;
        let (c, d) = slab(t0, dt, e.t[0], e.t[1])?;
        start = start.max(a).max(c);
        end = end.min(b).min(d);
    }
    if !(start <= end) || !start.is_finite() {
        return None;
    }
    let g = |lambda: f64| h0 + lambda * dh - relief.height(s0 + lambda * ds, t0 + lambda * dt);
    let slope = dh.abs() + relief.slope_bound * ds.hypot(dt);
    let mut lambda = start;
    let mut value = g(lambda);
    if value == 0.0 {
        return (lambda > 0.0).then_some(lambda);
    }
    let sign = value > 0.0;
    for _ in 0..MAX_MARCH_STEPS {
        if lambda >= end {
            return None;
        }
        let step = (value.abs() / slope).max(relief.min_step);
        let next = (lambda + step).min(end);
        let next_value = g(next);
        if next_value == 0.0 {
            return (next > 0.0).then_some(next);
        }
        if (next_value > 0.0) != sign {
            // The bracket [lambda, next] shrunk to the tolerance (the ray's direction is a unit
            // vector): regula falsi with the Illinois modification (superlinear; a stale end's
            // value is halved so that both ends close in), each step keeping the sign change
            // inside the bracket as bisection would.
            let (mut low, mut high) = (lambda, next);
            let (mut g_low, mut g_high) = (value, next_value);
            let mut side = 0i8;
            for _ in 0..200 {
                if high - low <= HEIGHT_FIELD_TOLERANCE {
                    break;
                }
                let mut x = high - g_high * (high - low) / (g_high - g_low);
                if !(x > low && x < high) {
                    x = 0.5 * (low + high);
                }
                let gx = g(x);
                if gx == 0.0 {
                    return (x > 0.0).then_some(x);
                }
                if (gx > 0.0) == sign {
                    low = x;
                    g_low = gx;
                    if side == -1 {
                        g_high *= 0.5;
                    }
                    side = -1;
                } else {
                    high = x;
                    g_high = gx;
                    if side == 1 {
                        g_low *= 0.5;
                    }
                    side = 1;
                }
            }
            let hit = 0.5 * (low + high);
            return (hit > 0.0).then_some(hit);
        }
        lambda = next;
        value = next_value;
    }
    None
}

/// A scene: surfaces, a background grey level for rays that hit nothing, and frames (the whole
/// scene moved by an offset per frame).
#[derive(Debug, Clone, PartialEq)]
pub struct TexturedScene {
    /// The surfaces (the nearest hit wins).
    pub surfaces: Vec<Surface>,
    /// Grey level of the water where a ray hits nothing.
    pub background: f64,
    /// Offset of every surface in each frame, master frame (one zero offset for a still scene).
    pub frames: Vec<Vector3<f64>>,
}

/// What a ray sees: the hit point (master frame) and its grey level, or nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// The point, master frame.
    pub point: Point3<f64>,
    /// Grey level 0 … 1.
    pub grey: f64,
}

impl TexturedScene {
    /// The nearest surface point on the water ray o + λd (λ > 0, d a unit vector) in `frame`.
    ///
    /// # Panics
    /// When `frame` is out of range.
    pub fn trace(&self, origin: &Point3<f64>, dir: &Vector3<f64>, frame: usize) -> Option<Hit> {
        let offset = self.frames[frame];
        // The scene stands still and the ray moves back by the frame's offset.
        let local = origin - offset;
        let (lambda, surface) = self
            .surfaces
            .iter()
            .filter_map(|s| s.hit(&local, dir).map(|l| (l, s)))
            .min_by(|a, b| a.0.total_cmp(&b.0))?;
        let on_surface = local + dir * lambda;
        Some(Hit {
            point: on_surface + offset,
            grey: surface.grey(&on_surface),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise() -> Texture {
        Texture::Noise {
            seed: 1,
            scale: 0.1,
            octaves: 3,
            contrast: 3.0,
        }
    }

    #[test]
    fn a_plane_a_sphere_and_the_nearest_wins() {
        let plane = Surface {
            shape: Shape::Plane {
                frame: SurfaceFrame::new(Point3::new(0.0, 0.0, 2.0), Vector3::new(0.0, 0.0, -1.0))
                    .unwrap(),
                extent: None,
            },
            texture: noise(),
        };
        let sphere = Surface {
            shape: Shape::Sphere(Sphere {
                centre: Point3::new(0.0, 0.0, 1.5),
                radius: 0.25,
            }),
            texture: noise(),
        };
        let scene = TexturedScene {
            surfaces: vec![plane, sphere],
            background: 0.4,
            frames: vec![Vector3::zeros(), Vector3::new(1.0, 0.0, 0.0)],
        };
        let o = Point3::new(0.0, 0.0, 0.1);
        let hit = scene.trace(&o, &Vector3::z(), 0).unwrap();
        assert!((hit.point.z - 1.25).abs() < 1e-12, "{hit:?}");
        // Frame 1 moves the sphere away: the plane behind it.
        let hit = scene.trace(&o, &Vector3::z(), 1).unwrap();
        assert!((hit.point.z - 2.0).abs() < 1e-12, "{hit:?}");
        assert!(scene.trace(&o, &-Vector3::z(), 0).is_none());
    }

    #[test]
    fn a_height_field_hit_lies_on_the_relief() {
        let frame =
            SurfaceFrame::new(Point3::new(0.0, 0.0, 1.5), Vector3::new(0.0, 0.1, -1.0)).unwrap();
        let relief = Relief::seeded(0.05, 0.3, 6, 3).unwrap();
        let surface = Surface {
            shape: Shape::HeightField {
                frame: frame.clone(),
                extent: None,
                relief: relief.clone(),
            },
            texture: noise(),
        };
        let o = Point3::new(0.05, -0.02, 0.05);
        let mut hits = 0;
        for i in 0..200 {
            let a = i as f64 * 0.013 - 1.3;
            let d = Vector3::new(a.sin() * 0.6, (a * 1.7).cos() * 0.3, 1.0).normalize();
            let Some(lambda) = surface.hit(&o, &d) else {
                continue;
            };
            hits += 1;
            let [s, t, h] = frame.local(&(o + d * lambda));
            assert!(
                (h - relief.height(s, t)).abs() < 1e-8,
                "off the relief by {}",
                h - relief.height(s, t)
            );
            // Nothing nearer: the ray stays on the water side of the relief before the hit.
            for k in 1..200 {
                let [s, t, h] = frame.local(&(o + d * (lambda * k as f64 / 200.0)));
                assert!(h > relief.height(s, t), "a nearer crossing was skipped");
            }
        }
        assert!(hits > 150, "{hits} hits");
    }
}
