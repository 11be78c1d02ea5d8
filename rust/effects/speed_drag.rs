//! `speed_drag`: speed-dependent resistance that the lower level does not cancel,
//! an additive acceleration `-(c0 s(v) + c2 v |v|)` with `s(v) = clip(v / 0.1, -1, 1)`
//! (rolling resistance fades in over the first 0.1 m/s, so it vanishes at rest).
//! `v` is the actual (simulated) speed.
//!
//! Linearisation: about a speed `v*` it adds `-2 c2 v* dv` with `dv = da / s`, i.e. the
//! factor `s / (s + 2 c2 v*)` on the acceleration: one more state than a `Linear`
//! holds, so none is given (it is exact only for `c2 v* = 0`, where the base is
//! returned); [`super::linearize_terms`] returns `beta = 2 c2 |v*|` separately (plus
//! the fade-in's slope `c0 / 0.1` when `|v*| < 0.1` m/s).
//! `road_load` is the full road-load polynomial (with a linear term `c1 v`); at
//! `c1 = 0` it is this effect, so the two are not offered together.

use super::{check_range, Effect, Operating, Terms};
use crate::error::{AvllError, Result};
use crate::model::{CommandKind, Linear};

/// Speed over which the rolling-resistance term fades in (m/s).
pub const V_FADE: f64 = 0.1;

#[derive(Debug, Clone)]
pub struct SpeedDrag {
    pub c0: f64,
    pub c2: f64,
}

impl Effect for SpeedDrag {
    const NAME: &'static str = "speed_drag";
    const PARAMS: &'static [&'static str] = &["c0", "c2"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.0, 0.6), (0.0, 0.006)];
    const NEUTRAL: &'static [f64] = &[0.0, 0.0];
    const NEEDS_SPEED: bool = true;
    const EXCLUDES: Option<&'static str> = Some("road_load");

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("speed_drag.c0", p[0], -10.0, 10.0)?;
        check_range("speed_drag.c2", p[1], -1.0, 1.0)?;
        Ok(Self { c0: p[0], c2: p[1] })
    }

    #[inline(always)]
    fn disturbance(&self, v: f64, _exo: f64) -> f64 {
        -(self.c0 * (v / V_FADE).clamp(-1.0, 1.0) + self.c2 * v * v.abs())
    }

    fn linearize(&self, lin: &Linear, op: &Operating) -> Result<Linear> {
        if self.c2 * op.v == 0.0 {
            Ok(*lin)
        } else {
            Err(AvllError::new(
                "speed_drag",
                "adds the factor s/(s + 2 c2 v) on the acceleration, which a second-order \
                 Linear cannot hold",
            ))
        }
    }

    fn linearize_terms(&self, lin: &Linear, op: &Operating) -> Result<(Linear, Terms)> {
        Ok((
            *lin,
            Terms {
                speed_feedback: 2.0 * self.c2 * op.v.abs()
                    + if op.v.abs() < V_FADE {
                        self.c0 / V_FADE
                    } else {
                        0.0
                    },
                ..Terms::default()
            },
        ))
    }
}
