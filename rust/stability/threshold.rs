//! Thresholds: the kv threshold on a grid (bisection with an early-exit "is anything
//! stable" test), and the continuous extrema of a boundary surface — the minimum
//! stable Tg over a (kg, kv) box (an infimum) and the largest stable kv over a
//! (kg, Tg) box (a supremum).
//!
//! The extrema are found by nested 1-D searches of the boundary
//! ([`super::boundary`]): for the minimum stable Tg, an outer search over kv of the
//! inner minimum over kg of the smallest stable Tg. Each 1-D search scans
//! `n_grid` points (log-spaced for kg > 0) and refines the best local minima of the
//! scan by golden section to `xtol` of the range. Where nothing is stable the
//! boundary is `+inf`, so a minimum at the edge of the stable set (the tip of a
//! stable region that closes, as for the proposed model) is approached from the
//! stable side. The value returned is a boundary value at a point that the search
//! reached: an upper bound of the true infimum (a lower bound of the supremum) that
//! the search could not improve; a local minimum narrower than the scan spacing
//! can be missed, which the tests check against dense grids.

use super::boundary::{first_stable, last_stable, Axis, PointTest, Scan};
use crate::error::{AvllError, Result};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

/// True when some point of the `kg × tg` grid at `kv` has a code `>= level`; stops at
/// the first such point (parallel, with a shared flag).
pub fn any_stable<T: PointTest + ?Sized>(
    test: &T,
    kg: &[f64],
    tg: &[f64],
    kv: f64,
    level: u8,
) -> bool {
    let n = kg.len() * tg.len();
    let ntg = tg.len();
    let found = AtomicBool::new(false);
    (0..n).into_par_iter().with_min_len(256).any(|i| {
        if found.load(Ordering::Relaxed) {
            return true;
        }
        let ok = test.code(kg[i / ntg], tg[i % ntg], kv) >= level;
        if ok {
            found.store(true, Ordering::Relaxed);
        }
        ok
    })
}

/// The kv beyond which no grid point is stable, by bisection between `kv_lo` (some
/// point stable) and `kv_hi` (none) down to `tol` (the midpoint of the last bracket).
pub fn kv_threshold_grid<T: PointTest + ?Sized>(
    test: &T,
    kg: &[f64],
    tg: &[f64],
    kv_lo: f64,
    kv_hi: f64,
    tol: f64,
) -> Result<f64> {
    if !(tol > 0.0 && tol.is_finite()) {
        return Err(AvllError::new(
            "tol",
            format!("must be finite and > 0, got {tol}"),
        ));
    }
    let (mut lo, mut hi) = (kv_lo, kv_hi);
    if !any_stable(test, kg, tg, lo, super::STABLE) {
        return Err(AvllError::new(
            "kv_lo",
            format!("nothing is stable at kv = {lo}"),
        ));
    }
    if any_stable(test, kg, tg, hi, super::STABLE) {
        return Err(AvllError::new(
            "kv_hi",
            format!("some point is still stable at kv = {hi}"),
        ));
    }
    while hi - lo > tol {
        let mid = 0.5 * (lo + hi);
        if any_stable(test, kg, tg, mid, super::STABLE) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(0.5 * (lo + hi))
}

/// A box `[lo, hi]` of one parameter, searched in log space when `log`.
#[derive(Debug, Clone, Copy)]
pub struct Range {
    pub lo: f64,
    pub hi: f64,
    pub log: bool,
}

impl Range {
    fn at_unit(&self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        let v = if self.log {
            (self.lo.ln() + u * (self.hi / self.lo).ln()).exp()
        } else {
            self.lo + u * (self.hi - self.lo)
        };
        if u == 0.0 {
            self.lo
        } else if u == 1.0 {
            self.hi
        } else {
            v
        }
    }
}

/// Options of the 2-D search.
#[derive(Debug, Clone, Copy)]
pub struct Search {
    /// Scan points of each 1-D search.
    pub n_grid: usize,
    /// Local minima of a scan refined by golden section.
    pub starts: usize,
    /// Final bracket of a golden-section refinement, as a fraction of the range (in
    /// the search space).
    pub xtol: f64,
}

impl Default for Search {
    fn default() -> Self {
        Self {
            n_grid: 32,
            starts: 3,
            xtol: 1e-12,
        }
    }
}

/// An extremum of a boundary surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extremum {
    /// The extreme boundary value (NaN when nothing is stable anywhere).
    pub value: f64,
    /// `[kg, tg, kv]` where it is reached (the boundary coordinate equal to `value`).
    pub at: [f64; 3],
    /// The boundary value is the end of the searched range of its axis (stable there).
    pub value_at_range_end: bool,
    /// Each of the two box coordinates is at an end of its range.
    pub on_box_edge: [bool; 2],
    /// Boundary evaluations used.
    pub evaluations: usize,
}

