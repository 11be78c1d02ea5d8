"""The defects the last review left listed, each with a test that fails on the code
before: the blank-line scan of CSV files, the one strict-JSON reader,
exogenous signals checked in the API, a missing file, the CLI naming its options."""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import err_line

import avll
from avll import _atomic
from avll.cli import main
from avll.effect_stability import effect_stability
from avll.io import read_runs
from avll.io._common import _has_blank_line, record_lines
from avll.synth_platoon import synth_platoon


def _blank_by_regex(data: bytes) -> bool:
    """The definition: an empty or white-space-only line before the last non-blank."""
    return re.search(rb"(^|\n)[ \t]*\r?(\n|$)", data.rstrip()) is not None


def test_blank_line_scan_agrees_with_the_definition_on_every_short_text() -> None:
    alphabet = [b"a", b" ", b"\t", b"\r", b"\n", b","]
    for n in range(7):
        for t in itertools.product(alphabet, repeat=n):
            data = b"".join(t)
            if data.strip():
                assert _has_blank_line(data) == _blank_by_regex(data), data


def test_blank_line_scan_finds_a_blank_line_deep_in_a_large_file(tmp_path: Path) -> None:
    body = b"".join(b"1,%d,0,0\n" % i for i in range(200_000))
    for blank in (b"\n", b"  \n", b"\t\r\n"):
        data = b"run,t,a,command\n" + body + blank + b"1,0,0,0\n"
        assert _has_blank_line(data)
        assert not _has_blank_line(b"run,t,a,command\n" + body + b"\n\n \n")  # trailing
    p = tmp_path / "late.csv"
    p.write_bytes(b"run,t,a,command\n" + body + b"\n" + b"1,9,0,0\n")
    assert record_lines(p, 200_001)[-1] == 200_003  # the last record, past the blank line


@pytest.mark.parametrize(("text", "words"), [
    ('{"a": 1, "a": 2}', "duplicated key 'a'"),
    ('{"a": NaN}', "NaN is not a JSON number"),
    ('[Infinity]', "Infinity is not a JSON number"),
    ('[-Infinity]', "-Infinity is not a JSON number"),
    ('{"a": 1' + "0" * 5000 + "}", "integer string conversion"),
    ('{"a": \n  [1, }', "not valid JSON (line 2, column"),
    ("[" * 100_000 + "]" * 100_000, "nested too deeply to parse"),
])
def test_loads_refuses_what_strict_json_does_not_allow(text: str, words: str) -> None:
    with pytest.raises(ValueError, match=re.escape(words)):
        _atomic.loads(text)


def test_loads_reads_back_what_dumps_writes_and_bounds_the_depth() -> None:
    doc = {"a": [1.5, None, {"b": "c"}], "n": float("nan")}
    assert _atomic.loads(_atomic.dumps(doc)) == json.loads(_atomic.dumps(doc))
    assert _atomic.json_depth({"a": [1, {"b": 2}]}) == 3 and _atomic.json_depth(5) == 0
    assert _atomic.loads('{"a": [[1]]}', max_depth=3) == {"a": [[1]]}
    with pytest.raises(ValueError, match="nested deeper than 2 levels"):
        _atomic.loads('{"a": [[1]]}', max_depth=2)


def test_a_manifest_with_nan_is_not_read_as_complete(tmp_path: Path) -> None:
    with _atomic.output_dir(tmp_path / "o", meta={"command": "test"}) as d:
        (d / "x.txt").write_text("x")
    mp = tmp_path / "o" / _atomic.MANIFEST
    assert _atomic.read_manifest(tmp_path / "o")["complete"] is True
    mp.write_text(mp.read_text().replace('"complete": true', '"complete": NaN'))
    with pytest.raises(ValueError, match="NaN is not a JSON number"):
        _atomic.read_manifest(tmp_path / "o")


