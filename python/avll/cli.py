"""The ``avll`` command. Each sub-command lives in its area's module as a
``register_cli(subparsers)`` function listed in ``_COMMANDS``.

Errors in the input (``ValueError``, ``OSError``) end the command with a one-line
message on stderr and exit code 2, without a traceback; Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# "module:function" registering one or more sub-commands, in help order.
_COMMANDS = [
    "avll.demo:register_cli",
    "avll.synth:register_cli",
    "avll.io.cli_load:register_cli",
    "avll.diagnose:register_cli",
    "avll.calibrate:register_cli",
    "avll.stability:register_cli",
    "avll.reproduce:register_cli",
    "avll.studies:register_cli",
]


def build_parser() -> argparse.ArgumentParser:
    """The ``avll`` argument parser with every registered sub-command."""
    parser = argparse.ArgumentParser(
        prog="avll",
        description="Lower-level controller models of automated vehicles: "
        "simulation, calibration, stability maps.",
    )
    from . import __version__

    parser.add_argument("--version", action="version", version=f"avll {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for spec in _COMMANDS:
        mod, fn = spec.split(":")
        getattr(importlib.import_module(mod), fn)(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the ``avll`` command; returns the exit code (0 ok, 2 bad input, 130 Ctrl-C)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"avll {args.command}: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as e:
        msg = " ".join(str(e).split())
        print(f"avll {args.command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
