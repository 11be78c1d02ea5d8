//! Rollouts on the one kernel: open loop (driven by a recorded command), closed loop
//! (behind a recorded leader through the upper-level constant-time-gap law, paper
//! Eq. 3) and platoons (time-major: every follower advances one sample before any
//! advances the next). Each takes an optional effect list (empty: the linear fast
//! path) with its exogenous signals, and writes into caller-provided slices
//! (`*_into`) or returns a [`Trajectory`].

use super::chain::{check_kind, lower_of, resolve_exo, Chain, Effects, Law, NoEffects, UpperChain};
use super::closed_blocks::closed_blocks;
use super::discretize::Integrators;
use super::kernel::{blocks_apply, response_blocks, run, Record, Response, Stepper, DIVERGED};
use super::plant::{start, Init, Plant, Start};
use super::with_plant;
use crate::effects::{AnyEffect, Level};
use crate::error::{check_finite, check_series, AvllError, Result};
use crate::model::{CommandKind, Linear};

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
            check_finite(n, x)?;
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

impl Trajectory {
    /// `n` samples of `fill`.
    pub fn filled(n: usize, fill: f64) -> Self {
        Self {
            a: vec![fill; n],
            v: vec![fill; n],
            x: vec![fill; n],
            command: vec![fill; n],
        }
    }
}

/// The effect list of a rollout with its exogenous series resolved.
#[derive(Debug, Clone, Copy)]
pub struct EffectsRef<'a> {
    pub effects: &'a [AnyEffect],
    pub exo: &'a [(&'a str, &'a [f64])],
}

impl<'a> EffectsRef<'a> {
    pub const NONE: EffectsRef<'static> = EffectsRef {
        effects: &[],
        exo: &[],
    };

    /// The lower-level chain for a run of `len` samples (checks the exogenous
    /// signals).
    fn chain(&self, len: usize) -> Result<Effects<'a>> {
        let effects = lower_of(self.effects);
        let exo = resolve_exo(&effects, self.exo, len)?;
        Ok(Effects { effects, exo })
    }

    /// The upper level `up` with the upper-level effects, reset for sample time `dt`.
    fn law(&self, up: &Upper, dt: f64) -> UpperChain {
        let mut law = UpperChain::new(*up, self.effects);
        law.reset(dt);
        law
    }

    /// Fails when an upper-level effect is given outside a closed loop.
    fn check_closed(&self, closed: bool) -> Result<()> {
        crate::effects::check_closed(
            self.effects
                .iter()
                .map(|e| (e.kind().name(), e.kind().level())),
            closed,
        )
    }

    /// Whether the modal form may be used (no effect switches the dynamics).
    pub fn modal(&self) -> bool {
        super::chain::modal_ok(self.effects)
    }
}

/// A stepper for `plant` with `chain`, started at `s` with the integrators at `int0`.
#[inline(always)]
pub(crate) fn stepper<const M: usize, const N: usize, const D: bool, const F: bool, C: Chain>(
    plant: Plant<M, N>,
    lin: &Linear,
    ints: Integrators,
    chain: C,
    accel: bool,
    s: &Start,
    int0: [f64; 2],
) -> Result<Stepper<M, N, D, F, C>> {
    let r = chain.brake_time_scale();
    if !C::NONE {
        // The braking side `kb G(rb s)` (the reference gain map's slope below 0 and
        // the time scale) must be asymptotically stable in the inner loop as well:
        // the same rule as the base, so a cost is `inf` and a rollout an error
        // exactly when the trajectory functions refuse the model.
        let g = -chain.reference(-1.0);
        if r != 1.0 || g != 1.0 {
            let lk = Linear {
                b1: g * r * lin.b1,
                b0: g * lin.b0,
                a2: r * r * lin.a2,
                a1: r * lin.a1,
                td: lin.td,
                k: lin.k,
            };
            let pk = Plant::<M, N>::new(&lk, ints, plant.dt, false)?;
            if !super::discretize::loop_stable(&lk, &pk) {
                return Err(AvllError::new(
                    "effects",
                    format!(
                        "the braking side kb G(rb s) (gain {g}, time scale {r}) is not \
                         asymptotically stable in the inner loop at dt={} s",
                        plant.dt
                    ),
                ));
            }
        }
    }
    let brake = if !C::NONE && r != 1.0 {
        let lb = Linear {
            b1: r * lin.b1,
            b0: lin.b0,
            a2: r * r * lin.a2,
            a1: r * lin.a1,
            td: lin.td,
            k: lin.k,
        };
        let bp = Plant::<M, N>::new(&lb, ints, plant.dt, false)?;
        let scale = if M == 2 { [r * r, r] } else { [r, 1.0] };
        Some((bp, scale))
    } else {
        None
    };
    let x0 = plant.state(s, int0);
    Ok(Stepper::new(
        plant, brake, chain, accel, lin.b0, x0, s.w_hist, s.u_hist,
    ))
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

#[inline(always)]
fn response_n<const M: usize, const N: usize, const D: bool, const F: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    u: &[f64],
    init: Init,
    y: &mut [f64],
) -> Result<()> {
    let s = start(lin, init, u.first().copied().unwrap_or(0.0))?;
    let mut st =
        stepper::<M, N, D, F, _>(plant, lin, Integrators::None, NoEffects, true, &s, [0.0; 2])?;
    if blocks_apply(&st.plant) {
        // Four samples at a time (the dead time makes them independent), the last
        // few one by one.
        let done = response_blocks(&mut st, u, y);
        for n in done..u.len() {
            let o = st.observe(n);
            y[n] = o.y_lin;
            st.step(n, &o, u[n]);
        }
    } else {
        run(&mut st, u.len(), |n, _| u[n], &mut Response(y));
    }
    // Linear: a finite stepper after the run proves the command finite (see
    // `Stepper::finite`); the command is read again only otherwise.
    if !st.finite() {
        check_series("command", u)?;
    }
    Ok(())
}

/// Open-loop response of the linear lower level (acceleration for an acceleration
/// command, speed for a speed command) into `y`.
/// A non-finite command sample is an error naming it (`y` is then to be discarded).
pub fn simulate_into(lin: &Linear, u: &[f64], dt: f64, init: Init, y: &mut [f64]) -> Result<()> {
    // The first sample sets a steady initial state: checked before it is used; the
    // others after the run (see `response_n`).
    check_series("command", &u[..u.len().min(1)])?;
    check_len("out", y, u.len())?;
    with_plant!(
        cached;
        lin,
        Integrators::None,
        dt,
        true,
        response_n(lin, u, init, y)
    )
}

