"""The blind tests of the diagnosis loop (:mod:`avll.studies.blind`, formerly scripts in
``benches/``): the tables render what a case returns, and a case reproduces its row of
the committed docs fragment (``docs/_generated/blind_physical.md``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from avll.studies.blind import physical
from avll.synth_blind import DEFAULTS

ROOT = Path(__file__).resolve().parents[1]


def _row(**kw: Any) -> dict[str, Any]:
    row: dict[str, Any] = {
        "scenario": "brake_lag", "acceptable": ["asymmetric"], "available": ["asymmetric"],
        "ranked_first": "asymmetric", "added": ["asymmetric", "speed_drag"],
        "params": {"asymmetric": {"kb": 0.8, "rb": 1.5}, "speed_drag": {"c0": 0.0, "c2": 5e-4}},
        "at_bound": {"asymmetric": [], "speed_drag": ["c0"]}, "hit": True,
        "false_additions": ["speed_drag"], "val_mse": [0.04, 0.01], "test_mse": [0.05, 0.02],
        "val_gain": 0.75, "test_gain": 0.6, "limited_share": 0.0, "shift_cut_share": 0.0,
        "overrides": physical.SCENARIOS["brake_lag"], "notes": [], "flags": ["at_bound"],
        "structure_found": False, "unexplained_share": None, "seconds": 12.0,
        "truth_params": {},
    }
    row.update(kw)
    p = {**DEFAULTS, **physical.SCENARIOS[row["scenario"]]}  # what the generator records
    row["truth_params"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in p.items()}
    return row


def test_table_renders_a_case() -> None:
    rows = [_row(), _row(scenario="clean", acceptable=[], available=[], hit=None, added=[],
                         params={}, at_bound={}, false_additions=[], val_gain=0.0,
                         test_gain=0.0, overrides=physical.SCENARIOS["clean"])]
    lines = physical.table(rows, timing=False)
    assert lines[0].startswith("| scenario |") and "time" not in lines[0]
    assert len(lines) == 4 and lines[2].startswith("| brake_lag |")
    assert "| yes |" in lines[2] and "+75 %" in lines[2] and "+60 %" in lines[2]
    assert "@bound" in lines[2]
    assert lines[3].startswith("| clean |") and "| — |" in lines[3]
    assert physical.table(rows)[0].rstrip("|").rstrip().endswith("time")  # timing column
    text = physical.render(rows)
    assert "| brake_lag |" in text and not text.startswith("<!--")  # docs.gen stamps it
    assert physical.summary(rows)  # counts of hits and false additions


def test_unknown_scenario_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="unknown scenario"):
        physical.collect(["no_such_scenario"])
    assert physical.main(["--only", "no_such_scenario"]) == 2


@pytest.mark.slow
def test_clean_case_reproduces_the_docs_row() -> None:
    """The control without an effect: the loop adds nothing, and its row is the one in
    the committed fragment (a stale fragment fails here: regenerate it with
    ``python -m docs.gen --only blind-physical``)."""
    d = physical.run_case("clean")
    assert d["added"] == [] and d["hit"] is None
    row = physical.table([d], timing=False)[2]
    committed = (ROOT / "docs" / "_generated" / "blind_physical.md").read_text(encoding="utf-8")
    assert row in committed.splitlines(), row


def test_stability_truth_is_measured_as_the_models_are(monkeypatch: pytest.MonkeyPatch
                                                       ) -> None:
    """blind.stability's true-vehicle amplification is effect_stability's measurement
    (same leader, window, fundamental fit and car ratios): with the model itself as the
    'true vehicle' it gives effect_stability's amplification to the bit."""
    import avll
    from avll.effect_stability import effect_stability
    from avll.rollout import platoon
    from avll.studies.blind import stability as bs

    m = avll.models.SecondOrder(**avll.paper.TABLE_II_PARAMS["second"])
    r = effect_stability(m, bs.UPPER, v0=bs.V0, amplitudes=(0.5, 2.0), n_cars=bs.N_CARS,
                         period=20.0, thresholds=False)

    def model_platoon(p: Any, lx: Any, lv: Any, dt: float, upper: Any, n: int, *,
                      v0: float) -> dict[str, Any]:
        return {"v": platoon(m, lx, lv, dt, upper, n).v}

    monkeypatch.setattr(bs, "simulate_platoon", model_platoon)
    assert bs.truth_amplification("brake_lag", r).tobytes() == r.amplification.tobytes()
