"""Sphinx configuration of the avll documentation.

The build imports ``avll`` (autodoc reads the docstrings of the installed package,
including its compiled Rust extension ``avll._core``; the command-line reference is
read from the installed ``avll`` argument parser), so install the package first:

    pip install ".[docs]"                    # the package, Sphinx and myst-parser
    sphinx-build -W --keep-going -b html docs docs/_build/html

(in a development checkout: ``maturin develop`` then ``pip install sphinx myst-parser``).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from docutils import nodes
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

import avll

project = "avll"
author = "the avll developers"
copyright = "the avll developers"
release = avll.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
]

source_suffix = {".md": "markdown"}
# _generated/ holds Markdown fragments written by scripts in benches/ and pulled into
# pages with {include}; they are not pages of their own.
exclude_patterns = ["_build", "_generated", "Thumbs.db", ".DS_Store"]

myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
# "[text](page.md#a-heading)" links resolve for headings down to level 3.
myst_heading_anchors = 3

nitpicky = False

# Three pages come from parallel branches (guarantees, stability, findings-openacc).
# Until they are merged they are one-line placeholders without a title, which Sphinx
# reports as "toctree contains reference to document ... that doesn't have a title".
# Only while such a placeholder is present is that one warning suppressed; the real
# pages have titles, and then nothing is suppressed.
_PLACEHOLDER = "(page arriving from a parallel branch)"
_HERE = Path(__file__).resolve().parent
suppress_warnings: list[str] = []
if any((_HERE / f"{p}.md").is_file()
       and (_HERE / f"{p}.md").read_text(encoding="utf-8").strip() == _PLACEHOLDER
       for p in ("guarantees", "stability", "findings-openacc")):
    suppress_warnings.append("toc.no_title")
autodoc_member_order = "bysource"
autodoc_default_options = {"members": True}
autodoc_typehints = "description"

html_theme = "alabaster"
html_title = f"avll {release}"
html_theme_options = {"description": "the lower-level controller of automated vehicles"}


# ---------------------------------------------------------------------------
# Docstrings: a "Parameters" section written as "name: text" items
# ---------------------------------------------------------------------------

_ITEM = re.compile(r"^(\s*)([A-Za-z_][A-Za-z0-9_]*): (.*)$")


def _colon_parameters(app: Sphinx, what: str, name: str, obj: Any, options: Any,
                      lines: list[str]) -> None:
    """Some docstrings list their arguments under a NumPy-style ``Parameters`` /
    ``----------`` header as ``name: text`` lines (continuations indented). Docutils
    would read that header as a section title inside a docstring and the items as a
    block quote (errors), so turn such a section into a field list
    (``:param name: text``), which renders as the parameter table."""
    i = 0
    while i + 1 < len(lines):
        if lines[i].strip() == "Parameters" and set(lines[i + 1].strip()) == {"-"}:
            out: list[str] = []
            j = i + 2
            while j < len(lines):
                line = lines[j]
                m = _ITEM.match(line)
                if m and len(m.group(1)) == len(lines[i]) - len(lines[i].lstrip()):
                    out.append(f"{m.group(1)}:param {m.group(2)}: {m.group(3)}")
                elif line.strip() and line[:1].isspace() and out:
                    out.append(line)
                elif not line.strip():
                    nxt = next((x for x in lines[j + 1:] if x.strip()), "")
                    if not _ITEM.match(nxt):
                        break
                else:
                    break
                j += 1
            lines[i:j] = [*out, ""]
            i += len(out) + 1
        else:
            i += 1


# ---------------------------------------------------------------------------
# {avll-help} COMMAND: the installed parser's --help text as a literal block
# ---------------------------------------------------------------------------


class AvllHelp(SphinxDirective):
    """``{avll-help}`` with a sub-command name: the text ``avll COMMAND --help`` prints;
    without one: ``avll --help`` followed by every sub-command's help under its own
    heading. Read from the installed argument parser at build time, so the reference
    cannot drift from the code."""

    optional_arguments = 1

    @staticmethod
    def _block(parser: Any) -> nodes.literal_block:
        import argparse

        parser.formatter_class = lambda prog: argparse.HelpFormatter(prog, width=88)
        text = parser.format_help().rstrip()
        block = nodes.literal_block(text, text)
        block["language"] = "text"
        return block

    def run(self) -> list[nodes.Node]:
        import argparse

        from avll.cli import build_parser

        parser = build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        if self.arguments:
            name = self.arguments[0]
            if name not in sub.choices:
                raise self.error(f"avll has no sub-command {name!r}")
            return [self._block(sub.choices[name])]
        out: list[nodes.Node] = [self._block(parser)]

        def walk(prefix: str, choices: dict[str, Any]) -> None:
            for name, p in choices.items():
                out.extend([nodes.rubric(text=f"{prefix} {name}"), self._block(p)])
                for a in p._actions:
                    if isinstance(a, argparse._SubParsersAction):
                        walk(f"{prefix} {name}", a.choices)

        walk("avll", sub.choices)
        return out


def setup(app: Sphinx) -> dict[str, Any]:
    """Registers the docstring adapter and the ``avll-help`` directive."""
    app.connect("autodoc-process-docstring", _colon_parameters)
    app.add_directive("avll-help", AvllHelp)
    return {"parallel_read_safe": True}