/// Open-loop response as a new vector.
pub fn simulate(lin: &Linear, u: &[f64], dt: f64, init: Init) -> Result<Vec<f64>> {
    let mut y = vec![0.0; u.len()];
    simulate_into(lin, u, dt, init, &mut y)?;
    Ok(y)
}

/// Output slices of one trajectory.
pub struct Out<'a> {
    pub a: &'a mut [f64],
    pub v: &'a mut [f64],
    pub x: &'a mut [f64],
    pub u: Option<&'a mut [f64]>,
}

impl<'a> Out<'a> {
    pub fn of(tr: &'a mut Trajectory) -> Self {
        Self {
            a: &mut tr.a,
            v: &mut tr.v,
            x: &mut tr.x,
            u: Some(&mut tr.command),
        }
    }
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn full_n<const M: usize, const N: usize, const D: bool, const F: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    eff: &EffectsRef,
    kind: CommandKind,
    u: &[f64],
    init: Init,
    v0: f64,
    p0: f64,
    out: Out,
) -> Result<()> {
    let ints = Integrators::for_kind(kind);
    let accel = kind == CommandKind::Acceleration;
    let s = start(lin, init, u.first().copied().unwrap_or(0.0))?;
    let int0 = if accel { [v0, p0] } else { [p0, 0.0] };
    if let Some(c) = &out.u {
        check_len("out", c, u.len())?;
    }
    let mut rec = Record::<false, false>::new(out.a, out.v, out.x);
    if eff.effects.is_empty() {
        let mut st = stepper::<M, N, D, F, _>(plant, lin, ints, NoEffects, accel, &s, int0)?;
        run(&mut st, u.len(), |n, _| u[n], &mut rec);
    } else {
        let ch = eff.chain(u.len())?;
        let mut st = stepper::<M, N, D, F, _>(plant, lin, ints, ch, accel, &s, int0)?;
        run(&mut st, u.len(), |n, _| u[n], &mut rec);
    }
    // The command recorded is the one given.
    if let Some(c) = out.u {
        c.copy_from_slice(u);
    }
    Ok(())
}

/// Open-loop rollout with the integrated states into `out` (see [`Trajectory`]);
/// the command slot of `out` receives the command. `v0`, `p0` are the initial speed
/// and position (for a speed command the initial speed is the model's own).
#[allow(clippy::too_many_arguments)]
pub fn simulate_full_into(
    lin: &Linear,
    eff: &EffectsRef,
    kind: CommandKind,
    u: &[f64],
    dt: f64,
    init: Init,
    v0: f64,
    p0: f64,
    out: Out,
) -> Result<()> {
    check_series("command", u)?;
    check_finite("v0", v0)?;
    check_finite("x0", p0)?;
    check_kind(eff.effects, kind)?;
    eff.check_closed(false)?;
    for s in [&out.a, &out.v, &out.x] {
        check_len("out", s, u.len())?;
    }
    let ints = Integrators::for_kind(kind);
    with_plant!(
        cached;
        lin,
        ints,
        dt,
        eff.modal(),
        full_n(lin, eff, kind, u, init, v0, p0, out)
    )
}

/// Open-loop rollout with the integrated states, as a new [`Trajectory`].
#[allow(clippy::too_many_arguments)]
pub fn simulate_full(
    lin: &Linear,
    eff: &EffectsRef,
    kind: CommandKind,
    u: &[f64],
    dt: f64,
    init: Init,
    v0: f64,
    p0: f64,
) -> Result<Trajectory> {
    let mut tr = Trajectory::filled(u.len(), 0.0);
    let mut out = Out::of(&mut tr);
    out.u = None;
    simulate_full_into(lin, eff, kind, u, dt, init, v0, p0, out)?;
    tr.command = u.to_vec();
    Ok(tr)
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn closed_n<const M: usize, const N: usize, const D: bool, const F: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    eff: &EffectsRef,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    v0: f64,
    p0: f64,
    out: Out,
) -> Result<()> {
    // Whether the command is recorded is decided once, not at every sample.
    let leader = (lead_x, lead_v);
    match out.u {
        Some(u) => closed_rec::<M, N, D, F, true>(
            plant,
            lin,
            eff,
            up,
            leader,
            [v0, p0],
            Record::with_command(out.a, out.v, out.x, u),
        ),
        None => closed_rec::<M, N, D, F, false>(
            plant,
            lin,
            eff,
            up,
            leader,
            [v0, p0],
            Record::new(out.a, out.v, out.x),
        ),
    }
}

#[inline(always)]
fn closed_rec<const M: usize, const N: usize, const D: bool, const F: bool, const U: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    eff: &EffectsRef,
    up: &Upper,
    (lead_x, lead_v): (&[f64], &[f64]),
    int0: [f64; 2],
    mut rec: Record<'_, true, U>,
) -> Result<()> {
    let s = start(lin, Init::Rest, 0.0)?;
    let ints = Integrators::SpeedPosition;
    // Both leader series as long as the run (checked by `closed_loop_into`): with
    // `run` bounding `n` by that length, the per-sample reads need no bounds check.
    let lead_v = &lead_v[..lead_x.len()];
    if eff.effects.is_empty() {
        let mut st = stepper::<M, N, D, F, _>(plant, lin, ints, NoEffects, true, &s, int0)?;
        // The kernel's steps, four samples at a time where that applies.
        closed_blocks(&mut st, up, lead_x, lead_v, &mut rec, true);
        // Linear: a run to the end with a finite stepper proves the leader finite
        // (see `Stepper::finite`); otherwise (divergence, or a bad sample to name)
        // the leader is checked now.
        if rec.written < lead_x.len() || !st.finite() {
            check_leader(lead_x, lead_v)?;
        }
    } else {
        // Effects may map a non-finite value to a finite one (a clamp): checked first.
        check_leader(lead_x, lead_v)?;
        let ch = eff.chain(lead_x.len())?;
        let mut st = stepper::<M, N, D, F, _>(plant, lin, ints, ch, true, &s, int0)?;
        let mut upper = eff.law(up, plant.dt);
        let law = |n: usize, o: &super::kernel::Obs| upper.command(lead_x[n], lead_v[n], o.p, o.v);
        run(&mut st, lead_x.len(), law, &mut rec);
    }
    // NaN from the divergence on (nothing when the run completed).
    rec.blank_rest();
    Ok(())
}

