"""Property-based fuzzing of the loaders and the main API.

CI-sized: derandomized (the same examples on every run), a few hundred examples in
all, a few seconds. The property everywhere: a call returns a well-formed result or
raises ``ValueError``/``TypeError`` (``avll.DataError`` is a ``ValueError``) -- never
another exception, a Rust panic (``RuntimeError``), a crash or a changed input file.
"""

from __future__ import annotations

import json
import math
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from loader_helpers import sha

import avll
from avll.io import load_carma, load_generic, read_runs

FUZZ = settings(derandomize=True, deadline=None, max_examples=60,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
OK_ERRORS = (ValueError, TypeError)

# cells: numbers of every kind, text, empty
CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**30, 10**30).map(str),
    st.sampled_from(["", "nan", "inf", "-inf", "1e300", "-1e308", "abc", "1,5", "0x10",
                     " 3 ", "NA", "None", "true", "\"", "'", ";", "é"]),
    st.floats(-20, 20).map(lambda x: f"{x:.4f}"),
)
NAMES = st.sampled_from(["run", "t", "a", "command", "v", "x", "lead_x", "lead_v", "lead_a",
                         "exo_grade", "exo_w", "Time", "junk", "a ", "t"])


def _csv(header: list[str], rows: list[list[str]]) -> str:
    return "\n".join([",".join(header), *(",".join(r) for r in rows)]) + "\n"


@st.composite
def tables(draw: Any) -> str:
    header = draw(st.lists(NAMES, min_size=1, max_size=8))
    n = draw(st.integers(0, 40))
    rows = []
    for i in range(n):
        row = []
        for h in header:
            if h == "t" and draw(st.booleans()):
                row.append(f"{0.05 * i:.2f}")
            elif h == "run":
                row.append(draw(st.sampled_from(["1", "2", "01", "1.0", "", "<b>"])))
            else:
                row.append(draw(CELLS))
        rows.append(row)
    return _csv(header, rows)


def _check_runs(runs: list[avll.Run]) -> None:
    assert isinstance(runs, list)
    for r in runs:
        assert isinstance(r, avll.Run) and len(r) >= 2
        assert np.all(np.isfinite(r.t)) and np.all(np.isfinite(r.a))


def _load_quietly(fn: Any, path: Path) -> None:
    before = sha(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", avll.DataWarning)
            _check_runs(fn(path))
    except OK_ERRORS:
        pass
    assert sha(path) == before


@FUZZ
@given(text=tables(), kind=st.sampled_from([None, "acceleration", "speed"]))
def test_fuzz_canonical_and_generic(text: str, kind: str | None) -> None:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "f.csv"
        p.write_text(text)
        _load_quietly(lambda q: read_runs(q, command_kind=kind), p)
        _load_quietly(lambda q: load_generic(q, command_kind=kind), p)
        _load_quietly(lambda q: load_generic(q, command_kind=kind or "speed", dt=0.1), p)


JSON = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5),
    lambda kids: st.lists(kids, max_size=3) | st.dictionaries(st.text(max_size=6), kids,
                                                             max_size=3),
    max_leaves=12,
)


@st.composite
def sidecars(draw: Any) -> Any:
    """Documents near the schema (most) or anywhere (some)."""
    if draw(st.booleans()):
        return draw(JSON)
    entry = st.fixed_dictionaries({}, optional={
        "upper": st.dictionaries(st.sampled_from(["kg", "kv", "Tg", "Gmin", "k"]),
                                 st.one_of(st.floats(), st.text(max_size=2), st.none()),
                                 max_size=4),
        "meta": JSON,
    })
    return draw(st.fixed_dictionaries({}, optional={
        "command_kind": st.sampled_from(["acceleration", "speed", "x", 1]),
        "runs": st.one_of(st.dictionaries(st.sampled_from(["1", "2", "01", "3", "1.0"]),
                                          st.one_of(entry, JSON), max_size=3), JSON),
    }))


@FUZZ
@given(doc=sidecars(), raw=st.booleans())
def test_fuzz_sidecar(doc: Any, raw: bool) -> None:
    from loader_helpers import canonical_frame

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "c.csv"
        canonical_frame(n=50, runs=("1", "2")).to_csv(p, index=False)
        sc = Path(d) / "c.csv.meta.json"
        sc.write_text(json.dumps(doc) if not raw else json.dumps(doc)[:-1])
        before = sha(sc)
        _load_quietly(lambda q: read_runs(q), p)
        assert sha(sc) == before


@FUZZ
@given(data=st.binary(max_size=300))
def test_fuzz_binary_files(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        for name in ("f.csv", "f.parquet"):
            p = Path(d) / name
            p.write_bytes(data)
            _load_quietly(lambda q: read_runs(q, command_kind="acceleration"), p)
            _load_quietly(lambda q: load_generic(q, command_kind="speed"), p)
            _load_quietly(lambda q: load_carma(q), p)


@settings(FUZZ, max_examples=15)
@given(cells=st.lists(st.tuples(st.integers(0, 59), st.sampled_from(
    ["leader_Speed_command", "leader_avg_speed_driven_wheels", "leader_acceleration",
     "leader_CARMA_mode", "Time"]), CELLS), max_size=6))
def test_fuzz_carma_cells(cells: list[tuple[int, str, str]]) -> None:
    from loader_helpers import carma_frame

    df = carma_frame(60, vehicles=("leader",)).astype(object)
    for row, col, val in cells:
        df.loc[row, col] = val
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "data5.csv"
        df.to_csv(p, index=False)
        _load_quietly(lambda q: load_carma(q, min_duration=0.5), p)


# ------------------------------------------------------------------ the API

NUMS = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                 st.sampled_from([0.0, -1.0, 1e-3, 0.05, 0.1, 1e300]))
ODD = st.sampled_from([None, "x", [1.0, 2.0], True, object()])


