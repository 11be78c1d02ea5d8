"""Sphinx configuration of the avll documentation.

The build imports ``avll`` (autodoc reads the docstrings of the installed package,
including its compiled Rust extension ``avll._core``; the command-line reference is
read from the installed ``avll`` argument parser), so install the package first:

    pip install ".[docs]"                    # the package, Sphinx and myst-parser
    sphinx-build -W --keep-going -b html docs docs/_build/html

(in a development checkout: ``maturin develop`` then ``pip install sphinx myst-parser``).
"""

from __future__ import annotations

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
    "sphinx.ext.napoleon",
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
# NumPy-style "Parameters" sections (napoleon); the Google style is off so that prose
# such as "Returns one run per stretch" stays prose.
napoleon_google_docstring = False
napoleon_numpy_docstring = True

autodoc_member_order = "bysource"
autodoc_default_options = {"members": True}
autodoc_typehints = "description"

html_theme = "alabaster"
html_title = f"avll {release}"
html_theme_options = {"description": "the lower-level controller of automated vehicles"}


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
    """Registers the ``avll-help`` directive."""
    app.add_directive("avll-help", AvllHelp)
    return {"parallel_read_safe": True}
