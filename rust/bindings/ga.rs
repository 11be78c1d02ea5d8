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
use pyo3::exceptions::{PyKeyboardInterrupt, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
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

/// GA options from a dict (`None`: the defaults); unknown keys are refused.
fn ga_options(options: Option<&Bound<'_, PyDict>>, initial: Vec<Vec<f64>>) -> PyResult<GaOptions> {
    let mut o = GaOptions {
        initial,
        ..GaOptions::default()
    };
    let Some(d) = options else {
        return Ok(o);
    };
    for (k, v) in d.iter() {
        let key: String = k.extract()?;
        let bad = |e: PyErr| PyValueError::new_err(format!("{key}: {e}"));
        match key.as_str() {
            "seed" => o.seed = v.extract().map_err(bad)?,
            "pop_size" => o.pop_size = v.extract().map_err(bad)?,
            "max_generations" => o.max_generations = v.extract().map_err(bad)?,
            "stall_generations" => o.stall_generations = v.extract().map_err(bad)?,
            "ftol" => o.ftol = v.extract().map_err(bad)?,
            "xtol" => o.xtol = v.extract().map_err(bad)?,
            "target" => o.target = v.extract().map_err(bad)?,
            "tournament" => o.tournament = v.extract().map_err(bad)?,
            "crossover_prob" => o.crossover_prob = v.extract().map_err(bad)?,
            "eta_c" => o.eta_c = v.extract().map_err(bad)?,
            "mutation_prob" => o.mutation_prob = v.extract().map_err(bad)?,
            "eta_m" => o.eta_m = v.extract().map_err(bad)?,
            "plus" => o.plus = v.extract().map_err(bad)?,
            "elite" => o.elite = v.extract().map_err(bad)?,
            "polish" => o.polish = v.extract().map_err(bad)?,
            "polish_max_evals" => o.polish_max_evals = v.extract().map_err(bad)?,
            "local_every" => o.local_every = v.extract().map_err(bad)?,
            "local_evals" => o.local_evals = v.extract().map_err(bad)?,
            _ => {
                return Err(PyValueError::new_err(format!(
                    "options: unknown GA option {key:?}"
                )))
            }
        }
    }
    Ok(o)
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
    Ok(())
}
