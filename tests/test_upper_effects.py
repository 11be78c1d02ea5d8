"""The upper-level structures of the effect registry (perception, speed_gains, closing,
feedforward, comfort): the Rust engine against the numpy reference
(:mod:`avll.reference.effects`) in the closed loop, the platoon and the batched cost,
the follower's frequency response against its oracle and the time domain, and where
they are refused."""

from __future__ import annotations

import numpy as np
import pytest

import avll
from avll.effect_stability import frequency_response
from avll.effects import (
    EFFECTS,
    Closing,
    Comfort,
    Feedforward,
    Perception,
    RateLimit,
    Saturation,
    SpeedGains,
    WithEffects,
)
from avll.reference import effects as ref

DT = 0.05
BASE = avll.PAPER_TABLE_II["proposed"]
UP = avll.UpperLevel(kg=0.2, kv=0.4, Tg=1.5, Gmin=3.0)
#: Parameters at which each structure acts on the test leader.
ACTIVE = {
    "perception": Perception(0.43),
    "speed_gains": SpeedGains(0.012, 0.02),
    "closing": Closing(1.6, 2.2),
    "feedforward": Feedforward(0.7, 0.6),
    "comfort": Comfort(0.6, 0.9, 1.5),
}
UPPER = [n for n in EFFECTS if EFFECTS[n].level == "upper"]