fn check_leader(lead_x: &[f64], lead_v: &[f64]) -> Result<()> {
    check_series("lead_x", lead_x)?;
    check_series("lead_v", lead_v)?;
    check_len("lead_v", lead_v, lead_x.len())
}

/// Closed-loop car following behind a recorded leader into `out` (the upper law
/// Eq. 3 evaluated at the samples; the lower level starts at rest). If the follower
/// diverges (`|a|` reaches [`DIVERGED`] or the speed is not finite) the rest of the
/// outputs are NaN.
#[allow(clippy::too_many_arguments)]
pub fn closed_loop_into(
    lin: &Linear,
    eff: &EffectsRef,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    v0: f64,
    p0: f64,
    mut out: Out,
) -> Result<()> {
    up.validate()?;
    // The leader's samples are checked in `closed_n`.
    check_len("lead_v", lead_v, lead_x.len())?;
    check_finite("v0", v0)?;
    check_finite("x0", p0)?;
    check_kind(eff.effects, CommandKind::Acceleration)?;
    let n = lead_x.len();
    for s in [&out.a, &out.v, &out.x] {
        check_len("out", s, n)?;
    }
    with_plant!(
        cached;
        lin,
        Integrators::SpeedPosition,
        dt,
        eff.modal(),
        closed_n(
            lin,
            eff,
            up,
            lead_x,
            lead_v,
            v0,
            p0,
            Out {
                a: &mut *out.a,
                v: &mut *out.v,
                x: &mut *out.x,
                u: out.u.as_deref_mut(),
            }
        )
    )
}

/// Closed-loop car following behind a recorded leader with a given upper law (any
/// [`Law`], e.g. the synthetic generator's [`super::synth::Hidden`], reset here for
/// `dt`) and the lower-level effects of `eff`, into `out` (as [`closed_loop_into`]:
/// the lower level at rest, NaN after a divergence).
#[allow(clippy::too_many_arguments)]
pub fn closed_loop_law_into(
    lin: &Linear,
    eff: &EffectsRef,
    law: &mut dyn Law,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    v0: f64,
    p0: f64,
    out: Out,
) -> Result<()> {
    check_leader(lead_x, lead_v)?;
    check_finite("v0", v0)?;
    check_finite("x0", p0)?;
    check_kind(eff.effects, CommandKind::Acceleration)?;
    if eff.effects.iter().any(|e| e.kind().level() == Level::Upper) {
        return Err(AvllError::new(
            "effects",
            "the law is given: upper-level effects would be a second law",
        ));
    }
    for s in [&out.a, &out.v, &out.x] {
        check_len("out", s, lead_x.len())?;
    }
    law.reset(dt);
    with_plant!(
        lin,
        Integrators::SpeedPosition,
        dt,
        eff.modal(),
        closed_law_n(lin, eff, law, lead_x, lead_v, [v0, p0], out)
    )
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn closed_law_n<const M: usize, const N: usize, const D: bool, const F: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    eff: &EffectsRef,
    law: &mut dyn Law,
    lead_x: &[f64],
    lead_v: &[f64],
    int0: [f64; 2],
    out: Out,
) -> Result<()> {
    let s = start(lin, Init::Rest, 0.0)?;
    let ch = eff.chain(lead_x.len())?;
    let mut st =
        stepper::<M, N, D, F, _>(plant, lin, Integrators::SpeedPosition, ch, true, &s, int0)?;
    let drive = |n: usize, o: &super::kernel::Obs| law.command(lead_x[n], lead_v[n], o.p, o.v);
    match out.u {
        Some(u) => {
            let mut rec = Record::<true, true>::with_command(out.a, out.v, out.x, u);
            run(&mut st, lead_x.len(), drive, &mut rec);
            rec.blank_rest();
        }
        None => {
            let mut rec = Record::<true, false>::new(out.a, out.v, out.x);
            run(&mut st, lead_x.len(), drive, &mut rec);
            rec.blank_rest();
        }
    }
    Ok(())
}

/// Closed-loop car following as a new [`Trajectory`] (see [`closed_loop_into`]).
#[allow(clippy::too_many_arguments)]
pub fn closed_loop(
    lin: &Linear,
    eff: &EffectsRef,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    v0: f64,
    p0: f64,
) -> Result<Trajectory> {
    let mut tr = Trajectory::filled(lead_x.len(), 0.0);
    closed_loop_into(lin, eff, up, lead_x, lead_v, dt, v0, p0, Out::of(&mut tr))?;
    Ok(tr)
}

/// Where a platoon's samples go: one [`Out`] per follower, or [`TimeMajor`]
/// arrays (sample-major, every follower's sample `n` side by side: the layout the
/// time-major stepping writes contiguously).
pub trait PlatoonOut {
    /// Number of followers.
    fn followers(&self) -> usize;
    /// Checks every output's length against the run's.
    fn check(&self, len: usize) -> Result<()>;
    /// Records follower `j`'s sample `n`.
    fn put(&mut self, j: usize, n: usize, a: f64, v: f64, x: f64, u: f64);
    /// Follower `j`'s acceleration and speed at sample `n`.
    fn get(&self, j: usize, n: usize) -> (f64, f64);
    /// Fills follower `j`'s outputs from sample `from` on with NaN.
    fn blank(&mut self, j: usize, from: usize);
    /// Records sample `n` of followers `j0..j0 + count` (`count <= 4`: one lane group
    /// of the linear platoon, lane `l` being follower `j0 + l`).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn put_group(
        &mut self,
        n: usize,
        j0: usize,
        count: usize,
        a: &Group,
        v: &Group,
        x: &Group,
        u: &Group,
    ) {
        for l in 0..count {
            self.put(j0 + l, n, a[l], v[l], x[l], u[l]);
        }
    }
    /// For time-major outputs: the number of followers per row and pointers to the
    /// acceleration, speed, position and command arrays (follower `j`'s sample `n`
    /// at offset `n * followers + j`, every one of `len * followers` checked by
    /// [`PlatoonOut::check`]), for the lane groups' vector stores.
    fn time_major(&mut self) -> Option<(usize, [*mut f64; 4])> {
        None
    }
    /// Whether the first `alive` followers stayed in range over samples `from..to`
    /// (`|a| < DIVERGED`, finite speed): a branch-free pass; [`platoon_divergence`]
    /// looks for the first bad sample only when this says there is one.
    fn chunk_ok(&self, alive: usize, from: usize, to: usize) -> bool {
        let mut ok = true;
        for j in 0..alive {
            for n in from..to {
                let (a, v) = self.get(j, n);
                ok &= (a.abs() < DIVERGED) & v.is_finite();
            }
        }
        ok
    }
}

