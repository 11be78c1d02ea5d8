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
        self.hit: tuple[float, int] | None = None

    def __call__(self, z: np.ndarray) -> float:
        self.evals += 1
        f = cost_lfilter(avll.Proposed(*to_user(z)), self.runs)
        self.best = min(self.best, f)
        if self.hit is None and self.target is not None and f <= self.target:
            self.hit = (time.perf_counter() - self.t0, self.evals)
        return f


def run_de(runs: list[avll.Run], seed: int, target: float | None) -> tuple[float, float, int]:
    """DE with polish. With a target: the wall time and evaluation count at the first
    evaluation reaching it (DE is stopped by its callback from then on), or the full
    run's if it never does."""
    obj = DEObjective(runs, target)

    def cb(intermediate_result: object) -> bool:
        return obj.hit is not None

    obj.t0 = time.perf_counter()
    res = differential_evolution(
        obj, [(0.0, 1.0)] * len(NAMES), seed=seed, polish=True, callback=cb
    )
    wall = time.perf_counter() - obj.t0
    best = min(rust_cost(to_user(res.x), runs), obj.best)
    if obj.hit is not None:
        return obj.hit[0], best, obj.hit[1]
    return wall, best, obj.evals


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="skip the full DE run")
    ap.add_argument("--ga-seeds", type=int, default=8, help="GA seeds for the spread")
    args = ap.parse_args()

    runs = paper_experiment(seed=args.seed, runs=PAPER_CAL_RUNS, duration=300.0)
    n = sum(len(r) for r in runs)
    print(f"problem: proposed model, {len(runs)} runs x 300 s at 20 Hz = {n} samples/eval")
    true = avll.PAPER_TABLE_II["proposed"]
    known = [rust_cost(true.to_array(), runs)]
    print(f"true parameters' cost: {known[0]:.6g}")

    # Warm-up (thread pool, caches).
    calibrate("proposed", runs[:1], seed=0, max_generations=2, polish=False)

    t0 = time.perf_counter()
    ga = calibrate("proposed", runs, seed=args.seed)
    ga_wall = time.perf_counter() - t0
    known.append(ga.cost)
    rate = ga.evaluations * n / ga_wall / 1e6
    print(
        f"avll GA (default, polish): {ga_wall:.2f} s, cost {ga.cost:.6g}, "
        f"{ga.generations} generations, {ga.evaluations} evaluations "
        f"({rate:.0f} M model-steps/s)"
    )

    de_full = None
    if not args.quick:
        de_full = run_de(runs, args.seed, None)
        known.append(de_full[1])
        rate = de_full[2] * n / de_full[0] / 1e6
        print(
            f"scipy DE + lfilter (default, polish): {de_full[0]:.2f} s, cost {de_full[1]:.6g}, "
            f"{de_full[2]} evaluations ({rate:.1f} M model-steps/s)"
        )

    best = min(known)
    print(f"best known MSE: {best:.6g}")
    rows = []
    for tol in (0.01, 0.001):
        target = best * (1 + tol)
        t0 = time.perf_counter()
        g = calibrate("proposed", runs, seed=args.seed, target=target)
        g_wall = time.perf_counter() - t0
        if g.cost > target:  # the GA stopped (stall) before the target: report it
            g_note = f" (stopped at {g.cost / best - 1:+.3%})"
        else:
            g_note = ""
        d_wall, d_cost, d_ev = run_de(runs, args.seed, target)
        d_note = "" if d_cost <= target else f" (stopped at {d_cost / best - 1:+.3%})"
        rows.append((tol, g_wall, g.evaluations, g_note, d_wall, d_ev, d_note))
    print()
    print("time to reach within tol of the best known MSE (wall s, evaluations)")
    print(f"{'tol':>6} {'avll GA':>16} {'scipy DE':>18} {'ratio':>7}")
    for tol, gw, ge, gn, dw, de, dn in rows:
        print(f"{tol:>6.1%} {gw:>7.2f} s ({ge:>6}) {dw:>8.2f} s ({de:>6}) {dw / gw:>6.1f}x{gn}{dn}")
    # The GA's spread over seeds (the DE side is run once: it is the slow one).
    walls, evs = [], []
    for sd in range(args.seed, args.seed + args.ga_seeds):
        t0 = time.perf_counter()
        g = calibrate("proposed", runs, seed=sd, target=best * 1.01)
        walls.append(time.perf_counter() - t0)
        evs.append(g.evaluations if g.cost <= best * 1.01 else -1)
    print(
        f"GA time to 1 % over seeds {args.seed}..{args.seed + args.ga_seeds - 1}: "
        f"median {np.median(walls):.2f} s, max {max(walls):.2f} s; evaluations {evs}"
    )
    if de_full is not None:
        print(f"full default runs: ratio {de_full[0] / ga_wall:.1f}x (DE {de_full[0]:.1f} s / "
              f"GA {ga_wall:.2f} s)")  # fmt: skip


if __name__ == "__main__":
    main()
