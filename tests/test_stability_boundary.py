"""Exact boundaries, thresholds as infima/suprema, the exact-delay test and the
Padé-error map, checked against dense grids of the exact point test."""

from __future__ import annotations

import math

import numpy as np
import pytest

import avll
from avll import stability as S

P = avll.PAPER_TABLE_II


def _stable(model: avll.LowerLevelModel, kg: object, tg: object, kv: object,
            order: int = 2) -> np.ndarray:
    return S.stability_points(model, kg, tg, kv, order) == S.STABLE


@pytest.mark.parametrize("name", ["first", "second", "proposed"])
def test_tg_min_boundary_against_a_dense_grid(name: str) -> None:
    """Contract of boundary(model, "tg_min", kg=, kv=): dims (kg, kv), NaN where nothing
    is stable in the searched range (an attribute); the value is stable, a point 1e-8
    below it is not, and no point of a 3001-point Tg grid below it is stable."""
    m = P[name]
    kg = np.geomspace(0.005, 3.0, 9)
    kv = np.array([-0.2, 0.0, 0.25, 0.45, 0.7, 1.0])
    b = avll.boundary(m, "tg_min", kg=kg, kv=kv)
    assert b.dims == ("kg", "kv") and b.shape == (9, 6)
    assert list(b.attrs["search_range"]) == [0.0, 15.0]
    assert b.attrs["model"] == name and b.attrs["pade_order"] == 2
    tg_grid = np.linspace(0, 15, 3001)
    n_val = n_nan = 0
    for i, g in enumerate(kg):
        for j, v in enumerate(kv):
            t = float(b.values[i, j])
            st = _stable(m, g, tg_grid, v)
            if math.isnan(t):
                assert not st.any(), (g, v)
                n_nan += 1
                continue
            n_val += 1
            assert _stable(m, g, t, v)
            if t > 0:
                assert not _stable(m, g, t * (1 - 1e-8), v), (g, t, v)
            assert not st[tg_grid < t].any(), (g, v, t)
            if st.any():
                assert t <= tg_grid[st][0]
    assert n_val > 5 and n_nan > 0


@pytest.mark.parametrize("name", ["second", "proposed"])
def test_kg_max_boundary_against_a_dense_grid(name: str) -> None:
    m = P[name]
    tg = np.array([1.0, 2.5, 4.0, 7.0, 12.0])
    kv = np.array([0.0, 0.3, 0.6])
    b = avll.boundary(m, "kg_max", tg=tg, kv=kv, search_range=(1e-3, 5.0))
    assert b.dims == ("Tg", "kv")
    kg_grid = np.geomspace(1e-3, 5.0, 3001)
    seen = 0
    for i, t in enumerate(tg):
        for j, v in enumerate(kv):
            k = float(b.values[i, j])
            st = _stable(m, kg_grid, t, v)
            if math.isnan(k):
                assert not st.any()
                continue
            seen += 1
            assert _stable(m, k, t, v)
            if k < 5.0:
                assert not _stable(m, k * (1 + 1e-8), t, v)
            assert not st[kg_grid > k].any()
    assert seen >= 5


def test_stable_intervals_cover_the_grid() -> None:
    """The stable set in Tg is not always one interval; every grid point's verdict
    matches membership in the returned intervals."""
    m = P["proposed"]
    rng = np.random.default_rng(4)
    for _ in range(25):
        kg, kv = 10 ** rng.uniform(-2.5, 0.3), rng.uniform(0, 0.9)
        ivs = S.stable_intervals(m, "tg", kg=kg, kv=kv)
        t = np.linspace(0, 15, 2001)
        inside = np.zeros(t.size, bool)
        near = np.zeros(t.size, bool)
        for lo, hi in ivs:
            inside |= (t >= lo) & (t <= hi)
            near |= (np.abs(t - lo) < 1e-6) | (np.abs(t - hi) < 1e-6)
        np.testing.assert_array_equal(_stable(m, kg, t, kv)[~near], inside[~near])


