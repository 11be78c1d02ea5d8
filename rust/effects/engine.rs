//! The stepping engine for a base model plus a list of effects: open loop (driven
//! by a recorded command), closed loop (behind a recorded leader through the upper
//! law, paper Eq. 3) and the batched calibration cost.
//!
//! It follows the discretization convention of [`crate::discretize`] exactly (the
//! same `Discrete` maps, input history and fractional dead time), so with no effect
//! it reproduces [`crate::rollout`] (tested to 1e-12). Per sample `n`:
//! 1. `a_lin = C x` (acceleration command) and the actual speed and position
//!    `v = v_lin + dv`, `p = p_lin + dp`, where `v_lin, p_lin` are the exact linear
//!    integrators and `dv, dp` integrate the difference `a_act - a_lin` with the
//!    same zero-order hold (`dv += dt e`, `dp += dt dv + dt²/2 e`);
//! 2. `a_act = output(a_lin) + sum disturbance(v, exo[n])`;
//! 3. the command `u[n]` (recorded, or the upper law of the actual `p, v`) passes
//!    the command hooks; `u_ref = u' + K a_act` (the inner loop feeds back the
//!    actual acceleration) passes the reference maps into the dead-time buffer;
//! 4. the interval is stepped with the base maps, or with the braking maps
//!    (`asymmetric`) when the braking demand is negative, converting the model
//!    states between the two controllable canonical forms (`x_b = D x`,
//!    `D = diag(r², r)` or `(r)`), which keeps the output continuous.
//!
//! For a speed command the response `y` is the speed; only the command hooks and
//! `asymmetric` apply (`a` is the right-limit derivative of the speed).

use super::{AnyEffect, EffectList};
use crate::discretize::{discretize, equilibrium, Discrete, Integrators};
use crate::error::{check_series, AvllError, Result};
use crate::model::{CommandKind, Linear};
use crate::rollout::{CostSpec, Init, RunRef, Trajectory, Upper, DIVERGED};

#[inline(always)]
fn dot<const N: usize>(a: &[f64; N], x: &[f64; N]) -> f64 {
    let mut s = 0.0;
    for j in 0..N {
        s += a[j] * x[j];
    }
    s
}

/// The discretized base and (if any effect switches dynamics) braking maps.
struct Maps<const N: usize> {
    d: Discrete<N>,
    brake: Option<(Discrete<N>, [f64; 2])>,
    b0: f64,
}

fn maps<const N: usize>(
    lin: &Linear,
    effects: &[AnyEffect],
    ints: Integrators,
    dt: f64,
) -> Result<Maps<N>> {
    let d = discretize::<N>(lin, ints, dt)?;
    let r: f64 = effects.iter().map(|e| e.brake_time_scale()).product();
    let brake = if r != 1.0 {
        let lb = Linear {
            b1: r * lin.b1,
            b0: lin.b0,
            a2: r * r * lin.a2,
            a1: r * lin.a1,
            td: lin.td,
            k: lin.k,
        };
        let db = discretize::<N>(&lb, ints, dt)?;
        let scale = if lin.order() == 2 {
            [r * r, r]
        } else {
            [r, 1.0]
        };
        Some((db, scale))
    } else {
        None
    };
    Ok(Maps {
        d,
        brake,
        b0: lin.b0,
    })
}

/// Initial model state and reference-input history (as in [`crate::rollout`]).
fn initial<const N: usize>(lin: &Linear, init: Init, u0: f64) -> Result<([f64; N], f64, f64)> {
    let mut x = [0.0; N];
    match init {
        Init::Rest => Ok((x, 0.0, 0.0)),
        Init::Steady => {
            let den = 1.0 - lin.k * lin.b0;
            if den.abs() < 1e-12 {
                return Err(AvllError::new(
                    "init",
                    "no steady state: K * K0 = 1 (the inner loop has a pole at s = 0)",
                ));
            }
            let w = u0 / den;
            let e = equilibrium(lin, w);
            x[..lin.order()].copy_from_slice(&e[..lin.order()]);
            Ok((x, w, u0))
        }
    }
}

