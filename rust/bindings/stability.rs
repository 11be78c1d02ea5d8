//! Bindings of the stability engine (paper Section IV).

use super::{guard, slice1};
use crate::model::ModelKind;
use crate::stability::{grid, pade, LoopModel};
use numpy::{IntoPyArray, PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray1};
use pyo3::prelude::*;

/// Points per chunk between two GIL re-acquisitions (Ctrl-C check, progress).
const CHUNK: usize = 1 << 20;

fn loop_model(model: &str, params: &[f64], pade_order: usize) -> PyResult<LoopModel> {
    guard(|| {
        let lin = ModelKind::from_name(model)?.linear(params)?;
        LoopModel::new(&lin, pade_order)
    })
}

/// Stability map over a kg × Tg × kv grid: uint8 codes, shape (len(kg), len(tg), len(kv)).
///
/// 0 = locally unstable, 1 = locally stable but string unstable, 2 = both stable.
/// The grid is evaluated in chunks with the GIL released; between chunks Ctrl-C is
/// honoured (KeyboardInterrupt) and `progress(done, total)` is called if given.
#[pyfunction]
#[pyo3(signature = (model, params, kg, tg, kv, pade_order = 2, threads = 0, progress = None))]
#[allow(clippy::too_many_arguments)]
fn stability_map<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    kg: PyReadonlyArray1<'py, f64>,
    tg: PyReadonlyArray1<'py, f64>,
    kv: PyReadonlyArray1<'py, f64>,
    pade_order: usize,
    threads: usize,
    progress: Option<Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray3<u8>>> {
    let lm = loop_model(model, &params, pade_order)?;
    let (kg, tg, kv) = (slice1("kg", &kg)?, slice1("tg", &tg)?, slice1("kv", &kv)?);
    let axes = guard(|| grid::Axes::new(kg, tg, kv))?;
    let total = axes.len();
    let mut out = vec![0u8; total];
    let mut start = 0;
    while start < total {
        let end = (start + CHUNK).min(total);
        let part = &mut out[start..end];
        py.detach(|| {
            guard(|| {
                crate::parallel::with_threads(threads, || grid::fill_range(&lm, &axes, start, part))
            })
        })?;
        start = end;
        py.check_signals()?;
        if let Some(cb) = &progress {
            cb.call1((start, total))?;
        }
    }
    let shape = [kg.len(), tg.len(), kv.len()];
    out.into_pyarray(py).reshape(shape)
}

/// Codes of scattered points (kg[i], tg[i], kv[i]).
#[pyfunction]
#[pyo3(signature = (model, params, kg, tg, kv, pade_order = 2, threads = 0))]
#[allow(clippy::too_many_arguments)]
fn stability_points<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    kg: PyReadonlyArray1<'py, f64>,
    tg: PyReadonlyArray1<'py, f64>,
    kv: PyReadonlyArray1<'py, f64>,
    pade_order: usize,
    threads: usize,
) -> PyResult<Bound<'py, PyArray1<u8>>> {
    let lm = loop_model(model, &params, pade_order)?;
    let (kg, tg, kv) = (slice1("kg", &kg)?, slice1("tg", &tg)?, slice1("kv", &kv)?);
    let out = py.detach(|| {
        guard(|| crate::parallel::with_threads(threads, || grid::classify_points(&lm, kg, tg, kv))?)
    })?;
    Ok(out.into_pyarray(py))
}

/// Ascending coefficients of N(s), D(s) (Eq. 8) and R(x) = P(x)/x at one point.
#[pyfunction]
#[pyo3(signature = (model, params, kg, tg, kv, pade_order = 2))]
#[allow(clippy::type_complexity)]
fn stability_polys(
    model: &str,
    params: Vec<f64>,
    kg: f64,
    tg: f64,
    kv: f64,
    pade_order: usize,
) -> PyResult<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let lm = loop_model(model, &params, pade_order)?;
    let (n, d) = lm.closed_loop(kg, tg, kv);
    let r = lm.string_poly(kg, tg, kv);
    Ok((
        n.coeffs().to_vec(),
        d.coeffs().to_vec(),
        r.coeffs().to_vec(),
    ))
}

/// Ascending coefficients of the Padé denominator Q(s): e^{-td s} ≈ Q(-s)/Q(s).
#[pyfunction]
fn pade_den(order: usize, td: f64) -> PyResult<Vec<f64>> {
    guard(|| {
        if !(1..=pade::MAX_ORDER).contains(&order) {
            return Err(crate::error::AvllError::new(
                "order",
                format!("must be in 1..={}, got {order}", pade::MAX_ORDER),
            ));
        }
        crate::error::check_nonneg("td", td)?;
        Ok(pade::pade_den(order, td).coeffs().to_vec())
    })
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("PADE_MAX_ORDER", pade::MAX_ORDER)?;
    m.add_function(wrap_pyfunction!(stability_map, m)?)?;
    m.add_function(wrap_pyfunction!(stability_points, m)?)?;
    m.add_function(wrap_pyfunction!(stability_polys, m)?)?;
    m.add_function(wrap_pyfunction!(pade_den, m)?)?;
    Ok(())
}
