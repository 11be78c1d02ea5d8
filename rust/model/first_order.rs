//! First-order lag, paper Eq. 1: `1 / (Td s + 1)`; `Td` is the lag time constant.

use super::{BaseModel, Linear};
use crate::error::{check_positive, Result};

pub struct FirstOrderLag;

impl BaseModel for FirstOrderLag {
    const NAME: &'static str = "first";
    const PARAMS: &'static [&'static str] = &["Td"];

    fn linear(p: &[f64]) -> Result<Linear> {
        let td = p[0];
        check_positive("Td", td)?;
        Ok(Linear {
            b1: 0.0,
            b0: 1.0,
            a2: 0.0,
            a1: td,
            td: 0.0,
            k: 0.0,
        })
    }
}
