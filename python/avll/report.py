"""A small document model written both as Markdown and as standalone HTML.

:class:`Report` collects headings, paragraphs, tables and figures; :meth:`Report.write`
renders the same content to ``report.md`` and ``report.html`` (figures are PNG files
next to them, referenced by relative path). No Markdown library is needed: the HTML
is generated from the same blocks, not converted from the Markdown text.

Every text that goes into the HTML -- title, headings, paragraphs, list items, table
headers and cells, captions, figure paths, preformatted blocks -- is escaped
(``html.escape``) before the few inline marks (``**bold**``, ``*italic*``, backquoted
code) are turned into tags, so a run id such as ``<img src=x onerror=alert(1)>`` is
shown as text, never interpreted.
"""

from __future__ import annotations

import html
import math
import numbers
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["Report", "fmt", "diff", "num", "md_table", "finite_or_none"]


def fmt(x: Any, digits: int = 4) -> str:
    """A number for a table cell: ``—`` for None/NaN, ``inf``, integers as such,
    otherwise ``digits`` significant digits (fixed notation where sensible)."""
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    v = float(x)
    if math.isnan(v):
        return "—"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if v == 0:
        return "0"
    a = abs(v)
    if 1e-3 <= a < 1e5:
        dec = max(1, digits - 1 - int(math.floor(math.log10(a))))
        return f"{v:.{dec}f}"
    return f"{v:.{digits - 1}e}"


def num(x: Any, spec: str = ".3g", none: str = "—") -> str:
    """A number in a generated table or sentence: ``none`` for None or a non-finite
    value, an integer in full (with a ``g`` spec), a string as it is, otherwise
    ``format(x, spec)``."""
    if x is None:
        return none
    if isinstance(x, str):
        return x
    if isinstance(x, numbers.Integral) and not isinstance(x, bool) and spec.endswith("g"):
        return str(int(x))
    if isinstance(x, numbers.Real) and not math.isfinite(x):
        return none
    return format(x, spec)


def finite_or_none(x: Any) -> float | None:
    """``x`` as a float when it is a finite number, otherwise None (for strict JSON)."""
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def md_table(head: Sequence[str], rows: Sequence[Sequence[Any]], spec: str = ".3g") -> str:
    """A Markdown table of ``rows`` under ``head`` (cells by :func:`num` with ``spec``)."""
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(num(c, spec) for c in r) + " |" for r in rows]
    return "\n".join(out)


def diff(ours: Any, paper: Any, digits: int = 3) -> str:
    """``ours - paper`` with its relative size, or ``—`` when either is missing."""
    if ours is None or paper is None:
        return "—"
    o, p = float(ours), float(paper)
    if not (math.isfinite(o) and math.isfinite(p)):
        return "—"
    d = o - p
    rel = f" ({100 * d / p:+.1f} %)" if p != 0 else ""
    return f"{d:+.{digits}g}{rel}"


@dataclass
class _Block:
    kind: str
    data: Any


_INLINE = [
    (re.compile(r"\*\*(.+?)\*\*"), r"<strong>\1</strong>"),
    (re.compile(r"`([^`]+)`"), r"<code>\1</code>"),
    (re.compile(r"(?<![\w*])\*([^*\s][^*]*?)\*(?![\w*])"), r"<em>\1</em>"),
]


def _inline_html(text: str) -> str:
    out = html.escape(text, quote=False)
    for pat, rep in _INLINE:
        out = pat.sub(rep, out)
    return out


_TAG = re.compile(r"<(?=[A-Za-z/!?])")


def _md(text: str) -> str:
    """Markdown text with anything that could open an HTML tag (``<`` before a letter,
    ``/``, ``!`` or ``?``) escaped, so a Markdown viewer that renders raw HTML shows it
    as text."""
    return _TAG.sub("&lt;", str(text))


def _cell_md(x: Any) -> str:
    return _md(fmt(x)).replace("|", "\\|").replace("\n", " ")


