"""The cross-validated residual loop on the OpenACC data: AstaZero per
predecessor->follower pair and ZalaZone per car, closed loop behind the recorded
predecessor with the upper-level law calibrated alongside (``avll diagnose`` on these
files does the same), each with a three-way split:

* **AstaZero** (``openacc-astazero``, road grade from ``Slope.csv``): calibration on
  platoon 7 (one run: three contiguous block folds), validation on the first half of
  platoon 8, test on its second half. Platoon 8 is the same five cars in the same order
  on the same day, so the test half is new data of the same car, never seen by the fits
  or the selection.
* **ZalaZone** (native ``openacc`` files, folder ``short_setting``: every car on its
  short ACC setting): per car present in ``dynamic_part12``, ``dynamic_part14`` and
  ``handling_part1`` (the car, not its position, is matched through the files'
  metadata): calibration on the two ``dynamic`` runs (leave-one-run-out: "most folds"
  means both), validation on the first half of the ``handling`` run, test on its second
  half -- another manoeuvre type than the calibration.

Base model ``second`` (the paper's second order with dead time), GA budget
``--max-generations`` (default 100) with the default starts, at most two effects.
Writes one strict JSON per case into OUT and prints the table of every JSON present (a
partial run renders what finished; a missing case says "not run");
``python -m docs.gen --only loop-openacc`` writes it to ``docs/_generated/loop_openacc.md``.

    MPLBACKEND=Agg python -m avll.studies.loops.openacc [--data ../shared/data] [--out OUT]
        [--max-generations 100] [--only astazero,zalazone] [--render-only]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from avll import _atomic
from avll.data import Run
from avll.diagnose import effect_loop
from avll.io import read_runs

from .table import HEADER, LEGEND, row, summary

BASE = "second"
PAIRS = ("v1-v2", "v2-v3", "v3-v4", "v4-v5")
ZALA_CAL = ("dynamic_part12", "dynamic_part14")
ZALA_TEST = "handling_part1"


def _halves(r: Run) -> tuple[Run, Run]:
    h = len(r) // 2
    return r.cut(0, h, f"[0:{h}]"), r.cut(h, len(r), f"[{h}:{len(r)}]")


def astazero_cases(data: Path) -> dict[str, tuple[list[Run], list[Run], list[Run]]]:
    """Pair -> (calibration, validation, test) runs."""
    plat = data / "openacc-astazero" / "platoon"
    days = {k: {r.run_id.split("/")[1]: r for r in read_runs(
        plat / f"ASta_040719_platoon{k}.csv", format="openacc-astazero",
        command_kind="acceleration")} for k in ("7", "8")}  # fmt: skip
    out = {}
    for pair in PAIRS:
        val, test = _halves(days["8"][pair])
        out[f"astazero {pair}"] = ([days["7"][pair]], [val], [test])
    return out


def zalazone_cases(data: Path) -> dict[str, tuple[list[Run], list[Run], list[Run]]]:
    """Car -> (calibration, validation, test) runs."""
    runs = read_runs(data / "openacc-zalazone" / "short_setting", format="openacc")
    by: dict[str, dict[str, Run]] = {}
    for r in runs:
        if r.meta.get("acc"):
            by.setdefault(str(r.meta["car"]), {})[r.run_id.split("/")[0]] = r
    out = {}
    for car in sorted(by):
        files = by[car]
        if all(f in files for f in (*ZALA_CAL, ZALA_TEST)):
            val, test = _halves(files[ZALA_TEST])
            out[f"zalazone {car}"] = ([files[f] for f in ZALA_CAL], [val], [test])
    return out


def _file(out: Path, case: str) -> Path:
    return out / (case.replace(" ", "_") + ".json")


def render(out: Path, cases: list[str], meta: dict[str, Any]) -> str:
    """The Markdown tables of every case's JSON in ``out``."""
    head = [
        f"Base `{BASE}`, closed loop with the upper-level law calibrated, GA "
        f"{meta.get('max_generations', '?')} generations per start, at most two effects, "
        "seed 0.",
        "",
        "AstaZero: calibration on platoon 7 (three block folds), validation on the first "
        "half of platoon 8, test on its second half. ZalaZone (short setting): calibration "
        f"on {' + '.join(ZALA_CAL)} (leave-one-run-out), validation on the first half of "
        f"{ZALA_TEST}, test on its second half. " + LEGEND,
        "",
        f"| case | {HEADER} | time (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    rows, done = [], {}
    for case in cases:
        p = _file(out, case)
        if not p.exists():
            rows.append(f"| {case} | not run | | | | | | |")
            continue
        d = done[case] = json.loads(p.read_text())
        rows.append(f"| {case} | {row(d)} | {d.get('seconds', '—')} |")
    return "\n".join(head + rows + ["", summary(done)]) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Runs the loop per case (skipping cases whose JSON exists) and renders."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="../shared/data")
    ap.add_argument("--out", default="out/loop_openacc")
    ap.add_argument("--max-generations", type=int, default=100,
                    help="GA generations per start of every fit (default: 100)")
    ap.add_argument("--only", default="astazero,zalazone")
    ap.add_argument("--render-only", action="store_true")
    a = ap.parse_args(argv)
    out, data = Path(a.out), Path(a.data)
    out.mkdir(parents=True, exist_ok=True)
    meta_path = out / "settings.json"
    cases: dict[str, tuple[list[Run], list[Run], list[Run]]] = {}
    only = set(a.only.split(","))
    if "astazero" in only:
        cases |= astazero_cases(data)
    if "zalazone" in only:
        cases |= zalazone_cases(data)
    if not a.render_only:
        _atomic.write_json(meta_path, {"max_generations": a.max_generations})
        for case, (cal, val, test) in cases.items():
            dest = _file(out, case)
            if dest.exists():
                continue
            t0 = time.perf_counter()
            res = effect_loop(BASE, cal, val, test_runs=test, seed=0,
                              max_generations=a.max_generations, max_effects=2,
                              progress=False)  # fmt: skip
            d = res.to_dict()
            d["seconds"] = round(time.perf_counter() - t0, 1)
            _atomic.write_json(dest, d)
            print(f"{case}: {d['effects'] or 'none'} ({d['seconds']} s)", flush=True)
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    print(render(out, list(cases), meta))
    return 0


if __name__ == "__main__":
    sys.exit(main())
