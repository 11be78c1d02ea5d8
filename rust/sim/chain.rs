//! The effect chain a rollout runs through: none (the linear fast path, every hook
//! the identity at compile time) or a list of effects with their exogenous signals;
//! and the upper level of a closed loop ([`Law`]): the constant-time-gap law alone
//! ([`Upper`]) or with its structures ([`UpperChain`]).
//!
//! The hooks and their order are those of [`crate::effects::Effect`]; the kernel
//! ([`super::kernel`]) calls them through this trait so that one stepping loop serves
//! both cases and the linear case pays nothing for the generality.

use super::rollout::Upper;
use crate::effects::{AnyEffect, Gains, Level};
use crate::error::{check_series, AvllError, Result};
use crate::model::CommandKind;

/// The hooks the kernel calls at each sample.
pub trait Chain: Send {
    /// `true` when every hook is the identity: the kernel then skips them, and the
    /// correction integrators, at compile time.
    const NONE: bool;
    /// Resets internal states before a run (`u_hist`: the command assumed before it).
    fn reset(&mut self, u_hist: f64, dt: f64);
    /// The command on its way to the lower level; `y` the actual response.
    fn command(&mut self, u: f64, y: f64) -> f64;
    /// Static map of the reference input before the dead time.
    fn reference(&self, w: f64) -> f64;
    /// The lower level's acceleration after the output maps (`v`: actual speed).
    fn output(&self, a: f64, v: f64) -> f64;
    /// Additive acceleration at sample `n` from the actual speed.
    fn disturbance(&self, v: f64, n: usize) -> f64;
    /// Time-scale ratio of the rational part while braking (1: no switching).
    fn brake_time_scale(&self) -> f64;
    /// The observed acceleration of this sample from the true one (called once per
    /// sample, in order; what sinks record and costs compare).
    fn measure(&mut self, a: f64) -> f64;
}

/// No effect: the linear lower level.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoEffects;

impl Chain for NoEffects {
    const NONE: bool = true;
    #[inline(always)]
    fn reset(&mut self, _: f64, _: f64) {}
    #[inline(always)]
    fn command(&mut self, u: f64, _: f64) -> f64 {
        u
    }
    #[inline(always)]
    fn reference(&self, w: f64) -> f64 {
        w
    }
    #[inline(always)]
    fn output(&self, a: f64, _: f64) -> f64 {
        a
    }
    #[inline(always)]
    fn disturbance(&self, _: f64, _: usize) -> f64 {
        0.0
    }
    fn brake_time_scale(&self) -> f64 {
        1.0
    }
    #[inline(always)]
    fn measure(&mut self, a: f64) -> f64 {
        a
    }
}

/// Effects in canonical order, each with its exogenous series (if it reads one).
#[derive(Debug, Clone)]
pub struct Effects<'a> {
    pub effects: Vec<AnyEffect>,
    pub exo: Vec<Option<&'a [f64]>>,
}

impl Chain for Effects<'_> {
    const NONE: bool = false;
    fn reset(&mut self, u_hist: f64, dt: f64) {
        for e in self.effects.iter_mut() {
            e.reset(u_hist, dt);
        }
    }
    #[inline(always)]
    fn command(&mut self, u: f64, y: f64) -> f64 {
        let mut c = u;
        for e in self.effects.iter_mut() {
            c = e.command(c, y);
        }
        c
    }
    #[inline(always)]
    fn reference(&self, w: f64) -> f64 {
        let mut r = w;
        for e in &self.effects {
            r = e.reference(r);
        }
        r
    }
    #[inline(always)]
    fn output(&self, a: f64, v: f64) -> f64 {
        let mut o = a;
        for e in &self.effects {
            o = e.output(o, v);
        }
        o
    }
    #[inline(always)]
    fn disturbance(&self, v: f64, n: usize) -> f64 {
        let mut d = 0.0;
        for (e, s) in self.effects.iter().zip(&self.exo) {
            d += e.disturbance(v, s.map_or(0.0, |s| s[n]));
        }
        d
    }
    fn brake_time_scale(&self) -> f64 {
        self.effects.iter().map(|e| e.brake_time_scale()).product()
    }
    #[inline(always)]
    fn measure(&mut self, a: f64) -> f64 {
        let mut o = a;
        for e in self.effects.iter_mut() {
            o = e.measure(o);
        }
        o
    }
}

