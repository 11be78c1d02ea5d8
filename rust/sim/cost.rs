//! The Eq. 6 cost on the one kernel: run references, the one cost specification
//! (base model, effects, command kind, weights, initial state, open or closed loop,
//! free upper-level gains), per-run costs with early abandoning, batched costs and
//! batched simulation over parameter rows x runs.
//!
//! A parameter row is `[base params | effect params (canonical order) | free upper
//! gains]`. Invalid or unstable rows cost `inf` (never NaN): parameters the model
//! refuses, a lower level whose inner loop is not asymptotically stable (Schur-Cohn
//! on the discretized loop, see [`crate::sim::discretize::inner_loop_stable`]) and
//! runs whose response leaves `|.| < DIVERGED`.

use super::chain::{lower_of, modal_ok, resolve_exo, Chain, Effects, Law, NoEffects, UpperChain};
use super::discretize::{loop_stable, Integrators};
use super::kernel::{self, Record, Sse};
use super::plant::{start, Init, Plant};
use super::rollout::{stepper, Upper};
use super::with_plant;
use crate::effects::{AnyEffect, EffectList};
use crate::error::{check_series, AvllError, Result};
use crate::model::{CommandKind, Linear, ModelKind};
use rayon::prelude::*;

/// One measured run, borrowed. Open loop uses `command`; closed loop uses the
/// leader (`lead_x`, `lead_v`) and `upper`; `exo` holds the exogenous series the
/// effects read (e.g. `grade`).
#[derive(Debug, Clone)]
pub struct RunRef<'a> {
    pub dt: f64,
    pub command: Option<&'a [f64]>,
    pub lead_x: Option<&'a [f64]>,
    pub lead_v: Option<&'a [f64]>,
    /// Measured acceleration (always present).
    pub a: &'a [f64],
    pub v: Option<&'a [f64]>,
    pub x: Option<&'a [f64]>,
    pub upper: Upper,
    pub exo: Vec<(&'a str, &'a [f64])>,
}

impl RunRef<'_> {
    pub fn len(&self) -> usize {
        self.a.len()
    }

    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }
}

/// What the cost compares, and how the runs are driven.
#[derive(Debug, Clone, PartialEq)]
pub struct CostSpec {
    pub model: ModelKind,
    /// Effects extending the base model (empty: the linear model).
    pub effects: EffectList,
    pub kind: CommandKind,
    /// Weights of the mean squared errors of acceleration, speed and position
    /// (the gap error equals the position error behind a recorded leader).
    pub weights: [f64; 3],
    pub init: Init,
    /// Closed loop: driven by the leader through the upper law.
    pub closed_loop: bool,
    /// Indices (0 kg, 1 kv, 2 Tg, 3 Gmin) of upper-level parameters that are
    /// calibrated: their values follow the model and effect parameters in each row,
    /// in this order, and override the runs' own.
    pub upper_free: Vec<usize>,
    /// The GA's search objective: a locally unstable closed loop keeps the cost of its
    /// rollout (it steers the search; the GA never returns it, see
    /// [`crate::optimize::ga::Objective::admissible`]). Everywhere else `false`: such a
    /// loop costs `inf` ([`CostSpec::locally_unstable`]).
    pub relaxed: bool,
}

impl CostSpec {
    /// A linear-model spec (no effects).
    pub fn linear(
        model: ModelKind,
        kind: CommandKind,
        weights: [f64; 3],
        init: Init,
        closed_loop: bool,
        upper_free: Vec<usize>,
    ) -> Self {
        Self {
            model,
            effects: EffectList::default(),
            kind,
            weights,
            init,
            closed_loop,
            upper_free,
            relaxed: false,
        }
    }

    /// Length of a parameter row.
    pub fn n_params(&self) -> usize {
        self.model.n_params() + self.effects.n_params() + self.upper_free.len()
    }

    /// Open loop, acceleration command, acceleration error only and no effect
    /// reading the speed: the rollout needs no integrators.
    pub fn accel_only(&self) -> bool {
        !self.closed_loop
            && self.kind == CommandKind::Acceleration
            && self.weights[1] == 0.0
            && self.weights[2] == 0.0
            && !self.effects.0.iter().any(|k| k.needs_speed())
    }

    /// Checks the spec against the runs, so that evaluation cannot fail later.
    pub fn validate(&self, runs: &[RunRef]) -> Result<()> {
        for (w, n) in self
            .weights
            .iter()
            .zip(["weight_a", "weight_v", "weight_x"])
        {
            crate::error::check_nonneg(n, *w)?;
        }
        if self.weights.iter().all(|w| *w == 0.0) {
            return Err(AvllError::new("weights", "all weights are zero"));
        }
        self.effects.check_closed(self.closed_loop)?;
        if self.closed_loop && self.kind != CommandKind::Acceleration {
            return Err(AvllError::new(
                "command_kind",
                "closed loop runs the upper law, which commands an acceleration",
            ));
        }
        if let Some(&i) = self.upper_free.iter().find(|&&i| i > 3) {
            return Err(AvllError::new(
                "upper_free",
                format!("index {i} is not in 0..4"),
            ));
        }
        if runs.is_empty() {
            return Err(AvllError::new("runs", "no runs given"));
        }
        let neutral: Vec<f64> = self
            .effects
            .0
            .iter()
            .flat_map(|k| k.neutral().iter().copied())
            .collect();
        let effs = self.effects.build(&neutral, self.kind)?;
        for (r, run) in runs.iter().enumerate() {
            let name = |s: &str| format!("runs[{r}].{s}");
            let n = run.len();
            if n < 2 {
                return Err(AvllError::new(name("a"), "needs at least 2 samples"));
            }
            if !(run.dt.is_finite() && run.dt > 0.0) {
                return Err(AvllError::new(
                    name("dt"),
                    format!("must be > 0, got {}", run.dt),
                ));
            }
            check_series(&name("a"), run.a)?;
            let need = |opt: Option<&[f64]>, what: &str, needed: bool| -> Result<()> {
                match opt {
                    Some(s) => {
                        if s.len() != n {
                            return Err(AvllError::new(
                                name(what),
                                format!("has length {} but must have length {n}", s.len()),
                            ));
                        }
                        check_series(&name(what), s)
                    }
                    None if needed => {
                        Err(AvllError::new(name(what), "is required here but missing"))
                    }
                    None => Ok(()),
                }
            };
            need(run.command, "command", !self.closed_loop)?;
            need(run.lead_x, "lead_x", self.closed_loop)?;
            need(run.lead_v, "lead_v", self.closed_loop)?;
            need(run.v, "v", self.weights[1] > 0.0 || self.closed_loop)?;
            need(run.x, "x", self.weights[2] > 0.0 || self.closed_loop)?;
            run.upper.validate()?;
            resolve_exo(&effs, &run.exo, n)
                .map_err(|e| AvllError::new(format!("runs[{r}].{}", e.arg), e.msg))?;
        }
        Ok(())
    }

