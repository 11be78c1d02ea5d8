"""Calibration of the lower-level models by a parallel genetic algorithm (paper
Section III.B–C).

The objective is the paper's Eq. 6: the mean over runs of each run's mean squared
acceleration error (optionally plus weighted speed and position errors), with the
model driven open loop by the recorded command or closed loop by the recorded
leader through the upper-level law (Eq. 3), whose gains may be calibrated too.
The GA (Rust, ``avll._core.calibrate``) evaluates whole populations in parallel
without Python in the loop, is reproducible from ``seed`` whatever the thread
count, and is polished by a bounded Nelder–Mead.

Bounds
------
The paper bounds most parameters to ``[0, Inf)``; a GA needs a finite box, so each
model has physically motivated default bounds (:data:`DEFAULT_BOUNDS`, the reasons in
:data:`avll.defaults.BOUND_REASONS`; the docs print both side by side), with a
logarithmic search scale for the positive coefficients that can span decades, and
:data:`UPPER_BOUNDS` for the upper-level gains calibrated in closed loop.

A fitted parameter within 0.1 % of a bound is reported in
:attr:`CalibrationResult.at_bound`; widen that bound (``bounds={"m3": (1e-3, 1e3)}``)
and calibrate again. Setting ``lo == hi`` fixes a parameter (e.g. ``m1 = 0`` of the
paper's last remark: ``bounds={"m1": (0, 0)}``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from . import _core, _sigint
from ._limits import check_int, check_memory, check_number, check_seed, check_threads
from .data import Run

# the defaults and the paper's calibration runs, re-exported here (their old home)
from .defaults import (
    AT_BOUND_TOL,
    DEFAULT_BOUNDS,
    DEFAULT_STARTS,
    EQ6_WEIGHTS,
    GA_OPTIONS,
    LEVEL,
    UPPER_BOUNDS,
    Bound,
    objective_weights,
    upper_index,
)
from .defaults import UPPER_NAMES as _UPPER_NAMES
from .effects import EFFECTS, WithEffects, canonical, exo_needs
from .models import LowerLevelModel, UpperLevel, model_class
from .paper import MODEL_TITLES as _LABELS
from .paper import MODELS, PAPER_CAL_RUNS
from .rollout import _structure, closed_loop, simulate
from .runs import RunSet, as_runset, positions
from .uncertainty import Uncertainty

#: The former name of the bootstrap's result: the one result type of intervals.
Bootstrap = Uncertainty

__all__ = [
    "DEFAULT_BOUNDS",
    "DEFAULT_STARTS",
    "UPPER_BOUNDS",
    "PAPER_CAL_RUNS",
    "CalibrationResult",
    "Bootstrap",
    "Workflow",
    "default_bounds",
    "calibrate",
    "calibrate_many",
    "bootstrap",
    "start_row",
    "paper_workflow",
    "split_runs",
]


def default_bounds(
    model: str | type[LowerLevelModel],
    upper_free: Sequence[int | str] = (),
    effects: Sequence[str] = (),
    kind: str = "acceleration",
) -> dict[str, Bound]:
    """The default search box of the parameter row ``[model | effects | free upper
    gains]``, the one place a box is derived (:func:`calibrate`, the diagnosis's fits
    and its ``at_bound``): :data:`DEFAULT_BOUNDS` for the model, each effect's own
    bounds (linear, named ``"effect.param"``, in canonical order; a parameter the
    command ``kind`` fixes, :attr:`avll.effects.Effect.fixed`, has equal bounds) and
    :data:`UPPER_BOUNDS` for the free gains."""
    cls = model_class(model)
    out = dict(DEFAULT_BOUNDS[cls.name])
    for e in canonical(list(effects)):
        ecls = EFFECTS[e]
        for p, (lo, hi) in zip(ecls.param_names(), ecls.bounds, strict=True):
            fx = ecls.fixed.get(kind, {}).get(p)
            out[f"{e}.{p}"] = (lo, hi, "linear") if fx is None else (fx, fx, "linear")
    for u in upper_free:
        name = _UPPER_NAMES[upper_index(u)]
        out[name] = UPPER_BOUNDS[name]
    return out


def _resolve_bounds(
    cls: type[LowerLevelModel],
    free: Sequence[int],
    bounds: Mapping[str, Sequence[Any]] | None,
    effects: Sequence[str] = (),
    kind: str = "acceleration",
) -> tuple[list[str], list[float], list[float], list[str]]:
    box = default_bounds(cls, free, effects, kind)
    names = list(box)
    for k, b in (bounds or {}).items():
        if k not in box:
            raise ValueError(
                f"bounds: unknown parameter {k!r} for model {cls.name!r}; known: {', '.join(names)}"
            )
        try:
            b = tuple(b)
        except TypeError:
            raise TypeError(f"bounds[{k!r}]: expected (lower, upper) or (lower, upper, scale), "
                            f"got {b!r}") from None
        if len(b) not in (2, 3):
            raise ValueError(f"bounds[{k!r}]: expected (lower, upper) or (lower, upper, scale)")
        try:
            lo, hi = float(b[0]), float(b[1])
        except (TypeError, ValueError, OverflowError):
            raise TypeError(f"bounds[{k!r}]: lower and upper must be numbers, got {b!r:.80}"
                            ) from None
        scale = str(b[2]) if len(b) == 3 else box[k][2]
        if scale == "log" and lo <= 0:
            scale = "linear"  # a user box reaching 0 cannot be log-scaled
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
            raise ValueError(f"bounds[{k!r}]: need finite lower <= upper, got ({lo}, {hi})")
        box[k] = (lo, hi, scale)
    return (
        names,
        [box[n][0] for n in names],
        [box[n][1] for n in names],
        [box[n][2] for n in names],
    )


@dataclass(frozen=True)
class CalibrationResult:
    """A calibrated model.

    ``cost`` is Eq. 6 on the calibration runs; ``per_run_mse`` each run's cost (the
    acceleration MSE with Eq. 6's weights; with others, ``weights``, the weighted sum of
    the MSEs); ``upper`` the calibrated upper-level
    gains (closed loop with ``upper_free``); ``history`` the best cost after each
    generation; ``interrupted`` is true when Ctrl-C (or the progress callable)
    stopped the search, the result then being the best so far. With effects,
    ``model`` is the base model and ``with_effects`` the base with its calibrated
    effects; ``x`` is the calibrated row ``[model | effects | free upper gains]``
    (the order of ``bounds``). ``intervals`` (name -> (low, high): parameters, then the
    identified combinations) and ``uncertainty`` (an :class:`avll.Uncertainty`) are
    filled when :func:`calibrate` is asked for intervals, ``None`` otherwise.
    """

    model: LowerLevelModel
    cost: float
    per_run_mse: dict[str, float]
    generations: int
    evaluations: int
    interrupted: bool
    stop: str
    history: np.ndarray
    cost_ga: float
    seed: int
    bounds: dict[str, Bound]
    upper: dict[str, float] = field(default_factory=dict)
    at_bound: tuple[str, ...] = ()
    #: Final cost of each independent start that ran (the best is the result; with a
    #: target, the starts after the first that reached it do not run).
    start_costs: tuple[float, ...] = ()
    with_effects: Any = None
    x: np.ndarray | None = None
    intervals: dict[str, tuple[float, float]] | None = None
    #: The uncertainty of the calibration (:class:`avll.Uncertainty`) when asked for
    #: with ``intervals=``; ``None`` otherwise.
    uncertainty: Any = None
    #: The objective's weights ``(wa, wv, wx)`` the costs are under.
    weights: tuple[float, float, float] = EQ6_WEIGHTS

    @property
    def params(self) -> dict[str, float]:
        """The calibrated parameters by name (model, then effects as ``"effect.param"``,
        then free upper-level gains)."""
        eff: dict[str, float] = {}
        if self.with_effects is not None:
            eff = {f"{e.name}.{k}": v for e in self.with_effects.effects
                   for k, v in e.to_dict().items()}  # fmt: skip
        return {**self.model.to_dict(), **eff, **self.upper}

    def plot(self) -> Any:
        """The GA's convergence: best cost per generation (a Figure,
        :func:`avll.plotting.convergence`)."""
        from . import plotting

        return plotting.convergence(self.history, model=self.model.name,
                                    title=f"{self.model.name}: cost {self.cost:.4g} "
                                    f"after {self.generations} generations ({self.stop})")


@dataclass(frozen=True)
class _Problem:
    cls: type[LowerLevelModel]
    rs: RunSet
    effects: tuple[str, ...]
    free: list[int]
    names: list[str]
    lower: list[float]
    upper: list[float]
    scale: list[str]
    kw: dict[str, Any]
    weights: tuple[float, float, float]
    init: str
    closed_loop: bool

    @property
    def runs(self) -> list[Run]:
        """The runs of the problem (``avll.maps`` reads them)."""
        return list(self.rs.runs)

    @property
    def box(self) -> dict[str, tuple[float, float, str]]:
        """The search box: name -> (lo, hi, scale)."""
        return {n: (lo, hi, sc) for n, lo, hi, sc in
                zip(self.names, self.lower, self.upper, self.scale, strict=True)}


class _Packs:
    """Run sets packed once (one :class:`avll.RunSet` per list of runs) and reused for
    the rest of one top-level call (e.g. :func:`paper_workflow` calibrating several
    models on the same runs and validating each on the same other runs). Keyed by the
    runs' identities; the entries hold the runs, so the identities stay valid while
    the cache lives."""

    def __init__(self) -> None:
        self._packed: dict[Any, RunSet] = {}

    def get(self, runs: RunSet | Sequence[Run]) -> RunSet:
        """The run set of ``runs``, built on the first request only."""
        if isinstance(runs, RunSet):
            return runs
        if not isinstance(runs, (list, tuple)):
            return RunSet(runs)  # names a wrong type; an iterator is used once
        key = tuple(id(r) for r in runs)
        if key not in self._packed:
            self._packed[key] = RunSet(runs)
        return self._packed[key]


def _problem(
    model: Any,
    runs: RunSet | Sequence[Run],
    *,
    bounds: Mapping[str, Sequence[Any]] | None,
    closed_loop: bool,
    upper_free: Sequence[int | str],
    weights: Sequence[float] | None,
    init: str,
    effects: Sequence[str] = (),
    packs: _Packs | None = None,
) -> _Problem:
    cls, names = _structure(model, effects)
    free = [upper_index(u) for u in upper_free]
    if free and not closed_loop:
        raise ValueError("upper_free: the upper-level gains can only be calibrated in closed loop")
    rs = (packs or _Packs()).get(runs)
    kw = rs.cost_kw(weights=weights, init=init, closed_loop=closed_loop, upper_free=free,
                    exo=exo_needs(names))  # fmt: skip
    kw["effects"] = list(names)
    lo_names, lo, hi, sc = _resolve_bounds(cls, free, bounds, names, rs.command_kind)
    return _Problem(cls, rs, names, free, lo_names, lo, hi, sc, kw, kw["weights"], init,
                    closed_loop)


def _ga_kwargs(options: Mapping[str, Any]) -> dict[str, Any]:
    """Every tunable GA option, the given ones checked by the Rust core (types, ranges)
    and the defaults of :data:`GA_OPTIONS` for the others."""
    for k in options:
        if k not in GA_OPTIONS:  # seed and target are arguments of their own
            raise ValueError(f"{k}: unknown GA option; known: {', '.join(GA_OPTIONS)}")
    return dict(_core.ga_check(dict(options)))


def _ga_memory(prob: _Problem, n_problems: int, ga: dict[str, Any]) -> None:
    """Refuses a calibration whose populations cannot fit in memory."""
    d = len(prob.names)
    pop = ga["pop_size"] or _core.ga_auto_pop(d)
    runs = len(prob.rs)
    per = 8.0 * (4 * pop * (d + 2) + ga["max_generations"] + runs + d)
    check_memory(per * n_problems,
                 f"calibrate: {n_problems} problem(s) x population {pop} x {d} parameters",
                 "solve fewer problems (bootstrap resamples, starts) per call",
                 per=per, unit="problems")


def _initial(prob: _Problem, initial: Sequence[Any] | None, name: str = "initial"
             ) -> np.ndarray | None:
    """Starting rows ``[model | effects | free upper gains]`` from models or numbers
    (``name`` the argument in errors); ``None`` for none."""
    if initial is None or (not isinstance(initial, np.ndarray) and not initial):
        return None
    if isinstance(initial, (str, bytes)) or not hasattr(initial, "__iter__"):
        raise TypeError(f"{name}: expected a list of models or parameter rows, got "
                        f"{initial!r:.60}")
    rows = []
    for k, m in enumerate(initial):
        if isinstance(m, LowerLevelModel):
            if type(m) is not prob.cls:
                raise ValueError(
                    f"{name}[{k}]: a {type(m).__name__}, expected {prob.cls.__name__}"
                )
            row = list(m.to_array())
            row += [0.5 * (prob.lower[i] + prob.upper[i]) for i in range(len(row), len(prob.names))]
        else:
            try:
                row = [float(v) for v in np.asarray(m, dtype=np.float64).ravel()]
            except (TypeError, ValueError):
                raise TypeError(f"{name}[{k}]: expected a model or numbers, got {m!r:.60}"
                                ) from None
        if len(row) != len(prob.names):
            raise ValueError(
                f"{name}[{k}]: expected {len(prob.names)} values ({', '.join(prob.names)}), "
                f"got {len(row)}"
            )
        if not all(math.isfinite(v) for v in row):
            raise ValueError(f"{name}[{k}]: not finite ({row})")
        rows.append(row)
    return np.ascontiguousarray(np.array(rows, dtype=np.float64))


def _initial_per_problem(prob: _Problem, per: Sequence[Sequence[Any]] | None, n: int,
                         starts: int) -> list[np.ndarray] | None:
    """Each problem's own starting rows (:func:`calibrate_many`'s ``initial_per_problem``:
    one list per problem), repeated for its ``starts``; ``None`` for none."""
    if per is None:
        return None
    if isinstance(per, (str, bytes)) or not hasattr(per, "__len__"):
        raise TypeError(f"initial_per_problem: expected one list of rows per problem, got "
                        f"{per!r:.60}")
    if len(per) != n:
        raise ValueError(f"initial_per_problem: {len(per)} lists of starting rows for {n} "
                         f"problems (one list per problem, empty for none)")
    d = len(prob.names)
    out = []
    for k, rows in enumerate(per):
        arr = _initial(prob, rows, f"initial_per_problem[{k}]")
        arr = np.zeros((0, d)) if arr is None else arr
        out += [arr] * starts
    return out


def start_row(result: CalibrationResult, effects: Sequence[str] = ()) -> np.ndarray:
    """The parameter row ``[model | effects | free upper gains]`` of ``result`` extended
    by ``effects`` at their neutral values (the effects of ``result`` and ``effects``
    together, in canonical order): a start for a calibration of the richer model that
    costs exactly what ``result`` costs (an effect at its neutral values is the
    identity), e.g. ``initial_per_problem`` of :func:`calibrate_many`."""
    x = np.asarray(result.x if result.x is not None else
                   [*result.model.to_array(), *result.upper.values()], dtype=np.float64)
    have = tuple(result.with_effects.effect_names) if result.with_effects is not None else ()
    for e in effects:
        if e not in EFFECTS:
            raise ValueError(f"effects: unknown effect {e!r}; known: {', '.join(EFFECTS)}")
    names = canonical(list(dict.fromkeys([*have, *effects])))
    n_model, n_upper = len(result.model.param_names()), len(result.upper)
    own, o = {}, n_model
    for e in have:
        k = len(EFFECTS[e].param_names())
        own[e], o = x[o:o + k], o + k
    return np.concatenate([x[:n_model],
                           *(own.get(e, np.asarray(EFFECTS[e].neutral, dtype=np.float64))
                             for e in names),
                           x[len(x) - n_upper:] if n_upper else np.zeros(0)])  # fmt: skip


class _Bar:
    """GA progress over generations (and finished problems): one
    :class:`avll.progress.Progress` stage that ends at 100 % when the search finishes,
    even when it converged before its generation budget."""

    def __init__(self, enabled: Any, total: int, desc: str) -> None:
        from .progress import Progress

        self.bar = Progress(total, desc or "calibrate", unit="gen", mode=enabled)
        self.seen: dict[int, int] = {}

    def __call__(self, info: dict[str, Any]) -> None:
        if info["phase"] == "ga":
            self.seen[info["problem"]] = info["iteration"]
            self.bar.advance_to(sum(self.seen.values()))
        self.bar.set_postfix(f"best={info['best']:.5g}, phase={info['phase']}")

    def close(self, complete: bool = True) -> None:
        self.bar.close(complete=complete)


def _result(prob: _Problem, raw: Mapping[str, Any], runs: Sequence[Run], seed: int,
            per_run: np.ndarray, start_costs: tuple[float, ...] = ()) -> CalibrationResult:
    x = np.asarray(raw["x"], dtype=np.float64)
    n_model = len(prob.cls.param_names())
    model = prob.cls.from_array(x[:n_model])
    with_effects = None
    n_row = n_model
    if prob.effects:
        n_row = len(x) - len(prob.free)
        with_effects = WithEffects.from_array(prob.cls.name, list(prob.effects), x[:n_row])
    upper = {_UPPER_NAMES[i]: float(x[n_row + j]) for j, i in enumerate(prob.free)}

    def unit(v: float, lo: float, hi: float, sc: str) -> float:
        if sc == "log":
            return math.log(v / lo) / math.log(hi / lo)
        return (v - lo) / (hi - lo)

    at_bound = tuple(
        n
        for n, v, lo, hi, sc in zip(prob.names, x, prob.lower, prob.upper, prob.scale, strict=True)
        if lo < hi and min(unit(v, lo, hi, sc), 1.0 - unit(v, lo, hi, sc)) <= AT_BOUND_TOL
    )
    return CalibrationResult(
        model=model,
        cost=float(raw["f"]),
        per_run_mse={r.run_id: float(c) for r, c in zip(runs, per_run, strict=True)},
        generations=int(raw["generations"]),
        evaluations=int(raw["evaluations"]),
        interrupted=bool(raw["interrupted"]),
        stop=str(raw["stop"]),
        history=np.asarray(raw["history"]),
        cost_ga=float(raw["f_ga"]),
        seed=int(seed),
        bounds=prob.box,
        upper=upper,
        at_bound=at_bound,
        start_costs=start_costs,
        with_effects=with_effects,
        x=x,
        weights=prob.weights,
    )


def _run(
    prob: _Problem,
    problems: list[list[int]] | None,
    *,
    seed: int,
    derive_seeds: bool,
    initial: Sequence[Any] | None,
    target: float | None,
    in_turn: bool = False,
    threads: int,
    progress: bool | str | Callable[[dict[str, Any]], Any],
    desc: str,
    options: Mapping[str, Any],
    initial_per_problem: list[np.ndarray] | None = None,
) -> list[dict[str, Any]]:
    ga = _ga_kwargs(options)
    seed = check_seed(seed)
    threads = check_threads(threads)
    n_problems = 1 if problems is None else len(problems)
    _ga_memory(prob, n_problems, ga)
    if target is not None:
        check_number(target, "target", finite=False)
        if math.isnan(float(target)):
            raise ValueError("target: must be a number (or -inf) or None, got nan")
    bar: Any
    if callable(progress):
        bar = progress
    else:
        bar = _Bar(progress, n_problems * ga["max_generations"], desc)
    done = False
    try:
        ga["seed"] = int(seed)
        ga["target"] = -math.inf if target is None else float(target)
        out = _core.calibrate(
            prob.cls.name,
            lower_bounds=prob.lower,
            upper_bounds=prob.upper,
            scale=prob.scale,
            problems=problems,
            derive_seeds=derive_seeds,
            in_turn=in_turn,
            options=ga,
            initial=_initial(prob, initial),
            initial_per_problem=initial_per_problem,
            progress=bar if (callable(progress) or bar.bar.mode != "none") else None,
            threads=int(threads),
            **prob.kw,
        )
        done = not any(bool(r.get("interrupted")) for r in out)
        if not done:
            _sigint.clear()  # delivered: the caller gets the best so far
        return out
    finally:
        if isinstance(bar, _Bar):
            bar.close(complete=done)


def calibrate(
    model: Any,
    runs: RunSet | Sequence[Run],
    *,
    effects: Sequence[str] = (),
    subsets: Sequence[Sequence[int | str]] | str | None = None,
    bounds: Mapping[str, Sequence[Any]] | None = None,
    seed: int = 0,
    closed_loop: bool = False,
    upper_free: Sequence[int | str] = (),
    weights: Sequence[float] | None = None,
    init: str = "rest",
    initial: Sequence[Any] | None = None,
    initial_per_problem: Sequence[Sequence[Any]] | None = None,
    target: float | None = None,
    starts: int = DEFAULT_STARTS,
    threads: int = 0,
    progress: bool | str | Callable[[dict[str, Any]], Any] = False,
    intervals: Any = None,
    **ga_options: Any,
) -> Any:
    """Calibrates ``model`` on ``runs`` by minimising Eq. 6 with the GA.

    The one calibration entry. ``model`` is a model name or class, or a model
    instance (a :class:`avll.WithEffects` calibrates its base with its effects; an
    instance's parameters join the first population); ``effects`` names effects to
    calibrate with a base given by name. ``runs`` is an :class:`avll.RunSet` or a
    list of runs (packed once). With ``subsets`` (per problem, run positions or ids,
    or ``"per_run"``) the independent problems are solved in one parallel call and a
    list of results is returned (see :func:`calibrate_many`).

    ``bounds`` overrides the default box per parameter (``{"Td": (0, 2)}``, optionally
    with a scale: ``{"m3": (1e-3, 1e3, "log")}``). ``closed_loop`` drives the model by
    the recorded leader through each run's upper law; ``upper_free`` (names or indices
    of kg, kv, Tg, Gmin) calibrates those gains too. ``weights`` weigh the mean squared
    errors of acceleration, speed and position (``None``: the paper's Eq. 6,
    acceleration only, in open loop; :data:`avll.defaults.CLOSED_LOOP_WEIGHTS` in
    closed loop). ``init`` is the rollouts' initial state
    (``"rest"`` or ``"steady"``). ``initial`` seeds the population with models or
    parameter vectors; with ``subsets``, ``initial_per_problem`` gives each problem its
    own starting rows too (one list per subset, see :func:`calibrate_many`).
    ``target`` stops as soon as the cost is at most that value.
    ``starts`` independent GA runs (seeds ``_core.derive_seed(seed, j)``; with one
    start, ``seed`` itself) run one after the other, each with all the threads, and
    the best is kept: on the proposed model a start occasionally settles in a local
    minimum at a bound corner (``K0`` at its upper bound, ``K`` strongly negative)
    with several times the cost, so two starts are the default. With a ``target``,
    the starts after the first that reaches it are skipped (``start_costs`` lists the
    starts that ran).
    ``threads`` (0 = all cores) does not change the result. ``progress`` shows the
    generations on stderr (``True``/``"auto"``: a bar on a terminal, log lines otherwise;
    ``"bar"``, ``"log"``, ``False``/``"none"``: see :mod:`avll.progress`), or is a
    callable receiving a dict per generation. Ctrl-C stops
    cleanly: the best so far is returned with ``interrupted=True``. Further GA options:
    see :data:`GA_OPTIONS` (``pop_size``, ``max_generations``, ``stall_generations``,
    ``ftol``, ``polish``, ...).

    ``intervals`` (``True``, an :class:`avll.Intervals` or a dict of its fields) adds
    a second stage after the GA: a block bootstrap over time refit by a local search
    from the optimum (:mod:`avll.uncertainty`), filling ``uncertainty`` and
    ``intervals`` of the result (with ``subsets``: of each problem, each with its own
    resamples). A Ctrl-C during that stage returns the calibration with the intervals
    of the resamples refit so far (``uncertainty.interrupted``).

    A calibration in which every parameter set tried costs ``inf`` (the model diverges
    on every candidate, or the data are out of range) raises a ``ValueError``: there is
    no fit to return.
    """
    if subsets is not None:
        return calibrate_many(
            model, runs, subsets, effects=effects, seed=seed, threads=threads,
            progress=progress, bounds=bounds, closed_loop=closed_loop, upper_free=upper_free,
            weights=weights, init=init, initial=initial, target=target, starts=starts,
            intervals=intervals, initial_per_problem=initial_per_problem, **ga_options,
        )  # fmt: skip
    if initial_per_problem is not None:
        raise ValueError("initial_per_problem: needs subsets (one list of rows per "
                         "problem); give a single problem's rows as initial=")
    return _calibrate(
        model, runs, bounds=bounds, seed=seed, closed_loop=closed_loop, upper_free=upper_free,
        weights=weights, init=init, initial=initial, target=target, starts=starts,
        threads=threads, progress=progress, ga_options=ga_options, effects=effects,
        intervals=intervals,
    )  # fmt: skip


def _calibrate(
    model: Any,
    runs: RunSet | Sequence[Run],
    *,
    bounds: Mapping[str, Sequence[Any]] | None,
    seed: int,
    closed_loop: bool,
    upper_free: Sequence[int | str],
    weights: Sequence[float] | None,
    init: str,
    initial: Sequence[Any] | None,
    target: float | None,
    starts: int,
    threads: int,
    progress: bool | str | Callable[[dict[str, Any]], Any],
    ga_options: Mapping[str, Any],
    packs: _Packs | None = None,
    effects: Sequence[str] = (),
    intervals: Any = None,
) -> CalibrationResult:
    """:func:`calibrate` with the run sets of ``packs`` (packed on first use)."""
    from .uncertainty import Intervals

    iopts = Intervals.of(intervals)
    check_seed(seed)
    check_threads(threads)
    n = check_int(starts, "starts", min=1)
    prob = _problem(
        model, runs, bounds=bounds, closed_loop=closed_loop, upper_free=upper_free,
        weights=weights, init=init, effects=effects, packs=packs,
    )  # fmt: skip
    initial = _with_start(model, initial)
    all_runs = list(range(len(prob.rs)))
    raws = _run(
        prob, None if n == 1 else [all_runs] * n, seed=seed, derive_seeds=n > 1,
        initial=initial, target=target, in_turn=True,
        threads=threads, progress=progress, desc=f"calibrate {prob.cls.name}", options=ga_options,
    )  # fmt: skip
    # The starts run in turn: those after the first that reached the target (or after
    # a Ctrl-C) did not run and are not in ``raws``.
    best, raw = _best(prob, raws, "")
    start_seed = int(seed) if n == 1 else _core.derive_seed(int(seed), best)
    res = _result(prob, raw, prob.rs.runs, start_seed, _per_run(raw, len(prob.rs)),
                  _costs(raws))
    if iopts is None or res.interrupted:
        return res
    return _with_uncertainty(prob, [all_runs], [res], iopts, seed, threads, progress)[0]


def _with_uncertainty(prob: _Problem, subsets: Sequence[Sequence[int]],
                      results: Sequence[CalibrationResult], opts: Any, seed: int,
                      threads: int, progress: Any) -> list[CalibrationResult]:
    """``results`` with their uncertainty (:func:`avll.uncertainty.estimate`)."""
    from .uncertainty import estimate

    xs = [np.asarray(r.x, dtype=np.float64) for r in results]
    us = estimate(prob, subsets, xs, opts, seed=seed, threads=threads, progress=progress)
    out = []
    for sub, r, u in zip(subsets, results, us, strict=True):
        if r.x is not None and not np.array_equal(u.estimate, r.x):
            r = _polished(prob, sub, r, u.estimate, u.cost_estimate, threads)
        out.append(replace(r, uncertainty=u, intervals=u.intervals))
    return out


def _polished(prob: _Problem, sub: Sequence[int], res: CalibrationResult, x: np.ndarray,
              cost: float, threads: int) -> CalibrationResult:
    """``res`` moved to the row ``x`` of full-data cost ``cost`` (the uncertainty
    stage's polish), its per-run costs recomputed there."""
    uniq = sorted(set(int(i) for i in sub))
    row = np.ascontiguousarray(np.asarray(x, dtype=np.float64)[None, :])
    per_run = np.asarray(_core.batch_cost(prob.cls.name, row, threads=check_threads(threads),
                                          **prob.kw))[0]
    raw = {"x": x, "f": cost, "f_ga": res.cost_ga, "generations": res.generations,
           "evaluations": res.evaluations, "interrupted": res.interrupted, "stop": res.stop,
           "history": res.history}
    return _result(prob, raw, [prob.rs.runs[i] for i in uniq], res.seed, per_run[uniq],
                   res.start_costs)


def _per_run(raw: Mapping[str, Any], n_runs: int) -> np.ndarray:
    """The per-run costs the GA returned for its best parameters (NaN for runs not in
    the problem)."""
    out = np.full(n_runs, np.nan)
    out[np.asarray(raw["per_run_index"], dtype=np.int64)] = raw["per_run_cost"]
    return out


def _best(prob: _Problem, group: Sequence[dict[str, Any]], where: str
          ) -> tuple[int, dict[str, Any]]:
    """The best start of ``group`` (the first of the lowest cost) with the evaluations
    of them all and whether any was interrupted; a best cost of inf (or NaN) is no fit:
    a ValueError that says why it may be."""
    j = min(range(len(group)), key=lambda i: (group[i]["f"], i))
    raw = dict(group[j])
    if not math.isfinite(float(raw["f"])):
        how = "interrupted before any finite cost was found; " if raw.get("interrupted") else ""
        raise ValueError(
            f"runs: the calibration of {prob.cls.name!r}{where} found no parameter set with a "
            f"finite cost ({how}every evaluated candidate diverged or gave a non-finite "
            f"error). Check the runs for implausible values (strict=True when loading), the "
            f"command kind and the bounds ({', '.join(prob.names)})")
    raw["evaluations"] = sum(int(r["evaluations"]) for r in group)
    raw["interrupted"] = any(bool(r["interrupted"]) for r in group)
    return j, raw


def _costs(group: Sequence[Mapping[str, Any]]) -> tuple[float, ...]:
    return tuple(float(r["f"]) for r in group)


def _subset_indices(runs: Sequence[Run], subset: Sequence[Any], k: int) -> list[int]:
    """Run positions of ``subset`` (positions or run ids) in ``runs`` (``avll.maps``)."""
    return positions([r.run_id for r in runs], subset, f"subsets[{k}]")


def _with_start(model: Any, initial: Sequence[Any] | None) -> Sequence[Any] | None:
    """``initial`` with the parameters of a model instance given as ``model``."""
    if not isinstance(model, (LowerLevelModel, WithEffects)):
        return initial
    return [*(initial or ()), np.asarray(model.to_array(), dtype=np.float64)]


def calibrate_many(
    model: Any,
    runs: RunSet | Sequence[Run],
    subsets: Sequence[Sequence[int | str]] | str = "per_run",
    *,
    effects: Sequence[str] = (),
    seed: int = 0,
    threads: int = 0,
    progress: bool | str | Callable[[dict[str, Any]], Any] = False,
    bounds: Mapping[str, Sequence[Any]] | None = None,
    closed_loop: bool = False,
    upper_free: Sequence[int | str] = (),
    weights: Sequence[float] | None = None,
    init: str = "rest",
    initial: Sequence[Any] | None = None,
    target: float | None = None,
    starts: int = DEFAULT_STARTS,
    intervals: Any = None,
    initial_per_problem: Sequence[Sequence[Any]] | None = None,
    **ga_options: Any,
) -> list[CalibrationResult]:
    """Solves many independent calibration problems in one parallel call.

    ``subsets`` lists, per problem, the runs (indices into ``runs`` or run ids;
    repeats allowed, e.g. a bootstrap resample) whose Eq. 6 it minimises, or is
    ``"per_run"`` (one problem per run). Problem ``k`` uses the seed
    ``_core.derive_seed(seed, k)``; results are the same for any ``threads``.
    With ``starts > 1`` each problem gets that many independent GA runs (problem
    ``k``, start ``j`` uses ``_core.derive_seed(seed, k * starts + j)``) and keeps
    the best. Each result's ``per_run_mse`` covers the runs of its problem (once
    each). ``intervals``: as :func:`calibrate`, each problem with its own resamples
    (drawn from ``numpy.random.default_rng([seed, k])`` for problem ``k``).

    ``initial`` rows join every problem's first population; ``initial_per_problem``
    (one list per problem of models or rows ``[model | effects | free upper gains]``,
    empty for none) gives each problem its own starts before them, e.g. the problem's
    base optimum extended by added effects at their neutral values
    (:func:`start_row`): the GA keeps its best individual, so such a fit never ends
    above the start's cost (to rounding).
    """
    from .uncertainty import Intervals

    iopts = Intervals.of(intervals)
    check_seed(seed)
    check_threads(threads)
    n_st = check_int(starts, "starts", min=1)
    prob = _problem(
        model, runs, bounds=bounds, closed_loop=closed_loop, upper_free=upper_free,
        weights=weights, init=init, effects=effects,
    )  # fmt: skip
    initial = _with_start(model, initial)
    if isinstance(subsets, str):
        if subsets != "per_run":
            raise ValueError(f"subsets: expected run lists or 'per_run', got {subsets!r}")
        idx = [[i] for i in range(len(prob.rs))]
    else:
        idx = [prob.rs.indices(s, f"subsets[{k}]") for k, s in enumerate(subsets)]
        if not idx:
            raise ValueError("subsets: no problems given")
    expanded = [sub for sub in idx for _ in range(n_st)]
    per = _initial_per_problem(prob, initial_per_problem, len(idx), n_st)
    raws = _run(
        prob, expanded, seed=seed, derive_seeds=True, initial=initial, target=target,
        threads=threads, progress=progress, desc=f"calibrate {prob.cls.name} x{len(idx)}",
        options=ga_options, initial_per_problem=per,
    )  # fmt: skip
    out = []
    for k, sub in enumerate(idx):
        group = raws[k * n_st : (k + 1) * n_st]
        j, raw = _best(prob, group, f" (problem {k})")
        uniq = sorted(set(sub))
        rs = [prob.rs.runs[i] for i in uniq]
        per_run = _per_run(raw, len(prob.rs))[uniq]
        out.append(_result(prob, raw, rs, _core.derive_seed(int(seed), k * n_st + j), per_run,
                           _costs(group)))
    if iopts is None or any(r.interrupted for r in out):
        return out
    return _with_uncertainty(prob, idx, out, iopts, seed, threads, progress)


def bootstrap(
    model: Any,
    runs: RunSet | Sequence[Run],
    n: int | None = None,
    *,
    seed: int = 0,
    level: float = LEVEL,
    threads: int = 0,
    progress: bool | str | Callable[[dict[str, Any]], Any] = False,
    method: str = "runs",
    block: float | None = None,
    **kwargs: Any,
) -> Any:
    """The uncertainty of a calibration (:class:`avll.Uncertainty`): :func:`calibrate`
    with ``intervals=avll.Intervals(n=n, level=level, method=method, block=block)``,
    its ``uncertainty`` (``n=None``: the resamples of :class:`avll.Intervals`, one
    default for both). ``method="runs"`` (the default here) resamples whole runs
    with replacement (the runs are the independent units: a problem of several runs);
    ``"blocks"`` resamples blocks of time within each run (the default of
    ``calibrate(intervals=True)``). Each resample is refit by a local search from the
    full-data optimum (:mod:`avll.uncertainty`). ``kwargs`` go to :func:`calibrate`.
    The combinations include the DC gain ``K0/(1 - K K0)``, which is identified even
    where the individual parameters trade off."""
    from .uncertainty import Intervals

    n = check_int(Intervals.n if n is None else n, "n", min=2)
    if isinstance(level, bool) or not isinstance(level, (int, float, np.floating)) or not (
            0 < level < 1):
        raise ValueError(f"level: must be in (0, 1), got {level!r}")
    seed = check_seed(seed)
    check_threads(threads)
    runs = as_runset(runs)
    # the resample weights (a few atoms per run and resample) before the GA's own estimate
    check_memory(80.0 * n * len(runs), f"bootstrap: n={n} resamples x {len(runs)} runs",
                 "use fewer resamples per call and pool the samples", per=80.0 * len(runs),
                 unit="resamples")
    opts = Intervals(n=n, level=float(level), method=method, block=block)
    res = calibrate(model, runs, seed=seed, threads=threads, progress=progress,
                    intervals=opts, **kwargs)
    return res.uncertainty


# ---------------------------------------------------------------------------
# The paper's workflow: calibrate on some runs, validate on the others.
# ---------------------------------------------------------------------------


def split_runs(
    runs: Sequence[Run], cal_runs: Sequence[Any] | str | None = None
) -> tuple[list[Run], list[Run]]:
    """Splits runs into calibration and validation runs.

    ``cal_runs`` lists run ids (or ``"paper"`` for the paper's runs 3, 4, 5, 9, 10,
    11, 15, 16, 17, 19); ``None`` means alternate runs in file order (1st, 3rd, ...
    calibrate; 2nd, 4th, ... validate).
    """
    runs = list(runs)
    if not runs:
        raise ValueError("runs: no runs given")
    if cal_runs is None:
        return runs[0::2], runs[1::2]
    if isinstance(cal_runs, str):
        if cal_runs != "paper":
            raise ValueError(f"cal_runs: expected run ids or 'paper', got {cal_runs!r}")
        cal_runs = PAPER_CAL_RUNS
    want = [str(c) for c in cal_runs]
    ids = [r.run_id for r in runs]
    missing = [c for c in want if c not in ids]
    if missing:
        raise ValueError(
            f"cal_runs: run(s) {', '.join(missing)} not in the data (runs: {', '.join(ids)})"
        )
    if not want:
        raise ValueError("cal_runs: is empty")
    cal = [r for r in runs if r.run_id in want]
    val = [r for r in runs if r.run_id not in want]
    return cal, val


def _average(d: Mapping[str, float] | None) -> float:
    return float(np.mean(list(d.values()))) if d else float("nan")


@dataclass(frozen=True)
class Workflow:
    """Calibration of several models on ``cal`` runs and their validation on ``val``
    runs (the paper's Tables II–IV and Figs. 3–4)."""

    results: dict[str, CalibrationResult]
    cal: list[Run]
    val: list[Run]
    val_mse: dict[str, dict[str, float]]
    closed_loop: bool = False
    init: str = "rest"
    #: The objective's weights ``(wa, wv, wx)`` of the calibration and validation costs.
    weights: tuple[float, float, float] = EQ6_WEIGHTS

    @property
    def interrupted(self) -> bool:
        return any(r.interrupted for r in self.results.values())

    def params_table(self) -> Any:
        """Table II: rows the parameters (paper names), columns the models."""
        import pandas as pd

        names: list[str] = []
        for r in self.results.values():
            names += [n for n in r.params if n not in names]
        cols = {m: pd.Series(r.params) for m, r in self.results.items()}
        return pd.DataFrame(cols).reindex(names)

    def mse_table(self, which: str = "cal") -> Any:
        """Table III (``"cal"``) or IV (``"val"``): per-run MSE, rows the models,
        columns the runs and their average."""
        import pandas as pd

        if which not in ("cal", "val"):
            raise ValueError(f"which: must be 'cal' or 'val', got {which!r}")
        rows = {}
        for m, r in self.results.items():
            d = r.per_run_mse if which == "cal" else self.val_mse[m]
            rows[_LABELS.get(m, m)] = {**d, "Average": _average(d)}
        return pd.DataFrame(rows).T

    def averages(self) -> Any:
        """Average calibration and validation MSE per model."""
        import pandas as pd

        return pd.DataFrame({"cal_mse": {m: r.cost for m, r in self.results.items()},
                             "val_mse": {m: _average(v) for m, v in self.val_mse.items()}})

    def to_text(self) -> str:
        """The tables as plain text."""
        import pandas as pd

        what = "MSE (m/s^2)^2" if self.weights == EQ6_WEIGHTS else (
            "cost wa MSE(a) + wv MSE(v) + wx MSE(x), (wa, wv, wx) = ("
            + ", ".join(f"{w:g}" for w in self.weights) + ")")
        with pd.option_context("display.width", 200, "display.max_columns", 50):
            parts = [
                "Calibrated parameters (cf. Table II; -: not a parameter of that model)",
                self.params_table().to_string(float_format=lambda v: f"{v:.4f}", na_rep="-"),
                "",
                f"Calibration {what} (cf. Table III)",
                self.mse_table("cal").to_string(float_format=lambda v: f"{v:.4f}"),
            ]
            if self.val:
                parts += [
                    "",
                    f"Validation {what} (cf. Table IV)",
                    self.mse_table("val").to_string(float_format=lambda v: f"{v:.4f}"),
                ]
        if self.interrupted:
            parts += ["", "(interrupted: results are the best found so far)"]
        return "\n".join(parts)

    def to_json(self) -> dict[str, Any]:
        """The CLI's JSON contract: ``{"models": {name: {"params", "cal_mse", "val_mse",
        "per_run_mse"}}, "weights": [wa, wv, wx]}`` (``per_run_mse`` covers calibration
        and validation runs; the costs are under ``weights``)."""
        models: dict[str, Any] = {}
        for m, r in self.results.items():
            v = self.val_mse[m]
            models[m] = {
                "params": r.params,
                "cal_mse": r.cost,
                "val_mse": _average(v) if v else None,
                "per_run_mse": {**r.per_run_mse, **v},
                "cal_runs": [x.run_id for x in self.cal],
                "val_runs": [x.run_id for x in self.val],
                "generations": r.generations,
                "evaluations": r.evaluations,
                "interrupted": r.interrupted,
                "at_bound": list(r.at_bound),
            }
        return {"models": models, "weights": list(self.weights)}

    def simulated(self, model: str, run: Run) -> np.ndarray:
        """The acceleration that ``model`` (as calibrated) simulates for ``run``."""
        res = self.results[model]
        if self.closed_loop:
            if run.upper is None or run.lead_x is None or run.lead_v is None:
                raise ValueError(f"run {run.run_id!r}: closed loop needs the leader and upper law")
            up = run.upper.to_array()
            for k, val in res.upper.items():
                up[_UPPER_NAMES.index(k)] = val
            v0 = float(run.v[0]) if run.v is not None else 0.0
            x0 = float(run.x[0]) if run.x is not None else 0.0
            tr = closed_loop(res.model, run.lead_x, run.lead_v, run.dt, UpperLevel(*up),
                             v0=v0, x0=x0)  # fmt: skip
            return tr.a
        if run.command is None:
            raise ValueError(f"run {run.run_id!r}: has no recorded command")
        return simulate(res.model, run.command, run.dt, init=self.init)

    def plot(self, run_id: Any, models: Sequence[str] | None = None) -> Any:
        """Recorded vs simulated acceleration of one run (cf. Figs. 3–4), a Figure drawn
        by :func:`avll.plotting.traces`; the recording is labelled "synthetic" for
        generated runs and "measured" otherwise."""
        from . import plotting

        runs = {r.run_id: r for r in self.cal + self.val}
        rid = str(run_id)
        if rid not in runs:
            raise ValueError(f"run_id: unknown run {run_id!r}; known: {', '.join(runs)}")
        run = runs[rid]
        sims = {m: self.simulated(m, run) for m in (models or list(self.results))}
        role = "calibration" if any(r.run_id == rid for r in self.cal) else "validation"
        return plotting.traces(run.t, run.a, sims, data=plotting.data_label(run),
                               title=f"Run {rid} ({role})")


def paper_workflow(
    runs: Sequence[Run],
    *,
    cal_runs: Sequence[Any] | str | None = "paper",
    models: Sequence[str] = MODELS,
    seed: int = 0,
    threads: int = 0,
    progress: bool | str = False,
    **kwargs: Any,
) -> Workflow:
    """The paper's workflow: calibrate each of ``models`` on the ``cal_runs`` (default:
    the paper's runs 3, 4, 5, 9, 10, 11, 15, 16, 17, 19; ``None``: alternate runs) and
    validate on the rest. ``kwargs`` go to :func:`calibrate` (bounds must then be per
    model: pass ``bounds={"proposed": {...}}``). Stops after the model being
    calibrated when interrupted (Ctrl-C); the workflow is then flagged interrupted."""
    check_seed(seed)
    check_threads(threads)
    cal, val = split_runs(runs, cal_runs)
    bounds_by_model = kwargs.pop("bounds", None) or {}
    results: dict[str, CalibrationResult] = {}
    val_mse: dict[str, dict[str, float]] = {}
    # The calibration runs and the validation runs are each packed once for all models.
    packs = _Packs()
    opts: dict[str, Any] = {"closed_loop": False, "upper_free": (), "weights": None,
                            "init": "rest", "initial": None, "target": None,
                            "starts": DEFAULT_STARTS}  # fmt: skip
    opts.update({k: kwargs.pop(k) for k in list(opts) if k in kwargs})
    free = [upper_index(u) for u in opts["upper_free"]]
    for m in models:
        cls = model_class(m)
        res = _calibrate(cls, cal, seed=seed, threads=threads, progress=progress,
                         bounds=bounds_by_model.get(cls.name), ga_options=kwargs, packs=packs,
                         **opts)  # fmt: skip
        results[cls.name] = res
        if val:
            kw = packs.get(val).cost_kw(weights=opts["weights"], init=opts["init"],
                                        closed_loop=bool(opts["closed_loop"]), upper_free=free)
            row = np.ascontiguousarray(np.array(list(res.params.values()), dtype=np.float64))
            c = _core.batch_cost(cls.name, row[None, :], threads=check_threads(threads), **kw)[0]
            val_mse[cls.name] = {r.run_id: float(x) for r, x in zip(val, c, strict=True)}
        else:
            val_mse[cls.name] = {}
        if res.interrupted:
            break
    return Workflow(results, cal, val, val_mse, bool(opts["closed_loop"]), str(opts["init"]),
                    objective_weights(opts["weights"], bool(opts["closed_loop"])))
