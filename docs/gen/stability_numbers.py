"""The numbers of docs/stability.md (Table II models): exact minimum stable
Tg (infimum) and where it is approached, the kv threshold as a supremum and its
behaviour as the lower kg bound goes to 0, grid thresholds for comparison, and the
Padé-order findings against the exact delay.

    python -m docs.gen --only stability-numbers    # minutes (the exact-delay infima)

The fragment ``docs/_generated/stability_numbers.md`` (included by docs/stability.md)
and its numbers ``stability_numbers.json``, written by :mod:`docs.gen`.
``quick=True`` skips the slow exact-delay infima (about a minute each).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

import avll

P = avll.PAPER_TABLE_II
NAMES = ("first", "second", "proposed")


def f(x: float | None, d: int = 6) -> str:
    return "—" if x is None or not math.isfinite(x) else f"{x:.{d}f}"


def g(x: float | None) -> str:
    return "—" if x is None or not math.isfinite(x) else f"{x:.4g}"


def render(quick: bool = False) -> tuple[str, dict[str, Any]]:
    """The fragment's body and its raw numbers."""
    t0 = time.perf_counter()
    doc: dict[str, Any] = {}
    md: list[str] = []

    # 1. minimum stable Tg (Padé 2, the paper's setting)
    md += ["### Minimum stable time gap (Padé order 2)", "",
           "Infimum of Tg over every locally and string stable point with kg in the box, "
           "kv in [0, 1.2], Tg in [0, 15] (`avll.min_stable_tg`).", "",
           "| model | kg box | inf Tg (s) | kg | kv | approached at box edge | capacity (veh/h) |",
           "|---|---|---|---|---|---|---|"]
    doc["min_stable_tg"] = {}
    for name in NAMES:
        for lo in (1e-3, 1e-6):
            e = avll.min_stable_tg(P[name], kg_range=(lo, 2.0), kv_range=(0.0, 1.2))
            doc["min_stable_tg"][f"{name}/{lo:g}"] = e.to_dict()
            md.append(f"| {name} | [{lo:g}, 2] | {f(e.value)} | {g(e.kg)} | {g(e.kv)} | "
                      f"{', '.join(e.on_edge) or 'no'} | {f(e.capacity, 1)} |")
    first = P["first"]
    if not isinstance(first, avll.FirstOrderLag):
        raise TypeError(f"PAPER_TABLE_II['first']: expected a FirstOrderLag, got {first!r}")
    td = first.Td
    md += ["", f"First-order lag: the infimum equals 2 Td = {f(2 * td)} s at "
           f"kv = 1/(2 Td) = {f(1 / (2 * td))} (paper Appendix A.4), for any kg; not attained.",
           ""]
    md += ["Second-order model, infimum against the lower end of the kg range "
           "(it is approached at that end):", "",
           "| kg lower end | inf Tg (s) | kv |", "|---|---|---|"]
    doc["second_kg_to_0"] = []
    for lo in (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        e = avll.min_stable_tg(P["second"], kg_range=(lo, 2.0), kv_range=(0.0, 1.2))
        doc["second_kg_to_0"].append([lo, e.value, e.kv])
        md.append(f"| {lo:g} | {f(e.value, 9)} | {f(e.kv)} |")
    md.append("")

    # 2. kv threshold as a supremum
    md += ["### kv threshold (Padé order 2)", "",
           "Supremum of kv over stable points with kg in [kg_lo, 5], Tg in [0, 15] "
           "(`avll.kv_supremum`), and the grid threshold of `avll.kv_threshold` "
           "(kg log-spaced kg_lo..5, 400 points; Tg 0..15, 301 points; tol 1e-6).", "",
           "| model | kg_lo | sup kv | at kg | at Tg | grid threshold |",
           "|---|---|---|---|---|---|"]
    doc["kv_supremum"] = {}
    for name in ("second", "proposed"):
        for lo in (1e-2, 1e-3, 1e-4, 1e-6):
            e = avll.kv_supremum(P[name], kg_range=(lo, 5.0), tg_range=(0.0, 15.0))
            grid = avll.kv_threshold(P[name], np.geomspace(lo, 5, 400), np.linspace(0, 15, 301),
                                     0.3, 1.2, tol=1e-6)
            doc["kv_supremum"][f"{name}/{lo:g}"] = {**e.to_dict(), "grid": grid}
            md.append(f"| {name} | {lo:g} | {f(e.value)} | {g(e.kg)} | {g(e.tg)} | {f(grid)} |")
    md += ["", "Largest stable kv at fixed kg as kg → 0 (`avll.boundary(model, 'kv_max', "
           "kg=..., tg=...)`, kv searched in [0, 2]):", "",
           "| model | Tg (s) | " + " | ".join(f"kg={k:g}" for k in (1e-2, 1e-4, 1e-6, 1e-8))
           + " |", "|---|---|---|---|---|---|"]
    doc["kv_max_small_kg"] = {}
    for name in ("second", "proposed"):
        b = avll.boundary(P[name], "kv_max", kg=[1e-2, 1e-4, 1e-6, 1e-8], tg=[15.0, 50.0],
                          search_range=(0.0, 2.0))
        doc["kv_max_small_kg"][name] = b.values.tolist()
        for j, t in enumerate((15.0, 50.0)):
            md.append(f"| {name} | {t:g} | " + " | ".join(f(v) for v in b.values[:, j]) + " |")
    md.append("")

    # 3. Padé orders against the exact delay
    md += ["### Padé order against the exact delay", "",
           "Infimum of Tg (box kg [1e-3, 2], kv [0, 1.2]) and supremum of kv (kg [1e-3, 5], "
           "Tg [0, 15]) per Padé order:", "",
           "| order | second inf Tg | proposed inf Tg | second sup kv | proposed sup kv |",
           "|---|---|---|---|---|"]
    doc["pade_orders"] = {}
    best: dict[str, Any] = {}
    for order in range(1, 11):
        row = []
        for name in ("second", "proposed"):
            e = avll.min_stable_tg(P[name], (1e-3, 2.0), (0.0, 1.2), order)
            s = avll.kv_supremum(P[name], (1e-3, 5.0), (0.0, 15.0), order)
            row.append((e.value, s.value))
            best[name] = e
        doc["pade_orders"][order] = row
        md.append(f"| {order} | {f(row[0][0])} | {f(row[1][0])} | {f(row[0][1])} | "
                  f"{f(row[1][1])} |")
    if not quick:
        ex = []
        for name in ("second", "proposed"):
            e10 = best[name]
            kg_box = (max(1e-3, e10.kg / 1.5), min(2.0, e10.kg * 1.5))
            kv_box = (max(0.0, e10.kv - 0.07), min(1.2, e10.kv + 0.07))
            e = avll.min_stable_tg(P[name], kg_box, kv_box, None, n_grid=12, n_scan=64)
            ex.append(e)
            doc.setdefault("exact_min_tg", {})[name] = {**e.to_dict(), "box_kg": kg_box,
                                                        "box_kv": kv_box}
        md.append(f"| exact delay | {f(ex[0].value)} | {f(ex[1].value)} | | |")
        md += ["", "The exact-delay infima are searched in a box around the Padé-10 "
               "minimiser (kg within a factor 1.5, kv within ±0.07; a coarser search, "
               "12-point scans and 64 Tg scan points, since every exact test costs about "
               "0.1 ms)."]
    md.append("")
    kg = np.geomspace(1e-3, 2.0, 40)
    tg = np.linspace(0.0, 15.0, 61)
    kv = np.array([0.0, 0.2, 0.4, 0.6, 0.75])
    md += ["Padé-error map on a grid (kg log 1e-3..2, 40; Tg 0..15, 61; kv "
           "0, 0.2, 0.4, 0.6, 0.75): share of certified points whose Padé code differs "
           "from the exact-delay code, and the counts of points Padé calls stable but "
           "the exact delay does not (false stable) and the reverse.", "",
           "| model | certified | " + " | ".join(f"order {o}" for o in range(1, 11)) + " |",
           "|---|---|" + "---|" * 10]
    doc["pade_error_map"] = {}
    for name in ("second", "proposed"):
        ds = avll.pade_error_map(P[name], kg, tg, kv)
        fr = ds["fraction_differs"].values
        fs, fu = ds["false_stable"].values, ds["false_unstable"].values
        doc["pade_error_map"][name] = {"fraction": fr.tolist(), "false_stable": fs.tolist(),
                                       "false_unstable": fu.tolist(),
                                       "certified": float(ds["certified"].mean())}
        md.append(f"| {name} | {100 * float(ds['certified'].mean()):.2f} % | "
                  + " | ".join(f"{100 * x:.2f} % ({a_}/{b_})"
                               for x, a_, b_ in zip(fr, fs, fu, strict=True)) + " |")
    md += ["", "(in brackets: false stable / false unstable points)", ""]
    md.append(f"_Computed in {time.perf_counter() - t0:.0f} s._")
    return "\n".join(md), doc
