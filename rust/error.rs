//! Error type of the plain-Rust core. Every error names the argument at fault;
//! the binding layer turns it into a Python `ValueError`.

use std::fmt;

#[derive(Debug, Clone, PartialEq)]
pub struct AvllError {
    /// The argument (or parameter) that is wrong, e.g. `"m2"` or `"command"`.
    pub arg: String,
    /// What is wrong with it.
    pub msg: String,
}

impl AvllError {
    pub fn new(arg: impl Into<String>, msg: impl Into<String>) -> Self {
        Self {
            arg: arg.into(),
            msg: msg.into(),
        }
    }
}

impl fmt::Display for AvllError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.arg, self.msg)
    }
}

impl std::error::Error for AvllError {}

pub type Result<T> = std::result::Result<T, AvllError>;

/// Fails unless `x` is finite.
pub fn check_finite(arg: &str, x: f64) -> Result<()> {
    if x.is_finite() {
        Ok(())
    } else {
        Err(AvllError::new(arg, format!("must be finite, got {x}")))
    }
}

/// Fails unless `x` is finite and strictly positive.
pub fn check_positive(arg: &str, x: f64) -> Result<()> {
    if x.is_finite() && x > 0.0 {
        Ok(())
    } else {
        Err(AvllError::new(
            arg,
            format!("must be finite and > 0, got {x}"),
        ))
    }
}

/// Fails unless `x` is finite and non-negative.
pub fn check_nonneg(arg: &str, x: f64) -> Result<()> {
    if x.is_finite() && x >= 0.0 {
        Ok(())
    } else {
        Err(AvllError::new(
            arg,
            format!("must be finite and >= 0, got {x}"),
        ))
    }
}

/// Fails unless every sample is finite; names the first bad index.
pub fn check_series(arg: &str, xs: &[f64]) -> Result<()> {
    match xs.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) => Err(AvllError::new(
            arg,
            format!("sample {i} is not finite ({})", xs[i]),
        )),
    }
}
