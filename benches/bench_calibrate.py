"""Benchmark: calibrate the proposed model on 10 runs of 300 s at 20 Hz.

avll's GA (Rust, rayon, all cores) against ``scipy.optimize.differential_evolution``
(polish on) driving ``scipy.signal.lfilter`` rollouts of the same exact
discretization (:mod:`avll.reference.lfilter`), on the same objective (Eq. 6, open
loop, from rest) over the same box in the same unit coordinates (log scale for
m1, m2, m3 as in :data:`avll.calibrate.DEFAULT_BOUNDS`).

"Best known MSE" is the lowest Eq. 6 value seen by any run below (and the
true parameters' value). Reported: full-run wall times with default settings,
and the time to reach within 1 % (and 0.1 %) of the best known MSE, measured with
the GA's ``target`` option and a DE callback that stops at the same target.

    python benches/bench_calibrate.py [--seed N] [--quick]
"""

from __future__ import annotations

import os

# One BLAS thread for the scipy route: small LAPACK calls are otherwise much slower
# on a loaded machine (and DE evaluates serially anyway).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from scipy.optimize import differential_evolution  # noqa: E402

import avll  # noqa: E402
from avll.calibrate import DEFAULT_BOUNDS, calibrate  # noqa: E402
from avll.reference.lfilter import cost_lfilter  # noqa: E402
from avll.synth import PAPER_CAL_RUNS, paper_experiment  # noqa: E402

BOX = DEFAULT_BOUNDS["proposed"]
NAMES = list(BOX)


def to_user(z: np.ndarray) -> np.ndarray:
    out = []
    for zi, (lo, hi, sc) in zip(z, BOX.values(), strict=True):
        zi = min(max(float(zi), 0.0), 1.0)
        out.append(lo * (hi / lo) ** zi if sc == "log" else lo + zi * (hi - lo))
    return np.array(out)


def rust_cost(p: np.ndarray, runs: list[avll.Run]) -> float:
    return float(avll.batch_cost("proposed", p[None], runs).mean())


class DEObjective:
    """The scipy route's objective; records when it first reaches ``target``."""

    def __init__(self, runs: list[avll.Run], target: float | None) -> None:
        self.runs = runs
        self.evals = 0
        self.best = np.inf
        self.target = target
        self.t0 = time.perf_counter()
        self.c0 = time.process_time()
        self.hit: tuple[float, float, int] | None = None

    def __call__(self, z: np.ndarray) -> float:
        self.evals += 1
        f = cost_lfilter(avll.Proposed(*to_user(z)), self.runs)
        self.best = min(self.best, f)
        if self.hit is None and self.target is not None and f <= self.target:
            self.hit = (time.perf_counter() - self.t0, time.process_time() - self.c0, self.evals)
        return f


def run_de(
    runs: list[avll.Run], seed: int, target: float | None
) -> tuple[float, float, float, int]:
    """DE with polish. With a target: the wall time and evaluation count at the first
    evaluation reaching it (DE is stopped by its callback from then on), or the full
    run's if it never does. Returns (wall s, CPU s, best cost, evaluations)."""
    obj = DEObjective(runs, target)

    def cb(intermediate_result: object) -> bool:
        return obj.hit is not None

    obj.t0 = time.perf_counter()
    obj.c0 = time.process_time()
    res = differential_evolution(
        obj, [(0.0, 1.0)] * len(NAMES), seed=seed, polish=True, callback=cb
    )
    wall = time.perf_counter() - obj.t0
    cpu = time.process_time() - obj.c0
    best = min(rust_cost(to_user(res.x), runs), obj.best)
    if obj.hit is not None:
        return obj.hit[0], obj.hit[1], best, obj.hit[2]
    return wall, cpu, best, obj.evals


def run_ga(runs: list[avll.Run], seed: int, target: float | None) -> tuple[float, float, Any]:
    """The avll GA with default settings; (wall s, CPU s of all threads, result)."""
    t0, c0 = time.perf_counter(), time.process_time()
    res = calibrate("proposed", runs, seed=seed, target=target)
    return time.perf_counter() - t0, time.process_time() - c0, res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats (minimum kept)")
    ap.add_argument("--ga-seeds", type=int, default=8, help="GA seeds for the spread")
    args = ap.parse_args()

    runs = paper_experiment(seed=args.seed, runs=PAPER_CAL_RUNS, duration=300.0)
    n = sum(len(r) for r in runs)
    print(f"problem: proposed model, {len(runs)} runs x 300 s at 20 Hz = {n} samples/eval")
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start")
    true = avll.PAPER_TABLE_II["proposed"]
    known = [rust_cost(true.to_array(), runs)]
    print(f"true parameters' cost: {known[0]:.6g}")

    # Warm-up (thread pool, caches).
    calibrate("proposed", runs[:1], seed=0, max_generations=2, polish=False)

    gw, gc, ga = run_ga(runs, args.seed, None)
    known.append(ga.cost)
    print(
        f"avll GA, full default run (2 starts, polish): {gw:.2f} s wall, {gc:.2f} s CPU, "
        f"cost {ga.cost:.6g}, {ga.evaluations} evaluations "
        f"({ga.evaluations * n / gc / 1e6:.0f} M model-steps per CPU-s)"
    )
    dw, dc, dcost, dev = run_de(runs, args.seed, None)
    known.append(dcost)
    print(
        f"scipy DE + lfilter, full default run (polish): {dw:.2f} s wall, {dc:.2f} s CPU, "
        f"cost {dcost:.6g}, {dev} evaluations ({dev * n / dc / 1e6:.1f} M model-steps per CPU-s)"
    )
    best = min(known)
    print(f"best known MSE: {best:.6g} (DE's default end point: {dcost / best - 1:+.3%})")

    print()
    print(f"time to reach within tol of the best known MSE (min of {args.repeats} repeats)")
    print(
        f"{'tol':>6} {'avll GA wall/CPU s':>20} {'scipy DE wall/CPU s':>21} {'ratio wall/CPU':>16}"
    )
    for tol in (0.01, 0.001):
        target = best * (1 + tol)
        g = [run_ga(runs, args.seed, target) for _ in range(args.repeats)]
        d = [run_de(runs, args.seed, target) for _ in range(args.repeats)]
        g_ok = all(r[2].cost <= target for r in g)
        d_ok = all(r[2] <= target for r in d)
        gw, gc = min(r[0] for r in g), min(r[1] for r in g)
        dw, dc = min(r[0] for r in d), min(r[1] for r in d)
        note = ("" if g_ok else " (GA missed)") + ("" if d_ok else " (DE missed)")
        print(
            f"{tol:>6.1%} {gw:>9.2f} / {gc:>6.2f} {dw:>10.2f} / {dc:>6.2f} "
            f"{dw / gw:>7.1f}x / {dc / gc:>4.1f}x{note}"
        )
    # The GA's spread over seeds (DE runs one seed: it is the slow side).
    walls, evs = [], []
    for sd in range(args.seed, args.seed + args.ga_seeds):
        w, _, g1 = run_ga(runs, sd, best * 1.01)
        walls.append(w)
        evs.append(g1.evaluations if g1.cost <= best * 1.01 else -1)
    print(
        f"GA time to 1 % over seeds {args.seed}..{args.seed + args.ga_seeds - 1}: "
        f"median {np.median(walls):.2f} s, max {max(walls):.2f} s; evaluations {evs}"
    )


if __name__ == "__main__":
    main()
