//! Rollouts: open loop (driven by a recorded command), closed loop (driven by a
//! leader through the upper-level constant-time-gap law, paper Eq. 3), platoons,
//! and the batched calibration cost (paper Eq. 6).
//!
//! Initial conditions (stated once, applied identically in `avll.reference`):
//! * `Init::Rest` — zero model state, zero input history, `y[0] = 0`;
//! * `Init::Steady` — the lower level at the equilibrium of the first command
//!   sample held forever: `w = u[0] / (1 - K b0)` fills the input history, the
//!   model states sit at `A x + B w = 0`, so `y[0] = b0 w` (the DC response);
//! * the integrators (speed, position) start at the given `v0`, `p0`.
//!
//! Closed loop and platoons start the lower level at rest (zero acceleration,
//! zero history); the follower's speed and position start at the given values.

use crate::discretize::{discretize, equilibrium, inner_loop_stable, Discrete, Integrators};
use crate::error::{check_series, AvllError, Result};
use crate::model::{CommandKind, Linear, ModelKind};
use rayon::prelude::*;

/// Responses beyond this magnitude (m/s² or m/s) count as divergence.
pub const DIVERGED: f64 = 1e6;

/// How the lower level starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Init {
    Rest,
    Steady,
}

impl Init {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "rest" => Ok(Init::Rest),
            "steady" => Ok(Init::Steady),
            _ => Err(AvllError::new(
                "init",
                format!("must be 'rest' or 'steady', got {name:?}"),
            )),
        }
    }
}

/// Upper-level constant-time-gap law, paper Eq. 3:
/// `a_cmd = kg (x_lead - x - Tg v - Gmin) + kv (v_lead - v)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Upper {
    pub kg: f64,
    pub kv: f64,
    pub tg: f64,
    pub gmin: f64,
}

impl Upper {
    pub const NAMES: [&'static str; 4] = ["kg", "kv", "Tg", "Gmin"];

    #[inline(always)]
    pub fn command(&self, lead_x: f64, lead_v: f64, x: f64, v: f64) -> f64 {
        self.kg * (lead_x - x - self.tg * v - self.gmin) + self.kv * (lead_v - v)
    }

    pub fn validate(&self) -> Result<()> {
        for (n, x) in Self::NAMES
            .iter()
            .zip([self.kg, self.kv, self.tg, self.gmin])
        {
            crate::error::check_finite(n, x)?;
        }
        Ok(())
    }

    pub fn get(&self, i: usize) -> f64 {
        [self.kg, self.kv, self.tg, self.gmin][i]
    }

    pub fn set(&mut self, i: usize, x: f64) {
        match i {
            0 => self.kg = x,
            1 => self.kv = x,
            2 => self.tg = x,
            _ => self.gmin = x,
        }
    }
}

/// A simulated trajectory. For an acceleration command `a` is the response and
/// `v`, `x` its integrals; for a speed command `v` is the response, `a` its time
/// derivative at each sample (right limit) and `x` its integral.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    pub a: Vec<f64>,
    pub v: Vec<f64>,
    pub x: Vec<f64>,
    /// Command fed to the lower level (closed loop: the upper law's output).
    pub command: Vec<f64>,
}

#[inline(always)]
fn dot<const N: usize>(a: &[f64; N], x: &[f64; N]) -> f64 {
    let mut s = 0.0;
    for j in 0..N {
        s += a[j] * x[j];
    }
    s
}

/// `t + row . x`, summed as a shallow tree with `t` (the input terms, known before
/// the state) added last: the state-to-state latency of a step is one multiply and
/// `ceil(log2 N) + 1` adds instead of a chain of `N + 2` dependent operations.
#[inline(always)]
fn affine<const N: usize>(row: &[f64; N], x: &[f64; N], t: f64) -> f64 {
    let (r, x) = (&row[..], &x[..]);
    match N {
        1 => t + r[0] * x[0],
        2 => t + (r[0] * x[0] + r[1] * x[1]),
        3 => (t + r[2] * x[2]) + (r[0] * x[0] + r[1] * x[1]),
        4 => t + ((r[0] * x[0] + r[1] * x[1]) + (r[2] * x[2] + r[3] * x[3])),
        _ => {
            let mut s = t;
            for j in 0..N {
                s += r[j] * x[j];
            }
            s
        }
    }
}

