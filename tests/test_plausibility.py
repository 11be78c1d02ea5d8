"""Plausibility warnings, strict mode, units and run-id resolution of the loaders."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from loader_helpers import ASTA, CARMA, NO_DATA, canonical_frame, carma_frame, sha

import avll
from avll import DataError, DataWarning, PlausibilityWarning
from avll.cli import main
from avll.io import FORMATS, load_carma, load_generic, read_runs


def _canonical(tmp: Path, df: pd.DataFrame, side: dict | None = None) -> Path:
    p = tmp / "c.csv"
    df.to_csv(p, index=False)
    (tmp / "c.csv.meta.json").write_text(json.dumps(side or {"command_kind": "acceleration"}))
    return p


@pytest.mark.parametrize(("col", "value", "fragment"), [
    ("a", 12.0, "column 'a', row 5 (line 7): acceleration 12 m/s² is outside the plausible "
                "range -10..10 m/s²"),
    ("v", 55.0, "column 'v', row 5 (line 7): speed 55 m/s is outside the plausible range "
                "-1..50 m/s"),
    ("v", -3.0, "column 'v', row 5 (line 7): speed -3 m/s is outside"),
    ("command", -11.0, "column 'command', row 5 (line 7): acceleration -11 m/s²"),
    ("x", None, "column 'x', row 5 (line 7): position jumps by"),
    ("exo_grade", 0.25, "column 'exo_grade', row 5 (line 7): grade 0.25 is outside the "
                        "plausible range -0.2..0.2"),
])
def test_warning_names_file_column_line_and_strict_refuses(tmp_path: Path, col: str,
                                                           value: float | None,
                                                           fragment: str) -> None:
    df = canonical_frame(runs=("1",))
    if col == "exo_grade":
        df[col] = 0.01
    if value is None:
        df.loc[5:, "x"] += 30.0  # a 30 m jump in one 0.05 s step
    else:
        df.loc[5, col] = value
    p = _canonical(tmp_path, df)
    before = sha(p)
    with pytest.warns(PlausibilityWarning) as rec:
        runs = read_runs(p)
    assert len(runs) == 1
    msgs = [str(w.message) for w in rec]
    assert any(str(p) in m and fragment in m for m in msgs), msgs
    with pytest.raises(DataError, match="outside the plausible|jumps"):
        read_runs(p, strict=True)
    with pytest.raises(DataError):
        avll.io.load_canonical(p, strict=True)
    assert sha(p) == before


def test_time_step_plausibility(tmp_path: Path) -> None:
    df = canonical_frame(runs=("1",))
    df["t"] = np.arange(len(df)) * 1.5  # 1.5 s steps: coarse but possible
    p = _canonical(tmp_path, df.drop(columns=["v", "x"]))
    with pytest.warns(PlausibilityWarning, match=r"column 't', row 1 \(line 3\): time step 1.5 s"):
        read_runs(p)
    df["t"] = np.arange(len(df)) * 100.0  # a 10 Hz log with time stamps in ms
    p = _canonical(tmp_path, df.drop(columns=["v", "x"]))
    with pytest.raises(DataError, match="are the time stamps in milliseconds"):
        read_runs(p)


def test_units_are_never_converted(tmp_path: Path) -> None:
    for factor, unit in ((3.6, "km/h"), (2.2369, "mph")):
        df = canonical_frame()
        df["v"] *= factor
        p = _canonical(tmp_path, df)
        with pytest.raises(DataError, match=f"column 'v': speed looks like {unit}"):
            read_runs(p)
        with pytest.raises(DataError, match=unit):
            load_generic(p, command_kind="acceleration")


def test_generic_carma_openacc_warn_too(tmp_path: Path) -> None:
    df = canonical_frame()
    df.loc[9, "a"] = 11.0
    g = tmp_path / "g.csv"
    df.to_csv(g, index=False)
    with pytest.warns(PlausibilityWarning, match=r"g.csv, column 'a', row 9 \(line 11\)"):
        load_generic(g, command_kind="acceleration")
    with pytest.raises(DataError, match="acceleration 11"):
        load_generic(g, command_kind="acceleration", strict=True)
    c = tmp_path / "c.csv"
    cf = carma_frame()
    cf.loc[100, "leader_acceleration"] = 12.0
    cf.to_csv(c, index=False)
    with pytest.warns(PlausibilityWarning, match="column 'leader_acceleration', row 100"):
        load_carma(c, min_duration=1.0)
    with pytest.raises(DataError, match="leader_acceleration"):
        load_carma(c, min_duration=1.0, strict=True)
    with pytest.raises(DataError, match="leader_acceleration"):
        FORMATS["carma"](c, min_duration=1.0, strict=True)
    with pytest.raises(TypeError, match="strict"):
        read_runs(c, format="carma", strict="yes")  # type: ignore[arg-type]


def test_warnings_are_held_back_when_the_load_fails(tmp_path: Path) -> None:
    """A load that ends in an error does not also print the warnings before it."""
    df = canonical_frame(runs=("1", "2"))
    df.loc[3, "a"] = 12.0  # a warning in run 1 ...
    df.loc[500, "t"] = df.loc[499, "t"]  # ... and an error in run 2
    p = _canonical(tmp_path, df)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        with pytest.raises(DataError, match="time repeats"):
            read_runs(p)
    assert not [w for w in rec if issubclass(w.category, DataWarning)]


# ------------------------------------------------------------------ run ids


def test_sidecar_run_ids_are_resolved_or_refused(tmp_path: Path) -> None:
    df = canonical_frame(runs=("04", "3.0"))
    up = {"kg": 0.5, "kv": 0.1, "Tg": 1.8, "Gmin": 9.5}
    # exact ids: applied
    p = _canonical(tmp_path, df, {"command_kind": "acceleration",
                                  "runs": {"04": {"upper": up}, "3.0": {"meta": {"k": 1}}}})
    runs = read_runs(p)
    assert [r.run_id for r in runs] == ["04", "3.0"]
    assert runs[0].upper == avll.UpperLevel(**up) and runs[1].meta["k"] == 1
    # the same numbers written differently: refused, naming both spellings
    for key, data_id in (("4", "04"), ("3", "3.0"), ("4.0", "04")):
        p = _canonical(tmp_path, df, {"command_kind": "acceleration",
                                      "runs": {key: {"upper": up}}})
        with pytest.raises(DataError, match=rf"runs.'{key}' matches no run of c.csv, whose run "
                                            rf"'{data_id}' is the same number"):
            read_runs(p)
    # an id that is in no form in the data: a warning (strict: an error)
    p = _canonical(tmp_path, df, {"command_kind": "acceleration", "runs": {"7": {}}})
    with pytest.warns(DataWarning, match=r"names 1 run\(s\) that are not in c.csv: '7'"):
        assert len(read_runs(p)) == 2
    with pytest.raises(DataError, match="'7'"):
        read_runs(p, strict=True)


def test_parquet_float_run_ids_are_whole_numbers(tmp_path: Path) -> None:
    pytest.importorskip("pyarrow")
    df = canonical_frame(runs=("1", "2"))
    df["run"] = df["run"].astype(float)  # 1.0, 2.0 as a writer of floats would store them
    p = tmp_path / "c.parquet"
    df.to_parquet(p, index=False)
    (tmp_path / "c.parquet.meta.json").write_text(json.dumps(
        {"command_kind": "acceleration", "runs": {"2": {"upper": {"kg": 0.4}}}}))
    runs = read_runs(p)
    assert [r.run_id for r in runs] == ["1", "2"] and runs[1].upper.kg == 0.4


def test_duplicated_header_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "c.csv"
    p.write_text("run,t,a,a\n1,0,0.1,0.2\n1,0.1,0.1,0.2\n")
    with pytest.raises(DataError, match=r"c.csv, column 'a': duplicated column \(header fields "
                                        r"3 and 4\)"):
        read_runs(p, command_kind="acceleration")
    p.write_text("run,t,a, a\n1,0,0.1,0.2\n1,0.1,0.1,0.2\n")  # the same after stripping
    with pytest.raises(DataError, match="duplicated column"):
        load_generic(p)


# ------------------------------------------------------------------ CLI


def test_cli_prints_warnings_as_lines_and_strict_refuses(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    df = canonical_frame(runs=("1",))
    df.loc[5, "a"] = 12.0
    p = _canonical(tmp_path, df)
    assert main(["load", str(p)]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("avll load: warning: ") and "line 7" in err
    assert main(["load", str(p), "--strict"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("avll load: error: ") and "line 7" in err


# ------------------------------------------------------------------ field data


@pytest.mark.data
@pytest.mark.skipif(not CARMA.is_dir() or not ASTA.is_dir(), reason=NO_DATA)
def test_the_field_data_are_plausible_even_strictly() -> None:
    """The thresholds fit the published data: no warning, even with strict=True."""
    assert len(read_runs(CARMA, format="carma", strict=True)) > 10
    assert len(read_runs(ASTA, format="openacc-astazero", strict=True)) > 5
