"""The effects real vehicles have (``road_load``, ``power_limit``,
``sensor``) and the acceleration-level effects on speed-command models (item 5): the
Rust engine against the numpy reference written from the equations, neutral
parameters against the base model, the defining properties of each effect, the
linearisations and the argument names in the errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

import avll
from avll import _core
from avll.effects import (
    EFFECTS,
    Grade,
    PowerLimit,
    RoadLoad,
    Saturation,
    Sensor,
    SpeedDrag,
    WithEffects,
)
from avll.reference.effects import rollout_effects
from avll.rollout import batch_cost, closed_loop, simulate_full

DT = 0.05
#: Effects acting on the acceleration that integrates into the speed (item 5).
ACCEL_LEVEL = ["saturation", "power_limit", "speed_drag", "road_load", "grade"]
SPEED_BASES = [
    avll.SecondOrder(K0=1.0, m2=0.8, m3=1.9, Td=0.23),
    # b1 != 0 (the derivative reads the reference input) and K != 0 (the inner loop
    # feeds back the actual speed), fractional dead time.
    avll.Proposed(m1=0.3, m2=0.6, m3=1.7, K0=0.8, Td=0.125, K=0.15),
    avll.FirstOrderLag(Td=0.9),
]
# Active on the speed-command test signal (speeds 6-14 m/s, |a| up to ~1 m/s²).
SPEED_ACTIVE = {
    "saturation": Saturation(a_max=0.35, d_max=0.45),
    "power_limit": PowerLimit(p=3.0, v_b=2.0),
    "speed_drag": SpeedDrag(c0=0.05, c2=0.002),
    "road_load": RoadLoad(c0=0.05, c1=0.01, c2=0.002),
    "grade": Grade(g_eff=6.0),
    "sensor": Sensor(tau=0.4, bias=-0.05),
}


def _speed_command(n: int = 1500) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * DT
    u = 10 + 3 * np.sin(0.2 * t) + np.sin(0.9 * t)
    grade = 0.03 * np.sin(0.05 * t + 1.0)
    return u, grade


def _accel_command(n: int = 1200) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * DT
    u = 1.4 * np.sin(0.35 * t) + 0.6 * np.sin(1.3 * t + 0.4) + 0.2
    grade = 0.03 * np.sin(0.05 * t + 1.0)
    return u, grade


def _leader(n: int = 1600) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * DT
    lv = 11.0 + 2.5 * np.sin(0.15 * t) + 0.8 * np.sin(0.6 * t)
    lx = 100.0 + np.concatenate([[0.0], np.cumsum(0.5 * DT * (lv[1:] + lv[:-1]))])
    return lx, lv


# --- item 5: acceleration-level effects on speed-command models -------------------


@pytest.mark.parametrize("name", [*ACCEL_LEVEL, "sensor"])
@pytest.mark.parametrize("base", SPEED_BASES, ids=lambda b: b.name)
@pytest.mark.parametrize("init", ["rest", "steady"])
def test_speed_command_accel_effects_match_reference(name, base, init) -> None:
    u, grade = _speed_command()
    m = WithEffects(base, (SPEED_ACTIVE[name],))
    exo = {"grade": grade}
    got = simulate_full(m, u, DT, command_kind="speed", init=init, x0=3.0, exo=exo)
    ref = rollout_effects(m, DT, command=u, command_kind="speed", init=init, x0=3.0, exo=exo)
    lin = avll.simulate_full(base, u, DT, command_kind="speed", init=init, x0=3.0)
    changed = "a" if name == "sensor" else "v"
    assert np.max(np.abs(getattr(got, changed) - getattr(lin, changed))) > 1e-3, \
        "the effect must act on this signal"
    for k in ("a", "v", "x"):
        np.testing.assert_allclose(getattr(got, k), ref[k], rtol=0, atol=1e-9)


@pytest.mark.parametrize("base", SPEED_BASES[:2], ids=lambda b: b.name)
def test_speed_command_effects_together_match_reference(base) -> None:
    """Braking dynamics switched per interval (asymmetric), a command delay and
    deadband, and every acceleration-level effect plus the sensor on one speed-command
    model."""
    from avll.effects import Asymmetric, Deadband, Delay

    u, grade = _speed_command()
    effs = (Delay(0.17), Deadband(0.2), Asymmetric(1.0, 1.6),
            *(e for n, e in SPEED_ACTIVE.items() if n != "speed_drag"))  # fmt: skip
    m = WithEffects(base, effs)
    exo = {"grade": grade}
    got = simulate_full(m, u, DT, command_kind="speed", init="steady", x0=3.0, exo=exo)
    ref = rollout_effects(m, DT, command=u, command_kind="speed", init="steady", x0=3.0, exo=exo)
    for k in ("a", "v", "x"):
        np.testing.assert_allclose(getattr(got, k), ref[k], rtol=0, atol=1e-9)


@pytest.mark.parametrize("base", SPEED_BASES, ids=lambda b: b.name)
@pytest.mark.parametrize("init", ["rest", "steady"])
def test_speed_command_neutral_effects_equal_base(base, init) -> None:
    u, grade = _speed_command()
    if init == "rest":
        # Ramp the command in: a 10 m/s step from rest would exceed saturation's
        # neutral limits (6 and 10 m/s²), which only tend to the identity.
        u = u * np.clip(np.arange(u.size) * DT / 30.0, 0.0, 1.0)
    neutral = tuple(EFFECTS[n](*EFFECTS[n].neutral) for n in [*ACCEL_LEVEL, "sensor"]
                    if n != "speed_drag")  # fmt: skip
    want = avll.simulate_full(base, u, DT, command_kind="speed", init=init, x0=3.0)
    got = simulate_full(WithEffects(base, neutral), u, DT, command_kind="speed", init=init,
                           x0=3.0, exo={"grade": grade})  # fmt: skip
    for k in ("a", "v", "x"):
        np.testing.assert_allclose(getattr(got, k), getattr(want, k), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("base", [avll.PAPER_TABLE_II["proposed"], avll.PAPER_TABLE_II["first"]],
                         ids=lambda b: b.name)  # fmt: skip
def test_neutral_vehicle_effects_equal_base_closed_loop(base) -> None:
    lx, lv = _leader()
    up = avll.UpperLevel(kg=0.5, kv=0.2, Tg=1.8, Gmin=9.5)
    want = avll.closed_loop(base, lx, lv, DT, up, v0=11.0, x0=lx[0] - 30.0)
    neutral = tuple(EFFECTS[n](*EFFECTS[n].neutral)
                    for n in ("saturation", "road_load", "power_limit", "grade", "sensor"))
    got = closed_loop(WithEffects(base, neutral), lx, lv, DT, up, v0=11.0,
                              x0=lx[0] - 30.0, exo={"grade": np.full(lx.size, 0.02)})
    for k in ("a", "v", "x", "command"):
        np.testing.assert_allclose(getattr(got, k), getattr(want, k), rtol=1e-12, atol=1e-12)


def test_speed_command_saturation_caps_the_speed_slope() -> None:
    """The clip acts on the acceleration that integrates into the speed: the actual
    speed's slope over every interval stays within the limits and the speed lags the
    base. The recorded acceleration is the linear right-limit derivative plus the
    same change (with K = 0 the model's own state is the base's, so the recorded
    acceleration minus the slope is the base's)."""
    base = avll.SecondOrder(K0=1.0, m2=0.8, m3=1.9, Td=0.23)
    u, _ = _speed_command()
    tr = simulate_full(WithEffects(base, (Saturation(0.35, 0.45),)), u, DT,
                          command_kind="speed")  # fmt: skip
    lin = avll.simulate_full(base, u, DT, command_kind="speed")
    slope = np.diff(tr.v) / DT
    assert slope.max() <= 0.35 + 1e-9 and slope.min() >= -0.45 - 1e-9
    assert slope.max() > 0.35 - 1e-9 and slope.min() < -0.45 + 1e-9, "both limits bind"
    np.testing.assert_allclose(tr.a[:-1] - slope, lin.a[:-1] - np.diff(lin.v) / DT,
                               rtol=0, atol=1e-9)  # fmt: skip
    assert np.max(np.abs(tr.v - lin.v)) > 0.1


def test_speed_command_grade_in_batch_cost() -> None:
    """A speed-command run set can be offered grade: the batched cost equals the
    simulated trajectory's errors."""
    base = avll.SecondOrder(K0=1.0, m2=0.8, m3=1.9, Td=0.23)
    m = WithEffects(base, (Grade(4.0),))
    runs = []
    for j in range(2):
        u, grade = _speed_command(900 + 100 * j)
        t = np.arange(u.size) * DT
        tr = simulate_full(m, u, DT, command_kind="speed", x0=0.0, exo={"grade": grade})
        runs.append(avll.Run(run_id=str(j), t=t, a=tr.a + 0.01 * np.sin(5 * t), command=u,
                             v=tr.v, x=tr.x, exo={"grade": grade},
                             command_kind="speed"))  # fmt: skip
    rows = np.vstack([m.to_array(), WithEffects(base, (Grade(0.0),)).to_array()])
    c = batch_cost("second", rows, runs, effects=["grade"], weights=(1.0, 1.0, 0.0), threads=1)
    for j, r in enumerate(runs):
        for i, g in enumerate((4.0, 0.0)):
            tr = simulate_full(WithEffects(base, (Grade(g),)), r.command, DT,
                                  command_kind="speed", x0=r.x[0], exo=r.exo)  # fmt: skip
            want = np.mean((tr.a - r.a) ** 2) + np.mean((tr.v - r.v) ** 2)
            assert c[i, j] == pytest.approx(want, rel=1e-12)
    assert np.all(c[0] < c[1])


# --- road_load ---------------------------------------------------------------------


def test_road_load_without_linear_term_is_speed_drag_and_differs_with_it() -> None:
    base = avll.PAPER_TABLE_II["proposed"]
    u, _ = _accel_command()
    rl = simulate_full(WithEffects(base, (RoadLoad(0.08, 0.0, 0.001),)), u, DT, v0=8.0)
    sd = simulate_full(WithEffects(base, (SpeedDrag(0.08, 0.001),)), u, DT, v0=8.0)
    for k in ("a", "v", "x"):
        np.testing.assert_allclose(getattr(rl, k), getattr(sd, k), rtol=0, atol=1e-12)
    rl1 = simulate_full(WithEffects(base, (RoadLoad(0.08, 0.02, 0.001),)), u, DT, v0=8.0)
    assert np.max(np.abs(rl1.v - sd.v)) > 0.5
    with pytest.raises(ValueError, match="not identifiable"):
        WithEffects(base, (RoadLoad(), SpeedDrag()))
    with pytest.raises(ValueError, match="not identifiable"):
        _core.simulate_full("proposed", list(base.to_array()), u, DT, "acceleration", "rest",
                            0.0, 0.0, effects=["road_load", "speed_drag"],
                            effect_params=[0.0] * 5)  # fmt: skip


def test_road_load_is_the_polynomial_on_the_actual_acceleration() -> None:
    """With a unit-gain instantaneous-free lag at rest command (u = 0) the lower level
    stays at 0, so the acceleration is exactly the road load of the recorded speed."""
    base = avll.FirstOrderLag(Td=0.5)
    u = np.zeros(400)
    e = RoadLoad(c0=0.1, c1=0.02, c2=0.0015)
    tr = simulate_full(WithEffects(base, (e,)), u, DT, v0=20.0)
    v = tr.v
    want = -(e.c0 * np.clip(v / 0.1, -1, 1) + e.c1 * v + e.c2 * v * np.abs(v))
    np.testing.assert_allclose(tr.a, want, rtol=0, atol=1e-12)
    assert tr.v[-1] < 20.0 - 0.5 * 400 * DT * 0.1  # decelerates (coast-down)


# --- power_limit -------------------------------------------------------------------


def test_power_limit_caps_positive_acceleration_by_speed() -> None:
    """With K = 0 the lower level's own response is the base's, so the actual
    acceleration is exactly ``min(a_lin, p / max(v, v_b))`` at the actual speed."""
    base = avll.PAPER_TABLE_II["second"]  # no inner feedback (K = 0)
    u, _ = _accel_command()
    u = 1.5 * u + 1.0
    e = PowerLimit(p=6.0, v_b=3.0)
    tr = simulate_full(WithEffects(base, (e,)), u, DT, v0=0.0)
    lin = avll.simulate_full(base, u, DT, v0=0.0)
    cap = e.p / np.maximum(np.abs(tr.v), e.v_b)
    np.testing.assert_allclose(tr.a, np.minimum(lin.a, cap), rtol=0, atol=1e-12)
    bind = lin.a > cap
    # It binds both below the base speed (the constant torque limit p / v_b) and
    # above it (the power hyperbola p / v); braking passes unchanged.
    assert np.any(bind & (tr.v < e.v_b)) and np.any(bind & (tr.v > 2 * e.v_b))
    assert tr.a.min() < -0.5


# --- sensor ------------------------------------------------------------------------


def _filtered(a: np.ndarray, tau: float, bias: float, dt: float) -> np.ndarray:
    """The observation from its definition: the exact solution of ``tau f' = a - f``
    with ``a`` held at ``a[n]`` over ``(t[n-1], t[n]]``, ``f(t[-1]) = a[0]``, written
    with ``expm`` of the scalar system (no lfilter, no recursion coefficients)."""
    if tau == 0:
        return a + bias
    f = np.empty_like(a)
    prev = a[0]
    m = np.array([[-dt / tau, dt / tau], [0.0, 0.0]])
    e = expm(m)
    for n, an in enumerate(a):
        prev = e[0, 0] * prev + e[0, 1] * an
        f[n] = prev
    return f + bias


@pytest.mark.parametrize("tau", [0.0, 0.05, 0.3])
def test_sensor_changes_only_the_observation_open_loop(tau) -> None:
    base = avll.PAPER_TABLE_II["proposed"]
    u, _ = _accel_command()
    lin = avll.simulate_full(base, u, DT, v0=8.0, x0=1.0)
    tr = simulate_full(WithEffects(base, (Sensor(tau=tau, bias=0.07),)), u, DT, v0=8.0, x0=1.0)
    np.testing.assert_array_equal(tr.v, lin.v)
    np.testing.assert_array_equal(tr.x, lin.x)
    np.testing.assert_allclose(tr.a, _filtered(lin.a, tau, 0.07, DT), rtol=0, atol=1e-12)


def test_sensor_does_not_enter_the_feedback_closed_loop() -> None:
    """Closed loop with the inner loop's K != 0: the commands, speeds and positions
    are the base model's; only the recorded acceleration is filtered and offset."""
    base = avll.PAPER_TABLE_II["proposed"]
    assert base.K != 0
    lx, lv = _leader()
    up = avll.UpperLevel(kg=0.5, kv=0.2, Tg=1.8, Gmin=9.5)
    want = avll.closed_loop(base, lx, lv, DT, up, v0=11.0, x0=lx[0] - 30.0)
    got = closed_loop(WithEffects(base, (Sensor(0.25, -0.1),)), lx, lv, DT, up,
                              v0=11.0, x0=lx[0] - 30.0)  # fmt: skip
    for k in ("v", "x", "command"):
        np.testing.assert_array_equal(getattr(got, k), getattr(want, k))
    np.testing.assert_allclose(got.a, _filtered(want.a, 0.25, -0.1, DT), rtol=0, atol=1e-12)


def test_sensor_cost_compares_the_observation() -> None:
    base = avll.PAPER_TABLE_II["second"]
    truth = WithEffects(base, (Sensor(0.3, 0.08),))
    runs = []
    for j in range(2):
        u, _ = _accel_command(700 + 50 * j)
        t = np.arange(u.size) * DT
        tr = simulate_full(truth, u, DT, v0=5.0)
        runs.append(avll.Run(run_id=str(j), t=t, a=tr.a, command=u, v=tr.v, x=tr.x))
    rows = np.vstack([truth.to_array(), WithEffects(base, (Sensor(),)).to_array()])
    for w in ((1.0, 0.0, 0.0), (1.0, 0.3, 0.1)):
        c = batch_cost("second", rows, runs, effects=["sensor"], weights=w, threads=1)
        assert np.all(c[0] < 1e-24), "the true observation model fits exactly"
        plain = avll.simulate_full(base, runs[0].command, DT, v0=5.0).a
        assert c[1, 0] == pytest.approx(w[0] * np.mean((plain - runs[0].a) ** 2), rel=1e-10)


# --- linearisations ----------------------------------------------------------------


def test_linearisations_of_the_new_effects() -> None:
    sec = avll.PAPER_TABLE_II["second"]
    base_lin = WithEffects(sec).linear()
    # power_limit and sensor are the identity in the small signal.
    assert WithEffects(sec, (PowerLimit(20.0, 5.0), Sensor(0.3, 0.1))).linear(v=15.0) == \
        pytest.approx(base_lin)
    # road_load: the speed feedback beta = c1 + 2 c2 v, outside a Linear.
    rl = WithEffects(sec, (RoadLoad(0.1, 0.01, 0.001),))
    with pytest.raises(ValueError, match="road_load"):
        rl.linear(v=12.0)
    assert WithEffects(sec, (RoadLoad(0.1, 0.0, 0.0),)).linear(v=12.0) == pytest.approx(base_lin)
    t = rl.linear(v=12.0, terms=True)
    assert t["speed_feedback"] == pytest.approx(0.01 + 2 * 0.001 * 12.0)
    assert {k: t[k] for k in base_lin} == pytest.approx(base_lin)
    t = WithEffects(sec, (SpeedDrag(0.1, 0.002), Sensor(0.3, 0.1))).linear(v=10.0, terms=True)
    assert t["speed_feedback"] == pytest.approx(0.04)
    assert (t["obs_tau"], t["obs_bias"]) == pytest.approx((0.3, 0.1))
    assert "speed_feedback" not in WithEffects(sec).linear()


def test_road_load_speed_feedback_is_its_small_signal() -> None:
    """Around cruising at v*, the road load's effect on a small acceleration
    perturbation is that of the speed feedback -beta dv (same response to 1 %)."""
    base = avll.FirstOrderLag(Td=0.4)
    e = RoadLoad(c0=0.1, c1=0.02, c2=0.001)
    vstar = 15.0
    a_hold = e.c0 + e.c1 * vstar + e.c2 * vstar**2  # command that holds v*
    n = 2000
    t = np.arange(n) * DT
    du = 0.02 * np.sin(0.4 * t)
    tr = simulate_full(WithEffects(base, (e,)), a_hold + du, DT, init="steady", v0=vstar)
    beta = WithEffects(base, (e,)).linear(v=vstar, terms=True)["speed_feedback"]
    # The linearised loop: a = lag(u) - a_hold - beta (v - v*), the lag stepped
    # exactly (no dead time), the speed deviation by the held acceleration.
    y = a_hold
    dv = 0.0
    a_lin = np.empty(n)
    phi = np.exp(-DT / base.Td)
    for k in range(n):
        a_lin[k] = y - a_hold - beta * dv
        dv += DT * a_lin[k]
        y = phi * y + (1 - phi) * (a_hold + du[k])
    resp = tr.a
    scale = np.max(np.abs(resp[200:]))
    assert scale > 5e-3
    assert np.max(np.abs(resp[200:] - a_lin[200:])) < 0.01 * scale


# --- validation --------------------------------------------------------------------


@pytest.mark.parametrize(
    "make, arg",
    [
        (lambda: RoadLoad(c0=-0.1), "road_load.c0"),
        (lambda: RoadLoad(c1=-1e-3), "road_load.c1"),
        (lambda: RoadLoad(c2=float("nan")), "road_load.c2"),
        (lambda: PowerLimit(p=0.0), "power_limit.p"),
        (lambda: PowerLimit(v_b=-1.0), "power_limit.v_b"),
        (lambda: Sensor(tau=-0.1), "sensor.tau"),
        (lambda: Sensor(bias=float("inf")), "sensor.bias"),
    ],
)
def test_bad_parameters_name_the_argument(make, arg) -> None:
    with pytest.raises(ValueError, match=arg.replace(".", r"\.")):
        make()


@pytest.mark.parametrize(
    "name, params, arg",
    [
        ("road_load", [0.1, -0.01, 0.0], "road_load.c1"),
        ("power_limit", [-5.0, 1.0], "power_limit.p"),
        ("power_limit", [5.0, 0.0], "power_limit.v_b"),
        ("sensor", [-0.2, 0.0], "sensor.tau"),
        ("sensor", [0.2, 1e3], "sensor.bias"),
    ],
)
def test_rust_validation_names_the_argument(name, params, arg) -> None:
    base = avll.PAPER_TABLE_II["second"]
    with pytest.raises(ValueError, match=arg.replace(".", r"\.")):
        _core.simulate_full("second", list(base.to_array()), np.zeros(10), DT, "acceleration",
                            "rest", 0.0, 0.0, effects=[name], effect_params=params)  # fmt: skip


def test_invalid_rows_cost_inf() -> None:
    base = avll.PAPER_TABLE_II["second"]
    u, _ = _accel_command(300)
    t = np.arange(u.size) * DT
    tr = avll.simulate_full(base, u, DT)
    runs = [avll.Run(run_id="0", t=t, a=tr.a, command=u, v=tr.v, x=tr.x)]
    good = np.concatenate([base.to_array(), [0.1, 0.01, 0.001]])
    bad = good.copy()
    bad[-2] = -0.01
    c = batch_cost("second", np.vstack([good, bad]), runs, effects=["road_load"])
    assert np.isfinite(c[0, 0]) and np.isinf(c[1, 0])
