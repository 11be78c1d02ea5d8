"""The OpenACC study's cross-validated structure selection
(avll.studies.openacc_select) on small synthetic campaigns with a known truth: a
structure hidden in the followers' law is accepted out of sample and the study's
contract comes from the final model (the base model's numbers beside it); with nothing
hidden nothing is accepted. The blind test to the targets is in test_synth_hidden."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from avll.studies import openacc as st
from avll.studies.openacc_select import select_structures
from avll.synth_platoon import HiddenUpper, synth_campaign, validate_selection

HID = HiddenUpper(radar_period=0.1, radar_latency=0.3, ff_gain=0.5, ff_window=1.5, ratio=1.5)
KW = dict(cars=2, files=2, max_generations=15, starts=1, duration=150.0,
          candidates=["closing", "feedforward"])


@pytest.fixture(scope="module")
def hidden_check():  # type: ignore[no-untyped-def]
    return validate_selection([3], hidden=HID, **KW)


def test_a_hidden_structure_is_accepted_out_of_sample(hidden_check) -> None:  # type: ignore[no-untyped-def]
    r = hidden_check
    assert len(r.rows) == 4
    assert r.with_structures > 0, "the hidden asymmetry must be found for some car"
    assert set(r.accepted) <= {"closing", "feedforward"}
    # the base model reads Tg + Gmin/v̄ long (the asymmetry shifts the mean gap); the
    # final model of the cars with an accepted structure reads it closer to the truth
    acc = [x for x in r.rows if x.effects]
    base = np.mean([abs(x.base_time_gap / x.time_gap - 1) for x in acc])
    final = np.mean([abs(x.time_gap_fit / x.time_gap - 1) for x in acc])
    assert r.base.time_gap_median_error > 0.02
    assert final < base
    assert r.seconds[0] > 0


def test_nothing_hidden_nothing_accepted() -> None:
    r = validate_selection([3], hidden=None, **KW)
    assert r.with_structures == 0 and r.accepted == {}
    for x in r.rows:
        assert x.amplification == x.base_amplification
        assert x.time_gap_fit == x.base_time_gap


def test_study_contract_from_the_final_model(tmp_path) -> None:  # type: ignore[no-untyped-def]
    runs = synth_campaign(2, 2, seed=3, hidden=HID, duration=150.0)
    s = st.openacc_study(runs, model="proposed", models=("proposed",), max_generations=15,
                         starts=1, intervals=False, figures=False,
                         structures=["closing", "feedforward"])
    sel = s.summary["structure_selection"]
    assert sel["enabled"] and sel["grouping"].startswith("per car and setting")
    assert sel["steps"] and all(0.0 <= x["p_value"] <= 1.0 for x in sel["steps"]
                                if x["p_value"] is not None)
    assert sel["seconds"] > 0
    assert {"base_oos_H_vs_h1", "final_oos_H_vs_h1"} <= set(sel["acc"])
    cars = s.summary["cars"]
    with_s = [c for c in cars if c["final_model_effects"]]
    assert with_s, "a structure is accepted for some car"
    assert {a["car"] for a in sel["accepted"]} == {c["car"] for c in with_s}
    for c in cars:
        b = c["base_model"]
        assert set(st.BASE_KEYS) <= set(b)
        assert c["structures"]["accepted"] == c["final_model_effects"]
        if not c["final_model_effects"]:
            assert c["amplification_predicted_oos"] == b["amplification_predicted_oos"]
            continue
        # the final model's parameters carry its structures; its predictions differ
        assert any("." in k for k in c["params"]) and not any("." in k for k in b["params"])
        assert c["final_model_effects_oos"] == c["final_model_effects"]
        assert c["amplification_predicted_oos"] != b["amplification_predicted_oos"]
        assert c["amplification_predicted"] is not None
        assert math.isfinite(c["time_gap_effective_oos"])
    s.save(tmp_path / "out")
    text = (tmp_path / "out" / "summary.json").read_text() if (
        tmp_path / "out" / "summary.json").exists() else json.dumps(s.summary, allow_nan=False)
    assert "NaN" not in text and "Infinity" not in text


def test_select_structures_checks_its_arguments() -> None:
    kw = dict(calibrate_kw={}, weights=st.WEIGHTS)
    plan = {"subsets": [], "problem": []}
    with pytest.raises(ValueError, match="candidates"):
        select_structures("proposed", [], plan, [], [], candidates=["nope"], **kw)
    with pytest.raises(ValueError, match="min_gain"):
        select_structures("proposed", [], plan, [], [], min_gain=1.5, **kw)
    with pytest.raises(ValueError, match="alpha"):
        select_structures("proposed", [], plan, [], [], alpha=0.0, **kw)
    with pytest.raises(ValueError, match="max_structures"):
        select_structures("proposed", [], plan, [], [], max_structures=-1, **kw)
    s = st.openacc_study(synth_campaign(1, 2, seed=1, duration=60.0), models=("first",),
                         model="first", max_generations=2, out_of_sample=False,
                         intervals=False, figures=False)
    sel = s.summary["structure_selection"]
    assert not sel["enabled"] and "out_of_sample" in sel["reason"]
    assert all(c["final_model_effects"] == [] for c in s.summary["cars"])
