"""The numbers of docs/guarantees.md are the code's (no number typed by hand)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from avll import _core, _limits
from avll.io import _common, canonical

DOC = Path(__file__).resolve().parents[1] / "docs" / "guarantees.md"

ROWS = {
    "speed (m/s)": "speed",
    "acceleration, acceleration command (m/s²)": "acceleration",
    "time step (s)": "time_step",
    "grade (rise over run)": "grade",
    "position (m)": "position",
    "any other signal": "other",
}


def _num(s: str) -> float:
    return float(s.replace("abs", "").strip())


@pytest.fixture(scope="module")
def text() -> str:
    return DOC.read_text(encoding="utf-8")


def test_range_table_is_the_code(text: str) -> None:
    seen = set()
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0] in ROWS:
            rg = _common.RANGES[ROWS[cells[0]]]
            lo, hi = (_num(x) for x in cells[1].split(".."))
            assert (lo, hi, _num(cells[2])) == (rg.lo, rg.hi, rg.hard), line
            seen.add(cells[0])
    assert seen == set(ROWS)


def test_other_numbers_are_the_code(text: str) -> None:
    assert f"`0 .. {_core.THREADS_PER_CORE} x cores`" in text
    assert f"{round(100 * _limits.MEMORY_FRACTION)} % of what the process" in text
    assert f"less than {_limits.SMALL // 2**20} MiB" in text
    assert f"deeper than {canonical.MAX_SIDECAR_DEPTH} levels" in text
    assert f"larger than {canonical.MAX_SIDECAR_BYTES // 2**20} MB" in text
    assert _common.MAX_TIME_GAP == 86400.0 and "longer than a day" in text
    assert f"imply more than {_common.MAX_POSITION_RATE:g} m/s" in text
    m = re.search(r"more than (\d+) x the C available cores", text)
    assert m is None or int(m.group(1)) == _core.THREADS_PER_CORE