/// Minimum of `f` (`+inf` = infeasible) over the unit interval: a scan of `n` points,
/// then golden section on the bracket around each of the `starts` best local minima of
/// the scan. Golden section also converges onto a minimum at the edge of the feasible
/// set (where `f` jumps to `+inf`). Returns `(value, u, evaluations)`.
fn min1d<F: Fn(f64) -> f64 + Sync>(f: F, opt: &Search) -> (f64, f64, usize) {
    let n = opt.n_grid.max(3);
    let xs: Vec<f64> = (0..n).map(|i| i as f64 / (n - 1) as f64).collect();
    let vs: Vec<f64> = xs.par_iter().map(|&x| f(x)).collect();
    let mut evals = n;
    let mut cand: Vec<usize> = (0..n)
        .filter(|&i| {
            vs[i].is_finite()
                && (i == 0 || vs[i] <= vs[i - 1])
                && (i + 1 == n || vs[i] <= vs[i + 1])
        })
        .collect();
    cand.sort_by(|&a, &b| vs[a].total_cmp(&vs[b]));
    cand.truncate(opt.starts.max(1));
    let (mut best, mut bx) = (f64::INFINITY, f64::NAN);
    if let Some(i) = (0..n)
        .filter(|&i| vs[i].is_finite())
        .min_by(|&a, &b| vs[a].total_cmp(&vs[b]))
    {
        best = vs[i];
        bx = xs[i];
    }
    let refined: Vec<(f64, f64, usize)> = cand
        .par_iter()
        .map(|&i| {
            let (mut a, mut b) = (xs[i.saturating_sub(1)], xs[(i + 1).min(n - 1)]);
            let (mut vb, mut xb) = (vs[i], xs[i]);
            let gr = (5f64.sqrt() - 1.0) / 2.0;
            let mut c = b - gr * (b - a);
            let mut d = a + gr * (b - a);
            let (mut fc, mut fd) = (f(c), f(d));
            let mut k = 2;
            while b - a > opt.xtol && k < 400 {
                if fc < fd || (fc == fd && fc.is_infinite() && xb < c) {
                    b = d;
                    d = c;
                    fd = fc;
                    c = b - gr * (b - a);
                    fc = f(c);
                } else {
                    a = c;
                    c = d;
                    fc = fd;
                    d = a + gr * (b - a);
                    fd = f(d);
                }
                k += 1;
                for (v, x) in [(fc, c), (fd, d)] {
                    if v < vb {
                        vb = v;
                        xb = x;
                    }
                }
            }
            (vb, xb, k)
        })
        .collect();
    for (v, x, k) in refined {
        evals += k;
        if v < best {
            best = v;
            bx = x;
        }
    }
    (best, bx, evals)
}

/// Nested 2-D search of `f(u, w)` (None = nothing stable) for its minimum (`sign = 1`)
/// or maximum (`sign = -1`): the outer 1-D search over `w` minimises the inner 1-D
/// search over `u`.
fn search2<F>(f: F, ru: Range, rw: Range, opt: &Search, sign: f64) -> (f64, f64, f64, bool, usize)
where
    F: Fn(f64, f64) -> Option<(f64, bool)> + Sync,
{
    use std::sync::atomic::AtomicUsize;
    let count = AtomicUsize::new(0);
    let key = |r: Option<(f64, bool)>| r.map_or(f64::INFINITY, |(v, _)| sign * v);
    let inner = |w: f64| {
        let (v, u, k) = min1d(|x| key(f(ru.at_unit(x), w)), opt);
        count.fetch_add(k, Ordering::Relaxed);
        (v, u)
    };
    let (_, wx, _) = min1d(|y| inner(rw.at_unit(y)).0, opt);
    let w = rw.at_unit(wx);
    let (_, ux) = inner(w);
    let u = ru.at_unit(ux);
    let r = f(u, w);
    match r {
        None => (f64::NAN, f64::NAN, f64::NAN, false, count.into_inner()),
        Some((v, e)) => (v, u, w, e, count.into_inner() + 1),
    }
}

