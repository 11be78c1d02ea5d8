"""avll: models of the lower-level (actuator) controller of automated vehicles.

Exact rollouts, parallel GA calibration and stability maps, in Rust, after
Liu et al., "Experimental study and modeling of the lower-level controller of
automated vehicle".
"""

from typing import TYPE_CHECKING, Any

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
    PowerLimit,
    RateLimit,
    RoadLoad,
    Saturation,
    Sensor,
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

#: Table II of the paper: the calibrated parameters of the three models.
PAPER_TABLE_II = {
    "first": FirstOrderLag(Td=1.0758),
    "second": SecondOrder(K0=0.7292, m2=0.0445, m3=0.1305, Td=0.7796),
    "proposed": Proposed(m1=6.7893, m2=1.2824, m3=8.8157, K0=0.3479, Td=0.7903, K=0.1008),
}

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
    "PowerLimit",
    "RateLimit",
    "RoadLoad",
    "Saturation",
    "Sensor",
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
    "model_from_dict",
    "simulate_run",
]

if TYPE_CHECKING:  # pragma: no cover - for type checkers; imported lazily below
    from . import io, synth
    from .diagnose.contract import model_from_dict, simulate_run

#: Subpackages imported on first use: ``avll.io`` brings pandas (the loaders), which
#: ``import avll`` alone does not need.
_LAZY = ("io", "synth")
#: Functions imported on first use from the module that defines them (the residual
#: loop's contract brings scipy).
_LAZY_FUNCTIONS = {"model_from_dict": ".diagnose.contract", "simulate_run": ".diagnose.contract"}


def __getattr__(name: str) -> Any:
    """Imports :mod:`avll.io` and :mod:`avll.synth`, and :func:`model_from_dict` /
    :func:`simulate_run` (from :mod:`avll.diagnose.contract`), on first access."""
    import importlib

    if name in _LAZY:
        mod = importlib.import_module(f".{name}", __name__)
        globals()[name] = mod
        return mod
    if name in _LAZY_FUNCTIONS:
        fn = getattr(importlib.import_module(_LAZY_FUNCTIONS[name], __name__), name)
        globals()[name] = fn
        return fn
    raise AttributeError(f"module 'avll' has no attribute {name!r}")
