"""Strict JSON everywhere: one helper turns non-finite numbers into null with a reason
beside them; every JSON file the CLI writes parses with NaN/Infinity refused."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from avll._atomic import dumps, json_safe, write_json
from avll.cli import main


def _refuse(token: str) -> Any:
    raise ValueError(f"non-strict JSON token {token}")


def _strict(path: Path) -> Any:
    return json.loads(path.read_text(encoding="utf-8"), parse_constant=_refuse)


def test_json_safe_nulls_with_reasons() -> None:
    doc = {"a": float("nan"), "b": np.float32("inf"), "c": [1.0, float("-inf"), np.int64(3)],
           "d": {"e": np.array([np.nan, 2.0])}, "f": (1, 2), "g": np.bool_(True)}
    out = json_safe(doc)
    assert out["a"] is None and out["a_note"] == "nan (not finite)"
    assert out["b"] is None and out["b_note"] == "inf (not finite)"
    assert out["c"] == [1.0, None, 3] and "position(s) (1)" in out["c_note"]
    assert out["d"]["e"] == [None, 2.0] and "e_note" in out["d"]
    assert out["f"] == [1, 2] and out["g"] is True
    text = dumps(doc)
    assert "NaN" not in text and "Infinity" not in text
    json.loads(text, parse_constant=_refuse)
    assert json_safe(out) == out  # idempotent


def test_write_json_is_strict(tmp_path: Path) -> None:
    p = write_json(tmp_path / "x.json", {"v": math.inf})
    assert _strict(p) == {"v": None, "v_note": "inf (not finite)"}


def test_cli_json_outputs_are_strict(tmp_path: Path) -> None:
    """synth's sidecar, load --json, calibrate --json, stability-map --json (the
    first-order lag has NaN thresholds: null with a note) all parse strictly."""
    data = tmp_path / "runs.csv"
    assert main(["synth", "--out", str(data), "--duration", "20", "--model", "second"]) == 0
    _strict(tmp_path / "runs.csv.meta.json")
    assert main(["load", str(data), "--json", str(tmp_path / "load.json")]) == 0
    _strict(tmp_path / "load.json")
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(data), "--models", "first,second", "--max-generations",
                 "4", "--starts", "1", "-q", "--json", str(cal)]) == 0
    doc = _strict(cal)
    assert set(doc["models"]) == {"first", "second"}
    sm = tmp_path / "map.json"
    assert main(["stability-map", "--models", "first,proposed", "--kg", "0.01", "2", "20",
                 "--tg", "0", "15", "16", "--kv", "0", "1", "6", "--out",
                 str(tmp_path / "m.png"), "--json", str(sm)]) == 0
    doc = _strict(sm)
    first = doc["models"]["first"]
    # the first-order lag is stable up to kv = 1 on this grid: no first empty kv
    assert first["kv_first_empty"] is None and "not finite" in first["kv_first_empty_note"]
