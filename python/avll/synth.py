"""The paper's car-following experiment, synthesised (the built-in data).

The paper's field data are not public, so avll ships a generator of the same
experiment (Section II, Table I): 21 runs, 20 Hz, a leader tracking a pre-set
oscillating speed profile from standstill, and a follower under the
constant-time-gap law (Eq. 3, ``kv = 0``, ``Gmin = 9.5 m``, Table I's ``kg`` and
``Tg``) with a chosen lower-level model (Table II's proposed model by default).
The follower's recorded command is the upper law's output; its measured
acceleration, speed and position carry Gaussian sensor noise and quantisation of
configurable size. Every run has its own random stream derived from
``(seed, run number)``, so a run does not change when others are added.
"""

from __future__ import annotations

import math

import numpy as np

from ._limits import check_int, check_memory, check_number, check_seed
from .data import Run
from .defaults import SYNTH_DT, SYNTH_DURATION, SYNTH_NOISE
from .models import LowerLevelModel, UpperLevel
from .paper import GMIN, PAPER_CAL_RUNS, PAPER_VAL_RUNS, TABLE_I, TABLE_II
from .rollout import closed_loop

__all__ = [
    "TABLE_I",
    "PAPER_CAL_RUNS",
    "PAPER_VAL_RUNS",
    "GMIN",
    "leader_profile",
    "paper_experiment",
]

#: The proposed model with Table II's parameters (the default true lower level).
TABLE_II_PROPOSED = TABLE_II["proposed"]


def _table_i_upper(r: int) -> UpperLevel:
    """Run ``r``'s constant-time-gap law: Table I's ``kg, Tg``, ``kv = 0``, ``Gmin``."""
    if r not in TABLE_I:
        raise ValueError(f"runs: run {r} is not in Table I (1..21)")
    kg, tg = TABLE_I[r]
    return UpperLevel(kg=kg, kv=0.0, Tg=tg, Gmin=GMIN)


#: A synthetic run must be longer than this many samples (:func:`_check_duration`).
MIN_SAMPLES = 10


def _check_duration(duration: float, dt: float) -> None:
    """The one rule on a synthetic run's length (:func:`paper_experiment`,
    :func:`avll.synth_blind.blind_experiment`): more than :data:`MIN_SAMPLES` samples."""
    if duration <= MIN_SAMPLES * dt:
        raise ValueError(f"duration: must be > {MIN_SAMPLES} dt, got {duration}")


def _noisy(rng: np.random.Generator, y: np.ndarray, sd: float) -> np.ndarray:
    """``y`` plus white Gaussian noise of standard deviation ``sd`` (a copy for 0)."""
    return y + rng.normal(0.0, sd, y.size) if sd > 0 else y.copy()


