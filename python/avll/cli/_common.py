"""Options shared by the ``avll`` sub-commands, defined once: ``--models M[,M...]``
(several models, comma-separated and/or repeated; ``--model M`` is always one),
``--cal-runs`` (run ids or glob patterns, :func:`select_runs`), ``--seed``,
``--threads``, ``--json PATH``, ``--progress``/``-q`` (:mod:`avll.progress`); the input
and output paths a command declares (:func:`declare_io`) are checked before any
computation (:func:`check_io`).
"""

from __future__ import annotations

import argparse
import fnmatch
import itertools
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .._limits import check_int
from ..models import MODELS as _MODELS

#: The lower-level models the commands know (the registry :data:`avll.models.MODELS`).
MODEL_NAMES: tuple[str, ...] = tuple(_MODELS)

#: The loaders of ``--format`` (the keys of :data:`avll.io.FORMATS`, listed here so that
#: ``avll --help`` does not import the loaders; a test checks the two agree).
FORMAT_NAMES: tuple[str, ...] = ("canonical", "carma", "generic", "openacc",
                                 "openacc-astazero")


def parse_list(opt: str, text: str) -> list[str]:
    """``text`` split at commas; a ``ValueError`` naming ``opt`` for an empty item."""
    items = [t.strip() for t in text.split(",")]
    if not text.strip() or any(not t for t in items):
        raise ValueError(f"{opt}: expected a comma-separated list, got {text!r}")
    return items


