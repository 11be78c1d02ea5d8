"""Output paths are checked before any computation; no command writes over one of its
inputs; ``stability-map --from`` maps a calibration JSON."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from cli_helpers import err_line

import avll
from avll.cli import main
from avll.paper import section_iv_axis

# a grid that takes many seconds: a failure must come before it is computed
_BIG = ["--kg", "0.001", "2", "2000", "--tg", "0", "15", "1501", "--kv", "0", "1", "201"]


def test_bad_json_fails_fast_before_work(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    fig = tmp_path / "fig.png"
    t0 = time.perf_counter()
    rc = main(["stability-map", *_BIG, "--out", str(fig), "--json", str(blocker / "x.json")])
    assert rc == 2 and time.perf_counter() - t0 < 5.0
    err_line(capsys, "--json", "is a file, not a folder")
    assert not fig.exists()


def test_json_that_is_a_folder_fails_fast(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["stability-map", *_BIG, "--out", str(tmp_path / "f.png"), "--json",
               str(tmp_path)])
    assert rc == 2
    err_line(capsys, "--json", "is a folder")


def test_output_folder_that_is_a_file(tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "out"
    f.write_text("x")
    assert main(["simulate", "--out", str(f)]) == 2
    err_line(capsys, "--out", "not a folder")


def test_unwritable_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import os

    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("running as a user who can write anywhere (root)")
        assert main(["stability-map", *_BIG, "--out", str(ro / "f.png")]) == 2
        err_line(capsys, "--out", "not writable")
    finally:
        ro.chmod(0o700)


def test_no_command_writes_over_its_input(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "runs.csv"
    assert main(["synth", "--out", str(data), "--duration", "20"]) == 0
    before = data.read_bytes()
    capsys.readouterr()
    for argv in (["calibrate", str(data), "--json", str(data)],
                 ["calibrate", str(data), "--figure", str(data)],
                 ["load", str(data), "--json", str(data)]):
        assert main(argv) == 2
        err_line(capsys, "would replace the input")
    assert data.read_bytes() == before
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"models": {"first": {"params": {"Td": 1.0}}}}))
    assert main(["stability-map", "--from", str(cal), "--json", str(cal)]) == 2
    err_line(capsys, "--json", "would replace the input")
    assert main(["stability-map", "--from", str(cal), "--json", str(tmp_path / "a.json"),
                 "--out", str(tmp_path / "a.json")]) == 2
    err_line(capsys, "also the output")


def test_stability_map_from_calibration_json(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """avll calibrate --json, then avll stability-map --from: the thresholds are those of
    the calibrated models computed through the API."""
    data = tmp_path / "runs.csv"
    assert main(["synth", "--out", str(data), "--duration", "20"]) == 0
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(data), "--models", "second,proposed", "--max-generations",
                 "40", "--starts", "1", "-q", "--json", str(cal)]) == 0
    out = tmp_path / "map.json"
    grid = ["--kg", "0.01", "2", "30", "--tg", "0", "15", "31", "--kv", "0", "1", "11"]
    assert main(["stability-map", "--from", str(cal), *grid, "--out",
                 str(tmp_path / "map.png"), "--thresholds-out", str(tmp_path / "th.png"),
                 "--json", str(out)]) == 0
    assert "models: calibrated (cal.json)" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["source"] == {"kind": "calibration", "path": str(cal)}
    caldoc = json.loads(cal.read_text())
    kg, tg, kv = (section_iv_axis(0.01, 2, 30, log=True), section_iv_axis(0, 15, 31),
                  section_iv_axis(0, 1, 11))  # the CLI's axes
    for name in ("second", "proposed"):
        params = caldoc["models"][name]["params"]
        assert doc["models"][name]["params"] == params
        model = avll.model_class(name)(**params)
        th = avll.thresholds(avll.stability_map(model, kg, tg, kv), kg, tg, kv)
        assert doc["models"][name] | {"params": None} == th.to_dict() | {
            "params": None, "capacity_at_min_tg": doc["models"][name]["capacity_at_min_tg"]}
    # something is stable: the comparison is not only between empty maps
    assert doc["models"]["proposed"]["tg_min_overall"] is not None
    # --models picks among the file's models; a model not in the file is an error
    assert main(["stability-map", "--from", str(cal), "--models", "proposed", *grid,
                 "--out", str(tmp_path / "p.png")]) == 0
    capsys.readouterr()
    assert main(["stability-map", "--from", str(cal), "--models", "first", *grid,
                 "--out", str(tmp_path / "p.png")]) == 2
    err_line(capsys, "first not in")


def test_stability_map_from_bad_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                     ) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{nope")
    assert main(["stability-map", "--from", str(bad), "--out", str(tmp_path / "x.png")]) == 2
    err_line(capsys, "--from", "not valid JSON")
    bad.write_text(json.dumps({"models": {"second": {"params": {"K0": None}}}}))
    assert main(["stability-map", "--from", str(bad), "--out", str(tmp_path / "x.png")]) == 2
    err_line(capsys, "models.second.params.K0")
    assert main(["stability-map", "--from", str(tmp_path / "none.json")]) == 2
    err_line(capsys, "none.json")
