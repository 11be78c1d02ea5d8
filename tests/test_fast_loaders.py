"""The loaders' fast paths give exactly what the exact paths give: the native OpenACC
loader's data block read by pandas' C parser (exact: csv.reader and ``_to_float``),
the CARMA and canonical tables read with their numbers parsed (exact: read as text,
then converted column by column). The same arrays bit for bit, the same metadata,
warnings and runs, or the same exception with the same message. Checked on every
field-data file and on small generated files with nasty cells; the exact path is
forced by disabling the fast one."""

from __future__ import annotations

import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from loader_helpers import NO_DATA, canonical_frame, carma_frame

import avll.io._common as common
import avll.io.canonical as canonical
import avll.io.openacc_native as native
from avll.io import load_canonical, load_carma, read_runs, write_runs

PROP = settings(derandomize=True, deadline=None, max_examples=300,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def same(a: Any, b: Any) -> bool:
    """Equal, arrays bit for bit (NaN payloads and the sign of zero included)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype
                and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
                and a.tobytes() == b.tobytes())
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return type(a) is type(b) and len(a) == len(b) and all(map(same, a, b))
    if hasattr(a, "__dataclass_fields__"):
        return type(a) is type(b) and all(same(getattr(a, f), getattr(b, f))
                                          for f in a.__dataclass_fields__)
    if isinstance(a, float) and isinstance(b, float) and a != a and b != b:
        return True  # NaN
    return type(a) is type(b) and bool(a == b)


def outcome(call: Callable[[], Any]) -> tuple[Any, Any, list[tuple[type, str]]]:
    """(result, (exception type, message) or None, warnings as (category, message))."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            res, err = call(), None
        except Exception as e:  # noqa: BLE001 - compared, type and message
            res, err = None, (type(e), str(e))
    return res, err, [(w.category, str(w.message)) for w in caught]


def exact_paths(mp: pytest.MonkeyPatch) -> None:
    """The loaders take their exact paths (every fast path disabled)."""
    mp.setattr(native, "_fast_read", lambda path: None)
    mp.setattr(common, "read_csv_numeric", lambda *a, **k: None)
    mp.setattr(canonical, "read_csv_numeric", lambda *a, **k: None)


def assert_same(call: Callable[[], Any]) -> Any:
    """``call`` gives the same result, exception and warnings on both paths."""
    fast = outcome(call)
    with pytest.MonkeyPatch.context() as mp:
        exact_paths(mp)
        slow = outcome(call)
    assert fast[1] == slow[1]
    assert fast[2] == slow[2]
    assert same(fast[0], slow[0])
    return fast


# ------------------------------------------------------------ field data


def native_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*.csv") if native.is_openacc_native(p))


def test_native_field_files_fast_equals_exact(shared_data):
    files = native_files(shared_data)
    if not files:
        pytest.skip(NO_DATA)
    for p in files:
        assert native._fast_read(p) is not None, f"{p}: the fast path refused a published file"
        res, err, _ = assert_same(lambda p=p: native.read_openacc_native(p))
        assert err is None


@pytest.mark.parametrize("campaign", ["openacc-jrc/Casale", "openacc-jrc/JRC low speed",
                                      "openacc-zalazone"])
def test_native_campaign_runs_fast_equals_exact(shared_data, campaign):
    folder = shared_data / campaign
    if not folder.is_dir():
        pytest.skip(NO_DATA)
    runs, err, _ = assert_same(lambda: read_runs(folder, format="openacc"))
    assert err is None and runs


def test_carma_field_files_are_read_once(shared_data, monkeypatch):
    """The date and clock columns are text: kept from the one read, not read again."""
    files = sorted((shared_data / "carma").glob("*.csv"))
    if not files:
        pytest.skip(NO_DATA)
    reads: list[Any] = []
    real = common.pd.read_csv
    monkeypatch.setattr(common.pd, "read_csv", lambda *a, **k: reads.append(k) or real(*a, **k))
    for p in files:
        reads.clear()
        df = common.read_table(p, numeric=True)
        assert len(reads) == 1, f"{p}: read {len(reads)} times"
        assert all(isinstance(df[c].dtype, common.pd.StringDtype) for c in ("Date", "Heure"))
        assert not df[["Date", "Heure"]].isna().any().any()


# ------------------------------------------------------- generated files

NASTY = ["", " ", "nan", "NaN", "-nan", "NA", "N/A", "NULL", "None", "inf", "-inf",
         "Infinity", "1e400", "-1e400", "1e-400", "-0", "0x1p3", "1_000", '"1.5"', '"2,5"',
         "1e5", " 2.5", "2.5 ", "+1", ".5", "5.", ".", "-", "e", "1e", "True", "\u0661",
         "\t3", "3\t", "ACC", "Human", " human ", "x"]
NUMBER = st.floats(0.0, 30.0, allow_nan=False).map(lambda x: repr(round(x, 3)))
DRIVER = ["ACC", "Human", "", "acc", " ACC ", "HUMAN", "x", "1", "nan"]
SHAPES = ["short", "long_blank", "long_space", "long_text", "blank_before"]


@st.composite
def native_text(draw: Any) -> str:
    """A small native file, clean, then up to four mutations: a nasty cell, a short
    row, a long row (blank, spaces or text beyond the header), a blank line."""
    trail = draw(st.booleans())
    header = ["Time", "Speed1", "Speed2", "Alt2", "IVS1", "Driver2"]
    n = draw(st.integers(2, 8))
    rows = [[f"{100 + i * 0.1:.1f}"] + [draw(st.one_of(NUMBER, st.just("")))
                                        for _ in header[1:-1]]
            + [draw(st.sampled_from(DRIVER[:3]))] + ([""] if trail else []) for i in range(n)]
    shapes = [""] * n
    for _ in range(draw(st.integers(0, 4))):
        i = draw(st.integers(0, n - 1))
        if draw(st.booleans()):
            j = draw(st.integers(0, len(header) - 1))
            rows[i][j] = draw(st.sampled_from(DRIVER if j == len(header) - 1 else NASTY))
        else:
            shapes[i] = draw(st.sampled_from(SHAPES))
    lines = []
    for cells, shape in zip(rows, shapes, strict=True):
        if shape == "short":
            cells = cells[:draw(st.integers(0, len(cells) - 1))]
        elif shape.startswith("long"):
            cells = cells + [{"long_blank": "", "long_space": "  ", "long_text": "7"}[shape]] * (
                draw(st.integers(1, 2)))
        elif shape == "blank_before":
            lines.append(draw(st.sampled_from(["", " ", ",,,", "\t"])))
        lines.append(",".join(cells))
    lines += draw(st.lists(st.sampled_from(["", " ", ",,,,,,,,", " , ,"]), max_size=3))
    meta = ["Date,8,10,2019", "Vehicle_order,CAR_A,CAR_B" + ("," if trail else ""),
            "Number_of_vehicles,2", "ACC," + draw(st.sampled_from(["1", "2", ""])),
            "Distance_setting,L", ",".join(header) + ("," if trail else "")]
    eol = draw(st.sampled_from(["\n", "\r\n"]))
    text = eol.join(meta + lines) + draw(st.sampled_from([eol, ""]))
    return draw(st.sampled_from(["", "\ufeff"])) + text


def test_native_clean_file_takes_the_fast_path(tmp_path):
    text = ("Date,8,10,2019\nVehicle_order,A,B,\nNumber_of_vehicles,2\nACC,2\n"
            "Distance_setting,L\nTime,Speed1,Speed2,IVS1,Driver2\n"
            + "".join(f"{i / 10:.1f},10.0,10.5,{20 + i / 100},{'ACC' if i % 2 else ''}\n"
                      for i in range(50)) + ",,,,\n\n")
    p = tmp_path / "handling_part2.csv"
    p.write_text(text)
    assert native._fast_read(p) is not None
    nf = assert_same(lambda: native.read_openacc_native(p))[0]
    assert nf.t.shape == (50,) and nf.drivers[2].dtype == np.int8


# ------------------------------------------------------ CARMA, canonical


def test_carma_field_files_fast_equals_exact(shared_data):
    files = sorted((shared_data / "carma").glob("*.csv"))
    if not files:
        pytest.skip(NO_DATA)
    for p in files:
        df = common.read_csv_numeric(p, encoding="utf-8-sig")
        assert df is not None and (df.dtypes == np.float64).sum() > 50  # numbers parsed
        runs, err, _ = assert_same(lambda p=p: load_carma(p))
        assert err is None and runs
    assert_same(lambda: read_runs(shared_data / "carma", format="carma"))


def test_canonical_of_field_runs_fast_equals_exact(shared_data, tmp_path):
    """No canonical file is published: the field runs (CARMA: speed commands; Casale:
    leader signals and the grade) written in the canonical format, read back."""
    sets = {"carma": shared_data / "carma" / "data9.csv",
            "casale": shared_data / "openacc-jrc" / "Casale" / "part7.csv"}
    if not all(p.is_file() for p in sets.values()):
        pytest.skip(NO_DATA)
    for name, src in sets.items():
        runs = read_runs(src, format="carma" if name == "carma" else "openacc")
        f = write_runs(runs, tmp_path / f"{name}.csv")
        back, err, _ = assert_same(lambda f=f: load_canonical(f))
        assert err is None and [r.run_id for r in back] == [r.run_id for r in runs]


def mutate(draw: Any, lines: list[str], *, first: int = 1) -> list[str]:
    """Up to four mutations of the data lines (from ``first``): a nasty cell, a short
    row, a long row, a blank line."""
    lines = list(lines)
    for _ in range(draw(st.integers(0, 4))):
        i = draw(st.integers(first, len(lines) - 1))
        cells = lines[i].split(",")
        what = draw(st.sampled_from(["cell", "cell", "short", "long", "blank"]))
        if what == "cell":
            cells[draw(st.integers(0, len(cells) - 1))] = draw(st.sampled_from(NASTY))
        elif what == "short":
            cells = cells[:draw(st.integers(0, max(len(cells) - 1, 0)))]
        elif what == "long":
            cells.append(draw(st.sampled_from(["", " ", "7"])))
        else:
            lines.insert(i, draw(st.sampled_from(["", " ", ",,"])))
            continue
        lines[i] = ",".join(cells)
    return lines


@st.composite
def carma_text(draw: Any) -> str:
    df = carma_frame(n=draw(st.integers(30, 60)), vehicles=("leader",),
                     seed=draw(st.integers(0, 3)))
    lines = mutate(draw, df.to_csv(index=False, float_format="%.6g").splitlines())
    eol = draw(st.sampled_from(["\n", "\r\n"]))
    return draw(st.sampled_from(["", "\ufeff"])) + eol.join(lines) + eol


@st.composite
def canonical_text(draw: Any) -> str:
    df = canonical_frame(n=draw(st.integers(3, 12)), runs=draw(st.sampled_from(
        [("r1",), ("1", "2"), ("01", "r2")])), seed=draw(st.integers(0, 3)))
    lines = mutate(draw, df.to_csv(index=False).splitlines())
    eol = draw(st.sampled_from(["\n", "\r\n"]))
    return eol.join(lines) + draw(st.sampled_from([eol, ""]))


#: Each format's generated files, the name they are written under and how they are read.
GENERATED = {
    "native": (native_text, "dynamic_part1.csv", native.read_openacc_native),
    "carma": (carma_text, "data1.csv", lambda p: load_carma(p, min_duration=1.0)),
    "canonical": (canonical_text, "runs.csv",
                  lambda p: load_canonical(p, command_kind="acceleration")),
}


@pytest.mark.parametrize("fmt", GENERATED)
@PROP
@given(data=st.data())
def test_generated_files_fast_equals_exact(fmt, data):
    strategy, name, read = GENERATED[fmt]
    text = data.draw(strategy())
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / name
        p.write_bytes(text.encode("utf-8"))
        assert_same(lambda: read(p))
