//! The number types path logic is written over, once for one path and for 8 or 16 at a time.
//!
//! `Real` is what a routine of the path kernel needs of its numbers: `f32` with `bool` masks
//! for one path (the scalar renderers), `F<S>` with `M<S>` masks for a vector of paths (thin
//! wrappers over `pulp`'s vectors: 8 lanes under AVX2, 16 under AVX-512). A routine written
//! generic over `Real` (and `V3<R>`, a 3-vector of them) is the single source of both: the
//! scalar renderers call it on `f32`, the wavefront on vectors. Every operation is the IEEE
//! operation lane by lane (no fused multiply-add, no approximate reciprocal), selects are
//! evaluated both ways and masked, and `V3`'s methods associate exactly as glam's `Vec3` does,
//! so every lane computes the bits the scalar instance computes.

use std::ops::{Add, BitAnd, BitOr, BitXor, Div, Mul, Neg, Not, Sub};

use pulp::Simd;

/// One f32 per lane.
#[derive(Clone, Copy, Debug)]
pub(crate) struct F<S: Simd> {
    s: S,
    v: S::f32s,
}

/// One condition per lane.
#[derive(Clone, Copy, Debug)]
pub(crate) struct M<S: Simd> {
    s: S,
    m: S::m32s,
}

/// One u32 per lane (float bit patterns).
#[derive(Clone, Copy, Debug)]
pub(crate) struct U<S: Simd> {
    s: S,
    v: S::u32s,
}

impl<S: Simd> F<S> {
    /// Every lane `x`.
    #[inline(always)]
    pub(crate) fn splat(s: S, x: f32) -> Self {
        F { s, v: s.splat_f32s(x) }
    }

    /// `f32::abs`.
    #[inline(always)]
    pub(crate) fn abs(self) -> Self {
        F { s: self.s, v: self.s.abs_f32s(self.v) }
    }

    /// `f32::sqrt`.
    #[inline(always)]
    pub(crate) fn sqrt(self) -> Self {
        F { s: self.s, v: self.s.sqrt_f32s(self.v) }
    }

    /// `f32::max(self, 0.0)` (NaN gives 0).
    #[inline(always)]
    pub(crate) fn max0(self) -> Self {
        let zero = F::splat(self.s, 0.0);
        self.gt(zero).select(self, zero)
    }

    /// `f32::min` for operands that are not NaN.
    #[inline(always)]
    pub(crate) fn min(self, o: Self) -> Self {
        self.lt(o).select(self, o)
    }

    /// glam's `max`: `if a > b { a } else { b }`.
    #[inline(always)]
    pub(crate) fn glam_max(self, o: Self) -> Self {
        self.gt(o).select(self, o)
    }

    /// The bits.
    #[inline(always)]
    pub(crate) fn to_bits(self) -> U<S> {
        U { s: self.s, v: self.s.transmute_u32s_f32s(self.v) }
    }

    /// `f32::copysign(self, sign)`.
    #[inline(always)]
    pub(crate) fn copysign(self, sign: Self) -> Self {
        let s = self.s;
        let magnitude = s.and_u32s(self.to_bits().v, s.splat_u32s(0x7fff_ffff));
        let sign = s.and_u32s(sign.to_bits().v, s.splat_u32s(0x8000_0000));
        U { s, v: s.or_u32s(magnitude, sign) }.to_f32()
    }

    /// `f32::is_finite`.
    #[inline(always)]
    pub(crate) fn is_finite(self) -> M<S> {
        self.abs().lt(F::splat(self.s, f32::INFINITY))
    }

    /// `self < o`.
    #[inline(always)]
    pub(crate) fn lt(self, o: Self) -> M<S> {
        M { s: self.s, m: self.s.less_than_f32s(self.v, o.v) }
    }

    /// `self <= o`.
    #[inline(always)]
    pub(crate) fn le(self, o: Self) -> M<S> {
        M { s: self.s, m: self.s.less_than_or_equal_f32s(self.v, o.v) }
    }

    /// `self > o`.
    #[inline(always)]
    pub(crate) fn gt(self, o: Self) -> M<S> {
        M { s: self.s, m: self.s.greater_than_f32s(self.v, o.v) }
    }

