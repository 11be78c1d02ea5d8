"""The paper's constants, defined once: its models' order and names, Table I (the
experiment), Table II (the calibrated parameters), the calibration runs, the grid on
which Section IV is reproduced and the published numbers of Tables III-IV and
Section IV (the reference ``avll reproduce`` compares with).

Liu et al., "Experimental study and modeling of the lower-level controller of
automated vehicle" (/work/shared/paper).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .models import GMIN, PADE_ORDER, FirstOrderLag, LowerLevelModel, Proposed, SecondOrder

__all__ = [
    "MODELS",
    "G",
    "MODEL_LABELS",
    "MODEL_TITLES",
    "TABLE_I",
    "TABLE_II_PARAMS",
    "TABLE_II",
    "PAPER_CAL_RUNS",
    "PAPER_VAL_RUNS",
    "GMIN",
    "PADE_ORDER",
    "SECTION_IV_GRID",
    "section_iv_axis",
    "PAPER",
]

#: The three lower-level models, in the paper's order of presentation.
MODELS: tuple[str, ...] = ("first", "second", "proposed")

#: Short names of the models (figure legends, report tables).
MODEL_LABELS: dict[str, str] = {
    "first": "first-order lag",
    "second": "second-order",
    "proposed": "proposed",
}

#: The paper's table row names of the models (Tables III-IV).
MODEL_TITLES: dict[str, str] = {
    "first": "First-order lag model",
    "second": "Second-order response model",
    "proposed": "The proposed model",
}

#: Table I: (kg in s^-2, Tg in s) of each run, in chronological order.
TABLE_I: dict[int, tuple[float, float]] = {
    1: (0.7, 2.0), 2: (0.7, 2.0), 3: (0.5, 1.8), 4: (0.5, 1.8), 5: (0.5, 1.8),
    6: (0.5, 1.8), 7: (0.5, 1.8), 8: (0.6, 2.0), 9: (0.6, 2.0), 10: (0.6, 2.0),
    11: (0.6, 2.0), 12: (0.6, 2.0), 13: (0.6, 2.0), 14: (0.6, 2.0), 15: (0.5, 2.0),
    16: (0.5, 2.0), 17: (0.5, 2.0), 18: (0.5, 2.0), 19: (0.4, 2.0), 20: (0.4, 2.0),
    21: (0.4, 2.0),
}  # fmt: skip

#: The paper's calibration runs (Table III); the others are its validation runs (Table IV).
PAPER_CAL_RUNS: tuple[int, ...] = (3, 4, 5, 9, 10, 11, 15, 16, 17, 19)
#: The paper's validation runs (Table IV).
PAPER_VAL_RUNS: tuple[int, ...] = tuple(r for r in TABLE_I if r not in PAPER_CAL_RUNS)

#: Standard gravity (m/s²): a road grade ``g`` (rise over run) pulls a car with
#: ``-G g``, wherever a grade becomes an acceleration.
G = 9.81

#: Table II: the calibrated parameters of the three models (s, s^2, and 1 for gains).
TABLE_II_PARAMS: dict[str, dict[str, float]] = {
    "first": {"Td": 1.0758},
    "second": {"K0": 0.7292, "m2": 0.0445, "m3": 0.1305, "Td": 0.7796},
    "proposed": {"m1": 6.7893, "m2": 1.2824, "m3": 8.8157, "K0": 0.3479, "Td": 0.7903,
                 "K": 0.1008},
}

#: Table II as models.
TABLE_II: dict[str, LowerLevelModel] = {
    "first": FirstOrderLag(**TABLE_II_PARAMS["first"]),
    "second": SecondOrder(**TABLE_II_PARAMS["second"]),
    "proposed": Proposed(**TABLE_II_PARAMS["proposed"]),
}

#: The grid on which Section IV is reproduced (``avll reproduce``, the README, the
#: docs, ``avll stability-map``): each axis ``(first, last, points)``, kg log-spaced,
#: Tg and kv evenly; the Padé order of the delay; the kv threshold bisected to
#: ``kv_tol`` on a Tg grid of step ``kv_tg_step``. The paper gives its thresholds for
#: Tg in [0, 15] s at 0.1 s resolution; they depend on how close to 0 the kg grid
#: goes, hence the stated ``kg`` axis.
SECTION_IV_GRID: dict[str, Any] = {
    "kg": (1e-3, 5.0, 400),
    "Tg": (0.0, 15.0, 151),
    "kv": (0.0, 1.2, 121),
    "pade_order": PADE_ORDER,
    "kv_tg_step": 0.05,
    "kv_tol": 1e-5,
}


def section_iv_axis(first: float, last: float, points: int, log: bool = False) -> np.ndarray:
    """An axis ``(first, last, points)`` as :data:`SECTION_IV_GRID` gives it: log-spaced
    with ``log``, else evenly spaced and rounded to 10 decimals, or to 4 more than the
    step's first significant decimal when the step is finer than 1e-6 (so that 0.1-steps
    are the decimal values and no fine step is rounded away)."""
    if log:
        return np.geomspace(first, last, int(points))
    step = abs(last - first) / max(int(points) - 1, 1)
    return np.round(np.linspace(first, last, int(points)),
                    max(10, 4 - math.floor(math.log10(step))) if step > 0 else 10)


#: The paper's published numbers (Tables II–IV, Section IV).
PAPER: dict[str, Any] = {
    "params": TABLE_II_PARAMS,
    "cal_mse": {"proposed": 0.0398, "second": 0.0551, "first": 0.1232},
    "val_mse": {"proposed": 0.0871, "second": 0.1213, "first": 0.2587},
    "cal_runs": {  # Table III
        "proposed": {"3": 0.03, "4": 0.03, "5": 0.05, "9": 0.04, "10": 0.05, "11": 0.06,
                     "15": 0.04, "16": 0.03, "17": 0.03, "19": 0.05},
        "second": {"3": 0.04, "4": 0.04, "5": 0.07, "9": 0.06, "10": 0.07, "11": 0.07,
                   "15": 0.05, "16": 0.04, "17": 0.04, "19": 0.06},
        "first": {"3": 0.09, "4": 0.08, "5": 0.14, "9": 0.17, "10": 0.17, "11": 0.18,
                  "15": 0.12, "16": 0.09, "17": 0.09, "19": 0.12},
    },
    "val_runs": {  # Table IV
        "proposed": {"1": 0.11, "2": 0.10, "6": 0.08, "7": 0.16, "8": 0.07, "12": 0.06,
                     "13": 0.07, "14": 0.07, "18": 0.06, "20": 0.07, "21": 0.11},
        "second": {"1": 0.16, "2": 0.13, "6": 0.13, "7": 0.22, "8": 0.09, "12": 0.08,
                   "13": 0.09, "14": 0.10, "18": 0.09, "20": 0.10, "21": 0.15},
        "first": {"1": 0.37, "2": 0.30, "6": 0.25, "7": 0.41, "8": 0.23, "12": 0.19,
                  "13": 0.22, "14": 0.24, "18": 0.18, "20": 0.19, "21": 0.27},
    },
    "kv_threshold": {"second": 0.8085, "proposed": 0.7395, "first": None},
    "min_tg": {"second": 1.9, "proposed": 3.5, "first": 2.2},
    "capacity": {"second": 1687.5, "proposed": 964.3, "first": 1479.5},
    "capacity_proposed_vs_second_pct": 42.86,  # % lower
    "capacity_first_vs_proposed_pct": 53.42,  # % larger
}
