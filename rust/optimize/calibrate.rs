//! The one calibration driver: the GA ([`super::ga::minimize`]) on the Eq. 6 cost
//! (paper Section III.B) of any [`CostSpec`] — linear or with effects, open or
//! closed loop, acceleration or speed command, with exogenous signals — over a run
//! (multi)set, one problem or many solved in parallel. Every result carries the
//! per-run costs of its best parameters, so nothing is re-simulated to fill a table.

use super::ga::{
    derive_seed, minimize, Bounds, GaOptions, GaResult, Objective, Progress, Survival,
};
use crate::error::{AvllError, Result};
use crate::sim::cost::{
    by_delay, lane_plants, lane_run, lanes_apply, run_groups, run_lanes, run_lanes_group,
    LanePlants, LANES,
};
use crate::sim::{run_cost, CostSpec, RunRef};
use rayon::prelude::*;

/// Eq. 6 over a (multi)set of runs: the weighted mean of the per-run costs over
/// `weights` (run index, multiplicity), evaluated in parallel and summed in a fixed
/// order; `inf` if any run's cost is.
pub fn subset_cost(spec: &CostSpec, row: &[f64], runs: &[RunRef], weights: &[(usize, f64)]) -> f64 {
    combine(&run_costs(spec, row, runs, weights, true), weights)
}

/// The run costs of `row` on the runs of `weights` (in that order), exactly
/// [`run_cost`] each: runs sharing `dt` and length are stepped together through the
/// lanes ([`run_lanes_group`]); when `par`, one share of the runs per thread.
fn run_costs(
    spec: &CostSpec,
    row: &[f64],
    runs: &[RunRef],
    weights: &[(usize, f64)],
    par: bool,
) -> Vec<f64> {
    let sel: Vec<&RunRef> = weights.iter().map(|&(j, _)| &runs[j]).collect();
    if !sel.iter().all(|r| lanes_apply(spec, r)) {
        // No lanes (closed loop, effects, ...): one task per run.
        let one = |r: &&RunRef| run_cost(spec, row, r, f64::INFINITY);
        return if par {
            sel.par_iter().map(one).collect()
        } else {
            sel.iter().map(one).collect()
        };
    }
    let threads = rayon::current_num_threads();
    if par && threads > 1 {
        // One contiguous share of the runs per thread, each share through its own lane
        // groups: e.g. 10 runs on 2 threads go as two shares of 5 runs (each one group
        // of five lanes, see `run_lanes`), not as the
        // lane groups (4), (4), (2), of which one thread would step two. The values do
        // not depend on the grouping.
        let (n, k) = (sel.len(), threads.min(sel.len()));
        let shares: Vec<std::ops::Range<usize>> =
            (0..k).map(|i| i * n / k..(i + 1) * n / k).collect();
        let parts: Vec<Vec<f64>> = shares
            .par_iter()
            .map(|r| run_lanes(spec, row, &sel[r.clone()], &vec![f64::INFINITY; r.len()]))
            .collect();
        return parts.concat();
    }
    let groups = run_groups(&sel);
    let one = |g: &Vec<usize>| {
        let rs: Vec<&RunRef> = g.iter().map(|&q| sel[q]).collect();
        run_lanes_group(spec, row, &rs, &vec![f64::INFINITY; rs.len()])
    };
    let parts: Vec<Vec<f64>> = if par {
        groups.par_iter().map(one).collect()
    } else {
        groups.iter().map(one).collect()
    };
    let mut out = vec![f64::INFINITY; sel.len()];
    for (g, cs) in groups.iter().zip(parts) {
        for (&q, c) in g.iter().zip(cs) {
            out[q] = c;
        }
    }
    out
}

/// The weighted mean of per-run costs (fixed summation order).
fn combine(costs: &[f64], weights: &[(usize, f64)]) -> f64 {
    let total: f64 = weights.iter().map(|w| w.1).sum();
    let s = costs.iter().zip(weights).fold(0.0, |s, (c, w)| s + c * w.1);
    let m = s / total;
    if m.is_finite() {
        m
    } else {
        f64::INFINITY
    }
}

