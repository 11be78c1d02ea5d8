//! Bindings of the models and rollouts.

use super::runs::runs_from_arrays;
use super::{guard, slice1, slice2};
use crate::model::{CommandKind, ModelKind};
use crate::rollout::{self, CostSpec, Init, Upper};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

fn linear(model: &str, params: &[f64]) -> PyResult<crate::model::Linear> {
    guard(|| ModelKind::from_name(model)?.linear(params))
}

/// Names of the registered models and their parameters.
#[pyfunction]
fn model_params(model: &str) -> PyResult<Vec<&'static str>> {
    guard(|| Ok(ModelKind::from_name(model)?.params().to_vec()))
}

/// Open-loop response of a model to a command (see `avll.simulate`).
#[pyfunction]
#[pyo3(signature = (model, params, command, dt, init = "rest"))]
fn simulate<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    command: PyReadonlyArray1<'py, f64>,
    dt: f64,
    init: &str,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let lin = linear(model, &params)?;
    let init = guard(|| Init::from_name(init))?;
    let u = slice1("command", &command)?;
    let y = py.detach(|| guard(|| rollout::simulate(&lin, u, dt, init)))?;
    Ok(y.into_pyarray(py))
}

fn trajectory<'py>(py: Python<'py>, tr: rollout::Trajectory) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("a", tr.a.into_pyarray(py))?;
    d.set_item("v", tr.v.into_pyarray(py))?;
    d.set_item("x", tr.x.into_pyarray(py))?;
    d.set_item("command", tr.command.into_pyarray(py))?;
    Ok(d)
}

/// Open-loop rollout with speed and position: dict of arrays a, v, x, command.
#[pyfunction]
#[pyo3(signature = (model, params, command, dt, command_kind = "acceleration", init = "rest", v0 = 0.0, x0 = 0.0))]
#[allow(clippy::too_many_arguments)]
fn simulate_full<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    command: PyReadonlyArray1<'py, f64>,
    dt: f64,
    command_kind: &str,
    init: &str,
    v0: f64,
    x0: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let lin = linear(model, &params)?;
    let kind = guard(|| CommandKind::from_name(command_kind))?;
    let init = guard(|| Init::from_name(init))?;
    let u = slice1("command", &command)?;
    let tr = py.detach(|| guard(|| rollout::simulate_full(&lin, kind, u, dt, init, v0, x0)))?;
    trajectory(py, tr)
}

/// Closed-loop car following behind a recorded leader (upper law Eq. 3).
#[pyfunction]
#[pyo3(signature = (model, params, lead_x, lead_v, dt, kg, kv, tg, gmin, v0, x0))]
#[allow(clippy::too_many_arguments)]
fn closed_loop<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    lead_x: PyReadonlyArray1<'py, f64>,
    lead_v: PyReadonlyArray1<'py, f64>,
    dt: f64,
    kg: f64,
    kv: f64,
    tg: f64,
    gmin: f64,
    v0: f64,
    x0: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let lin = linear(model, &params)?;
    let up = Upper { kg, kv, tg, gmin };
    let lx = slice1("lead_x", &lead_x)?;
    let lv = slice1("lead_v", &lead_v)?;
    let tr = py.detach(|| guard(|| rollout::closed_loop(&lin, &up, lx, lv, dt, v0, x0)))?;
    trajectory(py, tr)
}

/// Platoon of `followers` identical vehicles: dict of (followers, T) arrays.
#[pyfunction]
#[pyo3(signature = (model, params, lead_x, lead_v, dt, kg, kv, tg, gmin, followers))]
#[allow(clippy::too_many_arguments)]
fn platoon<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    lead_x: PyReadonlyArray1<'py, f64>,
    lead_v: PyReadonlyArray1<'py, f64>,
    dt: f64,
    kg: f64,
    kv: f64,
    tg: f64,
    gmin: f64,
    followers: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let lin = linear(model, &params)?;
    let up = Upper { kg, kv, tg, gmin };
    let lx = slice1("lead_x", &lead_x)?;
    let lv = slice1("lead_v", &lead_v)?;
    let trs = py.detach(|| guard(|| rollout::platoon(&lin, &up, lx, lv, dt, followers)))?;
    let t = lx.len();
    let d = PyDict::new(py);
    for (key, get) in [
        (
            "a",
            (|tr: &rollout::Trajectory| tr.a.clone()) as fn(&rollout::Trajectory) -> Vec<f64>,
        ),
        ("v", |tr| tr.v.clone()),
        ("x", |tr| tr.x.clone()),
        ("command", |tr| tr.command.clone()),
    ] {
        let flat: Vec<f64> = trs.iter().flat_map(get).collect();
        d.set_item(key, flat.into_pyarray(py).reshape([followers, t])?)?;
    }
    Ok(d)
}

/// Per-run costs (Eq. 6) of many parameter rows over many runs, in parallel.
///
/// Runs are concatenated: run `r` is `offsets[r]..offsets[r+1]` of every series.
/// Returns a (P, R) array; invalid or unstable rows get `inf`.
#[pyfunction]
#[pyo3(signature = (model, params, offsets, dt, a, command=None, lead_x=None, lead_v=None, v=None, x=None, upper=None, upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0), init="rest", closed_loop=false, threads=0))]
#[allow(clippy::too_many_arguments)]
fn batch_cost<'py>(
    py: Python<'py>,
    model: &str,
    params: PyReadonlyArray2<'py, f64>,
    offsets: Vec<usize>,
    dt: PyReadonlyArray1<'py, f64>,
    a: PyReadonlyArray1<'py, f64>,
    command: Option<PyReadonlyArray1<'py, f64>>,
    lead_x: Option<PyReadonlyArray1<'py, f64>>,
    lead_v: Option<PyReadonlyArray1<'py, f64>>,
    v: Option<PyReadonlyArray1<'py, f64>>,
    x: Option<PyReadonlyArray1<'py, f64>>,
    upper: Option<PyReadonlyArray2<'py, f64>>,
    upper_free: Vec<usize>,
    command_kind: &str,
    weights: (f64, f64, f64),
    init: &str,
    closed_loop: bool,
    threads: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let spec = guard(|| {
        Ok(CostSpec {
            model: ModelKind::from_name(model)?,
            kind: CommandKind::from_name(command_kind)?,
            weights: [weights.0, weights.1, weights.2],
            init: Init::from_name(init)?,
            closed_loop,
            upper_free,
        })
    })?;
    let (p, np, rows) = slice2("params", &params)?;
    if np != spec.n_params() {
        return Err(PyValueError::new_err(format!(
            "params: rows have {np} columns, expected {} ({} model parameters + {} free upper-level)",
            spec.n_params(),
            spec.model.n_params(),
            spec.upper_free.len()
        )));
    }
    let runs = runs_from_arrays(
        &offsets, &dt, &a, &command, &lead_x, &lead_v, &v, &x, &upper,
    )?;
    let r = runs.len();
    let out = py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || rollout::batch_cost(&spec, rows, &runs))?
        })
    })?;

    out.into_pyarray(py).reshape([p, r])
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(model_params, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_full, m)?)?;
    m.add_function(wrap_pyfunction!(closed_loop, m)?)?;
    m.add_function(wrap_pyfunction!(platoon, m)?)?;
    m.add_function(wrap_pyfunction!(batch_cost, m)?)?;
    Ok(())
}