impl PlatoonOut for [Out<'_>] {
    fn followers(&self) -> usize {
        self.len()
    }
    fn check(&self, len: usize) -> Result<()> {
        for o in self.iter() {
            for s in [&o.a, &o.v, &o.x] {
                check_len("out", s, len)?;
            }
        }
        Ok(())
    }
    #[inline(always)]
    fn put(&mut self, j: usize, n: usize, a: f64, v: f64, x: f64, u: f64) {
        let o = &mut self[j];
        o.a[n] = a;
        o.v[n] = v;
        o.x[n] = x;
        if let Some(c) = o.u.as_deref_mut() {
            c[n] = u;
        }
    }
    #[inline(always)]
    fn get(&self, j: usize, n: usize) -> (f64, f64) {
        (self[j].a[n], self[j].v[n])
    }
    fn blank(&mut self, j: usize, from: usize) {
        let o = &mut self[j];
        for s in [&mut *o.a, &mut *o.v, &mut *o.x] {
            s[from..].fill(f64::NAN);
        }
        if let Some(c) = o.u.as_deref_mut() {
            c[from..].fill(f64::NAN);
        }
    }
}

/// Sample-major platoon outputs: follower `j`'s sample `n` at `n * followers + j`
/// (a `(T, followers)` array; its transpose is the `(followers, T)` view).
pub struct TimeMajor<'a> {
    pub followers: usize,
    pub a: &'a mut [f64],
    pub v: &'a mut [f64],
    pub x: &'a mut [f64],
    pub u: &'a mut [f64],
}

impl PlatoonOut for TimeMajor<'_> {
    fn followers(&self) -> usize {
        self.followers
    }
    fn check(&self, len: usize) -> Result<()> {
        for s in [&self.a, &self.v, &self.x, &self.u] {
            check_len("out", s, len * self.followers)?;
        }
        Ok(())
    }
    #[inline(always)]
    fn put(&mut self, j: usize, n: usize, a: f64, v: f64, x: f64, u: f64) {
        let k = n * self.followers + j;
        self.a[k] = a;
        self.v[k] = v;
        self.x[k] = x;
        self.u[k] = u;
    }
    #[inline(always)]
    fn get(&self, j: usize, n: usize) -> (f64, f64) {
        let k = n * self.followers + j;
        (self.a[k], self.v[k])
    }
    #[inline(always)]
    fn put_group(
        &mut self,
        n: usize,
        j0: usize,
        count: usize,
        a: &Group,
        v: &Group,
        x: &Group,
        u: &Group,
    ) {
        let k = n * self.followers + j0;
        self.a[k..k + count].copy_from_slice(&a[..count]);
        self.v[k..k + count].copy_from_slice(&v[..count]);
        self.x[k..k + count].copy_from_slice(&x[..count]);
        self.u[k..k + count].copy_from_slice(&u[..count]);
    }
    fn time_major(&mut self) -> Option<(usize, [*mut f64; 4])> {
        Some((
            self.followers,
            [
                self.a.as_mut_ptr(),
                self.v.as_mut_ptr(),
                self.x.as_mut_ptr(),
                self.u.as_mut_ptr(),
            ],
        ))
    }
    fn chunk_ok(&self, alive: usize, from: usize, to: usize) -> bool {
        let f = self.followers;
        let mut ok = true;
        for n in from..to {
            let (a, v) = (&self.a[n * f..n * f + alive], &self.v[n * f..n * f + alive]);
            ok &= a
                .iter()
                .zip(v)
                .fold(true, |ok, (a, v)| ok & (a.abs() < DIVERGED) & v.is_finite());
        }
        ok
    }
    fn blank(&mut self, j: usize, from: usize) {
        let f = self.followers;
        let len = self.a.len() / f.max(1);
        for n in from..len {
            let k = n * f + j;
            self.a[k] = f64::NAN;
            self.v[k] = f64::NAN;
            self.x[k] = f64::NAN;
            self.u[k] = f64::NAN;
        }
    }
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn platoon_n<const M: usize, const N: usize, const D: bool, const F: bool>(
    plant: Plant<M, N>,
    lin: &Linear,
    eff: &EffectsRef,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    outs: &mut (impl PlatoonOut + ?Sized),
) -> Result<()> {
    if eff.effects.is_empty() {
        // F on x86_64: the CPU has FMA and AVX2 (`call_fma!`); elsewhere, lane by lane.
        let avx2 = F && cfg!(target_arch = "x86_64");
        platoon_linear::<M, N, D, F, _>(plant, lin, up, lead_x, lead_v, outs, avx2)
    } else {
        let ch = eff.chain(lead_x.len())?;
        let law = eff.law(up, plant.dt);
        platoon_chain::<M, N, D, F, _, _, _>(plant, lin, ch, law, lead_x, lead_v, outs)
    }
}

/// Time-major platoon stepping: at each sample every follower observes its state,
/// takes its upper law's command (each follower its own copy of `law`, with its own
/// state) from its predecessor's observed position and speed and steps. The
/// followers' steps within a sample are independent, so they overlap in the
/// pipeline.
fn platoon_chain<
    const M: usize,
    const N: usize,
    const D: bool,
    const F: bool,
    C: Chain + Clone,
    L: Law + Clone,
    P: PlatoonOut + ?Sized,