/// Eq. 6 over a weighted set of runs, with early abandoning: an offspring's runs
/// are rolled out one after the other, each with the bound on its weighted sum of
/// squared errors that the GA's survival threshold leaves.
struct Eq6<'a> {
    spec: &'a CostSpec,
    runs: &'a [RunRef<'a>],
    w: Vec<(usize, f64)>,
    total: f64,
    /// Whether a single point's runs are evaluated in parallel. Off when independent
    /// problems (starts) already occupy the threads: a point's run groups are too
    /// small to be worth a rendezvous of threads (and on a loaded machine each one
    /// waits for a descheduled thread). Values do not depend on it.
    par: bool,
}

impl Objective for Eq6<'_> {
    fn eval(&self, x: &[f64]) -> f64 {
        combine(
            &run_costs(self.spec, x, self.runs, &self.w, self.par),
            &self.w,
        )
    }

    /// A closed loop must be locally stable on every run of the problem (the spec is
    /// relaxed for the search: see [`CostSpec::relaxed`]).
    fn admissible(&self, x: &[f64]) -> bool {
        !self.spec.closed_loop
            || self
                .w
                .iter()
                .all(|&(j, _)| !self.spec.locally_unstable(x, &self.runs[j]))
    }

    /// The same per-run costs as [`subset_cost`] and the same combination (so an
    /// unabandoned value is bit-identical); `inf` once the partial sums prove the
    /// result `>= bound`.
    fn eval_bounded(&self, x: &[f64], bound: f64) -> f64 {
        let mut done = 0.0; // sum of w_j c_j over finished runs
        let mut costs = Vec::with_capacity(self.w.len());
        for &(j, wj) in &self.w {
            let run = &self.runs[j];
            // c_j = S_j / n_j; abandon once done + wj S_j / n_j >= bound * total.
            let limit = (bound * self.total - done) * run.len() as f64 / wj;
            let c = run_cost(self.spec, x, run, limit);
            if !c.is_finite() {
                return f64::INFINITY;
            }
            done += wj * c;
            costs.push(c);
        }
        combine(&costs, &self.w)
    }

    /// Offspring in groups of [`LANES`] stepped together through the lane kernel
    /// (the linear second-order open-loop acceleration cost; any other cost is
    /// evaluated point by point), in parallel over groups. Each value is bit-identical
    /// to `eval`/`eval_bounded` of the point alone (same per-run costs, same
    /// abandoning checks, same combination), whatever the grouping or the threads.
    fn eval_many(&self, xs: &[Vec<f64>], bound: f64) -> Vec<f64> {
        self.in_groups(xs, &|| bound, &|_| ())
    }

    /// [`Eq6::eval_many`] at the shared survival bound, read again before each run
    /// of a group; each value is offered as soon as it is known.
    fn eval_offspring(&self, xs: &[Vec<f64>], survival: &Survival) -> Vec<f64> {
        self.in_groups(xs, &|| survival.bound(), &|v| survival.offer(v))
    }
}

