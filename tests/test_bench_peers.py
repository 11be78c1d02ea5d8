"""The numba peers of ``benches/peers.py`` compute avll's numbers (to 1e-9 of the
signal scale), so that ``benches/bench_engine.py`` compares equal work."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("numba", reason="the benchmark peers need numba (pip install avll[bench])")

BENCHES = Path(__file__).resolve().parents[1] / "benches"
sys.path.insert(0, str(BENCHES))

import peers  # noqa: E402

import avll  # noqa: E402
from avll.reference import rollout as ref  # noqa: E402

DT = 0.05
PROPOSED = avll.PAPER_TABLE_II["proposed"]
# Dead times: Table II's (i = 15, fractional), none (i = 0), below one sample, and a
# whole number of samples (f = 0); plus the Table II second-order model.
MODELS = [
    PROPOSED,
    avll.Proposed(m1=6.7893, m2=1.2824, m3=8.8157, K0=0.3479, Td=0.0, K=0.1008),
    avll.Proposed(m1=6.7893, m2=1.2824, m3=8.8157, K0=0.3479, Td=0.03, K=0.1008),
    avll.Proposed(m1=0.5, m2=0.6, m3=2.0, K0=0.9, Td=0.25, K=-0.3),
    avll.PAPER_TABLE_II["second"],
]


def _has_real_poles(model: avll.LowerLevelModel) -> bool:
    c = model.linear()
    return c["a1"] ** 2 - 4 * c["a2"] > 1e-6


def _command(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.convolve(rng.normal(size=n), np.ones(8) / 8, mode="same")


def _leader(n: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * DT
    lv = 12.0 + 3.0 * np.sin(t / 9.0) + 1.0 * np.sin(t / 2.3)
    lx = 50.0 + np.concatenate([[0.0], np.cumsum((lv[1:] + lv[:-1]) / 2) * DT])
    return lx, lv


def _prepare(peer: peers.Peer, model: avll.LowerLevelModel) -> object:
    if peer.variant in ("best", "block") and not _has_real_poles(model):
        with pytest.raises(ValueError, match="complex"):
            peer.prepare(model, DT)
        pytest.skip("the modal peer needs real poles (it refuses complex ones, checked)")
    return peer.prepare(model, DT)


def test_discrete_matrices_are_the_reference_hold_maps() -> None:
    d = peers.discretize(PROPOSED, DT, integrators=True)
    i, f = ref.split_delay(PROPOSED.Td, DT)
    assert (d.i, d.f) == (i, f) and i == 15 and 0.8 < f < 0.81
    # the two hold pieces make up one full interval of the rational part
    d0 = peers.discretize(avll.Proposed(**{**PROPOSED.to_dict(), "Td": 0.0}), DT)
    np.testing.assert_allclose(d.g0[:2] + d.g1[:2], d0.g0, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize(
    "row",
    [
        PROPOSED.to_array(),
        [0.5, 0.6, 2.0, 0.9, 0.25, -0.3],
        [0.3, 1.3, 0.4, 0.8, 0.0, 0.2],  # complex poles, no dead time
        [6.0, 40.0, 0.01, 2.0, 2.9, 0.0],  # long dead time, lightly damped
    ],
)
def test_numba_discretization_matches_scipy(row: list[float]) -> None:
    ok, phi, g0, g1, c, k, i = peers._discretize_proposed(np.asarray(row, dtype=float), DT)
    want = peers.discretize(avll.Proposed(*row), DT)
    assert ok and i == want.i and k == want.k
    for got, w in ((phi, want.phi), (g0, want.g0), (g1, want.g1), (c, want.c)):
        np.testing.assert_allclose(got, w, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{m.name}-Td{m.Td}")
@pytest.mark.parametrize("peer", peers.OPEN_PEERS, ids=lambda p: p.variant)
def test_open_loop_peers_equal_avll(peer: peers.Peer, model: avll.LowerLevelModel) -> None:
    prep = _prepare(peer, model)
    u = _command(700)
    want = avll.simulate(model, u, DT)
    assert np.max(np.abs(want)) > 0.05  # a response worth comparing
    assert peers.check_close("open", peer.run(prep, u), want) <= 1e-9


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{m.name}-Td{m.Td}")
@pytest.mark.parametrize("peer", peers.CLOSED_PEERS, ids=lambda p: p.variant)
@pytest.mark.parametrize("kg", [0.5, 6.0], ids=["stable", "diverges"])
def test_closed_loop_peers_equal_avll(
    peer: peers.Peer, model: avll.LowerLevelModel, kg: float
) -> None:
    prep = _prepare(peer, model)
    lx, lv = _leader(3000)
    up = avll.UpperLevel(kg=kg, kv=0.1, Tg=1.8, Gmin=9.5)
    v0, x0 = float(lv[0]), float(lx[0]) - 30.0
    tr = avll.closed_loop(model, lx, lv, DT, up, v0=v0, x0=x0)
    got = peer.run(prep, up, lx, lv, v0, x0)
    for g, w, name in zip(got, (tr.a, tr.v, tr.x, tr.command), "avxu", strict=True):
        assert peers.check_close(name, g, w) <= 1e-9
    if kg == 6.0 and model is PROPOSED:
        assert np.isnan(tr.a[-1]) and np.isfinite(tr.a[0])  # the NaN tail is compared


@pytest.mark.parametrize("peer", peers.PLATOON_PEERS, ids=lambda p: p.variant)
@pytest.mark.parametrize(
    "up",
    [
        avll.UpperLevel(kg=0.2, kv=0.2, Tg=3.0, Gmin=9.5),
        avll.UpperLevel(kg=0.5, kv=0.0, Tg=1.8, Gmin=9.5),  # string-unstable: diverges
    ],
    ids=["string-stable", "diverges"],
)
def test_platoon_peers_equal_avll(peer: peers.Peer, up: avll.UpperLevel) -> None:
    prep = _prepare(peer, PROPOSED)
    lx, lv = _leader(2500)
    tr = avll.platoon(PROPOSED, lx, lv, DT, up, 20)
    got = peer.run(prep, up, lx, lv, 20)
    for g, w, name in zip(got, (tr.a, tr.v, tr.x, tr.command), "avxu", strict=True):
        assert peers.check_close(name, g, w) <= 1e-9
    if up.Tg == 1.8:
        assert np.isnan(tr.a[-1]).all() and np.isfinite(tr.a[0]).all()


@pytest.mark.parametrize("peer", peers.OPEN_INTO_PEERS, ids=lambda p: p.variant)
def test_open_loop_into_peers_equal_avll(peer: peers.Peer) -> None:
    prep = _prepare(peer, PROPOSED)
    u = _command(700)
    out = np.full(700, 7.0)
    assert peer.run(prep, u, out) is out
    assert peers.check_close("open", out, avll.simulate(PROPOSED, u, DT)) <= 1e-9


@pytest.mark.parametrize("peer", peers.CLOSED_INTO_PEERS, ids=lambda p: p.variant)
@pytest.mark.parametrize("kg", [0.5, 6.0], ids=["stable", "diverges"])
def test_closed_loop_into_peers_equal_avll(peer: peers.Peer, kg: float) -> None:
    prep = _prepare(peer, PROPOSED)
    lx, lv = _leader(3000)
    up = avll.UpperLevel(kg=kg, kv=0.1, Tg=1.8, Gmin=9.5)
    v0, x0 = float(lv[0]), float(lx[0]) - 30.0
    tr = avll.closed_loop(PROPOSED, lx, lv, DT, up, v0=v0, x0=x0)
    out = tuple(np.full(3000, 7.0) for _ in range(4))
    peer.run(prep, up, lx, lv, v0, x0, out)
    for g, w, name in zip(out, (tr.a, tr.v, tr.x, tr.command), "avxu", strict=True):
        assert peers.check_close(name, g, w) <= 1e-9


@pytest.mark.parametrize("peer", peers.PLATOON_INTO_PEERS, ids=lambda p: p.variant)
@pytest.mark.parametrize("kg", [0.2, 0.5], ids=["string-stable", "diverges"])
def test_platoon_into_peers_equal_avll(peer: peers.Peer, kg: float) -> None:
    prep = _prepare(peer, PROPOSED)
    lx, lv = _leader(2500)
    up = avll.UpperLevel(kg=kg, kv=0.2 if kg == 0.2 else 0.0, Tg=3.0 if kg == 0.2 else 1.8,
                         Gmin=9.5)
    tr = avll.platoon(PROPOSED, lx, lv, DT, up, 20)
    out = tuple(np.full((2500, 20), 7.0).T for _ in range(4))
    peer.run(prep, up, lx, lv, 20, out)
    for g, w, name in zip(out, (tr.a, tr.v, tr.x, tr.command), "avxu", strict=True):
        assert peers.check_close(name, g, w) <= 1e-9


def _cost_rows() -> np.ndarray:
    rng = np.random.default_rng(3)
    base = PROPOSED.to_array()
    rows = list(base * rng.uniform(0.5, 1.5, size=(40, base.size)))
    rows += [
        [6.8, -1.0, 8.8, 0.35, 0.79, 0.1],  # m2 < 0: invalid
        [6.8, 1.28, 8.8, 0.35, -0.1, 0.1],  # Td < 0: invalid
        [6.8, 1.28, math.nan, 0.35, 0.79, 0.1],  # not finite
        [6.8, 1.28, 8.8, 0.35, 0.79, 3.0],  # K K0 > 1
        [6.8, 1.28, 8.8, 0.35, 0.79, -40.0],  # delayed feedback oscillates
        [1.0, 1.28, -0.5, 0.35, 0.3, 0.0],  # negative damping
        [0.5, 1.28, 1.0, 0.9, 0.4, 0.1],  # complex poles (the expm path)
        [0.5, 1.28, 0.3, 0.9, 0.2, 0.5],  # complex poles
        [6.8, 1.28, 8.8, 0.35, 0.0, 0.1],  # no dead time
        [6.8, 1.28, 8.8, 0.35, 0.1, 0.1],  # dead time 2 samples exactly
        [0.0, 1.28, 8.8, 2.0e7, 0.5, 0.0],  # stable, |y| >= 1e6: inf
    ]
    return np.ascontiguousarray(rows, dtype=float)


def _huge_gain(runs: list[avll.Run]) -> list[float]:
    """A stable set whose response peaks at 6e5 (below the divergence bound) on the
    runs: an error sum beyond the bound of the modal peer's shortcut, no divergence."""
    unit = avll.Proposed(m1=0.0, m2=1.28, m3=8.8, K0=1.0, Td=0.5, K=0.0)
    peak = max(np.max(np.abs(avll.simulate(unit, r.command, DT))) for r in runs)
    return [0.0, 1.28, 8.8, 6e5 / peak, 0.5, 0.0]