/// One exact step: `x[n+1] = Phi x[n] + G0 w0 + G1 w1` (`w0` held over the last
/// `(1-f) dt`, `w1` over the first `f dt`).
#[inline(always)]
fn advance<const N: usize>(d: &Discrete<N>, x: &[f64; N], w0: f64, w1: f64) -> [f64; N] {
    std::array::from_fn(|r| affine(&d.phi[r], x, d.g0[r] * w0 + d.g1[r] * w1))
}

/// The one stepping loop every rollout uses. `input(n, x)` gives the command at
/// sample `n`; `out(n, x, y, u, w_first)` records it and returns `false` to stop.
/// Returns `false` if stopped early.
#[inline(always)]
fn step_loop<const N: usize>(
    d: &Discrete<N>,
    len: usize,
    x0: [f64; N],
    hist: f64,
    mut input: impl FnMut(usize, &[f64; N]) -> f64,
    mut out: impl FnMut(usize, &[f64; N], f64, f64, f64) -> bool,
) -> bool {
    let i = d.delay_steps;
    let cap = (i + 2).next_power_of_two();
    let mask = cap - 1;
    let mut buf = vec![hist; cap];
    let mut x = x0;
    let has_frac = d.frac > 0.0;
    for n in 0..len {
        let y = dot(&d.c, &x);
        let u = input(n, &x);
        let r = u + d.k * y;
        buf[n & mask] = r;
        // Without whole-sample delay the new input acts at once: keep it in a register
        // (a round trip through the delay line would lengthen the loop's latency).
        let w0 = if i == 0 {
            r
        } else {
            buf[n.wrapping_sub(i) & mask]
        };
        let w1 = buf[n.wrapping_sub(i + 1) & mask];
        let wf = if has_frac { w1 } else { w0 };
        if !out(n, &x, y, u, wf) {
            return false;
        }
        x = advance(d, &x, w0, w1);
    }
    true
}

/// The open-loop kernel behind `simulate` and the fast cost path: model states only,
/// driven by the recorded command `u`; `sink(n, y[n])` returns `false` to stop early
/// (then this returns `false`). Without inner feedback (`K = 0`) the delayed input is
/// the command itself, read straight from `u` (no delay line, no dependence of the
/// input on the state); with feedback it falls back to [`step_loop`].
#[inline(always)]
fn open_loop<const N: usize>(
    d: &Discrete<N>,
    u: &[f64],
    x0: [f64; N],
    hist: f64,
    mut sink: impl FnMut(usize, f64) -> bool,
) -> bool {
    if d.k != 0.0 {
        return step_loop(
            d,
            u.len(),
            x0,
            hist,
            |n, _| u[n],
            |n, _, y, _, _| sink(n, y),
        );
    }
    let i = d.delay_steps;
    let len = u.len();
    let w = |k: usize| if k <= i { hist } else { u[k - i - 1] };
    let mut x = x0;
    // Head: the delayed inputs still reach into the history (n - i - 1 < 0).
    let head = (i + 1).min(len);
    for n in 0..head {
        if !sink(n, dot(&d.c, &x)) {
            return false;
        }
        // w0 = u[n-i] (history if n < i), w1 = u[n-i-1] (history)
        x = advance(d, &x, w(n + 1), w(n));
    }
    // Body: w1 = u[n-i-1] = pair[0], w0 = u[n-i] = pair[1].
    for (n, pair) in (head..len).zip(u.windows(2)) {
        if !sink(n, dot(&d.c, &x)) {
            return false;
        }
        x = advance(d, &x, pair[1], pair[0]);
    }
    true
}

/// Initial model state and input history for an open-loop run.
fn initial<const N: usize>(lin: &Linear, init: Init, u0: f64) -> Result<([f64; N], f64)> {
    let mut x = [0.0; N];
    match init {
        Init::Rest => Ok((x, 0.0)),
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
            Ok((x, w))
        }
    }
}

