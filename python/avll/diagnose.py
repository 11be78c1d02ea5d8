"""Residual diagnosis and the add-effect / recalibrate loop (issue 6).

Given a calibrated model and runs, :func:`diagnose` looks at the residual
``e = a_measured - a_simulated`` (and the speed residual where the speed is known):
its spectrum, autocorrelation and cross-correlation with the command (a dead-time
mismatch shows as a peak off lag 0), its dependence on candidate signals (the
sign of the command and of the acceleration, speed, command magnitude, command
rate and jerk, small commands and every ``exo_*`` signal), each binned with 95 %
confidence bands, and it ranks the library's effects by evidence.

Evidence for an effect (a score test by simulation). Each effect not yet in the
model has a *signature*: the change of the simulated acceleration when the effect
is switched on, ``s = a(model + effect(phi)) - a(model)``, one column per effect
parameter (threshold-type effects — saturation, dead-band, rate limit — profiled
over a small grid of thresholds taken from the data). The residual is regressed
on the base model's own sensitivities ``J`` (finite differences: what a
recalibration of the present parameters could absorb) and then on ``[J, s]``:

* ``explained`` = ``(RSS_J - RSS_Js) / sum(e²)``, the share of the residual only
  the effect explains;
* ``F = ((RSS_J - RSS_Js)/q) / (RSS_Js/(n_eff - k))`` with ``n_eff = n / (1 + 2 sum
  rho_k)`` the effective sample size of the residual with the effect (Geyer's
  initial positive sequence: residuals at 10-20 Hz are far from independent, and
  ignoring that would make everything "significant"); the p-value is
  Bonferroni-corrected for the profiled grid and the number of candidates;
* ``val_explained``: the same coefficients applied to the held-out runs.

An effect is a candidate when ``p < alpha``, ``explained >= min_explained`` and
``val_explained > 0``; candidates are ranked by ``explained``.

The loop (:func:`effect_loop`): baseline fit -> diagnose -> add the top candidate
-> recalibrate all parameters -> accept it only if the held-out MSE falls
significantly (a likelihood-ratio test on the held-out runs with their effective
sample size, ``p < alpha``) **and** the calibration BIC (with ``n_eff``) falls;
otherwise try the next candidate; stop when none is accepted.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize, signal, stats

from ._limits import SEED_MAX, check_int, check_seed, check_threads
from .calibrate import DEFAULT_BOUNDS, DEFAULT_STARTS
from .calibrate import UPPER_BOUNDS as _UB
from .data import Run
from .effects import (
    EFFECTS,
    WithEffects,
    batch_cost_effects,
    calibrate_effects,
    canonical,
)
from .effects import ISSUE6_ORDER as CANONICAL_ORDER
from .models import LowerLevelModel, UpperLevel, model_class
from .rollout import simulate_batch

__all__ = [
    "BASE_BOUNDS",
    "Candidate",
    "SignalDependence",
    "Diagnosis",
    "Step",
    "LoopResult",
    "fit",
    "fit_full",
    "simulate_runs",
    "run_mse",
    "diagnose",
    "effect_loop",
    "mse_table",
    "write_report",
]

#: Search box of the base models: ``name -> (lower, upper, scale)`` — the same box
#: as :func:`avll.calibrate` (:data:`avll.calibrate.DEFAULT_BOUNDS`), so that a
#: diagnosis and a calibration of the same data answer the same question.
BASE_BOUNDS: dict[str, dict[str, tuple[float, float, str]]] = DEFAULT_BOUNDS


# ---------------------------------------------------------------------------
# Simulation and costs
# ---------------------------------------------------------------------------


def _init(runs: Sequence[Run], init: str) -> str:
    """``"auto"``: a speed command starts at its steady state (a run that begins
    while driving), an acceleration command at rest (the paper's experiment)."""
    if init == "auto":
        return "steady" if runs and runs[0].command_kind == "speed" else "rest"
    if init not in ("rest", "steady"):
        raise ValueError(f"init: must be 'auto', 'rest' or 'steady', got {init!r}")
    return init


def _closed(runs: Sequence[Run], closed_loop: bool | None) -> bool:
    if closed_loop is not None:
        return bool(closed_loop)
    return any(r.command is None for r in runs)


def simulate_runs(
    model: WithEffects, runs: Sequence[Run], *, closed_loop: bool | None = None,
    init: str = "auto",
) -> list[np.ndarray]:
    """The simulated acceleration of every run (open loop from the recorded command,
    or closed loop behind the recorded leader), as in the calibration cost."""
    closed = _closed(runs, closed_loop)
    init = _init(runs, init)
    runs = list(runs)
    for r in runs:
        if closed and (r.upper is None or r.lead_x is None or r.lead_v is None or r.v is None):
            raise ValueError(f"run {r.run_id!r}: closed loop needs lead_x, lead_v, v, upper")
        for n in model.effect_names:
            sig = EFFECTS[n].exo
            if sig is not None and sig not in r.exo:
                raise ValueError(f"run {r.run_id!r}: effect {n!r} needs the column 'exo_{sig}'")
    # One batched call for every run (the same rollouts as the cost).
    sims = simulate_batch(
        model.base.name, model.to_array()[None, :], runs, effects=model.effect_names,
        init=init, closed_loop=closed,
    )  # fmt: skip
    return [np.asarray(a[0]) for a in sims["a"]]


def _weights(runs: Sequence[Run], closed: bool) -> tuple[float, float, float]:
    return (1.0, 0.0, 0.0)


def run_mse(
    model: WithEffects, runs: Sequence[Run], *, closed_loop: bool | None = None,
    init: str = "auto", threads: int = 0,
) -> np.ndarray:
    """Per-run MSE of the acceleration (paper Eq. 6 per run); ``inf`` if unstable."""
    closed = _closed(runs, closed_loop)
    c = batch_cost_effects(
        model.base.name, model.effect_names, model.to_array()[None, :], runs,
        closed_loop=closed, init=_init(runs, init), threads=threads,
    )  # fmt: skip
    return c[0]


# ---------------------------------------------------------------------------
# Calibration (global for the baseline, multi-start local for added effects)
# ---------------------------------------------------------------------------


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
    """Parameters that a command kind fixes (a speed command has no braking gain)."""
    if kind == "speed" and effect == "asymmetric" and param == "kb":
        return 1.0
    return None


def _space(base: str, effects: Sequence[str], kind: str = "acceleration") -> _Space:
    bb = BASE_BOUNDS[model_class(base).name]
    names, lo, hi, lg = [], [], [], []
    for n, (a, b, s) in bb.items():
        names.append(n)
        lo.append(a)
        hi.append(b)
        lg.append(s == "log")
    for e in canonical(list(effects)):
        cls = EFFECTS[e]
        for n, (a, b) in zip(cls.param_names(), cls.bounds, strict=True):
            fx = _fixed(e, n, kind)
            if fx is not None:
                a = b = fx
            names.append(f"{e}.{n}")
            lo.append(a)
            hi.append(b)
            lg.append(False)
    return _Space(tuple(names), np.array(lo), np.array(hi), np.array(lg))


def _polish(f: Callable[[np.ndarray], np.ndarray], z0: np.ndarray, maxiter: int) -> np.ndarray:
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
                            options={"maxiter": maxiter})  # fmt: skip
    return np.asarray(res.x)


