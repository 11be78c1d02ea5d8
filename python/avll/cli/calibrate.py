"""``avll calibrate``: calibrate lower-level models on runs and validate them (the
paper's Tables II-IV)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from typing import Any

from .._limits import check_weights
from ..defaults import CLOSED_LOOP_WEIGHTS, EQ6_WEIGHTS
from ..paper import MODELS
from ._common import (
    add_astazero_options,
    add_cal_runs,
    add_command_kind,
    add_format,
    add_ga_budget,
    add_json,
    add_models,
    add_progress,
    add_seed,
    add_threads,
    astazero_options,
    check_informative,
    declare_io,
    models_of,
    parse_list,
    select_runs,
)


def load_runs(args: argparse.Namespace) -> tuple[list[Any], bool, list[str], str]:
    """Runs, closed loop, free upper gains and initial state for ``avll calibrate``.

    * ``--format carma`` also reads a folder of CARMA files; ``--regime`` keeps the
      launch or cruise parts (:func:`avll.studies.fielddata.split_launch_cruise`).
    * Mixed command kinds (the OpenACC folder: platoon pairs without a command and
      free-flow runs with a set speed) keep the kind given by ``--command-kind``, or
      else the closed-loop pairs (a note on stderr says so).
    * Runs without a command but with a leader run in closed loop; runs without an
      upper law get a placeholder and all four gains are calibrated (unless
      ``--upper-free`` says otherwise).
    * ``--init`` defaults to ``steady`` for the field-data formats (stretches cut out
      of longer drives) and ``rest`` otherwise.
    """
    from pathlib import Path

    from ..defaults import UPPER_NAMES, UPPER_PLACEHOLDER
    from ..io import read_runs
    from ..studies.fielddata import read_carma, split_launch_cruise

    fmt = args.format
    opts = astazero_options(args)
    if fmt == "carma" and Path(args.data).is_dir():
        runs = read_carma(args.data, command_kind=args.command_kind)
    else:
        runs = read_runs(args.data, command_kind=args.command_kind, format=fmt, **opts)
    if args.regime != "all":
        if fmt != "carma":
            raise ValueError("--regime: only for --format carma")
        launch, cruise = split_launch_cruise(runs)
        runs = launch if args.regime == "launch" else cruise
        if not runs:
            raise ValueError(f"--regime: no {args.regime} stretches in {args.data}")
    kinds = {r.command_kind for r in runs}
    if len(kinds) > 1:
        keep = [r for r in runs if r.command is None and r.lead_x is not None]
        if not keep:
            raise ValueError(
                f"{args.data}: mixed command kinds {sorted(kinds)}; pass --command-kind"
            )
        print(f"avll calibrate: {args.data} mixes command kinds; calibrating the "
              f"{len(keep)} closed-loop pairs (pass --command-kind speed for the others)",
              file=sys.stderr)  # fmt: skip
        runs = keep
    no_cmd = [r for r in runs if r.command is None]
    closed = bool(args.closed_loop) or bool(no_cmd)
    if no_cmd and len(no_cmd) != len(runs):
        raise ValueError(f"run {no_cmd[0].run_id!r}: has no command while other runs have one")
    if closed:
        bad = [r for r in runs if r.lead_x is None or r.lead_v is None]
        if bad:
            why = ("has no command and no leader (lead_x, lead_v): cannot calibrate it"
                   if no_cmd else "has no leader (lead_x, lead_v), which --closed-loop "
                   "needs; without --closed-loop it calibrates in open loop")
            raise ValueError(f"{args.data}: run {bad[0].run_id!r}: {why}")
    if args.upper_free is None:
        free = list(UPPER_NAMES) if closed and any(r.upper is None for r in runs) else []
    elif args.upper_free == "none":
        free = []
    else:
        free = parse_list("--upper-free", args.upper_free)
        for u in free:
            if u not in UPPER_NAMES:
                raise ValueError(f"--upper-free: unknown gain {u!r}; known: "
                                 f"{', '.join(UPPER_NAMES)}")
    if closed:
        missing = [r for r in runs if r.upper is None]
        if missing and len(free) < 4:
            raise ValueError(
                f"run {missing[0].run_id!r}: has no upper-level law; --upper-free must "
                "free all of kg,kv,Tg,Gmin"
            )
        runs = [r if r.upper is not None else replace(r, upper=UPPER_PLACEHOLDER)
                for r in runs]
    init = args.init or ("steady" if fmt in ("carma", "openacc-astazero", "openacc") else "rest")
    check_informative(runs, args.data)
    return runs, closed, free, init


def _csv(weights: tuple[float, float, float]) -> str:
    return ",".join(f"{w:g}" for w in weights)


def _weights(text: str) -> tuple[float, float, float]:
    try:
        weights = [float(w) for w in parse_list("--weights", text)]
    except ValueError:
        raise ValueError(f"--weights: expected three numbers, got {text!r}") from None
    return check_weights(weights, "--weights")


def _cmd(args: argparse.Namespace) -> int:
    from .. import _atomic
    from ..calibration import paper_workflow

    models = models_of(args)
    weights = None if args.weights is None else _weights(args.weights)
    runs, closed, free, init = load_runs(args)
    ids = [r.run_id for r in runs]
    if args.figure_run is not None and args.figure_run not in ids:
        more = ", ..." if len(ids) > 5 else ""
        raise ValueError(f"--figure-run: unknown run {args.figure_run!r}; known: "
                         f"{', '.join(ids[:5])}{more}")
    cal_runs: Any = args.cal_runs
    if cal_runs not in (None, "paper"):
        cal_runs = select_runs(ids, cal_runs)
    wf = paper_workflow(
        runs, cal_runs=cal_runs, models=models, seed=args.seed, threads=args.threads,
        progress=args.progress, closed_loop=closed, upper_free=free, init=init,
        weights=weights, starts=args.starts,
        max_generations=args.max_generations, pop_size=args.pop_size,
    )  # fmt: skip
    text = wf.to_text()  # names the weights when they are not Eq. 6's
    loop = f"closed loop, free upper gains {','.join(free) or 'none'}" if closed else "open loop"
    print(f"{len(runs)} runs, {loop}, init {init}")
    print(text)
    if args.json:
        _atomic.write_json(args.json, _atomic.json_safe(wf.to_json()))
    if args.figure:
        rid = args.figure_run or wf.cal[0].run_id
        fig = wf.plot(rid)
        _atomic.savefig(fig, args.figure)
    # said by avll.cli once the output group has committed them
    args.wrote = [p for p in (args.json, args.figure) if p]
    if wf.interrupted:
        print("avll calibrate: interrupted; results are the best so far", file=sys.stderr)
        return 130
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll calibrate``."""
    p = sub.add_parser(
        "calibrate",
        help="calibrate lower-level models on runs and validate them (Tables II-IV)",
        description="Calibrate the lower-level models by the GA on the calibration runs "
        "(Eq. 6) and validate them on the other runs. Tables go to stdout, progress to "
        "stderr. Without --cal-runs, alternate runs calibrate (the 1st, 3rd, ... in file "
        "order) and the others validate; --cal-runs paper takes the paper's runs "
        "3,4,5,9,10,11,15,16,17,19.",
    )
    p.add_argument("data", metavar="DATA",
                   help="runs file or folder (canonical CSV/Parquet, or see --format)")
    add_format(p)
    add_command_kind(p)
    add_models(p, MODELS)
    add_cal_runs(p, "alternate runs", ", or 'paper'")
    add_seed(p)
    add_json(p, "the calibrated parameters and the MSE per run")
    add_threads(p)
    p.add_argument("--closed-loop", action="store_true",
                   help="drive the model by the leader through the upper law, Eq. 3 "
                   "(default: off, open loop; on when the runs have no command)")
    p.add_argument("--init", choices=("rest", "steady"), default=None,
                   help="initial state of each open-loop rollout (default: steady for "
                   "--format carma, openacc-astazero and openacc, whose runs are cut out of "
                   "longer drives; rest otherwise)")
    p.add_argument("--weights", default=None, metavar="WA,WV,WX",
                   help="weights of the acceleration, speed and position MSE (default: "
                   f"{_csv(EQ6_WEIGHTS)}, the paper's Eq. 6, in open loop; "
                   f"{_csv(CLOSED_LOOP_WEIGHTS)} in closed loop)")
    p.add_argument("--upper-free", default=None, metavar="GAINS",
                   help="closed loop: upper-level gains to calibrate, e.g. kg,kv,Tg,Gmin or "
                   "'none' (default: all four when the runs have no upper law, as OpenACC "
                   "pairs; none otherwise)")
    p.add_argument("--regime", choices=("all", "cruise", "launch"), default="all",
                   help="CARMA only: keep the launch or cruise parts of the stretches "
                   "(default: all)")
    add_astazero_options(p)
    add_ga_budget(p, pop_size=True)
    p.add_argument("--figure", default=None, metavar="PATH",
                   help="save measured vs simulated acceleration of one run; .png, .svg or .pdf "
                   "(default: not drawn)")
    p.add_argument("--figure-run", default=None, metavar="RUN",
                   help="run of --figure (default: the first calibration run)")
    add_progress(p)
    declare_io(p, inputs=("data",), files=("json", "figure"), figures=("figure",))
    p.set_defaults(func=_cmd)
