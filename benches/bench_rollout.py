"""Rollout throughput: model-steps per second per core, avll (Rust) vs scipy.signal.lfilter
vs the plain numpy reference, all measured in this one process on the same series.

    python benches/bench_rollout.py [--samples 2000000] [--ref-samples 20000] [--repeat 5]

Use a release build (``maturin develop --release``). Rates are per core: work over
the best process CPU time of ``--repeat`` calls (robust on a shared machine); the
parallel batch_cost lines also give wall-clock rates, which need idle cores. For
each model (the paper's Table II parameters, dt = 0.05 s):

* open loop: ``avll.simulate`` (single thread); lfilter runs the *exact* discrete
  transfer function of the same rollout (fractional dead time via the modified
  z-transform, inner feedback closed at the samples:
  ``avll.reference.rollout.discrete_transfer_function``), so both compute the same
  numbers (the max relative difference is printed);
* closed loop behind a recorded leader (upper law Eq. 3): ``avll.closed_loop``;
  lfilter runs the closed-loop system's three input channels (leader position,
  leader speed, the constant Gmin) as three filters summed, derived here from the
  reference's hold maps (again the same numbers, checked with v0 = x0 = 0);
* the reference is ``avll.reference.rollout`` (one Python iteration per sample);
* batch_cost: P parameter rows x R runs of 5,400 samples (the paper's run length at
  20 Hz), acceleration MSE, with 1 and 2 threads.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections.abc import Callable

import numpy as np
import scipy.signal

import avll
from avll.reference import rollout as ref

DT = 0.05


WALL: dict[int, float] = {}


def best(fn: Callable[[], object], repeat: int) -> float:
    """Best CPU time (s) of ``repeat`` calls: the process's CPU time, all threads
    included, so ``work / best`` is the throughput per core even when other tenants
    share the cores. The matching best wall-clock time is kept in ``WALL[id(fn)]``."""
    fn()  # warm-up
    cpu, wall = [], []
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    WALL[id(fn)] = min(wall)
    return min(cpu)


def leader(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    acc = np.convolve(rng.normal(scale=0.5, size=n), np.ones(40) / 40, mode="same")
    lv = 15.0 + 3.0 * np.sin(np.arange(n) * DT / 20.0) + np.cumsum(acc) * DT * 0.01
    lx = 100.0 + np.concatenate([[0.0], np.cumsum((lv[1:] + lv[:-1]) / 2) * DT])
    return lx, lv


def closed_loop_filters(
    model: avll.LowerLevelModel, up: avll.UpperLevel
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(b, a)`` of the closed loop from lead_x, lead_v and the constant 1 to the
    follower's acceleration (zero initial state)."""
    p = ref.plant(model)
    i, f = ref.split_delay(p.Td, DT)
    m = p.A.shape[0]
    n = m + 2  # model, v, x
    A = np.zeros((n, n))
    A[:m, :m] = p.A
    A[m, :m] = p.C
    A[m + 1, m] = 1.0
    B = np.zeros(n)
    B[:m] = p.B
    phi_f, gam_f = ref.hold_map(A, B, f * DT)
    phi_r, gam_r = ref.hold_map(A, B, (1.0 - f) * DT)
    phi, g0, g1 = phi_r @ phi_f, gam_r, phi_r @ gam_f
    # u_ref[n] = F s[n] + H [lx, lv, 1]
    F = np.zeros(n)
    F[:m] = p.K * p.C
    F[m] = -up.kg * up.Tg - up.kv
    F[m + 1] = -up.kg
    H = np.array([up.kg, up.kv, -up.kg * up.Gmin])
    size = n + i + 1  # state, then the delay line u_ref[n-1] .. u_ref[n-i-1]
    M = np.zeros((size, size))
    N = np.zeros((size, 3))
    M[:n, :n] = phi
    if i == 0:
        M[:n, :n] += np.outer(g0, F)
        N[:n] += np.outer(g0, H)
    else:
        M[:n, n + i - 1] += g0
    M[:n, n + i] += g1
    M[n, :n] = F
    N[n] = H
    for k in range(1, i + 1):
        M[n + k, n + k - 1] = 1.0
    C = np.zeros((1, size))
    C[0, :m] = p.C
    out = []
    for j in range(3):
        b, a = scipy.signal.ss2tf(M, N, C, np.zeros((1, 3)), input=j)
        out.append((b[0], a))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=2_000_000)
    ap.add_argument("--ref-samples", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--population", type=int, default=256)
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args()
    T, TR, rep = args.samples, args.ref_samples, args.repeat

    print(f"avll {avll.__version__}; numpy {np.__version__}; scipy {scipy.__version__}")
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs")
    print(f"series: {T:,} samples (reference: {TR:,}); best of {rep}; dt = {DT} s\n")

    rng = np.random.default_rng(1)
    u = np.convolve(rng.normal(size=T), np.ones(10) / 10, mode="same")
    lx, lv = leader(T)
    up = avll.UpperLevel(kg=0.5, kv=0.0, Tg=2.0, Gmin=9.5)

    rows = []
    for name, model in avll.PAPER_TABLE_II.items():
        # -- open loop
        t_rust = best(lambda m=model: avll.simulate(m, u, DT), rep)
        b, a = ref.discrete_transfer_function(model, DT)
        t_lf = best(lambda b=b, a=a: scipy.signal.lfilter(b, a, u), rep)
        y_rust = avll.simulate(model, u, DT)
        y_lf = scipy.signal.lfilter(b, a, u)
        diff = np.max(np.abs(y_rust - y_lf)) / np.max(np.abs(y_lf))
        t_ref = best(lambda m=model: ref.simulate(m, u[:TR], DT), 1)
        rows.append((name, "open", T / t_rust, T / t_lf, TR / t_ref, diff))

        # -- closed loop
        t_rust = best(
            lambda m=model: avll.closed_loop(m, lx, lv, DT, up, v0=lv[0], x0=lx[0] - 40.0), rep
        )
        filt = closed_loop_filters(model, up)
        ones = np.ones(T)

        def lfilter_closed(filt=filt, ones=ones) -> np.ndarray:
            inputs = (lx, lv, ones)
            return sum(
                scipy.signal.lfilter(b, a, s) for (b, a), s in zip(filt, inputs, strict=True)
            )

        t_lf = best(lfilter_closed, rep)
        a_rust = avll.closed_loop(model, lx, lv, DT, up, v0=0.0, x0=0.0).a
        a_lf = lfilter_closed()
        k = min(T, 200_000)  # the check: same numbers from the same (zero) initial state
        diff = np.max(np.abs(a_rust[:k] - a_lf[:k])) / np.max(np.abs(a_lf[:k]))
        t_ref = best(
            lambda m=model: ref.closed_loop(m, lx[:TR], lv[:TR], DT, up, v0=lv[0], x0=lx[0] - 40.0),
            1,
        )
        rows.append((name, "closed", T / t_rust, T / t_lf, TR / t_ref, diff))

    # closed loop at the paper's run length (cache-resident): many short calls
    n_short, calls = 5400, 200
    m = avll.PAPER_TABLE_II["proposed"]
    t_short = best(
        lambda: [
            avll.closed_loop(m, lx[:n_short], lv[:n_short], DT, up, v0=lv[0], x0=lx[0] - 40.0)
            for _ in range(calls)
        ],
        rep,
    )

    hdr = (
        f"{'model':<9}{'loop':<8}{'avll M/s':>10}{'lfilter M/s':>13}{'reference M/s':>15}"
        f"{'avll/lfilter':>14}{'avll/ref':>10}{'max rel diff':>14}"
    )
    print("Model-steps per second per core (CPU time)")
    print(hdr)
    print("-" * len(hdr))
    for name, kind, r, lf, rf, diff in rows:
        print(
            f"{name:<9}{kind:<8}{r / 1e6:>10.1f}{lf / 1e6:>13.1f}{rf / 1e6:>15.3f}"
            f"{r / lf:>13.2f}x{r / rf:>9.0f}x{diff:>14.1e}"
        )

    print(
        f"\nproposed closed_loop on {n_short}-sample runs ({calls} calls, arrays stay in "
        f"cache): {calls * n_short / t_short / 1e6:.1f} M steps/s"
    )

    # -- batch cost (the GA's objective)
    n_run = 5400
    runs = []
    for j in range(args.runs):
        uj = np.convolve(rng.normal(size=n_run), np.ones(10) / 10, mode="same")
        aj = avll.simulate(avll.PAPER_TABLE_II["proposed"], uj, DT) + rng.normal(
            scale=0.05, size=n_run
        )
        runs.append(avll.Run(f"r{j}", np.arange(n_run) * DT, a=aj, command=uj))
    lxr, lvr = leader(n_run, seed=5)
    closed_runs = []
    for j in range(args.runs):
        tr = avll.closed_loop(
            avll.PAPER_TABLE_II["proposed"],
            lxr,
            lvr,
            DT,
            up,
            v0=float(lvr[0]),
            x0=float(lxr[0]) - 40.0,
        )
        closed_runs.append(
            avll.Run(
                f"c{j}",
                np.arange(n_run) * DT,
                a=tr.a + rng.normal(scale=0.05, size=n_run),
                v=tr.v,
                x=tr.x,
                lead_x=lxr,
                lead_v=lvr,
                upper=up,
            )
        )
    base = avll.PAPER_TABLE_II["proposed"].to_array()
    params = base * rng.uniform(0.8, 1.2, size=(args.population, base.size))
    steps = args.population * args.runs * n_run
    print(
        f"\nbatch_cost, proposed model: {args.population} rows x {args.runs} runs x "
        f"{n_run} samples = {steps / 1e6:.1f} M model-steps per call"
    )
    for label, rs, closed in (("open loop", runs, False), ("closed loop", closed_runs, True)):
        res = {}
        for threads in (1, 2):

            def call(th: int = threads, rs: list[avll.Run] = rs, c: bool = closed) -> None:
                avll.batch_cost("proposed", params, rs, closed_loop=c, threads=th)

            cpu = best(call, rep)
            wall = WALL[id(call)]
            res[threads] = wall
            print(
                f"  {label:<12} threads={threads}: per core {steps / cpu / 1e6:6.1f} M steps/s "
                f"(CPU {cpu * 1e3:6.1f} ms); wall {wall * 1e3:6.1f} ms = "
                f"{steps / wall / 1e6:6.1f} M steps/s, "
                f"{args.population * args.runs / wall:>7,.0f} run-evaluations/s"
            )
        print(f"  {label:<12} wall-clock speed-up 2 threads / 1 thread: {res[1] / res[2]:.2f}x")


if __name__ == "__main__":
    main()
