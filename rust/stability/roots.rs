//! Real roots of a real polynomial on an interval.
//!
//! The roots of `p'` split the interval into pieces on which `p` is monotone; a piece
//! whose end values differ in sign holds exactly one root, found by safeguarded
//! bisection to the last bit. The critical points come from the same routine applied
//! to `p'` (recursion down to degree 1). A root of even multiplicity shows as a
//! critical point where `p` vanishes exactly; in floating point such a tangency may
//! be reported as one root or missed (it is the boundary case of every use here, and
//! the callers never conclude stability from a root list alone).

use super::poly::Poly;

/// Fujiwara's bound: every complex root `z` of `p` has `|z| <= 2 max_k |c_{n-k}/c_n|^{1/k}`.
/// `p` must have a nonzero leading coefficient (trimmed).
pub fn root_bound(p: &Poly) -> f64 {
    let n = p.trimmed_deg();
    if n == 0 {
        return 0.0;
    }
    let lead = p.c[n].abs();
    let mut m = 0.0f64;
    for k in 1..=n {
        let c = p.c[n - k].abs() / lead;
        let r = if k == n {
            (c / 2.0).powf(1.0 / k as f64)
        } else {
            c.powf(1.0 / k as f64)
        };
        m = m.max(r);
    }
    2.0 * m * (1.0 + 1e-12) + f64::MIN_POSITIVE
}

/// The root of `p` in `(a, b)` where `p(a)` and `p(b)` have opposite signs (`fa = p(a)`).
fn bisect(p: &Poly, mut a: f64, mut b: f64, mut fa: f64) -> f64 {
    for _ in 0..200 {
        let m = 0.5 * (a + b);
        if m <= a || m >= b {
            break;
        }
        let fm = p.eval(m);
        if fm == 0.0 {
            return m;
        }
        if (fm > 0.0) == (fa > 0.0) {
            a = m;
            fa = fm;
        } else {
            b = m;
        }
    }
    0.5 * (a + b)
}

fn roots_rec(p: &Poly, lo: f64, hi: f64, out: &mut Vec<f64>) {
    let d = p.trimmed_deg();
    if d == 0 {
        return;
    }
    if d == 1 {
        let r = -p.c[0] / p.c[1];
        if r > lo && r < hi {
            out.push(r);
        }
        return;
    }
    let mut crit = Vec::with_capacity(d);
    roots_rec(&p.derivative(), lo, hi, &mut crit);
    crit.sort_by(f64::total_cmp);
    let mut a = lo;
    let mut fa = p.eval(lo);
    for &b in crit.iter().chain(std::iter::once(&hi)) {
        if b <= a {
            continue;
        }
        let fb = p.eval(b);
        if fa != 0.0 && fb != 0.0 && (fa > 0.0) != (fb > 0.0) {
            out.push(bisect(p, a, b, fa));
        } else if fb == 0.0 && b < hi {
            out.push(b);
        }
        a = b;
        fa = fb;
    }
}

/// The distinct real roots of `p` in the open interval `(lo, hi)`, ascending
/// (`lo`, `hi` finite).
pub fn real_roots(p: &Poly, lo: f64, hi: f64) -> Vec<f64> {
    let mut out = Vec::new();
    if p.is_zero() || lo >= hi || lo.is_nan() || hi.is_nan() {
        return out;
    }
    let mut q = *p;
    q.trim();
    roots_rec(&q, lo, hi, &mut out);
    out.sort_by(f64::total_cmp);
    out.dedup();
    out
}

/// The distinct positive real roots of `p`, ascending.
pub fn positive_roots(p: &Poly) -> Vec<f64> {
    let mut q = *p;
    q.trim();
    if q.trimmed_deg() == 0 {
        return Vec::new();
    }
    let hi = root_bound(&q) * 1.01 + 1.0;
    real_roots(&q, 0.0, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn from_roots(lead: f64, roots: &[f64]) -> Poly {
        roots
            .iter()
            .fold(Poly::constant(lead), |p, &r| p.mul(&Poly::linear(1.0, -r)))
    }

    #[test]
    fn finds_known_roots() {
        let rs = [-3.0, 0.02, 0.5, 2.0, 7.0, 130.0];
        let p = from_roots(-0.3, &rs);
        let got = positive_roots(&p);
        let want = [0.02, 0.5, 2.0, 7.0, 130.0];
        assert_eq!(got.len(), want.len(), "{got:?}");
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() <= 1e-12 * w, "{g} vs {w}");
        }
        let all = real_roots(&p, -10.0, 200.0);
        assert_eq!(all.len(), 6);
        // complex pairs only
        let q =
            Poly::from_ascending(&[2.0, -2.0, 1.0]).mul(&Poly::from_ascending(&[5.0, 0.0, 1.0]));
        assert!(positive_roots(&q).is_empty());
        // double root: found as the critical point where p vanishes exactly
        let d = from_roots(1.0, &[1.0, 1.0, 3.0]);
        let r = positive_roots(&d);
        assert!(
            r.iter().any(|&x| (x - 1.0).abs() < 1e-7) && r.iter().any(|&x| (x - 3.0).abs() < 1e-12)
        );
    }

    #[test]
    fn bound_holds() {
        let p = from_roots(2.0, &[-40.0, 1.0, 3.0, 9.0]);
        assert!(root_bound(&p) >= 40.0);
    }

    #[test]
    fn random_polynomials_against_construction() {
        let mut s = 3u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..500 {
            let n = 1 + (rnd() * 7.0) as usize;
            let mut roots: Vec<f64> = (0..n)
                .map(|_| {
                    let m = 10f64.powf(rnd() * 4.0 - 2.0);
                    if rnd() < 0.6 {
                        m
                    } else {
                        -m
                    }
                })
                .collect();
            roots.sort_by(f64::total_cmp);
            let sep = roots
                .windows(2)
                .all(|w| (w[1] - w[0]).abs() > 1e-3 * w[1].abs().max(w[0].abs()));
            if !sep {
                continue;
            }
            let p = from_roots(0.5 + rnd(), &roots).mul(&Poly::from_ascending(&[
                1.0 + rnd(),
                -0.5,
                1.0,
            ]));
            let want: Vec<f64> = roots.iter().copied().filter(|&r| r > 0.0).collect();
            let got = positive_roots(&p);
            assert_eq!(got.len(), want.len(), "{roots:?} -> {got:?}");
            for (g, w) in got.iter().zip(&want) {
                assert!((g - w).abs() <= 1e-9 * w.abs(), "{g} vs {w}");
            }
        }
    }
}
