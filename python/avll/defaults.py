"""Defaults, defined once: the GA's search boxes and options (the options read from
the Rust core, which also validates them), the objective weightings of open- and
closed-loop calibrations, the at-bound tolerance, the confidence level, the upper-level
placeholder of runs without an upper law, the synthetic experiments' length, sample time
and noise, and the figure styles (one colour per model and per stability class) every
command and the report use.

The bounds' reasons are :data:`BOUND_REASONS` (printed beside them in the docs).
"""

from __future__ import annotations

import numbers
from typing import Any

from . import _core
from ._limits import check_weights
from .models import UpperLevel

__all__ = [
    "Bound",
    "DEFAULT_BOUNDS",
    "DEFAULT_STARTS",
    "UPPER_BOUNDS",
    "BOUND_REASONS",
    "UPPER_NAMES",
    "upper_index",
    "AT_BOUND_TOL",
    "LEVEL",
    "GA_OPTIONS",
    "EQ6_WEIGHTS",
    "CLOSED_LOOP_WEIGHTS",
    "objective_weights",
    "UPPER_PLACEHOLDER",
    "SYNTH_DURATION",
    "SYNTH_DT",
    "SYNTH_NOISE",
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
#: Why each default bound is what it is (physical reasons; ``"model.param"`` overrides
#: ``"param"``). The generated bounds table of the docs prints them beside the values.
BOUND_REASONS: dict[str, str] = {
    "first.Td": "the lag's time constant: a powertrain and brake answer an acceleration "
                "command in a fraction of a second to about a second; the paper bounds it "
                "by 3 s, and the lower end keeps it positive at less than one sample of "
                "20 Hz data (indistinguishable from no lag)",
    "Td": "dead time: sensing, CAN, engine and brake-hydraulics delays of production "
          "ACCs are tenths of a second to about a second; 3 s is the paper's bound, far "
          "beyond any car that still follows",
    "K0": "static gain from command to acceleration: 1 for an ideal actuator, below 1 "
          "for a sluggish one; a negative gain would reverse the command. Up to 3 leaves "
          "room for closed-loop fits, where it trades against the upper gains",
    "m1": "the zero's time constant: at or below the lower end the zero lies beyond "
          "1000 rad/s, indistinguishable from the paper's m1 = 0 at 20 Hz; 100 s is far "
          "slower than any actuator",
    "m2": "sqrt(m2) is the second-order time scale: from below one sample of 20 Hz "
          "data to 10 s, slower than any vehicle's actuation",
    "m3": "damping time constant: from a millisecond (no effect at 20 Hz) to 100 s, far "
          "beyond the paper's fitted values",
    "K": "inner feedback gain: with |K K0| near 1 the inner loop is already marginal "
         "(such parameters cost inf), so [-3, 3] holds every stable inner loop with a "
         "gain K0 above 1/3",
    "kg": "gap gain of Eq. 3 (1/s²): identified production ACCs have gains of order "
          "0.01-1; beyond a few 1/s² a lower level with tenths of a second of delay is "
          "locally unstable",
    "kv": "speed-difference gain of Eq. 3 (1/s): the same range as kg, for the same "
          "reason",
    "Tg": "time gap: production ACC settings are about 1 to 2.5 s; 5 s leaves room for a "
          "fit that trades the time gap against the standstill distance",
    "Gmin": "standstill distance: a few metres in practice; 30 m covers spacing "
            "policies whose offset absorbs part of the time gap at speed",
}

#: The upper-level gains (Eq. 3) in the order of :class:`avll.UpperLevel`.
UPPER_NAMES: tuple[str, ...] = ("kg", "kv", "Tg", "Gmin")


def upper_index(u: int | str) -> int:
    """An entry of ``upper_free`` (a name of :data:`UPPER_NAMES` or its index 0..3) as
    the index, or a ``ValueError`` naming ``upper_free`` (never truncated: 0.7 and
    ``True`` are refused)."""
    if isinstance(u, str) and u in UPPER_NAMES:
        return UPPER_NAMES.index(u)
    if isinstance(u, numbers.Integral) and not isinstance(u, bool) and 0 <= u < 4:
        return int(u)
    raise ValueError(f"upper_free: expected a gain name ({', '.join(UPPER_NAMES)}) or its "
                     f"index 0..3, got {u!r}")

#: A fitted parameter within this share of its search box (in the box's own scale,
#: logarithmic for log-scaled parameters) of a bound is "at bound": the rule of
#: :attr:`avll.calibration.CalibrationResult.at_bound`, of the diagnosis's
#: :func:`avll.diagnose.fitting.at_bound` and of the intervals (:mod:`avll.uncertainty`).
AT_BOUND_TOL: float = 1e-3

#: Confidence level of every interval by default: bootstraps, parameter intervals, the
#: band gain's, the diagnosis's gains and the OpenACC study's amplification ratios.
LEVEL: float = 0.95

#: The GA's tunable options with their defaults, as the Rust core defines them
#: (``GaOptions::default()``, exported by ``avll._core.ga_defaults``; the core also
#: checks given values: ``avll._core.ga_check``). ``seed`` and ``target`` are arguments
#: of :func:`avll.calibrate` of their own. A ``None`` budget in a signature
#: (``max_generations=None``, ``pop_size=None``) means the value here.
GA_OPTIONS: dict[str, Any] = dict(_core.ga_defaults())

#: Objective weights ``(wa, wv, wx)`` of an open-loop calibration: the paper's Eq. 6,
#: the mean squared error of the acceleration alone.
EQ6_WEIGHTS: tuple[float, float, float] = (1.0, 0.0, 0.0)

#: Objective weights ``(wa, wv, wx)`` of every closed-loop calibration (the default of
#: ``weights=None`` with ``closed_loop=True`` in :func:`avll.calibrate`, the batched
#: costs and ``avll calibrate``; the diagnosis loop, the AstaZero ``"mixed"``
#: objective, the OpenACC study): the mean squared errors of acceleration (m/s²)²,
#: speed (m/s)² and position (m²). In closed loop the upper law's spacing (``Tg``,
#: ``Gmin``) acts on the gap, which the acceleration alone barely sees, and a measured
#: acceleration is often a differentiated speed (noise times 1/dt), so speed and
#: position carry weight too. The weights make errors of 0.1 m/s², 0.1 m/s and 1 m
#: cost the same (1 x 0.1² = 1 x 0.1² = 0.01 x 1²): errors of the order of the
#: sensors' and of practical relevance to a following car.
CLOSED_LOOP_WEIGHTS: tuple[float, float, float] = (1.0, 1.0, 0.01)


def objective_weights(weights: Any, closed_loop: bool) -> tuple[float, float, float]:
    """The objective weights a call uses: ``weights`` checked (three finite floats
    ``>= 0``, not all zero), or for ``None`` the default of its loop,
    :data:`CLOSED_LOOP_WEIGHTS` in closed loop and :data:`EQ6_WEIGHTS` in open loop."""
    if weights is None:
        return CLOSED_LOOP_WEIGHTS if closed_loop else EQ6_WEIGHTS
    return check_weights(weights)

#: Upper-level law given to runs that have none (OpenACC pairs) before all four gains
#: are calibrated: only a starting point, never a result.
UPPER_PLACEHOLDER = UpperLevel(kg=0.1, kv=0.5, Tg=1.0, Gmin=5.0)

#: The synthetic experiments' run length (s; :func:`avll.synth.paper_experiment`,
#: ``avll synth``, ``avll reproduce``) and sample time (s, 20 Hz), and their sensors: the
#: standard deviations of the measured acceleration (m/s²), speed (m/s) and position (m)
#: and the acceleration's quantization step (m/s²), by argument name.
SYNTH_DURATION, SYNTH_DT = 180.0, 0.05
SYNTH_NOISE: dict[str, float] = {"noise_a": 0.05, "noise_v": 0.02, "noise_x": 0.02,
                                 "quantization_a": 0.01}

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