def _leader(n: int = 2400, v: float = 14.0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * DT
    lv = v + 2.0 * np.sin(0.15 * t) + 0.7 * np.sin(0.55 * t + 0.3)
    lx = 150.0 + np.concatenate([[0.0], np.cumsum(0.5 * DT * (lv[1:] + lv[:-1]))])
    return lx, lv


def test_the_registry_has_the_upper_level() -> None:
    assert set(UPPER) == set(ACTIVE)
    for n in UPPER:
        cls = EFFECTS[n]
        assert cls.level == "upper" and cls() == cls(*cls.neutral)
    assert EFFECTS["delay"].level == "lower"
    assert EFFECTS["comfort"].excludes == "rate_limit"
    assert EFFECTS["rate_limit"].excludes == "comfort"
    m = WithEffects(BASE, (Saturation(2.0, 3.0), Perception(0.2), Closing(1.2, 1.3)))
    assert [e.name for e in m.lower] == ["saturation"]
    assert [e.name for e in m.upper] == ["perception", "closing"]


@pytest.mark.parametrize("name", UPPER)
def test_each_structure_matches_the_reference_closed_loop(name: str) -> None:
    lx, lv = _leader()
    m = WithEffects(BASE, (ACTIVE[name],))
    x0 = lx[0] - 25.0
    got = avll.closed_loop(m, lx, lv, DT, UP, v0=float(lv[0]), x0=x0)
    want = ref.rollout_effects(m, DT, lead_x=lx, lead_v=lv, upper=UP, v0=float(lv[0]), x0=x0)
    plain = avll.closed_loop(BASE, lx, lv, DT, UP, v0=float(lv[0]), x0=x0)
    assert np.max(np.abs(got.v - plain.v)) > 1e-2, "the structure must act on this leader"
    for k in ("a", "v", "x", "command"):
        np.testing.assert_allclose(getattr(got, k), want[k], rtol=0, atol=1e-9)


def test_both_levels_together_match_the_reference_closed_loop_and_platoon() -> None:
    lx, lv = _leader()
    grade = 0.02 * np.sin(np.arange(lx.size) * DT * 0.07)
    lower = (avll.Delay(0.2), avll.Deadband(0.05), avll.Asymmetric(0.8, 1.3),
             Saturation(1.5, 2.0), avll.RoadLoad(0.05, 0.005, 0.0004), avll.Grade(4.0),
             avll.Sensor(0.2, 0.05))  # fmt: skip
    m = WithEffects(BASE, (*lower, *ACTIVE.values()))
    got = avll.closed_loop(m, lx, lv, DT, UP, v0=float(lv[0]), x0=lx[0] - 28.0,
                           exo={"grade": grade})  # fmt: skip
    want = ref.rollout_effects(m, DT, lead_x=lx, lead_v=lv, upper=UP, v0=float(lv[0]),
                               x0=lx[0] - 28.0, exo={"grade": grade})  # fmt: skip
    for k in ("a", "v", "x", "command"):
        np.testing.assert_allclose(getattr(got, k), want[k], rtol=0, atol=1e-9)
    # the platoon (time-major in Rust) against the reference car by car
    pl = avll.platoon(m, lx[:1200], lv[:1200], DT, UP, 4, exo={"grade": grade[:1200]})
    pw = ref.platoon_effects(m, lx[:1200], lv[:1200], DT, UP, 4, exo={"grade": grade[:1200]})
    for k in ("a", "v", "x", "command"):
        np.testing.assert_allclose(getattr(pl, k), pw[k], rtol=0, atol=1e-8)


def test_platoon_starts_at_the_desired_gap_of_the_structures() -> None:
    lx, lv = _leader(600)
    lv = np.full_like(lv, lv[0])
    lx = lx[0] + lv[0] * np.arange(lv.size) * DT
    m = WithEffects(BASE, (SpeedGains(0.02, 0.0),))
    pl = avll.platoon(m, lx, lv, DT, UP, 3)
    # at a constant speed the platoon stays at its equilibrium: Gmin + (Tg + ch v) v
    gap = UP.Gmin + (UP.Tg + 0.02 * lv[0]) * lv[0]
    np.testing.assert_allclose(lx - pl.x[0], gap, atol=1e-9)
    np.testing.assert_allclose(pl.v, lv[0], atol=1e-9)
    assert m.upper_linear(UP, v=lv[0])["Tg_eq"] == pytest.approx(UP.Tg + 0.02 * lv[0])


def test_batch_cost_with_structures_equals_the_rollouts_error() -> None:
    lx, lv = _leader(1500)
    truth = WithEffects(BASE, (ACTIVE["perception"], ACTIVE["closing"]))
    tr = avll.closed_loop(truth, lx, lv, DT, UP, v0=float(lv[0]), x0=lx[0] - 25.0)
    rng = np.random.default_rng(3)
    run = avll.Run("r0", np.arange(lx.size) * DT, a=tr.a + rng.normal(0, 0.05, lx.size),
                   v=tr.v, x=tr.x, lead_x=lx, lead_v=lv, upper=UP)  # fmt: skip
    other = WithEffects(BASE, (Perception(0.1), Closing(1.0, 1.0)))
    rows = np.array([truth.to_array(), other.to_array()])
    c = avll.batch_cost(truth, rows, [run], closed_loop=True, weights=(1.0, 0.5, 0.1))
    for row, cost in zip(rows, c[:, 0], strict=True):
        m = WithEffects.from_array("proposed", truth.effect_names, row)
        s = avll.closed_loop(m, lx, lv, DT, UP, v0=float(tr.v[0]), x0=float(tr.x[0]))
        want = (np.mean((s.a - run.a) ** 2) + 0.5 * np.mean((s.v - tr.v) ** 2)
                + 0.1 * np.mean((s.x - tr.x) ** 2))  # fmt: skip
        assert cost == pytest.approx(want, rel=1e-9)
    assert c[0, 0] < c[1, 0]
    sims = avll.simulate_batch(truth, rows, [run], closed_loop=True)
    np.testing.assert_allclose(sims.a[0][0], tr.a, atol=1e-12)


def test_structures_need_a_closed_loop() -> None:
    u = np.sin(np.arange(200) * DT)
    m = WithEffects(BASE, (Perception(0.3),))
    with pytest.raises(ValueError, match="effects: .*perception.* closed loop"):
        avll.simulate_full(m, u, DT)
    with pytest.raises(ValueError, match="closed loop"):
        avll.simulate(m, u, DT)
    run = avll.Run("r", np.arange(200) * DT, a=u, command=u)
    with pytest.raises(ValueError, match="closed loop"):
        avll.batch_cost(m, m.to_array(), [run])
    with pytest.raises(ValueError, match="closed loop"):
        avll.calibrate(m, [run], max_generations=2)
    with pytest.raises(ValueError, match="not identifiable"):
        WithEffects(BASE, (Comfort(), RateLimit()))


@pytest.mark.parametrize("v", [0.05, 8.0, 25.0])
def test_frequency_response_matches_its_oracle(v: float) -> None:
    w = np.geomspace(0.02, 5.0, 40)
    lower = (avll.Delay(0.25), avll.RoadLoad(0.1, 0.01, 0.0004), avll.Asymmetric(0.8, 1.3),
             avll.Sensor(0.3, 0.1))  # fmt: skip
    for effs in [(), *((e,) for e in ACTIVE.values()), tuple(ACTIVE.values()),
                 (*lower, *ACTIVE.values())]:  # fmt: skip
        m = WithEffects(BASE, effs)
        np.testing.assert_allclose(frequency_response(m, UP, w, v=v),
                                   ref.frequency_response(m, UP, w, v=v), rtol=1e-11,
                                   err_msg=m.name)  # fmt: skip
    # without effects: Eq. 8 (the function the OpenACC study's transfer_gain reads)
    from avll.studies.openacc import transfer_gain

    np.testing.assert_allclose(transfer_gain(BASE, UP, w / (2 * np.pi)),
                               np.abs(ref.frequency_response(BASE, UP, w)), rtol=1e-12)


@pytest.mark.parametrize("name", UPPER)
def test_small_signal_form_is_the_simulated_amplification(name: str) -> None:
    """A small oscillation through a platoon of three: each car's steady amplitude ratio
    is |H| of the small-signal form at the operating speed (to the O(dt) error of
    evaluating the law at the samples, which the base model has too)."""
    f, v0, dt = 0.04, 15.0, 0.02
    t = np.arange(int(400 / dt)) * dt
    ramp = np.where(t < 25, 0.5 * (1 - np.cos(np.pi * t / 25)), 1.0)
    lv = v0 + 0.03 * ramp * np.sin(2 * np.pi * f * t)
    lx = 100 + np.concatenate([[0.0], np.cumsum(0.5 * dt * (lv[1:] + lv[:-1]))])
    m = WithEffects(BASE, (ACTIVE[name],))
    pl = avll.platoon(m, lx, lv, dt, UP, 3)
    keep = t > 150
    x = np.column_stack([np.ones(keep.sum()), np.sin(2 * np.pi * f * t[keep]),
                         np.cos(2 * np.pi * f * t[keep])])  # fmt: skip

    def amp(y: np.ndarray) -> float:
        c = np.linalg.lstsq(x, y[keep], rcond=None)[0]
        return float(np.hypot(c[1], c[2]))

    ratios = [amp(pl.v[0]) / amp(lv)] + [amp(pl.v[k]) / amp(pl.v[k - 1]) for k in (1, 2)]
    h = abs(frequency_response(m, UP, [2 * np.pi * f], v=v0)[0])
    if name == "closing":
        # The average slope is the describing function of a sinusoid: exact for the
        # first car; the cars behind it see the first car's distorted oscillation
        # (harmonics), and their fundamental's ratio drifts from it (2 % here).
        np.testing.assert_allclose(ratios[0], h, rtol=3e-3)
        np.testing.assert_allclose(ratios, h, rtol=3e-2)
    else:
        np.testing.assert_allclose(ratios, h, rtol=3e-3)


def test_diagnosis_offers_structures_only_in_closed_loop() -> None:
    from avll.diagnose.signatures import offered

    lx, lv = _leader(300)
    run = avll.Run("r", np.arange(300) * DT, a=np.zeros(300), command=np.zeros(300),
                   v=lv, x=lx - 20, lead_x=lx, lead_v=lv, upper=UP)  # fmt: skip
    model = WithEffects(BASE, (RateLimit(5.0),))
    open_ = offered(model, [run])
    closed = offered(model, [run], closed=True)
    assert not set(UPPER) & set(open_)
    assert set(UPPER) - {"comfort"} <= set(closed)
    assert "comfort" not in closed  # refused with the model's rate_limit
