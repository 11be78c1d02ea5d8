//! Bindings of the models, rollouts, batched costs and batched simulation (every
//! rollout runs on the one kernel, `crate::sim`).

use super::effects::{effects_of, Exo};
use super::outbuf;
use super::runs::RunSet;
use super::{guard, slice1, slice2};
use crate::effects::{AnyEffect, EffectList};
use crate::model::{CommandKind, Linear, ModelKind};
use crate::sim::rollout::{self, EffectsRef, Out, TimeMajor};
use crate::sim::{CostSpec, Init, Upper};
use numpy::ndarray::{Ix1, Ix2, Ix3};
use numpy::{
    IntoPyArray, PyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1,
    PyReadonlyArray2, PyReadwriteArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

fn linear(model: &str, params: &[f64]) -> PyResult<Linear> {
    guard(|| ModelKind::from_name(model)?.linear(params))
}

/// The one cost specification of the batched bindings (effects in canonical order).
#[allow(clippy::too_many_arguments)]
pub(super) fn cost_spec(
    model: &str,
    effects: &[String],
    upper_free: Vec<usize>,
    command_kind: &str,
    weights: (f64, f64, f64),
    init: &str,
    closed_loop: bool,
) -> PyResult<CostSpec> {
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
        Ok(CostSpec {
            model: ModelKind::from_name(model)?,
            effects: list,
            kind,
            weights: [weights.0, weights.1, weights.2],
            init: Init::from_name(init)?,
            closed_loop,
            upper_free,
            relaxed: false,
        })
    })
}

/// Checks a parameter array's row length against the spec.
pub(super) fn check_rows(spec: &CostSpec, np: usize) -> PyResult<()> {
    if np != spec.n_params() {
        return Err(PyValueError::new_err(format!(
            "params: rows have {np} columns, expected {} ({} model + {} effect + {} free upper-level)",
            spec.n_params(),
            spec.model.n_params(),
            spec.effects.n_params(),
            spec.upper_free.len()
        )));
    }
    Ok(())
}

/// The parameter rows of a batched call, checked against the spec: (P, row-major data).
fn spec_rows<'a>(
    spec: &CostSpec,
    params: &'a PyReadonlyArray2<'_, f64>,
) -> PyResult<(usize, &'a [f64])> {
    let (p, np, rows) = slice2("params", params)?;
    check_rows(spec, np)?;
    Ok((p, rows))
}

/// Short names of the registered base models, in registry order.
#[pyfunction]
fn model_names() -> Vec<&'static str> {
    ModelKind::ALL.iter().map(|k| k.name()).collect()
}

/// Parameter names of a registered model, in array order.
#[pyfunction]
fn model_params(model: &str) -> PyResult<Vec<&'static str>> {
    guard(|| Ok(ModelKind::from_name(model)?.params().to_vec()))
}

/// A caller's output array (numpy's `out=`): float64 of the expected shape,
/// C-contiguous; a `ValueError` naming the argument otherwise.
fn out_arg<'py, D: numpy::ndarray::Dimension>(
    name: &str,
    obj: &Bound<'py, PyAny>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyArray<f64, D>>> {
    let want = format!(
        "a float64 numpy array of shape {}, C-contiguous and writeable",
        py_shape(shape)
    );
    let arr = obj.cast::<PyArray<f64, D>>().map_err(|_| {
        let got = match obj.cast::<numpy::PyUntypedArray>() {
            Ok(a) => format!("dtype {} (shape {})", a.dtype(), py_shape(a.shape())),
            Err(_) => obj
                .get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default(),
        };
        PyValueError::new_err(format!("{name}: must be {want}, got {got}"))
    })?;
    if arr.shape() != shape {
        return Err(PyValueError::new_err(format!(
            "{name}: must be {want}, got shape {}",
            py_shape(arr.shape())
        )));
    }
    if !arr.is_c_contiguous() {
        return Err(PyValueError::new_err(format!(
            "{name}: must be {want}, got a non-contiguous array"
        )));
    }
    Ok(arr.clone())
}

