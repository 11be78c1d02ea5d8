//! The PyO3 module `avll._core`: the only code that knows about Python.
//!
//! Each area registers its functions from its own file. Heavy calls release the
//! GIL (`py.detach`); every core call runs under `guard`, which turns a core error
//! into `ValueError` and a panic (a bug) into `RuntimeError` rather than letting it
//! cross into Python.

mod checks;
mod effects;
mod ga;
mod outbuf;
mod rollout;
mod runs;
mod stability;

use crate::error::AvllError;
use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

impl From<AvllError> for PyErr {
    fn from(e: AvllError) -> Self {
        PyValueError::new_err(e.to_string())
    }
}

/// Runs `f`, converting a panic into `RuntimeError` (never a `PanicException`).
pub(crate) fn guard<T>(f: impl FnOnce() -> Result<T, AvllError>) -> PyResult<T> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(e.into()),
        Err(p) => {
            let msg = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown".into());
            Err(PyRuntimeError::new_err(format!(
                "avll internal error (please report): {msg}"
            )))
        }
    }
}

/// A vector of `n` copies of `fill`, allocated fallibly: a size the process cannot
/// get (or whose byte count overflows) is a `ValueError` naming `what` and the
/// estimate, not an abort of the process (Rust aborts on a failed infallible
/// allocation).
pub(crate) fn try_filled<T: Clone>(what: &str, n: usize, fill: T) -> PyResult<Vec<T>> {
    let bytes = n.checked_mul(std::mem::size_of::<T>().max(1));
    let refuse = || {
        let size = match bytes {
            Some(b) => format!("{:.1} GB", b as f64 / 1e9),
            None => "more bytes than an address space holds".to_string(),
        };
        PyValueError::new_err(format!(
            "{what}: {n} values need about {size}, which cannot be allocated; split the work \
             into smaller calls"
        ))
    };
    if bytes.is_none_or(|b| b > isize::MAX as usize) {
        return Err(refuse());
    }
    let mut v: Vec<T> = Vec::new();
    v.try_reserve_exact(n).map_err(|_| refuse())?;
    v.resize(n, fill);
    Ok(v)
}

/// A contiguous 1-D float64 view, or a `ValueError` naming the argument.
pub(crate) fn slice1<'a>(arg: &str, a: &'a PyReadonlyArray1<'_, f64>) -> PyResult<&'a [f64]> {
    a.as_slice()
        .map_err(|_| PyValueError::new_err(format!("{arg}: must be a contiguous float64 array")))
}

/// A contiguous 2-D float64 array as (rows, cols, row-major data).
pub(crate) fn slice2<'a>(
    arg: &str,
    a: &'a PyReadonlyArray2<'_, f64>,
) -> PyResult<(usize, usize, &'a [f64])> {
    let shape = a.shape();
    let s = a.as_slice().map_err(|_| {
        PyValueError::new_err(format!("{arg}: must be a C-contiguous float64 array"))
    })?;
    Ok((shape[0], shape[1], s))
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // The sources this extension was compiled from (build.rs): tests/test_build.py
    // and .ci/build_identity.py tell a stale or foreign build by it.
    m.add("SOURCE_DIGEST", env!("AVLL_SOURCE_DIGEST"))?;
    runs::register(m)?;
    rollout::register(m)?;
    outbuf::register(m)?;
    effects::register(m)?;
    ga::register(m)?;
    stability::register(m)?;
    checks::register(m)?;
    Ok(())
}
