"""Benchmark: stability-map grid points per second per core (proposed model, local +
string test, Padé 2) against the numpy reference, in one process.

Per-core rates use CPU time (``time.process_time``) of single-threaded runs, so they
stay meaningful on a shared machine; wall-clock rates are printed beside them.

    python benches/bench_stability.py [--n 1000] [--ref-points 2000]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import avll
from avll import stability as S
from avll.reference import stability as ref


def timed(f):  # type: ignore[no-untyped-def]
    w0, c0 = time.perf_counter(), time.process_time()
    out = f()
    return out, time.perf_counter() - w0, time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=1000, help="kg and Tg points (n x n map)")
    ap.add_argument("--ref-points", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    m = avll.PAPER_TABLE_II["proposed"]
    kg = np.geomspace(1e-3, 2.0, a.n)
    tg = np.linspace(0.0, 15.0, a.n)
    kv = np.array([0.3])
    npts = kg.size * tg.size
    S.stability_map(m, kg[:10], tg[:10], kv, threads=1)  # warm-up (pool, pages)

    best_cpu, best_wall = np.inf, np.inf
    for _ in range(a.repeat):
        codes, wall, cpu = timed(lambda: S.stability_map(m, kg, tg, kv, threads=1))
        best_cpu, best_wall = min(best_cpu, cpu), min(best_wall, wall)
    counts = np.bincount(codes.ravel(), minlength=3)
    rust_core = npts / best_cpu
    print(f"map {a.n} x {a.n} (kg log 1e-3..2, Tg 0..15, kv 0.3), codes 0/1/2 = {counts.tolist()}")
    print(f"rust, 1 thread : {rust_core / 1e6:8.2f} M points/s per core (CPU time), "
          f"{npts / best_wall / 1e6:8.2f} M points/s wall")
    allw = min(timed(lambda: S.stability_map(m, kg, tg, kv, threads=0))[1] for _ in range(a.repeat))
    print(f"rust, all {os.cpu_count()} cores: {npts / allw / 1e6:8.2f} M points/s wall, "
          f"{a.n} x {a.n} map in {allw * 1e3:.0f} ms")

    rng = np.random.default_rng(0)
    idx = rng.integers(0, npts, a.ref_points)
    pk, pt = kg[idx // tg.size], tg[idx % tg.size]
    _, wall, cpu = timed(
        lambda: [ref.stability_code(m, pk[i], pt[i], 0.3) for i in range(idx.size)]
    )
    ref_core = idx.size / cpu
    print(f"numpy reference (numpy.roots per point): {ref_core / 1e3:8.2f} k points/s per core "
          f"(CPU), {idx.size / wall / 1e3:.2f} k wall")
    (bc, _), wall, cpu = timed(lambda: ref.stability_codes(m, pk, pt, np.full(idx.size, 0.3)))
    print(f"numpy reference (batched eigvals)       : {idx.size / cpu / 1e3:8.2f} k points/s "
          f"per core (CPU; numpy may use several threads)")
    same = int((bc == codes.reshape(-1)[idx]).sum())
    print(f"reference codes equal to the map's at {same} of {idx.size} sampled points")
    print(f"ratio rust / numpy.roots reference: {rust_core / ref_core:,.0f} x (per core)")
    n_ex = min(5000, idx.size * 3)
    ek = kg[rng.integers(0, kg.size, n_ex)]
    et = tg[rng.integers(0, tg.size, n_ex)]
    (ec, ok), _, cpu = timed(lambda: S.exact_delay_codes(m, ek, et, np.full(n_ex, 0.3),
                                                         threads=1))
    c10 = S.stability_points(m, ek, et, 0.3, 10)
    print(f"exact delay (crossing count + certified interval sweep): {n_ex / cpu / 1e3:8.2f} k "
          f"points/s per core (CPU); certified {ok.mean():.4f}; equal to Padé 10 at "
          f"{(ec == c10).mean():.4f} of the points")


if __name__ == "__main__":
    main()
