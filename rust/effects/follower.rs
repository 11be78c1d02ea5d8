//! Certified stability of a follower with several delays: the lower level's dead time
//! `Td`, a command delay `c` outside its inner loop and the radar terms' perception
//! delay `τ` (with a feedforward and a speed feedback besides), where the exact test
//! of [`crate::stability::delay`] (one delay) does not apply.
//!
//! **The loop.** With `G = Nb e^{-Td s} / A` (`Nb = b1 s + b0`, `A = a2 s² + a1 s + 1`),
//! the lower level `G_fb = G e^{-c s} / (1 − K G + β/s)` and the law's small-signal form
//! (see [`super::UpperLin`]), the follower's response [`super::response`] is
//! `H = Num / Den` with the quasi-polynomials (each term a polynomial times
//! `e^{-delay s}`; `Φ = ff_tau s + 1` when the feedforward gain `ka ≠ 0`, else 1;
//! `M = (kg + kv s) Φ + ka s²`; `E = e^{-Td s}`, `C = e^{-c s}`, `D = e^{-τ s}`):
//!
//! ```text
//!   Den = Φ s (s + β) A − K s² Nb Φ E + Nb E C (kg Tg s Φ − ka s²) + Nb E C D M,
//!   Num = Nb E C D M.
//! ```
//!
//! `Den` is the characteristic function of the loop (the follower's position responds
//! to the command through `G_fb / s²`, whose zero at `s = 0` from the speed feedback
//! cancels one integrator: no mode is hidden), and `Den − Num = s X` with
//! `X = Φ (s + β) A − K s Nb Φ E + Nb E C (kg Tg Φ − ka s)`.
//!
//! **Local stability** (every root of `Den` in the open left half-plane), by the
//! argument principle. `Den` is of retarded type when its delay-free part `P0`
//! (degree `n`) has a higher degree than every delayed term (true with `a2 > 0`);
//! then the number of its roots in the closed right half-plane, when none is on the
//! imaginary axis, is `n/2 − Δθ/π`, `Δθ` the change of the continuous argument of
//! `Den(jω)` over `ω ∈ [0, ∞)` (the large semicircle contributes `n π`, as `P0`
//! dominates there; Stépán's formula). `Δθ` is certified: beyond `ω_c` (a Cauchy
//! bound: `|c_n| ω > Σ_j d_j` with `d_j` the sum of the magnitudes of every other
//! coefficient of power `j` over all terms, `ω ≥ 1`) `Den = c_n (jω)^n (1 + r)` with
//! `|r| < 1`, so its argument stays within `π/2` of `arg c_n + n π/2` and the tail's
//! change is `−arg(1 + r(ω_c))`; on `[0, ω_c]` the frequency axis is cut into pieces
//! over which `Den` is enclosed in interval arithmetic ([`crate::stability::interval`],
//! outward rounding): a piece whose rectangle excludes 0 lies in a sector of less
//! than `π` seen from the origin, so the argument's change over it is the principal
//! value of the ratio of its end values; a piece whose rectangle holds 0 is halved.
//! A sweep that exceeds its budget of pieces (a root on or very near the axis), a
//! non-retarded `Den`, or a count that is not a non-negative integer, is undecided.
//!
//! **String stability** (`|H(jω)| < 1` for every `ω > 0`): `|Den|² − |Num|² =
//! ω² g(ω)` with `g = |X|² − 2 q(ω)/ω`, `q = Im(X conj Num)` (odd in `ω`, so `q/ω` is
//! finite at 0: by the mean-value theorem it lies in the enclosure of `q'` over
//! `[0, ω]`, obtained by forward-mode differentiation in interval arithmetic). `g` is
//! enclosed piece by piece over `[0, ω_s]` (beyond `ω_s`, a Cauchy bound of the same
//! kind, `|Den| > |Num|`): a piece whose enclosure is positive is certified, a point
//! whose enclosure is negative is a certified witness of string instability, any other
//! piece is halved, and a sweep over its budget is undecided. Without delays other
//! than `Td` and without feedforward or speed feedback this is the same question as
//! [`crate::stability::delay::DelayLoop`] answers (a test checks that the verdicts
//! agree).