    /// `self >= o`.
    #[inline(always)]
    pub(crate) fn ge(self, o: Self) -> M<S> {
        M { s: self.s, m: self.s.greater_than_or_equal_f32s(self.v, o.v) }
    }

    /// `self == o`.
    #[inline(always)]
    pub(crate) fn eq(self, o: Self) -> M<S> {
        M { s: self.s, m: self.s.equal_f32s(self.v, o.v) }
    }

    /// Lane `i`.
    #[inline(always)]
    pub(crate) fn lane(&self, i: usize) -> f32 {
        bytemuck::cast_slice::<S::f32s, f32>(std::slice::from_ref(&self.v))[i]
    }

    /// Sets lane `i` to `x`.
    #[inline(always)]
    pub(crate) fn set_lane(&mut self, i: usize, x: f32) {
        bytemuck::cast_slice_mut::<S::f32s, f32>(std::slice::from_mut(&mut self.v))[i] = x;
    }
}

impl<S: Simd> U<S> {
    /// The instruction set.
    #[inline(always)]
    pub(crate) fn s(&self) -> S {
        self.s
    }

    /// Every lane `x`.
    #[inline(always)]
    pub(crate) fn splat(s: S, x: u32) -> Self {
        U { s, v: s.splat_u32s(x) }
    }

    /// The lanes as floats.
    #[inline(always)]
    pub(crate) fn to_f32(self) -> F<S> {
        F { s: self.s, v: self.s.transmute_f32s_u32s(self.v) }
    }

    /// Wrapping `self + o`.
    #[inline(always)]
    pub(crate) fn wrapping_add(self, o: Self) -> Self {
        U { s: self.s, v: self.s.add_u32s(self.v, o.v) }
    }

    /// Wrapping `self - o`.
    #[inline(always)]
    pub(crate) fn wrapping_sub(self, o: Self) -> Self {
        U { s: self.s, v: self.s.sub_u32s(self.v, o.v) }
    }

    /// Wrapping `self * o`.
    #[inline(always)]
    pub(crate) fn wrapping_mul(self, o: Self) -> Self {
        U { s: self.s, v: self.s.mul_u32s(self.v, o.v) }
    }

    /// The full 64-bit product `self * o`.
    #[inline(always)]
    pub(crate) fn widening_mul(self, o: Self) -> U64<S> {
        let (lo, hi) = self.s.widening_mul_u32s(self.v, o.v);
        U64 { lo: U { s: self.s, v: lo }, hi: U { s: self.s, v: hi } }
    }

    /// `self << n` (`n < 32`).
    #[inline(always)]
    pub(crate) fn shl(self, n: u32) -> Self {
        U { s: self.s, v: self.s.wrapping_dyn_shl_u32s(self.v, self.s.splat_u32s(n)) }
    }

    /// `self >> n` (`n < 32`).
    #[inline(always)]
    pub(crate) fn shr(self, n: u32) -> Self {
        U { s: self.s, v: self.s.wrapping_dyn_shr_u32s(self.v, self.s.splat_u32s(n)) }
    }

    /// `u32::reverse_bits`: neighbouring bits, then pairs, ... swapped (five steps).
    #[inline(always)]
    pub(crate) fn reverse_bits(self) -> Self {
        let mut x = self;
        for (n, mask) in BIT_STEPS {
            let m = U::splat(self.s, mask);
            x = (x.shr(n) & m) | (x & m).shl(n);
        }
        x
    }

    /// `x as f32` for lanes below 2^24 (exact: the low 23 bits as the mantissa of 2^23 + x,
    /// less 2^23, plus bit 23's 2^23).
    #[inline(always)]
    pub(crate) fn small_to_f32(self) -> F<S> {
        let s = self.s;
        let two23 = 8_388_608.0f32.to_bits();
        let low = (self & U::splat(s, 0x7f_ffff)) | U::splat(s, two23);
        let high = self.shr(23).wrapping_mul(U::splat(s, two23));
        (low.to_f32() - F::splat(s, 8_388_608.0)) + high.to_f32()
    }

    /// Lane `i` (for tests).
    #[cfg(test)]
    pub(crate) fn lane(&self, i: usize) -> u32 {
        bytemuck::cast_slice::<S::u32s, u32>(std::slice::from_ref(&self.v))[i]
    }

