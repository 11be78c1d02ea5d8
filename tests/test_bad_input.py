"""Bad input: a clear DataError naming the file, the column and the row; input files
are never modified. Property-based (hypothesis) corruption of valid files."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from loader_helpers import ASTA, NO_DATA, canonical_frame, carma_frame, sha

from avll import DataError, Run
from avll.io import load_carma, load_generic, load_openacc_astazero
from avll.io._common import check_runs_for_delay


def _write(df: pd.DataFrame, path: Path) -> Path:
    df.to_csv(path, index=False)
    return path


def _raises(fn, path: Path, column: str | None = None, row: int | None = None,
            match: str | None = None) -> str:
    before = sha(path)
    with pytest.raises(DataError) as ei:
        fn(path)
    assert sha(path) == before, "input file modified"
    msg = str(ei.value)
    assert str(path) in msg
    if column is not None:
        assert f"column {column!r}" in msg, msg
    if row is not None:
        assert f"row {row}" in msg, msg
    if match is not None:
        assert re.search(match, msg), msg
    return msg


def gen(p: Path) -> list[Run]:
    return load_generic(p, command_kind="acceleration")


# ------------------------------------------------------------------ generic
def test_missing_column(tmp_path):
    p = _write(canonical_frame().drop(columns="a"), tmp_path / "f.csv")
    _raises(gen, p, "a", match="missing column")


def test_empty_file_and_header_only(tmp_path):
    p = tmp_path / "empty.csv"
    p.write_text("")
    _raises(gen, p, match="empty file")
    q = tmp_path / "hdr.csv"
    q.write_text("run,t,command,a\n")
    _raises(gen, q, match="no data rows")


def test_non_monotonic_time(tmp_path):
    df = canonical_frame()
    df.loc[[10, 11], "t"] = df.loc[[11, 10], "t"].to_numpy()
    p = _write(df, tmp_path / "f.csv")
    _raises(gen, p, "t", 11, "backwards")


def test_duplicated_time(tmp_path):
    df = canonical_frame()
    df.loc[20, "t"] = df.loc[19, "t"]
    p = _write(df, tmp_path / "f.csv")
    _raises(gen, p, "t", 20, "duplicated")


def test_non_uniform_time(tmp_path):
    df = canonical_frame()
    df.loc[30:, "t"] += 0.01  # one step of 0.06 s in 0.05 s sampling
    p = _write(df, tmp_path / "f.csv")
    _raises(gen, p, "t", 30, "non-uniform")


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf", ""])
def test_nan_inf_empty(tmp_path, bad):
    df = canonical_frame().astype({"v": object})
    df.loc[42, "v"] = bad
    p = _write(df, tmp_path / "f.csv")
    _raises(gen, p, "v", 42)


def test_text_in_numeric_column(tmp_path):
    df = canonical_frame().astype({"a": object})
    df.loc[7, "a"] = "0,35"
    p = _write(df, tmp_path / "f.csv")
    msg = _raises(gen, p, "a", 7, "not a number")
    assert "line 9" in msg  # header + 0-based row 7


def test_speed_in_kmh_detected(tmp_path):
    df = canonical_frame()
    df["v"] = df["v"] * 3.6  # 43 km/h: below the hard limit, caught by dv/dt vs a
    p = _write(df, tmp_path / "f.csv")
    _raises(gen, p, "v", match="km/h")
    df["v"] = 100.0 + df["v"]  # > 70 "m/s"
    p2 = _write(df, tmp_path / "g.csv")
    _raises(gen, p2, "v", match="implausible")


def test_runs_too_short_for_delay():
    t = np.arange(12) * 0.1
    r = Run("short", t, np.zeros(12), meta={"file": "x.csv"})
    with pytest.raises(DataError, match=r"x.csv, run 'short'.*too short for a delay of 1"):
        check_runs_for_delay([r], 1.0)
    check_runs_for_delay([Run("ok", np.arange(40) * 0.1, np.zeros(40))], 1.0)
    with pytest.raises(ValueError, match="td"):
        check_runs_for_delay([r], -1.0)


# ------------------------------------------------------------------ CARMA
def carma(p: Path) -> list[Run]:
    return load_carma(p, min_duration=1.0)


def test_carma_missing_column(tmp_path):
    p = _write(carma_frame().drop(columns="follower1_Speed_command"), tmp_path / "c.csv")
    _raises(carma, p, "follower1_Speed_command", match="missing column")


def test_carma_text_cell(tmp_path):
    df = carma_frame().astype({"leader_acceleration": object})
    df.loc[123, "leader_acceleration"] = "n/a?"
    p = _write(df, tmp_path / "c.csv")
    _raises(carma, p, "leader_acceleration", 123, "not a number")


def test_carma_error_line_counts_blank_lines(tmp_path):
    """Row 123 of the table is line 125 of a plain file; with three blank lines
    before it (pandas skips them, the row count is unchanged) it is line 128."""
    df = carma_frame().astype({"leader_acceleration": object})
    df.loc[123, "leader_acceleration"] = "n/a?"
    p = _write(df, tmp_path / "c.csv")
    assert "row 123 (line 125)" in _raises(carma, p, "leader_acceleration", 123)
    lines = p.read_text().splitlines(keepends=True)
    p.write_text("".join(lines[:40] + ["\n", "  \n", "\n"] + lines[40:]))
    assert "row 123 (line 128)" in _raises(carma, p, "leader_acceleration", 123)


def test_carma_conflicting_duplicate_time(tmp_path):
    df = carma_frame()
    df.loc[50, "Time"] = df.loc[49, "Time"]
    p = _write(df, tmp_path / "c.csv")
    _raises(carma, p, "Time", 50, "duplicated")


def test_carma_exact_duplicate_rows_dropped(tmp_path):
    df = carma_frame()
    df = pd.concat([df.iloc[:50], df.iloc[[49]], df.iloc[50:]], ignore_index=True)
    p = _write(df, tmp_path / "c.csv")
    runs = carma(p)
    assert any("1 exact duplicate" in c for c in runs[0].meta["cleaning"])


def test_carma_off_grid_time(tmp_path):
    df = carma_frame()
    df.loc[77, "Time"] = df.loc[77, "Time"] + 0.04
    p = _write(df, tmp_path / "c.csv")
    _raises(carma, p, "Time", 77, "non-uniform")


def test_carma_kmh_speed(tmp_path):
    df = carma_frame()
    df["follower1_avg_speed_driven_wheels"] *= 3.6 * 1.5  # ~80 "m/s"
    p = _write(df, tmp_path / "c.csv")
    _raises(carma, p, "follower1_avg_speed_driven_wheels", match="km/h")


def test_carma_kmh_below_hard_limit(tmp_path):
    """A speed or a command in km/h that stays below 70 is still caught: the speed by
    its derivative against the CAN acceleration, the command by its ratio to the speed."""
    df = carma_frame()
    df["leader_avg_speed_driven_wheels"] *= 3.6
    df["leader_avg_speed_driven_wheels"] -= 30.0  # 24-35 "m/s": below the hard limit
    p = _write(df, tmp_path / "c.csv")
    _raises(carma, p, "leader_avg_speed_driven_wheels", match="km/h")
    df = carma_frame()
    df["follower1_Speed_command"] *= 3.6
    df["follower1_Speed_command"] -= 10.0
    p = _write(df, tmp_path / "d.csv")
    _raises(carma, p, "follower1_Speed_command", match="implausible units")


def test_carma_empty_engaged_stretch(tmp_path):
    df = carma_frame()
    df["leader_CARMA_mode"] = 0.0
    df["follower1_Speed_command"] = 0.0
    p = _write(df, tmp_path / "c.csv")
    _raises(carma, p, "leader_CARMA_mode", match="empty engaged stretch")
    # one vehicle empty, explicitly requested -> error; not requested -> fine
    df2 = carma_frame()
    df2["follower1_CARMA_mode"] = 0.0
    p2 = _write(df2, tmp_path / "c2.csv")
    assert [r.meta["vehicle"] for r in carma(p2)] == ["leader"]
    _raises(lambda q: load_carma(q, vehicles=["leader", "follower1"]), p2,
            "follower1_CARMA_mode", match="empty engaged")


def test_carma_inf(tmp_path):
    df = carma_frame()
    df.loc[5, "leader_Speed_command"] = np.inf
    p = _write(df, tmp_path / "c.csv")
    _raises(carma, p, "leader_Speed_command", 5, "inf")


def test_not_a_carma_file(tmp_path):
    p = _write(canonical_frame(), tmp_path / "x.csv")
    _raises(carma, p, "Time", match="missing column")


# ------------------------------------------------------------------ OpenACC
@pytest.mark.skipif(not ASTA.is_dir(), reason=NO_DATA)
@pytest.mark.data
def test_openacc_bad_copies(tmp_path):
    src = pd.read_csv(ASTA / "platoon" / "ASta_040719_platoon7.csv", nrows=600)
    for aux in ("Labels.csv", "Slope.csv"):
        (tmp_path / aux).write_bytes((ASTA / "platoon" / aux).read_bytes())
    p = _write(src.drop(columns="Spacing3"), tmp_path / "ASta_040719_platoon7.csv")
    _raises(load_openacc_astazero, p, "Spacing3", match="missing column")
    df = src.astype({"Accel4": object})
    df.loc[99, "Accel4"] = "x"
    p = _write(df, tmp_path / "ASta_040719_platoon7.csv")
    _raises(load_openacc_astazero, p, "Accel4", 99)
    df = src.copy()
    df["SpeedDoppler2"] *= 3.6
    p = _write(df, tmp_path / "ASta_040719_platoon7.csv")
    _raises(load_openacc_astazero, p, "SpeedDoppler2", match="km/h")
    p = _write(src, tmp_path / "ASta_999999_platoon1.csv")
    with pytest.raises(DataError, match="Labels.csv.*no row for 'ASta_999999_platoon1'"):
        load_openacc_astazero(p)


# ------------------------------------------------------------------ hypothesis
CORRUPTIONS = ("text", "nan", "inf", "drop_column", "swap_time", "dup_time", "kmh")


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kind=st.sampled_from(CORRUPTIONS), row=st.integers(1, 398),
       col=st.sampled_from(["command", "a", "v", "x"]), seed=st.integers(0, 10_000))
def test_generic_corruption_property(kind, row, col, seed):
    """Any single corruption of a valid canonical file gives a DataError naming the
    file (and the column and row where they exist); the file is left untouched."""
    df = canonical_frame(seed=seed, runs=("only",))
    df = df.astype({c: object for c in ("command", "a", "v", "x", "t")})
    expect_col, expect_row = col, row
    if kind == "text":
        df.loc[row, col] = "abc"
    elif kind == "nan":
        df.loc[row, col] = "nan"
    elif kind == "inf":
        df.loc[row, col] = "-inf"
    elif kind == "drop_column":
        col = "t" if col in ("v", "x") else "a"  # command, v, x are optional
        df = df.drop(columns=col)
        expect_col, expect_row = col, None
    elif kind == "swap_time":
        df.loc[[row, row + 1], "t"] = df.loc[[row + 1, row], "t"].to_numpy()
        expect_col, expect_row = "t", row + 1
    elif kind == "dup_time":
        df.loc[row, "t"] = df.loc[row - 1, "t"]
        expect_col = "t"
    elif kind == "kmh":
        df["v"] = df["v"].astype(float) * 3.6
        expect_col, expect_row = "v", None
    with tempfile.TemporaryDirectory() as d:
        p = _write(df, Path(d) / "corrupt.csv")
        _raises(gen, p, expect_col, expect_row)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(holes=st.lists(st.tuples(st.integers(0, 299), st.integers(1, 6),
                                st.sampled_from(["empty", "off", "override", "cmd0"])),
                      max_size=8),
       moved=st.lists(st.integers(1, 298), max_size=4, unique=True))
def test_carma_messy_but_valid_property(holes, moved):
    """Random empty cells, disengagements, overrides and misplaced rows: the loader
    returns runs whose every sample is engaged in the input (or a bridged hole of at
    most max_hole), never crosses an off sample, and records what it did."""
    n = 300
    df = carma_frame(n, vehicles=("leader",))
    for start, length, what in holes:
        sl = slice(start, min(n, start + length) - 1)
        if what == "empty":
            df.loc[sl, "leader_CARMA_mode"] = np.nan
        elif what == "off":
            df.loc[sl, "leader_CARMA_mode"] = 0.0
        elif what == "override":
            df.loc[sl, "leader_CARMA_ovr_manual"] = 1.0
        else:
            df.loc[sl, "leader_Speed_command"] = 0.0
    # the state of each sample, from the final cells (later holes overwrite earlier ones)
    mode = df["leader_CARMA_mode"].to_numpy()
    cmd = df["leader_Speed_command"].to_numpy()
    man = df["leader_CARMA_ovr_manual"].to_numpy()
    off = (~np.isnan(mode) & (mode != 2)) | (~np.isnan(cmd) & (cmd <= 0)) | (man == 1)
    empty = np.isnan(mode) & ~off
    order = list(range(n))
    for m in moved:  # move row m to the front of its neighbourhood
        order.remove(m)
        order.insert(max(0, m - 5), m)
    df = df.iloc[order]
    with tempfile.TemporaryDirectory() as d:
        p = _write(df, Path(d) / "messy.csv")
        before = sha(p)
        try:
            runs = load_carma(p, min_duration=0.5, max_hole=0.2)
        except DataError as e:
            assert "empty engaged stretch" in str(e)
            clean = np.r_[0, (~off & ~empty).astype(int), 0]
            d_ = np.diff(clean)
            longest = np.max(np.flatnonzero(d_ == -1) - np.flatnonzero(d_ == 1), initial=0)
            assert longest < 6  # a clean stretch of 0.5 s would have been kept
            return
        finally:
            assert sha(p) == before
    for r in runs:
        k = np.round(r.t * 10).astype(int)
        assert not off[k].any()
        # bridged samples are empty ones, in holes of at most 2 samples
        assert r.meta["bridged_samples"] == int(empty[k].sum())
        e = np.r_[0, empty[k].astype(int), 0]
        starts, stops = np.flatnonzero(np.diff(e) == 1), np.flatnonzero(np.diff(e) == -1)
        assert np.all(stops - starts <= 2)
        assert np.all(np.isfinite(r.v)) and np.all(r.command > 0)
        if moved:
            assert any("out of order" in c for c in r.meta["cleaning"])


# ------------------------------------------------------------------ CLI
def test_cli_load_bad_input_one_line_exit_2(tmp_path, capsys):
    from avll.cli import main

    df = carma_frame().astype({"leader_acceleration": object})
    df.loc[123, "leader_acceleration"] = "oops"
    p = _write(df, tmp_path / "c.csv")
    before = sha(p)
    assert main(["load", str(p), "--format", "carma"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "c.csv, column 'leader_acceleration', row 123 (line 125): not a number" in err
    assert sha(p) == before


def test_cli_load_converts_to_canonical(tmp_path, capsys):
    from avll.cli import main
    from avll.io import read_runs

    p = _write(carma_frame(), tmp_path / "c.csv")
    out = tmp_path / "canon.csv"
    rep = tmp_path / "rep" / "r.json"
    assert main(["load", str(p), "--format", "carma", "--min-duration", "1",
                 "--out", str(out), "--json", str(rep)]) == 0
    assert "2 runs" in capsys.readouterr().out
    back = read_runs(out)
    orig = load_carma(p, min_duration=1.0)
    assert [r.run_id for r in back] == [r.run_id for r in orig]
    assert back[0].command_kind == "speed"
    np.testing.assert_allclose(back[1].v, orig[1].v, rtol=1e-9)
    import json
    assert set(json.loads(rep.read_text())) == {r.run_id for r in orig}


CARMA_CORRUPTIONS = ("text", "inf", "drop_column", "off_grid", "dup_conflict", "kmh")


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kind=st.sampled_from(CARMA_CORRUPTIONS), row=st.integers(1, 298),
       veh=st.sampled_from(["leader", "follower1"]),
       field=st.sampled_from(["Speed_command", "avg_speed_driven_wheels", "acceleration",
                              "CARMA_mode"]))
def test_carma_corruption_property(kind, row, veh, field):
    """Single corruptions of a valid CARMA file: a DataError naming file, column and
    (where it exists) row; the file is untouched."""
    df = carma_frame(300)
    col, r = f"{veh}_{field}", row
    if kind == "text":
        df = df.astype({col: object})
        df.loc[row, col] = "x1"
    elif kind == "inf":
        df.loc[row, col] = np.inf
    elif kind == "drop_column":
        df = df.drop(columns=col)
        r = None
    elif kind == "off_grid":
        df.loc[row, "Time"] = df.loc[row, "Time"] + 0.05
        col = "Time"
    elif kind == "dup_conflict":
        df.loc[row, "Time"] = df.loc[row - 1, "Time"]
        col = "Time"
    else:
        col = f"{veh}_avg_speed_driven_wheels"
        df[col] = df[col] * 3.6 - 25.0
        r = None
    with tempfile.TemporaryDirectory() as d:
        p = _write(df, Path(d) / "corrupt.csv")
        _raises(carma, p, col, r)


@pytest.mark.parametrize("kind", ["text", "nan", "drop", "backwards", "kmh", "labels"])
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(row=st.integers(2, 590), veh=st.integers(1, 3))
def test_openacc_corruption_property(kind, row, veh):
    """Corrupted copies of a (synthetic) OpenACC platoon file."""
    from loader_helpers import openacc_dir

    with tempfile.TemporaryDirectory() as d:
        p = openacc_dir(Path(d))
        df = pd.read_csv(p)
        col, r = f"Accel{veh}", row
        if kind == "text":
            df = df.astype({col: object})
            df.loc[row, col] = "--"
        elif kind == "nan":
            col = f"X{veh}"
            df.loc[row, col] = np.nan
        elif kind == "drop":
            col = f"SpeedDoppler{veh}"
            df = df.drop(columns=col)
            r = None
        elif kind == "backwards":
            col = "Time"
            df.loc[[row, row + 1], col] = df.loc[[row + 1, row], col].to_numpy()
            r = row + 1
        elif kind == "kmh":
            col = f"SpeedDoppler{veh}"
            df[col] *= 3.6
            r = None
        else:
            lab = Path(d) / "Labels.csv"
            lab.write_text(LABELS_HEADER_ONLY, encoding="utf-8")
            _raises(lambda _: load_openacc_astazero(p), lab, "File", None,
                    "no row for 'ASta_010101_platoon1'")
            return
        _write(df, p)
        _raises(load_openacc_astazero, p, col, r)


LABELS_HEADER_ONLY = "File,type1\nsomething_else,1\n"