#: Search box of the upper-level law when it is calibrated (closed loop, no known
#: law): the same as :func:`avll.calibrate`'s.
UPPER_BOUNDS: dict[str, tuple[float, float]] = {k: (lo, hi) for k, (lo, hi, _) in _UB.items()}


#: Cost weights (acceleration, speed, position) of a closed-loop calibration.
CLOSED_LOOP_WEIGHTS: tuple[float, float, float] = (1.0, 0.1, 0.01)
#: ... and of a speed command, whose response is the speed (the acceleration alone
#: leaves the static gain free).
SPEED_COMMAND_WEIGHTS: tuple[float, float, float] = (1.0, 1.0, 0.0)


def fit_full(
    base: str | type[LowerLevelModel] | LowerLevelModel,
    effects: Sequence[str],
    runs: Sequence[Run],
    *,
    start: WithEffects | None = None,
    start_upper: UpperLevel | None = None,
    seed: int = 0,
    closed_loop: bool | None = None,
    free_upper: bool | None = None,
    weights: tuple[float, float, float] | None = None,
    popsize: int = 12,
    maxiter: int = 300,
    init: str = "auto",
    threads: int = 0,
    progress: bool = False,
    optimizer: str = "ga",
    starts: int = DEFAULT_STARTS,
) -> tuple[WithEffects, UpperLevel | None]:
    """As :func:`fit`, and in closed loop with ``free_upper`` (default: when a run
    has no known upper-level law) also the shared upper-level law ``kg, kv, Tg,
    Gmin`` (returned; ``None`` otherwise). ``weights`` of the acceleration, speed and
    position MSE default to ``(1, 0, 0)`` in open loop (paper Eq. 6), to
    :data:`SPEED_COMMAND_WEIGHTS` for a speed command and to
    :data:`CLOSED_LOOP_WEIGHTS` in closed loop, where the acceleration alone leaves
    the upper law's spacing unidentified. The loop reports acceleration MSEs.
    ``optimizer``: ``"ga"`` (the project's Rust GA, :func:`avll.effects.calibrate_effects`,
    with ``starts`` independent starts as :func:`avll.calibrate`) or ``"de"``
    (``scipy.optimize.differential_evolution`` on the batched cost)."""
    if optimizer not in ("ga", "de"):
        raise ValueError(f"optimizer: must be 'ga' or 'de', got {optimizer!r}")
    seed = check_seed(seed)
    threads = check_threads(threads)
    if not runs:
        raise ValueError("runs: no runs given")
    bname = model_class(base).name
    names = canonical(list(effects))
    closed = _closed(runs, closed_loop)
    if free_upper is None:
        free_upper = closed and any(r.upper is None for r in runs)
    sp = _space(bname, names, runs[0].command_kind)
    if free_upper:
        lo = [b[0] for b in UPPER_BOUNDS.values()]
        hi = [b[1] for b in UPPER_BOUNDS.values()]
        sp = _Space(sp.names + tuple(UPPER_BOUNDS), np.concatenate([sp.lo, lo]),
                    np.concatenate([sp.hi, hi]), np.concatenate([sp.log, [False] * 4]))  # fmt: skip
        placeholder = UpperLevel(kg=0.0, kv=0.0, Tg=0.0, Gmin=0.0)
        runs = [replace(r, upper=placeholder) for r in runs]
    ini = _init(runs, init)
    if weights is None:
        if closed:
            weights = CLOSED_LOOP_WEIGHTS
        elif runs[0].command_kind == "speed" and all(r.v is not None for r in runs):
            weights = SPEED_COMMAND_WEIGHTS
        else:
            weights = (1.0, 0.0, 0.0)
    rows_of = sp.from_z
    upper_free = [0, 1, 2, 3] if free_upper else []

    def f(z: np.ndarray) -> np.ndarray:
        rows = np.vstack([rows_of(zz) for zz in np.atleast_2d(z)])
        c = batch_cost_effects(bname, names, rows, runs, closed_loop=closed, init=ini,
                               upper_free=upper_free, weights=weights,
                               threads=threads)  # fmt: skip
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
        if free_upper:
            parts.append(start_upper.to_array() if start_upper is not None
                         else np.array([0.5, 0.5, 1.5, 5.0]))  # fmt: skip
        x0 = sp.to_z(np.concatenate(parts))
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=maxiter, desc="fit " + "+".join([bname, *names]), leave=False)
    if optimizer == "ga":
        x0p = None if x0 is None else sp.from_z(x0)[None, :]

        def gcb(info: dict[str, Any]) -> None:
            if bar is not None:
                bar.update(int(info["iteration"]) - bar.n)

        try:
            out = calibrate_effects(
                bname, names, runs, list(sp.lo), list(sp.hi),
                ["log" if lg else "linear" for lg in sp.log], weights=weights, init=ini,
                closed_loop=closed, upper_free=upper_free, initial=x0p, seed=seed,
                max_generations=maxiter, progress=gcb if bar is not None else None,
                threads=threads, starts=starts,
            )  # fmt: skip
        finally:
            if bar is not None:
                bar.close()
        p = np.asarray(out["x"], dtype=np.float64)
    else:

        def cb(intermediate_result: Any) -> None:
            if bar is not None:
                bar.update(1)

        try:
            res = optimize.differential_evolution(
                lambda zz: f(zz.T), [(0.0, 1.0)] * len(sp.names), seed=rng, vectorized=True,
                popsize=popsize, maxiter=maxiter, tol=1e-7, polish=False, updating="deferred",
                x0=x0, init="sobol", callback=cb,
            )  # fmt: skip
        finally:
            if bar is not None:
                bar.close()

        p = sp.from_z(_polish(f, np.asarray(res.x), 200))

    n_model = len(p) - (4 if free_upper else 0)
    model = WithEffects.from_array(bname, names, p[:n_model])
    up = UpperLevel(*[float(x) for x in p[n_model:]]) if free_upper else None
    return model, up


