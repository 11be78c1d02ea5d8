//! Effects: self-contained extensions of any base model.
//!
//! An effect adds one physical phenomenon that the linear lower-level models lack.
//! Each lives in its own file, implements [`Effect`] (only the hooks it needs; the
//! others default to the identity) and is listed once in the registry at the end of
//! this file: **one new effect = one new file + one registry line**.
//!
//! Hooks, in the order the kernel ([`crate::sim::kernel`]) applies them at each sample `n`:
//! 1. [`Effect::command`] — the command on its way to the lower level (transport
//!    `delay`, `rate_limit`, `deadband`), in registry order;
//! 2. [`Effect::reference`] — a static map of the reference input
//!    `u_ref = u' + K y_act` before the dead time (`asymmetric`'s braking gain);
//! 3. [`Effect::brake_time_scale`] — the rational part runs `r` times slower while
//!    braking (`asymmetric`): exact ZOH of `G(r s)`, switched per interval;
//! 4. [`Effect::output`] — the lower level's acceleration, given the actual speed
//!    (`saturation`, `power_limit`; these maps commute);
//! 5. [`Effect::disturbance`] — an additive acceleration from the actual speed and
//!    an exogenous signal (`speed_drag`, `road_load`, `grade`);
//! 6. [`Effect::measure`] — what is observed: the recorded and compared
//!    acceleration (`sensor`); the dynamics and every feedback use the true one.
//!
//! Hooks 4-5 act on *the acceleration that integrates into the actual speed*: for
//! an acceleration command the lower level's response `y_lin`; for a speed command
//! the derivative of the lower level's speed response (the actual speed is then the
//! linear response plus the integral of the difference, and the inner loop's `K`
//! feeds back the actual speed, as it feeds back the actual acceleration for an
//! acceleration command).
//!
//! With no effect the kernel runs the linear fast path; with every effect at its
//! neutral parameters it reproduces it (tested to 1e-11).
//!
//! **Two levels.** The effects above are *lower-level* ([`Level::Lower`]): they act
//! between the command and the vehicle. The *upper-level* structures
//! ([`Level::Upper`]: `perception`, `feedforward`, `closing`, `comfort`,
//! `speed_gains`) act on the car-following law itself, so only in a closed loop (a
//! recorded leader, or a platoon); the kernel's upper chain
//! ([`crate::sim::chain::UpperChain`]) evaluates, at each sample, from the
//! predecessor's position and speed and the follower's own:
//! 1. [`Effect::perceive`] — the radar signals, gap `x_p - x` and relative speed
//!    `v_p - v`, as the controller sees them (`perception`'s delay); the own speed is
//!    not delayed;
//! 2. [`Effect::gains`] — the law's `kg, kv, Tg` at the own speed (`speed_gains`);
//! 3. the gap error `e = gap - Tg v - Gmin` and the law's two terms `kg e`, `kv dv`,
//!    then [`Effect::shape`] — a static map of the two terms (`closing`: other gains
//!    while closing in);
//! 4. [`Effect::feedforward`] — an additive command from the perceived predecessor
//!    speed `v + dv` (`feedforward`: a gain on its filtered derivative);
//! 5. [`Effect::limit`] — the command's comfort limits (`comfort`).
//!
//! With no upper-level structure (or each at its neutral parameters) this is the
//! paper's Eq. 3. Their small-signal forms ([`Effect::linearize_upper`], collected by
//! [`linearize_upper`] into an [`UpperLin`]) enter the follower's exact frequency
//! response [`response`] beside the lower level's [`Linear`] and [`Terms`].
pub mod follower;

use crate::error::{check_finite, AvllError, Result};
use crate::model::{CommandKind, Linear};
use crate::sim::Upper;
use nalgebra::Complex;

/// Which part of the follower an effect belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// Between the command and the vehicle (the lower level, its actuators, the
    /// vehicle's resistances, the acceleration sensor).
    Lower,
    /// The car-following law (perception, gains, feedforward, command limits): acts
    /// only in a closed loop.
    Upper,
}

impl Level {
    pub fn name(self) -> &'static str {
        match self {
            Level::Lower => "lower",
            Level::Upper => "upper",
        }
    }
}

/// The constant-time-gap law's gains at a sample (what [`Effect::gains`] maps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gains {
    pub kg: f64,
    pub kv: f64,
    pub tg: f64,
}

