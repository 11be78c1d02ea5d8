//! Bindings of the models, rollouts, batched costs and batched simulation (every
//! rollout runs on the one kernel, `crate::sim`).

use super::effects::{effects_of, Exo};
use super::runs::RunSet;
use super::{guard, slice1, slice2};
use crate::effects::{AnyEffect, EffectList};
use crate::model::{CommandKind, Linear, ModelKind};
use crate::sim::rollout::{self, EffectsRef, Out, TimeMajor};
use crate::sim::{CostSpec, Init, Upper};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

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
    // SAFETY: uninitialised (no page-zeroing pass); `simulate_into` writes every
    // element before Python can see the array, and on an error it is dropped unseen.
    let y = unsafe { PyArray1::<f64>::new(py, u.len(), false) };
    {
        let mut w = y.readwrite();
        let out = w.as_slice_mut()?;
        py.detach(|| guard(|| rollout::simulate_into(&lin, u, dt, init, out)))?;
    }
    Ok(y)
}

/// Four new (rows, T) arrays a, v, x, command.
type Arrays<'py> = [Bound<'py, PyArray2<f64>>; 4];

/// Four new uninitialised (rows, T) arrays for the rollouts to fill.
///
/// Allocating through numpy without zeroing avoids a page-zeroing pass over every
/// output (the first version spent up to half of a long rollout page-faulting fresh
/// zeroed buffers). Every rollout that receives them writes each element (NaN after
/// a divergence) before returning, and an error drops them unseen.
fn arrays<'py>(py: Python<'py>, rows: usize, t: usize) -> Arrays<'py> {
    // SAFETY: see above: fully written before Python sees them.
    std::array::from_fn(|_| unsafe { PyArray2::<f64>::new(py, [rows, t], false) })
}

/// [`arrays`] starting on a 64-byte boundary (a cache line): views into numpy
/// arrays 8 elements longer (the 8 spare elements zeroed). The platoon's lane
/// groups store 4 doubles (32 bytes) at a time into rows of `followers` doubles;
/// from malloc's 16-byte alignment, every other such store would straddle two
/// cache lines.
fn aligned_arrays<'py>(py: Python<'py>, rows: usize, t: usize) -> PyResult<Arrays<'py>> {
    let n = rows * t;
    let one = || -> PyResult<Bound<'py, PyArray2<f64>>> {
        // SAFETY: the spare elements are zeroed below, the view is fully written
        // before Python sees it (as `arrays`).
        let base = unsafe { PyArray1::<f64>::new(py, n + 8, false) };
        let k = {
            let mut w = base.readwrite();
            let s = w.as_slice_mut()?;
            let k = s.as_ptr().align_offset(64).min(8);
            s[..k].fill(0.0);
            s[k + n..].fill(0.0);
            k
        };
        let view = base.get_item(pyo3::types::PySlice::new(
            py,
            k as isize,
            (k + n) as isize,
            1,
        ))?;
        let view = view.cast_into::<PyArray1<f64>>()?;
        view.reshape([rows, t])
    };
    Ok([one()?, one()?, one()?, one()?])
}

fn dict_of<'py>(py: Python<'py>, arrs: Arrays<'py>, flat: bool) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (k, a) in ["a", "v", "x", "command"].into_iter().zip(arrs) {
        if flat {
            let n = a.len();
            d.set_item(k, a.reshape([n; 1])?)?;
        } else {
            d.set_item(k, a)?;
        }
    }
    Ok(d)
}

/// Runs `f` on mutable row slices of the four arrays (one `Out` per row).
fn with_outs<R>(arrs: &Arrays<'_>, f: impl FnOnce(&mut [Out]) -> R) -> PyResult<R> {
    let mut ws: Vec<_> = arrs.iter().map(|a| a.readwrite()).collect();
    let [wa, wv, wx, wu] = &mut ws[..] else {
        unreachable!()
    };
    let (sa, sv, sx, su) = (
        wa.as_slice_mut()?,
        wv.as_slice_mut()?,
        wx.as_slice_mut()?,
        wu.as_slice_mut()?,
    );
    let rows = arrs[0].shape()[0];
    let t = arrs[0].shape()[1];
    let mut outs: Vec<Out> = if t == 0 {
        (0..rows)
            .map(|_| Out {
                a: &mut [],
                v: &mut [],
                x: &mut [],
                u: None,
            })
            .collect()
    } else {
        sa.chunks_mut(t)
            .zip(sv.chunks_mut(t))
            .zip(sx.chunks_mut(t))
            .zip(su.chunks_mut(t))
            .map(|(((a, v), x), u)| Out {
                a,
                v,
                x,
                u: Some(u),
            })
            .collect()
    };
    Ok(f(&mut outs))
}

fn exo_slices<'a>(exo: &'a Exo<'_>) -> PyResult<Vec<(&'a str, &'a [f64])>> {
    exo.iter()
        .map(|(k, v)| Ok((k.as_str(), slice1(&format!("exo[{k:?}]"), v)?)))
        .collect()
}

