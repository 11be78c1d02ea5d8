//! Bindings of the stability engine (paper Section IV).

use super::{guard, slice1, try_filled};
use crate::model::ModelKind;
use crate::stability::boundary::{self, Axis, End, PointTest, Scan};
use crate::stability::delay::DelayLoop;
use crate::stability::threshold::{self, Range, Search};
use crate::stability::{grid, pade, LoopModel};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

/// Points per chunk between two GIL re-acquisitions (Ctrl-C check, progress).
const CHUNK: usize = 1 << 20;
/// Largest scan length along a searched axis: every boundary search holds `n_scan`
/// points and verdicts per thread (about 9 bytes each) and evaluates the test at each.
pub const MAX_SCAN: usize = 10_000_000;
/// Largest `n_grid` of an extremum search (a grid of `n_grid` points per dimension).
pub const MAX_GRID: usize = 100_000;

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
    let mut out = try_filled("stability_map: the map", total, 0u8)?;
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

/// The point test: Padé order `1..=10`, or 0 for the exact delay.
fn point_test(
    model: &str,
    params: &[f64],
    pade_order: usize,
    budget: usize,
) -> PyResult<Box<dyn PointTest>> {
    guard(|| {
        let lin = ModelKind::from_name(model)?.linear(params)?;
        Ok(if pade_order == 0 {
            let mut d = DelayLoop::new(&lin)?;
            d.budget = budget.max(1);
            Box::new(d) as Box<dyn PointTest>
        } else {
            Box::new(LoopModel::new(&lin, pade_order)?) as Box<dyn PointTest>
        })
    })
}

fn axis_of(axis: usize) -> PyResult<Axis> {
    Axis::from_index(axis)
        .ok_or_else(|| PyValueError::new_err(format!("axis: must be 0, 1 or 2, got {axis}")))
}

fn check_scan(lo: f64, hi: f64, n_scan: usize, log: bool, rtol: f64, level: u8) -> PyResult<Scan> {
    if !(lo.is_finite() && hi.is_finite() && lo < hi) {
        return Err(PyValueError::new_err(format!(
            "range: need finite lo < hi, got ({lo}, {hi})"
        )));
    }
    if log && lo <= 0.0 {
        return Err(PyValueError::new_err(format!(
            "range: a log-spaced scan needs lo > 0, got {lo}"
        )));
    }
    if !(2..=MAX_SCAN).contains(&n_scan) {
        return Err(PyValueError::new_err(format!(
            "n_scan: must be in 2..={MAX_SCAN}, got {n_scan}"
        )));
    }
    if !(rtol > 0.0 && rtol < 1.0) {
        return Err(PyValueError::new_err(format!(
            "rtol: must be in (0, 1), got {rtol}"
        )));
    }
    if !(1..=2).contains(&level) {
        return Err(PyValueError::new_err(format!(
            "level: must be 1 or 2, got {level}"
        )));
    }
    Ok(Scan {
        n: n_scan,
        log,
        rtol,
        level,
        candidates: true,
    })
}

