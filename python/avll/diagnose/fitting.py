"""Simulation and calibration for the residual loop: the runs' simulated
acceleration, per-run errors, and the loop's fit (:func:`fit_full`: the one
calibration, :func:`avll.calibrate` through :func:`avll.calibration.calibrate_effects`,
in the box of :func:`avll.calibration.default_bounds`). Each takes an
:class:`avll.RunSet` (a list of runs is packed once)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize

from .. import _core
from .._limits import check_seed, check_threads
from ..calibration import calibrate_effects, default_bounds
from ..data import Run
from ..defaults import CLOSED_LOOP_WEIGHTS, DEFAULT_BOUNDS, DEFAULT_STARTS, GA_OPTIONS
from ..defaults import UPPER_BOUNDS as _UB
from ..defaults import UPPER_NAMES as _UPPER_NAMES
from ..effects import EFFECTS, WithEffects, canonical, exo_needs
from ..models import LowerLevelModel, UpperLevel, model_class
from ..rollout import batch_cost
from ..runs import RunSet, as_runset

__all__ = [
    "BASE_BOUNDS",
    "UPPER_BOUNDS",
    "CLOSED_LOOP_WEIGHTS",
    "DE_POP_SIZE",
    "SPEED_COMMAND_WEIGHTS",
    "simulate_runs",
    "run_mse",
    "fit_full",
    "fit",
    "at_bound",
]

#: Search box of the base models: ``name -> (lower, upper, scale)`` — the same box
#: as :func:`avll.calibrate` (:data:`avll.calibration.DEFAULT_BOUNDS`), so that a
#: diagnosis and a calibration of the same data answer the same question.
BASE_BOUNDS: dict[str, dict[str, tuple[float, float, str]]] = DEFAULT_BOUNDS

#: A fitted parameter within this share of its search box (in the box's own scale,
#: logarithmic for log-scaled parameters) of a bound is reported "at bound": the
#: rule of :attr:`avll.calibration.CalibrationResult.at_bound`.
AT_BOUND_TOL: float = 1e-3

def _init(runs: Any, init: str) -> str:
    """``"auto"``: a speed command starts at its steady state (a run that begins
    while driving), an acceleration command at rest (the paper's experiment)."""
    if init == "auto":
        runs = runs.runs if isinstance(runs, RunSet) else runs
        return "steady" if runs and runs[0].command_kind == "speed" else "rest"
    if init not in ("rest", "steady"):
        raise ValueError(f"init: must be 'auto', 'rest' or 'steady', got {init!r}")
    return init


def _closed(runs: Any, closed_loop: bool | None) -> bool:
    if closed_loop is not None:
        return bool(closed_loop)
    runs = runs.runs if isinstance(runs, RunSet) else runs
    return any(r.command is None for r in runs)


def _row(model: WithEffects, upper: UpperLevel | None) -> tuple[np.ndarray, list[int]]:
    """The parameter row of ``model`` (and of an upper-level law that replaces the
    runs' own: every gain free) and the free gains."""
    row = np.asarray(model.to_array(), dtype=np.float64)
    if upper is None:
        return row[None, :], []
    return np.concatenate([row, upper.to_array()])[None, :], [0, 1, 2, 3]


def simulate_runs(
    model: WithEffects, runs: RunSet | Sequence[Run], *, closed_loop: bool | None = None,
    init: str = "auto", upper: UpperLevel | None = None, threads: int = 0,
) -> list[np.ndarray]:
    """The simulated acceleration of every run (open loop from the recorded command,
    or closed loop behind the recorded leader), as in the calibration cost: one
    batched call on the run set (``runs`` packed once if a list). ``upper`` replaces
    the runs' upper-level law (default: the run set's, :meth:`avll.RunSet.with_upper`)."""
    rs = as_runset(runs)
    closed = _closed(rs, closed_loop)
    row, free = _row(model, upper if upper is not None else rs.upper)
    kw = rs.cost_kw(init=_init(rs, init), closed_loop=closed, upper_free=free,
                    exo=exo_needs(model.effect_names))  # fmt: skip
    d = _core.simulate_batch(model.base.name, row, effects=list(model.effect_names),
                             threads=check_threads(threads), **kw)  # fmt: skip
    off = rs.offsets
    return [np.asarray(d[0, 0, off[j] : off[j + 1]]) for j in range(len(rs))]


def run_mse(
    model: WithEffects, runs: RunSet | Sequence[Run], *, closed_loop: bool | None = None,
    init: str = "auto", threads: int = 0, upper: UpperLevel | None = None,
) -> np.ndarray:
    """Per-run MSE of the acceleration (paper Eq. 6 per run); ``inf`` if unstable. The
    one per-run error of the diagnosis: the Rust batched cost on the run set."""
    rs = as_runset(runs)
    row, free = _row(model, upper if upper is not None else rs.upper)
    c = batch_cost(model, row, rs, closed_loop=_closed(rs, closed_loop), init=_init(rs, init),
                   threads=threads, upper_free=free)
    return c[0]


@dataclass(frozen=True)
class _Space:
    names: tuple[str, ...]
    lo: np.ndarray
    hi: np.ndarray
    log: np.ndarray

    def to_z(self, p: np.ndarray) -> np.ndarray:
        p = np.clip(np.asarray(p, dtype=np.float64), self.lo, self.hi)
        z = np.where(self.log, np.log(np.where(self.log, np.maximum(p, 1e-300), 1.0)), p)
        zl, zh = self.zbounds()
        return (z - zl) / np.where(zh > zl, zh - zl, 1.0)

    def zbounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.where(self.log, np.log(np.where(self.log, self.lo, 1.0)), self.lo)
        hi = np.where(self.log, np.log(np.where(self.log, self.hi, 1.0)), self.hi)
        return lo, hi

    def from_z(self, z: np.ndarray) -> np.ndarray:
        zl, zh = self.zbounds()
        w = zl + np.asarray(z) * (zh - zl)
        return np.where(self.log, np.exp(w), w)


def _fixed(effect: str, param: str, kind: str) -> float | None:
    """Parameters that a command kind fixes (:attr:`avll.effects.Effect.fixed`: a speed
    command has no braking gain)."""
    return EFFECTS[effect].fixed.get(kind, {}).get(param)


def _space(base: str, effects: Sequence[str], kind: str = "acceleration",
           upper_free: bool = False,
           upper_bounds: Mapping[str, tuple[float, float]] | None = None) -> _Space:
    """The search box of :func:`avll.calibration.default_bounds` (the free upper gains'
    entries replaced by ``upper_bounds``)."""
    box = default_bounds(base, _UPPER_NAMES if upper_free else (), effects, kind)
    for k, b in (upper_bounds or {}).items():
        if k not in _UB:
            raise ValueError(f"upper_bounds: unknown gain {k!r}; known: {', '.join(_UB)}")
        box[k] = (float(b[0]), float(b[1]), "linear")
    lo, hi, sc = zip(*box.values(), strict=True)
    return _Space(tuple(box), np.array(lo, dtype=float), np.array(hi, dtype=float),
                  np.array([s == "log" for s in sc]))


def _polish(f: Callable[[np.ndarray], np.ndarray], z0: np.ndarray, max_iter: int) -> np.ndarray:
    h = 1e-5
    k = z0.size

    def fg(z: np.ndarray) -> tuple[float, np.ndarray]:
        pts = [z]
        for j in range(k):
            e = np.zeros(k)
            e[j] = h
            pts.append(np.clip(z + e, 0, 1))
            pts.append(np.clip(z - e, 0, 1))
        v = f(np.vstack(pts))
        g = np.empty(k)
        for j in range(k):
            zp, zm = pts[1 + 2 * j][j], pts[2 + 2 * j][j]
            g[j] = (v[1 + 2 * j] - v[2 + 2 * j]) / max(zp - zm, 1e-12)
        return float(v[0]), g

    res = optimize.minimize(fg, z0, jac=True, method="L-BFGS-B", bounds=[(0.0, 1.0)] * k,
                            options={"maxiter": max_iter})  # fmt: skip
    return np.asarray(res.x)


#: Search box of the upper-level law when it is calibrated (closed loop, no known
#: law): the same as :func:`avll.calibrate`'s.
UPPER_BOUNDS: dict[str, tuple[float, float]] = {k: (lo, hi) for k, (lo, hi, _) in _UB.items()}


#: Population size multiplier of the ``"de"`` optimizer (scipy's ``popsize``).
DE_POP_SIZE: int = 12
#: ... and of a speed command, whose response is the speed (the acceleration alone
#: leaves the static gain free).
SPEED_COMMAND_WEIGHTS: tuple[float, float, float] = (1.0, 1.0, 0.0)


def fit_full(
    base: str | type[LowerLevelModel] | LowerLevelModel,
    effects: Sequence[str],
    runs: RunSet | Sequence[Run],
    *,
    start: WithEffects | None = None,
    start_upper: UpperLevel | None = None,
    seed: int = 0,
    closed_loop: bool | None = None,
    upper_free: bool | None = None,
    weights: tuple[float, float, float] | None = None,
    pop_size: int | None = None,
    max_generations: int | None = None,
    init: str = "auto",
    threads: int = 0,
    progress: Any = False,
    optimizer: str = "ga",
    starts: int = DEFAULT_STARTS,
    upper_bounds: Mapping[str, tuple[float, float]] | None = None,
) -> tuple[WithEffects, UpperLevel | None]:
    """As :func:`fit`, and in closed loop with ``upper_free`` (default: when a run
    has no known upper-level law) also the shared upper-level law ``kg, kv, Tg,
    Gmin`` (returned; ``None`` otherwise). ``weights`` of the acceleration, speed and
    position MSE default to ``(1, 0, 0)`` in open loop (paper Eq. 6), to
    :data:`SPEED_COMMAND_WEIGHTS` for a speed command and to
    :data:`avll.defaults.CLOSED_LOOP_WEIGHTS` in closed loop, where the acceleration
    alone leaves the upper law's spacing unidentified. The loop reports acceleration
    MSEs. ``optimizer``: ``"ga"`` (the project's Rust GA,
    :func:`avll.calibration.calibrate_effects`, with ``starts`` independent starts as
    :func:`avll.calibrate`) or ``"de"`` (``scipy.optimize.differential_evolution`` on
    the batched cost). ``pop_size`` and ``max_generations`` are the GA's (``None``:
    :data:`avll.defaults.GA_OPTIONS`); with ``"de"``, scipy's ``popsize`` (``None``:
    :data:`DE_POP_SIZE`) and its iterations.
    ``upper_bounds`` (name -> ``(lo, hi)``) replaces entries of
    :data:`avll.calibration.UPPER_BOUNDS` for the free upper-level gains."""
    if optimizer not in ("ga", "de"):
        raise ValueError(f"optimizer: must be 'ga' or 'de', got {optimizer!r}")
    seed = check_seed(seed)
    threads = check_threads(threads)
    if not isinstance(runs, RunSet) and not runs:
        raise ValueError("runs: no runs given")
    rs = as_runset(runs)
    bname = model_class(base).name
    names = canonical(list(effects))
    closed = _closed(rs, closed_loop)
    if upper_free is None:
        upper_free = closed and any(r.upper is None for r in rs.runs)
    sp = _space(bname, names, rs.command_kind, bool(upper_free),
                upper_bounds if upper_free else None)
    ini = _init(rs, init)
    if weights is None:
        if closed:
            weights = CLOSED_LOOP_WEIGHTS
        elif rs.command_kind == "speed" and rs.has("v"):
            weights = SPEED_COMMAND_WEIGHTS
        else:
            weights = (1.0, 0.0, 0.0)
    rows_of = sp.from_z
    free_idx = [0, 1, 2, 3] if upper_free else []

    def f(z: np.ndarray) -> np.ndarray:
        rows = np.vstack([rows_of(zz) for zz in np.atleast_2d(z)])
        c = batch_cost(bname, rows, rs, effects=names, closed_loop=closed, init=ini,
                       upper_free=free_idx, weights=weights, threads=threads)
        m = c.mean(axis=1)
        return np.where(np.isfinite(m), m, 1e6)

    rng = np.random.default_rng(seed)
    x0 = None
    if start is not None:
        parts = [start.base.to_array()]
        for n in names:
            if n in start.effect_names:
                parts.append(dict((e.name, e) for e in start.effects)[n].to_array())
            else:
                parts.append(np.array(EFFECTS[n].neutral))
        if upper_free:
            parts.append(start_upper.to_array() if start_upper is not None
                         else np.array([0.5, 0.5, 1.5, 5.0]))  # fmt: skip
        x0 = sp.to_z(np.concatenate(parts))
    from ..progress import Progress

    # One stage per fit, over GA generations (DE: iterations); it ends at 100 % when
    # the search converges before its budget and stops where it was when interrupted.
    gens = GA_OPTIONS["max_generations"] if max_generations is None else max_generations
    bar = Progress(gens, "fit " + "+".join([bname, *names]), unit="gen",
                   mode=progress)
    done = False
    try:
        if optimizer == "ga":
            x0p = None if x0 is None else sp.from_z(x0)[None, :]

            def gcb(info: dict[str, Any]) -> None:
                bar.advance_to(float(info["iteration"]))

            out = calibrate_effects(
                bname, names, rs, list(sp.lo), list(sp.hi),
                ["log" if lg else "linear" for lg in sp.log], weights=weights, init=ini,
                closed_loop=closed, upper_free=free_idx, initial=x0p, seed=seed,
                max_generations=max_generations, pop_size=pop_size,
                progress=gcb if bar.mode != "none" else None, threads=threads, starts=starts,
            )  # fmt: skip
            if out.get("interrupted"):
                # The GA returned its best point after a Ctrl-C: a fit of the loop is
                # not a result to go on with, the loop stops (nothing is written).
                raise KeyboardInterrupt
            p = np.asarray(out["x"], dtype=np.float64)
        else:

            def cb(intermediate_result: Any) -> None:
                bar.update(1)

            res = optimize.differential_evolution(
                lambda zz: f(zz.T), [(0.0, 1.0)] * len(sp.names), seed=rng, vectorized=True,
                popsize=DE_POP_SIZE if pop_size is None else pop_size, maxiter=gens, tol=1e-7,
                polish=False,
                updating="deferred",
                x0=x0, init="sobol", callback=cb,
            )  # fmt: skip
            p = sp.from_z(_polish(f, np.asarray(res.x), 200))
        done = True
    finally:
        bar.close(complete=done)

    n_model = len(p) - (4 if upper_free else 0)
    model = WithEffects.from_array(bname, names, p[:n_model])
    up = UpperLevel(*[float(x) for x in p[n_model:]]) if upper_free else None
    return model, up


def fit(
    base: str | type[LowerLevelModel] | LowerLevelModel,
    effects: Sequence[str],
    runs: Sequence[Run],
    *,
    start: WithEffects | None = None,
    seed: int = 0,
    closed_loop: bool | None = None,
    pop_size: int | None = None,
    max_generations: int | None = None,
    init: str = "auto",
    threads: int = 0,
    optimizer: str = "ga",
) -> WithEffects:
    """Calibrates base + effects on ``runs`` (mean of the per-run acceleration MSE,
    paper Eq. 6; closed loop runs need their upper-level law, see :func:`fit_full`).

    A global search (``scipy.optimize.differential_evolution`` on the Rust batched
    cost, vectorised, seeded; ``start`` — e.g. the previous model with the new
    effect at its diagnosed guess — joins the initial population) in a box scaled
    to [0, 1] (log scale for positive time coefficients), then a bounded
    quasi-Newton polish (L-BFGS-B on batched central differences).
    """
    model, _ = fit_full(base, effects, runs, start=start, seed=seed, closed_loop=closed_loop,
                        upper_free=False, pop_size=pop_size, max_generations=max_generations,
                        init=init, threads=threads, optimizer=optimizer)  # fmt: skip
    return model




def at_bound(
    model: WithEffects,
    upper: UpperLevel | None = None,
    kind: str = "acceleration",
    tol: float = AT_BOUND_TOL,
    upper_bounds: Mapping[str, tuple[float, float]] | None = None,
) -> list[dict[str, Any]]:
    """The parameters of ``model`` (and of a calibrated ``upper`` law) that sit within
    ``tol`` of a bound of the box :func:`fit_full` searched (share of the box, in its
    own linear or logarithmic scale; fixed parameters are left out). Each entry:
    ``{"param", "value", "bound": "lower"|"upper", "lower", "upper"}``. Such a value
    is the edge of the search, not an estimate: widen the bound or doubt the effect.
    ``upper_bounds`` are the upper-law boxes :func:`fit_full` was given (default
    :data:`UPPER_BOUNDS`)."""
    sp = _space(model.base.name, model.effect_names, kind, upper is not None, upper_bounds)
    names = [f"upper.{n}" if n in _UB else n for n in sp.names]
    lo, hi, lg = list(sp.lo), list(sp.hi), list(sp.log)
    values = list(model.to_array())
    if upper is not None:
        values.extend(float(x) for x in upper.to_array())
    out = []
    for n, v, a, b, is_log in zip(names, values, lo, hi, lg, strict=True):
        if not a < b:
            continue
        if is_log:
            u = (np.log(max(v, 1e-300)) - np.log(a)) / (np.log(b) - np.log(a))
        else:
            u = (v - a) / (b - a)
        if u <= tol or u >= 1.0 - tol:
            out.append({"param": n, "value": float(v), "bound": "lower" if u <= tol else "upper",
                        "lower": float(a), "upper": float(b)})  # fmt: skip
    return out
