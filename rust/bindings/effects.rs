//! Bindings of the effects library (base model + effects rollouts, batched cost,
//! linearisation).

use super::runs::{runs_from_arrays, series};
use super::{guard, slice1, slice2};
use crate::effects::{engine, EffectKind, EffectList, Operating};
use crate::model::{CommandKind, Linear, ModelKind};
use crate::rollout::{CostSpec, Init, Trajectory, Upper};
use numpy::{IntoPyArray, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::collections::BTreeMap;

type Exo<'py> = BTreeMap<String, PyReadonlyArray1<'py, f64>>;

fn setup(
    model: &str,
    params: &[f64],
    effects: Vec<String>,
    effect_params: &[f64],
    kind: CommandKind,
) -> PyResult<(Linear, Vec<crate::effects::AnyEffect>)> {
    guard(|| {
        let lin = ModelKind::from_name(model)?.linear(params)?;
        let names: Vec<&str> = effects.iter().map(|s| s.as_str()).collect();
        let list = EffectList::from_names(&names, kind)?;
        // Parameters come in the caller's order; reorder to the canonical order.
        let mut by_name = BTreeMap::new();
        let mut o = 0;
        for n in &names {
            let k = EffectKind::from_name(n)?;
            if effect_params.len() < o + k.n_params() {
                return Err(crate::error::AvllError::new(
                    "effect_params",
                    format!("too few values for the effects {names:?}"),
                ));
            }
            by_name.insert(k, &effect_params[o..o + k.n_params()]);
            o += k.n_params();
        }
        if o != effect_params.len() {
            return Err(crate::error::AvllError::new(
                "effect_params",
                format!("expected {o} values, got {}", effect_params.len()),
            ));
        }
        let p: Vec<f64> = list
            .0
            .iter()
            .flat_map(|k| by_name[k].iter().copied())
            .collect();
        Ok((lin, list.build(&p, kind)?))
    })
}

fn exo_slices<'a>(exo: &'a Exo<'_>) -> PyResult<Vec<(&'a str, &'a [f64])>> {
    exo.iter()
        .map(|(k, v)| Ok((k.as_str(), slice1(&format!("exo[{k:?}]"), v)?)))
        .collect()
}

fn trajectory<'py>(py: Python<'py>, tr: Trajectory) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("a", tr.a.into_pyarray(py))?;
    d.set_item("v", tr.v.into_pyarray(py))?;
    d.set_item("x", tr.x.into_pyarray(py))?;
    d.set_item("command", tr.command.into_pyarray(py))?;
    Ok(d)
}

/// The registered effects: name, params, bounds, neutral values, exo, accel_only.
#[pyfunction]
fn effect_info<'py>(py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
    EffectKind::ALL
        .iter()
        .map(|k| {
            let d = PyDict::new(py);
            d.set_item("name", k.name())?;
            d.set_item("params", k.params().to_vec())?;
            d.set_item("bounds", k.bounds().to_vec())?;
            d.set_item("neutral", k.neutral().to_vec())?;
            d.set_item("exo", k.exo())?;
            d.set_item("accel_only", k.accel_only())?;
            Ok(d)
        })
        .collect()
}

/// Open-loop rollout of a base model with effects: dict of arrays a, v, x, command.
#[pyfunction]
#[pyo3(signature = (model, params, effects, effect_params, command, dt, command_kind = "acceleration", init = "rest", v0 = 0.0, x0 = 0.0, exo = BTreeMap::new()))]
#[allow(clippy::too_many_arguments)]
fn simulate_effects<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    effects: Vec<String>,
    effect_params: Vec<f64>,
    command: PyReadonlyArray1<'py, f64>,
    dt: f64,
    command_kind: &str,
    init: &str,
    v0: f64,
    x0: f64,
    exo: Exo<'py>,
) -> PyResult<Bound<'py, PyDict>> {
    let kind = guard(|| CommandKind::from_name(command_kind))?;
    let init = guard(|| Init::from_name(init))?;
    let (lin, effs) = setup(model, &params, effects, &effect_params, kind)?;
    let u = slice1("command", &command)?;
    let ex = exo_slices(&exo)?;
    let tr =
        py.detach(|| guard(|| engine::simulate_full(&lin, &effs, kind, u, dt, init, v0, x0, &ex)))?;
    trajectory(py, tr)
}

