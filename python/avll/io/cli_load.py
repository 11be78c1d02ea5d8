"""``avll load``: read measured data with any loader, report what the cleaning did,
and optionally convert it to the canonical format."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .. import _atomic
from . import FORMATS, read_runs, write_runs
from ._common import summarize

__all__ = ["register_cli", "add_astazero_options", "astazero_options"]


def add_astazero_options(p: argparse.ArgumentParser) -> None:
    """Add ``--slope FILE``, ``--no-grade`` and ``--lap-length M`` (the AstaZero
    loader's ``slope``, ``grade=False`` and ``lap_length``) to a command."""
    g = p.add_argument_group("OpenACC AstaZero (--format openacc-astazero)")
    g.add_argument("--slope", default=None, metavar="FILE",
                   help="road-grade profile Slope.csv (default: found beside the data, in "
                        "../platoon, one folder up or in ../../Exp)")
    g.add_argument("--no-grade", action="store_true",
                   help="do not add the road grade (no Slope.csv needed)")
    g.add_argument("--lap-length", type=float, default=None, metavar="M",
                   help="lap length (m) at which positions wrap onto the grade profile "
                        "(default: the last X of Slope.csv)")


def astazero_options(args: argparse.Namespace) -> dict[str, Any]:
    """The loader options of :func:`add_astazero_options`; a ``ValueError`` naming
    the option when it is given for another format or is invalid."""
    slope = getattr(args, "slope", None)
    no_grade = bool(getattr(args, "no_grade", False))
    lap_length = getattr(args, "lap_length", None)
    given = [name for name, on in (("--slope", slope is not None), ("--no-grade", no_grade),
                                   ("--lap-length", lap_length is not None)) if on]
    if not given:
        return {}
    if args.format != "openacc-astazero":
        raise ValueError(f"{given[0]}: only for --format openacc-astazero")
    opts: dict[str, Any] = {}
    if no_grade:
        if slope is not None or lap_length is not None:
            other = "--slope" if slope is not None else "--lap-length"
            raise ValueError(f"{other}: conflicts with --no-grade")
        opts["grade"] = False
    if slope is not None:
        if not Path(slope).is_file():
            raise FileNotFoundError(f"--slope: {slope}: no such file")
        opts["slope"] = slope
    if lap_length is not None:
        lap = float(lap_length)
        if not (lap > 0 and lap < float("inf")):
            raise ValueError(f"--lap-length: must be a finite length > 0 (m), got {lap:g}")
        opts["lap_length"] = lap
    return opts


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
    opts.update(astazero_options(args))
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
    add_astazero_options(p)
    p.add_argument("--out", default=None, help="write the runs in the canonical format")
    p.add_argument("--report", default=None, help="write the per-run cleaning as JSON")
    p.set_defaults(func=_cmd)
