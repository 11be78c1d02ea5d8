//! Exact count of the distinct real roots of a polynomial on `(0, +inf)`.
//!
//! Sturm's theorem: with `p0 = p`, `p1 = p'`, `p_{k+1} = -rem(p_{k-1}, p_k)`, the
//! number of distinct real roots in `(a, b]` is `V(a) - V(b)`, the difference of the
//! sign changes of the sequence at the two ends. At `a = 0+` each member's sign is
//! that of its lowest nonzero coefficient, at `b = +inf` that of its leading one;
//! neither end is a root, so the count is exact in exact arithmetic whatever the
//! multiplicities. In floating point the polynomial is first balanced (`x = σ y`,
//! which keeps the positive roots positive), every member is scaled to unit largest
//! coefficient, and a remainder coefficient below `REM_TOL` times the dividend's
//! largest one is taken as zero (exact cancellation: a multiple root, which for the
//! string test means a point on the boundary itself). The threshold is deliberately
//! not a worst-case rounding bound: near-degenerate but regular sequences (members
//! with tiny leading coefficients) occur well inside the regions for high Padé
//! orders, and a worst-case bound zeroed genuine coefficients there.

use super::dd::Dd;
use super::poly::{Poly, CAP};

/// Relative threshold below which a computed remainder coefficient counts as zero (f64).
pub const REM_TOL: f64 = 1e-14;
/// The same in double-double arithmetic.
pub const REM_TOL_DD: f64 = 1e-28;
/// An f64 sequence whose members' end coefficients fall below this fraction of
/// their size is recomputed in double-double arithmetic.
pub const COND_TOL: f64 = 1e-3;

#[inline]
fn sgn(x: f64) -> i8 {
    if x > 0.0 {
        1
    } else if x < 0.0 {
        -1
    } else {
        0
    }
}

/// Running count of sign changes, zeros skipped.
#[derive(Clone, Copy)]
struct Changes {
    last: i8,
    n: usize,
}

impl Changes {
    #[inline]
    fn push(&mut self, s: i8) {
        if s != 0 {
            if self.last != 0 && s != self.last {
                self.n += 1;
            }
            self.last = s;
        }
    }
}

/// The arithmetic a Sturm sequence runs in: `f64`, or [`Dd`] when `f64` is not enough.
trait Scalar:
    Copy
    + PartialEq
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
    + std::ops::Neg<Output = Self>
{
    const ZERO: Self;
    fn from_f64(x: f64) -> Self;
    /// Leading f64 part (the value for f64).
    fn hi(self) -> f64;
    /// Multiplication by a power of two.
    fn scale(self, f: f64) -> Self;
}

impl Scalar for f64 {
    const ZERO: f64 = 0.0;
    #[inline(always)]
    fn from_f64(x: f64) -> f64 {
        x
    }
    #[inline(always)]
    fn hi(self) -> f64 {
        self
    }
    #[inline(always)]
    fn scale(self, f: f64) -> f64 {
        self * f
    }
}

impl Scalar for Dd {
    const ZERO: Dd = Dd::ZERO;
    #[inline(always)]
    fn from_f64(x: f64) -> Dd {
        Dd::from_f64(x)
    }
    #[inline(always)]
    fn hi(self) -> f64 {
        self.hi
    }
    #[inline(always)]
    fn scale(self, f: f64) -> Dd {
        Dd::scale(self, f)
    }
}

/// Binary exponent of a nonzero finite f64 (subnormals count as -1023).
#[inline(always)]
fn binary_exponent(x: f64) -> i64 {
    ((x.to_bits() >> 52) & 0x7ff) as i64 - 1023
}

/// `2^-e` for the binary exponent `e` of a positive normal `m` (so `m 2^-e ∈ [1, 2)`).
#[inline(always)]
fn inv_pow2_of(m: f64) -> f64 {
    let e = ((m.to_bits() >> 52) & 0x7ff) as i64 - 1023;
    if (-1000..=1000).contains(&e) {
        f64::from_bits(((1023 - e) as u64) << 52)
    } else {
        1.0
    }
}

/// Scales `c[..=deg]` by a power of two to largest magnitude in `[1, 2)` (exact;
/// signs unchanged). Returns the largest magnitude after scaling.
#[inline]
fn normalise<T: Scalar>(c: &mut [T; CAP], deg: usize) -> f64 {
    let m = c[..=deg].iter().fold(0.0f64, |m, x| m.max(x.hi().abs()));
    if m > 0.0 && m.is_finite() {
        let f = inv_pow2_of(m);
        for x in c[..=deg].iter_mut() {
            *x = x.scale(f);
        }
        m * f
    } else {
        m
    }
}

