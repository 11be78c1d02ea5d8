//! `perception` (upper level): the radar's signals reach the car-following law `tau`
//! late — the gap `x_p - x` and the relative speed `v_p - v` as one delayed pair
//! (sensor latency, tracking filters, the bus); the own speed, from the vehicle's own
//! sensors, is not delayed. A fractional delay by linear interpolation between the
//! samples of the signals' history: with `tau/dt = i + f`,
//! `g'[n] = (1 - f) g[n-i] + f g[n-i-1]` (the same for the relative speed); the
//! history before the run is the first sample held (the run starts in a steady
//! state).
//!
//! Calibration bounds: `tau` in [0, 1.5] s. Radar cycle times are 50-100 ms and the
//! object tracking and the controller's filtering add a few cycles; identified ACC
//! models report total reaction delays of 0.3-1 s, part of which the lower level's
//! `Td` already holds. Neutral: 0.
//!
//! Small signal: the radar terms get `e^{-tau s}` (see [`super::UpperLin`]): the law's
//! `kg (gap) + kv (dv)` becomes `e^{-tau s} (kg + kv s)(X_p - X)` while `kg Tg v`
//! stays undelayed. Exact for any amplitude (a delay is linear).

use super::{check_range, Effect, Level, Operating, UpperLin};
use crate::discretize::DelayLine;
use crate::error::Result;
use crate::model::CommandKind;

#[derive(Debug, Clone)]
pub struct Perception {
    pub tau: f64,
    line: DelayLine<(f64, f64)>,
}

impl Effect for Perception {
    const NAME: &'static str = "perception";
    const PARAMS: &'static [&'static str] = &["tau"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.0, 1.5)];
    const NEUTRAL: &'static [f64] = &[0.0];
    const LEVEL: Level = Level::Upper;

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("perception.tau", p[0], 0.0, 60.0)?;
        Ok(Self {
            tau: p[0],
            line: DelayLine::default(),
        })
    }

    fn reset(&mut self, _u_hist: f64, dt: f64) {
        self.line.reset(self.tau, dt, (0.0, 0.0));
    }

    #[inline(always)]
    fn perceive(&mut self, gap: f64, dv: f64) -> (f64, f64) {
        if self.line.is_empty() {
            // The history: the first sample held.
            self.line.fill((gap, dv));
        }
        self.line.push((gap, dv))
    }

    fn linearize_upper(&self, u: &UpperLin, _op: &Operating) -> Result<UpperLin> {
        Ok(UpperLin {
            delay: u.delay + self.tau,
            ..*u
        })
    }
}
