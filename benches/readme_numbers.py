"""Writes the README's generated blocks from what the code computes.

    python benches/readme_numbers.py            # rewrite the blocks in README.md
    python benches/readme_numbers.py --check    # exit 1 if README.md is out of date

Blocks (each between ``<!-- generated:NAME ... -->`` and ``<!-- /generated:NAME -->``):

* ``section-iv``: the paper's Section IV with its Table II parameters — kv thresholds,
  minimum stable time gaps, capacities and their ratios — computed by
  ``avll.reproduce.stability_summary`` on the grids of ``avll reproduce``'s default
  settings (the numbers ``avll reproduce`` prints), next to the paper's published values
  (``avll.reproduce.PAPER``). Deterministic, about 10 s.
* ``cli``: the table of ``avll`` sub-commands and their one-line help, read from the
  argument parser (``avll.cli.build_parser``).

``tests/test_readme.py`` recomputes both and checks that README.md carries exactly them.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

_MODELS = ("second", "proposed", "first")

#: Where each sub-command is explained in the docs (commands not listed link to the
#: command-line reference page).
GUIDES: dict[str, str] = {
    "simulate": "docs/guide/simulate.md",
    "synth": "docs/guide/simulate.md",
    "load": "docs/guide/field-data.md",
    "calibrate": "docs/guide/calibrate.md",
    "stability-map": "docs/guide/stability.md",
    "diagnose": "docs/guide/diagnose.md",
    "reproduce": "docs/guide/reproduce.md",
    "data": "docs/data.md",
}


def section_iv(threads: int = 0) -> dict[str, Any]:
    """Section IV numbers of the paper's Table II models on ``avll reproduce``'s default
    grids: ``{"models": {name: {"kv_threshold", "min_tg", "capacity"}}, "ratios": {...},
    "settings": Settings, "paper": PAPER, "length", "speed"}`` (the last two: the
    capacity formula's constants)."""
    import avll
    from avll.reproduce import PAPER, SETTINGS, stability_summary

    settings = SETTINGS["default"]
    models = {}
    for m in _MODELS:
        s = stability_summary(avll.PAPER_TABLE_II[m], settings, threads=threads)
        models[m] = {k: s[k] for k in ("kv_threshold", "min_tg", "capacity")}
    cs, cp, cf = (models[m]["capacity"] for m in ("second", "proposed", "first"))
    ratios = {
        "capacity_proposed_vs_second_pct": None if not (cs and cp) else 100 * (1 - cp / cs),
        "capacity_first_vs_proposed_pct": None if not (cf and cp) else 100 * (cf / cp - 1),
    }
    from avll.stability import CAPACITY_LENGTH, CAPACITY_SPEED

    return {"models": models, "ratios": ratios, "settings": settings, "paper": PAPER,
            "length": CAPACITY_LENGTH, "speed": CAPACITY_SPEED}


def _f(x: float | None, fmt: str, none: str = "none") -> str:
    return none if x is None else format(x, fmt)


def render_section_iv(n: dict[str, Any]) -> str:
    """The ``section-iv`` block (Markdown) from :func:`section_iv`'s result."""
    p, m, r, s = n["paper"], n["models"], n["ratios"], n["settings"]

    def three(src: dict[str, Any], key: str, fmt: str) -> str:
        return " / ".join(_f(src[k][key] if key in src[k] else None, fmt)
                          for k in _MODELS)

    paper3 = {k: {"min_tg": p["min_tg"][k], "capacity": p["capacity"][k]} for k in _MODELS}
    none_kv = f"none up to kv = {s.kv_max:g}"
    rows = [
        ("kv threshold, second-order (1/s)", _f(p["kv_threshold"]["second"], ".4f"),
         _f(m["second"]["kv_threshold"], ".4f", none_kv)),
        ("kv threshold, proposed (1/s)", _f(p["kv_threshold"]["proposed"], ".4f"),
         _f(m["proposed"]["kv_threshold"], ".4f", none_kv)),
        ("kv threshold, first-order lag", "none",
         _f(m["first"]["kv_threshold"], ".4f", none_kv)),
        ("min stable Tg, second / proposed / first (s)", three(paper3, "min_tg", ".1f"),
         three(m, "min_tg", ".1f")),
        ("capacity at that Tg (veh/h)", three(paper3, "capacity", ".1f"),
         three(m, "capacity", ".1f")),
        ("capacity, proposed vs second-order",
         f"{p['capacity_proposed_vs_second_pct']:.2f} % lower",
         _f(r["capacity_proposed_vs_second_pct"], ".2f") + " % lower"),
        ("capacity, first-order lag vs proposed",
         f"{p['capacity_first_vs_proposed_pct']:.2f} % larger",
         _f(r["capacity_first_vs_proposed_pct"], ".2f") + " % larger"),
    ]
    lines = ["| Section IV, Table II parameters | paper | avll |", "|---|---|---|"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    lines.append("")
    lines.append(
        f"Grid: kg log-spaced {s.kg_min:g}..{s.kg_max:g} ({s.kg_n} points) × Tg "
        f"0..{s.tg_max:g} s step {s.tg_step:g} × kv 0..{s.kv_max:g} step {s.kv_step:g}, "
        f"Padé order {s.pade_order}; kv threshold by bisection to {s.kv_tol:g} on a "
        f"{s.kv_tg_step:g} s Tg grid; capacity `3600 / (Tg + {n['length']:g}/{n['speed']:g})`"
        " veh/h (an effective vehicle length of "
        f"{n['length']:g} m at {n['speed']:g} m/s, inferred from the paper's capacities)."
    )
    return "\n".join(lines)


def cli_commands() -> list[tuple[str, str]]:
    """``(name, help)`` of every ``avll`` sub-command, in ``avll --help`` order."""
    from avll.cli import build_parser

    parser = build_parser()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return [(a.dest, " ".join((a.help or "").split())) for a in action._choices_actions]
    raise RuntimeError("avll's parser has no sub-commands")


def render_cli(commands: list[tuple[str, str]]) -> str:
    """The ``cli`` block (Markdown) from :func:`cli_commands`'s result."""
    lines = ["| command | does | guide |", "|---|---|---|"]
    for name, text in commands:
        guide = GUIDES.get(name, "docs/cli.md")
        lines.append(f"| `avll {name}` | {text} | [{Path(guide).stem}]({guide}) |")
    return "\n".join(lines)


BLOCKS: dict[str, tuple[Callable[[], Any], Callable[[Any], str]]] = {
    "section-iv": (section_iv, render_section_iv),
    "cli": (cli_commands, render_cli),
}


def _pattern(name: str) -> re.Pattern[str]:
    return re.compile(
        rf"(^<!-- generated:{re.escape(name)}\b[^\n]*-->\n)(.*?)(^<!-- /generated:"
        rf"{re.escape(name)} -->$)",
        re.S | re.M,
    )


def read_block(text: str, name: str) -> str:
    """The current content of block ``name`` in ``text`` (ValueError when absent)."""
    mt = _pattern(name).search(text)
    if mt is None:
        raise ValueError(f"README.md: no '<!-- generated:{name} -->' block")
    return mt.group(2).rstrip("\n")


def replace_block(text: str, name: str, content: str) -> str:
    """``text`` with block ``name``'s content replaced by ``content``."""
    read_block(text, name)
    body = content.rstrip("\n") + "\n" if content.strip() else ""
    return _pattern(name).sub(lambda mt: mt.group(1) + body + mt.group(3), text, count=1)


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def main(argv: list[str] | None = None) -> int:
    """Rewrites (or with ``--check`` verifies) the generated blocks of README.md."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only compare, exit 1 if stale")
    ap.add_argument("--only", default=",".join(BLOCKS), help="blocks to handle")
    args = ap.parse_args(argv)
    names = [b for b in args.only.split(",") if b]
    unknown = [b for b in names if b not in BLOCKS]
    if unknown:
        print(f"readme_numbers: unknown block(s) {unknown}; known: {list(BLOCKS)}",
              file=sys.stderr)
        return 2
    text = README.read_text(encoding="utf-8")
    new = text
    for name in names:
        compute, render = BLOCKS[name]
        new = replace_block(new, name, render(compute()))
    if args.check:
        stale = [b for b in names if read_block(text, b) != read_block(new, b)]
        if stale:
            print(f"README.md: stale generated block(s): {', '.join(stale)}; run "
                  "python benches/readme_numbers.py", file=sys.stderr)
            return 1
        print("README.md: generated blocks are current")
        return 0
    if new != text:
        _write_atomic(README, new)
        print(f"README.md: rewrote {', '.join(names)}")
    else:
        print("README.md: already current")
    return 0


if __name__ == "__main__":
    sys.exit(main())