    /// The lower level, effects and upper law of one row for one run, or `None`
    /// when the row is invalid.
    fn prepare(&self, row: &[f64], run: &RunRef) -> Option<(Linear, Vec<AnyEffect>, Upper)> {
        let nb = self.model.n_params();
        let ne = self.effects.n_params();
        let lin = self.model.linear(&row[..nb]).ok()?;
        let effs = if self.effects.0.is_empty() {
            Vec::new()
        } else {
            self.effects.build(&row[nb..nb + ne], self.kind).ok()?
        };
        let mut up = run.upper;
        for (j, &i) in self.upper_free.iter().enumerate() {
            up.set(i, row[nb + ne + j]);
        }
        Some((lin, effs, up))
    }

    /// [`CostSpec::prepare`] for a cost: `None` also for a closed loop that is locally
    /// unstable ([`CostSpec::locally_unstable`]), unless the spec is
    /// [`CostSpec::relaxed`] (the GA's search).
    fn prepare_cost(&self, row: &[f64], run: &RunRef) -> Option<(Linear, Vec<AnyEffect>, Upper)> {
        let (lin, effs, up) = self.prepare(row, run)?;
        if self.closed_loop && !self.relaxed && unstable_loop(&lin, &effs, &up, run) {
            return None;
        }
        Some((lin, effs, up))
    }

    /// Whether `row` makes the closed loop of `run` locally unstable (an open-loop spec
    /// or invalid parameters: `false`; the cost decides those). A car followed its
    /// predecessor through the record, and a slowly diverging loop that fits a finite
    /// record is no description of it, so such a row costs `inf`. Without effects the
    /// exact test with the true delay
    /// ([`crate::stability::delay::DelayLoop::local`]); with effects the certified test
    /// of every delay ([`crate::effects::follower::FollowerLoop::local`]) of their
    /// small-signal form at the run's mean predecessor speed (the operating point of
    /// the study's predictions). Undecided loops, and effects without a small-signal
    /// form there, count as stable (the rollout decides).
    pub fn locally_unstable(&self, row: &[f64], run: &RunRef) -> bool {
        if !self.closed_loop {
            return false;
        }
        match self.prepare(row, run) {
            Some((lin, effs, up)) => unstable_loop(&lin, &effs, &up, run),
            None => false,
        }
    }

    fn integrators(&self) -> Integrators {
        if self.accel_only() {
            Integrators::None
        } else {
            Integrators::for_kind(self.kind)
        }
    }
}

/// See [`CostSpec::locally_unstable`].
fn unstable_loop(lin: &Linear, effs: &[AnyEffect], up: &Upper, run: &RunRef) -> bool {
    if effs.is_empty() {
        return match crate::stability::delay::DelayLoop::new(lin) {
            Ok(dl) => dl.local(up.kg, up.tg, up.kv) == Some(false),
            Err(_) => false,
        };
    }
    let Some(lead_v) = run.lead_v else {
        return false;
    };
    let v = lead_v.iter().sum::<f64>() / lead_v.len().max(1) as f64;
    let op = crate::effects::Operating { v, side: 0 };
    match (
        crate::effects::linearize_terms(lin, effs, &op),
        crate::effects::linearize_upper(up, effs, &op),
    ) {
        (Ok((l, t)), Ok(u)) => {
            crate::effects::follower::FollowerLoop::new(&l, &t, &u).local()
                == crate::effects::follower::Verdict::No
        }
        _ => false,
    }
}

/// The lower-level chain and the upper law of a run with effects: the lower-level
/// effects with their exogenous signals, and the run's law with the upper-level ones
/// (reset for the run's `dt`).
fn with_effects<'a>(
    effs: &[AnyEffect],
    up: &Upper,
    run: &RunRef<'a>,
) -> Result<(Effects<'a>, UpperChain)> {
    let effects = lower_of(effs);
    let exo = resolve_exo(&effects, &run.exo, run.len())?;
    let mut law = UpperChain::new(*up, effs);
    law.reset(run.dt);
    Ok((Effects { effects, exo }, law))
}

/// The Eq. 6 cost of `row` on `run` (`sum(w s) / len`), `inf` for invalid or
/// unstable parameters (in closed loop also a locally unstable loop,
/// `CostSpec::prepare_cost`) or a diverged response, and `inf` as soon as the weighted sum
/// of squared errors reaches `limit` (checked every [`super::kernel::CHUNK`]
/// samples; `inf` for no bound). An unabandoned value does not depend on `limit`.
/// Assumes `spec.validate(runs)` passed.
pub fn run_cost(spec: &CostSpec, row: &[f64], run: &RunRef, limit: f64) -> f64 {
    let Some((lin, effs, up)) = spec.prepare_cost(row, run) else {
        return f64::INFINITY;
    };
    let modal = modal_ok(&effs);
    let ints = spec.integrators();
    let r: Result<f64> = (|| {
        with_plant!(
            &lin,
            ints,
            run.dt,
            modal,
            cost_n(&lin, &effs, &up, spec, run, limit)
        )
    })();
    r.unwrap_or(f64::INFINITY)
}