fn check_len(arg: &str, xs: &[f64], len: usize) -> Result<()> {
    if xs.len() != len {
        return Err(AvllError::new(
            arg,
            format!("has length {} but must have length {len}", xs.len()),
        ));
    }
    Ok(())
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

fn response_n<const N: usize>(
    lin: &Linear,
    u: &[f64],
    dt: f64,
    init: Init,
    y: &mut [f64],
) -> Result<()> {
    let d = discretize::<N>(lin, Integrators::None, dt)?;
    let (x0, hist) = initial::<N>(lin, init, u.first().copied().unwrap_or(0.0))?;
    open_loop(&d, u, x0, hist, |n, yy| {
        y[n] = yy;
        true
    });
    Ok(())
}

/// Open-loop response (acceleration for an acceleration command, speed for a speed
/// command) into `y`, under the discretization convention of [`crate::discretize`].
pub fn simulate_into(lin: &Linear, u: &[f64], dt: f64, init: Init, y: &mut [f64]) -> Result<()> {
    check_series("command", u)?;
    check_len("out", y, u.len())?;
    with_dim!(lin.order(), response_n(lin, u, dt, init, y))
}

/// Open-loop response as a new vector.
pub fn simulate(lin: &Linear, u: &[f64], dt: f64, init: Init) -> Result<Vec<f64>> {
    let mut y = vec![0.0; u.len()];
    simulate_into(lin, u, dt, init, &mut y)?;
    Ok(y)
}

#[allow(clippy::too_many_arguments)]
fn full_n<const N: usize>(
    lin: &Linear,
    kind: CommandKind,
    u: &[f64],
    dt: f64,
    init: Init,
    v0: f64,
    p0: f64,
    tr: &mut Trajectory,
) -> Result<()> {
    let ints = Integrators::for_kind(kind);
    let d = discretize::<N>(lin, ints, dt)?;
    let m = lin.order();
    let (mut x0, hist) = initial::<N>(lin, init, u.first().copied().unwrap_or(0.0))?;
    match kind {
        CommandKind::Acceleration => {
            x0[m] = v0;
            x0[m + 1] = p0;
            step_loop(
                &d,
                u.len(),
                x0,
                hist,
                |n, _| u[n],
                |n, x, y, _, _| {
                    tr.a[n] = y;
                    tr.v[n] = x[m];
                    tr.x[n] = x[m + 1];
                    true
                },
            );
        }
        CommandKind::Speed => {
            x0[m] = p0;
            step_loop(
                &d,
                u.len(),
                x0,
                hist,
                |n, _| u[n],
                |n, x, y, _, wf| {
                    tr.v[n] = y;
                    tr.a[n] = dot(&d.ca, x) + d.cb * wf;
                    tr.x[n] = x[m];
                    true
                },
            );
        }
    }
    Ok(())
}

/// Open-loop rollout with the integrated states (see [`Trajectory`]). `v0`, `p0`
/// are the initial speed and position (for a speed command with `Init::Steady`
/// the initial speed is the model's equilibrium and `v0` is not used).
pub fn simulate_full(
    lin: &Linear,
    kind: CommandKind,
    u: &[f64],
    dt: f64,
    init: Init,
    v0: f64,
    p0: f64,
) -> Result<Trajectory> {
    check_series("command", u)?;
    crate::error::check_finite("v0", v0)?;
    crate::error::check_finite("x0", p0)?;
    let n = u.len();
    let mut tr = Trajectory {
        a: vec![0.0; n],
        v: vec![0.0; n],
        x: vec![0.0; n],
        command: u.to_vec(),
    };
    let dim = lin.order() + Integrators::for_kind(kind).count();
    with_dim!(dim, full_n(lin, kind, u, dt, init, v0, p0, &mut tr))?;
    Ok(tr)
}

/// Writes one closed-loop follower into the given output slices; returns the number
/// of samples written: all of them, or up to and including the one where the
/// response diverged (the rest of the outputs are then left unwritten).
#[allow(clippy::too_many_arguments)]
fn closed_n<const N: usize>(
    d: &Discrete<N>,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    v0: f64,
    p0: f64,
    a: &mut [f64],
    v: &mut [f64],
    x: &mut [f64],
    cmd: &mut [f64],
) -> usize {
    let m = d.order;
    let mut s0 = [0.0; N];
    s0[m] = v0;
    s0[m + 1] = p0;
    let mut stopped = None;
    step_loop(
        d,
        lead_x.len(),
        s0,
        0.0,
        |n, s| up.command(lead_x[n], lead_v[n], s[m + 1], s[m]),
        |n, s, y, u, _| {
            a[n] = y;
            v[n] = s[m];
            x[n] = s[m + 1];
            cmd[n] = u;
            let ok = y.abs() < DIVERGED && y.is_finite();
            if !ok {
                stopped = Some(n + 1);
            }
            ok
        },
    );
    stopped.unwrap_or(lead_x.len())
}

fn closed_loop_n<const N: usize>(
    lin: &Linear,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    v0: f64,
    p0: f64,
) -> Result<Trajectory> {
    let d = discretize::<N>(lin, Integrators::SpeedPosition, dt)?;
    let n = lead_x.len();
    let mut tr = Trajectory {
        a: vec![0.0; n],
        v: vec![0.0; n],
        x: vec![0.0; n],
        command: vec![0.0; n],
    };
    let written = closed_n(
        &d,
        up,
        lead_x,
        lead_v,
        v0,
        p0,
        &mut tr.a,
        &mut tr.v,
        &mut tr.x,
        &mut tr.command,
    );
    // Diverged: NaN from the sample after the divergence on.
    for s in [&mut tr.a, &mut tr.v, &mut tr.x, &mut tr.command] {
        s[written..].fill(f64::NAN);
    }
    Ok(tr)
}

fn check_leader(lead_x: &[f64], lead_v: &[f64]) -> Result<()> {
    check_series("lead_x", lead_x)?;
    check_series("lead_v", lead_v)?;
    check_len("lead_v", lead_v, lead_x.len())
}

/// Closed-loop car following behind a recorded leader (acceleration command from
/// the upper law Eq. 3, evaluated at the samples). If the follower diverges
/// (|a| > [`DIVERGED`]) the rest of the trajectory is NaN.
pub fn closed_loop(
    lin: &Linear,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    v0: f64,
    p0: f64,
) -> Result<Trajectory> {
    up.validate()?;
    check_leader(lead_x, lead_v)?;
    crate::error::check_finite("v0", v0)?;
    crate::error::check_finite("x0", p0)?;
    with_dim!(
        lin.order() + 2,
        closed_loop_n(lin, up, lead_x, lead_v, dt, v0, p0)
    )
}

/// A platoon of `followers` identical vehicles behind a recorded leader. Each
/// follower starts at the leader's initial speed, at the equilibrium gap
/// `Gmin + Tg v` behind its predecessor, with the lower level at rest. Returns one
/// trajectory per follower (leader excluded). A diverged follower's trajectory is
/// NaN from the divergence on, and so are the followers behind it.
pub fn platoon(
    lin: &Linear,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    followers: usize,
) -> Result<Vec<Trajectory>> {
    up.validate()?;
    check_leader(lead_x, lead_v)?;
    if lead_x.is_empty() {
        return Err(AvllError::new("lead_x", "is empty"));
    }
    let v0 = lead_v[0];
    let mut out: Vec<Trajectory> = Vec::with_capacity(followers);
    for _ in 0..followers {
        let (px, pv, p0) = match out.last() {
            None => (lead_x, lead_v, lead_x[0]),
            Some(t) => (&t.x[..], &t.v[..], t.x[0]),
        };
        let start = p0 - (up.gmin + up.tg * v0);
        let tr = if px.iter().any(|x| !x.is_finite()) {
            let n = lead_x.len();
            Trajectory {
                a: vec![f64::NAN; n],
                v: vec![f64::NAN; n],
                x: vec![f64::NAN; n],
                command: vec![f64::NAN; n],
            }
        } else {
            with_dim!(
                lin.order() + 2,
                closed_loop_n(lin, up, px, pv, dt, v0, start)
            )?
        };
        out.push(tr);
    }
    Ok(out)
}

// ---------------------------------------------------------------------------
// Batched cost (paper Eq. 6), the GA's objective.
// ---------------------------------------------------------------------------

/// One measured run, borrowed. Open loop uses `command`; closed loop uses the
/// leader (`lead_x`, `lead_v`) and `upper`.
#[derive(Debug, Clone, Copy)]
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
    pub kind: CommandKind,
    /// Weights of the mean squared errors of acceleration, speed and position
    /// (the gap error equals the position error behind a recorded leader).
    pub weights: [f64; 3],
    pub init: Init,
    /// Closed loop: driven by the leader through the upper law.
    pub closed_loop: bool,
    /// Indices (0 kg, 1 kv, 2 Tg, 3 Gmin) of upper-level parameters that are
    /// calibrated: their values follow the model parameters in each parameter row,
    /// in this order, and override the runs' own.
    pub upper_free: Vec<usize>,
}

