"""The residual loop on measured data (:mod:`avll.studies.loops`, formerly scripts in
``benches/``): the table row and summary of a loop result, and a table that renders
the cases that have not run as such."""

from __future__ import annotations

import json
from pathlib import Path

from avll.studies.loops import carma, openacc, table


def _result(**kw: object) -> dict:
    d = {
        "effects": ["asymmetric"],
        "steps": [{"effect": "asymmetric", "params": {"kb": 0.8, "rb": 1.5},
                   "val_mse_before": 0.04, "val_mse_after": 0.01,
                   "test_mse_before": 0.05, "test_mse_after": 0.04}],
        "trials": [{"effect": "asymmetric", "fold_selection": 1.0, "gain": 0.5,
                    "p_value": 0.001}],
        "flags": [{"kind": "test_gain_far_smaller"}],
        "unexplained": {"unexplained_share": 0.12,
                        "signals": [{"signal": "speed", "keeps_structure": True}]},
    }
    d.update(kw)
    return d


def test_row_and_summary() -> None:
    cells = table.row(_result()).split(" | ")
    assert len(cells) == len(table.HEADER.split(" | "))
    assert cells[0] == "asymmetric (kb 0.8, rb 1.5)"
    assert cells[1] == "asymmetric 1.00 (+50.0 %, p 0.001)"
    assert cells[2] == "+75.0 %" and cells[3] == "+20.0 %"
    assert cells[4] == "test_gain_far_smaller" and cells[5] == "12.0 % (speed)"
    none = table.row(_result(effects=[], steps=[], trials=[], flags=[], unexplained={}))
    assert none == "none | — | — | — | — | —"
    s = table.summary({"a": _result(), "b": _result(effects=[], steps=[])})
    assert s.startswith("Of 2 case(s), 1 accepted at least one effect (a: asymmetric)")
    assert "held (no test flag) in 0 of the 1" in s  # a test flag: the gain did not hold
    assert "in 2 of 2 the final residual keeps" in s
    assert table.summary({}) == "No case has run yet."


def test_tables_say_which_cases_ran(tmp_path: Path) -> None:
    (tmp_path / "carma_leader.json").write_text(json.dumps(_result()))
    text = carma.render(tmp_path)
    assert "| leader | asymmetric (kb 0.8, rb 1.5) |" in text
    assert "| follower1 | not run |" in text and not text.startswith("<!--")
    text = openacc.render(tmp_path, ["v1-v2"], {"max_generations": 7})
    assert "| v1-v2 | not run |" in text and "GA 7 generations" in text
    assert "No case has run yet." in text
