//! `saturation`: acceleration and deceleration limits on the lower level's output,
//! `a = min(max(a_lin, -d_max), a_max)` (a hard clip).
//!
//! Linearisation: the identity (small signals about an operating point inside the
//! limits); the describing function of a large oscillation is not a `Linear`.

use super::{check_range, Effect};
use crate::error::Result;
use crate::model::CommandKind;

#[derive(Debug, Clone)]
pub struct Saturation {
    pub a_max: f64,
    pub d_max: f64,
}

impl Effect for Saturation {
    const NAME: &'static str = "saturation";
    const PARAMS: &'static [&'static str] = &["a_max", "d_max"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.2, 6.0), (0.2, 10.0)];
    const NEUTRAL: &'static [f64] = &[6.0, 10.0];

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("saturation.a_max", p[0], 1e-6, 1e6)?;
        check_range("saturation.d_max", p[1], 1e-6, 1e6)?;
        Ok(Self {
            a_max: p[0],
            d_max: p[1],
        })
    }

    #[inline(always)]
    fn output(&self, a: f64, _v: f64) -> f64 {
        a.min(self.a_max).max(-self.d_max)
    }
}