impl CostSpec {
    /// Length of a parameter row.
    pub fn n_params(&self) -> usize {
        self.model.n_params() + self.upper_free.len()
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
                        check_len(&name(what), s, n)?;
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
        }
        Ok(())
    }
}

fn finite_or_inf(c: f64) -> f64 {
    if c.is_finite() {
        c
    } else {
        f64::INFINITY
    }
}

/// Cost of one parameter row on one run; `inf` for invalid parameters, for a lower
/// level that is not asymptotically stable (see
/// [`crate::discretize::inner_loop_stable`]: whatever the run's length), and for a
/// response that leaves `|y| < DIVERGED`. Assumes `spec.validate(runs)` passed.
pub fn run_cost(spec: &CostSpec, row: &[f64], run: &RunRef) -> f64 {
    let np = spec.model.n_params();
    let lin = match spec.model.linear(&row[..np]) {
        Ok(l) => l,
        Err(_) => return f64::INFINITY,
    };
    let mut up = run.upper;
    for (j, &i) in spec.upper_free.iter().enumerate() {
        up.set(i, row[np + j]);
    }
    let dim_full = lin.order() + Integrators::for_kind(spec.kind).count();
    let res = if spec.closed_loop {
        with_dim!(dim_full, cost_closed(&lin, &up, spec, run))
    } else if spec.kind == CommandKind::Acceleration
        && spec.weights[1] == 0.0
        && spec.weights[2] == 0.0
    {
        cost_open_accel(&lin, spec, run)
    } else {
        with_dim!(dim_full, cost_open_full(&lin, spec, run))
    };
    finite_or_inf(res.unwrap_or(f64::INFINITY))
}