/// Small-signal form of the upper level with its structures about a constant speed
/// `v` (the predecessor at the same speed, the gap at its equilibrium): the command is
///
/// ```text
///   U = R (X_p - X) - kg Tg s X + F (s X + D s (X_p - X)),
///   R = (kg + kv s) D,   D = e^{-delay s},   F = ff_gain s / (ff_tau s + 1),
/// ```
///
/// with `X_p`, `X` the predecessor's and the follower's positions: the radar terms
/// (gap and relative speed) seen `delay` late, the own speed's term `kg Tg v`
/// undelayed, and the feedforward `F` on the perceived predecessor speed
/// `v + D (v_p - v)`. Without structures: `kg, kv, Tg` of Eq. 3, no delay, no
/// feedforward.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpperLin {
    pub kg: f64,
    pub kv: f64,
    /// The small-signal time gap: the slope `d(desired gap)/dv` at the operating speed.
    pub tg: f64,
    /// The equilibrium time gap: the desired gap at the operating speed is
    /// `gmin + tg_eq v`.
    pub tg_eq: f64,
    pub gmin: f64,
    /// Perception delay (s) of the radar terms.
    pub delay: f64,
    /// Feedforward gain (s) and filter time constant (s).
    pub ff_gain: f64,
    pub ff_tau: f64,
}

impl UpperLin {
    /// Eq. 3 without structures.
    pub fn of(up: &Upper) -> Self {
        Self {
            kg: up.kg,
            kv: up.kv,
            tg: up.tg,
            tg_eq: up.tg,
            gmin: up.gmin,
            delay: 0.0,
            ff_gain: 0.0,
            ff_tau: 0.0,
        }
    }
}

/// Operating point of a linearisation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Operating {
    /// Speed (m/s).
    pub v: f64,
    /// Which side of an acceleration/braking asymmetry: `1` acceleration, `-1`
    /// braking, `0` the average of the two.
    pub side: i8,
}

/// Small-signal terms of an effect that a [`Linear`] cannot hold (see
/// [`linearize_terms`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Terms {
    /// `beta` (1/s): the actual acceleration gets `-beta dv` (a speed feedback:
    /// the factor `s / (s + beta)` on the acceleration), from speed-dependent
    /// resistances (`speed_drag`, `road_load`).
    pub speed_feedback: f64,
    /// Time constant (s) of the first-order filter `1 / (tau s + 1)` on the observed
    /// acceleration (`sensor`); not a dynamic of the vehicle.
    pub obs_tau: f64,
    /// Offset (m/s²) of the observed acceleration (`sensor`).
    pub obs_bias: f64,
    /// Transport delay (s) of the command outside the inner loop (`delay`): the
    /// factor `e^{-command_delay s}` before `G_fb`.
    pub command_delay: f64,
}

