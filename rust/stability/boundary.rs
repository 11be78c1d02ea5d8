//! Stability boundaries computed directly: the stable set along one parameter axis
//! (kg, Tg or kv, the other two fixed) as a union of intervals whose ends are found
//! by bracketing and bisection on the exact point test.
//!
//! Along any of the three axes the characteristic polynomial is affine,
//! `D = D0 + t D1` (`D = M s² + kv s Ga + kg (Tg s + 1) Ga`), so a root crosses the
//! imaginary axis only where `D0(jω) + t D1(jω) = 0` has a real solution `t`
//! (D-subdivision): at `ω = 0` (`t = −D0(0)/D1(0)`) and at the positive roots
//! `x = ω²` of `O0 E1 − E0 O1` (the `jω` even/odd parts), with
//! `t = −E0/E1 = −O0/O1`. These values are computed from the polynomial roots
//! ([`super::roots`]). The string polynomial `R` is quadratic in the parameter, so
//! the values where `R(0)` or its leading coefficient vanish are solved for as
//! well. Every such candidate `c` enters the scan together with `c (1 ± 1e-7)`.
//!
//! Between candidates the verdict can change only where `R` gains or loses a
//! positive double root; those events are found by the scan itself (`n_scan`
//! points, log-spaced for a positive kg axis, linear otherwise). A stable or
//! unstable stretch narrower than the scan spacing that does not start at a
//! candidate can therefore be missed; every boundary that is found is refined by
//! bisection on the exact test until the bracket is below `rtol` relative, and
//! the reported end is the stable side of the bracket (a point that the exact test
//! calls stable, with an unstable point within `rtol`).

use super::poly::Poly;
use super::{routh, LoopModel};

/// The parameter that varies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    Kg,
    Tg,
    Kv,
}

impl Axis {
    /// From 0 (kg), 1 (Tg), 2 (kv).
    pub fn from_index(i: usize) -> Option<Axis> {
        match i {
            0 => Some(Axis::Kg),
            1 => Some(Axis::Tg),
            2 => Some(Axis::Kv),
            _ => None,
        }
    }
}

/// A point test: the stability code (0, 1, 2) at `(kg, tg, kv)`, and optionally the
/// exact values along an axis at which the code can change.
pub trait PointTest: Sync {
    /// The code at one point.
    fn code(&self, kg: f64, tg: f64, kv: f64) -> u8;
    /// Pushes candidate boundary values in `(lo, hi)` along `axis` through `p`.
    fn candidates(&self, _axis: Axis, _p: [f64; 3], _lo: f64, _hi: f64, _out: &mut Vec<f64>) {}
}

impl PointTest for LoopModel {
    #[inline]
    fn code(&self, kg: f64, tg: f64, kv: f64) -> u8 {
        self.classify(kg, tg, kv)
    }

    fn candidates(&self, axis: Axis, p: [f64; 3], lo: f64, hi: f64, out: &mut Vec<f64>) {
        let (d0, d1) = self.affine_d(axis, p);
        local_crossings(&d0, &d1, lo, hi, out);
        // R(x; t) is quadratic in t: coefficient k is A_k + B_k t + C_k t^2.
        let at = |t: f64| {
            let mut q = p;
            q[axis as usize] = t;
            self.string_poly_fast(q[0], q[1], q[2])
        };
        let (r0, r1, rm) = (at(0.0), at(1.0), at(-1.0));
        let deg = r0.deg.max(r1.deg).max(rm.deg);
        let quad = |k: usize| {
            let a = r0.c[k];
            let b = 0.5 * (r1.c[k] - rm.c[k]);
            let c = 0.5 * (r1.c[k] + rm.c[k]) - a;
            (a, b, c)
        };
        for k in [0, 1, deg] {
            let (a, b, c) = quad(k);
            for t in solve_quadratic(c, b, a) {
                if t > lo && t < hi {
                    out.push(t);
                }
            }
        }
    }
}

