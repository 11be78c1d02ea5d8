"""The synthetic experiment with a physical effect the models do not have: blind
test data for :mod:`avll.diagnose`.

The generator's effects are realised *differently* from the library's
(:mod:`avll.effects`) wherever the physics allows, so that a blind test is not
circular (the library must approximate, not reproduce, the truth):

=============  ==============================================  ==========================
effect         generator (truth)                               library (fitted)
=============  ==============================================  ==========================
asymmetric     the braking part of the actuator input passes   ``kb G(rb s)`` while
               an extra first-order brake lag ``brake_lag``     braking
               and a gain ``brake_gain``
saturation     smooth ``A tanh(a/A)`` / ``D tanh(a/D)``          hard clip at ``a_max``,
                                                               ``d_max``
rate_limit     slew limit on the produced acceleration          slew limit on the command
               (an actuator jerk limit)
deadband       dead zone on ``u_ref`` (inside the inner loop)   dead zone on the command
speed_drag     force ``F0 tanh(v/0.5) + F2 v²`` on a mass ``M``  ``c0 s(v) + c2 v|v|``
grade          gravity ``g (1 - rho) sin(atan(grade(x)))`` of   ``g_eff * grade``
               a track profile in space, ``rho`` compensated
delay          the command is re-sampled by a slower ECU        a fractional transport
               (hold ``hold`` s) and shifted ``shift`` s         delay ``tau``
=============  ==============================================  ==========================

The rest follows :func:`avll.synth.paper_experiment`: Table I's runs, the leader
profile, the constant-time-gap upper law, sensor noise and quantisation, one
random stream per ``(seed, run)``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from scipy.linalg import expm

from .data import Run
from .defaults import SYNTH_DT, SYNTH_NOISE
from .models import LowerLevelModel, UpperLevel
from .paper import G
from .synth import GMIN, _measured, _table_i_upper, leader_profile

__all__ = ["GENERATOR_DEFAULTS", "expected_params", "paper_experiment_effects"]

#: Default generator parameters of each effect.
GENERATOR_DEFAULTS: dict[str, dict[str, float]] = {
    "asymmetric": {"brake_gain": 0.6, "brake_lag": 0.6},
    "saturation": {"A": 0.7, "D": 0.8},
    "rate_limit": {"j": 0.6},
    "deadband": {"delta": 0.15},
    "speed_drag": {"F0": 150.0, "F2": 4.0, "M": 1500.0},
    "grade": {"rho": 0.3, "amplitude": 0.04},
    "delay": {"shift": 0.3, "hold": 0.2},
}


_EXPECTED: dict[str, Callable[[Mapping[str, float]], dict[str, float]]] = {
    "asymmetric": lambda p: {"kb": p["brake_gain"]},
    "saturation": lambda p: {"a_max": p["A"], "d_max": p["D"]},
    "rate_limit": lambda p: {"j_max": p["j"]},
    "deadband": lambda p: {"delta": p["delta"]},
    "speed_drag": lambda p: {"c0": p["F0"] / p["M"], "c2": p["F2"] / p["M"]},
    "grade": lambda p: {"g_eff": G * (1 - p["rho"])},
    # Re-sampling every `hold` s from the runs' period dt (SYNTH_DT, the default of
    # paper_experiment_effects) lags (hold - dt)/2 on average.
    "delay": lambda p: {"tau": p["shift"] + 0.5 * (p["hold"] - SYNTH_DT)},
}


def expected_params(effect: str, gen: Mapping[str, float] | None = None) -> dict[str, float]:
    """What the library's parameters should come out near for the generator ``effect``
    with parameters ``gen`` (defaults :data:`GENERATOR_DEFAULTS`): first-order
    equivalences, the blind tests state their tolerances around them. An unknown
    ``effect`` is a ``ValueError``."""
    if effect not in _EXPECTED:
        raise ValueError(f"effect: unknown {effect!r}")
    return _EXPECTED[effect]({**GENERATOR_DEFAULTS[effect], **(gen or {})})


def _grade_profile(x: np.ndarray, amplitude: float, phase: float) -> np.ndarray:
    return amplitude * (0.7 * np.sin(2 * np.pi * x / 900.0 + phase)
                        + 0.3 * np.sin(2 * np.pi * x / 310.0 + 2 * phase))  # fmt: skip


def _truth_rollout(
    model: LowerLevelModel,
    effects: Mapping[str, Mapping[str, float]],
    lx: np.ndarray,
    lv: np.ndarray,
    dt: float,
    upper: UpperLevel,
    x0: float,
    grade_phase: float,
) -> dict[str, np.ndarray]:
    c = model.linear()
    b1, b0, a2, a1, td, k = c["b1"], c["b0"], c["a2"], c["a1"], c["Td"], c["K"]
    if a2 != 0:
        am = np.array([[0.0, 1.0], [-1 / a2, -a1 / a2]])
        bm = np.array([0.0, 1.0])
        cm = np.array([b0 / a2, b1 / a2])
    else:
        am, bm, cm = np.array([[-1 / a1]]), np.array([1.0]), np.array([b0 / a1])
    m = am.shape[0]
    asym = effects.get("asymmetric")
    tb = float(asym["brake_lag"]) if asym else 1.0
    gb = float(asym["brake_gain"]) if asym else 1.0
    # States: model, brake lag z (z' = (w_neg - z)/T, used by "asymmetric"), and the
    # exact integrators of the linear output (v' = y, p' = v).
    n_s = m + 3
    a_full = np.zeros((n_s, n_s))
    a_full[:m, :m] = am
    a_full[m, m] = -1.0 / tb
    if asym:
        a_full[:m, m] = bm * gb
    a_full[m + 1, :m] = cm
    a_full[m + 2, m + 1] = 1.0
    b_pos = np.zeros(n_s)
    b_pos[:m] = bm
    b_neg = np.zeros(n_s)
    if asym:
        b_neg[m] = 1.0 / tb
    else:
        b_neg[:m] = bm

    def zoh(tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        mm = np.zeros((n_s + 2, n_s + 2))
        mm[:n_s, :n_s] = a_full * tau
        mm[:n_s, n_s] = b_pos * tau
        mm[:n_s, n_s + 1] = b_neg * tau
        e = expm(mm)
        return e[:n_s, :n_s], e[:n_s, n_s], e[:n_s, n_s + 1]

    r = td / dt
    i = int(np.floor(r))
    f = r - i if r - i > 1e-12 else 0.0
    pa, ga_p, ga_n = zoh((1 - f) * dt)
    pb, gb_p, gb_n = zoh(f * dt)
    c_full = np.concatenate([cm, [0.0, 0.0, 0.0]])
    sat, rl, dz, drag, grd, dly = (effects.get(k) for k in (
        "saturation", "rate_limit", "deadband", "speed_drag", "grade", "delay"))
    n = lx.size
    out = {key: np.zeros(n) for key in ("a", "v", "x", "command", "grade")}
    x = np.zeros(n_s)
    x[m + 1], x[m + 2] = float(lv[0]), float(x0)
    dv = dp = 0.0
    refs: list[float] = []
    cmds: list[float] = []
    prev_a = 0.0
    hold_n = int(round(dly["hold"] / dt)) if dly else 1
    shift_n = int(round(dly["shift"] / dt)) if dly else 0
    for j in range(n):
        y = float(c_full @ x)
        v, p = x[m + 1] + dv, x[m + 2] + dp
        a = y
        if sat:
            a = sat["A"] * np.tanh(a / sat["A"]) if a >= 0 else sat["D"] * np.tanh(a / sat["D"])
        if rl:
            step = rl["j"] * dt
            prev_a += min(max(a - prev_a, -step), step)
            a = prev_a
        if drag:
            a -= (drag["F0"] * np.tanh(v / 0.5) + drag["F2"] * v * v) / drag["M"]
        gr = 0.0
        if grd:
            gr = float(_grade_profile(np.array([p]), grd["amplitude"], grade_phase)[0])
            a -= G * (1 - grd["rho"]) * np.sin(np.arctan(gr))
        u = upper.command(lx[j], lv[j], p, v)
        cmds.append(u)
        uc = u
        if dly:
            js = j - shift_n
            js = (js // hold_n) * hold_n if js >= 0 else -1
            uc = cmds[js] if js >= 0 else 0.0
        ref = uc + k * a
        if dz:
            d = dz["delta"]
            ref = ref - d if ref > d else (ref + d if ref < -d else 0.0)
        refs.append(ref)
        w0 = refs[j - i] if j - i >= 0 else 0.0
        w1 = refs[j - i - 1] if j - i - 1 >= 0 else 0.0
        out["a"][j], out["v"][j], out["x"][j], out["command"][j], out["grade"][j] = a, v, p, u, gr
        if not (abs(a) < 1e3 and np.isfinite(a)):
            raise ValueError(f"effects: the follower diverges (sample {j})")
        if asym:
            w0p, w0n, w1p, w1n = max(w0, 0), min(w0, 0), max(w1, 0), min(w1, 0)
        else:
            w0p, w0n, w1p, w1n = w0, 0.0, w1, 0.0
        if f > 0:  # the step is split at the fractional delay
            x = pb @ x + gb_p * w1p + gb_n * w1n
        x = pa @ x + ga_p * w0p + ga_n * w0n
        # Speed and position: exact for the linear output, plus the effects'
        # difference held over the interval.
        dp += dt * dv + 0.5 * dt * dt * (a - y)
        dv += dt * (a - y)
    return out


def paper_experiment_effects(
    model: LowerLevelModel,
    effects: Mapping[str, Mapping[str, float] | None] | None = None,
    *,
    seed: int = 0,
    runs: tuple[int, ...] = (1, 3, 8, 12, 15, 19),
    duration: float = 120.0,
    dt: float = SYNTH_DT,
    noise_a: float = SYNTH_NOISE["noise_a"],
    noise_v: float = SYNTH_NOISE["noise_v"],
    noise_x: float = SYNTH_NOISE["noise_x"],
    quantization_a: float = SYNTH_NOISE["quantization_a"],
    extra_exo: tuple[str, ...] = (),
    leader_speedup: float = 1.0,
) -> list[Run]:
    """Runs of the paper-like experiment whose true lower level is ``model`` plus
    the generator-side ``effects`` (``{"saturation": {"A": 0.7}}``, parameters
    defaulting to :data:`GENERATOR_DEFAULTS`). With ``grade`` the runs carry
    ``exo_grade``; ``extra_exo`` adds irrelevant smooth random exogenous columns of
    those names (false-positive checks). ``leader_speedup`` plays the leader's
    profile that many times faster (accelerations scale by it, jerks by its square),
    for effects that only show in brisk manoeuvres (``rate_limit``)."""
    if not (np.isfinite(leader_speedup) and leader_speedup > 0):
        raise ValueError(f"leader_speedup: must be > 0, got {leader_speedup}")
    effs: dict[str, dict[str, float]] = {}
    for name, par in (effects or {}).items():
        if name not in GENERATOR_DEFAULTS:
            raise ValueError(f"effects: unknown generator effect {name!r}")
        unknown = set(par or {}) - set(GENERATOR_DEFAULTS[name])
        if unknown:
            raise ValueError(f"effects[{name!r}]: unknown parameters {sorted(unknown)}")
        effs[name] = {**GENERATOR_DEFAULTS[name], **(par or {})}
    out = []
    for r in runs:
        upper = _table_i_upper(r)
        rng = np.random.default_rng([int(seed), r, 6])
        t, lx, lv = leader_profile(duration * leader_speedup, dt, rng)
        if leader_speedup != 1.0:
            ts = np.arange(0.0, duration, dt)
            lv = np.interp(ts * leader_speedup, t, lv)
            lx = np.interp(ts * leader_speedup, t, lx) / leader_speedup
            t = ts
        phase = float(rng.uniform(0, 2 * np.pi))
        tr = _truth_rollout(model, effs, lx, lv, dt, upper, lx[0] - GMIN, phase)
        a, v, x = _measured(rng, tr["a"], tr["v"], tr["x"], noise_a, noise_v, noise_x,
                            quantization_a)
        exo: dict[str, Any] = {"grade": tr["grade"]} if "grade" in effs else {}
        for name in extra_exo:
            # A smooth irrelevant signal: filtered noise.
            w = rng.normal(size=t.size)
            k = np.exp(-np.arange(200) * dt / 2.0)
            exo[name] = np.convolve(w, k / k.sum(), mode="full")[: t.size] * 5
        out.append(
            Run(
                run_id=str(r), t=t, a=a, command_kind="acceleration", command=tr["command"],
                v=v, x=x, lead_x=lx, lead_v=lv, lead_a=np.gradient(lv, dt), exo=exo,
                upper=upper,
                meta={"synthetic": True, "true_model": {"name": model.name, **model.to_dict()},
                      "true_effects": effs, "seed": int(seed)},
            )
        )  # fmt: skip
    return out
