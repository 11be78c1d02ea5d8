"""The calibrated model as a JSON dict and back, and the one simulation the loop's
reported errors come from (the contract of ``avll diagnose``: scripts depend on it).

``final_model`` in the JSON of :func:`avll.diagnose.effect_loop` /
``avll diagnose`` is :func:`model_to_dict` of the final model::

    {"base": "second", "params": {"K0": ..., ...},
     "effects": [{"name": "delay", "params": {"tau": ...}}, ...],
     "upper": {"kg": ..., "kv": ..., "Tg": ..., "Gmin": ...} or null,
     "simulation": {"init": "rest", "closed_loop": false}}

:func:`model_from_dict` rebuilds the model (a :class:`~avll.WithEffects`, or the plain
base model when there are no effects); :func:`simulate_run` gives its simulated
acceleration on an :class:`~avll.Run` — every per-run MSE the loop reports
(calibration, validation, test) is ``mean((run.a - simulate_run(...))**2)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from ..data import Run
from ..effects import WithEffects, effect_class
from ..models import LowerLevelModel, UpperLevel, model_class
from .fitting import _closed, _init, simulate_runs

__all__ = ["model_to_dict", "model_from_dict", "simulate_run"]


def model_to_dict(
    model: WithEffects | LowerLevelModel,
    *,
    upper: UpperLevel | None = None,
    init: str | None = None,
    closed_loop: bool | None = None,
) -> dict[str, Any]:
    """The JSON dict of ``model`` (see the module doc); ``upper`` is the calibrated
    upper-level law (closed loop with unknown law), ``init``/``closed_loop`` how the
    loop simulated the runs."""
    if isinstance(model, LowerLevelModel):
        model = WithEffects(model, ())
    if not isinstance(model, WithEffects):
        raise TypeError(f"model: expected an avll model or WithEffects, got {type(model).__name__}")
    return {
        "base": model.base.name,
        "params": model.base.to_dict(),
        "effects": [{"name": e.name, "params": e.to_dict()} for e in model.effects],
        "upper": None if upper is None else {
            "kg": upper.kg, "kv": upper.kv, "Tg": upper.Tg, "Gmin": upper.Gmin},
        "simulation": {"init": init, "closed_loop": closed_loop},
    }  # fmt: skip


def model_from_dict(d: Mapping[str, Any]) -> WithEffects | LowerLevelModel:
    """Rebuilds the model of a ``final_model`` dict (or of a whole ``avll diagnose``
    JSON, whose ``final_model`` is taken): a :class:`~avll.WithEffects` with the
    effects in their canonical order, or the plain base model when there are none.
    A ``ValueError`` names the key that is missing or wrong."""
    if not isinstance(d, Mapping):
        raise TypeError(f"model_from_dict: expected a dict, got {type(d).__name__}")
    if "final_model" in d and "base" not in d:
        d = d["final_model"]
        if not isinstance(d, Mapping):
            raise ValueError("final_model: expected a dict")
    for key in ("base", "params"):
        if key not in d:
            raise ValueError(f"model_from_dict: missing key {key!r}")
    cls = model_class(str(d["base"]))
    params = d["params"]
    if not isinstance(params, Mapping):
        raise ValueError("params: expected a dict of parameter values")
    missing = [n for n in cls.param_names() if n not in params]
    extra = [k for k in params if k not in cls.param_names()]
    if missing or extra:
        raise ValueError(f"params: model {cls.name!r} takes {list(cls.param_names())}; "
                         f"missing {missing}, unknown {extra}")  # fmt: skip
    base = cls.from_array([float(params[n]) for n in cls.param_names()])
    effs = []
    for k, e in enumerate(d.get("effects") or []):
        if not isinstance(e, Mapping) or "name" not in e:
            raise ValueError(f"effects[{k}]: expected {{'name': ..., 'params': {{...}}}}")
        ecls = effect_class(str(e["name"]))
        ep = e.get("params") or {}
        bad = [n for n in ecls.param_names() if n not in ep]
        if bad:
            raise ValueError(f"effects[{k}] ({ecls.name}): missing parameters {bad}")
        effs.append(ecls(**{n: float(ep[n]) for n in ecls.param_names()}))
    return WithEffects(base, tuple(effs)) if effs else base


def simulate_run(
    model: WithEffects | LowerLevelModel,
    run: Run,
    *,
    upper: UpperLevel | None = None,
    init: str = "auto",
    closed_loop: bool | None = None,
) -> np.ndarray:
    """The simulated acceleration of ``model`` on ``run``: open loop from the run's
    command, or — when the run has no command (or ``closed_loop=True``) — closed
    loop behind the run's leader through the run's upper-level law (``upper``
    replaces it, e.g. the calibrated law of ``final_model["upper"]``). The initial
    state comes from the run (its first measured speed and position; ``init="auto"``:
    at rest for an acceleration command, steady state for a speed command), exogenous
    signals (``exo_*``) from the run. The same rollout as the calibration cost and as
    every error :func:`avll.diagnose.effect_loop` reports."""
    if isinstance(model, LowerLevelModel):
        model = WithEffects(model, ())
    if not isinstance(model, WithEffects):
        raise TypeError(f"model: expected an avll model or WithEffects, got {type(model).__name__}")
    if not isinstance(run, Run):
        raise TypeError(f"run: expected an avll.Run, got {type(run).__name__}")
    if upper is not None:
        run = replace(run, upper=upper)
    closed = _closed([run], closed_loop)
    return simulate_runs(model, [run], closed_loop=closed, init=_init([run], init))[0]
