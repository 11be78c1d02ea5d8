//! Interval arithmetic with outward rounding, for certified frequency sweeps.
//!
//! Every operation is computed in round-to-nearest and its result widened by one
//! unit in the last place on each side (`next_down`/`next_up`), which encloses the
//! exact result of the operation on the enclosed reals. `cos`/`sin` enclose the
//! endpoint values (the platform's `cos`/`sin`, accurate to about one ulp; the
//! result is widened by `TRIG_PAD`) and the extrema inside the interval.

use std::f64::consts::PI;
use std::ops::{Add, Mul, Neg, Sub};

/// Absolute widening of a trigonometric enclosure (a few ulps of 1, covering the
/// error of the platform's `cos`/`sin` and of the argument's reduction by `π`).
pub const TRIG_PAD: f64 = 4e-16;

/// A closed interval `[lo, hi]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Iv {
    pub lo: f64,
    pub hi: f64,
}

impl Iv {
    /// The point `[x, x]`.
    #[inline(always)]
    pub fn point(x: f64) -> Iv {
        Iv { lo: x, hi: x }
    }

    /// `[lo, hi]` (`lo <= hi`).
    #[inline(always)]
    pub fn new(lo: f64, hi: f64) -> Iv {
        Iv { lo, hi }
    }

    /// Square (tight: non-negative).
    #[inline]
    pub fn sqr(self) -> Iv {
        let (a, b) = (self.lo * self.lo, self.hi * self.hi);
        if self.lo >= 0.0 {
            Iv::new(a.next_down().max(0.0), b.next_up())
        } else if self.hi <= 0.0 {
            Iv::new(b.next_down().max(0.0), a.next_up())
        } else {
            Iv::new(0.0, a.max(b).next_up())
        }
    }

    /// `self * x` for a float `x`.
    #[inline]
    pub fn scale(self, x: f64) -> Iv {
        self * Iv::point(x)
    }

    /// Enclosure of `cos` over the interval.
    pub fn cos(self) -> Iv {
        if self.hi - self.lo >= PI || self.hi.is_nan() || self.lo.is_nan() {
            return Iv::new(-1.0, 1.0);
        }
        let (c1, c2) = (self.lo.cos(), self.hi.cos());
        let (mut lo, mut hi) = (c1.min(c2), c1.max(c2));
        // extrema at j π: j even a maximum, odd a minimum
        let j0 = (self.lo / PI - 1e-9).ceil() as i64;
        let j1 = (self.hi / PI + 1e-9).floor() as i64;
        for j in j0..=j1 {
            if j.rem_euclid(2) == 0 {
                hi = 1.0;
            } else {
                lo = -1.0;
            }
        }
        Iv::new((lo - TRIG_PAD).max(-1.0), (hi + TRIG_PAD).min(1.0))
    }

    /// Enclosure of `sin` over the interval.
    pub fn sin(self) -> Iv {
        if self.hi - self.lo >= PI || self.hi.is_nan() || self.lo.is_nan() {
            return Iv::new(-1.0, 1.0);
        }
        let (s1, s2) = (self.lo.sin(), self.hi.sin());
        let (mut lo, mut hi) = (s1.min(s2), s1.max(s2));
        // extrema at π/2 + j π: j even a maximum, odd a minimum
        let j0 = (self.lo / PI - 0.5 - 1e-9).ceil() as i64;
        let j1 = (self.hi / PI - 0.5 + 1e-9).floor() as i64;
        for j in j0..=j1 {
            if j.rem_euclid(2) == 0 {
                hi = 1.0;
            } else {
                lo = -1.0;
            }
        }
        Iv::new((lo - TRIG_PAD).max(-1.0), (hi + TRIG_PAD).min(1.0))
    }
}

impl Add for Iv {
    type Output = Iv;
    #[inline(always)]
    fn add(self, o: Iv) -> Iv {
        Iv::new((self.lo + o.lo).next_down(), (self.hi + o.hi).next_up())
    }
}

impl Sub for Iv {
    type Output = Iv;
    #[inline(always)]
    fn sub(self, o: Iv) -> Iv {
        Iv::new((self.lo - o.hi).next_down(), (self.hi - o.lo).next_up())
    }
}

