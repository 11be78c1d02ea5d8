"""``avll diagnose``: registered by :func:`avll.diagnose.register_cli` (the command
lives with the diagnosis package, :mod:`avll.diagnose.cli`). This module adds what
the shared CLI conventions need on top of it: a description, help text stating every
default, and the declaration of the input and output paths checked before any work."""

from __future__ import annotations

import argparse

from ._common import declare_io

_DESCRIPTION = (
    "Fit the base model on the calibration runs, rank the library's effects by the "
    "residual, accept an effect only when cross-validation over the calibration runs says "
    "so (see docs/guide/diagnose.md), report validation and test runs, and say what the "
    "residual still depends on."
)

#: Help of the options avll.diagnose registers without one (argparse dest -> help).
_HELP = {
    "data": "runs file or folder in the --format (required)",
    "command_kind": "kind of the recorded command (default: from the file's sidecar or "
                    "the loader)",
    "format": "data format, see avll load (default: canonical)",
    "model": "base model: first, second or proposed (default: proposed)",
    "cal_runs": "comma-separated calibration run ids: fitting and the cross-validated "
                "selection (required; no default)",
    "seed": "seed of the calibrations (default: 0)",
    "json": "output JSON file (required; no default)",
    "report": "folder for a Markdown/HTML report (default: not written)",
    "init": "initial state of the rollouts: auto is steady for a speed command, rest "
            "otherwise (default: auto)",
    "optimizer": "calibration: the Rust GA or scipy's differential evolution (default: ga)",
    "quiet": "no progress output (default: off)",
}


#: The one-line help of ``avll diagnose`` (as :func:`avll.diagnose.register_cli` gives it;
#: a test checks the two agree).
HELP = "residual diagnosis and the add-effect loop"


def register(sub: argparse._SubParsersAction, full: bool = True) -> None:
    """Registers ``avll diagnose`` through :func:`avll.diagnose.register_cli` and
    completes its help. ``full=False`` registers only its name, help and description
    (for ``avll --help`` and the other commands, without importing scipy)."""
    if not full:
        sub.add_parser("diagnose", help=HELP, description=_DESCRIPTION)
        return
    from ..diagnose import register_cli

    register_cli(sub)
    p = sub.choices["diagnose"]
    p.description = p.description or _DESCRIPTION
    for a in p._actions:
        if a.dest == "help":
            continue
        text = _HELP.get(a.dest)
        if not a.help:
            a.help = text
        elif "default" not in a.help and text is not None:
            a.help = text
    declare_io(p, inputs=("data",), files=("json",), folders=("report",))
