"""numpy's ``out=`` convention on every rollout and batched call, and the recycled
output blocks of the default path.

With ``out=`` the results are bit-identical to the allocating path (the arrays are
pre-filled with a sentinel, so an element left unwritten shows), the result refers
to the caller's arrays, and a bad ``out`` (dtype, shape, layout, read-only, shared
memory, count) is a ``ValueError`` naming the argument. The default path hands out
arrays whose memory avll recycles: one kept alive is never written by a later call.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

import avll
from avll import _core
from avll.rollout import output_cache

DT = 0.05
MODEL = avll.PAPER_TABLE_II["proposed"]
UP = avll.UpperLevel(kg=0.5, kv=0.1, Tg=1.8, Gmin=9.5)
#: Destabilising upper-level gains: the follower diverges (NaN after it).
WILD = avll.UpperLevel(3.0, 3.0, 0.0, 9.5)
SENTINEL = 12345.0


def leader(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    acc = np.convolve(rng.normal(scale=0.6, size=n), np.ones(20) / 20, mode="same")[:n]
    lv = np.maximum(12.0 + np.cumsum(acc) * DT, 0.0)
    lx = 40.0 + np.concatenate([[0.0], np.cumsum((lv[1:] + lv[:-1]) / 2) * DT])
    return lx, lv


def command(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.convolve(rng.normal(size=n), np.ones(10) / 10, mode="same")[:n]


def same_bits(a: np.ndarray, b: np.ndarray) -> None:
    """Equal bit for bit (NaN patterns included)."""
    assert a.shape == b.shape
    assert np.array_equal(np.ascontiguousarray(a).view(np.int64),
                          np.ascontiguousarray(b).view(np.int64))


def filled(shape: tuple[int, ...]) -> np.ndarray:
    return np.full(shape, SENTINEL)


def four(shape: tuple[int, ...]) -> list[np.ndarray]:
    return [filled(shape) for _ in range(4)]


# Sizes on both sides of the recycled-block threshold (128 KiB = 16,384 doubles).
SIZES = [1, 500, 40_000]


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("init", ["rest", "steady"])
def test_simulate_out_is_bit_identical_and_returned(n: int, init: str) -> None:
    u = command(n)
    want = avll.simulate(MODEL, u, DT, init=init)
    out = filled((n,))
    got = avll.simulate(MODEL, u, DT, init=init, out=out)
    assert got is out
    same_bits(out, want)


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("kind", ["acceleration", "speed"])
def test_simulate_full_out(n: int, kind: str) -> None:
    u = command(n) + (8.0 if kind == "speed" else 0.0)
    want = avll.simulate_full(MODEL, u, DT, command_kind=kind, v0=2.0, x0=1.0)
    outs = four((n,))
    got = avll.simulate_full(MODEL, u, DT, command_kind=kind, v0=2.0, x0=1.0, out=outs)
    for k, f in enumerate(("a", "v", "x", "command")):
        assert getattr(got, f) is outs[k]
        same_bits(outs[k], getattr(want, f))


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("upper", [UP, WILD], ids=["stable", "diverging"])
def test_closed_loop_out(n: int, upper: avll.UpperLevel) -> None:
    lx, lv = leader(max(n, 1))
    want = avll.closed_loop(MODEL, lx, lv, DT, upper, v0=12.0, x0=0.0)
    if upper is WILD and n > 1000:
        assert np.isnan(want.a[-1])  # the case really diverges
    tr = avll.Trajectory(*four((lx.size,)))
    got = avll.closed_loop(MODEL, lx, lv, DT, upper, v0=12.0, x0=0.0, out=tr)
    assert got is tr  # a Trajectory passed as out is returned itself
    for f in ("a", "v", "x", "command"):
        same_bits(getattr(tr, f), getattr(want, f))


@pytest.mark.parametrize("n,followers", [(1, 1), (300, 3), (6_000, 20)])
def test_platoon_out(n: int, followers: int) -> None:
    lx, lv = leader(n, seed=3)
    want = avll.platoon(MODEL, lx, lv, DT, UP, followers)
    outs = [np.full((n, followers), SENTINEL).T for _ in range(4)]
    got = avll.platoon(MODEL, lx, lv, DT, UP, followers, out=outs)
    for k, f in enumerate(("a", "v", "x", "command")):
        assert getattr(got, f) is outs[k]
        same_bits(outs[k], getattr(want, f))
    # a platoon's own result is a valid out (the loop a user writes)
    again = avll.platoon(MODEL, lx, lv, DT, UP, followers, out=want)
    assert again is want
    for f in ("a", "v", "x", "command"):
        same_bits(getattr(again, f), getattr(got, f))


def test_platoon_out_diverging() -> None:
    m = avll.PAPER_TABLE_II["second"]
    lx, lv = leader(3000, seed=2)
    want = avll.platoon(m, lx, lv, DT, WILD, 3)
    assert np.isnan(want.a[2, -1])
    outs = [np.full((3000, 3), SENTINEL).T for _ in range(4)]
    avll.platoon(m, lx, lv, DT, WILD, 3, out=outs)
    for k, f in enumerate(("a", "v", "x", "command")):
        same_bits(outs[k], getattr(want, f))


def _runs(n_runs: int = 3, n: int = 400, closed: bool = False) -> list[avll.Run]:
    out = []
    for r in range(n_runs):
        t = np.arange(n) * DT
        lx, lv = leader(n, seed=10 + r)
        if closed:
            tr = avll.closed_loop(MODEL, lx, lv, DT, UP, v0=float(lv[0]), x0=float(lx[0] - 30))
            out.append(avll.Run(f"r{r}", t, a=tr.a, v=tr.v, x=tr.x, lead_x=lx, lead_v=lv,
                                command=tr.command, upper=UP))
        else:
            u = command(n, seed=20 + r)
            tr = avll.simulate_full(MODEL, u, DT)
            out.append(avll.Run(f"r{r}", t, a=tr.a + 0.01, v=tr.v, x=tr.x, command=u))
    return out


def _rows(p: int = 7) -> np.ndarray:
    rng = np.random.default_rng(5)
    rows = MODEL.to_array() * rng.uniform(0.7, 1.3, size=(p, 6))
    rows[0, 1] = -1.0  # invalid: inf cost, NaN trajectories
    return rows


@pytest.mark.parametrize("closed", [False, True])
def test_batch_cost_out(closed: bool) -> None:
    runs, rows = _runs(closed=closed), _rows()
    want = avll.batch_cost("proposed", rows, runs, closed_loop=closed, threads=1)
    out = filled(want.shape)
    got = avll.batch_cost("proposed", rows, runs, closed_loop=closed, threads=1, out=out)
    assert got is out
    same_bits(out, want)
    assert np.isinf(out[0]).all()


@pytest.mark.parametrize("closed", [False, True])
def test_simulate_batch_out(closed: bool) -> None:
    runs, rows = _runs(closed=closed), _rows()
    want = avll.rollout.simulate_batch("proposed", rows, runs, closed_loop=closed, threads=1)
    total = sum(len(r) for r in runs)
    out = filled((3, rows.shape[0], total))
    got = avll.rollout.simulate_batch("proposed", rows, runs, closed_loop=closed, threads=1,
                                      out=out)
    for k, f in enumerate(("a", "v", "x")):
        for j in range(len(runs)):
            same_bits(getattr(got, f)[j], getattr(want, f)[j])
            assert np.shares_memory(getattr(got, f)[j], out[k])
        same_bits(np.concatenate(getattr(want, f), axis=1), out[k])
    assert np.isnan(out[:, 0]).all()


# ------------------------------------------------------------------ bad `out`

def _bad_cases() -> list[tuple[str, Callable[[], Any], str]]:
    n = 50
    u = command(n)
    lx, lv = leader(n)

    def sim(out: Any) -> Callable[[], Any]:
        return lambda: avll.simulate(MODEL, u, DT, out=out)

    def cl(out: Any) -> Callable[[], Any]:
        return lambda: avll.closed_loop(MODEL, lx, lv, DT, UP, v0=12.0, x0=0.0, out=out)

    def pl(out: Any) -> Callable[[], Any]:
        return lambda: avll.platoon(MODEL, lx, lv, DT, UP, 2, out=out)

    ro = np.zeros(n)
    ro.flags.writeable = False
    shared = np.zeros(n)
    good = [np.zeros(n) for _ in range(3)]
    pgood = [np.zeros((n, 2)).T for _ in range(3)]
    return [
        ("float32", sim(np.zeros(n, dtype=np.float32)), "out: .*dtype float32"),
        ("shape", sim(np.zeros(n + 1)), r"out: .*shape \(51,\)"),
        ("2-D", sim(np.zeros((n, 1))), r"out: .*shape \(50, 1\)"),
        ("strided", sim(np.zeros(2 * n)[::2]), "out: .*non-contiguous"),
        ("read-only", sim(ro), "out: .*read-only"),
        ("list", sim([0.0] * n), "out: .*got list"),
        ("input", lambda: avll.simulate(MODEL, u, DT, out=u),
         "out: shares memory with another output or an input"),
        ("three", cl(good), "out: must be an avll.Trajectory or a sequence of four"),
        ("twice", cl([shared, shared, np.zeros(n), np.zeros(n)]),
         r"out\[1\] \(v\): shares memory"),
        ("leader", cl([np.zeros(n), np.zeros(n), lx, np.zeros(n)]),
         r"out\[2\] \(x\): shares memory"),
        ("cl dtype", cl([np.zeros(n), np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n)]),
         r"out\[1\] \(v\): .*dtype int64"),
        ("platoon C order", pl([np.zeros((2, n)) for _ in range(4)]),
         r"out\[0\] \(a\): .*Fortran-ordered.*non-contiguous"),
        ("platoon shape", pl([*pgood, np.zeros((n, 3)).T]), r"out\[3\] \(command\): .*shape"),
        ("batch shape", lambda: avll.batch_cost("proposed", _rows(), _runs(), out=np.zeros((7, 2))),
         r"out: .*shape \(7, 3\)"),
        ("sim batch shape",
         lambda: avll.rollout.simulate_batch("proposed", _rows(), _runs(), out=np.zeros((7, 1200))),
         r"out: .*shape \(3, 7, 1200\)"),
    ]


@pytest.mark.parametrize("case", _bad_cases(), ids=lambda c: c[0])
def test_bad_out_is_a_value_error_naming_it(case: tuple[str, Callable[[], Any], str]) -> None:
    _, call, match = case
    with pytest.raises(ValueError, match=match):
        call()


def test_core_checks_out_itself() -> None:
    """The bindings check ``out`` too (the Python layer is not the only guard): a
    ValueError naming it, never a panic or a silent write."""
    p = MODEL.values()
    u = command(40)
    for bad, match in [
        (np.zeros(41), r"out: must be a float64 numpy array of shape \(40,\)"),
        (np.zeros(40, dtype=np.float32), "out: must be .* got dtype float32"),
        (np.zeros(80)[::2], "out: .*non-contiguous"),
        ("no", "out: must be .* got str"),
    ]:
        with pytest.raises(ValueError, match=match):
            _core.simulate(MODEL.name, p, u, DT, "rest", bad)
    ro = np.zeros(40)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="out: must be writeable, got a read-only array"):
        _core.simulate(MODEL.name, p, u, DT, "rest", ro)
    with pytest.raises(ValueError, match="out: shares memory"):
        _core.simulate(MODEL.name, p, u, DT, "rest", u)
    lx, lv = leader(40)
    a = np.zeros(40)
    with pytest.raises(ValueError, match=r"out\[1\] \(v\): shares memory"):
        _core.closed_loop(MODEL.name, p, lx, lv, DT, 0.5, 0.0, 1.8, 9.5, 12.0, 0.0,
                          out=[a, a, np.zeros(40), np.zeros(40)])
    with pytest.raises(ValueError, match="out: must be an avll.Trajectory or a sequence of 4 "
                                         "arrays, got 3"):
        _core.closed_loop(MODEL.name, p, lx, lv, DT, 0.5, 0.0, 1.8, 9.5, 12.0, 0.0,
                          out=[np.zeros(40)] * 3)


# ------------------------------------------------------- recycled output blocks

def test_recycled_blocks_never_alias_a_live_array() -> None:
    """A trajectory's arrays above the threshold come from recycled blocks: an array
    kept alive keeps its values whatever later calls write, and a freed one is
    reused."""
    n = 50_000
    lx, lv = leader(n)
    first = avll.closed_loop(MODEL, lx, lv, DT, UP, v0=12.0, x0=0.0)
    keep = [a.copy() for a in (first.a, first.v, first.x, first.command)]
    assert all(isinstance(a.base, _core.OutputBlock)
               for a in (first.a, first.v, first.x, first.command))
    arrays = [first.a, first.v, first.x, first.command]
    for i, a in enumerate(arrays):
        for b in arrays[i + 1:]:
            assert not np.shares_memory(a, b)
    for k in range(3):
        second = avll.closed_loop(MODEL, lx, lv, DT, UP, v0=11.0 + k, x0=0.0)
        for a in arrays:
            for b in (second.a, second.v, second.x, second.command):
                assert not np.shares_memory(a, b)
        del second
    for a, b in zip(arrays, keep, strict=True):
        same_bits(a, b)
    # a view outliving its trajectory keeps the block alive
    view = avll.closed_loop(MODEL, lx, lv, DT, UP, v0=12.0, x0=0.0).v[10:20]
    avll.closed_loop(MODEL, lx, lv, DT, UP, v0=3.0, x0=0.0)
    same_bits(view, keep[1][10:20])


def test_recycled_results_equal_fresh_ones() -> None:
    """The values do not depend on where the memory came from: the cache disabled
    (fresh blocks) and enabled (recycled) give the same bits."""
    n = 60_000
    lx, lv = leader(n, seed=4)
    held, limit = output_cache()
    try:
        assert output_cache(0) == (0, 0)
        fresh = avll.platoon(MODEL, lx, lv, DT, UP, 4)
        fresh_cl = avll.closed_loop(MODEL, lx, lv, DT, UP, v0=12.0, x0=0.0)
        output_cache(limit)
        for _ in range(2):
            again = avll.platoon(MODEL, lx, lv, DT, UP, 4)
            again_cl = avll.closed_loop(MODEL, lx, lv, DT, UP, v0=12.0, x0=0.0)
            for f in ("a", "v", "x", "command"):
                same_bits(getattr(again, f), getattr(fresh, f))
                same_bits(getattr(again_cl, f), getattr(fresh_cl, f))
            del again, again_cl
        assert output_cache()[0] > 0  # freed blocks went back to the cache
    finally:
        output_cache(limit)


def test_output_cache_bound() -> None:
    _, limit = output_cache()
    try:
        lx, lv = leader(50_000)
        avll.closed_loop(MODEL, lx, lv, DT, UP, v0=12.0, x0=0.0)  # freed at once: cached
        held, _ = output_cache()
        assert 4 * 50_000 * 8 <= held <= limit
        assert output_cache(0) == (0, 0)
        avll.closed_loop(MODEL, lx, lv, DT, UP, v0=12.0, x0=0.0)
        assert output_cache()[0] == 0  # nothing kept with limit 0
        with pytest.raises(ValueError, match="limit"):
            output_cache(-1)
    finally:
        output_cache(limit)