/// The engine's stepping loop. `input(n, v, p)` gives the command at sample `n`
/// from the actual speed and position; `out(n, a, v, p, u)` records and returns
/// `false` to stop. Returns `false` if stopped early.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn step_loop<const N: usize>(
    mp: &Maps<N>,
    kind: CommandKind,
    dt: f64,
    len: usize,
    x0: [f64; N],
    hist: f64,
    effects: &mut [AnyEffect],
    exo: &[Option<&[f64]>],
    mut input: impl FnMut(usize, f64, f64) -> f64,
    mut out: impl FnMut(usize, f64, f64, f64, f64) -> bool,
) -> bool {
    let d = &mp.d;
    let m = d.order;
    let i = d.delay_steps;
    let cap = (i + 2).next_power_of_two();
    let mask = cap - 1;
    let mut h = hist;
    for e in effects.iter() {
        h = e.reference(h);
    }
    let mut buf = vec![h; cap];
    let mut x = x0;
    let has_frac = d.frac > 0.0;
    let acc = kind == CommandKind::Acceleration;
    // Without integrators (a cost on the acceleration alone) speed and position are 0.
    let ints = N > m;
    let (mut dv, mut dp) = (0.0, 0.0);
    let half_dt2 = 0.5 * dt * dt;
    for n in 0..len {
        let y_lin = dot(&d.c, &x);
        if y_lin.abs() >= DIVERGED || y_lin.is_nan() {
            // The linear part diverged (an output clip may hide it).
            return false;
        }
        let (v, p, y_act) = if !ints {
            let mut a = y_lin;
            for e in effects.iter() {
                a = e.output(a);
            }
            for (e, s) in effects.iter().zip(exo) {
                a += e.disturbance(0.0, s.map_or(0.0, |s| s[n]));
            }
            (0.0, 0.0, if acc { a } else { y_lin })
        } else if acc {
            let v = x[m] + dv;
            let mut a = y_lin;
            for e in effects.iter() {
                a = e.output(a);
            }
            for (e, s) in effects.iter().zip(exo) {
                a += e.disturbance(v, s.map_or(0.0, |s| s[n]));
            }
            (v, x[m + 1] + dp, a)
        } else {
            (y_lin, x[m], y_lin)
        };
        let u = input(n, v, p);
        let mut uc = u;
        for e in effects.iter_mut() {
            uc = e.command(uc, y_act);
        }
        let mut r = uc + d.k * y_act;
        for e in effects.iter() {
            r = e.reference(r);
        }
        buf[n & mask] = r;
        let w0 = buf[n.wrapping_sub(i) & mask];
        let w1 = buf[n.wrapping_sub(i + 1) & mask];
        let wf = if has_frac { w1 } else { w0 };
        let brake = match &mp.brake {
            None => None,
            Some(b) => {
                let demand = if acc { w0 } else { mp.b0 * w0 - y_lin };
                if demand < 0.0 {
                    Some(b)
                } else {
                    None
                }
            }
        };
        match brake {
            None => {
                let a = if acc {
                    y_act
                } else {
                    dot(&d.ca, &x) + d.cb * wf
                };
                if !out(n, a, v, p, u) {
                    return false;
                }
                let mut nx = [0.0; N];
                for (r, o) in nx.iter_mut().enumerate() {
                    *o = dot(&d.phi[r], &x) + d.g0[r] * w0 + d.g1[r] * w1;
                }
                x = nx;
            }
            Some((db, s)) => {
                let mut xb = x;
                for j in 0..m {
                    xb[j] *= s[j];
                }
                let a = if acc {
                    y_act
                } else {
                    dot(&db.ca, &xb) + db.cb * wf
                };
                if !out(n, a, v, p, u) {
                    return false;
                }
                let mut nx = [0.0; N];
                for (r, o) in nx.iter_mut().enumerate() {
                    *o = dot(&db.phi[r], &xb) + db.g0[r] * w0 + db.g1[r] * w1;
                }
                for j in 0..m {
                    nx[j] /= s[j];
                }
                x = nx;
            }
        }
        if acc {
            let e = y_act - y_lin;
            dp += dt * dv + half_dt2 * e;
            dv += dt * e;
        }
    }
    true
}