    /// Sets lane `i` to `x`.
    #[inline(always)]
    pub(crate) fn set_lane(&mut self, i: usize, x: u32) {
        bytemuck::cast_slice_mut::<S::u32s, u32>(std::slice::from_mut(&mut self.v))[i] = x;
    }
}

/// Per bit `b` of a bit position: the shift `2^b`, and the positions whose bit `b` is clear
/// (bit-reversal's swaps, and the sampler's superset sums).
pub(crate) const BIT_STEPS: [(u32, u32); 5] =
    [(1, 0x5555_5555), (2, 0x3333_3333), (4, 0x0f0f_0f0f), (8, 0x00ff_00ff), (16, 0x0000_ffff)];

/// One u64 per lane, as its low and high halves.
#[derive(Clone, Copy, Debug)]
pub(crate) struct U64<S: Simd> {
    pub(crate) lo: U<S>,
    pub(crate) hi: U<S>,
}

impl<S: Simd> U64<S> {
    /// Every lane `x`.
    #[inline(always)]
    pub(crate) fn splat(s: S, x: u64) -> Self {
        U64 { lo: U::splat(s, x as u32), hi: U::splat(s, (x >> 32) as u32) }
    }

    /// `self ^ (self >> n)` (`0 < n < 32`).
    #[inline(always)]
    pub(crate) fn xor_shr(self, n: u32) -> Self {
        let lo = self.lo ^ (self.lo.shr(n) | self.hi.shl(32 - n));
        U64 { lo, hi: self.hi ^ self.hi.shr(n) }
    }

    /// Wrapping `self * k`.
    #[inline(always)]
    pub(crate) fn wrapping_mul(self, k: u64) -> Self {
        let s = self.lo.s;
        let (k_lo, k_hi) = (U::splat(s, k as u32), U::splat(s, (k >> 32) as u32));
        let p = self.lo.widening_mul(k_lo);
        let hi =
            p.hi.wrapping_add(self.hi.wrapping_mul(k_lo)).wrapping_add(self.lo.wrapping_mul(k_hi));
        U64 { lo: p.lo, hi }
    }

    /// `self ^ o`.
    #[inline(always)]
    pub(crate) fn xor(self, o: Self) -> Self {
        U64 { lo: self.lo ^ o.lo, hi: self.hi ^ o.hi }
    }

    /// Sets lane `i` to `x`.
    #[inline(always)]
    pub(crate) fn set_lane(&mut self, i: usize, x: u64) {
        self.lo.set_lane(i, x as u32);
        self.hi.set_lane(i, (x >> 32) as u32);
    }
}

/// A binary operator of `F` or `U`, lane by lane.
macro_rules! lane_op {
    ($ty:ident, $tr:ident, $f:ident, $op:ident) => {
        impl<S: Simd> $tr for $ty<S> {
            type Output = $ty<S>;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                $ty { s: self.s, v: self.s.$op(self.v, o.v) }
            }
        }
    };
}
lane_op!(U, BitAnd, bitand, and_u32s);
lane_op!(U, BitOr, bitor, or_u32s);
lane_op!(U, BitXor, bitxor, xor_u32s);

impl<S: Simd> M<S> {
    /// Conditions from bools, one per lane (`lanes.len()` is at least the lane count).
    #[inline(always)]
    pub(crate) fn from_bools(s: S, lanes: &[bool]) -> Self {
        let mut v = s.splat_u32s(0);
        let out = bytemuck::cast_slice_mut::<S::u32s, u32>(std::slice::from_mut(&mut v));
        for (o, &b) in out.iter_mut().zip(lanes) {
            *o = b as u32;
        }
        M { s, m: s.equal_u32s(v, s.splat_u32s(1)) }
    }

    /// Writes the conditions to `out`, one per lane.
    #[inline(always)]
    pub(crate) fn to_bools(self, out: &mut [bool]) {
        let v = self.s.select_u32s(self.m, self.s.splat_u32s(1), self.s.splat_u32s(0));
        let lanes = bytemuck::cast_slice::<S::u32s, u32>(std::slice::from_ref(&v));
        for (o, &l) in out.iter_mut().zip(lanes) {
            *o = l != 0;
        }
    }

