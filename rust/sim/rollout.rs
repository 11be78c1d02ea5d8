//! Rollouts on the one kernel: open loop (driven by a recorded command), closed loop
//! (behind a recorded leader through the upper-level constant-time-gap law, paper
//! Eq. 3) and platoons (time-major: every follower advances one sample before any
//! advances the next). Each takes an optional effect list (empty: the linear fast
//! path) with its exogenous signals, and writes into caller-provided slices
//! (`*_into`) or returns a [`Trajectory`].

use super::chain::{check_kind, resolve_exo, Chain, Effects, NoEffects};
use super::discretize::Integrators;
use super::kernel::{blocks_apply, response_blocks, run, Record, Response, Stepper, DIVERGED};
use super::plant::{start, Init, Plant, Start};
use super::with_plant;
use crate::effects::AnyEffect;
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

    /// The chain for a run of `len` samples (checks the exogenous signals).
    fn chain(&self, len: usize) -> Result<Effects<'a>> {
        Ok(Effects {
            effects: self.effects.to_vec(),
            exo: resolve_exo(self.effects, self.exo, len)?,
        })
    }

    /// Whether the modal form may be used (no effect switches the dynamics).
    pub fn modal(&self) -> bool {
        super::chain::modal_ok(self.effects)
    }
}