@pytest.fixture(scope="module")
def cost_runs() -> list[avll.Run]:
    return avll.synth.paper_experiment(seed=1, runs=(3, 9, 19), duration=40.0)


@pytest.mark.parametrize("peer", peers.COST_PEERS, ids=lambda p: p.variant)
def test_batched_cost_peers_equal_avll(peer: peers.Peer, cost_runs: list[avll.Run]) -> None:
    rows = np.vstack([_cost_rows(), _huge_gain(cost_runs)])
    want = avll.batch_cost("proposed", rows, cost_runs)
    assert np.isinf(want[40:50]).all(axis=1).sum() == 6  # the inf cases are exercised
    assert np.isinf(want[-2]).all()
    sums = want[-1] * np.array([len(r) for r in cost_runs])
    assert np.all(np.isfinite(sums)) and np.all(sums > 1e12)
    packed = peer.prepare(cost_runs)
    peers.set_threads(1)
    got1 = peer.run(rows, packed)
    peers.set_threads(2)
    got2 = peer.run(rows, packed)
    assert peers.check_close("cost", got1, want) <= 1e-9
    np.testing.assert_array_equal(got1, got2)  # thread count does not matter


def test_check_close_fails_on_a_difference() -> None:
    want = np.array([1.0, 2.0, np.nan])
    with pytest.raises(AssertionError, match="relative difference"):
        peers.check_close("x", np.array([1.0, 2.0 + 1e-6, np.nan]), want)
    with pytest.raises(AssertionError, match="non-finite"):
        peers.check_close("x", np.array([1.0, 2.0, 3.0]), want)


