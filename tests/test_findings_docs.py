"""The field-data pages' generated numbers are not stale.

``docs/gen/fielddata.py`` (``python -m docs.gen --only fielddata-PART``) writes
``docs/_generated/fielddata_*.md`` and their numbers ``fielddata_*.json``;
``docs/findings.md`` and ``docs/guide/field-data.md`` include the fragments. These
tests recompute the cheap parts (the loaders' statistics, the grade scans and the
paper's Table II models driven by the CARMA speed command: seconds) from
``../shared/data`` and compare them with the committed JSON and fragments, so a
fragment that the code no longer reproduces fails. The GA studies (minutes) are not
rerun here.
"""

from __future__ import annotations

import importlib
import json
import math
import re
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

pytestmark = pytest.mark.data

ROOT = Path(__file__).resolve().parents[1]
GEN = ROOT / "docs" / "_generated"
STALE = "stale: rerun python -m docs.gen --only fielddata-PART (then commit docs/_generated)"


def _script() -> ModuleType:
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    return importlib.import_module("docs.gen.fielddata")


def _close(a: Any, b: Any, where: str = "") -> None:
    """``a`` (recomputed, through strict JSON) equals ``b`` (committed) to 1e-9."""
    if isinstance(b, dict):
        assert isinstance(a, dict) and set(a) == set(b), f"{where}: keys differ; {STALE}"
        for k in b:
            _close(a[k], b[k], f"{where}.{k}")
    elif isinstance(b, list):
        assert isinstance(a, list) and len(a) == len(b), f"{where}: lengths differ; {STALE}"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, f"{where}[{i}]")
    elif isinstance(b, float) and not isinstance(a, bool):
        assert isinstance(a, (int, float)), f"{where}: {a!r} vs {b!r}; {STALE}"
        assert math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12), f"{where}: {a} vs {b}; {STALE}"
    else:
        assert a == b, f"{where}: {a!r} vs {b!r}; {STALE}"


@pytest.fixture(scope="module")
def script() -> ModuleType:
    return _script()


@pytest.mark.parametrize("part", ["loaders", "grade"])
def test_cheap_parts_reproduce(part: str, shared_data: Path, script: ModuleType) -> None:
    from avll import _atomic

    committed = json.loads((GEN / f"fielddata_{part}.json").read_text())
    fresh = json.loads(_atomic.dumps(script.COMPUTE[part](shared_data, seed=0, threads=1)))
    _close(fresh, committed, part)
    # the committed fragment is what the renderer makes of these numbers
    frag = (GEN / f"fielddata_{part}.md").read_text()
    body = importlib.import_module("docs.gen").body  # the fragment without its stamp
    assert script.RENDER[part](fresh).rstrip("\n") == body(frag), f"fielddata_{part}.md is {STALE}"


def test_table_ii_transfer_reproduces(shared_data: Path, script: ModuleType) -> None:
    """The first look's Table II rows (DC gain, speed and acceleration MSE of the paper's
    models driven by the CARMA speed command) match the committed fragment."""
    fresh = script.table_ii_transfer(script.carma_runs(shared_data))
    frag = (GEN / "fielddata_firstlook.md").read_text()
    if "has not been run" in frag:
        pytest.fail(f"fielddata_firstlook.md: the part was not run; {STALE}")
    for name, e in fresh.items():
        row = (f"| {name} | {e['dc_gain']:.3g} | {e['mse_v']:.3g} | {e['mse_a']:.3g} |")
        assert row in frag, f"fielddata_firstlook.md lacks {row!r}; {STALE}"


def test_pages_include_fragments_and_type_no_study_numbers() -> None:
    """Both pages include their fragments, and none of the old hand-typed note remains."""
    pages = {ROOT / "docs" / "findings.md": ("fielddata_summary", "fielddata_firstlook",
                                             "fielddata_closed", "fielddata_carma",
                                             "fielddata_astazero"),
             ROOT / "docs" / "guide" / "field-data.md": ("fielddata_loaders",
                                                         "fielddata_grade")}  # fmt: skip
    for page, frags in pages.items():
        text = page.read_text()
        assert "not yet regenerated" not in text, page
        for f in frags:
            assert re.search(rf"```{{include}} [./]*_generated/{f}\.md", text), (page, f)
            assert (GEN / f"{f}.md").is_file(), f