use super::{Linear, Terms, UpperLin};
use crate::stability::interval::{sweep_positive, Cx, DIv, Iv, Num, Sweep};
use crate::stability::poly::Poly;
use crate::stability::{LOCAL_UNSTABLE, STABLE, STRING_UNSTABLE};
use std::f64::consts::PI;

/// Default budget of interval evaluations per test (local and string each).
pub const DEFAULT_BUDGET: usize = 20_000;

/// A quasi-polynomial: a sum of polynomials times `e^{-delay s}`.
#[derive(Debug, Clone, Default)]
pub struct Quasi {
    /// `(delay, polynomial)`, delays distinct, the delay-free term (if any) first.
    pub terms: Vec<(f64, Poly)>,
}

impl Quasi {
    /// Adds `p e^{-delay s}` (merged with a term of the same delay).
    fn push(&mut self, delay: f64, p: Poly) {
        if p.is_zero() {
            return;
        }
        if let Some(t) = self.terms.iter_mut().find(|t| t.0 == delay) {
            t.1 = t.1.add(&p).trimmed();
        } else {
            self.terms.push((delay, p));
            self.terms.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
    }

    /// The delay-free part (zero if none).
    fn p0(&self) -> Poly {
        self.terms
            .iter()
            .find(|t| t.0 == 0.0)
            .map(|t| t.1)
            .unwrap_or(Poly::ZERO)
    }

    /// The value at `s = jω` over `Num` arithmetic.
    fn eval<T: Num>(&self, om: T) -> Cx<T> {
        let x = om.sqr();
        let horner = |q: &Poly| {
            let mut acc = T::cst(0.0);
            for i in (0..=q.deg).rev() {
                acc = acc * x + T::cst(q.c[i]);
            }
            acc
        };
        let mut acc = Cx::new(T::cst(0.0), T::cst(0.0));
        for (tau, p) in &self.terms {
            let v = Cx::new(horner(&p.even_jw()), om * horner(&p.odd_jw()));
            let v = if *tau == 0.0 {
                v
            } else {
                let th = om.scale(*tau);
                v * Cx::new(th.cos(), -th.sin())
            };
            acc = Cx::new(acc.re + v.re, acc.im + v.im);
        }
        acc
    }

    /// `(n, c_n, Σ_j d_j)`: the degree and leading coefficient of the delay-free part
    /// and the sum of the magnitudes of every other coefficient (all terms).
    fn cauchy(&self) -> (usize, f64, f64) {
        let p0 = self.p0();
        let n = p0.trimmed_deg();
        let cn = p0.c[n];
        let mut rest = 0.0;
        for (tau, p) in &self.terms {
            for (j, c) in p.coeffs().iter().enumerate() {
                if !(*tau == 0.0 && j == n) {
                    rest += c.abs();
                }
            }
        }
        (n, cn, rest)
    }

    /// Whether every delayed term has a lower degree than the delay-free part.
    fn retarded(&self) -> bool {
        let p0 = self.p0();
        if p0.is_zero() {
            return false;
        }
        let n = p0.trimmed_deg();
        self.terms
            .iter()
            .all(|(tau, p)| *tau == 0.0 || p.trimmed_deg() < n)
    }

    /// The sum of the coefficients' magnitudes over all terms.
    fn sum_abs(&self) -> f64 {
        self.terms
            .iter()
            .flat_map(|t| t.1.coeffs().iter().map(|c| c.abs()))
            .sum()
    }
}

/// The follower's loop with its structures, as quasi-polynomials (see the module doc).
#[derive(Debug, Clone)]
pub struct FollowerLoop {
    pub den: Quasi,
    pub num: Quasi,
    /// `(Den − Num) / s`.
    pub x: Quasi,
    /// Interval evaluations allowed per test.
    pub budget: usize,
}

fn cx_sub<T: Num>(a: Cx<T>, b: Cx<T>) -> Cx<T> {
    Cx::new(a.re - b.re, a.im - b.im)
}

/// `[a.lo, a.hi] / [b.lo, b.hi]` for `b.lo > 0`, rounded outwards.
fn div_pos(a: Iv, b: Iv) -> Iv {
    let q = [a.lo / b.lo, a.lo / b.hi, a.hi / b.lo, a.hi / b.hi];
    let lo = q.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = q.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    Iv::new(lo.next_down(), hi.next_up())
}

/// Outcome of a certified test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    Yes,
    No,
    Undecided,
}