#[inline(always)]
fn cost_n<const M: usize, const N: usize, const D: bool, const F: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    effs: &[AnyEffect],
    up: &Upper,
    spec: &CostSpec,
    run: &RunRef,
    limit: f64,
) -> Result<f64> {
    if !loop_stable(lin, &plant) {
        return Ok(f64::INFINITY);
    }
    if effs.is_empty() {
        cost_chain::<M, N, D, F, _, _>(plant, lin, NoEffects, *up, spec, run, limit)
    } else {
        let (ch, law) = with_effects(effs, up, run)?;
        cost_chain::<M, N, D, F, _, _>(plant, lin, ch, law, spec, run, limit)
    }
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn cost_chain<const M: usize, const N: usize, const D: bool, const F: bool, C: Chain, L: Law>(
    plant: Plant<M, N>,
    lin: &Linear,
    chain: C,
    mut law: L,
    spec: &CostSpec,
    run: &RunRef,
    limit: f64,
) -> Result<f64> {
    let len = run.len();
    let u = run.command.unwrap_or(&[]);
    let (lx, lv) = (run.lead_x.unwrap_or(&[]), run.lead_v.unwrap_or(&[]));
    let mut st = start_stepper::<M, N, D, F, C>(plant, lin, chain, spec, run)?;
    // The drive is chosen outside the loop (one monomorphization each).
    macro_rules! go {
        ($sse:expr) => {{
            let mut sse = $sse;
            let done = if spec.closed_loop {
                kernel::run(
                    &mut st,
                    len,
                    |n, o| law.command(lx[n], lv[n], o.p, o.v),
                    &mut sse,
                )
            } else {
                kernel::run(&mut st, len, |n, _| u[n], &mut sse)
            };
            Ok(sse.cost(done, len))
        }};
    }
    if N == M {
        go!(Sse::<false>::new(run.a, run.a, run.a, spec.weights, limit))
    } else {
        go!(Sse::<true>::new(
            run.a,
            run.v.unwrap_or(run.a),
            run.x.unwrap_or(run.a),
            spec.weights,
            limit,
        ))
    }
}

/// The stepper of a cost or batched-simulation rollout: the closed loop starts the
/// lower level at rest with the measured speed and position; the open loop by
/// `spec.init` with the measured (or zero) speed and position.
#[inline(always)]
fn start_stepper<const M: usize, const N: usize, const D: bool, const F: bool, C: Chain>(
    plant: Plant<M, N>,
    lin: &Linear,
    chain: C,
    spec: &CostSpec,
    run: &RunRef,
) -> Result<super::kernel::Stepper<M, N, D, F, C>> {
    let accel = spec.kind == CommandKind::Acceleration;
    let v0 = run.v.map_or(0.0, |v| v[0]);
    let p0 = run.x.map_or(0.0, |x| x[0]);
    let (s, int0) = if spec.closed_loop {
        (start(lin, Init::Rest, 0.0)?, [v0, p0])
    } else {
        let s = start(lin, spec.init, run.command.map_or(0.0, |u| u[0]))?;
        (s, if accel { [v0, p0] } else { [p0, 0.0] })
    };
    stepper::<M, N, D, F, C>(plant, lin, spec.integrators(), chain, accel, &s, int0)
}

/// Costs of `P` parameter rows (row-major, `spec.n_params()` each) on every run:
/// a `P x R` row-major matrix of per-run costs, evaluated in parallel. Invalid or
/// unstable rows get `inf`. Validates the spec and the runs first.
pub fn batch_cost(spec: &CostSpec, params: &[f64], runs: &[RunRef]) -> Result<Vec<f64>> {
    spec.validate(runs)?;
    let np = spec.n_params();
    let p = rows(np, params)?;
    let r = runs.len();
    let probe: Vec<&[f64]> = params.chunks(np).take(1).collect();
    if lane_plants(spec, &probe, &runs[0]).is_none() {
        return cost_matrix(np, params, runs, |row, run| {
            run_cost(spec, row, run, f64::INFINITY)
        });
    }
    // The rows in the order of their dead time (see `by_delay`), the results put back
    // in the rows' own order.
    let order = by_delay(spec, &params.chunks(np).collect::<Vec<_>>(), &runs[0]);
    let sorted: Vec<f64> = order
        .iter()
        .flat_map(|&q| &params[q * np..(q + 1) * np])
        .copied()
        .collect();
    let got = lane_matrix(spec, np, p, &sorted, runs);
    let mut out = vec![0.0; p * r];
    for (k, &q) in order.iter().enumerate() {
        out[q * r..(q + 1) * r].copy_from_slice(&got[k * r..(k + 1) * r]);
    }
    Ok(out)
}

/// [`batch_cost`] through the lanes, rows grouped in the order given.
fn lane_matrix(spec: &CostSpec, np: usize, p: usize, params: &[f64], runs: &[RunRef]) -> Vec<f64> {
    let r = runs.len();
    // Groups of LANES rows stepped together, in parallel over (group, run); the
    // plants are discretized once per group when every run has the same dt. The
    // rows of a last, partial group go the other way round when that takes fewer
    // passes (e.g. one row on 10 runs: 3 passes of runs stepped together instead of
    // 10 passes with three idle lanes).
    let refs: Vec<&RunRef> = runs.iter().collect();
    let run_sets = run_groups(&refs);
    let tail = p % LANES;
    let by_runs = tail > 0 && tail * run_sets.len() < r;
    let groups = if by_runs {
        p / LANES
    } else {
        p.div_ceil(LANES)
    };
    let group = |g: usize| -> Vec<&[f64]> {
        params[g * LANES * np..((g + 1) * LANES).min(p) * np]
            .chunks(np)
            .collect()
    };
    let same_dt = runs.iter().all(|x| x.dt == runs[0].dt);
    let plants: Vec<Option<Vec<(usize, Plant<2, 2>, Linear)>>> = (0..groups)
        .into_par_iter()
        .map(|g| {
            if same_dt {
                lane_plants(spec, &group(g), &runs[0])
            } else {
                None
            }
        })
        .collect();
    let parts: Vec<Vec<f64>> = (0..groups * r)
        .into_par_iter()
        .map(|k| {
            let (g, j) = (k / r, k % r);
            let rs = group(g);
            match &plants[g] {
                Some(pl) => lane_run(spec, pl, rs.len(), &runs[j], &[f64::INFINITY; LANES]),
                None => lane_costs(spec, &rs, &runs[j]).unwrap_or_else(|| {
                    rs.iter()
                        .map(|row| run_cost(spec, row, &runs[j], f64::INFINITY))
                        .collect()
                }),
            }
        })
        .collect();
    let mut out = vec![0.0; p * r];
    for (k, costs) in parts.into_iter().enumerate() {
        let (g, j) = (k / r, k % r);
        for (q, c) in costs.into_iter().enumerate() {
            out[(g * LANES + q) * r + j] = c;
        }
    }
    if by_runs {
        // In parallel over (tail row, run group).
        let first = groups * LANES;
        let ns = run_sets.len();
        let parts: Vec<Vec<f64>> = (0..tail * ns)
            .into_par_iter()
            .map(|k| {
                let row = &params[(first + k / ns) * np..(first + k / ns + 1) * np];
                let rs: Vec<&RunRef> = run_sets[k % ns].iter().map(|&j| &runs[j]).collect();
                run_lanes_group(spec, row, &rs, &vec![f64::INFINITY; rs.len()])
            })
            .collect();
        for (k, costs) in parts.into_iter().enumerate() {
            let i = first + k / ns;
            for (&j, c) in run_sets[k % ns].iter().zip(costs) {
                out[i * r + j] = c;
            }
        }
    }
    out
}

/// Evaluates `cost(row, run)` for every parameter row (row-major, `np` values each) and
/// every run, in parallel: a `P x R` row-major matrix.
pub fn cost_matrix<R: Sync>(
    np: usize,
    params: &[f64],
    runs: &[R],
    cost: impl Fn(&[f64], &R) -> f64 + Sync,
) -> Result<Vec<f64>> {
    let p = rows(np, params)?;
    let r = runs.len();
    let mut out = vec![0.0; p * r];
    out.par_iter_mut().enumerate().for_each(|(k, o)| {
        let (i, j) = (k / r, k % r);
        *o = cost(&params[i * np..(i + 1) * np], &runs[j]);
    });
    Ok(out)
}

/// Number of rows of a row-major parameter array.
fn rows(np: usize, params: &[f64]) -> Result<usize> {
    if np == 0 || !params.len().is_multiple_of(np) {
        return Err(AvllError::new(
            "params",
            format!(
                "length {} is not a multiple of the row length {np}",
                params.len()
            ),
        ));
    }
    Ok(params.len() / np)
}

/// Simulated acceleration, speed and position of every row on every run, as the
/// cost sees them (the same drive, initial state and effects): row-major `P x T`
/// arrays with `T` the runs' total length (run `r` at its offset). A row the cost
/// calls invalid or unstable is NaN throughout; a closed-loop rollout that diverges
/// is NaN after the divergence. Evaluated in parallel over (row, run).
pub fn simulate_batch(
    spec: &CostSpec,
    params: &[f64],
    runs: &[RunRef],
    a: &mut [f64],
    v: &mut [f64],
    x: &mut [f64],
) -> Result<()> {
    spec.validate(runs)?;
    let np = spec.n_params();
    let p = rows(np, params)?;
    let total: usize = runs.iter().map(|r| r.len()).sum();
    for s in [&*a, &*v, &*x] {
        if s.len() != p * total {
            return Err(AvllError::new(
                "out",
                format!("has length {} but must have length {}", s.len(), p * total),
            ));
        }
    }
    let mut offsets = Vec::with_capacity(runs.len() + 1);
    offsets.push(0);
    for r in runs {
        offsets.push(offsets.last().copied().unwrap_or(0) + r.len());
    }
    // Disjoint (row, run) output pieces, in parallel.
    let mut pieces = Vec::with_capacity(p * runs.len());
    let (mut ra, mut rv, mut rx) = (a, v, x);
    for i in 0..p {
        for r in runs {
            let n = r.len();
            let (ha, ta) = std::mem::take(&mut ra).split_at_mut(n);
            let (hv, tv) = std::mem::take(&mut rv).split_at_mut(n);
            let (hx, tx) = std::mem::take(&mut rx).split_at_mut(n);
            pieces.push((i, r, ha, hv, hx));
            ra = ta;
            rv = tv;
            rx = tx;
        }
    }
    pieces.into_par_iter().for_each(|(i, run, pa, pv, px)| {
        let row = &params[i * np..(i + 1) * np];
        if !simulate_one(spec, row, run, pa, pv, px) {
            pa.fill(f64::NAN);
            pv.fill(f64::NAN);
            px.fill(f64::NAN);
        }
    });
    Ok(())
}

/// One (row, run) rollout of [`simulate_batch`]; `false` when the row is invalid or
/// unstable.
fn simulate_one(
    spec: &CostSpec,
    row: &[f64],
    run: &RunRef,
    a: &mut [f64],
    v: &mut [f64],
    x: &mut [f64],
) -> bool {
    let Some((lin, effs, up)) = spec.prepare(row, run) else {
        return false;
    };
    let modal = modal_ok(&effs);
    let ints = Integrators::for_kind(spec.kind);
    let r: Result<bool> = (|| {
        with_plant!(
            &lin,
            ints,
            run.dt,
            modal,
            sim_n(&lin, &effs, &up, spec, run, a, v, x)
        )
    })();
    r.unwrap_or(false)
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn sim_n<const M: usize, const N: usize, const D: bool, const F: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    effs: &[AnyEffect],
    up: &Upper,
    spec: &CostSpec,
    run: &RunRef,
    a: &mut [f64],
    v: &mut [f64],
    x: &mut [f64],
) -> Result<bool> {
    if !loop_stable(lin, &plant) {
        return Ok(false);
    }
    // The trajectory needs the integrators even where the cost does not.
    let full = CostSpec {
        weights: [1.0, 1.0, 1.0],
        ..spec.clone()
    };
    let len = run.len();
    let u = run.command.unwrap_or(&[]);
    let (lx, lv) = (run.lead_x.unwrap_or(&[]), run.lead_v.unwrap_or(&[]));
    let closed = spec.closed_loop;
    if effs.is_empty() {
        let mut st = start_stepper::<M, N, D, F, _>(plant, lin, NoEffects, &full, run)?;
        let law = *up;
        let f = |n: usize, o: &super::kernel::Obs| {
            if closed {
                law.command(lx[n], lv[n], o.p, o.v)
            } else {
                u[n]
            }
        };
        record(&mut st, len, f, a, v, x, closed);
    } else {
        let (ch, mut law) = with_effects(effs, up, run)?;
        let mut st = start_stepper::<M, N, D, F, _>(plant, lin, ch, &full, run)?;
        let f = |n: usize, o: &super::kernel::Obs| {
            if closed {
                law.command(lx[n], lv[n], o.p, o.v)
            } else {
                u[n]
            }
        };
        record(&mut st, len, f, a, v, x, closed);
    }
    Ok(true)
}

/// Runs into the output slices: a closed loop that diverges is NaN after the
/// divergence; an open loop is recorded as it is.
#[inline(always)]
fn record<const M: usize, const N: usize, const D: bool, const F: bool, C: Chain>(
    st: &mut super::kernel::Stepper<M, N, D, F, C>,
    len: usize,
    f: impl FnMut(usize, &super::kernel::Obs) -> f64,
    a: &mut [f64],
    v: &mut [f64],
    x: &mut [f64],
    closed: bool,
) {
    if closed {
        let mut rec = Record::<true, false>::new(a, v, x);
        if !kernel::run(st, len, f, &mut rec) {
            rec.blank_rest();
        }
    } else {
        kernel::run(st, len, f, &mut Record::<false, false>::new(a, v, x));
    }
}

// ---------------------------------------------------------------------------
// Lanes: several parameter rows stepped together on one run.
// ---------------------------------------------------------------------------

/// Rows stepped together by [`lane_costs`].
pub const LANES: usize = 4;

/// One lane's second-order plant in kernel coordinates, with its start.
struct Lane {
    p: Plant<2, 2>,
    w_hist: f64,
    z0: [f64; 2],
}

/// The Eq. 6 costs of up to [`LANES`] rows on one run, stepped together: the
/// linear second-order models' open-loop, acceleration-only path (the GA's and
/// `batch_cost`'s common case). Each lane performs exactly the operations of the
/// one kernel ([`crate::sim::kernel`]: `observe`, the dead-time line, `advance` in
/// its full-block form, whose zero off-diagonal terms leave a modal lane's values
/// unchanged, and the SSE sink), so each cost is bit-identical to [`run_cost`]; the
/// lanes' independent recurrences fill the pipeline and vectorize. `None` when the
/// path does not apply (the caller then uses [`run_cost`] per row).
pub fn lane_costs(spec: &CostSpec, rows: &[&[f64]], run: &RunRef) -> Option<Vec<f64>> {
    let lanes = lane_plants(spec, rows, run)?;
    Some(lane_run(
        spec,
        &lanes,
        rows.len(),
        run,
        &[f64::INFINITY; LANES],
    ))
}

/// The lanes' plants of a group of rows: (row index, plant, model).
pub type LanePlants = Vec<(usize, Plant<2, 2>, Linear)>;

/// Whether the lane path covers this cost on this run: the linear second-order
/// models' open-loop, acceleration-only cost with a recorded command.
pub fn lanes_apply(spec: &CostSpec, run: &RunRef) -> bool {
    spec.accel_only()
        && spec.effects.0.is_empty()
        && spec.model.n_params() != 1
        && run.command.is_some()
}

/// The lanes' plants (row index, plant, model) for runs sampled at `run.dt` (they
/// depend on the run only through `dt`); rows the cost calls invalid or unstable are
/// left out (they cost `inf`). `None` when the lane path does not apply.
pub fn lane_plants(spec: &CostSpec, rows: &[&[f64]], run: &RunRef) -> Option<LanePlants> {
    if !lanes_apply(spec, run) || rows.len() > LANES {
        return None;
    }
    let mut out = Vec::with_capacity(LANES);
    for (k, row) in rows.iter().enumerate() {
        let Some((lin, _, _)) = spec.prepare_cost(row, run) else {
            continue;
        };
        if lin.order() != 2 {
            return None;
        }
        let Ok(p) = Plant::<2, 2>::new(&lin, Integrators::None, run.dt, true) else {
            continue;
        };
        if loop_stable(&lin, &p) {
            out.push((k, p, lin));
        }
    }
    Some(out)
}

/// The rows' indices ordered (stably) by their whole-sample dead time at `run.dt`,
/// rows the model refuses last: the order in which to group rows into lanes, so that
/// a group's lanes mostly share one dead time and read their delayed inputs as one
/// row of the line. Any grouping gives the same values (each lane is exactly
/// [`run_cost`]); this one is only faster.
pub fn by_delay(spec: &CostSpec, rows: &[&[f64]], run: &RunRef) -> Vec<usize> {
    let key = |row: &[f64]| {
        spec.model
            .linear(&row[..spec.model.n_params()])
            .ok()
            .map_or(usize::MAX, |lin| {
                super::discretize::split_delay(lin.td, run.dt).0
            })
    };
    let keys: Vec<usize> = rows.iter().map(|r| key(r)).collect();
    let mut order: Vec<usize> = (0..rows.len()).collect();
    order.sort_by_key(|&q| keys[q]);
    order
}

/// The lanes' costs on one run (same `dt` as their plants): `out[k]` is row `k`'s
/// run cost, exactly [`run_cost`]`(spec, rows[k], run, limits[k])` — the same value,
/// and `inf` once the weighted sum of squared errors reaches `limits[k]` at the same
/// checks (every [`super::kernel::CHUNK`] samples); rows left out of `plants` cost
/// `inf`. The group stops as soon as every lane is abandoned or diverged.
pub fn lane_run(
    spec: &CostSpec,
    plants: &[(usize, Plant<2, 2>, Linear)],
    n_rows: usize,
    run: &RunRef,
    limits: &[f64],
) -> Vec<f64> {
    let mut out = vec![f64::INFINITY; n_rows];
    let u = run.command.unwrap_or(&[]);
    let mut lanes: Vec<(usize, Lane)> = Vec::with_capacity(LANES);
    for (k, p, lin) in plants {
        let Ok(s) = start(lin, spec.init, u.first().copied().unwrap_or(0.0)) else {
            continue;
        };
        lanes.push((
            *k,
            Lane {
                p: *p,
                w_hist: s.w_hist,
                z0: p.to_kernel(s.x),
            },
        ));
    }
    if lanes.is_empty() {
        return out;
    }
    let lim: [f64; LANES] =
        std::array::from_fn(|j| lanes.get(j).map_or(f64::INFINITY, |l| limits[l.0]));
    let (us, ms) = ([u; LANES], [run.a; LANES]);
    let wa = spec.weights[0];
    // Rows whose dead times round to the same whole number of samples read one row
    // of the dead-time line (as one plant on several runs) instead of gathering
    // each lane's own; a converging population mostly has them.
    let one_delay = lanes.iter().all(|l| l.1.p.delay == lanes[0].1.p.delay);
    let costs = lane_sse_for::<LANES, true>(&lanes, us, ms, wa, lim, one_delay);
    for ((k, _), c) in lanes.iter().zip(costs) {
        out[*k] = c;
    }
    out
}

/// The run costs of one row on several runs, stepped together (one run per lane):
/// `out[q]` is exactly [`run_cost`]`(spec, row, runs[q], limits[q])`, like
/// [`lane_run`] with the roles of rows and runs exchanged. Runs that share `dt` and
/// length go through the lanes in groups of [`LANES`]; the others, and costs the
/// lane path does not cover, through [`run_cost`].
pub fn run_lanes(spec: &CostSpec, row: &[f64], runs: &[&RunRef], limits: &[f64]) -> Vec<f64> {
    let alike = runs
        .iter()
        .all(|r| r.dt == runs[0].dt && r.len() == runs[0].len());
    if alike && runs.len() == LANES + 1 {
        // Five runs (a thread's share of ten): one group of five lanes, whose fifth
        // lane overlaps with the other four, instead of four lanes then a lone run
        // stepped on its own.
        return run_lanes_n::<{ LANES + 1 }>(spec, row, runs, limits);
    }
    let mut out = vec![f64::INFINITY; runs.len()];
    for g in run_groups(runs) {
        let rs: Vec<&RunRef> = g.iter().map(|&j| runs[j]).collect();
        let ls: Vec<f64> = g.iter().map(|&j| limits[j]).collect();
        for (&j, c) in g.iter().zip(run_lanes_group(spec, row, &rs, &ls)) {
            out[j] = c;
        }
    }
    out
}

/// The runs in groups of up to [`LANES`] that share `dt` and length (in order of
/// their first run): the groups [`run_lanes`] steps together.
pub fn run_groups(runs: &[&RunRef]) -> Vec<Vec<usize>> {
    let mut done = vec![false; runs.len()];
    let mut out = Vec::new();
    for q in 0..runs.len() {
        if done[q] {
            continue;
        }
        let group: Vec<usize> = (q..runs.len())
            .filter(|&j| !done[j] && runs[j].dt == runs[q].dt && runs[j].len() == runs[q].len())
            .take(LANES)
            .collect();
        for &j in &group {
            done[j] = true;
        }
        out.push(group);
    }
    out
}

/// [`run_lanes`] on one group of [`run_groups`] (up to [`LANES`] runs sharing `dt`
/// and length; anything else goes through [`run_cost`] run by run).
pub fn run_lanes_group(spec: &CostSpec, row: &[f64], runs: &[&RunRef], limits: &[f64]) -> Vec<f64> {
    run_lanes_n::<LANES>(spec, row, runs, limits)
}

/// [`run_lanes_group`] for up to `L` runs stepped together.
fn run_lanes_n<const L: usize>(
    spec: &CostSpec,
    row: &[f64],
    runs: &[&RunRef],
    limits: &[f64],
) -> Vec<f64> {
    let mut out = vec![f64::INFINITY; runs.len()];
    let alike = runs
        .iter()
        .all(|r| r.dt == runs[0].dt && r.len() == runs[0].len());
    let lanes = if alike && runs.len() > 1 && runs.len() <= L {
        lane_plants(spec, &[row], runs[0])
    } else {
        None
    };
    let Some(pl) = lanes else {
        for (j, run) in runs.iter().enumerate() {
            out[j] = run_cost(spec, row, run, limits[j]);
        }
        return out;
    };
    let Some((_, p, lin)) = pl.first() else {
        return out; // invalid or unstable: inf on every run
    };
    let mut ls: Vec<(usize, Lane)> = Vec::with_capacity(LANES);
    for (j, run) in runs.iter().enumerate() {
        let u0 = run.command.and_then(|u| u.first().copied()).unwrap_or(0.0);
        let Ok(s) = start(lin, spec.init, u0) else {
            continue;
        };
        let lane = Lane {
            p: *p,
            w_hist: s.w_hist,
            z0: p.to_kernel(s.x),
        };
        ls.push((j, lane));
    }
    if ls.is_empty() {
        return out;
    }
    let pick = |k: usize| ls[k.min(ls.len() - 1)].0;
    let us: [&[f64]; L] = std::array::from_fn(|k| runs[pick(k)].command.unwrap_or(&[]));
    let ms: [&[f64]; L] = std::array::from_fn(|k| runs[pick(k)].a);
    let lim: [f64; L] = std::array::from_fn(|k| ls.get(k).map_or(f64::INFINITY, |l| limits[l.0]));
    let wa = spec.weights[0];
    let costs = lane_sse_for::<L, false>(&ls, us, ms, wa, lim, true);
    for ((j, _), c) in ls.iter().zip(costs) {
        out[*j] = c;
    }
    out
}

/// [`lane_sse`] with its const parameters from the CPU (FMA), `one` (every lane has
/// the same whole-sample dead time) and the lanes' plants (all diagonal: modal
/// coordinates with real poles).
fn lane_sse_for<const L: usize, const SAME: bool>(
    lanes: &[(usize, Lane)],
    us: [&[f64]; L],
    ms: [&[f64]; L],
    wa: f64,
    lim: [f64; L],
    one: bool,
) -> Vec<f64> {
    let diag = lanes
        .iter()
        .all(|l| l.1.p.phi[0][1] == 0.0 && l.1.p.phi[1][0] == 0.0);
    macro_rules! go {
        ($one:literal, $diag:literal) => {
            if super::fma() {
                // SAFETY: the CPU supports FMA and AVX2 (checked just above).
                unsafe {
                    super::with_fma(
                        #[inline(always)]
                        || lane_sse::<L, true, SAME, $one, $diag>(lanes, us, ms, wa, lim),
                    )
                }
            } else {
                lane_sse::<L, false, SAME, $one, $diag>(lanes, us, ms, wa, lim)
            }
        };
    }
    match (one, diag) {
        (true, true) => go!(true, true),
        (true, false) => go!(true, false),
        (false, true) => go!(false, true),
        (false, false) => go!(false, false),
    }
}

/// The lanes' weighted SSE loop. With `SAME` every lane reads the same command and
/// measurement (several rows on one run: `us[0]`, `ms[0]`); otherwise lane `j` reads
/// its own (one row on several runs of equal length: one plant, so one dead time).
/// With `ONE` every lane has the same whole-sample dead time, and the delayed inputs
/// are one row of the line (otherwise each lane's is gathered from its own row).
/// With `DIAG` every lane's model block is diagonal (zero off-diagonal terms): the
/// update skips the two off-diagonal multiply-adds, which leaves each mode's chain
/// one multiply-add per sample instead of two through the other mode. Those terms
/// add an exact zero (`fma(0, z, t) = t`, a `-0` turned `+0` at most, which no cost
/// can tell: the response and its error square it away), so the costs are the same
/// bits either way, and the same as the kernel's, whose diagonal form skips them too.
#[inline(always)]
fn lane_sse<const L: usize, const F: bool, const SAME: bool, const ONE: bool, const DIAG: bool>(
    lanes: &[(usize, Lane)],
    us: [&[f64]; L],
    ms: [&[f64]; L],
    wa: f64,
    lim: [f64; L],
) -> Vec<f64> {
    use super::kernel::{madd, CHUNK, DIVERGED};
    let len = (0..L)
        .map(|j| us[j].len().min(ms[j].len()))
        .min()
        .unwrap_or(0);
    let us: [&[f64]; L] = std::array::from_fn(|j| &us[j][..len]);
    let ms: [&[f64]; L] = std::array::from_fn(|j| &ms[j][..len]);
    let nl = lanes.len();
    // Coefficients by lane (unused lanes repeat the first: their results are dropped).
    let pick = |k: usize| &lanes[k.min(nl - 1)].1;
    let col = |f: &dyn Fn(&Lane) -> f64| -> [f64; L] { std::array::from_fn(|k| f(pick(k))) };
    let (c0, c1) = (col(&|l| l.p.c[0]), col(&|l| l.p.c[1]));
    let k = col(&|l| l.p.k);
    let (g00, g01) = (col(&|l| l.p.g0[0]), col(&|l| l.p.g0[1]));
    let (g10, g11) = (col(&|l| l.p.g1[0]), col(&|l| l.p.g1[1]));
    let (p00, p01) = (col(&|l| l.p.phi[0][0]), col(&|l| l.p.phi[0][1]));
    let (p10, p11) = (col(&|l| l.p.phi[1][0]), col(&|l| l.p.phi[1][1]));
    let delay: [usize; L] = std::array::from_fn(|k| pick(k).p.delay);
    debug_assert!(!ONE || delay.iter().all(|&d| d == delay[0]));
    let cap = (delay.iter().max().copied().unwrap_or(0) + 2).next_power_of_two();
    let mask = cap - 1;
    let hist = col(&|l| l.w_hist);
    let mut ring = vec![[0.0; L]; cap];
    for slot in ring.iter_mut() {
        *slot = hist;
    }
    let mut z0 = col(&|l| l.z0[0]);
    let mut z1 = col(&|l| l.z0[1]);
    let mut wp = hist;
    let mut s = [0.0; L];
    let mut peak = [0.0; L];
    let bigger = |m: f64, x: f64| if x > m { x } else { m };
    // The kernel's checks (every CHUNK samples, as `Sse::proceed`): a lane whose
    // response diverged or whose weighted SSE reached its limit is abandoned; the
    // group stops once every lane is.
    let mut alive = [true; L];
    let mut from = 0;
    while from < len {
        let to = (from + CHUNK).min(len);
        for n in from..to {
            let mut y = [0.0; L];
            let mut w0 = [0.0; L];
            for j in 0..L {
                y[j] = madd::<F>(c1[j], z1[j], c0[j] * z0[j]);
            }
            let un: [f64; L] = if SAME {
                [us[0][n]; L]
            } else {
                std::array::from_fn(|j| us[j][n])
            };
            let mn: [f64; L] = if SAME {
                [ms[0][n]; L]
            } else {
                std::array::from_fn(|j| ms[j][n])
            };
            for j in 0..L {
                let e = y[j] - mn[j];
                s[j] += e * e;
                let ay = y[j].abs();
                peak[j] = bigger(bigger(peak[j], ay), ay);
            }
            let row = &mut ring[n & mask];
            for j in 0..L {
                row[j] = un[j] + k[j] * y[j];
            }
            if !ONE {
                for j in 0..L {
                    w0[j] = ring[n.wrapping_sub(delay[j]) & mask][j];
                }
            } else {
                // One delay on every lane: one row of the line.
                w0 = ring[n.wrapping_sub(delay[0]) & mask];
            }
            for j in 0..L {
                let w1 = wp[j];
                let t0 = madd::<F>(g10[j], w1, g00[j] * w0[j]);
                let t1 = madd::<F>(g11[j], w1, g01[j] * w0[j]);
                let (n0, n1) = if DIAG {
                    (madd::<F>(p00[j], z0[j], t0), madd::<F>(p11[j], z1[j], t1))
                } else {
                    (
                        madd::<F>(p00[j], z0[j], madd::<F>(p01[j], z1[j], t0)),
                        madd::<F>(p11[j], z1[j], madd::<F>(p10[j], z0[j], t1)),
                    )
                };
                z0[j] = n0;
                z1[j] = n1;
            }
            wp = w0;
        }
        let mut any = false;
        for j in 0..nl {
            let ok = peak[j] < DIVERGED && wa * s[j] + 0.0 * 0.0 + 0.0 * 0.0 < lim[j];
            alive[j] &= ok;
            any |= alive[j];
        }
        if !any {
            break;
        }
        from = to;
    }
    (0..nl)
        .map(|j| {
            let c = (wa * s[j] + 0.0 * 0.0 + 0.0 * 0.0) / len as f64;
            if alive[j] && peak[j] < DIVERGED && c.is_finite() {
                c
            } else {
                f64::INFINITY
            }
        })
        .collect()
}

/// Sums of the weighted squared errors (`wa ea² + wv ev² + wx ex²`, the Eq. 6 run
/// term before its division by the length) per *atom*: consecutive stretches of
/// `atom` samples (the last one shorter). A block bootstrap over time reweights these
/// sums (a resample is a vector of atom multiplicities), so one rollout of a
/// parameter row serves every resample.
struct AtomSse<'a, const FULL: bool, const RES: bool> {
    a: &'a [f64],
    v: &'a [f64],
    x: &'a [f64],
    w: [f64; 3],
    out: &'a mut [f64],
    /// With `RES`: the weighted residuals (see [`run_residuals`]), `nch` per sample.
    res: &'a mut [f64],
    sw: [f64; 3],
    nch: usize,
    atom: usize,
    /// The current atom and the first sample of the next one.
    cur: usize,
    next: usize,
    peak: f64,
}

