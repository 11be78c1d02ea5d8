"""Generates the numbers of the intervals guide (docs/guide/intervals.md): the coverage
of the 95 % intervals of the band amplification and of ``Tg + Gmin / v̄`` on synthetic
platoons with a known truth (:func:`avll.synth_platoon.validate_intervals`, the slow test's
seeds), the same cars' plain percentile intervals, and the cost of intervals in the
OpenACC study on the shared ZalaZone folder (from
``docs/_generated/intervals_bench.json``, written by ``benches/bench_intervals.py``).

    python -m docs.gen --only intervals      # 48 calibrations with intervals (minutes)
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from avll.synth_platoon import validate_intervals

#: Fresh seeds of the final check with the converged refits (the method was chosen on
#: 7301-7308; 7501-7508 were its first final check, with refits that stopped early).
SEEDS = tuple(range(7601, 7609))
CARS = 6
N = 200
BENCH = Path(__file__).resolve().parents[1] / "_generated" / "intervals_bench.json"


def collect() -> dict[str, Any]:
    """The validation's summary and the benchmark's numbers (None when not run)."""
    v = validate_intervals(list(SEEDS), cars=CARS, n=N)
    bench = json.loads(BENCH.read_text(encoding="utf-8")) if BENCH.exists() else None
    return {"validation": v["summary"], "bench": bench}


def _p(x: Any) -> str:
    return "–" if x is None else f"{100 * x:.1f} %"


def render(numbers: dict[str, Any]) -> str:
    """The Markdown body."""
    s = numbers["validation"]
    lines = [
        f"Synthetic platoons (seeds {s['seeds'][0]}–{s['seeds'][-1]}, {s['cars']} cars, "
        f"{s['resamples']} resamples each, level {s['level']:g}; seeds not used while the "
        f"method was chosen). The resampled deviations were widened by a median factor "
        f"of {s['median_widening']:.2f}.",
        "",
        "| quantity | intervals holding the truth | cars without an interval | median "
        "relative width | plain percentile: holding | plain percentile: width | estimates "
        "within 10 % | mean error | median abs error | median miss (widths) |",
        "|---|---|---|---|---|---|---|---|---|---|"]
    for key, lab in (("amplification", "band amplification"),
                     ("time_gap_effective", "Tg + Gmin / v̄")):
        d = s[key]
        lines.append(f"| {lab} | {_p(d['coverage'])} | {_p(d['undetermined'])} | "
                     f"{_p(d['median_rel_width'])} | {_p(d['uncorrected_coverage'])} | "
                     f"{_p(d['uncorrected_median_rel_width'])} | {_p(d['within_10pct'])} | "
                     f"{100 * d['mean_error']:+.2f} % | {_p(d['median_abs_error'])} | "
                     f"{d['median_miss_in_widths']:.2f} |")
    miss = {lab: s[k].get("no_estimate", 0) for k, lab in
            (("amplification", "amplification"), ("time_gap_effective", "Tg + Gmin / v̄"))}
    if any(miss.values()):
        lines += ["", "Cars whose calibrated closed loop is locally unstable (no amplification "
                  "estimate; not within 10 %, left out of the errors): "
                  + ", ".join(f"{v} ({k})" for k, v in miss.items()) + "."]
    lines += ["", "\"Intervals holding the truth\" and the width count the cars with an "
              "interval; a car whose record has fewer effective blocks than fitted "
              "parameters has none (counted as holding, the share would be "
              + ", ".join(f"{_p(s[k]['coverage_all'])} ({lab})" for k, lab in
                          (("amplification", "amplification"),
                           ("time_gap_effective", "Tg + Gmin / v̄"))) + ")."]
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
