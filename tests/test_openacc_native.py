"""The native OpenACC loader (``format="openacc"``): synthetic files
in the published layout (always run), corrupted files, and the real ZalaZone files
(marked ``data``)."""

from __future__ import annotations

import numpy as np
import pytest
from loader_helpers import NATIVE_NAMES, NO_DATA, ZALA, native_platoon, write_native

from avll import DataError
from avll.cli import main
from avll.io import load_openacc_native, openacc_native_report, read_openacc_native, read_runs
from avll.io.openacc_native import arc_length, derive_acceleration, grade_from_altitude


@pytest.fixture(scope="module")
def platoon():
    return native_platoon()


def test_synthetic_file_runs_and_metadata(tmp_path, platoon):
    f = write_native(tmp_path / "long_setting" / "dynamic_part3.csv", platoon)
    runs = read_runs(f, format="openacc")
    assert [r.run_id for r in runs] == ["dynamic_part3/v1-v2", "dynamic_part3/v2-v3",
                                        "dynamic_part3/v3-v4"]
    for k, r in enumerate(runs, start=1):
        m = r.meta
        assert m["file"] == str(f)
        assert m["car"] == NATIVE_NAMES[k] and m["lead_car"] == NATIVE_NAMES[k - 1]
        assert m["setting"] == "L" and m["acc"] is True and m["track"] == "dynamic"
        assert m["position"] == k and m["vehicle_index"] == k + 1
        assert m["date"] == "2019-10-08" and m["folder"] == "long_setting"
        assert r.command is None and r.command_kind == "acceleration" and r.upper is None
        # the gap is the published spacing, exactly
        np.testing.assert_allclose(r.lead_x - r.x, platoon[f"IVS{k}"], atol=1e-9)
        # the path position is the arc length (the circle's chords are 0.8 m at most)
        s = platoon[f"s{k + 1}"]
        np.testing.assert_allclose(r.x, s - s[0], atol=2e-3)
        # the acceleration follows the true one (filter: 1.5 Hz, zero phase)
        err = r.a - platoon[f"a{k + 1}"]
        assert np.sqrt(np.mean(err[20:-20] ** 2)) < 0.02
        assert np.max(np.abs(err[20:-20])) < 0.1
        # grade: altitude 243 + 0.015 N on a circle -> 0.015 cos(theta)
        th = s / 150.0
        np.testing.assert_allclose(r.exo["grade"][30:-30], 0.015 * np.cos(th)[30:-30],
                                   atol=5e-4)
        assert m["ivs_offset"] == pytest.approx(4.0, abs=1e-9)


def test_no_acc_file_has_no_setting(tmp_path, platoon):
    f = write_native(tmp_path / "handling_part22.csv", platoon, acc="0", setting="")
    runs = load_openacc_native(f)
    assert all(r.meta["setting"] is None and r.meta["acc"] is False for r in runs)
    assert all(r.meta["track"] == "handling" for r in runs)


def test_more_names_than_vehicles(tmp_path, platoon):
    f = write_native(tmp_path / "dynamic_part1.csv", platoon, names=NATIVE_NAMES)
    nf = read_openacc_native(f)
    assert nf.n_vehicles == 4 and nf.names == NATIVE_NAMES[:4] and nf.listed == NATIVE_NAMES
    runs = load_openacc_native(f)
    assert [r.meta["car"] for r in runs] == list(NATIVE_NAMES[1:4])
    assert any("first 4 are the cars" in c for c in runs[0].meta["cleaning"])


def test_missing_vehicle_columns(tmp_path, platoon):
    # the target (1) and vehicle 3 are not recorded, as in the handling-course files
    f = write_native(tmp_path / "handling_part1.csv", platoon, vehicles=(2, 3, 4))
    runs, rep = openacc_native_report(f)
    assert [r.run_id for r in runs] == ["handling_part1/v2-v3", "handling_part1/v3-v4"]
    assert [r.meta["position"] for r in runs] == [2, 3]
    assert rep["skipped"][0]["follower"] == 2
    assert "predecessor vehicle 1 (SMART_TARGET) has no columns" in rep["skipped"][0]["reason"]
    solo = load_openacc_native(f, require_predecessor=False)
    assert solo[0].run_id == "handling_part1/v1-v2" and solo[0].lead_x is None