>(
    plant: Plant<M, N>,
    lin: &Linear,
    chain: C,
    law: L,
    lead_x: &[f64],
    lead_v: &[f64],
    outs: &mut P,
) -> Result<()> {
    let len = lead_x.len();
    let f = outs.followers();
    let v0 = lead_v[0];
    let s = start(lin, Init::Rest, 0.0)?;
    let gap = law.gap(v0);
    let mut laws = vec![law; f];
    let mut cars = Vec::with_capacity(f);
    for j in 0..f {
        let p0 = lead_x[0] - (j + 1) as f64 * gap;
        cars.push(stepper::<M, N, D, F, C>(
            plant,
            lin,
            Integrators::SpeedPosition,
            chain.clone(),
            true,
            &s,
            [v0, p0],
        )?);
    }
    // `alive`: followers ahead of the first diverged one (it and those behind stop).
    let mut alive = f;
    let mut from = 0;
    while from < len && alive > 0 {
        let to = (from + super::kernel::CHUNK).min(len);
        for n in from..to {
            let (mut px, mut pv) = (lead_x[n], lead_v[n]);
            for (j, (car, law)) in cars[..alive].iter_mut().zip(&mut laws).enumerate() {
                let ob = car.observe(n);
                let u = law.command(px, pv, ob.p, ob.v);
                let a = car.step(n, &ob, u);
                outs.put(j, n, a, ob.v, ob.p, u);
                px = ob.p;
                pv = ob.v;
            }
        }
        alive = platoon_divergence(outs, alive, from, to);
        from = to;
    }
    Ok(())
}

/// Followers stepped side by side in the linear platoon: one lane group (four
/// doubles, one AVX2 vector).
pub const GROUP: usize = 4;
/// One value per follower of a lane group.
pub type Group = [f64; GROUP];

/// The linear platoon's state between chunks: each state component of all
/// followers side by side (follower `j` at index `j + 1`; index 0 of the speed and
/// position holds the leader's at the current sample), so a group's predecessors
/// are the same four lanes one index back; and the followers' dead-time lines side
/// by side (follower `j`'s row of sample `n` at `(n & mask) * width + j`).
struct Soa<const N: usize> {
    st: [Vec<f64>; N],
    ring: Vec<f64>,
    /// Followers rounded up to whole lane groups.
    width: usize,
    mask: usize,
    /// Whole-sample dead time.
    delay: usize,
}

impl<const N: usize> Soa<N> {
    /// The ring offsets of sample `n`'s row and of the rows `delay` and `delay + 1`
    /// samples back (`w0` and `w1`). The ring holds at least `delay + 2` rows, so
    /// neither is the row written at `n` unless the delay is 0, where `w0` is that
    /// row, as in the kernel.
    #[inline(always)]
    fn rows(&self, n: usize) -> (usize, usize, usize) {
        let w = self.width;
        (
            (n & self.mask) * w,
            (n.wrapping_sub(self.delay) & self.mask) * w,
            (n.wrapping_sub(self.delay + 1) & self.mask) * w,
        )
    }
}

/// What the linear platoon's chunks step by: the plant, the upper law, the leader.
#[derive(Clone, Copy)]
struct Drive<'a, const M: usize, const N: usize> {
    pl: &'a Plant<M, N>,
    up: &'a Upper,
    lead_x: &'a [f64],
    lead_v: &'a [f64],
}

/// The linear platoon in lane groups: the followers are taken four at a time, and
/// per sample each group does its whole step (responses, commands, outputs, its
/// part of the dead-time line, state update) on four lanes at once. A lane's
/// predecessor is the lane before it (the first lane's, the previous group's last
/// or the leader), at the sample, before its update. The last group's lanes past
/// the last follower continue the platoon: stepped, never written. Divergence
/// (`|a| >= DIVERGED` or a speed that is not finite) is flagged on the way, lane by
/// lane, and looked for in the outputs only when flagged. With FMA the step is
/// written in AVX2 intrinsics ([`platoon_chunk_avx2`]), otherwise lane by lane
/// ([`platoon_chunk`]). Both do the arithmetic of the kernel
/// ([`crate::sim::kernel`]'s `observe` and `advance`), operation for operation: the
/// result is bit-identical to followers stepped one by one (tested, and the two
/// chunk forms against each other).
///
/// `avx2` (the AVX2 form) must be true only when the CPU has FMA and AVX2 (and `F`
/// is then true).
#[allow(clippy::too_many_arguments)]
fn platoon_linear<
    const M: usize,
    const N: usize,
    const D: bool,
    const F: bool,
    P: PlatoonOut + ?Sized,
>(
    plant: Plant<M, N>,
    lin: &Linear,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    outs: &mut P,
    avx2: bool,
) -> Result<()> {
    use super::kernel::CHUNK;
    let len = lead_x.len();
    let f = outs.followers();
    if f == 0 {
        return Ok(());
    }
    let v0 = lead_v[0];
    let s = start(lin, Init::Rest, 0.0)?;
    let gap = up.gmin + up.tg * v0;
    let width = f.div_ceil(GROUP) * GROUP;
    let mut st: [Vec<f64>; N] = std::array::from_fn(|_| vec![0.0; width + 1]);
    for j in 0..width {
        let x = plant.state(&s, [v0, lead_x[0] - (j + 1) as f64 * gap]);
        for k in 0..N {
            st[k][j + 1] = x[k];
        }
    }
    let cap = (plant.delay + 2).next_power_of_two();
    let mut soa = Soa {
        st,
        ring: vec![s.w_hist; cap * width],
        width,
        mask: cap - 1,
        delay: plant.delay,
    };
    let drive = Drive {
        pl: &plant,
        up,
        lead_x,
        lead_v,
    };
    let mut alive = f;
    let mut from = 0;
    while from < len && alive > 0 {
        let to = (from + CHUNK).min(len);
        let ok = if F && avx2 {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `avx2` only when the CPU has FMA and AVX2 (documented above).
            unsafe {
                platoon_chunk_avx2::<M, N, D, P>(drive, &mut soa, outs, from, to, alive)
            }
            #[cfg(not(target_arch = "x86_64"))]
            unreachable!("AVX2 on x86_64 only")
        } else {
            platoon_chunk::<M, N, D, F, P>(drive, &mut soa, outs, from, to, alive)
        };
        if !ok {
            alive = first_divergence(outs, alive, from, to);
        }
        from = to;
    }
    Ok(())
}

