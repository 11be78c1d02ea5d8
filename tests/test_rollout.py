"""The Rust rollouts against the plain numpy reference, plus properties and errors.

Cross-checks: relative error <= 1e-9 (max norm) on random parameters and inputs,
fractional delays and inner feedback K included, both command kinds, both initial
conditions, closed loop, platoon and the batched cost.
"""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import avll
from avll import _core
from avll.defaults import CLOSED_LOOP_WEIGHTS
from avll.reference import rollout as ref
from avll.reference import stability as ref_stability

TOL = 1e-9
DT = 0.05


def relerr(got: np.ndarray, want: np.ndarray, floor: float = 1e-300) -> float:
    """Max-norm relative error; ``floor`` bounds the scale from below for signals that
    are zero up to rounding (e.g. the derivative of a steady response)."""
    got, want = np.asarray(got), np.asarray(want)
    assert got.shape == want.shape
    scale = max(float(np.max(np.abs(want))), floor)
    return float(np.max(np.abs(got - want))) / scale


def random_model(rng: np.random.Generator, name: str) -> avll.LowerLevelModel:
    """Random, asymptotically stable parameters; dead times mostly fractional."""
    Td = float(rng.choice([0.0, rng.uniform(0, 1.5), DT * rng.integers(1, 20)]))
    if name == "first":
        return avll.FirstOrderLag(float(rng.uniform(0.05, 3.0)))
    m2, m3, K0 = rng.uniform(0.02, 3.0), rng.uniform(0.1, 9.0), rng.uniform(0.1, 2.0)
    if name == "second":
        return avll.SecondOrder(K0=K0, m2=m2, m3=m3, Td=Td)
    m1 = rng.uniform(0.0, 8.0)
    K = rng.uniform(-1.0, 0.9 / K0)  # K K0 < 1: a steady state exists
    return avll.Proposed(m1=m1, m2=m2, m3=m3, K0=K0, Td=Td, K=K)


def bounded(tr: dict[str, np.ndarray]) -> bool:
    return all(bool(np.all(np.abs(v) < 1e6)) for v in tr.values())


def leader(rng: np.random.Generator, n: int, v0: float = 12.0) -> tuple[np.ndarray, np.ndarray]:
    acc = np.convolve(rng.normal(scale=0.6, size=n), np.ones(20) / 20, mode="same")
    lv = np.maximum(v0 + np.cumsum(acc) * DT, 0.0)
    lx = 40.0 + np.concatenate([[0.0], np.cumsum((lv[1:] + lv[:-1]) / 2) * DT])
    return lx, lv


# ------------------------------------------------------------ Rust vs reference


@pytest.mark.parametrize("name", ["first", "second", "proposed"])
@pytest.mark.parametrize("kind", ["acceleration", "speed"])
@pytest.mark.parametrize("init", ["rest", "steady"])
def test_open_loop_matches_reference(name: str, kind: str, init: str) -> None:
    rng = np.random.default_rng(zlib.crc32(f"{name}{kind}{init}".encode()))
    checked = 0
    for _ in range(8):
        m = random_model(rng, name)
        u = rng.normal(size=int(rng.integers(2, 250))) + rng.normal()
        want = ref.simulate_full(m, u, DT, command_kind=kind, init=init, v0=3.0, x0=-7.0)
        if not ref.lower_level_stable(m, DT):  # the delayed inner loop may be unstable
            with pytest.raises(ValueError, match="not asymptotically stable"):
                avll.simulate_full(m, u, DT, command_kind=kind, init=init)
            continue
        if not bounded(want):
            continue
        got = avll.simulate_full(m, u, DT, command_kind=kind, init=init, v0=3.0, x0=-7.0)
        floor = 1e-6 * max(1.0, float(np.max(np.abs(u))))
        for key in ("a", "v", "x", "command"):
            assert relerr(getattr(got, key), want[key], floor) <= TOL, (m, key)
        assert relerr(avll.simulate(m, u, DT, init=init), ref.simulate(m, u, DT, init=init)) <= TOL
        checked += 1
    assert checked >= 4


