//! Local and string stability of a platoon under the upper-level law (paper
//! Section IV and Appendix).
//!
//! For a lower level reduced to [`Linear`] (`G = b(s) e^{-Td s} / a(s)`,
//! `G_fb = G / (1 - K G)`) and the delay replaced by its order-`n` Padé
//! approximant `Q(-s)/Q(s)` ([`pade`]), paper Eqs. 9–10 read
//! `Ga = b(s) Q(-s)`, `Gb = a(s) Q(s)`, and the closed loop of Eq. 8 is
//!
//! ```text
//!   H(s) = N(s) / D(s),   N = Ga (kv s + kg),
//!                         D = (Gb - K Ga) s^2 + Ga (mu s + kg),   mu = kv + Tg kg   (Eq. 12)
//! ```
//!
//! (no delay, as for the first-order lag: `Q = 1`). All are built as polynomial
//! products; the model part `Ga`, `M = Gb - K Ga` is computed once per map.
//!
//! * Local stability: Routh–Hurwitz on `D` ([`routh::hurwitz`]).
//! * String stability: `P(x) = |D(j√x)|² − |N(j√x)|² > 0` for all `x > 0`. Since
//!   `|D|² − |N|² = Re[(D − N) conj(D + N)]` and `D − N = s C` with
//!   `C = M s + kg Tg Ga`, one has exactly `P(x) = x R(x)` with
//!   `R = E_C O_B − O_C E_B` (`B = D + N`, `p(jω) = E_p(ω²) + jω O_p(ω²)`): the root
//!   at 0 is divided out symbolically, with no cancellation. The test is
//!   `R(0+) > 0` (lowest nonzero coefficient) and no root of `R` on `(0, ∞)`,
//!   decided by Descartes' rule when it settles it and otherwise by a Sturm count
//!   ([`sturm::count_positive_roots`]); no frequency is sampled.

pub mod boundary;
pub mod dd;
pub mod delay;
pub mod grid;
pub mod interval;
pub mod pade;
pub mod poly;
pub mod roots;
pub mod routh;
pub mod sturm;
pub mod threshold;

use crate::error::{AvllError, Result};
use crate::model::Linear;
use poly::Poly;

/// Map code: locally unstable (or not asymptotically stable).
pub const LOCAL_UNSTABLE: u8 = 0;
/// Map code: locally stable, string unstable.
pub const STRING_UNSTABLE: u8 = 1;
/// Map code: locally and string stable.
pub const STABLE: u8 = 2;

/// The model part of the closed-loop polynomials, fixed for a map.
///
/// Besides `Ga`, `Gb` and `M = Gb − K Ga`, it holds the pieces that make the per-point
/// work a few multiply-adds: `D` and `R` are affine/bilinear in the upper-level
/// parameters, `D = M s² + μ (s Ga) + kg Ga` and, with `α = kg Tg`, `β = μ + kv`,
/// `γ = 2 kg`, `R = R00 + β R01 + γ R02 + α R10 + α β R11`, where the `Rij` are
/// products of the `jω` even/odd parts of `s M`, `s² M`, `Ga`, `s Ga` (the `α γ`
/// term is `E_Ga O_Ga − O_Ga E_Ga = 0`). [`LoopModel::string_poly`] computes `R` from
/// `C` and `B` directly; a unit test checks that both agree.
#[derive(Debug, Clone, Copy)]
pub struct LoopModel {
    /// `Ga = b(s) Q(-s)`.
    pub ga: Poly,
    /// `Gb = a(s) Q(s)`.
    pub gb: Poly,
    /// `M = Gb − K Ga`.
    pub m: Poly,
    /// Padé order used (irrelevant when the model has no delay).
    pub pade_order: usize,
    d_m: Poly,
    d_mu: Poly,
    r00: Poly,
    r01: Poly,
    r02: Poly,
    r10: Poly,
    r11: Poly,
}

impl LoopModel {
    /// Builds `Ga`, `Gb` (Eqs. 9–10) for a Padé order in `1..=pade::MAX_ORDER`.
    pub fn new(lin: &Linear, pade_order: usize) -> Result<Self> {
        if !(1..=pade::MAX_ORDER).contains(&pade_order) {
            return Err(AvllError::new(
                "pade_order",
                format!("must be in 1..={}, got {pade_order}", pade::MAX_ORDER),
            ));
        }
        for (n, x) in [
            ("b1", lin.b1),
            ("b0", lin.b0),
            ("a2", lin.a2),
            ("a1", lin.a1),
            ("Td", lin.td),
            ("K", lin.k),
        ] {
            crate::error::check_finite(n, x)?;
        }
        let q = pade::pade_den(pade_order, lin.td);
        let b = Poly::linear(lin.b1, lin.b0);
        let a = Poly::from_ascending(&[1.0, lin.a1, lin.a2]);
        let ga = b.mul(&q.reflect());
        let gb = a.mul(&q);
        let m = gb.sub(&ga.scale(lin.k));
        let (ms1, ms2, gas1) = (m.shift(1), m.shift(2), ga.shift(1));
        let (e1, o1) = (ms1.even_jw(), ms1.odd_jw());
        let (e2, o2) = (ga.even_jw(), ga.odd_jw());
        let (e3, o3) = (ms2.even_jw(), ms2.odd_jw());
        let (e4, o4) = (gas1.even_jw(), gas1.odd_jw());
        let cross = |e: &Poly, o: &Poly, e_: &Poly, o_: &Poly| e.mul(o_).sub(&o.mul(e_));
        Ok(Self {
            ga,
            gb,
            m,
            pade_order,
            d_m: ms2,
            d_mu: gas1,
            r00: cross(&e1, &o1, &e3, &o3),
            r01: cross(&e1, &o1, &e4, &o4),
            r02: cross(&e1, &o1, &e2, &o2),
            r10: cross(&e2, &o2, &e3, &o3),
            r11: cross(&e2, &o2, &e4, &o4),
        })
    }

