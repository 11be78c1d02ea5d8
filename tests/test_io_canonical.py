"""The canonical run format: round trip and bad input naming file, column and line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import avll
from avll.io import read_runs, write_runs
from avll.synth import paper_experiment


@pytest.fixture(scope="module")
def runs() -> list[avll.Run]:
    return paper_experiment(seed=3, runs=(1, 3), duration=20.0)


def test_round_trip_csv(tmp_path: Path, runs: list[avll.Run]) -> None:
    path = write_runs(runs, tmp_path / "r.csv")
    back = read_runs(path)
    assert [r.run_id for r in back] == ["1", "3"]
    for a, b in zip(runs, back, strict=True):
        assert b.command_kind == "acceleration"
        assert b.upper == a.upper
        for name in ("t", "a", "command", "v", "x", "lead_x", "lead_v"):
            np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=1e-9, atol=1e-9)
        assert b.meta["true_model"]["name"] == "proposed"


def test_round_trip_parquet(tmp_path: Path, runs: list[avll.Run]) -> None:
    pytest.importorskip("pyarrow")
    path = write_runs(runs, tmp_path / "r.parquet")
    back = read_runs(path)
    np.testing.assert_array_equal(back[1].a, runs[1].a)


def test_exogenous_columns_round_trip(tmp_path: Path) -> None:
    t = np.arange(50) * 0.1
    run = avll.Run("g", t, np.sin(t), command=np.cos(t), exo={"grade": 0.01 * t})
    back = read_runs(write_runs([run], tmp_path / "g.csv"))
    np.testing.assert_allclose(back[0].exo["grade"], 0.01 * t)


def _write(tmp_path: Path, text: str, kind: str | None = "acceleration") -> Path:
    p = tmp_path / "bad.csv"
    p.write_text(text)
    if kind:
        (tmp_path / "bad.csv.meta.json").write_text(json.dumps({"command_kind": kind}))
    return p


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("", "empty"),
        ("run,t,a\n", "no data rows"),
        ("run,t,command\n1,0,1\n1,0.1,1\n", "missing column(s) 'a'"),
        ("run,t,a\n1,0,1\n1,0.1,1\n1,0.05,1\n", "column 't' line 4: time goes backwards"),
        ("run,t,a\n1,0,1\n1,0.1,1\n1,0.1,1\n", "column 't' line 4: time repeats"),
        ("run,t,a\n1,0,1\n1,0.1,nan\n", "column 'a' line 3: 'nan' is not a number"),
        ("run,t,a\n1,0,1\n1,0.1,\n", "column 'a' line 3: is empty"),
        ("run,t,a\n1,0,1\n1,0.1,abc\n", "column 'a' line 3: 'abc' is not a number"),
        ("run,t,a\n1,0,1\n1,0.1,inf\n", "column 'a' line 3: value inf is not finite"),
        ("run,t,a\n1,0,1\n1,0.1,1\n1,0.2,1\n1,0.5,1\n", "line 5: non-uniform sampling"),
        ("run,t,a\n1,0,1\n2,0,1\n2,0.1,1\n1,0.1,1\n", "not contiguous"),
    ],
)
def test_bad_input_names_file_column_line(tmp_path: Path, text: str, fragment: str) -> None:
    p = _write(tmp_path, text)
    before = p.read_bytes()
    with pytest.raises(avll.DataError) as e:
        read_runs(p)
    assert fragment in str(e.value)
    assert str(p) in str(e.value)
    assert p.read_bytes() == before  # input untouched


def test_command_kind_required(tmp_path: Path) -> None:
    p = _write(tmp_path, "run,t,a\n1,0,1\n1,0.1,1\n", kind=None)
    with pytest.raises(avll.DataError, match="command kind is not given"):
        read_runs(p)
    assert read_runs(p, command_kind="speed")[0].command_kind == "speed"


def test_unknown_format_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown format 'nope'"):
        read_runs(tmp_path, format="nope")
    with pytest.raises(FileNotFoundError, match="missing.csv: no such file"):
        read_runs(tmp_path / "missing.csv")
