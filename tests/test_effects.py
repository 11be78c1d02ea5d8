"""Effects library: the Rust engine against the numpy reference, the no-effect
identity with the linear rollouts, linearisations and the batched cost."""

from __future__ import annotations

import numpy as np
import pytest

import avll
from avll import _core
from avll.effects import (
    CANONICAL_ORDER,
    EFFECTS,
    Asymmetric,
    Deadband,
    Delay,
    Grade,
    PowerLimit,
    RateLimit,
    RoadLoad,
    Saturation,
    Sensor,
    SpeedDrag,
    WithEffects,
)
from avll.reference.effects import rollout_effects
from avll.rollout import batch_cost, closed_loop, simulate_full

DT = 0.05
BASES = [
    avll.PAPER_TABLE_II["proposed"],
    avll.PAPER_TABLE_II["second"],
    avll.PAPER_TABLE_II["first"],
    avll.Proposed(m1=0.4, m2=0.3, m3=1.1, K0=0.9, Td=0.125, K=0.05),  # fractional Td
]
# Non-neutral parameters that make every effect act on the test signals.
ACTIVE = {
    "delay": Delay(tau=0.33),
    "rate_limit": RateLimit(j_max=1.2),
    "deadband": Deadband(delta=0.25),
    "asymmetric": Asymmetric(kb=0.7, rb=1.6),
    "saturation": Saturation(a_max=0.8, d_max=1.1),
    "speed_drag": SpeedDrag(c0=0.05, c2=0.003),
    "grade": Grade(g_eff=6.0),
    "road_load": RoadLoad(c0=0.05, c1=0.01, c2=0.002),
    "power_limit": PowerLimit(p=6.0, v_b=3.0),
    "sensor": Sensor(tau=0.3, bias=0.1),
}