/// One effect. Parameters are validated by [`Effect::new`] (physical validity);
/// [`Effect::BOUNDS`] are the calibration search bounds.
pub trait Effect: Clone + Send + Sync + Sized {
    /// The registry name (scripts depend on it).
    const NAME: &'static str;
    /// Parameter names, in row order.
    const PARAMS: &'static [&'static str];
    /// Calibration bounds `(lo, hi)` per parameter.
    const BOUNDS: &'static [(f64, f64)];
    /// Parameter values at which the effect is (or tends to) the identity.
    const NEUTRAL: &'static [f64];
    /// Name of the exogenous signal the effect reads (e.g. `"grade"`).
    const EXO: Option<&'static str> = None;
    /// `true` if the effect needs an acceleration command (none of the registered
    /// ones since the acceleration-level effects act on the derivative of a speed
    /// response too; kept for effects that cannot).
    const ACCEL_ONLY: bool = false;
    /// `true` if the effect reads the actual speed (the engine then integrates it
    /// even when the cost does not need it).
    const NEEDS_SPEED: bool = false;
    /// The part of the follower it belongs to (upper-level effects act only in a
    /// closed loop).
    const LEVEL: Level = Level::Lower;
    /// An effect refused together with this one (their parameters are not
    /// identifiable together).
    const EXCLUDES: Option<&'static str> = None;

    /// Builds the effect from validated parameters (`p.len() == PARAMS.len()`,
    /// finite).
    fn new(p: &[f64], kind: CommandKind) -> Result<Self>;
    /// Resets the internal state before a run; `u_hist` is the command assumed
    /// before the run (0 at rest, `u[0]` at steady state).
    fn reset(&mut self, _u_hist: f64, _dt: f64) {}
    /// Transforms the command; `y` is the actual response at this sample
    /// (acceleration or speed, by command kind).
    fn command(&mut self, u: f64, _y: f64) -> f64 {
        u
    }
    /// Static map of the reference input before the dead time.
    fn reference(&self, w: f64) -> f64 {
        w
    }
    /// Time-scale ratio of the rational part while braking (1 = no switching).
    fn brake_time_scale(&self) -> f64 {
        1.0
    }
    /// Transforms the lower level's acceleration `a`; `v` is the actual speed.
    fn output(&self, a: f64, _v: f64) -> f64 {
        a
    }
    /// Additive acceleration from the actual speed `v` and the exogenous sample
    /// `exo` (0 when the effect reads none).
    fn disturbance(&self, _v: f64, _exo: f64) -> f64 {
        0.0
    }
    /// The observed acceleration from the true one `a` (sample by sample, in order).
    fn measure(&mut self, a: f64) -> f64 {
        a
    }
    /// The small-signal equivalent of base + this effect as a [`Linear`], or an
    /// error saying why none exists.
    fn linearize(&self, lin: &Linear, _op: &Operating) -> Result<Linear> {
        Ok(*lin)
    }
    /// The small-signal equivalent split into the lower level's [`Linear`] and the
    /// [`Terms`] outside it (speed feedback, observation filter).
    fn linearize_terms(&self, lin: &Linear, op: &Operating) -> Result<(Linear, Terms)> {
        Ok((self.linearize(lin, op)?, Terms::default()))
    }
    /// Upper level: the radar's gap and relative speed as the controller sees them.
    fn perceive(&mut self, gap: f64, dv: f64) -> (f64, f64) {
        (gap, dv)
    }
    /// Upper level: the law's gains at the own speed `v`.
    fn gains(&self, g: Gains, _v: f64) -> Gains {
        g
    }
    /// Upper level: a static map of the law's gap term `kg e` and speed term `kv dv`.
    fn shape(&self, eg: f64, ev: f64) -> (f64, f64) {
        (eg, ev)
    }
    /// Upper level: an additive command from the perceived predecessor speed `vp`
    /// (sample by sample, in order).
    fn feedforward(&mut self, _vp: f64) -> f64 {
        0.0
    }
    /// Upper level: the command after its limits (sample by sample, in order).
    fn limit(&mut self, u: f64) -> f64 {
        u
    }
    /// Upper level: the small-signal form with this structure.
    fn linearize_upper(&self, u: &UpperLin, _op: &Operating) -> Result<UpperLin> {
        Ok(*u)
    }
}

/// Checks a parameter against a closed interval of physical validity.
pub(crate) fn check_range(arg: &str, x: f64, lo: f64, hi: f64) -> Result<()> {
    check_finite(arg, x)?;
    if x < lo || x > hi {
        return Err(AvllError::new(
            arg,
            format!("must be in [{lo}, {hi}], got {x}"),
        ));
    }
    Ok(())
}

