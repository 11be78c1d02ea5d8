"""Reproduces the paper's Section IV numbers with avll (see README § Stability maps).

    python benches/reproduce_stability.py
"""

from __future__ import annotations

import time

import numpy as np

import avll
from avll import stability as S
from avll.paper import SECTION_IV_GRID, section_iv_axis

P = avll.PAPER_TABLE_II
t0 = time.perf_counter()

print("== kv threshold (nothing stable beyond it, Tg in [0, 15]) ==")
for kg_min in (1e-2, 1e-3, 1e-4):
    kg = np.geomspace(kg_min, 5.0, 400)
    tg = np.linspace(0.0, 15.0, 301)
    row = []
    for name in ("second", "proposed"):
        row.append(S.kv_threshold(P[name], kg, tg, 0.5, 1.0, tol=1e-5))
    print(f"kg log-spaced {kg_min:g}..5 (400), Tg 0..15 step 0.05: "
          f"second {row[0]:.4f}, proposed {row[1]:.4f}")
kg = np.geomspace(1e-3, 5.0, 400)
tg = np.linspace(0.0, 15.0, 301)
for order in (1, 2, 3, 4, 5, 8):
    row = [S.kv_threshold(P[n], kg, tg, 0.3, 1.2, order, tol=1e-5) for n in ("second", "proposed")]
    print(f"Padé order {order}: second {row[0]:.4f}, proposed {row[1]:.4f}")

print("\n== minimum stable Tg (0.1 s grid) and capacity ==")
kg = section_iv_axis(*SECTION_IV_GRID["kg"], log=True)
tg = section_iv_axis(*SECTION_IV_GRID["Tg"])
kv = section_iv_axis(*SECTION_IV_GRID["kv"])
tmin = {}
for name in ("second", "proposed", "first"):
    th = S.thresholds(S.stability_map(P[name], kg, tg, kv), kg, tg, kv)
    tmin[name] = th.tg_min_overall
    j = int(np.nanargmin(th.tg_min))
    # the same minimum on a 0.001 s Tg grid around it (the exact boundary value)
    fine = np.round(np.arange(max(0, th.tg_min_overall - 0.2), th.tg_min_overall + 0.0001,
                              0.001), 10)
    kvf = np.round(np.arange(max(0, kv[j] - 0.05), kv[j] + 0.05001, 0.001), 10)
    thf = S.thresholds(S.stability_map(P[name], kg, fine, kvf), kg, fine, kvf)
    print(f"{name:9s}: min Tg {th.tg_min_overall:.1f} s (at kv = {kv[j]:.2f}); "
          f"on a 0.001 s grid {thf.tg_min_overall:.3f} s; "
          f"capacity {S.capacity(th.tg_min_overall):.1f} veh/h")
cs, cp, cf = (S.capacity(tmin[n]) for n in ("second", "proposed", "first"))
print(f"proposed vs second: {100 * (1 - cp / cs):.2f} % lower (paper 42.86 %)")
print(f"first vs proposed : {100 * (cf / cp - 1):.2f} % larger (paper 53.42 %)")

print("\n== Padé-2 map vs the exact delay ==")
kg = np.geomspace(1e-3, 2.0, 40)
tg = np.linspace(0.0, 15.0, 61)
kv = np.array([0.0, 0.2, 0.4, 0.6, 0.75])
for name in ("second", "proposed"):
    rep = S.pade_report(P[name], kg, tg, kv)
    print(f"{name:9s}: {rep.summary()}; unsettled local verdicts: {int(rep.unsettled.sum())}")
print(f"\n(total {time.perf_counter() - t0:.0f} s)")