fn check_range(name: &str, r: &Range) -> Result<()> {
    if !(r.lo.is_finite() && r.hi.is_finite() && r.lo <= r.hi) {
        return Err(AvllError::new(
            name,
            format!("need finite lo <= hi, got ({}, {})", r.lo, r.hi),
        ));
    }
    if r.log && r.lo <= 0.0 {
        return Err(AvllError::new(
            name,
            format!("a log-searched range needs lo > 0, got {}", r.lo),
        ));
    }
    Ok(())
}

/// The infimum of the stable Tg over `kg × kv` (Tg searched in `tg`).
pub fn min_stable_tg<T: PointTest + ?Sized>(
    test: &T,
    kg: Range,
    kv: Range,
    tg: Range,
    scan: &Scan,
    opt: &Search,
) -> Result<Extremum> {
    check_range("kg_range", &kg)?;
    check_range("kv_range", &kv)?;
    check_range("tg_range", &tg)?;
    let f = |g: f64, v: f64| first_stable(test, Axis::Tg, [g, 0.0, v], tg.lo, tg.hi, scan);
    let (value, g, v, edge, evaluations) = search2(f, kg, kv, opt, 1.0);
    let on = |r: &Range, x: f64| x == r.lo || x == r.hi;
    Ok(Extremum {
        value,
        at: [g, value, v],
        value_at_range_end: edge,
        on_box_edge: [on(&kg, g), on(&kv, v)],
        evaluations,
    })
}

/// The supremum of the stable kv over `kg × tg` (kv searched in `kv`).
pub fn max_stable_kv<T: PointTest + ?Sized>(
    test: &T,
    kg: Range,
    tg: Range,
    kv: Range,
    scan: &Scan,
    opt: &Search,
) -> Result<Extremum> {
    check_range("kg_range", &kg)?;
    check_range("tg_range", &tg)?;
    check_range("kv_range", &kv)?;
    let f = |g: f64, t: f64| last_stable(test, Axis::Kv, [g, t, 0.0], kv.lo, kv.hi, scan);
    let (value, g, t, edge, evaluations) = search2(f, kg, tg, opt, -1.0);
    let on = |r: &Range, x: f64| x == r.lo || x == r.hi;
    Ok(Extremum {
        value,
        at: [g, t, value],
        value_at_range_end: edge,
        on_box_edge: [on(&kg, g), on(&tg, t)],
        evaluations,
    })
}

impl Range {
    /// Checked constructor.
    pub fn new(lo: f64, hi: f64, log: bool) -> Range {
        Range { lo, hi, log }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ModelKind;
    use crate::stability::LoopModel;

    fn proposed() -> LoopModel {
        let l = ModelKind::Proposed
            .linear(&[6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008])
            .unwrap();
        LoopModel::new(&l, 2).unwrap()
    }

    #[test]
    fn min_tg_is_below_every_grid_point_and_stable() {
        let lm = proposed();
        let scan = Scan::default();
        let e = min_stable_tg(
            &lm,
            Range::new(1e-3, 2.0, true),
            Range::new(0.0, 1.2, false),
            Range::new(0.0, 15.0, false),
            &scan,
            &Search::default(),
        )
        .unwrap();
        let [kg, tg, kv] = e.at;
        assert_eq!(lm.classify(kg, tg, kv), 2);
        assert_ne!(lm.classify(kg, tg * (1.0 - 1e-8), kv), 2);
        // a dense grid finds nothing stable below it
        for i in 0..120 {
            let kg = 1e-3 * (2000f64).powf(i as f64 / 119.0);
            for j in 0..121 {
                let kv = 1.2 * j as f64 / 120.0;
                for k in 0..200 {
                    let t = e.value * k as f64 / 200.0;
                    assert_ne!(lm.classify(kg, t, kv), 2, "{kg} {t} {kv} below {}", e.value);
                }
            }
        }
    }

    #[test]
    fn kv_threshold_grid_matches_a_plain_loop() {
        let lm = proposed();
        let kg: Vec<f64> = (0..60)
            .map(|i| 1e-3 * 5000f64.powf(i as f64 / 59.0))
            .collect();
        let tg: Vec<f64> = (0..61).map(|i| 15.0 * i as f64 / 60.0).collect();
        let thr = kv_threshold_grid(&lm, &kg, &tg, 0.5, 1.0, 1e-6).unwrap();
        let any = |v: f64| {
            kg.iter()
                .any(|&g| tg.iter().any(|&t| lm.classify(g, t, v) == 2))
        };
        assert!(any(thr - 1e-6) && !any(thr + 1e-6));
        assert!(kv_threshold_grid(&lm, &kg, &tg, 0.95, 1.0, 1e-6).is_err());
    }
}
