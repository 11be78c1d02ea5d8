//! Padé approximation of the dead time, `e^{-Td s} ≈ Q(-s) / Q(s)`.
//!
//! The diagonal `[n/n]` approximant has
//! `Q(s) = Σ_{k=0}^{n} (2n-k)! n! / ((2n)! k! (n-k)!) (Td s)^k`;
//! order 2 gives the paper's Eq. 10, `1 + Td s / 2 + (Td s)^2 / 12`.

use super::poly::Poly;

/// Highest supported order (keeps every closed-loop polynomial within [`Poly`]'s capacity).
pub const MAX_ORDER: usize = 10;

/// The denominator `Q(s)` of the order-`n` Padé approximant of `e^{-td s}`.
/// `td = 0` gives the constant 1 (no delay). Panics if `n` is 0 or above [`MAX_ORDER`]
/// (checked by the callers).
pub fn pade_den(n: usize, td: f64) -> Poly {
    assert!((1..=MAX_ORDER).contains(&n), "Pade order {n} out of range");
    if td == 0.0 {
        return Poly::constant(1.0);
    }
    let mut c = [0.0; MAX_ORDER + 1];
    // c_0 = 1; c_{k+1} / c_k = (n - k) / ((2n - k)(k + 1)).
    c[0] = 1.0;
    let mut tk = 1.0;
    for k in 0..n {
        c[k + 1] = c[k] * (n - k) as f64 / (((2 * n - k) * (k + 1)) as f64);
    }
    for ck in c.iter_mut().take(n + 1) {
        *ck *= tk;
        tk *= td;
    }
    Poly::from_ascending(&c[..=n])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_two_is_eq10() {
        let td = 0.7903;
        let q = pade_den(2, td);
        assert_eq!(q.deg, 2);
        assert!((q.c[1] - td / 2.0).abs() < 1e-15);
        assert!((q.c[2] - td * td / 12.0).abs() < 1e-15);
    }

    #[test]
    fn approximates_delay_on_imaginary_axis() {
        // |Q(-jw)/Q(jw)| = 1 and the phase error shrinks with the order.
        let td = 1.0;
        let w = 1.0;
        let mut prev = f64::INFINITY;
        for n in 1..=6 {
            let q = pade_den(n, td);
            let (nr, ni) = q.reflect().eval_complex(0.0, w);
            let (dr, di) = q.eval_complex(0.0, w);
            let (mag_n, mag_d) = ((nr * nr + ni * ni).sqrt(), (dr * dr + di * di).sqrt());
            assert!((mag_n / mag_d - 1.0).abs() < 1e-12);
            let phase = ni.atan2(nr) - di.atan2(dr);
            let err = ((phase + w * td).sin()).abs();
            assert!(err < prev, "order {n}: error {err} not below {prev}");
            prev = err;
        }
        assert!(prev < 1e-9);
    }
}
