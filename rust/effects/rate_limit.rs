//! `rate_limit`: the command reaches the lower level through a slew-rate limiter,
//! `u'[n] = u'[n-1] + clip(u[n] - u'[n-1], -j_max dt, j_max dt)` — a jerk limit for
//! an acceleration command (m/s³), an acceleration limit for a speed command (m/s²).
//! `u'[-1]` is the command assumed before the run (0 at rest, `u[0]` at steady state).
//!
//! Linearisation: the identity (small signals below the limit).

use super::{check_range, Effect};
use crate::error::Result;
use crate::model::CommandKind;

#[derive(Debug, Clone)]
pub struct RateLimit {
    pub j_max: f64,
    step: f64,
    prev: f64,
}

impl Effect for RateLimit {
    const NAME: &'static str = "rate_limit";
    const PARAMS: &'static [&'static str] = &["j_max"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.1, 30.0)];
    const NEUTRAL: &'static [f64] = &[30.0];
    /// `comfort`'s jerk limit is the same slew limit of the command.
    const EXCLUDES: Option<&'static str> = Some("comfort");

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("rate_limit.j_max", p[0], 1e-6, 1e9)?;
        Ok(Self {
            j_max: p[0],
            step: f64::INFINITY,
            prev: 0.0,
        })
    }

    fn reset(&mut self, u_hist: f64, dt: f64) {
        self.prev = u_hist;
        self.step = self.j_max * dt;
    }

    #[inline(always)]
    fn command(&mut self, u: f64, _y: f64) -> f64 {
        let d = (u - self.prev).min(self.step).max(-self.step);
        self.prev += d;
        self.prev
    }
}