impl<const FULL: bool, const RES: bool> kernel::Sink for AtomSse<'_, FULL, RES> {
    #[inline(always)]
    fn put(&mut self, n: usize, a: f64, v: f64, p: f64, _u: f64, y_lin: f64) {
        if n == self.next {
            self.cur += 1;
            self.next += self.atom;
        }
        let e = a - self.a[n];
        let mut s = self.w[0] * e * e;
        if FULL {
            let ev = v - self.v[n];
            let ex = p - self.x[n];
            s += self.w[1] * ev * ev + self.w[2] * ex * ex;
            self.peak = self.peak.max(v.abs());
            if RES {
                let mut k = n * self.nch;
                for (c, d) in [e, ev, ex].into_iter().enumerate() {
                    if self.w[c] > 0.0 {
                        self.res[k] = self.sw[c] * d;
                        k += 1;
                    }
                }
            }
        } else if RES {
            self.res[n] = self.sw[0] * e;
        }
        self.out[self.cur] += s;
        self.peak = self.peak.max(a.abs()).max(y_lin.abs());
    }

    #[inline(always)]
    fn proceed(&mut self, _: usize, _: usize) -> bool {
        // NaN makes `peak < DIVERGED` false only through the sums: check them too.
        self.peak < kernel::DIVERGED && self.out[self.cur].is_finite()
    }

    #[inline(always)]
    fn capacity(&self) -> usize {
        if FULL {
            self.a.len().min(self.v.len()).min(self.x.len())
        } else {
            self.a.len()
        }
    }
}

