//! The grey image that the matcher reads (and `flatport render` draws): plain rows of `f32`,
//! so that the library and Python need no image-file crate to hold one.

/// A grey image, row-major, values 0 … 1.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width · height` values, row-major.
    pub pixels: Vec<f32>,
}

impl GreyImage {
    /// The image as 8-bit grey levels (rounded, clamped).
    pub fn to_u8(&self) -> Vec<u8> {
        self.pixels
            .iter()
            .map(|&p| (p * 255.0).round().clamp(0.0, 255.0) as u8)
            .collect()
    }

    /// The image as 16-bit grey levels (rounded, clamped).
    pub fn to_u16(&self) -> Vec<u16> {
        self.pixels
            .iter()
            .map(|&p| (p * 65535.0).round().clamp(0.0, 65535.0) as u16)
            .collect()
    }

    /// The image smoothed by a Gaussian of standard deviation `sigma` pixels (separable, the
    /// kernel cut at 3σ and renormalised, the border pixels repeated); `sigma <= 0` returns a
    /// copy. Written here rather than taken from the `image` crate, which the library does not
    /// need without its `images` feature (the targetless matcher smooths degraded footage with
    /// it, and runs without that feature).
    pub fn smoothed(&self, sigma: f64) -> GreyImage {
        if !(sigma > 0.0) || self.pixels.is_empty() {
            return self.clone();
        }
        let radius = (3.0 * sigma).ceil() as i64;
        let kernel: Vec<f32> = (-radius..=radius)
            .map(|i| (-((i * i) as f64) / (2.0 * sigma * sigma)).exp() as f32)
            .collect();
        let total: f32 = kernel.iter().sum();
        let kernel: Vec<f32> = kernel.iter().map(|k| k / total).collect();
        let (w, h) = (self.width as i64, self.height as i64);
        let pass = |from: &[f32], along_rows: bool| -> Vec<f32> {
            let mut out = vec![0.0f32; from.len()];
            for y in 0..h {
                for x in 0..w {
                    let mut sum = 0.0f32;
                    for (j, k) in kernel.iter().enumerate() {
                        let d = j as i64 - radius;
                        let (sx, sy) = if along_rows {
                            ((x + d).clamp(0, w - 1), y)
                        } else {
                            (x, (y + d).clamp(0, h - 1))
                        };
                        sum += k * from[(sy * w + sx) as usize];
                    }
                    out[(y * w + x) as usize] = sum;
                }
            }
            out
        };
        let rows = pass(&self.pixels, true);
        GreyImage {
            width: self.width,
            height: self.height,
            pixels: pass(&rows, false),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothing_keeps_a_constant_and_spreads_an_impulse_as_a_gaussian() {
        let flat = GreyImage {
            width: 9,
            height: 7,
            pixels: vec![0.25; 63],
        };
        assert!(
            flat.smoothed(1.5)
                .pixels
                .iter()
                .all(|p| (p - 0.25).abs() < 1e-6)
        );
        let mut impulse = vec![0.0f32; 21 * 21];
        impulse[10 * 21 + 10] = 1.0;
        let image = GreyImage {
            width: 21,
            height: 21,
            pixels: impulse,
        };
        let sigma = 1.3;
        let out = image.smoothed(sigma);
        // Mass kept (the impulse is far from the border); the second moment along each axis σ²
        // less what the kernel's cut at ⌈3σ⌉ takes (a normal cut at 3σ keeps 97.3 % of its
        // variance); neighbours in the ratio of the Gaussian's, exp(−1/(2σ²)).
        let mass: f32 = out.pixels.iter().sum();
        assert!((mass - 1.0).abs() < 1e-5, "{mass}");
        let moment: f64 = (0..21 * 21)
            .map(|i| f64::from(out.pixels[i]) * ((i % 21) as f64 - 10.0).powi(2))
            .sum();
        assert!((moment / (sigma * sigma) - 0.985).abs() < 0.015, "{moment}");
        let ratio = f64::from(out.pixels[10 * 21 + 11] / out.pixels[10 * 21 + 10]);
        assert!(
            (ratio - (-1.0 / (2.0 * sigma * sigma)).exp()).abs() < 1e-4,
            "{ratio}"
        );
        assert_eq!(image.smoothed(0.0), image);
    }
}