impl Neg for Iv {
    type Output = Iv;
    #[inline(always)]
    fn neg(self) -> Iv {
        Iv::new(-self.hi, -self.lo)
    }
}

impl Mul for Iv {
    type Output = Iv;
    #[inline(always)]
    fn mul(self, o: Iv) -> Iv {
        let (a, b, c, d) = (
            self.lo * o.lo,
            self.lo * o.hi,
            self.hi * o.lo,
            self.hi * o.hi,
        );
        Iv::new(
            a.min(b).min(c).min(d).next_down(),
            a.max(b).max(c).max(d).next_up(),
        )
    }
}

/// The arithmetic the certified sweep is written in: intervals ([`Iv`]) or intervals
/// with a derivative ([`DIv`], forward-mode differentiation in interval arithmetic).
pub trait Num:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Neg<Output = Self>
{
    /// A constant.
    fn cst(x: f64) -> Self;
    /// `self * x` for a float constant.
    fn scale(self, x: f64) -> Self;
    /// Square.
    fn sqr(self) -> Self;
    fn cos(self) -> Self;
    fn sin(self) -> Self;
}

impl Num for Iv {
    #[inline(always)]
    fn cst(x: f64) -> Iv {
        Iv::point(x)
    }
    #[inline(always)]
    fn scale(self, x: f64) -> Iv {
        Iv::scale(self, x)
    }
    #[inline(always)]
    fn sqr(self) -> Iv {
        Iv::sqr(self)
    }
    #[inline(always)]
    fn cos(self) -> Iv {
        Iv::cos(self)
    }
    #[inline(always)]
    fn sin(self) -> Iv {
        Iv::sin(self)
    }
}

/// An interval value with an interval derivative (with respect to one variable).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DIv {
    pub v: Iv,
    pub d: Iv,
}

impl DIv {
    /// The variable itself over `x` (derivative 1).
    pub fn var(x: Iv) -> DIv {
        DIv {
            v: x,
            d: Iv::point(1.0),
        }
    }
}

impl Add for DIv {
    type Output = DIv;
    #[inline(always)]
    fn add(self, o: DIv) -> DIv {
        DIv {
            v: self.v + o.v,
            d: self.d + o.d,
        }
    }
}

impl Sub for DIv {
    type Output = DIv;
    #[inline(always)]
    fn sub(self, o: DIv) -> DIv {
        DIv {
            v: self.v - o.v,
            d: self.d - o.d,
        }
    }
}

impl Neg for DIv {
    type Output = DIv;
    #[inline(always)]
    fn neg(self) -> DIv {
        DIv {
            v: -self.v,
            d: -self.d,
        }
    }
}

impl Mul for DIv {
    type Output = DIv;
    #[inline(always)]
    fn mul(self, o: DIv) -> DIv {
        DIv {
            v: self.v * o.v,
            d: self.d * o.v + self.v * o.d,
        }
    }
}

impl Num for DIv {
    #[inline(always)]
    fn cst(x: f64) -> DIv {
        DIv {
            v: Iv::point(x),
            d: Iv::point(0.0),
        }
    }
    #[inline(always)]
    fn scale(self, x: f64) -> DIv {
        DIv {
            v: self.v.scale(x),
            d: self.d.scale(x),
        }
    }
    #[inline(always)]
    fn sqr(self) -> DIv {
        DIv {
            v: self.v.sqr(),
            d: (self.v * self.d).scale(2.0),
        }
    }
    #[inline(always)]
    fn cos(self) -> DIv {
        DIv {
            v: self.v.cos(),
            d: -(self.v.sin() * self.d),
        }
    }
    #[inline(always)]
    fn sin(self) -> DIv {
        DIv {
            v: self.v.sin(),
            d: self.v.cos() * self.d,
        }
    }
}

/// A complex number over [`Num`] (a rectangle for intervals).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cx<T> {
    pub re: T,
    pub im: T,
}

impl<T: Num> Cx<T> {
    #[inline(always)]
    pub fn new(re: T, im: T) -> Cx<T> {
        Cx { re, im }
    }

