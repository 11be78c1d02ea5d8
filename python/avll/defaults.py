"""Defaults, defined once: the GA's search boxes and options, the upper-level
placeholder of runs without an upper law, and the figure styles (one colour per model
and per stability class) every command and the report use.

The bounds are explained in :mod:`avll.calibrate`.
"""

from __future__ import annotations

from typing import Any

from .models import UpperLevel

__all__ = [
    "Bound",
    "DEFAULT_BOUNDS",
    "DEFAULT_STARTS",
    "UPPER_BOUNDS",
    "UPPER_NAMES",
    "GA_OPTIONS",
    "UPPER_PLACEHOLDER",
    "MODEL_COLORS",
    "MODEL_LINESTYLES",
    "CLASS_COLORS",
    "CLASS_LABELS",
    "MEASURED_COLOR",
]

#: A search-box entry: ``(lower, upper, scale)`` with scale ``"linear"`` or ``"log"``.
Bound = tuple[float, float, str]

#: Default search box per model: ``name -> (lower, upper, scale)``; see the module doc.
DEFAULT_BOUNDS: dict[str, dict[str, Bound]] = {
    "first": {"Td": (0.01, 3.0, "linear")},
    "second": {
        "K0": (0.0, 3.0, "linear"),
        "m2": (1e-3, 100.0, "log"),
        "m3": (1e-3, 100.0, "log"),
        "Td": (0.0, 3.0, "linear"),
    },
    "proposed": {
        "m1": (1e-4, 100.0, "log"),
        "m2": (1e-3, 100.0, "log"),
        "m3": (1e-3, 100.0, "log"),
        "K0": (0.0, 3.0, "linear"),
        "Td": (0.0, 3.0, "linear"),
        "K": (-3.0, 3.0, "linear"),
    },
}

#: Independent GA starts of a calibration (the best is kept): on the proposed model a
#: start occasionally settles in a corner local minimum, so two by default.
DEFAULT_STARTS: int = 2

#: Default box of the upper-level gains when they are calibrated (``upper_free``).
UPPER_BOUNDS: dict[str, Bound] = {
    "kg": (0.0, 3.0, "linear"),
    "kv": (0.0, 3.0, "linear"),
    "Tg": (0.0, 5.0, "linear"),
    "Gmin": (0.0, 30.0, "linear"),
}
#: The upper-level gains (Eq. 3) in the order of :class:`avll.UpperLevel`.
UPPER_NAMES: tuple[str, ...] = ("kg", "kv", "Tg", "Gmin")

#: GA options passed through to the Rust core, with their defaults.
GA_OPTIONS: dict[str, Any] = {
    "pop_size": 0,
    "max_generations": 300,
    "stall_generations": 20,
    "ftol": 1e-4,
    "xtol": 1e-8,
    "tournament": 2,
    "crossover_prob": 0.9,
    "eta_c": 10.0,
    "mutation_prob": 0.0,
    "eta_m": 20.0,
    "plus": True,
    "elite": 0,
    "polish": True,
    "polish_max_evals": 0,
    "local_every": 3,
    "local_evals": 0,
}

#: Upper-level law given to runs that have none (OpenACC pairs) before all four gains
#: are calibrated: only a starting point, never a result.
UPPER_PLACEHOLDER = UpperLevel(kg=0.1, kv=0.5, Tg=1.0, Gmin=5.0)

#: One colour per lower-level model, in every figure.
MODEL_COLORS: dict[str, str] = {
    "first": "tab:orange",
    "second": "tab:green",
    "proposed": "tab:blue",
}

#: One line style per lower-level model (simulated traces).
MODEL_LINESTYLES: dict[str, str] = {"first": ":", "second": "--", "proposed": "-"}

#: Colour of measured (or synthetic "measured") data.
MEASURED_COLOR = "black"

#: One colour per stability class (code of :func:`avll.stability_map`).
CLASS_COLORS: dict[int, str] = {0: "#d9d9d9", 1: "#fdb863", 2: "#5aae61"}

#: Meaning of each stability class.
CLASS_LABELS: dict[int, str] = {
    0: "locally unstable",
    1: "locally stable, string unstable",
    2: "locally and string stable",
}