def test_bench_engine_runs_and_writes_strict_json(tmp_path: Path) -> None:
    import bench_engine

    out = tmp_path / "engine.json"
    argv = [
        "--only", "open,cost", "--open-samples", "3000", "--cost-params", "60",
        "--cost-runs-params", "12", "--repeat", "1", "--json", str(out),
        # the allocator left alone (the default; `keep` would raise this test
        # process's thresholds)
        "--allocator", "default",
    ]  # fmt: skip
    assert bench_engine.main(argv) == 0
    doc = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"non-strict {c}"))
    keys = [w["key"] for w in doc["workloads"]]
    assert keys == [
        "open_3000", "open_3000_out", "cost_1run_1t", "cost_1run_2t", "cost_10runs_1t",
        "cost_10runs_2t",
    ]  # fmt: skip
    n_peers = {"open": len(peers.OPEN_PEERS), "open_out": len(peers.OPEN_INTO_PEERS),
               "cost": len(peers.COST_PEERS)}
    for w in doc["workloads"]:
        kind = "open_out" if w["key"].endswith("_out") else w["key"].split("_")[0]
        assert w["avll"]["rate"] > 0 and len(w["peers"]) == n_peers[kind]
        assert all(p["max_rel_diff"] <= 1e-9 for p in w["peers"])
        assert w["ratio"] == pytest.approx(w["avll"]["rate"] / max(p["rate"] for p in w["peers"]))
        lo, hi = w["ratio_range"]
        assert lo <= w["ratio_median"] <= hi and w["paired_rounds"] >= 1
        if w["target"] is not None:
            assert w["met"] == (w["ratio_median"] >= w["target"])
        assert all(r["faults_per_call"] >= 0 for r in [w["avll"], *w["peers"]])
    assert [s["threads"] for s in doc["scaling"]] == [[1, 2], [1, 2]]
    assert doc["meta"]["allocator"] == "allocator left as it is"


def test_bench_calibrate_unit_box_and_recorder() -> None:
    import bench_calibrate as bc

    z = np.random.default_rng(0).random((5, len(bc.NAMES)))
    np.testing.assert_allclose(bc.to_unit(bc.to_user(z[0])), z[0], rtol=0, atol=1e-12)
    assert np.all(bc.to_user(z) >= bc.LO) and np.all(bc.to_user(z) <= bc.HI)
    assert bc.speedup(2.0, 0.5) == 4.0 and bc.speedup(1.0, math.inf) == 0.0
    assert math.isnan(bc.speedup(math.inf, math.inf))
    rec = bc.Recorder(lambda x: x.sum(axis=1), stop_at=1.0, budget=60.0)
    rec(np.array([[3.0, 1.0], [2.0, 2.0]]))
    rec(np.array([[0.5, 0.25]]))
    assert rec.trace.evals == 3 and rec.trace.best == 0.75 and rec.done()
    assert [p[2:] for p in rec.trace.points] == [(2, 4.0), (3, 0.75)]
    assert rec.trace.first(1.0) is not None and rec.trace.first(0.5) is None