/// Samples `from..to` of the linear platoon's first `alive` followers, lane by lane
/// (see [`platoon_linear`]); false when one of them diverged. The groups go from the
/// last to the first, so a group's predecessors, the lanes one index back in
/// [`Soa`], still hold their values at the sample.
#[inline(always)]
fn platoon_chunk<const M: usize, const N: usize, const D: bool, const F: bool, P>(
    drive: Drive<'_, M, N>,
    soa: &mut Soa<N>,
    outs: &mut P,
    from: usize,
    to: usize,
    alive: usize,
) -> bool
where
    P: PlatoonOut + ?Sized,
{
    use super::kernel::madd;
    let Drive {
        pl,
        up,
        lead_x,
        lead_v,
    } = drive;
    let (g0, g1, phi) = (&pl.g0, &pl.g1, &pl.phi);
    let lanes = |xs: &[f64], at: usize| -> Group {
        let mut g = [0.0; GROUP];
        g.copy_from_slice(&xs[at..at + GROUP]);
        g
    };
    let live = alive.div_ceil(GROUP);
    let mut ok = [true; GROUP];
    for n in from..to {
        let (row, back, back1) = soa.rows(n);
        let (st, ring) = (&mut soa.st, &mut soa.ring);
        st[M][0] = lead_v[n];
        st[M + 1][0] = lead_x[n];
        for g in (0..live).rev() {
            let (j0, o) = (g * GROUP, g * GROUP + 1);
            let z: [Group; M] = std::array::from_fn(|k| lanes(&st[k], o));
            let (vs, ps) = (lanes(&st[M], o), lanes(&st[M + 1], o));
            let (lv, lx) = (lanes(&st[M], o - 1), lanes(&st[M + 1], o - 1));
            // Responses at n: y = C z (as `observe`).
            let mut y = [0.0; GROUP];
            for l in 0..GROUP {
                y[l] = z[0][l] * pl.c[0];
            }
            if M == 2 {
                for l in 0..GROUP {
                    y[l] = madd::<F>(pl.c[1], z[1][l], y[l]);
                }
            }
            // Commands from the predecessors' positions and speeds at n.
            let u: Group = std::array::from_fn(|l| up.command(lx[l], lv[l], ps[l], vs[l]));
            let count = (alive - j0).min(GROUP);
            outs.put_group(n, j0, count, &y, &vs, &ps, &u);
            for l in 0..GROUP {
                let good = (y[l].abs() < DIVERGED) & (vs[l].abs() < f64::INFINITY);
                ok[l] &= good | (l >= count);
            }
            // The dead-time line: this sample's references in, then the delayed ones.
            let r: Group = std::array::from_fn(|l| u[l] + pl.k * y[l]);
            ring[row + j0..row + j0 + GROUP].copy_from_slice(&r);
            let (w0, w1) = (lanes(ring, back + j0), lanes(ring, back1 + j0));
            // The exact step (as `advance`): integrators first, they read the model
            // states before the update.
            let (mut nv, mut np, mut nz) = (vs, ps, z);
            for l in 0..GROUP {
                let mut tv = madd::<F>(g1[M], w1[l], g0[M] * w0[l]);
                for k in 0..M {
                    tv = madd::<F>(phi[M][k], z[k][l], tv);
                }
                let mut tp = madd::<F>(g1[M + 1], w1[l], g0[M + 1] * w0[l]);
                tp = madd::<F>(phi[M + 1][M], vs[l], tp);
                for k in 0..M {
                    tp = madd::<F>(phi[M + 1][k], z[k][l], tp);
                }
                nv[l] += tv;
                np[l] += tp;
            }
            if D || M == 1 {
                for r in 0..M {
                    for l in 0..GROUP {
                        let t = madd::<F>(g1[r], w1[l], g0[r] * w0[l]);
                        nz[r][l] = madd::<F>(phi[r][r], z[r][l], t);
                    }
                }
            } else {
                for l in 0..GROUP {
                    let (z0, z1) = (z[0][l], z[1][l]);
                    let t0 = madd::<F>(g1[0], w1[l], g0[0] * w0[l]);
                    let t1 = madd::<F>(g1[1], w1[l], g0[1] * w0[l]);
                    nz[0][l] = madd::<F>(phi[0][0], z0, madd::<F>(phi[0][1], z1, t0));
                    nz[1][l] = madd::<F>(phi[1][1], z1, madd::<F>(phi[1][0], z0, t1));
                }
            }
            for k in 0..M {
                st[k][o..o + GROUP].copy_from_slice(&nz[k]);
            }
            st[M][o..o + GROUP].copy_from_slice(&nv);
            st[M + 1][o..o + GROUP].copy_from_slice(&np);
        }
    }
    ok.iter().all(|&g| g)
}

