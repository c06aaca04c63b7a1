//! [`F64s`]: [`LANES`] f64 numbers that every operation treats lane by lane, and [`Mask`], a
//! boolean per lane.
//!
//! Every operation is a plain loop over the lanes, `#[inline(always)]`, so that inside a function
//! compiled for AVX-512 (or AVX2, or NEON: see [`super`]'s dispatch) LLVM turns each into one
//! or two vector instructions: `vsqrtpd`, `vdivpd`, `vcmppd` and blends. There is no `unsafe` and
//! no intrinsic here.
//!
//! Why not a crate: `wide` picks its instructions by the features the crate is *compiled* for
//! (SSE2 in a default x86-64 build) and cannot follow a runtime choice; `pulp` does, but its
//! vocabulary (`simd.add_f64s(a, b)`, 8-wide only under its `x86-v4` feature) would make the
//! kernels read nothing like the scalar model they must track. These loops, with
//! `multiversion` for the runtime choice, give the same instructions (checked in `cargo bench
//! --bench cpu` against the scalar path) and kernels that read like `model/`.
//!
//! Arithmetic is IEEE per lane: a lane computes bit for bit what the scalar expression in the
//! same order computes (no fused multiply-add is formed: Rust does not contract).

use std::ops::{Add, AddAssign, BitAnd, BitOr, Div, Mul, Neg, Not, Sub, SubAssign};

/// Number of lanes: 16 f64, i.e. two AVX-512 registers (four AVX2 ones, eight NEON ones) per
/// value. Not one register: √ and ÷ take ~20 cycles of latency and a Newton step waits on them, so
/// several independent registers per operation keep the units busy. Measured on the bench
/// workload (AMD EPYC, AVX-512, one thread): 8 lanes 3.3×, 16 lanes 6.9× the scalar
/// back-projection; forward projection 2.0×, 4.0× (32 lanes: 4.8×, but back-projection fell back
/// to 5×).
pub const LANES: usize = 16;

/// [`LANES`] f64 values.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(64))]
pub struct F64s(pub [f64; LANES]);

/// A boolean per lane.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Mask(pub [bool; LANES]);

macro_rules! lanewise {
    ($a:expr, |$l:ident| $body:expr) => {{
        let mut out = [Default::default(); LANES];
        let mut $l = 0;
        while $l < LANES {
            out[$l] = $body;
            $l += 1;
        }
        out
    }};
}

impl F64s {
    /// Every lane `x`.
    #[inline(always)]
    pub fn splat(x: f64) -> Self {
        Self([x; LANES])
    }

    /// Lane-wise √.
    #[inline(always)]
    pub fn sqrt(self) -> Self {
        Self(lanewise!(self, |l| self.0[l].sqrt()))
    }

    /// Lane-wise |x|.
    #[inline(always)]
    pub fn abs(self) -> Self {
        Self(lanewise!(self, |l| self.0[l].abs()))
    }

    /// Lane-wise [`f64::min`] (a NaN lane takes the other operand).
    #[inline(always)]
    pub fn min(self, other: Self) -> Self {
        Self(lanewise!(self, |l| self.0[l].min(other.0[l])))
    }

    /// Lane-wise [`f64::max`] (a NaN lane takes the other operand).
    #[inline(always)]
    pub fn max(self, other: Self) -> Self {
        Self(lanewise!(self, |l| self.0[l].max(other.0[l])))
    }

    /// `self < other` per lane (false where either is NaN).
    #[inline(always)]
    pub fn lt(self, other: Self) -> Mask {
        Mask(lanewise!(self, |l| self.0[l] < other.0[l]))
    }

    /// `self <= other` per lane.
    #[inline(always)]
    pub fn le(self, other: Self) -> Mask {
        Mask(lanewise!(self, |l| self.0[l] <= other.0[l]))
    }

    /// `self > other` per lane.
    #[inline(always)]
    pub fn gt(self, other: Self) -> Mask {
        Mask(lanewise!(self, |l| self.0[l] > other.0[l]))
    }

    /// `self >= other` per lane.
    #[inline(always)]
    pub fn ge(self, other: Self) -> Mask {
        Mask(lanewise!(self, |l| self.0[l] >= other.0[l]))
    }

    /// `self == other` per lane.
    #[inline(always)]
    pub fn eq(self, other: Self) -> Mask {
        Mask(lanewise!(self, |l| self.0[l] == other.0[l]))
    }

