"""The reference rollouts (and the Rust core) against closed forms and scipy.signal.

Each oracle here is independent of both implementations: analytic step responses
(partial fractions of the continuous transfer function), the first-order lag's
closed-form recursion, and scipy.signal's own ZOH discretization / simulation.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

import avll
from avll.reference import rollout as ref


def relerr(got: np.ndarray, want: np.ndarray) -> float:
    """Max-norm relative error."""
    got, want = np.asarray(got), np.asarray(want)
    scale = max(float(np.max(np.abs(want))), 1e-300)
    return float(np.max(np.abs(got - want))) / scale


def step_response(n1: float, n0: float, m2: float, m3: float, t: np.ndarray) -> np.ndarray:
    """Unit step response of ``(n1 s + n0) / (m2 s^2 + m3 s + 1)`` (distinct poles) by
    partial fractions: ``Y(s) = n0/s + sum_k c_k / (s - p_k)``."""
    p1, p2 = np.roots([m2, m3, 1.0]).astype(complex)
    out = np.full(t.shape, n0, dtype=complex)
    for pk, pj in ((p1, p2), (p2, p1)):
        ck = (n1 * pk + n0) / (m2 * pk * (pk - pj))
        out += ck * np.exp(pk * t)
    return np.where(t >= 0, out.real, 0.0)


def rational(model: avll.LowerLevelModel) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator (highest power first) of the rational part G,
    ``(b1 s + b0) / (a2 s^2 + a1 s + 1)``, without dead time and inner feedback."""
    c = model.linear()
    num = np.trim_zeros(np.array([c["b1"], c["b0"]]), "f")
    den = np.trim_zeros(np.array([c["a2"], c["a1"], 1.0]), "f")
    return num, den


DT = 0.05
N = 200
T = np.arange(N) * DT


# ---------------------------------------------------------------- analytic steps


@pytest.mark.parametrize("tau", [0.05, 0.4, 1.0758, 3.0])
def test_first_order_lag_step_is_closed_form(tau: float) -> None:
    want = 1.0 - np.exp(-T / tau)
    m = avll.FirstOrderLag(tau)
    u = np.ones(N)
    assert relerr(ref.simulate(m, u, DT), want) < 1e-12
    assert relerr(ref.first_order_lag_recursion(tau, u, DT), want) < 1e-12
    assert relerr(avll.simulate(m, u, DT), want) < 1e-12


def test_first_order_recursion_matches_reference_on_random_input() -> None:
    rng = np.random.default_rng(3)
    u = rng.normal(size=N)
    for init in ("rest", "steady"):
        want = ref.first_order_lag_recursion(0.37, u, DT, init=init)
        assert relerr(ref.simulate(avll.FirstOrderLag(0.37), u, DT, init=init), want) < 1e-12


@pytest.mark.parametrize(
    "Td",
    [0.0, 0.05, 0.15, 0.7796, 0.7903, 0.0123, 1.23456],
    ids=lambda x: f"Td={x}",
)
@pytest.mark.parametrize(
    "m2,m3", [(0.0445, 0.1305), (1.2824, 8.8157), (0.3, 0.2)], ids=["paper2", "paper3", "under"]
)
def test_second_order_delayed_step_is_closed_form(Td: float, m2: float, m3: float) -> None:
    """The exact hold of a delayed step: y(t_n) = s(t_n - Td), integer or fractional Td."""
    K0 = 0.7292
    want = step_response(0.0, K0, m2, m3, T - Td)
    m = avll.SecondOrder(K0=K0, m2=m2, m3=m3, Td=Td)
    u = np.ones(N)
    assert relerr(ref.simulate(m, u, DT), want) < 1e-10
    assert relerr(avll.simulate(m, u, DT), want) < 1e-10


@pytest.mark.parametrize("Td", [0.0, 0.1, 0.7903], ids=lambda x: f"Td={x}")
def test_proposed_without_feedback_step_has_the_zero(Td: float) -> None:
    m1, m2, m3, K0 = 6.7893, 1.2824, 8.8157, 0.3479
    want = step_response(m1, K0, m2, m3, T - Td)
    m = avll.Proposed(m1=m1, m2=m2, m3=m3, K0=K0, Td=Td, K=0.0)
    assert relerr(ref.simulate(m, np.ones(N), DT), want) < 1e-10
    assert relerr(avll.simulate(m, np.ones(N), DT), want) < 1e-10


def test_speed_response_derivative_of_step_is_impulse_response() -> None:
    """For a speed command the acceleration is dv/dt(t_n+): for a step at rest with
    Td = 0 that is the impulse response g(t_n) (right limit), here for the zero
    ``m1 s + K0``: g(0+) = m1/m2."""
    m1, m2, m3, K0 = 0.8, 0.5, 1.1, 0.9
    p1, p2 = np.roots([m2, m3, 1.0]).astype(complex)
    g = sum(
        (m1 * pk + K0) / (m2 * (pk - pj)) * np.exp(pk * T) for pk, pj in ((p1, p2), (p2, p1))
    ).real
    m = avll.Proposed(m1=m1, m2=m2, m3=m3, K0=K0, Td=0.0, K=0.0)
    for tr in (
        ref.simulate_full(m, np.ones(N), DT, command_kind="speed"),
        avll.simulate_full(m, np.ones(N), DT, command_kind="speed").__dict__,
    ):
        assert relerr(tr["a"], g) < 1e-10
        assert tr["a"][0] == pytest.approx(m1 / m2, rel=1e-12)
        assert relerr(tr["v"], step_response(m1, K0, m2, m3, T)) < 1e-10


