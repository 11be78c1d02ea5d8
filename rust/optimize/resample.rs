//! Refits of resampled Eq. 6 costs, warm-started from the full-data optimum: the
//! second stage of a calibration that estimates its uncertainty (a block bootstrap
//! over time, or over whole runs, expressed as weights).
//!
//! A problem's runs are cut into *atoms* (consecutive stretches of a few seconds);
//! one rollout of a parameter row gives the weighted squared-error sum of every atom
//! ([`crate::sim::cost::run_atom_sums`]). A resample is a vector of atom
//! multiplicities (a moving-block bootstrap whose blocks start on atom boundaries
//! gives each atom the number of drawn blocks covering it; resampling whole runs
//! gives every atom its run's multiplicity), so its cost is a weighted sum of the
//! atom sums: no data is copied. Resample `b`'s Eq. 6 cost is the mean over runs of
//! the weighted MSE, each run counted with its effective multiplicity
//! `r_j = Σ_a w_a n_a / n_j`:
//!
//! `cost_b = Σ_j (Σ_{a∈j} w_a s_a) / n_j  /  Σ_j r_j`
//!
//! (with all weights 1 this is Eq. 6 over the problem's runs). Each resample is refit
//! by the GA's bounded Nelder–Mead ([`super::ga::local_search`]) in the GA's unit
//! coordinates from the full-data optimum; the resamples of a problem run in
//! parallel and share a cache of atom sums keyed by the parameter row (the first
//! simplex and the first moves are common to many resamples), which changes no value.
//! Nothing is random here (the weights are given), so the result is the same for any
//! number of threads.

use super::ga::{local_search, Bounds, Objective};
use crate::error::{AvllError, Result};
use crate::sim::cost::{n_atoms, residual_channels, run_atom_sums, run_residuals};
use crate::sim::{CostSpec, RunRef};
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// One problem to resample: its runs (index, multiplicity), the atom length of each
/// (samples), the full-data optimum `x0` and the `B x A` row-major resample weights
/// (`A` the total number of atoms of the runs, in their order).
#[derive(Debug, Clone)]
pub struct ResampleProblem {
    pub runs: Vec<(usize, f64)>,
    pub atom: Vec<usize>,
    pub x0: Vec<f64>,
    pub weights: Vec<f64>,
}

/// Settings of the refits.
#[derive(Debug, Clone, PartialEq)]
pub struct RefitOptions {
    /// Evaluation budget of each refit.
    pub budget: usize,
    /// Initial simplex step in unit coordinates (every coordinate).
    pub step: f64,
    /// A refit stops when its best value improved by at most `ftol * |best|` over the
    /// last `10 d` iterations.
    pub ftol: f64,
    /// Largest number of cached atom-sum rows per problem.
    pub cache_rows: usize,
    /// How each resample is refit.
    pub method: RefitMethod,
}

/// How each resample is refit from the full-data optimum.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RefitMethod {
    /// The GA's bounded Nelder–Mead ([`super::ga::local_search`]) on the resample's cost.
    Simplex,
    /// A bounded Levenberg–Marquardt iteration on the resample's weighted residuals
    /// ([`lm_refit`]): the cost is a weighted sum of squares, so Gauss–Newton steps
    /// from forward-difference Jacobians reach the minimum in far fewer rollouts.
    LevenbergMarquardt,
}

impl RefitMethod {
    /// `"simplex"` or `"lm"`.
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "simplex" => Ok(Self::Simplex),
            "lm" => Ok(Self::LevenbergMarquardt),
            _ => Err(AvllError::new(
                "method",
                format!("must be 'simplex' or 'lm', got {name:?}"),
            )),
        }
    }
}

impl Default for RefitOptions {
    fn default() -> Self {
        Self {
            budget: 0,
            step: 0.02,
            ftol: 1e-9,
            cache_rows: 4096,
            method: RefitMethod::Simplex,
        }
    }
}

/// The refit of one resample: parameters, resampled cost there and at `x0`,
/// evaluations, and whether it ran (`false`: skipped after a stop).
#[derive(Debug, Clone, PartialEq)]
pub struct Refit {
    pub x: Vec<f64>,
    pub f: f64,
    pub f_x0: f64,
    pub evaluations: usize,
    pub done: bool,
}

/// A problem's refits, its full-data cost at `x0` (from the atom sums) and how many
/// rollouts the cache saved.
#[derive(Debug, Clone, PartialEq)]
pub struct Resampled {
    pub refits: Vec<Refit>,
    pub f_full: f64,
    pub cache_hits: usize,
    pub rollouts: usize,
}

/// Atom sums per parameter row (its bits); `None` for a row whose cost is `inf`.
type Cache = Mutex<HashMap<Vec<u64>, Option<Arc<Vec<f64>>>>>;

/// Atom sums of a problem's runs, cached per parameter row.
struct Atoms<'a> {
    spec: &'a CostSpec,
    runs: Vec<&'a RunRef<'a>>,
    atom: Vec<usize>,
    /// Offsets of each run's atoms in a row of atom sums, and their sample counts.
    offsets: Vec<usize>,
    counts: Vec<f64>,
    lens: Vec<f64>,
    cache: Cache,
    cache_rows: usize,
    hits: std::sync::atomic::AtomicUsize,
    rollouts: std::sync::atomic::AtomicUsize,
    /// The atom of each entry of [`Atoms::residuals`].
    entry_atom: Vec<u32>,
}

