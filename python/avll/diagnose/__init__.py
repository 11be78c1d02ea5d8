"""Residual diagnosis and the add-effect / recalibrate loop.

Given a calibrated model and runs, :func:`diagnose` looks at the residual
``e = a_measured - a_simulated``: its spectrum, autocorrelation, cross-correlation
with the command, its dependence on candidate signals, and ranks the effects of the
registry (:data:`avll.effects.EFFECTS`) by a score test by simulation.
:func:`effect_loop` adds effects one at a time, accepting one only when
cross-validation over the calibration runs says it lowers the out-of-fold error in
most folds by a minimum effect size with a test that respects autocorrelated
residuals; validation runs are only reported, test runs only simulated at the end;
what the residual keeps afterwards is reported ("none of these").

One module per job:

* :mod:`avll.diagnose.stats` — effective sample size, binned dependence, the
  loss-difference test, the moving-block bootstrap;
* :mod:`avll.diagnose.signatures` — effect signatures, the score test, ranking,
  residual structure;
* :mod:`avll.diagnose.fitting` — simulation, per-run errors, the objective weights and
  the parameters at a bound (the fits are :func:`avll.calibrate` itself);
* :mod:`avll.diagnose.loop` — folds and the cross-validated loop;
* :mod:`avll.diagnose.contract` — ``final_model`` as a dict, :func:`model_from_dict`,
  :func:`simulate_run`;
* :mod:`avll.diagnose.report` — tables, figures, the report;
* the command ``avll diagnose`` is :mod:`avll.cli.diagnose`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover - for type checkers; imported lazily below
    from .contract import model_from_dict, model_to_dict, simulate_run
    from .fitting import (
        BASE_BOUNDS,
        CLOSED_LOOP_WEIGHTS,
        SPEED_COMMAND_WEIGHTS,
        UPPER_BOUNDS,
        AtBound,
        at_bound,
        calibrate_kw,
        default_weights,
        run_mse,
        simulate_runs,
    )
    from .loop import (
        MIN_GAIN,
        Flag,
        LoopResult,
        Selection,
        Splits,
        Step,
        Trial,
        effect_loop,
        make_folds,
    )
    from .report import mse_table, plot_diagnosis, plot_unexplained, write_report
    from .signatures import Candidate, Diagnosis, diagnose, offered, residual_structure
    from .stats import (
        BootstrapGain,
        LossTest,
        SignalDependence,
        binned_dependence,
        block_bootstrap_gain,
        effective_sample_size,
        loss_difference_test,
    )


#: Where each public name lives: the submodules load on first use, so that
#: importing the package (e.g. for :data:`MIN_GAIN`) does not import scipy.
_WHERE = {
    **dict.fromkeys(("model_from_dict", "model_to_dict", "simulate_run"), "contract"),
    **dict.fromkeys(("BASE_BOUNDS", "CLOSED_LOOP_WEIGHTS", "SPEED_COMMAND_WEIGHTS",
                     "UPPER_BOUNDS", "at_bound", "AtBound", "calibrate_kw", "default_weights",
                     "run_mse", "simulate_runs"), "fitting"),
    "MIN_GAIN": "defaults",
    **dict.fromkeys(("LoopResult", "Step", "Trial", "Flag", "Splits", "Selection",
                     "effect_loop", "make_folds"), "loop"),
    **dict.fromkeys(("mse_table", "plot_diagnosis", "plot_unexplained", "write_report"),
                    "report"),
    **dict.fromkeys(("Candidate", "Diagnosis", "diagnose", "offered", "residual_structure"),
                    "signatures"),
    **dict.fromkeys(("SignalDependence", "LossTest", "BootstrapGain", "binned_dependence",
                     "block_bootstrap_gain", "effective_sample_size", "loss_difference_test"),
                    "stats"),
}  # fmt: skip


__all__ = [*_WHERE]


def __getattr__(name: str) -> Any:
    """The public names of the submodules, imported on first access."""
    if name in _WHERE:
        import importlib

        value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'avll.diagnose' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names and the lazily imported public ones."""
    return sorted(set(globals()) | set(__all__))
