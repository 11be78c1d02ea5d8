//! `speed_gains` (upper level): a time gap and gains that depend on the own speed `v`:
//!
//! ```text
//!   Tg(v) = Tg + ch v,          kg(v) = kg / r(v),   kv(v) = kv / r(v),
//!   r(v)  = max(1 + cs max(v, 0), 0.1),
//! ```
//!
//! so the desired gap is `Gmin + Tg v + ch v²` (the "variable time headway" or
//! quadratic spacing policy of the ACC literature) and the gains fall with speed for
//! `cs > 0` (softer at highway speed, for comfort). `r` is bounded below so that the
//! gains stay finite for any speed.
//!
//! Calibration bounds: `ch` in [-0.03, 0.06] s²/m (at 25 m/s the time gap moves by
//! -0.75 to +1.5 s from its value at rest: commercial ACCs' settings span 1-2.5 s,
//! some lengthen them with speed); `cs` in [-0.01, 0.05] s/m (at 25 m/s the gains are
//! between 1.3 and 0.44 times their value at rest). Neutral: 0, 0.
//!
//! Small signal at the operating speed `v*` (with the predecessor at `v*` and the gap
//! at its equilibrium `Gmin + Tg(v*) v*`, where the gap error and the relative speed
//! vanish, so the gains' own slopes drop out): `kg(v*)`, `kv(v*)` and the time gap
//! `d(Tg(v) v)/dv = Tg + 2 ch v*` (not the equilibrium's `Tg + ch v*`: the data's
//! mean headway and the loop's small-signal time gap differ).

use super::{check_range, Effect, Gains, Level, Operating, UpperLin};
use crate::error::Result;
use crate::model::CommandKind;

/// Lower bound of the gains' divisor `r(v)`.
pub const R_MIN: f64 = 0.1;

#[derive(Debug, Clone)]
pub struct SpeedGains {
    pub ch: f64,
    pub cs: f64,
}

impl SpeedGains {
    #[inline(always)]
    fn divisor(&self, v: f64) -> f64 {
        (1.0 + self.cs * v.max(0.0)).max(R_MIN)
    }
}

impl Effect for SpeedGains {
    const NAME: &'static str = "speed_gains";
    const PARAMS: &'static [&'static str] = &["ch", "cs"];
    const BOUNDS: &'static [(f64, f64)] = &[(-0.03, 0.06), (-0.01, 0.05)];
    const NEUTRAL: &'static [f64] = &[0.0, 0.0];
    const LEVEL: Level = Level::Upper;

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("speed_gains.ch", p[0], -1.0, 1.0)?;
        check_range("speed_gains.cs", p[1], -1.0, 10.0)?;
        Ok(Self { ch: p[0], cs: p[1] })
    }

    #[inline(always)]
    fn gains(&self, g: Gains, v: f64) -> Gains {
        let r = self.divisor(v);
        Gains {
            kg: g.kg / r,
            kv: g.kv / r,
            tg: g.tg + self.ch * v,
        }
    }

    fn linearize_upper(&self, u: &UpperLin, op: &Operating) -> Result<UpperLin> {
        let r = self.divisor(op.v);
        Ok(UpperLin {
            kg: u.kg / r,
            kv: u.kv / r,
            tg: u.tg + 2.0 * self.ch * op.v,
            tg_eq: u.tg_eq + self.ch * op.v,
            ..*u
        })
    }
}