def _signals(n: int = 1200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(n) * DT
    u = 1.4 * np.sin(0.35 * t) + 0.6 * np.sin(1.3 * t + 0.4) + 0.2
    grade = 0.03 * np.sin(0.05 * t + 1.0)
    return t, u, grade


def _leader(n: int = 1600) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * DT
    lv = 11.0 + 2.5 * np.sin(0.15 * t) + 0.8 * np.sin(0.6 * t)
    lx = 100.0 + np.concatenate([[0.0], np.cumsum(0.5 * DT * (lv[1:] + lv[:-1]))])
    return lx, lv


def test_registry_matches_rust() -> None:
    info = {d["name"]: d for d in _core.effect_info()}
    assert tuple(info) == CANONICAL_ORDER == tuple(EFFECTS)
    for name, cls in EFFECTS.items():
        assert tuple(info[name]["params"]) == cls.param_names()
        assert tuple(tuple(b) for b in info[name]["bounds"]) == cls.bounds
        assert tuple(info[name]["neutral"]) == cls.neutral
        assert info[name]["exo"] == cls.exo
        assert info[name]["accel_only"] == cls.accel_only
        assert info[name]["needs_speed"] == cls.needs_speed
        assert info[name]["level"] == cls.level in ("lower", "upper")
        assert info[name]["excludes"] == cls.excludes
        assert cls() == cls(*cls.neutral), "the defaults are the neutral parameters"
        lo, hi = zip(*cls.bounds, strict=True)
        assert all(a <= n <= b for a, n, b in zip(lo, cls.neutral, hi, strict=True))


@pytest.mark.parametrize("base", BASES, ids=lambda b: f"{b.name}-{b.to_array()[0]:.2f}")
@pytest.mark.parametrize("init", ["rest", "steady"])
@pytest.mark.parametrize("kind", ["acceleration", "speed"])
def test_no_effect_equals_linear_rollout(base, init, kind) -> None:
    _, u, _ = _signals()
    want = avll.simulate_full(base, u, DT, command_kind=kind, init=init, v0=4.0, x0=2.0)
    got = simulate_full(base, u, DT, command_kind=kind, init=init, v0=4.0, x0=2.0)
    for k in ("a", "v", "x"):
        # same arithmetic in another order: equal to rounding (positions reach ~1e3 m)
        np.testing.assert_allclose(getattr(got, k), getattr(want, k), rtol=1e-12, atol=1e-12)
    if kind == "acceleration":
        np.testing.assert_allclose(got.a, avll.simulate(base, u, DT, init=init), atol=1e-12)


@pytest.mark.parametrize("base", BASES[:2], ids=lambda b: b.name)
def test_neutral_effects_equal_linear_closed_loop(base) -> None:
    lx, lv = _leader()
    up = avll.UpperLevel(kg=0.5, kv=0.2, Tg=1.8, Gmin=9.5)
    want = avll.closed_loop(base, lx, lv, DT, up, v0=11.0, x0=lx[0] - 30.0)
    neutral = WithEffects(
        base, tuple(EFFECTS[n](*EFFECTS[n].neutral) for n in ("delay", "deadband", "asymmetric",
                                                                "speed_drag", "grade"))
    )
    got = closed_loop(
        neutral, lx, lv, DT, up, v0=11.0, x0=lx[0] - 30.0, exo={"grade": np.full(lx.size, 0.02)}
    )
    for k in ("a", "v", "x", "command"):
        # same arithmetic in another order: equal to rounding (positions reach ~1e3 m)
        np.testing.assert_allclose(getattr(got, k), getattr(want, k), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", [n for n in CANONICAL_ORDER if EFFECTS[n].level == "lower"])
@pytest.mark.parametrize("base", BASES, ids=lambda b: f"{b.name}-{b.to_array()[0]:.2f}")
def test_each_effect_matches_reference_open_loop(name, base) -> None:
    _, u, grade = _signals()
    m = WithEffects(base, (ACTIVE[name],))
    exo = {"grade": grade}
    got = simulate_full(m, u, DT, v0=8.0, x0=1.0, exo=exo)
    ref = rollout_effects(m, DT, command=u, v0=8.0, x0=1.0, exo=exo)
    lin = avll.simulate_full(base, u, DT, v0=8.0, x0=1.0)
    assert np.max(np.abs(got.a - lin.a)) > 1e-3, "the effect must act on this signal"
    for k in ("a", "v", "x"):
        np.testing.assert_allclose(getattr(got, k), ref[k], rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", ["delay", "rate_limit", "deadband", "asymmetric"])
@pytest.mark.parametrize("init", ["rest", "steady"])
def test_speed_command_effects_match_reference(name, init) -> None:
    base = avll.SecondOrder(K0=1.0, m2=0.8, m3=1.9, Td=0.23)
    t = np.arange(1500) * DT
    u = 10 + 3 * np.sin(0.2 * t) + np.sin(0.9 * t)
    eff = ACTIVE[name] if name != "asymmetric" else Asymmetric(kb=1.0, rb=1.7)
    m = WithEffects(base, (eff,))
    got = simulate_full(m, u, DT, command_kind="speed", init=init, x0=3.0)
    ref = rollout_effects(m, DT, command=u, command_kind="speed", init=init, x0=3.0)
    assert np.max(np.abs(got.v - avll.simulate(base, u, DT, init=init))) > 1e-3
    for k in ("a", "v", "x"):
        np.testing.assert_allclose(getattr(got, k), ref[k], rtol=0, atol=1e-9)


@pytest.mark.parametrize("drop", ["road_load", "speed_drag"])
def test_all_effects_together_match_reference_closed_loop(drop) -> None:
    lx, lv = _leader()
    grade = 0.02 * np.sin(np.arange(lx.size) * DT * 0.07)
    up = avll.UpperLevel(kg=0.6, kv=0.3, Tg=2.0, Gmin=9.5)
    # speed_drag and road_load are one family and are refused together.
    effs = tuple(e for n, e in ACTIVE.items() if n != drop)
    m = WithEffects(avll.PAPER_TABLE_II["proposed"], effs)
    got = closed_loop(m, lx, lv, DT, up, v0=11.0, x0=lx[0] - 31.5, exo={"grade": grade})
    ref = rollout_effects(
        m, DT, lead_x=lx, lead_v=lv, upper=up, v0=11.0, x0=lx[0] - 31.5, exo={"grade": grade}
    )
    for k in ("a", "v", "x", "command"):
        np.testing.assert_allclose(getattr(got, k), ref[k], rtol=0, atol=1e-9)


def test_asymmetric_linearisation_is_exact_on_the_braking_side() -> None:
    base = avll.SecondOrder(K0=0.9, m2=0.4, m3=1.2, Td=0.3)
    m = WithEffects(base, (Asymmetric(kb=0.6, rb=1.5),))
    _, u, _ = _signals()
    u = -np.abs(u) - 0.05
    lb = m.linear(side=-1)
    assert lb["b0"] == pytest.approx(0.54) and lb["a2"] == pytest.approx(0.4 * 2.25)
    eq = avll.SecondOrder(K0=lb["b0"], m2=lb["a2"], m3=lb["a1"], Td=lb["Td"])
    np.testing.assert_allclose(
        simulate_full(m, u, DT).a, avll.simulate(eq, u, DT), rtol=0, atol=1e-10
    )
    assert m.linear(side=1) == pytest.approx(base.linear())


def test_other_linearisations() -> None:
    sec = avll.PAPER_TABLE_II["second"]
    assert WithEffects(sec, (Delay(0.2),)).linear()["Td"] == pytest.approx(sec.Td + 0.2)
    with pytest.raises(ValueError, match="delay"):
        WithEffects(avll.PAPER_TABLE_II["proposed"], (Delay(0.2),)).linear()
    with pytest.raises(ValueError, match="speed_drag"):
        WithEffects(sec, (SpeedDrag(0.0, 0.002),)).linear(v=10.0)
    ident = WithEffects(sec, (Saturation(1, 1), Deadband(0.1), RateLimit(2.0), Grade(9.0)))
    assert ident.linear(v=10.0) == pytest.approx(sec.linear())


def _runs(model: WithEffects, n_runs: int = 3) -> list[avll.Run]:
    out = []
    for j in range(n_runs):
        t, u, grade = _signals(800 + 100 * j)
        u = u * (1 + 0.2 * j)
        tr = simulate_full(model, u, DT, v0=9.0, x0=0.0, exo={"grade": grade})
        out.append(
            avll.Run(run_id=str(j), t=t, a=tr.a + 0.01 * np.sin(7 * t), command=u, v=tr.v,
                     x=tr.x, exo={"grade": grade})
        )  # fmt: skip
    return out


def test_batch_cost_matches_simulation_and_flags_invalid_rows() -> None:
    base = avll.PAPER_TABLE_II["proposed"]
    m = WithEffects(base, (Saturation(0.9, 1.2), Grade(5.0)))
    runs = _runs(m)
    row = m.to_array()
    bad = row.copy()
    bad[6] = -1.0  # a_max < 0
    unstable = row.copy()
    unstable[2] = -5.0  # m3 < 0: G itself unstable
    c = batch_cost("proposed", np.vstack([row, bad, unstable]), runs,
                   effects=["saturation", "grade"], weights=(1.0, 0.5, 0.0), threads=1)
    for j, r in enumerate(runs):
        tr = simulate_full(m, r.command, DT, v0=r.v[0], x0=r.x[0], exo=r.exo)
        want = np.mean((tr.a - r.a) ** 2) + 0.5 * np.mean((tr.v - r.v) ** 2)
        assert c[0, j] == pytest.approx(want, rel=1e-12)
    assert np.all(np.isinf(c[1:]))
    # Same answer with another thread count.
    c2 = batch_cost("proposed", row[None, :], runs, effects=["saturation", "grade"], threads=2)
    c1 = batch_cost("proposed", row[None, :], runs, effects=["saturation", "grade"], threads=1)
    np.testing.assert_array_equal(c1, c2)
    # The acceleration-only fast path (no integrators) gives the same costs.
    for j, r in enumerate(runs):
        tr = simulate_full(m, r.command, DT, v0=r.v[0], x0=r.x[0], exo=r.exo)
        assert c1[0, j] == pytest.approx(np.mean((tr.a - r.a) ** 2), rel=1e-12)
    drag = WithEffects(base, (SpeedDrag(0.05, 0.002),))
    cd = batch_cost("proposed", drag.to_array()[None, :], runs, effects=["speed_drag"])
    for j, r in enumerate(runs):
        tr = simulate_full(drag, r.command, DT, v0=r.v[0], x0=r.x[0])
        assert cd[0, j] == pytest.approx(np.mean((tr.a - r.a) ** 2), rel=1e-12)


def test_bad_input_names_the_argument() -> None:
    base = avll.PAPER_TABLE_II["second"]
    _, u, _ = _signals(100)
    with pytest.raises(ValueError, match="exo_grade"):
        simulate_full(WithEffects(base, (Grade(9.8),)), u, DT)
    with pytest.raises(ValueError, match="duplicate"):
        WithEffects(base, (Delay(0.1), Delay(0.2)))
    with pytest.raises(ValueError, match="unknown effect"):
        batch_cost("second", np.zeros((1, 5)), _runs(WithEffects(base)), effects=["wind"])
    with pytest.raises(ValueError, match="saturation.a_max"):
        Saturation(a_max=-1.0, d_max=1.0)
    with pytest.raises(ValueError, match="kb must be 1"):
        simulate_full(WithEffects(base, (Asymmetric(0.5, 1.0),)), u + 5, DT,
                         command_kind="speed")  # fmt: skip


def test_equivalent_model_for_stability_maps() -> None:
    from avll.effects import equivalent_model

    prop = avll.PAPER_TABLE_II["proposed"]
    brake = equivalent_model(WithEffects(prop, (Asymmetric(0.8, 1.5),)), side=-1)
    assert isinstance(brake, avll.Proposed)
    assert brake.K0 == pytest.approx(0.8 * prop.K0) and brake.m2 == pytest.approx(2.25 * prop.m2)
    assert brake.m1 == pytest.approx(0.8 * 1.5 * prop.m1) and brake.K == prop.K
    first = equivalent_model(WithEffects(avll.FirstOrderLag(Td=0.7), (Saturation(1, 1),)))
    assert first == avll.FirstOrderLag(Td=0.7)
    with pytest.raises(ValueError, match="neither"):
        equivalent_model(WithEffects(avll.FirstOrderLag(Td=0.7), (Asymmetric(0.5, 1.0),)), side=-1)


def test_stability_maps_redrawn_with_an_effect() -> None:
    from avll.effects import equivalent_model
    from avll.stability import stability_map

    prop = avll.PAPER_TABLE_II["proposed"]
    kg, tg, kv = np.linspace(0.05, 1.5, 30), np.linspace(0.1, 6, 30), [0.0, 0.3]
    base = stability_map(prop, kg, tg, kv)
    # Effects whose small-signal model is the identity leave the map unchanged.
    same = equivalent_model(WithEffects(prop, (Saturation(1, 1), Deadband(0.1), Grade(9.8))))
    np.testing.assert_array_equal(stability_map(same, kg, tg, kv), base)
    # Slower braking dynamics (more lag) shrink the stable region; faster ones grow it.
    n = {r: int((stability_map(equivalent_model(WithEffects(prop, (Asymmetric(1.0, r),)),
                                                side=-1), kg, tg, kv) == 2).sum())
         for r in (0.7, 1.5)}  # fmt: skip
    n0 = int((base == 2).sum())
    assert n[1.5] < n0 < n[0.7]


def test_ga_calibration_recovers_effect_params_thread_independently() -> None:
    base = avll.SecondOrder(K0=0.9, m2=0.3, m3=1.0, Td=0.25)
    truth = WithEffects(base, (Saturation(0.9, 1.2),))
    runs = _runs(truth)
    lo = [0.5, 0.05, 0.2, 0.0, 0.2, 0.2]
    hi = [1.5, 1.0, 3.0, 1.0, 3.0, 3.0]
    scale = ["linear", "log", "log", "linear", "linear", "linear"]
    from avll.calibration import default_bounds

    names = list(default_bounds("second", effects=["saturation"]))
    box = dict(zip(names, zip(lo, hi, scale, strict=True), strict=True))
    out = [avll.calibrate("second", runs, effects=["saturation"], bounds=box, seed=3,
                          starts=1, max_generations=150, threads=t) for t in (1, 2)]  # fmt: skip
    np.testing.assert_array_equal(out[0].x, out[1].x)
    np.testing.assert_allclose(out[0].x, truth.to_array(), rtol=0.05)


def test_braking_side_unstable_costs_inf_like_the_trajectory_refuses():
    """A row whose braking side kb G(rb s) is not asymptotically stable in the inner
    loop costs inf exactly when the trajectory functions refuse it, whether or not
    the run is long enough to show the divergence (found as a GA optimum of a
    closed-loop OpenACC fit before the cost checked the braking side)."""
    from avll import Proposed, Run
    from avll.effects import Asymmetric, WithEffects

    base = Proposed(8.1645, 0.0017358, 99.356, 1.0202, 1.33e-5, 0.98015)
    dt = 0.1
    t = np.arange(0.0, 0.3, dt)  # three samples: too short for any divergence to show
    cmd = 0.5 + 0.3 * np.sin(0.5 * t)
    run = Run(run_id="o", t=t, a=np.zeros_like(t), command=cmd)
    grid = [(kb, rb) for kb in (0.5, 1.0, 1.5, 2.0, 2.5) for rb in (0.4, 0.6, 1.0, 2.0)]
    models = [WithEffects(base, (Asymmetric(kb, rb),)) for kb, rb in grid]
    cost = batch_cost("proposed", np.array([m.to_array() for m in models]), [run],
                      effects=["asymmetric"])[:, 0]
    refused = []
    for m in models:
        try:
            simulate_full(m, cmd, dt)
            refused.append(False)
        except ValueError as e:
            assert "braking side" in str(e)
            refused.append(True)
    assert any(refused) and not all(refused)
    assert [bool(np.isinf(c)) for c in cost] == refused
