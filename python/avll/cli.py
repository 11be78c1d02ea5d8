"""The ``avll`` command. Each sub-command lives in its area's module as a
``register_cli(subparsers)`` function listed in ``_COMMANDS``.

Shared behaviour of every sub-command (see docs/guarantees.md):

* errors in the input (``ValueError``, ``TypeError``, ``OSError``, ``MemoryError``) end
  the command with a one-line message on stderr and exit code 2, without a traceback;
  Ctrl-C exits with 130;
* warnings about the data (:class:`avll.DataWarning`, e.g. implausible values) are
  printed as one line each; ``--strict`` turns them into errors (exit 2);
* an output path that is the same file as an input (or as another output) is refused
  before any computation. A sub-command names its input and output options with
  ``set_defaults(io_inputs=(...), io_outputs=(...))`` (argparse ``dest`` names).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from collections.abc import Sequence
from typing import Any

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

#: Input and output options (argparse dests) of the sub-commands that do not declare
#: them with ``set_defaults(io_inputs=..., io_outputs=...)``.
_IO: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "simulate": ((), ("out",)),
    "synth": ((), ("out",)),
    "load": (("path",), ("out", "report")),
    "diagnose": (("data",), ("json", "report")),
    "calibrate": (("data",), ("json", "figure")),
    "stability-map": ((), ("out", "thresholds_out", "json")),
    "reproduce": (("data_path",), ("out", "json")),
}


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
    for p in sub.choices.values():
        if not any("--strict" in a.option_strings for a in p._actions):
            p.add_argument("--strict", action="store_true",
                           help="treat warnings about the data (implausible values, "
                           "sidecar entries for missing runs) as errors")
    return parser


def _check_paths(args: argparse.Namespace) -> None:
    """Refuses an output that is the same file as an input or as another output."""
    from ._atomic import check_not_inputs, same_file

    ins, outs = _IO.get(args.command, ((), ()))
    ins = tuple(getattr(args, "io_inputs", ins))
    outs = tuple(getattr(args, "io_outputs", outs))

    def opt(dest: str) -> str:
        return dest.upper() if dest in ("path", "data") else "--" + dest.replace("_", "-")

    inputs = [(opt(d), getattr(args, d, None)) for d in ins]
    outputs = [(opt(d), getattr(args, d, None)) for d in outs]
    check_not_inputs(outputs, inputs)
    given = [(lab, p) for lab, p in outputs if p is not None]
    for i, (la, pa) in enumerate(given):
        for lb, pb in given[i + 1:]:
            if same_file(pa, pb):
                raise ValueError(f"{lb}: {pb} is also the output of {la}; choose distinct names")


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: Any = None, line: str | None = None, *, command: str = "") -> None:
    text = " ".join(str(message).split())
    print(f"avll {command}: warning: {text}", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the ``avll`` command; returns the exit code (0 ok, 2 bad input, 130 Ctrl-C)."""
    command = "?"
    try:
        from .data import DataWarning
        from .io._common import strict_warnings

        parser = build_parser()
        args = parser.parse_args(argv)
        command = args.command
        with warnings.catch_warnings():
            warnings.simplefilter("always", DataWarning)
            warnings.showwarning = lambda *a, **k: _show_warning(*a, **k, command=command)
            _check_paths(args)
            with strict_warnings(bool(getattr(args, "strict", False))):
                return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"avll {command}: interrupted", file=sys.stderr)
        return 130
    except (ValueError, TypeError, OSError, MemoryError) as e:
        msg = " ".join(str(e).split())
        if isinstance(e, MemoryError):
            msg = f"out of memory{': ' + msg if msg else ''} (use a smaller problem)"
        print(f"avll {command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
