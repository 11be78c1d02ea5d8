"""The ``avll`` command: one module per sub-command in this package (each a
``register(subparsers)`` listed in ``_COMMANDS``), the options they share in
:mod:`avll.cli._common`.

Every sub-command (see docs/guarantees.md): errors in the input (``ValueError``,
``TypeError``, ``OSError``, ``MemoryError``, ``ArithmeticError``) end it with one line on
stderr and exit code 2, Ctrl-C with 130, SIGTERM (handled as a Ctrl-C: staged outputs
removed) with 143; warnings about the data are one line each
(``--strict``: errors); every output path is checked before any computation
(:func:`avll.cli._common.check_io`); progress goes to stderr (``--progress``, ``-q``); the
files a command lists in ``args.wrote`` are said ("wrote PATH") once they are committed.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import os
import re
import sys
import warnings
from collections.abc import Sequence
from typing import Any

from .. import _sigint

# the sub-command modules of this package, each with a register(subparsers), in help order
_COMMANDS = ("simulate", "synth", "load", "diagnose", "calibrate", "stability_map", "reproduce",
             "study", "data")


def build_parser() -> argparse.ArgumentParser:
    """The ``avll`` argument parser with every registered sub-command (no
    registration imports a heavy package)."""
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="avll",
        description="Lower-level controller models of automated vehicles: "
        "simulation, calibration, stability maps.",
    )
    parser.add_argument("--version", action="version", version=f"avll {__version__}",
                        help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    from ._common import add_dpi

    for p in _all_parsers(parser):
        # no abbreviations: `--model` must not silently mean `--models`
        p.allow_abbrev = False
        if p is parser or any(isinstance(a, argparse._SubParsersAction) for a in p._actions):
            continue
        have = {o for a in p._actions for o in a.option_strings}
        inputs = [d for d in p.get_default("io_inputs") or () if d != "source"]
        folders = p.get_default("io_folders") or ()
        figures = p.get_default("io_figures") or ()
        # --strict only where data are read (a calibration JSON is not data)
        if inputs and "--strict" not in have:
            p.add_argument("--strict", action="store_true",
                           help="treat warnings about the data (implausible values, sidecar "
                           "entries for missing runs) as errors (default: off)")
        if folders and "--overwrite" not in have:
            p.add_argument("--overwrite", action="store_true",
                           help="write into an output folder even when it holds another "
                           "command's output (its MANIFEST.json) (default: off, refused)")
        if (folders or figures) and "--dpi" not in have:
            add_dpi(p)
        # an error about a library argument an option sets names the option (_main)
        p.set_defaults(option_of={a.dest: max(a.option_strings, key=len)
                                  for a in p._actions if a.option_strings})
    return parser


def _all_parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    out = [parser]
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for p in dict.fromkeys(a.choices.values()):
                out += _all_parsers(p)
    return out


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: Any = None, line: str | None = None, *, who: str = "avll") -> None:
    text = " ".join(str(message).split())
    print(f"{who}: warning: {text}", file=sys.stderr)


class _QuietPipe:
    """``sys.stdout`` while a command runs: when the reader of a pipe goes away
    (``avll ... | head``), the rest of the output is dropped quietly and the command
    goes on (its files are still written) and ends with its own exit code."""

    def __init__(self, stream: Any) -> None:
        self._stream = stream
        self.gone = False

    def write(self, s: str) -> int:
        self._guarded(self._stream.write, s)
        return len(s)

    def flush(self) -> None:
        self._guarded(self._stream.flush)

    def _guarded(self, call: Any, *args: Any) -> None:
        if self.gone:
            return
        try:
            call(*args)
        except BrokenPipeError:
            self.gone = True
            # what is still buffered goes nowhere at exit instead of raising again
            with contextlib.suppress(OSError, ValueError, AttributeError,
                                     io.UnsupportedOperation):
                fd = self._stream.fileno()
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, fd)
                os.close(null)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the ``avll`` command; returns the exit code (0 ok, 2 bad input, 130 Ctrl-C,
    143 SIGTERM).
    A closed pipe on stdout is not an error (the rest of the output is dropped)."""
    real = sys.stdout
    guard = _QuietPipe(real)
    late = False  # a Ctrl-C outside _main's own handling, before quiet_exit takes over
    code = -1  # until _main returns one
    try:
        _sigint.command_starts()
        sys.stdout = guard
        code = _main(argv)
        guard.flush()
    except KeyboardInterrupt:
        late = True
    finally:
        while True:  # the hand-over completes whatever instant a Ctrl-C lands in it
            try:
                sys.stdout = real
                _forget_unhandled_interrupt()
                _sigint.command_ends()
                break
            except KeyboardInterrupt:
                late = True
    if late and code not in (130, 143):
        # the outputs are committed (or removed) by now: the exit code says interrupted
        term = _sigint.terminated()
        print(f"avll: {'terminated (SIGTERM)' if term else 'interrupted'}", file=sys.stderr)
        return 143 if term else 130
    return code


