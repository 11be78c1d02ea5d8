"""Reference rollouts in plain numpy/scipy, written from the paper's equations.

These are the oracles the tests check the Rust core against. They are slow on
purpose: one Python iteration per sample, with the per-interval maps computed by
``scipy.linalg.expm`` of the augmented matrix. Nothing here is translated from
the Rust code; in particular the state-space realization used here (observable
canonical form) differs from the core's, so agreement checks the mathematics,
not a shared implementation.

The models (command ``u`` -> response ``y``)::

    first-order lag (Eq. 1)      y = 1 / (Td s + 1) u
    second-order (Eq. 2, m1 = 0)  y = K0 e^{-Td s} / (m2 s^2 + m3 s + 1) u
    proposed (Eqs. 2, 5)          y = G / (1 - K G) u,
                                  G = (m1 s + K0) e^{-Td s} / (m2 s^2 + m3 s + 1)

In the time domain the proposed model is ``u_ref = u + K y`` and ``y = G u_ref``.

Discretization convention (the project's, see ``avll.rollout``):

* ``u_ref[n] = u[n] + K y[n]`` is held constant over ``[t_n, t_{n+1})``;
* the rational part is driven by ``w(t) = u_ref(t - Td)``. With ``Td/dt = i + f``
  (``i`` integer, ``0 <= f < 1``; ``f < 1e-12`` counts as 0), during
  ``[t_n, t_{n+1})`` the input ``w`` equals ``u_ref[n-i-1]`` over the first
  ``f dt`` and ``u_ref[n-i]`` over the rest; the state is advanced exactly
  over each of these two constant pieces;
* ``y[n] = C x[n]``;
* ``init="rest"``: zero state and ``u_ref[k] = 0`` for ``k < 0``;
  ``init="steady"``: the equilibrium of ``u[0]`` held forever, i.e.
  ``u_ref[k] = w_ss = u[0] / (1 - K K0)`` for ``k < 0`` and ``A x + B w_ss = 0``;
* speed and position are extra states (``v' = a``, ``x' = v``) advanced in the
  same exact step, so they integrate the response under the same hold;
* for a speed command the response is the speed and the reported acceleration is
  the right-limit derivative ``dy/dt(t_n+) = C (A x[n] + B w(t_n+))``.

Closed loop (paper Eq. 3): at each sample the follower's command is
``a_cmd[n] = kg (x_lead[n] - x[n] - Tg v[n] - Gmin) + kv (v_lead[n] - v[n])``;
the lower level starts at rest, the follower at the given speed and position.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from ..data import Run
from ..models import FirstOrderLag, LowerLevelModel, Proposed, SecondOrder, UpperLevel
from .stability import stability_code

__all__ = [
    "DIVERGED",
    "LinearPlant",
    "first_order_lag_plant",
    "second_order_plant",
    "proposed_plant",
    "plant",
    "first_order_lag_recursion",
    "simulate",
    "open_loop_acceleration",
    "open_loop_speed",
    "simulate_full",
    "closed_loop",
    "platoon",
    "mse",
    "lower_level_stable",
    "lower_level_spectral_radius",
    "run_cost",
    "batch_cost",
    "discrete_transfer_function",
    "split_delay",
    "hold_map",
]

#: A response (m/s² or m/s) beyond this magnitude counts as divergence (infinite cost).
DIVERGED = 1e6


# ---------------------------------------------------------------------------
# The models as continuous state-space systems (one function per model).
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class LinearPlant:
    """``x' = A x + B w``, ``y = C x`` with ``w(t) = u_ref(t - Td)``,
    ``u_ref = u + K y``. ``dc`` is the static gain of the rational part."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    Td: float
    K: float
    dc: float


def first_order_lag_plant(model: FirstOrderLag) -> LinearPlant:
    """Eq. 1, ``1 / (Td s + 1)``: ``y' = (u - y) / Td`` with the state ``y`` itself."""
    tau = model.Td
    return LinearPlant(
        A=np.array([[-1.0 / tau]]),
        B=np.array([1.0 / tau]),
        C=np.array([1.0]),
        Td=0.0,  # Td is the lag's time constant here, not a dead time
        K=0.0,
        dc=1.0,
    )