/// The fast path: acceleration command, acceleration error only.
fn cost_open_accel(lin: &Linear, spec: &CostSpec, run: &RunRef) -> Result<f64> {
    let s = open_accel_sse(lin, spec.init, run, f64::INFINITY);
    Ok(if s.is_finite() {
        spec.weights[0] * s / run.len() as f64
    } else {
        f64::INFINITY
    })
}

/// Sum of squared acceleration errors of the open-loop rollout of `lin` driven by
/// `run.command` (an acceleration command) — the kernel of the fast cost path
/// (`cost = weight_a * sse / len`), public so that callers with a bound (the GA's
/// early abandoning) get bit-identical values. `inf` if the parameters are invalid
/// for `run.dt`, the lower level is not asymptotically stable
/// ([`inner_loop_stable`]), the response leaves `|y| < DIVERGED`, or the partial
/// sum reaches `limit` (checked every 64 samples; pass `inf` for no bound).
pub fn open_accel_sse(lin: &Linear, init: Init, run: &RunRef, limit: f64) -> f64 {
    let r = match lin.order() {
        1 => open_accel_sse_n::<1>(lin, init, run, limit),
        _ => open_accel_sse_n::<2>(lin, init, run, limit),
    };
    r.unwrap_or(f64::INFINITY)
}