def test_exogenous_signals_of_absurd_magnitude_are_refused_in_the_api() -> None:
    m = avll.WithEffects(avll.FirstOrderLag(0.5), (avll.Grade(0.5),))
    u = np.zeros(50)
    # any finite disturbance is accepted (the synthetic platoon's reach beyond 1)
    assert np.all(np.isfinite(avll.simulate(m, u, 0.1, exo={"grade": np.full(50, 3.0)})))
    with pytest.raises(ValueError, match=r"exo\['grade'\]: sample 7 is 1e\+300, beyond the "
                                         r"hard limit \+-1e\+12"):
        avll.simulate(m, u, 0.1, exo={"grade": np.where(np.arange(50) == 7, 1e300, 0.0)})
    with pytest.raises(avll.DataError, match=r"run 'r': column 'exo_grade': sample 0 is 1e\+13"):
        avll.Run("r", np.arange(50) * 0.1, a=u, command=u, command_kind="acceleration",
                 exo={"grade": np.full(50, 1e13)})


def test_a_missing_file_is_a_file_not_found_error_on_every_path(tmp_path: Path) -> None:
    missing = tmp_path / "nope.csv"
    for call in (lambda: read_runs(missing), lambda: avll.io.load_canonical(missing),
                 lambda: read_runs(missing, format="generic"),
                 lambda: avll.io.load_openacc_native(missing)):
        with pytest.raises(FileNotFoundError, match="nope.csv: no such file"):
            call()