/// Replaces `a` by `-rem(a, b)` in place, with coefficients below `tol` times the
/// dividend's largest set to zero. Returns the new degree, or `None` when the
/// remainder vanishes.
#[inline]
fn neg_rem_in_place<T: Scalar>(
    a: &mut [T; CAP],
    da: usize,
    b: &[T; CAP],
    db: usize,
    tol: f64,
) -> Option<usize> {
    let lb = b[db];
    let amax = a[..=da].iter().fold(0.0f64, |m, x| m.max(x.hi().abs()));
    let mut k = da;
    while k >= db {
        let q = a[k] / lb;
        for i in 0..db {
            a[k - db + i] = a[k - db + i] - q * b[i];
        }
        a[k] = T::ZERO;
        if k == 0 {
            break;
        }
        k -= 1;
    }
    if db == 0 {
        return None;
    }
    let thr = tol * amax;
    let mut deg = None;
    for (i, x) in a[..db].iter_mut().enumerate() {
        if x.hi().abs() <= thr {
            *x = T::ZERO;
        } else {
            *x = -*x;
            deg = Some(i);
        }
    }
    deg
}

/// Sturm count in arithmetic `T`; also returns the smallest ratio, over the members,
/// of the end coefficients (whose signs are used) to the member's largest one.
fn sturm_in<T: Scalar>(p: &Poly, pd: usize, tol: f64) -> (usize, f64) {
    let mut bufs = [[T::ZERO; CAP]; 2];
    let mut deg = [pd, pd - 1];
    for (x, &c) in bufs[0].iter_mut().zip(&p.c[..=pd]) {
        *x = T::from_f64(c);
    }
    // Balance the coefficients by substituting x = σ y, σ a power of two (exact;
    // σ > 0 keeps the roots on (0, ∞)) making the lowest nonzero and the leading
    // coefficient about equal in size.
    if let Some(i0) = p.c[..pd].iter().position(|&x| x != 0.0) {
        let ediff = binary_exponent(p.c[i0]) - binary_exponent(p.c[pd]);
        let e = (ediff as f64 / (pd - i0) as f64).round() as i64;
        if (-60..=60).contains(&e) {
            let s2 = f64::from_bits(((1023 + e) as u64) << 52);
            let mut f = 1.0;
            for x in bufs[0][..=pd].iter_mut() {
                *x = x.scale(f);
                f *= s2;
            }
        }
    }
    normalise(&mut bufs[0], pd);
    for k in 1..=pd {
        bufs[1][k - 1] = bufs[0][k] * T::from_f64(k as f64);
    }
    let mut worst = f64::INFINITY;
    let mut at0 = Changes { last: 0, n: 0 };
    let mut atinf = Changes { last: 0, n: 0 };
    let mut note = |c: &[T; CAP], d: usize, max: f64, worst: &mut f64| {
        let lo = c[..=d]
            .iter()
            .map(|x| x.hi())
            .find(|&x| x != 0.0)
            .unwrap_or(0.0);
        let hi = c[d].hi();
        at0.push(sgn(lo));
        atinf.push(sgn(hi));
        *worst = worst.min(lo.abs().min(hi.abs()) / max);
    };
    normalise(&mut bufs[1], deg[1]);
    // p and p' carry the input's own signs: only the remainders can be noise
    let mut ignore = f64::INFINITY;
    note(&bufs[0], deg[0], 1.0, &mut ignore);
    note(&bufs[1], deg[1], 1.0, &mut ignore);
    let mut ia = 0;
    while deg[1 - ia] > 0 {
        let (lo, hi) = bufs.split_at_mut(1);
        let (a, b) = if ia == 0 {
            (&mut lo[0], &hi[0])
        } else {
            (&mut hi[0], &lo[0])
        };
        match neg_rem_in_place(a, deg[ia], b, deg[1 - ia], tol) {
            None => break,
            Some(d) => {
                let m = normalise(a, d);
                note(a, d, m, &mut worst);
                deg[ia] = d;
            }
        }
        ia = 1 - ia;
    }
    (at0.n.saturating_sub(atinf.n), worst)
}

