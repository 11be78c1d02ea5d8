//! Routh–Hurwitz test (paper Table V): all roots in the open left half-plane.

use super::poly::{Poly, CAP};

/// True iff every root of `d` has a strictly negative real part.
///
/// Necessary: all coefficients nonzero and of one sign (Eq. 15a). Then the first
/// column of the Routh array must keep that sign (Eq. 15b). A zero anywhere in the
/// first column (including the singular cases that need the epsilon or auxiliary
/// polynomial tricks) means a root on or right of the imaginary axis, or a pair
/// symmetric about the origin: not asymptotically stable.
pub fn hurwitz(d: &Poly) -> bool {
    let n = d.deg;
    let lead = d.lead();
    if lead == 0.0 || !lead.is_finite() {
        return false;
    }
    let sgn = lead.signum();
    for &x in d.coeffs() {
        if x * sgn <= 0.0 || x.is_nan() {
            return false;
        }
    }
    if n <= 2 {
        return true;
    }
    // Rows of the Routh array, from the highest power down, sign-normalised.
    let mut top = [0.0f64; CAP / 2 + 1];
    let mut bot = [0.0f64; CAP / 2 + 1];
    let mut i = 0;
    while 2 * i <= n {
        top[i] = sgn * d.c[n - 2 * i];
        i += 1;
    }
    let mut i = 0;
    while 2 * i < n {
        bot[i] = sgn * d.c[n - 1 - 2 * i];
        i += 1;
    }
    // Row lengths: rows k = 0..=n have ceil((n - k + 1) / 2) entries.
    for k in 2..=n {
        let len = (n - k) / 2 + 1;
        let f = top[0] / bot[0];
        let mut new = [0.0f64; CAP / 2 + 1];
        for j in 0..len {
            new[j] = top[j + 1] - f * bot[j + 1];
        }
        if new[0] <= 0.0 || new[0].is_nan() {
            return false;
        }
        top = bot;
        bot = new;
    }
    true
}

/// Number of roots of `d` with a positive real part, from the sign changes of the
/// first column of the Routh array; `None` when a zero appears in that column (a
/// root on the imaginary axis or a pair symmetric about the origin: the count is
/// then not defined by the regular array).
pub fn rhp_count(d: &Poly) -> Option<usize> {
    let mut d = *d;
    d.trim();
    let n = d.deg;
    let lead = d.lead();
    if lead == 0.0 || !lead.is_finite() || d.c[0] == 0.0 {
        return None;
    }
    if n == 0 {
        return Some(0);
    }
    let mut top = [0.0f64; CAP / 2 + 1];
    let mut bot = [0.0f64; CAP / 2 + 1];
    let mut i = 0;
    while 2 * i <= n {
        top[i] = d.c[n - 2 * i];
        i += 1;
    }
    let mut i = 0;
    while 2 * i < n {
        bot[i] = d.c[n - 1 - 2 * i];
        i += 1;
    }
    let mut changes = 0;
    let mut prev = top[0];
    for k in 1..=n {
        let cur = bot[0];
        if cur == 0.0 || !cur.is_finite() {
            return None;
        }
        if (cur > 0.0) != (prev > 0.0) {
            changes += 1;
        }
        if k == n {
            break;
        }
        let len = (n - k - 1) / 2 + 1;
        let f = top[0] / bot[0];
        let mut new = [0.0f64; CAP / 2 + 1];
        for j in 0..len {
            new[j] = top[j + 1] - f * bot[j + 1];
        }
        prev = cur;
        top = bot;
        bot = new;
    }
    Some(changes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn from_roots(roots: &[(f64, f64)]) -> Poly {
        // real roots (re, 0) or conjugate pairs (re, im) with im > 0
        let mut p = Poly::constant(1.0);
        for &(re, im) in roots {
            if im == 0.0 {
                p = p.mul(&Poly::linear(1.0, -re));
            } else {
                p = p.mul(&Poly::from_ascending(&[re * re + im * im, -2.0 * re, 1.0]));
            }
        }
        p
    }

    #[test]
    fn known_polynomials() {
        assert!(hurwitz(&from_roots(&[
            (-1.0, 0.0),
            (-2.0, 0.0),
            (-0.5, 3.0)
        ])));
        assert!(hurwitz(&from_roots(&[
            (-0.1, 5.0),
            (-3.0, 0.0),
            (-0.2, 0.1),
            (-7.0, 1.0)
        ])));
        assert!(!hurwitz(&from_roots(&[
            (-1.0, 0.0),
            (0.05, 2.0),
            (-2.0, 0.0)
        ])));
        assert!(!hurwitz(&from_roots(&[
            (-1.0, 0.0),
            (-1.0, 0.0),
            (-1.0, 1.0),
            (0.3, 0.0)
        ])));
        // roots on the axis: not asymptotically stable
        assert!(!hurwitz(&from_roots(&[
            (-1.0, 0.0),
            (0.0, 1.0),
            (-2.0, 0.0)
        ])));
        assert!(!hurwitz(&from_roots(&[(-1.0, 0.0), (0.0, 0.0)])));
        // s^3 + s^2 + 2 s + 8: all coefficients positive but unstable
        assert!(!hurwitz(&Poly::from_ascending(&[8.0, 2.0, 1.0, 1.0])));
        // negative leading coefficient of a stable polynomial
        assert!(hurwitz(
            &from_roots(&[(-1.0, 0.0), (-2.0, 1.0)]).scale(-3.0)
        ));
        // third order: a2 a1 > a3 a0 boundary
        assert!(hurwitz(&Poly::from_ascending(&[5.9, 2.0, 3.0, 1.0])));
        assert!(!hurwitz(&Poly::from_ascending(&[6.0, 2.0, 3.0, 1.0])));
    }

    #[test]
    fn rhp_counts() {
        let cases: [(&[(f64, f64)], usize); 5] = [
            (&[(-1.0, 0.0), (-2.0, 0.0), (-0.5, 3.0)], 0),
            (&[(-1.0, 0.0), (0.05, 2.0), (-2.0, 0.0)], 2),
            (&[(-1.0, 0.0), (-1.0, 1.0), (0.3, 0.0)], 1),
            (&[(2.0, 0.0), (0.1, 1.0), (0.3, 0.0), (-4.0, 0.5)], 4),
            (&[(3.0, 0.0)], 1),
        ];
        for (roots, want) in cases {
            let p = from_roots(roots);
            assert_eq!(rhp_count(&p), Some(want), "{roots:?}");
            assert_eq!(rhp_count(&p.scale(-2.0)), Some(want));
            assert_eq!(hurwitz(&p), want == 0);
        }
        assert_eq!(rhp_count(&from_roots(&[(-1.0, 0.0), (0.0, 1.0)])), None);
    }
}