/// A shape as Python prints it: `(5,)`, `(3, 4)`.
fn py_shape(s: &[usize]) -> String {
    match s {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            s.iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// The name of output `i` of `n`: `out`, or `out[1] (v)` for the four arrays of a
/// trajectory.
fn out_label(name: &str, i: usize, n: usize) -> String {
    match n {
        1 => name.to_string(),
        4 => format!("{name}[{i}] ({})", ["a", "v", "x", "command"][i]),
        _ => format!("{name}[{i}]"),
    }
}

/// Mutable borrows of output arrays, or a `ValueError` (read-only, or sharing
/// memory with each other or an input).
fn borrow_out<'py, D: numpy::ndarray::Dimension>(
    name: &str,
    arrs: &[Bound<'py, PyArray<f64, D>>],
) -> PyResult<Vec<PyReadwriteArray<'py, f64, D>>> {
    arrs.iter()
        .enumerate()
        .map(|(i, a)| {
            a.try_readwrite().map_err(|e| {
                let which = out_label(name, i, arrs.len());
                PyValueError::new_err(match e {
                    numpy::BorrowError::NotWriteable => {
                        format!("{which}: must be writeable, got a read-only array")
                    }
                    _ => format!(
                        "{which}: shares memory with another output or an input; pass \
                         separate arrays"
                    ),
                })
            })
        })
        .collect()
}

/// `K` caller arrays (a tuple of `K`) of one shape, checked by [`out_arg`].
fn out_args<'py, D: numpy::ndarray::Dimension, const K: usize>(
    name: &str,
    obj: &Bound<'py, PyAny>,
    shape: &[usize],
) -> PyResult<[Bound<'py, PyArray<f64, D>>; K]> {
    let items: Vec<Bound<'py, PyAny>> = obj
        .try_iter()
        .and_then(|it| it.collect::<PyResult<Vec<_>>>())
        .map_err(|_| {
            PyValueError::new_err(format!(
                "{name}: must be an avll.Trajectory or a sequence of {K} arrays"
            ))
        })?;
    if items.len() != K {
        return Err(PyValueError::new_err(format!(
            "{name}: must be an avll.Trajectory or a sequence of {K} arrays, got {}",
            items.len()
        )));
    }
    let v: Vec<_> = items
        .iter()
        .enumerate()
        .map(|(i, o)| out_arg::<D>(&out_label(name, i, K), o, shape))
        .collect::<PyResult<_>>()?;
    Ok(v.try_into().unwrap_or_else(|_| unreachable!()))
}

/// Open-loop response of a model to a command (see `avll.simulate`), into `out`
/// when given (returned).
#[pyfunction]
#[pyo3(signature = (model, params, command, dt, init = "rest", out = None))]
#[allow(clippy::too_many_arguments)]
fn simulate<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    command: PyReadonlyArray1<'py, f64>,
    dt: f64,
    init: &str,
    out: Option<Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let lin = linear(model, &params)?;
    let init = guard(|| Init::from_name(init))?;
    let u = slice1("command", &command)?;
    let y = match &out {
        Some(o) => out_arg::<Ix1>("out", o, &[u.len()])?,
        // uninitialised: `simulate_into` writes every element before Python can see
        // the array, and on an error it is dropped unseen
        None => outbuf::empty1(py, u.len(), false),
    };
    {
        let mut w = borrow_out("out", std::slice::from_ref(&y))?;
        let out = w[0].as_slice_mut()?;
        py.detach(|| guard(|| rollout::simulate_into(&lin, u, dt, init, out)))?;
    }
    Ok(y)
}

/// Four (T,) arrays a, v, x, command: the caller's (`out`, a sequence of four) or
/// new uninitialised ones, which every rollout that receives them writes in full
/// (NaN after a divergence) before returning; an error drops them unseen.
fn four<'py>(
    py: Python<'py>,
    out: Option<&Bound<'py, PyAny>>,
    t: usize,
) -> PyResult<[Bound<'py, PyArray1<f64>>; 4]> {
    match out {
        Some(o) => out_args::<Ix1, 4>("out", o, &[t]),
        None => Ok(std::array::from_fn(|_| outbuf::empty1(py, t, true))),
    }
}

