//! `grade`: a road-grade term the lower level does not cancel, an additive
//! acceleration `-g_eff * grade` from the exogenous signal `exo_grade`
//! (dimensionless slope, positive uphill). `g_eff = 9.81` m/s² means no
//! compensation at all; a controller with partial compensation shows less.
//!
//! Linearisation: the identity (an exogenous input does not change the transfer
//! function from command to acceleration).

use super::{check_range, Effect};
use crate::error::Result;
use crate::model::CommandKind;

#[derive(Debug, Clone)]
pub struct Grade {
    pub g_eff: f64,
}

impl Effect for Grade {
    const NAME: &'static str = "grade";
    const PARAMS: &'static [&'static str] = &["g_eff"];
    const BOUNDS: &'static [(f64, f64)] = &[(-5.0, 20.0)];
    const NEUTRAL: &'static [f64] = &[0.0];
    const EXO: Option<&'static str> = Some("grade");

    fn new(p: &[f64], _kind: CommandKind) -> Result<Self> {
        check_range("grade.g_eff", p[0], -100.0, 100.0)?;
        Ok(Self { g_eff: p[0] })
    }

    #[inline(always)]
    fn disturbance(&self, _v: f64, exo: f64) -> f64 {
        -self.g_eff * exo
    }
}
