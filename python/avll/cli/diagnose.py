"""``avll diagnose``: the residual diagnosis and the cross-validated add-effect loop
(:func:`avll.diagnose.effect_loop`) on measured or synthetic runs. Registration imports
nothing heavy. The command's contract (scripts depend on it)::

    avll diagnose DATA --command-kind ... --model ... --cal-runs ... [--val-runs ...]
        [--test-runs ...] --seed N --json OUT.json [--report DIR]
"""

from __future__ import annotations

import argparse
import itertools
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..diagnose.defaults import MAX_EFFECTS, MIN_GAIN
from ._common import (
    add_astazero_options,
    add_command_kind,
    add_format,
    add_ga_budget,
    add_json,
    add_model,
    add_progress,
    add_seed,
    add_threads,
    astazero_options,
    check_informative,
    declare_io,
    parse_list,
    select_runs,
)

if TYPE_CHECKING:  # pragma: no cover
    from ..data import Run

__all__ = ["HELP", "register"]

#: The one-line help of ``avll diagnose`` in ``avll --help``.
HELP = "residual diagnosis and the cross-validated add-effect loop"

_DESCRIPTION = (
    "Fit the base model on the calibration runs, rank the library's effects by the "
    "residual, accept an effect only when cross-validation over the calibration runs says "
    "so (see docs/guide/diagnose.md), report validation and test runs, and say what the "
    "residual still depends on. Run selections are comma-separated run ids or glob "
    "patterns ('data5/*'); the three selections must be disjoint."
)

#: The three run selections: option, argparse dest, help.
_SPLITS = (
    ("--cal-runs", "cal_runs", "calibration runs, used for fitting and the "
     "cross-validated selection (required; no default)"),
    ("--val-runs", "val_runs", "validation runs, only reported (default: every run not "
     "in --cal-runs or --test-runs)"),
    ("--test-runs", "test_runs", "test runs, simulated only once the loop has ended "
     "(default: none)"),
)


def _pick(opt: str, text: str | None, runs: Sequence[Run]) -> list[Run]:
    """The runs ``text`` selects, in the file's order; a ``ValueError`` naming ``opt``
    for an unknown id or a pattern matching nothing."""
    if text is None:
        return []
    known = [r.run_id for r in runs]
    ids = select_runs(known, text, opt)
    missing = [i for i in ids if i not in known]
    if missing:
        shown = ", ".join(known[:20]) + (", ..." if len(known) > 20 else "")
        raise ValueError(f"{opt}: unknown run(s) {', '.join(missing)}; known: {shown}")
    chosen = set(ids)
    return [r for r in runs if r.run_id in chosen]


def _cmd(args: argparse.Namespace) -> int:
    import numpy as np

    from .. import _atomic
    from ..diagnose.loop import effect_loop
    from ..diagnose.report import write_report
    from ..io import read_runs

    cands = None
    if args.candidates is not None:
        from ..effects import EFFECTS

        cands = parse_list("--candidates", args.candidates)
        unknown = [c for c in cands if c not in EFFECTS]
        if unknown:
            raise ValueError(f"--candidates: unknown effect(s) {', '.join(unknown)}; known: "
                             f"{', '.join(EFFECTS)}")
    runs = read_runs(args.data, command_kind=args.command_kind, format=args.format,
                     **astazero_options(args))  # fmt: skip
    cal = _pick("--cal-runs", args.cal_runs, runs)
    check_informative(cal, args.data, "diagnose")
    test = _pick("--test-runs", args.test_runs, runs)
    splits = {"--cal-runs": cal, "--test-runs": test}
    if args.val_runs is not None:
        val = splits["--val-runs"] = _pick("--val-runs", args.val_runs, runs)
    else:
        taken = {r.run_id for r in (*cal, *test)}
        val = [r for r in runs if r.run_id not in taken]
    for a, b in itertools.combinations(splits, 2):
        both = sorted({r.run_id for r in splits[a]} & {r.run_id for r in splits[b]})
        if both:
            raise ValueError(f"{b}: run(s) {', '.join(both)} are also in {a}; the "
                             "selections must be disjoint")
    res = effect_loop(args.model, cal, val, test_runs=test, seed=args.seed, init=args.init,
                      folds=args.folds, min_gain=args.min_gain,
                      max_effects=args.max_effects, max_generations=args.max_generations,
                      starts=args.starts, candidates=cands, threads=args.threads,
                      progress=args.progress)  # fmt: skip
    d = res.to_dict()
    _atomic.write_json(args.json, _atomic.json_safe(d))
    if args.report:
        speeds = [float(np.mean(r.v)) for r in cal if r.v is not None]
        write_report(res, args.report, v0=float(np.mean(speeds)) if speeds else None)
    added = ", ".join(d["effects"]) or "none"
    extra = (f"; {len(d['flags'])} flag(s): " + "; ".join(f["kind"] for f in d["flags"])
             if d["flags"] else "")
    print(f"effects added: {added}{extra}; JSON written to {args.json}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll diagnose`` (imports nothing heavy)."""
    p = sub.add_parser("diagnose", help=HELP, description=_DESCRIPTION)
    p.add_argument("data", help="runs file or folder in the --format (required)")
    add_format(p)
    add_command_kind(p)
    add_model(p, "proposed", "base model the effects are added to")
    for opt, dest, text in _SPLITS:
        p.add_argument(opt, dest=dest, required=dest == "cal_runs", default=None,
                       metavar="IDS", help=text)
    p.add_argument("--folds", type=int, default=None,
                   help="cross-validation folds (default: min(5, calibration runs); 3 "
                   "contiguous blocks of a single calibration run)")
    p.add_argument("--min-gain", type=float, default=MIN_GAIN,
                   help="minimum relative reduction of the out-of-fold MSE to accept an "
                   f"effect (default: {MIN_GAIN})")
    p.add_argument("--max-effects", type=int, default=MAX_EFFECTS,
                   help=f"at most this many effects (default: {MAX_EFFECTS})")
    add_ga_budget(p, what="every fit")
    p.add_argument("--candidates", default=None, metavar="E[,E...]",
                   help="effects offered, comma-separated (default: every registered "
                   "effect that applies to the data)")
    add_seed(p, "fits and of the folds")
    add_threads(p)
    add_json(p, "the loop's result (base_model, steps, effects, final_model, ...)",
             required=True)
    p.add_argument("--report", default=None, metavar="DIR",
                   help="folder for a Markdown/HTML report with figures (default: not "
                   "written)")
    p.add_argument("--init", choices=("auto", "rest", "steady"), default="auto",
                   help="initial state of the rollouts: steady for a speed command, rest "
                   "otherwise when auto (default: auto)")
    add_progress(p)
    add_astazero_options(p)
    declare_io(p, inputs=("data",), files=("json",), folders=("report",))
    p.set_defaults(func=_cmd)
