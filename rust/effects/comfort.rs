//! `comfort` (upper level): the law's command limited to what the ACC allows itself,
//! an acceleration bound `a_max`, a deceleration bound `d_max` and a jerk limit
//! `j_max` (a slew limit of the command):
//!
//! ```text
//!   c[n] = clip(u[n], -d_max, a_max),
//!   u'[n] = u'[n-1] + clip(c[n] - u'[n-1], -j_max dt, j_max dt),
//! ```
//!
//! with `u'[-1]` the command before the run (0: the lower level starts at rest).
//!
//! Calibration bounds: `a_max` in [0.3, 4] m/s², `d_max` in [0.5, 8] m/s², `j_max`
//! in [0.5, 30] m/s³. The ACC standard (ISO 15622) caps the automatic deceleration at
//! 3.5-5 m/s² and the acceleration at 2-4 m/s² (speed dependent) and recommends jerk
//! limits of 2.5-5 m/s³; production systems are often softer. Neutral: the upper
//! bounds, which car following at cruising speed does not reach.
//!
//! Small signal: the identity (inside the limits). `rate_limit` is the same slew
//! limit on the lower level's command: the two are refused together.

use super::{check_range, Effect, Level};
use crate::error::Result;
use crate::model::CommandKind;

#[derive(Debug, Clone)]
pub struct Comfort {
    pub a_max: f64,
    pub d_max: f64,
    pub j_max: f64,
    step: f64,
    prev: f64,
}

impl Effect for Comfort {
    const NAME: &'static str = "comfort";
    const PARAMS: &'static [&'static str] = &["a_max", "d_max", "j_max"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.3, 4.0), (0.5, 8.0), (0.5, 30.0)];
    const NEUTRAL: &'static [f64] = &[4.0, 8.0, 30.0];
    const LEVEL: Level = Level::Upper;
    const EXCLUDES: Option<&'static str> = Some("rate_limit");

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("comfort.a_max", p[0], 1e-6, 1e6)?;
        check_range("comfort.d_max", p[1], 1e-6, 1e6)?;
        check_range("comfort.j_max", p[2], 1e-6, 1e9)?;
        Ok(Self {
            a_max: p[0],
            d_max: p[1],
            j_max: p[2],
            step: f64::INFINITY,
            prev: 0.0,
        })
    }

    fn reset(&mut self, u_hist: f64, dt: f64) {
        self.prev = u_hist;
        self.step = self.j_max * dt;
    }

    #[inline(always)]
    fn limit(&mut self, u: f64) -> f64 {
        let c = u.min(self.a_max).max(-self.d_max);
        let d = (c - self.prev).min(self.step).max(-self.step);
        self.prev += d;
        self.prev
    }
}
