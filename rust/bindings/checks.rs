//! Small checks the Python layer runs before a call: the thread bound of
//! [`crate::parallel`] and the asymptotic stability of a lower level (the test
//! behind the costs' `inf`), so that the trajectory functions can refuse an unstable
//! lower level with a clear error instead of returning NaN.

use super::guard;
use crate::discretize::{discretize, inner_loop_stable, Integrators};
use crate::error::{check_finite, check_positive};
use crate::model::Linear;
use pyo3::prelude::*;

/// The largest accepted `threads` (a multiple of the available cores).
#[pyfunction]
fn max_threads() -> usize {
    crate::parallel::max_threads()
}

/// The cores available to this process.
#[pyfunction]
fn available_cores() -> usize {
    crate::parallel::cores()
}

/// Whether the lower level `(b1 s + b0) e^{-td s} / (a2 s^2 + a1 s + 1)` with the
/// inner loop `u_ref = u + k y` closed at the samples is asymptotically stable at
/// sample time `dt` (exactly the test the batched costs use: an unstable one costs
/// `inf`). Coefficients the discretization cannot handle count as not stable.
#[pyfunction]
#[pyo3(signature = (b1, b0, a2, a1, td, k, dt))]
#[allow(clippy::too_many_arguments)]
fn lower_level_stable(
    b1: f64,
    b0: f64,
    a2: f64,
    a1: f64,
    td: f64,
    k: f64,
    dt: f64,
) -> PyResult<bool> {
    guard(|| {
        check_positive("dt", dt)?;
        for (n, x) in [
            ("b1", b1),
            ("b0", b0),
            ("a2", a2),
            ("a1", a1),
            ("Td", td),
            ("K", k),
        ] {
            check_finite(n, x)?;
        }
        if td < 0.0 || a2 < 0.0 {
            return Ok(false);
        }
        let lin = Linear {
            b1,
            b0,
            a2,
            a1,
            td,
            k,
        };
        Ok(match lin.order() {
            1 => {
                if a1 == 0.0 {
                    return Ok(false);
                }
                discretize::<1>(&lin, Integrators::None, dt)
                    .is_ok_and(|d| inner_loop_stable(&d, &lin))
            }
            _ => discretize::<2>(&lin, Integrators::None, dt)
                .is_ok_and(|d| inner_loop_stable(&d, &lin)),
        })
    })
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("THREADS_PER_CORE", crate::parallel::THREADS_PER_CORE)?;
    m.add_function(wrap_pyfunction!(max_threads, m)?)?;
    m.add_function(wrap_pyfunction!(available_cores, m)?)?;
    m.add_function(wrap_pyfunction!(lower_level_stable, m)?)?;
    Ok(())
}
