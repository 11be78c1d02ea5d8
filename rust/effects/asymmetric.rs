//! `asymmetric`: different gain and time constant for acceleration and braking.
//!
//! While braking the lower level is `kb G(rb s)` instead of `G(s)`: the reference
//! input passes through the static map `w -> w (w >= 0), kb w (w < 0)` (continuous
//! at 0), and the rational part runs `rb` times slower (its time constants scaled
//! by `rb`: `b1 -> rb b1, a2 -> rb^2 a2, a1 -> rb a1`). The dynamics switch per
//! sample interval on the sign of the braking demand: the delayed reference input
//! for an acceleration command; `b0 w - y` (the demanded speed change) for a speed
//! command, where the gain map does not apply (`kb` must be 1).
//!
//! Linearisation: exact on either side (`side = 1`: the base; `side = -1`:
//! `kb G(rb s)` inside the inner loop); `side = 0` uses the mean gain and time
//! scale (a describing function for symmetric oscillations about 0).

use super::{check_range, Effect, Operating};
use crate::error::{AvllError, Result};
use crate::model::{CommandKind, Linear};

#[derive(Debug, Clone)]
pub struct Asymmetric {
    pub kb: f64,
    pub rb: f64,
}

impl Effect for Asymmetric {
    const NAME: &'static str = "asymmetric";
    const PARAMS: &'static [&'static str] = &["kb", "rb"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.3, 3.0), (0.3, 3.0)];
    const NEUTRAL: &'static [f64] = &[1.0, 1.0];

    fn new(p: &[f64], kind: CommandKind) -> Result<Self> {
        check_range("asymmetric.kb", p[0], 0.01, 100.0)?;
        check_range("asymmetric.rb", p[1], 0.01, 100.0)?;
        if kind == CommandKind::Speed && p[0] != 1.0 {
            return Err(AvllError::new(
                "asymmetric.kb",
                "a speed command has no braking gain: kb must be 1",
            ));
        }
        Ok(Self { kb: p[0], rb: p[1] })
    }

    #[inline(always)]
    fn reference(&self, w: f64) -> f64 {
        if w < 0.0 {
            self.kb * w
        } else {
            w
        }
    }

    fn brake_time_scale(&self) -> f64 {
        self.rb
    }

    fn linearize(&self, lin: &Linear, op: &Operating) -> Result<Linear> {
        let (g, r) = match op.side {
            1 => (1.0, 1.0),
            -1 => (self.kb, self.rb),
            _ => (0.5 * (1.0 + self.kb), 0.5 * (1.0 + self.rb)),
        };
        Ok(Linear {
            b1: g * r * lin.b1,
            b0: g * lin.b0,
            a2: r * r * lin.a2,
            a1: r * lin.a1,
            td: lin.td,
            k: lin.k,
        })
    }
}