macro_rules! registry {
    ($($variant:ident => $module:ident :: $ty:ident),+ $(,)?) => {
        $(pub mod $module;)+

        /// The registered effects, in their canonical application order.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub enum EffectKind { $($variant),+ }

        /// An effect instance (static dispatch).
        #[derive(Debug, Clone)]
        pub enum AnyEffect { $($variant($module::$ty)),+ }

        impl EffectKind {
            pub const ALL: &'static [EffectKind] = &[$(EffectKind::$variant),+];

            pub fn name(self) -> &'static str {
                match self { $(EffectKind::$variant => <$module::$ty as Effect>::NAME),+ }
            }
            pub fn params(self) -> &'static [&'static str] {
                match self { $(EffectKind::$variant => <$module::$ty as Effect>::PARAMS),+ }
            }
            pub fn bounds(self) -> &'static [(f64, f64)] {
                match self { $(EffectKind::$variant => <$module::$ty as Effect>::BOUNDS),+ }
            }
            pub fn neutral(self) -> &'static [f64] {
                match self { $(EffectKind::$variant => <$module::$ty as Effect>::NEUTRAL),+ }
            }
            pub fn exo(self) -> Option<&'static str> {
                match self { $(EffectKind::$variant => <$module::$ty as Effect>::EXO),+ }
            }
            pub fn accel_only(self) -> bool {
                match self { $(EffectKind::$variant => <$module::$ty as Effect>::ACCEL_ONLY),+ }
            }
            pub fn needs_speed(self) -> bool {
                match self { $(EffectKind::$variant => <$module::$ty as Effect>::NEEDS_SPEED),+ }
            }
            pub fn level(self) -> Level {
                match self { $(EffectKind::$variant => <$module::$ty as Effect>::LEVEL),+ }
            }
            pub fn excludes(self) -> Option<&'static str> {
                match self { $(EffectKind::$variant => <$module::$ty as Effect>::EXCLUDES),+ }
            }
            fn build(self, p: &[f64], kind: CommandKind) -> Result<AnyEffect> {
                match self {
                    $(EffectKind::$variant => Ok(AnyEffect::$variant(
                        <$module::$ty as Effect>::new(p, kind)?))),+
                }
            }
        }

        impl AnyEffect {
            pub fn kind(&self) -> EffectKind {
                match self { $(AnyEffect::$variant(_) => EffectKind::$variant),+ }
            }
            #[inline]
            pub fn reset(&mut self, u: f64, dt: f64) {
                match self { $(AnyEffect::$variant(e) => e.reset(u, dt)),+ }
            }
            #[inline(always)]
            pub fn command(&mut self, u: f64, y: f64) -> f64 {
                match self { $(AnyEffect::$variant(e) => e.command(u, y)),+ }
            }
            #[inline(always)]
            pub fn reference(&self, w: f64) -> f64 {
                match self { $(AnyEffect::$variant(e) => e.reference(w)),+ }
            }
            #[inline]
            pub fn brake_time_scale(&self) -> f64 {
                match self { $(AnyEffect::$variant(e) => e.brake_time_scale()),+ }
            }
            #[inline(always)]
            pub fn output(&self, a: f64, v: f64) -> f64 {
                match self { $(AnyEffect::$variant(e) => e.output(a, v)),+ }
            }
            #[inline(always)]
            pub fn measure(&mut self, a: f64) -> f64 {
                match self { $(AnyEffect::$variant(e) => e.measure(a)),+ }
            }
            #[inline(always)]
            pub fn disturbance(&self, v: f64, exo: f64) -> f64 {
                match self { $(AnyEffect::$variant(e) => e.disturbance(v, exo)),+ }
            }
            pub fn linearize(&self, lin: &Linear, op: &Operating) -> Result<Linear> {
                match self { $(AnyEffect::$variant(e) => e.linearize(lin, op)),+ }
            }
            pub fn linearize_terms(&self, lin: &Linear, op: &Operating) -> Result<(Linear, Terms)> {
                match self { $(AnyEffect::$variant(e) => e.linearize_terms(lin, op)),+ }
            }
            #[inline(always)]
            pub fn perceive(&mut self, gap: f64, dv: f64) -> (f64, f64) {
                match self { $(AnyEffect::$variant(e) => e.perceive(gap, dv)),+ }
            }
            #[inline(always)]
            pub fn gains(&self, g: Gains, v: f64) -> Gains {
                match self { $(AnyEffect::$variant(e) => e.gains(g, v)),+ }
            }
            #[inline(always)]
            pub fn shape(&self, eg: f64, ev: f64) -> (f64, f64) {
                match self { $(AnyEffect::$variant(e) => e.shape(eg, ev)),+ }
            }
            #[inline(always)]
            pub fn feedforward(&mut self, vp: f64) -> f64 {
                match self { $(AnyEffect::$variant(e) => e.feedforward(vp)),+ }
            }
            #[inline(always)]
            pub fn limit(&mut self, u: f64) -> f64 {
                match self { $(AnyEffect::$variant(e) => e.limit(u)),+ }
            }
            pub fn linearize_upper(&self, u: &UpperLin, op: &Operating) -> Result<UpperLin> {
                match self { $(AnyEffect::$variant(e) => e.linearize_upper(u, op)),+ }
            }
        }
    };
}

registry! {
    Delay => delay::Delay,
    RateLimit => rate_limit::RateLimit,
    Deadband => deadband::Deadband,
    Asymmetric => asymmetric::Asymmetric,
    Saturation => saturation::Saturation,
    SpeedDrag => speed_drag::SpeedDrag,
    Grade => grade::Grade,
    RoadLoad => road_load::RoadLoad,
    PowerLimit => power_limit::PowerLimit,
    Sensor => sensor::Sensor,
    // The upper level (closed loop only).
    Perception => perception::Perception,
    SpeedGains => speed_gains::SpeedGains,
    Closing => closing::Closing,
    Feedforward => feedforward::Feedforward,
    Comfort => comfort::Comfort,
}

