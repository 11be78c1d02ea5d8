"""The ``avll diagnose`` sub-command (registered by :func:`register_cli`)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from .defaults import MIN_GAIN

if TYPE_CHECKING:  # pragma: no cover
    from ..data import Run

__all__ = ["register_cli"]


def _ids(opt: str, text: str | None) -> list[str]:
    if text is None:
        return []
    ids = [s.strip() for s in text.split(",") if s.strip()]
    if not ids:
        raise ValueError(f"{opt}: no run ids in {text!r}")
    return ids


def _pick(opt: str, ids: list[str], runs: Sequence[Run]) -> list[Run]:
    known = {r.run_id for r in runs}
    missing = [i for i in ids if i not in known]
    if missing:
        raise ValueError(f"{opt}: unknown run(s) {missing}; known: {sorted(known)}")
    return [r for r in runs if r.run_id in ids]


def _cmd(args: argparse.Namespace) -> int:
    from .. import _atomic
    from ..io import read_runs
    from ..io.cli_load import astazero_options
    from ..models import model_class
    from .loop import effect_loop
    from .report import write_report

    model_class(args.model)
    cal_ids = _ids("--cal-runs", args.cal_runs)
    val_ids = _ids("--val-runs", args.val_runs)
    test_ids = _ids("--test-runs", args.test_runs)
    for a, la, b, lb in (("cal", cal_ids, "val", val_ids), ("cal", cal_ids, "test", test_ids),
                         ("val", val_ids, "test", test_ids)):  # fmt: skip
        both = sorted(set(la) & set(lb))
        if both:
            raise ValueError(f"--{b}-runs: run(s) {both} are also in --{a}-runs")
    cands = None
    if args.candidates is not None:
        cands = [s.strip() for s in args.candidates.split(",") if s.strip()]
    runs = read_runs(args.data, command_kind=args.command_kind, format=args.format,
                     **astazero_options(args))  # fmt: skip
    cal = _pick("--cal-runs", cal_ids, runs)
    test = _pick("--test-runs", test_ids, runs)
    if args.val_runs is not None:
        val = _pick("--val-runs", val_ids, runs)
    else:
        # Compatibility: every run not named for calibration or test validates.
        val = [r for r in runs if r.run_id not in cal_ids and r.run_id not in test_ids]
    res = effect_loop(args.model, cal, val, test_runs=test, seed=args.seed, init=args.init,
                      optimizer=args.optimizer, folds=args.folds, min_gain=args.min_gain,
                      max_effects=args.max_effects, maxiter=args.maxiter,
                      candidates=cands, progress=args.progress != "none")  # fmt: skip
    d = res.to_dict()
    _atomic.write_json(args.json, _atomic.json_safe(d), default=float)
    if args.report:
        speeds = [float(np.mean(r.v)) for r in cal if r.v is not None]
        write_report(res, args.report, v0=float(np.mean(speeds)) if speeds else None)
    names = ", ".join(d["effects"]) or "none"
    extra = f"; {len(d['flags'])} flag(s): " + "; ".join(f["kind"] for f in d["flags"]) \
        if d["flags"] else ""
    print(f"effects added: {names}{extra}; JSON written to {args.json}")
    return 0


def register_cli(sub: argparse._SubParsersAction) -> None:
    """Registers the ``diagnose`` sub-command with the ``avll`` parser."""
    p = sub.add_parser(
        "diagnose", help="residual diagnosis and the add-effect loop",
        description="Fit the base model on the calibration runs, rank the library's "
        "effects by the residual, accept an effect only when cross-validation over the "
        "calibration runs says so (see docs/guide/diagnose.md), report validation and "
        "test runs, and say what the residual still depends on.")  # fmt: skip
    p.add_argument("data", help="runs in the canonical format (CSV/Parquet) or --format")
    p.add_argument("--command-kind", choices=["acceleration", "speed"], default=None,
                   help="kind of the command column (default: from the data)")
    p.add_argument("--format", default="canonical",
                   help="data format (see `avll load`), default canonical")
    p.add_argument("--model", default="proposed",
                   help="base model: first|second|proposed (default proposed)")
    p.add_argument("--cal-runs", required=True,
                   help="comma-separated calibration run ids (fitting and selection)")
    p.add_argument("--val-runs", default=None,
                   help="comma-separated validation run ids, reported only (default: every "
                   "run not in --cal-runs or --test-runs)")
    p.add_argument("--test-runs", default=None,
                   help="comma-separated test run ids, simulated only at the end (default: "
                   "none)")
    p.add_argument("--folds", type=int, default=None,
                   help="cross-validation folds (default min(5, calibration runs); 3 blocks "
                   "of a single calibration run)")
    p.add_argument("--min-gain", type=float, default=MIN_GAIN,
                   help=f"minimum relative MSE reduction to accept an effect (default "
                   f"{MIN_GAIN})")
    p.add_argument("--max-effects", type=int, default=3, help="at most this many effects "
                   "(default 3)")
    p.add_argument("--maxiter", type=int, default=300,
                   help="GA generations of every fit (default 300)")
    p.add_argument("--candidates", default=None,
                   help="comma-separated effects offered (default: every registered effect "
                   "that applies)")
    p.add_argument("--seed", type=int, default=0, help="seed of the fits and folds (default 0)")
    p.add_argument("--json", required=True, help="output JSON file")
    p.add_argument("--report", default=None, help="folder for a Markdown/HTML report")
    p.add_argument("--init", choices=["auto", "rest", "steady"], default="auto",
                   help="initial state (auto: steady for a speed command, else rest)")
    p.add_argument("--optimizer", choices=["ga", "de"], default="ga",
                   help="calibration: the Rust GA (default) or scipy's differential evolution")
    from ..cli._common import add_progress
    from ..io.cli_load import add_astazero_options

    add_progress(p)

    add_astazero_options(p)
    p.set_defaults(func=_cmd)
