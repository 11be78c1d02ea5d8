"""avll: models of the lower-level (actuator) controller of automated vehicles.

Exact rollouts, parallel GA calibration and stability maps, in Rust, after
Liu et al., "Experimental study and modeling of the lower-level controller of
automated vehicle".
"""

from typing import TYPE_CHECKING, Any

from . import paper as _paper
from ._atomic import read_manifest
from ._core import __version__
from .calibrate import (
    Bootstrap,
    CalibrationResult,
    Workflow,
    bootstrap,
    calibrate,
    calibrate_many,
    paper_workflow,
)
from .data import DataError, DataWarning, PlausibilityWarning, Run
from .effects import (
    EFFECTS,
    Asymmetric,
    Deadband,
    Delay,
    Grade,
    RateLimit,
    Saturation,
    SpeedDrag,
    WithEffects,
    batch_cost_effects,
    closed_loop_effects,
    simulate_effects,
)
from .maps import (
    calibrate_many_distributed,
    map_dataset,
    map_thresholds,
    min_stable_tg_samples,
    models_from_bootstrap,
    open_map,
    stability_probability,
    sweep,
    write_map,
)
from .models import (
    MODELS,
    FirstOrderLag,
    LowerLevelModel,
    Proposed,
    SecondOrder,
    UpperLevel,
    model_class,
)
from .rollout import Trajectory, batch_cost, closed_loop, platoon, simulate, simulate_full
from .stability import (
    Extremum,
    PadeReport,
    Thresholds,
    boundary,
    capacity,
    exact_delay_codes,
    kv_supremum,
    kv_threshold,
    min_stable_tg,
    pade_error_map,
    pade_report,
    stability_map,
    stability_points,
    stable_intervals,
    thresholds,
)

#: Table II of the paper: the calibrated parameters of the three models
#: (:data:`avll.paper.TABLE_II`).
PAPER_TABLE_II = _paper.TABLE_II

__all__ = [
    "io",
    "synth",
    "__version__",
    "DataError",
    "DataWarning",
    "PlausibilityWarning",
    "Run",
    "MODELS",
    "FirstOrderLag",
    "LowerLevelModel",
    "Proposed",
    "SecondOrder",
    "UpperLevel",
    "model_class",
    "Trajectory",
    "batch_cost",
    "closed_loop",
    "platoon",
    "simulate",
    "simulate_full",
    "PAPER_TABLE_II",
    "EFFECTS",
    "Asymmetric",
    "Deadband",
    "Delay",
    "Grade",
    "RateLimit",
    "Saturation",
    "SpeedDrag",
    "WithEffects",
    "batch_cost_effects",
    "closed_loop_effects",
    "simulate_effects",
    "Bootstrap",
    "CalibrationResult",
    "Workflow",
    "bootstrap",
    "calibrate",
    "calibrate_many",
    "paper_workflow",
    "PadeReport",
    "Thresholds",
    "capacity",
    "exact_delay_codes",
    "kv_threshold",
    "pade_report",
    "stability_map",
    "stability_points",
    "thresholds",
    "Extremum",
    "boundary",
    "kv_supremum",
    "min_stable_tg",
    "pade_error_map",
    "stable_intervals",
    "calibrate_many_distributed",
    "map_dataset",
    "map_thresholds",
    "min_stable_tg_samples",
    "models_from_bootstrap",
    "open_map",
    "stability_probability",
    "sweep",
    "write_map",
    "read_manifest",
]

if TYPE_CHECKING:  # pragma: no cover - for type checkers; imported lazily below
    from . import io, synth

#: Submodules imported on first use: ``avll.io`` brings pandas (the loaders), which
#: ``import avll`` alone does not need; ``avll.plotting`` the figures (matplotlib on
#: first drawing), ``avll.progress`` the progress display, ``avll.cli`` the command.
_LAZY = ("io", "synth", "plotting", "progress", "cli")


def __getattr__(name: str) -> Any:
    """Imports the submodules of ``_LAZY`` (:mod:`avll.io`, :mod:`avll.synth`, ...) on
    first access."""
    if name in _LAZY:
        import importlib

        mod = importlib.import_module(f".{name}", __name__)
        globals()[name] = mod
        return mod
    raise AttributeError(f"module 'avll' has no attribute {name!r}")