def _second_order_observable(
    n1: float, n0: float, m2: float, m3: float, Td: float, K: float
) -> LinearPlant:
    """Observable canonical form of ``(n1 s + n0) / (m2 s^2 + m3 s + 1)`` (dead time
    ``Td``, inner feedback gain ``K``).

    Dividing by ``m2``: ``(b1 s + b0)/(s^2 + a1 s + a0)`` with ``b = n/m2``,
    ``a1 = m3/m2``, ``a0 = 1/m2``; then ``x1' = -a1 x1 + x2 + b1 w``,
    ``x2' = -a0 x1 + b0 w``, ``y = x1``.
    """
    a1, a0 = m3 / m2, 1.0 / m2
    b1, b0 = n1 / m2, n0 / m2
    return LinearPlant(
        A=np.array([[-a1, 1.0], [-a0, 0.0]]),
        B=np.array([b1, b0]),
        C=np.array([1.0, 0.0]),
        Td=Td,
        K=K,
        dc=n0,
    )


def second_order_plant(model: SecondOrder) -> LinearPlant:
    """Eq. 2 with ``m1 = 0``: ``K0 e^{-Td s} / (m2 s^2 + m3 s + 1)``, no inner feedback."""
    return _second_order_observable(0.0, model.K0, model.m2, model.m3, model.Td, 0.0)


def proposed_plant(model: Proposed) -> LinearPlant:
    """Eqs. 2 and 5: ``G = (m1 s + K0) e^{-Td s} / (m2 s^2 + m3 s + 1)`` inside the
    inner feedback ``u_ref = u + K y``."""
    return _second_order_observable(model.m1, model.K0, model.m2, model.m3, model.Td, model.K)


def plant(model: LowerLevelModel) -> LinearPlant:
    """The state-space form of one of the paper's models."""
    if isinstance(model, FirstOrderLag):
        return first_order_lag_plant(model)
    if isinstance(model, SecondOrder):
        return second_order_plant(model)
    if isinstance(model, Proposed):
        return proposed_plant(model)
    raise ValueError(f"model: the reference knows no model {type(model).__name__}")


def first_order_lag_recursion(
    Td: float, command: Any, dt: float, *, init: str = "rest"
) -> np.ndarray:
    """The first-order lag's closed form: ``y[n+1] = a y[n] + (1 - a) u[n]``,
    ``a = exp(-dt/Td)`` (an oracle that needs no matrix exponential)."""
    u = _series("command", command)
    _check_dt(dt)
    a = math.exp(-dt / Td)
    y = np.empty_like(u)
    y_n = _initial_scalar(init, u, dc=1.0)
    for n in range(u.size):
        y[n] = y_n
        y_n = a * y_n + (1.0 - a) * u[n]
    return y


# ---------------------------------------------------------------------------
# Exact discretization over one sample interval.
# ---------------------------------------------------------------------------


def _series(name: str, x: Any) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 1:
        raise ValueError(f"{name}: must be 1-D, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains non-finite values")
    return arr


def _check_dt(dt: float) -> None:
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be finite and > 0, got {dt}")


def _initial_scalar(init: str, u: np.ndarray, dc: float) -> float:
    if init == "rest":
        return 0.0
    if init == "steady":
        return dc * float(u[0]) if u.size else 0.0
    raise ValueError(f"init: must be 'rest' or 'steady', got {init!r}")


def split_delay(Td: float, dt: float) -> tuple[int, float]:
    """``Td/dt = i + f`` with integer ``i`` and ``0 <= f < 1`` (``f < 1e-12`` -> 0)."""
    r = Td / dt
    i = math.floor(r)
    f = r - i
    if f < 1e-12:
        f = 0.0
    return int(i), f