    /// Complex conjugate.
    #[inline(always)]
    pub fn conj(self) -> Cx<T> {
        Cx::new(self.re, -self.im)
    }

    /// `|z|²`.
    #[inline(always)]
    pub fn abs2(self) -> T {
        self.re.sqr() + self.im.sqr()
    }
}

impl<T: Num> Mul for Cx<T> {
    type Output = Cx<T>;
    #[inline(always)]
    fn mul(self, o: Cx<T>) -> Cx<T> {
        Cx::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trig_encloses_samples() {
        let mut s = 11u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..5000 {
            let a = rnd() * 200.0 - 20.0;
            let w = rnd() * rnd() * 3.0;
            let iv = Iv::new(a, a + w);
            let (c, sn) = (iv.cos(), iv.sin());
            for k in 0..=20 {
                let t = a + w * k as f64 / 20.0;
                assert!(c.lo <= t.cos() && t.cos() <= c.hi, "cos {iv:?} {t}");
                assert!(sn.lo <= t.sin() && t.sin() <= sn.hi, "sin {iv:?} {t}");
            }
        }
    }

    #[test]
    fn arithmetic_encloses() {
        let a = Iv::new(-1.5, 2.0);
        let b = Iv::new(0.25, 3.0);
        let p = a * b;
        assert!(p.lo <= -4.5 && p.hi >= 6.0);
        assert!((a - b).lo <= -4.5 && (a - b).hi >= 1.75);
        assert_eq!(Iv::new(-2.0, 1.0).sqr().lo, 0.0);
        let x = Iv::point(0.1) + Iv::point(0.2);
        assert!(x.lo <= 0.30000000000000004 && x.hi >= 0.3);
    }
}

/// How a certified sweep of `g(ω) > 0` ([`sweep_positive`]) ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sweep {
    /// `g > 0` on the whole of `[0, w_cut]`.
    Positive,
    /// A point where `g < 0` for certain.
    Negative,
    /// Neither within the budget.
    Undecided,
}

/// Certifies `g(ω) > 0` on `[0, w_cut]` from interval enclosures `g(piece)`: first
/// `g(0)` and 65 log-spaced points from `1e-6 w_cut` to `w_cut` as witnesses of a
/// negative value, then each piece between them bisected until its enclosure, or
/// `refine(lo, hi, g(mid))` (a sharper bound the caller may have, e.g. a mean-value
/// form), is positive; a midpoint where `g < 0` is a witness, more than `budget`
/// pieces (or a piece too small to split) leave it undecided.
pub fn sweep_positive(
    w_cut: f64,
    budget: usize,
    g: impl Fn(Iv) -> Iv,
    refine: impl Fn(f64, f64, Iv) -> bool,
) -> Sweep {
    if g(Iv::point(0.0)).hi < 0.0 {
        return Sweep::Negative;
    }
    let n0 = 64;
    let w_lo = w_cut * 1e-6;
    let mut edges = Vec::with_capacity(n0 + 2);
    edges.push(0.0);
    for i in 0..=n0 {
        edges.push(w_lo * (w_cut / w_lo).powf(i as f64 / n0 as f64));
    }
    if let Some(last) = edges.last_mut() {
        *last = w_cut;
    }
    if edges[1..].iter().any(|&w| g(Iv::point(w)).hi < 0.0) {
        return Sweep::Negative;
    }
    let mut stack: Vec<(f64, f64)> = edges.windows(2).rev().map(|e| (e[0], e[1])).collect();
    let mut evals = 0usize;
    while let Some((lo, hi)) = stack.pop() {
        evals += 1;
        if evals > budget {
            return Sweep::Undecided;
        }
        if g(Iv::new(lo, hi)).lo > 0.0 {
            continue;
        }
        let mid = 0.5 * (lo + hi);
        let gm = g(Iv::point(mid));
        if gm.hi < 0.0 {
            return Sweep::Negative;
        }
        if refine(lo, hi, gm) {
            continue;
        }
        if mid <= lo || mid >= hi {
            return Sweep::Undecided;
        }
        stack.push((mid, hi));
        stack.push((lo, mid));
    }
    Sweep::Positive
}