/// The four arrays of a trajectory, `(a, v, x, command)` (typed by the stubs; a
/// platoon's are the sample-major `(T, followers)` arrays, which the Python layer
/// transposes).
type Arrays4<'py, D> = (
    Bound<'py, PyArray<f64, D>>,
    Bound<'py, PyArray<f64, D>>,
    Bound<'py, PyArray<f64, D>>,
    Bound<'py, PyArray<f64, D>>,
);

fn exo_slices<'a>(exo: &'a Exo<'_>) -> PyResult<Vec<(&'a str, &'a [f64])>> {
    exo.iter()
        .map(|(k, v)| Ok((k.as_str(), slice1(&format!("exo[{k:?}]"), v)?)))
        .collect()
}

/// Open-loop rollout with speed and position (optionally with effects): dict of
/// arrays a, v, x, command (the caller's four `out` arrays when given).
#[pyfunction]
#[pyo3(signature = (model, params, command, dt, command_kind = "acceleration", init = "rest", v0 = 0.0, x0 = 0.0, effects = Vec::new(), effect_params = Vec::new(), exo = Exo::new(), out = None))]
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
    effects: Vec<String>,
    effect_params: Vec<f64>,
    exo: Exo<'py>,
    out: Option<Bound<'py, PyAny>>,
) -> PyResult<Arrays4<'py, Ix1>> {
    let kind = guard(|| CommandKind::from_name(command_kind))?;
    let init = guard(|| Init::from_name(init))?;
    let lin = linear(model, &params)?;
    let effs: Vec<AnyEffect> = effects_of(&effects, &effect_params, kind)?;
    let u = slice1("command", &command)?;
    let ex = exo_slices(&exo)?;
    let arrs = four(py, out.as_ref(), u.len())?;
    {
        let mut ws = borrow_out("out", &arrs)?;
        let [wa, wv, wx, wu] = &mut ws[..] else {
            unreachable!()
        };
        let o = Out {
            a: wa.as_slice_mut()?,
            v: wv.as_slice_mut()?,
            x: wx.as_slice_mut()?,
            u: None,
        };
        let cmd = wu.as_slice_mut()?;
        let eff = EffectsRef {
            effects: &effs,
            exo: &ex,
        };
        py.detach(|| {
            guard(|| rollout::simulate_full_into(&lin, &eff, kind, u, dt, init, v0, x0, o))
        })?;
        cmd.copy_from_slice(u);
    }
    Ok(arrs.into())
}

/// Closed-loop car following behind a recorded leader (upper law Eq. 3), optionally
/// with effects: dict of arrays a, v, x, command (the caller's four `out` arrays
/// when given).
#[pyfunction]
#[pyo3(signature = (model, params, lead_x, lead_v, dt, kg, kv, tg, gmin, v0, x0, effects = Vec::new(), effect_params = Vec::new(), exo = Exo::new(), out = None))]
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
    effects: Vec<String>,
    effect_params: Vec<f64>,
    exo: Exo<'py>,
    out: Option<Bound<'py, PyAny>>,
) -> PyResult<Arrays4<'py, Ix1>> {
    let lin = linear(model, &params)?;
    let effs = effects_of(&effects, &effect_params, CommandKind::Acceleration)?;
    let up = Upper { kg, kv, tg, gmin };
    let lx = slice1("lead_x", &lead_x)?;
    let lv = slice1("lead_v", &lead_v)?;
    let ex = exo_slices(&exo)?;
    let arrs = four(py, out.as_ref(), lx.len())?;
    {
        let mut ws = borrow_out("out", &arrs)?;
        let [wa, wv, wx, wu] = &mut ws[..] else {
            unreachable!()
        };
        let o = Out {
            a: wa.as_slice_mut()?,
            v: wv.as_slice_mut()?,
            x: wx.as_slice_mut()?,
            u: Some(wu.as_slice_mut()?),
        };
        let eff = EffectsRef {
            effects: &effs,
            exo: &ex,
        };
        py.detach(|| guard(|| rollout::closed_loop_into(&lin, &eff, &up, lx, lv, dt, v0, x0, o)))?;
    }
    Ok(arrs.into())
}

