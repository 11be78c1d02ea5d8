//! `sensor`: bias and first-order lag of the *measured* acceleration. The vehicle's
//! dynamics, its speed and position (the integrals of the true acceleration) and
//! every feedback of the actual state (the inner loop's `K a`, the upper law) use
//! the true acceleration `a`; only what is recorded and compared with the data is
//! `a_obs = L_tau(a) + b`, `L_tau = 1 / (tau s + 1)` (the observation hook, applied
//! last).
//!
//! Discretization: exact for the lag driven by `a[n]` held over the interval
//! `(t_{n-1}, t_n]`: `f[n] = alpha f[n-1] + (1 - alpha) a[n]`, `alpha = exp(-dt / tau)`
//! (`alpha = 0` for `tau = 0`: no lag, `a_obs = a + b`), started in equilibrium with
//! the first sample (`f[-1] = a[0]`).
//!
//! Calibration bounds: `tau` in [0, 1] s (accelerometer and CAN-signal filtering,
//! typically 0.02-0.5 s; a lag near 1 s would be a filter designed for display, not
//! control); `bias` in [-0.5, 0.5] m/s² (mounting pitch of a few degrees, 0.1 rad
//! ≈ 1 m/s² at most, and offset drift; beyond 0.5 m/s² a calibration error to fix
//! in the data).
//!
//! Linearisation: the identity — the dynamics are unchanged; the observation
//! filter `L_tau` and the offset `b` are returned by [`super::linearize_terms`].

use super::{check_range, Effect, Operating, Terms};
use crate::error::Result;
use crate::model::{CommandKind, Linear};

#[derive(Debug, Clone)]
pub struct Sensor {
    pub tau: f64,
    pub bias: f64,
    alpha: f64,
    f: f64,
    started: bool,
}

impl Effect for Sensor {
    const NAME: &'static str = "sensor";
    const PARAMS: &'static [&'static str] = &["tau", "bias"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.0, 1.0), (-0.5, 0.5)];
    const NEUTRAL: &'static [f64] = &[0.0, 0.0];

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("sensor.tau", p[0], 0.0, 600.0)?;
        check_range("sensor.bias", p[1], -100.0, 100.0)?;
        Ok(Self {
            tau: p[0],
            bias: p[1],
            alpha: 0.0,
            f: 0.0,
            started: false,
        })
    }

    fn reset(&mut self, _u_hist: f64, dt: f64) {
        self.alpha = if self.tau > 0.0 {
            (-dt / self.tau).exp()
        } else {
            0.0
        };
        self.f = 0.0;
        self.started = false;
    }

    #[inline(always)]
    fn measure(&mut self, a: f64) -> f64 {
        if !self.started {
            self.started = true;
            self.f = a;
        }
        self.f = self.alpha * self.f + (1.0 - self.alpha) * a;
        self.f + self.bias
    }

    fn linearize_terms(&self, lin: &Linear, _op: &Operating) -> Result<(Linear, Terms)> {
        Ok((
            *lin,
            Terms {
                obs_tau: self.tau,
                obs_bias: self.bias,
                ..Terms::default()
            },
        ))
    }
}