@dataclass
class Report:
    """An ordered list of blocks; see the module doc."""

    title: str
    blocks: list[_Block] = field(default_factory=list)

    def heading(self, text: str, level: int = 2) -> None:
        """Adds a heading (level 2–4; the title is level 1)."""
        self.blocks.append(_Block("h", (max(2, min(4, level)), text)))

    def para(self, text: str) -> None:
        """Adds a paragraph (``**bold**``, ``*italic*`` and backquoted code allowed)."""
        self.blocks.append(_Block("p", text))

    def bullets(self, items: Sequence[str]) -> None:
        """Adds a bullet list."""
        self.blocks.append(_Block("ul", list(items)))

    def table(self, header: Sequence[str], rows: Sequence[Sequence[Any]],
              caption: str | None = None) -> None:
        """Adds a table; cells are formatted by :func:`fmt`."""
        self.blocks.append(_Block("table", (list(header), [list(r) for r in rows], caption)))

    def columns(self, meanings: Sequence[tuple[str, str]]) -> None:
        """A paragraph giving the meaning and unit of each column of the table above
        (``(column, "meaning (unit)")`` pairs)."""
        self.para("Columns: " + "; ".join(f"*{c}*: {m}" for c, m in meanings) + ".")

    def figure(self, path: str, caption: str) -> None:
        """Adds a figure by its path relative to the report."""
        self.blocks.append(_Block("img", (path, caption)))

    def code(self, text: str) -> None:
        """Adds a preformatted block."""
        self.blocks.append(_Block("pre", text))

    def to_markdown(self) -> str:
        """The report as GitHub-flavoured Markdown."""
        out = [f"# {_md(self.title)}", ""]
        for b in self.blocks:
            if b.kind == "h":
                lvl, text = b.data
                out += ["#" * lvl + " " + _md(text), ""]
            elif b.kind == "p":
                out += [_md(b.data), ""]
            elif b.kind == "ul":
                out += [f"* {_md(it)}" for it in b.data] + [""]
            elif b.kind == "table":
                head, rows, cap = b.data
                if cap:
                    out += [f"**{_md(cap)}**", ""]
                out.append("| " + " | ".join(_cell_md(h) for h in head) + " |")
                out.append("|" + "---|" * len(head))
                out += ["| " + " | ".join(_cell_md(c) for c in r) + " |" for r in rows]
                out.append("")
            elif b.kind == "img":
                path, cap = b.data
                out += [f"![{_md(cap)}]({path})", "", f"*{_md(cap)}*", ""]
            elif b.kind == "pre":
                out += ["```", b.data.rstrip("\n"), "```", ""]
        return "\n".join(out)

    def to_html(self) -> str:
        """The report as a standalone HTML page (inline CSS, figures by relative path)."""
        css = (
            "body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;"
            "line-height:1.45;color:#222}table{border-collapse:collapse;margin:0.6em 0 1.2em}"
            "th,td{border:1px solid #bbb;padding:3px 8px;text-align:right}"
            "th{background:#eee}td:first-child,th:first-child{text-align:left}"
            "img{max-width:100%;border:1px solid #ddd}figure{margin:1em 0}"
            "figcaption{font-style:italic;font-size:0.9em}caption{font-weight:bold;"
            "text-align:left;padding-bottom:4px}pre{background:#f6f6f6;padding:0.6em;"
            "overflow-x:auto}code{background:#f3f3f3}"
        )
        out = [
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            f"<title>{html.escape(self.title)}</title><style>{css}</style></head><body>",
            f"<h1>{html.escape(self.title)}</h1>",
        ]
        for b in self.blocks:
            if b.kind == "h":
                lvl, text = b.data
                out.append(f"<h{lvl}>{_inline_html(text)}</h{lvl}>")
            elif b.kind == "p":
                out.append(f"<p>{_inline_html(b.data)}</p>")
            elif b.kind == "ul":
                out.append("<ul>" + "".join(f"<li>{_inline_html(i)}</li>" for i in b.data)
                           + "</ul>")
            elif b.kind == "table":
                head, rows, cap = b.data
                out.append("<table>")
                if cap:
                    out.append(f"<caption>{_inline_html(cap)}</caption>")
                out.append("<tr>" + "".join(f"<th>{_inline_html(str(h))}</th>" for h in head)
                           + "</tr>")
                for r in rows:
                    out.append("<tr>" + "".join(f"<td>{_inline_html(fmt(c))}</td>" for c in r)
                               + "</tr>")
                out.append("</table>")
            elif b.kind == "img":
                path, cap = b.data
                out.append(f'<figure><img src="{html.escape(path)}" alt="{html.escape(cap)}">'
                           f"<figcaption>{_inline_html(cap)}</figcaption></figure>")
            elif b.kind == "pre":
                out.append(f"<pre>{html.escape(b.data)}</pre>")
        out.append("</body></html>")
        return "\n".join(out) + "\n"

    def write(self, out_dir: str | Path, stem: str = "report") -> tuple[Path, Path]:
        """Writes ``<stem>.md`` and ``<stem>.html`` into ``out_dir``, both atomically
        (temporary names renamed together); returns both paths."""
        from . import _atomic

        d = Path(out_dir)
        md, ht = d / f"{stem}.md", d / f"{stem}.html"
        with _atomic.atomic_paths(md, ht) as (tmd, tht):
            tmd.write_text(self.to_markdown() + "\n", encoding="utf-8")
            tht.write_text(self.to_html(), encoding="utf-8")
        return md, ht