    /// Lane by lane `if self { a } else { b }`.
    #[inline(always)]
    pub(crate) fn select(self, a: F<S>, b: F<S>) -> F<S> {
        F { s: self.s, v: self.s.select_f32s(self.m, a.v, b.v) }
    }

    /// Lane by lane `if self { a } else { b }` on conditions.
    #[inline(always)]
    pub(crate) fn select_m(self, a: M<S>, b: M<S>) -> M<S> {
        (self & a) | (!self & b)
    }

    /// Lane by lane `if self { a } else { b }` on bit patterns.
    #[inline(always)]
    pub(crate) fn select_u(self, a: U<S>, b: U<S>) -> U<S> {
        U { s: self.s, v: self.s.select_u32s(self.m, a.v, b.v) }
    }

    /// Lane by lane `if self { a } else { b }` on vectors.
    #[inline(always)]
    pub(crate) fn select3(self, a: V3<F<S>>, b: V3<F<S>>) -> V3<F<S>> {
        V3 { x: self.select(a.x, b.x), y: self.select(a.y, b.y), z: self.select(a.z, b.z) }
    }
}

lane_op!(F, Add, add, add_f32s);
lane_op!(F, Sub, sub, sub_f32s);
lane_op!(F, Mul, mul, mul_f32s);
lane_op!(F, Div, div, div_f32s);

impl<S: Simd> Neg for F<S> {
    type Output = F<S>;
    #[inline(always)]
    fn neg(self) -> Self {
        let s = self.s;
        U { s, v: s.xor_u32s(self.to_bits().v, s.splat_u32s(0x8000_0000)) }.to_f32()
    }
}

macro_rules! maskop {
    ($tr:ident, $f:ident, $op:ident) => {
        impl<S: Simd> $tr for M<S> {
            type Output = M<S>;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                M { s: self.s, m: self.s.$op(self.m, o.m) }
            }
        }
    };
}
maskop!(BitAnd, bitand, and_m32s);
maskop!(BitOr, bitor, or_m32s);
maskop!(BitXor, bitxor, xor_m32s);

impl<S: Simd> Not for M<S> {
    type Output = M<S>;
    #[inline(always)]
    fn not(self) -> Self {
        M { s: self.s, m: self.s.not_m32s(self.m) }
    }
}

/// Numbers a routine of the path kernel is written over: `f32` (one path) or `F<S>` (a vector
/// of paths). Constants come from a value of the same type (`konst`), which carries the
/// instruction set of a vector.
pub(crate) trait Real:
    Copy
    + std::fmt::Debug
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// One condition per lane.
    type Mask: Copy
        + BitAnd<Output = Self::Mask>
        + BitOr<Output = Self::Mask>
        + BitXor<Output = Self::Mask>
        + Not<Output = Self::Mask>;
    /// One bit pattern per lane.
    type Bits: Copy;

    /// `x` in every lane, of `self`'s type.
    fn konst(self, x: f32) -> Self;
    /// `f32::abs`.
    fn abs(self) -> Self;
    /// `f32::sqrt`.
    fn sqrt(self) -> Self;
    /// `if self > 0 { self } else { 0 }` (NaN gives 0).
    fn max0(self) -> Self;
    /// `if self < o { self } else { o }` (`f32::min` for operands that are not NaN).
    fn min(self, o: Self) -> Self;
    /// glam's `max`: `if self > o { self } else { o }`.
    fn glam_max(self, o: Self) -> Self;
    /// `f32::copysign`.
    fn copysign(self, sign: Self) -> Self;
    /// `f32::is_finite`.
    fn is_finite(self) -> Self::Mask;
    /// `self < o`.
    fn lt(self, o: Self) -> Self::Mask;
    /// `self <= o`.
    fn le(self, o: Self) -> Self::Mask;
    /// `self > o`.
    fn gt(self, o: Self) -> Self::Mask;
    /// `self >= o`.
    fn ge(self, o: Self) -> Self::Mask;
    /// `self == o`.
    fn eq(self, o: Self) -> Self::Mask;
    /// Lane by lane `if m { a } else { b }`, free of branches.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    /// The bits.
    fn to_bits(self) -> Self::Bits;
    /// The number of bits `b`.
    fn from_bits(b: Self::Bits) -> Self;
    /// `x` in every lane, as bits of `self`'s type.
    fn konst_bits(self, x: u32) -> Self::Bits;
    /// Wrapping `a + b` of bit patterns.
    fn bits_add(a: Self::Bits, b: Self::Bits) -> Self::Bits;
    /// Wrapping `a - b` of bit patterns.
    fn bits_sub(a: Self::Bits, b: Self::Bits) -> Self::Bits;
    /// Lane by lane `if m { a } else { b }` on bit patterns.
    fn select_bits(m: Self::Mask, a: Self::Bits, b: Self::Bits) -> Self::Bits;
    /// `f(self, o)` lane by lane: a scalar function (a math library's `exp` or `powf`, a table
    /// lookup) on every lane, so that each lane has the scalar instance's bits.
    fn each2(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self;
    /// `f` lane by lane on `N` inputs to `K` outputs: a scalar routine (table lookups and the
    /// arithmetic around them) run on every lane, its code written once however many places call
    /// it, so that each lane has the scalar instance's bits.
    fn map_lanes<const N: usize, const K: usize>(
        inputs: [Self; N],
        f: impl Fn([f32; N]) -> [f32; K],
    ) -> [Self; K];
}