impl FollowerLoop {
    /// The loop of the lower level `lin` with its outer terms `t` under the law `u`.
    pub fn new(lin: &Linear, t: &Terms, u: &UpperLin) -> Self {
        let nb = Poly::linear(lin.b1, lin.b0);
        let a = Poly::from_ascending(&[1.0, lin.a1, lin.a2]);
        let phi = if u.ff_gain != 0.0 {
            Poly::linear(u.ff_tau, 1.0)
        } else {
            Poly::constant(1.0)
        };
        let s = Poly::linear(1.0, 0.0);
        let m = Poly::linear(u.kv, u.kg)
            .mul(&phi)
            .add(&Poly::constant(u.ff_gain).shift(2));
        let td = lin.td;
        let tc = td + t.command_delay;
        let tp = tc + u.delay;
        let s_beta = Poly::linear(1.0, t.speed_feedback);
        let kgtg = u.kg * u.tg;
        // X = Φ (s + β) A − K s Nb Φ E + Nb E C (kg Tg Φ − ka s)
        let mut x = Quasi::default();
        x.push(0.0, phi.mul(&s_beta).mul(&a));
        x.push(td, s.mul(&nb).mul(&phi).scale(-lin.k));
        x.push(
            tc,
            nb.mul(&phi.scale(kgtg).sub(&Poly::linear(u.ff_gain, 0.0))),
        );
        let mut num = Quasi::default();
        num.push(tp, nb.mul(&m));
        let mut den = Quasi::default();
        for (tau, p) in &x.terms {
            den.push(*tau, p.shift(1));
        }
        den.push(tp, nb.mul(&m));
        Self {
            den,
            num,
            x,
            budget: DEFAULT_BUDGET,
        }
    }

    /// Certified local stability (`Yes`: every root of `Den` in the open left
    /// half-plane).
    pub fn local(&self) -> Verdict {
        if !self.den.retarded() {
            return Verdict::Undecided;
        }
        let d0 = self.den.eval(Iv::point(0.0));
        if d0.re.lo <= 0.0 && d0.re.hi >= 0.0 {
            // a root at (or numerically at) s = 0
            return if d0.re.lo == 0.0 && d0.re.hi == 0.0 {
                Verdict::No
            } else {
                Verdict::Undecided
            };
        }
        let (n, cn, rest) = self.den.cauchy();
        let wc = (1.01 * rest / cn.abs()).max(1.0);
        let mid = |z: Cx<Iv>| (0.5 * (z.re.lo + z.re.hi), 0.5 * (z.im.lo + z.im.hi));
        let point = |w: f64| mid(self.den.eval(Iv::point(w)));
        let mut edges = vec![0.0];
        let n0 = 64;
        let w_lo = wc * 1e-6;
        for i in 0..=n0 {
            edges.push(w_lo * (wc / w_lo).powf(i as f64 / n0 as f64));
        }
        *edges.last_mut().unwrap() = wc;
        let mut stack: Vec<(f64, f64)> = edges.windows(2).rev().map(|e| (e[0], e[1])).collect();
        let mut evals = 0usize;
        let mut dtheta = 0.0;
        while let Some((lo, hi)) = stack.pop() {
            evals += 1;
            if evals > self.budget {
                return Verdict::Undecided;
            }
            let z = self.den.eval(Iv::new(lo, hi));
            let holds_zero = z.re.lo <= 0.0 && z.re.hi >= 0.0 && z.im.lo <= 0.0 && z.im.hi >= 0.0;
            if !holds_zero && z.re.lo.is_finite() && z.im.hi.is_finite() {
                let (ar, ai) = point(lo);
                let (br, bi) = point(hi);
                // principal argument of b / a
                dtheta += (ar * bi - ai * br).atan2(ar * br + ai * bi);
                continue;
            }
            let m = 0.5 * (lo + hi);
            if m <= lo || m >= hi {
                return Verdict::Undecided;
            }
            stack.push((m, hi));
            stack.push((lo, m));
        }
        // the tail: Den = c_n (jω)^n (1 + r), |r| < 1 beyond ω_c
        let (er, ei) = point(wc);
        let lead = if cn > 0.0 { 0.0 } else { PI } + n as f64 * PI / 2.0;
        let (lr, li) = (lead.cos(), lead.sin());
        let rho = (lr * ei - li * er).atan2(lr * er + li * ei);
        if rho.abs() >= PI / 2.0 {
            return Verdict::Undecided;
        }
        // Δθ over [0, ∞): the sweep's change to ω_c, then the tail's −ρ(ω_c)
        let count = n as f64 / 2.0 - (dtheta - rho) / PI;
        let k = count.round();
        if (count - k).abs() > 0.25 || k < 0.0 {
            return Verdict::Undecided;
        }
        if k == 0.0 {
            Verdict::Yes
        } else {
            Verdict::No
        }
    }