impl Atoms<'_> {
    fn sums(&self, row: &[f64]) -> Option<Arc<Vec<f64>>> {
        let key: Vec<u64> = row.iter().map(|v| v.to_bits()).collect();
        if let Some(v) = self
            .cache
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&key)
        {
            self.hits.fetch_add(1, Ordering::Relaxed);
            return v.clone();
        }
        self.rollouts.fetch_add(1, Ordering::Relaxed);
        let total = *self.offsets.last().unwrap_or(&0);
        let mut out = vec![0.0; total];
        let mut ok = true;
        for (j, run) in self.runs.iter().enumerate() {
            let part = &mut out[self.offsets[j]..self.offsets[j + 1]];
            if !run_atom_sums(self.spec, row, run, self.atom[j], part) {
                ok = false;
                break;
            }
        }
        let v = ok.then(|| Arc::new(out));
        let mut c = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        if c.len() < self.cache_rows {
            c.insert(key, v.clone());
        }
        v
    }

    /// The weighted residuals of `row` on the problem's runs, run after run
    /// ([`run_residuals`]); `None` where the cost is `inf`. Entry `e` belongs to atom
    /// `self.entry_atom[e]`.
    fn residuals(&self, row: &[f64]) -> Option<Vec<f64>> {
        self.rollouts.fetch_add(1, Ordering::Relaxed);
        let mut all = vec![0.0; self.entry_atom.len()];
        let mut sums = vec![0.0; *self.offsets.last().unwrap_or(&0)];
        let nch = residual_channels(self.spec);
        let mut at = 0;
        for (j, run) in self.runs.iter().enumerate() {
            let part = &mut all[at..at + run.len() * nch];
            let s = &mut sums[self.offsets[j]..self.offsets[j + 1]];
            if !run_residuals(self.spec, row, run, self.atom[j], s, part) {
                return None;
            }
            at += run.len() * nch;
        }
        Some(all)
    }

    /// Resample cost of atom sums `s` under weights `w` (see the module doc).
    fn cost(&self, s: &[f64], w: &[f64]) -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        for j in 0..self.runs.len() {
            let (a, b) = (self.offsets[j], self.offsets[j + 1]);
            let mut sw = 0.0;
            let mut nw = 0.0;
            for q in a..b {
                sw += w[q] * s[q];
                nw += w[q] * self.counts[q];
            }
            num += sw / self.lens[j];
            den += nw / self.lens[j];
        }
        let c = num / den;
        if c.is_finite() {
            c
        } else {
            f64::INFINITY
        }
    }
}

/// The objective of one resample.
struct OneResample<'a, 'b> {
    atoms: &'b Atoms<'a>,
    w: &'b [f64],
}

impl Objective for OneResample<'_, '_> {
    fn eval(&self, x: &[f64]) -> f64 {
        match self.atoms.sums(x) {
            Some(s) => self.atoms.cost(&s, self.w),
            None => f64::INFINITY,
        }
    }

    /// The points of a simplex one after the other: the resamples already occupy
    /// the threads.
    fn eval_many(&self, xs: &[Vec<f64>], _bound: f64) -> Vec<f64> {
        xs.iter().map(|x| self.eval(x)).collect()
    }
}

/// Forward-difference step (unit coordinates) of the Levenberg–Marquardt Jacobians.
const LM_STEP: f64 = 1e-4;
/// Trial steps of a Levenberg–Marquardt refit at most (the evaluation budget caps it
/// first in practice).
const LM_ITERS: usize = 1000;

/// The Jacobian of the residuals `r` at unit point `z` (one column per parameter free
/// in the box, a forward difference of [`LM_STEP`] into the box; `None` for a column
/// whose both steps give a row that costs `inf`), with the indices of those parameters.
type Jacobian = (Vec<usize>, Vec<Option<Vec<f64>>>);

fn jacobian(atoms: &Atoms, bounds: &Bounds, z: &[f64], r: &[f64]) -> Jacobian {
    let free: Vec<usize> = (0..z.len())
        .filter(|&i| bounds.upper()[i] > bounds.lower()[i])
        .collect();
    let mut x = vec![0.0; z.len()];
    let cols = free
        .iter()
        .map(|&i| {
            let first = if z[i] + LM_STEP <= 1.0 {
                LM_STEP
            } else {
                -LM_STEP
            };
            [first, -first].into_iter().find_map(|h| {
                let mut zh = z.to_vec();
                zh[i] = (z[i] + h).clamp(0.0, 1.0);
                let hh = zh[i] - z[i];
                if hh == 0.0 {
                    return None;
                }
                bounds.to_user(&zh, &mut x);
                let rh = atoms.residuals(&x)?;
                Some(rh.iter().zip(r).map(|(a, b)| (a - b) / hh).collect())
            })
        })
        .collect();
    (free, cols)
}

/// Entries per block of [`weighted_gram`] (a multiple of 4): the block's weighted
/// columns and their products stay in the first-level cache.
const GRAM_BLOCK: usize = 256;

