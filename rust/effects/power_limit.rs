//! `power_limit`: a speed-dependent traction limit. The powertrain delivers at most
//! the specific power `p` = P/m (W/kg = m²/s³) at the wheels, so the lower level's
//! positive acceleration is capped at `p / max(|v|, v_b)`:
//! `a = min(a_lin, p / max(|v|, v_b))` (braking is not limited). Below the base
//! speed `v_b` the cap is the constant `p / v_b`: the torque (or first-gear / grip)
//! limit that every real powertrain has at low speed, which also keeps the cap
//! finite at rest. `v` is the actual (simulated) speed, read by the output hook.
//!
//! Calibration bounds: `p` in [5, 500] W/kg (a fully loaded 40-60 t truck with
//! 300-400 kW has 5-10 W/kg; hypercars reach about 500 W/kg); `v_b` in [0.5, 20] m/s
//! (the corner of the torque-power curve: a few m/s for a combustion engine in
//! first gear, 10-20 m/s for an electric motor's base speed). At the neutral
//! `(500, 0.5)` the cap exceeds the friction limit (~10 m/s²) below 50 m/s, so it
//! does not bind in road data.
//!
//! Linearisation: the identity. Small signals about steady cruising (`a = 0`) stay
//! below the cap, which is positive at every speed; the limit is amplitude
//! dependent (a time-domain question, not a `Linear`).

use super::{check_range, Effect};
use crate::error::Result;
use crate::model::CommandKind;

#[derive(Debug, Clone)]
pub struct PowerLimit {
    pub p: f64,
    pub v_b: f64,
}

impl Effect for PowerLimit {
    const NAME: &'static str = "power_limit";
    const PARAMS: &'static [&'static str] = &["p", "v_b"];
    const BOUNDS: &'static [(f64, f64)] = &[(5.0, 500.0), (0.5, 20.0)];
    const NEUTRAL: &'static [f64] = &[500.0, 0.5];
    const NEEDS_SPEED: bool = true;

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("power_limit.p", p[0], 1e-6, 1e9)?;
        check_range("power_limit.v_b", p[1], 1e-3, 1e3)?;
        Ok(Self {
            p: p[0],
            v_b: p[1],
        })
    }

    #[inline(always)]
    fn output(&self, a: f64, v: f64) -> f64 {
        a.min(self.p / v.abs().max(self.v_b))
    }
}
