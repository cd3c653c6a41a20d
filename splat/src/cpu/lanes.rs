//! Eight `f32` lanes as one value, for code that handles eight Gaussians at once
//! ([`crate::cpu::project::lanes`]). Every operation is a loop over the lanes, which the compiler
//! turns into vector instructions (AVX2 where the caller is compiled with it); no lane mixes
//! with another, so each lane gets the bits a scalar evaluation of the same expression gets
//! ([`F8::exp`] included, but for rare arguments where it rounds the other way from `expf`).

use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// Lanes per value.
pub const LANES: usize = 8;

/// What the formulas shared by the scalar and the lane code (SH basis, quaternion rotation and
/// its backward) need of a number: `f32` for the scalar path, [`F8`] for eight Gaussians at
/// once. Both evaluate the same expressions in the same order, so each lane gets the scalar
/// bits.
pub trait Lane:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + Add<f32, Output = Self>
    + Sub<f32, Output = Self>
    + Mul<f32, Output = Self>
{
    fn splat(v: f32) -> Self;
}

impl Lane for f32 {
    #[inline(always)]
    fn splat(v: f32) -> f32 {
        v
    }
}

impl Lane for F8 {
    #[inline(always)]
    fn splat(v: f32) -> F8 {
        F8([v; LANES])
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct F8(pub [f32; LANES]);

/// A lane mask.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct M8(pub [bool; LANES]);

macro_rules! binop {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: F8) -> F8 {
                F8(std::array::from_fn(|l| self.0[l] $op o.0[l]))
            }
        }
        impl $tr<f32> for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: f32) -> F8 {
                F8(std::array::from_fn(|l| self.0[l] $op o))
            }
        }
        impl $tr<F8> for f32 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: F8) -> F8 {
                F8(std::array::from_fn(|l| self $op o.0[l]))
            }
        }
    };
}

binop!(Add, add, +);
binop!(Sub, sub, -);
binop!(Mul, mul, *);
binop!(Div, div, /);

impl Neg for F8 {
    type Output = F8;
    #[inline(always)]
    fn neg(self) -> F8 {
        self.map(|v| -v)
    }
}

impl F8 {
    #[inline(always)]
    pub fn splat(v: f32) -> F8 {
        F8([v; LANES])
    }

    #[inline(always)]
    pub fn map(self, f: impl Fn(f32) -> f32) -> F8 {
        F8(std::array::from_fn(|l| f(self.0[l])))
    }

    #[inline(always)]
    fn zip(self, o: F8, f: impl Fn(f32, f32) -> f32) -> F8 {
        F8(std::array::from_fn(|l| f(self.0[l], o.0[l])))
    }

    #[inline(always)]
    fn test(self, o: F8, f: impl Fn(f32, f32) -> bool) -> M8 {
        M8(std::array::from_fn(|l| f(self.0[l], o.0[l])))
    }

    #[inline(always)]
    pub fn sqrt(self) -> F8 {
        self.map(f32::sqrt)
    }

    #[inline(always)]
    pub fn abs(self) -> F8 {
        self.map(f32::abs)
    }

    #[inline(always)]
    pub fn ceil(self) -> F8 {
        self.map(f32::ceil)
    }

    /// `f32::min` per lane (a NaN lane takes the other operand).
    #[inline(always)]
    pub fn min(self, o: F8) -> F8 {
        self.zip(o, f32::min)
    }

    #[inline(always)]
    pub fn max(self, o: F8) -> F8 {
        self.zip(o, f32::max)
    }

    /// `f32::clamp` per lane (NaN stays NaN).
    #[inline(always)]
    pub fn clamp(self, lo: f32, hi: f32) -> F8 {
        self.map(|v| v.clamp(lo, hi))
    }

    #[inline(always)]
    pub fn lt(self, o: F8) -> M8 {
        self.test(o, |a, b| a < b)
    }

    #[inline(always)]
    pub fn le(self, o: F8) -> M8 {
        self.test(o, |a, b| a <= b)
    }

    #[inline(always)]
    pub fn gt(self, o: F8) -> M8 {
        self.test(o, |a, b| a > b)
    }