/// Boundary surface: over the grid u × w of the two fixed parameters (in kg, Tg, kv
/// order), the infimum (`end = "inf"`) or supremum (`"sup"`) of the stable set along
/// `axis` (0 kg, 1 Tg, 2 kv) within [lo, hi]; NaN where no scan point is stable.
#[pyfunction]
#[pyo3(signature = (model, params, axis, u, w, lo, hi, end, pade_order = 2, level = 2, n_scan = 256, log = false, rtol = 1e-10, budget = 20000, threads = 0, progress = None))]
#[allow(clippy::too_many_arguments)]
fn stability_boundary<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    axis: usize,
    u: PyReadonlyArray1<'py, f64>,
    w: PyReadonlyArray1<'py, f64>,
    lo: f64,
    hi: f64,
    end: &str,
    pade_order: usize,
    level: u8,
    n_scan: usize,
    log: bool,
    rtol: f64,
    budget: usize,
    threads: usize,
    progress: Option<Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let test = point_test(model, &params, pade_order, budget)?;
    let axis = axis_of(axis)?;
    let scan = check_scan(lo, hi, n_scan, log, rtol, level)?;
    let end = match end {
        "inf" => End::Inf,
        "sup" => End::Sup,
        _ => {
            return Err(PyValueError::new_err(format!(
                "end: must be 'inf' or 'sup', got {end:?}"
            )))
        }
    };
    let (u, w) = (slice1("u", &u)?, slice1("w", &w)?);
    guard(|| {
        crate::error::check_series("u", u)?;
        crate::error::check_series("w", w)
    })?;
    let total = u.len().saturating_mul(w.len());
    let mut out = try_filled("stability_boundary: the boundary", total, f64::NAN)?;
    // rows per chunk: about 4096 boundary searches between Ctrl-C checks
    let rows = (4096 / w.len().max(1)).max(1);
    let mut r0 = 0;
    while r0 < u.len() {
        let r1 = (r0 + rows).min(u.len());
        let part = &mut out[r0 * w.len()..r1 * w.len()];
        let uu = &u[r0..r1];
        let t = &*test;
        py.detach(|| {
            guard(|| {
                crate::parallel::with_threads(threads, || {
                    boundary::surface(t, axis, uu, w, lo, hi, end, &scan, part)
                })
            })
        })?;
        r0 = r1;
        py.check_signals()?;
        if let Some(cb) = &progress {
            cb.call1((r0 * w.len(), total))?;
        }
    }
    out.into_pyarray(py).reshape([u.len(), w.len()])
}

/// The stable set along `axis` through `point` = [kg, tg, kv] within [lo, hi], as
/// (lo, hi, lo_is_range_end, hi_is_range_end) tuples.
#[pyfunction]
#[pyo3(signature = (model, params, axis, point, lo, hi, pade_order = 2, level = 2, n_scan = 256, log = false, rtol = 1e-10, budget = 20000))]
#[allow(clippy::too_many_arguments)]
fn stability_intervals(
    py: Python<'_>,
    model: &str,
    params: Vec<f64>,
    axis: usize,
    point: [f64; 3],
    lo: f64,
    hi: f64,
    pade_order: usize,
    level: u8,
    n_scan: usize,
    log: bool,
    rtol: f64,
    budget: usize,
) -> PyResult<Vec<(f64, f64, bool, bool)>> {
    let test = point_test(model, &params, pade_order, budget)?;
    let axis = axis_of(axis)?;
    let scan = check_scan(lo, hi, n_scan, log, rtol, level)?;
    guard(|| crate::error::check_series("point", &point))?;
    let t = &*test;
    let ivs =
        py.detach(|| guard(|| Ok(boundary::stable_intervals(t, axis, point, lo, hi, &scan))))?;
    Ok(ivs
        .into_iter()
        .map(|i| (i.lo, i.hi, i.lo_edge, i.hi_edge))
        .collect())
}

/// A point test that answers "unstable" at once after `stop` is set, so that a long
/// search winds down quickly when Ctrl-C arrives.
struct Cancellable<'a> {
    inner: &'a dyn PointTest,
    stop: &'a AtomicBool,
}

impl PointTest for Cancellable<'_> {
    fn code(&self, kg: f64, tg: f64, kv: f64) -> u8 {
        if self.stop.load(Ordering::Relaxed) {
            0
        } else {
            self.inner.code(kg, tg, kv)
        }
    }

    fn candidates(&self, axis: Axis, p: [f64; 3], lo: f64, hi: f64, out: &mut Vec<f64>) {
        if !self.stop.load(Ordering::Relaxed) {
            self.inner.candidates(axis, p, lo, hi, out);
        }
    }
}

