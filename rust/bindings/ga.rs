//! The one calibration binding (`avll.calibrate`, `avll.calibrate_many`,
//! `avll.bootstrap` and the diagnosis use it), with its progress and Ctrl-C path.
//!
//! The GA runs on a worker of the requested rayon pool (the global one for
//! `threads = 0`: `parallel::on_worker`), started from a scoped thread, with the
//! GIL released; the calling thread waits for per-generation progress messages and,
//! for each batch of them, re-takes the GIL, calls `py.check_signals()` (Ctrl-C)
//! and the optional Python progress callable. Ctrl-C sets a stop flag that every
//! problem sees at its next generation; the results are then the best so far,
//! flagged `interrupted`.

use super::rollout::cost_spec;
use super::runs::RunSet;
use super::{guard, slice2};
use crate::ga::{self, Bounds, GaOptions, Phase, Scale, StopReason};
use crate::optimize::calibrate::Calibration;
use numpy::{IntoPyArray, PyReadonlyArray2};
use pyo3::exceptions::{PyKeyboardInterrupt, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

enum Msg {
    Progress {
        problem: usize,
        phase: Phase,
        iteration: usize,
        evaluations: usize,
        best: f64,
    },
    /// A resample refit finished: `done` of the problem's `total`.
    Resample {
        problem: usize,
        done: usize,
        total: usize,
    },
    Done,
}

impl Msg {
    /// The dict the Python progress callable receives.
    fn info<'py>(&self, py: Python<'py>, n_problems: usize) -> PyResult<Bound<'py, PyDict>> {
        let info = PyDict::new(py);
        match *self {
            Msg::Progress {
                problem,
                phase,
                iteration,
                evaluations,
                best,
            } => {
                info.set_item("problem", problem)?;
                info.set_item("phase", if phase == Phase::Ga { "ga" } else { "polish" })?;
                info.set_item("iteration", iteration)?;
                info.set_item("evaluations", evaluations)?;
                info.set_item("best", best)?;
            }
            Msg::Resample {
                problem,
                done,
                total,
            } => {
                info.set_item("problem", problem)?;
                info.set_item("phase", "resample")?;
                info.set_item("done", done)?;
                info.set_item("total", total)?;
            }
            Msg::Done => {}
        }
        info.set_item("problems", n_problems)?;
        Ok(info)
    }
}

fn result_dict<'py>(
    py: Python<'py>,
    c: Calibration,
    by_user: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let r = c.ga;
    let d = PyDict::new(py);
    // A callback stop is the user's (Ctrl-C or the progress callback's
    // KeyboardInterrupt); any other error of the callback is raised instead.
    let interrupted = r.stop == StopReason::Callback && by_user;
    let stop = r.stop.name();
    d.set_item("x", r.x.into_pyarray(py))?;
    d.set_item("f", r.f)?;
    d.set_item("f_ga", r.f_ga)?;
    d.set_item("generations", r.generations)?;
    d.set_item("evaluations", r.evaluations)?;
    d.set_item("stop", stop)?;
    d.set_item("interrupted", interrupted)?;
    d.set_item("history", r.history.into_pyarray(py))?;
    let (idx, cost): (Vec<usize>, Vec<f64>) = c.per_run.into_iter().unzip();
    d.set_item("per_run_index", idx)?;
    d.set_item("per_run_cost", cost.into_pyarray(py))?;
    Ok(d)
}

/// The tunable GA options (every field of `GaOptions` except `seed`, `target` and
/// `initial`, which `calibrate` takes as arguments of their own) with their values:
/// the one list Python's `avll.defaults.GA_OPTIONS` is read from.
fn tunable<'py>(py: Python<'py>, o: &GaOptions) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("pop_size", o.pop_size)?;
    d.set_item("max_generations", o.max_generations)?;
    d.set_item("stall_generations", o.stall_generations)?;
    d.set_item("ftol", o.ftol)?;
    d.set_item("xtol", o.xtol)?;
    d.set_item("tournament", o.tournament)?;
    d.set_item("crossover_prob", o.crossover_prob)?;
    d.set_item("eta_c", o.eta_c)?;
    d.set_item("mutation_prob", o.mutation_prob)?;
    d.set_item("eta_m", o.eta_m)?;
    d.set_item("plus", o.plus)?;
    d.set_item("elite", o.elite)?;
    d.set_item("polish", o.polish)?;
    d.set_item("polish_max_evals", o.polish_max_evals)?;
    d.set_item("local_every", o.local_every)?;
    d.set_item("local_evals", o.local_evals)?;
    Ok(d)
}

