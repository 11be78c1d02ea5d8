"""The README and the docs as a reader meets them: every Markdown link and ``#anchor``
resolves, every "page § Section" reference names a section that exists, and every
``avll`` command shown in a shell block parses and (slow) runs.

Python blocks run elsewhere: the README's tour in ``tests/test_readme.py`` and every
``docs/`` page's blocks in ``tests/test_docs.py``; here a test checks that nothing falls
between the two (the README has no other Python block).

The commands run as written, in one temporary folder per page and in page order, with
two kinds of additions stated in :data:`BUDGET` (appended options, which override the
written ones: a smaller GA budget, ``--quick``), so that the suite stays minutes long;
the options, paths and files of each command are the page's. Commands that read
``../shared/data`` run when the data are present and are skipped otherwise. A page whose
commands read ``runs.csv`` without writing it first gets the synthetic experiment
(``avll synth --out runs.csv``) beforehand, as the page says it should come from.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SHARED = ROOT.parent / "shared" / "data"

#: Every page a reader meets: the README, the project files, and docs/ (the generated
#: fragments are part of the pages that include them).
PAGES = [ROOT / "README.md", ROOT / "CONTRIBUTING.md"] + sorted(
    p for p in DOCS.rglob("*.md") if "_build" not in p.relative_to(DOCS).parts)

#: Options appended to a command to keep the suite short (later options win in argparse).
BUDGET = {
    "calibrate": ["--max-generations", "3", "--starts", "1", "-q"],
    "diagnose": ["--max-generations", "3", "--starts", "1", "--max-effects", "1", "-q"],
    "reproduce": ["--quick", "-q"],
    "stability-map": ["-q"],
}

_FENCE = re.compile(r"^(```+|~~~+)([^\n]*)\n(.*?)^\1[ \t]*$", re.S | re.M)


def _strip_code(text: str) -> str:
    """``text`` without fenced blocks and inline code (links there are not links)."""
    text = _FENCE.sub("", text)
    return re.sub(r"`[^`\n]*`", "", text)


def _slug(heading: str) -> str:
    """The anchor myst-parser (``myst_heading_anchors``, its GitHub-style default) and
    GitHub give a heading: the rendered text lowercased, spaces made hyphens, then
    every character that is not a word character, a hyphen or a CJK ideograph dropped."""
    h = re.sub(r"`([^`]*)`", r"\1", heading.strip())
    h = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", h)  # a link in a heading: its text
    h = re.sub(r"[*_]{1,2}([^*_]+)[*_]{1,2}", r"\1", h)  # emphasis: its text
    return re.sub(r"[^\w\u4e00-\u9fff\-]", "", h.lower().replace(" ", "-"))


def _headings(page: Path) -> list[str]:
    """The headings of a page, those of the fragments it includes (``{include}``)
    in place."""
    raw = page.read_text(encoding="utf-8")
    heads = []
    for m in re.finditer(r"^```\{include\}\s*(\S+)", raw, re.M):
        inc = (page.parent / m.group(1)).resolve()
        if inc.is_file():
            heads += _headings(inc)
    text = _FENCE.sub("", raw)
    return heads + [m.group(2).strip()
                    for m in re.finditer(r"^(#{1,6})\s+(.+?)\s*#*\s*$", text, re.M)]


def _links(page: Path) -> list[str]:
    text = _strip_code(page.read_text(encoding="utf-8"))
    return re.findall(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)", text)


def test_every_markdown_link_and_anchor_resolves() -> None:
    bad: list[str] = []
    checked = 0
    for page in PAGES:
        for target in _links(page):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
                continue
            checked += 1
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            where = f"{page.relative_to(ROOT)}: ({target})"
            if not dest.exists():
                bad.append(f"{where}: {path} does not exist")
                continue
            if anchor:
                if dest.suffix != ".md":
                    bad.append(f"{where}: an anchor into a file that is not Markdown")
                elif anchor not in {_slug(h) for h in _headings(dest)}:
                    bad.append(f"{where}: no heading #{anchor} in {dest.relative_to(ROOT)}")
    assert checked > 50  # the check ran over the real pages
    assert not bad, "\n".join(bad)


def test_link_checker_catches_a_missing_anchor_and_file(tmp_path: Path) -> None:
    # the checker's parts on a page that is wrong on purpose
    page = tmp_path / "p.md"
    page.write_text("# Top\n\n## Calibration bounds\n\n[a](#calibration-bounds) "
                    "[b](#nope) [c](missing.md) `[d](in-code.md)`\n", encoding="utf-8")
    assert _links(page) == ["#calibration-bounds", "#nope", "missing.md"]
    assert {_slug(h) for h in _headings(page)} == {"top", "calibration-bounds"}
    assert _slug("CARMA (`format=\"carma\"`)") == "carma-formatcarma"
    assert _slug("CARMA: speed command → speed") == "carma-speed-command--speed"
    assert _slug("The paper's Table II") == "the-papers-table-ii"


#: "X.md § Section" or "README § Section" in prose, docstrings and report texts.
_SECTION_REF = re.compile(r"((?:[\w./-]+\.md)|README)\s+§\s+([^)\n\"]+)")


def _section_refs() -> list[tuple[Path, str, str]]:
    files = list(PAGES) + sorted((ROOT / "python" / "avll").rglob("*.py"))
    out = []
    for f in files:
        for m in _SECTION_REF.finditer(f.read_text(encoding="utf-8")):
            out.append((f, m.group(1), m.group(2)))
    return out


def test_every_section_reference_names_a_section_that_exists() -> None:
    # e.g. the reproduction report said "README § Calibration" twice: there is none
    refs = _section_refs()
    assert refs  # the pattern still finds the references
    bad = []
    for f, page, words in refs:
        target = ROOT / "README.md" if page == "README" else None
        if target is None:
            for base in (f.parent, ROOT, DOCS):
                if (base / page).is_file():
                    target = base / page
                    break
        if target is None:
            bad.append(f"{f.relative_to(ROOT)}: {page} § {words}: no page {page}")
            continue
        # the reference runs on into the sentence, and may name a heading by its head
        # (the words before a colon or parenthesis): one of them must start the other
        norm = " ".join(re.sub(r"[`*]", "", words).split()).rstrip(".,;:").lower()
        heads = [" ".join(re.sub(r"[`*]", "", h).split()).lower() for h in _headings(target)]
        heads += [re.split(r"[:(]", h)[0].strip() for h in heads]

        if not any(_names(h, norm) for h in heads):
            bad.append(f"{f.relative_to(ROOT)}: {page} § {words.strip()}: no such section")
    assert not bad, "\n".join(bad)


def _names(heading: str, ref: str) -> bool:
    """Whether the reference text ``ref`` names ``heading`` (both lowercased)."""
    return bool(heading) and (heading.startswith(ref) or ref.startswith(heading + " ")
                              or ref == heading)


# -- avll commands in shell blocks ------------------------------------------------------


def _commands(page: Path) -> list[list[str]]:
    """The ``avll`` commands of a page's shell blocks, as argument lists (continuation
    lines joined, ``$`` prompts and comments dropped, ``a && avll b`` split)."""
    out = []
    for m in _FENCE.finditer(page.read_text(encoding="utf-8")):
        lang = m.group(2).strip()
        if lang not in ("bash", "sh", "shell", "console", "text"):
            continue
        body = re.sub(r"\\\n\s*", " ", m.group(3))
        for line in body.splitlines():
            line = line.strip()
            if lang in ("console", "text"):  # output blocks: only the prompted lines
                if not line.startswith("$ "):
                    continue
                line = line[2:]
            for part in line.split("&&"):
                if part.strip().startswith("avll "):
                    out.append(shlex.split(part, comments=True)[1:])
    return out


COMMAND_PAGES = [p for p in PAGES if _commands(p)]


def test_the_pages_show_avll_commands() -> None:
    names = {p.name for p in COMMAND_PAGES}
    assert {"README.md", "calibrate.md", "stability.md", "simulate.md"} <= names


@pytest.mark.parametrize("page", COMMAND_PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_avll_command_shown_parses(page: Path) -> None:
    from avll.cli import build_parser

    parser = build_parser()
    for argv in _commands(page):
        parser.parse_args(argv)  # an unknown or renamed option exits with code 2


def test_readme_python_blocks_are_the_tour() -> None:
    # the tour runs in tests/test_readme.py; any other Python block would run nowhere
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = [m for m in _FENCE.finditer(text) if m.group(2).strip() == "python"]
    assert len(blocks) == 1 and text.index("## Python API, a tour") < blocks[0].start()


@pytest.mark.slow
@pytest.mark.parametrize("page", COMMAND_PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_avll_command_shown_runs(page: Path, tmp_path: Path) -> None:
    cmds = _commands(page)
    needs_data = [c for c in cmds if any("shared/data" in a for a in c)]
    if needs_data and not SHARED.is_dir():
        cmds = [c for c in cmds if c not in needs_data]
        if not cmds:
            pytest.skip(f"{page.name}: every command reads ../shared/data (absent)")
    writes_runs = any(c[:1] == ["synth"] for c in cmds)
    if not writes_runs and any("runs.csv" in c for c in cmds):
        _avll(["synth", "--out", "runs.csv", "--duration", "60"], tmp_path)
    for argv in cmds:
        argv = [a.replace("../shared/data", str(SHARED)) for a in argv]
        if argv[:2] == ["data", "fetch"]:
            _fetch_from_local_mirror(argv, tmp_path)
            continue
        _avll(argv + BUDGET.get(argv[0], []), tmp_path)


def _fetch_from_local_mirror(argv: list[str], cwd: Path) -> None:
    """``avll data fetch NAME ...`` as shown, but from a flat mirror on 127.0.0.1
    (``--base-url``) holding the dataset's files found in ../shared/data (verified by
    hash): the tests reach no internet. A dataset the shared copy does not hold whole
    is not fetched (that would need the internet); its command still parses (above)."""
    import hashlib
    import http.server
    import threading

    from avll import datasets

    try:
        files = datasets.info(argv[2]).files
    except ValueError:
        return  # a dataset without a registered file list: fetch refuses it (tested)
    shared = {}
    if SHARED.is_dir():
        for f in SHARED.rglob("*"):
            if f.is_file():
                shared.setdefault(f.name, []).append(f)
    mirror = cwd / f"mirror-{argv[2]}"
    mirror.mkdir(exist_ok=True)
    for df in files:
        found = [f for f in shared.get(df.mirror_name, [])
                 if f.stat().st_size == df.size
                 and hashlib.sha256(f.read_bytes()).hexdigest() == df.sha256]
        if not found:
            return  # not in the shared copy: fetching it needs the internet
        (mirror / df.mirror_name).write_bytes(found[0].read_bytes())

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a: object, **k: object) -> None:
            super().__init__(*a, directory=str(mirror), **k)  # type: ignore[misc]

        def log_message(self, *a: object) -> None:
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        url = f"http://127.0.0.1:{httpd.server_address[1]}"
        dest = [] if "--dest" in argv else ["--dest", str(cwd / f"cache-{argv[2]}")]
        _avll([*argv, *dest, "--base-url", url], cwd)
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(timeout=10)


def _avll(argv: list[str], cwd: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "avll", *argv], cwd=cwd, capture_output=True,
                       text=True, timeout=900, env=_env())
    assert r.returncode == 0, f"avll {' '.join(argv)}: exit {r.returncode}\n{r.stderr[-2000:]}"


def _env() -> dict[str, str]:
    import os

    return dict(os.environ, MPLBACKEND="Agg")