/// Real solutions of `a t² + b t + c = 0` (any of the coefficients may be 0).
fn solve_quadratic(a: f64, b: f64, c: f64) -> Vec<f64> {
    let scale = a.abs().max(b.abs()).max(c.abs());
    if scale == 0.0 || !scale.is_finite() {
        return Vec::new();
    }
    if a.abs() <= 1e-14 * scale {
        if b.abs() <= 1e-14 * scale {
            return Vec::new();
        }
        return vec![-c / b];
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return Vec::new();
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    let mut v = vec![q / a];
    if q != 0.0 {
        v.push(c / q);
    }
    v
}

/// D-subdivision of `D0 + t D1`: the values of `t` in `(lo, hi)` at which a root of
/// the polynomial lies on the imaginary axis.
pub fn local_crossings(d0: &Poly, d1: &Poly, lo: f64, hi: f64, out: &mut Vec<f64>) {
    let mut push = |t: f64| {
        if t.is_finite() && t > lo && t < hi {
            out.push(t);
        }
    };
    if d1.c[0] != 0.0 {
        push(-d0.c[0] / d1.c[0]);
    }
    // leading coefficient vanishing (degree drop)
    let n1 = d1.trimmed_deg();
    if n1 >= d0.trimmed_deg() && d1.c[n1] != 0.0 {
        push(-d0.c[n1] / d1.c[n1]);
    }
    let (e0, o0) = (d0.even_jw(), d0.odd_jw());
    let (e1, o1) = (d1.even_jw(), d1.odd_jw());
    let f = o0.mul(&e1).sub(&e0.mul(&o1));
    if f.is_zero() {
        return;
    }
    for x in super::roots::positive_roots(&f) {
        let (ve1, vo1) = (e1.eval(x), o1.eval(x));
        let t = if ve1.abs() >= vo1.abs() * x.sqrt() {
            -e0.eval(x) / ve1
        } else {
            -o0.eval(x) / vo1
        };
        push(t);
    }
}

impl LoopModel {
    /// `D = D0 + t D1` along `axis` at the point `p = [kg, tg, kv]` (the entry of the
    /// varying parameter is ignored).
    pub fn affine_d(&self, axis: Axis, p: [f64; 3]) -> (Poly, Poly) {
        let [kg, tg, kv] = p;
        let ms2 = self.m.shift(2);
        let sga = self.ga.shift(1);
        match axis {
            Axis::Kg => (ms2.add(&sga.scale(kv)), sga.scale(tg).add(&self.ga)),
            Axis::Tg => (
                ms2.add(&sga.scale(kv)).add(&self.ga.scale(kg)),
                sga.scale(kg),
            ),
            Axis::Kv => (ms2.add(&sga.scale(kg * tg)).add(&self.ga.scale(kg)), sga),
        }
    }

    /// Local stability only (Routh–Hurwitz on `D`).
    #[inline]
    pub fn locally_stable(&self, kg: f64, tg: f64, kv: f64) -> bool {
        routh::hurwitz(&self.char_poly(kg, tg, kv))
    }
}

/// How an axis is scanned.
#[derive(Debug, Clone, Copy)]
pub struct Scan {
    /// Scan points over the range (besides the candidates).
    pub n: usize,
    /// Log-spaced scan (needs `lo > 0`).
    pub log: bool,
    /// Relative width of a refined bracket.
    pub rtol: f64,
    /// A point counts as stable when its code is at least this (2: local and
    /// string stable; 1: locally stable).
    pub level: u8,
    /// Add the exact candidates of the point test to the scan.
    pub candidates: bool,
}

impl Default for Scan {
    fn default() -> Self {
        Self {
            n: 256,
            log: false,
            rtol: 1e-10,
            level: super::STABLE,
            candidates: true,
        }
    }
}

/// One interval of the stable set along an axis. `lo`/`hi` are stable points of the
/// exact test; `lo_edge`/`hi_edge` say whether the end is the end of the searched
/// range (stable there) rather than a boundary.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    pub lo: f64,
    pub hi: f64,
    pub lo_edge: bool,
    pub hi_edge: bool,
}

#[inline]
fn at(p: [f64; 3], axis: Axis, t: f64) -> [f64; 3] {
    let mut q = p;
    q[axis as usize] = t;
    q
}

