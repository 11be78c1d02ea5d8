"""``scipy.signal``-based rollouts of the lower-level models: the "scipy route" that
the calibration tests and benchmark compare the Rust GA against.

Written from the discretization convention (see :mod:`avll.rollout`): the rational
part ``(b1 s + b0) / (a2 s² + a1 s + 1)`` in state-space form, its exact
zero-order-hold discretization ``Φ = e^{A dt}``; with ``Td/dt = i + f`` the delayed
input over ``[t_n, t_{n+1})`` is ``w[n-i-1]`` for the first ``f dt`` and ``w[n-i]``
for the rest, so

    x[n+1] = Φ x[n] + Γ0 w[n-i] + Γ1 w[n-i-1],   y[n] = C x[n],
    Γ0 = ∫_0^{(1-f)dt} e^{Aτ} dτ B,   Γ1 = e^{A(1-f)dt} ∫_0^{f dt} e^{Aτ} dτ B.

In ``z^{-1}``: ``Y = B(z^{-1}) W / A(z^{-1})`` with ``B = z^{-i} (N0 + z^{-1} N1)``;
the inner feedback ``w = u + K y`` closes the loop to ``Y (A - K B) = B U``, one
``scipy.signal.lfilter`` call per run (zero initial state: ``init="rest"``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import signal

from ..data import Run
from ..models import LowerLevelModel
from .rollout import split_delay

__all__ = ["filter_coefficients", "simulate_lfilter", "cost_lfilter"]


def controllable_form(c: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``A, B, C`` (``B``, ``C`` 1-D) of the controllable canonical form of the rational
    part ``(b1 s + b0) / (a2 s² + a1 s + 1)``, first order when ``a2 = 0``; ``c`` is
    :meth:`~avll.models.LowerLevelModel.linear`."""
    b1, b0, a2, a1 = c["b1"], c["b0"], c["a2"], c["a1"]
    if a2 != 0.0:
        A = np.array([[0.0, 1.0], [-1.0 / a2, -a1 / a2]])
        B = np.array([0.0, 1.0])
        C = np.array([b0 / a2, b1 / a2])
    else:
        A = np.array([[-1.0 / a1]])
        B = np.array([1.0])
        C = np.array([b0 / a1])
    return A, B, C


def _expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring of a Taylor series (tiny matrices;
    ``scipy.linalg.expm`` is avoided because its threaded LAPACK calls are slow on a
    loaded machine for 3x3 matrices)."""
    norm = float(np.max(np.sum(np.abs(M), axis=1)))
    s = max(0, int(np.ceil(np.log2(norm / 0.25)))) if norm > 0.25 else 0
    A = M / 2.0**s
    E = np.eye(M.shape[0])
    term = np.eye(M.shape[0])
    for k in range(1, 20):
        term = term @ A / k
        E = E + term
    for _ in range(s):
        E = E @ E
    return E


def _zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """``e^{A h}`` and ``∫_0^h e^{Aτ} dτ B`` (a column) from one matrix exponential."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A * h
    M[:n, n] = B * h
    E = _expm(M)
    return E[:n, :n], E[:n, n:]


def filter_coefficients(model: LowerLevelModel, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(b, a)`` of the model's exact discretization for ``lfilter`` (see module doc)."""
    c = model.linear()
    A, B, C = controllable_form(c)
    n = A.shape[0]
    i, f = split_delay(c["Td"], dt)
    phi, _ = _zoh(A, B, dt)
    e_a, g_a = _zoh(A, B, (1.0 - f) * dt)
    _, g_b = _zoh(A, B, f * dt)
    num0, den = signal.ss2tf(phi, g_a, C[None, :], np.zeros((1, 1)))
    num1, _ = signal.ss2tf(phi, e_a @ g_b, C[None, :], np.zeros((1, 1)))
    a = np.asarray(den, dtype=np.float64).ravel()
    bpoly = np.zeros(n + 2 + i)
    bpoly[i : i + n + 1] += np.asarray(num0).ravel()
    bpoly[i + 1 : i + n + 2] += np.asarray(num1).ravel()
    apoly = np.zeros_like(bpoly)
    apoly[: n + 1] = a
    apoly -= c["K"] * bpoly
    return bpoly, apoly


def simulate_lfilter(model: LowerLevelModel, command: np.ndarray, dt: float) -> np.ndarray:
    """Open-loop response from rest by ``scipy.signal.lfilter``."""
    b, a = filter_coefficients(model, dt)
    return signal.lfilter(b, a, np.asarray(command, dtype=np.float64))


def cost_lfilter(model: LowerLevelModel, runs: Sequence[Run], penalty: float = 1e10) -> float:
    """Eq. 6 over ``runs`` (acceleration command, open loop, from rest) by ``lfilter``;
    ``penalty`` for diverging parameters (``|y| > 1e6`` as in the Rust core; a finite
    stand-in for the core's ``inf`` that local optimisers tolerate)."""
    total = 0.0
    cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    for r in runs:
        if r.dt not in cache:
            cache[r.dt] = filter_coefficients(model, r.dt)
        b, a = cache[r.dt]
        y = signal.lfilter(b, a, r.command)
        if not np.all(np.abs(y) < 1e6):
            return penalty
        e = y - r.a
        total += float(np.mean(e * e))
    return total / len(runs)
