"""Do the loop's findings fix the stability conclusions? The fragment
docs/_generated/blind_stability.md (written by ``python -m docs.gen --only blind-stability``).

For a scenario of the physical generator :mod:`avll.synth_blind` the diagnosis loop
(``effect_loop('second', ...)``, calibration runs 1, 3, 8, 15, validation 12, 19)
gives a baseline fit (no effect) and a final model (with the accepted effects). Both
go through :func:`avll.effect_stability.effect_stability`; the *true* vehicle
(:func:`avll.synth_blind.simulate_platoon`, the same leader, the same fit of the
speed fundamental over the same window) gives the amplification the models should
predict. The linearised thresholds exist only for the models.

    python -m avll.studies.blind.stability       # ~2 min, prints it
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

import avll
from avll.diagnose import effect_loop
from avll.effect_stability import (
    EffectStability,
    car_ratios,
    effect_stability,
    fundamental_amplitude,
    sine_leader,
)
from avll.report import num as _f
from avll.synth_blind import DEFAULTS, SCENARIOS, blind_experiment, simulate_platoon

UPPER = avll.UpperLevel(kg=0.2, kv=0.3, Tg=1.5)
V0 = 12.0  # inside the speed range of the runs
AMPS = (0.1, 0.5, 1.0, 2.0, 3.0)
N_CARS = 4
SCENARIO_LIST = ("power_limit", "brake_lag")


def truth_amplification(scenario: str, r: EffectStability) -> np.ndarray:
    """Per-car amplification of the true vehicles, same leader and method as ``r``: the
    speed fundamental fitted as :func:`avll.effect_stability.effect_stability` fits it
    (:func:`~avll.effect_stability.fundamental_amplitude`), each car's over the car ahead's
    by its rule (:func:`~avll.effect_stability.car_ratios`)."""
    p = {**DEFAULTS, **SCENARIOS[scenario]}
    amps = np.asarray(r.amplitudes, dtype=float)
    speed_amp = np.full((amps.size, N_CARS + 1), np.nan)
    for k, a in enumerate(amps):
        t, lx, lv, meas = sine_leader(V0, a, r.omega, r.dt, r.warm_periods, r.measure_periods)
        pl = simulate_platoon(p, lx, lv, r.dt, UPPER, N_CARS, v0=V0)
        speed_amp[k] = [fundamental_amplitude(t[meas], v[meas], r.omega)
                        for v in (lv, *pl["v"])]
    return car_ratios(speed_amp, amps)


def _params(d: dict[str, float]) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in d.items())


def _gm(a: np.ndarray) -> np.ndarray:
    return np.exp(np.mean(np.log(a), axis=1))


def case(scenario: str) -> list[str]:
    """One scenario's section."""
    runs = blind_experiment(scenario, seed=0)
    res = effect_loop("second", runs[:4], runs[4:6], seed=1)
    kw: dict[str, Any] = {"v0": V0, "amplitudes": AMPS, "n_cars": N_CARS, "period": 20.0}
    rb = effect_stability(res.baseline, UPPER, **kw)
    rf = effect_stability(res.final, UPPER, **kw)
    tr = truth_amplification(scenario, rf)
    lines = [
        f"### {scenario}",
        "",
        f"Baseline fit `{res.baseline.base.name}` ({_params(res.baseline.base.to_dict())}); "
        f"final model `{res.final.name}` ({_params(res.final.base.to_dict())}; "
        + "; ".join(f"{e.name} {_params(e.to_dict())}" for e in res.final.effects) + ").",
        "",
        "| model | linearisation | code at the gains | \\|H(jω)\\| | smallest stable Tg at "
        "kg, kv (s) | min stable Tg over the box (s) | kv threshold over the box |",
        "|---|---|---|---|---|---|---|",
    ]
    for who, r in (("baseline", rb), ("final", rf)):
        for e in r.linear:
            label = "base part only" if who == "final" and e.label == "base" else e.label
            lines.append(f"| {who} | {label} | {_f(e.code, 'd')} | {_f(e.gain_at_omega, '.4g')} | "
                         f"{_f(e.tg_min_at_gains, '.3f')} | {_f(e.min_stable_tg, '.3f')} | "
                         f"{_f(e.kv_threshold, '.4f')} |")  # fmt: skip
    lines += [
        "",
        "Amplification (speed fundamental, car i / car i−1; geometric mean over the "
        f"{N_CARS} followers, then per car for the final model and the truth):",
        "",
        "| A (m/s) | baseline | final | true vehicle | final, per car | true vehicle, per car |",
        "|---|---|---|---|---|---|",
    ]
    gb, gf, gt = _gm(rb.amplification), _gm(rf.amplification), _gm(tr)
    for k, a in enumerate(AMPS):
        lines.append(
            f"| {a:g} | {_f(float(gb[k]), '.4g')} | {_f(float(gf[k]), '.4g')} | "
            f"{_f(float(gt[k]), '.4g')} | "
            f"{', '.join(_f(float(x), '.3f') for x in rf.amplification[k])} | "
            f"{', '.join(_f(float(x), '.3f') for x in tr[k])} |"
        )
    notes = [*rb.notes, *rf.notes]
    if notes:
        lines += ["", "Notes: " + "; ".join(notes)]
    return lines


def render() -> str:
    """The fragment's body (stamped and written by
    ``python -m docs.gen --only blind-stability``)."""
    lines = [
        f"Upper level kg = {UPPER.kg:g}, kv = {UPPER.kv:g}, Tg = {UPPER.Tg:g} s, "
        f"v0 = {V0:g} m/s, disturbance period 20 s, {N_CARS} followers; data seed 0, loop "
        "seed 1. Codes: 0 locally unstable, 1 string unstable, 2 stable (Padé order 2).",
        "",
    ]
    for sc in SCENARIO_LIST:
        lines += case(sc) + [""]
    return "\n".join(lines)


def main() -> int:
    """Prints the fragment (``python -m docs.gen --only blind-stability`` writes it)."""
    print(render())
    return 0


if __name__ == "__main__":
    sys.exit(main())
