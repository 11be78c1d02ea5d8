"""The cross-validated residual loop on CARMA (speed command), per vehicle, with a
three-way split. Cruise stretches only (the launches are another
regime, see the field-data guide): calibration on data5 and data9 (two runs: leave-one-
run-out, so "most folds" means both), validation on data6 (reported only), test on
data10 (simulated only after the loop). Base model: second order (the paper's models do
not transfer to a speed command; the second-order one fits least badly). Writes one
strict JSON per vehicle into OUT and prints the table of every JSON present (so a
partial run still renders what finished); ``python -m docs.gen --only loop-carma``
writes it to ``docs/_generated/loop_carma.md``.

    MPLBACKEND=Agg python -m avll.studies.loops.carma [--data ../shared/data/carma]
        [--out OUT]        [--max-generations 150] [--vehicles leader,follower1,...] [--render-only]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import avll
from avll import _atomic
from avll.diagnose import effect_loop
from avll.studies.fielddata import read_carma, split_launch_cruise

from .table import HEADER, LEGEND, row, summary

VEHICLES = ("leader", "follower1", "follower2", "follower3", "follower4")
SPLIT = {"cal": ("data5", "data9"), "val": ("data6",), "test": ("data10",)}


def render(out: Path) -> str:
    """The Markdown table of every vehicle's JSON in ``out``."""
    rows, done = [], {}
    for veh in VEHICLES:
        p = out / f"carma_{veh}.json"
        if not p.exists():
            rows.append(f"| {veh} | not run | | | | | |")
            continue
        d = done[veh] = json.loads(p.read_text())
        rows.append(f"| {veh} | {row(d)} |")
    head = [
        "CARMA cruise stretches, speed command, base `second`; calibration (fitting and "
        "the cross-validated selection) on data5 + data9 (leave-one-run-out folds), "
        "validation on data6, test on data10. " + LEGEND,
        "",
        f"| vehicle | {HEADER} |",
        "|---|---|---|---|---|---|---|",
    ]
    return "\n".join(head + rows + ["", summary(done)]) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Runs the loop per vehicle (skipping vehicles whose JSON exists) and renders."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="../shared/data/carma")
    ap.add_argument("--out", default="out/loop_carma")
    ap.add_argument("--max-generations", type=int, default=150, help="GA generations per fit")
    ap.add_argument("--vehicles", default=",".join(VEHICLES))
    ap.add_argument("--render-only", action="store_true")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if not a.render_only:
        _, cruise = split_launch_cruise(read_carma(a.data))
        for veh in [v for v in a.vehicles.split(",") if v]:
            dest = out / f"carma_{veh}.json"
            if dest.exists():
                continue

            def pick(files: tuple[str, ...], veh: str = veh) -> list[avll.Run]:
                return [r for r in cruise if r.run_id.split("/")[1] == veh
                        and r.run_id.split("/")[0] in files]  # fmt: skip

            t0 = time.perf_counter()
            res = effect_loop("second", pick(SPLIT["cal"]), pick(SPLIT["val"]),
                              test_runs=pick(SPLIT["test"]), seed=0,
                              max_generations=a.max_generations, max_effects=2,
                              progress=False)  # fmt: skip
            d = res.to_dict()
            d["seconds"] = round(time.perf_counter() - t0, 1)
            _atomic.write_json(dest, _atomic.json_safe(d))
            print(f"{veh}: {d['effects']} ({d['seconds']} s)", flush=True)
    print(render(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