#[inline]
fn stable_at<T: PointTest + ?Sized>(test: &T, p: [f64; 3], axis: Axis, t: f64, level: u8) -> bool {
    let q = at(p, axis, t);
    test.code(q[0], q[1], q[2]) >= level
}

/// Bisects the bracket `(a, b)` with `stable(a) != stable(b)`; returns the final
/// `(a, b)` (same orientation), `|b − a| <= rtol max(|a|, |b|)` or adjacent floats.
#[allow(clippy::too_many_arguments)]
fn refine<T: PointTest + ?Sized>(
    test: &T,
    p: [f64; 3],
    axis: Axis,
    mut a: f64,
    mut b: f64,
    level: u8,
    rtol: f64,
    log: bool,
) -> (f64, f64) {
    let sa = stable_at(test, p, axis, a, level);
    let floor = 1e-300f64;
    for _ in 0..400 {
        let width = (b - a).abs();
        if width <= rtol * a.abs().max(b.abs()).max(floor) {
            break;
        }
        let m = if log && a > 0.0 && b > 0.0 && (a / b > 4.0 || b / a > 4.0) {
            (a * b).sqrt()
        } else {
            0.5 * (a + b)
        };
        if m == a || m == b {
            break;
        }
        if stable_at(test, p, axis, m, level) == sa {
            a = m;
        } else {
            b = m;
        }
    }
    (a, b)
}

/// The scan points over `[lo, hi]` (sorted, unique), with the test's candidates.
pub fn scan_points<T: PointTest + ?Sized>(
    test: &T,
    axis: Axis,
    p: [f64; 3],
    lo: f64,
    hi: f64,
    scan: &Scan,
) -> Vec<f64> {
    let n = scan.n.max(2);
    let mut pts = Vec::with_capacity(n + 16);
    let log = scan.log && lo > 0.0;
    for i in 0..n {
        let f = i as f64 / (n - 1) as f64;
        let t = if log {
            (lo.ln() + f * (hi / lo).ln()).exp()
        } else {
            lo + f * (hi - lo)
        };
        pts.push(t);
    }
    pts[0] = lo;
    pts[n - 1] = hi;
    if scan.candidates {
        let mut c = Vec::new();
        test.candidates(axis, p, lo, hi, &mut c);
        for t in c {
            for f in [1.0 - 1e-7, 1.0, 1.0 + 1e-7] {
                let u = t * f;
                if u > lo && u < hi {
                    pts.push(u);
                }
            }
        }
    }
    pts.sort_by(f64::total_cmp);
    pts.dedup();
    pts
}

/// The stable set along `axis` within `[lo, hi]` as intervals, ascending.
pub fn stable_intervals<T: PointTest + ?Sized>(
    test: &T,
    axis: Axis,
    p: [f64; 3],
    lo: f64,
    hi: f64,
    scan: &Scan,
) -> Vec<Interval> {
    let pts = scan_points(test, axis, p, lo, hi, scan);
    let st: Vec<bool> = pts
        .iter()
        .map(|&t| stable_at(test, p, axis, t, scan.level))
        .collect();
    let mut out = Vec::new();
    let mut cur: Option<(f64, bool)> = if st[0] { Some((lo, true)) } else { None };
    for i in 1..pts.len() {
        if st[i] == st[i - 1] {
            continue;
        }
        let (a, b) = refine(
            test,
            p,
            axis,
            pts[i - 1],
            pts[i],
            scan.level,
            scan.rtol,
            scan.log,
        );
        if st[i] {
            // unstable a -> stable b: an interval starts at b
            cur = Some((b, false));
        } else if let Some((s, e)) = cur.take() {
            out.push(Interval {
                lo: s,
                hi: a,
                lo_edge: e,
                hi_edge: false,
            });
        }
    }
    if let Some((s, e)) = cur {
        out.push(Interval {
            lo: s,
            hi,
            lo_edge: e,
            hi_edge: true,
        });
    }
    out
}

