//! Seeded procedural noise for textured scenes: 3-D gradient noise (Perlin's improved noise with
//! hashed lattice gradients instead of a permutation table, so any seed gives an independent
//! field), summed over octaves (fractional Brownian motion) and pushed through a tanh for
//! high-contrast detail at every scale.
//!
//! Gradient noise n(p) at a point p: with i = ⌊p⌋ and f = p − i, each of the 8 lattice corners c
//! carries a gradient g_c (one of the 12 cube-edge directions, chosen by a hash of c and the seed);
//! n(p) = trilinear blend of g_c·(f − c) with weights from the quintic fade
//! φ(t) = 6t⁵ − 15t⁴ + 10t³ (C² continuous). n is 0 at every lattice point and lies in about
//! [−1, 1]. Octave k is n(2ᵏ·p/scale + o_k) with amplitude 2⁻ᵏ (o_k a seeded offset), so the
//! largest features are `scale` metres across and each octave adds detail half that size.

/// A 32-bit integer hash of three lattice coordinates and a seed (the finaliser of MurmurHash3
/// applied to a mix of the inputs): equal inputs give equal outputs on every platform.
#[inline]
fn hash(x: i64, y: i64, z: i64, seed: u64) -> u32 {
    let mut h = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((x as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
        .wrapping_add((y as u64).wrapping_mul(0x1656_67B1_9E37_79F9))
        .wrapping_add((z as u64).wrapping_mul(0x27D4_EB2F_1656_67C5));
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h = h.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    h ^= h >> 33;
    h as u32
}

/// The 12 cube-edge gradients of Perlin's improved noise.
const GRADIENTS: [[f64; 3]; 12] = [
    [1.0, 1.0, 0.0],
    [-1.0, 1.0, 0.0],
    [1.0, -1.0, 0.0],
    [-1.0, -1.0, 0.0],
    [1.0, 0.0, 1.0],
    [-1.0, 0.0, 1.0],
    [1.0, 0.0, -1.0],
    [-1.0, 0.0, -1.0],
    [0.0, 1.0, 1.0],
    [0.0, -1.0, 1.0],
    [0.0, 1.0, -1.0],
    [0.0, -1.0, -1.0],
];

/// φ(t) = 6t⁵ − 15t⁴ + 10t³.
#[inline]
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

#[inline]
fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + t * (b - a)
}

/// Gradient noise at `p` for `seed`: about [−1, 1], 0 at integer points, C² smooth.
pub fn gradient_noise(p: [f64; 3], seed: u64) -> f64 {
    let cell = p.map(f64::floor);
    let f = [p[0] - cell[0], p[1] - cell[1], p[2] - cell[2]];
    let i = cell.map(|c| c as i64);
    let corner = |dx: i64, dy: i64, dz: i64| {
        let g = GRADIENTS[(hash(i[0] + dx, i[1] + dy, i[2] + dz, seed) % 12) as usize];
        g[0] * (f[0] - dx as f64) + g[1] * (f[1] - dy as f64) + g[2] * (f[2] - dz as f64)
    };
    let (u, v, w) = (fade(f[0]), fade(f[1]), fade(f[2]));
    let x00 = lerp(corner(0, 0, 0), corner(1, 0, 0), u);
    let x10 = lerp(corner(0, 1, 0), corner(1, 1, 0), u);
    let x01 = lerp(corner(0, 0, 1), corner(1, 0, 1), u);
    let x11 = lerp(corner(0, 1, 1), corner(1, 1, 1), u);
    lerp(lerp(x00, x10, v), lerp(x01, x11, v), w)
}

/// Sum of `octaves` octaves of [`gradient_noise`] at `p` (metres): octave k at frequency
/// 2ᵏ/`scale` with amplitude 2⁻ᵏ, divided by the sum of the amplitudes. Each octave has its own
/// seed and a seeded offset, so the octaves' lattices do not line up.
pub fn fractal_noise(p: [f64; 3], scale: f64, octaves: u32, seed: u64) -> f64 {
    let (mut sum, mut norm, mut amplitude, mut frequency) = (0.0, 0.0, 1.0, 1.0 / scale);
    for k in 0..octaves {
        let s = seed.wrapping_mul(1_000_003).wrapping_add(u64::from(k));
        let offset = [0, 1, 2].map(|a| f64::from(hash(a, 7, 11, s) % 4096) / 64.0);
        let q = [
            p[0] * frequency + offset[0],
            p[1] * frequency + offset[1],
            p[2] * frequency + offset[2],
        ];
        sum += amplitude * gradient_noise(q, s);
        norm += amplitude;
        amplitude *= 0.5;
        frequency *= 2.0;
    }
    sum / norm
}

/// Grey level (0.05 … 0.95) of the procedural texture at `p`: 0.5 + 0.45·tanh(contrast · fBm(p)).
pub fn texture_grey(p: [f64; 3], scale: f64, octaves: u32, contrast: f64, seed: u64) -> f64 {
    0.5 + 0.45 * (contrast * fractal_noise(p, scale, octaves, seed)).tanh()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_zero_on_the_lattice_bounded_and_seeded() {
        assert_eq!(gradient_noise([3.0, -2.0, 5.0], 1), 0.0);
        let mut max = 0f64;
        let mut differ = 0;
        for i in 0..2000 {
            let p = [
                i as f64 * 0.137,
                i as f64 * 0.291 - 40.0,
                (i % 17) as f64 * 0.43,
            ];
            let (a, b) = (gradient_noise(p, 1), gradient_noise(p, 2));
            max = max.max(a.abs());
            if (a - b).abs() > 1e-6 {
                differ += 1;
            }
            assert_eq!(a, gradient_noise(p, 1), "deterministic");
        }
        assert!(max <= 1.5 && max > 0.3, "max |n| = {max}");
        assert!(
            differ > 1500,
            "seeds give different fields ({differ} of 2000 differ)"
        );
    }

    #[test]
    fn texture_has_contrast_at_several_scales() {
        // Standard deviation of the grey level over a line of samples: well above camera noise.
        let values: Vec<f64> = (0..4000)
            .map(|i| texture_grey([i as f64 * 0.001, 0.3, 1.2], 0.05, 5, 3.0, 9))
            .collect();
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        let sd =
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt();
        assert!(sd > 0.15, "sd {sd}");
        assert!(values.iter().all(|v| (0.05..=0.95).contains(v)));
    }
}