fn open_accel_sse_n<const N: usize>(
    lin: &Linear,
    init: Init,
    run: &RunRef,
    limit: f64,
) -> Result<f64> {
    let u = run.command.unwrap_or(&[]);
    if u.is_empty() || run.a.len() != u.len() {
        return Ok(f64::INFINITY);
    }
    let d = discretize::<N>(lin, Integrators::None, run.dt)?;
    if !inner_loop_stable(&d, lin) {
        return Ok(f64::INFINITY);
    }
    let (x0, hist) = initial::<N>(lin, init, u[0])?;
    let meas = run.a;
    let mut s = 0.0;
    let ok = open_loop(&d, u, x0, hist, |n, y| {
        let e = y - meas[n];
        s += e * e;
        y.abs() < DIVERGED && !(n & 63 == 63 && s >= limit)
    });
    Ok(if ok { s } else { f64::INFINITY })
}

fn cost_open_full<const N: usize>(lin: &Linear, spec: &CostSpec, run: &RunRef) -> Result<f64> {
    let u = run.command.unwrap_or(&[]);
    let d = discretize::<N>(lin, Integrators::for_kind(spec.kind), run.dt)?;
    if !inner_loop_stable(&d, lin) {
        return Ok(f64::INFINITY);
    }
    let m = lin.order();
    let (mut x0, hist) = initial::<N>(lin, spec.init, u[0])?;
    let v0 = run.v.map_or(0.0, |v| v[0]);
    let p0 = run.x.map_or(0.0, |x| x[0]);
    let acc = spec.kind == CommandKind::Acceleration;
    if acc {
        x0[m] = v0;
        x0[m + 1] = p0;
    } else {
        x0[m] = p0;
    }
    let [wa, wv, wx] = spec.weights;
    let (mut sa, mut sv, mut sx) = (0.0, 0.0, 0.0);
    let ok = step_loop(
        &d,
        u.len(),
        x0,
        hist,
        |n, _| u[n],
        |n, x, y, _, wf| {
            let (a, v, p) = if acc {
                (y, x[m], x[m + 1])
            } else {
                (dot(&d.ca, x) + d.cb * wf, y, x[m])
            };
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
            y.abs() < DIVERGED
        },
    );
    let n = u.len() as f64;
    Ok(weighted_mse(ok, [wa, wv, wx], [sa, sv, sx], n))
}

fn cost_closed<const N: usize>(
    lin: &Linear,
    up: &Upper,
    spec: &CostSpec,
    run: &RunRef,
) -> Result<f64> {
    let d = discretize::<N>(lin, Integrators::SpeedPosition, run.dt)?;
    if !inner_loop_stable(&d, lin) {
        return Ok(f64::INFINITY);
    }
    let lx = run.lead_x.unwrap_or(&[]);
    let lv = run.lead_v.unwrap_or(&[]);
    let vm = run.v.unwrap_or(&[]);
    let xm = run.x.unwrap_or(&[]);
    let m = d.order;
    let mut s0 = [0.0; N];
    s0[m] = vm[0];
    s0[m + 1] = xm[0];
    let [wa, wv, wx] = spec.weights;
    let (mut sa, mut sv, mut sx) = (0.0, 0.0, 0.0);
    let ok = step_loop(
        &d,
        lx.len(),
        s0,
        0.0,
        |n, s| up.command(lx[n], lv[n], s[m + 1], s[m]),
        |n, s, y, _, _| {
            let ea = y - run.a[n];
            let ev = s[m] - vm[n];
            let ex = s[m + 1] - xm[n];
            sa += ea * ea;
            sv += ev * ev;
            sx += ex * ex;
            y.abs() < DIVERGED
        },
    );
    let n = lx.len() as f64;
    Ok(weighted_mse(ok, [wa, wv, wx], [sa, sv, sx], n))
}

/// Costs of `P` parameter rows (row-major, `spec.n_params()` each) on every run:
/// a `P x R` row-major matrix of per-run costs, evaluated in parallel. Invalid or
/// unstable rows get `inf`. Validates the spec and the runs first.
pub fn batch_cost(spec: &CostSpec, params: &[f64], runs: &[RunRef]) -> Result<Vec<f64>> {
    spec.validate(runs)?;
    cost_matrix(spec.n_params(), params, runs, |row, run| {
        run_cost(spec, row, run)
    })
}

