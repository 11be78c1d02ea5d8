//! `deadband`: a dead zone of half-width `delta` around zero demand (the
//! throttle/brake switching region), continuous:
//! `dz(e) = sign(e) max(|e| - delta, 0)`. The demand is the command for an
//! acceleration command (`u' = dz(u)`) and the speed error for a speed command
//! (`u' = y + dz(u - y)`, `y` the actual speed).
//!
//! Linearisation: the identity for an operating point outside the band (slope 1;
//! the offset `delta` is a static bias, not a dynamic); inside it the loop is open.

use super::{check_range, Effect};
use crate::error::Result;
use crate::model::CommandKind;

#[derive(Debug, Clone)]
pub struct Deadband {
    pub delta: f64,
    speed: bool,
}

#[inline(always)]
fn dz(e: f64, d: f64) -> f64 {
    if e > d {
        e - d
    } else if e < -d {
        e + d
    } else {
        0.0
    }
}

impl Effect for Deadband {
    const NAME: &'static str = "deadband";
    const PARAMS: &'static [&'static str] = &["delta"];
    const BOUNDS: &'static [(f64, f64)] = &[(0.0, 1.0)];
    const NEUTRAL: &'static [f64] = &[0.0];

    fn new(p: &[f64], kind: CommandKind) -> Result<Self> {
        check_range("deadband.delta", p[0], 0.0, 1e6)?;
        Ok(Self {
            delta: p[0],
            speed: kind == CommandKind::Speed,
        })
    }

    #[inline(always)]
    fn command(&mut self, u: f64, y: f64) -> f64 {
        if self.speed {
            y + dz(u - y, self.delta)
        } else {
            dz(u, self.delta)
        }
    }
}