/// A count option: a Python or numpy integer >= 0 (`bool` and `1.5` are refused).
fn count(key: &str, v: &Bound<'_, PyAny>) -> PyResult<usize> {
    if v.is_instance_of::<PyBool>() || !v.hasattr("__index__")? {
        return Err(PyTypeError::new_err(format!(
            "{key}: must be an integer, got {}",
            v.repr()?
        )));
    }
    v.extract().map_err(|_| {
        PyValueError::new_err(format!(
            "{key}: must be an integer in 0..={}, got {}",
            usize::MAX,
            v.repr().map(|r| r.to_string()).unwrap_or_default()
        ))
    })
}

/// A real option (`bool`, `None` and strings are refused; the ranges are checked by
/// `GaOptions::validate`).
fn real(key: &str, v: &Bound<'_, PyAny>) -> PyResult<f64> {
    if v.is_instance_of::<PyBool>() {
        return Err(PyTypeError::new_err(format!(
            "{key}: must be a number, got {}",
            v.repr()?
        )));
    }
    v.extract().map_err(|_| {
        PyTypeError::new_err(format!(
            "{key}: must be a number, got {}",
            v.repr().map(|r| r.to_string()).unwrap_or_default()
        ))
    })
}

/// A switch option: `True` or `False` (Python or numpy), not an integer.
fn switch(key: &str, v: &Bound<'_, PyAny>) -> PyResult<bool> {
    v.extract().map_err(|_| {
        PyTypeError::new_err(format!(
            "{key}: must be True or False, got {}",
            v.repr().map(|r| r.to_string()).unwrap_or_default()
        ))
    })
}

/// GA options from a dict (`None`: the defaults), typed strictly; unknown keys are
/// refused with the list of the known ones. The values' ranges are checked by
/// `GaOptions::validate` (here for the options alone: `initial` is checked against
/// the problem's dimension by the GA).
fn ga_options(options: Option<&Bound<'_, PyDict>>, initial: Vec<Vec<f64>>) -> PyResult<GaOptions> {
    let mut o = GaOptions::default();
    if let Some(d) = options {
        for (k, v) in d.iter() {
            let key: String = k.extract()?;
            let v = &v;
            match key.as_str() {
                "seed" => o.seed = count("seed", v)? as u64,
                "pop_size" => o.pop_size = count(&key, v)?,
                "max_generations" => o.max_generations = count(&key, v)?,
                "stall_generations" => o.stall_generations = count(&key, v)?,
                "ftol" => o.ftol = real(&key, v)?,
                "xtol" => o.xtol = real(&key, v)?,
                "target" => o.target = real(&key, v)?,
                "tournament" => o.tournament = count(&key, v)?,
                "crossover_prob" => o.crossover_prob = real(&key, v)?,
                "eta_c" => o.eta_c = real(&key, v)?,
                "mutation_prob" => o.mutation_prob = real(&key, v)?,
                "eta_m" => o.eta_m = real(&key, v)?,
                "plus" => o.plus = switch(&key, v)?,
                "elite" => o.elite = count(&key, v)?,
                "polish" => o.polish = switch(&key, v)?,
                "polish_max_evals" => o.polish_max_evals = count(&key, v)?,
                "local_every" => o.local_every = count(&key, v)?,
                "local_evals" => o.local_evals = count(&key, v)?,
                _ => {
                    let known: Vec<String> = tunable(d.py(), &GaOptions::default())?
                        .keys()
                        .iter()
                        .map(|k| k.to_string())
                        .collect();
                    return Err(PyValueError::new_err(format!(
                        "{key}: unknown GA option; known: {}, seed, target",
                        known.join(", ")
                    )));
                }
            }
        }
    }
    guard(|| o.validate(0))?;
    o.initial = initial;
    Ok(o)
}

