//! `delay`: an extra transport delay `tau` of the command on its way to the lower
//! level (outside the inner feedback loop, unlike the model's `Td`), as a fractional
//! delay by linear interpolation: with `tau/dt = i + f`,
//! `u'[n] = (1 - f) u[n-i] + f u[n-i-1]`; samples before the run are the command
//! assumed before it (0 at rest, `u[0]` at steady state).
//!
//! Linearisation: `G_fb(s) e^{-tau s}`; a `Linear` holds it exactly only when `K = 0`
//! (then `Td + tau`), otherwise none is given; [`super::linearize_terms`] returns it
//! as the outer term `command_delay` for any `K`.

use super::{check_range, Effect, Operating, Terms};
use crate::discretize::DelayLine;
use crate::error::{AvllError, Result};
use crate::model::{CommandKind, Linear};

#[derive(Debug, Clone)]
pub struct Delay {
    pub tau: f64,
    line: DelayLine<f64>,
}

impl Effect for Delay {
    const NAME: &'static str = "delay";
    const PARAMS: &'static [&'static str] = &["tau"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.0, 2.0)];
    const NEUTRAL: &'static [f64] = &[0.0];

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("delay.tau", p[0], 0.0, 600.0)?;
        Ok(Self {
            tau: p[0],
            line: DelayLine::default(),
        })
    }

    fn reset(&mut self, u_hist: f64, dt: f64) {
        self.line.reset(self.tau, dt, u_hist);
    }

    #[inline(always)]
    fn command(&mut self, u: f64, _y: f64) -> f64 {
        self.line.push(u)
    }

    fn linearize(&self, lin: &Linear, _op: &Operating) -> Result<Linear> {
        if lin.k == 0.0 || self.tau == 0.0 {
            Ok(Linear {
                td: lin.td + self.tau,
                ..*lin
            })
        } else {
            Err(AvllError::new(
                "delay",
                "a command delay outside the inner loop (K != 0) is not a Linear's Td",
            ))
        }
    }

    fn linearize_terms(&self, lin: &Linear, _op: &Operating) -> Result<(Linear, Terms)> {
        Ok((
            *lin,
            Terms {
                command_delay: self.tau,
                ..Terms::default()
            },
        ))
    }
}