macro_rules! with_dim {
    ($dim:expr, $f:ident ( $($arg:expr),* )) => {
        match $dim {
            1 => $f::<1>($($arg),*),
            2 => $f::<2>($($arg),*),
            3 => $f::<3>($($arg),*),
            4 => $f::<4>($($arg),*),
            d => Err(AvllError::new("model", format!("internal: unsupported state size {d}"))),
        }
    };
}

/// Resolves each effect's exogenous signal among the run's `exo` series.
pub fn resolve_exo<'a>(
    effects: &[AnyEffect],
    exo: &[(&str, &'a [f64])],
    len: usize,
) -> Result<Vec<Option<&'a [f64]>>> {
    effects
        .iter()
        .map(|e| match e.kind().exo() {
            None => Ok(None),
            Some(name) => match exo.iter().find(|(n, _)| *n == name) {
                Some((_, s)) => {
                    if s.len() != len {
                        return Err(AvllError::new(
                            format!("exo_{name}"),
                            format!("has length {} but must have length {len}", s.len()),
                        ));
                    }
                    check_series(&format!("exo_{name}"), s)?;
                    Ok(Some(*s))
                }
                None => Err(AvllError::new(
                    format!("exo_{name}"),
                    format!(
                        "effect {:?} needs the exogenous signal exo_{name}",
                        e.kind().name()
                    ),
                )),
            },
        })
        .collect()
}