def _measured(rng: np.random.Generator, a: np.ndarray, v: np.ndarray, x: np.ndarray,
              noise_a: float, noise_v: float, noise_x: float, quantization_a: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The logged ``a, v, x`` of the true ones: white noise on each, ``a`` then rounded to
    multiples of ``quantization_a`` (0: not)."""
    a = _noisy(rng, a, noise_a)
    if quantization_a > 0:
        a = np.round(a / quantization_a) * quantization_a
    return a, _noisy(rng, v, noise_v), _noisy(rng, x, noise_x)


def _ar1(rng: np.random.Generator, n: int, phi: float, std: float) -> np.ndarray:
    """A stationary AR(1) ``e[k] = phi e[k-1] + w[k]`` of standard deviation ``std``
    (zeros for ``std <= 0``)."""
    if std <= 0 or n == 0:
        return np.zeros(n)
    from scipy import signal

    w = rng.normal(0.0, std * math.sqrt(1.0 - phi * phi), n)
    w[0] = rng.normal(0.0, std)
    return np.asarray(signal.lfilter([1.0], [1.0, -phi], w))


def leader_profile(
    duration: float, dt: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A leader speed profile from standstill: a smooth ramp to a cruise speed, then
    alternating speed dips and bumps (raised-cosine shapes of random depth and
    length, so the acceleration is continuous). Returns time, position, speed."""
    t = np.arange(0.0, duration, dt)
    v_c = rng.uniform(9.0, 13.0)
    t_ramp = rng.uniform(15.0, 25.0)
    v = np.where(t < t_ramp, v_c * 0.5 * (1 - np.cos(np.pi * t / t_ramp)), v_c)
    start = t_ramp + rng.uniform(3.0, 8.0)
    sign = -1.0
    while start < duration:
        period = rng.uniform(10.0, 30.0)
        depth = rng.uniform(1.5, 4.5) if sign < 0 else rng.uniform(1.0, 3.0)
        m = (t >= start) & (t < start + period)
        v[m] += sign * depth * 0.5 * (1 - np.cos(2 * np.pi * (t[m] - start) / period))
        start += period + rng.uniform(0.0, 6.0)
        sign = -sign
    v = np.maximum(v, 0.0)
    x = np.concatenate([[0.0], np.cumsum(0.5 * dt * (v[1:] + v[:-1]))])
    return t, x, v


def paper_experiment(
    model: LowerLevelModel = TABLE_II_PROPOSED,
    *,
    seed: int = 0,
    runs: tuple[int, ...] | None = None,
    duration: float = SYNTH_DURATION,
    dt: float = SYNTH_DT,
    noise_a: float = SYNTH_NOISE["noise_a"],
    noise_v: float = SYNTH_NOISE["noise_v"],
    noise_x: float = SYNTH_NOISE["noise_x"],
    quantization_a: float = SYNTH_NOISE["quantization_a"],
) -> list[Run]:
    """Synthesises the paper's 21-run experiment (or the listed ``runs``).

    ``noise_*`` are the standard deviations of the Gaussian sensor noise on the
    measured acceleration (m/s²), speed (m/s) and position (m); the measured
    acceleration is then rounded to multiples of ``quantization_a`` (0 = none).
    The recorded command and the leader's trajectory are exact.
    """
    seed = check_seed(seed)
    dt = check_number(dt, "dt", positive=True)
    duration = check_number(duration, "duration", positive=True)
    _check_duration(duration, dt)
    n_runs = len(TABLE_I) if runs is None else len(runs)
    per_run = 16 * 8.0 * (duration / dt)  # ~16 float64 series per run
    check_memory(per_run * n_runs, f"paper_experiment: {n_runs} runs x {duration:g} s / "
                 f"dt={dt:g} s x 16 series x 8 bytes", "use a shorter duration or fewer runs",
                 per=per_run, unit="runs")
    for name, val in (
        ("noise_a", noise_a), ("noise_v", noise_v), ("noise_x", noise_x),
        ("quantization_a", quantization_a),
    ):  # fmt: skip
        check_number(val, name, nonneg=True)
    chosen = tuple(TABLE_I) if runs is None else tuple(
        check_int(r, "runs", min=1, max=len(TABLE_I)) for r in runs)
    out = []
    for r in chosen:
        upper = _table_i_upper(r)
        rng = np.random.default_rng([int(seed), r])
        t, lx, lv = leader_profile(duration, dt, rng)
        tr = closed_loop(model, lx, lv, dt, upper, v0=0.0, x0=lx[0] - GMIN)
        if not np.all(np.isfinite(tr.a)):
            raise ValueError(f"model: the follower diverges in run {r} ({model})")
        a, v, x = _measured(rng, tr.a, tr.v, tr.x, noise_a, noise_v, noise_x, quantization_a)
        noise = {"a": noise_a, "v": noise_v, "x": noise_x, "quant_a": quantization_a}
        out.append(
            Run(
                run_id=str(r), t=t, a=a, command_kind="acceleration", command=tr.command,
                v=v, x=x, lead_x=lx, lead_v=lv, lead_a=np.gradient(lv, dt), upper=upper,
                meta={"synthetic": True, "true_model": {"name": model.name, **model.to_dict()},
                      "seed": int(seed), "noise": noise,
                      "calibration_run": r in PAPER_CAL_RUNS},
            )
        )  # fmt: skip
    return out