def test_gaps_only_empty_cells_change(tmp_path, platoon):
    short = [300, 301, 302]  # 0.3 s: interpolated
    long = list(range(600, 650))  # 5 s: splits the record
    f = write_native(tmp_path / "dynamic_part2.csv", platoon,
                     empty={"Speed3": short + long, "IVS2": list(range(100, 140)),
                            "E3": [200], "N3": [200], "IVS1": [500, 501]})
    runs = {r.run_id: r for r in load_openacc_native(f)}
    # every stretch of at least min_duration is a run (was: the longest only):
    # rows 0..599 and 650..899 (25 s), split by the 5 s hole in Speed3
    r = runs["dynamic_part2/v2-v3/s1"]
    assert len(r) == 600 and r.t[0] == platoon["t"][0]
    r2 = runs["dynamic_part2/v2-v3/s2"]
    assert r2.meta["rows"] == [650, 899] and r2.meta["stretch"] == 2
    np.testing.assert_array_equal(r2.v, platoon["Speed3"][650:900])
    present = [k for k in range(600) if k not in short]
    np.testing.assert_array_equal(r.v[present], platoon["Speed3"][present])
    ends = platoon["Speed3"][[299, 303]]
    np.testing.assert_allclose(r.v[short], np.interp(short, [299, 303], ends))
    # 4 s of empty IVS2 while both positions are known: reconstructed exactly
    np.testing.assert_allclose((r.lead_x - r.x)[100:140], platoon["IVS2"][100:140], atol=1e-9)
    assert any("IVS2: 40 empty cells reconstructed" in c for c in r.meta["cleaning"])
    assert any("stretch 1 of 2" in c for c in r.meta["cleaning"])
    # the follower of vehicle 3 sees the same split through its predecessor
    assert len(runs["dynamic_part2/v3-v4/s1"]) == 600
    assert len(runs["dynamic_part2/v3-v4/s2"]) == 250


def test_folder_recursive_and_filters(tmp_path, platoon):
    write_native(tmp_path / "a" / "long_setting" / "dynamic_part16.csv", platoon)
    write_native(tmp_path / "b" / "short_setting" / "handling_part1.csv", platoon, setting="S")
    write_native(tmp_path / "b" / "no_ACC" / "handling_part22.csv", platoon, acc="0",
                 setting="")
    runs = read_runs(tmp_path, format="openacc")
    assert len(runs) == 9
    assert {r.run_id.split("/")[0] for r in runs} == {"dynamic_part16", "handling_part1",
                                                      "handling_part22"}
    assert {r.meta["setting"] for r in read_runs(tmp_path, format="openacc", setting="S")} == {"S"}
    assert len(read_runs(tmp_path, format="openacc", setting=["L", "none"])) == 6
    assert {r.meta["track"] for r in read_runs(tmp_path, format="openacc",
                                               track="handling")} == {"handling"}
    bmw = read_runs(tmp_path, format="openacc", car="bmw_i3")
    assert len(bmw) == 3 and {r.meta["car"] for r in bmw} == {"BMW_I3"}
    with pytest.raises(DataError, match="no follower runs match"):
        read_runs(tmp_path, format="openacc", car="VOLVO")
    with pytest.raises(ValueError, match="setting"):
        read_runs(tmp_path, format="openacc", setting="X")
    with pytest.raises(DataError, match="no 'speed' runs"):
        read_runs(tmp_path, format="openacc", command_kind="speed")
    # resampling through the format registry
    half = read_runs(tmp_path / "a", format="openacc", dt=0.2)
    assert all(abs(r.dt - 0.2) < 1e-9 for r in half)