/// The weighted normal equations of columns `cols` and residuals `r` under entry
/// weights `w`: `H_kl = Σ_e w_e c_k[e] c_l[e]`, `g_k = Σ_e w_e c_k[e] r[e]`. Each sum
/// is [`dot`]`(w ∘ c_k, c_l)` to the bit (four interleaved partial sums, then the
/// entries past the last multiple of four), computed block by block of
/// [`GRAM_BLOCK`] entries so that one pass over the columns serves every pair:
/// a pair at a time over the whole columns streamed them from memory `d (d + 1)`
/// times, and that, not the rollouts, was most of a refit's time on long records.
#[inline(always)]
fn weighted_gram(cols: &[&[f64]], r: &[f64], w: &[f64]) -> (nalgebra::DMatrix<f64>, Vec<f64>) {
    let n = cols.len();
    let len = w.len();
    let body = len - len % 4;
    // Partial sums of the pairs (k, l >= k), then of g_k, in that order.
    let np = n * (n + 1) / 2;
    let mut acc = vec![[0.0f64; 4]; np + n];
    let mut wc = vec![[0.0f64; GRAM_BLOCK]; n];
    let mut start = 0;
    while start < body {
        let end = (start + GRAM_BLOCK).min(body);
        let m = end - start;
        for (o, c) in wc.iter_mut().zip(cols) {
            for (x, (a, b)) in o[..m]
                .iter_mut()
                .zip(w[start..end].iter().zip(&c[start..end]))
            {
                *x = a * b;
            }
        }
        let mut p = 0;
        for k in 0..n {
            let x = &wc[k][..m];
            for c in &cols[k..] {
                acc[p] = partial4(acc[p], x, &c[start..end]);
                p += 1;
            }
            acc[np + k] = partial4(acc[np + k], x, &r[start..end]);
        }
        start = end;
    }
    let finish = |s: [f64; 4], k: usize, y: &[f64]| -> f64 {
        let mut t = (s[0] + s[1]) + (s[2] + s[3]);
        for e in body..len {
            t += (w[e] * cols[k][e]) * y[e];
        }
        t
    };
    let mut h = nalgebra::DMatrix::zeros(n, n);
    let mut g = vec![0.0; n];
    let mut p = 0;
    for k in 0..n {
        for l in k..n {
            let v = finish(acc[p], k, cols[l]);
            h[(k, l)] = v;
            h[(l, k)] = v;
            p += 1;
        }
        g[k] = finish(acc[np + k], k, r);
    }
    (h, g)
}

/// The four interleaved partial sums of [`dot`] carried on over `a`, `b` (lengths a
/// multiple of 4).
#[inline(always)]
fn partial4(mut s: [f64; 4], a: &[f64], b: &[f64]) -> [f64; 4] {
    for (x, y) in a.chunks_exact(4).zip(b.chunks_exact(4)) {
        for i in 0..4 {
            s[i] += x[i] * y[i];
        }
    }
    s
}

/// `Σ a_i b_i` in four interleaved partial sums (the order [`weighted_gram`] keeps).
#[cfg(test)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut s = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for i in 0..4 {
            s[i] += x[i] * y[i];
        }
    }
    let mut t = (s[0] + s[1]) + (s[2] + s[3]);
    for (x, y) in ra.iter().zip(rb) {
        t += x * y;
    }
    t
}

/// The step `s` minimising `g·s + s·H·s / 2` within `lo <= s <= hi` (`H` symmetric
/// positive definite, `lo <= 0 <= hi`): projected Newton from 0 (the Newton step on the
/// coordinates not held at a face by the gradient, an Armijo search along the
/// projected path).
fn box_qp(g: &[f64], h: &nalgebra::DMatrix<f64>, lo: &[f64], hi: &[f64]) -> Vec<f64> {
    let n = g.len();
    let mut x = vec![0.0; n];
    let q = |v: &[f64]| -> f64 {
        let hv = h * nalgebra::DVector::from_column_slice(v);
        (0..n).map(|i| g[i] * v[i] + 0.5 * v[i] * hv[i]).sum()
    };
    let mut qx = 0.0;
    for _ in 0..100 {
        let hx = h * nalgebra::DVector::from_column_slice(&x);
        let grad: Vec<f64> = (0..n).map(|i| g[i] + hx[i]).collect();
        let f: Vec<usize> = (0..n)
            .filter(|&i| !((x[i] <= lo[i] && grad[i] > 0.0) || (x[i] >= hi[i] && grad[i] < 0.0)))
            .collect();
        if f.is_empty() {
            break;
        }
        let hf = nalgebra::DMatrix::from_fn(f.len(), f.len(), |a, b| h[(f[a], f[b])]);
        let rhs = nalgebra::DVector::from_iterator(f.len(), f.iter().map(|&i| -grad[i]));
        let Some(sol) = hf
            .clone()
            .cholesky()
            .map(|c| c.solve(&rhs))
            .or_else(|| hf.lu().solve(&rhs))
        else {
            break;
        };
        let mut dx = vec![0.0; n];
        for (k, &i) in f.iter().enumerate() {
            dx[i] = sol[k];
        }
        let mut t = 1.0;
        let mut moved = false;
        for _ in 0..40 {
            let xn: Vec<f64> = (0..n)
                .map(|i| (x[i] + t * dx[i]).clamp(lo[i], hi[i]))
                .collect();
            let qn = q(&xn);
            let slope: f64 = (0..n).map(|i| grad[i] * (xn[i] - x[i])).sum();
            if qn <= qx + 1e-4 * slope {
                moved = (0..n).any(|i| (xn[i] - x[i]).abs() > 1e-13);
                x = xn;
                qx = qn;
                break;
            }
            t *= 0.5;
        }
        if !moved {
            break;
        }
    }
    x
}

