"""avll: models of the lower-level (actuator) controller of automated vehicles.

Exact rollouts, parallel GA calibration and stability maps, in Rust, after
Liu et al., "Experimental study and modeling of the lower-level controller of
automated vehicle".
"""

from typing import TYPE_CHECKING, Any

# first: in the `avll` command, a Ctrl-C while the package imports is one line, exit 130
from . import _startup  # noqa: F401
from ._core import __version__
from .data import DataError, DataWarning, PlausibilityWarning, Run
from .models import (
    MODELS,
    FirstOrderLag,
    LowerLevelModel,
    Proposed,
    SecondOrder,
    UpperLevel,
    model_class,
)

#: Public names imported from their module on first use (``import avll`` loads only
#: the Rust core, the models and the data class; see ``benches/bench_import.py``).
_LAZY_NAMES: dict[str, str] = {
    "read_manifest": "_atomic",
    "RunSet": "runs",
    **dict.fromkeys(("Bootstrap", "CalibrationResult", "Workflow", "bootstrap", "calibrate",
                     "calibrate_many", "paper_workflow"), "calibration"),
    **dict.fromkeys(("EFFECTS", "Asymmetric", "Closing", "Comfort", "Deadband", "Delay",
                     "Feedforward", "Grade", "Perception", "PowerLimit", "RateLimit",
                     "RoadLoad", "Saturation", "Sensor", "SpeedDrag", "SpeedGains",
                     "WithEffects"), "effects"),
    **dict.fromkeys(("model_from_dict", "simulate_run"), "diagnose.contract"),
    **dict.fromkeys(("calibrate_many_distributed", "map_dataset", "map_thresholds",
                     "min_stable_tg_samples", "models_from_bootstrap", "open_map",
                     "stability_probability", "sweep", "write_map"), "maps"),
    **dict.fromkeys(("BatchSimulation", "Trajectory", "batch_cost", "closed_loop", "platoon",
                     "simulate", "simulate_batch", "simulate_full"), "rollout"),
    **dict.fromkeys(("Extremum", "PadeReport", "Thresholds", "boundary", "capacity",
                     "exact_delay_codes", "kv_supremum", "kv_threshold", "min_stable_tg",
                     "pade_error_map", "pade_report", "stability_map", "stability_points",
                     "stable_intervals", "thresholds"), "stability"),
    **dict.fromkeys(("Intervals", "Uncertainty"), "uncertainty"),
}

__all__ = ["io", "synth", "datasets", "__version__", "DataError", "DataWarning",
           "PlausibilityWarning", "Run", "MODELS", "FirstOrderLag", "LowerLevelModel", "Proposed",
           "SecondOrder", "UpperLevel", "model_class", "PAPER_TABLE_II", *_LAZY_NAMES]

if TYPE_CHECKING:  # pragma: no cover - for type checkers; imported lazily below
    from . import cli as cli
    from . import datasets, io, synth
    from . import plotting as plotting
    from . import progress as progress
    from ._atomic import read_manifest
    from .calibration import (
        Bootstrap,
        CalibrationResult,
        Workflow,
        bootstrap,
        calibrate,
        calibrate_many,
        paper_workflow,
    )
    from .diagnose.contract import model_from_dict, simulate_run
    from .effects import (
        EFFECTS,
        Asymmetric,
        Closing,
        Comfort,
        Deadband,
        Delay,
        Feedforward,
        Grade,
        Perception,
        PowerLimit,
        RateLimit,
        RoadLoad,
        Saturation,
        Sensor,
        SpeedDrag,
        SpeedGains,
        WithEffects,
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
    from .paper import TABLE_II as PAPER_TABLE_II
    from .rollout import (
        BatchSimulation,
        Trajectory,
        batch_cost,
        closed_loop,
        platoon,
        simulate,
        simulate_batch,
        simulate_full,
    )
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
    from .uncertainty import Intervals, Uncertainty

# Submodules are imported on first access (``avll.io`` brings pandas, ``avll.plotting``
# matplotlib on first drawing, ``avll.datasets`` pooch: ``import avll`` alone needs none).


def __getattr__(name: str) -> Any:
    """Imports the public names of ``_LAZY_NAMES`` (from their module), the public
    submodules and ``PAPER_TABLE_II`` (Table II of the paper, :data:`avll.paper.TABLE_II`)
    on first access."""
    import importlib
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        val: Any = importlib.import_module(f".{name}", __name__)
    elif name == "PAPER_TABLE_II":
        val = importlib.import_module(".paper", __name__).TABLE_II
    elif name in _LAZY_NAMES:
        val = getattr(importlib.import_module(f".{_LAZY_NAMES[name]}", __name__), name)
    else:
        raise AttributeError(f"module 'avll' has no attribute {name!r}")
    globals()[name] = val
    return val


def __dir__() -> list[str]:
    """The module's names including the lazily imported ones and every public submodule
    (not the typing helpers this file imports for itself)."""
    import pkgutil

    subs = {m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")}
    return sorted({n for n in globals() if n.startswith("_")} | set(__all__) | subs)