class _Models(argparse.Action):
    """``--models a,b --models c``: known model names, accumulated."""

    def __call__(self, parser: argparse.ArgumentParser, ns: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        got = list(getattr(ns, self.dest) or [])
        for name in parse_list(option_string or "--models", str(values)):
            if name not in MODEL_NAMES:
                parser.error(f"{option_string}: unknown model {name!r}; known: "
                             f"{', '.join(MODEL_NAMES)}")
            if name not in got:
                got.append(name)
        setattr(ns, self.dest, got)


def add_models(p: argparse.ArgumentParser, default: Sequence[str], *,
               what: str = "models") -> None:
    """``--models``: several models; ``models_of`` gives the selection or ``default``."""
    p.add_argument("--models", dest="models", action=_Models, default=None,
                   metavar="M[,M...]",
                   help=f"{what}, comma-separated or repeated, from {', '.join(MODEL_NAMES)} "
                   f"(default: {','.join(default)})")
    p.set_defaults(models_default=tuple(default))


def models_of(args: argparse.Namespace) -> list[str]:
    """The models selected by :func:`add_models` (its default when none given)."""
    return list(args.models or args.models_default)


def add_model(p: argparse.ArgumentParser, default: str, what: str) -> None:
    """``--model M``: one model (``what`` says which role it plays)."""
    p.add_argument("--model", default=default, choices=MODEL_NAMES,
                   help=f"{what} (default: {default})")


def add_cal_runs(p: argparse.ArgumentParser, default_text: str, extra: str = "") -> None:
    """``--cal-runs``: calibration runs as ids or glob patterns."""
    p.add_argument("--cal-runs", default=None, metavar="IDS",
                   help="calibration runs: comma-separated run ids or glob patterns "
                   f"(e.g. 'data5/*,data9/*'){extra} (default: {default_text})")


def select_runs(run_ids: Sequence[str], text: str, opt: str = "--cal-runs") -> list[str]:
    """Run ids selected by ``text`` (comma-separated ids or glob patterns with
    ``*``, ``?`` or ``[``), in the order given; a ``ValueError`` naming ``opt`` for a
    pattern that matches nothing or an unknown id."""
    out: list[str] = []
    known = list(run_ids)
    for item in parse_list(opt, text):
        if any(c in item for c in "*?["):
            hit = [r for r in known if fnmatch.fnmatchcase(r, item)]
            if not hit:
                raise ValueError(f"{opt}: pattern {item!r} matches no run")
            out += [h for h in hit if h not in out]
        elif item not in out:
            out.append(item)
    return out


def add_seed(p: argparse.ArgumentParser, what: str = "GA") -> None:
    p.add_argument("--seed", type=int, default=0,
                   help=f"seed of the {what}; the same seed gives the same result on any "
                   "number of threads (default: 0)")


def add_threads(p: argparse.ArgumentParser) -> None:
    p.add_argument("--threads", type=int, default=0,
                   help="worker threads (default: 0, all cores)")


class _Count(argparse.Action):
    """An integer option ``>= minimum``; a ``ValueError`` (one line, exit code 2)
    otherwise."""

    def __init__(self, *a: Any, minimum: int = 1, **k: Any) -> None:
        super().__init__(*a, **k)
        self.minimum = minimum

    def __call__(self, parser: argparse.ArgumentParser, ns: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        name = self.option_strings[0]
        try:
            n = int(str(values))
        except ValueError:
            raise ValueError(f"{name}: expected an integer, got {values!r}") from None
        setattr(ns, self.dest, check_int(n, name, min=self.minimum))


def add_ga_budget(p: argparse.ArgumentParser, *, pop_size: bool = False, what: str = "") -> None:
    """The GA budget, named alike on every command, defaulting to the library's
    (:data:`avll.defaults.GA_OPTIONS`): ``--max-generations`` (per start), ``--starts``
    and, with ``pop_size``, ``--pop-size`` (0: automatic)."""
    from ..defaults import DEFAULT_STARTS, GA_OPTIONS

    generations, starts = GA_OPTIONS["max_generations"], DEFAULT_STARTS
    of = f" of {what}" if what else ""
    p.add_argument("--max-generations", dest="max_generations", action=_Count,
                   default=generations, metavar="N",
                   help=f"GA generation budget per start{of} (default: {generations})")
    p.add_argument("--starts", action=_Count, default=starts, metavar="N",
                   help=f"independent GA starts{of}, the best kept (default: {starts})")
    if pop_size:
        pop = GA_OPTIONS["pop_size"]
        from .._core import GA_AUTO_POP as auto
        p.add_argument("--pop-size", action=_Count, minimum=0, default=pop, metavar="N",
                       help=f"GA population (default: {pop}; 0 is automatic: "
                       f"max({auto[0]} x parameters, {auto[1]}))")


def add_json(p: argparse.ArgumentParser, what: str, default: str = "not written",
             required: bool = False) -> None:
    """``--json PATH``: the command's results as strict JSON (``required``: the
    command's main output, no default)."""
    p.add_argument("--json", default=None, metavar="PATH", required=required,
                   help=f"write {what} as strict JSON (non-finite numbers are null with "
                   "a note beside them) ("
                   + ("required; no default)" if required else f"default: {default})"))


def add_progress(p: argparse.ArgumentParser) -> None:
    from ..progress import MODES

    p.add_argument("--progress", choices=MODES, default="auto",
                   help="progress on stderr: a bar, plain log lines, or nothing (default: "
                   "auto, a bar on a terminal and log lines otherwise)")
    p.add_argument("-q", "--quiet", dest="progress", action="store_const", const="none",
                   help="no progress output (same as --progress none; default: off)")


def add_format(p: argparse.ArgumentParser, default: str = "canonical") -> None:
    p.add_argument("--format", default=default, choices=FORMAT_NAMES,
                   help="loader of the data: canonical CSV/Parquet, generic, carma (a file "
                   "or folder), openacc-astazero (a file or folder; platoon pairs run in "
                   "closed loop), openacc (native OpenACC files, e.g. ZalaZone) "
                   f"(default: {default})")


def add_command_kind(p: argparse.ArgumentParser) -> None:
    p.add_argument("--command-kind", choices=("acceleration", "speed"), default=None,
                   help="kind of the recorded command (default: from the file's sidecar "
                   "or the loader)")


def add_astazero_options(p: argparse.ArgumentParser) -> None:
    """``--slope FILE``, ``--no-grade`` and ``--lap-length M``: the AstaZero loader's
    ``slope``, ``grade=False`` and ``lap_length``."""
    g = p.add_argument_group("OpenACC AstaZero (--format openacc-astazero)")
    g.add_argument("--slope", default=None, metavar="FILE",
                   help="road-grade profile Slope.csv (default: found beside the data, in "
                        "../platoon, one folder up or in ../../Exp)")
    g.add_argument("--no-grade", action="store_true",
                   help="do not add the road grade, no Slope.csv needed (default: off)")
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


# ---------------------------------------------------------------------------
# Input and output paths, checked before any computation
# ---------------------------------------------------------------------------


def declare_io(p: argparse.ArgumentParser, inputs: Sequence[str] = (),
               files: Sequence[str] = (), folders: Sequence[str] = (),
               figures: Sequence[str] = (), runs: Sequence[str] = ()) -> None:
    """Declares a command's input paths and its output files and folders (argparse
    ``dest`` names) for :func:`check_io`; ``figures`` are the output files among
    ``files`` that are figures (their suffix picks the format: ``FIGURE_FORMATS``),
    ``runs`` those written in the canonical format (with a ``.meta.json`` sidecar,
    itself an output). Call it after adding those arguments: the messages name each
    path by its option as the parser knows it (``--from`` for ``dest="source"``), a
    positional one by its metavar."""
    declared = {*inputs, *files, *folders}
    labels = {a.dest: max(a.option_strings, key=len) if a.option_strings
              else str(a.metavar or a.dest.upper())
              for a in p._actions if a.dest in declared}
    p.set_defaults(io_inputs=tuple(inputs), io_outputs=tuple(files) + tuple(folders),
                   io_folders=tuple(folders), io_figures=tuple(figures),
                   io_runs=tuple(runs), io_labels=labels)


#: Figure formats the commands write, chosen by the output's suffix.
FIGURE_FORMATS: tuple[str, ...] = ("png", "svg", "pdf")


def add_dpi(p: argparse.ArgumentParser) -> None:
    from ..plotting import DEFAULT_DPI

    p.add_argument("--dpi", action=_Count, minimum=10, default=DEFAULT_DPI, metavar="N",
                   help="resolution of PNG figures in dots per inch; SVG and PDF figures "
                   f"are vector graphics, chosen by the file's suffix (default: {DEFAULT_DPI})")


def check_figure_path(label: str, path: str | os.PathLike[str]) -> None:
    """A ``ValueError`` naming ``label`` when ``path``'s suffix is not a figure format
    the commands write (``.png``, ``.svg``, ``.pdf``)."""
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in FIGURE_FORMATS:
        raise ValueError(f"{label}: {path}: the suffix picks the figure format; use "
                         f"{', '.join('.' + f for f in FIGURE_FORMATS)}")


def _input_files(label: str, path: Any) -> list[tuple[str, Any]]:
    """An input, its sidecar (``X.meta.json``) and every file below it (a folder)."""
    out: list[tuple[str, Any]] = [(label, path)]
    if path is None:
        return out
    p = Path(path)
    out.append((f"{label} (its sidecar)", p.with_name(p.name + ".meta.json")))
    if p.is_dir():
        from ..io._common import walk_files

        try:
            below = walk_files(p)
        except OSError:  # an unreadable subfolder: the loader reports it
            below = []
        out += [(f"{label} (a file it holds)", f) for f in below[:100_000]]
    return out


def check_not_foreign(label: str, folder: Path, command: str, overwrite: bool) -> None:
    """A ``ValueError`` naming ``label`` when ``folder`` holds another command's output
    (the ``command`` of its MANIFEST.json: ``avll X`` writes only over its own folders)
    and ``overwrite`` is not set."""
    from .._atomic import MANIFEST, loads

    mp = folder / MANIFEST
    if overwrite or not mp.is_file():
        return
    try:
        doc = loads(mp.read_text(encoding="utf-8"))
        cmd = doc.get("command") if isinstance(doc, dict) else None
        other = str(cmd) if cmd else "an unknown command"
    except (OSError, ValueError):
        other = "an unreadable manifest"
    if command not in other.split():
        raise ValueError(f"{label}: {folder} holds the output of {other!r} (its "
                         "MANIFEST.json); writing there would replace it: choose another "
                         "folder, or pass --overwrite")


def _writable_target(label: str, path: Path, folder: bool) -> None:
    if folder:
        if path.exists() and not path.is_dir():
            raise ValueError(f"{label}: {path} exists and is not a folder")
    elif path.is_dir():
        raise ValueError(f"{label}: {path} is a folder, expected a file name")
    # the writers create missing parent folders: the nearest existing one must be a
    # writable folder
    anc = path if (folder and path.is_dir()) else path.parent
    anc = Path(os.path.abspath(anc))
    while not anc.exists():
        anc = anc.parent
    if not anc.is_dir():
        raise ValueError(f"{label}: {path}: {anc} is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise PermissionError(f"{label}: {path}: folder {anc} is not writable")


def check_io(args: argparse.Namespace) -> None:
    """Checks the paths :func:`declare_io` named, before any computation: every output
    can be written (not a folder where a file is expected or the reverse, its nearest
    existing folder writable), none is one of the inputs (no command writes over its
    input), and no two outputs are the same file. Raises ``ValueError``/``OSError``
    naming the option and the path."""
    from .._atomic import check_not_inputs, same_file

    ins = tuple(getattr(args, "io_inputs", ()))
    outs = tuple(getattr(args, "io_outputs", ()))
    folders = set(getattr(args, "io_folders", ()))
    label = getattr(args, "io_labels", {})

    def given(d: str) -> Any:
        v = getattr(args, d, None)
        return None if v == "" else v  # an empty path means "not written" (--out "")

    inputs = [f for d in ins for f in _input_files(label[d], given(d))]
    outputs = [(label[d], given(d), d in folders) for d in outs]
    for d in getattr(args, "io_runs", ()):
        if given(d) is not None:  # the canonical writer's sidecar is an output too
            path = Path(given(d))
            _writable_target(label[d], path, False)  # "/" or "." has no name to extend
            outputs.append((f"{label[d]} (its sidecar)",
                            path.with_name(path.name + ".meta.json"), False))
    check_not_inputs([(lab, pth) for lab, pth, _ in outputs], inputs)
    named = [(lab, pth) for lab, pth, _ in outputs if pth is not None]
    for (la, pa), (lb, pb) in itertools.combinations(named, 2):
        if same_file(pa, pb):
            raise ValueError(f"{lb}: {pb} is also the output of {la}; choose distinct names")
    for d in getattr(args, "io_figures", ()):
        if given(d) is not None:
            check_figure_path(label[d], given(d))
    for lab, pth, folder in outputs:
        if pth is not None:
            _writable_target(lab, Path(pth), folder)
            if folder and Path(pth).is_dir():
                check_not_foreign(lab, Path(pth), str(getattr(args, "command", "")),
                                  bool(getattr(args, "overwrite", False)))


# ---------------------------------------------------------------------------
# Data that cannot identify a model
# ---------------------------------------------------------------------------

#: Fewer samples than this in a run cannot calibrate a model (the proposed one has six
#: parameters and a dead time spanning several samples).
MIN_SAMPLES = 20


def _degenerate(r: Any) -> str | None:
    """What makes run ``r`` useless for a fit (None: nothing)."""
    import numpy as np

    n = len(r)
    if n < MIN_SAMPLES:
        return f"too short: {n} samples (at least {MIN_SAMPLES} needed)"
    name = "command" if r.command is not None else "lead_v"
    if getattr(r, name) is None:
        return None
    a, d = np.asarray(r.a, dtype=float), np.asarray(getattr(r, name), dtype=float)
    if not (np.any(a) or np.any(d)):
        return f"{name} and a are all zero: nothing to fit"
    if np.ptp(d) == 0 and np.ptp(a) == 0:
        # (a constant set speed alone is fine when the response moves: the free-flow
        # runs of a speed loop)
        return (f"{name} and a are constant ({d[0]:g} and {a[0]:g}): nothing excites "
                "the model")
    return None


def check_informative(runs: Sequence[Any], source: Any, what: str = "calibrate") -> None:
    """A warning (:class:`avll.DataWarning`, naming the file and the run) for each run
    that is too short, constant or all zero; a :class:`avll.DataError` when every run is
    so (nothing to ``what`` on)."""
    from ..data import DataError, DataWarning

    bad = [(r.run_id, why) for r in runs if (why := _degenerate(r)) is not None]
    if bad and len(bad) == len(runs):
        rid, why = bad[0]
        more = f" (and {len(bad) - 1} more run(s) alike)" if len(bad) > 1 else ""
        raise DataError(f"{source}: run {rid!r}: {why}{more}; nothing to {what} on")
    for rid, why in bad:
        warnings.warn(f"{source}: run {rid!r}: {why}", DataWarning, stacklevel=2)
