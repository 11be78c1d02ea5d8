"""``avll simulate``: the paper's three Table II models on a built-in command."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import declare_io

#: The default output folder (each command has its own).
DEFAULT_OUT = "avll-out/simulate"


def _cmd(args: argparse.Namespace) -> int:
    from ..demo import run

    res = run(Path(args.out), args.dt)
    for name, y in res.items():
        print(f"{name:9s} peak {y.max():+.3f}  trough {y.min():+.3f} m/s²")
    print(f"wrote {Path(args.out) / 'simulate.csv'} and simulate.png")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll simulate``."""
    p = sub.add_parser(
        "simulate", help="simulate the paper's three models on a built-in command",
        description="Simulate the first-order, second-order and proposed models with the "
        "paper's Table II parameters on a built-in 60 s command acceleration (1 m/s² for "
        "10 s, -0.5 m/s² for 10 s, then a 0.1 Hz sine of amplitude 0.8 m/s²); writes "
        "simulate.csv and simulate.png into --out.")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output folder (default: {DEFAULT_OUT})")
    p.add_argument("--dt", type=float, default=0.05,
                   help="sample time in s (default: 0.05)")
    declare_io(p, folders=("out",))
    p.set_defaults(func=_cmd)