/// Resolves each effect's exogenous signal among a run's `exo` series (by name),
/// checking its length and values.
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

/// Whether the modal form may be used with these effects: none switches the
/// dynamics while braking (the braking maps live in the canonical coordinates).
pub fn modal_ok(effects: &[AnyEffect]) -> bool {
    effects.iter().all(|e| e.brake_time_scale() == 1.0)
}

/// Refuses effects that need an acceleration command with a speed command (none of
/// the registered effects does: the acceleration-level ones act on the derivative
/// of the speed response).
pub fn check_kind(effects: &[AnyEffect], kind: CommandKind) -> Result<()> {
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

/// The upper level of a closed loop: the command from the predecessor's and the
/// follower's position and speed, sample by sample in order.
pub trait Law: Send {
    /// Resets internal states before a run (`dt`: the sample time).
    fn reset(&mut self, dt: f64);
    /// The command of this sample.
    fn command(&mut self, lead_x: f64, lead_v: f64, x: f64, v: f64) -> f64;
    /// The desired gap at a constant speed `v` (where a platoon's followers start).
    fn gap(&self, v: f64) -> f64;
}

impl Law for Upper {
    #[inline(always)]
    fn reset(&mut self, _dt: f64) {}
    #[inline(always)]
    fn command(&mut self, lead_x: f64, lead_v: f64, x: f64, v: f64) -> f64 {
        Upper::command(self, lead_x, lead_v, x, v)
    }
    fn gap(&self, v: f64) -> f64 {
        self.gmin + self.tg * v
    }
}

/// The constant-time-gap law with upper-level structures, applied in the stages of
/// [`crate::effects`] (perceive, gains, shape, feedforward, limit). With no structure
/// (or neutral ones) it is [`Upper::command`]: the same operations in the same order.
#[derive(Debug, Clone)]
pub struct UpperChain {
    pub up: Upper,
    /// Upper-level effects only, in canonical order.
    pub effects: Vec<AnyEffect>,
}

impl UpperChain {
    /// The law `up` with the upper-level effects among `effects`.
    pub fn new(up: Upper, effects: &[AnyEffect]) -> Self {
        Self {
            up,
            effects: upper_of(effects),
        }
    }

    #[inline(always)]
    fn gains(&self, v: f64) -> Gains {
        let mut g = Gains {
            kg: self.up.kg,
            kv: self.up.kv,
            tg: self.up.tg,
        };
        for e in &self.effects {
            g = e.gains(g, v);
        }
        g
    }
}

impl Law for UpperChain {
    fn reset(&mut self, dt: f64) {
        // The command before the run: 0 (the closed loops start the lower level at
        // rest).
        for e in self.effects.iter_mut() {
            e.reset(0.0, dt);
        }
    }

    #[inline(always)]
    fn command(&mut self, lead_x: f64, lead_v: f64, x: f64, v: f64) -> f64 {
        let (mut gap, mut dv) = (lead_x - x, lead_v - v);
        for e in self.effects.iter_mut() {
            (gap, dv) = e.perceive(gap, dv);
        }
        let g = self.gains(v);
        let (mut eg, mut ev) = (g.kg * (gap - g.tg * v - self.up.gmin), g.kv * dv);
        for e in &self.effects {
            (eg, ev) = e.shape(eg, ev);
        }
        let mut u = eg + ev;
        let vp = v + dv;
        for e in self.effects.iter_mut() {
            u += e.feedforward(vp);
        }
        for e in self.effects.iter_mut() {
            u = e.limit(u);
        }
        u
    }

    fn gap(&self, v: f64) -> f64 {
        self.up.gmin + self.gains(v).tg * v
    }
}

/// The lower-level effects of `effects` (what [`Effects`] runs).
pub fn lower_of(effects: &[AnyEffect]) -> Vec<AnyEffect> {
    effects
        .iter()
        .filter(|e| e.kind().level() == Level::Lower)
        .cloned()
        .collect()
}

/// The upper-level effects of `effects` (what [`UpperChain`] runs).
pub fn upper_of(effects: &[AnyEffect]) -> Vec<AnyEffect> {
    effects
        .iter()
        .filter(|e| e.kind().level() == Level::Upper)
        .cloned()
        .collect()
}
