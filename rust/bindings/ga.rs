//! Bindings of the GA calibration (`avll.calibrate` uses them).
//!
//! The GA runs on a scoped worker thread (inside the requested rayon pool) with the
//! GIL released; the calling thread waits for per-generation progress messages and,
//! for each batch of them, re-takes the GIL, calls `py.check_signals()` (Ctrl-C)
//! and the optional Python progress callable. Ctrl-C sets a stop flag that every
//! problem sees at its next generation; the results are then the best so far,
//! flagged `interrupted`.

use super::runs::runs_from_arrays;
use super::{guard, slice2};
use crate::ga::{self, Bounds, GaOptions, GaResult, Phase, Scale, StopReason};
use crate::model::{CommandKind, ModelKind};
use crate::rollout::{CostSpec, Init};
use numpy::{IntoPyArray, PyReadonlyArray1, PyReadonlyArray2};
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

fn result_dict<'py>(py: Python<'py>, r: GaResult, by_user: bool) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    // A callback stop is an interrupt when the user asked for it; otherwise another
    // start of the same problem reached the target (`stop_all_at_target`).
    let interrupted = r.stop == StopReason::Callback && by_user;
    let stop = if r.stop == StopReason::Callback && !by_user {
        "target"
    } else {
        r.stop.name()
    };
    d.set_item("x", r.x.into_pyarray(py))?;
    d.set_item("f", r.f)?;
    d.set_item("f_ga", r.f_ga)?;
    d.set_item("generations", r.generations)?;
    d.set_item("evaluations", r.evaluations)?;
    d.set_item("stop", stop)?;
    d.set_item("interrupted", interrupted)?;
    d.set_item("history", r.history.into_pyarray(py))?;
    Ok(d)
}

/// Calibrates a model by the GA on Eq. 6: one problem over all runs, or many
/// independent problems (`problems`: run-index lists, repeats allowed) solved in
/// parallel. Returns one dict per problem (x, f, f_ga, generations, evaluations,
/// stop, interrupted, history). With `stop_all_at_target`, every problem stops once
/// any reaches `target` (independent starts of one problem).
#[pyfunction]
#[pyo3(signature = (
    model, offsets, dt, a, lower_bounds, upper_bounds, scale,
    command=None, lead_x=None, lead_v=None, v=None, x=None, upper=None,
    upper_free=Vec::new(), command_kind="acceleration", weights=(1.0, 0.0, 0.0),
    init="rest", closed_loop=false, problems=None, derive_seeds=true, stop_all_at_target=false,
    seed=0, pop_size=0, max_generations=300, stall_generations=20, ftol=1e-4,
    xtol=1e-8, target=f64::NEG_INFINITY, tournament=2, crossover_prob=0.9, eta_c=10.0,
    mutation_prob=0.0, eta_m=20.0, plus=true, elite=0, polish=true, polish_max_evals=0, local_every=3, local_evals=0,
    initial=None, progress=None, threads=0
))]
#[allow(clippy::too_many_arguments)]
fn calibrate<'py>(
    py: Python<'py>,
    model: &str,
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
    problems: Option<Vec<Vec<usize>>>,
    derive_seeds: bool,
    stop_all_at_target: bool,
    seed: u64,
    pop_size: usize,
    max_generations: usize,
    stall_generations: usize,
    ftol: f64,
    xtol: f64,
    target: f64,
    tournament: usize,
    crossover_prob: f64,
    eta_c: f64,
    mutation_prob: f64,
    eta_m: f64,
    plus: bool,
    elite: usize,
    polish: bool,
    polish_max_evals: usize,
    local_every: usize,
    local_evals: usize,
    initial: Option<PyReadonlyArray2<'py, f64>>,
    progress: Option<Py<PyAny>>,
    threads: usize,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
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
        xtol,
        target,
        tournament,
        crossover_prob,
        eta_c,
        mutation_prob,
        eta_m,
        plus,
        elite,
        seed,
        polish,
        polish_max_evals,
        local_every,
        local_evals,
        initial,
    };
    let runs = runs_from_arrays(
        &offsets, &dt, &a, &command, &lead_x, &lead_v, &v, &x, &upper,
    )?;
    let problems = problems.unwrap_or_else(|| vec![(0..runs.len()).collect()]);
    let n_problems = problems.len();

    let stop = AtomicBool::new(false);
    let target_hit = AtomicBool::new(false);
    let (tx, rx) = mpsc::channel::<Msg>();
    let mut interrupted_by_user = false;
    let mut py_error: Option<PyErr> = None;
    let outcome = py.detach(|| {
        let rx = rx;
        std::thread::scope(|s| {
            let (spec, runs, problems, bounds, opts, stop, target_hit) =
                (&spec, &runs, &problems, &bounds, &opts, &stop, &target_hit);
            let worker = s.spawn(move || {
                let tx = std::sync::Mutex::new(tx);
                let res = guard(|| {
                    crate::parallel::with_threads(threads, || {
                        ga::calibrate_many(spec, runs, problems, bounds, opts, derive_seeds, {
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
                                if stop_all_at_target && p.best_f <= opts.target {
                                    target_hit.store(true, Ordering::Relaxed);
                                }
                                Some(
                                    !(stop.load(Ordering::Relaxed)
                                        || target_hit.load(Ordering::Relaxed)),
                                )
                            }
                        })
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
