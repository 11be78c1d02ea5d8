"""``avll reproduce``: the paper end to end, with a report next to its numbers."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..report import num
from ._common import add_json, add_progress, add_seed, add_threads, declare_io

#: The default output folder (each command has its own).
DEFAULT_OUT = "avll-out/reproduce"


def _cmd(args: argparse.Namespace) -> int:
    from ..reproduce import SETTINGS, reproduce

    settings = SETTINGS["quick" if args.quick else "default"]
    if args.no_diagnosis:
        settings = replace(settings, diagnosis=False)
    s = reproduce(args.out, data=args.data, data_path=args.data_path, settings=settings,
                  seed=args.seed, threads=args.threads, progress=args.progress,
                  json_path=args.json)
    out = Path(args.out)
    print(f"report: {out / 'report.md'} and {out / 'report.html'}; summary: "
          f"{s['files']['summary_json']} ({s['timing_s']['total']:.0f} s)")

    def q(x: Any, spec: str, unit: str) -> str:  # "none" without a unit
        v = num(x, spec, "none")
        return v if v == "none" else f"{v} {unit}"

    for m in ("proposed", "second", "first"):
        c, st = s["calibration"][m], s["stability"][m]
        print(f"  {m:9s} cal {num(c['cal_mse'], '.4g', 'none')} "
              f"val {num(c['val_mse'], '.4g', 'none')} | "
              f"Table II: kv* {q(st['kv_threshold'], '.4g', '1/s')}, min Tg "
              f"{q(st['min_tg'], '.1f', 's')}, capacity {q(st['capacity'], '.1f', 'veh/h')}")
    print("  (kv* none: no kv threshold within the grid)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll reproduce``."""
    p = sub.add_parser(
        "reproduce",
        help="the paper end to end (Tables II-IV, Figs. 3-8, Section IV) with a report",
        description="Generate the synthetic 21-run experiment (or load measured data), "
        "calibrate and validate the three models, compute the stability maps and "
        "thresholds with Table II's and the calibrated parameters, run the residual "
        "loop, and write report.md/report.html/summary.json with the paper's numbers "
        "side by side.",
    )
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output folder (default: {DEFAULT_OUT})")
    add_json(p, "the summary", default="OUT/summary.json")
    p.add_argument("--data", default="synthetic",
                   choices=("synthetic", "carma", "openacc-astazero"),
                   help="the built-in synthetic experiment or measured data (default: "
                   "synthetic)")
    p.add_argument("--data-path", default=None, metavar="DIR",
                   help="folder of the measured data (default: ../shared/data/<data>)")
    add_seed(p, "synthetic data and the GA")
    add_threads(p)
    p.add_argument("--quick", action="store_true",
                   help="coarse grids and a small GA, seconds; numbers not meaningful "
                   "(default: off, the full budgets)")
    p.add_argument("--no-diagnosis", action="store_true",
                   help="skip the residual loop (default: off, the loop runs)")
    add_progress(p)
    declare_io(p, inputs=("data_path",), files=("json",), folders=("out",))
    p.set_defaults(func=_cmd)
