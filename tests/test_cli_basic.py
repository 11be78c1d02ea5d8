"""The CLI: sub-commands run, bad input gives a one-line error and exit code 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from avll.cli import main


def test_simulate_writes_outputs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "simulate.png").stat().st_size > 1000
    assert "proposed" in capsys.readouterr().out


def test_synth_writes_canonical(tmp_path: Path) -> None:
    out = tmp_path / "runs.csv"
    assert main(["synth", "--out", str(out), "--duration", "20"]) == 0
    assert out.exists() and (tmp_path / "runs.csv.meta.json").exists()


def test_bad_input_is_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["synth", "--out", str(tmp_path / "x.csv"), "--noise-a", "-1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--noise-a:" in err and "Traceback" not in err