/// The number of atoms of `atom` samples in a run of `len` samples.
pub fn n_atoms(len: usize, atom: usize) -> usize {
    len.div_ceil(atom.max(1))
}

/// The weighted squared-error sums of `row` on `run` per atom of `atom` samples
/// (see [`n_atoms`]) into `out` (zeroed first); their total over the atoms divided by
/// the run's length is [`run_cost`] up to the summation order. Returns `false` (and
/// leaves `out` unspecified) for an invalid or unstable row or a diverged response,
/// where the cost is `inf`. Assumes `spec.validate(runs)` passed.
pub fn run_atom_sums(
    spec: &CostSpec,
    row: &[f64],
    run: &RunRef,
    atom: usize,
    out: &mut [f64],
) -> bool {
    run_residuals(spec, row, run, atom, out, &mut [])
}

/// The channels of positive weight (acceleration, speed, position) of `spec`.
pub fn residual_channels(spec: &CostSpec) -> usize {
    spec.weights.iter().filter(|w| **w > 0.0).count()
}

/// [`run_atom_sums`] and, in the same rollout, the weighted residuals behind them into
/// `res` (sample-major: for each sample `t` and each channel `c` of positive weight, in
/// the order acceleration, speed, position, `sqrt(w_c) (ŷ_c(t) - y_c(t))`;
/// `run.len() x` [`residual_channels`] values, or none when `res` is empty), so that
/// each atom's sum is the sum of its residuals' squares. Returns `false` where
/// [`run_atom_sums`] does, and for a `res` of another length.
pub fn run_residuals(
    spec: &CostSpec,
    row: &[f64],
    run: &RunRef,
    atom: usize,
    out: &mut [f64],
    res: &mut [f64],
) -> bool {
    if !res.is_empty() && res.len() != run.len() * residual_channels(spec) {
        return false;
    }
    let atom = atom.max(1);
    if out.len() != n_atoms(run.len(), atom) {
        return false;
    }
    out.iter_mut().for_each(|o| *o = 0.0);
    let Some((lin, effs, up)) = spec.prepare_cost(row, run) else {
        return false;
    };
    let modal = modal_ok(&effs);
    let ints = spec.integrators();
    let r: Result<bool> = (|| {
        with_plant!(
            &lin,
            ints,
            run.dt,
            modal,
            atoms_n(&lin, &effs, &up, spec, run, atom, &mut *out, &mut *res)
        )
    })();
    r.unwrap_or(false) && out.iter().all(|s| s.is_finite())
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn atoms_n<const M: usize, const N: usize, const D: bool, const F: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    effs: &[AnyEffect],
    up: &Upper,
    spec: &CostSpec,
    run: &RunRef,
    atom: usize,
    out: &mut [f64],
    res: &mut [f64],
) -> Result<bool> {
    if !loop_stable(lin, &plant) {
        return Ok(false);
    }
    if effs.is_empty() {
        atoms_chain::<M, N, D, F, _, _>(plant, lin, NoEffects, *up, spec, run, atom, out, res)
    } else {
        // The upper-level structures act through the law, as in the cost itself.
        let (ch, law) = with_effects(effs, up, run)?;
        atoms_chain::<M, N, D, F, _, _>(plant, lin, ch, law, spec, run, atom, out, res)
    }
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn atoms_chain<const M: usize, const N: usize, const D: bool, const F: bool, C: Chain, L: Law>(
    plant: Plant<M, N>,
    lin: &Linear,
    chain: C,
    mut law: L,
    spec: &CostSpec,
    run: &RunRef,
    atom: usize,
    out: &mut [f64],
    res: &mut [f64],
) -> Result<bool> {
    let len = run.len();
    let sw = spec.weights.map(f64::sqrt);
    let nch = residual_channels(spec);
    let mut st = start_stepper::<M, N, D, F, C>(plant, lin, chain, spec, run)?;
    let (u, lx, lv) = (
        run.command.unwrap_or(&[]),
        run.lead_x.unwrap_or(&[]),
        run.lead_v.unwrap_or(&[]),
    );
    macro_rules! go {
        ($full:literal, $res:literal, $v:expr, $x:expr) => {{
            let mut sink = AtomSse::<$full, $res> {
                a: run.a,
                v: $v,
                x: $x,
                w: spec.weights,
                out,
                res,
                sw,
                nch,
                atom,
                cur: 0,
                next: atom,
                peak: 0.0,
            };
            let done = if spec.closed_loop {
                kernel::run(
                    &mut st,
                    len,
                    |n, o| law.command(lx[n], lv[n], o.p, o.v),
                    &mut sink,
                )
            } else {
                kernel::run(&mut st, len, |n, _| u[n], &mut sink)
            };
            Ok(done && sink.peak < kernel::DIVERGED)
        }};
    }
    match (N == M, res.is_empty()) {
        (true, true) => go!(false, false, run.a, run.a),
        (true, false) => go!(false, true, run.a, run.a),
        (false, true) => go!(true, false, run.v.unwrap_or(run.a), run.x.unwrap_or(run.a)),
        (false, false) => go!(true, true, run.v.unwrap_or(run.a), run.x.unwrap_or(run.a)),
    }
}