    /// Whether each lane is finite (not ±∞, not NaN).
    #[inline(always)]
    pub fn is_finite(self) -> Mask {
        Mask(lanewise!(self, |l| self.0[l].is_finite()))
    }

    /// `|self| <= limit` per lane: false for NaN.
    #[inline(always)]
    pub fn within(self, limit: f64) -> Mask {
        Mask(lanewise!(self, |l| self.0[l].abs() <= limit))
    }
}

impl Mask {
    /// Every lane `b`.
    #[inline(always)]
    pub fn splat(b: bool) -> Self {
        Self([b; LANES])
    }

    /// Whether any lane is set.
    #[inline(always)]
    pub fn any(self) -> bool {
        self.0.iter().fold(false, |a, &b| a | b)
    }

    /// Whether every lane is set.
    #[inline(always)]
    pub fn all(self) -> bool {
        self.0.iter().fold(true, |a, &b| a & b)
    }

    /// Lane-wise `if self { a } else { b }`.
    #[inline(always)]
    pub fn select(self, a: F64s, b: F64s) -> F64s {
        F64s(lanewise!(self, |l| if self.0[l] { a.0[l] } else { b.0[l] }))
    }

    /// Lane-wise `self && !other`.
    #[inline(always)]
    pub fn and_not(self, other: Mask) -> Mask {
        self & !other
    }
}

macro_rules! binary {
    ($trait:ident, $method:ident, $op:tt) => {
        impl $trait for F64s {
            type Output = F64s;
            #[inline(always)]
            fn $method(self, rhs: F64s) -> F64s {
                F64s(lanewise!(self, |l| self.0[l] $op rhs.0[l]))
            }
        }
        impl $trait<f64> for F64s {
            type Output = F64s;
            #[inline(always)]
            fn $method(self, rhs: f64) -> F64s {
                F64s(lanewise!(self, |l| self.0[l] $op rhs))
            }
        }
        impl $trait<F64s> for f64 {
            type Output = F64s;
            #[inline(always)]
            fn $method(self, rhs: F64s) -> F64s {
                F64s(lanewise!(rhs, |l| self $op rhs.0[l]))
            }
        }
    };
}

binary!(Add, add, +);
binary!(Sub, sub, -);
binary!(Mul, mul, *);
binary!(Div, div, /);

impl AddAssign for F64s {
    #[inline(always)]
    fn add_assign(&mut self, rhs: F64s) {
        *self = *self + rhs;
    }
}

impl SubAssign for F64s {
    #[inline(always)]
    fn sub_assign(&mut self, rhs: F64s) {
        *self = *self - rhs;
    }
}

impl Neg for F64s {
    type Output = F64s;
    #[inline(always)]
    fn neg(self) -> F64s {
        F64s(lanewise!(self, |l| -self.0[l]))
    }
}

impl BitAnd for Mask {
    type Output = Mask;
    #[inline(always)]
    fn bitand(self, rhs: Mask) -> Mask {
        Mask(lanewise!(self, |l| self.0[l] & rhs.0[l]))
    }
}

impl BitOr for Mask {
    type Output = Mask;
    #[inline(always)]
    fn bitor(self, rhs: Mask) -> Mask {
        Mask(lanewise!(self, |l| self.0[l] | rhs.0[l]))
    }
}

impl Not for Mask {
    type Output = Mask;
    #[inline(always)]
    fn not(self) -> Mask {
        Mask(lanewise!(self, |l| !self.0[l]))
    }
}

/// Three lanes of vectors: (x, y, z) with a vector per lane.
#[derive(Debug, Clone, Copy)]
pub struct Vec3s {
    /// x of every lane.
    pub x: F64s,
    /// y of every lane.
    pub y: F64s,
    /// z of every lane.
    pub z: F64s,
}

impl Vec3s {
    /// The same vector in every lane.
    #[inline(always)]
    pub fn splat(v: [f64; 3]) -> Self {
        Self {
            x: F64s::splat(v[0]),
            y: F64s::splat(v[1]),
            z: F64s::splat(v[2]),
        }
    }

    /// a·b, summed as nalgebra does for 3-vectors: (x·x + y·y) + z·z.
    #[inline(always)]
    pub fn dot(self, other: Vec3s) -> F64s {
        self.x * other.x + self.y * other.y + self.z * other.z
    }

    /// |v|², as [`dot`](Self::dot) with itself.
    #[inline(always)]
    pub fn norm_squared(self) -> F64s {
        self.dot(self)
    }

