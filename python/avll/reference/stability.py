"""Reference (numpy) stability test, written directly from paper Eqs. 8–20.

Independent of the Rust engine: the Padé coefficients come from factorials, the
closed loop from ``numpy.polymul`` of ``Ga``, ``Gb`` (Eqs. 9–12), local stability from
the roots of ``D`` (``numpy.roots``; a batched form computes the same companion-matrix
eigenvalues for many points at once), and string stability from the roots of
``P(x) = |D(j√x)|² − |N(j√x)|²`` formed as ``D(s)D(−s) − N(s)N(−s)`` at ``s² = −x``
(not from the engine's ``(D−N)(D+N)`` factorisation). All polynomials here are
highest power first (numpy's convention).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..models import LowerLevelModel
from ..paper import PADE_ORDER

__all__ = [
    "pade_den",
    "closed_loop_polys",
    "string_poly",
    "stability_code",
    "stability_codes",
    "ROOT_TOL",
]

#: A root of P/x counts as real when |Im r| <= ROOT_TOL * max(|r|, 1).
ROOT_TOL = 1e-7


def pade_den(order: int, td: float) -> np.ndarray:
    """Denominator Q(s) of the [n/n] Padé approximant of e^{-td s} (highest first)."""
    n = int(order)
    c = [
        math.factorial(2 * n - k) * math.factorial(n)
        / (math.factorial(2 * n) * math.factorial(k) * math.factorial(n - k))
        * td**k
        for k in range(n + 1)
    ]
    q = np.array(c[::-1], dtype=float)
    return np.trim_zeros(q, "f") if td > 0 else np.array([1.0])


def _reflect(p: np.ndarray) -> np.ndarray:
    """p(-s) for p highest first."""
    return p * (-1.0) ** np.arange(len(p) - 1, -1, -1)


def closed_loop_polys(
    model: LowerLevelModel, kg: float, tg: float, kv: float, pade_order: int = PADE_ORDER
) -> tuple[np.ndarray, np.ndarray]:
    """N(s), D(s) of Eq. 8 with the delay replaced by its Padé approximant."""
    c = model.linear()
    q = pade_den(pade_order, c["Td"])
    ga = np.polymul(np.trim_zeros(np.array([c["b1"], c["b0"]]), "f"), _reflect(q))
    gb = np.polymul(np.trim_zeros(np.array([c["a2"], c["a1"], 1.0]), "f"), q)
    mu = kv + tg * kg
    n = np.polymul([kv, kg], ga)
    m_s2 = np.polymul(np.polysub(gb, c["K"] * ga), [1.0, 0.0, 0.0])
    d = np.polyadd(m_s2, np.polymul(ga, [mu, kg]))
    return np.trim_zeros(n, "f"), np.trim_zeros(d, "f")


def string_poly(n: np.ndarray, d: np.ndarray) -> np.ndarray:
    """P(x) (highest first in x = ω²) from D(s)D(−s) − N(s)N(−s) at s² = −x."""
    e: np.ndarray = np.polysub(np.polymul(d, _reflect(d)), np.polymul(n, _reflect(n)))
    # an even polynomial in s: keep the even powers, s^{2k} -> (-x)^k
    even = e[::-1][::2]  # ascending in s, even powers
    return (even * (-1.0) ** np.arange(len(even)))[::-1]


def _string_from_roots(r_desc: np.ndarray, roots: np.ndarray) -> bool:
    """R(x) > 0 on (0, inf) from its coefficients (highest first) and roots."""
    asc = r_desc[::-1]
    scale = np.max(np.abs(asc))
    nz = np.nonzero(np.abs(asc) > 1e-14 * scale)[0]
    if len(nz) == 0 or asc[nz[0]] <= 0:
        return False
    real_pos = (np.abs(roots.imag) <= ROOT_TOL * np.maximum(np.abs(roots), 1.0)) & (
        roots.real > 0
    )
    return not bool(np.any(real_pos))


def stability_code(
    model: LowerLevelModel, kg: float, tg: float, kv: float, pade_order: int = PADE_ORDER
) -> int:
    """Map code of one point (0 locally unstable, 1 string unstable, 2 stable) with
    ``numpy.roots`` per polynomial."""
    n, d = closed_loop_polys(model, kg, tg, kv, pade_order)
    if d[-1] == 0 or np.max(np.roots(d).real) >= 0:
        return 0
    p = string_poly(n, d)
    r = p[:-1]  # P(0) = 0: divide by x
    return 2 if _string_from_roots(r, np.roots(r)) else 1


def _batched_roots(polys: np.ndarray) -> np.ndarray:
    """Roots of many polynomials of one degree (rows, highest first): the eigenvalues
    of their companion matrices, as ``numpy.roots`` computes them."""
    m, k = polys.shape
    deg = k - 1
    comp = np.zeros((m, deg, deg))
    comp[:, 0, :] = -polys[:, 1:] / polys[:, :1]
    if deg > 1:
        idx = np.arange(deg - 1)
        comp[:, idx + 1, idx] = 1.0
    return np.linalg.eigvals(comp)


def stability_codes(
    model: LowerLevelModel, kg: Any, tg: Any, kv: Any, pade_order: int = PADE_ORDER
) -> tuple[np.ndarray, np.ndarray]:
    """Codes of many scattered points at once, and a local-stability margin
    (``-max Re(root of D)``; the string test's margin is not defined here).

    Same mathematics as :func:`stability_code`, with the roots of all points
    computed as one batch of companion-matrix eigenvalue problems.
    """
    kg, tg, kv = (np.asarray(a, dtype=float).ravel() for a in (kg, tg, kv))
    npts = len(kg)
    ds, rs = [], []
    for i in range(npts):
        n, d = closed_loop_polys(model, float(kg[i]), float(tg[i]), float(kv[i]), pade_order)
        ds.append(d)
        rs.append(string_poly(n, d)[:-1])
    width_d = max(len(d) for d in ds)
    width_r = max(len(r) for r in rs)
    dmat = np.array([np.concatenate([np.zeros(width_d - len(d)), d]) for d in ds])
    rmat = np.array([np.concatenate([np.zeros(width_r - len(r)), r]) for r in rs])
    codes = np.zeros(npts, dtype=np.uint8)
    margin = np.full(npts, -np.inf)
    ok = dmat[:, -1] != 0
    if np.any(ok):
        droots = _batched_roots(dmat[ok])
        margin[ok] = -np.max(droots.real, axis=1)
    local = margin > 0
    if np.any(local):
        idx = np.nonzero(local)[0]
        rroots = _batched_roots(rmat[idx])
        for j in range(idx.size):
            i = int(idx[j])
            codes[i] = 2 if _string_from_roots(rmat[i], rroots[j]) else 1
    return codes, margin
