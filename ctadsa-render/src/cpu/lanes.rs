//! Eight f32 lanes with element-wise arithmetic, so that per-Gaussian set-up code reads like
//! scalar maths and compiles to vector instructions (every operation is a plain 8-iteration
//! loop, which LLVM turns into one AVX instruction inside the `multiversion` kernels). The loops
//! index explicitly and take no closures from callers that could end up not inlined (an
//! out-of-line helper would be compiled for the baseline target and lose the vector code).
#![allow(clippy::needless_range_loop)]

use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// Lane count.
pub const LANES: usize = 8;

/// Eight f32 values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct F8(pub [f32; LANES]);

/// Eight booleans (one per lane), each stored as a full-width lane mask (`0` or `!0`), the form
/// vector compares produce and blends consume (a `bool` per lane compiled to byte extractions).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct M8([u32; LANES]);

impl F8 {
    /// All lanes `v`.
    #[inline(always)]
    pub fn splat(v: f32) -> Self {
        Self([v; LANES])
    }

    #[inline(always)]
    fn map(self, f: impl Fn(f32) -> f32) -> Self {
        let mut out = [0.0; LANES];
        for l in 0..LANES {
            out[l] = f(self.0[l]);
        }
        Self(out)
    }

    #[inline(always)]
    fn zip(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
        let mut out = [0.0; LANES];
        for l in 0..LANES {
            out[l] = f(self.0[l], o.0[l]);
        }
        Self(out)
    }

    #[inline(always)]
    fn test(self, o: Self, f: impl Fn(f32, f32) -> bool) -> M8 {
        let mut out = [0; LANES];
        for l in 0..LANES {
            out[l] = if f(self.0[l], o.0[l]) { !0 } else { 0 };
        }
        M8(out)
    }

    /// Square root per lane.
    #[inline(always)]
    pub fn sqrt(self) -> Self {
        self.map(f32::sqrt)
    }

    /// Round up per lane.
    #[inline(always)]
    pub fn ceil(self) -> Self {
        self.map(f32::ceil)
    }

    /// Round down per lane.
    #[inline(always)]
    pub fn floor(self) -> Self {
        self.map(f32::floor)
    }

    /// Lane-wise `max` (NaN-ignoring like [`f32::max`]).
    #[inline(always)]
    pub fn max(self, o: impl Into<F8>) -> Self {
        self.zip(o.into(), f32::max)
    }

    /// Lane-wise `min` (NaN-ignoring like [`f32::min`]).
    #[inline(always)]
    pub fn min(self, o: impl Into<F8>) -> Self {
        self.zip(o.into(), f32::min)
    }

    /// Whether each lane is finite.
    #[inline(always)]
    pub fn is_finite(self) -> M8 {
        self.test(self, |a, _| a.is_finite())
    }

    /// `self > o` per lane (false for NaN).
    #[inline(always)]
    pub fn gt(self, o: impl Into<F8>) -> M8 {
        self.test(o.into(), |a, b| a > b)
    }

    /// `self < o` per lane (false for NaN).
    #[inline(always)]
    pub fn lt(self, o: impl Into<F8>) -> M8 {
        self.test(o.into(), |a, b| a < b)
    }

    /// `self ≥ o` per lane (false for NaN).
    #[inline(always)]
    pub fn ge(self, o: impl Into<F8>) -> M8 {
        self.test(o.into(), |a, b| a >= b)
    }

    /// `self ≤ o` per lane (false for NaN).
    #[inline(always)]
    pub fn le(self, o: impl Into<F8>) -> M8 {
        self.test(o.into(), |a, b| a <= b)
    }
}

impl M8 {
    /// Every lane set.
    pub const ALL: M8 = M8([!0; LANES]);

    /// Whether lane `l` is set.
    #[inline(always)]
    pub fn lane(self, l: usize) -> bool {
        self.0[l] != 0
    }

    /// The lanes as bit masks (`!0` set, `0` clear).
    #[inline(always)]
    pub fn bits(self) -> [u32; LANES] {
        self.0
    }

    /// The lanes as booleans.
    pub fn to_bools(self) -> [bool; LANES] {
        std::array::from_fn(|l| self.lane(l))
    }

    /// Per lane: `a` where the mask is set, else `b` (a bitwise blend).
    #[inline(always)]
    pub fn select(self, a: impl Into<F8>, b: impl Into<F8>) -> F8 {
        let (a, b) = (a.into(), b.into());
        let mut out = [0.0; LANES];
        for l in 0..LANES {
            let m = self.0[l];
            out[l] = f32::from_bits((a.0[l].to_bits() & m) | (b.0[l].to_bits() & !m));
        }
        F8(out)
    }
}

impl From<f32> for F8 {
    #[inline(always)]
    fn from(v: f32) -> Self {
        Self::splat(v)
    }
}

macro_rules! binary {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: F8) -> F8 {
                self.zip(o, |a, b| a $op b)
            }
        }
        impl $tr<f32> for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: f32) -> F8 {
                self.map(|a| a $op o)
            }
        }
        impl $tr<F8> for f32 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: F8) -> F8 {
                o.map(|b| self $op b)
            }
        }
    };
}
binary!(Add, add, +);
binary!(Sub, sub, -);
binary!(Mul, mul, *);
binary!(Div, div, /);

impl Neg for F8 {
    type Output = F8;
    #[inline(always)]
    fn neg(self) -> F8 {
        self.map(|a| -a)
    }
}

impl BitAnd for M8 {
    type Output = M8;
    #[inline(always)]
    fn bitand(self, o: M8) -> M8 {
        let mut out = self.0;
        for l in 0..LANES {
            out[l] &= o.0[l];
        }
        M8(out)
    }
}

impl BitOr for M8 {
    type Output = M8;
    #[inline(always)]
    fn bitor(self, o: M8) -> M8 {
        let mut out = self.0;
        for l in 0..LANES {
            out[l] |= o.0[l];
        }
        M8(out)
    }
}

impl Not for M8 {
    type Output = M8;
    #[inline(always)]
    fn not(self) -> M8 {
        let mut out = self.0;
        for v in &mut out {
            *v = !*v;
        }
        M8(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lanes_follow_scalar_semantics() {
        let a = F8([1.0, -2.0, f32::NAN, 4.0, 0.0, f32::INFINITY, -0.5, 9.0]);
        let b = F8::splat(2.0);
        assert_eq!((a * b).0[1], -4.0);
        assert_eq!((1.0 / b).0[0], 0.5);
        assert_eq!(a.max(0.0).0[2], 0.0, "max ignores NaN like f32::max");
        assert_eq!(a.is_finite().to_bools(), [true, true, false, true, true, false, true, true]);
        assert_eq!(a.gt(0.0).to_bools(), [true, false, false, true, false, true, false, true]);
        let m = a.gt(0.0) & a.is_finite();
        assert_eq!(m.select(a, -1.0).0, [1.0, -1.0, -1.0, 4.0, -1.0, -1.0, -1.0, 9.0]);
        assert_eq!(F8::splat(-0.5).ceil().0[0], 0.0);
        assert_eq!(F8::splat(9.0).sqrt().0[7], 3.0);
    }
}
