"""Throughput of the effects engine against the linear rollout and the numpy
reference (one process, one thread each; prints numbers and ratios)."""

from __future__ import annotations

import time

import numpy as np

import avll
from avll.effects import (
    Asymmetric,
    Deadband,
    Delay,
    Grade,
    RateLimit,
    Saturation,
    SpeedDrag,
    WithEffects,
)
from avll.reference.effects import rollout_effects


def _best(f, reps: int = 5) -> float:
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return min(ts)


def main() -> None:
    dt, n = 0.05, 200_000
    t = np.arange(n) * dt
    u = 1.4 * np.sin(0.35 * t) + 0.6 * np.sin(1.3 * t)
    g = 0.03 * np.sin(0.01 * t)
    base = avll.PAPER_TABLE_II["proposed"]
    effects = (Delay(0.2), RateLimit(2.0), Deadband(0.05), Asymmetric(0.8, 1.3),
               Saturation(1.5, 2.0), SpeedDrag(0.05, 0.001), Grade(9.0))  # fmt: skip
    allfx = WithEffects(base, effects)
    t_lin = _best(lambda: avll.simulate_full(base, u, dt))
    t_none = _best(lambda: avll.simulate_full(WithEffects(base, ()), u, dt))
    t_all = _best(lambda: avll.simulate_full(allfx, u, dt, exo={"grade": g}))
    m = 3000
    t_ref = _best(lambda: rollout_effects(allfx, dt, command=u[:m], exo={"grade": g[:m]}), 1)
    print(f"linear simulate_full     {n / t_lin / 1e6:8.1f} M steps/s")
    print(f"engine, no effect        {n / t_none / 1e6:8.1f} M steps/s  ({t_none / t_lin:.2f}x)")
    print(f"engine, all 7 effects    {n / t_all / 1e6:8.1f} M steps/s  ({t_all / t_lin:.2f}x)")
    print(f"numpy reference, all 7   {m / t_ref / 1e6:8.4f} M steps/s  "
          f"(engine {t_ref / m / (t_all / n):.0f}x faster)")  # fmt: skip
    runs = [avll.Run(run_id=str(k), t=t[:3600], a=u[:3600], command=u[:3600],
                     exo={"grade": g[:3600]}) for k in range(3)]  # fmt: skip
    steps = 256 * 3 * 3600
    base_rows = np.repeat(base.to_array()[None, :], 256, axis=0)
    t_lb = _best(lambda: avll.batch_cost("proposed", base_rows, runs, threads=1), 3)
    t_eb = _best(lambda: avll.batch_cost("proposed", base_rows, runs, effects=[], threads=1), 3)
    print(f"batched cost, linear      {steps / t_lb / 1e6:8.1f} M steps/s (1 thread)")
    print(f"batched cost, no effect   {steps / t_eb / 1e6:8.1f} M steps/s ({t_eb / t_lb:.2f}x)")
    rows = np.repeat(allfx.to_array()[None, :], 256, axis=0)
    names = list(allfx.effect_names)
    for th in (1, 2):
        tb = _best(lambda th=th: avll.batch_cost("proposed", rows, runs, effects=names,
                                                 threads=th), 3)
        print(f"batched cost, all 7, {th} thread(s) {steps / tb / 1e6:8.1f} M steps/s")


if __name__ == "__main__":
    main()
