"""Generates the kg -> 0 section of docs/stability.md: the largest stable kv at a fixed
small kg (its limit kv0, which does not depend on Tg), and the check that the
second-order model's minimum stable Tg tends to the low-frequency bound
(1 - K b0) / (b0 kv0) as kg -> 0.

    python -m docs.gen --only stability-limits     # seconds

As kg -> 0 the low-frequency condition R(0) > 0 of the string test,
kg b0 (Tg b0 (2 kv + kg Tg) - 2 (1 - K b0)) > 0, becomes Tg kv > (1 - K b0) / b0, and
the rest of the test tends to that of the velocity-only loop (kg = 0), whose largest
string-stable kv is kv0. So a stable point with a small kg needs kv < kv0 (about) and
Tg > (1 - K b0) / (b0 kv): the infimum of Tg over small kg is (1 - K b0) / (b0 kv0).
"""

from __future__ import annotations

import avll

P = avll.PAPER_TABLE_II
KGS = (1e-6, 1e-8, 1e-10, 1e-12, 1e-14)
TGS = (15.0, 50.0)


def render() -> str:
    """The fragment's body."""
    md = ["Largest stable kv at a fixed small kg (`avll.boundary(model, 'kv_max', ...)`, "
          "Padé 2, kv searched in [0, 2]):", "",
          "| model | Tg (s) | " + " | ".join(f"kg={k:g}" for k in KGS) + " |",
          "|---|---|" + "---|" * len(KGS)]
    kv0 = {}
    for name in ("second", "proposed"):
        b = avll.boundary(P[name], "kv_max", kg=list(KGS), tg=list(TGS), search_range=(0.0, 2.0))
        for j, t in enumerate(TGS):
            vals = " | ".join(f"{v:.7f}" for v in b.values[:, j])
            md.append(f"| {name} | {t:g} | {vals} |")
        kv0[name] = float(b.values[-1, 0])
    md += [""]
    for name in ("second", "proposed"):
        c = P[name].linear()
        bound = (1 - c["K"] * c["b0"]) / (c["b0"] * kv0[name])
        e = avll.min_stable_tg(P[name], kg_range=(1e-8, 2.0), kv_range=(0.0, 1.2))
        md.append(f"- {name}: kv0 ≈ {kv0[name]:.6f}; low-frequency bound (1 − K b0)/(b0 kv0) "
                  f"= {bound:.6f} s; infimum of Tg over kg in [1e-8, 2] = {e.value:.6f} s "
                  f"(at kg = {e.kg:.3g}).")
    return "\n".join(md)