@pytest.mark.parametrize("name", ["first", "second", "proposed"])
def test_closed_loop_matches_reference(name: str) -> None:
    rng = np.random.default_rng({"first": 1, "second": 2, "proposed": 3}[name])
    checked = 0
    for _ in range(5):
        m = random_model(rng, name)
        up = avll.UpperLevel(
            kg=float(rng.uniform(0.1, 0.8)),
            kv=float(rng.uniform(0.0, 0.8)),
            Tg=float(rng.uniform(0.8, 3.0)),
            Gmin=float(rng.uniform(2.0, 10.0)),
        )
        lx, lv = leader(rng, int(rng.integers(2, 300)))
        v0, x0 = float(rng.uniform(5, 15)), float(rng.uniform(-20, 10))
        want = ref.closed_loop(m, lx, lv, DT, up, v0=v0, x0=x0)
        if not ref.lower_level_stable(m, DT):
            with pytest.raises(ValueError, match="not asymptotically stable"):
                avll.closed_loop(m, lx, lv, DT, up, v0=v0, x0=x0)
            continue
        if not bounded(want):
            continue
        got = avll.closed_loop(m, lx, lv, DT, up, v0=v0, x0=x0)
        for key in ("a", "v", "x", "command"):
            assert relerr(getattr(got, key), want[key]) <= TOL, (m, up, key)
        checked += 1
    assert checked >= 3


@pytest.mark.parametrize("model", list(avll.PAPER_TABLE_II.values()), ids=lambda m: m.name)
def test_platoon_matches_reference(model: avll.LowerLevelModel) -> None:
    rng = np.random.default_rng(7)
    lx, lv = leader(rng, 240, v0=15.0)
    up = avll.UpperLevel(kg=0.5, kv=0.2, Tg=2.0, Gmin=9.5)
    want = ref.platoon(model, lx, lv, DT, up, 4)
    got = avll.platoon(model, lx, lv, DT, up, 4)
    for key in ("a", "v", "x", "command"):
        assert getattr(got, key).shape == (4, 240)
        assert relerr(getattr(got, key), want[key]) <= TOL, key
    # starting condition of the convention: leader's speed, equilibrium gaps
    gap = up.Gmin + up.Tg * lv[0]
    assert np.allclose(got.v[:, 0], lv[0])
    assert np.allclose(np.diff(np.concatenate([[lx[0]], got.x[:, 0]])), -gap)
    assert np.all(got.a[:, 0] == 0.0)


#: Laws tried after the drawn one until the closed loop is locally stable (an unstable
#: one costs inf): kg, kv, Tg.
_LAWS = [(kg, kv, tg) for tg in (2.0, 3.0, 4.0) for kv in (0.0, 0.5, 1.0, 2.0)
         for kg in (0.3, 0.1, 0.03, 0.01)]


def _stable_law(m: avll.LowerLevelModel, kg0: float) -> avll.UpperLevel | None:
    """The law ``kg0, kv = 0, Tg = 2`` or the first of :data:`_LAWS` whose closed loop
    with ``m`` is locally stable (the reference's Padé-8 test), else None."""
    for kg, kv, tg in [(kg0, 0.0, 2.0), *_LAWS]:
        if ref_stability.stability_code(m, kg, tg, kv, pade_order=8) != 0:
            return avll.UpperLevel(kg=kg, kv=kv, Tg=tg, Gmin=9.5)
    return None