impl Eq6<'_> {
    /// `xs` in groups of [`LANES`] through [`Eq6::lane_group`] (point by point where
    /// the lanes do not apply), in parallel over groups, each at the value `bound`
    /// gives when it is read; every value is passed to `offer` once known.
    fn in_groups(
        &self,
        xs: &[Vec<f64>],
        bound: &(dyn Fn() -> f64 + Sync),
        offer: &(dyn Fn(f64) + Sync),
    ) -> Vec<f64> {
        // Grouped in the order of their dead time where the lanes apply (see
        // `by_delay`: same values, faster groups), the values returned in `xs`'s order.
        let given: Vec<&[f64]> = xs.iter().map(|x| x.as_slice()).collect();
        let order: Vec<usize> = match self.w.first().map(|&(j, _)| &self.runs[j]) {
            Some(run) if lanes_apply(self.spec, run) => by_delay(self.spec, &given, run),
            _ => (0..xs.len()).collect(),
        };
        let rows: Vec<&[f64]> = order.iter().map(|&q| given[q]).collect();
        let groups = rows.len().div_ceil(LANES);
        let one = |g: usize| -> Vec<f64> {
            let rs = &rows[g * LANES..((g + 1) * LANES).min(rows.len())];
            if let Some(vs) = self.lane_group(rs, bound) {
                vs.iter().for_each(|&v| offer(v));
                return vs;
            }
            rs.iter()
                .map(|x| {
                    let b = bound();
                    let v = if b.is_finite() {
                        self.eval_bounded(x, b)
                    } else {
                        self.eval(x)
                    };
                    offer(v);
                    v
                })
                .collect()
        };
        let parts: Vec<Vec<f64>> = (0..groups).into_par_iter().map(one).collect();
        let mut out = vec![f64::INFINITY; xs.len()];
        for (&q, v) in order.iter().zip(parts.concat()) {
            out[q] = v;
        }
        out
    }

    /// Up to [`LANES`] rows through the lane kernel, run after run with each row's
    /// own abandoning limit (as [`Eq6::eval_bounded`]) at the value `bound` gives
    /// before each run; `None` when the lane path does not apply. The plants are
    /// discretized once per distinct `dt`.
    fn lane_group(&self, rows: &[&[f64]], bound: impl Fn() -> f64) -> Option<Vec<f64>> {
        let nr = rows.len();
        let mut plants: Vec<(f64, LanePlants)> = Vec::new();
        let mut done = vec![0.0; nr];
        let mut alive = vec![true; nr];
        let mut costs: Vec<Vec<f64>> = vec![Vec::with_capacity(self.w.len()); nr];
        let mut limits = [f64::INFINITY; LANES];
        for &(j, wj) in &self.w {
            let run = &self.runs[j];
            let pi = match plants.iter().position(|p| p.0 == run.dt) {
                Some(i) => i,
                None => {
                    plants.push((run.dt, lane_plants(self.spec, rows, run)?));
                    plants.len() - 1
                }
            };
            let live: LanePlants = plants[pi]
                .1
                .iter()
                .filter(|p| alive[p.0])
                .copied()
                .collect();
            let bound = bound();
            for k in 0..nr {
                limits[k] = if bound.is_finite() {
                    (bound * self.total - done[k]) * run.len() as f64 / wj
                } else {
                    f64::INFINITY
                };
            }
            let c = if live.is_empty() {
                vec![f64::INFINITY; nr]
            } else {
                lane_run(self.spec, &live, nr, run, &limits)
            };
            for k in 0..nr {
                if !alive[k] {
                    continue;
                }
                if c[k].is_finite() {
                    done[k] += wj * c[k];
                    costs[k].push(c[k]);
                } else {
                    alive[k] = false;
                }
            }
            if !alive.iter().any(|&a| a) {
                break;
            }
        }
        Some(
            (0..nr)
                .map(|k| {
                    if alive[k] {
                        combine(&costs[k], &self.w)
                    } else {
                        f64::INFINITY
                    }
                })
                .collect(),
        )
    }
}

/// A calibration: the GA's result and the per-run costs (Eq. 6 run terms) of its
/// best parameters, one per distinct run of the problem in index order.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub ga: GaResult,
    pub per_run: Vec<(usize, f64)>,
}

/// Multiplicities of a subset: sorted unique indices with their counts.
pub fn multiplicities(subset: &[usize], r: usize, problem: usize) -> Result<Vec<(usize, f64)>> {
    if subset.is_empty() {
        return Err(AvllError::new(
            format!("problems[{problem}]"),
            "has no runs",
        ));
    }
    let mut counts = vec![0usize; r];
    for &j in subset {
        if j >= r {
            return Err(AvllError::new(
                format!("problems[{problem}]"),
                format!("run index {j} is out of range (there are {r} runs)"),
            ));
        }
        counts[j] += 1;
    }
    Ok(counts
        .iter()
        .enumerate()
        .filter(|(_, &c)| c > 0)
        .map(|(j, &c)| (j, c as f64))
        .collect())
}

/// Calibrates `spec.model` (and the free upper-level gains) on `runs` by the GA:
/// minimises Eq. 6. `bounds` has `spec.n_params()` coordinates.
pub fn calibrate(
    spec: &CostSpec,
    runs: &[RunRef],
    bounds: &Bounds,
    opts: &GaOptions,
    callback: impl FnMut(&Progress) -> bool,
) -> Result<Calibration> {
    spec.validate(runs)?;
    let all: Vec<usize> = (0..runs.len()).collect();
    calibrate_one(spec, runs, &all, bounds, opts, 0, true, callback)
}

