"""Effect signatures and the score test by simulation: which effect of the
registry (:data:`avll.effects.EFFECTS`) the residual of a model points at.

Each effect not yet in the model has a *signature*: the change of the simulated
acceleration when the effect is switched on, ``s = a(model + effect(phi)) -
a(model)``, one column per effect parameter (threshold-type effects — saturation,
dead-band, rate limit — profiled over a small grid of thresholds taken from the
data; an effect this module has no special knowledge of — any new registry entry —
gets one column per free parameter, each moved from its neutral value a third of
the way to its farther bound, profiled over two such steps). The residual is
regressed on the base model's own sensitivities ``J`` (finite differences: what a
recalibration of the present parameters could absorb) and then on ``[J, s]``:

* ``explained`` = ``(RSS_J - RSS_Js) / sum(e²)``, the share of the residual only
  the effect explains;
* ``F = ((RSS_J - RSS_Js)/q) / (RSS_Js/(n_eff - k))`` with the effective sample size
  of the residual with the effect (:mod:`avll.diagnose.stats`); the p-value is
  Bonferroni-corrected for the profiled grid and the number of candidates;
* ``val_explained``: the same coefficients applied to held-out runs (when given).

An effect is a candidate when ``p < alpha``, ``explained >= min_explained`` and (when
held-out runs are given) ``val_explained > 0``; candidates are ranked by
``explained``. The loop (:func:`avll.diagnose.effect_loop`) uses this only to choose
which effects to cross-validate; it does not accept anything by itself.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from scipy import signal, stats

from ..data import Run
from ..effects import CANONICAL_ORDER, EFFECTS, WithEffects
from ..models import LowerLevelModel
from ..runs import RunSet, as_runset
from .defaults import ALPHA, MIN_SHARE
from .fitting import BATCH, _fixed, _setup, _simulate, _split
from .stats import SignalDependence, _binned, _ess, _lag1, _lstsq

__all__ = ["Candidate", "Diagnosis", "diagnose", "offered", "residual_structure"]


@dataclass(frozen=True)
class Candidate:
    """Evidence for one effect (see the module doc)."""

    effect: str
    explained: float
    val_explained: float
    F: float
    df: int
    p_value: float
    hint: dict[str, float]
    significant: bool


@dataclass(frozen=True)
class Diagnosis:
    """Residual statistics of a model on calibration runs (and held-out runs)."""

    model: WithEffects
    residual_rms: float
    speed_residual_rms: float | None
    lag1: float
    n_eff: float
    autocorr: np.ndarray
    freq: np.ndarray
    psd: np.ndarray
    xcorr_lags: np.ndarray
    xcorr: np.ndarray
    best_lag: float
    signals: list[SignalDependence]
    candidates: list[Candidate]

    @property
    def ranked(self) -> list[Candidate]:
        """Significant candidates, best first."""
        return [c for c in self.candidates if c.significant]

    def plot(self) -> list[tuple[str, Any]]:
        """The diagnosis' figures by name (:func:`avll.plotting.residual_diagnosis`)."""
        from ..plotting import residual_diagnosis

        return residual_diagnosis(self)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (the ``avll diagnose`` JSON contract)."""
        return {
            "model": self.model.name,
            "residual_rms": self.residual_rms,
            "speed_residual_rms": self.speed_residual_rms,
            "lag1_autocorrelation": self.lag1,
            "n_eff": self.n_eff,
            "xcorr_best_lag_s": self.best_lag,
            "signals": [s.to_dict() for s in self.signals],
            "candidates": [asdict(c) for c in self.candidates],
        }


def _signals(run: Run, sim: np.ndarray) -> dict[str, np.ndarray]:
    dt = run.dt
    u = run.command if run.command is not None else sim
    du = np.gradient(u, dt)
    out = {
        "command": u,
        "|command|": np.abs(u),
        "command rate": du,
        "command jerk": np.gradient(du, dt),
        "simulated acceleration": sim,
    }
    if run.command_kind == "speed" and run.command is not None and run.v is not None:
        # For a speed command the demand is the speed error; its sign says braking.
        out["speed error"] = run.command - run.v
        out["sign of speed error"] = np.sign(run.command - run.v)
    else:
        out["sign of command"] = np.sign(u)
    out["sign of acceleration"] = np.sign(sim)
    if run.v is not None:
        out["speed"] = run.v
    for k, v in run.exo.items():
        out[f"exo_{k}"] = v
    return out


def _commands(runs: Sequence[Run], sims: list[np.ndarray]) -> list[np.ndarray]:
    return [r.command if r.command is not None else s for r, s in zip(runs, sims, strict=True)]


def _rate_limit_trials(runs: Sequence[Run], sims: list[np.ndarray]) -> list[dict[str, float]]:
    du = np.concatenate([np.abs(np.diff(u)) / r.dt
                         for r, u in zip(runs, _commands(runs, sims), strict=True)])
    qs = np.quantile(du, [0.7, 0.85, 0.93, 0.97, 0.99])
    return [{"j_max": float(max(q, 0.1))} for q in qs]


def _deadband_trials(runs: Sequence[Run], sims: list[np.ndarray]) -> list[dict[str, float]]:
    u = np.abs(np.concatenate(_commands(runs, sims)))
    qs = np.quantile(u, [0.05, 0.1, 0.2, 0.3, 0.45])
    return [{"delta": float(min(max(q, 0.005), 1.0))} for q in qs]


def _saturation_trials(runs: Sequence[Run], sims: list[np.ndarray]) -> list[dict[str, float]]:
    a = np.concatenate(sims)
    pos, neg = a[a > 0], -a[a < 0]
    qa = np.quantile(pos, [0.6, 0.8, 0.9, 0.97]) if pos.size > 20 else np.array([6.0])
    qd = np.quantile(neg, [0.6, 0.8, 0.9, 0.97]) if neg.size > 20 else np.array([10.0])
    return [{"a_max": float(max(x, 0.2)), "d_max": float(max(y, 0.2))}
            for x in qa for y in qd]  # fmt: skip


#: Trial settings taken from the data (thresholds at quantiles of the command, its
#: rate or the acceleration), for the threshold effects.
_TRIALS_FROM_DATA = {"rate_limit": _rate_limit_trials, "deadband": _deadband_trials,
                     "saturation": _saturation_trials}


def _effect_grid(name: str, runs: Sequence[Run], sims: list[np.ndarray]) -> list[dict[str, float]]:
    """Parameter settings whose signatures are tried for an effect not in the model:
    the effect's own ``trials`` (:class:`avll.effects.Effect`), else thresholds from the
    data, else every free parameter moved from its neutral value towards its farther
    bound, by two step sizes (see the module doc)."""
    if name not in EFFECTS:
        raise ValueError(f"effect: unknown {name!r}")
    if EFFECTS[name].trials:
        return [dict(t) for t in EFFECTS[name].trials]
    if name in _TRIALS_FROM_DATA:
        return _TRIALS_FROM_DATA[name](runs, sims)
    return [_generic_setting(name, f, runs[0].command_kind) for f in _GENERIC_STEPS]


#: The shares of the way from the neutral value to the farther bound at which the
#: signature of an effect without trial settings is taken.
_GENERIC_STEPS: tuple[float, ...] = (1.0 / 6.0, 1.0 / 3.0)


def _generic_setting(name: str, step: float, kind: str) -> dict[str, float]:
    cls = EFFECTS[name]
    out = {}
    for p, n0, (lo, hi) in zip(cls.param_names(), cls.neutral, cls.bounds, strict=True):
        fx = _fixed(name, p, kind)
        if fx is not None:
            out[p] = fx
            continue
        far = hi if abs(hi - n0) >= abs(lo - n0) else lo
        out[p] = float(n0 + step * (far - n0))
    return out


def _signatures(
    model: WithEffects, name: str, grid: Sequence[dict[str, float]], rs: RunSet,
    base: np.ndarray, closed: bool, init: str,
) -> Iterator[list[np.ndarray] | None]:
    """The signature columns of effect ``name`` at each setting of ``grid`` in turn (one
    per parameter of a linear-in-parameter effect, one per threshold setting
    otherwise), concatenated over runs, the settings simulated together in batched
    calls of at most :data:`avll.diagnose.fitting.BATCH` row-samples; ``None`` for a
    setting the effect refuses. ``base`` is the model's own simulation (concatenated)."""
    cls = EFFECTS[name]
    neutral = dict(zip(cls.param_names(), cls.neutral, strict=True))
    models: list[list[WithEffects] | None] = []
    for setting in grid:
        if cls.signature in ("linear", "each"):  # one parameter moved at a time
            moved = [{**neutral, p: setting[p]} for p in cls.param_names()
                     if cls.signature == "each" or _fixed(name, p, rs.command_kind) is None]
        else:
            moved = [dict(setting)]
        try:
            models.append([WithEffects(model.base, (*model.effects, cls(**d))) for d in moved])
        except ValueError:
            models.append(None)
    per_call = max(1, BATCH // max(base.size, 1))
    i = 0
    while i < len(models):
        chunk = [models[i]]
        while i + len(chunk) < len(models) and sum(len(ms or ()) for ms in chunk) + len(
                models[i + len(chunk)] or ()) <= per_call:
            chunk.append(models[i + len(chunk)])
        every = [m for ms in chunk if ms for m in ms]
        sims = _simulate(every[0], np.vstack([m.to_array() for m in every]), rs, closed,
                         init) if every else base[None, :0]  # fmt: skip
        k = 0
        for ms in chunk:
            yield None if ms is None else [sims[k + j] - base for j in range(len(ms))]
            k += len(ms or ())
        i += len(chunk)


def _sensitivities(
    model: WithEffects, rs: RunSet, base: np.ndarray, closed: bool, init: str,
) -> np.ndarray:
    """Finite-difference sensitivities of the simulated acceleration to the model's
    own parameters, concatenated over runs (one batched call): (n, p)."""
    p0 = model.to_array()
    rows, steps = [], []
    for j in range(p0.size):
        h = 1e-4 * max(abs(p0[j]), 1e-2)
        p = p0.copy()
        p[j] += h
        try:
            WithEffects.from_array(model.base.name, model.effect_names, p)
        except ValueError:
            continue
        rows.append(p)
        steps.append(h)
    cols = [] if not rows else list(
        (_simulate(model, np.vstack(rows), rs, closed, init) - base) / np.array(steps)[:, None])
    cols = [c for c in cols if np.all(np.isfinite(c))]
    return np.column_stack(cols) if cols else np.zeros((base.size, 0))


def offered(
    model: WithEffects, runs: Sequence[Run], candidates: Sequence[str] | None = None,
    *, closed: bool = False,
) -> list[str]:
    """The effects of the registry (or of ``candidates``) that can be tried on
    ``model`` with ``runs``: not already in the model, allowed for the runs' command
    kind (``accel_only`` effects not for a speed command), not refused together with
    an effect of the model (``road_load`` / ``speed_drag``), with their exogenous
    signal (``exo_<name>``) in every run, and upper-level structures only in a closed
    loop (``closed``: in an open loop the recorded command replaces the law)."""
    names = list(CANONICAL_ORDER if candidates is None else candidates)
    why = not_offered(model.effect_names, runs, names, closed=closed)
    return [n for n in names if n not in why]


def not_offered(have: Sequence[str], runs: Sequence[Run], candidates: Sequence[str], *,
                closed: bool = False) -> dict[str, str]:
    """Why each of ``candidates`` that :func:`offered` leaves out, for a model with the
    effects ``have``, is left out (effect name -> reason); a ``ValueError`` for a name
    that is not an effect."""
    kind = runs[0].command_kind if runs else "acceleration"
    out: dict[str, str] = {}
    for n in candidates:
        if n not in EFFECTS:
            raise ValueError(f"candidates: unknown effect {n!r}; known: {', '.join(EFFECTS)}")
        cls = EFFECTS[n]
        missing = [r.run_id for r in runs if cls.exo is not None and cls.exo not in r.exo]
        if n in have:
            reason = "it is already in the model"
        elif cls.accel_only and kind == "speed":
            reason = "it needs an acceleration command"
        elif cls.level == "upper" and not closed:
            reason = "an upper-level structure needs a closed loop"
        elif cls.excludes in have:
            reason = f"it is not identifiable together with {cls.excludes!r}"
        elif missing:
            reason = (f"it needs the column 'exo_{cls.exo}', which run(s) "
                      f"{', '.join(map(repr, missing[:5]))} lack")
        else:
            continue
        out[n] = reason
    return out


def diagnose(
    model: WithEffects | LowerLevelModel,
    runs: Sequence[Run],
    val_runs: Sequence[Run] = (),
    *,
    closed_loop: bool | None = None,
    alpha: float = ALPHA,
    min_explained: float = 0.01,
    candidates: Sequence[str] | None = None,
    init: str = "auto",
) -> Diagnosis:
    """Residual diagnosis of ``model`` on ``runs`` (the held-out ``val_runs`` check
    the candidates). See the module doc for the statistics."""
    if isinstance(model, LowerLevelModel):
        model = WithEffects(model, ())
    if not runs:
        raise ValueError("runs: no runs given")
    # packed once for the batched simulations below (a RunSet is used as it is)
    runs, closed, init = _setup(runs, closed_loop, init)
    val_runs = as_runset(val_runs) if val_runs else ()
    base = _simulate(model, model.to_array(), runs, closed, init)[0]
    sims = _split(base, runs)
    res = [r.a - s for r, s in zip(runs, sims, strict=True)]
    if not all(np.all(np.isfinite(x)) for x in res):
        raise ValueError("model: the simulation diverges on the runs")
    e = np.concatenate(res)
    r1 = _lag1(res)
    n_eff = _ess(res)
    # Speed residual (open loop: integrate the simulated acceleration from v[0]).
    speed_rms = None
    if all(r.v is not None for r in runs):
        evs = []
        for r, s in zip(runs, sims, strict=True):
            assert r.v is not None
            vs = r.v[0] + np.concatenate([[0.0], np.cumsum(0.5 * r.dt * (s[1:] + s[:-1]))])
            evs.append(r.v - vs)
        speed_rms = float(np.sqrt(np.mean(np.concatenate(evs) ** 2)))
    # Spectrum and autocorrelation (of the longest run's residual, averaged over runs).
    nper = int(min(512, min(len(x) for x in res)))
    psds = [signal.welch(x - x.mean(), fs=1.0 / r.dt, nperseg=nper)
            for r, x in zip(runs, res, strict=True)]
    freq, psd = psds[0][0], np.mean([p for _, p in psds if p.size == psds[0][1].size], axis=0)
    maxlag = int(min(200, nper - 1))  # every run has at least nper samples
    ac = np.zeros(maxlag + 1)
    for x in res:
        xc = x - x.mean()
        full = signal.correlate(xc, xc, mode="full", method="fft")[xc.size - 1 :]
        ac += full[: maxlag + 1] / max(full[0], 1e-300)
    ac /= len(res)
    # Cross-correlation of the residual with the command rate (a delay mismatch
    # makes the residual proportional to the command's derivative at some lag).
    lags = np.arange(-maxlag, maxlag + 1)
    xcs = np.zeros(lags.size)
    for r, x in zip(runs, res, strict=True):
        u = r.command if r.command is not None else sims[0][: len(x)]
        du = np.gradient(u, r.dt)
        du = du - du.mean()
        xc = x - x.mean()
        full = signal.correlate(xc, du, mode="full", method="fft")
        mid = du.size - 1
        xcs += full[mid - maxlag : mid + maxlag + 1] / max(
            float(np.sqrt((xc @ xc) * (du @ du))), 1e-300
        )
    xcs /= len(runs)
    best_lag = float(lags[int(np.argmax(np.abs(xcs)))] * runs[0].dt)
    # Dependence on candidate signals.
    sig_runs = [_signals(r, s) for r, s in zip(runs, sims, strict=True)]
    names = [k for k in sig_runs[0] if all(k in s for s in sig_runs)]
    cuts = np.cumsum([len(r) for r in runs])[:-1]
    deps = [replace(_binned(np.concatenate([s[k] for s in sig_runs]), e, cuts), signal=k)
            for k in names]
    # Candidate effects: the score test by simulation.
    kind = runs[0].command_kind
    allowed = offered(model, [*runs, *val_runs], candidates, closed=closed)
    J = _sensitivities(model, runs, base, closed, init)
    _, rss0 = _lstsq(J, e)
    sse = float(e @ e)
    if val_runs:
        vbase = _simulate(model, model.to_array(), val_runs, closed, init)[0]
        ev = np.concatenate([r.a for r in val_runs]) - vbase
        Jv = _sensitivities(model, val_runs, vbase, closed, init)
    cands = []
    n_tests = max(len(allowed), 1)
    for name in allowed:
        grid = _effect_grid(name, runs, sims)
        best: tuple[float, dict[str, float], np.ndarray, list[np.ndarray]] | None = None
        for setting, cols in zip(grid, _signatures(model, name, grid, runs, base, closed, init),
                                 strict=True):  # fmt: skip
            if cols is None or not all(np.all(np.isfinite(c)) for c in cols):
                continue
            X = np.column_stack([J, *cols])
            beta, rss1 = _lstsq(X, e)
            if best is None or rss1 < best[0]:
                best = (rss1, setting, beta, cols)
        if best is None:
            continue
        rss1, setting, beta, cols = best
        q = len(cols)
        k = J.shape[1] + q
        # Effective sample size of the residual under the alternative (with the effect).
        r_alt = e - np.column_stack([J, *cols]) @ beta
        n_eff_c = _ess(np.split(r_alt, cuts))
        explained = max(rss0 - rss1, 0.0) / sse if sse > 0 else 0.0
        F = ((rss0 - rss1) / q) / (rss1 / max(n_eff_c - k, 1.0)) if rss1 > 0 else np.inf
        p = float(stats.f.sf(F, q, max(n_eff_c - k, 1.0))) * len(grid) * n_tests
        p = min(p, 1.0)
        val_explained = float("nan")
        if val_runs:
            vcols = next(_signatures(model, name, [setting], val_runs, vbase, closed, init))
            if vcols is not None and Jv.shape[1] == J.shape[1]:
                # Held-out: the base part re-fitted there, the effect's coefficient
                # carried over from the calibration runs.
                try:
                    ev_eff = ev - np.column_stack(vcols) @ beta[J.shape[1]:]
                    _, r_before = _lstsq(Jv, ev)
                    _, r_after = _lstsq(Jv, ev_eff)
                    val_explained = (r_before - r_after) / float(ev @ ev)
                except ValueError:  # a non-finite held-out signature
                    val_explained = float("nan")
        hint = _hint(name, setting, beta[J.shape[1]:], kind)
        significant = bool(p < alpha and explained >= min_explained
                           and (not val_runs or val_explained > 0))  # fmt: skip
        cands.append(Candidate(name, float(explained), float(val_explained), float(F), q, p,
                               hint, significant))  # fmt: skip
    cands.sort(key=lambda c: (not c.significant, -c.explained))
    return Diagnosis(
        model=model, residual_rms=float(np.sqrt(np.mean(e**2))), speed_residual_rms=speed_rms,
        lag1=r1, n_eff=n_eff, autocorr=ac, freq=freq, psd=psd, xcorr_lags=lags * runs[0].dt,
        xcorr=xcs, best_lag=best_lag, signals=deps, candidates=cands,
    )  # fmt: skip


def _hint(
    name: str, setting: dict[str, float], gamma: np.ndarray, kind: str = "acceleration"
) -> dict[str, float]:
    """A starting guess of the effect's parameters from the signature coefficients."""
    cls = EFFECTS[name]
    neutral = dict(zip(cls.param_names(), cls.neutral, strict=True))
    out = dict(setting)
    if cls.signature == "linear":
        free = [p for p in cls.param_names() if _fixed(name, p, kind) is None]
        for g, p in zip(gamma, free, strict=True):
            out[p] = float(neutral[p] + g * (setting[p] - neutral[p]))
        for p in cls.param_names():
            fx = _fixed(name, p, kind)
            if fx is not None:
                out[p] = fx
    elif cls.signature == "scaled":
        for p in cls.param_names():
            out[p] = float(gamma[0] * setting[p])
    for (lo, hi), p in zip(cls.bounds, cls.param_names(), strict=True):
        out[p] = float(np.clip(out[p], lo, hi))
    return out


def residual_structure(
    model: WithEffects | LowerLevelModel,
    runs: Sequence[Run],
    *,
    closed_loop: bool | None = None,
    init: str = "auto",
    alpha: float = ALPHA,
    min_share: float = MIN_SHARE,
    nbins: int = 10,
) -> dict[str, Any]:
    """What the residual of ``model`` on ``runs`` still depends on: the residual binned
    against the speed, the time since the start of the run and the command (in
    closed loop, without a command: the simulated acceleration), each with the share
    of the residual's variance the bin means explain and the ANOVA p-value with the
    effective sample size (:func:`avll.diagnose.stats.binned_dependence`). A signal
    *keeps structure* when ``p < alpha`` and its share ``>= min_share``.

    Returns ``{"structure_found", "unexplained_share", "signals": [...with bins],
    "lag1_autocorrelation", "n_eff", "n", "residual_mse"}``; ``unexplained_share`` is
    the largest share of residual variance explained by one such signal (0 when none
    keeps structure): variance with a systematic pattern that no accepted effect
    accounts for. The lag-1 autocorrelation and ``n_eff / n`` are descriptive (coloured
    sensor noise is autocorrelated too and is not an effect)."""
    from .stats import binned_dependence

    if isinstance(model, LowerLevelModel):
        model = WithEffects(model, ())
    runs, closed, init = _setup(runs, closed_loop, init)
    sims = _split(_simulate(model, model.to_array(), runs, closed, init)[0], runs)
    res = [r.a - s for r, s in zip(runs, sims, strict=True)]
    if not all(np.all(np.isfinite(x)) for x in res):
        raise ValueError("model: the simulation diverges on the runs")
    e = np.concatenate(res)
    lengths = [len(r) for r in runs]
    xs: dict[str, np.ndarray] = {}
    if all(r.v is not None for r in runs):
        xs["speed"] = np.concatenate([np.asarray(r.v) for r in runs])
    xs["time in run"] = np.concatenate([r.t - r.t[0] for r in runs])
    if all(r.command is not None for r in runs):
        xs["command"] = np.concatenate([np.asarray(r.command) for r in runs])
    else:
        xs["simulated acceleration"] = np.concatenate(sims)
    sigs = []
    for name, x in xs.items():
        d = binned_dependence(name, x, e, lengths, nbins)
        keeps = bool(d.p_value < alpha and d.explained >= min_share)
        sigs.append({**d.to_dict(bins=True), "keeps_structure": keeps})
    kept = [s["explained"] for s in sigs if s["keeps_structure"]]
    n_eff = _ess(res)
    return {
        "structure_found": bool(kept),
        "unexplained_share": float(max(kept)) if kept else 0.0,
        "signals": sigs,
        "alpha": float(alpha),
        "min_share": float(min_share),
        "lag1_autocorrelation": _lag1(res),
        "n_eff": float(n_eff),
        "n": int(e.size),
        "residual_mse": float(np.mean(e**2)),
    }
