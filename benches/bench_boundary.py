"""Benchmark: an n x n boundary surface (the smallest stable Tg over kg x kv) computed
directly, against reading it off a grid of the same resolution (n x n x n map, Tg
0..15 in n points), in one process: time and accuracy.

    python benches/bench_boundary.py [--n 200] [--threads 0]

``--n 1000`` is the issue's 1000 x 1000 surface (the grid side is then a 10^9-point
map, about a minute per core).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import avll
from avll import stability as S


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--model", default="proposed", choices=["first", "second", "proposed"])
    a = ap.parse_args()
    m = avll.PAPER_TABLE_II[a.model]
    n = a.n
    kg = np.geomspace(1e-3, 2.0, n)
    kv = np.linspace(0.0, 1.2, n)
    tg = np.linspace(0.0, 15.0, n)

    t0 = time.perf_counter()
    b = avll.boundary(m, "tg_min", kg=kg, kv=kv, threads=a.threads)
    t_b = time.perf_counter() - t0

    t0 = time.perf_counter()
    codes = S.stability_map(m, kg, tg, kv, threads=a.threads)
    st = codes == S.STABLE
    has = st.any(axis=1)
    first = np.where(has, tg[np.argmax(st, axis=1)], np.nan)  # (kg, kv)
    t_g = time.perf_counter() - t0

    exact = b.values
    both = np.isfinite(exact) & np.isfinite(first)
    only_exact = int((np.isfinite(exact) & ~np.isfinite(first)).sum())
    only_grid = int((~np.isfinite(exact) & np.isfinite(first)).sum())
    err = first[both] - exact[both]
    print(f"{a.model}: {n} x {n} tg_min surface (kg log 1e-3..2, kv 0..1.2, Tg in [0, 15])")
    print(f"  boundary (exact to 1e-10 relative): {t_b:.2f} s "
          f"({n * n / t_b / 1e3:.1f} k boundary points/s)")
    print(f"  grid of the same resolution ({n}^3 = {n**3:.3g} points, Tg step "
          f"{15 / (n - 1):.4f} s): {t_g:.2f} s")
    print(f"  time ratio grid / boundary: {t_g / t_b:.2f}")
    print(f"  grid minus exact where both stable: max {err.max():.4g} s, mean {err.mean():.4g} s,"
          f" min {err.min():.3g} s (never below 0: {bool((err >= 0).all())})")
    print(f"  stable only per the boundary (a stable stretch between grid points): "
          f"{only_exact}; only per the grid: {only_grid}")
    print(f"  min over the surface: exact {np.nanmin(exact):.6f} s, grid {np.nanmin(first):.6f} s")


if __name__ == "__main__":
    main()