/// Runs `work` on a scoped thread with the GIL released, checking for Ctrl-C every
/// 50 ms; on a signal, sets `stop`, waits for the work to wind down and returns the
/// signal's exception (KeyboardInterrupt).
fn run_interruptible<T: Send>(
    py: Python<'_>,
    stop: &AtomicBool,
    work: impl FnOnce() -> PyResult<T> + Send,
) -> PyResult<T> {
    py.detach(|| {
        std::thread::scope(|sc| {
            let h = sc.spawn(work);
            let mut interrupted = None;
            while !h.is_finished() {
                std::thread::sleep(std::time::Duration::from_millis(50));
                if interrupted.is_none() {
                    if let Err(e) = Python::attach(|py| py.check_signals()) {
                        stop.store(true, Ordering::Relaxed);
                        interrupted = Some(e);
                    }
                }
            }
            let out = h.join().unwrap_or_else(|_| {
                Err(pyo3::exceptions::PyRuntimeError::new_err(
                    "avll internal error (please report): search thread panicked",
                ))
            });
            match interrupted {
                Some(e) => Err(e),
                None => out,
            }
        })
    })
}

type ExtremumTuple = (f64, [f64; 3], bool, [bool; 2], usize);

/// Extremum of a boundary surface over a box: `which = "tg_min"` (infimum of the
/// stable Tg over the (kg, kv) box `r1 × r2`, Tg in `r3`) or `"kv_max"` (supremum of
/// the stable kv over the (kg, Tg) box `r1 × r2`, kv in `r3`). Ranges are
/// (lo, hi, log). Returns (value, [kg, tg, kv], value_at_range_end, on_box_edge, evaluations).
#[pyfunction]
#[pyo3(signature = (model, params, which, r1, r2, r3, pade_order = 2, n_scan = 256, rtol = 1e-10, n_grid = 32, starts = 3, xtol = 1e-12, budget = 20000, threads = 0))]
#[allow(clippy::too_many_arguments)]
fn stability_extremum(
    py: Python<'_>,
    model: &str,
    params: Vec<f64>,
    which: &str,
    r1: (f64, f64, bool),
    r2: (f64, f64, bool),
    r3: (f64, f64, bool),
    pade_order: usize,
    n_scan: usize,
    rtol: f64,
    n_grid: usize,
    starts: usize,
    xtol: f64,
    budget: usize,
    threads: usize,
) -> PyResult<ExtremumTuple> {
    let test = point_test(model, &params, pade_order, budget)?;
    let scan = check_scan(
        r3.0,
        r3.1.max(r3.0 + f64::MIN_POSITIVE),
        n_scan.max(2),
        r3.2,
        rtol,
        2,
    )?;
    if !(2..=MAX_GRID).contains(&n_grid) {
        return Err(PyValueError::new_err(format!(
            "n_grid: must be in 2..={MAX_GRID}, got {n_grid}"
        )));
    }
    if !(xtol > 0.0 && xtol < 1.0) {
        return Err(PyValueError::new_err(format!(
            "xtol: must be in (0, 1), got {xtol}"
        )));
    }
    let opt = Search {
        n_grid,
        starts: starts.max(1),
        xtol,
    };
    let rg = |r: (f64, f64, bool)| Range::new(r.0, r.1, r.2);
    if which != "tg_min" && which != "kv_max" {
        return Err(PyValueError::new_err(format!(
            "which: must be 'tg_min' or 'kv_max', got {which:?}"
        )));
    }
    let stop = AtomicBool::new(false);
    let t = Cancellable {
        inner: &*test,
        stop: &stop,
    };
    let work = || {
        guard(|| {
            crate::parallel::with_threads(threads, || {
                if which == "tg_min" {
                    threshold::min_stable_tg(&t, rg(r1), rg(r2), rg(r3), &scan, &opt)
                } else {
                    threshold::max_stable_kv(&t, rg(r1), rg(r2), rg(r3), &scan, &opt)
                }
            })?
        })
    };
    let e = run_interruptible(py, &stop, work)?;
    Ok((
        e.value,
        e.at,
        e.value_at_range_end,
        e.on_box_edge,
        e.evaluations,
    ))
}