def test_min_stable_tg_first_order_is_twice_the_lag() -> None:
    """Appendix A.4 of the paper: the first-order lag is stable iff ... and
    (Tg/Td - 2) kg > (kv - 1/(2Td))^2, so the infimum of Tg is 2 Td, approached at
    kv = 1/(2 Td) (for any kg)."""
    td = P["first"].Td
    e = avll.min_stable_tg(P["first"])
    assert e.value == pytest.approx(2 * td, rel=1e-9)
    # the boundary is quadratic in kv - 1/(2 Td) there: a 1e-10 value tolerance
    # locates kv to about 1e-5
    assert e.kv == pytest.approx(1 / (2 * td), rel=1e-4)
    assert not e.attained


@pytest.mark.parametrize("name", ["second", "proposed"])
def test_min_stable_tg_is_an_infimum(name: str) -> None:
    """The returned point is stable; no random point of the box with a smaller Tg is
    stable; a larger box never gives a larger infimum."""
    m = P[name]
    e = avll.min_stable_tg(m, kg_range=(1e-3, 2.0), kv_range=(0.0, 1.2))
    assert _stable(m, e.kg, e.tg, e.kv)
    assert not _stable(m, e.kg, e.tg * (1 - 1e-8), e.kv)
    rng = np.random.default_rng(1)
    n = 400_000
    kg = 10 ** rng.uniform(-3, math.log10(2.0), n)
    kv = rng.uniform(0, 1.2, n)
    tg = rng.uniform(0, e.value, n)
    assert not _stable(m, kg, tg, kv).any()
    # a dense grid around the point where it is approached: nothing below either
    kgl = np.geomspace(max(1e-3, e.kg / 1.5), min(2.0, e.kg * 1.5), 200)
    kvl = np.linspace(max(0, e.kv - 0.05), min(1.2, e.kv + 0.05), 200)
    g = np.meshgrid(kgl, kvl, indexing="ij")
    for f in (0.9999, 0.99999):
        assert not _stable(m, g[0], e.value * f, g[1]).any()
    bigger = avll.min_stable_tg(m, kg_range=(1e-6, 2.0), kv_range=(0.0, 1.2))
    assert bigger.value <= e.value + 1e-7
    assert e.capacity == pytest.approx(S.capacity(e.value))
    assert e.to_dict()["quantity"] == "tg_min"


def test_kv_supremum_and_grid_threshold() -> None:
    m = P["second"]
    e = avll.kv_supremum(m, kg_range=(1e-3, 5.0), tg_range=(0.0, 15.0))
    assert _stable(m, e.kg, e.tg, e.kv)
    assert not _stable(m, e.kg, e.tg, e.kv + 1e-7)
    rng = np.random.default_rng(2)
    n = 300_000
    kg = 10 ** rng.uniform(-3, math.log10(5), n)
    tg = rng.uniform(0, 15, n)
    kv = rng.uniform(e.value, e.value + 0.05, n)
    assert not _stable(m, kg, tg, kv).any()
    # the grid threshold is a lower bound of the supremum (up to its tolerance)
    thr = avll.kv_threshold(m, np.geomspace(1e-3, 5, 300), np.linspace(0, 15, 301), 0.5, 1.0,
                            tol=1e-6)
    assert thr <= e.value + 1e-6
    assert "tg" in e.on_edge  # reached at the Tg range end (15 s)


def _kv_threshold_python(model: avll.LowerLevelModel, kg: np.ndarray, tg: np.ndarray,
                         lo: float, hi: float, tol: float, order: int = 2) -> float:
    """The former pure-Python bisection (the oracle of the Rust one)."""

    def any_stable(v: float) -> bool:
        return bool((S.stability_map(model, kg, tg, [v], order) == S.STABLE).any())

    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if any_stable(mid):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("order", [1, 2, 5])