/// Number of distinct real roots of `p` in `(0, +inf)`. `p` must not be zero.
///
/// Runs in f64; when a member of the sequence has an end coefficient below
/// [`COND_TOL`] of its size (its sign may then be rounding noise), the sequence is
/// recomputed in double-double arithmetic.
pub fn count_positive_roots(p: &Poly) -> usize {
    let pd = p.trimmed_deg();
    if pd == 0 {
        return 0;
    }
    let (n, worst) = sturm_in::<f64>(p, pd, REM_TOL);
    if worst >= COND_TOL {
        return n;
    }
    sturm_in::<Dd>(p, pd, REM_TOL_DD).0
}

/// Outcome of [`quick_check`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quick {
    /// Proven positive on `(0, ∞)`.
    Positive,
    /// Proven to take a negative value on `(0, ∞)` (so, with `p(0+) > 0`, to have a root).
    NegativeSomewhere,
    /// Not settled: count the roots.
    Unknown,
}

/// Cheap exact shortcuts for a polynomial `p` (trimmed degree `deg`) with all sign
/// information needed: `p(0+) > 0` and a positive leading coefficient.
///
/// * Certificate of positivity (AM–GM): every negative coefficient `c_k` has positive
///   neighbours and `c_k² < 4 L R`, where `L`, `R` are the shares of `c_{k−1}`,
///   `c_{k+1}` not claimed by another negative neighbour (half when shared); then
///   `L x^{k−1} + R x^{k+1} ≥ 2√(LR) x^k > |c_k| x^k` for all `x > 0`.
/// * Witness of a root: `p(x) < 0` (beyond rounding) at `x = √(c_{k−1}/c_{k+1})`, the
///   point where that AM–GM bound is tightest.
///
/// A witness proves instability; stability is only ever concluded from a certificate,
/// Descartes' rule or a Sturm count — never from sampled values.
#[inline]
pub fn quick_check(p: &Poly, deg: usize) -> Quick {
    let c = &p.c;
    let mut cert = true;
    for k in 1..deg {
        if c[k] >= 0.0 {
            continue;
        }
        let (a, b) = (c[k - 1], c[k + 1]);
        if a > 0.0 && b > 0.0 {
            let x = (a / b).sqrt();
            let (mut v, mut mag) = (0.0f64, 0.0f64);
            for i in (0..=deg).rev() {
                v = v * x + c[i];
                mag = mag * x + c[i].abs();
            }
            if v < -1e-12 * mag {
                return Quick::NegativeSomewhere;
            }
            let l = if k >= 2 && c[k - 2] < 0.0 { 0.5 * a } else { a };
            let r = if k + 2 <= deg && c[k + 2] < 0.0 {
                0.5 * b
            } else {
                b
            };
            if c[k] * c[k] >= 4.0 * l * r * (1.0 - 1e-12) {
                cert = false;
            }
        } else {
            cert = false;
        }
    }
    if cert {
        Quick::Positive
    } else {
        Quick::Unknown
    }
}