/// The kv beyond which no point of the kg × tg grid is stable (bisection in Rust
/// with an early-exit "is anything stable" test).
#[pyfunction]
#[pyo3(signature = (model, params, kg, tg, kv_lo, kv_hi, pade_order = 2, tol = 1e-5, budget = 20000, threads = 0))]
#[allow(clippy::too_many_arguments)]
fn kv_threshold_grid<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    kg: PyReadonlyArray1<'py, f64>,
    tg: PyReadonlyArray1<'py, f64>,
    kv_lo: f64,
    kv_hi: f64,
    pade_order: usize,
    tol: f64,
    budget: usize,
    threads: usize,
) -> PyResult<f64> {
    let test = point_test(model, &params, pade_order, budget)?;
    let (kg, tg) = (slice1("kg", &kg)?, slice1("tg", &tg)?);
    guard(|| {
        grid::Axes::new(kg, tg, &[0.0])?;
        crate::error::check_finite("kv_lo", kv_lo)?;
        crate::error::check_finite("kv_hi", kv_hi)
    })?;
    let t = &*test;
    py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || {
                threshold::kv_threshold_grid(t, kg, tg, kv_lo, kv_hi, tol)
            })?
        })
    })
}

/// An exact-delay loop with its scattered points kg, tg, kv.
type DelayPoints<'a> = (DelayLoop, &'a [f64], &'a [f64], &'a [f64]);

/// The exact-delay loop of a model and its scattered points (kg, tg, kv of one length,
/// finite), shared by the point-wise exact-delay bindings.
fn delay_points_setup<'a>(
    model: &str,
    params: &[f64],
    kg: &'a PyReadonlyArray1<'_, f64>,
    tg: &'a PyReadonlyArray1<'_, f64>,
    kv: &'a PyReadonlyArray1<'_, f64>,
    budget: usize,
) -> PyResult<DelayPoints<'a>> {
    let mut dl = guard(|| DelayLoop::new(&ModelKind::from_name(model)?.linear(params)?))?;
    dl.budget = budget.max(1);
    let (kg, tg, kv) = (slice1("kg", kg)?, slice1("tg", tg)?, slice1("kv", kv)?);
    if tg.len() != kg.len() || kv.len() != kg.len() {
        return Err(PyValueError::new_err(format!(
            "tg: kg, tg and kv must have one length, got {}, {}, {}",
            kg.len(),
            tg.len(),
            kv.len()
        )));
    }
    guard(|| {
        crate::error::check_series("kg", kg)?;
        crate::error::check_series("tg", tg)?;
        crate::error::check_series("kv", kv)
    })?;
    Ok((dl, kg, tg, kv))
}

/// Exact-delay codes of scattered points and whether each is certified.
#[pyfunction]
#[pyo3(signature = (model, params, kg, tg, kv, budget = 20000, threads = 0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn delay_points<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    kg: PyReadonlyArray1<'py, f64>,
    tg: PyReadonlyArray1<'py, f64>,
    kv: PyReadonlyArray1<'py, f64>,
    budget: usize,
    threads: usize,
) -> PyResult<(Bound<'py, PyArray1<u8>>, Bound<'py, PyArray1<bool>>)> {
    let (dl, kg, tg, kv) = delay_points_setup(model, &params, &kg, &tg, &kv, budget)?;
    let n = kg.len();
    let mut codes = try_filled("delay_points: the codes", n, 0u8)?;
    let mut ok = try_filled("delay_points: the flags", n, false)?;
    let chunk = 4096;
    let mut s = 0;
    while s < n {
        let e = (s + chunk).min(n);
        let (c, o) = (&mut codes[s..e], &mut ok[s..e]);
        let (a, b, d) = (&kg[s..e], &tg[s..e], &kv[s..e]);
        py.detach(|| {
            guard(|| {
                crate::parallel::with_threads(threads, || {
                    crate::stability::delay::classify_points(&dl, a, b, d, c, o)
                })
            })
        })?;
        s = e;
        py.check_signals()?;
    }
    Ok((codes.into_pyarray(py), ok.into_pyarray(py)))
}