def hold_map(A: np.ndarray, B: np.ndarray, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact map of ``z' = A z + B w`` over ``tau`` seconds of constant ``w``:
    ``z(tau) = Phi z(0) + Gamma w`` with ``expm([[A, B], [0, 0]] tau) = [[Phi, Gamma], [0, 1]]``."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A
    M[:n, n] = B
    E = scipy.linalg.expm(M * tau)
    return E[:n, :n], E[:n, n]


class _Stepper:
    """The augmented plant (model states, then integrators) and its two hold maps.

    ``z`` holds the model states followed by ``integrators`` extra states:
    ``("v", "x")`` for an acceleration response (``v' = y``, ``x' = v``) or
    ``("x",)`` for a speed response (``x' = y``).
    """

    def __init__(self, p: LinearPlant, dt: float, integrators: tuple[str, ...]) -> None:
        _check_dt(dt)
        m = p.A.shape[0]
        n = m + len(integrators)
        A = np.zeros((n, n))
        A[:m, :m] = p.A
        B = np.zeros(n)
        B[:m] = p.B
        if integrators == ("v", "x"):
            A[m, :m] = p.C  # v' = y (acceleration)
            A[m + 1, m] = 1.0  # x' = v
        elif integrators == ("x",):
            A[m, :m] = p.C  # x' = y (speed)
        C = np.zeros(n)
        C[:m] = p.C
        self.A, self.B, self.C, self.m = A, B, C, m
        self.K = p.K
        self.i, self.f = split_delay(p.Td, dt)
        # first f*dt of the interval, then the remaining (1-f)*dt
        self.phi_first, self.gam_first = hold_map(A, B, self.f * dt)
        self.phi_rest, self.gam_rest = hold_map(A, B, (1.0 - self.f) * dt)

    def delayed(self, u_ref: list[float], n: int, hist: float) -> tuple[float, float]:
        """``(w over the first f dt, w over the rest)`` of interval ``n``."""

        def at(k: int) -> float:
            return u_ref[k] if k >= 0 else hist

        return at(n - self.i - 1), at(n - self.i)

    def advance(self, z: np.ndarray, w_first: float, w_rest: float) -> np.ndarray:
        """State at ``t_{n+1}`` from the state at ``t_n``: two exact constant-input pieces."""
        z = self.phi_first @ z + self.gam_first * w_first
        return self.phi_rest @ z + self.gam_rest * w_rest

    def w_right(self, w_first: float, w_rest: float) -> float:
        """``w(t_n+)``: the value held right after the sample."""
        return w_first if self.f > 0.0 else w_rest

    def derivative(self, z: np.ndarray, w_now: float) -> float:
        """Right-limit time derivative of the response, ``C (A z + B w(t_n+))``."""
        return float(self.C @ (self.A @ z + self.B * w_now))


def _steady_state(p: LinearPlant, u0: float) -> tuple[np.ndarray, float]:
    """Model states and delayed input when ``u0`` has been applied forever."""
    den = 1.0 - p.K * p.dc
    if den == 0.0:
        raise ValueError("init: no steady state, K * K0 = 1")
    w = u0 / den
    x = np.linalg.solve(p.A, -p.B * w)
    return x, w


def _start(
    p: LinearPlant, st: _Stepper, init: str, u0: float, tail: Sequence[float]
) -> tuple[np.ndarray, float]:
    z = np.zeros(st.A.shape[0])
    if init == "rest":
        hist = 0.0
    elif init == "steady":
        z[: st.m], hist = _steady_state(p, u0)
    else:
        raise ValueError(f"init: must be 'rest' or 'steady', got {init!r}")
    z[st.m :] = tail
    return z, hist


# ---------------------------------------------------------------------------
# Open loop.
# ---------------------------------------------------------------------------


def open_loop_acceleration(
    model: LowerLevelModel,
    command: Any,
    dt: float,
    *,
    init: str = "rest",
    v0: float = 0.0,
    x0: float = 0.0,
) -> dict[str, np.ndarray]:
    """Acceleration command -> acceleration ``a``; ``v`` and ``x`` are its exact
    integrals from ``v0``, ``x0``."""
    u = _series("command", command)
    p = plant(model)
    st = _Stepper(p, dt, ("v", "x"))
    z, hist = _start(p, st, init, float(u[0]) if u.size else 0.0, (v0, x0))
    a, v, x = (np.empty(u.size) for _ in range(3))
    u_ref: list[float] = []
    for n in range(u.size):
        y = float(st.C @ z)
        a[n], v[n], x[n] = y, z[st.m], z[st.m + 1]
        u_ref.append(u[n] + p.K * y)
        z = st.advance(z, *st.delayed(u_ref, n, hist))
    return {"a": a, "v": v, "x": x, "command": u.copy()}


def open_loop_speed(
    model: LowerLevelModel,
    command: Any,
    dt: float,
    *,
    init: str = "rest",
    x0: float = 0.0,
) -> dict[str, np.ndarray]:
    """Speed command -> speed ``v``; ``a`` is the right-limit time derivative of
    the speed at each sample and ``x`` its exact integral from ``x0``."""
    u = _series("command", command)
    p = plant(model)
    st = _Stepper(p, dt, ("x",))
    z, hist = _start(p, st, init, float(u[0]) if u.size else 0.0, (x0,))
    a, v, x = (np.empty(u.size) for _ in range(3))
    u_ref: list[float] = []
    for n in range(u.size):
        y = float(st.C @ z)
        u_ref.append(u[n] + p.K * y)
        w_first, w_rest = st.delayed(u_ref, n, hist)
        a[n] = st.derivative(z, st.w_right(w_first, w_rest))
        v[n], x[n] = y, z[st.m]
        z = st.advance(z, w_first, w_rest)
    return {"a": a, "v": v, "x": x, "command": u.copy()}


def simulate_full(
    model: LowerLevelModel,
    command: Any,
    dt: float,
    *,
    command_kind: str = "acceleration",
    init: str = "rest",
    v0: float = 0.0,
    x0: float = 0.0,
) -> dict[str, np.ndarray]:
    """Open-loop rollout of either command kind (``v0`` is ignored for a speed command,
    whose speed is the response)."""
    if command_kind == "acceleration":
        return open_loop_acceleration(model, command, dt, init=init, v0=v0, x0=x0)
    if command_kind == "speed":
        return open_loop_speed(model, command, dt, init=init, x0=x0)
    raise ValueError(f"command_kind: must be 'acceleration' or 'speed', got {command_kind!r}")


def simulate(model: LowerLevelModel, command: Any, dt: float, *, init: str = "rest") -> np.ndarray:
    """The response alone (acceleration for an acceleration command, speed for a speed
    command: the same numbers, the rollout does not depend on the kind)."""
    return open_loop_acceleration(model, command, dt, init=init)["a"]


# ---------------------------------------------------------------------------
# Closed loop (upper law Eq. 3) and platoons.
# ---------------------------------------------------------------------------


def _leader(lead_x: Any, lead_v: Any) -> tuple[np.ndarray, np.ndarray]:
    lx = _series("lead_x", lead_x)
    lv = _series("lead_v", lead_v)
    if lx.size != lv.size:
        raise ValueError(f"lead_v: has length {lv.size}, lead_x has {lx.size}")
    return lx, lv


def _follow(
    model: LowerLevelModel,
    lx: np.ndarray,
    lv: np.ndarray,
    dt: float,
    upper: UpperLevel,
    v0: float,
    x0: float,
) -> dict[str, np.ndarray]:
    """:func:`closed_loop` behind checked leader series (a diverged platoon follower,
    the next one's leader, may hold ``inf``/``nan``)."""
    p = plant(model)
    st = _Stepper(p, dt, ("v", "x"))
    z, hist = _start(p, st, "rest", 0.0, (v0, x0))
    a, v, x, cmd = (np.empty(lx.size) for _ in range(4))
    u_ref: list[float] = []
    for n in range(lx.size):
        y, v_n, x_n = float(st.C @ z), z[st.m], z[st.m + 1]
        a_cmd = upper.kg * (lx[n] - x_n - upper.Tg * v_n - upper.Gmin) + upper.kv * (lv[n] - v_n)
        a[n], v[n], x[n], cmd[n] = y, v_n, x_n, a_cmd
        u_ref.append(a_cmd + p.K * y)
        z = st.advance(z, *st.delayed(u_ref, n, hist))
    return {"a": a, "v": v, "x": x, "command": cmd}


def closed_loop(
    model: LowerLevelModel,
    lead_x: Any,
    lead_v: Any,
    dt: float,
    upper: UpperLevel,
    *,
    v0: float,
    x0: float,
) -> dict[str, np.ndarray]:
    """One follower behind a recorded leader. The state (model states, speed,
    position) is advanced exactly over each interval; the command is the upper law
    evaluated at the samples."""
    lx, lv = _leader(lead_x, lead_v)
    return _follow(model, lx, lv, dt, upper, v0, x0)


def platoon(
    model: LowerLevelModel,
    lead_x: Any,
    lead_v: Any,
    dt: float,
    upper: UpperLevel,
    followers: int,
) -> dict[str, np.ndarray]:
    """``followers`` identical vehicles behind a recorded leader; arrays are
    (follower, sample). Every follower starts at the leader's initial speed, at the
    equilibrium gap ``Gmin + Tg v0`` behind its predecessor, lower level at rest.
    Follower ``k``'s command at sample ``n`` uses its predecessor's position and
    speed at sample ``n`` (so the followers are simulated car by car)."""
    lx, lv = _leader(lead_x, lead_v)
    if followers < 1:
        raise ValueError(f"followers: must be >= 1, got {followers}")
    gap = upper.Gmin + upper.Tg * float(lv[0])
    cars = [{"x": lx, "v": lv}]
    for k in range(followers):
        x0 = float(lx[0]) - (k + 1) * gap
        cars.append(_follow(model, cars[-1]["x"], cars[-1]["v"], dt, upper, float(lv[0]), x0))
    return {key: np.array([car[key] for car in cars[1:]]) for key in ("a", "v", "x", "command")}


# ---------------------------------------------------------------------------
# Calibration cost (paper Eq. 6).
# ---------------------------------------------------------------------------


def _interval_maps(
    p: LinearPlant, dt: float
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """``i`` and ``Phi, G0, G1`` of one interval of the rational part,
    ``x[n+1] = Phi x[n] + G0 u_ref[n-i] + G1 u_ref[n-i-1]``: ``Phi = Phi_rest Phi_first``,
    ``G0 = Gamma_rest``, ``G1 = Phi_rest Gamma_first`` (the hold maps of the convention)."""
    _check_dt(dt)
    i, f = split_delay(p.Td, dt)
    phi_f, gam_f = hold_map(p.A, p.B, f * dt)
    phi_r, gam_r = hold_map(p.A, p.B, (1.0 - f) * dt)
    return i, phi_r @ phi_f, gam_r, phi_r @ gam_f


def lower_level_stable(model: LowerLevelModel, dt: float) -> bool:
    """Whether the sampled lower level is asymptotically stable: the spectral radius of
    its autonomous (``u = 0``) state map (:func:`lower_level_spectral_radius`) is
    below ``1 - 1e-12``. Systems on the boundary (an undamped rational part,
    ``K K0 = 1``) count as unstable."""
    return lower_level_spectral_radius(model, dt) < 1.0 - 1e-12


def lower_level_spectral_radius(model: LowerLevelModel, dt: float) -> float:
    """Spectral radius of the sampled lower level's autonomous (``u = 0``) state map.

    The state is the model state plus the delay line ``u_ref[n-1] ... u_ref[n-i-1]``;
    one step is ``x' = Phi x + G0 u_ref[n-i] + G1 u_ref[n-i-1]`` (:func:`_interval_maps`)
    with ``u_ref[n] = K y[n] = K C x[n]``."""
    p = plant(model)
    i, phi, g0, g1 = _interval_maps(p, dt)
    m = p.A.shape[0]
    size = m + i + 1
    M = np.zeros((size, size))
    feedback = p.K * p.C  # u_ref[n] as a row over the state
    M[:m, :m] = phi
    if i == 0:
        M[:m, :m] += np.outer(g0, feedback)  # w0 = u_ref[n]
    else:
        M[:m, m + i - 1] += g0  # w0 = u_ref[n-i] = r_i
    M[:m, m + i] += g1  # w1 = u_ref[n-i-1] = r_{i+1}
    M[m, :m] = feedback  # r_1' = u_ref[n]
    for k in range(1, i + 1):
        M[m + k, m + k - 1] = 1.0  # r_{k+1}' = r_k
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def mse(sim: np.ndarray, meas: np.ndarray) -> float:
    """Mean squared error ``(1/T) sum_t (sim_t - meas_t)^2``."""
    return float(np.mean((np.asarray(sim) - np.asarray(meas)) ** 2))


#: Padé order of the reference's local-stability test of a closed loop (the Rust cost
#: keeps the delay exact; the two agree away from the edge).
CLOSED_LOOP_PADE = 8


def run_cost(
    model: LowerLevelModel,
    run: Run,
    *,
    weights: tuple[float, float, float] = (1.0, 0.0, 0.0),
    init: str = "rest",
    closed_loop_: bool = False,
    upper: UpperLevel | None = None,
) -> float:
    """One run's cost ``wa MSE(a) + wv MSE(v) + wx MSE(x)`` (Eq. 6's inner mean with
    the default weights). Open loop drives the model with the run's command, its
    speed and position starting at the run's measured first samples (0 if absent);
    closed loop drives it with the leader through ``upper`` (default: the run's
    law), starting at the run's measured speed and position, lower level at rest.
    A lower level that is not asymptotically stable (:func:`lower_level_stable`,
    whatever the run's length), in closed loop a locally unstable loop (the roots of
    Eq. 8's denominator with the delay's Padé-8 approximant, :mod:`.stability`), or a
    response that leaves ``|y| < DIVERGED`` costs ``inf``."""
    wa, wv, wx = weights
    if not lower_level_stable(model, run.dt):
        return math.inf
    law = upper if upper is not None else run.upper
    if closed_loop_ and law is not None:
        if stability_code(model, law.kg, law.Tg, law.kv, pade_order=CLOSED_LOOP_PADE) == 0:
            return math.inf
    v0 = float(run.v[0]) if run.v is not None else 0.0
    x0 = float(run.x[0]) if run.x is not None else 0.0
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging follower is inf here
        if closed_loop_:
            if law is None or run.lead_x is None or run.lead_v is None:
                raise ValueError(f"run {run.run_id!r}: closed loop needs the leader and the law")
            tr = closed_loop(model, run.lead_x, run.lead_v, run.dt, law, v0=v0, x0=x0)
            response = tr["a"]
        else:
            tr = simulate_full(
                model, run.command, run.dt, command_kind=run.command_kind, init=init, v0=v0, x0=x0
            )
            response = tr["a"] if run.command_kind == "acceleration" else tr["v"]
        if not np.all(np.abs(response) < DIVERGED):
            return math.inf
    cost = wa * mse(tr["a"], run.a)
    if wv > 0:
        if run.v is None:
            raise ValueError(f"run {run.run_id!r}: column 'v' is needed for weight_v > 0")
        cost += wv * mse(tr["v"], run.v)
    if wx > 0:
        if run.x is None:
            raise ValueError(f"run {run.run_id!r}: column 'x' is needed for weight_x > 0")
        cost += wx * mse(tr["x"], run.x)
    return cost if math.isfinite(cost) else math.inf


def batch_cost(
    models: Sequence[LowerLevelModel],
    runs: Sequence[Run],
    **kwargs: Any,
) -> np.ndarray:
    """``(P, R)`` per-run costs, one Python call per (model, run) pair."""
    return np.array([[run_cost(m, r, **kwargs) for r in runs] for m in models])


# ---------------------------------------------------------------------------
# The same open-loop rollout as a rational transfer function (for scipy.signal).
# ---------------------------------------------------------------------------


def discrete_transfer_function(model: LowerLevelModel, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(b, a)`` for ``scipy.signal.lfilter`` such that ``lfilter(b, a, u)`` is the
    open-loop response at rest under the convention above, dead time (fractional
    part included) and inner feedback included.

    Over one interval ``x[n+1] = Phi x[n] + G0 u_ref[n-i] + G1 u_ref[n-i-1]``
    (:func:`_interval_maps`; the modified z-transform), so the rational part is
    ``Gd(z) = z^-i (N0(z) + z^-1 N1(z)) / D(z)`` and the inner loop gives
    ``Y = Gd (U + K Y)``, i.e. ``Y/U = Gd_num / (D - K Gd_num)``.
    """
    import scipy.signal

    p = plant(model)
    i, phi, g0, g1 = _interval_maps(p, dt)
    gains = np.column_stack([g0, g1])
    m = p.A.shape[0]
    num0, den = scipy.signal.ss2tf(phi, gains, p.C[None, :], np.zeros((1, 2)), input=0)
    num1, _ = scipy.signal.ss2tf(phi, gains, p.C[None, :], np.zeros((1, 2)), input=1)
    # descending powers of z with equal length m+1 == ascending powers of z^-1
    b = np.zeros(i + m + 2)
    b[i : i + m + 1] += num0[0]
    b[i + 1 : i + m + 2] += num1[0]
    a = np.zeros_like(b)
    a[: m + 1] = den
    a = a - p.K * b
    return b, a