def test_duplicate_stems_get_their_folder(tmp_path, platoon):
    write_native(tmp_path / "x" / "dynamic_part1.csv", platoon)
    write_native(tmp_path / "y" / "dynamic_part1.csv", platoon, setting="S")
    ids = [r.run_id for r in load_openacc_native(tmp_path)]
    assert "x/dynamic_part1/v1-v2" in ids and "y/dynamic_part1/v1-v2" in ids


def _lines(tmp_path, platoon, name="dynamic_part9.csv"):
    f = write_native(tmp_path / name, platoon)
    return f, f.read_text().splitlines()


@pytest.mark.parametrize("line, text, match", [
    (0, "Dat,8,10,2019", r"line 1: expected the metadata line 'Date'"),
    (0, "Date,32,10,2019", r"line 1: Date must be"),
    (1, "Vehicle_order,A,B", r"line 2: Vehicle_order lists 2 names but Number_of_vehicles"),
    (2, "Number_of_vehicles,x", r"line 3: Number_of_vehicles must be an integer"),
    (3, "ACC,3", r"line 4: ACC must be 0, 1, 2 or empty"),
    (4, "Distance_setting,XL", r"line 5: Distance_setting must be one of L, M, S, SL, min"),
])
def test_bad_header(tmp_path, platoon, line, text, match):
    f, lines = _lines(tmp_path, platoon)
    lines[line] = text
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=match) as e:
        load_openacc_native(f)
    assert str(f) in str(e.value)


def test_wrong_vehicle_count(tmp_path, platoon):
    f, lines = _lines(tmp_path, platoon)
    lines[2] = "Number_of_vehicles,3"
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"column 'Speed4', line 6: vehicle 4 but "
                                        r"Number_of_vehicles \(line 3\) is 3"):
        load_openacc_native(f)


def test_non_numeric_cell_names_column_and_line(tmp_path, platoon):
    f, lines = _lines(tmp_path, platoon)
    header = lines[5].split(",")
    row = lines[6 + 41].split(",")
    row[header.index("E3")] = "12,5".replace(",", ";")
    lines[6 + 41] = ",".join(row)
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"column 'E3', row 41 \(line 48\): not a number: "
                                        r"'12;5'") as e:
        load_openacc_native(f)
    assert str(f) in str(e.value)


def test_ragged_row_and_unknown_column(tmp_path, platoon):
    f, lines = _lines(tmp_path, platoon)
    lines[10] = lines[10] + ",1.0,2.0"
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"row 4 \(line 11\): the row has"):
        load_openacc_native(f)
    f, lines = _lines(tmp_path, platoon, "dynamic_part8.csv")
    lines[5] = lines[5].replace("Lat2", "Latitude2")
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"column 'Latitude2', line 6: unknown column"):
        load_openacc_native(f)


def test_empty_and_foreign_files(tmp_path, platoon):
    e = tmp_path / "empty.csv"
    e.write_text("")
    with pytest.raises(DataError, match="empty file"):
        load_openacc_native(e)
    write_native(tmp_path / "dynamic_part1.csv", platoon)
    (tmp_path / "notes.csv").write_text("a,b\n1,2\n")
    e.unlink()
    with pytest.raises(DataError, match=r"notes.csv, line 1: expected the metadata line"):
        load_openacc_native(tmp_path)
    runs, rep = openacc_native_report(tmp_path, skip_foreign=True)
    assert len(runs) == 3 and rep["not_native"] == [str(tmp_path / "notes.csv")]
    with pytest.raises(FileNotFoundError):
        load_openacc_native(tmp_path / "nope.csv")


def test_helpers():
    v = np.array([0.0, 0.0, 0.0, 1.0, 1.0])
    e = np.array([0.0, 0.01, 0.0, 0.1, 0.2])
    n = np.zeros(5)
    s = arc_length(e, n, v)
    assert s[2] == 0.0 and s[-1] == pytest.approx(0.2)  # standstill jitter ignored
    t = np.arange(0, 60, 0.1)
    a = derive_acceleration(np.sin(0.5 * t), 0.1)
    np.testing.assert_allclose(a[30:-30], 0.5 * np.cos(0.5 * t)[30:-30], atol=2e-3)
    with pytest.raises(ValueError, match="accel_cutoff"):
        derive_acceleration(np.sin(t), 0.1, cutoff=6.0)
    x = np.linspace(0, 500, 5001)
    g = grade_from_altitude(x, 240 + 0.02 * x + 0.01 * np.random.default_rng(1).standard_normal(
        x.size))
    np.testing.assert_allclose(g, 0.02, atol=1e-3)


