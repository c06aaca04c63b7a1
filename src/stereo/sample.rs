//! Bilinear sampling of one row of projections, the inner loop of the tabulated warp.

/// `out[x]` = `image` sampled bilinearly at (`u[x]`, `v[x]`) as [`sample_bilinear`] samples it
/// (NaN outside the image, and where a coordinate is NaN), bit for bit, 8 pixels at a time with
/// AVX-512 gathers where the processor has them.
///
/// Why intrinsics: the four samples of a bilinear read are scattered loads that LLVM vectorises
/// only with gathers, which its generic x86-64 cost model never chooses; one at a time they wait
/// on the cache (a third of the 1280 × 1024 pair's time, `docs/performance.md`).
///
/// [`sample_bilinear`]: super::project::sample_bilinear
pub(crate) fn sample_row(
    pixels: &[f32],
    w: usize,
    h: usize,
    u: &[f64],
    v: &[f64],
    out: &mut [f32],
) {
    assert!(u.len() == out.len() && v.len() == out.len() && pixels.len() == w * h);
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if w >= 2
        && h >= 2
        && w * h < i32::MAX as usize
        && std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vl")
    {
        // SAFETY: the processor has AVX-512F and VL (checked above); the function's loads are masked
        // to pixels inside the image (see there).
        done = unsafe { avx512::sample_row(pixels, w, h, u, v, out) };
    }
    for x in done..out.len() {
        out[x] = super::project::sample_bilinear(pixels, w, h, u[x], v[x]);
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    /// [`super::sample_row`] for the first multiple of 8 pixels; returns how many it did. The
    /// image must be at least 2 × 2 and under 2³¹ pixels.
    #[target_feature(enable = "avx512f,avx512vl")]
    pub(super) fn sample_row(
        pixels: &[f32],
        w: usize,
        h: usize,
        u: &[f64],
        v: &[f64],
        out: &mut [f32],
    ) -> usize {
        let n = out.len() / 8 * 8;
        let (u_max, v_max) = (
            _mm512_set1_pd((w - 1) as f64),
            _mm512_set1_pd((h - 1) as f64),
        );
        let zero = _mm512_setzero_pd();
        let (x_last, y_last) = (
            _mm512_set1_pd((w - 2) as f64),
            _mm512_set1_pd((h - 2) as f64),
        );
        let width = _mm256_set1_epi32(w as i32);
        // The gather reads 8 bytes at base + 4·index, aligned or not.
        let base = pixels.as_ptr().cast::<i64>();
        for x in (0..n).step_by(8) {
            // SAFETY (loads and stores): x + 8 ≤ n ≤ the slices' length.
            let (uu, vv) = unsafe {
                (
                    _mm512_loadu_pd(u.as_ptr().add(x)),
                    _mm512_loadu_pd(v.as_ptr().add(x)),
                )
            };
            // Inside [0, w − 1] × [0, h − 1]; a NaN fails every comparison.
            let inside = _mm512_cmp_pd_mask::<_CMP_GE_OQ>(uu, zero)
                & _mm512_cmp_pd_mask::<_CMP_LE_OQ>(uu, u_max)
                & _mm512_cmp_pd_mask::<_CMP_GE_OQ>(vv, zero)
                & _mm512_cmp_pd_mask::<_CMP_LE_OQ>(vv, v_max);
            // The cell's corner: trunc, one short of the last column and row (as the scalar).
            let x0 = _mm512_min_pd(
                _mm512_roundscale_pd::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(uu),
                x_last,
            );
            let y0 = _mm512_min_pd(
                _mm512_roundscale_pd::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(vv),
                y_last,
            );
            let fx = _mm512_cvtpd_ps(_mm512_sub_pd(uu, x0));
            let fy = _mm512_cvtpd_ps(_mm512_sub_pd(vv, y0));
            // Outside lanes read pixel 0 (masked off below, and their index is 0 by the mask).
            let index = _mm512_maskz_cvttpd_epi32(
                inside,
                _mm512_add_pd(x0, _mm512_mul_pd(y0, _mm512_set1_pd(w as f64))),
            );
            let index_below = _mm256_add_epi32(index, width);
            // Two neighbouring floats as one 64-bit element: (x0, y0) with (x0 + 1, y0).
            // SAFETY: a lane inside the image has x0 + 1 ≤ w − 1 and y0 + 1 ≤ h − 1, so both
            // pairs lie within `pixels`; other lanes are masked off.
            let (top, bottom) = unsafe {
                (
                    _mm512_mask_i32gather_epi64::<4>(_mm512_setzero_si512(), inside, index, base),
                    _mm512_mask_i32gather_epi64::<4>(
                        _mm512_setzero_si512(),
                        inside,
                        index_below,
                        base,
                    ),
                )
            };
            // Low halves are the left samples, high halves the right ones.
            let left_top = _mm256_castsi256_ps(_mm512_cvtepi64_epi32(top));
            let right_top =
                _mm256_castsi256_ps(_mm512_cvtepi64_epi32(_mm512_srli_epi64::<32>(top)));
            let left_bottom = _mm256_castsi256_ps(_mm512_cvtepi64_epi32(bottom));
            let right_bottom =
                _mm256_castsi256_ps(_mm512_cvtepi64_epi32(_mm512_srli_epi64::<32>(bottom)));
            // top + fx·(right − left), as the scalar rounds (no fused multiply-add).
            let upper = _mm256_add_ps(
                left_top,
                _mm256_mul_ps(fx, _mm256_sub_ps(right_top, left_top)),
            );
            let lower = _mm256_add_ps(
                left_bottom,
                _mm256_mul_ps(fx, _mm256_sub_ps(right_bottom, left_bottom)),
            );
            let value = _mm256_add_ps(upper, _mm256_mul_ps(fy, _mm256_sub_ps(lower, upper)));
            let value = _mm256_mask_blend_ps(inside, _mm256_set1_ps(f32::NAN), value);
            // SAFETY: x + 8 ≤ n ≤ out.len().
            unsafe { _mm256_storeu_ps(out.as_mut_ptr().add(x), value) };
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::super::project::sample_bilinear;

    #[test]
    fn a_row_is_sampled_as_one_pixel_at_a_time_bit_for_bit() {
        let (w, h) = (13usize, 7usize);
        let pixels: Vec<f32> = (0..w * h)
            .map(|i| ((i * 37) % 101) as f32 / 101.0 + (i as f32 * 0.7).sin())
            .collect();
        // Inside, on every edge and corner, just outside, far outside, NaN, −0: 43 pixels (not a
        // multiple of 8, so the scalar tail runs too).
        let mut u = vec![
            0.0,
            12.0,
            12.0,
            -0.0,
            11.999,
            12.0001,
            -1e-9,
            3.25,
            f64::NAN,
            1e9,
        ];
        let mut v = vec![0.0, 6.0, 0.0, 6.0, 5.5, 3.0, 2.0, f64::NAN, 1.0, 2.0];
        for k in 0..33 {
            u.push(k as f64 * 0.41 - 0.7);
            v.push(6.3 - k as f64 * 0.2);
        }
        let mut out = vec![0f32; u.len()];
        super::sample_row(&pixels, w, h, &u, &v, &mut out);
        for (x, &got) in out.iter().enumerate() {
            let expected = sample_bilinear(&pixels, w, h, u[x], v[x]);
            assert_eq!(
                got.to_bits(),
                expected.to_bits(),
                "pixel {x} at ({}, {}): {got} against {expected}",
                u[x],
                v[x]
            );
        }
        assert!(out[8].is_nan() && out[9].is_nan() && out[5].is_nan() && out[6].is_nan());
    }
}