/// Sign changes of the coefficient sequence (Descartes' bound on positive roots).
#[inline]
pub fn descartes(p: &Poly) -> usize {
    let mut last = 0.0f64;
    let mut n = 0;
    for &x in p.coeffs() {
        if x != 0.0 {
            if last != 0.0 && (x > 0.0) != (last > 0.0) {
                n += 1;
            }
            last = x;
        }
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    fn from_real_roots(lead: f64, roots: &[f64]) -> Poly {
        roots
            .iter()
            .fold(Poly::constant(lead), |p, &r| p.mul(&Poly::linear(1.0, -r)))
    }

    #[test]
    fn counts_known_roots() {
        let p = from_real_roots(1.0, &[-3.0, 0.5, 2.0, 7.0]);
        assert_eq!(count_positive_roots(&p), 3);
        let p = from_real_roots(-2.0, &[-3.0, -0.5, 4.0]);
        assert_eq!(count_positive_roots(&p), 1);
        let p = from_real_roots(1.0, &[-1.0, -2.0, -3.0]);
        assert_eq!(count_positive_roots(&p), 0);
        // multiple roots are counted once
        let p = from_real_roots(1.0, &[1.5, 1.5, 1.5, -2.0, 4.0]);
        assert_eq!(count_positive_roots(&p), 2);
        // a complex pair near (not on) the positive axis
        let q = Poly::from_ascending(&[1.0 + 1e-6, -2.0, 1.0]); // (x-1)^2 + 1e-6
        assert_eq!(count_positive_roots(&q), 0);
        let q = Poly::from_ascending(&[1.0 - 1e-6, -2.0, 1.0]);
        assert_eq!(count_positive_roots(&q), 2);
        // a root at 0 is not in (0, inf)
        let p = from_real_roots(1.0, &[0.0, 3.0, -1.0]);
        assert_eq!(count_positive_roots(&p), 1);
        let p = from_real_roots(1.0, &[0.0, 0.0, -1.0]);
        assert_eq!(count_positive_roots(&p), 0);
    }

    #[test]
    fn widely_scaled_roots() {
        let roots = [1e-3, 0.02, 0.7, 30.0, 900.0];
        let p = from_real_roots(1.0, &roots);
        assert_eq!(count_positive_roots(&p), 5);
        let p = from_real_roots(1.0, &[-1e-3, 0.02, -0.7, 30.0, -900.0]);
        assert_eq!(count_positive_roots(&p), 2);
    }

    #[test]
    fn pseudo_random_against_construction() {
        // deterministic LCG: polynomials with known numbers of positive roots
        let mut state = 12345u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..2000 {
            let mut p = Poly::constant(0.5 + rnd());
            let mut expect = 0;
            let nreal = (rnd() * 4.0) as usize;
            let npair = (rnd() * 3.0) as usize;
            for _ in 0..nreal {
                let mag = 10f64.powf(rnd() * 4.0 - 2.0);
                let r = if rnd() < 0.5 { mag } else { -mag };
                // keep roots separated so that the count is well defined in f64
                if r > 0.0 {
                    expect += 1;
                }
                p = p.mul(&Poly::linear(1.0, -r));
            }
            for _ in 0..npair {
                let re = 4.0 * rnd() - 2.0;
                let im = 0.2 + rnd();
                p = p.mul(&Poly::from_ascending(&[re * re + im * im, -2.0 * re, 1.0]));
            }
            // skip draws with nearly coincident positive roots
            let c = count_positive_roots(&p);
            assert!(c <= expect);
            if c != expect {
                // only allowed when two positive roots are within 1e-6 relative
                panic!("count {c} != {expect} for {:?}", p.coeffs());
            }
        }
    }

    #[test]
    fn badly_scaled_degree_eight() {
        // R(x) of the proposed model, Padé 5, kg = 0.00588, Tg = 14.6, kv = 0.76:
        // roots -557, 1.174, 0.579, -0.001 and two complex pairs; coefficients span
        // eleven orders of magnitude.
        let r = Poly::from_ascending(&[
            0.012740426987576457,
            12.44173069211328,
            -32.48072122924222,
            19.215687434421937,
            -0.502593637896823,
            0.006213388066443448,
            -1.736439636570731e-05,
            4.090513140691302e-08,
            1.7092408528980463e-10,
        ]);
        assert_eq!(count_positive_roots(&r), 2);
        // the same model at kg = 0.0031, Tg = 14.85, kv = 0.8: roots 0.394 and 1.374;
        // its Sturm sequence has a member with a leading coefficient ~1e-6 of its size
        let r = Poly::from_ascending(&[
            0.007089735698463542,
            9.900001075607214,
            -32.68710512657546,
            19.224426974180595,
            -0.5027535194331367,
            0.006214234823990493,
            -1.7366121221778515e-05,
            4.0905436488920945e-08,
            1.7092408528980463e-10,
        ]);
        assert_eq!(count_positive_roots(&r), 2);
    }

    #[test]
    fn quick_check_never_contradicts_sturm() {
        let mut state = 99u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut pos, mut neg) = (0, 0);
        for _ in 0..20000 {
            let deg = 2 + (rnd() * 7.0) as usize;
            let mut c = vec![0.0; deg + 1];
            for x in c.iter_mut() {
                *x = (rnd() - 0.3) * 10f64.powf(4.0 * rnd() - 2.0);
            }
            c[0] = c[0].abs() + 1e-3;
            c[deg] = c[deg].abs() + 1e-3;
            let p = Poly::from_ascending(&c);
            let n = count_positive_roots(&p);
            match quick_check(&p, p.deg) {
                Quick::Positive => {
                    assert_eq!(n, 0, "{c:?}");
                    pos += 1;
                }
                Quick::NegativeSomewhere => {
                    assert!(n >= 1, "{c:?}");
                    neg += 1;
                }
                Quick::Unknown => {}
            }
        }
        assert!(pos > 1000 && neg > 1000, "{pos} {neg}");
    }

    #[test]
    fn descartes_rule() {
        assert_eq!(descartes(&Poly::from_ascending(&[1.0, -1.0, 0.0, 2.0])), 2);
        assert_eq!(descartes(&Poly::from_ascending(&[1.0, 2.0, 3.0])), 0);
    }
}
