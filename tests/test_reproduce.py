"""Tests of ``avll reproduce`` (the paper end to end)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from avll import reproduce as R
from avll.cli import main
from avll.report import Report, diff, fmt

# Tiny budgets: short runs, a very small GA, coarse grids, no residual loop by default.
TINY = replace(R.SETTINGS["quick"], duration=30.0, max_generations=3, kg_n=16, tg_step=1.0,
               kv_step=0.2, kv_tg_step=1.0, kv_tol=0.05, diagnosis=False,
               field_max_generations=3)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("repro")
    s = R.reproduce(out, settings=TINY, seed=1, progress=False)
    return out, s


def test_summary_keys(tiny: tuple[Path, dict]) -> None:
    out, s = tiny
    def refuse(token: str) -> None:
        raise ValueError(f"non-strict JSON token {token}")

    on_disk = json.loads((out / "summary.json").read_text(), parse_constant=refuse)
    for doc in (s, on_disk):
        assert set(R.MODELS) <= set(doc["stability"])
        assert set(R.MODELS) <= set(doc["calibration"])
        for m in R.MODELS:
            assert {"kv_threshold", "min_tg", "capacity"} <= set(doc["stability"][m])
            assert {"kv_threshold", "min_tg", "capacity"} <= set(doc["stability_calibrated"][m])
            c = doc["calibration"][m]
            assert {"params", "cal_mse", "val_mse"} <= set(c)
            assert c["cal_mse"] > 0 and c["val_mse"] > 0
        assert {"base_model", "steps", "effects"} <= set(doc["diagnosis"])
    # the calibrated parameter names are the models' own
    assert set(on_disk["calibration"]["proposed"]["params"]) == {"m1", "m2", "m3", "K0", "Td",
                                                                   "K"}
    assert on_disk["data"]["cal_runs"] == [str(r) for r in (3, 4, 5, 9, 10, 11, 15, 16, 17, 19)]


def test_report_files_and_paper_numbers(tiny: tuple[Path, dict]) -> None:
    out, s = tiny
    md = (out / "report.md").read_text(encoding="utf-8")
    ht = (out / "report.html").read_text(encoding="utf-8")
    figs = s["files"]["figures"]
    assert {"fig3", "fig4", "fig5_table2", "fig6_table2", "fig7_table2", "fig8_table2",
            "fig5_calibrated", "fig8_calibrated"} <= set(figs)
    for fn in figs.values():
        p = out / fn
        assert p.exists() and p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert fn in md and fn in ht
    for text in (md, ht):
        for paper in ("0.0398", "0.0551", "0.1232", "0.0871", "0.1213", "0.2587", "0.8085",
                      "0.7395", "1687.5", "964.3", "1479.5", "42.86", "53.42", "6.7893"):
            assert paper in text, paper
    # our numbers are next to them: the averages we computed appear in the tables
    for m in R.MODELS:
        assert fmt(s["calibration"][m]["cal_mse"]) in md
        assert fmt(s["calibration"][m]["val_mse"]) in md
    assert "cannot equal" in md and ht.startswith("<!DOCTYPE html>")


def test_stability_summary_tiny_grid() -> None:
    import avll

    st = R.stability_summary(avll.PAPER_TABLE_II["second"], TINY)
    kg, tg, kv = TINY.axes()
    assert st["codes"].shape == (kg.size, tg.size, kv.size)
    # on a 1 s Tg grid the minimum stable Tg of the second-order model is 2 s (exact 1.857)
    assert st["min_tg"] == pytest.approx(2.0)
    assert st["kv_threshold"] is not None and 0.7 < st["kv_threshold"] < 0.9
    # the first-order lag: no kv threshold up to kv_max (stable at large kv)
    st1 = R.stability_summary(avll.PAPER_TABLE_II["first"], TINY)
    assert st1["kv_threshold"] is None and st1["min_tg"] == pytest.approx(3.0)


def test_report_writer(tmp_path: Path) -> None:
    r = Report("t")
    r.heading("H")
    r.para("a **b** `c`")
    r.table(["x", "y"], [["a|b", 1.23456], ["n", None]])
    md, ht = r.write(tmp_path)
    text = md.read_text()
    assert "| a\\|b | 1.235 |" in text and "| n | — |" in text
    assert "<strong>b</strong>" in ht.read_text() and "<code>c</code>" in ht.read_text()
    assert diff(1.1, 1.0) == "+0.1 (+10.0 %)" and diff(None, 1) == "—"


def test_cli_summary_says_none_without_a_unit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    # a model without a kv threshold prints "kv* none", not "kv* none 1/s"
    st = {"kv_threshold": None, "min_tg": 2.2, "capacity": 1479.46}
    summary = {"files": {"summary_json": "s.json"}, "timing_s": {"total": 1.0},
               "calibration": {m: {"cal_mse": 0.01, "val_mse": None} for m in R.MODELS},
               "stability": {m: {**st, "kv_threshold": 0.7398 if m == "second" else None}
                             for m in R.MODELS}}
    monkeypatch.setattr(R, "reproduce", lambda *a, **k: summary)
    assert main(["reproduce", "--out", str(tmp_path / "o"), "-q"]) == 0
    lines = capsys.readouterr().out.splitlines()
    first = next(ln for ln in lines if ln.strip().startswith("first"))
    second = next(ln for ln in lines if ln.strip().startswith("second"))
    assert "val none | Table II: kv* none, min Tg 2.2 s, capacity 1479.5 veh/h" in first
    assert "kv* 0.7398 1/s, min Tg 2.2 s" in second


def test_cli_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["reproduce", "--out", str(tmp_path), "--data", "carma", "--data-path",
               str(tmp_path / "nope"), "-q"])
    assert rc == 2
    assert "--data-path" in capsys.readouterr().err


@pytest.mark.data
def test_real_data_carma_quick(tmp_path: Path) -> None:
    data = Path(__file__).resolve().parents[2] / "shared" / "data" / "carma"
    if not data.exists():
        pytest.skip("no ../shared/data/carma")
    s = R.reproduce(tmp_path, data="carma", data_path=data, settings=TINY, progress=False)
    assert s["data"]["name"] == "carma"
    assert set(R.MODELS) <= set(s["calibration"]) and s["stability_calibrated"] is None
    assert s["stability"]["second"]["min_tg"] == pytest.approx(2.0)  # Table II, 1 s grid
    md = (tmp_path / "report.md").read_text()
    assert "speed** command" in md and "skipped" in md and "Table I experiment" in md
    for fn in s["files"]["figures"].values():
        assert (tmp_path / fn).exists()


def test_ctrl_c_stops_cleanly(tmp_path: Path) -> None:
    """SIGINT during the default run (once its first figure is staged, with the
    stability maps and the diagnosis still to come): exit 130, one line, no traceback,
    no summary written."""
    import subprocess
    import sys

    from signal_helpers import SIGINT_DEFAULT, interrupt_once_staged

    p = subprocess.Popen([sys.executable, "-m", "avll.cli", "reproduce", "--out",
                          str(tmp_path), "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, **SIGINT_DEFAULT)
    interrupt_once_staged(p, tmp_path)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert not (tmp_path / "summary.json").exists()


@pytest.mark.slow
def test_default_reproduce(tmp_path: Path) -> None:
    """The default run: Section IV with Table II parameters as in README § Stability maps,
    and the calibrated models ranked as in the paper."""
    rc = main(["reproduce", "--out", str(tmp_path), "-q"])
    assert rc == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    st = s["stability"]
    assert st["second"]["min_tg"] == pytest.approx(1.9)
    assert st["proposed"]["min_tg"] == pytest.approx(3.5)
    assert st["first"]["min_tg"] == pytest.approx(2.2)
    assert abs(st["second"]["kv_threshold"] - 0.8085) < 1e-3
    assert abs(st["proposed"]["kv_threshold"] - 0.7395) < 1e-3
    assert st["first"]["kv_threshold"] is None
    assert st["second"]["capacity"] == pytest.approx(1687.5, abs=0.05)
    assert st["proposed"]["capacity"] == pytest.approx(964.3, abs=0.05)
    assert st["first"]["capacity"] == pytest.approx(1479.5, abs=0.05)
    c = s["calibration"]
    assert c["proposed"]["val_mse"] < c["second"]["val_mse"] < c["first"]["val_mse"]
    assert c["proposed"]["cal_mse"] < c["second"]["cal_mse"] < c["first"]["cal_mse"]
    assert (tmp_path / "report.html").exists()


def test_diagnosis_section_reads_the_loops_json(tmp_path) -> None:
    # The report's diagnosis table reads the cross-validated loop's JSON keys: a real
    # loop result (an accepted effect, a candidate not accepted) shows its numbers, no
    # dash where the loop gave a number.
    from avll import FirstOrderLag
    from avll.diagnose import effect_loop
    from avll.report import Report
    from avll.reproduce import _diag_section
    from avll.synth_effects import paper_experiment_effects

    runs = paper_experiment_effects(FirstOrderLag(Td=1.0758), {"rate_limit": {"j": 1.0}},
                                    seed=0, leader_speedup=3.0, runs=(1, 3, 8, 12, 15))
    res = effect_loop("first", runs[:3], runs[3:], seed=1, max_generations=25)
    d = res.to_dict() | {"available": True}
    assert d["steps"], "the known effect should be accepted here"
    rep = Report("t")
    _diag_section(rep, d, synthetic=True)
    rep.write(tmp_path)
    text = (tmp_path / "report.md").read_text()
    step = d["steps"][0]
    row = next(ln for ln in text.splitlines() if ln.startswith(f"| {step['effect']} |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert "—" not in cells, row
    assert float(cells[-2]) == pytest.approx(step["fold_selection"], abs=5e-3)