/// Closed-loop car following of a base model with effects behind a recorded leader.
#[pyfunction]
#[pyo3(signature = (model, params, effects, effect_params, lead_x, lead_v, dt, kg, kv, tg, gmin, v0, x0, exo = BTreeMap::new()))]
#[allow(clippy::too_many_arguments)]
fn closed_loop_effects<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    effects: Vec<String>,
    effect_params: Vec<f64>,
    lead_x: PyReadonlyArray1<'py, f64>,
    lead_v: PyReadonlyArray1<'py, f64>,
    dt: f64,
    kg: f64,
    kv: f64,
    tg: f64,
    gmin: f64,
    v0: f64,
    x0: f64,
    exo: Exo<'py>,
) -> PyResult<Bound<'py, PyDict>> {
    let (lin, effs) = setup(
        model,
        &params,
        effects,
        &effect_params,
        CommandKind::Acceleration,
    )?;
    let up = Upper { kg, kv, tg, gmin };
    let lx = slice1("lead_x", &lead_x)?;
    let lv = slice1("lead_v", &lead_v)?;
    let ex = exo_slices(&exo)?;
    let tr =
        py.detach(|| guard(|| engine::closed_loop(&lin, &effs, &up, lx, lv, dt, v0, x0, &ex)))?;
    trajectory(py, tr)
}

/// The small-signal `Linear` of base + effects at speed `v` on `side` (1 accel,
/// -1 braking, 0 average): dict b1, b0, a2, a1, Td, K.
#[pyfunction]
#[pyo3(signature = (model, params, effects, effect_params, v = 0.0, side = 0, command_kind = "acceleration"))]
#[allow(clippy::too_many_arguments)]
fn linearize_effects<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    effects: Vec<String>,
    effect_params: Vec<f64>,
    v: f64,
    side: i8,
    command_kind: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let kind = guard(|| CommandKind::from_name(command_kind))?;
    let (lin, effs) = setup(model, &params, effects, &effect_params, kind)?;
    let l = guard(|| crate::effects::linearize(&lin, &effs, &Operating { v, side }))?;
    let d = PyDict::new(py);
    for (k, x) in [
        ("b1", l.b1),
        ("b0", l.b0),
        ("a2", l.a2),
        ("a1", l.a1),
        ("Td", l.td),
        ("K", l.k),
    ] {
        d.set_item(k, x)?;
    }
    Ok(d)
}

/// The cost specification of the batched functions (effects in canonical order).
fn eff_spec(
    model: &str,
    effects: &[String],
    upper_free: Vec<usize>,
    command_kind: &str,
    weights: (f64, f64, f64),
    init: &str,
    closed_loop: bool,
) -> PyResult<engine::EffCostSpec> {
    guard(|| {
        let kind = CommandKind::from_name(command_kind)?;
        let names: Vec<&str> = effects.iter().map(|s| s.as_str()).collect();
        let list = EffectList::from_names(&names, kind)?;
        if list.0.iter().map(|k| k.name()).ne(names.iter().copied()) {
            return Err(crate::error::AvllError::new(
                "effects",
                format!(
                    "must be in the canonical order {:?}",
                    list.0.iter().map(|k| k.name()).collect::<Vec<_>>()
                ),
            ));
        }
        Ok(engine::EffCostSpec {
            base: CostSpec {
                model: ModelKind::from_name(model)?,
                kind,
                weights: [weights.0, weights.1, weights.2],
                init: Init::from_name(init)?,
                closed_loop,
                upper_free,
            },
            effects: list,
        })
    })
}