impl Real for f32 {
    type Mask = bool;
    type Bits = u32;

    #[inline(always)]
    fn each2(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
        f(self, o)
    }

    #[inline(always)]
    fn map_lanes<const N: usize, const K: usize>(
        inputs: [Self; N],
        f: impl Fn([f32; N]) -> [f32; K],
    ) -> [Self; K] {
        f(inputs)
    }

    #[inline(always)]
    fn konst(self, x: f32) -> Self {
        x
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f32::abs(self)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn max0(self) -> Self {
        Real::select(self > 0.0, self, 0.0)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        f32::min(self, o)
    }
    #[inline(always)]
    fn glam_max(self, o: Self) -> Self {
        Real::select(self > o, self, o)
    }
    #[inline(always)]
    fn copysign(self, sign: Self) -> Self {
        f32::copysign(self, sign)
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
    #[inline(always)]
    fn lt(self, o: Self) -> bool {
        self < o
    }
    #[inline(always)]
    fn le(self, o: Self) -> bool {
        self <= o
    }
    #[inline(always)]
    fn gt(self, o: Self) -> bool {
        self > o
    }
    #[inline(always)]
    fn ge(self, o: Self) -> bool {
        self >= o
    }
    #[inline(always)]
    fn eq(self, o: Self) -> bool {
        self == o
    }
    /// By bit masks: the compiler keeps it free of branches (a select is often a coin flip).
    #[inline(always)]
    fn select(m: bool, a: Self, b: Self) -> Self {
        let mask = (m as u32).wrapping_neg();
        f32::from_bits((a.to_bits() & mask) | (b.to_bits() & !mask))
    }
    #[inline(always)]
    fn to_bits(self) -> u32 {
        f32::to_bits(self)
    }
    #[inline(always)]
    fn from_bits(b: u32) -> Self {
        f32::from_bits(b)
    }
    #[inline(always)]
    fn konst_bits(self, x: u32) -> u32 {
        x
    }
    #[inline(always)]
    fn bits_add(a: u32, b: u32) -> u32 {
        a.wrapping_add(b)
    }
    #[inline(always)]
    fn bits_sub(a: u32, b: u32) -> u32 {
        a.wrapping_sub(b)
    }
    #[inline(always)]
    fn select_bits(m: bool, a: u32, b: u32) -> u32 {
        let mask = (m as u32).wrapping_neg();
        (a & mask) | (b & !mask)
    }
}

/// The most `f32` lanes of a vector (AVX-512).
const MAX_F32_LANES: usize = 16;

/// `b[k][i] = f(a[..][i])[k]` for the first `lanes` lanes ([`Real::map_lanes`]).
#[inline(never)]
fn map_arrays<const N: usize, const K: usize>(
    a: &[[f32; MAX_F32_LANES]; N],
    b: &mut [[f32; MAX_F32_LANES]; K],
    lanes: usize,
    f: &impl Fn([f32; N]) -> [f32; K],
) {
    for i in 0..lanes.min(MAX_F32_LANES) {
        let y = f(a.map(|a| a[i]));
        for (b, y) in b.iter_mut().zip(y) {
            b[i] = y;
        }
    }
}

impl<S: Simd> Real for F<S> {
    type Mask = M<S>;
    type Bits = U<S>;

    #[inline(always)]
    fn each2(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
        let mut out = self;
        for i in 0..S::F32_LANES {
            out.set_lane(i, f(self.lane(i), o.lane(i)));
        }
        out
    }

    #[inline(always)]
    fn map_lanes<const N: usize, const K: usize>(
        inputs: [Self; N],
        f: impl Fn([f32; N]) -> [f32; K],
    ) -> [Self; K] {
        // The lanes go through arrays to a loop out of line, so that each call adds to the
        // vector kernel only its stores and loads.
        let lanes = S::F32_LANES;
        let mut a = [[0.0f32; MAX_F32_LANES]; N];
        for (a, x) in a.iter_mut().zip(&inputs) {
            a[..lanes].copy_from_slice(bytemuck::cast_slice(std::slice::from_ref(&x.v)));
        }
        let mut b = [[0.0f32; MAX_F32_LANES]; K];
        map_arrays(&a, &mut b, lanes, &f);
        let mut out = [inputs[0]; K];
        for (o, b) in out.iter_mut().zip(&b) {
            bytemuck::cast_slice_mut(std::slice::from_mut(&mut o.v)).copy_from_slice(&b[..lanes]);
        }
        out
    }

    #[inline(always)]
    fn konst(self, x: f32) -> Self {
        F::splat(self.s, x)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        F::abs(self)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        F::sqrt(self)
    }
    #[inline(always)]
    fn max0(self) -> Self {
        F::max0(self)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        F::min(self, o)
    }
    #[inline(always)]
    fn glam_max(self, o: Self) -> Self {
        F::glam_max(self, o)
    }
    #[inline(always)]
    fn copysign(self, sign: Self) -> Self {
        F::copysign(self, sign)
    }
    #[inline(always)]
    fn is_finite(self) -> M<S> {
        F::is_finite(self)
    }
    #[inline(always)]
    fn lt(self, o: Self) -> M<S> {
        F::lt(self, o)
    }
    #[inline(always)]
    fn le(self, o: Self) -> M<S> {
        F::le(self, o)
    }
    #[inline(always)]
    fn gt(self, o: Self) -> M<S> {
        F::gt(self, o)
    }
    #[inline(always)]
    fn ge(self, o: Self) -> M<S> {
        F::ge(self, o)
    }
    #[inline(always)]
    fn eq(self, o: Self) -> M<S> {
        F::eq(self, o)
    }
    #[inline(always)]
    fn select(m: M<S>, a: Self, b: Self) -> Self {
        m.select(a, b)
    }
    #[inline(always)]
    fn to_bits(self) -> U<S> {
        F::to_bits(self)
    }
    #[inline(always)]
    fn from_bits(b: U<S>) -> Self {
        b.to_f32()
    }
    #[inline(always)]
    fn konst_bits(self, x: u32) -> U<S> {
        U::splat(self.s, x)
    }
    #[inline(always)]
    fn bits_add(a: U<S>, b: U<S>) -> U<S> {
        a.wrapping_add(b)
    }
    #[inline(always)]
    fn bits_sub(a: U<S>, b: U<S>) -> U<S> {
        a.wrapping_sub(b)
    }
    #[inline(always)]
    fn select_bits(m: M<S>, a: U<S>, b: U<S>) -> U<S> {
        m.select_u(a, b)
    }
}

/// A 3-vector of `Real`s: a `Vec3` per lane.
#[derive(Clone, Copy, Debug)]
pub(crate) struct V3<R> {
    /// x of every lane.
    pub(crate) x: R,
    /// y of every lane.
    pub(crate) y: R,
    /// z of every lane.
    pub(crate) z: R,
}

impl<R: Real> V3<R> {
    /// A vector from its components.
    #[inline(always)]
    pub(crate) fn new(x: R, y: R, z: R) -> Self {
        V3 { x, y, z }
    }

    /// Lane by lane `if m { a } else { b }`.
    #[inline(always)]
    pub(crate) fn select(m: R::Mask, a: Self, b: Self) -> Self {
        V3 { x: R::select(m, a.x, b.x), y: R::select(m, a.y, b.y), z: R::select(m, a.z, b.z) }
    }

    /// `Vec3::dot`: `(x * x') + (y * y') + (z * z')`.
    #[inline(always)]
    pub(crate) fn dot(self, o: Self) -> R {
        (self.x * o.x) + (self.y * o.y) + (self.z * o.z)
    }

    /// `Vec3::cross`.
    #[inline(always)]
    pub(crate) fn cross(self, o: Self) -> Self {
        V3 {
            x: self.y * o.z - o.y * self.z,
            y: self.z * o.x - o.z * self.x,
            z: self.x * o.y - o.x * self.y,
        }
    }

    /// `Vec3::length_squared`.
    #[inline(always)]
    pub(crate) fn length_squared(self) -> R {
        self.dot(self)
    }

    /// `Vec3::normalize`: times the reciprocal of the length, as glam computes it.
    #[inline(always)]
    pub(crate) fn normalize(self) -> Self {
        self.scale(self.x.konst(1.0) / self.length_squared().sqrt())
    }

    /// `Vec3::abs`.
    #[inline(always)]
    pub(crate) fn abs(self) -> Self {
        V3 { x: self.x.abs(), y: self.y.abs(), z: self.z.abs() }
    }

    /// `Vec3 * f32`.
    #[inline(always)]
    pub(crate) fn scale(self, k: R) -> Self {
        V3 { x: self.x * k, y: self.y * k, z: self.z * k }
    }

    /// `Vec3 / f32`.
    #[inline(always)]
    pub(crate) fn div(self, k: R) -> Self {
        V3 { x: self.x / k, y: self.y / k, z: self.z / k }
    }

    /// `Vec3 * Vec3`, component by component.
    #[inline(always)]
    pub(crate) fn mul(self, o: Self) -> Self {
        V3 { x: self.x * o.x, y: self.y * o.y, z: self.z * o.z }
    }

    /// glam's `max_element`.
    #[inline(always)]
    pub(crate) fn max_element(self) -> R {
        self.x.glam_max(self.y).glam_max(self.z)
    }

    /// `v == Vec3::ZERO`.
    #[inline(always)]
    pub(crate) fn is_zero(self) -> R::Mask {
        let zero = self.x.konst(0.0);
        self.x.eq(zero) & self.y.eq(zero) & self.z.eq(zero)
    }

    /// `Vec3::is_finite`.
    #[inline(always)]
    pub(crate) fn is_finite(self) -> R::Mask {
        self.x.is_finite() & self.y.is_finite() & self.z.is_finite()
    }
}

impl<S: Simd> V3<F<S>> {
    /// Every lane `v`.
    #[inline(always)]
    pub(crate) fn splat(s: S, v: glam::Vec3) -> Self {
        V3 { x: F::splat(s, v.x), y: F::splat(s, v.y), z: F::splat(s, v.z) }
    }

    /// Lane `i`.
    #[inline(always)]
    pub(crate) fn lane(&self, i: usize) -> glam::Vec3 {
        glam::Vec3::new(self.x.lane(i), self.y.lane(i), self.z.lane(i))
    }

    /// Sets lane `i` to `v`.
    #[inline(always)]
    pub(crate) fn set_lane(&mut self, i: usize, v: glam::Vec3) {
        self.x.set_lane(i, v.x);
        self.y.set_lane(i, v.y);
        self.z.set_lane(i, v.z);
    }
}

impl From<glam::Vec3> for V3<f32> {
    #[inline(always)]
    fn from(v: glam::Vec3) -> Self {
        V3 { x: v.x, y: v.y, z: v.z }
    }
}

impl From<V3<f32>> for glam::Vec3 {
    #[inline(always)]
    fn from(v: V3<f32>) -> Self {
        glam::Vec3::new(v.x, v.y, v.z)
    }
}

impl<R: Real> Add for V3<R> {
    type Output = V3<R>;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        V3 { x: self.x + o.x, y: self.y + o.y, z: self.z + o.z }
    }
}

impl<R: Real> Sub for V3<R> {
    type Output = V3<R>;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        V3 { x: self.x - o.x, y: self.y - o.y, z: self.z - o.z }
    }
}

impl<R: Real> Neg for V3<R> {
    type Output = V3<R>;
    #[inline(always)]
    fn neg(self) -> Self {
        V3 { x: -self.x, y: -self.y, z: -self.z }
    }
}