    /// `g(ω) = (|Den|² − |Num|²)/ω²` enclosed over `om` (`om.lo >= 0`).
    pub fn g(&self, om: Iv) -> Iv {
        let xv = self.x.eval(om);
        let nv = self.num.eval(om);
        let x2 = xv.abs2();
        // q/ω: away from 0, q(piece) / piece; near 0 (by the mean-value theorem) within
        // the enclosure of q' over [0, ω_hi], intersected with the former when it exists
        let direct = (om.lo > 0.0).then(|| div_pos((xv * nv.conj()).im, om));
        let q_over = match direct {
            Some(d) if om.lo > 0.5 * om.hi => d,
            _ => {
                let w = DIv::var(Iv::new(0.0, om.hi));
                let qd = (self.x.eval(w) * self.num.eval(w).conj()).im.d;
                match direct {
                    Some(d) if d.lo.max(qd.lo) <= d.hi.min(qd.hi) => {
                        Iv::new(d.lo.max(qd.lo), d.hi.min(qd.hi))
                    }
                    _ => qd,
                }
            }
        };
        x2 - q_over.scale(2.0)
    }

    /// Certified string stability at a locally stable loop (`Yes`: `|H(jω)| < 1` for
    /// every `ω > 0`).
    pub fn string(&self) -> Verdict {
        let (_, cn, rest) = self.den.cauchy();
        let ws = (1.01 * (rest + self.num.sum_abs()) / cn.abs()).max(1.0);
        match sweep_positive(ws, self.budget, |w| self.g(w), |_, _, _| false) {
            Sweep::Positive => Verdict::Yes,
            Sweep::Negative => Verdict::No,
            Sweep::Undecided => Verdict::Undecided,
        }
    }

    /// The map code (0 locally unstable, 1 string unstable, 2 stable) and whether it is
    /// certified (an undecided local test gives 0, an undecided string test 1, both
    /// uncertified).
    pub fn code(&self) -> (u8, bool) {
        match self.local() {
            Verdict::Undecided => (LOCAL_UNSTABLE, false),
            Verdict::No => (LOCAL_UNSTABLE, true),
            Verdict::Yes => match self.string() {
                Verdict::Yes => (STABLE, true),
                Verdict::No => (STRING_UNSTABLE, true),
                Verdict::Undecided => (STRING_UNSTABLE, false),
            },
        }
    }

    /// `H(jω) = Num / Den` in plain floating point (for tests).
    pub fn h(&self, w: f64) -> nalgebra::Complex<f64> {
        let mid = |z: Cx<Iv>| {
            nalgebra::Complex::new(0.5 * (z.re.lo + z.re.hi), 0.5 * (z.im.lo + z.im.hi))
        };
        mid(self.num.eval(Iv::point(w))) / mid(self.den.eval(Iv::point(w)))
    }