/// The defaults of the tunable GA options (`GaOptions::default()`).
#[pyfunction]
fn ga_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    tunable(py, &GaOptions::default())
}

/// The GA's automatic population of a problem of `d` parameters (`pop_size = 0`).
#[pyfunction]
fn ga_auto_pop(d: usize) -> usize {
    ga::auto_pop(d)
}

/// GA options checked as `calibrate` checks them (types, ranges, unknown names):
/// the tunable options with the given values and the defaults for the others.
#[pyfunction]
#[pyo3(signature = (options=None))]
fn ga_check<'py>(
    py: Python<'py>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    tunable(py, &ga_options(options, Vec::new())?)
}

/// The one calibration binding: the GA on Eq. 6 for any cost (model with effects,
/// open or closed loop, free upper-level gains) over a run set — one problem over
/// all runs, or many independent problems (`problems`: run-index lists, repeats
/// allowed) solved in parallel. `options` is a dict of GA options (seed, pop_size,
/// max_generations, ..., see `GaOptions`). Returns one dict per problem (x, f, f_ga,
/// generations, evaluations, stop, interrupted, history, per_run: the run indices
/// and Eq. 6 run costs of the best parameters). With `in_turn` the problems are
/// independent starts of one problem, run one after the other with all the threads
/// each; the starts after the first that reaches the target (or after a Ctrl-C) are
/// skipped, and only the starts that ran are returned. `initial` rows (R x d) join
/// every problem's first population; `initial_per_problem` (one R_k x d array per
/// problem) adds problem `k`'s own rows before them (e.g. each problem's base optimum
/// with added effects at their neutral values).
#[pyfunction]
#[pyo3(signature = (
    model, runs, lower_bounds, upper_bounds, scale, effects=Vec::new(),
    upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0),
    init="rest", closed_loop=false, problems=None, derive_seeds=true, in_turn=false,
    options=None, initial=None, initial_per_problem=None, progress=None, threads=0
))]
#[allow(clippy::too_many_arguments)]
fn calibrate<'py>(
    py: Python<'py>,
    model: &str,
    runs: &Bound<'py, RunSet>,
    lower_bounds: Vec<f64>,
    upper_bounds: Vec<f64>,
    scale: Vec<String>,
    effects: Vec<String>,
    upper_free: Vec<usize>,
    command_kind: &str,
    weights: (f64, f64, f64),
    init: &str,
    closed_loop: bool,
    problems: Option<Vec<Vec<usize>>>,
    derive_seeds: bool,
    in_turn: bool,
    options: Option<&Bound<'py, PyDict>>,
    initial: Option<PyReadonlyArray2<'py, f64>>,
    initial_per_problem: Option<Vec<PyReadonlyArray2<'py, f64>>>,
    progress: Option<Py<PyAny>>,
    threads: usize,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let spec = cost_spec(
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
    let opts = ga_options(options, initial)?;
    let rs = runs.get();
    let runs = rs.refs();
    let problems = problems.unwrap_or_else(|| vec![(0..runs.len()).collect()]);
    let n_problems = problems.len();
    let mut per_problem: Vec<Vec<Vec<f64>>> = Vec::new();
    for (k, arr) in initial_per_problem.iter().flatten().enumerate() {
        let (_, c, s) = slice2(&format!("initial_per_problem[{k}]"), arr)?;
        per_problem.push(if c == 0 {
            Vec::new()
        } else {
            s.chunks(c).map(|r| r.to_vec()).collect()
        });
    }
    if initial_per_problem.is_some() {
        guard(|| {
            crate::optimize::calibrate::check_initial(&per_problem, n_problems, bounds.dim())
        })?;
    }

    let (outcome, by_user) = relay(py, threads, progress.as_ref(), n_problems, |send, stop| {
        crate::optimize::calibrate::calibrate_many(
            &spec,
            &runs,
            &problems,
            &bounds,
            &opts,
            derive_seeds,
            in_turn,
            &per_problem,
            move |k, p| {
                send(Msg::Progress {
                    problem: k,
                    phase: p.phase,
                    iteration: p.iteration,
                    evaluations: p.evaluations,
                    best: p.best_f,
                });
                Some(!stop.load(Ordering::Relaxed))
            },
        )
    })?;
    outcome
        .into_iter()
        .map(|r| result_dict(py, r, by_user))
        .collect()
}

