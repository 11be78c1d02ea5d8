"""``avll load``: read measured data with any loader, report what the cleaning did,
and optionally convert it to the canonical format."""

from __future__ import annotations

import argparse
from typing import Any

from .. import _atomic
from . import FORMATS, read_runs, write_runs
from ._common import summarize

__all__ = ["register_cli"]


def _cmd(args: argparse.Namespace) -> int:
    opts: dict[str, Any] = {}
    if (args.dt is not None or args.max_gap is not None) and args.format == "canonical":
        raise ValueError("--dt: the canonical format is already uniformly sampled and is not "
                         "resampled; use --format generic to resample a table")
    if args.dt is not None:
        opts["dt"] = args.dt
    if args.max_gap is not None:
        opts["max_gap"] = args.max_gap
    if args.min_duration is not None:
        if args.format != "carma":
            raise ValueError("--min-duration: only for --format carma")
        opts["min_duration"] = args.min_duration
    if args.grade_offset is not None:
        if args.format != "openacc-astazero":
            raise ValueError("--grade-offset: only for --format openacc-astazero")
        opts["grade_offset"] = args.grade_offset
    runs = read_runs(args.path, command_kind=args.command_kind, format=args.format, **opts)
    print(summarize(runs))
    total = sum((len(r) - 1) * r.dt for r in runs)
    print(f"{len(runs)} runs, {total:.1f} s in total")
    if args.report:
        _atomic.write_json(args.report, {
            r.run_id: {"samples": len(r), "dt": r.dt, "duration_s": (len(r) - 1) * r.dt,
                       "command_kind": r.command_kind,
                       "cleaning": list(r.meta.get("cleaning", []))}
            for r in runs}, indent=1)
    if args.out:
        out = write_runs(runs, args.out)
        print(f"wrote {out}")
    return 0


def register_cli(sub: argparse._SubParsersAction) -> None:
    """Register ``avll load``."""
    p = sub.add_parser("load", help="read measured data, report the cleaning, convert to "
                                    "the canonical format")
    p.add_argument("path", help="data file or folder")
    p.add_argument("--format", default="canonical", choices=sorted(FORMATS))
    p.add_argument("--command-kind", choices=["acceleration", "speed"], default=None)
    p.add_argument("--dt", type=float, default=None, help="resample to this step (s)")
    p.add_argument("--max-gap", type=float, default=None,
                   help="longest gap bridged by interpolation when resampling (s)")
    p.add_argument("--min-duration", type=float, default=None,
                   help="CARMA: shortest engaged stretch kept (s, default 10)")
    p.add_argument("--grade-offset", type=float, default=None,
                   help="OpenACC: shift (m) of the lap position where the grade is read")
    p.add_argument("--out", default=None, help="write the runs in the canonical format")
    p.add_argument("--report", default=None, help="write the per-run cleaning as JSON")
    p.set_defaults(func=_cmd)