def test_cli_load(tmp_path, platoon, capsys):
    f = write_native(tmp_path / "dynamic_part5.csv", platoon)
    assert main(["load", str(f), "--format", "openacc"]) == 0
    assert "3 runs" in capsys.readouterr().out
    bad = tmp_path / "bad.csv"
    bad.write_text("Date,1,1,2019\nVehicle_order,A\n")
    assert main(["load", str(bad), "--format", "openacc"]) == 2
    assert "line 3" in capsys.readouterr().err


# ---------------------------------------------------------------------------
# the real ZalaZone files
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def zala():
    if not ZALA.exists():
        pytest.skip(NO_DATA)
    return openacc_native_report(ZALA)


@pytest.mark.data
def test_zalazone_all_files(zala):
    runs, rep = zala
    assert len(rep["files"]) == 7
    # every stretch of at least 20 s is a run (was: the longest per follower,
    # 58 runs); the same 58 followers have runs, some split where the spacing jumps
    assert len({(r.meta["file"], r.meta["vehicle_index"]) for r in runs}) == 58
    assert len(runs) == sum(1 for s in rep["stretches"] if s["kept"]) >= 58
    assert {d["kind"] for d in rep["non_data"]} == {"notes", "copyright",
                                                    "vehicle specifications",
                                                    "long-setting list"}
    assert {(s["file"].split("/")[-1], s["follower"]) for s in rep["skipped"]} == {
        ("handling_part22.csv", 2), ("handling_part22.csv", 10), ("handling_part1.csv", 2)}
    for r in runs:
        m = r.meta
        nf_names = m["vehicle_order"]
        assert m["car"] == nf_names[m["vehicle_index"] - 1]
        assert m["position"] == m["vehicle_index"] - 1
        assert m["setting"] in ("L", "S", None) and (m["setting"] is None) == (not m["acc"])
        assert m["track"] in ("dynamic", "handling")
        assert r.lead_x is not None and r.lead_v is not None and r.lead_a is not None
        assert len(r) * r.dt >= 20.0
        assert np.all(np.abs(r.a) < 4.0)
        assert np.all(np.abs(r.exo["grade"]) < 0.3)
    by = {r.run_id: r for r in runs}
    assert by["dynamic_part16/v1-v2"].meta["setting"] == "L"
    assert by["handling_part22/v2-v3"].meta["acc"] is False
    # the dynamic platform is a tilted plane: grades within about +-2 %
    dyn = [r for r in runs if r.meta["track"] == "dynamic"]
    assert max(np.sqrt(np.mean(r.exo["grade"] ** 2)) for r in dyn) < 0.012
    # the documented speed/track disagreement of AUDI_A4 in handling_part1
    assert by["handling_part1/v9-v10"].meta["speed_position_ratio"] > 1.02


@pytest.mark.data
def test_zalazone_gap_is_ivs_where_present(zala):
    runs, _ = zala
    files = {f: read_openacc_native(f) for f in {r.meta["file"] for r in runs}}
    for r in runs:
        nf = files[r.meta["file"]]
        a, b = r.meta["rows"]
        ivs = nf.ivs[r.meta["lead_index"]][a:b + 1]
        ok = np.isfinite(ivs)
        # exact where the spacing was published and its positions were not glitches
        close = np.isclose((r.lead_x - r.x)[ok], ivs[ok], atol=1e-9)
        assert close.mean() > 0.98, r.run_id
        # and the spacing agrees with the two positions minus a constant (< 1 cm spread)
        assert r.meta["ivs_offset"] is not None