/// Runs `work` on a worker of the requested pool with the GIL released, relaying its
/// progress messages (sent through `send`) to the Python callable `progress` and
/// watching for Ctrl-C on the calling thread: Ctrl-C (or a `KeyboardInterrupt` from
/// the callable) sets `stop`, which `work` polls; any other error of the callable
/// sets it too and is raised. Returns `work`'s value and whether the user stopped it.
fn relay<T: Send>(
    py: Python<'_>,
    threads: usize,
    progress: Option<&Py<PyAny>>,
    n_problems: usize,
    work: impl FnOnce(&(dyn Fn(Msg) + Sync), &AtomicBool) -> crate::error::Result<T> + Send,
) -> PyResult<(T, bool)> {
    let stop = AtomicBool::new(false);
    let (tx, rx) = mpsc::channel::<Msg>();
    let mut interrupted_by_user = false;
    let mut py_error: Option<PyErr> = None;
    let outcome = py.detach(|| {
        let rx = rx;
        std::thread::scope(|s| {
            let stop = &stop;
            let worker = s.spawn(move || {
                let tx = std::sync::Mutex::new(tx);
                let send = |m: Msg| {
                    if let Ok(t) = tx.lock() {
                        let _ = t.send(m);
                    }
                };
                let res = guard(|| crate::parallel::on_worker(threads, || work(&send, stop))?);
                send(Msg::Done);
                res
            });
            let mut last: Option<Msg> = None;
            loop {
                let mut finished = false;
                match rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(Msg::Done) => finished = true,
                    Ok(m) => last = Some(m),
                    Err(mpsc::RecvTimeoutError::Timeout) => {}
                    Err(mpsc::RecvTimeoutError::Disconnected) => finished = true,
                }
                // Coalesce whatever else is queued.
                while let Ok(m) = rx.try_recv() {
                    match m {
                        Msg::Done => finished = true,
                        m => last = Some(m),
                    }
                }
                if finished {
                    break;
                }
                if stop.load(Ordering::Relaxed) {
                    continue;
                }
                Python::attach(|py| {
                    if let Err(e) = py.check_signals() {
                        if e.is_instance_of::<PyKeyboardInterrupt>(py) {
                            interrupted_by_user = true;
                        } else {
                            py_error = Some(e);
                        }
                        stop.store(true, Ordering::Relaxed);
                        return;
                    }
                    if let (Some(cb), Some(m)) = (progress, last.take()) {
                        let r = (|| -> PyResult<()> {
                            let info = m.info(py, n_problems)?;
                            cb.bind(py).call1((info,))?;
                            Ok(())
                        })();
                        if let Err(e) = r {
                            if e.is_instance_of::<PyKeyboardInterrupt>(py) {
                                interrupted_by_user = true;
                            } else {
                                py_error = Some(e);
                            }
                            stop.store(true, Ordering::Relaxed);
                        }
                    }
                });
            }
            worker.join().unwrap_or_else(|_| {
                Err(PyRuntimeError::new_err(
                    "avll internal error (please report): GA worker panicked",
                ))
            })
        })
    });
    if let Some(e) = py_error {
        return Err(e);
    }
    Ok((outcome?, interrupted_by_user))
}