/// [`platoon_chunk`] with FMA, in AVX2 intrinsics: one vector per lane group, the
/// same operations in the same order (`a.mul_add(b, c)` is `_mm256_fmadd_pd(a, b,
/// c)`; Rust contracts nothing else), so the same bits. The groups go from the
/// first to the last, each passing its last lane's position and speed (before its
/// update) to the next in a register. The time-major outputs are written with
/// vector stores and requested for writing 32 samples ahead (a prefetch): the
/// stores to output lines not yet in cache were a third of the time.
///
/// # Safety
/// The CPU must support FMA and AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn platoon_chunk_avx2<const M: usize, const N: usize, const D: bool, P>(
    drive: Drive<'_, M, N>,
    soa: &mut Soa<N>,
    outs: &mut P,
    from: usize,
    to: usize,
    alive: usize,
) -> bool
where
    P: PlatoonOut + ?Sized,
{
    use std::arch::x86_64::*;
    let Drive {
        pl,
        up,
        lead_x,
        lead_v,
    } = drive;
    let c = _mm256_set1_pd;
    let (g0, g1, phi) = (&pl.g0, &pl.g1, &pl.phi);
    let (c0, c1, k) = (c(pl.c[0]), c(pl.c[1 % N]), c(pl.k));
    let (kg, kv, tg, gmin) = (c(up.kg), c(up.kv), c(up.tg), c(up.gmin));
    let ga: [__m256d; N] = std::array::from_fn(|r| c(g0[r]));
    let gb: [__m256d; N] = std::array::from_fn(|r| c(g1[r]));
    let ph: [[__m256d; N]; N] = std::array::from_fn(|r| std::array::from_fn(|q| c(phi[r][q])));
    let (big, inf) = (c(DIVERGED), c(f64::INFINITY));
    let sign = c(-0.0);
    let live = alive.div_ceil(GROUP);
    // Lanes past the last alive follower of the last group count as fine.
    let pad: [__m256d; GROUP + 1] = std::array::from_fn(|count| {
        let m: [f64; GROUP] = std::array::from_fn(|l| {
            if l >= count {
                f64::from_bits(u64::MAX)
            } else {
                0.0
            }
        });
        _mm256_loadu_pd(m.as_ptr())
    });
    let mut ok = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
    let width = soa.width;
    let direct = outs.time_major();
    let to_len = lead_x.len();
    debug_assert!(direct.is_none_or(|(f, _)| f >= alive));
    // The leader's slot (index 0) is not used: the predecessors come in registers.
    debug_assert!(soa.st.iter().all(|x| x.len() == width + 1));
    let sp: [*mut f64; N] = std::array::from_fn(|q| soa.st[q].as_mut_ptr());
    let rp = soa.ring.as_mut_ptr();
    for n in from..to {
        let (row, back, back1) = soa.rows(n);
        debug_assert!(row.max(back).max(back1) + width <= soa.ring.len());
        // The predecessor of a group's first lane, in every lane: the leader, then the
        // previous group's last follower before its update. Forward, in registers: a
        // load one index back would straddle two of the last sample's stores, which
        // the CPU cannot forward (measured: a fifth of the time waiting on it).
        let (mut pv, mut px) = (c(lead_v[n]), c(lead_x[n]));
        for g in 0..live {
            let (j0, o) = (g * GROUP, g * GROUP + 1);
            // SAFETY (every pointer below): `o + GROUP <= width + 1`, the length of each
            // state row, and `row, back, back1 + j0 + GROUP <= ring.len()` (above).
            let z: [__m256d; M] = std::array::from_fn(|q| _mm256_loadu_pd(sp[q].add(o)));
            let vs = _mm256_loadu_pd(sp[M].add(o));
            let ps = _mm256_loadu_pd(sp[M + 1].add(o));
            // [pred, lane 0, lane 1, lane 2]; then this group's last lane, broadcast.
            const ROT: i32 = 0b10_01_00_11;
            let lv = _mm256_blend_pd::<1>(_mm256_permute4x64_pd::<ROT>(vs), pv);
            let lx = _mm256_blend_pd::<1>(_mm256_permute4x64_pd::<ROT>(ps), px);
            pv = _mm256_permute4x64_pd::<0xFF>(vs);
            px = _mm256_permute4x64_pd::<0xFF>(ps);
            let mut y = _mm256_mul_pd(z[0], c0);
            if M == 2 {
                y = _mm256_fmadd_pd(c1, z[1 % M], y);
            }
            // up.command: kg (lx - x - tg v - gmin) + kv (lv - v), in that order.
            let gap = _mm256_sub_pd(
                _mm256_sub_pd(_mm256_sub_pd(lx, ps), _mm256_mul_pd(tg, vs)),
                gmin,
            );
            let u = _mm256_add_pd(
                _mm256_mul_pd(kg, gap),
                _mm256_mul_pd(kv, _mm256_sub_pd(lv, vs)),
            );
            let count = (alive - j0).min(GROUP);
            match direct {
                // SAFETY: `n < len` and `j0 + GROUP <= alive <= f`: inside the arrays.
                Some((f, [pa, pv, px, pu])) if count == GROUP => {
                    let at = n * f + j0;
                    if n + 32 < to_len {
                        let ahead = at + 32 * f;
                        _mm_prefetch::<_MM_HINT_ET0>(pa.add(ahead) as *const i8);
                        _mm_prefetch::<_MM_HINT_ET0>(pv.add(ahead) as *const i8);
                        _mm_prefetch::<_MM_HINT_ET0>(px.add(ahead) as *const i8);
                        _mm_prefetch::<_MM_HINT_ET0>(pu.add(ahead) as *const i8);
                    }
                    _mm256_storeu_pd(pa.add(at), y);
                    _mm256_storeu_pd(pv.add(at), vs);
                    _mm256_storeu_pd(px.add(at), ps);
                    _mm256_storeu_pd(pu.add(at), u);
                }
                _ => {
                    let mut lanes = [[0.0; GROUP]; 4];
                    _mm256_storeu_pd(lanes[0].as_mut_ptr(), y);
                    _mm256_storeu_pd(lanes[1].as_mut_ptr(), vs);
                    _mm256_storeu_pd(lanes[2].as_mut_ptr(), ps);
                    _mm256_storeu_pd(lanes[3].as_mut_ptr(), u);
                    outs.put_group(n, j0, count, &lanes[0], &lanes[1], &lanes[2], &lanes[3]);
                }
            }
            let good = _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, y), big),
                _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, vs), inf),
            );
            ok = _mm256_and_pd(ok, _mm256_or_pd(good, pad[count]));
            // The dead-time line: u + k y in, then the delayed rows.
            _mm256_storeu_pd(rp.add(row + j0), _mm256_add_pd(u, _mm256_mul_pd(k, y)));
            let w0 = _mm256_loadu_pd(rp.add(back + j0));
            let w1 = _mm256_loadu_pd(rp.add(back1 + j0));
            // The exact step (as `advance`): integrators first.
            let mut tv = _mm256_fmadd_pd(gb[M], w1, _mm256_mul_pd(ga[M], w0));
            for q in 0..M {
                tv = _mm256_fmadd_pd(ph[M][q], z[q], tv);
            }
            let mut tp = _mm256_fmadd_pd(gb[M + 1], w1, _mm256_mul_pd(ga[M + 1], w0));
            tp = _mm256_fmadd_pd(ph[M + 1][M], vs, tp);
            for q in 0..M {
                tp = _mm256_fmadd_pd(ph[M + 1][q], z[q], tp);
            }
            _mm256_storeu_pd(sp[M].add(o), _mm256_add_pd(vs, tv));
            _mm256_storeu_pd(sp[M + 1].add(o), _mm256_add_pd(ps, tp));
            if D || M == 1 {
                for r in 0..M {
                    let t = _mm256_fmadd_pd(gb[r], w1, _mm256_mul_pd(ga[r], w0));
                    _mm256_storeu_pd(sp[r].add(o), _mm256_fmadd_pd(ph[r][r], z[r], t));
                }
            } else {
                let (z0, z1) = (z[0], z[1 % M]);
                let t0 = _mm256_fmadd_pd(gb[0], w1, _mm256_mul_pd(ga[0], w0));
                let t1 = _mm256_fmadd_pd(gb[1 % M], w1, _mm256_mul_pd(ga[1 % M], w0));
                let n0 = _mm256_fmadd_pd(ph[0][0], z0, _mm256_fmadd_pd(ph[0][1 % M], z1, t0));
                let n1 =
                    _mm256_fmadd_pd(ph[1 % M][1 % M], z1, _mm256_fmadd_pd(ph[1 % M][0], z0, t1));
                _mm256_storeu_pd(sp[0].add(o), n0);
                _mm256_storeu_pd(sp[1 % M].add(o), n1);
            }
        }
    }
    _mm256_movemask_pd(ok) == 0b1111
}