/// Infimum of the stable set along `axis` within `[lo, hi]` (the stable side of a
/// bracket narrower than `rtol`), with `true` when it is `lo` itself; `None` when no
/// scan point is stable. Scans upward and stops at the first stable point.
pub fn first_stable<T: PointTest + ?Sized>(
    test: &T,
    axis: Axis,
    p: [f64; 3],
    lo: f64,
    hi: f64,
    scan: &Scan,
) -> Option<(f64, bool)> {
    let pts = scan_points(test, axis, p, lo, hi, scan);
    let mut prev: Option<f64> = None;
    for &t in &pts {
        if stable_at(test, p, axis, t, scan.level) {
            return Some(match prev {
                None => (t, true),
                Some(u) => (
                    refine(test, p, axis, u, t, scan.level, scan.rtol, scan.log).1,
                    false,
                ),
            });
        }
        prev = Some(t);
    }
    None
}

/// Supremum of the stable set along `axis` within `[lo, hi]`, with `true` when it is
/// `hi` itself; `None` when no scan point is stable. Scans downward.
pub fn last_stable<T: PointTest + ?Sized>(
    test: &T,
    axis: Axis,
    p: [f64; 3],
    lo: f64,
    hi: f64,
    scan: &Scan,
) -> Option<(f64, bool)> {
    let pts = scan_points(test, axis, p, lo, hi, scan);
    let mut prev: Option<f64> = None;
    for &t in pts.iter().rev() {
        if stable_at(test, p, axis, t, scan.level) {
            return Some(match prev {
                None => (t, true),
                Some(u) => (
                    refine(test, p, axis, u, t, scan.level, scan.rtol, scan.log).1,
                    false,
                ),
            });
        }
        prev = Some(t);
    }
    None
}

/// Which end of the stable set a boundary surface reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    /// The infimum (e.g. the smallest stable Tg).
    Inf,
    /// The supremum (e.g. the largest stable kg).
    Sup,
}