#[allow(clippy::too_many_arguments)]
fn calibrate_one(
    spec: &CostSpec,
    runs: &[RunRef],
    subset: &[usize],
    bounds: &Bounds,
    opts: &GaOptions,
    problem: usize,
    par: bool,
    callback: impl FnMut(&Progress) -> bool,
) -> Result<Calibration> {
    if bounds.dim() != spec.n_params() {
        return Err(AvllError::new(
            "bounds",
            format!(
                "has {} parameters, the model {:?} with {} effect parameters and {} free \
                 upper-level gains needs {}",
                bounds.dim(),
                spec.model.name(),
                spec.effects.n_params(),
                spec.upper_free.len(),
                spec.n_params()
            ),
        ));
    }
    let w = multiplicities(subset, runs.len(), problem)?;
    let total = w.iter().map(|p| p.1).sum();
    let search = CostSpec {
        relaxed: true,
        ..spec.clone()
    };
    let f = Eq6 {
        spec: &search,
        runs,
        w,
        total,
        par,
    };
    let ga = minimize(&f, bounds, opts, callback)?;
    let per_run =
        f.w.iter()
            .map(|p| p.0)
            .zip(run_costs(spec, &ga.x, runs, &f.w, par))
            .collect();
    Ok(Calibration { ga, per_run })
}

/// Checks per-problem starting rows (`initial[k]`: the rows of problem `k`; empty: none
/// for any problem): one list per problem, each row `d` finite values.
pub fn check_initial(initial: &[Vec<Vec<f64>>], n_problems: usize, d: usize) -> Result<()> {
    if initial.is_empty() {
        return Ok(());
    }
    if initial.len() != n_problems {
        return Err(AvllError::new(
            "initial_per_problem",
            format!(
                "has {} lists of starting rows, one per problem is needed ({n_problems})",
                initial.len()
            ),
        ));
    }
    for (k, rows) in initial.iter().enumerate() {
        for (j, x) in rows.iter().enumerate() {
            if x.len() != d {
                return Err(AvllError::new(
                    format!("initial_per_problem[{k}][{j}]"),
                    format!("has {} values, expected {d}", x.len()),
                ));
            }
            if x.iter().any(|v| !v.is_finite()) {
                return Err(AvllError::new(
                    format!("initial_per_problem[{k}][{j}]"),
                    "is not finite",
                ));
            }
        }
    }
    Ok(())
}