fn check_kind(effects: &[AnyEffect], kind: CommandKind) -> Result<()> {
    if kind == CommandKind::Speed {
        if let Some(e) = effects.iter().find(|e| e.kind().accel_only()) {
            return Err(AvllError::new(
                "effects",
                format!(
                    "effect {:?} acts on the acceleration and needs an acceleration command",
                    e.kind().name()
                ),
            ));
        }
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn full_n<const N: usize>(
    lin: &Linear,
    effects: &mut [AnyEffect],
    kind: CommandKind,
    u: &[f64],
    dt: f64,
    init: Init,
    v0: f64,
    p0: f64,
    exo: &[Option<&[f64]>],
    tr: &mut Trajectory,
) -> Result<()> {
    let ints = Integrators::for_kind(kind);
    let mp = maps::<N>(lin, effects, ints, dt)?;
    let m = lin.order();
    let u0 = u.first().copied().unwrap_or(0.0);
    let (mut x0, hist, uh) = initial::<N>(lin, init, u0)?;
    for e in effects.iter_mut() {
        e.reset(uh, dt);
    }
    if kind == CommandKind::Acceleration {
        x0[m] = v0;
        x0[m + 1] = p0;
    } else {
        x0[m] = p0;
    }
    step_loop(
        &mp,
        kind,
        dt,
        u.len(),
        x0,
        hist,
        effects,
        exo,
        |n, _, _| u[n],
        |n, a, v, p, _| {
            tr.a[n] = a;
            tr.v[n] = v;
            tr.x[n] = p;
            true
        },
    );
    Ok(())
}

/// Open-loop rollout of a base model with effects (see [`crate::rollout::simulate_full`]
/// for the meaning of the arguments). `exo` holds the exogenous series by name.
#[allow(clippy::too_many_arguments)]
pub fn simulate_full(
    lin: &Linear,
    effects: &[AnyEffect],
    kind: CommandKind,
    u: &[f64],
    dt: f64,
    init: Init,
    v0: f64,
    p0: f64,
    exo: &[(&str, &[f64])],
) -> Result<Trajectory> {
    check_series("command", u)?;
    crate::error::check_finite("v0", v0)?;
    crate::error::check_finite("x0", p0)?;
    check_kind(effects, kind)?;
    let ex = resolve_exo(effects, exo, u.len())?;
    let mut effs = effects.to_vec();
    let n = u.len();
    let mut tr = Trajectory {
        a: vec![0.0; n],
        v: vec![0.0; n],
        x: vec![0.0; n],
        command: u.to_vec(),
    };
    let dim = lin.order() + Integrators::for_kind(kind).count();
    with_dim!(
        dim,
        full_n(lin, &mut effs, kind, u, dt, init, v0, p0, &ex, &mut tr)
    )?;
    Ok(tr)
}

#[allow(clippy::too_many_arguments)]
fn closed_n<const N: usize>(
    lin: &Linear,
    effects: &mut [AnyEffect],
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    v0: f64,
    p0: f64,
    exo: &[Option<&[f64]>],
    tr: &mut Trajectory,
) -> Result<()> {
    let mp = maps::<N>(lin, effects, Integrators::SpeedPosition, dt)?;
    let m = lin.order();
    for e in effects.iter_mut() {
        e.reset(0.0, dt);
    }
    let mut x0 = [0.0; N];
    x0[m] = v0;
    x0[m + 1] = p0;
    step_loop(
        &mp,
        CommandKind::Acceleration,
        dt,
        lead_x.len(),
        x0,
        0.0,
        effects,
        exo,
        |n, v, p| up.command(lead_x[n], lead_v[n], p, v),
        |n, a, v, p, u| {
            tr.a[n] = a;
            tr.v[n] = v;
            tr.x[n] = p;
            tr.command[n] = u;
            a.abs() < DIVERGED && a.is_finite() && v.is_finite()
        },
    );
    Ok(())
}

/// Closed-loop car following of a base model with effects behind a recorded leader
/// (the lower level starts at rest, as in [`crate::rollout::closed_loop`]). A diverged
/// follower's trajectory is NaN from the divergence on.
#[allow(clippy::too_many_arguments)]
pub fn closed_loop(
    lin: &Linear,
    effects: &[AnyEffect],
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    v0: f64,
    p0: f64,
    exo: &[(&str, &[f64])],
) -> Result<Trajectory> {
    up.validate()?;
    check_series("lead_x", lead_x)?;
    check_series("lead_v", lead_v)?;
    if lead_v.len() != lead_x.len() {
        return Err(AvllError::new(
            "lead_v",
            format!(
                "has length {} but must have length {}",
                lead_v.len(),
                lead_x.len()
            ),
        ));
    }
    crate::error::check_finite("v0", v0)?;
    crate::error::check_finite("x0", p0)?;
    let ex = resolve_exo(effects, exo, lead_x.len())?;
    let mut effs = effects.to_vec();
    let n = lead_x.len();
    let mut tr = Trajectory {
        a: vec![f64::NAN; n],
        v: vec![f64::NAN; n],
        x: vec![f64::NAN; n],
        command: vec![f64::NAN; n],
    };
    with_dim!(
        lin.order() + 2,
        closed_n(lin, &mut effs, up, lead_x, lead_v, dt, v0, p0, &ex, &mut tr)
    )?;
    Ok(tr)
}

// ---------------------------------------------------------------------------
// Batched cost over parameter rows `[base params | effect params | free upper]`.
// ---------------------------------------------------------------------------

/// A run with its exogenous series.
#[derive(Debug, Clone)]
pub struct EffRun<'a> {
    pub run: RunRef<'a>,
    pub exo: Vec<(&'a str, &'a [f64])>,
}

/// The cost of [`crate::rollout::CostSpec`] for a base model extended by effects.
#[derive(Debug, Clone, PartialEq)]
pub struct EffCostSpec {
    pub base: CostSpec,
    pub effects: EffectList,
}

impl EffCostSpec {
    /// Row length: base parameters, effect parameters, free upper-level parameters.
    pub fn n_params(&self) -> usize {
        self.base.model.n_params() + self.effects.n_params() + self.base.upper_free.len()
    }

    /// Validates the spec against the runs (including the exogenous signals).
    pub fn validate(&self, runs: &[EffRun]) -> Result<()> {
        let refs: Vec<RunRef> = runs.iter().map(|r| r.run).collect();
        self.base.validate(&refs)?;
        let neutral: Vec<f64> = self
            .effects
            .0
            .iter()
            .flat_map(|k| k.neutral().iter().copied())
            .collect();
        let effs = self.effects.build(&neutral, self.base.kind)?;
        for (j, r) in runs.iter().enumerate() {
            resolve_exo(&effs, &r.exo, r.run.len())
                .map_err(|e| AvllError::new(format!("runs[{j}].{}", e.arg), e.msg))?;
        }
        Ok(())
    }
}

/// Open loop, acceleration command, acceleration error only and no effect reading
/// the speed: the integrators are not needed (as in the linear cost's fast path).
fn fast_path(spec: &EffCostSpec) -> bool {
    let b = &spec.base;
    !b.closed_loop
        && b.kind == CommandKind::Acceleration
        && b.weights[1] == 0.0
        && b.weights[2] == 0.0
        && !spec.effects.0.iter().any(|k| k.needs_speed())
}

fn finite_or_inf(c: f64) -> f64 {
    if c.is_finite() {
        c
    } else {
        f64::INFINITY
    }
}

/// Cost of one row on one run; `inf` for invalid or unstable parameters. Assumes
/// `spec.validate(runs)` passed.
pub fn run_cost(spec: &EffCostSpec, row: &[f64], run: &EffRun) -> f64 {
    let nb = spec.base.model.n_params();
    let ne = spec.effects.n_params();
    let lin = match spec.base.model.linear(&row[..nb]) {
        Ok(l) => l,
        Err(_) => return f64::INFINITY,
    };
    let mut effs = match spec.effects.build(&row[nb..nb + ne], spec.base.kind) {
        Ok(e) => e,
        Err(_) => return f64::INFINITY,
    };
    let mut up = run.run.upper;
    for (j, &i) in spec.base.upper_free.iter().enumerate() {
        up.set(i, row[nb + ne + j]);
    }
    let exo = match resolve_exo(&effs, &run.exo, run.run.len()) {
        Ok(e) => e,
        Err(_) => return f64::INFINITY,
    };
    let ints = if fast_path(spec) {
        Integrators::None
    } else {
        Integrators::for_kind(spec.base.kind)
    };
    let dim = lin.order() + ints.count();
    let res = with_dim!(dim, cost_n(&lin, &mut effs, &up, spec, &run.run, &exo));
    finite_or_inf(res.unwrap_or(f64::INFINITY))
}

fn cost_n<const N: usize>(
    lin: &Linear,
    effects: &mut [AnyEffect],
    up: &Upper,
    spec: &EffCostSpec,
    run: &RunRef,
    exo: &[Option<&[f64]>],
) -> Result<f64> {
    let kind = spec.base.kind;
    let closed = spec.base.closed_loop;
    let ints = if fast_path(spec) {
        Integrators::None
    } else {
        Integrators::for_kind(kind)
    };
    let mp = maps::<N>(lin, effects, ints, run.dt)?;
    let m = lin.order();
    let len = run.len();
    let (mut x0, hist, uh) = if closed {
        ([0.0; N], 0.0, 0.0)
    } else {
        initial::<N>(lin, spec.base.init, run.command.map_or(0.0, |u| u[0]))?
    };
    for e in effects.iter_mut() {
        e.reset(uh, run.dt);
    }
    let v0 = run.v.map_or(0.0, |v| v[0]);
    let p0 = run.x.map_or(0.0, |x| x[0]);
    if N > m {
        if kind == CommandKind::Acceleration {
            x0[m] = v0;
            x0[m + 1] = p0;
        } else {
            x0[m] = p0;
        }
    }
    let [wa, wv, wx] = spec.base.weights;
    let (mut sa, mut sv, mut sx) = (0.0, 0.0, 0.0);
    let u = run.command.unwrap_or(&[]);
    let lx = run.lead_x.unwrap_or(&[]);
    let lv = run.lead_v.unwrap_or(&[]);
    let ok = step_loop(
        &mp,
        kind,
        run.dt,
        len,
        x0,
        hist,
        effects,
        exo,
        |n, v, p| {
            if closed {
                up.command(lx[n], lv[n], p, v)
            } else {
                u[n]
            }
        },
        |n, a, v, p, _| {
            let ea = a - run.a[n];
            sa += ea * ea;
            if wv > 0.0 {
                let e = v - run.v.map_or(0.0, |s| s[n]);
                sv += e * e;
            }
            if wx > 0.0 {
                let e = p - run.x.map_or(0.0, |s| s[n]);
                sx += e * e;
            }
            a.abs() < DIVERGED && v.abs() < DIVERGED && a.is_finite()
        },
    );
    let n = len as f64;
    Ok(crate::rollout::weighted_mse(
        ok,
        [wa, wv, wx],
        [sa, sv, sx],
        n,
    ))
}

/// Per-run costs of `P` rows (row-major, `spec.n_params()` each) on every run: a
/// `P x R` row-major matrix, evaluated in parallel. Invalid or unstable rows get
/// `inf`, never NaN. Validates the spec and the runs first.
pub fn batch_cost(spec: &EffCostSpec, params: &[f64], runs: &[EffRun]) -> Result<Vec<f64>> {
    spec.validate(runs)?;
    crate::rollout::cost_matrix(spec.n_params(), params, runs, |row, run| {
        run_cost(spec, row, run)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::EffectKind;
    use crate::rollout;

    fn proposed() -> Linear {
        Linear {
            b1: 6.7893,
            b0: 0.3479,
            a2: 1.2824,
            a1: 8.8157,
            td: 0.7903,
            k: 0.1008,
        }
    }

    fn cmd(n: usize) -> Vec<f64> {
        (0..n)
            .map(|k| {
                let t = k as f64 * 0.05;
                1.5 * (0.3 * t).sin() + 0.7 * (1.1 * t).cos()
            })
            .collect()
    }

    /// Largest difference relative to the signal's size (at least 1): the two
    /// engines do the same arithmetic in a different order.
    fn max_diff(a: &[f64], b: &[f64]) -> f64 {
        let scale = b.iter().fold(1.0f64, |m, y| m.max(y.abs()));
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
            / scale
    }

    #[test]
    fn no_effect_equals_linear_open_loop() {
        let u = cmd(3000);
        for init in [Init::Rest, Init::Steady] {
            for kind in [CommandKind::Acceleration, CommandKind::Speed] {
                let a =
                    rollout::simulate_full(&proposed(), kind, &u, 0.05, init, 3.0, 5.0).unwrap();
                let b =
                    simulate_full(&proposed(), &[], kind, &u, 0.05, init, 3.0, 5.0, &[]).unwrap();
                assert!(max_diff(&a.a, &b.a) < 1e-12);
                assert!(max_diff(&a.v, &b.v) < 1e-12);
                assert!(max_diff(&a.x, &b.x) < 1e-12);
            }
        }
    }

    #[test]
    fn neutral_effects_equal_linear_closed_loop() {
        let n = 4000;
        let dt = 0.05;
        let lv: Vec<f64> = (0..n)
            .map(|k| 10.0 + 2.0 * (0.2 * k as f64 * dt).sin())
            .collect();
        let mut lx = vec![100.0; n];
        for k in 1..n {
            lx[k] = lx[k - 1] + 0.5 * dt * (lv[k] + lv[k - 1]);
        }
        let up = Upper {
            kg: 0.5,
            kv: 0.1,
            tg: 2.0,
            gmin: 9.5,
        };
        let a = rollout::closed_loop(&proposed(), &up, &lx, &lv, dt, 10.0, 70.0).unwrap();
        // Neutral: delay 0, deadband 0, asymmetric (1, 1), grade 0, drag 0.
        let list = EffectList::from_names(
            &["delay", "deadband", "asymmetric", "grade", "speed_drag"],
            CommandKind::Acceleration,
        )
        .unwrap();
        let p: Vec<f64> = list
            .0
            .iter()
            .flat_map(|k| k.neutral().iter().copied())
            .collect();
        let effs = list.build(&p, CommandKind::Acceleration).unwrap();
        let g = vec![0.01; n];
        let b = closed_loop(
            &proposed(),
            &effs,
            &up,
            &lx,
            &lv,
            dt,
            10.0,
            70.0,
            &[("grade", &g)],
        )
        .unwrap();
        let d = max_diff(&a.a, &b.a);
        assert!(d < 1e-11, "{d}"); // closed-loop rounding accumulates over the run
        assert!(max_diff(&a.x, &b.x) < 1e-11);
        assert!(max_diff(&a.command, &b.command) < 1e-11);
    }

    #[test]
    fn asymmetric_braking_side_equals_scaled_model() {
        // A command that stays negative: the braking dynamics kb G(rb s) throughout.
        let u: Vec<f64> = cmd(2000).iter().map(|x| -x.abs() - 0.1).collect();
        let lin = Linear {
            k: 0.0,
            ..proposed()
        };
        let e = EffectList::from_names(&["asymmetric"], CommandKind::Acceleration)
            .unwrap()
            .build(&[0.7, 1.6], CommandKind::Acceleration)
            .unwrap();
        let got = simulate_full(
            &lin,
            &e,
            CommandKind::Acceleration,
            &u,
            0.05,
            Init::Rest,
            0.0,
            0.0,
            &[],
        )
        .unwrap();
        let lb = e[0]
            .linearize(&lin, &crate::effects::Operating { v: 0.0, side: -1 })
            .unwrap();
        let want = rollout::simulate(&lb, &u, 0.05, Init::Rest).unwrap();
        assert!(
            max_diff(&got.a, &want) < 1e-10,
            "{}",
            max_diff(&got.a, &want)
        );
    }

    #[test]
    fn saturation_clips_and_speed_integrates_the_clip() {
        let u = vec![3.0; 400];
        let lin = Linear {
            b1: 0.0,
            b0: 1.0,
            a2: 0.0,
            a1: 0.5,
            td: 0.0,
            k: 0.0,
        };
        let e = EffectList::from_names(&["saturation"], CommandKind::Acceleration)
            .unwrap()
            .build(&[1.5, 2.0], CommandKind::Acceleration)
            .unwrap();
        let tr = simulate_full(
            &lin,
            &e,
            CommandKind::Acceleration,
            &u,
            0.05,
            Init::Rest,
            0.0,
            0.0,
            &[],
        )
        .unwrap();
        assert!(tr.a.iter().all(|a| *a <= 1.5 + 1e-15));
        assert!((tr.a[399] - 1.5).abs() < 1e-12);
        // Once clipped, speed grows by exactly 1.5 dt per sample.
        assert!((tr.v[399] - tr.v[398] - 1.5 * 0.05).abs() < 1e-12);
    }

    #[test]
    fn invalid_rows_cost_inf() {
        let u = cmd(500);
        let a = u.clone();
        let spec = EffCostSpec {
            base: CostSpec {
                model: crate::model::ModelKind::Proposed,
                kind: CommandKind::Acceleration,
                weights: [1.0, 0.0, 0.0],
                init: Init::Rest,
                closed_loop: false,
                upper_free: vec![],
            },
            effects: EffectList(vec![EffectKind::Saturation]),
        };
        let run = EffRun {
            run: RunRef {
                dt: 0.05,
                command: Some(&u),
                lead_x: None,
                lead_v: None,
                a: &a,
                v: None,
                x: None,
                upper: Upper {
                    kg: 0.5,
                    kv: 0.0,
                    tg: 2.0,
                    gmin: 9.5,
                },
            },
            exo: vec![],
        };
        let rows = [
            6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008, 1.0, 1.0, // fine
            6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008, -1.0, 1.0, // a_max < 0
            1.0, 1.0, -5.0, 1.0, 0.1, 0.0, 1.0, 1.0, // unstable G (hidden by the clip)
        ];
        let c = batch_cost(&spec, &rows, &[run]).unwrap();
        assert!(c[0].is_finite(), "{c:?}");
        assert_eq!(c[1], f64::INFINITY, "{c:?}");
        assert_eq!(c[2], f64::INFINITY);
    }
}