def make_run(
    rng: np.random.Generator,
    m: avll.LowerLevelModel,
    n: int,
    kind: str = "acceleration",
    closed: bool = False,
    rid: str = "r",
) -> avll.Run:
    """A noisy synthetic run generated by the reference with model ``m``."""
    t = np.arange(n) * DT
    if closed:
        up = _stable_law(m, float(rng.uniform(0.3, 0.7)))
        assert up is not None, f"no locally stable law for {m}"
        lx, lv = leader(rng, n)
        tr = ref.closed_loop(m, lx, lv, DT, up, v0=float(lv[0]), x0=float(lx[0] - 30))
        noise = rng.normal(scale=0.05, size=(3, n))
        return avll.Run(
            rid,
            t,
            a=tr["a"] + noise[0],
            v=tr["v"] + noise[1],
            x=tr["x"] + noise[2],
            lead_x=lx,
            lead_v=lv,
            command=tr["command"],
            upper=up,
        )
    u = np.convolve(rng.normal(size=n), np.ones(10) / 10, mode="same") + (
        8.0 if kind == "speed" else 0.0
    )
    tr = ref.simulate_full(m, u, DT, command_kind=kind, v0=2.0, x0=1.0)
    noise = rng.normal(scale=0.05, size=(3, n))
    return avll.Run(
        rid,
        t,
        a=tr["a"] + noise[0],
        v=tr["v"] + noise[1],
        x=tr["x"] + noise[2],
        command_kind=kind,
        command=u,
    )


@pytest.mark.parametrize("name", ["first", "second", "proposed"])
@pytest.mark.parametrize(
    "kind,weights,closed",
    [
        ("acceleration", (1.0, 0.0, 0.0), False),
        ("acceleration", (1.0, 0.5, 0.01), False),
        # position weighted, speed not: the measured v[0] still starts the speed (every
        # column a run carries is packed), as in the reference
        ("acceleration", (1.0, 0.0, 0.05), False),
        ("speed", (1.0, 0.0, 0.0), False),
        ("speed", (0.3, 1.0, 0.02), False),
        ("acceleration", (1.0, 0.0, 0.0), True),
        ("acceleration", (1.0, 0.2, 0.01), True),
    ],
)
def test_batch_cost_matches_reference(
    name: str, kind: str, weights: tuple[float, float, float], closed: bool
) -> None:
    rng = np.random.default_rng(zlib.crc32(f"{name}{kind}{weights}{closed}".encode()))
    true = random_model(rng, name)
    while not ref.lower_level_stable(true, DT) or (closed and _stable_law(true, 0.5) is None):
        true = random_model(rng, name)
    runs = [
        make_run(rng, true, int(rng.integers(20, 160)), kind, closed, f"r{j}") for j in range(3)
    ]
    models = [random_model(rng, name) for _ in range(4)] + [true]
    params = np.array([m.to_array() for m in models])
    inits = ("rest",) if closed else ("rest", "steady")
    for init in inits:
        got = avll.batch_cost(
            name, params, runs, weights=weights, init=init, closed_loop=closed, threads=2
        )
        want = ref.batch_cost(models, runs, weights=weights, init=init, closed_loop_=closed)
        assert got.shape == (5, 3)
        fin = np.isfinite(want)
        assert np.array_equal(np.isfinite(got), fin)
        assert np.all(np.abs(got[fin] - want[fin]) <= TOL * np.abs(want[fin]))
        assert fin[-1].all()  # the generating model is stable


def test_batch_cost_upper_free_overrides_the_runs_law() -> None:
    rng = np.random.default_rng(21)
    m = avll.PAPER_TABLE_II["proposed"]
    runs = [make_run(rng, m, 120, closed=True, rid=f"r{j}") for j in range(2)]
    rows, want = [], []
    for kg, Tg in [(0.3, 1.5), (0.6, 2.4)]:
        rows.append(np.concatenate([m.to_array(), [kg, Tg]]))
        want.append(
            [
                ref.run_cost(
                    m,
                    r,
                    closed_loop_=True,
                    upper=avll.UpperLevel(kg=kg, kv=r.upper.kv, Tg=Tg, Gmin=r.upper.Gmin),
                    weights=CLOSED_LOOP_WEIGHTS,  # batch_cost's closed-loop default
                )
                for r in runs
            ]
        )
    got = avll.batch_cost("proposed", np.array(rows), runs, closed_loop=True, upper_free=[0, 2])
    assert relerr(got, np.array(want)) <= TOL


