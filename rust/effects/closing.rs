//! `closing` (upper level): other gains while closing in than while the gap opens.
//! The law's gap term `kg e` (gap error `e = gap - Tg v - Gmin`) is multiplied by
//! `rg` when negative (closer than desired), and its relative-speed term `kv dv` by
//! `rv` when negative (`dv = v_p - v < 0`: the predecessor is slower, the gap
//! closes):
//!
//! ```text
//!   u = kg e (rg if e < 0, else 1) + kv dv (rv if dv < 0, else 1)
//! ```
//!
//! (for positive gains), continuous at 0. Commercial ACCs react harder to a closing
//! gap than to an opening one (safety first, then comfort): `rg, rv > 1`.
//!
//! Calibration bounds: `rg`, `rv` in [0.25, 4] (up to four times softer or harder on
//! the closing side). Neutral: 1, 1.
//!
//! Small signal: each term is piecewise linear, positively homogeneous: its odd part is
//! the average slope, `kg (1 + rg)/2` and `kv (1 + rv)/2` (the small-signal form
//! given: the describing function of a sinusoid, of any amplitude), its even part
//! `|z| (r - 1)/2` a rectifier. Under an oscillation the even part shifts the mean
//! gap error away from 0 (which a symmetric law reads as another `Gmin + Tg v`) and
//! makes even harmonics, which in the closed loop return through the law into the
//! fundamental: the average slope's error is of the order `((r - 1)/(r + 1))^2`
//! (about 1 % in the tests at r = 1.6-2.2; the closing and opening slopes themselves
//! are exact on either side).

use super::{check_range, Effect, Level, Operating, UpperLin};
use crate::error::Result;
use crate::model::CommandKind;

#[derive(Debug, Clone)]
pub struct Closing {
    pub rg: f64,
    pub rv: f64,
}

impl Effect for Closing {
    const NAME: &'static str = "closing";
    const PARAMS: &'static [&'static str] = &["rg", "rv"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.25, 4.0), (0.25, 4.0)];
    const NEUTRAL: &'static [f64] = &[1.0, 1.0];
    const LEVEL: Level = Level::Upper;

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("closing.rg", p[0], 0.0, 100.0)?;
        check_range("closing.rv", p[1], 0.0, 100.0)?;
        Ok(Self { rg: p[0], rv: p[1] })
    }

    #[inline(always)]
    fn shape(&self, eg: f64, ev: f64) -> (f64, f64) {
        (
            if eg < 0.0 { self.rg * eg } else { eg },
            if ev < 0.0 { self.rv * ev } else { ev },
        )
    }

    fn linearize_upper(&self, u: &UpperLin, _op: &Operating) -> Result<UpperLin> {
        Ok(UpperLin {
            kg: u.kg * 0.5 * (1.0 + self.rg),
            kv: u.kv * 0.5 * (1.0 + self.rv),
            ..*u
        })
    }
}