/// Refits of resampled Eq. 6 costs warm-started from each problem's full-data
/// optimum (`crate::optimize::resample`): `problems` are run-index lists (repeats
/// count), `x0` their optima (P x d), `atoms` the atom length (samples) of each
/// problem's distinct runs in increasing index order, `resample_weights` one B x A
/// array per problem (A: those runs' atoms in that order). Returns one dict per
/// problem: `x` (B x d), `f`, `f_x0` (the resampled cost at the optimum),
/// `evaluations`, `done` (False: skipped after a stop), `f_full`, `cache_hits`,
/// `rollouts`, `interrupted`. `method`: `"simplex"` (the bounded Nelder–Mead) or
/// `"lm"` (bounded Levenberg–Marquardt on the weighted residuals).
#[pyfunction]
#[pyo3(signature = (
    model, runs, lower_bounds, upper_bounds, scale, problems, x0, atoms, resample_weights,
    effects=Vec::new(), upper_free=Vec::new(), command_kind="acceleration",
    weights=(1.0, 0.0, 0.0), init="rest", closed_loop=false, budget=0, step=0.02,
    ftol=1e-9, method="simplex", progress=None, threads=0
))]
#[allow(clippy::too_many_arguments)]
fn refit_resamples<'py>(
    py: Python<'py>,
    model: &str,
    runs: &Bound<'py, RunSet>,
    lower_bounds: Vec<f64>,
    upper_bounds: Vec<f64>,
    scale: Vec<String>,
    problems: Vec<Vec<usize>>,
    x0: PyReadonlyArray2<'py, f64>,
    atoms: Vec<Vec<usize>>,
    resample_weights: Vec<PyReadonlyArray2<'py, f64>>,
    effects: Vec<String>,
    upper_free: Vec<usize>,
    command_kind: &str,
    weights: (f64, f64, f64),
    init: &str,
    closed_loop: bool,
    budget: usize,
    step: f64,
    ftol: f64,
    method: &str,
    progress: Option<Py<PyAny>>,
    threads: usize,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    use crate::optimize::resample::{
        refit_resamples as refit, RefitMethod, RefitOptions, ResampleProblem,
    };
    let method = guard(|| RefitMethod::from_name(method))?;
    let spec = cost_spec(
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
    let (np, d, xs) = slice2("x0", &x0)?;
    let n = problems.len();
    if np != n || atoms.len() != n || resample_weights.len() != n {
        return Err(PyValueError::new_err(format!(
            "problems: {n} problems need as many x0 rows, atom lists and weight arrays, got \
             {np}, {}, {}",
            atoms.len(),
            resample_weights.len()
        )));
    }
    let mut probs = Vec::with_capacity(n);
    let mut sizes = Vec::with_capacity(n);
    let rs = runs.get();
    let refs = rs.refs();
    for (k, sub) in problems.iter().enumerate() {
        let runs_m = guard(|| crate::optimize::calibrate::multiplicities(sub, refs.len(), k))?;
        let (b, _, w) = slice2(&format!("resample_weights[{k}]"), &resample_weights[k])?;
        sizes.push(b);
        probs.push(ResampleProblem {
            runs: runs_m,
            atom: atoms[k].clone(),
            x0: xs[k * d..(k + 1) * d].to_vec(),
            weights: w.to_vec(),
        });
    }
    let opts = RefitOptions {
        budget,
        step,
        ftol,
        method,
        ..Default::default()
    };
    let (out, by_user) = relay(py, threads, progress.as_ref(), n, |send, stop| {
        refit(&spec, &refs, &probs, &bounds, &opts, |k, done| {
            send(Msg::Resample {
                problem: k,
                done,
                total: sizes[k],
            });
            !stop.load(Ordering::Relaxed)
        })
    })?;
    out.into_iter()
        .map(|r| {
            let dct = PyDict::new(py);
            let b = r.refits.len();
            let x: Vec<f64> = r.refits.iter().flat_map(|f| f.x.iter().copied()).collect();
            let arr = numpy::ndarray::Array2::from_shape_vec((b, d), x)
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            dct.set_item("x", arr.into_pyarray(py))?;
            let col = |g: &dyn Fn(&crate::optimize::resample::Refit) -> f64| -> Vec<f64> {
                r.refits.iter().map(g).collect()
            };
            dct.set_item("f", col(&|f| f.f).into_pyarray(py))?;
            dct.set_item("f_x0", col(&|f| f.f_x0).into_pyarray(py))?;
            dct.set_item(
                "evaluations",
                col(&|f| f.evaluations as f64).into_pyarray(py),
            )?;
            let done: Vec<bool> = r.refits.iter().map(|f| f.done).collect();
            let interrupted = by_user && done.iter().any(|d| !d);
            dct.set_item("done", done.into_pyarray(py))?;
            dct.set_item("f_full", r.f_full)?;
            dct.set_item("cache_hits", r.cache_hits)?;
            dct.set_item("rollouts", r.rollouts)?;
            dct.set_item("interrupted", interrupted || (by_user && b == 0))?;
            Ok(dct)
        })
        .collect()
}

