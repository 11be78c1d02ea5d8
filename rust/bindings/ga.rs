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
use pyo3::exceptions::{PyKeyboardInterrupt, PyTypeError, PyValueError};
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
    Done,
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
/// skipped, and only the starts that ran are returned.
#[pyfunction]
#[pyo3(signature = (
    model, runs, lower_bounds, upper_bounds, scale, effects=Vec::new(),
    upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0),
    init="rest", closed_loop=false, problems=None, derive_seeds=true, in_turn=false,
    options=None, initial=None, progress=None, threads=0
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

    let stop = AtomicBool::new(false);
    let (tx, rx) = mpsc::channel::<Msg>();
    let mut interrupted_by_user = false;
    let mut py_error: Option<PyErr> = None;
    let outcome = py.detach(|| {
        let rx = rx;
        std::thread::scope(|s| {
            let (spec, runs, problems, bounds, opts, stop) =
                (&spec, &runs, &problems, &bounds, &opts, &stop);
            let worker = s.spawn(move || {
                let tx = std::sync::Mutex::new(tx);
                let res = guard(|| {
                    crate::parallel::on_worker(threads, || {
                        crate::optimize::calibrate::calibrate_many(
                            spec,
                            runs,
                            problems,
                            bounds,
                            opts,
                            derive_seeds,
                            in_turn,
                            {
                                let tx = &tx;
                                move |k, p| {
                                    if let Ok(t) = tx.lock() {
                                        let _ = t.send(Msg::Progress {
                                            problem: k,
                                            phase: p.phase,
                                            iteration: p.iteration,
                                            evaluations: p.evaluations,
                                            best: p.best_f,
                                        });
                                    }
                                    Some(!stop.load(Ordering::Relaxed))
                                }
                            },
                        )
                    })?
                });
                if let Ok(t) = tx.lock() {
                    let _ = t.send(Msg::Done);
                }
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
                    if let (
                        Some(cb),
                        Some(Msg::Progress {
                            problem,
                            phase,
                            iteration,
                            evaluations,
                            best,
                        }),
                    ) = (&progress, last.take())
                    {
                        let info = PyDict::new(py);
                        let r = (|| -> PyResult<()> {
                            info.set_item("problem", problem)?;
                            info.set_item(
                                "phase",
                                if phase == Phase::Ga { "ga" } else { "polish" },
                            )?;
                            info.set_item("iteration", iteration)?;
                            info.set_item("evaluations", evaluations)?;
                            info.set_item("best", best)?;
                            info.set_item("problems", n_problems)?;
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
            worker
                .join()
                .unwrap_or_else(|_| Err(PyValueError::new_err("avll internal error: GA worker")))
        })
    });
    if let Some(e) = py_error {
        return Err(e);
    }
    let results = outcome?;
    results
        .into_iter()
        .map(|r| result_dict(py, r, interrupted_by_user))
        .collect()
}

/// Default seed of problem `k` when `derive_seeds` is true.
#[pyfunction]
fn derive_seed(seed: u64, k: u64) -> u64 {
    ga::derive_seed(seed, k)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(derive_seed, m)?)?;
    m.add_function(wrap_pyfunction!(ga_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(ga_check, m)?)?;
    Ok(())
}
