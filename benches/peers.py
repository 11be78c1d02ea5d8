"""Numba peers of avll's rollouts: what a performance-minded user would write.

These are the comparison points of the performance targets. Each workload
has a *plain* loop (the straightforward scalar loop a user writes first) and the
best variant we could write (modal form, branch-free delay line, time-major
platoon, parameter sets in parallel). Every peer computes the same numbers as
avll (checked to 1e-9 of the signal scale by :func:`check_close`, by
``benches/bench_engine.py`` before timing, and by ``tests/test_bench_peers.py``).

Discretization: the peers do not re-derive it. For one model, the discrete
matrices come from :mod:`avll.reference.rollout` (``plant``, ``split_delay``,
``hold_map``: scipy's matrix exponential of the augmented matrix), exactly as a user
who got them from scipy would, and the peers implement only the stepping loop:

    x[n+1] = Phi x[n] + G0 u_ref[n-i] + G1 u_ref[n-i-1],   y[n] = C x[n],
    u_ref[n] = u[n] + K y[n],   Td/dt = i + f,
    Phi = Phi_rest Phi_first,  G0 = Gamma_rest,  G1 = Phi_rest Gamma_first,

at rest (zero state, zero input history). Speed and position are extra states of
the same exact step. For the batched cost the matrices change with every parameter
set, so the peers discretize inside numba: the plain one by a scaling-and-squaring
Taylor matrix exponential of the same augmented matrix (checked against the
reference's ``hold_map`` by the tests), the best one straight in modal form from the
continuous poles (``exp``/``expm1`` per mode; the matrix exponential only for complex
or nearly repeated poles). Both test stability exactly as avll does (Schur-Cohn on
the inner loop's characteristic polynomial): unstable or invalid sets cost ``inf``.

What makes the best variants fast (measured on a 2-core AMD EPYC, numba 0.68):
the modal form (one multiply-add per mode on the state's dependency chain), a
power-of-two ring buffer for the delay line (a full-length ``u_ref`` array
page-faults: 4x slower at 1e6 samples), no divergence test inside the hot loop
(chunked scans, or for the cost a bound on the error sum), FMA contraction, and for
the platoon all followers stepped together (time-major: independent recurrences
within a sample, vectorized across followers). Tried and not kept: four parameter
sets of equal delay stepped together in one rollout (scalar code, LLVM does not
vectorize it): 435 vs 451 M steps/s for one set per rollout, which is already
throughput-bound (about 11 floating-point operations per step).

The peers cover the second-order models (``Proposed``, ``SecondOrder``): the
benchmarks run the paper's proposed model.

Semantics mirrored from avll (``python/avll/rollout.py``, ``rust/rollout.rs``):

* closed loop: ``a_cmd[n] = kg (lead_x[n] - x[n] - Tg v[n] - Gmin) + kv (lead_v[n]
  - v[n])``; lower level at rest, speed and position from ``v0``, ``x0``; once
  ``|a[n]| < 1e6`` fails, every output is NaN from sample ``n + 1`` on;
* platoon: every follower starts at the leader's first speed ``v0``, at the gap
  ``Gmin + Tg v0`` behind its predecessor's first position (subtracted car after
  car), lower level at rest; follower ``k`` follows follower ``k-1``'s position and
  speed at the same sample; a follower behind a diverged one (any non-finite
  position) is NaN throughout;
* batched cost: per run ``sum((y - a)^2) / len`` (acceleration MSE, open loop, at
  rest), ``inf`` for invalid parameters (non-finite, ``m2 <= 0``, ``Td < 0``), an
  unstable lower level, or a response reaching ``|y| >= 1e6``.

Requires numba (``pip install avll[bench]``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

try:
    import numba
    from numba import njit, prange
except ImportError as e:  # pragma: no cover - depends on the environment
    raise ImportError("benches/peers.py needs numba: pip install 'avll[bench]'") from e

import avll
from avll.reference import rollout as ref

__all__ = [
    "DIVERGED",
    "Discrete",
    "Modal",
    "discretize",
    "modal",
    "check_close",
    "open_plain",
    "open_modal",
    "Block",
    "block",
    "open_block",
    "closed_plain",
    "closed_modal",
    "platoon_plain",
    "platoon_time_major",
    "pack",
    "cost_plain",
    "cost_modal",
    "OPEN_PEERS",
    "CLOSED_PEERS",
    "PLATOON_PEERS",
    "OPEN_INTO_PEERS",
    "CLOSED_INTO_PEERS",
    "PLATOON_INTO_PEERS",
    "COST_PEERS",
    "Peer",
    "set_threads",
]

#: A response beyond this magnitude counts as divergence (avll's threshold).
DIVERGED = ref.DIVERGED
#: Largest entry of ``[A, B] tau`` avll accepts (its ``MAX_SCALED_ENTRY``).
MAX_SCALED_ENTRY = 1e12

JIT = dict(cache=True, nogil=True, error_model="numpy")
#: The fast variants let LLVM fuse multiply-adds (FMA, one rounding instead of two:
#: still far inside the 1e-9 check); it lengthens the plain loops' chains, so they
#: keep numba's default.
FAST = dict(JIT, fastmath={"contract"})


# ---------------------------------------------------------------------------
# Discretization (Python, from avll.reference) and the modal form.
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Discrete:
    """One model's exact discrete step. States: the model's two (the reference's
    observable canonical form), then speed and position when ``integrators``."""

    phi: np.ndarray
    g0: np.ndarray
    g1: np.ndarray
    c: np.ndarray
    k: float
    i: int
    f: float
    m: int


@dataclass(frozen=True)
class Modal:
    """:class:`Discrete` with the model block of ``phi`` diagonalised
    (``phi[:m, :m] = diag(lam)``; integrator rows transformed alike)."""

    lam: np.ndarray
    phi: np.ndarray
    g0: np.ndarray
    g1: np.ndarray
    c: np.ndarray
    k: float
    i: int


def discretize(model: avll.LowerLevelModel, dt: float, integrators: bool = False) -> Discrete:
    """The exact discrete step of ``model`` from the reference's hold maps (scipy
    ``expm``); with ``integrators`` the speed and position follow the model states."""
    p = ref.plant(model)
    m = p.A.shape[0]
    if m != 2:
        raise ValueError(f"model: the peers cover second-order models, got {model!r}")
    n = m + (2 if integrators else 0)
    A = np.zeros((n, n))
    A[:m, :m] = p.A
    B = np.zeros(n)
    B[:m] = p.B
    if integrators:
        A[m, :m] = p.C  # v' = y
        A[m + 1, m] = 1.0  # x' = v
    i, f = ref.split_delay(p.Td, dt)
    phi_f, gam_f = ref.hold_map(A, B, f * dt)
    phi_r, gam_r = ref.hold_map(A, B, (1.0 - f) * dt)
    c = np.zeros(n)
    c[:m] = p.C
    return Discrete(
        phi=np.ascontiguousarray(phi_r @ phi_f),
        g0=np.ascontiguousarray(gam_r),
        g1=np.ascontiguousarray(phi_r @ gam_f),
        c=c,
        k=float(p.K),
        i=int(i),
        f=float(f),
        m=m,
    )


def modal(d: Discrete) -> Modal:
    """Diagonalises the model block of ``d.phi`` (real, distinct eigenvalues needed:
    true for the paper's models, whose poles are real)."""
    m = d.m
    lam, V = np.linalg.eig(d.phi[:m, :m])
    if np.iscomplexobj(lam) and np.any(np.abs(lam.imag) > 0):
        raise ValueError("modal: complex eigenvalues (use the plain peer)")
    lam, V = lam.real, V.real
    if np.linalg.cond(V) > 1e6:
        raise ValueError("modal: nearly repeated eigenvalues (use the plain peer)")
    n = d.phi.shape[0]
    T = np.eye(n)
    T[:m, :m] = V
    Ti = np.linalg.inv(T)
    phi = Ti @ d.phi @ T
    phi[:m, :m] = np.diag(lam)  # exact zeros off the diagonal
    return Modal(
        lam=np.ascontiguousarray(lam),
        phi=np.ascontiguousarray(phi),
        g0=np.ascontiguousarray(Ti @ d.g0),
        g1=np.ascontiguousarray(Ti @ d.g1),
        c=np.ascontiguousarray(d.c @ T),
        k=d.k,
        i=d.i,
    )


def check_close(name: str, got: Any, want: Any, tol: float = 1e-9) -> float:
    """``max |got - want| / max |want|`` over the finite samples; raises
    ``AssertionError`` when it exceeds ``tol`` or the NaN patterns differ."""
    g = np.asarray(got, dtype=np.float64)
    w = np.asarray(want, dtype=np.float64)
    if g.shape != w.shape:
        raise AssertionError(f"{name}: shape {g.shape} != avll's {w.shape}")
    if not np.array_equal(np.isnan(g), np.isnan(w)) or not np.array_equal(np.isinf(g), np.isinf(w)):
        raise AssertionError(f"{name}: non-finite entries differ from avll's")
    fin = np.isfinite(w)
    if not fin.any():
        return 0.0
    if np.any(np.isinf(w) & (np.sign(g) != np.sign(w))):
        raise AssertionError(f"{name}: infinite entries differ from avll's")
    scale = float(np.max(np.abs(w[fin])))
    err = float(np.max(np.abs(g[fin] - w[fin]))) / (scale if scale > 0 else 1.0)
    if not err <= tol:
        raise AssertionError(f"{name}: max relative difference {err:.3g} > {tol:g}")
    return err


def _pow2(n: int) -> int:
    cap = 1
    while cap < n:
        cap *= 2
    return cap


# ---------------------------------------------------------------------------
# (a) Open loop.
# ---------------------------------------------------------------------------


@njit(**JIT)
def _open_plain(phi, g0, g1, c, k, i, u):  # pragma: no cover - compiled
    y = np.empty(u.size)
    _open_plain_into(phi, g0, g1, c, k, i, u, y)
    return y


@njit(**JIT)
def _open_plain_into(phi, g0, g1, c, k, i, u, y):  # pragma: no cover - compiled
    T = u.size
    cap = 1
    while cap < i + 2:
        cap *= 2
    mask = cap - 1
    buf = np.zeros(cap)
    p00, p01, p10, p11 = phi[0, 0], phi[0, 1], phi[1, 0], phi[1, 1]
    a0, a1, b0, b1 = g0[0], g0[1], g1[0], g1[1]
    c0, c1 = c[0], c[1]
    x0 = 0.0
    x1 = 0.0
    for n in range(T):
        yn = c0 * x0 + c1 * x1
        y[n] = yn
        buf[n & mask] = u[n] + k * yn
        w0 = buf[(n - i) & mask]
        w1 = buf[(n - i - 1) & mask]
        x0, x1 = (
            p00 * x0 + p01 * x1 + a0 * w0 + b0 * w1,
            p10 * x0 + p11 * x1 + a1 * w0 + b1 * w1,
        )


@njit(**FAST)
def _open_modal(lam, g0, g1, c, k, i, u):  # pragma: no cover - compiled
    y = np.empty(u.size)
    _open_modal_into(lam, g0, g1, c, k, i, u, y)
    return y


@njit(**FAST)
def _open_modal_into(lam, g0, g1, c, k, i, u, y):  # pragma: no cover - compiled
    # Modal form: one multiply-add per mode on the state's dependency chain. The
    # delay line is a power-of-two ring buffer indexed with a mask (no branch, stays
    # in L1: a full-length u_ref array is 4x slower at 1e6 samples, page faults);
    # w1 is the previous w0, kept in a register.
    T = u.size
    l0, l1 = lam[0], lam[1]
    a0, a1, b0, b1 = g0[0], g0[1], g1[0], g1[1]
    c0, c1 = c[0], c[1]
    cap = 1
    while cap < i + 2:
        cap *= 2
    mask = cap - 1
    buf = np.zeros(cap)
    z0 = 0.0
    z1 = 0.0
    w1 = 0.0
    for n in range(T):
        yn = c0 * z0 + c1 * z1
        y[n] = yn
        buf[n & mask] = u[n] + k * yn
        w0 = buf[(n - i) & mask]
        z0 = l0 * z0 + (a0 * w0 + b0 * w1)
        z1 = l1 * z1 + (a1 * w0 + b1 * w1)
        w1 = w0


@dataclass(frozen=True)
class Block:
    """:class:`Modal` with the maps of four samples stepped together (the block form
    avll's open loop uses when the dead time is at least four samples): ``yx[m, j] =
    c_m lam_m^j``, ``yg[k + 1, j]`` the response of sample ``j`` of a block to the line
    output ``g[n0 + k]``, ``s[k + 1, m]`` mode ``m``'s state after the block, ``l4 =
    lam^4``."""

    md: Modal
    yx: np.ndarray
    yg: np.ndarray
    s: np.ndarray
    l4: np.ndarray


def block(md: Modal) -> Block:
    """The four-sample block maps of a (two-mode, no integrator) modal step, written
    from ``x[n+1] = lam x[n] + g0 g[n] + g1 g[n-1]`` and ``y = c x``."""
    lam, a, b, c = md.lam, md.g0[:2], md.g1[:2], md.c[:2]
    yx = np.array([[c[m] * lam[m] ** j for j in range(4)] for m in range(2)])
    yg = np.zeros((4, 4))
    for j in range(4):
        for k in range(-1, 3):
            h = 0.0
            for m in range(2):
                if 0 <= k < j:
                    h += c[m] * a[m] * lam[m] ** (j - 1 - k)
                if k + 1 < j:
                    h += c[m] * b[m] * lam[m] ** (j - 2 - k)
            yg[k + 1, j] = h
    s = np.zeros((5, 2))
    for k in range(-1, 4):
        for m in range(2):
            v = 0.0
            if k >= 0:
                v += a[m] * lam[m] ** (3 - k)
            if k <= 2:
                v += b[m] * lam[m] ** (2 - k)
            s[k + 1, m] = v
    return Block(md=md, yx=yx, yg=yg, s=s, l4=lam**4)


@njit(**FAST)
def _open_block(lam, g0, g1, c, k, i, yx, yg, s, l4, u):  # pragma: no cover - compiled
    y = np.empty(u.size)
    _open_block_into(lam, g0, g1, c, k, i, yx, yg, s, l4, u, y)
    return y


@njit(**FAST)
def _open_block_into(lam, g0, g1, c, k, i, yx, yg, s, l4, u, y):  # pragma: no cover
    # Four samples per iteration when the dead time is at least four samples: the
    # block reads its five line outputs before writing its four references. The
    # line is a power-of-two ring with a mirror of its first eight slots, so the five
    # reads are contiguous; the last samples (and any dead time under four samples)
    # go one by one as in the modal loop. Every coefficient is a local (numba's arrays
    # may alias the outputs, so LLVM would reload them after each store).
    T = u.size
    cap = 4
    while cap < i + 8:
        cap *= 2
    mask = cap - 1
    line = np.zeros(cap + 8)
    a00, a01, a02, a03 = yg[0, 0], yg[0, 1], yg[0, 2], yg[0, 3]
    a10, a11, a12, a13 = yg[1, 0], yg[1, 1], yg[1, 2], yg[1, 3]
    a20, a21, a22, a23 = yg[2, 0], yg[2, 1], yg[2, 2], yg[2, 3]
    a30, a31, a32, a33 = yg[3, 0], yg[3, 1], yg[3, 2], yg[3, 3]
    x00, x01, x02, x03 = yx[0, 0], yx[0, 1], yx[0, 2], yx[0, 3]
    x10, x11, x12, x13 = yx[1, 0], yx[1, 1], yx[1, 2], yx[1, 3]
    s00, s10, s20, s30, s40 = s[0, 0], s[1, 0], s[2, 0], s[3, 0], s[4, 0]
    s01, s11, s21, s31, s41 = s[0, 1], s[1, 1], s[2, 1], s[3, 1], s[4, 1]
    l40, l41 = l4[0], l4[1]
    z0 = 0.0
    z1 = 0.0
    nb = T // 4 if i >= 4 else 0
    for blk in range(nb):
        n0 = 4 * blk
        base = (n0 - i - 1) & mask
        q0 = line[base]
        q1 = line[base + 1]
        q2 = line[base + 2]
        q3 = line[base + 3]
        q4 = line[base + 4]
        ya = a00 * q0 + a10 * q1 + a20 * q2 + a30 * q3 + x10 * z1 + x00 * z0
        yb = a01 * q0 + a11 * q1 + a21 * q2 + a31 * q3 + x11 * z1 + x01 * z0
        yc = a02 * q0 + a12 * q1 + a22 * q2 + a32 * q3 + x12 * z1 + x02 * z0
        yd = a03 * q0 + a13 * q1 + a23 * q2 + a33 * q3 + x13 * z1 + x03 * z0
        y[n0] = ya
        y[n0 + 1] = yb
        y[n0 + 2] = yc
        y[n0 + 3] = yd
        ra = u[n0] + k * ya
        rb = u[n0 + 1] + k * yb
        rc = u[n0 + 2] + k * yc
        rd = u[n0 + 3] + k * yd
        w = n0 & mask
        line[w] = ra
        line[w + 1] = rb
        line[w + 2] = rc
        line[w + 3] = rd
        if w < 8:
            line[cap + w] = ra
            line[cap + w + 1] = rb
            line[cap + w + 2] = rc
            line[cap + w + 3] = rd
        z0 = l40 * z0 + (s00 * q0 + s10 * q1 + s20 * q2 + s30 * q3 + s40 * q4)
        z1 = l41 * z1 + (s01 * q0 + s11 * q1 + s21 * q2 + s31 * q3 + s41 * q4)
    w1 = line[(4 * nb - 1 - i) & mask]
    for n in range(4 * nb, T):
        yn = c[0] * z0 + c[1] * z1
        y[n] = yn
        line[n & mask] = u[n] + k * yn
        w0 = line[(n - i) & mask]
        z0 = lam[0] * z0 + (g0[0] * w0 + g1[0] * w1)
        z1 = lam[1] * z1 + (g0[1] * w0 + g1[1] * w1)
        w1 = w0


def open_block(bl: Block, u: np.ndarray) -> np.ndarray:
    """Open-loop response at rest: avll's four-sample block form written in numba."""
    md = bl.md
    return _open_block(md.lam, md.g0, md.g1, md.c, md.k, md.i, bl.yx, bl.yg, bl.s, bl.l4, u)


def open_plain(d: Discrete, u: np.ndarray) -> np.ndarray:
    """Open-loop response at rest: the plain loop (full 2x2 step, ring buffer)."""
    return _open_plain(d.phi, d.g0, d.g1, d.c, d.k, d.i, u)


def open_modal(md: Modal, u: np.ndarray) -> np.ndarray:
    """Open-loop response at rest: modal form, masked ring-buffer delay line."""
    return _open_modal(md.lam, md.g0, md.g1, md.c, md.k, md.i, u)


# The same loops writing into an array the caller allocated once (``out``).


def open_plain_into(d: Discrete, u: np.ndarray, out: np.ndarray) -> np.ndarray:
    """:func:`open_plain` into ``out``."""
    _open_plain_into(d.phi, d.g0, d.g1, d.c, d.k, d.i, u, out)
    return out


def open_modal_into(md: Modal, u: np.ndarray, out: np.ndarray) -> np.ndarray:
    """:func:`open_modal` into ``out``."""
    _open_modal_into(md.lam, md.g0, md.g1, md.c, md.k, md.i, u, out)
    return out


def open_block_into(bl: Block, u: np.ndarray, out: np.ndarray) -> np.ndarray:
    """:func:`open_block` into ``out``."""
    md = bl.md
    _open_block_into(md.lam, md.g0, md.g1, md.c, md.k, md.i, bl.yx, bl.yg, bl.s, bl.l4, u, out)
    return out


# ---------------------------------------------------------------------------
# (b) Closed loop behind a recorded leader.
# ---------------------------------------------------------------------------


@njit(**JIT)
def _nan_from(a, v, x, cmd, start):  # pragma: no cover - compiled
    for n in range(start, a.size):
        a[n] = np.nan
        v[n] = np.nan
        x[n] = np.nan
        cmd[n] = np.nan


@njit(**JIT)
def _closed_plain(phi, g0, g1, c, k, i, kg, kv, tg, gmin, lx, lv, v0, x0):  # pragma: no cover
    T = lx.size
    a, v, x, cmd = np.empty(T), np.empty(T), np.empty(T), np.empty(T)
    _closed_plain_into(phi, g0, g1, c, k, i, kg, kv, tg, gmin, lx, lv, v0, x0, a, v, x, cmd)
    return a, v, x, cmd


@njit(**JIT)
def _closed_plain_into(
    phi, g0, g1, c, k, i, kg, kv, tg, gmin, lx, lv, v0, x0, a, v, x, cmd
):  # pragma: no cover
    # The plain loop: the full 4x4 step as scalars, a ring buffer for the delay line,
    # the divergence test on every sample.
    T = lx.size
    cap = 1
    while cap < i + 2:
        cap *= 2
    mask = cap - 1
    buf = np.zeros(cap)
    p00, p01, p02, p03 = phi[0, 0], phi[0, 1], phi[0, 2], phi[0, 3]
    p10, p11, p12, p13 = phi[1, 0], phi[1, 1], phi[1, 2], phi[1, 3]
    p20, p21, p22, p23 = phi[2, 0], phi[2, 1], phi[2, 2], phi[2, 3]
    p30, p31, p32, p33 = phi[3, 0], phi[3, 1], phi[3, 2], phi[3, 3]
    a0, a1, a2, a3 = g0[0], g0[1], g0[2], g0[3]
    b0, b1, b2, b3 = g1[0], g1[1], g1[2], g1[3]
    c0, c1 = c[0], c[1]
    s0 = 0.0
    s1 = 0.0
    s2 = v0
    s3 = x0
    written = T
    for n in range(T):
        y = c0 * s0 + c1 * s1
        u = kg * (lx[n] - s3 - tg * s2 - gmin) + kv * (lv[n] - s2)
        a[n] = y
        v[n] = s2
        x[n] = s3
        cmd[n] = u
        if not abs(y) < 1e6:
            written = n + 1
            break
        buf[n & mask] = u + k * y
        w0 = buf[(n - i) & mask]
        w1 = buf[(n - i - 1) & mask]
        # (the position, which grows large, is added last: one rounding at its scale)
        s0, s1, s2, s3 = (
            p00 * s0 + p01 * s1 + p02 * s2 + a0 * w0 + b0 * w1 + p03 * s3,
            p10 * s0 + p11 * s1 + p12 * s2 + a1 * w0 + b1 * w1 + p13 * s3,
            p20 * s0 + p21 * s1 + p22 * s2 + a2 * w0 + b2 * w1 + p23 * s3,
            p30 * s0 + p31 * s1 + p32 * s2 + a3 * w0 + b3 * w1 + p33 * s3,
        )
    _nan_from(a, v, x, cmd, written)


@njit(**JIT)
def _first_diverged(a, start, stop):  # pragma: no cover - compiled
    # Index of the first sample in [start, stop) with |a| >= 1e6 (or NaN), else -1.
    ok = True
    for n in range(start, stop):
        ok &= abs(a[n]) < 1e6
    if ok:
        return -1
    for n in range(start, stop):
        if not abs(a[n]) < 1e6:
            return n
    return -1


@njit(**FAST)
def _closed_modal(phi, g0, g1, c, k, i, kg, kv, tg, gmin, lx, lv, v0, x0):  # pragma: no cover
    T = lx.size
    a, v, x, cmd = np.empty(T), np.empty(T), np.empty(T), np.empty(T)
    _closed_modal_into(phi, g0, g1, c, k, i, kg, kv, tg, gmin, lx, lv, v0, x0, a, v, x, cmd)
    return a, v, x, cmd


@njit(**FAST)
def _closed_modal_into(
    phi, g0, g1, c, k, i, kg, kv, tg, gmin, lx, lv, v0, x0, a, v, x, cmd
):  # pragma: no cover
    # Modal model states z0, z1 (diagonal), then the integrators' rows:
    # v' = pv0 z0 + pv1 z1 + pvv v + inputs, x' = px0 z0 + px1 z1 + pxv v + pxx x + inputs.
    # u_ref goes through a masked power-of-two ring buffer (branch-free, in L1). The
    # hot loop has no divergence test: each chunk's accelerations are scanned after
    # it (a vectorized pass over data still in cache) and the outputs past the first
    # divergence are overwritten with NaN, as avll's are.
    T = lx.size
    l0, l1 = phi[0, 0], phi[1, 1]
    pv0, pv1, pvv = phi[2, 0], phi[2, 1], phi[2, 2]
    px0, px1, pxv, pxx = phi[3, 0], phi[3, 1], phi[3, 2], phi[3, 3]
    a0, a1, av, ax = g0[0], g0[1], g0[2], g0[3]
    b0, b1, bv, bx = g1[0], g1[1], g1[2], g1[3]
    c0, c1 = c[0], c[1]
    cap = 1
    while cap < i + 2:
        cap *= 2
    mask = cap - 1
    buf = np.zeros(cap)
    z0 = 0.0
    z1 = 0.0
    sv = v0
    sx = x0
    w1 = 0.0
    written = T
    chunk = 2048
    for start in range(0, T, chunk):
        stop = min(start + chunk, T)
        for n in range(start, stop):
            y = c0 * z0 + c1 * z1
            u = kg * (lx[n] - sx - tg * sv - gmin) + kv * (lv[n] - sv)
            a[n] = y
            v[n] = sv
            x[n] = sx
            cmd[n] = u
            buf[n & mask] = u + k * y
            w0 = buf[(n - i) & mask]
            nz0 = l0 * z0 + (a0 * w0 + b0 * w1)
            nz1 = l1 * z1 + (a1 * w0 + b1 * w1)
            nv = pvv * sv + (pv0 * z0 + pv1 * z1) + (av * w0 + bv * w1)
            nx = pxx * sx + pxv * sv + (px0 * z0 + px1 * z1) + (ax * w0 + bx * w1)
            z0, z1, sv, sx = nz0, nz1, nv, nx
            w1 = w0
        bad = _first_diverged(a, start, stop)
        if bad >= 0:
            written = bad + 1
            break
    _nan_from(a, v, x, cmd, written)


def closed_plain(
    d: Discrete, up: avll.UpperLevel, lead_x: np.ndarray, lead_v: np.ndarray, v0: float, x0: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed loop (a, v, x, command): full 4x4 step, ring buffer, per-step check."""
    return _closed_plain(
        d.phi, d.g0, d.g1, d.c, d.k, d.i, up.kg, up.kv, up.Tg, up.Gmin, lead_x, lead_v,
        float(v0), float(x0),
    )  # fmt: skip


def closed_modal(
    md: Modal, up: avll.UpperLevel, lead_x: np.ndarray, lead_v: np.ndarray, v0: float, x0: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closed loop (a, v, x, command): modal form, ring buffer, chunked checks."""
    return _closed_modal(
        md.phi, md.g0, md.g1, md.c, md.k, md.i, up.kg, up.kv, up.Tg, up.Gmin, lead_x, lead_v,
        float(v0), float(x0),
    )  # fmt: skip


def closed_plain_into(
    d: Discrete, up: avll.UpperLevel, lead_x: np.ndarray, lead_v: np.ndarray, v0: float,
    x0: float, out: tuple[np.ndarray, ...],
) -> tuple[np.ndarray, ...]:
    """:func:`closed_plain` into the four arrays ``out`` (a, v, x, command)."""
    _closed_plain_into(
        d.phi, d.g0, d.g1, d.c, d.k, d.i, up.kg, up.kv, up.Tg, up.Gmin, lead_x, lead_v,
        float(v0), float(x0), *out,
    )
    return out


def closed_modal_into(
    md: Modal, up: avll.UpperLevel, lead_x: np.ndarray, lead_v: np.ndarray, v0: float,
    x0: float, out: tuple[np.ndarray, ...],
) -> tuple[np.ndarray, ...]:
    """:func:`closed_modal` into the four arrays ``out`` (a, v, x, command)."""
    _closed_modal_into(
        md.phi, md.g0, md.g1, md.c, md.k, md.i, up.kg, up.kv, up.Tg, up.Gmin, lead_x, lead_v,
        float(v0), float(x0), *out,
    )
    return out


# ---------------------------------------------------------------------------
# (c) Platoon.
# ---------------------------------------------------------------------------


def _platoon_nan(a: np.ndarray, v: np.ndarray, x: np.ndarray, cmd: np.ndarray) -> None:
    """avll's divergence rules on (follower, sample) arrays, in place: a follower is
    NaN from the sample after its first ``|a| >= 1e6``, and NaN throughout when its
    predecessor's position has any non-finite value."""
    for k in range(a.shape[0]):
        if k > 0 and not np.all(np.isfinite(x[k - 1])):
            bad = 0
        else:
            hits = np.flatnonzero(~(np.abs(a[k]) < DIVERGED))
            bad = int(hits[0]) + 1 if hits.size else a.shape[1]
        for s in (a, v, x, cmd):
            s[k, bad:] = np.nan


def platoon_plain(
    d: Discrete, up: avll.UpperLevel, lead_x: np.ndarray, lead_v: np.ndarray, followers: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Platoon, follower-major: the plain closed loop of each follower behind the
    previous one's trajectory. Arrays are (follower, sample)."""
    T = lead_x.size
    out = [np.empty((followers, T)) for _ in range(4)]
    v0 = float(lead_v[0])
    px, pv, p0 = lead_x, lead_v, float(lead_x[0])
    for k in range(followers):
        start = p0 - (up.Gmin + up.Tg * v0)
        if not np.all(np.isfinite(px)):
            for s in out:
                s[k] = np.nan
        else:
            res = _closed_plain(
                d.phi, d.g0, d.g1, d.c, d.k, d.i, up.kg, up.kv, up.Tg, up.Gmin, px, pv, v0, start
            )
            for s, r in zip(out, res, strict=True):
                s[k] = r
        px, pv, p0 = out[2][k], out[1][k], float(out[2][k, 0])
    return out[0], out[1], out[2], out[3]


@njit(**JIT)
def _platoon_tm(phi, g0, g1, c, k, i, kg, kv, tg, gmin, lx, lv, F):  # pragma: no cover
    T = lx.size
    A, V, X, U = np.empty((T, F)), np.empty((T, F)), np.empty((T, F)), np.empty((T, F))
    _platoon_tm_into(phi, g0, g1, c, k, i, kg, kv, tg, gmin, lx, lv, F, A, V, X, U)
    return A, V, X, U


@njit(**JIT)
def _platoon_tm_into(
    phi, g0, g1, c, k, i, kg, kv, tg, gmin, lx, lv, F, A, V, X, U
):  # pragma: no cover
    # Time-major: all followers advance one sample together. Follower j's command at
    # sample n uses follower j-1's state at n, so within a sample the followers are
    # independent recurrences: the loops over j vectorize. Outputs are (sample,
    # follower) arrays; the delay line is a ring of (power of two, F) rows.
    T = lx.size
    l0, l1 = phi[0, 0], phi[1, 1]
    pv0, pv1, pvv = phi[2, 0], phi[2, 1], phi[2, 2]
    px0, px1, pxv, pxx = phi[3, 0], phi[3, 1], phi[3, 2], phi[3, 3]
    a0, a1, av, ax = g0[0], g0[1], g0[2], g0[3]
    b0, b1, bv, bx = g1[0], g1[1], g1[2], g1[3]
    c0, c1 = c[0], c[1]
    cap = 1
    while cap < i + 2:
        cap *= 2
    mask = cap - 1
    ring = np.zeros((cap, F))
    z0 = np.zeros(F)
    z1 = np.zeros(F)
    sv = np.empty(F)
    sx = np.empty(F)
    w1 = np.zeros(F)
    aheadx = np.empty(F)
    aheadv = np.empty(F)
    v0 = lv[0]
    gap = gmin + tg * v0
    p = lx[0]
    for j in range(F):
        p = p - gap
        sv[j] = v0
        sx[j] = p
    for n in range(T):
        aheadx[0] = lx[n]
        aheadv[0] = lv[n]
        for j in range(1, F):
            aheadx[j] = sx[j - 1]
            aheadv[j] = sv[j - 1]
        An = A[n]
        Vn = V[n]
        Xn = X[n]
        Un = U[n]
        Rn = ring[n & mask]
        W0 = ring[(n - i) & mask]
        for j in range(F):
            y = c0 * z0[j] + c1 * z1[j]
            u = kg * (aheadx[j] - sx[j] - tg * sv[j] - gmin) + kv * (aheadv[j] - sv[j])
            An[j] = y
            Vn[j] = sv[j]
            Xn[j] = sx[j]
            Un[j] = u
            Rn[j] = u + k * y
        for j in range(F):
            w0 = W0[j]
            wp = w1[j]
            zz0 = z0[j]
            zz1 = z1[j]
            vv = sv[j]
            z0[j] = l0 * zz0 + (a0 * w0 + b0 * wp)
            z1[j] = l1 * zz1 + (a1 * w0 + b1 * wp)
            sv[j] = pvv * vv + (pv0 * zz0 + pv1 * zz1) + (av * w0 + bv * wp)
            sx[j] = pxx * sx[j] + pxv * vv + (px0 * zz0 + px1 * zz1) + (ax * w0 + bx * wp)
            w1[j] = w0


def platoon_time_major(
    md: Modal, up: avll.UpperLevel, lead_x: np.ndarray, lead_v: np.ndarray, followers: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Platoon, time-major and modal: every follower advances one sample together.
    Returns (follower, sample) views of (sample, follower) arrays."""
    A, V, X, U = _platoon_tm(
        md.phi, md.g0, md.g1, md.c, md.k, md.i, up.kg, up.kv, up.Tg, up.Gmin, lead_x, lead_v,
        int(followers),
    )  # fmt: skip
    out = (A.T, V.T, X.T, U.T)
    if _first_diverged(A.reshape(-1), 0, A.size) >= 0:  # a scan, no temporaries
        _platoon_nan(*out)
    return out


def platoon_time_major_into(
    md: Modal, up: avll.UpperLevel, lead_x: np.ndarray, lead_v: np.ndarray, followers: int,
    out: tuple[np.ndarray, ...],
) -> tuple[np.ndarray, ...]:
    """:func:`platoon_time_major` into ``out``: four (follower, sample) arrays that
    are transposes of C-contiguous (sample, follower) arrays."""
    A, V, X, U = (o.T for o in out)
    _platoon_tm_into(
        md.phi, md.g0, md.g1, md.c, md.k, md.i, up.kg, up.kv, up.Tg, up.Gmin, lead_x, lead_v,
        int(followers), A, V, X, U,
    )  # fmt: skip
    if _first_diverged(A.reshape(-1), 0, A.size) >= 0:
        _platoon_nan(*out)
    return out


# ---------------------------------------------------------------------------
# (d) Batched Eq. 6 cost: discretization and stability test inside numba.
# ---------------------------------------------------------------------------


@njit(**JIT)
def _mm3(A, B, out):  # pragma: no cover - compiled
    for r in range(3):
        for col in range(3):
            out[r, col] = A[r, 0] * B[0, col] + A[r, 1] * B[1, col] + A[r, 2] * B[2, col]


@njit(**JIT)
def _expm3(M):  # pragma: no cover - compiled
    # Scaling and squaring of the Taylor series (3x3: ||M / 2^s|| <= 1/4, 18 terms).
    norm = 0.0
    for r in range(3):
        norm = max(norm, abs(M[r, 0]) + abs(M[r, 1]) + abs(M[r, 2]))
    s = 0
    if norm > 0.25:
        s = int(math.ceil(math.log2(norm / 0.25)))
    A = M / 2.0**s
    E = np.eye(3)
    term = np.eye(3)
    tmp = np.empty((3, 3))
    for q in range(1, 19):
        _mm3(term, A, tmp)
        for r in range(3):
            for col in range(3):
                term[r, col] = tmp[r, col] / q
                E[r, col] += term[r, col]
    for _ in range(s):
        _mm3(E, E, tmp)
        E[:, :] = tmp
    return E


@njit(**JIT)
def _hold2(A, B, tau):  # pragma: no cover - compiled
    # expm([[A, B], [0, 0]] tau) = [[Phi, Gamma], [0, 1]]; inf when out of range.
    M = np.zeros((3, 3))
    for r in range(2):
        for col in range(2):
            M[r, col] = A[r, col] * tau
        M[r, 2] = B[r] * tau
    for r in range(2):
        for col in range(3):
            if not abs(M[r, col]) <= MAX_SCALED_ENTRY:
                return np.full((2, 2), np.inf), np.full(2, np.inf)
    E = _expm3(M)
    return E[:2, :2].copy(), E[:2, 2].copy()


@njit(**JIT)
def _discretize_proposed(p, dt):  # pragma: no cover - compiled
    """(valid, phi, g0, g1, c, K, i) of a proposed-model row (m1, m2, m3, K0, Td, K)
    in the reference's observable canonical form."""
    m1, m2, m3, k0, td, kk = p[0], p[1], p[2], p[3], p[4], p[5]
    phi = np.zeros((2, 2))
    g0 = np.zeros(2)
    g1 = np.zeros(2)
    c = np.array([1.0, 0.0])
    for j in range(6):
        if not math.isfinite(p[j]):
            return False, phi, g0, g1, c, kk, 0
    if not (m2 > 0.0 and td >= 0.0):
        return False, phi, g0, g1, c, kk, 0
    A = np.array([[-m3 / m2, 1.0], [-1.0 / m2, 0.0]])
    B = np.array([m1 / m2, k0 / m2])
    r = td / dt
    i = math.floor(r)
    f = r - i
    if f < 1e-12:
        f = 0.0
    if i > (1 << 24):
        return False, phi, g0, g1, c, kk, 0
    phi_r, gam_r = _hold2(A, B, (1.0 - f) * dt)
    if f > 0.0:
        phi_f, gam_f = _hold2(A, B, f * dt)
        for row in range(2):
            for col in range(2):
                phi[row, col] = phi_r[row, 0] * phi_f[0, col] + phi_r[row, 1] * phi_f[1, col]
            g1[row] = phi_r[row, 0] * gam_f[0] + phi_r[row, 1] * gam_f[1]
    else:
        phi[:, :] = phi_r
    g0[:] = gam_r
    ok = np.all(np.isfinite(phi)) and np.all(np.isfinite(g0)) and np.all(np.isfinite(g1))
    return ok, phi, g0, g1, c, kk, int(i)


@njit(**JIT)
def _schur_stable(cf):  # pragma: no cover - compiled
    # All roots of the polynomial (ascending coefficients) strictly inside the unit
    # circle: the Schur-Cohn reduction, normalised as avll's.
    n = cf.size - 1
    while n > 0 and cf[n] == 0.0:
        n -= 1
    for j in range(n + 1):
        if not math.isfinite(cf[j]):
            return False
    q = np.zeros(n + 1)
    while n > 0:
        a0 = cf[0]
        an = cf[n]
        if not abs(a0) < abs(an):
            return False
        for j in range(n):
            q[j] = an * cf[j + 1] - a0 * cf[n - 1 - j]
        n -= 1
        lead = q[n]
        if not (math.isfinite(lead) and lead > 0.0):
            return False
        for j in range(n + 1):
            cf[j] = q[j] / lead
    return True


@njit(**JIT)
def _inner_loop_stable(phi, g0, g1, c, kk, b0, a1, a2, i):  # pragma: no cover - compiled
    # The sampled lower level with u_ref = u + K y closed at the samples:
    # p(z) = z^{i+1} det(zI - Phi) - K (z N0(z) + N1(z)), Nk = c adj(zI - Phi) gk.
    if kk == 0.0:
        return a1 > 0.0 and a2 >= 0.0
    if kk * b0 >= 1.0:
        return False
    deg = i + 3
    if deg > (1 << 14):
        return True
    p = np.zeros(deg + 1)
    f11, f12, f21, f22 = phi[0, 0], phi[0, 1], phi[1, 0], phi[1, 1]
    p[i + 1] = f11 * f22 - f12 * f21
    p[i + 2] = -(f11 + f22)
    p[i + 3] = 1.0
    c1, c2 = c[0], c[1]
    n00 = c1 * (f12 * g0[1] - f22 * g0[0]) + c2 * (f21 * g0[0] - f11 * g0[1])
    n01 = c1 * g0[0] + c2 * g0[1]
    n10 = c1 * (f12 * g1[1] - f22 * g1[0]) + c2 * (f21 * g1[0] - f11 * g1[1])
    n11 = c1 * g1[0] + c2 * g1[1]
    p[0] -= kk * n10
    p[1] -= kk * (n11 + n00)
    p[2] -= kk * n01
    return _schur_stable(p)


@njit(**JIT)
def _sse_plain(phi, g0, g1, c, k, i, u, meas):  # pragma: no cover - compiled
    T = u.size
    cap = 1
    while cap < i + 2:
        cap *= 2
    mask = cap - 1
    buf = np.zeros(cap)
    p00, p01, p10, p11 = phi[0, 0], phi[0, 1], phi[1, 0], phi[1, 1]
    a0, a1, b0, b1 = g0[0], g0[1], g1[0], g1[1]
    c0, c1 = c[0], c[1]
    x0 = 0.0
    x1 = 0.0
    s = 0.0
    for n in range(T):
        y = c0 * x0 + c1 * x1
        if not abs(y) < 1e6:
            return np.inf
        e = y - meas[n]
        s += e * e
        buf[n & mask] = u[n] + k * y
        w0 = buf[(n - i) & mask]
        w1 = buf[(n - i - 1) & mask]
        x0, x1 = (
            p00 * x0 + p01 * x1 + a0 * w0 + b0 * w1,
            p10 * x0 + p11 * x1 + a1 * w0 + b1 * w1,
        )
    return s


@njit(**FAST)
def _sse_modal(l0, l1, a0, a1, b0, b1, c0, c1, k, i, u, meas, thr):  # pragma: no cover
    # Modal form, ring-buffer delay line indexed with a mask (branch-free, stays in
    # L1), no divergence test in the hot loop: a sample with |y| >= 1e6 makes the sum
    # at least (1e6 - max|meas|)^2 > thr, so a sum below thr proves there was none;
    # otherwise (rare) the rollout is replayed with the test.
    T = u.size
    cap = 1
    while cap < i + 2:
        cap *= 2
    mask = cap - 1
    buf = np.zeros(cap)
    z0 = 0.0
    z1 = 0.0
    w1 = 0.0
    s = 0.0
    for n in range(T):
        y = c0 * z0 + c1 * z1
        e = y - meas[n]
        s += e * e
        buf[n & mask] = u[n] + k * y
        w0 = buf[(n - i) & mask]
        z0 = l0 * z0 + (a0 * w0 + b0 * w1)
        z1 = l1 * z1 + (a1 * w0 + b1 * w1)
        w1 = w0
    if s < thr:
        return s
    buf[:] = 0.0
    z0 = 0.0
    z1 = 0.0
    w1 = 0.0
    for n in range(T):
        y = c0 * z0 + c1 * z1
        if not abs(y) < 1e6:
            return np.inf
        buf[n & mask] = u[n] + k * y
        w0 = buf[(n - i) & mask]
        z0 = l0 * z0 + (a0 * w0 + b0 * w1)
        z1 = l1 * z1 + (a1 * w0 + b1 * w1)
        w1 = w0
    return s


@njit(**JIT)
def _modal2(phi, g0, g1, c):  # pragma: no cover - compiled
    """(ok, l0, l1, a0, a1, b0, b1, c0, c1): the 2x2 step diagonalised when its
    eigenvalues are real and well separated."""
    p00, p01, p10, p11 = phi[0, 0], phi[0, 1], phi[1, 0], phi[1, 1]
    tr = p00 + p11
    det = p00 * p11 - p01 * p10
    disc = 0.25 * tr * tr - det
    scale = max(abs(tr), 1e-300)
    if not disc > (1e-6 * scale) ** 2:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    sq = math.sqrt(disc)
    l0 = 0.5 * tr + sq
    l1 = 0.5 * tr - sq
    # eigenvectors v_j = (p01, l_j - p00) or (l_j - p11, p10)
    if abs(p01) >= abs(p10):
        v00, v10 = p01, l0 - p00
        v01, v11 = p01, l1 - p00
    else:
        v00, v10 = l0 - p11, p10
        v01, v11 = l1 - p11, p10
    dv = v00 * v11 - v01 * v10
    if dv == 0.0 or not math.isfinite(dv):
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    # V^-1 = [[v11, -v01], [-v10, v00]] / dv
    a0 = (v11 * g0[0] - v01 * g0[1]) / dv
    a1 = (-v10 * g0[0] + v00 * g0[1]) / dv
    b0 = (v11 * g1[0] - v01 * g1[1]) / dv
    b1 = (-v10 * g1[0] + v00 * g1[1]) / dv
    c0 = c[0] * v00 + c[1] * v10
    c1 = c[0] * v01 + c[1] * v11
    return True, l0, l1, a0, a1, b0, b1, c0, c1


@njit(parallel=True, **JIT)
def _cost_plain(params, u, meas, offsets, dt):  # pragma: no cover - compiled
    P = params.shape[0]
    R = offsets.size - 1
    out = np.empty((P, R))
    for q in prange(P):
        p = params[q]
        ok, phi, g0, g1, c, kk, i = _discretize_proposed(p, dt)
        if ok:
            ok = _inner_loop_stable(phi, g0, g1, c, kk, p[3], p[2], p[1], i)
        for r in range(R):
            lo, hi = offsets[r], offsets[r + 1]
            if ok:
                out[q, r] = _sse_plain(phi, g0, g1, c, kk, i, u[lo:hi], meas[lo:hi]) / (hi - lo)
            else:
                out[q, r] = np.inf
    return out


@njit(**JIT)
def _modal_direct(p, dt):  # pragma: no cover - compiled
    """The proposed model's discrete step straight in modal form, from the
    continuous poles (no matrix exponential): ``(status, coef, i)`` with status 0
    invalid, 1 modal, 2 poles complex or nearly repeated (use the expm path);
    ``coef = (l0, l1, a0, a1, b0, b1, c0, c1)``.

    Observable form ``A = [[-a1, 1], [-a0, 0]]`` (``a1 = m3/m2``, ``a0 = 1/m2``) has
    the eigenvectors ``(lam, -a0)``; per mode ``z' = lam z + beta w``, so over a
    hold of ``tau`` seconds ``z -> e^{lam tau} z + beta expm1(lam tau)/lam w``."""
    coef = np.zeros(8)
    m1, m2, m3, k0, td = p[0], p[1], p[2], p[3], p[4]
    for j in range(6):
        if not math.isfinite(p[j]):
            return 0, coef, 0
    if not (m2 > 0.0 and td >= 0.0):
        return 0, coef, 0
    a1 = m3 / m2
    a0 = 1.0 / m2
    bb1 = m1 / m2
    bb0 = k0 / m2
    big = max(max(abs(a1), abs(a0)), max(abs(bb1), abs(bb0)))
    if not big * dt <= MAX_SCALED_ENTRY:
        return 0, coef, 0
    disc = a1 * a1 - 4.0 * a0
    if not disc > 1e-8 * a1 * a1:
        return 2, coef, 0
    q = -0.5 * (a1 + math.copysign(math.sqrt(disc), a1))
    lam0 = q
    lam1 = a0 / q
    r = td / dt
    i = math.floor(r)
    f = r - i
    if f < 1e-12:
        f = 0.0
    if i > (1 << 24):
        return 0, coef, 0
    det = a0 * (lam1 - lam0)
    beta0 = (-a0 * bb1 - lam1 * bb0) / det
    beta1 = (a0 * bb1 + lam0 * bb0) / det
    tr = (1.0 - f) * dt
    tf = f * dt
    coef[0] = math.exp(lam0 * tr) * math.exp(lam0 * tf)
    coef[1] = math.exp(lam1 * tr) * math.exp(lam1 * tf)
    coef[2] = beta0 * math.expm1(lam0 * tr) / lam0
    coef[3] = beta1 * math.expm1(lam1 * tr) / lam1
    coef[4] = math.exp(lam0 * tr) * beta0 * math.expm1(lam0 * tf) / lam0
    coef[5] = math.exp(lam1 * tr) * beta1 * math.expm1(lam1 * tf) / lam1
    coef[6] = lam0
    coef[7] = lam1
    for j in range(8):
        if not math.isfinite(coef[j]):
            return 0, coef, 0
    return 1, coef, int(i)


@njit(**JIT)
def _modal_stable(coef, kk, b0, a1, a2, i):  # pragma: no cover - compiled
    # avll's inner-loop test on the modal form (the polynomial is invariant):
    # det(zI - Phi) = (z - l0)(z - l1), Nk(z) = c0 gk0 (z - l1) + c1 gk1 (z - l0).
    if kk == 0.0:
        return a1 > 0.0 and a2 >= 0.0
    if kk * b0 >= 1.0:
        return False
    deg = i + 3
    if deg > (1 << 14):
        return True
    l0, l1, g00, g01, g10, g11, c0, c1 = (
        coef[0], coef[1], coef[2], coef[3], coef[4], coef[5], coef[6], coef[7],
    )  # fmt: skip
    p = np.zeros(deg + 1)
    p[i + 1] = l0 * l1
    p[i + 2] = -(l0 + l1)
    p[i + 3] = 1.0
    n01 = c0 * g00 + c1 * g01
    n00 = -(c0 * g00 * l1 + c1 * g01 * l0)
    n11 = c0 * g10 + c1 * g11
    n10 = -(c0 * g10 * l1 + c1 * g11 * l0)
    p[0] -= kk * n10
    p[1] -= kk * (n11 + n00)
    p[2] -= kk * n01
    return _schur_stable(p)


@njit(parallel=True, **FAST)
def _cost_modal(params, u, meas, offsets, dt):  # pragma: no cover - compiled
    P = params.shape[0]
    R = offsets.size - 1
    out = np.empty((P, R))
    thr = np.empty(R)
    for r in range(R):
        big = np.max(np.abs(meas[offsets[r] : offsets[r + 1]]))
        thr[r] = 0.99 * (1e6 - big) ** 2 if big < 0.5e6 else 0.0
    for q in prange(P):
        p = params[q]
        status, coef, i = _modal_direct(p, dt)
        if status == 2:  # complex or repeated poles: expm and the plain step
            ok, phi, g0, g1, c, kk, i = _discretize_proposed(p, dt)
            if ok:
                ok = _inner_loop_stable(phi, g0, g1, c, kk, p[3], p[2], p[1], i)
            for r in range(R):
                lo, hi = offsets[r], offsets[r + 1]
                if ok:
                    s = _sse_plain(phi, g0, g1, c, kk, i, u[lo:hi], meas[lo:hi])
                    out[q, r] = s / (hi - lo)
                else:
                    out[q, r] = np.inf
            continue
        if status == 0 or not _modal_stable(coef, p[5], p[3], p[2], p[1], i):
            out[q, :] = np.inf
            continue
        l0, l1, a0, a1, b0, b1, c0, c1 = (
            coef[0], coef[1], coef[2], coef[3], coef[4], coef[5], coef[6], coef[7],
        )  # fmt: skip
        for r in range(R):
            lo, hi = offsets[r], offsets[r + 1]
            s = _sse_modal(l0, l1, a0, a1, b0, b1, c0, c1, p[5], i, u[lo:hi], meas[lo:hi], thr[r])
            out[q, r] = s / (hi - lo) if math.isfinite(s) else np.inf
    return out


def pack(runs: Sequence[avll.Run]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Open-loop acceleration runs as ``(command, a, offsets, dt)``: concatenated
    series and run boundaries, packed once as a user would (one dt for all runs)."""
    dts = {float(r.dt) for r in runs}
    if len(dts) != 1:
        raise ValueError(f"runs: the peers need one sample time, got {sorted(dts)}")
    if any(r.command is None or r.command_kind != "acceleration" for r in runs):
        raise ValueError("runs: the peers need acceleration commands")
    u = np.ascontiguousarray(np.concatenate([r.command for r in runs]))  # type: ignore[misc]
    a = np.ascontiguousarray(np.concatenate([r.a for r in runs]))
    offsets = np.concatenate([[0], np.cumsum([len(r) for r in runs])]).astype(np.int64)
    return u, a, offsets, dts.pop()


def cost_plain(params: np.ndarray, packed: tuple[Any, ...]) -> np.ndarray:
    """(P, R) per-run acceleration MSE: prange over parameter sets, plain loop."""
    u, a, offsets, dt = packed
    return _cost_plain(np.ascontiguousarray(params, dtype=np.float64), u, a, offsets, dt)


def cost_modal(params: np.ndarray, packed: tuple[Any, ...]) -> np.ndarray:
    """(P, R) per-run acceleration MSE: prange over parameter sets, modal form,
    branch-free delay line, divergence tested per block."""
    u, a, offsets, dt = packed
    return _cost_modal(np.ascontiguousarray(params, dtype=np.float64), u, a, offsets, dt)


# ---------------------------------------------------------------------------
# The registry the benchmark iterates over.
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Peer:
    """One peer of one workload: ``prepare`` (not timed: the discrete matrices, or the
    packed runs) and ``run`` (timed). ``variant`` is ``"plain"`` or ``"best"``."""

    name: str
    variant: str
    prepare: Any
    run: Any


def _disc(model: avll.LowerLevelModel, dt: float) -> Discrete:
    return discretize(model, dt)


def _modal(model: avll.LowerLevelModel, dt: float) -> Modal:
    return modal(discretize(model, dt))


def _block(model: avll.LowerLevelModel, dt: float) -> Block:
    return block(modal(discretize(model, dt)))


def _disc4(model: avll.LowerLevelModel, dt: float) -> Discrete:
    return discretize(model, dt, integrators=True)


def _modal4(model: avll.LowerLevelModel, dt: float) -> Modal:
    return modal(discretize(model, dt, integrators=True))


#: run(prepared, u) -> y
OPEN_PEERS = (
    Peer("numba plain loop (2x2 step, ring buffer)", "plain", _disc, open_plain),
    Peer("numba modal, ring-buffer delay line", "best", _modal, open_modal),
    Peer("numba, avll's four-sample block form", "block", _block, open_block),
)
#: run(prepared, upper, lead_x, lead_v, v0, x0) -> (a, v, x, command)
CLOSED_PEERS = (
    Peer("numba plain loop (4x4 step, per-sample check)", "plain", _disc4, closed_plain),
    Peer("numba modal, ring buffer, chunk checks", "best", _modal4, closed_modal),
)
#: run(prepared, upper, lead_x, lead_v, followers) -> (a, v, x, command), (follower, sample)
PLATOON_PEERS = (
    Peer("numba plain loop, follower-major", "plain", _disc4, platoon_plain),
    Peer("numba modal, time-major (followers vectorized)", "best", _modal4, platoon_time_major),
)
#: The peers writing into outputs the caller allocated once: run(prepared, ..., out),
#: the same arguments as the allocating peers' followed by the outputs.
OPEN_INTO_PEERS = (
    Peer("numba plain loop into a preallocated array", "plain", _disc, open_plain_into),
    Peer("numba modal into a preallocated array", "best", _modal, open_modal_into),
    Peer("numba block form into a preallocated array", "block", _block, open_block_into),
)
CLOSED_INTO_PEERS = (
    Peer("numba plain loop into preallocated arrays", "plain", _disc4, closed_plain_into),
    Peer("numba modal into preallocated arrays", "best", _modal4, closed_modal_into),
)
PLATOON_INTO_PEERS = (
    Peer("numba modal, time-major, into preallocated arrays", "best", _modal4,
         platoon_time_major_into),
)
#: run(params, prepared) -> (P, R) costs; prepare(runs) -> packed runs
COST_PEERS = (
    Peer("numba prange, plain loop (expm per set)", "plain", pack, cost_plain),
    Peer("numba prange, modal from the poles, no per-sample check", "best", pack, cost_modal),
)


def set_threads(n: int) -> None:
    """Threads of the prange peers (``numba.set_num_threads``)."""
    numba.set_num_threads(int(n))