/// A boundary surface: for every `(u[i], w[j])` of the two fixed parameters (in
/// ascending axis order, e.g. `(kg, kv)` when `axis` is Tg), the infimum or supremum
/// of the stable set along `axis` within `[lo, hi]` (NaN where no point is stable).
/// Row-major `(len(u), len(w))`; parallel over the points.
#[allow(clippy::too_many_arguments)]
pub fn surface<T: PointTest + ?Sized>(
    test: &T,
    axis: Axis,
    u: &[f64],
    w: &[f64],
    lo: f64,
    hi: f64,
    end: End,
    scan: &Scan,
    out: &mut [f64],
) {
    use rayon::prelude::*;
    let (iu, iw) = match axis {
        Axis::Kg => (1, 2),
        Axis::Tg => (0, 2),
        Axis::Kv => (0, 1),
    };
    let nw = w.len();
    out.par_iter_mut().enumerate().for_each(|(k, o)| {
        let mut p = [0.0; 3];
        p[iu] = u[k / nw];
        p[iw] = w[k % nw];
        let r = match end {
            End::Inf => first_stable(test, axis, p, lo, hi, scan),
            End::Sup => last_stable(test, axis, p, lo, hi, scan),
        };
        *o = r.map_or(f64::NAN, |(v, _)| v);
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ModelKind;
    use crate::stability::LoopModel;

    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn models(order: usize) -> Vec<LoopModel> {
        [
            (ModelKind::FirstOrder, vec![1.0758]),
            (ModelKind::SecondOrder, vec![0.7292, 0.0445, 0.1305, 0.7796]),
            (
                ModelKind::Proposed,
                vec![6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008],
            ),
        ]
        .iter()
        .map(|(k, p)| LoopModel::new(&k.linear(p).unwrap(), order).unwrap())
        .collect()
    }

    fn inside(ivs: &[Interval], t: f64) -> bool {
        ivs.iter().any(|iv| t >= iv.lo && t <= iv.hi)
    }

    fn near_end(ivs: &[Interval], t: f64, rel: f64) -> bool {
        ivs.iter().any(|iv| {
            (t - iv.lo).abs() <= rel * iv.lo.abs().max(1e-12)
                || (t - iv.hi).abs() <= rel * iv.hi.abs().max(1e-12)
        })
    }

    /// Along each axis the intervals agree with a dense grid of the exact test (2001
    /// points; grid points within 1e-6 relative of an end are not judged), ends are
    /// stable and a point 1e-8 outside an inner end is not.
    #[test]
    fn intervals_agree_with_dense_grids() {
        let mut r = Lcg(17);
        let mut checked = 0;
        for order in [2, 5] {
            for lm in models(order) {
                for _ in 0..30 {
                    let p = [
                        10f64.powf(r.next() * 2.5 - 2.0),
                        r.next() * 12.0,
                        r.next() * 0.9,
                    ];
                    for (axis, lo, hi, log) in [
                        (Axis::Kg, 1e-3, 3.0, true),
                        (Axis::Tg, 0.0, 15.0, false),
                        (Axis::Kv, -0.5, 1.5, false),
                    ] {
                        for level in [1u8, 2] {
                            let scan = Scan {
                                log,
                                level,
                                ..Scan::default()
                            };
                            let ivs = stable_intervals(&lm, axis, p, lo, hi, &scan);
                            for iv in &ivs {
                                assert!(stable_at(&lm, p, axis, iv.lo, level));
                                assert!(stable_at(&lm, p, axis, iv.hi, level));
                                if !iv.lo_edge {
                                    assert!(!stable_at(
                                        &lm,
                                        p,
                                        axis,
                                        iv.lo - 1e-8 * iv.lo.abs().max(1e-3),
                                        level
                                    ));
                                }
                                if !iv.hi_edge {
                                    assert!(!stable_at(
                                        &lm,
                                        p,
                                        axis,
                                        iv.hi + 1e-8 * iv.hi.abs().max(1e-3),
                                        level
                                    ));
                                }
                            }
                            let n = 2001;
                            for i in 0..n {
                                let f = i as f64 / (n - 1) as f64;
                                let t = if log {
                                    lo * (hi / lo).powf(f)
                                } else {
                                    lo + f * (hi - lo)
                                };
                                if near_end(&ivs, t, 1e-6) {
                                    continue;
                                }
                                assert_eq!(
                                    stable_at(&lm, p, axis, t, level),
                                    inside(&ivs, t),
                                    "{axis:?} level {level} p {p:?} t {t} {ivs:?}"
                                );
                                checked += 1;
                            }
                            // first/last agree with the intervals
                            let f = first_stable(&lm, axis, p, lo, hi, &scan);
                            let l = last_stable(&lm, axis, p, lo, hi, &scan);
                            assert_eq!(f.map(|x| x.0), ivs.first().map(|iv| iv.lo));
                            assert_eq!(l.map(|x| x.0), ivs.last().map(|iv| iv.hi));
                        }
                    }
                }
            }
        }
        assert!(checked > 1_000_000);
    }

    /// Local stability changes only at the D-subdivision values: with no scan points
    /// besides the range ends, the locally stable intervals still match a dense grid.
    #[test]
    fn d_subdivision_alone_finds_every_local_boundary() {
        let mut r = Lcg(3);
        let mut found = 0;
        for order in [1, 2, 4, 8] {
            for lm in models(order) {
                for _ in 0..40 {
                    let p = [
                        10f64.powf(r.next() * 2.5 - 2.0),
                        r.next() * 12.0,
                        r.next() * 1.5 - 0.3,
                    ];
                    for (axis, lo, hi) in [
                        (Axis::Kg, 1e-4, 5.0),
                        (Axis::Tg, 0.0, 15.0),
                        (Axis::Kv, -1.0, 2.0),
                    ] {
                        let scan = Scan {
                            n: 2,
                            level: 1,
                            ..Scan::default()
                        };
                        let ivs = stable_intervals(&lm, axis, p, lo, hi, &scan);
                        found += ivs.iter().filter(|iv| !iv.lo_edge || !iv.hi_edge).count();
                        for i in 0..1001 {
                            let t = lo + (hi - lo) * i as f64 / 1000.0;
                            if near_end(&ivs, t, 1e-6) {
                                continue;
                            }
                            assert_eq!(
                                stable_at(&lm, p, axis, t, 1),
                                inside(&ivs, t),
                                "{axis:?} {p:?} {t} {ivs:?}"
                            );
                        }
                    }
                }
            }
        }
        assert!(found > 100, "{found}");
    }
}
