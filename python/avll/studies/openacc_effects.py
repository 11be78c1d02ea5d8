"""Which effect closes the amplification gap?

:func:`avll.studies.openacc.openacc_study` compares, per car, the measured
amplification of the predecessor's speed oscillations with the amplification of
each calibrated lower-level model replayed behind the measured predecessor. Where
**no** lower-level model replays within ``tol`` (10 %) of the measured value,
:func:`effect_gaps` asks which effect of the library, added to the best of the
three lower-level models, gets there:

1. for each such car and each candidate effect, the base model, the effect and
   the upper-level law (``kg``, ``kv``, ``Tg``, ``Gmin``) are calibrated together
   in closed loop behind the measured predecessor (the study's objective
   :data:`~avll.studies.openacc.WEIGHTS` and box; the effect's own
   :attr:`~avll.effects.Effect.bounds`; the car's calibrated linear model joins
   the first population with the effect at its neutral parameters, so the fit can
   only improve on it);
2. the calibrated model with its effect is replayed behind the measured
   predecessor (:func:`avll.closed_loop`) and its amplification
   measured with the same band-pass as the data
   (:func:`~avll.studies.openacc.amplification`).

An effect *closes the gap* of a car when its replayed amplification is within
``tol`` of the measured one **and** it lowers the calibration cost by at least
``min_gain`` (2 % by default: an effect the fit switches off changes the cost by
round-off and must not be credited with a replay the linear model already had). The
amplification was never an objective of the fit, so a closed gap is evidence that
the effect captures what makes that car amplify; it is still in-sample (the same
run is fitted and replayed), which the summary says. Effects reading an exogenous
signal the runs lack (``grade`` without ``exo_grade``) are skipped with the reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict
from typing import Any

import numpy as np

from ..data import Run
from ..defaults import GA_OPTIONS, UPPER_NAMES
from ..effects import EFFECTS, WithEffects
from ..models import UpperLevel
from ..rollout import closed_loop
from .openacc import WEIGHTS, OpenACCStudy, _fin, _model_of, _upper_of, amplification

__all__ = ["EFFECT_CANDIDATES", "effect_gaps"]

#: Effects tried by default: the actuator's and the vehicle's (``speed_drag`` is
#: left out, ``road_load`` contains it; ``grade`` needs ``exo_grade``).
EFFECT_CANDIDATES: tuple[str, ...] = (
    "delay", "rate_limit", "deadband", "asymmetric", "saturation", "power_limit",
    "road_load", "sensor", "grade",
)  # fmt: skip


def _gap_cars(study: OpenACCStudy, tol: float) -> list[tuple[int, str]]:
    """(index, best model) of the cars where no model replays within ``tol``."""
    out = []
    for i, c in enumerate(study.summary["cars"]):
        meas = c.get("amplification_measured")
        if meas is None:
            continue
        errs = {m: d["amplification_replay_error"] for m, d in c["models"].items()
                if d.get("amplification_replay_error") is not None}
        if not errs:
            continue
        best = min(errs, key=lambda m: abs(errs[m]))
        if abs(errs[best]) > tol:
            out.append((i, best))
    return out


def _fit_effect(run: Run, base: str, params: Mapping[str, float], effect: str, *,
                gmin_max: float, seed: int, max_generations: int, starts: int,
                threads: int) -> tuple[WithEffects, UpperLevel, float]:
    """The calibration (:func:`avll.calibrate`) of base + ``effect`` + the upper law in
    the study's box and objective, started from the car's linear calibration (the
    effect at its neutral value); returns the model, the law and its cost (the study's
    Eq. 6 with :data:`WEIGHTS`)."""
    from ..calibration import calibrate

    neutral = EFFECTS[effect].from_array(np.array(EFFECTS[effect].neutral))
    start = WithEffects(_model_of(base, params), (neutral,)).to_array()
    res = calibrate(
        base, [run], effects=[effect], initial=[np.r_[start, _upper_of(params).to_array()]],
        seed=seed, closed_loop=True, upper_free=UPPER_NAMES, weights=WEIGHTS,
        max_generations=max_generations, init="rest", threads=threads, starts=starts,
        bounds={"Gmin": (0.0, gmin_max)},
    )  # fmt: skip
    if res.interrupted:
        raise KeyboardInterrupt
    return res.with_effects, UpperLevel(**res.upper), float(res.cost)


def effect_gaps(
    study: OpenACCStudy,
    *,
    effects: Sequence[str] = EFFECT_CANDIDATES,
    tol: float = 0.10,
    min_gain: float = 0.02,
    seed: int = 0,
    max_generations: int | None = None,
    starts: int = 1,
    threads: int = 0,
    band: Sequence[float] | None = None,
    gmin_max: float | None = None,
    log: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """For every car of ``study`` whose amplification no lower-level model replays
    within ``tol``, calibrates the best model plus each of ``effects`` and replays
    it (see the module doc). Returns a strict-JSON-ready dict: ``cars`` (per car:
    the measured amplification, the best linear model's replay and, per effect,
    the calibration cost before/after and its relative gain, the replayed
    amplification and its error, or the reason it was skipped), ``closed_by``
    (effect -> number of cars whose gap it closes) and ``not_closed`` (the cars
    no effect closes)."""
    if not (isinstance(tol, (int, float)) and 0 < tol < 1):
        raise ValueError(f"tol: must be a number in (0, 1), got {tol!r}")
    if not (isinstance(min_gain, (int, float)) and 0 <= min_gain < 1):
        raise ValueError(f"min_gain: must be a number in [0, 1), got {min_gain!r}")
    for e in effects:
        if e not in EFFECTS:
            raise ValueError(f"effects: unknown effect {e!r}; known: {', '.join(EFFECTS)}")
    say = log or (lambda s: None)
    if max_generations is None:
        max_generations = GA_OPTIONS["max_generations"]
    s = study.summary
    band = tuple(s["band_hz"]) if band is None else tuple(band)
    gmax = float(s["bounds"]["Gmin"][1]) if gmin_max is None else float(gmin_max)
    gap = _gap_cars(study, tol)
    runs = {r.run_id: r for r in study.runs}
    out_cars = []
    closed_by = dict.fromkeys(effects, 0)
    not_closed = []
    for k, (i, best) in enumerate(gap):
        c = s["cars"][i]
        r = runs[c["run_id"]]
        assert r.lead_x is not None and r.lead_v is not None and r.v is not None
        meas = float(c["amplification_measured"])
        md = c["models"][best]
        entry: dict[str, Any] = {
            "run_id": c["run_id"], "car": c["car"], "setting": c["setting"],
            "campaign": c.get("campaign"), "setting_rank": c.get("setting_rank"),
            "acc": c.get("acc"), "group": c.get("group"),
            "amplification_measured": meas, "base_model": best,
            "base_amplification_replay": md["amplification_replay"],
            "base_amplification_replay_error": md["amplification_replay_error"],
            "base_cal_mse": md["cal_mse"], "effects": {},
        }
        say(f"[{k + 1}/{len(gap)}] {c['run_id']}: measured {meas:.3f}, {best} replays "
            f"{md['amplification_replay']:.3f}")
        closers = []
        for j, e in enumerate(effects):
            sig = EFFECTS[e].exo
            if sig is not None and sig not in r.exo:
                entry["effects"][e] = {"skipped": f"the run has no 'exo_{sig}' signal"}
                continue
            try:
                model, up, f = _fit_effect(r, best, md["params"], e, gmin_max=gmax,
                                           seed=int(seed) + 100 * j + 10_000 * i,
                                           max_generations=max_generations, starts=starts,
                                           threads=threads)  # fmt: skip
            except ValueError as err:
                entry["effects"][e] = {"skipped": f"calibration failed: {err}"}
                continue
            why = None
            try:
                tr = closed_loop(model, r.lead_x, r.lead_v, r.dt, up, v0=float(r.v[0]),
                                 x0=float(r.x[0]) if r.x is not None else 0.0, exo=r.exo)
                a_r = (amplification(tr.v, r.lead_v, r.dt, band)[0]
                       if np.all(np.isfinite(tr.v)) else math.nan)  # fmt: skip
            except ValueError as err:  # a calibrated model the trajectory functions refuse
                a_r, why = math.nan, f"no replay: {err}"
            err_r = a_r / meas - 1.0 if math.isfinite(a_r) else math.nan
            base_cost = md["cal_mse"]
            better = (base_cost is not None and math.isfinite(f)
                      and f < (1.0 - min_gain) * base_cost)
            closes = bool(math.isfinite(err_r) and abs(err_r) <= tol and better)
            d: dict[str, Any] = {
                "params": model.effects[0].to_dict(), "upper": asdict(up),
                "cal_mse": _fin(f), "amplification_replay": _fin(a_r),
                "amplification_replay_error": _fin(err_r),
                "cost_gain": _fin(1.0 - f / base_cost) if base_cost else None,
                "lowers_cost": bool(better),
                "closes_gap": closes,
            }
            if not math.isfinite(a_r):
                d["amplification_replay_reason"] = why or "the replay with the effect diverges"
            entry["effects"][e] = d
            if closes:
                closers.append(e)
                closed_by[e] += 1
            say(f"  + {e}: cost {base_cost if base_cost is None else round(base_cost, 5)} -> "
                f"{f:.5g}, replay {a_r:.3f} ({err_r:+.1%})" + (" closes" if closes else ""))
        entry["closed_by"] = closers
        if closers:
            errs = {e: abs(entry["effects"][e]["amplification_replay_error"]) for e in closers}
            entry["best_effect"] = min(errs, key=errs.__getitem__)
        else:
            not_closed.append(c["run_id"])
        out_cars.append(entry)
    return {
        "tol": float(tol), "min_gain": float(min_gain), "effects": list(effects),
        "band_hz": list(band), "gmin_max": gmax, "seed": int(seed),
        "ga": {"max_generations": int(max_generations), "starts": int(starts)},
        "n_cars": len(s["cars"]), "n_gap": len(gap), "cars": out_cars,
        "closed_by": closed_by, "not_closed": not_closed,
        "caveat": ("in-sample: each car's effect is calibrated on the run it is replayed "
                   "on; the amplification is not part of the objective"),
    }