def fit(
    base: str | type[LowerLevelModel] | LowerLevelModel,
    effects: Sequence[str],
    runs: Sequence[Run],
    *,
    start: WithEffects | None = None,
    seed: int = 0,
    closed_loop: bool | None = None,
    popsize: int = 12,
    maxiter: int = 300,
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
                        free_upper=False, popsize=popsize, maxiter=maxiter, init=init,
                        threads=threads, optimizer=optimizer)  # fmt: skip
    return model


# ---------------------------------------------------------------------------
# Diagnosis
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class SignalDependence:
    """Residual binned against one candidate signal (means with 95 % bands that use
    the effective sample size of each bin)."""

    signal: str
    centers: np.ndarray
    means: np.ndarray
    half_width: np.ndarray
    counts: np.ndarray
    explained: float
    p_value: float


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

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (the ``avll diagnose`` JSON contract)."""
        return {
            "model": self.model.name,
            "residual_rms": self.residual_rms,
            "speed_residual_rms": self.speed_residual_rms,
            "lag1_autocorrelation": self.lag1,
            "n_eff": self.n_eff,
            "xcorr_best_lag_s": self.best_lag,
            "signals": [
                {"signal": s.signal, "explained": s.explained, "p_value": s.p_value}
                for s in self.signals
            ],
            "candidates": [
                {"effect": c.effect, "explained": c.explained, "val_explained": c.val_explained,
                 "F": c.F, "df": c.df, "p_value": c.p_value, "hint": c.hint,
                 "significant": c.significant}
                for c in self.candidates
            ],  # fmt: skip
        }


def _lag1(res: list[np.ndarray]) -> float:
    num = sum(float(np.dot(r[1:], r[:-1])) for r in res)
    den = sum(float(np.dot(r, r)) for r in res)
    return float(np.clip(num / den, -0.99, 0.999)) if den > 0 else 0.0


def _ess(res: Sequence[np.ndarray]) -> float:
    """Effective sample size of autocorrelated residuals, ``n / (1 + 2 sum rho_k)``,
    with the pooled autocorrelation summed by Geyer's initial positive sequence
    (pairs ``rho_2m + rho_2m+1`` while positive) — the standard estimator for
    correlated samples; residuals at 10-20 Hz are far from independent."""
    n = sum(len(r) for r in res)
    maxlag = int(min(min(len(r) for r in res) // 2, 4000))
    if maxlag < 2:
        return float(n)
    acov = np.zeros(maxlag + 1)
    for r in res:
        x = r - r.mean()
        m = 1 << int(np.ceil(np.log2(2 * x.size)))
        f = np.fft.rfft(x, m)
        acov += np.fft.irfft(f * np.conj(f), m)[: maxlag + 1]
    if acov[0] <= 0:
        return float(n)
    rho = acov / acov[0]
    tau = 1.0  # 1 + 2 sum_{k>=1} rho_k = -1 + 2 sum_m Gamma_m
    total = 0.0
    for m in range(maxlag // 2):
        g = rho[2 * m] + rho[2 * m + 1]
        if g <= 0:
            break
        total += g
    tau = max(2 * total - 1.0, 1.0)
    return max(float(n) / tau, 10.0)


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


def _binned(x: np.ndarray, e: np.ndarray, cuts: np.ndarray, nbins: int = 10) -> SignalDependence:
    uniq = np.unique(x)
    if uniq.size <= 3:
        edges = np.concatenate([[uniq[0] - 0.5], (uniq[1:] + uniq[:-1]) / 2, [uniq[-1] + 0.5]])
    else:
        edges = np.unique(np.quantile(x, np.linspace(0, 1, nbins + 1)))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    k = edges.size - 1
    centers, means, hw, counts = (np.zeros(k) for _ in range(4))
    for b in range(k):
        m = idx == b
        if m.any():
            means[b] = float(np.mean(e[m]))
    # Effective sample size of the residual under the alternative (bin means removed).
    ratio = _ess(np.split(e - means[idx], cuts)) / e.size
    for b in range(k):
        m = idx == b
        counts[b] = m.sum()
        if counts[b] == 0:
            centers[b] = means[b] = np.nan
            continue
        centers[b] = float(np.mean(x[m]))
        means[b] = float(np.mean(e[m]))
        ne = max(counts[b] * ratio, 2.0)
        hw[b] = 1.96 * float(np.std(e[m])) / math.sqrt(ne)
    # One-way ANOVA of the bins with effective sample sizes.
    ok = counts > 0
    ss_between = float(np.sum(counts[ok] * (means[ok] - e.mean()) ** 2))
    ss_tot = float(np.sum((e - e.mean()) ** 2))
    explained = ss_between / ss_tot if ss_tot > 0 else 0.0
    n_eff = max(e.size * ratio, 10.0)
    kk = int(ok.sum())
    if kk > 1 and ss_tot > ss_between:
        F = (explained / (kk - 1)) / ((1 - explained) / max(n_eff - kk, 1))
        p = float(stats.f.sf(F, kk - 1, max(n_eff - kk, 1)))
    else:
        p = 1.0
    return SignalDependence("", centers, means, hw, counts, explained, p)


def _effect_grid(name: str, runs: Sequence[Run], sims: list[np.ndarray]) -> list[dict[str, float]]:
    """Parameter settings whose signatures are tried for an effect not in the model."""
    a = np.concatenate(sims)
    if name == "delay":
        return [{"tau": t} for t in (0.05, 0.1, 0.2, 0.35, 0.5, 0.8)]
    if name == "rate_limit":
        du = np.concatenate([np.abs(np.diff(r.command if r.command is not None else s)) / r.dt
                             for r, s in zip(runs, sims, strict=True)])  # fmt: skip
        qs = np.quantile(du, [0.7, 0.85, 0.93, 0.97, 0.99])
        return [{"j_max": float(max(q, 0.1))} for q in qs]
    if name == "deadband":
        u = np.concatenate([np.abs(r.command if r.command is not None else s)
                            for r, s in zip(runs, sims, strict=True)])  # fmt: skip
        qs = np.quantile(u, [0.05, 0.1, 0.2, 0.3, 0.45])
        return [{"delta": float(min(max(q, 0.005), 1.0))} for q in qs]
    if name == "saturation":
        pos, neg = a[a > 0], -a[a < 0]
        qa = np.quantile(pos, [0.6, 0.8, 0.9, 0.97]) if pos.size > 20 else np.array([6.0])
        qd = np.quantile(neg, [0.6, 0.8, 0.9, 0.97]) if neg.size > 20 else np.array([10.0])
        return [{"a_max": float(max(x, 0.2)), "d_max": float(max(y, 0.2))}
                for x in qa for y in qd]  # fmt: skip
    if name == "asymmetric":
        return [{"kb": 0.8, "rb": 1.25}]
    if name == "speed_drag":
        return [{"c0": 0.05, "c2": 0.001}]
    if name == "grade":
        return [{"g_eff": 5.0}]
    raise ValueError(f"effect: unknown {name!r}")


def _columns(
    model: WithEffects, name: str, setting: dict[str, float], runs: Sequence[Run],
    base_sims: list[np.ndarray], closed: bool, init: str = "auto",
) -> list[np.ndarray]:
    """Signature columns (one per parameter of a linear-in-parameter effect; one per
    threshold for threshold effects), concatenated over runs."""
    cls = EFFECTS[name]
    neutral = dict(zip(cls.param_names(), cls.neutral, strict=True))
    cols = []
    if name in ("asymmetric", "speed_drag"):
        # One column per parameter: perturb one at a time.
        for p in cls.param_names():
            if _fixed(name, p, runs[0].command_kind) is not None:
                continue
            eff = cls(**{**neutral, p: setting[p]})
            sims = simulate_runs(WithEffects(model.base, (*model.effects, eff)), runs,
                                 closed_loop=closed, init=init)  # fmt: skip
            cols.append(np.concatenate([s - b for s, b in zip(sims, base_sims, strict=True)]))
    elif name == "saturation":
        for p in ("a_max", "d_max"):
            eff = cls(**{**neutral, p: setting[p]})
            sims = simulate_runs(WithEffects(model.base, (*model.effects, eff)), runs,
                                 closed_loop=closed, init=init)  # fmt: skip
            cols.append(np.concatenate([s - b for s, b in zip(sims, base_sims, strict=True)]))
    else:
        eff = cls(**setting)
        sims = simulate_runs(WithEffects(model.base, (*model.effects, eff)), runs,
                             closed_loop=closed, init=init)  # fmt: skip
        cols.append(np.concatenate([s - b for s, b in zip(sims, base_sims, strict=True)]))
    return cols


def _sensitivities(
    model: WithEffects, runs: Sequence[Run], base_sims: list[np.ndarray], closed: bool,
    init: str = "auto",
) -> np.ndarray:
    """Finite-difference sensitivities of the simulated acceleration to the model's
    own parameters, concatenated over runs: (n, p)."""
    p0 = model.to_array()
    cols = []
    for j in range(p0.size):
        h = 1e-4 * max(abs(p0[j]), 1e-2)
        p = p0.copy()
        p[j] += h
        try:
            m = WithEffects.from_array(model.base.name, model.effect_names, p)
            sims = simulate_runs(m, runs, closed_loop=closed, init=init)
        except ValueError:
            continue
        col = np.concatenate([(s - b) / h for s, b in zip(sims, base_sims, strict=True)])
        if np.all(np.isfinite(col)):
            cols.append(col)
    n = sum(len(r) for r in runs)
    return np.column_stack(cols) if cols else np.zeros((n, 0))


def _lstsq(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    if X.shape[1] == 0:
        return np.zeros(0), float(y @ y)
    sc = np.linalg.norm(X, axis=0)
    sc[sc == 0] = 1.0
    beta, *_ = np.linalg.lstsq(X / sc, y, rcond=None)
    beta = beta / sc
    r = y - X @ beta
    return beta, float(r @ r)


def diagnose(
    model: WithEffects | LowerLevelModel,
    runs: Sequence[Run],
    val_runs: Sequence[Run] = (),
    *,
    closed_loop: bool | None = None,
    alpha: float = 1e-3,
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
    closed = _closed(runs, closed_loop)
    init = _init(runs, init)
    sims = simulate_runs(model, runs, closed_loop=closed, init=init)
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
    freqs, psds = [], []
    for r, x in zip(runs, res, strict=True):
        fq, pp = signal.welch(x - x.mean(), fs=1.0 / r.dt, nperseg=nper)
        freqs.append(fq)
        psds.append(pp)
    freq, psd = freqs[0], np.mean([p for p in psds if p.size == psds[0].size], axis=0)
    maxlag = int(min(200, nper))
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
    deps = []
    for k in names:
        x = np.concatenate([s[k] for s in sig_runs])
        d = _binned(x, e, np.cumsum([len(r) for r in runs])[:-1])
        deps.append(SignalDependence(k, d.centers, d.means, d.half_width, d.counts,
                                     d.explained, d.p_value))  # fmt: skip
    # Candidate effects: the score test by simulation.
    kind = runs[0].command_kind
    allowed = [n for n in (candidates or CANONICAL_ORDER) if n not in model.effect_names]
    allowed = [n for n in allowed if not (EFFECTS[n].accel_only and kind == "speed")]
    every = [*runs, *val_runs]
    allowed = [n for n in allowed
               if EFFECTS[n].exo is None or all(EFFECTS[n].exo in r.exo for r in every)]
    J = _sensitivities(model, runs, sims, closed, init)
    _, rss0 = _lstsq(J, e)
    sse = float(e @ e)
    if val_runs:
        vsims = simulate_runs(model, val_runs, closed_loop=closed, init=init)
        ev = np.concatenate([r.a - s for r, s in zip(val_runs, vsims, strict=True)])
        Jv = _sensitivities(model, val_runs, vsims, closed, init)
    cands = []
    n_tests = max(len(allowed), 1)
    for name in allowed:
        grid = _effect_grid(name, runs, sims)
        best: tuple[float, dict[str, float], np.ndarray, list[np.ndarray]] | None = None
        for setting in grid:
            try:
                cols = _columns(model, name, setting, runs, sims, closed, init)
            except ValueError:
                continue
            if not all(np.all(np.isfinite(c)) for c in cols):
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
        cuts = np.cumsum([len(r) for r in runs])[:-1]
        n_eff_c = _ess(np.split(r_alt, cuts))
        explained = max(rss0 - rss1, 0.0) / sse if sse > 0 else 0.0
        F = ((rss0 - rss1) / q) / (rss1 / max(n_eff_c - k, 1.0)) if rss1 > 0 else np.inf
        p = float(stats.f.sf(F, q, max(n_eff_c - k, 1.0))) * len(grid) * n_tests
        p = min(p, 1.0)
        val_explained = float("nan")
        if val_runs:
            try:
                vcols = _columns(model, name, setting, val_runs, vsims, closed, init)
                Xv0 = Jv if Jv.shape[1] == J.shape[1] else None
                if Xv0 is not None:
                    # Held-out: the base part re-fitted there, the effect's coefficient
                    # carried over from the calibration runs.
                    gamma = beta[J.shape[1]:]
                    ev_eff = ev - np.column_stack(vcols) @ gamma
                    _, r_before = _lstsq(Jv, ev)
                    _, r_after = _lstsq(Jv, ev_eff)
                    val_explained = (r_before - r_after) / float(ev @ ev)
            except ValueError:
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
    if name in ("asymmetric", "speed_drag"):
        free = [p for p in cls.param_names() if _fixed(name, p, kind) is None]
        for g, p in zip(gamma, free, strict=True):
            out[p] = float(neutral[p] + g * (setting[p] - neutral[p]))
        for p in cls.param_names():
            fx = _fixed(name, p, kind)
            if fx is not None:
                out[p] = fx
    elif name == "grade":
        out["g_eff"] = float(gamma[0] * setting["g_eff"])
    for (lo, hi), p in zip(cls.bounds, cls.param_names(), strict=True):
        out[p] = float(np.clip(out[p], lo, hi))
    return out


# ---------------------------------------------------------------------------
# The loop
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Step:
    """One accepted effect with the errors before and after (per run and mean)."""

    effect: str
    params: dict[str, float]
    model: WithEffects
    cal_before: dict[str, float]
    cal_after: dict[str, float]
    val_before: dict[str, float]
    val_after: dict[str, float]
    lr_p_value: float
    bic_before: float
    bic_after: float

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (the ``avll diagnose`` JSON contract)."""
        return {
            "effect": self.effect,
            "params": self.params,
            "cal_mse_before": _mean(self.cal_before),
            "cal_mse_after": _mean(self.cal_after),
            "val_mse_before": _mean(self.val_before),
            "val_mse_after": _mean(self.val_after),
            "cal_mse_before_per_run": self.cal_before,
            "cal_mse_after_per_run": self.cal_after,
            "val_mse_before_per_run": self.val_before,
            "val_mse_after_per_run": self.val_after,
            "lr_p_value": self.lr_p_value,
            "bic_before": self.bic_before,
            "bic_after": self.bic_after,
            "model": self.model.name,
        }


