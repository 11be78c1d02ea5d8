//! Exact count of the distinct real roots of a polynomial on `(0, +inf)`.
//!
//! Sturm's theorem: with `p0 = p`, `p1 = p'`, `p_{k+1} = -rem(p_{k-1}, p_k)`, the
//! number of distinct real roots in `(a, b]` is `V(a) - V(b)`, the difference of the
//! sign changes of the sequence at the two ends. At `a = 0+` each member's sign is
//! that of its lowest nonzero coefficient, at `b = +inf` that of its leading one;
//! neither end is a root, so the count is exact in exact arithmetic whatever the
//! multiplicities. In floating point, a remainder coefficient within a relative
//! `REM_TOL` of the rounding bound of its computation is taken as zero (this only
//! matters for polynomials within rounding of a degenerate configuration, i.e. on
//! the stability boundary itself).

use super::poly::{Poly, CAP};

/// Relative threshold below which a computed remainder coefficient counts as zero.
pub const REM_TOL: f64 = 1e-11;

#[inline]
fn sign_changes(signs: &[i8]) -> usize {
    let mut last = 0i8;
    let mut n = 0;
    for &s in signs {
        if s != 0 {
            if last != 0 && s != last {
                n += 1;
            }
            last = s;
        }
    }
    n
}

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

/// Normalises `p` to unit largest coefficient (a positive factor: signs unchanged).
#[inline]
fn normalised(p: Poly) -> Poly {
    let m = p.max_abs();
    if m > 0.0 && m.is_finite() {
        p.scale(1.0 / m)
    } else {
        p
    }
}

/// `-rem(a, b)` with tiny coefficients (relative to the rounding bound) set to zero.
#[inline]
fn neg_rem(a: &Poly, b: &Poly) -> Poly {
    let mut r = *a;
    let db = b.deg;
    let lb = b.lead();
    let bmax = b.max_abs();
    let mut bound = a.max_abs();
    if r.deg >= db {
        let mut k = r.deg;
        loop {
            let q = r.c[k] / lb;
            bound = bound.max(q.abs() * bmax);
            for i in 0..db {
                r.c[k - db + i] -= q * b.c[i];
            }
            r.c[k] = 0.0;
            if k == db {
                break;
            }
            k -= 1;
        }
        r.deg = if db == 0 { 0 } else { db - 1 };
    }
    let tol = REM_TOL * bound;
    for k in 0..=r.deg {
        r.c[k] = if r.c[k].abs() <= tol { 0.0 } else { -r.c[k] };
    }
    r.trimmed()
}

/// Number of distinct real roots of `p` in `(0, +inf)`. `p` must not be zero.
pub fn count_positive_roots(p: &Poly) -> usize {
    let p = p.trimmed();
    if p.deg == 0 {
        return 0;
    }
    let mut s0 = [0i8; CAP + 1];
    let mut sinf = [0i8; CAP + 1];
    let mut n = 0;
    let mut push = |q: &Poly, n: &mut usize| {
        let lo = q.lowest_nonzero().map_or(0.0, |i| q.c[i]);
        s0[*n] = sgn(lo);
        sinf[*n] = sgn(q.lead());
        *n += 1;
    };
    let mut a = normalised(p);
    let mut b = normalised(a.derivative());
    push(&a, &mut n);
    push(&b, &mut n);
    while b.deg > 0 {
        let r = neg_rem(&a, &b);
        if r.is_zero() {
            break;
        }
        let r = normalised(r);
        push(&r, &mut n);
        a = b;
        b = r;
    }
    let v0 = sign_changes(&s0[..n]);
    let vinf = sign_changes(&sinf[..n]);
    v0.saturating_sub(vinf)
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
    fn descartes_rule() {
        assert_eq!(descartes(&Poly::from_ascending(&[1.0, -1.0, 0.0, 2.0])), 2);
        assert_eq!(descartes(&Poly::from_ascending(&[1.0, 2.0, 3.0])), 0);
    }
}