/// Solves many independent calibration problems: problem `k` is Eq. 6 over the runs
/// `problems[k]` (repeats allowed), with the seed `derive_seed(opts.seed, k)` when
/// `derive` is true (else `opts.seed` for all). Problem `k` starts from its own rows
/// `initial[k]` (when `initial` is not empty; e.g. a base model's optimum for the same
/// problem with the added effects at their neutral values) followed by the rows
/// `opts.initial` shared by every problem: the GA keeps its best individual (plus
/// survival, or the elite), so the result costs at most what the best of those rows
/// costs. `callback(k, progress)` returns
/// `None`/`Some(true)` to continue and `Some(false)` to stop every problem (each then
/// returns its best so far).
///
/// Without `in_turn` the problems run in parallel. With `in_turn` (independent starts
/// of one problem) they run one after the other, each with all the threads for its
/// population and runs, so the first start's answer arrives as early as a single
/// start's; once a start reaches `opts.target` (or the callback stops it) the later
/// starts are skipped and only the starts that ran are returned. Either way the
/// result is the same for any number of threads.
#[allow(clippy::too_many_arguments)]
pub fn calibrate_many(
    spec: &CostSpec,
    runs: &[RunRef],
    problems: &[Vec<usize>],
    bounds: &Bounds,
    opts: &GaOptions,
    derive: bool,
    in_turn: bool,
    initial: &[Vec<Vec<f64>>],
    callback: impl Fn(usize, &Progress) -> Option<bool> + Sync,
) -> Result<Vec<Calibration>> {
    spec.validate(runs)?;
    opts.validate(bounds.dim())?;
    for (k, p) in problems.iter().enumerate() {
        multiplicities(p, runs.len(), k)?;
    }
    check_initial(initial, problems.len(), bounds.dim())?;
    let seeded = |k: usize| {
        let mut o = opts.clone();
        if derive {
            o.seed = derive_seed(opts.seed, k as u64);
        }
        if let Some(own) = initial.get(k) {
            o.initial = own.iter().chain(&opts.initial).cloned().collect();
        }
        o
    };
    if in_turn {
        let mut out = Vec::with_capacity(problems.len());
        for (k, subset) in problems.iter().enumerate() {
            let mut stopped = false;
            let c = calibrate_one(spec, runs, subset, bounds, &seeded(k), k, true, |p| {
                let go = callback(k, p).unwrap_or(true);
                stopped |= !go;
                go
            })?;
            let reached = c.ga.f <= opts.target;
            out.push(c);
            if reached || stopped {
                break;
            }
        }
        return Ok(out);
    }
    // With at least as many problems as threads, the problems keep the threads busy.
    let par = problems.len() < rayon::current_num_threads();
    problems
        .par_iter()
        .enumerate()
        .map(|(k, subset)| {
            calibrate_one(spec, runs, subset, bounds, &seeded(k), k, par, |p| {
                callback(k, p).unwrap_or(true)
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optimize::ga::Scale;
    use crate::sim::Init;

    fn synthetic_runs() -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        let lin = crate::model::ModelKind::Proposed
            .linear(&[6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008])
            .unwrap();
        let mut us = Vec::new();
        let mut ys = Vec::new();
        for r in 0..3 {
            let u: Vec<f64> = (0..1500)
                .map(|k| {
                    let t = k as f64 * 0.05;
                    (0.3 * t + r as f64).sin() + 0.5 * (0.05 * t * t / 10.0).sin()
                })
                .collect();
            let mut y = crate::sim::simulate(&lin, &u, 0.05, Init::Rest).unwrap();
            for (k, v) in y.iter_mut().enumerate() {
                *v += 0.05 * ((k * 7919 + r * 104729) as f64).sin();
            }
            us.push(u);
            ys.push(y);
        }
        (us, ys)
    }

    fn spec() -> CostSpec {
        CostSpec::linear(
            crate::model::ModelKind::Proposed,
            crate::model::CommandKind::Acceleration,
            [1.0, 0.0, 0.0],
            Init::Rest,
            false,
            vec![],
        )
    }

    fn refs<'a>(us: &'a [Vec<f64>], ys: &'a [Vec<f64>]) -> Vec<RunRef<'a>> {
        us.iter()
            .zip(ys)
            .map(|(u, y)| RunRef {
                dt: 0.05,
                command: Some(u),
                lead_x: None,
                lead_v: None,
                a: y,
                v: None,
                x: None,
                upper: crate::sim::Upper {
                    kg: 0.5,
                    kv: 0.0,
                    tg: 2.0,
                    gmin: 9.5,
                },
                exo: vec![],
            })
            .collect()
    }

    #[test]
    fn bounded_objective_is_exact_or_abandons_above_the_bound() {
        let (us, ys) = synthetic_runs();
        let runs = refs(&us, &ys);
        let sp = spec();
        let w = vec![(0, 2.0), (1, 1.0), (2, 1.0)];
        let f = Eq6 {
            spec: &sp,
            runs: &runs,
            w: w.clone(),
            total: 4.0,
            par: true,
        };
        for row in [
            [6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008],
            [1.0, 0.5, 2.0, 0.8, 0.33, -0.4],
            [0.0, 0.04, 0.13, 0.73, 0.78, 0.0],
        ] {
            let exact = subset_cost(&sp, &row, &runs, &w);
            assert_eq!(f.eval_bounded(&row, 1e300).to_bits(), exact.to_bits());
            assert_eq!(
                f.eval_bounded(&row, exact * 1.0001).to_bits(),
                exact.to_bits()
            );
            assert!(f.eval_bounded(&row, exact * 0.5) >= exact * 0.5);
        }
        // The GA with abandoning finds the same as with exact values throughout.
        let b = proposed_box();
        let o = GaOptions {
            seed: 3,
            max_generations: 25,
            ..Default::default()
        };
        let plain = |x: &[f64]| subset_cost(&sp, x, &runs, &w);
        let r1 = minimize(&plain, &b, &o, |_| true).unwrap();
        let r2 = minimize(&f, &b, &o, |_| true).unwrap();
        assert_eq!(r1.x, r2.x);
        assert_eq!(r1.history, r2.history);
        assert!(r2.f < 0.01, "{}", r2.f);
    }

    #[test]
    fn lane_groups_equal_the_point_by_point_values_bit_for_bit() {
        let (us, ys) = synthetic_runs();
        let mut runs = refs(&us, &ys);
        // A run of another dt (plants per dt) and a shorter run.
        runs[2].dt = 0.1;
        runs[1].a = &ys[1][..900];
        runs[1].command = Some(&us[1][..900]);
        let sp = spec();
        let w = vec![(0, 2.0), (1, 1.0), (2, 1.0)];
        let f = Eq6 {
            spec: &sp,
            runs: &runs,
            w,
            total: 4.0,
            par: false,
        };
        // Modal, complex-pole, unstable and invalid rows, near and far from the fit;
        // 7 rows: a full group and a partial one.
        let xs: Vec<Vec<f64>> = vec![
            vec![6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008],
            vec![0.0, 0.0445, 0.1305, 0.7292, 0.7796, 0.0],
            vec![1.0, 0.5, 2.0, 0.8, 0.33, -0.4],
            vec![1.0, 1.0, 1.0, 1.0, 0.1, 5.0],
            vec![1.0, -1.0, 1.0, 1.0, 0.1, 0.0],
            vec![6.0, 1.3, 8.0, 0.35, 0.8, 0.1],
            vec![0.2, 0.8, 1.9, 1.1, 0.05, 0.3],
        ];
        let exact: Vec<f64> = xs.iter().map(|x| f.eval(x)).collect();
        let finite: Vec<f64> = exact.iter().copied().filter(|v| v.is_finite()).collect();
        assert!(finite.len() >= 4, "{exact:?}");
        let mid = {
            let mut s = finite.clone();
            s.sort_by(f64::total_cmp);
            s[s.len() / 2]
        };
        for bound in [f64::INFINITY, 1e300, mid, mid * 0.5, finite[0] * 1.0001] {
            let got = f.eval_many(&xs, bound);
            let want: Vec<f64> = xs
                .iter()
                .map(|x| {
                    if bound.is_finite() {
                        f.eval_bounded(x, bound)
                    } else {
                        f.eval(x)
                    }
                })
                .collect();
            for (i, (g, e)) in got.iter().zip(&want).enumerate() {
                assert_eq!(
                    g.to_bits(),
                    e.to_bits(),
                    "row {i}, bound {bound}: {g} vs {e}"
                );
            }
            // Abandoned values are >= the bound; the others exact.
            for (g, e) in got.iter().zip(&exact) {
                assert!(g.to_bits() == e.to_bits() || *g >= bound);
            }
            if bound == mid * 0.5 {
                let abandoned = got
                    .iter()
                    .zip(&exact)
                    .filter(|(g, e)| g.is_infinite() && e.is_finite())
                    .count();
                assert!(abandoned >= 2, "{got:?} {exact:?}");
            }
        }
        // The lane path was taken (not the point-by-point fallback).
        assert!(f.lane_group(&[&xs[0], &xs[1]], || f64::INFINITY).is_some());
    }

    /// The default search box of the proposed model (log for m1..m3).
    fn proposed_box() -> Bounds {
        Bounds::new(
            vec![1e-4, 1e-3, 1e-3, 0.0, 0.0, -3.0],
            vec![100.0, 100.0, 100.0, 3.0, 3.0, 3.0],
            vec![
                Scale::Log,
                Scale::Log,
                Scale::Log,
                Scale::Linear,
                Scale::Linear,
                Scale::Linear,
            ],
        )
        .unwrap()
    }

    #[test]
    fn calibration_is_bit_identical_for_any_thread_count() {
        let (us, ys) = synthetic_runs();
        let runs = refs(&us, &ys);
        let sp = spec();
        let b = proposed_box();
        let o = GaOptions {
            seed: 11,
            max_generations: 12,
            polish_max_evals: 200,
            ..Default::default()
        };
        let problems = vec![vec![0, 1, 2], vec![0, 0, 2], vec![1]];
        let run = |t: usize| {
            crate::parallel::with_threads(t, || {
                calibrate_many(&sp, &runs, &problems, &b, &o, true, false, &[], |_, _| None)
            })
            .unwrap()
            .unwrap()
        };
        let (r1, r2, r3) = (run(1), run(2), run(3));
        assert_eq!(r1, r2);
        assert_eq!(r1, r3);
        assert!(r1.iter().all(|c| c.ga.f.is_finite()));
        // Starts of one problem in turn: the same for any threads; without a target
        // every start runs and each equals the start run alone.
        let all = vec![vec![0, 1, 2]; 3];
        let run2 = |t: usize, o: &GaOptions| {
            crate::parallel::with_threads(t, || {
                calibrate_many(&sp, &runs, &all, &b, o, true, true, &[], |_, _| None)
            })
            .unwrap()
            .unwrap()
        };
        let full = run2(2, &o);
        assert_eq!(full, run2(1, &o));
        assert_eq!(full.len(), 3);
        let parallel = crate::parallel::with_threads(2, || {
            calibrate_many(&sp, &runs, &all, &b, &o, true, false, &[], |_, _| None)
        })
        .unwrap()
        .unwrap();
        assert_eq!(full, parallel);
        // With a target only the first start has no cost above it: the later ones
        // are skipped once a start reaches it.
        let j = (0..3)
            .min_by(|&a, &c| full[a].ga.f.total_cmp(&full[c].ga.f))
            .unwrap();
        let o2 = GaOptions {
            target: full[j].ga.f * 1.000001,
            ..o.clone()
        };
        let (t1, t2, t3) = (run2(1, &o2), run2(2, &o2), run2(3, &o2));
        assert_eq!(t1, t2);
        assert_eq!(t1, t3);
        let last = t1.last().unwrap();
        assert!(last.ga.f <= o2.target);
        assert!(
            t1.len() <= j + 1,
            "{} starts ran, start {j} reaches it",
            t1.len()
        );
        assert!(t1[..t1.len() - 1].iter().all(|c| c.ga.f > o2.target));
        for c in &t1 {
            let w = multiplicities(&all[0], runs.len(), 0).unwrap();
            assert_eq!(c.ga.f, subset_cost(&sp, &c.ga.x, &runs, &w));
        }
    }

    #[test]
    fn per_problem_starts_bound_each_result_and_are_checked() {
        let (us, ys) = synthetic_runs();
        let runs = refs(&us, &ys);
        let sp = spec();
        let b = proposed_box();
        // A short search that cannot find the optimum alone; each problem starts from
        // its own row: problem 0 from the truth, problem 1 from a poor row, problem 2
        // from none.
        let o = GaOptions {
            seed: 5,
            max_generations: 2,
            polish: false,
            local_every: 0,
            ..Default::default()
        };
        let truth = vec![6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008];
        let poor = vec![1.0, 0.5, 2.0, 0.8, 0.33, -0.4];
        let problems = vec![vec![0, 1, 2], vec![1, 2], vec![2]];
        let initial = vec![vec![truth.clone()], vec![poor.clone()], vec![]];
        let run = |t: usize, init: &[Vec<Vec<f64>>]| {
            crate::parallel::with_threads(t, || {
                calibrate_many(&sp, &runs, &problems, &b, &o, true, false, init, |_, _| {
                    None
                })
            })
            .unwrap()
            .unwrap()
        };
        let (r1, r2) = (run(1, &initial), run(2, &initial));
        assert_eq!(r1, r2);
        let cost = |row: &[f64], k: usize| {
            let w = multiplicities(&problems[k], runs.len(), k).unwrap();
            subset_cost(&sp, row, &runs, &w)
        };
        assert!(r1[0].ga.f <= cost(&truth, 0) * (1.0 + 1e-12));
        assert!(r1[1].ga.f <= cost(&poor, 1) * (1.0 + 1e-12));
        // without its row, problem 0 ends well above the truth's cost in 2 generations
        let plain = run(1, &[]);
        assert!(plain[0].ga.f > 2.0 * cost(&truth, 0), "{}", plain[0].ga.f);
        // the problem without rows is the same search as without any rows
        assert_eq!(plain[2], r1[2]);
        // shapes are checked, naming the problem and the row
        let err = |init: &[Vec<Vec<f64>>]| {
            calibrate_many(&sp, &runs, &problems, &b, &o, true, false, init, |_, _| {
                None
            })
            .unwrap_err()
            .to_string()
        };
        assert!(err(&[vec![truth.clone()]]).contains("one per problem"));
        let short = vec![vec![], vec![vec![1.0; 5]], vec![]];
        assert!(err(&short).contains("initial_per_problem[1][0]"));
        let nan = vec![vec![], vec![], vec![vec![f64::NAN; 6]]];
        assert!(err(&nan).contains("initial_per_problem[2][0]"));
    }
}