def test_batch_cost_is_thread_count_independent() -> None:
    rng = np.random.default_rng(4)
    m = avll.PAPER_TABLE_II["proposed"]
    runs = [make_run(rng, m, 200, rid=f"r{j}") for j in range(3)]
    params = np.array([random_model(rng, "proposed").to_array() for _ in range(16)])
    c1 = avll.batch_cost("proposed", params, runs, threads=1)
    c2 = avll.batch_cost("proposed", params, runs, threads=2)
    assert np.array_equal(c1, c2)


# ------------------------------------------------------------------ properties

finite = st.floats(-5.0, 5.0, allow_nan=False)


@st.composite
def linear_models(draw: st.DrawFn) -> avll.LowerLevelModel:
    name = draw(st.sampled_from(["first", "second", "proposed"]))
    if name == "first":
        return avll.FirstOrderLag(draw(st.floats(0.05, 3.0)))
    K0 = draw(st.floats(0.1, 2.0))
    m2, m3 = draw(st.floats(0.02, 3.0)), draw(st.floats(0.1, 9.0))
    Td = draw(st.floats(0.0, 1.0))
    if name == "second":
        return avll.SecondOrder(K0=K0, m2=m2, m3=m3, Td=Td)
    return avll.Proposed(
        m1=draw(st.floats(0.0, 8.0)),
        m2=m2,
        m3=m3,
        K0=K0,
        Td=Td,
        K=draw(st.floats(-1.0, 0.9)) / K0,
    )


def _scale(y: np.ndarray) -> float:
    return max(1.0, float(np.max(np.abs(y))))


@settings(max_examples=60, deadline=None)
@given(
    m=linear_models(),
    u1=st.lists(finite, min_size=1, max_size=80),
    seed=st.integers(0, 2**32 - 1),
    alpha=finite,
    beta=finite,
)
def test_linearity(
    m: avll.LowerLevelModel, u1: list[float], seed: int, alpha: float, beta: float
) -> None:
    assume(ref.lower_level_stable(m, DT))  # unstable ones are refused (tested elsewhere)
    a = np.array(u1)
    b = np.random.default_rng(seed).normal(size=a.size)
    ya, yb = avll.simulate(m, a, DT), avll.simulate(m, b, DT)
    y = avll.simulate(m, alpha * a + beta * b, DT)
    want = alpha * ya + beta * yb
    assert np.max(np.abs(y - want)) <= 1e-9 * _scale(want) * (1 + abs(alpha) + abs(beta))


@settings(max_examples=60, deadline=None)
@given(m=linear_models(), u=st.lists(finite, min_size=1, max_size=80), shift=st.integers(1, 30))
def test_time_invariance(m: avll.LowerLevelModel, u: list[float], shift: int) -> None:
    """At rest, delaying the input by k samples delays the output by k samples."""
    assume(ref.lower_level_stable(m, DT))
    x = np.array(u)
    y = avll.simulate(m, x, DT)
    ys = avll.simulate(m, np.concatenate([np.zeros(shift), x]), DT)
    assert np.all(ys[:shift] == 0.0)
    assert np.max(np.abs(ys[shift:] - y)) <= 1e-12 * _scale(y)


@settings(max_examples=40, deadline=None)
@given(m=linear_models(), n=st.integers(1, 200), kind=st.sampled_from(["acceleration", "speed"]))
def test_zero_in_zero_out(m: avll.LowerLevelModel, n: int, kind: str) -> None:
    if not ref.lower_level_stable(m, DT):
        with pytest.raises(ValueError, match="not asymptotically stable"):
            avll.simulate_full(m, np.zeros(n), DT, command_kind=kind)
        return
    for init in ("rest", "steady"):
        tr = avll.simulate_full(m, np.zeros(n), DT, command_kind=kind, init=init)
        for key in ("a", "v", "x"):
            assert np.all(getattr(tr, key) == 0.0)