/// Closed-loop car following under the synthetic generator's law with hidden
/// structures (`crate::sim::synth::Hidden`; `hidden` in `HiddenParams::NAMES` order)
/// and lower-level effects: a tuple of arrays a, v, x, command.
#[pyfunction]
#[pyo3(signature = (model, params, lead_x, lead_v, dt, kg, kv, tg, gmin, v0, x0, hidden, effects = Vec::new(), effect_params = Vec::new(), exo = Exo::new()))]
#[allow(clippy::too_many_arguments)]
fn synth_closed_loop<'py>(
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
    hidden: Vec<f64>,
    effects: Vec<String>,
    effect_params: Vec<f64>,
    exo: Exo<'py>,
) -> PyResult<Arrays4<'py, Ix1>> {
    let lin = linear(model, &params)?;
    let effs = effects_of(&effects, &effect_params, CommandKind::Acceleration)?;
    let up = Upper { kg, kv, tg, gmin };
    guard(|| up.validate())?;
    let hp = guard(|| crate::sim::synth::HiddenParams::from_slice(&hidden))?;
    let lx = slice1("lead_x", &lead_x)?;
    let lv = slice1("lead_v", &lead_v)?;
    let ex = exo_slices(&exo)?;
    let arrs = four(py, None, lx.len())?;
    {
        let mut ws = borrow_out("out", &arrs)?;
        let [wa, wv, wx, wu] = &mut ws[..] else {
            unreachable!()
        };
        let o = Out {
            a: wa.as_slice_mut()?,
            v: wv.as_slice_mut()?,
            x: wx.as_slice_mut()?,
            u: Some(wu.as_slice_mut()?),
        };
        let eff = EffectsRef {
            effects: &effs,
            exo: &ex,
        };
        let mut law = crate::sim::synth::Hidden::new(up, hp);
        py.detach(|| {
            guard(|| rollout::closed_loop_law_into(&lin, &eff, &mut law, lx, lv, dt, v0, x0, o))
        })?;
    }
    Ok(arrs.into())
}

/// Platoon of `followers` identical vehicles (time-major stepping): dict of
/// (followers, T) arrays a, v, x, command — transposed views of sample-major (T,
/// followers) arrays, the layout the stepping writes contiguously. `out`: four
/// C-contiguous (T, followers) arrays to write into instead (the transposes of the
/// arrays a platoon returns).
#[pyfunction]
#[pyo3(signature = (model, params, lead_x, lead_v, dt, kg, kv, tg, gmin, followers, effects = Vec::new(), effect_params = Vec::new(), exo = Exo::new(), out = None))]
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
    effects: Vec<String>,
    effect_params: Vec<f64>,
    exo: Exo<'py>,
    out: Option<Bound<'py, PyAny>>,
) -> PyResult<Arrays4<'py, Ix2>> {
    let lin = linear(model, &params)?;
    let effs = effects_of(&effects, &effect_params, CommandKind::Acceleration)?;
    let up = Upper { kg, kv, tg, gmin };
    let lx = slice1("lead_x", &lead_x)?;
    let lv = slice1("lead_v", &lead_v)?;
    let ex = exo_slices(&exo)?;
    // The blocks of `outbuf` are page-aligned: the lane groups' 32-byte stores into
    // rows of `followers` doubles then never straddle two cache lines needlessly.
    let arrs: [Bound<'py, PyArray2<f64>>; 4] = match &out {
        Some(o) => out_args::<Ix2, 4>("out", o, &[lx.len(), followers])?,
        None => std::array::from_fn(|_| outbuf::empty2(py, lx.len(), followers, true)),
    };
    {
        let mut ws = borrow_out("out", &arrs)?;
        let [wa, wv, wx, wu] = &mut ws[..] else {
            unreachable!()
        };
        let mut tm = TimeMajor {
            followers,
            a: wa.as_slice_mut()?,
            v: wv.as_slice_mut()?,
            x: wx.as_slice_mut()?,
            u: wu.as_slice_mut()?,
        };
        let eff = EffectsRef {
            effects: &effs,
            exo: &ex,
        };
        py.detach(|| guard(|| rollout::platoon_into(&lin, &eff, &up, lx, lv, dt, &mut tm)))?;
    }
    Ok(arrs.into())
}

