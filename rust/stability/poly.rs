//! Fixed-size, allocation-free real polynomials.
//!
//! Coefficients are stored in ascending powers (`c[k]` multiplies `s^k`) in a
//! `[f64; CAP]` with an explicit degree, so a polynomial is a plain `Copy` value
//! that lives on the stack. Products whose degree would not fit are a bug of the
//! caller (the stability engine bounds the Padé order so that they always fit).

/// Capacity: the largest storable degree is `CAP - 1`.
pub const CAP: usize = 16;

/// A real polynomial `c[0] + c[1] s + ... + c[deg] s^deg`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Poly {
    pub c: [f64; CAP],
    pub deg: usize,
}

impl Default for Poly {
    fn default() -> Self {
        Self::ZERO
    }
}

impl Poly {
    /// The zero polynomial (degree 0, coefficient 0).
    pub const ZERO: Poly = Poly {
        c: [0.0; CAP],
        deg: 0,
    };

    /// The constant `a`.
    #[inline]
    pub fn constant(a: f64) -> Poly {
        let mut p = Poly::ZERO;
        p.c[0] = a;
        p
    }

    /// From ascending coefficients; trailing (highest-power) zeros are trimmed.
    pub fn from_ascending(cs: &[f64]) -> Poly {
        assert!(
            !cs.is_empty() && cs.len() <= CAP,
            "polynomial degree out of range"
        );
        let mut p = Poly::ZERO;
        p.c[..cs.len()].copy_from_slice(cs);
        p.deg = cs.len() - 1;
        p.trimmed()
    }

    /// The linear polynomial `a1 s + a0`.
    #[inline]
    pub fn linear(a1: f64, a0: f64) -> Poly {
        Poly::from_ascending(&[a0, a1])
    }

    /// The coefficients `c[0..=deg]`, ascending.
    #[inline]
    pub fn coeffs(&self) -> &[f64] {
        &self.c[..=self.deg]
    }

    /// Leading coefficient.
    #[inline]
    pub fn lead(&self) -> f64 {
        self.c[self.deg]
    }

    /// True for the zero polynomial.
    #[inline]
    pub fn is_zero(&self) -> bool {
        self.deg == 0 && self.c[0] == 0.0
    }

    /// Drops exactly-zero leading coefficients, in place.
    #[inline]
    pub fn trim(&mut self) {
        while self.deg > 0 && self.c[self.deg] == 0.0 {
            self.deg -= 1;
        }
    }

    /// Degree once exactly-zero leading coefficients are dropped.
    #[inline]
    pub fn trimmed_deg(&self) -> usize {
        let mut d = self.deg;
        while d > 0 && self.c[d] == 0.0 {
            d -= 1;
        }
        d
    }

    /// Drops exactly-zero leading coefficients.
    #[inline]
    pub fn trimmed(mut self) -> Poly {
        while self.deg > 0 && self.c[self.deg] == 0.0 {
            self.deg -= 1;
        }
        self
    }

    /// Product.
    #[inline]
    pub fn mul(&self, o: &Poly) -> Poly {
        let deg = self.deg + o.deg;
        assert!(
            deg < CAP,
            "polynomial product degree {deg} exceeds capacity"
        );
        let mut r = Poly::ZERO;
        for i in 0..=self.deg {
            let a = self.c[i];
            for j in 0..=o.deg {
                r.c[i + j] += a * o.c[j];
            }
        }
        r.deg = deg;
        r.trimmed()
    }

    /// Sum.
    #[inline]
    pub fn add(&self, o: &Poly) -> Poly {
        let deg = self.deg.max(o.deg);
        let mut r = Poly::ZERO;
        for k in 0..=deg {
            r.c[k] = self.c[k] + o.c[k];
        }
        r.deg = deg;
        r.trimmed()
    }

    /// Difference.
    #[inline]
    pub fn sub(&self, o: &Poly) -> Poly {
        let deg = self.deg.max(o.deg);
        let mut r = Poly::ZERO;
        for k in 0..=deg {
            r.c[k] = self.c[k] - o.c[k];
        }
        r.deg = deg;
        r.trimmed()
    }

    /// `a * p`.
    #[inline]
    pub fn scale(&self, a: f64) -> Poly {
        let mut r = *self;
        for k in 0..=r.deg {
            r.c[k] *= a;
        }
        r.trimmed()
    }

    /// `s^k * p`.
    #[inline]
    pub fn shift(&self, k: usize) -> Poly {
        if self.is_zero() || k == 0 {
            return *self;
        }
        let deg = self.deg + k;
        assert!(deg < CAP, "polynomial degree {deg} exceeds capacity");
        let mut r = Poly::ZERO;
        r.c[k..=deg].copy_from_slice(&self.c[..=self.deg]);
        r.deg = deg;
        r
    }

