//! The paper's proposed model, Eqs. 2 and 5: `G / (1 - K G)` with
//! `G = (m1 s + K0) e^{-Td s} / (m2 s^2 + m3 s + 1)`. In time:
//! `u_ref = u + K y`, and the rational part is driven by `u_ref(t - Td)`.

use super::{BaseModel, Linear};
use crate::error::{check_nonneg, check_positive, Result};

pub struct Proposed;

impl BaseModel for Proposed {
    const NAME: &'static str = "proposed";
    const PARAMS: &'static [&'static str] = &["m1", "m2", "m3", "K0", "Td", "K"];

    fn linear(p: &[f64]) -> Result<Linear> {
        let (m1, m2, m3, k0, td, k) = (p[0], p[1], p[2], p[3], p[4], p[5]);
        check_positive("m2", m2)?;
        check_nonneg("Td", td)?;
        Ok(Linear {
            b1: m1,
            b0: k0,
            a2: m2,
            a1: m3,
            td,
            k,
        })
    }
}