/// Sampled exact-delay string margin min (1 − |H(jω)|²)/ω² (s²) at scattered points.
#[pyfunction]
#[pyo3(signature = (model, params, kg, tg, kv, w_min, w_max, n_w, xtol = 1e-9, threads = 0))]
#[allow(clippy::too_many_arguments)]
fn delay_margin<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    kg: PyReadonlyArray1<'py, f64>,
    tg: PyReadonlyArray1<'py, f64>,
    kv: PyReadonlyArray1<'py, f64>,
    w_min: f64,
    w_max: f64,
    n_w: usize,
    xtol: f64,
    threads: usize,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    use rayon::prelude::*;
    let dl = guard(|| DelayLoop::new(&ModelKind::from_name(model)?.linear(&params)?))?;
    let (kg, tg, kv) = (slice1("kg", &kg)?, slice1("tg", &tg)?, slice1("kv", &kv)?);
    if tg.len() != kg.len() || kv.len() != kg.len() {
        return Err(PyValueError::new_err(
            "tg: kg, tg and kv must have one length",
        ));
    }
    if !(w_min > 0.0 && w_max > w_min && w_max.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "w_min, w_max: need 0 < w_min < w_max, got {w_min}, {w_max}"
        )));
    }
    if xtol.is_nan() || xtol <= 0.0 {
        return Err(PyValueError::new_err(format!(
            "xtol: must be > 0, got {xtol}"
        )));
    }
    if !(2..=MAX_SCAN).contains(&n_w) {
        return Err(PyValueError::new_err(format!(
            "n_w: must be in 2..={MAX_SCAN}, got {n_w}"
        )));
    }
    let mut out = try_filled("delay_margin: the margins", kg.len(), 0.0)?;
    py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || {
                out.par_iter_mut().enumerate().for_each(|(i, o)| {
                    *o = dl.margin(kg[i], tg[i], kv[i], w_min, w_max, n_w, xtol);
                })
            })
        })
    })?;
    Ok(out.into_pyarray(py))
}

/// Certified exact-delay string test alone (|H(jω)| < 1 for all ω > 0), whatever the
/// local verdict: (stable, certified) per point.
#[pyfunction]
#[pyo3(signature = (model, params, kg, tg, kv, budget = 20000, threads = 0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn delay_string<'py>(
    py: Python<'py>,
    model: &str,
    params: Vec<f64>,
    kg: PyReadonlyArray1<'py, f64>,
    tg: PyReadonlyArray1<'py, f64>,
    kv: PyReadonlyArray1<'py, f64>,
    budget: usize,
    threads: usize,
) -> PyResult<(Bound<'py, PyArray1<bool>>, Bound<'py, PyArray1<bool>>)> {
    use crate::stability::delay::Verdict;
    use rayon::prelude::*;
    let (dl, kg, tg, kv) = delay_points_setup(model, &params, &kg, &tg, &kv, budget)?;
    let v: Vec<Verdict> = py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || {
                (0..kg.len())
                    .into_par_iter()
                    .map(|i| dl.string(kg[i], tg[i], kv[i]))
                    .collect()
            })
        })
    })?;
    let st: Vec<bool> = v.iter().map(|&x| x == Verdict::Stable).collect();
    let ok: Vec<bool> = v.iter().map(|&x| x != Verdict::Undecided).collect();
    Ok((st.into_pyarray(py), ok.into_pyarray(py)))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("PADE_MAX_ORDER", pade::MAX_ORDER)?;
    m.add("MAX_SCAN", MAX_SCAN)?;
    m.add("MAX_GRID", MAX_GRID)?;
    m.add_function(wrap_pyfunction!(stability_map, m)?)?;
    m.add_function(wrap_pyfunction!(stability_points, m)?)?;
    m.add_function(wrap_pyfunction!(stability_polys, m)?)?;
    m.add_function(wrap_pyfunction!(pade_den, m)?)?;
    m.add_function(wrap_pyfunction!(stability_boundary, m)?)?;
    m.add_function(wrap_pyfunction!(stability_intervals, m)?)?;
    m.add_function(wrap_pyfunction!(stability_extremum, m)?)?;
    m.add_function(wrap_pyfunction!(kv_threshold_grid, m)?)?;
    m.add_function(wrap_pyfunction!(delay_points, m)?)?;
    m.add_function(wrap_pyfunction!(delay_margin, m)?)?;
    m.add_function(wrap_pyfunction!(delay_string, m)?)?;
    Ok(())
}