def test_cli_names_the_option_a_library_message_asks_for(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "nk.csv"
    p.write_text("run,t,a,command\n1,0,0,0\n1,0.1,0,0\n1,0.2,0,0\n")
    assert main(["load", str(p)]) == 2
    line = err_line(capsys)
    assert "pass --command-kind 'acceleration' or 'speed'" in line
    assert "command_kind" not in line


def test_stability_map_refuses_a_grid_too_large_naming_its_options(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code = main(["stability-map", "--kg", "0.01", "10", "20000", "--tg", "0", "15", "20000",
                 "--kv", "-1", "2", "20000", "--out", str(tmp_path / "m.png")])
    assert code == 2
    line = err_line(capsys)
    assert "--kg x --tg x --kv: 20000 x 20000 x 20000" in line
    assert "use a smaller N in --kg, --tg or --kv" in line
    assert not (tmp_path / "m.png").exists()


# -- one default per decision ------------------------------------------------------------


def test_weights_none_is_the_loops_default_everywhere() -> None:
    from avll.defaults import CLOSED_LOOP_WEIGHTS, EQ6_WEIGHTS, objective_weights

    assert objective_weights(None, False) == EQ6_WEIGHTS == (1.0, 0.0, 0.0)
    assert objective_weights(None, True) == CLOSED_LOOP_WEIGHTS
    assert objective_weights((2, 0, 1), True) == (2.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="weights"):
        objective_weights((-1, 0, 0), False)
    sp = synth_platoon(2, seed=3, duration=60.0, models=("first",))
    run = sp.runs[0]
    row = np.concatenate([avll.PAPER_TABLE_II["first"].to_array(), [0.5, 0.5, 1.5, 5.0]])[None]
    kw = dict(closed_loop=True, upper_free=["kg", "kv", "Tg", "Gmin"])
    default = avll.batch_cost("first", row, [run], **kw)
    assert default[0, 0] == avll.batch_cost("first", row, [run], weights=CLOSED_LOOP_WEIGHTS,
                                            **kw)[0, 0]
    assert default[0, 0] != avll.batch_cost("first", row, [run], weights=EQ6_WEIGHTS,
                                            **kw)[0, 0]
    # the calibration's cost is the closed-loop weighting's at its optimum
    res = avll.calibrate("first", [run], max_generations=2, starts=1, **kw)
    at = np.concatenate([res.model.to_array(), [res.upper[k] for k in kw["upper_free"]]])[None]
    want = avll.batch_cost("first", at, [run], weights=CLOSED_LOOP_WEIGHTS, **kw)[0, 0]
    assert res.cost == pytest.approx(want, rel=1e-12)
    assert res.weights == CLOSED_LOOP_WEIGHTS
    wf = avll.paper_workflow(sp.runs, cal_runs=[sp.runs[0].run_id], models=("first",),
                             max_generations=2, starts=1, **kw)
    assert wf.weights == CLOSED_LOOP_WEIGHTS and wf.to_json()["weights"] == [1.0, 1.0, 0.01]
    assert "(wa, wv, wx) = (1, 1, 0.01)" in wf.to_text() and "MSE (m/s^2)^2" not in wf.to_text()
    from avll.synth import paper_experiment

    open_wf = avll.paper_workflow(paper_experiment(seed=0, duration=20.0), cal_runs=None,
                                  models=("first",), max_generations=2, starts=1)
    assert open_wf.weights == EQ6_WEIGHTS and "Calibration MSE (m/s^2)^2" in open_wf.to_text()


def test_calibrate_many_starts_like_calibrate_with_subsets() -> None:
    sp = synth_platoon(2, seed=4, duration=40.0, models=("first",))
    kw = dict(closed_loop=True, upper_free=["kg", "kv", "Tg", "Gmin"], seed=5,
              max_generations=3)
    many = avll.calibrate_many("first", sp.runs, "per_run", **kw)
    via = avll.calibrate("first", sp.runs, subsets="per_run", **kw)
    assert [m.params for m in many] == [m.params for m in via]
    assert all(len(m.start_costs) == avll.defaults.DEFAULT_STARTS for m in many)


def test_stability_map_default_axes_are_reproduces_bit_for_bit() -> None:
    from avll.cli.stability_map import _range
    from avll.paper import SECTION_IV_GRID as G
    from avll.reproduce import SETTINGS

    want = SETTINGS["default"].axes()
    got = (_range([f"{x!r}" for x in G["kg"]], "kg", log=True),
           _range([f"{x!r}" for x in G["Tg"]], "tg"), _range([f"{x!r}" for x in G["kv"]], "kv"))
    for w, g in zip(want, got, strict=True):
        np.testing.assert_array_equal(w, g)
    fine = _range(["0", "1e-9", "11"], "kv")  # steps below 10 decimals are not rounded away
    assert np.unique(fine).size == 11


def test_effect_stability_progress_modes(capsys: pytest.CaptureFixture[str]) -> None:
    up = avll.UpperLevel(kg=0.5, kv=0.5, Tg=2.0, Gmin=5.0)
    kw = dict(amplitudes=(0.5,), n_cars=2, thresholds=False, warm_periods=1,
              measure_periods=1)
    with pytest.raises(ValueError, match="progress"):
        effect_stability(avll.PAPER_TABLE_II["first"], up, progress="loud", **kw)
    effect_stability(avll.PAPER_TABLE_II["first"], up, progress="none", **kw)
    assert capsys.readouterr().err == ""
    effect_stability(avll.PAPER_TABLE_II["first"], up, progress="log", **kw)
    assert "platoon" in capsys.readouterr().err


def test_write_runs_round_trips_exactly(tmp_path: Path) -> None:
    """The canonical CSV was written with 10 significant digits: a run read back
    differed from the one written (a time of 123456.789012345 s came back rounded)."""
    rng = np.random.default_rng(1)
    t = 123456.789012345 + np.arange(200) * 0.05
    a = rng.normal(size=200) * np.pi
    run = avll.Run("r1", t, a=a, command=a / 3, command_kind="acceleration",
                   v=20 + np.cumsum(a) * 0.05, exo={"grade": rng.normal(size=200) / 97})
    back = read_runs(avll.io.write_runs([run], tmp_path / "r.csv"))[0]
    for name in ("t", "a", "command", "v"):
        np.testing.assert_array_equal(getattr(back, name), getattr(run, name))
    np.testing.assert_array_equal(back.exo["grade"], run.exo["grade"])
