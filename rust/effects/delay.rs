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
use crate::discretize::split_delay;
use crate::error::{AvllError, Result};
use crate::model::{CommandKind, Linear};

#[derive(Debug, Clone)]
pub struct Delay {
    pub tau: f64,
    i: usize,
    f: f64,
    n: usize,
    mask: usize,
    buf: Vec<f64>,
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
            i: 0,
            f: 0.0,
            n: 0,
            mask: 0,
            buf: Vec::new(),
        })
    }

    fn reset(&mut self, u_hist: f64, dt: f64) {
        let (i, f) = split_delay(self.tau, dt);
        self.i = i;
        self.f = f;
        self.n = 0;
        let cap = (i + 2).next_power_of_two();
        self.mask = cap - 1;
        self.buf.clear();
        self.buf.resize(cap, u_hist);
    }

    #[inline(always)]
    fn command(&mut self, u: f64, _y: f64) -> f64 {
        let n = self.n;
        self.buf[n & self.mask] = u;
        self.n += 1;
        let u0 = self.buf[n.wrapping_sub(self.i) & self.mask];
        if self.f > 0.0 {
            let u1 = self.buf[n.wrapping_sub(self.i + 1) & self.mask];
            (1.0 - self.f) * u0 + self.f * u1
        } else {
            u0
        }
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