/// A stepper for `plant` with `chain`, started at `s` with the integrators at `int0`.
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
    let mut rec = Record::<false>::new(out.a, out.v, out.x, out.u);
    if eff.effects.is_empty() {
        let mut st = stepper::<M, N, D, F, _>(plant, lin, ints, NoEffects, accel, &s, int0)?;
        run(&mut st, u.len(), |n, _| u[n], &mut rec);
    } else {
        let ch = eff.chain(u.len())?;
        let mut st = stepper::<M, N, D, F, _>(plant, lin, ints, ch, accel, &s, int0)?;
        run(&mut st, u.len(), |n, _| u[n], &mut rec);
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
    for s in [&out.a, &out.v, &out.x] {
        check_len("out", s, u.len())?;
    }
    let ints = Integrators::for_kind(kind);
    with_plant!(
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
) -> Result<usize> {
    let s = start(lin, Init::Rest, 0.0)?;
    let ints = Integrators::SpeedPosition;
    let mut rec = Record::<true>::new(out.a, out.v, out.x, out.u);
    let law = |n: usize, o: &super::kernel::Obs| up.command(lead_x[n], lead_v[n], o.p, o.v);
    if eff.effects.is_empty() {
        let mut st = stepper::<M, N, D, F, _>(plant, lin, ints, NoEffects, true, &s, [v0, p0])?;
        run(&mut st, lead_x.len(), law, &mut rec);
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
        let mut st = stepper::<M, N, D, F, _>(plant, lin, ints, ch, true, &s, [v0, p0])?;
        run(&mut st, lead_x.len(), law, &mut rec);
    }
    Ok(rec.written)
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
    let written = with_plant!(
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
    )?;
    out.a[written..].fill(f64::NAN);
    out.v[written..].fill(f64::NAN);
    out.x[written..].fill(f64::NAN);
    if let Some(u) = out.u {
        u[written..].fill(f64::NAN);
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
    /// Records sample `n` of the first `a.len()` followers (one value per follower in
    /// each slice).
    #[inline(always)]
    fn put_row(&mut self, n: usize, a: &[f64], v: &[f64], x: &[f64], u: &[f64]) {
        for j in 0..a.len() {
            self.put(j, n, a[j], v[j], x[j], u[j]);
        }
    }
    /// The output rows of sample `n` for the first `a` followers (acceleration, speed,
    /// position, command), when they are contiguous (time-major outputs): the stepping
    /// then writes them in place instead of through [`PlatoonOut::put_row`].
    #[inline(always)]
    fn rows(&mut self, _n: usize, _a: usize) -> Option<[&mut [f64]; 4]> {
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
    fn rows(&mut self, n: usize, a: usize) -> Option<[&mut [f64]; 4]> {
        let k = n * self.followers;
        Some([
            &mut self.a[k..k + a],
            &mut self.v[k..k + a],
            &mut self.x[k..k + a],
            &mut self.u[k..k + a],
        ])
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
        platoon_linear::<M, N, D, F, _>(plant, lin, up, lead_x, lead_v, outs)
    } else {
        let ch = eff.chain(lead_x.len())?;
        platoon_chain::<M, N, D, F, _, _>(plant, lin, ch, up, lead_x, lead_v, outs)
    }
}

/// Time-major platoon stepping: at each sample every follower observes its state,
/// takes the upper law's command from its predecessor's observed position and speed
/// and steps. The followers' steps within a sample are independent, so they overlap
/// in the pipeline.
fn platoon_chain<
    const M: usize,
    const N: usize,
    const D: bool,
    const F: bool,
    C: Chain + Clone,
    P: PlatoonOut + ?Sized,
>(
    plant: Plant<M, N>,
    lin: &Linear,
    chain: C,
    up: &Upper,
    lead_x: &[f64],
    lead_v: &[f64],
    outs: &mut P,
) -> Result<()> {
    let len = lead_x.len();
    let f = outs.followers();
    let v0 = lead_v[0];
    let s = start(lin, Init::Rest, 0.0)?;
    let gap = up.gmin + up.tg * v0;
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
            for (j, car) in cars[..alive].iter_mut().enumerate() {
                let ob = car.observe(n);
                let u = up.command(px, pv, ob.p, ob.v);
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

/// The linear platoon in struct-of-arrays form: per sample, each pass (responses,
/// commands, dead-time line, state update) runs over all followers, with each state
/// component of all followers side by side and the followers' dead-time lines side
/// by side in one ring (`slot * F + j`), so the passes are independent across
/// followers and vectorize. The arithmetic, operation for operation, is the kernel's
/// ([`crate::sim::kernel`]'s `observe` and `advance`): the result is bit-identical
/// to followers stepped one by one (tested).
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
) -> Result<()> {
    use super::kernel::{madd, CHUNK};
    let len = lead_x.len();
    let f = outs.followers();
    if f == 0 {
        return Ok(());
    }
    let pl = &plant;
    let v0 = lead_v[0];
    let s = start(lin, Init::Rest, 0.0)?;
    let gap = up.gmin + up.tg * v0;
    // st[k][j]: state component k of follower j (model modes, speed, position).
    let mut st: [Vec<f64>; N] = std::array::from_fn(|_| vec![0.0; f]);
    for j in 0..f {
        let x = plant.state(&s, [v0, lead_x[0] - (j + 1) as f64 * gap]);
        for k in 0..N {
            st[k][j] = x[k];
        }
    }
    let cap = (plant.delay + 2).next_power_of_two();
    let mask = cap - 1;
    let mut ring = vec![s.w_hist; cap * f];
    let i = plant.delay;
    // One sample of the first `a` followers, its outputs written to `ya, va, xa, ua`
    // (the time-major output rows themselves, or local rows put afterwards).
    let mut sample =
        |n: usize, a: usize, ya: &mut [f64], va: &mut [f64], xa: &mut [f64], ua: &mut [f64]| {
            let (ya, va, xa, ua) = (&mut ya[..a], &mut va[..a], &mut xa[..a], &mut ua[..a]);
            // Responses at n: y = C z (as `observe`).
            for (yj, z0) in ya.iter_mut().zip(&st[0][..a]) {
                *yj = z0 * pl.c[0];
            }
            if M == 2 {
                for (yj, z1) in ya.iter_mut().zip(&st[1][..a]) {
                    *yj = madd::<F>(pl.c[1], *z1, *yj);
                }
            }
            // Commands from the predecessors' positions and speeds at n, recorded with
            // the followers' own.
            {
                let (vs, ps) = (&st[M][..a], &st[M + 1][..a]);
                ua[0] = up.command(lead_x[n], lead_v[n], ps[0], vs[0]);
                va[0] = vs[0];
                xa[0] = ps[0];
                for j in 1..a {
                    ua[j] = up.command(ps[j - 1], vs[j - 1], ps[j], vs[j]);
                    va[j] = vs[j];
                    xa[j] = ps[j];
                }
            }
            // The dead-time line: this sample's row in; the rows i and i + 1 samples back
            // are `w0` and `w1` (the ring holds at least i + 2 rows, so neither is the one
            // just written unless i = 0, where `w0` is that row, as in the kernel).
            let row = (n & mask) * f;
            for ((r, uj), yj) in ring[row..row + a].iter_mut().zip(&*ua).zip(&*ya) {
                *r = uj + pl.k * yj;
            }
            let back = (n.wrapping_sub(i) & mask) * f;
            let back1 = (n.wrapping_sub(i + 1) & mask) * f;
            // The exact step (as `advance`).
            step_soa::<M, N, D, F>(pl, &mut st, &ring[back..back + a], &ring[back1..back1 + a]);
        };
    let (mut y, mut u) = (vec![0.0; f], vec![0.0; f]);
    let (mut vb, mut xb) = (vec![0.0; f], vec![0.0; f]);
    let mut alive = f;
    let mut from = 0;
    while from < len && alive > 0 {
        let to = (from + CHUNK).min(len);
        for n in from..to {
            let a = alive;
            if let Some([ya, va, xa, ua]) = outs.rows(n, a) {
                sample(n, a, ya, va, xa, ua);
            } else {
                sample(n, a, &mut y, &mut vb, &mut xb, &mut u);
                outs.put_row(n, &y[..a], &vb[..a], &xb[..a], &u[..a]);
            }
        }
        alive = platoon_divergence(outs, alive, from, to);
        from = to;
    }
    Ok(())
}

/// `advance` over all followers at once (struct of arrays): `w0` and `w1` are the
/// followers' delayed references `u_ref[n - i]` and `u_ref[n - i - 1]`.
#[inline(always)]
fn step_soa<const M: usize, const N: usize, const D: bool, const F: bool>(
    pl: &Plant<M, N>,
    st: &mut [Vec<f64>; N],
    w0: &[f64],
    w1: &[f64],
) {
    use super::kernel::madd;
    let a = w0.len();
    let (g0, g1, phi) = (&pl.g0, &pl.g1, &pl.phi);
    // Integrators first: they read the model states before the update.
    {
        let (zs, ints) = st.split_at_mut(M);
        let (vs, ps) = ints.split_at_mut(1);
        let (vs, ps) = (&mut vs[0][..a], &mut ps[0][..a]);
        for j in 0..a {
            let (w0j, w1j) = (w0[j], w1[j]);
            let mut tv = madd::<F>(g1[M], w1j, g0[M] * w0j);
            for k in 0..M {
                tv = madd::<F>(phi[M][k], zs[k][j], tv);
            }
            let mut tp = madd::<F>(g1[M + 1], w1j, g0[M + 1] * w0j);
            tp = madd::<F>(phi[M + 1][M], vs[j], tp);
            for k in 0..M {
                tp = madd::<F>(phi[M + 1][k], zs[k][j], tp);
            }
            vs[j] += tv;
            ps[j] += tp;
        }
    }
    if D || M == 1 {
        for r in 0..M {
            let z = &mut st[r][..a];
            for j in 0..a {
                let t = madd::<F>(g1[r], w1[j], g0[r] * w0[j]);
                z[j] = madd::<F>(phi[r][r], z[j], t);
            }
        }
    } else {
        let (z0, z1) = st.split_at_mut(1);
        let (z0, z1) = (&mut z0[0][..a], &mut z1[0][..a]);
        for j in 0..a {
            let t0 = madd::<F>(g1[0], w1[j], g0[0] * w0[j]);
            let t1 = madd::<F>(g1[1], w1[j], g0[1] * w0[j]);
            let n0 = madd::<F>(phi[0][0], z0[j], madd::<F>(phi[0][1], z1[j], t0));
            let n1 = madd::<F>(phi[1][1], z1[j], madd::<F>(phi[1][0], z0[j], t1));
            z0[j] = n0;
            z1[j] = n1;
        }
    }
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