def test_kv_threshold_in_rust_equals_the_python_bisection(order: int) -> None:
    kg = np.geomspace(1e-3, 5, 120)
    tg = np.linspace(0, 15, 121)
    for name in ("second", "proposed"):
        got = avll.kv_threshold(P[name], kg, tg, 0.3, 1.2, order, tol=1e-5)
        want = _kv_threshold_python(P[name], kg, tg, 0.3, 1.2, 1e-5, order)
        assert got == want, (name, order, got, want)
    with pytest.raises(ValueError, match="kv_hi"):
        avll.kv_threshold(P["second"], kg, tg, 0.3, 0.5)
    with pytest.raises(ValueError, match="kv_lo"):
        avll.kv_threshold(P["second"], kg, tg, 1.1, 1.2)


def test_exact_delay_against_high_pade_orders() -> None:
    """Away from the boundary the exact-delay codes equal Padé order 10's; the first-
    order lag (no delay) equals its Padé map everywhere."""
    rng = np.random.default_rng(8)
    for name in ("second", "proposed"):
        m = P[name]
        n = 3000
        kg = 10 ** rng.uniform(-2.5, 0.3, n)
        tg = rng.uniform(0, 12, n)
        kv = rng.uniform(-0.2, 1.0, n)
        c10 = S.stability_points(m, kg, tg, kv, 10)
        far = np.ones(n, bool)
        for f in (0.97, 1.03):
            far &= S.stability_points(m, kg * f, tg, kv, 10) == c10
            far &= S.stability_points(m, kg, tg * f, kv, 10) == c10
        codes, ok = avll.exact_delay_codes(m, kg, tg, kv)
        assert ok[far].all()
        np.testing.assert_array_equal(codes[far], c10[far])
        assert np.bincount(codes[far], minlength=3).min() > 50
    m = P["first"]
    kg, tg, kv = rng.uniform(0.01, 2, 2000), rng.uniform(0, 8, 2000), rng.uniform(-0.3, 1, 2000)
    codes, ok = avll.exact_delay_codes(m, kg, tg, kv)
    c = S.stability_points(m, kg, tg, kv)
    agree = (codes == c) | ~ok
    assert agree.all() and ok.mean() > 0.99


def test_exact_delay_local_boundary_is_sharp() -> None:
    """Points 1e-6 either side of an exact-delay local boundary (found by bisection on
    the exact test) get opposite local verdicts, and the Padé-10 boundary is close."""
    m = P["proposed"]
    kv, tg = 0.2, 3.0
    lo, hi = 0.01, 3.0
    c_lo = avll.exact_delay_codes(m, lo, tg, kv)[0][0] > 0
    c_hi = avll.exact_delay_codes(m, hi, tg, kv)[0][0] > 0
    assert c_lo != c_hi
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if (avll.exact_delay_codes(m, mid, tg, kv)[0][0] > 0) == c_lo:
            lo = mid
        else:
            hi = mid
    k = S.stable_intervals(m, "kg", tg=tg, kv=kv, pade_order=10, level="local",
                           search_range=(0.01, 3.0))
    ends = [x for iv in k for x in iv]
    assert min(abs(e - lo) / lo for e in ends) < 1e-3
    b = avll.boundary(m, "kg_max", tg=[tg], kv=[kv], pade_order=None, level="local",
                      search_range=(0.01, 3.0))
    assert float(b.values[0, 0]) == pytest.approx(lo, rel=1e-8)


def test_exact_delay_string_certified_and_margin() -> None:
    m = P["proposed"]
    st, margin = S.exact_delay_string(m, [0.3, 0.05, 0.3], [4.0, 1.0, 9.0], [0.2, 0.3, 0.5])
    assert st.dtype == bool and margin.shape == (3,)
    # the sampled margin agrees in sign with the certified verdict
    assert ((margin > 0) == st).all()