impl EffectKind {
    /// Looks an effect up by its registry name.
    pub fn from_name(name: &str) -> Result<Self> {
        EffectKind::ALL
            .iter()
            .copied()
            .find(|e| e.name() == name)
            .ok_or_else(|| {
                let known: Vec<_> = EffectKind::ALL.iter().map(|e| e.name()).collect();
                AvllError::new(
                    "effects",
                    format!("unknown effect {name:?}; known: {}", known.join(", ")),
                )
            })
    }

    pub fn n_params(self) -> usize {
        self.params().len()
    }
}

/// A list of distinct effect kinds (the structure of an extended model), sorted
/// into the canonical order.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct EffectList(pub Vec<EffectKind>);

impl EffectList {
    /// Parses names; rejects duplicates, accel-only effects with a speed command and
    /// pairs an effect [`Effect::EXCLUDES`] (e.g. `speed_drag` and `road_load`: one
    /// model family, `road_load` with `c1 = 0` is `speed_drag`, so their parameters
    /// would not be identifiable together).
    pub fn from_names(names: &[&str], kind: CommandKind) -> Result<Self> {
        let mut v = Vec::with_capacity(names.len());
        for n in names {
            let k = EffectKind::from_name(n)?;
            if v.contains(&k) {
                return Err(AvllError::new(
                    "effects",
                    format!("effect {n:?} given twice"),
                ));
            }
            if k.accel_only() && kind == CommandKind::Speed {
                return Err(AvllError::new(
                    "effects",
                    format!(
                        "effect {n:?} acts on the acceleration and needs an acceleration command"
                    ),
                ));
            }
            v.push(k);
        }
        for k in &v {
            if let Some(x) = k.excludes() {
                if v.iter().any(|o| o.name() == x) {
                    return Err(AvllError::new(
                        "effects",
                        format!(
                            "{:?} and {x:?} together: one contains the other, so their \
                             parameters are not identifiable together; use one",
                            k.name()
                        ),
                    ));
                }
            }
        }
        v.sort();
        Ok(EffectList(v))
    }

    /// Whether any effect acts on the upper level (the list then needs a closed loop).
    pub fn has_upper(&self) -> bool {
        self.0.iter().any(|k| k.level() == Level::Upper)
    }

    /// Fails when an upper-level effect is asked for outside a closed loop.
    pub fn check_closed(&self, closed: bool) -> Result<()> {
        check_closed(self.0.iter().map(|k| (k.name(), k.level())), closed)
    }

    /// Total number of effect parameters.
    pub fn n_params(&self) -> usize {
        self.0.iter().map(|k| k.n_params()).sum()
    }

    /// Builds the effect instances from a parameter slice (in list order).
    pub fn build(&self, p: &[f64], kind: CommandKind) -> Result<Vec<AnyEffect>> {
        if p.len() != self.n_params() {
            return Err(AvllError::new(
                "effect_params",
                format!("expected {} values, got {}", self.n_params(), p.len()),
            ));
        }
        let mut out = Vec::with_capacity(self.0.len());
        let mut o = 0;
        for k in &self.0 {
            let q = &p[o..o + k.n_params()];
            for (x, n) in q.iter().zip(k.params()) {
                check_finite(&format!("{}.{n}", k.name()), *x)?;
            }
            out.push(k.build(q, kind)?);
            o += k.n_params();
        }
        Ok(out)
    }
}

/// The small-signal equivalent of a base model with effects, applying each effect's
/// linearisation in canonical order.
pub fn linearize(lin: &Linear, effects: &[AnyEffect], op: &Operating) -> Result<Linear> {
    let mut l = *lin;
    for e in effects {
        l = e.linearize(&l, op)?;
    }
    Ok(l)
}