/// Evaluates `cost(row, run)` for every parameter row (row-major, `np` values each) and
/// every run, in parallel: a `P x R` row-major matrix. Shared by every batched cost.
pub fn cost_matrix<R: Sync>(
    np: usize,
    params: &[f64],
    runs: &[R],
    cost: impl Fn(&[f64], &R) -> f64 + Sync,
) -> Result<Vec<f64>> {
    if np == 0 || !params.len().is_multiple_of(np) {
        return Err(AvllError::new(
            "params",
            format!(
                "length {} is not a multiple of the row length {np}",
                params.len()
            ),
        ));
    }
    let p = params.len() / np;
    let r = runs.len();
    let mut out = vec![0.0; p * r];
    out.par_iter_mut().enumerate().for_each(|(k, o)| {
        let (i, j) = (k / r, k % r);
        *o = cost(&params[i * np..(i + 1) * np], &runs[j]);
    });
    Ok(out)
}

/// The Eq. 6 run cost from the sums of squared errors of acceleration, speed and
/// position over `n` samples: `sum(w s) / n`, or `inf` when the rollout diverged.
pub fn weighted_mse(ok: bool, w: [f64; 3], sums: [f64; 3], n: f64) -> f64 {
    if ok {
        (w[0] * sums[0] + w[1] * sums[1] + w[2] * sums[2]) / n
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn first_order_step_is_analytic() {
        let lin = Linear {
            b1: 0.0,
            b0: 1.0,
            a2: 0.0,
            a1: 1.0758,
            td: 0.0,
            k: 0.0,
        };
        let dt = 0.05;
        let u = vec![1.0; 200];
        let y = simulate(&lin, &u, dt, Init::Rest).unwrap();
        for (n, yn) in y.iter().enumerate() {
            let t = n as f64 * dt;
            assert!((yn - (1.0 - (-t / 1.0758).exp())).abs() < 1e-12, "n={n}");
        }
    }

    #[test]
    fn second_order_step_with_integer_delay_is_analytic() {
        // K0/((s+1)(s+2)) * 2 = 2K0/(s^2+3s+2) -> m2 = 0.5, m3 = 1.5.
        let k0 = 0.8;
        let lin = Linear {
            b1: 0.0,
            b0: k0,
            a2: 0.5,
            a1: 1.5,
            td: 0.3,
            k: 0.0,
        };
        let dt = 0.05;
        let u = vec![1.0; 300];
        let y = simulate(&lin, &u, dt, Init::Rest).unwrap();
        for (n, yn) in y.iter().enumerate() {
            let t = n as f64 * dt - 0.3;
            let want = if t <= 0.0 {
                0.0
            } else {
                k0 * (1.0 - 2.0 * (-t).exp() + (-2.0 * t).exp())
            };
            assert!((yn - want).abs() < 1e-12, "n={n} {yn} {want}");
        }
    }

    #[test]
    fn fractional_delay_step_is_analytic() {
        let lin = Linear {
            b1: 0.0,
            b0: 1.0,
            a2: 0.5,
            a1: 1.5,
            td: 0.137,
            k: 0.0,
        };
        let u = vec![1.0; 100];
        let y = simulate(&lin, &u, 0.05, Init::Rest).unwrap();
        for (n, yn) in y.iter().enumerate() {
            let t = n as f64 * 0.05 - 0.137;
            let want = if t <= 0.0 {
                0.0
            } else {
                1.0 - 2.0 * (-t).exp() + (-2.0 * t).exp()
            };
            assert!((yn - want).abs() < 1e-12);
        }
    }

    #[test]
    fn open_loop_kernel_matches_generic_step_loop() {
        // The K = 0 kernel (command read in place) and the delay-line loop agree, for
        // dead times shorter and longer than the series, integer and fractional.
        let u: Vec<f64> = (0..40).map(|n| ((n * 7919) % 13) as f64 - 6.0).collect();
        for td in [0.0, 0.05, 0.37, 1.0, 1.95, 2.5] {
            let lin = Linear {
                b1: 0.4,
                b0: 0.9,
                a2: 0.6,
                a1: 1.3,
                td,
                k: 0.0,
            };
            for init in [Init::Rest, Init::Steady] {
                let d = discretize::<2>(&lin, Integrators::None, 0.05).unwrap();
                let (x0, hist) = initial::<2>(&lin, init, u[0]).unwrap();
                let mut want = vec![0.0; u.len()];
                step_loop(
                    &d,
                    u.len(),
                    x0,
                    hist,
                    |n, _| u[n],
                    |n, _, y, _, _| {
                        want[n] = y;
                        true
                    },
                );
                let got = simulate(&lin, &u, 0.05, init).unwrap();
                for (g, w) in got.iter().zip(&want) {
                    assert!((g - w).abs() <= 1e-12 * (1.0 + w.abs()), "td={td}");
                }
            }
        }
    }

    #[test]
    fn proposed_dc_gain() {
        let lin = proposed();
        let u = vec![1.0; 20000];
        let y = simulate(&lin, &u, 0.05, Init::Rest).unwrap();
        assert!((y[19999] - lin.dc_gain()).abs() < 1e-6);
    }

    #[test]
    fn steady_init_stays_put() {
        let lin = proposed();
        let u = vec![2.0; 500];
        let y = simulate(&lin, &u, 0.05, Init::Steady).unwrap();
        for yn in &y {
            assert!((yn - 2.0 * lin.dc_gain()).abs() < 1e-9);
        }
    }

    #[test]
    fn integrators_match_cumulative_response() {
        let lin = Linear {
            b1: 0.0,
            b0: 1.0,
            a2: 0.0,
            a1: 0.5,
            td: 0.0,
            k: 0.0,
        };
        let u: Vec<f64> = (0..400).map(|n| (n as f64 * 0.03).sin()).collect();
        let tr = simulate_full(
            &lin,
            CommandKind::Acceleration,
            &u,
            0.05,
            Init::Rest,
            3.0,
            10.0,
        )
        .unwrap();
        // Trapezoid of a is close to v (exact for a smooth response up to O(dt^2)).
        let mut v = 3.0;
        for n in 1..u.len() {
            v += 0.5 * 0.05 * (tr.a[n - 1] + tr.a[n]);
            assert!((v - tr.v[n]).abs() < 1e-3);
        }
    }

    #[test]
    fn closed_loop_reaches_equilibrium_gap() {
        let lin = proposed();
        let up = Upper {
            kg: 0.5,
            kv: 0.0,
            tg: 2.0,
            gmin: 9.5,
        };
        let n = 20000;
        let dt = 0.05;
        let lv = vec![10.0; n];
        let lx: Vec<f64> = (0..n).map(|k| 100.0 + 10.0 * k as f64 * dt).collect();
        let tr = closed_loop(&lin, &up, &lx, &lv, dt, 10.0, 100.0 - 29.5 - 5.0).unwrap();
        let gap = lx[n - 1] - tr.x[n - 1];
        assert!((gap - 29.5).abs() < 1e-3, "gap {gap}");
    }

    #[test]
    fn unstable_params_give_infinite_cost() {
        let spec = CostSpec {
            model: ModelKind::Proposed,
            kind: CommandKind::Acceleration,
            weights: [1.0, 0.0, 0.0],
            init: Init::Rest,
            closed_loop: false,
            upper_free: vec![],
        };
        let u: Vec<f64> = (0..2000).map(|n| (n as f64 * 0.01).sin()).collect();
        let a = u.clone();
        let run = RunRef {
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
        };
        // K K0 > 1: the inner loop is unstable; m2 < 0: invalid.
        let rows = [1.0, 1.0, 1.0, 1.0, 0.1, 5.0, 1.0, -1.0, 1.0, 1.0, 0.1, 0.0];
        let c = batch_cost(&spec, &rows, &[run]).unwrap();
        assert_eq!(c, vec![f64::INFINITY, f64::INFINITY]);
    }
}
