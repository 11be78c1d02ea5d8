//! GA calibration of a base model with effects: the project's generic GA
//! ([`crate::ga::minimize`]) on the mean over runs of the effects engine's cost.

use super::engine::{run_cost, EffCostSpec, EffRun};
use crate::error::{AvllError, Result};
use crate::ga::{minimize, Bounds, GaOptions, GaResult, Progress};

/// Mean over runs of the per-run costs of one parameter row (`inf` if any is).
pub fn mean_cost(spec: &EffCostSpec, row: &[f64], runs: &[EffRun]) -> f64 {
    let mut s = 0.0;
    for run in runs {
        s += run_cost(spec, row, run);
        if !s.is_finite() {
            return f64::INFINITY;
        }
    }
    s / runs.len() as f64
}

/// Minimises [`mean_cost`] over `bounds` (`spec.n_params()` coordinates: base,
/// effects in canonical order, free upper-level gains) by the GA. `callback` runs
/// after every generation; returning `false` stops with the best so far.
pub fn calibrate(
    spec: &EffCostSpec,
    runs: &[EffRun],
    bounds: &Bounds,
    opts: &GaOptions,
    callback: impl FnMut(&Progress) -> bool,
) -> Result<GaResult> {
    spec.validate(runs)?;
    if bounds.dim() != spec.n_params() {
        return Err(AvllError::new(
            "bounds",
            format!(
                "has {} parameters, the model with its effects and free upper-level gains needs {}",
                bounds.dim(),
                spec.n_params()
            ),
        ));
    }
    let f = |x: &[f64]| mean_cost(spec, x, runs);
    minimize(&f, bounds, opts, callback)
}