/// As [`linearize`], but effects whose small-signal content lies outside the lower
/// level (a speed feedback from speed-dependent resistances, a filter on the
/// observation) contribute [`Terms`] instead of an error: the lower level's
/// [`Linear`] (command to actuator acceleration) and the terms, summed
/// (`speed_feedback`) or taken from the one `sensor`.
pub fn linearize_terms(
    lin: &Linear,
    effects: &[AnyEffect],
    op: &Operating,
) -> Result<(Linear, Terms)> {
    let mut l = *lin;
    let mut t = Terms::default();
    for e in effects {
        let (l2, t2) = e.linearize_terms(&l, op)?;
        l = l2;
        t.speed_feedback += t2.speed_feedback;
        t.obs_tau += t2.obs_tau;
        t.obs_bias += t2.obs_bias;
        t.command_delay += t2.command_delay;
    }
    Ok((l, t))
}

/// Fails when an upper-level effect of `effects` (name, level) is used outside a
/// closed loop (its law is not evaluated in an open loop driven by a recorded command).
pub fn check_closed<'a>(
    effects: impl IntoIterator<Item = (&'a str, Level)>,
    closed: bool,
) -> Result<()> {
    if closed {
        return Ok(());
    }
    match effects.into_iter().find(|(_, l)| *l == Level::Upper) {
        Some((n, _)) => Err(AvllError::new(
            "effects",
            format!(
                "effect {n:?} acts on the upper level (the car-following law) and needs a \
                 closed loop (a recorded leader, or a platoon)"
            ),
        )),
        None => Ok(()),
    }
}

/// The small-signal form of the upper level `up` with the upper-level effects among
/// `effects` at the operating point (each effect's [`Effect::linearize_upper`] in
/// canonical order; lower-level effects are ignored).
pub fn linearize_upper(up: &Upper, effects: &[AnyEffect], op: &Operating) -> Result<UpperLin> {
    let mut u = UpperLin::of(up);
    for e in effects {
        if e.kind().level() == Level::Upper {
            u = e.linearize_upper(&u, op)?;
        }
    }
    Ok(u)
}

/// The follower's exact frequency response `H(jω) = V(jω) / V_p(jω)` (predecessor
/// speed to follower speed, the paper's Eq. 8 with the true delays) at `omega`
/// (rad/s, > 0), for the lower level `lin` with its outer [`Terms`] and the upper
/// level [`UpperLin`]:
///
/// ```text
///   G    = (b1 s + b0) e^{-Td s} / (a2 s² + a1 s + 1),
///   G_fb = G e^{-command_delay s} / (1 - K G + speed_feedback / s),
///   U    = P X_p - Q X   (see UpperLin),
///   P    = R + F s D,    Q = R + kg Tg s - F s (1 - D),
///   H    = G_fb P / (s² + G_fb Q).
/// ```
///
/// The observation terms (`obs_tau`, `obs_bias`) do not enter: they change what is
/// recorded, not the vehicle. Without terms and structures this is Eq. 8:
/// `G_fb (kv s + kg) / (s² + G_fb ((kv + kg Tg) s + kg))`.
pub fn response(lin: &Linear, t: &Terms, u: &UpperLin, omega: f64) -> Complex<f64> {
    let s = Complex::new(0.0, omega);
    let delay = |tau: f64| (-s * tau).exp();
    let g = (s * lin.b1 + lin.b0) * delay(lin.td) / (s * s * lin.a2 + s * lin.a1 + 1.0);
    let gfb = g * delay(t.command_delay) / (-g * lin.k + 1.0 + t.speed_feedback / s);
    let d = delay(u.delay);
    let r = (s * u.kv + u.kg) * d;
    let f = s * u.ff_gain / (s * u.ff_tau + 1.0);
    let p = r + f * s * d;
    let q = r + s * (u.kg * u.tg) - f * s * (-d + 1.0);
    gfb * p / (s * s + gfb * q)
}

/// The lower level of a loop run at sample period `hold` (s): the law's command and
/// the inner feedback held over each sample, which acts on the response below the
/// Nyquist frequency as a dead time of half a period. The rollouts run so (every
/// model and effect at the run's `dt`), so a model calibrated on runs sampled at `dt`
/// describes the follower with `td + dt / 2` (`hold = 0`: the continuous loop, the
/// paper's Eq. 8).
pub fn held(mut lin: Linear, hold: f64) -> Linear {
    lin.td += 0.5 * hold;
    lin
}

