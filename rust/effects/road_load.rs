//! `road_load`: the coast-down road-load polynomial that the lower level does not
//! compensate, an additive acceleration
//! `a_rl(v) = -(c0 s(v) + c1 v + c2 v |v|)`, `s(v) = clip(v / 0.1, -1, 1)`,
//! on the actual acceleration (the disturbance hook), from the actual speed `v`.
//! Sign convention: positive coefficients resist the motion (the term opposes `v`;
//! for the data's `v >= 0` it is `-(c0 + c1 v + c2 v²)` once `v >= 0.1` m/s); the
//! constant (rolling) term fades in over the first 0.1 m/s so that it vanishes at
//! rest, as in `speed_drag`.
//!
//! How it differs from `speed_drag` (`-(c0 s(v) + c2 v |v|)`): `road_load` is the
//! full polynomial `F = A + B v + C v²` of a coast-down test (SAE J2263) divided by
//! the mass, with the linear term `c1 v` (driveline and tyre losses growing with
//! speed) that `speed_drag` lacks, and with physically signed bounds for all three
//! coefficients; at `c1 = 0` the two coincide, which is why the diagnosis should
//! not be offered both in one model (they are not identifiable together).
//!
//! Parameters are resistive by definition (`>= 0`; an over-compensating controller
//! is not a road load). Calibration bounds: `c0` in [0, 0.6] m/s² (rolling
//! resistance `f_r g` is about 0.1 m/s² for `f_r = 0.01`; 0.6 allows soft or
//! unpaved surfaces and brake drag); `c1` in [0, 0.03] 1/s (coast-down fits give
//! `B/m` of 0.001-0.01 1/s); `c2` in [0, 0.002] 1/m (`rho Cd A / (2 m)` is 2-4e-4
//! 1/m for a passenger car and 3-4e-4 for a loaded truck; a headwind as fast as the
//! vehicle quadruples the term, so 0.002 is about five times the largest nominal
//! value).
//!
//! Linearisation: about a speed `v*` (outside the fade-in) the term adds the speed feedback
//! `-beta dv` with `beta = c1 + 2 c2 v*` (1/s), i.e. the factor `s / (s + beta)` on the
//! acceleration: one state more than a `Linear` holds. The exact linearisation is
//! given only for `beta = 0`; [`super::linearize_terms`] returns `beta` separately.

use super::{check_range, speed_drag::V_FADE, Effect, Operating, Terms};
use crate::error::{AvllError, Result};
use crate::model::{CommandKind, Linear};

#[derive(Debug, Clone)]
pub struct RoadLoad {
    pub c0: f64,
    pub c1: f64,
    pub c2: f64,
}

impl RoadLoad {
    /// `beta = d(-a_rl)/dv = c1 + 2 c2 |v|` at the operating speed, plus the fade-in's
    /// slope `c0 / 0.1` below 0.1 m/s (which regularises standstill).
    fn beta(&self, v: f64) -> f64 {
        let fade = if v.abs() < V_FADE { self.c0 / V_FADE } else { 0.0 };
        self.c1 + 2.0 * self.c2 * v.abs() + fade
    }
}

impl Effect for RoadLoad {
    const NAME: &'static str = "road_load";
    const PARAMS: &'static [&'static str] = &["c0", "c1", "c2"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.0, 0.6), (0.0, 0.03), (0.0, 0.002)];
    const NEUTRAL: &'static [f64] = &[0.0, 0.0, 0.0];
    const NEEDS_SPEED: bool = true;
    const EXCLUDES: Option<&'static str> = Some("speed_drag");

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("road_load.c0", p[0], 0.0, 10.0)?;
        check_range("road_load.c1", p[1], 0.0, 1.0)?;
        check_range("road_load.c2", p[2], 0.0, 1.0)?;
        Ok(Self {
            c0: p[0],
            c1: p[1],
            c2: p[2],
        })
    }

    #[inline(always)]
    fn disturbance(&self, v: f64, _exo: f64) -> f64 {
        -(self.c0 * (v / V_FADE).clamp(-1.0, 1.0) + self.c1 * v + self.c2 * v * v.abs())
    }

    fn linearize(&self, lin: &Linear, op: &Operating) -> Result<Linear> {
        let beta = self.beta(op.v);
        if beta == 0.0 {
            Ok(*lin)
        } else {
            Err(AvllError::new(
                "road_load",
                format!(
                    "adds the speed feedback -beta v with beta = c1 + 2 c2 v = {beta} 1/s \
                     (the factor s/(s + beta) on the acceleration), which a second-order \
                     Linear cannot hold"
                ),
            ))
        }
    }

    fn linearize_terms(&self, lin: &Linear, op: &Operating) -> Result<(Linear, Terms)> {
        Ok((
            *lin,
            Terms {
                speed_feedback: self.beta(op.v),
                ..Terms::default()
            },
        ))
    }
}
