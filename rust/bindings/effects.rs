//! Bindings of the effects library: the registry and the linearisation (rollouts,
//! costs and calibration with effects go through the common bindings).

use super::guard;
use crate::effects::{AnyEffect, EffectKind, EffectList, Operating};
use crate::model::{CommandKind, ModelKind};
use crate::sim::Upper;
use numpy::{Complex64, IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::collections::BTreeMap;

/// Exogenous series by name.
pub(super) type Exo<'py> = BTreeMap<String, PyReadonlyArray1<'py, f64>>;

/// The effect instances of `effects` (any order) with their parameters in the same
/// order, validated, in the canonical order.
pub(super) fn effects_of(
    effects: &[String],
    effect_params: &[f64],
    kind: CommandKind,
) -> PyResult<Vec<AnyEffect>> {
    guard(|| {
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
        list.build(&p, kind)
    })
}

/// The registered effects in the canonical order: name, params, bounds, neutral
/// values, exo, accel_only, needs_speed, level (`"lower"`/`"upper"`), excludes.
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
            d.set_item("needs_speed", k.needs_speed())?;
            d.set_item("level", k.level().name())?;
            d.set_item("excludes", k.excludes())?;
            Ok(d)
        })
        .collect()
}

/// The small-signal `Linear` of base + effects at speed `v` on `side` (1 accel,
/// -1 braking, 0 average): dict b1, b0, a2, a1, Td, K. With `terms`, effects whose
/// small-signal content lies outside a `Linear` do not fail: the dict adds
/// `speed_feedback` (1/s), `obs_tau` (s) and `obs_bias` (m/s²), see
/// `crate::effects::Terms`.
#[pyfunction]
#[pyo3(signature = (model, params, effects, effect_params, v = 0.0, side = 0, command_kind = "acceleration", terms = false))]
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
    terms: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let kind = guard(|| CommandKind::from_name(command_kind))?;
    let lin = guard(|| ModelKind::from_name(model)?.linear(&params))?;
    let effs = effects_of(&effects, &effect_params, kind)?;
    let op = Operating { v, side };
    let (l, t) = if terms {
        let (l, t) = guard(|| crate::effects::linearize_terms(&lin, &effs, &op))?;
        (l, Some(t))
    } else {
        (guard(|| crate::effects::linearize(&lin, &effs, &op))?, None)
    };
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
    if let Some(t) = t {
        d.set_item("speed_feedback", t.speed_feedback)?;
        d.set_item("obs_tau", t.obs_tau)?;
        d.set_item("obs_bias", t.obs_bias)?;
        d.set_item("command_delay", t.command_delay)?;
    }
    Ok(d)
}

/// The small-signal form of the upper level (kg, kv, Tg, Gmin) with the upper-level
/// effects among `effects` at speed `v`: dict kg, kv, Tg (the small-signal time gap),
/// Tg_eq (the equilibrium's), Gmin, delay, ff_gain, ff_tau
/// (`crate::effects::UpperLin`).
#[pyfunction]
#[pyo3(signature = (effects, effect_params, kg, kv, tg, gmin, v = 0.0))]
#[allow(clippy::too_many_arguments)]
fn linearize_upper<'py>(
    py: Python<'py>,
    effects: Vec<String>,
    effect_params: Vec<f64>,
    kg: f64,
    kv: f64,
    tg: f64,
    gmin: f64,
    v: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let effs = effects_of(&effects, &effect_params, CommandKind::Acceleration)?;
    let up = Upper { kg, kv, tg, gmin };
    guard(|| up.validate())?;
    let op = Operating { v, side: 0 };
    let u = guard(|| crate::effects::linearize_upper(&up, &effs, &op))?;
    let d = PyDict::new(py);
    for (k, x) in [
        ("kg", u.kg),
        ("kv", u.kv),
        ("Tg", u.tg),
        ("Tg_eq", u.tg_eq),
        ("Gmin", u.gmin),
        ("delay", u.delay),
        ("ff_gain", u.ff_gain),
        ("ff_tau", u.ff_tau),
    ] {
        d.set_item(k, x)?;
    }
    Ok(d)
}

/// The follower's exact frequency response `H(j omega)` (predecessor speed to
/// follower speed; `crate::effects::response`) of base + effects (both levels) under
/// the law (kg, kv, tg, gmin), linearised at speed `v` on `side`: a complex array.
#[pyfunction]
#[pyo3(signature = (model, params, effects, effect_params, kg, kv, tg, gmin, omega, v = 0.0, side = 0, hold = 0.0))]
#[allow(clippy::too_many_arguments)]
fn follower_response<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    effects: Vec<String>,
    effect_params: Vec<f64>,
    kg: f64,
    kv: f64,
    tg: f64,
    gmin: f64,
    omega: PyReadonlyArray1<'py, f64>,
    v: f64,
    side: i8,
    hold: f64,
) -> PyResult<Bound<'py, PyArray1<Complex64>>> {
    guard(|| crate::error::check_nonneg("hold", hold))?;
    let lin = guard(|| ModelKind::from_name(model)?.linear(&params))?;
    let effs = effects_of(&effects, &effect_params, CommandKind::Acceleration)?;
    let up = Upper { kg, kv, tg, gmin };
    guard(|| up.validate())?;
    let w = super::slice1("omega", &omega)?;
    if let Some(x) = w.iter().find(|x| !(x.is_finite() && **x > 0.0)) {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "omega: frequencies must be finite and > 0, got {x}"
        )));
    }
    let op = Operating { v, side };
    let (l, t) = guard(|| crate::effects::linearize_terms(&lin, &effs, &op))?;
    let l = crate::effects::held(l, hold);
    let u = guard(|| crate::effects::linearize_upper(&up, &effs, &op))?;
    let h: Vec<Complex64> = py.detach(|| {
        w.iter()
            .map(|&x| crate::effects::response(&l, &t, &u, x))
            .collect()
    });
    Ok(h.into_pyarray(py))
}