/// The small-signal forms of a parameter row `[model | effects | kg, kv, Tg, Gmin]`.
fn row_forms(
    model: crate::model::ModelKind,
    effects: &EffectList,
    kind: CommandKind,
    row: &[f64],
    op: &Operating,
) -> Result<(Linear, Terms, UpperLin)> {
    let (nm, ne) = (model.n_params(), effects.n_params());
    let lin = model.linear(&row[..nm])?;
    let effs = effects.build(&row[nm..nm + ne], kind)?;
    let u = &row[nm + ne..];
    let up = Upper {
        kg: u[0],
        kv: u[1],
        tg: u[2],
        gmin: u[3],
    };
    up.validate()?;
    let (l, t) = linearize_terms(&lin, &effs, op)?;
    Ok((l, t, linearize_upper(&up, &effs, op)?))
}

/// Checks the shape of parameter rows `[model | effects | kg, kv, Tg, Gmin]`.
fn check_rows(
    model: crate::model::ModelKind,
    effects: &EffectList,
    rows: &[f64],
    d: usize,
) -> Result<()> {
    let (nm, ne) = (model.n_params(), effects.n_params());
    if d != nm + ne + 4 {
        return Err(AvllError::new(
            "rows",
            format!(
                "have {d} columns; the model {:?} ({nm}), the effects ({ne}) and kg, kv, Tg, \
                 Gmin need {}",
                model.name(),
                nm + ne + 4
            ),
        ));
    }
    if !rows.len().is_multiple_of(d) {
        return Err(AvllError::new("rows", "is not a whole number of rows"));
    }
    Ok(())
}

/// Certified stability codes (0 locally unstable, 1 string unstable, 2 string stable)
/// of many parameter rows `[model | effects | kg, kv, Tg, Gmin]` linearised at `op`,
/// with every delay kept exactly ([`follower::FollowerLoop`]: the dead time, a command
/// delay, a perception delay), and whether each is certified; a row without a
/// small-signal form gets `(0, false)`. `budget` interval evaluations per test. In
/// parallel over rows.
pub fn codes_rows(
    model: crate::model::ModelKind,
    effects: &EffectList,
    kind: CommandKind,
    rows: &[f64],
    d: usize,
    op: &Operating,
    budget: usize,
) -> Result<Vec<(u8, bool)>> {
    use rayon::prelude::*;
    check_rows(model, effects, rows, d)?;
    Ok(rows
        .par_chunks(d)
        .map(|row| match row_forms(model, effects, kind, row, op) {
            Ok((l, t, u)) => {
                let mut fl = follower::FollowerLoop::new(&l, &t, &u);
                fl.budget = budget.max(1);
                fl.code()
            }
            Err(_) => (0, false),
        })
        .collect())
}

/// The follower's exact frequency response ([`response`]) of many parameter rows at
/// once: each row of `rows` (row-major, `n x d`) is `[model | effects | kg, kv, Tg,
/// Gmin]` (the effects' parameters in the canonical order of `effects`), linearised at
/// the operating point `op`, the loop run at sample period `hold` ([`held`]; 0: the
/// continuous loop); the result is `n x omega.len()` (row-major). A row whose
/// parameters the model, an effect or the law refuses, or whose small-signal form does
/// not exist, gives NaN. In parallel over rows (the values do not depend on the
/// threads).
#[allow(clippy::too_many_arguments)]
pub fn response_rows(
    model: crate::model::ModelKind,
    effects: &EffectList,
    kind: CommandKind,
    rows: &[f64],
    d: usize,
    omega: &[f64],
    op: &Operating,
    hold: f64,
) -> Result<Vec<Complex<f64>>> {
    use rayon::prelude::*;
    check_rows(model, effects, rows, d)?;
    crate::error::check_nonneg("hold", hold)?;
    if let Some(w) = omega.iter().find(|w| !(w.is_finite() && **w > 0.0)) {
        return Err(AvllError::new(
            "omega",
            format!("frequencies must be finite and > 0, got {w}"),
        ));
    }
    let m = omega.len();
    let nan = Complex::new(f64::NAN, f64::NAN);
    let one = |row: &[f64]| -> Vec<Complex<f64>> {
        match row_forms(model, effects, kind, row, op) {
            Ok((l, t, u)) => {
                let l = held(l, hold);
                omega.iter().map(|&w| response(&l, &t, &u, w)).collect()
            }
            Err(_) => vec![nan; m],
        }
    };
    let parts: Vec<Vec<Complex<f64>>> = rows.par_chunks(d).with_min_len(8).map(one).collect();
    Ok(parts.concat())
}
