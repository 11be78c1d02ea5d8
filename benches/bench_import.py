"""Import time of avll against numpy's (``import avll`` at most 2x ``import
numpy``), each measured in fresh interpreters, median of ``--runs``.

    python benches/bench_import.py [--runs 15]

Runs with bytecode writing on (an installed package has its ``.pyc`` files; the first,
untimed run writes avll's), numpy and avll interleaved. Prints the medians of
``python -c "import numpy"`` and ``python -c "import avll"`` (which imports numpy
itself), their ratio, and the heavy packages that ``import avll``
leaves unimported (pandas, scipy, matplotlib, xarray, dask load on first use).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys

PROBE = (
    "import time, sys; t = time.perf_counter(); import {mod}; "
    "print(time.perf_counter() - t); "
    "print(','.join(m for m in ('pandas', 'scipy', 'matplotlib', 'xarray', 'dask') "
    "if m in sys.modules))"
)


def _env() -> dict[str, str]:
    """The environment without ``PYTHONDONTWRITEBYTECODE``: an installed package has its
    bytecode compiled (numpy's is), so avll's must be too, or every run would time
    the compilation of avll's sources rather than their import."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def timed(mod: str) -> tuple[float, str]:
    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(mod=mod)], capture_output=True, text=True,
        check=True, env=_env(),
    ).stdout.split("\n")
    return float(out[0]), out[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=15)
    a = ap.parse_args()
    timed("avll")  # warm the file cache (and write avll's bytecode, see _env)
    res: dict[str, list[tuple[float, str]]] = {"numpy": [], "avll": []}
    for _ in range(a.runs):  # interleaved, so that a change of machine load hits both
        for m in res:
            res[m].append(timed(m))
    med = {m: statistics.median(t for t, _ in r) for m, r in res.items()}
    print(f"import numpy: {med['numpy'] * 1e3:.0f} ms (median of {a.runs} fresh interpreters)")
    print(f"import avll:  {med['avll'] * 1e3:.0f} ms (numpy included)")
    ratio = med["avll"] / med["numpy"]
    print(f"ratio avll / numpy: {ratio:.2f}x (target <= 2x: {'met' if ratio <= 2 else 'not met'})")
    loaded = res["avll"][0][1]
    print(f"heavy packages loaded by import avll: {loaded or 'none'}")


if __name__ == "__main__":
    main()
