// Division and square root to within an ulp or two on every adapter. Vulkan lets a driver
// approximate f64 division and square root (SPIR-V's OpFDiv and GLSL.std.450 Sqrt carry no
// accuracy requirement for f64), and a kernel whose result depends on their last digits (the
// affine grid's Cholesky factor, its per-corner weights) then differs from the CPU by far more
// than rounding. One Newton correction from the driver's value: the residual is computed in
// plain multiplications and subtractions (correctly rounded everywhere), and the correction's
// own approximate division enters only as a relative error of the (tiny) correction. With the
// driver's value within 2^-20 relative (any usable approximation), the result is within a few
// ulps of the correctly rounded one; on an adapter that divides exactly the correction is zero
// or one ulp.

// a / b (a zero, infinite or NaN quotient as the driver gives it).
fn div_exact(a: real, b: real) -> real {
    let q = a / b;
    if (!(abs(q) <= REAL_HUGE) || q == 0.0) {
        return q;
    }
    return q + (a - b * q) / b;
}

// 1 / b (an infinite or NaN reciprocal as the driver gives it).
fn recip_exact(b: real) -> real {
    let y = 1.0 / b;
    if (!(abs(y) <= REAL_HUGE)) {
        return y;
    }
    return y + y * (1.0 - b * y);
}

// √x for x ≥ 0 (0 stays 0).
fn sqrt_exact(x: real) -> real {
    let s = sqrt(x);
    if (!(s > 0.0)) {
        return s;
    }
    return s + (x - s * s) / (2.0 * s);
}