@settings(max_examples=40, deadline=None)
@given(m=linear_models(), u0=st.floats(-3.0, 3.0).filter(lambda x: abs(x) > 1e-3))
def test_dc_gain(m: avll.LowerLevelModel, u0: float) -> None:
    """A constant command from the steady state stays at ``K0/(1 - K K0) u0``; the
    speed response's derivative is then zero. (Only for a stable sampled lower level:
    an unstable one leaves the equilibrium on rounding errors, as it should.)"""
    assume(ref.lower_level_stable(m, DT))
    c = m.linear()
    gain = c["b0"] / (1.0 - c["K"] * c["b0"])
    assert gain == pytest.approx(m.dc_gain)
    y = avll.simulate(m, np.full(50, u0), DT, init="steady")
    assert np.allclose(y, gain * u0, rtol=1e-9, atol=1e-12)
    tr = avll.simulate_full(m, np.full(50, u0), DT, command_kind="speed", init="steady", x0=1.0)
    assert np.allclose(tr.a, 0.0, atol=1e-9 * abs(gain * u0) + 1e-12)
    assert np.allclose(tr.x, 1.0 + gain * u0 * np.arange(50) * DT, rtol=1e-9)


def test_dc_gain_reached_from_rest() -> None:
    for m in avll.PAPER_TABLE_II.values():
        y = avll.simulate(m, np.ones(20000), DT)
        assert y[-1] == pytest.approx(m.dc_gain, rel=1e-6)


# -------------------------------------------------------------- errors, no NaN

U = np.linspace(0.0, 1.0, 50)
PROP = [6.7893, 1.2824, 8.8157, 0.3479, 0.7903, 0.1008]


@pytest.mark.parametrize(
    "call,arg",
    [
        (lambda: avll.Proposed(1.0, 0.0, 1.0, 1.0, 0.1, 0.0), "m2"),
        (lambda: avll.Proposed(1.0, -1.0, 1.0, 1.0, 0.1, 0.0), "m2"),
        (lambda: avll.SecondOrder(1.0, 1.0, 1.0, -0.1), "Td"),
        (lambda: avll.FirstOrderLag(0.0), "Td"),
        (lambda: _core.simulate("proposed", [1, 0, 1, 1, 0.1, 0], U, DT), "m2"),
        (lambda: _core.simulate("proposed", [1, 1, 1, 1, -0.1, 0], U, DT), "Td"),
        (lambda: _core.simulate("proposed", [1, 1, 1, math.nan, 0.1, 0], U, DT), "K0"),
        (lambda: _core.simulate("proposed", PROP[:5], U, DT), "params"),
        (lambda: avll.simulate(avll.PAPER_TABLE_II["second"], U, 0.0), "dt"),
        (lambda: avll.simulate(avll.PAPER_TABLE_II["second"], U, -0.05), "dt"),
        (lambda: avll.simulate(avll.PAPER_TABLE_II["second"], U, math.nan), "dt"),
        (lambda: avll.simulate(avll.PAPER_TABLE_II["first"], [0.0, math.nan], DT), "command"),
        (lambda: avll.simulate(avll.PAPER_TABLE_II["first"], [0.0, math.inf], DT), "command"),
        (lambda: avll.simulate(avll.PAPER_TABLE_II["first"], U, DT, init="cold"), "init"),
        (lambda: _core.simulate("third", [1.0], U, DT), "model"),
        (lambda: avll.batch_cost("third", [[1.0]], []), "model"),
        (
            lambda: avll.simulate_full(avll.PAPER_TABLE_II["first"], U, DT, command_kind="jerk"),
            "command_kind",
        ),
        (
            lambda: avll.closed_loop(
                avll.PAPER_TABLE_II["first"],
                np.arange(5.0),
                np.arange(4.0),
                DT,
                avll.UpperLevel(0.5),
                v0=0.0,
                x0=0.0,
            ),
            "lead_v",
        ),
        (
            lambda: avll.closed_loop(
                avll.PAPER_TABLE_II["first"],
                [0.0, math.nan],
                [0.0, 0.0],
                DT,
                avll.UpperLevel(0.5),
                v0=0.0,
                x0=0.0,
            ),
            "lead_x",
        ),
        (
            lambda: _core.batch_cost(
                "first",
                np.ones((1, 1)),
                _core.RunSet([0, 3], np.array([DT]), np.zeros(3), command=np.zeros(4)),
            ),
            "command",
        ),
        (
            lambda: _core.batch_cost(
                "first",
                np.ones((1, 1)),
                _core.RunSet([0, 3], np.array([0.0]), np.zeros(3), command=np.zeros(3)),
            ),
            "dt",
        ),
        (
            lambda: _core.batch_cost(
                "first",
                np.ones((1, 1)),
                _core.RunSet(
                    [0, 3], np.array([DT]), np.array([0, math.nan, 0]), command=np.zeros(3)
                ),
            ),
            "a",
        ),
        (
            lambda: _core.batch_cost(
                "first",
                np.ones((1, 1)),
                _core.RunSet([0, 3], np.array([DT]), np.zeros(3), command=np.zeros(3)),
                init="hot",
            ),
            "init",
        ),
        (
            lambda: _core.batch_cost(
                "first",
                np.ones((1, 2)),
                _core.RunSet([0, 3], np.array([DT]), np.zeros(3), command=np.zeros(3)),
            ),
            "params",
        ),
    ],
)
def test_bad_input_raises_value_error_naming_the_argument(call, arg: str) -> None:  # noqa: ANN001
    with pytest.raises(ValueError) as exc:
        call()
    prefix = str(exc.value).split(":")[0]
    assert prefix.split(".")[-1] == arg, str(exc.value)


