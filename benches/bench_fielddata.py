"""Field-data studies (issue 5): runs :func:`avll.studies.fielddata.carma_study` and
:func:`avll.studies.fielddata.astazero_study` on ``../shared/data`` and saves their tables
(CSV), figures (PNG), ``*_summary.json`` and ``*_report.txt`` to ``--out``
(default ``out/fielddata``, git-ignored). Prints the wall times, the average
calibration and validation MSE per model, and the closed-loop amplification of the
speed oscillations (std of the follower's speed over std of its predecessor's,
measured vs simulated, after a 20 s high-pass).

``--budget`` also recalibrates with the GA's full default budget (300
generations, 2 starts) to show what the studies' reduced budget costs.

    MPLBACKEND=Agg python benches/bench_fielddata.py [--data ../shared/data] [--out DIR]
        [--seed N] [--budget]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from avll.models import UpperLevel
from avll.rollout import closed_loop
from avll.studies.fielddata import _UPPER, _model, astazero_study, carma_study


def _avg(st, key: str) -> None:
    for which in ("cal", "val"):
        t = st.tables[f"{which}_{key}"]
        print(f"  {which} {key}: " + ", ".join(f"{i} {v:.4g}" for i, v in t["Average"].items()))


def _hp(x: np.ndarray, n: int = 200) -> np.ndarray:
    """High-pass: minus the centred moving average over ``n`` samples (20 s)."""
    return x - np.convolve(x, np.ones(n) / n, mode="same")


def _amplification(st) -> None:
    """Oscillation amplification per car: std of the high-passed (20 s) speed of the
    follower over that of its predecessor (edges of 20 s left out)."""
    fits = st.summary["studies"]["mixed"]["models"]
    runs = st.runs["pairs"]
    print("  oscillation amplification std(hp v)/std(hp v_lead), 20 s high-pass")
    print("  (measured | simulated first, second, proposed; fitted on 'mixed')")
    for r in runs:
        pair = r.run_id.split("/")[-1]
        sl = slice(200, len(r) - 200)
        ref = np.std(_hp(r.lead_v)[sl])
        meas = np.std(_hp(r.v)[sl]) / ref
        sims = []
        for m, e in fits.items():
            p = e["params"][pair]
            tr = closed_loop(_model(m, p), r.lead_x, r.lead_v, r.dt,
                             UpperLevel(*(p[k] for k in _UPPER)), v0=float(r.v[0]),
                             x0=float(r.x[0]))  # fmt: skip
            sims.append(np.std(_hp(tr.v)[sl]) / ref)
        print(f"  {r.run_id:32s} {meas:.3f} | " + ", ".join(f"{s:.3f}" for s in sims))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--out", default="out/fielddata")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--budget", action="store_true")
    a = ap.parse_args()
    data = Path(a.data)

    st = carma_study(data / "carma", seed=a.seed, out=a.out)
    print(f"CARMA study: {st.seconds:.1f} s (budget {st.summary['ga']})")
    for rg in ("cruise", "launch"):
        for obj, m in (("acceleration", "a"), ("speed", "v"), ("acceleration", "v")):
            _avg(st, f"{rg}_{obj}_{m}")
    if a.budget:
        t0 = time.perf_counter()
        full = carma_study(data / "carma", seed=a.seed, regimes=("cruise",), figures=False,
                           max_generations=300, stall_generations=20, starts=2)  # fmt: skip
        print(f"CARMA cruise, full GA budget: {time.perf_counter() - t0:.1f} s")
        for obj, m in (("acceleration", "a"), ("speed", "v")):
            _avg(full, f"cruise_{obj}_{m}")

    sa = astazero_study(data / "openacc-astazero" / "platoon", seed=a.seed, out=a.out)
    print(f"AstaZero study: {sa.seconds:.1f} s (budget {sa.summary['ga']})")
    for obj in ("acceleration", "mixed"):
        for m in ("a", "v", "x"):
            _avg(sa, f"{obj}_{m}")
    _amplification(sa)
    if a.budget:
        t0 = time.perf_counter()
        full = astazero_study(data / "openacc-astazero" / "platoon", seed=a.seed,
                              objectives=("mixed",), baseline=False, figures=False,
                              max_generations=300, stall_generations=20, starts=2)  # fmt: skip
        print(f"AstaZero mixed, full GA budget: {time.perf_counter() - t0:.1f} s")
        for m in ("a", "v", "x"):
            _avg(full, f"mixed_{m}")
    print(f"saved to {a.out}")


if __name__ == "__main__":
    main()
