"""``avll load``: read measured data with any loader, report what the cleaning did,
and optionally convert it to the canonical format."""

from __future__ import annotations

import argparse
from typing import Any

from ._common import (
    add_astazero_options,
    add_command_kind,
    add_format,
    add_json,
    astazero_options,
    declare_io,
)


def _cmd(args: argparse.Namespace) -> int:
    from .. import _atomic
    from ..io import read_runs, write_runs
    from ..io._common import summarize

    opts: dict[str, Any] = {k: v for k in ("dt", "max_gap") if (v := getattr(args, k)) is not None}
    if opts and args.format == "canonical":
        given = " and ".join(f"--{k.replace('_', '-')}" for k in opts)
        raise ValueError(f"{given}: the canonical format is already uniformly sampled and is "
                         "not resampled; use --format generic to resample a table")
    # the loader options of one format
    for key, fmt in (("min_duration", "carma"), ("grade_offset", "openacc-astazero")):
        if getattr(args, key) is not None:
            if args.format != fmt:
                raise ValueError(f"--{key.replace('_', '-')}: only for --format {fmt}")
            opts[key] = getattr(args, key)
    opts.update(astazero_options(args))
    runs = read_runs(args.path, command_kind=args.command_kind, format=args.format, **opts)
    print(summarize(runs))
    total = sum((len(r) - 1) * r.dt for r in runs)
    print(f"{len(runs)} runs, {total:.1f} s in total")
    if args.json:
        _atomic.write_json(args.json, _atomic.json_safe({
            # 12 significant digits: a step read off time stamps carries no more
            # (0.049999999999999996 is 0.05)
            r.run_id: {"samples": len(r), "dt": float(f"{r.dt:.12g}"),
                       "duration_s": float(f"{(len(r) - 1) * r.dt:.12g}"),
                       "command_kind": r.command_kind,
                       "cleaning": list(r.meta.get("cleaning", []))}
            for r in runs}), indent=1)
    if args.out:
        out = write_runs(runs, args.out)
        print(f"wrote {out}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll load``."""
    p = sub.add_parser(
        "load", help="read measured data, report the cleaning, convert to the canonical "
        "format",
        description="Read measured data with one of the loaders, print a per-run summary "
        "and what the cleaning did (gaps, resampling, implausible values), and optionally "
        "write the runs in the canonical format (--out) and the cleaning as JSON "
        "(--json).")
    p.add_argument("path", metavar="PATH", help="data file or folder (required)")
    add_format(p)
    add_command_kind(p)
    p.add_argument("--dt", type=float, default=None,
                   help="resample to this step in s (default: not resampled)")
    p.add_argument("--max-gap", type=float, default=None,
                   help="longest gap in s bridged by interpolation when resampling "
                   "(default: 2.5 x --dt)")
    p.add_argument("--min-duration", type=float, default=None,
                   help="CARMA: shortest engaged stretch kept, in s (default: 10)")
    p.add_argument("--grade-offset", type=float, default=None,
                   help="OpenACC AstaZero: shift in m of the lap position where the grade "
                   "is read (default: 0)")
    add_astazero_options(p)
    p.add_argument("--out", default=None, metavar="FILE",
                   help="write the runs in the canonical format, CSV or Parquet (default: "
                   "not written)")
    add_json(p, "the per-run cleaning (samples, dt, duration, command kind, every "
             "cleaning step)")
    declare_io(p, inputs=("path",), files=("out", "json"), runs=("out",))
    p.set_defaults(func=_cmd)