    /// `Den − Num − s X` at `jω` (zero up to rounding; for tests).
    pub fn identity_residual(&self, w: f64) -> f64 {
        let om = Iv::point(w);
        let d = cx_sub(self.den.eval(om), self.num.eval(om));
        let xv = self.x.eval(om);
        // s X = jω X = (−ω X.im, ω X.re)
        let sx = Cx::new(-(om * xv.im), om * xv.re);
        let r = cx_sub(d, sx);
        r.re.lo
            .abs()
            .max(r.re.hi.abs())
            .max(r.im.lo.abs())
            .max(r.im.hi.abs())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::{linearize_terms, linearize_upper, EffectList, Operating};
    use crate::model::{CommandKind, ModelKind};
    use crate::sim::Upper;
    use crate::stability::delay::DelayLoop;

    fn rnd(s: &mut u64) -> f64 {
        *s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*s >> 11) as f64 / (1u64 << 53) as f64
    }

    const PROPOSED: [f64; 6] = [6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008];

    fn forms(effects: &[&str], p: &[f64], up: Upper, v: f64) -> (Linear, Terms, UpperLin) {
        let lin = ModelKind::Proposed.linear(&PROPOSED).unwrap();
        let list = EffectList::from_names(effects, CommandKind::Acceleration).unwrap();
        let effs = list.build(p, CommandKind::Acceleration).unwrap();
        let op = Operating { v, side: 0 };
        let (l, t) = linearize_terms(&lin, &effs, &op).unwrap();
        (l, t, linearize_upper(&up, &effs, &op).unwrap())
    }

    /// `s + k e^{−τs}` (k > 0) is stable iff `k τ < π/2`; `s² + 2 s + k e^{-τ s}` has
    /// its roots' count checked against the one-delay crossing argument.
    #[test]
    fn argument_principle_on_classic_equations() {
        for &(k, tau) in &[
            (1.0, 1.5),
            (1.0, 1.6),
            (2.0, 0.7),
            (2.0, 0.8),
            (0.5, 3.0),
            (0.5, 3.2),
        ] {
            let mut d = Quasi::default();
            d.push(0.0, Poly::linear(1.0, 0.0));
            d.push(tau, Poly::constant(k));
            let fl = FollowerLoop {
                den: d,
                num: Quasi::default(),
                x: Quasi::default(),
                budget: DEFAULT_BUDGET,
            };
            let want = if k * tau < PI / 2.0 {
                Verdict::Yes
            } else {
                Verdict::No
            };
            assert_eq!(fl.local(), want, "k {k} tau {tau}");
        }
        // two incommensurate delays: s + a e^{-τ1 s} + b e^{-τ2 s}; at τ2 = τ1 it is
        // the one-delay case with k = a + b
        for &(a, b, t1) in &[
            (0.6, 0.4, 1.5),
            (0.6, 0.4, 1.6),
            (1.0, 1.0, 0.7),
            (1.0, 1.0, 0.8),
        ] {
            let mut d = Quasi::default();
            d.push(0.0, Poly::linear(1.0, 0.0));
            d.push(t1, Poly::constant(a));
            d.push(t1 * (1.0 + 1e-9), Poly::constant(b));
            let fl = FollowerLoop {
                den: d,
                num: Quasi::default(),
                x: Quasi::default(),
                budget: DEFAULT_BUDGET,
            };
            let want = if (a + b) * t1 < PI / 2.0 {
                Verdict::Yes
            } else {
                Verdict::No
            };
            assert_eq!(fl.local(), want, "a {a} b {b} t1 {t1}");
        }
    }

