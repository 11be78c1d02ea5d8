"""Rollouts of the lower-level models (Rust core; the GIL is released).

Discretization convention (shared with :mod:`avll.reference` and the tests):

* the reference input ``u_ref[n] = u[n] + K y[n]`` is held over ``[t_n, t_{n+1})``;
* the rational part is driven by ``u_ref(t - Td)``, discretized exactly for that
  piecewise-constant input: with ``Td/dt = i + f`` the interval's first ``f dt``
  carries ``u_ref[n-i-1]`` and the rest ``u_ref[n-i]``, so results are smooth in Td;
* ``y[n] = C x[n]``: the input at sample ``n`` first shows in ``y[n+1]``;
* ``init="rest"``: zero state and zero input history (``y[0] = 0``);
  ``init="steady"``: the equilibrium of the first command sample held forever
  (``y[0] = dc_gain * u[0]``), for runs that do not start at rest;
* speed and position integrate the response exactly under the same hold.

One family for base models and models with effects. Every rollout
(:func:`simulate`, :func:`simulate_full`, :func:`closed_loop`, :func:`platoon`) and
batched call (:func:`batch_cost`, :func:`simulate_batch`) takes a base model or an
:class:`avll.WithEffects` (lower-level effects, and upper-level structures in the closed
loop and the platoon); the same Rust kernel runs both, and a model with no effect is its
base exactly. ``exo`` maps the exogenous signals the effects read (e.g. ``"grade"``) to
arrays of the run's length (a platoon's followers read the same series).

An unstable lower level. Every trajectory function raises a ``ValueError`` naming the
model and its parameters when the lower level itself (with an ``asymmetric`` effect,
its braking side ``kb G(rb s)`` too) is not asymptotically stable at the sample time
``dt`` -- the same test (the inner loop ``G/(1 - K G)`` with its dead time,
discretized at ``dt``) that makes the costs (:func:`batch_cost`, the calibration)
return ``inf``. So no trajectory function returns
an array of NaN for such a model. A closed loop whose lower level is stable but whose
car-following loop diverges (unstable upper-level gains) is a legitimate result: its
trajectory is NaN from the divergence on.

Output arrays (numpy's ``out=``). :func:`simulate`, :func:`simulate_full`,
:func:`closed_loop`, :func:`platoon`, :func:`batch_cost` and :func:`simulate_batch`
take ``out=``: arrays the caller allocated once, written in place (every element) and
referred to by the result, so that a loop of calls pays for no new memory. Each must be
a float64 numpy array of the result's shape, C-contiguous (for the platoon: laid out
as the platoon returns its arrays, see :func:`platoon`), writeable, and share no memory
with the inputs or the other outputs; anything else is a ``ValueError`` naming the
argument. The values are bit-identical to those of the call without ``out=``. When a
call raises after it started writing (e.g. a diverged open-loop response), the
contents of ``out`` are unspecified.

Without ``out=``, the arrays of a trajectory (128 KiB and more each), and any output
beyond 32 MiB, live in blocks avll recycles: when numpy frees such an array, its block
goes back to a cache of at most 128 MiB (oldest blocks released first), and the next
call takes it with its pages already mapped instead of page-faulting fresh ones;
fresh blocks of 2 MiB and more are advised for transparent huge pages. A single
smaller output (:func:`simulate`) is an ordinary numpy array, which glibc already
recycles. :func:`output_cache` reports or bounds the cache (``limit=0``
empties and disables it). Nothing process-wide (allocator settings) is changed.

Memory. :func:`platoon` and :func:`batch_cost` estimate the bytes their outputs need
(``followers x samples x 4 arrays x 8 bytes``, twice while copying; ``P x R x 8``) and
refuse a call that cannot fit in the available memory with a ``ValueError`` that says
how to split it (:func:`avll._limits.check_memory`), instead of letting the allocation
abort the process.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _core
from ._limits import (
    check_choice,
    check_floats,
    check_int,
    check_memory,
    check_number,
    check_range,
    check_threads,
)
from .data import COMMAND_KINDS, INITS, Run
from .effects import Asymmetric, WithEffects, canonical, exo_needs
from .models import LowerLevelModel, UpperLevel, model_class

__all__ = [
    "Trajectory",
    "BatchSimulation",
    "output_cache",
    "simulate",
    "simulate_full",
    "closed_loop",
    "platoon",
    "batch_cost",
    "simulate_batch",
]

#: What every rollout takes as its model: a base model or a base with effects.
Model = LowerLevelModel | WithEffects


@dataclass(frozen=True)
class Trajectory:
    """Simulated acceleration ``a`` (m/s²), speed ``v`` (m/s), position ``x`` (m) and
    the command fed to the lower level. Platoon trajectories are 2-D
    (follower, sample)."""

    a: np.ndarray
    v: np.ndarray
    x: np.ndarray
    command: np.ndarray


def output_cache(limit: int | None = None) -> tuple[int, int]:
    """Bytes of freed output blocks avll keeps for reuse (see the module doc) and
    their bound; ``limit`` (bytes) sets the bound first, ``0`` releases every block
    and keeps none from then on."""
    if limit is not None:
        limit = check_int(limit, "limit", min=0)
    return _core.output_cache(limit)


def _check_out(
    outs: Sequence[tuple[str, Any]], shape: tuple[int, ...], inputs: Sequence[np.ndarray],
    order: str = "C",
) -> None:
    """``ValueError`` naming the array unless each of a caller's ``(name, array)`` outputs
    is a numpy float64 array of ``shape``, contiguous in ``order`` ("C", or "F" for the
    platoon's transposed layout) and writeable, sharing no memory with ``inputs`` or
    another output (numpy's bounds test)."""
    lay = ("C-contiguous" if order == "C" else
           f"Fortran-ordered (e.g. np.empty({shape[::-1]}).T)")
    want = f"a float64 numpy array of shape {shape}, {lay} and writeable"
    for name, arr in outs:
        if not isinstance(arr, np.ndarray):
            raise ValueError(f"{name}: must be {want}, got {type(arr).__name__}")
        if arr.dtype != np.float64:
            raise ValueError(f"{name}: must be {want}, got dtype {arr.dtype}")
        if arr.shape != shape:
            raise ValueError(f"{name}: must be {want}, got shape {arr.shape}")
        if not (arr.flags.c_contiguous if order == "C" else arr.flags.f_contiguous):
            raise ValueError(f"{name}: must be {want}, got a non-contiguous array")
        if not arr.flags.writeable:
            raise ValueError(f"{name}: must be {want}, got a read-only array")
    for k, (name, o) in enumerate(outs):
        for a in inputs:
            if np.may_share_memory(o, a):
                raise ValueError(f"{name}: shares memory with an input; pass a separate array")
        for other, o2 in outs[k + 1 :]:
            if np.may_share_memory(o, o2):
                raise ValueError(f"{name}: shares memory with {other}; pass separate arrays")


def _out_seq(out: Any) -> tuple[Any, ...]:
    """The four output arrays (a, v, x, command) of a :class:`Trajectory` or a
    sequence of four."""
    if isinstance(out, Trajectory):
        return (out.a, out.v, out.x, out.command)
    if isinstance(out, (str, bytes, np.ndarray)) or not hasattr(out, "__len__") or len(out) != 4:
        raise ValueError("out: must be an avll.Trajectory or a sequence of four arrays "
                         "(a, v, x, command)")
    return tuple(out)


def _result(out: Any, arrs: Any) -> Trajectory:
    """The result of a rollout: the caller's ``out`` itself when it is a Trajectory,
    else a new one over ``arrs``."""
    return out if isinstance(out, Trajectory) else Trajectory(*arrs)


def _dt(dt: Any) -> float:
    """``dt`` checked (a positive finite number), with a fast path for a float."""
    if type(dt) is float and 0.0 < dt < math.inf:
        return dt
    return check_number(dt, "dt", positive=True)


def _f64(name: str, x: Any) -> np.ndarray:
    arr = check_floats(x, name)
    if arr.ndim != 1:
        raise ValueError(f"{name}: must be 1-D, got shape {arr.shape}")
    return np.ascontiguousarray(arr)


#: The last model checked by :func:`_model_at`, with its ``dt``, name and values.
_last: tuple[Any, float, str, list[float]] | None = None


def _model_at(model: LowerLevelModel, dt: float) -> tuple[str, list[float]]:
    """Name and values of ``model`` after :func:`check_lower_level` at ``dt``, remembered
    for the last model object (models are frozen: the same object has the same values),
    so that a loop of calls on one model pays for them once."""
    global _last
    c = _last  # one read: another thread may replace it, never half of it
    if c is not None and c[0] is model and c[1] == dt:
        return c[2], c[3]
    name, p = model.name, model.values()
    check_lower_level(model, dt)
    _last = (model, dt, name, p)
    return name, list(p)


def _base(model: Any) -> LowerLevelModel | None:
    """The base model when ``model`` carries no effect (the linear path), else None."""
    if isinstance(model, LowerLevelModel):
        return model
    if isinstance(model, WithEffects):
        return model.base if not model.effects else None
    raise ValueError(f"model: expected an avll model or avll.WithEffects, got "
                     f"{type(model).__name__}")


def _with_effects(model: WithEffects, dt: float) -> tuple[str, list[float], list[str],
                                                           list[float]]:
    """Base name and values, effect names and values of a model with effects, after
    the stability policy (the base, and the braking side of an ``asymmetric``)."""
    check_lower_level(model.base, dt)
    asym = [e for e in model.effects if isinstance(e, Asymmetric)]
    if asym:
        c = WithEffects(model.base, tuple(asym)).linear(side=-1)
        if not _stable(c, dt):
            raise ValueError(
                f"model: the braking side of {model!r} (kb G(rb s): {c}) is not "
                f"asymptotically stable at dt={dt:g} s; its response diverges when braking, so "
                "no trajectory is returned")
    return (model.base.name, model.base.values(), list(model.effect_names),
            [float(x) for e in model.effects for x in e.to_array()])


def _parts(model: Any, base: LowerLevelModel | None, dt: float
           ) -> tuple[str, list[float], list[str], list[float]]:
    """Model name and values, effect names and values of the core call, after the
    stability policy: ``base`` (:func:`_base`) with no effect, else :func:`_with_effects`."""
    if base is not None:
        return (*_model_at(base, dt), [], [])
    assert isinstance(model, WithEffects)
    return _with_effects(model, dt)


def _start(init: Any, command_kind: Any) -> tuple[str, str]:
    return check_choice(init, "init", INITS), check_choice(command_kind, "command_kind",
                                                           COMMAND_KINDS)


def _exo(exo: Mapping[str, Any] | None) -> dict[str, np.ndarray]:
    if exo is not None and not isinstance(exo, Mapping):
        raise TypeError(f"exo: expected a mapping of signal name -> array, got {exo!r:.40}")
    out = {str(k): _f64(f"exo[{k!r}]", v) for k, v in (exo or {}).items()}
    for k, v in out.items():  # absurd magnitudes only: a synthetic exo can be any signal
        check_range(v, "other", f"exo[{k!r}]")
    return out


def _upper(upper: Any) -> UpperLevel:
    if not isinstance(upper, UpperLevel):
        raise TypeError(f"upper: expected an avll.UpperLevel, got {upper!r:.60}")
    return upper


def lower_level_stable(model: LowerLevelModel, dt: float) -> bool:
    """Whether the lower level of ``model`` (``G/(1 - K G)`` with its dead time) is
    asymptotically stable when sampled every ``dt`` seconds: the test behind the costs'
    ``inf`` (:func:`batch_cost`)."""
    c = model.linear()
    return _stable(c, check_number(dt, "dt", positive=True))


def _stable(c: Mapping[str, float], dt: float) -> bool:
    """The test of :func:`lower_level_stable` on the coefficients ``model.linear()``."""
    return _stable_at(c["b1"], c["b0"], c["a2"], c["a1"], c["Td"], c["K"], dt)


@functools.lru_cache(maxsize=4096)
def _stable_at(b1: float, b0: float, a2: float, a1: float, td: float, k: float,
               dt: float) -> bool:
    # cached: the test discretizes (a matrix exponential) and runs Schur-Cohn, ~8 us
    return bool(_core.lower_level_stable(b1, b0, a2, a1, td, k, dt))


def check_lower_level(model: LowerLevelModel, dt: float, *, what: str = "") -> None:
    """Raises ``ValueError`` naming the model and its parameters unless
    :func:`lower_level_stable` (the policy of every trajectory function)."""
    c = model.linear()
    if not _stable(c, float(dt)):
        why = (f"K K0 = {c['K'] * c['b0']:.4g} >= 1: the inner loop has no steady state"
               if c["K"] * c["b0"] >= 1 else
               "a pole of G/(1 - K G), with its dead time, sampled at dt, lies on or outside "
               "the unit circle")
        raise ValueError(
            f"model: the lower level {what}{model!r} is not asymptotically stable at "
            f"dt={dt:g} s ({why}); its response diverges, so no trajectory is returned "
            "(such parameters cost inf in batch_cost and the calibration)")


def _finite_or_raise(model: Any, dt: float, *arrays: np.ndarray) -> None:
    # a diverged rollout is NaN from the divergence to the end: the last sample tells
    for a in arrays:
        if a.size and not math.isfinite(float(a[-1])):
            raise ValueError(f"model: the response of {model!r} at dt={dt:g} s diverged "
                             "(|y| beyond 1e9 or not finite): the lower level, the command or "
                             "the initial state is out of range")


def simulate(
    model: Model, command: Any, dt: float, *, init: str = "rest",
    command_kind: str = "acceleration", exo: Mapping[str, Any] | None = None,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Open-loop response of ``model`` (a base model or an :class:`avll.WithEffects`) to
    ``command`` sampled every ``dt`` seconds.

    For an acceleration command the response is the acceleration (with effects: as
    observed, after a ``sensor``); for a speed command, the speed. ``init`` is
    ``"rest"`` or ``"steady"`` (see the module doc). ``command_kind`` and ``exo`` matter
    only with effects (a base model's response is the same for both kinds). ``out``: a
    float64 array of the command's length to write the response into (returned; see
    the module doc). An unstable lower level is a ``ValueError`` (see the module doc).
    """
    dt = _dt(dt)
    u = _f64("command", command)
    init, command_kind = _start(init, command_kind)
    base = _base(model)
    if base is not None:
        # `out` is checked by the binding (dtype, shape, layout, writeable, shared memory)
        y = _core.simulate(*_model_at(base, dt), u, dt, init, out)
    else:
        speed = command_kind == "speed"
        arrs = None
        if out is not None:
            spare = [np.empty(u.size) for _ in range(3)]
            arrs = [*spare[:1], out, *spare[1:]] if speed else [out, *spare]
        name, p, en, ep = _parts(model, None, dt)
        a, v, _, _ = _core.simulate_full(name, p, u, dt, command_kind, init, 0.0, 0.0,
                                         effects=en, effect_params=ep, exo=_exo(exo), out=arrs)
        y = v if speed else a
    _finite_or_raise(model, dt, y)
    return y


def simulate_full(
    model: Model,
    command: Any,
    dt: float,
    *,
    command_kind: str = "acceleration",
    init: str = "rest",
    v0: float = 0.0,
    x0: float = 0.0,
    exo: Mapping[str, Any] | None = None,
    out: Trajectory | Sequence[np.ndarray] | None = None,
) -> Trajectory:
    """Open-loop rollout with speed and position of a base model or an
    :class:`avll.WithEffects` (lower-level effects only: the upper-level structures act
    in the closed loop). For a speed command, ``a`` is the time derivative of the
    simulated speed at each sample (right limit). ``out``: a :class:`Trajectory` or four
    arrays (a, v, x, command) of the command's length to write into (see the module
    doc). An unstable lower level is a ``ValueError`` (see the module doc)."""
    dt = check_number(dt, "dt", positive=True)
    u = _f64("command", command)
    init, command_kind = _start(init, command_kind)
    v0, x0 = check_number(v0, "v0"), check_number(x0, "x0")
    arrs = None if out is None else _out_seq(out)  # the arrays are checked by the binding
    name, p, en, ep = _parts(model, _base(model), dt)
    d = _core.simulate_full(name, p, u, dt, command_kind, init, v0, x0, effects=en,
                            effect_params=ep, exo=_exo(exo), out=arrs)  # fmt: skip
    _finite_or_raise(model, dt, d[0], d[1], d[2])
    return _result(out, d if arrs is None else arrs)


def closed_loop(
    model: Model,
    lead_x: Any,
    lead_v: Any,
    dt: float,
    upper: UpperLevel,
    *,
    v0: float,
    x0: float,
    exo: Mapping[str, Any] | None = None,
    out: Trajectory | Sequence[np.ndarray] | None = None,
) -> Trajectory:
    """Car following behind a recorded leader: the upper law (Eq. 3, with the model's
    upper-level structures) evaluated at the samples commands the lower level (with its
    effects); the follower starts at speed ``v0`` and position ``x0`` with the lower
    level at rest. ``out``: a :class:`Trajectory` or four arrays (a, v, x, command) of the
    leader's length to write into (see the module doc). An unstable lower level is a
    ``ValueError``; a follower that diverges with a stable lower level (unstable
    upper-level gains) has a trajectory that is NaN from the divergence on."""
    base = _base(model)
    up = _upper(upper)
    dt = _dt(dt)
    lx, lv = _f64("lead_x", lead_x), _f64("lead_v", lead_v)
    v0, x0 = check_number(v0, "v0"), check_number(x0, "x0")
    if lv.size != lx.size:
        raise ValueError(f"lead_v: length {lv.size} differs from lead_x's {lx.size}")
    arrs = None if out is None else _out_seq(out)  # the arrays are checked by the binding
    if base is not None:  # the fast path of a loop of calls: no effect arguments
        d = _core.closed_loop(*_model_at(base, dt), lx, lv, dt, up.kg, up.kv, up.Tg, up.Gmin,
                              v0, x0, out=arrs)  # fmt: skip
    else:
        name, p, en, ep = _parts(model, None, dt)
        d = _core.closed_loop(name, p, lx, lv, dt, up.kg, up.kv, up.Tg, up.Gmin, v0, x0,
                              effects=en, effect_params=ep, exo=_exo(exo), out=arrs)
    return _result(out, d if arrs is None else arrs)


def platoon(
    model: Model,
    lead_x: Any,
    lead_v: Any,
    dt: float,
    upper: UpperLevel,
    followers: int,
    *,
    exo: Mapping[str, Any] | None = None,
    out: Trajectory | Sequence[np.ndarray] | None = None,
) -> Trajectory:
    """``followers`` identical vehicles (a base model or an :class:`avll.WithEffects`,
    upper-level structures included) behind a recorded leader, stepped time-major, each
    starting at the leader's initial speed and the equilibrium gap (``Gmin + Tg v``, the
    desired gap of the model's upper level at that speed) with the lower level at rest;
    each follower's upper law sees its predecessor's simulated position and speed.
    Arrays are (follower, sample), laid out sample-major (Fortran order: each is the
    transpose of a C-contiguous (sample, follower) array, the layout the stepping
    writes). ``out``: a :class:`Trajectory` or four such (followers, samples) arrays to
    write into, e.g. a platoon's earlier result or ``np.empty((samples, followers)).T``
    (see the module doc). ``followers`` must be an integer >= 1; a platoon whose arrays
    cannot fit in memory is refused with a ``ValueError`` (simulate it in slices of
    followers: the last follower of a slice is the leader of the next). An unstable
    lower level is a ``ValueError``; a diverging follower (and every one behind it) is
    NaN from the divergence on."""
    nf = check_int(followers, "followers", min=1)
    base = _base(model)
    up = _upper(upper)
    dt = _dt(dt)
    lx, lv = _f64("lead_x", lead_x), _f64("lead_v", lead_v)
    arrs = None if out is None else _out_seq(out)
    if arrs is not None:
        names = [f"out[{k}] ({f})" for k, f in enumerate(("a", "v", "x", "command"))]
        _check_out(list(zip(names, arrs, strict=True)), (nf, lx.size), [lx, lv], order="F")
    else:
        per = 2 * 4 * 8 * max(lx.size, 1)
        check_memory(
            float(nf) * per, f"platoon: followers={nf} x {lx.size} samples x 4 arrays x 8 "
            "bytes (twice while copying)",
            "simulate fewer followers per call (the last follower's x and v lead the next "
            "slice)",
            per=per, unit="followers")
    name, p, en, ep = _parts(model, base, dt)
    d = _core.platoon(name, p, lx, lv, dt, up.kg, up.kv, up.Tg, up.Gmin, nf, effects=en,
                      effect_params=ep, exo=_exo(exo),
                      out=None if arrs is None else [a.T for a in arrs])  # fmt: skip
    return _result(out, [a.T for a in d] if arrs is None else arrs)


def _structure(
    model: Any, effects: Sequence[str]
) -> tuple[type[LowerLevelModel], tuple[str, ...]]:
    """The base class and the effects (canonical order) of a batched call: ``model`` a
    name, a class, a model, or an :class:`avll.WithEffects` (its effects; not also
    ``effects``)."""
    if isinstance(model, WithEffects):
        if effects:
            raise ValueError("effects: give them either in the model or as effects=, not both")
        return type(model.base), tuple(model.effect_names)
    return model_class(model), canonical(list(effects)) if effects else ()


def batch_cost(
    model: str | type[LowerLevelModel] | Model,
    params: Any,
    runs: Any,
    *,
    effects: Sequence[str] = (),
    weights: Sequence[float] | None = None,
    init: str = "rest",
    closed_loop: bool = False,
    upper_free: Sequence[int] = (),
    threads: int = 0,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Per-run costs of many parameter sets: a (P, R) array (``out``, a float64 (P, R)
    array to write into, when given; see the module doc).

    ``model`` names the structure of the parameter rows: a base model (name, class or
    instance) with ``effects`` (names, any order), or an :class:`avll.WithEffects`
    (its effects; its values are not used). Rows are ``[model | effects (canonical
    order) | free upper gains]``. ``runs``: an :class:`avll.RunSet` or a list of runs
    (packed once, :class:`avll.RunSet`: every column the runs have, so the measured
    speed and position start the integrators whenever the runs carry them).

    Each cost is ``wa MSE(a) + wv MSE(v) + wx MSE(x)`` over the run's samples;
    ``weights=None`` are the loop's defaults (:func:`avll.defaults.objective_weights`:
    the paper's Eq. 6 in open loop, whose value is the mean over runs, and
    :data:`avll.defaults.CLOSED_LOOP_WEIGHTS` in closed loop). Open loop
    drives the model with each run's recorded command; closed loop drives it with the
    recorded leader through the run's upper law, whose parameters listed in
    ``upper_free`` (0 kg, 1 kv, 2 Tg, 3 Gmin) are taken from the extra columns of
    ``params``. Invalid or unstable parameter sets cost ``inf``. ``threads`` (0 = all
    cores) is bounded by the machine; a ``(P, R)`` result that cannot fit in memory is
    refused (evaluate the parameter rows in slices).
    """
    from .runs import as_runset

    nt = check_threads(threads)
    cls, names = _structure(model, effects)
    p = params_2d(params)
    if isinstance(runs, (str, bytes, Run)) or not hasattr(runs, "__len__"):
        raise TypeError(f"runs: expected a sequence of avll.Run, got {type(runs).__name__}")
    nr = max(len(runs), 1)
    if out is not None:
        _check_out([("out", out)], (p.shape[0], len(runs)), [p])
    check_memory(8.0 * p.shape[0] * nr,
                 f"batch_cost: {p.shape[0]} parameter rows x {len(runs)} runs x 8 bytes",
                 "evaluate the parameter rows in slices", per=8.0 * nr, unit="rows")
    kw = as_runset(runs).cost_kw(weights=weights, init=init, closed_loop=closed_loop,
                                 upper_free=upper_free, exo=exo_needs(names))  # fmt: skip
    return _core.batch_cost(cls.name, p, effects=list(names), threads=nt, out=out, **kw)


def params_2d(params: Any, name: str = "params") -> np.ndarray:
    """Parameter rows as a C-contiguous (P, n) float64 array (a ``ValueError`` naming
    ``name`` for anything that is not numbers; ``ValueError`` for more than 2-D)."""
    p = check_floats(params, name)
    if p.ndim > 2:
        raise ValueError(f"{name}: must be 1-D (one row) or 2-D (rows), got shape {p.shape}")
    return np.ascontiguousarray(np.atleast_2d(p))


@dataclass(frozen=True)
class BatchSimulation:
    """The result of :func:`simulate_batch`: per run, (P, len(run)) arrays of the
    simulated acceleration ``a``, speed ``v`` and position ``x`` and the ``residual``
    (simulated minus measured acceleration); row ``p`` is parameter row ``p``."""

    a: list[np.ndarray]
    v: list[np.ndarray]
    x: list[np.ndarray]
    residual: list[np.ndarray]


def simulate_batch(
    model: str | type[LowerLevelModel] | Model,
    params: Any,
    runs: Any,
    *,
    effects: Sequence[str] = (),
    weights: Sequence[float] | None = None,
    init: str = "rest",
    closed_loop: bool = False,
    upper_free: Sequence[int] = (),
    threads: int = 0,
    out: np.ndarray | None = None,
) -> BatchSimulation:
    """Simulates P parameter rows on R runs in one parallel call, exactly as the cost
    sees them (same drive, initial state, effects and free upper-level gains).

    ``model``, ``effects`` and the rows as in :func:`batch_cost`. Returns a
    :class:`BatchSimulation`. Rows the cost calls invalid or unstable are NaN; a closed
    loop that diverges is NaN after the divergence. ``out``: a float64 C-contiguous (3,
    P, T) array (``T`` the runs' total length) to write a, v, x into, run after run; the
    lists then hold views of it (``residual`` is new; see the module doc).
    """
    from .runs import as_runset

    cls, names = _structure(model, effects)
    p = params_2d(params)
    if isinstance(runs, (str, bytes, Run)) or not hasattr(runs, "__len__") or not len(runs):
        raise ValueError("runs: no runs given")
    rs = as_runset(runs)
    kw = rs.cost_kw(weights=weights, init=init, closed_loop=closed_loop,
                    upper_free=upper_free, exo=exo_needs(names))  # fmt: skip
    if out is not None:
        _check_out([("out", out)], (3, p.shape[0], rs.total), [p])
    arr = _core.simulate_batch(cls.name, p, effects=list(names), threads=check_threads(threads),
                               out=out, **kw)  # fmt: skip
    off = rs.offsets
    a, v, x = ([arr[k][:, off[j] : off[j + 1]] for j in range(len(rs))] for k in range(3))
    return BatchSimulation(a, v, x, [a[j] - rs[j].a[None, :] for j in range(len(rs))])