    /// `p(-s)`.
    #[inline]
    pub fn reflect(&self) -> Poly {
        let mut r = *self;
        for k in (1..=r.deg).step_by(2) {
            r.c[k] = -r.c[k];
        }
        r
    }

    /// Value at `x` (Horner).
    #[inline]
    pub fn eval(&self, x: f64) -> f64 {
        let mut acc = 0.0;
        for k in (0..=self.deg).rev() {
            acc = acc * x + self.c[k];
        }
        acc
    }

    /// Value at a complex point `(re, im)`, as `(re, im)`.
    pub fn eval_complex(&self, re: f64, im: f64) -> (f64, f64) {
        let (mut ar, mut ai) = (0.0, 0.0);
        for k in (0..=self.deg).rev() {
            let nr = ar * re - ai * im + self.c[k];
            ai = ar * im + ai * re;
            ar = nr;
        }
        (ar, ai)
    }

    /// Derivative.
    #[inline]
    pub fn derivative(&self) -> Poly {
        if self.deg == 0 {
            return Poly::ZERO;
        }
        let mut r = Poly::ZERO;
        for k in 1..=self.deg {
            r.c[k - 1] = self.c[k] * k as f64;
        }
        r.deg = self.deg - 1;
        r.trimmed()
    }

    /// The real part of `p(jω)` as a polynomial in `x = ω²`:
    /// `E(x) = Σ_k (-1)^k c[2k] x^k`.
    #[inline]
    pub fn even_jw(&self) -> Poly {
        let mut r = Poly::ZERO;
        let mut sign = 1.0;
        let mut k = 0;
        while 2 * k <= self.deg {
            r.c[k] = sign * self.c[2 * k];
            sign = -sign;
            k += 1;
        }
        r.deg = k - 1;
        r.trimmed()
    }

    /// The imaginary part of `p(jω)` divided by `ω`, as a polynomial in `x = ω²`:
    /// `O(x) = Σ_k (-1)^k c[2k+1] x^k`, so that `p(jω) = E(ω²) + j ω O(ω²)`.
    #[inline]
    pub fn odd_jw(&self) -> Poly {
        if self.deg == 0 {
            return Poly::ZERO;
        }
        let mut r = Poly::ZERO;
        let mut sign = 1.0;
        let mut k = 0;
        while 2 * k < self.deg {
            r.c[k] = sign * self.c[2 * k + 1];
            sign = -sign;
            k += 1;
        }
        r.deg = k - 1;
        r.trimmed()
    }

    /// Largest coefficient magnitude.
    #[inline]
    pub fn max_abs(&self) -> f64 {
        self.coeffs().iter().fold(0.0f64, |m, x| m.max(x.abs()))
    }

    /// Index of the lowest nonzero coefficient (`None` for the zero polynomial).
    #[inline]
    pub fn lowest_nonzero(&self) -> Option<usize> {
        self.coeffs().iter().position(|&x| x != 0.0)
    }

    /// `p(x) / x^k` for the `k` lowest coefficients, which are dropped (the caller
    /// knows they vanish).
    #[inline]
    pub fn divide_by_x_pow(&self, k: usize) -> Poly {
        if k == 0 {
            return *self;
        }
        if k > self.deg {
            return Poly::ZERO;
        }
        let mut r = Poly::ZERO;
        r.c[..=self.deg - k].copy_from_slice(&self.c[k..=self.deg]);
        r.deg = self.deg - k;
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn product_and_eval() {
        // (s + 1)(s - 2) = s^2 - s - 2
        let p = Poly::linear(1.0, 1.0).mul(&Poly::linear(1.0, -2.0));
        assert_eq!(p.coeffs(), &[-2.0, -1.0, 1.0]);
        assert_eq!(p.eval(3.0), 4.0);
        assert_eq!(p.reflect().coeffs(), &[-2.0, 1.0, 1.0]);
        assert_eq!(p.derivative().coeffs(), &[-1.0, 2.0]);
        assert_eq!(p.shift(2).coeffs(), &[0.0, 0.0, -2.0, -1.0, 1.0]);
        assert!(p.sub(&p).is_zero());
    }

    #[test]
    fn jw_parts_reassemble() {
        let p = Poly::from_ascending(&[1.5, -2.0, 0.25, 3.0, -0.5, 0.75]);
        for &w in &[0.0, 0.3, 1.7, 4.0] {
            let (re, im) = p.eval_complex(0.0, w);
            let x = w * w;
            assert!((re - p.even_jw().eval(x)).abs() < 1e-12 * (1.0 + re.abs()));
            assert!((im - w * p.odd_jw().eval(x)).abs() < 1e-12 * (1.0 + im.abs()));
        }
    }
}
