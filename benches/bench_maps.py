"""Benchmark: chunked maps streamed to Zarr (wall time, peak memory) and the speed-up
of distributed map sweeps from one to two worker processes.

    python benches/bench_maps.py [--points 1e8] [--chunk 1e7] [--sweep-maps 8]

``--points 1e10`` is the issue's 10^10-point map (kg 5000 x Tg 5000 x kv 400 at the
default aspect); it takes several minutes per 10^9 points on two cores. Peak memory
is the process's maximum resident set size (``ru_maxrss``) above its level before
the map, for the threaded Dask scheduler in this process.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time

import numpy as np

import avll
from avll import maps as M


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def dir_size(path: str) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)


def zarr_bench(points: float, chunk: float, workers: int) -> None:
    import dask

    n_kv = max(1, int(round((points / 62_500) ** (1 / 3))))  # kg : Tg : kv = 12.5 : 12.5 : 1
    n = max(2, int(round(np.sqrt(points / n_kv))))
    kg = np.geomspace(1e-3, 2.0, n)
    tg = np.linspace(0.0, 15.0, n)
    kv = np.linspace(0.0, 1.0, n_kv)
    total = kg.size * tg.size * kv.size
    side = max(1, int(round(np.sqrt(chunk / n_kv))))
    chunks = {"kg": side, "Tg": side, "kv": n_kv}
    m = avll.PAPER_TABLE_II["proposed"]
    lazy = M.map_dataset(m, kg, tg, kv, chunks=chunks)
    nchunks = int(np.prod([len(c) for c in lazy.chunks]))
    out = tempfile.mkdtemp(prefix="avll-bench-", dir=os.environ.get("TMPDIR", "/tmp"))
    path = os.path.join(out, "map.zarr")
    base = rss_mb()
    t0 = time.perf_counter()
    with dask.config.set(scheduler="threads", num_workers=workers):
        M.write_map(lazy, path)
    wall = time.perf_counter() - t0
    peak = rss_mb() - base
    size = dir_size(path)
    # spot check: a few chunks equal the eager kernel
    back = M.open_map(path)
    i = slice(0, min(50, n))
    np.testing.assert_array_equal(back[i, i, :].values, avll.stability_map(m, kg[i], tg[i], kv))
    print(f"map {kg.size} x {tg.size} x {kv.size} = {total:.3g} points, chunks {chunks} "
          f"({nchunks} chunks of {side * side * n_kv / 1e6:.1f} MB)")
    print(f"  to Zarr with {workers} threads: {wall:.1f} s wall, "
          f"{total / wall / 1e6:.1f} M points/s;"
          f" peak RSS above baseline {peak:.0f} MB (map {total / 1e6:.0f} MB uncompressed);"
          f" on disk {size / 1e6:.1f} MB")
    shutil.rmtree(out, ignore_errors=True)


def sweep_bench(n_maps: int, side: int) -> None:
    m = avll.PAPER_TABLE_II["proposed"]
    base = m.to_dict()
    models = [type(m)(**{**base, "Td": base["Td"] * (0.9 + 0.2 * i / max(1, n_maps - 1))})
              for i in range(n_maps)]
    kg = np.geomspace(1e-3, 2.0, side)
    tg = np.linspace(0.0, 15.0, side)
    kv = np.linspace(0.0, 1.0, 8)
    times = {}
    ref = None
    for workers in (1, 2):
        c = M.local_client(n_workers=workers, threads_per_worker=1)
        try:
            M.sweep(models[:workers], kg[:10], tg[:10], kv, client=c)  # warm-up
            t0 = time.perf_counter()
            r = M.sweep(models, kg, tg, kv, client=c, threads=1)
            times[workers] = time.perf_counter() - t0
        finally:
            cl = c.cluster
            c.close()
            cl.close()
        if ref is None:
            ref = r.values
        else:
            assert np.array_equal(ref, r.values)
    pts = n_maps * side * side * kv.size
    print(f"sweep of {n_maps} maps x {side * side * kv.size / 1e6:.1f} M points "
          f"(one task per map, 1 thread per worker):")
    for w, t in times.items():
        print(f"  {w} worker(s): {t:.2f} s, {pts / t / 1e6:.1f} M points/s")
    print(f"  speed-up 1 -> 2 workers: {times[1] / times[2]:.2f}x (results identical)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--points", type=float, default=1e8, help="map size (1e10 for the issue's)")
    ap.add_argument("--chunk", type=float, default=1e7, help="points per chunk")
    ap.add_argument("--workers", type=int, default=2, help="Dask threads for the Zarr map")
    ap.add_argument("--sweep-maps", type=int, default=8)
    ap.add_argument("--sweep-side", type=int, default=500)
    ap.add_argument("--skip-zarr", action="store_true")
    ap.add_argument("--skip-sweep", action="store_true")
    a = ap.parse_args()
    print(f"machine: {os.cpu_count()} cores")
    if not a.skip_zarr:
        zarr_bench(a.points, a.chunk, a.workers)
    if not a.skip_sweep:
        sweep_bench(a.sweep_maps, a.sweep_side)


if __name__ == "__main__":
    main()