@dataclass(frozen=True)
class LoopResult:
    """The baseline, the accepted steps, and every diagnosis and rejected try."""

    baseline: WithEffects
    final: WithEffects
    steps: list[Step]
    diagnoses: list[Diagnosis]
    rejected: list[dict[str, Any]] = field(default_factory=list)
    upper: UpperLevel | None = None

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (the ``avll diagnose`` JSON contract)."""
        return {
            "upper": None if self.upper is None else {
                "kg": self.upper.kg, "kv": self.upper.kv, "Tg": self.upper.Tg,
                "Gmin": self.upper.Gmin},
            "base_model": self.baseline.base.name,
            "baseline_params": self.baseline.base.to_dict(),
            "steps": [s.to_dict() for s in self.steps],
            "effects": [s.effect for s in self.steps],
            "final_params": {e.name: e.to_dict() for e in self.final.effects}
            | {"base": self.final.base.to_dict()},
            "diagnoses": [d.to_dict() for d in self.diagnoses],
            "rejected": self.rejected,
        }


def _mean(d: dict[str, float]) -> float:
    return float(np.mean(list(d.values()))) if d else float("nan")


def _per_run(
    model: WithEffects, runs: Sequence[Run], closed: bool, init: str
) -> dict[str, float]:
    if not runs:
        return {}
    mse = run_mse(model, runs, closed_loop=closed, init=init)
    return {r.run_id: float(c) for r, c in zip(runs, mse,
                                                 strict=True)}  # fmt: skip


def _bic(model: WithEffects, mse: dict[str, float], n_eff: float, extra: int = 0) -> float:
    k = model.to_array().size + extra
    return float(n_eff * math.log(max(_mean(mse), 1e-300)) + k * math.log(n_eff))


def effect_loop(
    base: str | type[LowerLevelModel],
    cal_runs: Sequence[Run],
    val_runs: Sequence[Run],
    *,
    seed: int = 0,
    closed_loop: bool | None = None,
    alpha: float = 1e-3,
    max_effects: int = 3,
    tries: int = 2,
    baseline: LowerLevelModel | None = None,
    candidates: Sequence[str] | None = None,
    init: str = "auto",
    optimizer: str = "ga",
    progress: bool = False,
) -> LoopResult:
    """Baseline fit -> diagnose -> add the top-ranked effect -> recalibrate -> keep it
    only if the held-out MSE falls significantly and the calibration BIC falls;
    repeat while that happens (see the module doc)."""
    max_effects = check_int(max_effects, "max_effects", min=0, max=len(EFFECTS))
    seed = check_int(seed, "seed", min=0, max=SEED_MAX - 1000 * (max_effects + 1))
    if not cal_runs:
        raise ValueError("cal_runs: no calibration runs")
    if not val_runs:
        raise ValueError("val_runs: the loop needs held-out runs")
    closed = _closed([*cal_runs, *val_runs], closed_loop)
    init = _init(cal_runs, init)
    bname = model_class(base).name
    if progress:
        from tqdm.auto import tqdm

        say: Callable[[str], None] = tqdm.write
    else:
        say = lambda msg: None  # noqa: E731
    free_upper = closed and any(r.upper is None for r in [*cal_runs, *val_runs])
    upper: UpperLevel | None = None

    def with_upper(rs: Sequence[Run], up: UpperLevel | None) -> list[Run]:
        # The calibrated upper-level law replaces the unknown one (also on the
        # validation runs: the same vehicle's law).
        return [replace(r, upper=up) for r in rs] if free_upper else list(rs)

    if baseline is None:
        current, upper = fit_full(bname, (), cal_runs, seed=seed, closed_loop=closed, init=init,
                                  free_upper=free_upper, progress=progress,
                                  optimizer=optimizer)  # fmt: skip
    else:
        current = WithEffects(baseline, ())
        if free_upper:
            raise ValueError("baseline: give runs with their upper-level law in closed loop")
    cal_runs, val_runs = with_upper(cal_runs, upper), with_upper(val_runs, upper)
    say(f"baseline {current.base}" + (f", upper {upper}" if upper is not None else ""))
    out_base = current
    steps: list[Step] = []
    diags: list[Diagnosis] = []
    rejected: list[dict[str, Any]] = []
    for it in range(max_effects):
        d = diagnose(current, cal_runs, val_runs, closed_loop=closed, alpha=alpha, init=init,
                     candidates=candidates)  # fmt: skip
        diags.append(d)
        ranked = d.ranked
        say("candidates: " + ", ".join(f"{c.effect} {c.explained:.3f} p={c.p_value:.2g}"
                                       for c in d.candidates))  # fmt: skip
        if not ranked:
            break
        cal0 = _per_run(current, cal_runs, closed, init)
        val0 = _per_run(current, val_runs, closed, init)
        accepted = False
        for c in ranked[:tries]:
            cls = EFFECTS[c.effect]
            start = WithEffects(current.base, (*current.effects, cls(**c.hint)))
            new, up1 = fit_full(bname, [*current.effect_names, c.effect], cal_runs,
                                start=start, start_upper=upper, seed=seed + 1000 * (it + 1),
                                closed_loop=closed, init=init, free_upper=free_upper,
                                progress=progress, optimizer=optimizer)  # fmt: skip
            cal_new, val_new = with_upper(cal_runs, up1), with_upper(val_runs, up1)
            cal1 = _per_run(new, cal_new, closed, init)
            val1 = _per_run(new, val_new, closed, init)
            vsim1 = simulate_runs(new, val_new, closed_loop=closed, init=init)
            vres = [r.a - s for r, s in zip(val_new, vsim1, strict=True)]
            n_eff_val = _ess(vres)
            mv0, mv1 = _mean(val0), _mean(val1)
            lr = n_eff_val * math.log(mv0 / mv1) if mv1 > 0 and math.isfinite(mv1) else -np.inf
            q = len(cls.param_names())
            p_lr = float(stats.chi2.sf(lr, q)) if lr > 0 else 1.0
            # Both BICs with the effective sample size of the calibration residual
            # under the larger model (the restricted residual's own autocorrelation
            # contains the very structure the effect explains).
            csim1 = simulate_runs(new, cal_new, closed_loop=closed, init=init)
            n_eff_cal = _ess([r.a - s for r, s in zip(cal_new, csim1, strict=True)])
            bic0 = _bic(current, cal0, n_eff_cal, 4 if free_upper else 0)
            bic1 = _bic(new, cal1, n_eff_cal, 4 if free_upper else 0)
            ok = p_lr < alpha and bic1 < bic0 and mv1 < mv0
            say(f"try {c.effect}: cal {_mean(cal0):.4g} -> {_mean(cal1):.4g}, val {mv0:.4g} -> "
                f"{mv1:.4g}, LR p={p_lr:.2g}, BIC {bic0:.1f} -> {bic1:.1f}: "
                f"{'accepted' if ok else 'rejected'}")  # fmt: skip
            if ok:
                eff = dict((e.name, e) for e in new.effects)[c.effect]
                steps.append(Step(c.effect, eff.to_dict(), new, cal0, cal1, val0, val1, p_lr,
                                  bic0, bic1))  # fmt: skip
                current = new
                if free_upper:
                    upper, cal_runs, val_runs = up1, cal_new, val_new
                accepted = True
                break
            rejected.append({"effect": c.effect,
                             "params": dict((e.name, e) for e in new.effects)[c.effect].to_dict(),
                             "cal_mse_before": _mean(cal0), "cal_mse_after": _mean(cal1),
                             "val_mse_before": mv0,
                             "val_mse_after": mv1, "lr_p_value": p_lr,
                             "bic_before": bic0, "bic_after": bic1})  # fmt: skip
        if not accepted:
            break
    return LoopResult(out_base, current, steps, diags, rejected, upper)


# ---------------------------------------------------------------------------
# Tables, figures, report, CLI
# ---------------------------------------------------------------------------


def mse_table(rows: dict[str, dict[str, float]], title: str, per_line: int = 6) -> str:
    """A Markdown table in the paper's format (Tables III/IV): runs across, models
    down, wrapped every ``per_line`` runs, with the average last."""
    runs = list(next(iter(rows.values())).keys())
    out = [f"**{title}** (unit: (m/s²)²)", ""]
    for i in range(0, len(runs), per_line):
        chunk = runs[i : i + per_line]
        last = i + per_line >= len(runs)
        head = ["Run No.", *chunk] + (["Average"] if last else [])
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for name, vals in rows.items():
            cells = [f"{vals[r]:.4f}" for r in chunk]
            if last:
                cells.append(f"{_mean(vals):.4f}")
            out.append(f"| {name} | " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)


def plot_diagnosis(d: Diagnosis) -> list[tuple[str, Any]]:
    """Figures: residual against each candidate signal (binned, 95 % bands), the
    residual spectrum, autocorrelation and cross-correlation with the command rate."""
    import matplotlib.pyplot as plt

    figs = []
    n = len(d.signals)
    cols = 3
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3 * rows), squeeze=False)
    for ax, s in zip(axes.ravel(), d.signals, strict=False):
        ok = s.counts > 0
        ax.errorbar(s.centers[ok], s.means[ok], yerr=s.half_width[ok], fmt="o-", capsize=3)
        ax.axhline(0, color="k", lw=0.6)
        ax.set_title(f"{s.signal}\nexpl. {100 * s.explained:.1f} %, p={s.p_value:.2g}",
                     fontsize=9)  # fmt: skip
        ax.set_ylabel("residual (m/s²)", fontsize=8)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    fig.tight_layout()
    figs.append(("residual_vs_signals", fig))
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.2))
    axes[0].semilogy(d.freq[1:], d.psd[1:])
    axes[0].set_xlabel("frequency (Hz)")
    axes[0].set_title("residual PSD")
    dt = d.xcorr_lags[1] - d.xcorr_lags[0] if d.xcorr_lags.size > 1 else 1.0
    axes[1].plot(np.arange(d.autocorr.size) * dt, d.autocorr)
    axes[1].set_xlabel("lag (s)")
    axes[1].set_title(f"autocorrelation (lag-1 {d.lag1:.2f})")
    axes[2].plot(d.xcorr_lags, d.xcorr)
    axes[2].set_xlabel("lag (s)")
    axes[2].set_title(f"xcorr with command rate (peak {d.best_lag:+.2f} s)")
    fig.tight_layout()
    figs.append(("residual_spectrum", fig))
    return figs


def write_report(result: LoopResult, out_dir: str | Path, title: str = "avll diagnosis") -> Path:
    """Writes ``report.md``, ``report.html`` and PNG figures into ``out_dir`` as one
    unit (built in a hidden temporary folder inside it, committed with a ``MANIFEST.json``
    written last: see :mod:`avll._atomic`). Every text, run ids included, is escaped
    in the HTML."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from . import _atomic
    from .report import Report

    rep = Report(title)
    rep.para(f"Baseline: `{result.baseline.base}`")
    if not result.steps:
        rep.para("No effect was added: no candidate was significant and improved the "
                 "held-out error.")
    for k, s in enumerate(result.steps, 1):
        rep.heading(f"Step {k}: add `{s.effect}` {s.params}")
        rep.para(f"held-out likelihood-ratio p = {s.lr_p_value:.3g}; "
                 f"BIC {s.bic_before:.1f} -> {s.bic_after:.1f}")
        rep.code(mse_table({"before": s.cal_before, "after": s.cal_after},
                           "Calibration MSE of acceleration"))
        rep.code(mse_table({"before": s.val_before, "after": s.val_after},
                           "Validation MSE of acceleration"))
    out = Path(out_dir)
    with _atomic.output_dir(out, meta={"command": "avll diagnose"}) as stage:
        for k, d in enumerate(result.diagnoses):
            rep.heading(f"Diagnosis {k + 1} of `{d.model.name}`")
            rep.para(f"residual RMS {d.residual_rms:.4f} m/s², lag-1 autocorrelation "
                     f"{d.lag1:.3f}, effective samples {d.n_eff:.0f}, xcorr peak with the "
                     f"command rate at {d.best_lag:+.2f} s")
            rep.table(["effect", "explained", "held-out", "F", "df", "p (Bonferroni)",
                       "candidate"],
                      [[c.effect, f"{100 * c.explained:.2f} %",
                        f"{100 * c.val_explained:.2f} %", f"{c.F:.1f}", c.df,
                        f"{c.p_value:.2g}", "yes" if c.significant else "no"]
                       for c in d.candidates])
            for name, fig in plot_diagnosis(d):
                fn = f"diag{k + 1}_{name}.png"
                _atomic.savefig(fig, stage / fn, dpi=90)
                plt.close(fig)
                rep.figure(fn, name)
        rep.write(stage)
    return out / "report.md"