    /// a × b.
    #[inline(always)]
    pub fn cross(self, b: Vec3s) -> Vec3s {
        Vec3s {
            x: self.y * b.z - self.z * b.y,
            y: self.z * b.x - self.x * b.z,
            z: self.x * b.y - self.y * b.x,
        }
    }

    /// Every component times `s`.
    #[inline(always)]
    pub fn scale(self, s: F64s) -> Vec3s {
        Vec3s {
            x: self.x * s,
            y: self.y * s,
            z: self.z * s,
        }
    }

    /// Lane-wise `if mask { a } else { b }`.
    #[inline(always)]
    pub fn select(mask: Mask, a: Vec3s, b: Vec3s) -> Vec3s {
        Vec3s {
            x: mask.select(a.x, b.x),
            y: mask.select(a.y, b.y),
            z: mask.select(a.z, b.z),
        }
    }

    /// Whether every component of each lane is finite.
    #[inline(always)]
    pub fn is_finite(self) -> Mask {
        self.x.is_finite() & self.y.is_finite() & self.z.is_finite()
    }
}

impl Add for Vec3s {
    type Output = Vec3s;
    #[inline(always)]
    fn add(self, b: Vec3s) -> Vec3s {
        Vec3s {
            x: self.x + b.x,
            y: self.y + b.y,
            z: self.z + b.z,
        }
    }
}

impl Sub for Vec3s {
    type Output = Vec3s;
    #[inline(always)]
    fn sub(self, b: Vec3s) -> Vec3s {
        Vec3s {
            x: self.x - b.x,
            y: self.y - b.y,
            z: self.z - b.z,
        }
    }
}

/// A constant vector times a lane of scalars: `v·s` per lane, with v the same in every lane.
#[inline(always)]
pub fn scaled(v: [f64; 3], s: F64s) -> Vec3s {
    Vec3s {
        x: v[0] * s,
        y: v[1] * s,
        z: v[2] * s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lanes(f: impl Fn(usize) -> f64) -> F64s {
        F64s(std::array::from_fn(f))
    }

    #[test]
    fn operations_are_the_scalar_ones_lane_by_lane() {
        let a = lanes(|l| l as f64 - 3.5);
        let b = lanes(|l| 0.25 + l as f64 * 1.5);
        for l in 0..LANES {
            let (x, y) = (a.0[l], b.0[l]);
            assert_eq!((a + b).0[l], x + y);
            assert_eq!((a - b).0[l], x - y);
            assert_eq!((a * b).0[l], x * y);
            assert_eq!((a / b).0[l], x / y);
            assert_eq!(b.sqrt().0[l], y.sqrt());
            assert_eq!(a.abs().0[l], x.abs());
            assert_eq!(a.min(b).0[l], x.min(y));
            assert_eq!(a.lt(b).0[l], x < y);
            assert_eq!(a.ge(b).0[l], x >= y);
            assert_eq!(a.lt(b).select(a, b).0[l], if x < y { x } else { y });
        }
    }

    #[test]
    fn nan_compares_false_and_is_not_finite() {
        let a = F64s::splat(f64::NAN);
        let one = F64s::splat(1.0);
        assert!(!a.lt(one).any() && !a.ge(one).any() && !a.eq(a).any());
        assert!(!a.is_finite().any());
        assert!(!a.within(1.0).any());
        assert_eq!(a.min(one), one, "min takes the number, as f64::min");
        assert!(
            F64s::splat(f64::INFINITY)
                .within(f64::MAX)
                .0
                .iter()
                .all(|&b| !b)
        );
    }

    #[test]
    fn masks_combine() {
        let m = Mask(std::array::from_fn(|l| l % 2 == 0));
        assert!(m.any() && !m.all());
        assert!((m | !m).all());
        assert!(!(m & !m).any());
        assert_eq!(m.and_not(m), Mask::splat(false));
    }

    #[test]
    fn vectors() {
        let a = Vec3s::splat([1.0, 2.0, 3.0]);
        let b = Vec3s::splat([-2.0, 0.5, 4.0]);
        assert_eq!(a.dot(b).0[3], 1.0 * -2.0 + 2.0 * 0.5 + 3.0 * 4.0);
        let c = a.cross(b);
        assert_eq!(
            [c.x.0[0], c.y.0[0], c.z.0[0]],
            [
                2.0 * 4.0 - 3.0 * 0.5,
                3.0 * -2.0 - 1.0 * 4.0,
                1.0 * 0.5 - 2.0 * -2.0
            ]
        );
    }
}
