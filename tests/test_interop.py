"""to_scipy() / to_control() against avll's own responses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

import avll
from avll.models import pade


def test_pade_order_2_is_paper_eq_10() -> None:
    num, den = pade(0.8, 2)
    p1, p2 = 0.5, 1 / 12
    np.testing.assert_allclose(den, [p2 * 0.8**2, p1 * 0.8, 1.0])
    np.testing.assert_allclose(num, [p2 * 0.8**2, -p1 * 0.8, 1.0])


def test_pade_converges_to_delay() -> None:
    w = 1.3
    for order, tol in ((2, 1e-2), (4, 1e-6)):
        num, den = pade(0.79, order)
        h = np.polyval(num, 1j * w) / np.polyval(den, 1j * w)
        assert abs(h - np.exp(-1j * w * 0.79)) < tol


@pytest.mark.parametrize(
    "model",
    [
        avll.FirstOrderLag(Td=0.7),
        avll.SecondOrder(K0=0.9, m2=0.3, m3=0.9, Td=0.0),
        avll.Proposed(m1=0.6, m2=1.2, m3=2.5, K0=0.8, Td=0.0, K=0.0),
    ],
)
def test_to_scipy_zoh_equals_simulate_without_delay(model: avll.LowerLevelModel) -> None:
    dt = 0.05
    u = np.random.default_rng(0).normal(size=400)
    num, den = model.to_scipy().num, model.to_scipy().den
    dsys = signal.cont2discrete(signal.tf2ss(num, den), dt, method="zoh")
    _, y, _ = signal.dlsim(dsys, u)
    np.testing.assert_allclose(avll.simulate(model, u, dt), y.ravel(), atol=1e-10)


def test_sampled_inner_feedback_converges_to_continuous_g_fb() -> None:
    # avll samples and holds the inner feedback K y[n] (the convention), while G_fb
    # feeds back continuously: the two agree to O(dt).
    m = avll.Proposed(m1=0.6, m2=1.2, m3=2.5, K0=0.8, Td=0.0, K=0.15)
    errs = []
    for dt in (0.02, 0.01, 0.005):
        t = np.arange(0, 30, dt)
        u = np.sin(0.5 * t)
        dsys = signal.cont2discrete(signal.tf2ss(*m.transfer_function()), dt, method="zoh")
        _, y, _ = signal.dlsim(dsys, u)
        errs.append(np.max(np.abs(avll.simulate(m, u, dt) - y.ravel())))
    assert errs[0] < 0.01
    assert 1.7 < errs[0] / errs[1] < 2.3 and 1.7 < errs[1] / errs[2] < 2.3  # first order in dt


def test_to_scipy_with_pade_approximates_delayed_response() -> None:
    m = avll.PAPER_TABLE_II["proposed"]
    dt = 0.01
    t = np.arange(0, 40, dt)
    u = np.sin(0.4 * t)
    _, y, _ = signal.lsim(m.to_scipy(pade_order=5), u, t)
    ours = avll.simulate(m, u, dt)
    assert np.max(np.abs(y - ours)) < 0.02 * np.max(np.abs(ours))


def test_to_control_matches_scipy() -> None:
    control = pytest.importorskip("control")
    m = avll.PAPER_TABLE_II["second"]
    sys = m.to_control(pade_order=3)
    w = np.array([0.1, 1.0, 3.0])
    ref = m.to_scipy(pade_order=3)
    _, h = signal.freqresp(ref, w)
    np.testing.assert_allclose(control.evalfr(sys, 1j * w[1]), h[1], rtol=1e-12)


def test_pade_rejects_bad_order() -> None:
    with pytest.raises(ValueError, match="pade_order"):
        pade(0.5, -1)
