//! `feedforward` (upper level): a gain `ka` on an estimate of the predecessor's
//! acceleration, added to the law's command. The estimate is the filtered derivative
//! of the predecessor speed the controller perceives, `vp = v + dv` (own speed plus
//! the radar's relative speed, after any `perception` delay):
//!
//! ```text
//!   â = s / (tau s + 1) vp,      u += ka â,
//! ```
//!
//! realised with the filter state `z' = (vp - z) / tau`, `â = (vp - z) / tau`,
//! discretized exactly for `vp` held over each sample interval:
//! `z[n+1] = alpha z[n] + (1 - alpha) vp[n]`, `alpha = exp(-dt / tau)`, started at
//! `z[0] = vp[0]` (no acceleration seen at the start of a run).
//!
//! Calibration bounds: `ka` in [0, 1.5] s (a cooperative ACC feeds the predecessor's
//! acceleration forward with a gain near 1; radar-only estimates are noisy and
//! commercial systems use a fraction of it); `tau` in [0.2, 3] s (the derivative of a
//! radar's range rate needs filtering: time constants of a few tenths of a second
//! to seconds). Neutral: `ka = 0` (then `tau` has no effect; its neutral value 1 s is
//! a placeholder).
//!
//! Small signal: `ka s / (tau s + 1)` on the perceived predecessor speed
//! `V + e^{-delay s} (V_p - V)` (see [`super::UpperLin`]); exact (the filter is
//! linear).

use super::{check_range, Effect, Level, Operating, UpperLin};
use crate::error::{AvllError, Result};
use crate::model::CommandKind;

#[derive(Debug, Clone)]
pub struct Feedforward {
    pub ka: f64,
    pub tau: f64,
    alpha: f64,
    z: f64,
    started: bool,
}

impl Effect for Feedforward {
    const NAME: &'static str = "feedforward";
    const PARAMS: &'static [&'static str] = &["ka", "tau"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.0, 1.5), (0.2, 3.0)];
    const NEUTRAL: &'static [f64] = &[0.0, 1.0];
    const LEVEL: Level = Level::Upper;

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("feedforward.ka", p[0], -100.0, 100.0)?;
        check_range("feedforward.tau", p[1], 1e-3, 600.0)?;
        Ok(Self {
            ka: p[0],
            tau: p[1],
            alpha: 0.0,
            z: 0.0,
            started: false,
        })
    }

    fn reset(&mut self, _u_hist: f64, dt: f64) {
        self.alpha = (-dt / self.tau).exp();
        self.z = 0.0;
        self.started = false;
    }

    #[inline(always)]
    fn feedforward(&mut self, vp: f64) -> f64 {
        if !self.started {
            self.started = true;
            self.z = vp;
        }
        let a = (vp - self.z) / self.tau;
        self.z = self.alpha * self.z + (1.0 - self.alpha) * vp;
        self.ka * a
    }

    fn linearize_upper(&self, u: &UpperLin, _op: &Operating) -> Result<UpperLin> {
        if u.ff_gain != 0.0 {
            return Err(AvllError::new("feedforward", "a second feedforward"));
        }
        Ok(UpperLin {
            ff_gain: self.ka,
            ff_tau: self.tau,
            ..*u
        })
    }
}
