"""Simulation and per-run errors for the residual loop: the runs' simulated
acceleration (:func:`simulate_runs`), per-run errors (:func:`run_mse`), the loop's
objective weights (:func:`default_weights`) and which fitted parameters sit at a bound
of the search box (:func:`at_bound`, in the box of
:func:`avll.calibration.default_bounds`). The loop's fits are :func:`avll.calibrate`
itself. Each takes an :class:`avll.RunSet` (a list of runs is packed once)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import _core
from .._limits import check_threads
from ..calibration import default_bounds
from ..data import Run
from ..defaults import AT_BOUND_TOL, CLOSED_LOOP_WEIGHTS, DEFAULT_BOUNDS, EQ6_WEIGHTS
from ..defaults import UPPER_BOUNDS as _UB
from ..defaults import UPPER_NAMES as _UPPER_NAMES
from ..effects import EFFECTS, WithEffects, exo_needs
from ..models import UpperLevel
from ..rollout import batch_cost
from ..runs import RunSet, as_runset

__all__ = [
    "AtBound",
    "BASE_BOUNDS",
    "UPPER_BOUNDS",
    "CLOSED_LOOP_WEIGHTS",
    "SPEED_COMMAND_WEIGHTS",
    "default_weights",
    "calibrate_kw",
    "simulate_runs",
    "run_mse",
    "at_bound",
]

#: Search box of the base models: ``name -> (lower, upper, scale)`` — the same box
#: as :func:`avll.calibrate` (:data:`avll.calibration.DEFAULT_BOUNDS`), so that a
#: diagnosis and a calibration of the same data answer the same question.
BASE_BOUNDS: dict[str, dict[str, tuple[float, float, str]]] = DEFAULT_BOUNDS



def _init(runs: Any, init: str) -> str:
    """``"auto"``: a speed command starts at its steady state (a run that begins
    while driving), an acceleration command at rest (the paper's experiment)."""
    if init == "auto":
        return "steady" if runs and runs[0].command_kind == "speed" else "rest"
    if init not in ("rest", "steady"):
        raise ValueError(f"init: must be 'auto', 'rest' or 'steady', got {init!r}")
    return init


def _closed(runs: Any, closed_loop: bool | None) -> bool:
    if closed_loop is not None:
        return bool(closed_loop)
    return any(r.command is None for r in runs)


def _setup(runs: RunSet | Sequence[Run], closed_loop: bool | None,
           init: str) -> tuple[RunSet, bool, str]:
    """The run set (packed once if a list) and the resolved ``closed_loop`` and ``init``."""
    rs = as_runset(runs)
    return rs, _closed(rs, closed_loop), _init(rs, init)


def calibrate_kw(runs: Sequence[Run], closed_loop: bool | None = None,
                 init: str = "auto") -> dict[str, Any]:
    """The keywords :func:`avll.calibrate` fits the loop's models with on ``runs``:
    ``closed_loop`` (default: when a run has no command), ``init`` (``"auto"``: see
    :func:`simulate_runs`), ``upper_free`` (in closed loop, all four gains when a run
    has no upper-level law) and ``weights`` (:func:`default_weights`)."""
    runs = list(runs)
    closed = _closed(runs, closed_loop)
    speed = runs[0].command_kind == "speed" and all(r.v is not None for r in runs)
    return {"closed_loop": closed, "init": _init(runs, init),
            "upper_free": _UPPER_NAMES if closed and any(r.upper is None for r in runs) else (),
            "weights": default_weights(closed, speed)}  # fmt: skip


#: Parameter rows x samples of one batched simulation (its three outputs take 24 bytes
#: per row and sample): more rows are simulated in several calls.
BATCH = 4_000_000


def _simulate(model: WithEffects, rows: np.ndarray, rs: RunSet, closed: bool, init: str,
              upper: UpperLevel | None = None, threads: int = 0) -> np.ndarray:
    """The simulated acceleration (P, samples of every run) of the parameter rows
    ``[base | effects]`` of ``model``'s structure on ``rs``, in batched calls of at most
    :data:`BATCH` row-samples.
    ``upper`` (default: the run set's, :meth:`avll.RunSet.with_upper`) replaces the
    runs' upper-level law: its gains enter every row as free gains."""
    up = upper if upper is not None else rs.upper
    rows = np.atleast_2d(np.asarray(rows, dtype=np.float64))
    if up is not None:
        rows = np.hstack([rows, np.tile(up.to_array(), (rows.shape[0], 1))])
    free = [0, 1, 2, 3] if up is not None else []
    kw = rs.cost_kw(init=init, closed_loop=closed, upper_free=free,
                    exo=exo_needs(model.effect_names))  # fmt: skip
    per_call = max(1, BATCH // max(rs.total, 1))
    return np.vstack([np.asarray(_core.simulate_batch(
        model.base.name, np.ascontiguousarray(rows[i : i + per_call]),
        effects=list(model.effect_names), threads=check_threads(threads), **kw))[0]
        for i in range(0, rows.shape[0], per_call)])  # fmt: skip


def _split(a: np.ndarray, rs: RunSet) -> list[np.ndarray]:
    """A row of samples of every run, cut into the runs."""
    off = rs.offsets
    return [a[off[j] : off[j + 1]] for j in range(len(rs))]


def simulate_runs(
    model: WithEffects, runs: RunSet | Sequence[Run], *, closed_loop: bool | None = None,
    init: str = "auto", upper: UpperLevel | None = None, threads: int = 0,
) -> list[np.ndarray]:
    """The simulated acceleration of every run (open loop from the recorded command,
    or closed loop behind the recorded leader), as in the calibration cost: one
    batched call on the run set (``runs`` packed once if a list). ``init="auto"``: a
    speed command starts at its steady state (a run that begins while driving), an
    acceleration command at rest (the paper's experiment). ``upper`` replaces the
    runs' upper-level law (default: the run set's, :meth:`avll.RunSet.with_upper`)."""
    rs, closed, init = _setup(runs, closed_loop, init)
    return _split(_simulate(model, model.to_array(), rs, closed, init, upper, threads)[0], rs)


def run_mse(
    model: WithEffects, runs: RunSet | Sequence[Run], *, closed_loop: bool | None = None,
    init: str = "auto", threads: int = 0, upper: UpperLevel | None = None,
) -> np.ndarray:
    """Per-run MSE of the acceleration (paper Eq. 6 per run); ``inf`` if unstable. The
    one per-run error of the diagnosis: the Rust batched cost on the run set."""
    rs, closed, init = _setup(runs, closed_loop, init)
    up = upper if upper is not None else rs.upper
    row = model.to_array() if up is None else np.r_[model.to_array(), up.to_array()]
    return batch_cost(model, row[None, :], rs, closed_loop=closed, init=init, threads=threads,
                      upper_free=[0, 1, 2, 3] if up is not None else [],
                      weights=EQ6_WEIGHTS)[0]  # the acceleration's MSE in either loop


def _fixed(effect: str, param: str, kind: str) -> float | None:
    """Parameters that a command kind fixes (:attr:`avll.effects.Effect.fixed`: a speed
    command has no braking gain)."""
    return EFFECTS[effect].fixed.get(kind, {}).get(param)


#: Search box of the upper-level law when it is calibrated (closed loop, no known
#: law): the same as :func:`avll.calibrate`'s.
UPPER_BOUNDS: dict[str, tuple[float, float]] = {k: (lo, hi) for k, (lo, hi, _) in _UB.items()}

#: Objective weights of a speed command, whose response is the speed (the acceleration
#: alone leaves the static gain free).
SPEED_COMMAND_WEIGHTS: tuple[float, float, float] = (1.0, 1.0, 0.0)


def default_weights(closed: bool, speed: bool = False) -> tuple[float, float, float]:
    """The loop's objective weights ``(wa, wv, wx)``: :data:`avll.defaults.CLOSED_LOOP_WEIGHTS`
    in closed loop (the acceleration alone leaves the upper law's spacing unidentified),
    :data:`SPEED_COMMAND_WEIGHTS` for a ``speed`` command with a measured speed,
    otherwise the paper's Eq. 6 (:data:`avll.defaults.EQ6_WEIGHTS`). The loop reports
    acceleration MSEs."""
    if closed:
        return CLOSED_LOOP_WEIGHTS
    return SPEED_COMMAND_WEIGHTS if speed else EQ6_WEIGHTS


@dataclass(frozen=True)
class AtBound:
    """A fitted parameter at a bound of its search box: its name (``upper.kg`` for a
    calibrated upper-level gain), value, which bound (``"lower"`` or ``"upper"``) and
    the box."""

    param: str
    value: float
    bound: str
    lower: float
    upper: float


def at_bound(
    model: WithEffects,
    upper: UpperLevel | None = None,
    kind: str = "acceleration",
    tol: float = AT_BOUND_TOL,
    upper_bounds: Mapping[str, tuple[float, float]] | None = None,
) -> tuple[AtBound, ...]:
    """The parameters of ``model`` (and of a calibrated ``upper`` law) that sit within
    ``tol`` of a bound of the box :func:`avll.calibrate` searched (share of the box, in
    its own linear or logarithmic scale; fixed parameters are left out). Such a value
    is the edge of the search, not an estimate: widen the bound or doubt the effect.
    ``upper_bounds`` are the upper-law boxes the fit was given (default
    :data:`UPPER_BOUNDS`)."""
    box = default_bounds(model.base.name, _UPPER_NAMES if upper is not None else (),
                         model.effect_names, kind)
    for k, (lo_k, hi_k) in (upper_bounds or {}).items():
        if k not in _UB:
            raise ValueError(f"upper_bounds: unknown gain {k!r}; known: {', '.join(_UB)}")
        box[k] = (float(lo_k), float(hi_k), "linear")
    names = [f"upper.{n}" if n in _UB else n for n in box]
    values = list(model.to_array())
    if upper is not None:
        values.extend(float(x) for x in upper.to_array())
    out = []
    for n, v, (a, b, scale) in zip(names, values, box.values(), strict=True):
        if not a < b:
            continue
        if scale == "log":
            u = (np.log(max(v, 1e-300)) - np.log(a)) / (np.log(b) - np.log(a))
        else:
            u = (v - a) / (b - a)
        if u <= tol or u >= 1.0 - tol:
            out.append(AtBound(n, float(v), "lower" if u <= tol else "upper", float(a), float(b)))
    return tuple(out)