/// The concatenated run arrays of the batched functions as borrowed runs: run `r`
/// is `offsets[r]..offsets[r+1]` of every series.
#[allow(clippy::too_many_arguments)]
fn eff_runs<'a>(
    offsets: &[usize],
    dt: &'a PyReadonlyArray1<'_, f64>,
    a: &'a PyReadonlyArray1<'_, f64>,
    command: &'a Option<PyReadonlyArray1<'_, f64>>,
    lead_x: &'a Option<PyReadonlyArray1<'_, f64>>,
    lead_v: &'a Option<PyReadonlyArray1<'_, f64>>,
    v: &'a Option<PyReadonlyArray1<'_, f64>>,
    x: &'a Option<PyReadonlyArray1<'_, f64>>,
    upper: &'a Option<PyReadonlyArray2<'_, f64>>,
    exo: &'a Exo<'_>,
) -> PyResult<Vec<engine::EffRun<'a>>> {
    let runs = runs_from_arrays(offsets, dt, a, command, lead_x, lead_v, v, x, upper)?;
    let total = offsets[runs.len()];
    let mut exos = Vec::new();
    for (k, arr) in exo {
        exos.push((k.as_str(), series(&format!("exo[{k:?}]"), arr, total)?));
    }
    Ok(runs
        .into_iter()
        .enumerate()
        .map(|(k, run)| engine::EffRun {
            run,
            exo: exos
                .iter()
                .map(|(n, s)| (*n, &s[offsets[k]..offsets[k + 1]]))
                .collect(),
        })
        .collect())
}

/// Per-run costs of base+effects parameter rows `[base | effects (canonical order) |
/// free upper]` over concatenated runs, in parallel: a (P, R) array, `inf` for
/// invalid or unstable rows.
#[pyfunction]
#[pyo3(signature = (model, effects, params, offsets, dt, a, command=None, lead_x=None, lead_v=None, v=None, x=None, upper=None, upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0), init="rest", closed_loop=false, exo=BTreeMap::new(), threads=0))]
#[allow(clippy::too_many_arguments)]
fn batch_cost_effects<'py>(
    py: Python<'py>,
    model: &str,
    effects: Vec<String>,
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
    exo: Exo<'py>,
    threads: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let spec = eff_spec(
        model,
        &effects,
        upper_free,
        command_kind,
        weights,
        init,
        closed_loop,
    )?;
    let (p, np, rows) = slice2("params", &params)?;
    if np != spec.n_params() {
        return Err(PyValueError::new_err(format!(
            "params: rows have {np} columns, expected {} ({} model + {} effect + {} free upper-level)",
            spec.n_params(),
            spec.base.model.n_params(),
            spec.effects.n_params(),
            spec.base.upper_free.len()
        )));
    }
    let runs = eff_runs(
        &offsets, &dt, &a, &command, &lead_x, &lead_v, &v, &x, &upper, &exo,
    )?;
    let r = runs.len();
    let out = py.detach(|| {
        guard(|| crate::parallel::with_threads(threads, || engine::batch_cost(&spec, rows, &runs))?)
    })?;
    out.into_pyarray(py).reshape([p, r])
}

