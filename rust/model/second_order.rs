//! Second-order response with dead time, paper Eq. 2 with `m1 = 0`:
//! `K0 e^{-Td s} / (m2 s^2 + m3 s + 1)`.

use super::{BaseModel, Linear};
use crate::error::{check_nonneg, check_positive, Result};

pub struct SecondOrder;

impl BaseModel for SecondOrder {
    const NAME: &'static str = "second";
    const PARAMS: &'static [&'static str] = &["K0", "m2", "m3", "Td"];

    fn linear(p: &[f64]) -> Result<Linear> {
        let (k0, m2, m3, td) = (p[0], p[1], p[2], p[3]);
        check_positive("m2", m2)?;
        check_nonneg("Td", td)?;
        crate::error::check_finite("m3", m3)?;
        crate::error::check_finite("K0", k0)?;
        Ok(Linear {
            b1: 0.0,
            b0: k0,
            a2: m2,
            a1: m3,
            td,
            k: 0.0,
        })
    }
}