def _one_run(n: int = 200) -> avll.Run:
    t = np.arange(n) * DT
    u = np.sin(t)
    return avll.Run("r", t, a=0.5 * u, v=np.cumsum(u) * DT, x=np.zeros(n), command=u)


@pytest.mark.parametrize("n", [20, 200, 4000])
@pytest.mark.parametrize(
    "row",
    [
        [1.0, 1.0, 1.0, 1.0, 0.1, 5.0],  # K K0 > 1: a real pole in the right half-plane
        [1.0, 1.0, 1.0, 2.0, 0.1, 0.5],  # K K0 = 1: a pole at s = 0
        [0.0, 1.0, -0.5, 1.0, 0.1, 0.0],  # negative damping, no feedback
        [0.0, 1.0, -0.01, 1.0, 0.3, 0.0],  # slightly negative damping
        [0.0, 1.0, 0.0, 1.0, 0.3, 0.0],  # undamped: not asymptotically stable
        [6.7893, 1.2824, 8.8157, 0.3479, 0.7903, -40.0],  # strong negative feedback + delay
    ],
)
def test_unstable_parameters_cost_inf(row: list[float], n: int) -> None:
    run = _one_run(n)
    for weights in ((1.0, 0.0, 0.0), (1.0, 1.0, 1.0)):
        c = avll.batch_cost("proposed", np.array([row, PROP]), [run], weights=weights)
        assert math.isinf(c[0, 0]) and c[0, 0] > 0, c
        assert np.isfinite(c[1, 0])


def test_invalid_rows_cost_inf_never_nan() -> None:
    run = _one_run()
    rows = np.array(
        [
            [1.0, 0.0, 1.0, 1.0, 0.1, 0.0],  # m2 = 0
            [1.0, 1.0, 1.0, 1.0, -0.1, 0.0],  # Td < 0
            [1.0, math.nan, 1.0, 1.0, 0.1, 0.0],
            [1.0, 1.0, 1.0, 1.0, math.inf, 0.0],
            [1e308, 1e-308, 1e308, 1e308, 1e308, 1e308],
            PROP,
        ]
    )
    c = avll.batch_cost("proposed", rows, [run], weights=(1.0, 1.0, 1.0))
    assert not np.isnan(c).any()
    assert np.all(np.isinf(c[:5])) and np.isfinite(c[5, 0])