    /// The quasi-polynomials hold the response: `Num/Den` is [`super::super::response`]
    /// and `Den − Num = s X`, for every structure with a small-signal form.
    #[test]
    fn quasi_polynomials_are_the_response() {
        let up = Upper {
            kg: 0.15,
            kv: 0.4,
            tg: 1.5,
            gmin: 3.0,
        };
        let cases: Vec<(Vec<&str>, Vec<f64>)> = vec![
            (vec![], vec![]),
            (vec!["perception"], vec![0.35]),
            (vec!["feedforward"], vec![0.6, 0.8]),
            (
                vec!["perception", "closing", "feedforward"],
                vec![0.3, 1.6, 1.3, 0.5, 0.7],
            ),
            (
                vec!["delay", "road_load", "perception", "speed_gains"],
                vec![0.2, 0.1, 0.01, 0.0005, 0.25, 0.02, 0.01],
            ),
        ];
        for (names, p) in cases {
            let (l, t, u) = forms(&names, &p, up, 20.0);
            let fl = FollowerLoop::new(&l, &t, &u);
            for &w in &[0.01, 0.2, 0.9, 3.0, 12.0] {
                let want = super::super::response(&l, &t, &u, w);
                let got = fl.h(w);
                assert!(
                    (got - want).norm() <= 1e-10 * want.norm().max(1.0),
                    "{names:?} {w}"
                );
                let scale = fl.den.eval(Iv::point(w)).abs2().hi.sqrt();
                assert!(
                    fl.identity_residual(w) <= 1e-12 * scale.max(1.0),
                    "{names:?} {w}"
                );
            }
            // g encloses (|Den|² − |Num|²)/ω² at points and over pieces
            for &w in &[0.02, 0.5, 2.0] {
                let d = fl.den.eval(Iv::point(w)).abs2();
                let n = fl.num.eval(Iv::point(w)).abs2();
                let direct = 0.5 * (d.lo + d.hi - n.lo - n.hi) / (w * w);
                let gi = fl.g(Iv::new(w * (1.0 - 1e-9), w * (1.0 + 1e-9)));
                let tol = 1e-8 * d.hi / (w * w);
                assert!(
                    gi.lo - tol <= direct && direct <= gi.hi + tol,
                    "{names:?} {w} {gi:?}"
                );
                let wide = fl.g(Iv::new(0.0, w));
                assert!(wide.lo <= gi.hi && gi.lo <= wide.hi);
            }
        }
    }

    /// Without structures the certified verdicts are the one-delay engine's
    /// ([`DelayLoop`]) wherever that one is certified.
    #[test]
    fn agrees_with_the_one_delay_engine() {
        let mut s = 17u64;
        let lin = ModelKind::Proposed.linear(&PROPOSED).unwrap();
        let dl = DelayLoop::new(&lin).unwrap();
        let mut counts = [0usize; 3];
        let mut n = 0;
        while n < 300 {
            let kg = 10f64.powf(rnd(&mut s) * 2.5 - 2.0);
            let tg = rnd(&mut s) * 12.0;
            let kv = rnd(&mut s) * 1.2 - 0.1;
            let (c1, ok1) = dl.code(kg, tg, kv);
            if !ok1 {
                continue;
            }
            let up = Upper {
                kg,
                kv,
                tg,
                gmin: 2.0,
            };
            let fl = FollowerLoop::new(&lin, &Terms::default(), &UpperLin::of(&up));
            let (c2, ok2) = fl.code();
            assert!(ok2, "undecided at {kg} {tg} {kv}");
            assert_eq!(c1, c2, "{kg} {tg} {kv}");
            counts[c1 as usize] += 1;
            n += 1;
        }
        assert!(counts.iter().all(|&c| c > 20), "{counts:?}");
    }

    /// A perception delay destabilises: the verdicts along a growing delay switch from
    /// stable to locally unstable once, and a zero delay is the base loop's verdict.
    #[test]
    fn perception_delay_is_decided_along_a_sweep() {
        let up = Upper {
            kg: 0.2,
            kv: 0.5,
            tg: 1.6,
            gmin: 3.0,
        };
        let mut last = 2u8;
        let mut switches = 0;
        for i in 0..60 {
            let tau = 0.05 * i as f64;
            let (l, t, u) = forms(&["perception"], &[tau], up, 20.0);
            let (c, ok) = FollowerLoop::new(&l, &t, &u).code();
            assert!(ok, "undecided at tau {tau}");
            if (c == 0) != (last == 0) {
                switches += 1;
            }
            last = c;
        }
        assert_eq!(last, 0, "a 3 s perception delay destabilises");
        assert_eq!(switches, 1);
    }
}
