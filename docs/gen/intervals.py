"""Generates the numbers of the intervals guide (docs/guide/intervals.md): the coverage
of the 95 % intervals of the band amplification and of ``Tg + Gmin / v̄`` on synthetic
platoons with a known truth (:func:`avll.synth_platoon.validate_intervals`, the slow test's
seeds), the same cars' intervals without the small-sample widening, the two refits
compared on the same resamples (:func:`compare_refits`), and the cost of intervals in
the OpenACC study on the shared ZalaZone folder (from
``docs/_generated/intervals_bench.json``, written by ``benches/bench_intervals.py``).

    python -m docs.gen --only intervals      # 48 calibrations with intervals (minutes)
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from avll.synth_platoon import validate_intervals
from avll.uncertainty import BLOCK_FACTOR, LM_BUDGET_PER_PARAM

#: Fresh seeds of the final check of the block factor (chosen on 7301-7308, with the
#: symmetric intervals, the k-step refits and the gap-loop rule; 7501-7508, 7601-7608 and
#: 7701-7708 were the final checks of earlier rules, 7801-7804 their long records).
SEEDS = tuple(range(7901, 7909))
CARS = 6
N = 200
#: Record length (s) of the validation's cars.
DURATION = 300.0
#: The same method on records four times as long (fresh seeds; half the cars): whether
#: the shortfall of the 300 s records is theirs or the method's.
LONG_SEEDS = tuple(range(8001, 8005))
LONG_DURATION = 1200.0
BENCH = Path(__file__).resolve().parents[1] / "_generated" / "intervals_bench.json"
#: The development seeds on which the block factor was chosen, and the factors compared.
DEV_SEEDS = tuple(range(7301, 7309))
BLOCK_FACTORS = (1.0, 1.25, 1.5, 2.0)


#: The comparison of the two refits: the first seed's cars, this many resamples each.
COMPARE_N = 50


def compare_refits(seed: int = SEEDS[0], cars: int = CARS, n: int = COMPARE_N
                   ) -> dict[str, Any]:
    """The two refits of :class:`avll.Intervals` on the same resamples (the validation's
    calibrations of ``seed``, one thread): CPU time of the calibrations alone and with
    intervals by each refit, rollouts per refit, and the refits' resampled costs
    (Levenberg-Marquardt relative to the simplex, per resample)."""
    import time

    import numpy as np

    from avll import Intervals
    from avll.calibration import calibrate_many
    from avll.defaults import UPPER_NAMES
    from avll.studies.openacc import GMIN_MAX, WEIGHTS
    from avll.synth_platoon import synth_platoon

    sp = synth_platoon(cars, seed=seed, duration=300.0, models=("proposed",))
    kw: dict[str, Any] = dict(seed=seed, starts=2, closed_loop=True, upper_free=UPPER_NAMES,
                              weights=WEIGHTS, bounds={"Gmin": (0.0, GMIN_MAX)}, threads=1)
    out: dict[str, Any] = {"seed": seed, "cars": cars, "resamples": n}
    costs = {}
    for name, iv in (("none", None), ("simplex", Intervals(n=n, refit="simplex")),
                     ("lm", Intervals(n=n, refit="lm"))):
        c0 = time.process_time()
        res = calibrate_many("proposed", sp.runs, "per_run", intervals=iv, **kw)
        out[name] = {"cpu_seconds": time.process_time() - c0}
        if iv is not None:
            us = [r.uncertainty for r in res]
            out[name]["rollouts_per_refit"] = sum(u.rollouts for u in us) / (n * cars)
            costs[name] = [np.asarray(u.costs) for u in us]
    for name in ("simplex", "lm"):
        out[name]["intervals_cpu_seconds"] = out[name]["cpu_seconds"] - out["none"]["cpu_seconds"]
        out[name]["ratio_to_calibration"] = out[name]["cpu_seconds"] / out["none"]["cpu_seconds"]
    rel = np.concatenate([a / b - 1.0 for a, b in zip(costs["lm"], costs["simplex"],
                                                        strict=True) if a.shape == b.shape])
    rel = rel[np.isfinite(rel)]
    out["lm_cost_vs_simplex"] = {"median": float(np.median(rel)), "min": float(rel.min()),
                                 "max": float(rel.max()),
                                 "below_or_equal": float(np.mean(rel <= 1e-12))}
    return out


def collect() -> dict[str, Any]:
    """The validation's summary, the refits' comparison and the benchmark's numbers
    (None when not run)."""
    dev = {str(f): validate_intervals(list(DEV_SEEDS), cars=CARS, n=N, duration=DURATION,
                                      options={"block_factor": f})["summary"]
           for f in BLOCK_FACTORS}
    v = validate_intervals(list(SEEDS), cars=CARS, n=N, duration=DURATION)
    long = validate_intervals(list(LONG_SEEDS), cars=CARS, n=N, duration=LONG_DURATION)
    bench = json.loads(BENCH.read_text(encoding="utf-8")) if BENCH.exists() else None
    return {"validation": v["summary"], "duration": DURATION, "long": long["summary"],
            "long_duration": LONG_DURATION, "refits": compare_refits(), "bench": bench,
            "block_factors": dev}


def _p(x: Any) -> str:
    return "–" if x is None else f"{100 * x:.1f} %"


def _row(s: dict[str, Any], key: str, lab: str) -> str:
    d = s[key]
    return (f"| {lab} | {_p(d['coverage'])} | {_p(d['undetermined'])} | "
            f"{_p(d['median_rel_width'])} | {_p(d['uncorrected_coverage'])} | "
            f"{_p(d['uncorrected_median_rel_width'])} | {_p(d['within_10pct'])} | "
            f"{100 * d['mean_error']:+.2f} % | {_p(d['median_abs_error'])} | "
            f"{d['median_miss_in_widths']:.2f} |")


def render(numbers: dict[str, Any]) -> str:
    """The Markdown body."""
    s = numbers["validation"]
    lines = [
        f"Synthetic platoons (seeds {s['seeds'][0]}–{s['seeds'][-1]}, {s['cars']} cars, "
        f"records of {numbers.get('duration', DURATION):g} s, {s['resamples']} resamples "
        f"each, level {s['level']:g}; seeds not used while the method was chosen). The "
        f"resampled deviations were widened by a median factor of "
        f"{s['median_widening']:.2f}.",
        "",
        "| quantity | intervals holding the truth | cars without an interval | median "
        "relative width | unwidened: holding | unwidened: width | estimates "
        "within 10 % | mean error | median abs error | median miss (widths) |",
        "|---|---|---|---|---|---|---|---|---|---|"]
    for key, lab in (("amplification", "band amplification"),
                     ("time_gap_effective", "Tg + Gmin / v̄")):
        lines.append(_row(s, key, lab))
    lg = numbers.get("long")
    if lg:
        lines += ["", f"The same on records of {numbers['long_duration']:g} s instead of "
                  f"{numbers['duration']:g} s (fresh seeds {lg['seeds'][0]}–{lg['seeds'][-1]}, "
                  f"{lg['cars']} cars):", "", *lines[2:4]]
        for key, lab in (("amplification", "band amplification"),
                         ("time_gap_effective", "Tg + Gmin / v̄")):
            lines.append(_row(lg, key, lab))
    miss = {lab: s[k].get("no_estimate", 0) for k, lab in
            (("amplification", "amplification"), ("time_gap_effective", "Tg + Gmin / v̄"))}
    if any(miss.values()):
        lines += ["", "Cars whose calibrated closed loop is locally unstable (no amplification "
                  "estimate; not within 10 %, left out of the errors): "
                  + ", ".join(f"{v} ({k})" for k, v in miss.items()) + "."]
    lines += ["", "\"Intervals holding the truth\" and the width count the cars with an "
              "interval (symmetric about the estimate); a car whose record has fewer "
              "effective blocks than fitted parameters has none, nor for Tg + Gmin / v̄ a "
              "car whose fitted gap loop is slower than its record (kg or the lower "
              "level's DC gain at zero: `Uncertainty.gap_loop_too_slow`; counted as "
              "holding, the share would be "
              + ", ".join(f"{_p(s[k]['coverage_all'])} ({lab})" for k, lab in
                          (("amplification", "amplification"),
                           ("time_gap_effective", "Tg + Gmin / v̄"))) + ")."]
    if s.get("gap_loop_slow"):
        lines += ["", f"Of the {s['gap_loop_slow']} cars without an interval of Tg + Gmin / v̄ "
                  f"(gap loop slower than the record), {s['gap_loop_slow_below_truth_cost']} "
                  "have a fit whose cost is below that of the true parameters on the same "
                  "record: the data, not the optimiser, leave their time gap open."]
    dev = numbers.get("block_factors")
    if dev:
        d0 = next(iter(dev.values()))
        lines += ["", f"The block factor (`Intervals(block_factor=...)`, the Politis–White "
                  f"length times it) on the development seeds ({d0['seeds'][0]}–"
                  f"{d0['seeds'][-1]}, {d0['cars']} cars, the same fits), where "
                  f"{BLOCK_FACTOR:g} was chosen as the smallest whose standardised errors of "
                  "Tg + Gmin / v̄ have a standard deviation of one (estimate minus truth over "
                  "the half-width, times the normal quantile):", "",
                  "| factor | median block | widening | Tg + Gmin / v̄: holding | its width "
                  "| its standardised errors' sd | amplification: holding | its width |",
                  "|---|---|---|---|---|---|---|---|"]
        for f, d in dev.items():
            t, a = d["time_gap_effective"], d["amplification"]
            lines.append(f"| {float(f):g} | {d['median_block_s']:.1f} s | "
                         f"{d['median_widening']:.2f} | {_p(t['coverage'])} | "
                         f"{_p(t['median_rel_width'])} | {t['standardised_error_sd']:.2f} | "
                         f"{_p(a['coverage'])} | {_p(a['median_rel_width'])} |")
    c = numbers.get("refits")
    if c:
        q = c["lm_cost_vs_simplex"]
        lines += ["", f"The two refits of the same resamples (seed {c['seed']}, {c['cars']} "
                  f"cars, {c['resamples']} resamples each, one thread; CPU time):", "",
                  "| refit | intervals' CPU time | rollouts per refit | calibration with "
                  "intervals / calibration alone |", "|---|---|---|---|"]
        for k, lab in (("lm", "Levenberg–Marquardt (`refit=\"lm\"`, the default)"),
                       ("simplex", "Nelder–Mead (`refit=\"simplex\"`)")):
            d = c[k]
            lines.append(f"| {lab} | {d['intervals_cpu_seconds']:.0f} s | "
                         f"{d['rollouts_per_refit']:.0f} | {d['ratio_to_calibration']:.2f} |")
        lines += ["", f"The calibrations alone: {c['none']['cpu_seconds']:.0f} s. "
                  "Levenberg–Marquardt's resampled cost relative to the simplex's, per "
                  f"resample: median {100 * q['median']:+.3f} %, from "
                  f"{100 * q['min']:+.2f} % to {100 * q['max']:+.2f} %; at or below it "
                  f"for {_p(q['below_or_equal'])} of the resamples (the cost has local "
                  "minima; the simplex stops at its evaluation cap, Levenberg–Marquardt "
                  f"after {LM_BUDGET_PER_PARAM} d rollouts: a k-step bootstrap)."]
    b = numbers.get("bench")
    if b:
        lines += ["", f"OpenACC study on the ZalaZone folder ({b['without']['cars']} cars, "
                  f"{b['cores']} cores, threads {b['threads']}): {b['without']['seconds']} s "
                  f"without intervals, {b['with']['seconds']} s with them: ratio "
                  f"{b['ratio']:.2f} (target ≤ {b['target']:g}); "
                  + (f"CPU time {b['without']['cpu_seconds']} s and "
                     f"{b['with']['cpu_seconds']} s: ratio {b['cpu_ratio']:.2f}; "
                     if "cpu_ratio" in b else "")
                  + "1-minute load "
                  f"{b['without']['load_before']}–{b['without']['load_after']} and "
                  f"{b['with']['load_before']}–{b['with']['load_after']} (a shared machine)."]
    else:
        lines += ["", "The benchmark of the study's cost has not been run "
                  "(`python benches/bench_intervals.py --json "
                  "docs/_generated/intervals_bench.json`)."]
    return "\n".join(lines) + "\n"
