"""``avll study openacc``: the setting-order check, the
amplification measures, the JSON contract and the CLI's exit codes. The GA budget is
tiny here (the numbers of the study come from its default budget)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from loader_helpers import NO_DATA, ZALA, native_platoon, write_native

import avll
from avll import FirstOrderLag, Proposed, SecondOrder, UpperLevel, _atomic, closed_loop
from avll.cli import main
from avll.reference.stability import closed_loop_polys
from avll.studies import openacc as st

FAST = ["--max-generations", "3", "--pop-size", "8", "--starts", "1", "--bootstrap", "100",
        "--model", "first", "--models", "first", "-q"]
CONTRACT = {"file", "car", "setting", "position", "params", "Tg", "cal_mse",
            "amplification_measured", "amplification_measured_ci", "amplification_predicted"}


def test_setting_order_logic():
    rows = [
        {"car": "A", "setting": "L", "Tg": 2.0}, {"car": "A", "setting": "L", "Tg": 1.8},
        {"car": "A", "setting": "S", "Tg": 1.0},
        {"car": "B", "setting": "L", "Tg": 0.5}, {"car": "B", "setting": "M", "Tg": 1.0},
        {"car": "B", "setting": "S", "Tg": 0.2},
        {"car": "C", "setting": "S", "Tg": 1.0},  # one setting only: no check
        {"car": "D", "setting": "L", "Tg": math.nan}, {"car": "D", "setting": "S", "Tg": 1.0},
        {"car": "E", "setting": None, "Tg": 3.0}, {"car": "E", "setting": "S", "Tg": 1.0},
    ]
    o = st.setting_order(rows)
    # A: L>S held; B: L>M failed, L>S held, M>S held
    assert o["checked"] == 4 and o["held"] == 3
    failed = [c for c in o["checks"] if not c["held"]]
    assert [(c["car"], c["longer"], c["shorter"]) for c in failed] == [("B", "L", "M")]
    a = [c for c in o["checks"] if c["car"] == "A"][0]
    assert a["value_longer"] == pytest.approx(1.9) and a["n_longer"] == 2
    assert o["file_pairs_checked"] == 5 and o["file_pairs_held"] == 4
    assert st.setting_order([])["checked"] == 0


@pytest.mark.parametrize("model", [FirstOrderLag(0.6), SecondOrder(0.9, 0.1, 0.5, 0.0),
                                   Proposed(0.2, 0.5, 1.5, 0.8, 0.0, 0.1)])
def test_transfer_gain_matches_eq8_without_delay(model):
    up = UpperLevel(kg=0.3, kv=0.7, Tg=1.4, Gmin=5.0)
    n, d = closed_loop_polys(model, up.kg, up.Tg, up.kv)
    f = np.array([0.01, 0.05, 0.1, 0.3, 1.0])
    s = 2j * np.pi * f
    np.testing.assert_allclose(st.transfer_gain(model, up, f),
                               np.abs(np.polyval(n, s) / np.polyval(d, s)), rtol=1e-10)


def test_transfer_gain_true_delay_vs_high_order_pade():
    model = Proposed(0.2, 0.5, 1.5, 0.8, 0.4, 0.1)
    up = UpperLevel(kg=0.3, kv=0.7, Tg=1.4, Gmin=5.0)
    n, d = closed_loop_polys(model, up.kg, up.Tg, up.kv, pade_order=8)
    f = np.array([0.01, 0.05, 0.2])
    s = 2j * np.pi * f
    np.testing.assert_allclose(st.transfer_gain(model, up, f),
                               np.abs(np.polyval(n, s) / np.polyval(d, s)), rtol=1e-8)


def test_amplification_of_a_scaled_oscillation():
    dt = 0.1
    t = np.arange(0, 300, dt)
    rng = np.random.default_rng(0)
    lead = 10 + 0.5 * np.sin(2 * np.pi * 0.05 * t) + 0.01 * rng.standard_normal(t.size)
    v = 10 + 1.3 * 0.5 * np.sin(2 * np.pi * 0.05 * (t - 2.0))
    a, rf, rp = st.amplification(v, lead, dt)
    assert a == pytest.approx(1.3, rel=0.02)
    assert rp == pytest.approx(0.5 / np.sqrt(2), rel=0.05)
    lo, hi = st.bootstrap_ci(st.bandpass(v, dt), st.bandpass(lead, dt), dt, n=300)
    assert lo < a < hi and hi - lo < 0.2
    with pytest.raises(ValueError, match="band"):
        st.bandpass(v, dt, (0.3, 0.1))


def test_replay_and_H_agree_for_a_linear_car():
    """The linear closed loop replayed behind a sinusoidal leader amplifies by |H| at
    that frequency: the two predictions and the measurement agree."""
    dt = 0.1
    t = np.arange(0, 600, dt)
    w = 2 * np.pi * 0.06
    lead_v = 10 + 0.6 * np.sin(w * t)
    lead_x = 10 * t - 0.6 / w * np.cos(w * t) + 200.0
    model = SecondOrder(1.0, 0.2, 0.8, 0.3)
    up = UpperLevel(kg=0.25, kv=0.8, Tg=1.2, Gmin=4.0)
    x0 = float(lead_x[0]) - up.Gmin - up.Tg * 10.0
    tr = closed_loop(model, lead_x, lead_v, dt, up, v0=10.0, x0=x0)
    meas = st.amplification(tr.v[1000:], lead_v[1000:], dt)[0]
    h = float(st.transfer_gain(model, up, [0.06])[0])
    pred = st.predicted_amplification(model, up, lead_v[1000:], dt)
    assert meas == pytest.approx(h, rel=0.01)
    assert pred == pytest.approx(h, rel=0.02)


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("native")
    p = native_platoon(n=1200)
    write_native(d / "long_setting" / "dynamic_part1.csv", p, setting="L")
    write_native(d / "short_setting" / "dynamic_part2.csv", native_platoon(n=1200, tg=0.8),
                 setting="S")
    write_native(d / "no_ACC" / "handling_part3.csv", p, acc="0", setting="")
    return d


def test_cli_contract(study_dir, tmp_path, capsys):
    out, js = tmp_path / "out", tmp_path / "res" / "study.json"
    assert main(["study", "openacc", str(study_dir), "--out", str(out), "--json", str(js),
                 "--seed", "3", *FAST]) == 0
    assert "setting order held" in capsys.readouterr().out

    def strict(x):
        raise ValueError(f"non-strict JSON constant {x}")

    doc = json.loads(js.read_text(), parse_constant=strict)
    assert doc == json.loads((out / "summary.json").read_text())
    assert len(doc["cars"]) == 9
    for c in doc["cars"]:
        assert CONTRACT <= set(c)
        assert c["setting"] in ("L", "S", None) and isinstance(c["position"], int)
        assert set(c["params"]) == {"Td", "kg", "kv", "Tg", "Gmin"}
        assert c["Tg"] == c["params"]["Tg"]
        assert len(c["amplification_measured_ci"]) == 2
        for k in ("Tg", "cal_mse", "amplification_measured", "amplification_predicted"):
            assert c[k] is not None or f"{k}_reason" in c
    so = doc["setting_order"]
    assert set(so) >= {"checked", "held"} and 0 <= so["held"] <= so["checked"]
    # the same three cars are under L and S: one check per car model
    assert so["checked"] == 3
    assert doc["seed"] == 3 and doc["model"] == "first"
    for name in ("cars.csv", "models.csv", "tg_by_car_setting.csv", "setting_order.csv",
                 "model_comparison.csv", "files.csv", "amplification.png", "tg_setting.png",
                 "report.md"):
        assert (out / name).stat().st_size > 0, name
    assert not list(out.glob(".*.tmp"))
    assert "## Findings" in (out / "report.md").read_text()


def test_cli_exit_codes(study_dir, tmp_path, capsys, monkeypatch):
    f = tmp_path / "afile"
    f.write_text("x")
    assert main(["study", "openacc", str(study_dir), "--out", str(f), *FAST]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["study", "openacc", str(study_dir), "--out", str(tmp_path / "o"), "--json",
                 str(tmp_path), *FAST]) == 2
    assert "--json" in capsys.readouterr().err
    assert main(["study", "openacc", str(tmp_path / "nope"), "--out", str(tmp_path / "o"),
                 *FAST]) == 2
    assert main(["study", "openacc", str(study_dir), "--out", str(tmp_path / "o"), "--band",
                 "0.3,0.1", *FAST]) == 2
    assert "band" in capsys.readouterr().err
    assert main(["study", "openacc", str(study_dir), "--out", str(tmp_path / "o"),
                 "--max-generations", "0", "-q"]) == 2
    assert main(["study", "openacc", str(study_dir), "--out", str(tmp_path / "o"), "--car",
                 "VOLVO", *FAST]) == 2
    assert "no follower runs match" in capsys.readouterr().err

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(st, "calibrate_many", boom)
    out = tmp_path / "ctrlc"
    js = tmp_path / "ctrlc.json"
    assert main(["study", "openacc", str(study_dir), "--out", str(out), "--json", str(js),
                 *FAST]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not js.exists() and (not out.exists() or not list(out.iterdir()))


@pytest.mark.data
def test_real_file_quick(tmp_path):
    f = ZALA / "short_setting" / "dynamic_part14.csv"
    if not f.exists():
        pytest.skip(NO_DATA)
    res = st.openacc_study(f, model="first", models=("first",), max_generations=3,
                           pop_size=8, starts=1, n_boot=100, figures=False,
                           intervals=avll.Intervals(n=10))
    cars = res.summary["cars"]
    assert len(cars) == 9
    first = cars[0]
    # the target drives at constant speed: its follower is not excited
    assert first["position"] == 1 and first["amplification_measured"] is None
    assert "does not excite" in first["amplification_measured_reason"]
    assert first["amplification_measured_ci"] == [None, None]
    assert sum(c["amplification_measured"] is not None for c in cars) >= 6
    # the contract's interval keys: a value, or null with a reason
    for c in cars:
        assert c["final_model_effects"] == []
        for k in ("amplification_predicted_ci", "time_gap_effective_ci",
                  "string_stable_probability", "params_ci", "identified"):
            assert c[k] is not None or c[f"{k}_reason"], k
        if c["time_gap_effective_ci"] is not None:
            lo, hi = c["time_gap_effective_ci"]
            assert lo <= hi and set(c["params_ci"]) == set(c["params"])
    json.dumps(_atomic.json_safe(res.summary), allow_nan=False)