@settings(max_examples=150, deadline=None)
@given(
    row=st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=6, max_size=6),
    closed=st.booleans(),
)
def test_cost_never_nan_and_never_panics(row: list[float], closed: bool) -> None:
    rng = np.random.default_rng(0)
    run = make_run(rng, avll.PAPER_TABLE_II["proposed"], 60, closed=closed)
    c = avll.batch_cost("proposed", np.array([row]), [run], closed_loop=closed)
    assert not np.isnan(c).any()
    assert np.all(c >= 0)


@settings(max_examples=150, deadline=None)
@given(
    name=st.sampled_from(["first", "second", "proposed", "x"]),
    params=st.lists(st.floats(width=64), min_size=0, max_size=7),
    u=st.lists(st.floats(width=64), min_size=0, max_size=20),
    dt=st.floats(width=64),
    init=st.sampled_from(["rest", "steady", ""]),
    kind=st.sampled_from(["acceleration", "speed", "?"]),
)
def test_no_panic_crosses_into_python(
    name: str, params: list[float], u: list[float], dt: float, init: str, kind: str
) -> None:
    """Arbitrary arguments give results or ValueError, never a Rust panic."""
    arr = np.array(u, dtype=np.float64)
    for call in (
        lambda: _core.simulate(name, params, arr, dt, init),
        lambda: _core.simulate_full(name, params, arr, dt, kind, init, 0.0, 0.0),
        lambda: _core.closed_loop(name, params, arr, arr, dt, 0.5, 0.1, 2.0, 9.5, 1.0, 0.0),
        lambda: _core.platoon(name, params, arr, arr, dt, 0.5, 0.1, 2.0, 9.5, 2),
    ):
        try:
            call()
        except ValueError:
            pass


def test_inf_cost_pattern_matches_reference_stability() -> None:
    """The core's stability rule (Schur-Cohn on the loop's characteristic polynomial)
    against the reference's (eigenvalues of the delay-augmented state map), on random
    rows many of which are unstable; rows within 1e-6 of the boundary are skipped."""
    rng = np.random.default_rng(99)
    run = _one_run(30)  # far too short for the divergence check to notice
    rows, stable = [], []
    while len(rows) < 60:
        m = avll.Proposed(
            m1=float(rng.uniform(0, 8)),
            m2=float(rng.uniform(0.02, 3)),
            m3=float(rng.uniform(-1, 5)),
            K0=float(rng.uniform(0.1, 2)),
            Td=float(rng.uniform(0, 1.5)),
            K=float(rng.uniform(-6, 3)),
        )
        r = ref.lower_level_spectral_radius(m, DT)
        if abs(r - 1.0) < 1e-6:
            continue
        rows.append(m.to_array())
        stable.append(r < 1.0)
    c = avll.batch_cost("proposed", np.array(rows), [run])[:, 0]
    assert 10 < sum(stable) < 50  # both kinds are exercised
    assert np.array_equal(np.isfinite(c), np.array(stable))


def test_extreme_time_constants_raise_instead_of_hanging() -> None:
    """Regression: |A dt| ~ 1e59 made nalgebra's matrix exponential loop forever."""
    row = [1.4085411909858596e75, 1.2248913874710556e16, 1.4085411909858596e75, 1e-191, 1e-9, -1.08]
    with pytest.raises(ValueError, match="^params"):
        _core.simulate("proposed", row, np.ones(5), DT)
    assert math.isinf(avll.batch_cost("proposed", np.array([row]), [_one_run(20)])[0, 0])