/// Open-loop rollout with speed and position (optionally with effects): dict of
/// arrays a, v, x, command.
#[pyfunction]
#[pyo3(signature = (model, params, command, dt, command_kind = "acceleration", init = "rest", v0 = 0.0, x0 = 0.0, effects = Vec::new(), effect_params = Vec::new(), exo = Exo::new()))]
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
) -> PyResult<Bound<'py, PyDict>> {
    let kind = guard(|| CommandKind::from_name(command_kind))?;
    let init = guard(|| Init::from_name(init))?;
    let lin = linear(model, &params)?;
    let effs: Vec<AnyEffect> = effects_of(&effects, &effect_params, kind)?;
    let u = slice1("command", &command)?;
    let ex = exo_slices(&exo)?;
    let arrs = arrays(py, 1, u.len());
    with_outs(&arrs, |outs| {
        let o = outs.iter_mut().next().map(|o| Out {
            a: &mut *o.a,
            v: &mut *o.v,
            x: &mut *o.x,
            u: None,
        });
        let eff = EffectsRef {
            effects: &effs,
            exo: &ex,
        };
        py.detach(|| {
            guard(|| match o {
                Some(o) => rollout::simulate_full_into(&lin, &eff, kind, u, dt, init, v0, x0, o),
                None => Ok(()),
            })
        })
    })??;
    let d = dict_of(py, arrs, true)?;
    d.set_item("command", u.to_vec().into_pyarray(py))?;
    Ok(d)
}

/// Closed-loop car following behind a recorded leader (upper law Eq. 3), optionally
/// with effects: dict of arrays a, v, x, command.
#[pyfunction]
#[pyo3(signature = (model, params, lead_x, lead_v, dt, kg, kv, tg, gmin, v0, x0, effects = Vec::new(), effect_params = Vec::new(), exo = Exo::new()))]
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
) -> PyResult<Bound<'py, PyDict>> {
    let lin = linear(model, &params)?;
    let effs = effects_of(&effects, &effect_params, CommandKind::Acceleration)?;
    let up = Upper { kg, kv, tg, gmin };
    let lx = slice1("lead_x", &lead_x)?;
    let lv = slice1("lead_v", &lead_v)?;
    let ex = exo_slices(&exo)?;
    let arrs = arrays(py, 1, lx.len());
    with_outs(&arrs, |outs| {
        let eff = EffectsRef {
            effects: &effs,
            exo: &ex,
        };
        py.detach(|| {
            guard(|| match outs.iter_mut().next() {
                Some(o) => rollout::closed_loop_into(
                    &lin,
                    &eff,
                    &up,
                    lx,
                    lv,
                    dt,
                    v0,
                    x0,
                    Out {
                        a: &mut *o.a,
                        v: &mut *o.v,
                        x: &mut *o.x,
                        u: o.u.as_deref_mut(),
                    },
                ),
                None => Ok(()),
            })
        })
    })??;
    dict_of(py, arrs, true)
}

/// Platoon of `followers` identical vehicles (time-major stepping): dict of
/// (followers, T) arrays a, v, x, command — transposed views of sample-major (T,
/// followers) arrays, the layout the stepping writes contiguously.
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
    let arrs = aligned_arrays(py, lx.len(), followers)?;
    {
        let mut ws: Vec<_> = arrs.iter().map(|a| a.readwrite()).collect();
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
        py.detach(|| {
            guard(|| rollout::platoon_into(&lin, &EffectsRef::NONE, &up, lx, lv, dt, &mut tm))
        })?;
    }
    let d = PyDict::new(py);
    for (k, a) in ["a", "v", "x", "command"].into_iter().zip(arrs) {
        d.set_item(k, a.as_any().getattr("T")?)?;
    }
    Ok(d)
}

/// Per-run costs (Eq. 6) of many parameter rows `[model | effects (canonical) | free
/// upper]` over a run set, in parallel: a (P, R) array; invalid or unstable rows
/// get `inf`.
#[pyfunction]
#[pyo3(signature = (model, params, runs, effects=Vec::new(), upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0), init="rest", closed_loop=false, threads=0))]
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
    let out = py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || crate::sim::batch_cost(&spec, rows, &refs))?
        })
    })?;
    out.into_pyarray(py).reshape([p, r])
}

/// Simulated acceleration, speed and position of every parameter row on every run
/// of a run set, as the cost sees them: dict of (P, T) arrays a, v, x (run `r` at
/// `runs.offsets[r]`); rows the cost calls invalid or unstable are NaN.
#[pyfunction]
#[pyo3(signature = (model, params, runs, effects=Vec::new(), upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0), init="rest", closed_loop=false, threads=0))]
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
) -> PyResult<Bound<'py, PyDict>> {
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
    // SAFETY: `simulate_batch` writes every element (NaN for invalid rows).
    let out: [Bound<'py, PyArray3<f64>>; 1] =
        [unsafe { PyArray3::<f64>::new(py, [3, p, t], false) }];
    {
        let mut w = out[0].readwrite();
        let s = w.as_slice_mut()?;
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
    let d = PyDict::new(py);
    let [arr] = out;
    for (i, k) in ["a", "v", "x"].into_iter().enumerate() {
        d.set_item(k, arr.as_any().get_item(i)?)?;
    }
    Ok(d)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(model_names, m)?)?;
    m.add_function(wrap_pyfunction!(model_params, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_full, m)?)?;
    m.add_function(wrap_pyfunction!(closed_loop, m)?)?;
    m.add_function(wrap_pyfunction!(platoon, m)?)?;
    m.add_function(wrap_pyfunction!(batch_cost, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_batch, m)?)?;
    Ok(())
}