/// Exact-delay stability codes (0 locally unstable, 1 string unstable, 2 string
/// stable) of many closed loops, one per row: the lower level `params[i]` of
/// `model` with the upper gains `kg[i]`, `tg[i]`, `kv[i]` (the true delay), and
/// whether each verdict is certified. Rows whose parameters the model refuses get
/// code 0, uncertified. In parallel over rows.
#[pyfunction]
#[pyo3(signature = (model, params, kg, tg, kv, budget=20000, threads=0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn delay_codes_rows<'py>(
    py: Python<'py>,
    model: &str,
    params: PyReadonlyArray2<'py, f64>,
    kg: Vec<f64>,
    tg: Vec<f64>,
    kv: Vec<f64>,
    budget: usize,
    threads: usize,
) -> PyResult<(
    Bound<'py, numpy::PyArray1<u8>>,
    Bound<'py, numpy::PyArray1<bool>>,
)> {
    use crate::stability::delay::{classify_points, DelayLoop};
    use rayon::prelude::*;
    let kind = guard(|| crate::model::ModelKind::from_name(model))?;
    let (n, p, rows) = slice2("params", &params)?;
    if kg.len() != n || tg.len() != n || kv.len() != n {
        return Err(PyValueError::new_err(format!(
            "kg: params ({n} rows), kg, tg and kv must have one length, got {}, {}, {}",
            kg.len(),
            tg.len(),
            kv.len()
        )));
    }
    guard(|| {
        crate::error::check_series("kg", &kg)?;
        crate::error::check_series("tg", &tg)?;
        crate::error::check_series("kv", &kv)
    })?;
    let out: Vec<(u8, bool)> = py.detach(|| {
        guard(|| {
            crate::parallel::with_threads(threads, || {
                (0..n)
                    .into_par_iter()
                    .map(|i| {
                        let Ok(lin) = kind.linear(&rows[i * p..(i + 1) * p]) else {
                            return (0u8, false);
                        };
                        let Ok(mut dl) = DelayLoop::new(&lin) else {
                            return (0u8, false);
                        };
                        dl.budget = budget.max(1);
                        let (mut c, mut o) = ([0u8], [false]);
                        classify_points(&dl, &kg[i..=i], &tg[i..=i], &kv[i..=i], &mut c, &mut o);
                        (c[0], o[0])
                    })
                    .collect()
            })
        })
    })?;
    let (codes, ok): (Vec<u8>, Vec<bool>) = out.into_iter().unzip();
    Ok((codes.into_pyarray(py), ok.into_pyarray(py)))
}

/// Default seed of problem `k` when `derive_seeds` is true.
#[pyfunction]
fn derive_seed(seed: u64, k: u64) -> u64 {
    ga::derive_seed(seed, k)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(derive_seed, m)?)?;
    m.add_function(wrap_pyfunction!(refit_resamples, m)?)?;
    m.add_function(wrap_pyfunction!(delay_codes_rows, m)?)?;
    m.add_function(wrap_pyfunction!(ga_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(ga_check, m)?)?;
    m.add_function(wrap_pyfunction!(ga_auto_pop, m)?)?;
    m.add("GA_AUTO_POP", ga::AUTO_POP)?;
    Ok(())
}