def test_unstable_lower_level_is_a_value_error_everywhere() -> None:
    """The policy of every trajectory function: a lower level that is not
    asymptotically stable (here K K0 > 1) is a ValueError naming the model and its
    parameters, never an array of NaN; its costs are inf."""
    m = avll.Proposed(m1=0.0, m2=1.0, m3=1.0, K0=1.0, Td=0.1, K=5.0)  # K K0 > 1
    assert not ref.lower_level_stable(m, DT)
    lx, lv = leader(np.random.default_rng(2), 300)
    up = avll.UpperLevel(0.5, 0.0, 2.0, 9.5)
    calls = [
        lambda: avll.simulate(m, np.ones(100), DT),
        lambda: avll.simulate_full(m, np.ones(100), DT),
        lambda: avll.closed_loop(m, lx, lv, DT, up, v0=12.0, x0=0.0),
        lambda: avll.platoon(m, lx, lv, DT, up, 2),
        lambda: avll.simulate_full(m, np.ones(100), DT),
        lambda: avll.closed_loop(m, lx, lv, DT, up, v0=12.0, x0=0.0),
        lambda: avll.simulate_full(avll.WithEffects(m, (avll.Saturation(2.0, 2.0),)),
                                      np.ones(100), DT),
    ]
    for call in calls:
        with pytest.raises(ValueError, match=r"Proposed\(m1=0.0, m2=1.0.*K=5.0\).*not "
                                             "asymptotically stable"):
            call()
    run = avll.Run("r", np.arange(100) * DT, np.zeros(100), command=np.ones(100))
    assert np.isinf(avll.batch_cost("proposed", m.to_array(), [run])).all()
    # the braking side of an asymmetric lower level is checked too
    base = avll.SecondOrder(K0=1.0, m2=0.5, m3=0.1, Td=0.0)
    assert ref.lower_level_stable(base, DT)
    avll.simulate_full(avll.WithEffects(base, (avll.Asymmetric(1.0, 1.0),)), np.ones(50), DT)


def test_binding_agrees_with_the_reference_stability_test() -> None:
    """_core.lower_level_stable (the Rust test behind the costs' inf) against the
    reference's spectral radius of the sampled lower level, on random parameters."""
    rng = np.random.default_rng(11)
    seen = {True: 0, False: 0}
    for _ in range(400):
        Td = float(rng.choice([0.0, rng.uniform(0, 1.5)]))
        m = avll.Proposed(m1=float(rng.uniform(-2, 8)), m2=float(rng.uniform(0.02, 3)),
                          m3=float(rng.uniform(-0.5, 9)), K0=float(rng.uniform(0.1, 2)),
                          Td=Td, K=float(rng.uniform(-2, 2)))
        rho = ref.lower_level_spectral_radius(m, DT)
        if abs(rho - 1.0) < 1e-6:  # too close to the boundary to compare
            continue
        got = avll.rollout.lower_level_stable(m, DT)
        assert got == (rho < 1.0), (m, rho)
        seen[got] += 1
    assert seen[True] > 50 and seen[False] > 50


def test_diverging_follower_is_nan_after_the_divergence() -> None:
    """A stable lower level under destabilising upper-level gains: the car-following
    loop diverges, which is a result (NaN from the divergence on), not an error."""
    m = avll.PAPER_TABLE_II["second"]
    assert ref.lower_level_stable(m, DT)
    lx, lv = leader(np.random.default_rng(2), 3000)
    tr = avll.closed_loop(m, lx, lv, DT, avll.UpperLevel(3.0, 3.0, 0.0, 9.5), v0=12.0, x0=0.0)
    bad = np.flatnonzero(~np.isfinite(tr.a))
    assert bad.size > 0
    k = bad[0]
    assert abs(tr.a[k - 1]) >= ref.DIVERGED  # the diverged sample is kept, NaN after it
    assert np.all(np.isfinite(tr.a[:k])) and np.all(np.isnan(tr.a[k:]))
    for key in ("v", "x", "command"):
        assert np.all(np.isnan(getattr(tr, key)[k:])) and np.all(np.isfinite(getattr(tr, key)[:k]))
    plat = avll.platoon(m, lx, lv, DT, avll.UpperLevel(3.0, 3.0, 0.0, 9.5), 2)
    assert np.isnan(plat.a[1, -1])  # and so are the followers behind it


def test_rust_and_python_model_registries_agree() -> None:
    """The Rust registry's parameter names equal the Python parameter objects'."""
    for name, cls in avll.MODELS.items():
        assert tuple(_core.model_params(name)) == cls.param_names()
    with pytest.raises(ValueError, match="unknown model"):
        _core.model_params("third")


def test_model_registry_is_the_cores() -> None:
    from avll.models import MODELS

    assert list(MODELS) == list(_core.model_names())
