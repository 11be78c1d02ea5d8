"""Renders ``bench_engine.py --json`` output as the docs' engine tables.

    python benches/bench_engine.py --json docs/_generated/engine_bench.json
    python benches/render_engine.py docs/_generated/engine_bench.json \
        docs/_generated/engine_bench.md

Every number in the tables comes from the JSON (rates in M steps/s per core, the
ratio avll / best peer as the median and range of the paired rounds and as the ratio
of best times, the target and whether the median meets it); the machine, the
versions, the allocator and the load average during the run are stated with it.
``--fresh`` (optional) appends the summary of a second run (e.g. ``--allocator keep``).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path
from typing import Any


def _calls(m: dict[str, Any]) -> str:
    """How many calls each rate is the best of (runs before ``--seconds`` existed
    made exactly ``repeat`` calls)."""
    sec = m.get("seconds", 0.0)
    if not sec:
        return f"best of {m['repeat']} calls"
    return (f"best of at least {m['repeat']} calls and {sec:g} s of calls per "
            "implementation, round-robin")

def _faults(r: dict) -> str:
    f = r.get("faults_per_call")
    return "" if f is None else f"{f:,.0f}"


def render(d: dict, fresh: dict | None = None) -> str:
    """The engine tables of ``d``; with ``fresh`` (a run with ``--allocator
    default``), its summary table after them."""
    m = d["meta"]
    load = ", ".join(f"{x:.1f}" for x in m.get("load_average_start", []))
    alloc = m.get("allocator", "allocator left as it is")
    lines = [
        f"Measured by `benches/bench_engine.py` (avll {m['avll']}, numba {m['numba']}, "
        f"numpy {m['numpy']}; {m['machine']}, {m['cpus']} CPUs; load average at start "
        f"{load}; {_calls(m)}, CPU time, so rates are per core; {alloc}"
        + (f"; {m['isolation']}" if "isolation" in m else "") + "). "
        f"Every peer was checked equal to avll to {m['tolerance']:g} before timing.",
        "",
        *_summary(d),
        "",
        "Every peer (the best one is in the table above):",
        "",
        "| workload | peer | M steps/s | avll / peer | max rel diff to avll "
        "| page faults per call |",
        "|---|---|---|---|---|---|",
    ]
    for w in d["workloads"]:
        for p in w["peers"]:
            diff = p.get("max_rel_diff")
            lines.append(
                f"| {w['title']} | {p['name']} | {p['rate']:.0f} | "
                f"{w['avll']['rate'] / p['rate']:.2f}x | "
                f"{'' if diff is None else f'{diff:.1e}'} | {_faults(p)} |"
            )
    for s in d.get("scaling", []):
        lines.append("")
        note = ("" if s["met"] else " With the cores busy with other jobs the wall speed-up "
                "cannot show; the CPU efficiency bounds it (speed-up <= threads x efficiency).")
        lines.append(
            f"{s['title']}: avll {s['speedup']['avll']:.2f}x (CPU efficiency "
            f"{s['cpu_efficiency']['avll']:.2f}; load average {s['load_average']:.1f} on "
            f"{m['cpus']} CPUs); target >= {s['target']:g}x: "
            f"{'met' if s['met'] else 'not met'}.{note}"
        )
    if fresh is not None:
        fm = fresh["meta"]
        fload = ", ".join(f"{x:.1f}" for x in fm.get("load_average_start", []))
        lines += [
            "",
            f"The same benchmark run again ({fm.get('allocator', 'allocator left as it is')}; "
            f"load average at start {fload}):",
            "",
            *_summary(fresh),
        ]
    return "\n".join(lines) + "\n"


def _ratio(w: dict) -> str:
    """Median of the paired rounds with their range (runs before the pairing: the
    ratio of best times)."""
    if "ratio_median" not in w:
        return f"{w['ratio']:.2f}x"
    lo, hi = w["ratio_range"]
    return f"{w['ratio_median']:.2f}x ({lo:.2f}-{hi:.2f})"


def _summary(d: dict) -> list[str]:
    lines = [
        "| workload | avll | best peer | avll / best peer: median of paired rounds (range) "
        "| ratio of best times | target | met | page faults per call (avll, best peer) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for w in d["workloads"]:
        best = max(w["peers"], key=lambda p: p["rate"])
        target = w.get("target")
        met = "" if target is None else ("yes" if w.get("met") else "no")
        if target is not None and not w.get("met") and w.get("shortfall_factor"):
            met += f" (short by {w['shortfall_factor']:.2f}x)"
        lines.append(
            f"| {w['title']} | {w['avll']['rate']:.0f} | {best['rate']:.0f} ({best['name']}) "
            f"| {_ratio(w)} | {w['ratio']:.2f}x | {'' if target is None else f'>= {target:g}x'} "
            f"| {met} | {_faults(w['avll'])}, {_faults(best)} |"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--fresh", type=Path, default=None,
                    help="a second run (e.g. --allocator keep), summarized after the tables")
    a = ap.parse_args()
    fresh = None if a.fresh is None else json.loads(a.fresh.read_text())
    text = render(json.loads(a.json.read_text()), fresh)
    fd, tmp = tempfile.mkstemp(dir=a.out.parent, prefix=a.out.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, a.out)


if __name__ == "__main__":
    main()
