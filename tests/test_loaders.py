"""Loaders: CARMA, OpenACC AstaZero, generic CSV/Parquet, resampling."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from loader_helpers import ASTA, CARMA, NO_DATA, canonical_frame, carma_frame, sha

from avll import DataError
from avll.io import carma_report, load_carma, load_generic, load_openacc_astazero
from avll.io.openacc import grade_at, load_slope
from avll.io.resample import resample_arrays

needs_carma = pytest.mark.skipif(not CARMA.is_dir(), reason=NO_DATA)
needs_asta = pytest.mark.skipif(not ASTA.is_dir(), reason=NO_DATA)


# ----------------------------------------------------------------- CARMA, synthetic
def test_carma_synthetic_stretches_holes_sorting(tmp_path):
    df = carma_frame(600)
    # leader: off (mode 0) over rows 200-219 -> two stretches; one empty cell at 100
    # (bridged); five empty cells at 400-404 (longer than 0.2 s: split)
    df.loc[200:219, "leader_CARMA_mode"] = 0
    df.loc[100, "leader_avg_speed_driven_wheels"] = np.nan
    df.loc[400:404, ["leader_CARMA_mode", "leader_Speed_command"]] = np.nan
    # follower1: driver override flagged on rows 50-59, command 0 on rows 300-309
    df.loc[50:59, "follower1_CARMA_ovr_manual"] = 1
    df.loc[300:309, "follower1_Speed_command"] = 0.0
    # three misplaced rows
    df = pd.concat([df.iloc[:10], df.iloc[[30]], df.iloc[10:30], df.iloc[31:]])
    p = tmp_path / "synth.csv"
    df.to_csv(p, index=False)
    before = sha(p)
    runs = load_carma(p, min_duration=1.0)
    assert sha(p) == before
    ids = [r.run_id for r in runs]
    assert ids == ["synth/leader/s01", "synth/leader/s02", "synth/leader/s03",
                   "synth/follower1/s01", "synth/follower1/s02", "synth/follower1/s03"]
    lead = runs[:3]
    ends = [r.t[i] for r in lead for i in (0, -1)]
    assert ends == pytest.approx([0.0, 19.9, 22.0, 39.9, 40.5, 59.9])
    assert lead[0].meta["bridged_samples"] == 1
    # the bridged sample is the mean of its neighbours (linear interpolation)
    v = lead[0].v
    assert v[100] == pytest.approx(0.5 * (v[99] + v[101]))
    assert any("1 rows were out of order" in c for c in lead[0].meta["cleaning"])
    fol = runs[3:]
    ends = [r.t[i] for r in fol for i in (0, -1)]
    assert ends == pytest.approx([0.0, 4.9, 6.0, 29.9, 31.0, 59.9])
    for r in runs:
        assert r.command_kind == "speed" and r.dt == pytest.approx(0.1)
        assert np.all(r.command > 0)
    rep = carma_report(runs)
    assert set(rep["vehicle"]) == {"leader", "follower1"}
    assert int(rep.loc[rep.vehicle == "leader", "bridged"].iloc[0]) == 1
    assert int(rep.loc[rep.vehicle == "leader", "long_holes"].iloc[0]) == 1


def test_carma_min_duration_and_no_bridging(tmp_path):
    df = carma_frame(600)
    df.loc[[100, 250], "leader_acceleration"] = np.nan
    p = tmp_path / "d.csv"
    df.to_csv(p, index=False)
    assert len(load_carma(p, vehicles=["leader"], min_duration=1.0)) == 1
    runs0 = load_carma(p, vehicles=["leader"], min_duration=1.0, max_hole=0.0)
    assert len(runs0) == 3 and all(r.meta["bridged_samples"] == 0 for r in runs0)
    long = load_carma(p, vehicles=["leader"], min_duration=20.0, max_hole=0.0)
    assert [r.run_id for r in long] == ["d/leader/s01"]  # only the last stretch (25.1-59.9 s)
    assert long[0].t[0] == pytest.approx(25.1)


# ----------------------------------------------------------------- CARMA, published
@needs_carma
@pytest.mark.data
@pytest.mark.parametrize("name,descents", [("data5", 5), ("data6", 4), ("data9", 8),
                                           ("data10", 0)])
def test_carma_published_files(name, descents):
    path = CARMA / f"{name}.csv"
    before = sha(path)
    runs = load_carma(path, min_duration=10.0)
    assert sha(path) == before
    assert runs and all(r.run_id.startswith(f"{name}/") for r in runs)
    note = [c for c in runs[0].meta["cleaning"] if c.startswith("sorted by Time")]
    assert (note[0].split(": ")[1].startswith(f"{descents} rows") if descents else not note)
    # every kept sample is engaged in the raw file, except the bridged (empty) ones
    raw = pd.read_csv(path, low_memory=False).sort_values("Time", kind="stable")
    raw = raw.set_index(np.round(raw["Time"].to_numpy() * 10).astype(int))
    for r in runs:
        veh = r.meta["vehicle"]
        rows = raw.loc[np.round(r.t * 10).astype(int)]
        mode = rows[f"{veh}_CARMA_mode"].to_numpy()
        cmd = rows[f"{veh}_Speed_command"].to_numpy()
        spd = rows[f"{veh}_avg_speed_driven_wheels"].to_numpy()
        acc = rows[f"{veh}_acceleration"].to_numpy()
        ok = (mode == 2) & (cmd > 0) & np.isfinite(spd) & np.isfinite(acc)
        assert int((~ok).sum()) == r.meta["bridged_samples"]
        # no bridged sample is explicitly "off"
        off = (mode[~ok] != 2) & np.isfinite(mode[~ok]) | (cmd[~ok] <= 0)
        assert not off.any()
        assert (len(r) - 1) * r.dt >= 10.0 - 1e-9
        # CAN acceleration quantised in steps of 0.01 g (0.098 m/s²)
        q = r.meta["a_quantum"]
        assert np.isnan(q) or q == pytest.approx(0.098, abs=0.006)
    quanta = [v["a_quantum"] for v in runs[0].meta["file_report"]["vehicles"].values()]
    assert quanta == pytest.approx([0.098] * len(quanta), abs=0.0015)


@needs_carma
@pytest.mark.data
def test_carma_units_are_si():
    """The wheel speed is in m/s: its derivative matches the CAN acceleration with slope
    about 1 (km/h would give 3.6), and it tracks the command within a few m/s."""
    runs = load_carma(CARMA / "data9.csv", min_duration=60.0)
    dv = np.concatenate([np.gradient(r.v, r.dt) for r in runs])
    a = np.concatenate([r.a for r in runs])
    k = float(np.dot(dv, a) / np.dot(a, a))
    assert 0.8 < k < 1.25
    err = np.concatenate([r.v - r.command for r in runs])
    assert np.median(np.abs(err)) < 1.0


# ----------------------------------------------------------------- OpenACC
@needs_asta
@pytest.mark.data
def test_openacc_platoon_pairs():
    path = ASTA / "platoon" / "ASta_040719_platoon7.csv"
    runs = load_openacc_astazero(path)
    assert [r.run_id for r in runs] == [f"ASta_040719_platoon7/v{i}-v{i + 1}" for i in range(1, 5)]
    raw = pd.read_csv(path)
    for i, r in enumerate(runs, start=2):
        assert r.command is None and r.command_kind == "acceleration"
        np.testing.assert_allclose(r.lead_x - r.x, raw[f"Spacing{i}"], atol=1e-6)
        np.testing.assert_array_equal(r.lead_v, raw[f"SpeedDoppler{i - 1}"])
        np.testing.assert_array_equal(r.a, raw[f"Accel{i}"])
        assert r.meta["length"] > 4 and r.meta["lead_length"] > 4
        g = r.exo["grade"]
        assert np.all(np.abs(g) < 0.031) and g.std() > 0.005
    assert runs[0].meta["lead_length"] == pytest.approx(5.196)


@needs_asta
@pytest.mark.data
def test_openacc_freeflow_matches_platoon_leader():
    """The free-flow file 30-270 s is the platoon file's leader over that window; its
    position is the platoon position modulo the lap of Slope.csv, which the loader
    unwraps, and the grades read at both positions agree."""
    ff = load_openacc_astazero(ASTA / "freeflow" / "ASta_040719_platoon7_30_270_V70.csv")[0]
    pl = load_openacc_astazero(ASTA / "platoon" / "ASta_040719_platoon7.csv")[0]
    assert ff.command_kind == "speed" and np.all(ff.command == pytest.approx(19.44))
    assert np.all(np.diff(ff.x) > 0)
    i0 = int(np.argmin(np.abs(pl.t - 30.0)))
    lead_x = pl.lead_x[i0:i0 + len(ff)] + pl.meta["lead_length"]
    assert np.max(np.abs((lead_x - lead_x[0]) - (ff.x - ff.x[0]))) < 1e-6
    np.testing.assert_allclose(ff.v, pl.lead_v[i0:i0 + len(ff)])
    slope = load_slope(ASTA / "platoon" / "Slope.csv")
    np.testing.assert_allclose(ff.exo["grade"], grade_at(lead_x, slope), atol=1e-12)


@needs_asta
@pytest.mark.data
def test_openacc_directory_and_kinds():
    runs = load_openacc_astazero(ASTA)
    assert len(runs) == 8 + 7
    assert sum(r.command_kind == "speed" for r in runs) == 7
    assert len(load_openacc_astazero(ASTA, command_kind="speed")) == 7
    flat = load_openacc_astazero(ASTA / "platoon" / "ASta_040719_platoon8.csv", grade=False)
    assert all("grade" not in r.exo for r in flat)


def test_grade_at_periodic():
    sx = np.linspace(0, 100, 21)
    slope = (sx, np.sin(2 * np.pi * sx / 100) * 0.02, 100.0)
    x = np.linspace(0, 350, 71)
    np.testing.assert_allclose(grade_at(x, slope), grade_at(x + 300.0, slope), atol=1e-12)
    np.testing.assert_allclose(grade_at(x, slope, offset=10.0), grade_at(x + 10.0, slope))


# ----------------------------------------------------------------- generic
def test_generic_roundtrip_csv_and_parquet(tmp_path):
    df = canonical_frame()
    for name in ("c.csv", "c.parquet"):
        p = tmp_path / name
        df.to_csv(p, index=False) if name.endswith("csv") else df.to_parquet(p)
        runs = load_generic(p, command_kind="acceleration")
        assert [r.run_id for r in runs] == ["r1", "r2"]
        for r, (_, g) in zip(runs, df.groupby("run", sort=False), strict=True):
            np.testing.assert_allclose(r.a, g["a"].to_numpy(), rtol=1e-15)
            np.testing.assert_allclose(r.v, g["v"].to_numpy(), rtol=1e-15)
            assert r.dt == pytest.approx(0.05)


def test_generic_mapping_and_exo(tmp_path):
    df = canonical_frame(runs=("only",)).drop(columns="run")
    df = df.rename(columns={"t": "Time", "a": "acc", "v": "speed"})
    df["exo_grade"] = 0.01
    p = tmp_path / "m.csv"
    df.to_csv(p, index=False)
    runs = load_generic(p, mapping={"t": "Time", "a": "acc", "v": "speed"},
                        command_kind="speed")
    assert len(runs) == 1 and runs[0].run_id == "m"
    assert runs[0].command_kind == "speed"
    np.testing.assert_array_equal(runs[0].exo["grade"], 0.01)
    with pytest.raises(ValueError, match="command_kind"):
        load_generic(p, mapping={"t": "Time", "a": "acc", "v": "speed"})


def test_generic_resample_interpolates_short_gaps_and_splits_long(tmp_path):
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.08, 0.12, 500))
    t = np.r_[t[:200], t[200:] + 3.0]  # a 3 s gap
    a = np.sin(t)
    p = tmp_path / "nu.csv"
    pd.DataFrame({"t": t, "a": a}).to_csv(p, index=False)
    with pytest.raises(DataError, match="non-uniform"):
        load_generic(p)
    runs = load_generic(p, dt=0.1, max_gap=0.5)
    assert [r.run_id for r in runs] == ["nu/r01", "nu/r02"]
    for r in runs:
        assert r.dt == pytest.approx(0.1)
        # linear interpolation of a sine over <= 0.12 s steps: error <= h²/8
        assert np.max(np.abs(r.a - np.sin(r.t))) < 0.12**2 / 8 + 1e-12
        assert any("resampled" in c for c in r.meta["cleaning"])
    assert runs[0].t[-1] <= t[199] and runs[1].t[0] >= t[200]


def test_resample_arrays_nan_is_a_hole():
    t = np.arange(100) * 0.1
    v = np.sin(t)
    v[40] = np.nan
    v[60:70] = np.nan
    segs = resample_arrays(t, {"v": v}, 0.1, max_gap=0.25)
    assert [(s.start, s.stop) for s in segs] == [(0, 60), (70, 100)]
    assert segs[0].columns["v"][40] == pytest.approx(0.5 * (v[39] + v[41]))


def test_load_format_dispatch_and_resample(tmp_path):
    from avll.io import load_format, read_runs

    p = tmp_path / "c.csv"
    carma_frame(300).to_csv(p, index=False)
    runs = load_format(p, "carma", min_duration=1.0)
    assert [r.run_id for r in runs] == ["c/leader/s01", "c/follower1/s01"]
    via = read_runs(p, format="carma", min_duration=1.0)
    np.testing.assert_array_equal(via[1].v, runs[1].v)
    with pytest.raises(ValueError, match="CARMA commands are speeds"):
        read_runs(p, command_kind="acceleration", format="carma")
    half = read_runs(p, format="carma", dt=0.2, min_duration=1.0)
    assert [len(r) for r in half] == [150, 150] and half[0].dt == pytest.approx(0.2)
    np.testing.assert_allclose(half[0].v, runs[0].v[::2])
    with pytest.raises(ValueError, match="format"):
        load_format(p, "nope")


def test_openacc_synthetic_platoon(tmp_path):
    from loader_helpers import openacc_dir

    p = openacc_dir(tmp_path)
    runs = load_openacc_astazero(p)
    assert [r.run_id for r in runs] == ["ASta_010101_platoon1/v1-v2", "ASta_010101_platoon1/v2-v3"]
    raw = pd.read_csv(p)
    for i, r in enumerate(runs, start=2):
        np.testing.assert_allclose(r.lead_x - r.x, raw[f"Spacing{i}"], atol=1e-9)
        # grade read at x mod 1000 on the synthetic sine profile (5 m linear interpolation)
        np.testing.assert_allclose(r.exo["grade"], 0.02 * np.sin(2 * np.pi * r.x / 1000.0),
                                   atol=0.02 * (2 * np.pi * 5 / 1000) ** 2 / 8 + 1e-12)
    assert runs[1].meta["lead_length"] == 4.5 and runs[1].meta["length"] == 4.8