/// The follower's exact frequency response of many parameter rows (`n x d`: `[model |
/// effects | kg, kv, Tg, Gmin]`, the effects' parameters in their canonical order) at
/// the frequencies `omega` (rad/s), linearised at speed `v` on `side`
/// (`crate::effects::response_rows`): a complex `n x len(omega)` array, NaN rows where
/// a row's parameters are refused or have no small-signal form. In parallel over rows.
#[pyfunction]
#[pyo3(signature = (model, rows, effects, omega, v = 0.0, side = 0, command_kind = "acceleration", threads = 0, hold = 0.0))]
#[allow(clippy::too_many_arguments)]
fn follower_response_rows<'py>(
    py: Python<'py>,
    model: &str,
    rows: PyReadonlyArray2<'py, f64>,
    effects: Vec<String>,
    omega: PyReadonlyArray1<'py, f64>,
    v: f64,
    side: i8,
    command_kind: &str,
    threads: usize,
    hold: f64,
) -> PyResult<Bound<'py, PyArray2<Complex64>>> {
    let kind = guard(|| CommandKind::from_name(command_kind))?;
    let mk = guard(|| ModelKind::from_name(model))?;
    let list = canonical_list(&effects, kind)?;
    guard(|| crate::error::check_finite("v", v))?;
    let (n, d, data) = super::slice2("rows", &rows)?;
    let w = super::slice1("omega", &omega)?;
    let op = Operating { v, side };
    let h = py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || {
                crate::effects::response_rows(mk, &list, kind, data, d, w, &op, hold)
            })?
        })
    })?;
    let arr = numpy::ndarray::Array2::from_shape_vec((n, w.len()), h)
        .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))?;
    Ok(arr.into_pyarray(py))
}

/// The list of `effects`, refused unless given in their canonical order (the order of
/// the parameter rows' columns).
fn canonical_list(effects: &[String], kind: CommandKind) -> PyResult<EffectList> {
    let names: Vec<&str> = effects.iter().map(|s| s.as_str()).collect();
    let list = guard(|| EffectList::from_names(&names, kind))?;
    if list.0.iter().map(|k| k.name()).ne(names.iter().copied()) {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "effects: give them in their canonical order ({}), got {}",
            list.0
                .iter()
                .map(|k| k.name())
                .collect::<Vec<_>>()
                .join(", "),
            names.join(", ")
        )));
    }
    Ok(list)
}

/// Certified stability codes (0 locally unstable, 1 string unstable, 2 string stable)
/// and their certification flags of many parameter rows (`n x d`: `[model | effects |
/// kg, kv, Tg, Gmin]`) linearised at speed `v` on `side`, every delay kept exactly
/// (`crate::effects::follower`). In parallel over rows.
#[pyfunction]
#[pyo3(signature = (model, rows, effects, v = 0.0, side = 0, command_kind = "acceleration", budget = 20000, threads = 0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn follower_codes_rows<'py>(
    py: Python<'py>,
    model: &str,
    rows: PyReadonlyArray2<'py, f64>,
    effects: Vec<String>,
    v: f64,
    side: i8,
    command_kind: &str,
    budget: usize,
    threads: usize,
) -> PyResult<(Bound<'py, PyArray1<u8>>, Bound<'py, PyArray1<bool>>)> {
    let kind = guard(|| CommandKind::from_name(command_kind))?;
    let mk = guard(|| ModelKind::from_name(model))?;
    let list = canonical_list(&effects, kind)?;
    guard(|| crate::error::check_finite("v", v))?;
    let (_, d, data) = super::slice2("rows", &rows)?;
    let out = py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || {
                crate::effects::codes_rows(mk, &list, kind, data, d, &Operating { v, side }, budget)
            })?
        })
    })?;
    let (c, ok): (Vec<u8>, Vec<bool>) = out.into_iter().unzip();
    Ok((c.into_pyarray(py), ok.into_pyarray(py)))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(follower_codes_rows, m)?)?;
    m.add_function(wrap_pyfunction!(follower_response_rows, m)?)?;
    m.add_function(wrap_pyfunction!(effect_info, m)?)?;
    m.add_function(wrap_pyfunction!(linearize_effects, m)?)?;
    m.add_function(wrap_pyfunction!(linearize_upper, m)?)?;
    m.add_function(wrap_pyfunction!(follower_response, m)?)?;
    Ok(())
}