/// One resample refit by a bounded Levenberg–Marquardt iteration in the GA's unit
/// coordinates from the full-data optimum (`start`: its unit point, residuals and
/// Jacobian, shared by the resamples). The resample's cost is `Σ_e ω_e r_e²` over the
/// weighted residuals `r` ([`run_residuals`]) with `ω_e = w_a / n_run` for the atom
/// `a` of entry `e` (the module doc's numerator). Each iteration solves the damped
/// Gauss–Newton model (Marquardt's scaling by the curvature's diagonal) within the box
/// ([`box_qp`]) and keeps the step when one rollout shows that it lowers the cost; the
/// damping follows the ratio of the actual to the predicted decrease (Nielsen's rule).
/// Stops when an accepted step lowers the cost by at most `ftol` relative, when no
/// damping gives a lower cost, after [`LM_ITERS`] iterations or `budget` rollouts.
/// Returns the parameters, the resampled cost and the rollouts (those of the shared
/// start counted too, as the local search counts its own).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn lm_refit(
    atoms: &Atoms,
    bounds: &Bounds,
    start: &(Vec<f64>, Vec<f64>, Jacobian),
    w: &[f64],
    (x0, f0): (&[f64], f64),
    budget: usize,
    ftol: f64,
    stop: &AtomicBool,
) -> (Vec<f64>, f64, usize) {
    let (z0, r0, jac0) = start;
    // Per-atom weight of a squared residual, and the cost's denominator.
    let mut om = vec![0.0; w.len()];
    let mut den = 0.0;
    for j in 0..atoms.runs.len() {
        for q in atoms.offsets[j]..atoms.offsets[j + 1] {
            om[q] = w[q] / atoms.lens[j];
            den += w[q] * atoms.counts[q] / atoms.lens[j];
        }
    }
    let ea = &atoms.entry_atom;
    let we: Vec<f64> = ea.iter().map(|&q| om[q as usize]).collect();
    let sse = |r: &[f64]| -> f64 { r.iter().zip(&we).map(|(e, w)| w * e * e).sum() };
    let mut evals = 1 + jac0.1.len();
    let mut z = z0.clone();
    let mut r = r0.clone();
    let mut jac: std::borrow::Cow<Jacobian> = std::borrow::Cow::Borrowed(jac0);
    let mut s = sse(&r);
    let (mut mu, mut nu) = (1e-3, 2.0);
    let mut moved = false;
    let mut x = vec![0.0; z.len()];
    // `fresh`: the Jacobian is the finite-difference one at `z` (not a Broyden update).
    let (mut fresh, mut since) = (true, 0usize);
    let refresh_after = 2 * jac0.0.len().max(1);
    let mut trials = 0;
    'outer: while trials < LM_ITERS {
        if evals >= budget || stop.load(Ordering::Relaxed) || !(s.is_finite() && s > 0.0) {
            break;
        }
        let (free, cols) = &*jac;
        // The free parameters with a Jacobian column.
        let act: Vec<usize> = (0..free.len()).filter(|&k| cols[k].is_some()).collect();
        if act.is_empty() {
            break;
        }
        let n = act.len();
        // The weighted normal equations: H = Jᵀ Ω J, g = Jᵀ Ω r.
        let cs: Vec<&[f64]> = act.iter().filter_map(|&k| cols[k].as_deref()).collect();
        let (h, g) = weighted_gram(&cs, &r, &we);
        let dmax = (0..n).map(|k| h[(k, k)]).fold(0.0, f64::max);
        let lo: Vec<f64> = act.iter().map(|&k| -z[free[k]]).collect();
        let hi: Vec<f64> = act.iter().map(|&k| 1.0 - z[free[k]]).collect();
        let usable = dmax > 0.0 && g.iter().chain(h.iter()).all(|v| v.is_finite());
        let mut accepted = None;
        while usable && evals < budget && mu <= 1e12 && !stop.load(Ordering::Relaxed) {
            let mut hd = h.clone();
            for k in 0..n {
                hd[(k, k)] += mu * h[(k, k)].max(1e-12 * dmax);
            }
            let step = box_qp(&g, &hd, &lo, &hi);
            if step.iter().all(|v| v.abs() <= 1e-12) {
                break;
            }
            // predicted decrease of the sum of squares: -2 (g·s + s·H·s / 2)
            let hs = &h * nalgebra::DVector::from_column_slice(&step);
            let pred: f64 = -2.0
                * (0..n)
                    .map(|k| g[k] * step[k] + 0.5 * step[k] * hs[k])
                    .sum::<f64>();
            let mut zt = z.clone();
            for (k, &a) in act.iter().enumerate() {
                zt[free[a]] = (z[free[a]] + step[k]).clamp(0.0, 1.0);
            }
            bounds.to_user(&zt, &mut x);
            evals += 1;
            trials += 1;
            let (rt, st) = match atoms.residuals(&x) {
                Some(rt) => {
                    let st = sse(&rt);
                    (Some(rt), st)
                }
                None => (None, f64::INFINITY),
            };
            if let (Some(rt), true) = (rt, st < s) {
                let rho = if pred > 0.0 { (s - st) / pred } else { 1.0 };
                mu *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                nu = 2.0;
                accepted = Some((zt, rt, st));
                break;
            }
            if !fresh {
                // A rejected step on an updated Jacobian: recompute it before damping more.
                break;
            }
            mu *= nu;
            nu *= 2.0;
        }
        let Some((zt, rt, st)) = accepted else {
            if fresh {
                break;
            }
            let j = jacobian(atoms, bounds, &z, &r);
            evals += j.1.len();
            jac = std::borrow::Cow::Owned(j);
            (fresh, since) = (true, 0);
            continue 'outer;
        };
        let rel = (s - st) / s;
        if rel <= ftol && fresh {
            (z, s, moved) = (zt, st, true);
            break;
        }
        // Broyden's rank-one update of the Jacobian along the step (Madsen, Nielsen and
        // Tingleff, Methods for non-linear least squares problems, 2004, sec. 3.4),
        // recomputed by differences every `refresh_after` steps and when a step on the
        // updated one fails or gains almost nothing.
        since += 1;
        let refresh = rel <= ftol || since >= refresh_after;
        if refresh {
            let j = jacobian(atoms, bounds, &zt, &rt);
            evals += j.1.len();
            jac = std::borrow::Cow::Owned(j);
            (fresh, since) = (true, 0);
        } else {
            let dz: Vec<f64> = act.iter().map(|&k| zt[free[k]] - z[free[k]]).collect();
            let dd: f64 = dz.iter().map(|v| v * v).sum();
            if dd > 0.0 {
                let cols = &mut jac.to_mut().1;
                let mut u: Vec<f64> = rt.iter().zip(&r).map(|(p, q)| p - q).collect();
                for (k, &c) in act.iter().enumerate() {
                    if let Some(cv) = cols[c].as_deref() {
                        u.iter_mut().zip(cv).for_each(|(ui, ji)| *ui -= ji * dz[k]);
                    }
                }
                for (k, &c) in act.iter().enumerate() {
                    if let Some(cv) = cols[c].as_mut() {
                        let f = dz[k] / dd;
                        cv.iter_mut().zip(&u).for_each(|(ji, ui)| *ji += ui * f);
                    }
                }
            }
            fresh = false;
        }
        (z, r, s, moved) = (zt, rt, st, true);
    }
    let f = s / den;
    if !moved || f.is_nan() || f >= f0 {
        return (x0.to_vec(), f0, evals);
    }
    bounds.to_user(&z, &mut x);
    (x, f, evals)
}