    #[inline(always)]
    pub fn ge(self, o: F8) -> M8 {
        self.test(o, |a, b| a >= b)
    }

    #[inline(always)]
    pub fn ne(self, o: F8) -> M8 {
        self.test(o, |a, b| a != b)
    }

    #[inline(always)]
    pub fn is_finite(self) -> M8 {
        M8(std::array::from_fn(|l| self.0[l].is_finite()))
    }

    /// `a` where `m`, else `b`.
    #[inline(always)]
    pub fn select(m: M8, a: F8, b: F8) -> F8 {
        F8(std::array::from_fn(
            |l| if m.0[l] { a.0[l] } else { b.0[l] },
        ))
    }

    /// `e^x`, evaluated in float64 and rounded once: `x = n ln2 + r` with `|r| ≤ ln2/2`, a
    /// degree-10 Taylor polynomial for `e^r` (relative error below 1e-12) and `2^n` made in the
    /// exponent bits. The rounding to float32 then gives the correctly rounded result, as the
    /// C library's `expf` does, except where `e^x` lies within 1e-12 of a halfway point
    /// (tested: every lane equal to `f32::exp` over a dense sweep, or within one unit in the
    /// last place). Overflow gives infinity, underflow zero or a subnormal, NaN stays NaN; all
    /// of it in arithmetic and integer operations the compiler vectorises.
    #[inline(always)]
    pub fn exp(self) -> F8 {
        self.map(|v| {
            // 1.5 · 2⁵²: adding it rounds to an integer held in the low mantissa bits.
            const MAGIC: f64 = 6_755_399_441_055_744.0;
            let x = (v as f64).clamp(-104.0, 89.0);
            let t = x * std::f64::consts::LOG2_E + MAGIC;
            let n = t - MAGIC;
            let r = x - n * std::f64::consts::LN_2;
            let mut p = 1.0 / 3_628_800.0;
            for c in [
                1.0 / 362_880.0,
                1.0 / 40_320.0,
                1.0 / 5_040.0,
                1.0 / 720.0,
                1.0 / 120.0,
                1.0 / 24.0,
                1.0 / 6.0,
                0.5,
                1.0,
                1.0,
            ] {
                p = p * r + c;
            }
            let bits = (t.to_bits().wrapping_sub(MAGIC.to_bits()).wrapping_add(1023)) << 52;
            (p * f64::from_bits(bits)) as f32
        })
    }
}

impl BitAnd for M8 {
    type Output = M8;
    #[inline(always)]
    fn bitand(self, o: M8) -> M8 {
        M8(std::array::from_fn(|l| self.0[l] & o.0[l]))
    }
}

impl BitOr for M8 {
    type Output = M8;
    #[inline(always)]
    fn bitor(self, o: M8) -> M8 {
        M8(std::array::from_fn(|l| self.0[l] | o.0[l]))
    }
}

impl Not for M8 {
    type Output = M8;
    #[inline(always)]
    fn not(self) -> M8 {
        M8(self.0.map(|v| !v))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_rounds_as_the_c_library_does() {
        let (mut differ, mut total) = (0u32, 0u32);
        for i in 0..=4_000_000u32 {
            let x = -110.0 + i as f32 * (200.0 / 4_000_000.0);
            let got = F8::splat(x).exp().0[0];
            let want = x.exp();
            total += 1;
            if got.to_bits() != want.to_bits() {
                differ += 1;
                let ulps = (got.to_bits() as i64 - want.to_bits() as i64).abs();
                assert!(ulps <= 1, "e^{x}: {got:e} vs {want:e}");
            }
        }
        eprintln!("{differ} of {total} values differ from expf by one unit in the last place");
        assert!(differ * 1_000 < total, "{differ} of {total} differ");
        let edge = F8([
            -1e30,
            1e30,
            f32::NEG_INFINITY,
            f32::INFINITY,
            0.0,
            -88.0,
            89.0,
            f32::NAN,
        ])
        .exp();
        assert_eq!(
            edge.0[..7],
            [
                0.0,
                f32::INFINITY,
                0.0,
                f32::INFINITY,
                1.0,
                (-88.0f32).exp(),
                f32::INFINITY
            ]
        );
        assert!(edge.0[7].is_nan());
    }
}