def _forget_unhandled_interrupt() -> None:
    """Every Ctrl-C has been handled when :func:`main` returns, but CPython may not
    know it: a ``KeyboardInterrupt`` that ends a string ``exec``/``eval`` (e.g. a
    Ctrl-C landing in the code ``dataclasses`` or ``namedtuple`` generate) marks the
    interrupt as unhandled even when a caller catches it, and ``python -m avll``
    then ends the process by SIGINT instead of with the exit code. Each string
    evaluation clears that mark when it starts, so an empty one forgets it."""
    exec("", {})


def _main(argv: Sequence[str] | None) -> int:
    who = "avll"  # in messages: "avll COMMAND" once the command is known
    option_of: dict[str, str] = {}
    try:
        args = build_parser().parse_args(argv)
        who = f"avll {args.command}"
        option_of = args.option_of

        from ..data import DataWarning
        from ._common import check_io

        check_io(args)  # before any work (and before loading the loaders)
        # imported after parsing: `avll --help` does not load the loaders (pandas)
        from .._atomic import figure_dpi, output_group
        from ..io._common import strict_warnings

        with warnings.catch_warnings(), _sigint.latched(), figure_dpi(getattr(args, "dpi", None)):
            warnings.simplefilter("always", DataWarning)
            warnings.showwarning = lambda *a, **k: _show_warning(*a, **k, who=who)
            # every output of the command is committed as one unit at its end
            with strict_warnings(bool(getattr(args, "strict", False))), output_group():
                code = int(args.func(args) or 0)
                # a Ctrl-C Python had to ignore (avll._sigint), before the outputs commit
                _sigint.check()
            # the files a command lists in args.wrote, said once they are committed
            for path in getattr(args, "wrote", ()):
                print(f"wrote {path}", file=sys.stderr)
            # a SIGTERM a calibration delivered by returning its best point early
            return 143 if _sigint.terminated() else code
    except (KeyboardInterrupt, Exception) as e:
        # A Ctrl-C another error hid counts as a Ctrl-C, whatever the error: a library's
        # own type, or Python 3.11's RuntimeError "Error calling __set_name__" around a
        # KeyboardInterrupt that lands while a class is created (a lazily imported module).
        if isinstance(e, KeyboardInterrupt) or (_sigint.console and _sigint.interrupted()):
            if _sigint.terminated():
                print(f"{who}: terminated (SIGTERM)", file=sys.stderr)
                return 143
            print(f"{who}: interrupted", file=sys.stderr)
            return 130
        if not isinstance(e, (ValueError, TypeError, OSError, MemoryError, ArithmeticError)):
            raise  # a defect, not bad input: its traceback is the report
        msg = " ".join(str(e).split())
        head, colon, rest = msg.partition(":")  # "pop_size: ..." -> "--pop-size: ..."
        if colon and head in option_of:
            msg = option_of[head] + colon + rest
        # "pass slope=PATH" -> "pass --slope PATH"
        msg = re.sub(r"\bpass (\w+)=", lambda m: f"pass {option_of[m[1]]} "
                     if m[1] in option_of else m[0], msg)
        if isinstance(e, MemoryError):
            msg = f"out of memory{': ' + msg if msg else ''} (use a smaller problem)"
        print(f"{who}: error: {msg}", file=sys.stderr)
        return 2