def _cmd(args: argparse.Namespace) -> int:
    from . import _atomic
    from .io import read_runs
    from .io.cli_load import astazero_options

    runs = read_runs(args.data, command_kind=args.command_kind, format=args.format,
                     **astazero_options(args))
    ids = [s.strip() for s in args.cal_runs.split(",") if s.strip()]
    known = {r.run_id for r in runs}
    missing = [i for i in ids if i not in known]
    if missing:
        raise ValueError(f"--cal-runs: unknown run(s) {missing}; known: {sorted(known)}")
    cal = [r for r in runs if r.run_id in ids]
    val = [r for r in runs if r.run_id not in ids]
    if not val:
        raise ValueError("--cal-runs: every run is a calibration run; keep some for validation")
    model_class(args.model)
    res = effect_loop(args.model, cal, val, seed=args.seed, init=args.init,
                      optimizer=args.optimizer, progress=not args.quiet)  # fmt: skip
    d = res.to_dict()
    _atomic.write_json(args.json, _atomic.json_safe(d), default=float)
    if args.report:
        write_report(res, args.report)
    names = ", ".join(d["effects"]) or "none"
    print(f"effects added: {names}; JSON written to {args.json}")
    return 0


def register_cli(sub: argparse._SubParsersAction) -> None:
    """Registers this module's sub-command with the ``avll`` parser."""
    p = sub.add_parser("diagnose", help="residual diagnosis and the add-effect loop")
    p.add_argument("data", help="runs in the canonical format (CSV/Parquet)")
    p.add_argument("--command-kind", choices=["acceleration", "speed"], default=None)
    p.add_argument("--format", default="canonical",
                   help="data format (see `avll load`), default canonical")
    p.add_argument("--model", default="proposed", help="base model: first|second|proposed")
    p.add_argument("--cal-runs", required=True, help="comma-separated calibration run ids")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", required=True, help="output JSON file")
    p.add_argument("--report", default=None, help="folder for a Markdown/HTML report")
    p.add_argument("--init", choices=["auto", "rest", "steady"], default="auto",
                   help="initial state (auto: steady for a speed command, else rest)")
    p.add_argument("--optimizer", choices=["ga", "de"], default="ga",
                   help="calibration: the Rust GA (default) or scipy's differential evolution")
    p.add_argument("--quiet", action="store_true")
    from .io.cli_load import add_astazero_options

    add_astazero_options(p)
    p.set_defaults(func=_cmd)
