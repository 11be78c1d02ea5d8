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

/// Whether every sample is finite: `0 x` is 0 for a finite `x` and NaN otherwise,
/// summed in eight independent lanes, so the pass is branch-free and vectorizes (the
/// common, valid case costs a fraction of a scalar `position` search).
fn all_finite(xs: &[f64]) -> bool {
    let mut acc = [0.0f64; 8];
    let mut chunks = xs.chunks_exact(8);
    for c in &mut chunks {
        for k in 0..8 {
            acc[k] += c[k] * 0.0;
        }
    }
    let tail: f64 = chunks.remainder().iter().map(|x| x * 0.0).sum();
    (acc.iter().sum::<f64>() + tail) == 0.0
}

/// Fails unless every sample is finite; names the first bad index.
pub fn check_series(arg: &str, xs: &[f64]) -> Result<()> {
    if all_finite(xs) {
        return Ok(());
    }
    match xs.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) => Err(AvllError::new(
            arg,
            format!("sample {i} is not finite ({})", xs[i]),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_series_names_the_first_bad_sample_at_any_position() {
        for n in 0..20 {
            let ok: Vec<f64> = (0..n)
                .map(|i| [1e308, -1e308, 0.0, 5e-324][i % 4])
                .collect();
            assert!(check_series("x", &ok).is_ok());
            for i in 0..n {
                for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                    let mut xs = ok.clone();
                    xs[i] = bad;
                    if i + 1 < n {
                        xs[n - 1] = f64::NAN; // a later bad one is not the one named
                    }
                    let e = check_series("x", &xs).unwrap_err();
                    assert!(e.to_string().contains(&format!("sample {i} ")), "{e}");
                }
            }
        }
    }
}