@st.composite
def models(draw: Any) -> Any:
    name = draw(st.sampled_from(["first", "second", "proposed"]))
    cls = avll.MODELS[name]
    k = len(cls.param_names())
    vals = draw(st.lists(st.one_of(st.floats(-3, 10), NUMS), min_size=k, max_size=k))
    try:
        return cls(*vals)
    except OK_ERRORS:
        return avll.PAPER_TABLE_II[name]


@st.composite
def arrays(draw: Any, n: int | None = None) -> Any:
    shape = draw(st.sampled_from([(), (0,), (1,), (2,), (30,), (3, 2)])) if n is None else (n,)
    size = int(np.prod(shape)) if shape else 1
    vals = draw(st.lists(st.one_of(st.floats(-5, 5), NUMS), min_size=size, max_size=size))
    if draw(st.integers(0, 9)) == 0:
        return draw(ODD)
    return np.array(vals, dtype=float).reshape(shape)


DT = st.one_of(st.sampled_from([0.05, 0.1, 1e-3, 0.0, -0.1, math.nan, math.inf, 1e6]),
               st.floats(0.01, 1.0), ODD)


@FUZZ
@given(m=models(), u=arrays(), dt=DT, init=st.sampled_from(["rest", "steady", "x"]))
def test_fuzz_simulate(m: Any, u: Any, dt: Any, init: str) -> None:
    try:
        y = avll.simulate(m, u, dt, init=init)
    except OK_ERRORS:
        return
    assert y.shape == np.shape(u) and np.all(np.isfinite(y))
    try:
        tr = avll.simulate_full(m, u, dt, command_kind="speed", init=init)
    except OK_ERRORS:
        return
    assert tr.v.shape == np.shape(u) and np.all(np.isfinite(tr.v))


@FUZZ
@given(m=models(), lx=arrays(), lv=arrays(), dt=DT,
       up=st.tuples(NUMS, NUMS, NUMS, NUMS), v0=NUMS,
       followers=st.one_of(st.integers(-2, 4), ODD))
def test_fuzz_closed_loop_and_platoon(m: Any, lx: Any, lv: Any, dt: Any, up: Any, v0: Any,
                                      followers: Any) -> None:
    try:
        upper = avll.UpperLevel(*up)
    except OK_ERRORS:
        upper = avll.UpperLevel(0.3, 0.2, 2.0, 9.5)
    try:
        tr = avll.closed_loop(m, lx, lv, dt, upper, v0=v0, x0=0.0)
        assert tr.a.shape == np.shape(lx)
    except OK_ERRORS:
        pass
    try:
        pl = avll.platoon(m, lx, lv, dt, upper, followers)
        assert pl.a.shape == (followers, np.size(lx))
    except OK_ERRORS:
        pass


@FUZZ
@given(params=arrays(), model=st.sampled_from(["first", "second", "proposed", "nope"]),
       threads=st.one_of(st.integers(-1, 3), ODD, st.just(10**6)),
       weights=st.tuples(NUMS, NUMS, NUMS),
       closed=st.booleans())
def test_fuzz_batch_cost(params: Any, model: str, threads: Any, weights: Any,
                         closed: bool) -> None:
    runs = _RUNS
    try:
        c = avll.batch_cost(model, params, runs, threads=threads, weights=weights,
                            closed_loop=closed)
    except OK_ERRORS:
        return
    assert c.shape[1] == len(runs)
    assert not np.any(np.isnan(c))  # invalid or unstable rows are inf, never NaN


_RUNS = avll.synth.paper_experiment(runs=(1, 3), duration=8.0)


@FUZZ
@given(kg=arrays(), tg=arrays(), kv=arrays(), m=models(),
       order=st.one_of(st.integers(-1, 12), st.floats(0, 3), ODD),
       threads=st.one_of(st.integers(-1, 3), ODD))
def test_fuzz_stability_map(kg: Any, tg: Any, kv: Any, m: Any, order: Any,
                            threads: Any) -> None:
    try:
        codes = avll.stability_map(m, kg, tg, kv, order, threads=threads)
    except OK_ERRORS:
        return
    assert codes.shape == (np.size(kg), np.size(tg), np.size(kv))
    assert set(np.unique(codes)) <= {0, 1, 2}


@pytest.mark.parametrize("value", [-7 / 30, -1, math.inf, math.nan, "x", None])
def test_capacity_refuses_what_is_not_a_time_gap(value: Any) -> None:
    if isinstance(value, float) and math.isnan(value):
        assert math.isnan(avll.capacity(value))  # "no stable Tg" stays NaN
        return
    with pytest.raises(OK_ERRORS, match="tg"):
        avll.capacity(value)


def test_issue_api_cases_name_their_argument() -> None:
    m = avll.PAPER_TABLE_II["proposed"]
    t = np.arange(50) * 0.05
    with pytest.raises(TypeError, match="upper: expected an avll.UpperLevel, got None"):
        avll.closed_loop(m, 10 * t, np.full(50, 10.0), 0.05, None, v0=10, x0=0)  # type: ignore
    with pytest.raises(ValueError, match="seed: must be <= 18446744073709551615"):
        avll.calibrate("first", _RUNS, seed=99999999999999999999999)
    with pytest.raises(TypeError, match="dt: must be a number, got 'a'"):
        avll.simulate(m, np.ones(5), "a")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="command: expected an array of numbers"):
        avll.simulate(m, "abc", 0.05)
    with pytest.raises(TypeError, match="kv_lo: must be a number, got None"):
        avll.kv_threshold(m, [0.1], [2.0], None, 1.0)  # type: ignore[arg-type]