def test_integrators_are_exact_for_a_step() -> None:
    """v and x are the exact integrals of the response: for the lag with unit step,
    v(t) = t - tau (1 - e^{-t/tau}), x(t) = t^2/2 - tau t + tau^2 (1 - e^{-t/tau})."""
    tau, v0, x0 = 0.6, 1.5, -2.0
    tr = ref.open_loop_acceleration(avll.FirstOrderLag(tau), np.ones(N), DT, v0=v0, x0=x0)
    e = 1.0 - np.exp(-T / tau)
    assert relerr(tr["v"], v0 + T - tau * e) < 1e-12
    assert relerr(tr["x"], x0 + v0 * T + T**2 / 2 - tau * T + tau**2 * e) < 1e-12


def test_step_formula_sanity() -> None:
    # The partial-fraction oracle itself: s(0) = 0, s(inf) = K0, s(t < 0) = 0.
    s = step_response(0.2, 0.7, 0.5, 0.3, np.array([-1.0, 0.0, 200.0]))
    assert s[0] == 0.0 and abs(s[1]) < 1e-12 and s[2] == pytest.approx(0.7, rel=1e-9)


# ---------------------------------------------------------------- scipy.signal


MODELS_NO_DELAY = [
    avll.FirstOrderLag(1.0758),
    avll.SecondOrder(K0=0.7292, m2=0.0445, m3=0.1305, Td=0.0),
    avll.Proposed(m1=6.7893, m2=1.2824, m3=8.8157, K0=0.3479, Td=0.0, K=0.0),
]


@pytest.mark.parametrize("model", MODELS_NO_DELAY, ids=lambda m: m.name)
def test_no_delay_matches_scipy_zoh_lfilter_and_lsim(model: avll.LowerLevelModel) -> None:
    rng = np.random.default_rng(11)
    u = rng.normal(size=N)
    num, den = rational(model)
    bd, ad, _ = scipy.signal.cont2discrete((num, den), DT, method="zoh")
    want = scipy.signal.lfilter(bd.ravel(), ad, u)
    _, want_lsim, _ = scipy.signal.lsim((num, den), u, T, interp=False)
    assert relerr(want_lsim, want) < 1e-9  # the two scipy paths agree
    assert relerr(ref.simulate(model, u, DT), want) < 1e-9
    assert relerr(avll.simulate(model, u, DT), want) < 1e-9


@pytest.mark.parametrize("i", [1, 3, 16])
@pytest.mark.parametrize("K", [0.0, 0.1008, -0.4])
def test_integer_delay_and_feedback_match_lfilter(i: int, K: float) -> None:
    """Integer delay i dt, inner loop closed at the samples:
    Y = z^-i Gd (U + K Y)  =>  lfilter(z^-i B, A - K z^-i B)."""
    m = avll.Proposed(m1=6.7893, m2=1.2824, m3=8.8157, K0=0.3479, Td=i * DT, K=K)
    num, den = rational(m)
    bd, ad, _ = scipy.signal.cont2discrete((num, den), DT, method="zoh")
    b = np.concatenate([np.zeros(i), bd.ravel()])
    a = np.concatenate([ad, np.zeros(i)]) - K * b
    rng = np.random.default_rng(i)
    u = rng.normal(size=N)
    want = scipy.signal.lfilter(b, a, u)
    assert relerr(ref.simulate(m, u, DT), want) < 1e-9
    assert relerr(avll.simulate(m, u, DT), want) < 1e-9
    # steady start: the filter state of u[0] held forever
    want_ss, _ = scipy.signal.lfilter(b, a, u, zi=scipy.signal.lfilter_zi(b, a) * u[0])
    assert relerr(ref.simulate(m, u, DT, init="steady"), want_ss) < 1e-9
    assert relerr(avll.simulate(m, u, DT, init="steady"), want_ss) < 1e-9


def test_fractional_delay_transfer_function_matches_step_loop() -> None:
    """The modified-z transfer function (used by the benchmark) and the step loop agree."""
    rng = np.random.default_rng(5)
    u = rng.normal(size=N)
    for m in (
        avll.PAPER_TABLE_II["proposed"],
        avll.PAPER_TABLE_II["second"],
        avll.Proposed(m1=0.5, m2=0.3, m3=0.9, K0=1.2, Td=0.0371, K=-0.3),
    ):
        b, a = ref.discrete_transfer_function(m, DT)
        want = scipy.signal.lfilter(b, a, u)
        assert relerr(ref.simulate(m, u, DT), want) < 1e-9
        assert relerr(avll.simulate(m, u, DT), want) < 1e-9