    /// `N(s)` and `D(s)` of Eq. 8 at one upper-level point, as products.
    #[inline]
    pub fn closed_loop(&self, kg: f64, tg: f64, kv: f64) -> (Poly, Poly) {
        let mu = kv + tg * kg;
        let n = self.ga.mul(&Poly::linear(kv, kg));
        let d = self.m.shift(2).add(&self.ga.mul(&Poly::linear(mu, kg)));
        (n, d)
    }

    /// `D(s)` from the precomputed pieces (the map's fast path).
    #[inline]
    pub fn char_poly(&self, kg: f64, tg: f64, kv: f64) -> Poly {
        let mu = kv + tg * kg;
        let mut d = self.d_m;
        for k in 0..=self.d_mu.deg {
            d.c[k] += mu * self.d_mu.c[k];
        }
        for k in 0..=self.ga.deg {
            d.c[k] += kg * self.ga.c[k];
        }
        d.deg = d.deg.max(self.d_mu.deg);
        d.trim();
        d
    }

    /// `R(x) = P(x) / x` (see the module doc), in powers of `x = ω²`, computed from
    /// `C = s M + kg Tg Ga` and `B = D + N` as `E_C O_B − O_C E_B`.
    #[inline]
    pub fn string_poly(&self, kg: f64, tg: f64, kv: f64) -> Poly {
        let mu = kv + tg * kg;
        let c = self.m.shift(1).add(&self.ga.scale(kg * tg));
        let b = self
            .m
            .shift(2)
            .add(&self.ga.mul(&Poly::linear(mu + kv, 2.0 * kg)));
        let (ec, oc) = (c.even_jw(), c.odd_jw());
        let (eb, ob) = (b.even_jw(), b.odd_jw());
        ec.mul(&ob).sub(&oc.mul(&eb))
    }

    /// `R(x)` from the precomputed bilinear pieces (the map's fast path).
    #[inline]
    pub fn string_poly_fast(&self, kg: f64, tg: f64, kv: f64) -> Poly {
        let alpha = kg * tg;
        let beta = 2.0 * kv + alpha;
        let gamma = 2.0 * kg;
        let ab = alpha * beta;
        let mut r = self.r00;
        let deg = r
            .deg
            .max(self.r01.deg)
            .max(self.r02.deg)
            .max(self.r10.deg)
            .max(self.r11.deg);
        for k in 0..=deg {
            r.c[k] += beta * self.r01.c[k]
                + gamma * self.r02.c[k]
                + alpha * self.r10.c[k]
                + ab * self.r11.c[k];
        }
        r.deg = deg;
        r.trim();
        r
    }

    /// The map code at one point: [`LOCAL_UNSTABLE`], [`STRING_UNSTABLE`] or [`STABLE`].
    #[inline]
    pub fn classify(&self, kg: f64, tg: f64, kv: f64) -> u8 {
        if !routh::hurwitz(&self.char_poly(kg, tg, kv)) {
            return LOCAL_UNSTABLE;
        }
        if string_stable(&self.string_poly_fast(kg, tg, kv)) {
            STABLE
        } else {
            STRING_UNSTABLE
        }
    }
}

/// `R > 0` on `(0, ∞)`: positive just right of 0 and no root on `(0, ∞)`.
#[inline]
pub fn string_stable(r: &Poly) -> bool {
    let deg = r.trimmed_deg();
    let lo = match r.c[..=deg].iter().copied().find(|&x| x != 0.0) {
        None => return false,
        Some(x) => x,
    };
    if lo <= 0.0 || lo.is_nan() || !r.c[deg].is_finite() {
        return false;
    }
    // Descartes: no sign change => no positive root; one => exactly one. Then an
    // AM-GM positivity certificate or a negative value as witness; else Sturm.
    match sturm::descartes(r) {
        0 => true,
        1 => false,
        _ => match sturm::quick_check(r, deg) {
            sturm::Quick::Positive => true,
            sturm::Quick::NegativeSomewhere => false,
            sturm::Quick::Unknown => sturm::count_positive_roots(r) == 0,
        },
    }
}

/// Classifies one point for a model (convenience; maps use [`LoopModel`] directly).
pub fn classify(lin: &Linear, pade_order: usize, kg: f64, tg: f64, kv: f64) -> Result<u8> {
    Ok(LoopModel::new(lin, pade_order)?.classify(kg, tg, kv))
}

#[cfg(test)]
mod tests;