/// Evaluations per parameter of a refit when `budget` is 0. The refits run until
/// their best value stalls (no relative gain above `ftol` over `10 d` iterations,
/// counted from the first improvement on the start); this is the cap. Refits of the
/// paper experiment's resamples (proposed model, 6 parameters) stall after 700-1,300
/// evaluations; a cap of `40 d` stopped them at a tenth of their parameters' spread.
pub const DEFAULT_BUDGET_PER_PARAM: usize = 200;

/// Refits every resample of every problem (problems in turn, each one's resamples in
/// parallel). `callback(problem, resamples_done)` runs after each refit; `false`
/// stops: the refits not started are returned with `done = false` (NaN values).
pub fn refit_resamples(
    spec: &CostSpec,
    runs: &[RunRef],
    problems: &[ResampleProblem],
    bounds: &Bounds,
    opts: &RefitOptions,
    callback: impl Fn(usize, usize) -> bool + Sync,
) -> Result<Vec<Resampled>> {
    spec.validate(runs)?;
    let d = bounds.dim();
    if d != spec.n_params() {
        return Err(AvllError::new(
            "bounds",
            format!("has {d} parameters, the cost needs {}", spec.n_params()),
        ));
    }
    if !(opts.step > 0.0 && opts.step <= 0.5) {
        return Err(AvllError::new(
            "step",
            format!("must be in (0, 0.5], got {}", opts.step),
        ));
    }
    crate::error::check_nonneg("ftol", opts.ftol)?;
    let budget = if opts.budget == 0 {
        DEFAULT_BUDGET_PER_PARAM * d
    } else {
        opts.budget
    };
    let stop = AtomicBool::new(false);
    let mut out = Vec::with_capacity(problems.len());
    for (k, p) in problems.iter().enumerate() {
        let name = |s: &str| format!("problems[{k}].{s}");
        if p.runs.is_empty() {
            return Err(AvllError::new(name("runs"), "has no runs"));
        }
        if p.atom.len() != p.runs.len() {
            return Err(AvllError::new(
                name("atom"),
                format!("has {} lengths for {} runs", p.atom.len(), p.runs.len()),
            ));
        }
        if p.x0.len() != d || p.x0.iter().any(|v| !v.is_finite()) {
            return Err(AvllError::new(
                name("x0"),
                format!("must hold {d} finite values"),
            ));
        }
        let mut offsets = vec![0usize];
        let mut counts = Vec::new();
        let mut lens = Vec::new();
        let mut refs = Vec::with_capacity(p.runs.len());
        for (&(j, m), &atom) in p.runs.iter().zip(&p.atom) {
            let run = runs.get(j).ok_or_else(|| {
                AvllError::new(
                    name("runs"),
                    format!(
                        "run index {j} is out of range (there are {} runs)",
                        runs.len()
                    ),
                )
            })?;
            if !(m.is_finite() && m > 0.0) {
                return Err(AvllError::new(
                    name("runs"),
                    format!("multiplicity {m} of run {j} must be > 0"),
                ));
            }
            if atom == 0 {
                return Err(AvllError::new(name("atom"), "lengths must be >= 1"));
            }
            let na = n_atoms(run.len(), atom);
            for q in 0..na {
                counts.push(((q + 1) * atom).min(run.len()) as f64 - (q * atom) as f64);
            }
            // The problem's multiplicity m divides the run's length: the run counts m times.
            lens.push(run.len() as f64 / m);
            offsets.push(offsets.last().unwrap() + na);
            refs.push(run);
        }
        let a = *offsets.last().unwrap();
        if p.weights.is_empty() || p.weights.len() % a != 0 {
            return Err(AvllError::new(
                name("weights"),
                format!(
                    "must be B x {a} (the runs' atoms), got {} values",
                    p.weights.len()
                ),
            ));
        }
        if p.weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(AvllError::new(name("weights"), "must be finite and >= 0"));
        }
        let b = p.weights.len() / a;
        let atoms = Atoms {
            spec,
            runs: refs,
            atom: p.atom.clone(),
            offsets,
            counts,
            lens,
            cache: Mutex::new(HashMap::new()),
            cache_rows: opts.cache_rows,
            hits: 0.into(),
            rollouts: 0.into(),
            entry_atom: Vec::new(),
        };
        let mut atoms = atoms;
        if opts.method == RefitMethod::LevenbergMarquardt {
            let chans = residual_channels(spec);
            let mut ea = Vec::new();
            for (j, run) in atoms.runs.iter().enumerate() {
                for t in 0..run.len() {
                    let q = (atoms.offsets[j] + t / atoms.atom[j]) as u32;
                    ea.extend(std::iter::repeat_n(q, chans));
                }
            }
            atoms.entry_atom = ea;
        }
        // The optimum as the unit coordinates give it back (log scales round).
        let mut x0 = vec![0.0; d];
        bounds.to_user(&bounds.to_unit(&p.x0), &mut x0);
        let ones = vec![1.0; a];
        let f_full = OneResample {
            atoms: &atoms,
            w: &ones,
        }
        .eval(&x0);
        let done_count = std::sync::atomic::AtomicUsize::new(0);
        // Levenberg–Marquardt: the residuals and Jacobian at the optimum, common to
        // every resample.
        let lm_start = (opts.method == RefitMethod::LevenbergMarquardt && f_full.is_finite())
            .then(|| {
                let z0 = bounds.to_unit(&x0);
                let r0 = atoms.residuals(&x0)?;
                let jac = jacobian(&atoms, bounds, &z0, &r0);
                Some((z0, r0, jac))
            })
            .flatten();
        let steps = vec![opts.step; d];
        let window = 10 * d;
        let refits: Vec<Refit> = (0..b)
            .into_par_iter()
            .map(|i| {
                let skipped = || Refit {
                    x: vec![f64::NAN; d],
                    f: f64::NAN,
                    f_x0: f64::NAN,
                    evaluations: 0,
                    done: false,
                };
                if stop.load(Ordering::Relaxed) {
                    return skipped();
                }
                let f = OneResample {
                    atoms: &atoms,
                    w: &p.weights[i * a..(i + 1) * a],
                };
                let f0 = f.eval(&x0);
                // The stall window counts from the first improvement on the start: from
                // the full-data optimum the first simplexes are all worse until they have
                // shrunk to the resample's displacement, and a window counted from the
                // start stopped refits there, at the start itself.
                let mut hist: Vec<f64> = Vec::new();
                let (x, fx, evals) = if let (Some(st), true) = (&lm_start, f0.is_finite()) {
                    let w = &p.weights[i * a..(i + 1) * a];
                    if crate::sim::fma() {
                        // SAFETY: the CPU has AVX2 and FMA (checked just above). The
                        // iteration's sums and updates then run four wide; nothing
                        // contracts a product and a sum into one rounding, so every
                        // value is the same as without.
                        unsafe {
                            crate::sim::with_fma(
                                #[inline(always)]
                                || {
                                    lm_refit(
                                        &atoms,
                                        bounds,
                                        st,
                                        w,
                                        (&x0, f0),
                                        budget,
                                        opts.ftol,
                                        &stop,
                                    )
                                },
                            )
                        }
                    } else {
                        lm_refit(&atoms, bounds, st, w, (&x0, f0), budget, opts.ftol, &stop)
                    }
                } else if f0.is_finite() {
                    local_search(&f, bounds, &x0, f0, &steps, budget, |_, fb| {
                        if fb >= f0 {
                            return !stop.load(Ordering::Relaxed);
                        }
                        hist.push(fb);
                        let n = hist.len();
                        let stalled =
                            n > window && hist[n - 1 - window] - fb <= opts.ftol * fb.abs();
                        !(stalled || stop.load(Ordering::Relaxed))
                    })
                } else {
                    (x0.clone(), f0, 0)
                };
                let n = done_count.fetch_add(1, Ordering::Relaxed) + 1;
                if !callback(k, n) {
                    stop.store(true, Ordering::Relaxed);
                }
                Refit {
                    x,
                    f: fx,
                    f_x0: f0,
                    evaluations: evals + 1,
                    done: true,
                }
            })
            .collect();
        out.push(Resampled {
            refits,
            f_full,
            cache_hits: atoms.hits.load(Ordering::Relaxed),
            rollouts: atoms.rollouts.load(Ordering::Relaxed),
        });
        if stop.load(Ordering::Relaxed) {
            // The problems not started: every refit skipped.
            for q in problems.iter().skip(k + 1) {
                let a: usize = q
                    .runs
                    .iter()
                    .zip(&q.atom)
                    .map(|(&(j, _), &at)| runs.get(j).map_or(0, |r| n_atoms(r.len(), at.max(1))))
                    .sum();
                let b = q.weights.len().checked_div(a).unwrap_or(0);
                out.push(Resampled {
                    refits: (0..b)
                        .map(|_| Refit {
                            x: vec![f64::NAN; d],
                            f: f64::NAN,
                            f_x0: f64::NAN,
                            evaluations: 0,
                            done: false,
                        })
                        .collect(),
                    f_full: f64::NAN,
                    cache_hits: 0,
                    rollouts: 0,
                });
            }
            break;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optimize::ga::Scale;
    use crate::sim::cost::run_cost;
    use crate::sim::{Init, Upper};

    fn data() -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        let lin = crate::model::ModelKind::SecondOrder
            .linear(&[1.0, 0.3, 0.8, 0.2])
            .unwrap();
        let (mut us, mut ys) = (Vec::new(), Vec::new());
        for r in 0..2 {
            let u: Vec<f64> = (0..1200)
                .map(|k| ((0.02 * k as f64) + r as f64).sin() + 0.3 * (0.11 * k as f64).cos())
                .collect();
            let mut y = crate::sim::simulate(&lin, &u, 0.1, Init::Rest).unwrap();
            for (k, v) in y.iter_mut().enumerate() {
                *v += 0.05 * ((k * 7919 + r * 104729) as f64).sin();
            }
            us.push(u);
            ys.push(y);
        }
        (us, ys)
    }

    fn refs<'a>(us: &'a [Vec<f64>], ys: &'a [Vec<f64>]) -> Vec<RunRef<'a>> {
        us.iter()
            .zip(ys)
            .map(|(u, y)| RunRef {
                dt: 0.1,
                command: Some(u),
                lead_x: None,
                lead_v: None,
                a: y,
                v: None,
                x: None,
                upper: Upper {
                    kg: 0.5,
                    kv: 0.0,
                    tg: 2.0,
                    gmin: 9.5,
                },
                exo: vec![],
            })
            .collect()
    }

    fn spec() -> CostSpec {
        CostSpec::linear(
            crate::model::ModelKind::SecondOrder,
            crate::model::CommandKind::Acceleration,
            [1.0, 0.0, 0.0],
            Init::Rest,
            false,
            vec![],
        )
    }

    fn bounds() -> Bounds {
        Bounds::new(
            vec![0.1, 1e-3, 1e-3, 0.0],
            vec![10.0, 10.0, 10.0, 2.0],
            vec![Scale::Log, Scale::Log, Scale::Log, Scale::Linear],
        )
        .unwrap()
    }

    /// Both runs in atoms of 40 samples, `b` resamples: 0 all ones, the others
    /// pseudo-random multiplicities; the start near the truth.
    fn problem(runs: &[RunRef], b: usize) -> ResampleProblem {
        let atom = 40;
        let a: usize = runs.iter().map(|r| n_atoms(r.len(), atom)).sum();
        let mut w = vec![1.0; a];
        for i in 1..b {
            w.extend((0..a).map(|q| ((q * 31 + i * 17) % 3) as f64));
        }
        ResampleProblem {
            runs: vec![(0, 1.0), (1, 1.0)],
            atom: vec![atom, atom],
            x0: vec![1.05, 0.28, 0.85, 0.18],
            weights: w,
        }
    }

    #[test]
    fn atom_sums_add_up_to_the_run_cost() {
        let (us, ys) = data();
        let runs = refs(&us, &ys);
        let sp = spec();
        for atom in [1, 7, 50, 5000] {
            let row = [1.1, 0.25, 0.9, 0.15];
            let mut out = vec![0.0; n_atoms(runs[0].len(), atom)];
            assert!(run_atom_sums(&sp, &row, &runs[0], atom, &mut out));
            let total: f64 = out.iter().sum::<f64>() / runs[0].len() as f64;
            let c = run_cost(&sp, &row, &runs[0], f64::INFINITY);
            assert!((total - c).abs() <= 1e-12 * c, "{total} vs {c}");
        }
        // An unstable row: no sums.
        let mut out = vec![0.0; n_atoms(runs[0].len(), 10)];
        assert!(!run_atom_sums(
            &sp,
            &[1.0, 1.0, -1.0, 0.0],
            &runs[0],
            10,
            &mut out
        ));
    }

    #[test]
    fn unit_weights_give_the_full_cost_and_refits_do_not_depend_on_threads() {
        let (us, ys) = data();
        let runs = refs(&us, &ys);
        let sp = spec();
        let b = bounds();
        let p = problem(&runs, 6);
        let x0 = p.x0.clone();
        let o = RefitOptions {
            budget: 300,
            ..Default::default()
        };
        let go = |t: usize| {
            crate::parallel::with_threads(t, || {
                refit_resamples(&sp, &runs, std::slice::from_ref(&p), &b, &o, |_, _| true)
            })
            .unwrap()
            .unwrap()
        };
        let (r1, r2) = (go(1), go(2));
        // The values; the cache's counts depend on the threads' timing.
        assert_eq!(r1[0].refits, r2[0].refits);
        assert_eq!(r1[0].f_full.to_bits(), r2[0].f_full.to_bits());
        let r = &r1[0];
        let mut xr = vec![0.0; 4];
        b.to_user(&b.to_unit(&x0), &mut xr);
        let full = (run_cost(&sp, &xr, &runs[0], f64::INFINITY)
            + run_cost(&sp, &xr, &runs[1], f64::INFINITY))
            / 2.0;
        assert!((r.f_full - full).abs() <= 1e-12 * full);
        assert!((r.refits[0].f_x0 - full).abs() <= 1e-12 * full);
        for f in &r.refits {
            assert!(f.done && f.f <= f.f_x0, "{f:?}");
        }
        // The all-ones refit moves towards the truth.
        let e0: f64 = x0
            .iter()
            .zip([1.0, 0.3, 0.8, 0.2])
            .map(|(a, t)| (a - t).abs())
            .sum();
        let e1: f64 = r.refits[0]
            .x
            .iter()
            .zip([1.0, 0.3, 0.8, 0.2])
            .map(|(a, t)| (a - t).abs())
            .sum();
        assert!(e1 < e0, "{e1} vs {e0}");
        assert!(r.cache_hits > 0);
        // A stop after the first refit skips the rest.
        let stopped =
            refit_resamples(&sp, &runs, std::slice::from_ref(&p), &b, &o, |_, _| false).unwrap();
        assert!(stopped[0].refits.iter().any(|f| !f.done));
    }

    #[test]
    fn the_blocked_gram_is_the_pairwise_dots_to_the_bit() {
        for (len, n) in [
            (0, 2),
            (1, 1),
            (3, 3),
            (255, 4),
            (256, 10),
            (257, 2),
            (1031, 7),
        ] {
            let f = |k: usize, e: usize| ((k * 7919 + e * 104_729) % 1000) as f64 / 37.0 - 13.0;
            let cols: Vec<Vec<f64>> = (0..n)
                .map(|k| (0..len).map(|e| f(k, e)).collect())
                .collect();
            let w: Vec<f64> = (0..len).map(|e| 0.5 + f(99, e).abs()).collect();
            let r: Vec<f64> = (0..len).map(|e| f(7, e) * 1e-3).collect();
            let cs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
            let (h, g) = weighted_gram(&cs, &r, &w);
            for k in 0..n {
                let wc: Vec<f64> = w.iter().zip(&cols[k]).map(|(a, b)| a * b).collect();
                for l in k..n {
                    let want = dot(&wc, &cols[l]).to_bits();
                    assert_eq!(h[(k, l)].to_bits(), want, "{len} {k} {l}");
                    assert_eq!(h[(l, k)].to_bits(), want);
                }
                assert_eq!(g[k].to_bits(), dot(&wc, &r).to_bits(), "{len} g{k}");
            }
        }
    }

    #[test]
    fn levenberg_marquardt_reaches_the_simplex_minimum_in_fewer_rollouts() {
        let (us, ys) = data();
        let runs = refs(&us, &ys);
        let sp = spec();
        let b = bounds();
        let p = problem(&runs, 8);
        let go = |method| {
            let o = RefitOptions {
                method,
                ..Default::default()
            };
            refit_resamples(&sp, &runs, std::slice::from_ref(&p), &b, &o, |_, _| true)
                .unwrap()
                .remove(0)
        };
        let (nm, lm) = (
            go(RefitMethod::Simplex),
            go(RefitMethod::LevenbergMarquardt),
        );
        assert_eq!(nm.f_full.to_bits(), lm.f_full.to_bits());
        let (mut e_nm, mut e_lm) = (0usize, 0usize);
        for (s, l) in nm.refits.iter().zip(&lm.refits) {
            assert!(l.done && l.f <= l.f_x0 && l.f_x0 == s.f_x0, "{l:?}");
            // the same minimum (LM at most 1e-6 above; often below)
            assert!(l.f <= s.f * (1.0 + 1e-6), "lm {} vs simplex {}", l.f, s.f);
            // and the same parameters, to the cost's resolution
            let zs = b.to_unit(&s.x);
            let zl = b.to_unit(&l.x);
            let dz = zs
                .iter()
                .zip(&zl)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f64::max);
            assert!(dz < 2e-3, "{:?} vs {:?}", s.x, l.x);
            e_nm += s.evaluations;
            e_lm += l.evaluations;
        }
        assert!(2 * e_lm < e_nm, "lm {e_lm} vs simplex {e_nm} evaluations");
        // the residuals' squares are the atom sums
        let row = [1.1, 0.25, 0.9, 0.15];
        let n = runs[0].len();
        let (mut r, mut sums) = (vec![0.0; n], vec![0.0; n_atoms(n, 7)]);
        assert!(run_residuals(&sp, &row, &runs[0], 7, &mut sums, &mut r));
        let sse: f64 = r.iter().map(|e| e * e).sum();
        let c = run_cost(&sp, &row, &runs[0], f64::INFINITY) * n as f64;
        assert!((sse - c).abs() <= 1e-10 * c, "{sse} vs {c}");
        let first: f64 = r[..7].iter().map(|e| e * e).sum();
        assert!((first - sums[0]).abs() <= 1e-12 * sums[0]);
        let bad = [1.0, 1.0, -1.0, 0.0];
        assert!(!run_residuals(&sp, &bad, &runs[0], 7, &mut sums, &mut r));
        assert!(RefitMethod::from_name("newton").is_err());
    }
}