/// Per-run costs (Eq. 6) of many parameter rows `[model | effects (canonical) | free
/// upper]` over a run set, in parallel: a (P, R) array; invalid or unstable rows
/// get `inf`.
#[pyfunction]
#[pyo3(signature = (model, params, runs, effects=Vec::new(), upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0), init="rest", closed_loop=false, threads=0, out=None))]
#[allow(clippy::too_many_arguments)]
fn batch_cost<'py>(
    py: Python<'py>,
    model: &str,
    params: PyReadonlyArray2<'py, f64>,
    runs: &Bound<'py, RunSet>,
    effects: Vec<String>,
    upper_free: Vec<usize>,
    command_kind: &str,
    weights: (f64, f64, f64),
    init: &str,
    closed_loop: bool,
    threads: usize,
    out: Option<Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let spec = cost_spec(
        model,
        &effects,
        upper_free,
        command_kind,
        weights,
        init,
        closed_loop,
    )?;
    let (p, rows) = spec_rows(&spec, &params)?;
    let rs = runs.get();
    let refs = rs.refs();
    let r = refs.len();
    let dst = match &out {
        Some(o) => Some(out_arg::<Ix2>("out", o, &[p, r])?),
        None => None,
    };
    let costs = py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || crate::sim::batch_cost(&spec, rows, &refs))?
        })
    })?;
    match dst {
        Some(d) => {
            // (P, R) values: the copy is negligible next to the P x R rollouts
            borrow_out("out", std::slice::from_ref(&d))?[0]
                .as_slice_mut()?
                .copy_from_slice(&costs);
            Ok(d)
        }
        None => costs.into_pyarray(py).reshape([p, r]),
    }
}

/// Simulated acceleration, speed and position of every parameter row on every run
/// of a run set, as the cost sees them: one (3, P, T) array (a, v, x; run `r` at
/// `runs.offsets[r]`); rows the cost calls invalid or unstable are NaN.
#[pyfunction]
#[pyo3(signature = (model, params, runs, effects=Vec::new(), upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0), init="rest", closed_loop=false, threads=0, out=None))]
#[allow(clippy::too_many_arguments)]
fn simulate_batch<'py>(
    py: Python<'py>,
    model: &str,
    params: PyReadonlyArray2<'py, f64>,
    runs: &Bound<'py, RunSet>,
    effects: Vec<String>,
    upper_free: Vec<usize>,
    command_kind: &str,
    weights: (f64, f64, f64),
    init: &str,
    closed_loop: bool,
    threads: usize,
    out: Option<Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let spec = cost_spec(
        model,
        &effects,
        upper_free,
        command_kind,
        weights,
        init,
        closed_loop,
    )?;
    let (p, rows) = spec_rows(&spec, &params)?;
    let rs = runs.get();
    let refs = rs.refs();
    let t = rs.len_total();
    // New arrays are uninitialised: `simulate_batch` writes every element (NaN for
    // invalid rows).
    let out: [Bound<'py, PyArray3<f64>>; 1] = match &out {
        Some(o) => [out_arg::<Ix3>("out", o, &[3, p, t])?],
        None => [outbuf::empty3(py, [3, p, t], false)],
    };
    {
        let mut w = borrow_out("out", &out)?;
        let s = w[0].as_slice_mut()?;
        let (a, rest) = s.split_at_mut(p * t);
        let (v, x) = rest.split_at_mut(p * t);
        py.detach(|| {
            guard(|| {
                crate::parallel::with_threads(threads, || {
                    crate::sim::cost::simulate_batch(&spec, rows, &refs, a, v, x)
                })?
            })
        })?;
    }
    let [arr] = out;
    Ok(arr)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(model_names, m)?)?;
    m.add_function(wrap_pyfunction!(model_params, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_full, m)?)?;
    m.add_function(wrap_pyfunction!(closed_loop, m)?)?;
    m.add_function(wrap_pyfunction!(platoon, m)?)?;
    m.add_function(wrap_pyfunction!(synth_closed_loop, m)?)?;
    m.add_function(wrap_pyfunction!(batch_cost, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_batch, m)?)?;
    Ok(())
}