def test_pade_error_map_shrinks_with_the_order() -> None:
    kg = np.geomspace(0.003, 2.0, 24)
    tg = np.linspace(0, 15, 31)
    kv = np.array([0.0, 0.3, 0.6])
    ds = avll.pade_error_map(P["proposed"], kg, tg, kv, orders=(1, 2, 4, 10))
    assert ds["pade"].dims == ("pade_order", "kg", "Tg", "kv")
    frac = ds["fraction_differs"].values
    assert frac[-1] <= frac[0] and frac[-1] < 0.01
    assert ds["certified"].values.mean() > 0.99
    np.testing.assert_array_equal(ds["pade"].sel(pade_order=2).values,
                                  S.stability_map(P["proposed"], kg, tg, kv, 2))


def test_boundary_bad_input() -> None:
    m = P["proposed"]
    with pytest.raises(ValueError, match="which"):
        avll.boundary(m, "foo", kg=[0.1], kv=[0.1])
    with pytest.raises(ValueError, match="kv"):
        avll.boundary(m, "tg_min", kg=[0.1])
    with pytest.raises(ValueError, match="search_range"):
        avll.boundary(m, "tg_min", kg=[0.1], kv=[0.1], search_range=(5, 1))
    with pytest.raises(ValueError, match="level"):
        avll.boundary(m, "tg_min", kg=[0.1], kv=[0.1], level="both")
    with pytest.raises(ValueError, match="kg_range"):
        avll.min_stable_tg(m, kg_range=(0.0, 1.0))
    with pytest.raises(ValueError, match="model"):
        avll.boundary("proposed", "tg_min", kg=[0.1], kv=[0.1])  # type: ignore[arg-type]


def test_cli_exact_thresholds(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    import json

    from avll.cli import main

    js = tmp_path / "th.json"
    rc = main(["stability-map", "--models", "proposed", "--kg", "0.001", "2", "20",
               "--tg", "0", "15", "31", "--kv", "0", "1", "6", "--out", "",
               "--json", str(js), "--quiet", "--exact"])
    assert rc == 0
    doc = json.loads(js.read_text())
    e = doc["exact"]["proposed"]["min_stable_tg"]
    assert e["value"] == avll.min_stable_tg(P["proposed"], (0.001, 2.0), (0.0, 1.0)).value
    assert "inf Tg" in capsys.readouterr().out


def test_ctrl_c_stops_an_exact_delay_search(sigint_handler: None) -> None:
    """An exact-delay infimum search takes a minute; SIGINT stops it within seconds."""
    import os
    import signal
    import threading
    import time

    if os.name != "posix":
        pytest.skip("needs SIGINT delivery")
    timer = threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT))
    t0 = time.perf_counter()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        avll.min_stable_tg(P["proposed"], (0.1, 0.4), (0.3, 0.6), None)
    timer.cancel()
    assert time.perf_counter() - t0 < 10.0


def test_generated_docs_numbers_match_the_code() -> None:
    """docs/_generated/stability_numbers.json (docs/gen/stability_numbers.py) is not
    stale: a few of its numbers recomputed."""
    import json
    import pathlib

    path = pathlib.Path(__file__).resolve().parents[1] / "docs/_generated/stability_numbers.json"
    if not path.exists():
        pytest.skip("generated docs numbers absent")
    doc = json.loads(path.read_text())
    for name in ("second", "proposed"):
        e = avll.min_stable_tg(P[name], kg_range=(1e-3, 2.0), kv_range=(0.0, 1.2))
        assert doc["min_stable_tg"][f"{name}/0.001"]["value"] == pytest.approx(e.value, rel=1e-9)
        s = avll.kv_supremum(P[name], kg_range=(1e-3, 5.0), tg_range=(0.0, 15.0))
        assert doc["kv_supremum"][f"{name}/0.001"]["value"] == pytest.approx(s.value, rel=1e-9)