/// Calibrates base + effects (and free upper-level gains) by the project's GA on the
/// mean over runs of the effects cost. Rows/bounds: `[base | effects (canonical) |
/// free upper]`. `progress(dict)` is called between generations; Ctrl-C stops the GA
/// with the best so far and raises `KeyboardInterrupt`. Returns a dict (x, f, f_ga,
/// generations, evaluations, stop, history).
#[pyfunction]
#[pyo3(signature = (
    model, effects, offsets, dt, a, lower_bounds, upper_bounds, scale,
    command=None, lead_x=None, lead_v=None, v=None, x=None, upper=None,
    upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0),
    init="rest", closed_loop=false, exo=BTreeMap::new(), seed=0, pop_size=0,
    max_generations=300, stall_generations=20, ftol=1e-4, polish=true, local_every=3,
    initial=None, progress=None, threads=0
))]
#[allow(clippy::too_many_arguments)]
fn calibrate_effects<'py>(
    py: Python<'py>,
    model: &str,
    effects: Vec<String>,
    offsets: Vec<usize>,
    dt: PyReadonlyArray1<'py, f64>,
    a: PyReadonlyArray1<'py, f64>,
    lower_bounds: Vec<f64>,
    upper_bounds: Vec<f64>,
    scale: Vec<String>,
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
    exo: Exo<'py>,
    seed: u64,
    pop_size: usize,
    max_generations: usize,
    stall_generations: usize,
    ftol: f64,
    polish: bool,
    local_every: usize,
    initial: Option<PyReadonlyArray2<'py, f64>>,
    progress: Option<Py<PyAny>>,
    threads: usize,
) -> PyResult<Bound<'py, PyDict>> {
    use crate::ga::{Bounds, GaOptions, Scale};
    let spec = eff_spec(
        model,
        &effects,
        upper_free,
        command_kind,
        weights,
        init,
        closed_loop,
    )?;
    let scales = guard(|| scale.iter().map(|s| Scale::from_name(s)).collect())?;
    let bounds = guard(|| Bounds::new(lower_bounds, upper_bounds, scales))?;
    let initial: Vec<Vec<f64>> = match &initial {
        None => Vec::new(),
        Some(arr) => {
            let (_, c, s) = slice2("initial", arr)?;
            if c == 0 {
                Vec::new()
            } else {
                s.chunks(c).map(|r| r.to_vec()).collect()
            }
        }
    };
    let opts = GaOptions {
        pop_size,
        max_generations,
        stall_generations,
        ftol,
        seed,
        polish,
        local_every,
        initial,
        ..GaOptions::default()
    };
    let runs = eff_runs(
        &offsets, &dt, &a, &command, &lead_x, &lead_v, &v, &x, &upper, &exo,
    )?;
    let mut interrupted = false;
    let mut cb_error: Option<PyErr> = None;
    let res = py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || {
                crate::effects::calibrate::calibrate(&spec, &runs, &bounds, &opts, |p| {
                    Python::attach(|py| {
                        if let Err(e) = py.check_signals() {
                            interrupted = true;
                            cb_error = Some(e);
                            return false;
                        }
                        if let Some(cb) = &progress {
                            let info = PyDict::new(py);
                            let r = (|| -> PyResult<()> {
                                info.set_item("iteration", p.iteration)?;
                                info.set_item("evaluations", p.evaluations)?;
                                info.set_item("best", p.best_f)?;
                                cb.bind(py).call1((info,))?;
                                Ok(())
                            })();
                            if let Err(e) = r {
                                cb_error = Some(e);
                                return false;
                            }
                        }
                        true
                    })
                })
            })?
        })
    })?;
    if let Some(e) = cb_error {
        let _ = interrupted;
        return Err(e);
    }
    let d = PyDict::new(py);
    d.set_item("x", res.x.into_pyarray(py))?;
    d.set_item("f", res.f)?;
    d.set_item("f_ga", res.f_ga)?;
    d.set_item("generations", res.generations)?;
    d.set_item("evaluations", res.evaluations)?;
    d.set_item("stop", res.stop.name())?;
    d.set_item("history", res.history.into_pyarray(py))?;
    Ok(d)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(effect_info, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_effects, m)?)?;
    m.add_function(wrap_pyfunction!(closed_loop_effects, m)?)?;
    m.add_function(wrap_pyfunction!(linearize_effects, m)?)?;
    m.add_function(wrap_pyfunction!(batch_cost_effects, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate_effects, m)?)?;
    Ok(())
}
