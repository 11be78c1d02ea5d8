"""The documentation's examples run (the generated fragments: tests/test_docs_gen.py).

Every ```python block of a page under docs/ runs, in page order and in one namespace
per page, in a temporary folder (blocks that read the field data run when
../shared/data is present and are skipped otherwise). A block whose first line is a
comment starting with "# not run by the docs tests" is skipped; the comment says why.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SHARED = ROOT.parent / "shared" / "data"
SKIP_MARK = "# not run by the docs tests"

PAGES = sorted(
    p for p in DOCS.rglob("*.md")
    if not ({"_build", "_generated"} & set(p.relative_to(DOCS).parts))
)


def _blocks(page: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", page.read_text(encoding="utf-8"), re.S | re.M)


def test_docs_have_runnable_examples() -> None:
    with_code = [p.relative_to(DOCS).as_posix() for p in PAGES if _blocks(p)]
    assert {"guide/simulate.md", "guide/calibrate.md", "guide/stability.md",
            "guide/diagnose.md", "guide/field-data.md"} <= set(with_code)


@pytest.mark.slow
@pytest.mark.parametrize(
    "page", [p for p in PAGES if _blocks(p)], ids=lambda p: p.relative_to(DOCS).as_posix()
)
def test_docs_examples_run(page: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import matplotlib

    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    ran = 0
    for i, code in enumerate(_blocks(page)):
        if code.lstrip().startswith(SKIP_MARK):
            continue
        if "shared/data" in code:
            if not SHARED.is_dir():
                continue
            code = code.replace("../shared/data", str(SHARED))
        code = code.replace("progress=True", "progress=False")
        exec(compile(code, f"{page.relative_to(ROOT)} block {i + 1}", "exec"), ns)
        ran += 1
    if ran == 0:
        pytest.skip(f"{page.name}: every example needs ../shared/data (absent)")
