"""Benchmark: the cost of intervals in the OpenACC study (the target: at most 2x).

Runs :func:`avll.studies.openacc.openacc_study` on the shared ZalaZone folder twice in
one process, without intervals (``intervals=False``) and with them (the default
:class:`avll.Intervals`: a moving-block bootstrap over time of the main model's
calibrations, in-sample and out of sample, refit by a local search from the full-data
optimum), same seed and GA budget, and reports both wall times, their ratio and the
machine's load (1-minute load average before and after each run, and the cores),
since the machine is shared; and both CPU times of this process (every thread), whose
ratio the other users of a shared machine do not change.

    python benches/bench_intervals.py [--data /work/shared/data/openacc-zalazone]
        [--threads 0] [--n 200] [--models proposed,first,second] [--no-structures]
        [--json OUT] [--out DIR]

``--models`` (the study's ``models``; default: the study's three) and
``--no-structures`` (the study without its structure selection, which runs the same in
both and takes hours here) narrow the study; the JSON says which was run.

``--out DIR`` also saves the study with intervals (its summary, tables and report:
the out-of-sample predictions with their intervals, the bias and the shares inside
the intervals on the ZalaZone cars).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any

from perf_tables import head_commit

import avll
from avll import _atomic
from avll.studies.openacc import openacc_study


def run(data: str, threads: int, n: int, out_dir: str | None = None,
        models: tuple[str, ...] | None = None, structures: bool = True
        ) -> dict[str, object]:
    """Both timings, their ratio and the load around each."""
    out: dict[str, object] = {"data": data, "threads": threads, "cores": os.cpu_count(),
                              "avll": avll.__version__, "resamples": n,
                              "models": list(models) if models else "the study's default",
                              "structures": structures}
    narrow: dict[str, Any] = {"structures": structures}
    if models:
        narrow["models"] = models
    for name, iv in (("without", False), ("with", avll.Intervals(n=n))):
        load0 = os.getloadavg()[0]
        t0, c0 = time.perf_counter(), time.process_time()
        st = openacc_study(data, intervals=iv, threads=threads, figures=False,
                           **narrow)
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
        out[name] = {"seconds": round(dt, 1), "cpu_seconds": round(cpu, 1),
                     "load_before": round(load0, 2),
                     "load_after": round(os.getloadavg()[0], 2),
                     "cars": len(st.summary["cars"])}
        print(f"{name} intervals: {dt:.1f} s (load {load0:.2f} -> "
              f"{os.getloadavg()[0]:.2f})", file=sys.stderr)
        if name == "with" and out_dir:
            st.save(out_dir)
    w, wo = out["with"], out["without"]
    assert isinstance(w, dict) and isinstance(wo, dict)
    out["ratio"] = round(w["seconds"] / wo["seconds"], 3)
    out["cpu_ratio"] = round(w["cpu_seconds"] / wo["cpu_seconds"], 3)
    out["target"] = 2.0
    return out


def main() -> None:
    """Command line."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", default="/work/shared/data/openacc-zalazone")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--n", type=int, default=avll.Intervals().n)
    ap.add_argument("--models", default=None, help="comma-separated lower-level models")
    ap.add_argument("--no-structures", action="store_true",
                    help="without the structure selection (in both runs)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    models = tuple(m.strip() for m in a.models.split(",")) if a.models else None
    res = run(a.data, a.threads, a.n, a.out, models, not a.no_structures)
    res["commit"] = head_commit()
    res["command"] = "python " + " ".join(["benches/bench_intervals.py", *sys.argv[1:]])
    print(json.dumps(res, indent=1))
    if a.json:
        _atomic.write_json(a.json, res, indent=1)


if __name__ == "__main__":
    main()
