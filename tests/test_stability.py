"""Stability maps (paper Section IV): Rust engine vs the numpy reference, the
paper's closed forms, Padé orders, the exact delay and time-domain platoons."""

from __future__ import annotations

import math
import os
import signal
import threading
import time

import numpy as np
import pytest

import avll
from avll import _core
from avll import stability as S
from avll.reference import stability as ref

P = avll.PAPER_TABLE_II
NAMES = ["first", "second", "proposed"]
#: relative parameter perturbation within which a point counts as "on the boundary"
BOUNDARY_REL = 1e-6


def _params(m: avll.LowerLevelModel) -> list[float]:
    return [float(v) for v in m.to_array()]


def _random_points(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    # half log-uniform kg (small gains matter for the thresholds), half uniform
    kg = np.concatenate([10 ** rng.uniform(-3, 0.3, n // 2), rng.uniform(0, 2, n - n // 2)])
    tg = rng.uniform(0, 15, n)
    kv = rng.uniform(-0.3, 1.5, n)
    return kg, tg, kv


def _boundary_points(
    model: avll.LowerLevelModel, rng: np.random.Generator, n: int
) -> tuple[np.ndarray, ...]:
    """Points at a relative distance 1e-4 (in kg) on either side of a code change
    found by bisection along kg with the engine (all pairs bisected at once)."""
    kg, tg, kv = _random_points(rng, 8 * n)
    kg2 = kg * rng.uniform(0.2, 5.0, kg.size)
    c = S.stability_points(model, kg, tg, kv)
    c2 = S.stability_points(model, kg2, tg, kv)
    sel = np.nonzero(c != c2)[0][: n // 2]
    assert sel.size == n // 2
    lo, hi, clo, tg, kv = kg[sel], kg2[sel], c[sel], tg[sel], kv[sel]
    for _ in range(60):
        mid = np.sqrt(lo * hi)
        same = S.stability_points(model, mid, tg, kv) == clo
        lo, hi = np.where(same, mid, lo), np.where(same, hi, mid)
    kgb = np.concatenate([lo * (1 - 1e-4), lo * (1 + 1e-4)])
    return kgb, np.concatenate([tg, tg]), np.concatenate([kv, kv])


def _flips_nearby(
    model: avll.LowerLevelModel, kg: float, tg: float, kv: float, order: int = 2
) -> bool:
    """True if the reference verdict changes within BOUNDARY_REL of the point."""
    base = ref.stability_code(model, kg, tg, kv, order)
    for j in range(3):
        for f in (1 - BOUNDARY_REL, 1 + BOUNDARY_REL):
            p = [kg, tg, kv]
            p[j] = p[j] * f if p[j] != 0 else (f - 1)
            if ref.stability_code(model, p[0], p[1], p[2], order) != base:
                return True
    return False


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize(
    "n_random", [2_000, pytest.param(10_000, marks=pytest.mark.slow)]
)
def test_engine_agrees_with_numpy_reference(name: str, n_random: int) -> None:
    """>= 10,000 random points per model (slow variant; 2,000 in the fast one) plus
    points 1e-4 (relative, in kg) from the engine's boundary, against the reference."""
    model = P[name]
    rng = np.random.default_rng(100 + NAMES.index(name) + n_random)
    kg, tg, kv = _random_points(rng, n_random)
    bkg, btg, bkv = _boundary_points(model, rng, n_random // 10)
    kg, tg, kv = (np.concatenate(p) for p in ((kg, bkg), (tg, btg), (kv, bkv)))
    rust = S.stability_points(model, kg, tg, kv)
    refc, _ = ref.stability_codes(model, kg, tg, kv)
    counts = np.bincount(refc, minlength=3)
    assert (counts > n_random // 50).all(), counts  # every code is exercised
    bad = np.nonzero(rust != refc)[0]
    unexplained = [i for i in bad if not _flips_nearby(model, kg[i], tg[i], kv[i])]
    assert not unexplained, [(kg[i], tg[i], kv[i], rust[i], refc[i]) for i in unexplained]
    # explained (on-boundary) disagreements are rare
    assert len(bad) <= 0.002 * kg.size, len(bad)


@pytest.mark.parametrize("name", ["second", "proposed"])
def test_engine_agrees_with_reference_at_every_pade_order(name: str) -> None:
    """Orders 1..PADE_MAX_ORDER (high orders make R badly scaled: a Sturm count
    without rescaling once missed two positive roots at order 5)."""
    model = P[name]
    rng = np.random.default_rng(77)
    # half in the small-kg, large-Tg, kv ~ threshold corner where R is worst scaled
    kg = np.concatenate([10 ** rng.uniform(-3.5, -1.0, 300), rng.uniform(0, 2, 300)])
    tg = np.concatenate([rng.uniform(2, 15, 300), rng.uniform(0, 15, 300)])
    kv = np.concatenate([rng.uniform(0.4, 1.0, 300), rng.uniform(-0.3, 1.5, 300)])
    for order in range(1, S.PADE_MAX_ORDER + 1):
        rust = S.stability_points(model, kg, tg, kv, order)
        refc, _ = ref.stability_codes(model, kg, tg, kv, order)
        bad = [i for i in np.nonzero(rust != refc)[0]
               if not _flips_nearby(model, kg[i], tg[i], kv[i], order)]
        assert not bad, (order, [(kg[i], tg[i], kv[i], rust[i], refc[i]) for i in bad])


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("order", [1, 2, 3, 5])
def test_polynomials_equal_reference_products(name: str, order: int) -> None:
    rng = np.random.default_rng(order)
    for _ in range(20):
        kg, tg, kv = rng.uniform(0, 2), rng.uniform(0, 10), rng.uniform(-1, 2)
        n, d, r = _core.stability_polys(name, _params(P[name]), kg, tg, kv, order)
        rn, rd = ref.closed_loop_polys(P[name], kg, tg, kv, order)
        np.testing.assert_allclose(n[::-1], rn, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(d[::-1], rd, rtol=1e-12, atol=1e-14)
        rp = ref.string_poly(rn, rd)
        assert abs(rp[-1]) <= 1e-12 * np.abs(rp).max()  # P(0) = 0
        np.testing.assert_allclose(r[::-1], rp[:-1], rtol=1e-9, atol=1e-12 * np.abs(rp).max())


def test_paper_eq14_coefficients() -> None:
    """Eq. 14 (a1..a7) and Eq. 17 (b1'..b5') of the proposed model, Padé 2."""
    m = P["proposed"]
    m1, m2, m3, k0, td, k = m.m1, m.m2, m.m3, m.K0, m.Td, m.K
    p1, p2 = 0.5, 1 / 12
    for kg, tg, kv in [(0.5, 2.0, 0.05), (0.1, 5.0, 0.4), (1.3, 0.7, 1.1)]:
        mu = kv + tg * kg
        a = [
            m2 * td**2 * p2,
            -(td**2) * k * m1 * p2 + td**2 * m3 * p2 + td * m2 * p1,
            -k * k0 * td**2 * p2 + k * m1 * td * p1 + td**2 * p2 + m3 * td * p1 + m2
            + m1 * td**2 * p2 * mu,
            k * k0 * td * p1 + td * p1 - k * m1 + m3 + (k0 * td**2 * p2 - td * m1 * p1) * mu
            + m1 * td**2 * p2 * kg,
            -k * k0 + (-k0 * td * p1 + m1) * mu + (k0 * td**2 * p2 - td * m1 * p1) * kg + 1,
            k0 * mu + (-k0 * td * p1 + m1) * kg,
            k0 * kg,
        ]
        b = [
            td**2 * kv * m1 * p2,
            k0 * td**2 * kv * p2 + td**2 * kg * m1 * p2 - td * kv * m1 * p1,
            k0 * td**2 * kg * p2 - k0 * td * kv * p1 - td * kg * m1 * p1 + kv * m1,
            -k0 * td * kg * p1 + k0 * kv + kg * m1,
            k0 * kg,
        ]
        n, d, _ = _core.stability_polys("proposed", _params(m), kg, tg, kv, 2)
        np.testing.assert_allclose(d[::-1], a, rtol=1e-12)
        np.testing.assert_allclose(n[::-1], b, rtol=1e-12, atol=1e-15)


def test_first_order_lag_matches_appendix() -> None:
    td = P["first"].Td
    rng = np.random.default_rng(5)
    kg = rng.uniform(1e-3, 2, 50_000)
    tg = rng.uniform(0, 6, kg.size)
    kv = rng.uniform(-0.5, 2, kg.size)
    mu = kv + tg * kg
    local = kv + kg * (tg - td)  # A.3
    c0 = tg * kv + tg**2 * kg / 2 - 1
    edge = mu - 1 / (2 * td)
    disc = (tg / td - 2) * kg - (kv - 1 / (2 * td)) ** 2
    string = ((edge <= 0) & (c0 > 0)) | ((edge >= 0) & (disc > 0))  # A.4
    expect = np.where(local <= 0, 0, np.where(string, 2, 1))
    keep = np.min(np.abs([local, c0, edge, disc]), axis=0) > 1e-9
    got = S.stability_points(P["first"], kg, tg, kv)
    assert keep.mean() > 0.99
    np.testing.assert_array_equal(got[keep], expect[keep])


def test_pade_orders_agree_far_from_boundary() -> None:
    """Away from the boundary (the order-5 verdict unchanged within ±10 % of every
    parameter) all orders 2..5 give the same code."""
    rng = np.random.default_rng(9)
    for name in ("second", "proposed"):
        m = P[name]
        kg, tg, kv = _random_points(rng, 4000)
        c5 = S.stability_points(m, kg, tg, kv, 5)
        far = np.ones(kg.size, dtype=bool)
        for j in range(3):
            for f in (0.9, 1.1):
                p = [kg, tg, kv]
                p[j] = p[j] * f
                far &= S.stability_points(m, *p, pade_order=5) == c5
        assert far.mean() > 0.5
        for order in (2, 3, 4):
            c = S.stability_points(m, kg, tg, kv, order)
            np.testing.assert_array_equal(c[far], c5[far])


def test_map_layout_threads_and_errors() -> None:
    m = P["proposed"]
    kg = np.linspace(0.01, 1, 17)
    tg = np.linspace(0, 10, 13)
    kv = np.array([0.0, 0.3, 0.6])
    mp = S.stability_map(m, kg, tg, kv, threads=1)
    assert mp.shape == (17, 13, 3) and mp.dtype == np.uint8
    assert np.array_equal(mp, S.stability_map(m, kg, tg, kv, threads=2))
    g = np.meshgrid(kg, tg, kv, indexing="ij")
    assert np.array_equal(mp, S.stability_points(m, *g))
    with pytest.raises(ValueError, match="pade_order"):
        S.stability_map(m, kg, tg, kv, pade_order=0)
    with pytest.raises(ValueError, match="pade_order"):
        S.stability_map(m, kg, tg, kv, pade_order=S.PADE_MAX_ORDER + 1)
    with pytest.raises(ValueError, match="kg"):
        S.stability_map(m, [], tg, kv)
    with pytest.raises(ValueError, match="tg"):
        S.stability_map(m, kg, [np.nan], kv)
    with pytest.raises(ValueError, match="model"):
        S.stability_map("proposed", kg, tg, kv)  # type: ignore[arg-type]


def test_progress_callback_and_interrupt_from_callback() -> None:
    m = P["second"]
    kg = np.linspace(0.01, 1, 1500)
    tg = np.linspace(0, 15, 1500)
    calls: list[tuple[int, int]] = []
    _core.stability_map("second", _params(m), kg, tg, np.array([0.2]), 2, 0,
                        lambda d, t: calls.append((d, t)))
    assert calls[-1] == (kg.size * tg.size, kg.size * tg.size) and len(calls) >= 2
    assert all(a[0] < b[0] for a, b in zip(calls, calls[1:], strict=False))

    def stop(done: int, total: int) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _core.stability_map("second", _params(m), kg, tg, np.array([0.2]), 2, 0, stop)


@pytest.mark.skipif(os.name != "posix", reason="needs SIGINT delivery")
def test_ctrl_c_interrupts_a_long_map(sigint_handler: None) -> None:
    m = P["proposed"]
    kg = np.linspace(0.01, 1, 4000)
    tg = np.linspace(0, 15, 4000)
    kv = np.linspace(0, 1, 8)  # 128 M points: many seconds
    timer = threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT))
    t0 = time.perf_counter()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        S.stability_map(m, kg, tg, kv, pade_order=5)
    timer.cancel()
    assert time.perf_counter() - t0 < 5.0


def test_thresholds_on_a_hand_made_map() -> None:
    kg = np.array([0.1, 0.2, 0.3])
    tg = np.array([1.0, 2.0, 3.0, 4.0])
    kv = np.array([0.5, 0.0, 1.0])
    codes = np.zeros((3, 4, 3), dtype=np.uint8)
    codes[0, 3, 1] = 2
    codes[1, 2, 1] = 2
    codes[2, 1, 0] = 2
    codes[0, 0, 0] = 1  # string unstable: not counted
    th = S.thresholds(codes, kg, tg, kv)
    np.testing.assert_array_equal(th.kg_max, [0.3, 0.2, np.nan])
    np.testing.assert_array_equal(th.tg_min, [2.0, 3.0, np.nan])
    assert th.kv_last_stable == 0.5 and th.kv_first_empty == 1.0
    assert th.tg_min_overall == 2.0
    assert th.to_dict()["kg_max"][2] is None
    with pytest.raises(ValueError, match="codes"):
        S.thresholds(codes[:2], kg, tg, kv)


def test_capacity_formula() -> None:
    # the stated formula with the default constants (l/v = 7/30 s)
    assert S.capacity(1.9) == pytest.approx(1687.5)
    assert S.capacity(3.5) == pytest.approx(964.2857, rel=1e-6)
    assert S.capacity(2.2) == pytest.approx(1479.45, rel=1e-5)
    np.testing.assert_allclose(S.capacity(np.array([0.0])), [3600 / (7 / 30)])
    assert S.capacity(2.0, length=0.0) == 1800.0
    with pytest.raises(ValueError, match="speed"):
        S.capacity(2.0, speed=0.0)


def test_section_iv_minimum_time_gaps() -> None:
    """Paper: minimum stable Tg 1.9 s (second), 3.5 s (proposed), 2.2 s (first) at 0.1 s
    resolution over Tg in [0, 15], kv in [0, 1.2]."""
    kg = np.geomspace(1e-3, 5, 300)
    tg = np.round(np.arange(0, 15.0001, 0.1), 10)
    kv = np.linspace(0, 1.2, 61)
    got = {n: S.thresholds(S.stability_map(P[n], kg, tg, kv), kg, tg, kv).tg_min_overall
           for n in NAMES}
    assert got == {"first": 2.2, "second": 1.9, "proposed": 3.5}


def test_section_iv_kv_thresholds() -> None:
    """Paper: beyond kv = 0.8085 (second) / 0.7395 (proposed) nothing is stable for
    Tg in [0, 15]; here kg in [1e-3, 5] (log, 300) and Tg at 0.05 s."""
    kg = np.geomspace(1e-3, 5, 300)
    tg = np.linspace(0, 15, 301)
    for name, paper in (("second", 0.8085), ("proposed", 0.7395)):
        thr = S.kv_threshold(P[name], kg, tg, 0.5, 1.0, tol=1e-4)
        assert abs(thr - paper) < 2e-3, (name, thr)


def test_exact_delay_string_matches_high_order_pade_far_from_boundary() -> None:
    rng = np.random.default_rng(21)
    m = P["proposed"]
    kg, tg, kv = _random_points(rng, 300)
    c8 = S.stability_points(m, kg, tg, kv, 8)
    loc = c8 > 0
    kg, tg, kv, c8 = kg[loc], tg[loc], kv[loc], c8[loc]
    st, margin = S.exact_delay_string(m, kg, tg, kv)
    far = np.ones(kg.size, dtype=bool)
    for f in (0.97, 1.03):
        far &= S.stability_points(m, kg * f, tg, kv, 8) == c8
        far &= S.stability_points(m, kg, tg * f, kv, 8) == c8
    assert far.sum() > 30
    np.testing.assert_array_equal(st[far], c8[far] == 2)
    # the exact low-frequency limit equals R(0)/D(0)^2 of the Padé form
    n, d, r = _core.stability_polys("proposed", _params(m), 0.3, 4.0, 0.2, 2)
    _, mg = S.exact_delay_string(m, 0.3, 4.0, 0.2, w_min=1e-6, w_max=1e-5, n_w=3)
    assert mg[0] == pytest.approx(min(r[0] / d[0] ** 2, mg[0]), rel=1e-9)


def test_pade_report_on_paper_models() -> None:
    kg = np.geomspace(0.01, 2, 24)
    tg = np.linspace(0, 15, 31)
    rep = S.pade_report(P["proposed"], kg, tg, [0.0, 0.4])
    assert rep.pade.shape == rep.exact.shape == (24, 31, 2)
    assert 0 <= rep.fraction < 0.1
    assert "Padé-2 differs" in rep.summary()
    # first-order lag has no delay: Padé changes nothing
    rep1 = S.pade_report(P["first"], kg, tg, [0.0, 0.4])
    assert rep1.fraction == 0.0


def _amplitudes(model: avll.LowerLevelModel, kg: float, tg: float, kv: float, w: float,
                followers: int = 25) -> np.ndarray:
    """Speed-oscillation amplitude at frequency w of the leader and each follower
    (lock-in over the last 20 periods, after >= 300 s and 20 periods of transient)."""
    dt = 0.05
    period = 2 * math.pi / w
    t_end = max(300.0, 20 * period) + 20 * period
    t = np.arange(0, t_end, dt)
    v0, amp = 20.0, 0.5
    lead_v = v0 + amp * np.sin(w * t)
    lead_x = v0 * t + amp / w * (1 - np.cos(w * t))
    tr = avll.platoon(model, lead_x, lead_v, dt, avll.UpperLevel(kg=kg, kv=kv, Tg=tg),
                      followers)
    tail = t >= t_end - 20 * period
    ph = np.exp(-1j * w * t[tail])
    v = tr.v[:, tail]
    a = 2 * np.abs(((v - v.mean(axis=1, keepdims=True)) * ph).mean(axis=1))
    return np.concatenate([[amp], a])


def _h_abs2(model: avll.LowerLevelModel, kg: float, tg: float, kv: float,
            w: np.ndarray) -> np.ndarray:
    """|H(jω)|² with the true delay, in plain numpy complex arithmetic (Eq. 8)."""
    c = model.linear()
    s = 1j * w
    g = (c["b1"] * s + c["b0"]) * np.exp(-s * c["Td"]) / (c["a2"] * s * s + c["a1"] * s + 1)
    gfb = g / (1 - c["K"] * g)
    h = gfb * (kv * s + kg) / (s * s + gfb * ((kv + tg * kg) * s + kg))
    return np.abs(h) ** 2


def _peak_w(model: avll.LowerLevelModel, kg: float, tg: float, kv: float) -> float:
    """Frequency of the largest |H(jω)| on [0.05, 3] rad/s (true delay)."""
    w = np.geomspace(0.05, 3, 2000)
    return float(w[np.argmax(_h_abs2(model, kg, tg, kv, w))])


@pytest.mark.parametrize("name", ["second", "proposed"])
def test_time_domain_platoon_agrees_with_map(name: str) -> None:
    m = P[name]
    kg_axis = np.geomspace(0.02, 1, 40)
    tg_axis = np.linspace(0.5, 12, 47)
    mp = S.stability_map(m, kg_axis, tg_axis, [0.2])[:, :, 0]
    # a point deep inside each region: code unchanged over its 5x5 neighbourhood
    for code in (1, 2):
        inside = [
            (kg_axis[i], tg_axis[j])
            for i in range(2, kg_axis.size - 2)
            for j in range(2, tg_axis.size - 2)
            if (mp[i - 2 : i + 3, j - 2 : j + 3] == code).all()
        ]
        assert inside, code
        kg, tg = inside[len(inside) // 2]
        assert S.exact_delay_codes(m, kg, tg, 0.2)[0][0] == code
        w = _peak_w(m, kg, tg, 0.2)
        a = _amplitudes(m, kg, tg, 0.2, w)
        assert np.all(np.isfinite(a))
        if code == 2:
            assert np.all(np.diff(a) < 0), (kg, tg, w, a)  # decays vehicle after vehicle
        else:
            assert np.all(np.diff(a) > 0), (kg, tg, w, a)  # grows along the platoon
    # a locally unstable point: the first follower already diverges
    bad = [(kg_axis[i], tg_axis[j]) for i in range(40) for j in range(47) if mp[i, j] == 0]
    kg, tg = bad[len(bad) // 2]
    a = _amplitudes(m, kg, tg, 0.2, 0.3, followers=2)
    assert not np.isfinite(a[1]) or a[1] > 1e3


def test_cli_stability_map(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from avll.cli import main

    out = tmp_path / "map.png"
    js = tmp_path / "th.json"
    rc = main(["stability-map", "--models", "second", "--models", "proposed",
               "--kg", "0.001", "2", "60", "--tg", "0", "15", "76", "--kv", "0", "1", "11",
               "--out", str(out), "--json", str(js), "--quiet"])
    assert rc == 0 and out.stat().st_size > 1000
    import json

    doc = json.loads(js.read_text())
    kg, tg, kv = np.geomspace(0.001, 2, 60), np.linspace(0, 15, 76), np.linspace(0, 1, 11)
    for name in ("second", "proposed"):
        th = S.thresholds(S.stability_map(P[name], kg, tg, kv), kg, tg, kv)
        assert doc["models"][name]["tg_min_overall"] == pytest.approx(th.tg_min_overall)
        assert doc["models"][name]["kv_last_stable"] == pytest.approx(th.kv_last_stable)
    text = capsys.readouterr().out
    assert "kv last stable" in text and "proposed" in text
    assert main(["stability-map", "--kg", "0", "1", "5", "--quiet"]) == 2


def test_progress_bar_option(capsys) -> None:  # type: ignore[no-untyped-def]
    m = P["first"]
    kg, tg, kv = np.linspace(0.01, 1, 30), np.linspace(0, 5, 20), np.array([0.1, 0.2])
    a = S.stability_map(m, kg, tg, kv, progress=True)
    assert np.array_equal(a, S.stability_map(m, kg, tg, kv))
    assert "stability first" in capsys.readouterr().err