/// After samples `from..to`: the first follower (among the first `alive`) whose
/// acceleration left the range (or whose speed is not finite) gets NaN after that
/// sample, those behind it
/// NaN throughout; returns how many followers stay alive.
fn platoon_divergence<P: PlatoonOut + ?Sized>(
    outs: &mut P,
    alive: usize,
    from: usize,
    to: usize,
) -> usize {
    if outs.chunk_ok(alive, from, to) {
        return alive;
    }
    first_divergence(outs, alive, from, to)
}

/// [`platoon_divergence`] once a divergence is known to lie in samples `from..to`
/// (or to check without the branch-free pass).
fn first_divergence<P: PlatoonOut + ?Sized>(
    outs: &mut P,
    alive: usize,
    from: usize,
    to: usize,
) -> usize {
    let mut first = None;
    'scan: for j in 0..alive {
        for n in from..to {
            let (a, v) = outs.get(j, n);
            if !(a.abs() < DIVERGED && v.is_finite()) {
                first = Some((j, n));
                break 'scan;
            }
        }
    }
    let Some((j, n)) = first else {
        return alive;
    };
    outs.blank(j, n + 1);
    for k in j + 1..outs.followers() {
        outs.blank(k, 0);
    }
    j
}

/// A platoon of identical vehicles behind a recorded leader, one output per
/// follower (leader excluded) in `outs` (per follower, or [`TimeMajor`]), stepped
/// time-major. Each follower starts at the
/// leader's initial speed, at the equilibrium gap `Gmin + Tg v` behind its
/// predecessor, with the lower level at rest. A diverged follower's outputs are NaN
/// after the divergence, and those of the followers behind it throughout.
pub fn platoon_into<P: PlatoonOut + ?Sized>(
    lin: &Linear,
    eff: &EffectsRef,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    outs: &mut P,
) -> Result<()> {
    up.validate()?;
    check_leader(lead_x, lead_v)?;
    check_kind(eff.effects, CommandKind::Acceleration)?;
    if lead_x.is_empty() {
        return Err(AvllError::new("lead_x", "is empty"));
    }
    outs.check(lead_x.len())?;
    with_plant!(
        cached;
        lin,
        Integrators::SpeedPosition,
        dt,
        eff.modal(),
        platoon_n(lin, eff, up, lead_x, lead_v, outs)
    )
}

/// A platoon as new trajectories (see [`platoon_into`]).
pub fn platoon(
    lin: &Linear,
    eff: &EffectsRef,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    dt: f64,
    followers: usize,
) -> Result<Vec<Trajectory>> {
    let mut trs: Vec<Trajectory> = (0..followers)
        .map(|_| Trajectory::filled(lead_x.len(), 0.0))
        .collect();
    let mut outs: Vec<Out> = trs.iter_mut().map(Out::of).collect();
    platoon_into(lin, eff, up, lead_x, lead_v, dt, &mut outs[..])?;
    Ok(trs)
}

#[cfg(test)]
mod lane_tests {
    use super::*;
    use crate::sim::discretize::Integrators;

    /// The two chunk forms of the linear platoon (AVX2 intrinsics, and lane by lane
    /// with the same FMA arithmetic) give the same bits, for a real-pole, a
    /// complex-pole and a first-order model, 1 to 9 followers (partial groups), and
    /// a diverging platoon.
    #[test]
    fn avx2_lanes_equal_the_lane_by_lane_form() {
        if !crate::sim::fma() {
            return;
        }
        let n = 700;
        let lv: Vec<f64> = (0..n)
            .map(|k| 15.0 + 3.0 * (k as f64 * 0.01).sin())
            .collect();
        let mut lx = vec![100.0; n];
        for k in 1..n {
            lx[k] = lx[k - 1] + 0.025 * (lv[k] + lv[k - 1]);
        }
        let ups = [
            Upper {
                kg: 0.2,
                kv: 0.2,
                tg: 3.0,
                gmin: 9.5,
            },
            Upper {
                kg: 40.0,
                kv: 0.0,
                tg: 0.1,
                gmin: 2.0,
            },
        ];
        let lin = |b1, b0, a2, a1, td, k| Linear {
            b1,
            b0,
            a2,
            a1,
            td,
            k,
        };
        let models = [
            // The paper's proposed model (real poles), an underdamped one (complex
            // poles, K < 0, dead time below 4 samples), a first order.
            lin(6.7893, 0.3479, 1.2824, 8.8157, 0.7903, 0.1008),
            lin(0.3, 1.0, 0.8, 0.4, 0.12, -0.3),
            lin(0.0, 1.0, 0.0, 0.45, 0.33, 0.0),
        ];
        for lin in &models {
            for up in &ups {
                for f in 1..=9 {
                    let run = |avx2: bool| {
                        let mut bufs = [
                            vec![0.0; f * n],
                            vec![0.0; f * n],
                            vec![0.0; f * n],
                            vec![0.0; f * n],
                        ];
                        let [a, v, x, u] = &mut bufs;
                        let mut tm = TimeMajor {
                            followers: f,
                            a,
                            v,
                            x,
                            u,
                        };
                        let ints = Integrators::SpeedPosition;
                        if lin.order() == 2 {
                            let pl = Plant::<2, 4>::new(lin, ints, 0.05, true).unwrap();
                            if pl.diag {
                                platoon_linear::<2, 4, true, true, _>(
                                    pl, lin, up, &lx, &lv, &mut tm, avx2,
                                )
                            } else {
                                platoon_linear::<2, 4, false, true, _>(
                                    pl, lin, up, &lx, &lv, &mut tm, avx2,
                                )
                            }
                        } else {
                            let pl = Plant::<1, 3>::new(lin, ints, 0.05, false).unwrap();
                            platoon_linear::<1, 3, true, true, _>(
                                pl, lin, up, &lx, &lv, &mut tm, avx2,
                            )
                        }
                        .unwrap();
                        bufs
                    };
                    let (fast, lanes) = (run(true), run(false));
                    for (p, q) in fast.iter().zip(&lanes) {
                        for (a, b) in p.iter().zip(q) {
                            assert_eq!(a.to_bits(), b.to_bits(), "{f} followers");
                        }
                    }
                }
            }
        }
    }
}
