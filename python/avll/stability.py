"""Local and string stability of a platoon of identical AVs (paper Section IV).

For the upper-level law Eq. 3 on top of a lower-level model, the closed loop
``A_n = H(s) A_{n-1}`` has ``H = N/D`` (Eq. 8) once the dead time is replaced by
its Padé approximant (order 2 in the paper, Eq. 10). A grid point is

* locally stable when every root of ``D`` has a negative real part (Routh–Hurwitz);
* string stable when ``P(x) = |D(j√x)|² − |N(j√x)|² > 0`` for all ``x > 0``, decided
  exactly (the root at ``x = 0`` divided out, then a Sturm root count), not by
  sampling frequencies.

Codes: ``0`` locally unstable, ``1`` locally stable but string unstable, ``2`` both.
The engine is Rust (:mod:`avll._core`); :mod:`avll.reference.stability` is the
independent numpy oracle the tests compare it with.

Beyond the paper, :func:`exact_delay_codes` tests the true delay ``e^{-jωTd}``
(no Padé) and :func:`pade_report` shows where a Padé map differs from it.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from . import _atomic, _core
from ._limits import check_int, check_memory, check_number, check_threads
from .models import LowerLevelModel

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

__all__ = [
    "LOCAL_UNSTABLE",
    "STRING_UNSTABLE",
    "STABLE",
    "PADE_MAX_ORDER",
    "stability_map",
    "stability_points",
    "Thresholds",
    "thresholds",
    "kv_threshold",
    "capacity",
    "CAPACITY_LENGTH",
    "CAPACITY_SPEED",
    "exact_delay_string",
    "exact_delay_codes",
    "PadeReport",
    "pade_report",
    "plot_regions",
    "plot_thresholds",
]

LOCAL_UNSTABLE = 0
STRING_UNSTABLE = 1
STABLE = 2
#: Highest Padé order the engine accepts.
PADE_MAX_ORDER: int = int(_core.PADE_MAX_ORDER)


def _model(model: LowerLevelModel) -> tuple[str, list[float]]:
    if not isinstance(model, LowerLevelModel):
        raise ValueError(f"model: expected an avll model object, got {type(model).__name__}")
    return model.name, [float(v) for v in model.to_array()]


def _floats(name: str, x: Any) -> np.ndarray:
    if isinstance(x, (str, bytes)) or x is None:
        raise ValueError(f"{name}: expected numbers, got {x!r:.40}")
    try:
        return np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}: expected numbers ({e})") from None


def _grid_memory(what: str, points: float, per_point: float) -> None:
    check_memory(points * per_point, f"{what}: {points:.0f} points x {per_point:g} bytes",
                 "split the grid (e.g. a few kv values per call) and concatenate",
                 per=per_point, unit="points")


def _axis(name: str, x: Any) -> np.ndarray:
    arr = np.ascontiguousarray(np.atleast_1d(_floats(name, x)))
    if arr.ndim != 1:
        raise ValueError(f"{name}: must be a scalar or 1-D, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name}: is empty")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: values must be finite")
    return arr


def _order(pade_order: int) -> int:
    if isinstance(pade_order, (bool, str, bytes)) or not isinstance(pade_order, (int, float,
                                                                               np.number)):
        raise ValueError(f"pade_order: must be an integer, got {pade_order!r}")
    if not np.isfinite(pade_order) or int(pade_order) != pade_order:
        raise ValueError(f"pade_order: must be an integer, got {pade_order!r}")
    if not 1 <= int(pade_order) <= PADE_MAX_ORDER:
        raise ValueError(f"pade_order: must be in 1..{PADE_MAX_ORDER}, got {pade_order}")
    return int(pade_order)


def stability_map(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv: Any,
    pade_order: int = 2,
    *,
    threads: int = 0,
    progress: bool = False,
) -> np.ndarray:
    """Stability codes over the grid ``kg × tg × kv``: a uint8 array of shape
    ``(len(kg), len(tg), len(kv))`` (0 locally unstable, 1 string unstable, 2 stable).

    Runs in parallel with the GIL released (``threads=0``: all cores); memory is the
    output only. Ctrl-C interrupts a long map (``KeyboardInterrupt``); ``progress=True``
    shows a tqdm bar.
    """
    nt = check_threads(threads)
    name, p = _model(model)
    kg, tg, kv = _axis("kg", kg), _axis("tg", tg), _axis("kv", kv)
    order = _order(pade_order)
    # the uint8 map, and as much again for what a caller derives from it (codes == 2)
    _grid_memory(f"stability_map: {kg.size} kg x {tg.size} tg x {kv.size} kv",
                 float(kg.size) * tg.size * kv.size, 2.0)
    if not progress:
        return _core.stability_map(name, p, kg, tg, kv, order, nt)
    from tqdm import tqdm

    total = kg.size * tg.size * kv.size
    with tqdm(total=total, unit="pt", unit_scale=True, desc=f"stability {name}") as bar:

        def cb(done: int, _total: int) -> None:
            bar.update(done - bar.n)

        return _core.stability_map(name, p, kg, tg, kv, order, nt, cb)


def stability_points(
    model: LowerLevelModel, kg: Any, tg: Any, kv: Any, pade_order: int = 2, *, threads: int = 0
) -> np.ndarray:
    """Codes at scattered points ``(kg[i], tg[i], kv[i])`` (arrays broadcast)."""
    nt = check_threads(threads)
    name, p = _model(model)
    try:
        kg, tg, kv = np.broadcast_arrays(*(_floats(n, a) for n, a in
                                           (("kg", kg), ("tg", tg), ("kv", kv))))
    except ValueError as e:
        raise ValueError(f"kg, tg, kv: shapes do not broadcast ({e})") from None
    _grid_memory("stability_points", float(kg.size), 3 * 8.0 + 1.0)
    shape = kg.shape
    flat = [np.ascontiguousarray(a.ravel()) for a in (kg, tg, kv)]
    for n, a in zip(("kg", "tg", "kv"), flat, strict=True):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{n}: values must be finite")
    out = _core.stability_points(
        name, p, flat[0], flat[1], flat[2], _order(pade_order), nt
    )
    return out.reshape(shape)


# ---------------------------------------------------------------------------
# Thresholds and capacity
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Thresholds:
    """Thresholds read off a map (NaN where nothing is stable).

    ``kg_max[i]``: largest stable kg at ``kv[i]`` (over all Tg of the grid);
    ``tg_min[i]``: smallest stable Tg at ``kv[i]`` (over all kg of the grid);
    ``kv_last_stable``: largest kv of the grid with a stable point, and
    ``kv_first_empty``: the next grid value, from which on nothing is stable in the
    given ranges (NaN when the last kv still has stable points);
    ``tg_min_overall``: smallest stable Tg anywhere on the grid.
    """

    kv: np.ndarray
    kg_max: np.ndarray
    tg_min: np.ndarray
    kv_last_stable: float
    kv_first_empty: float
    tg_min_overall: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (NaN -> None)."""

        def clean(x: Any) -> Any:
            if isinstance(x, np.ndarray):
                return [clean(v) for v in x.tolist()]
            if isinstance(x, float) and not math.isfinite(x):
                return None
            return x

        return {k: clean(v) for k, v in asdict(self).items()}


def thresholds(codes: np.ndarray, kg: Any, tg: Any, kv: Any) -> Thresholds:
    """Thresholds of a map from :func:`stability_map` over the same axes."""
    kg, tg, kv = _axis("kg", kg), _axis("tg", tg), _axis("kv", kv)
    codes = np.asarray(codes)
    if codes.shape != (kg.size, tg.size, kv.size):
        raise ValueError(
            f"codes: shape {codes.shape} does not match the axes "
            f"({kg.size}, {tg.size}, {kv.size})"
        )
    stable = codes == STABLE
    any_kg = stable.any(axis=1)  # (kg, kv)
    any_tg = stable.any(axis=0)  # (tg, kv)
    kg_max = np.array(
        [kg[any_kg[:, j]].max() if any_kg[:, j].any() else np.nan for j in range(kv.size)]
    )
    tg_min = np.array(
        [tg[any_tg[:, j]].min() if any_tg[:, j].any() else np.nan for j in range(kv.size)]
    )
    has = stable.any(axis=(0, 1))
    order = np.argsort(kv)
    last = np.nan
    first_empty = np.nan
    for pos, j in enumerate(order):
        if has[j]:
            last = float(kv[j])
            first_empty = float(kv[order[pos + 1]]) if pos + 1 < len(order) else np.nan
    tg_all = tg[stable.any(axis=(0, 2))]
    return Thresholds(
        kv=kv.copy(),
        kg_max=kg_max,
        tg_min=tg_min,
        kv_last_stable=last,
        kv_first_empty=first_empty,
        tg_min_overall=float(tg_all.min()) if tg_all.size else np.nan,
    )


def kv_threshold(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv_lo: float,
    kv_hi: float,
    pade_order: int = 2,
    *,
    tol: float = 1e-5,
    threads: int = 0,
) -> float:
    """The kv beyond which no point of the ``kg × tg`` grid is stable, refined by
    bisection between ``kv_lo`` (some point stable) and ``kv_hi`` (none stable) to
    ``tol``. Assumes the stable set shrinks with kv (as in the paper's Fig. 5).
    """
    check_threads(threads)
    kg, tg = _axis("kg", kg), _axis("tg", tg)
    kv_lo, kv_hi = check_number(kv_lo, "kv_lo"), check_number(kv_hi, "kv_hi")
    tol = check_number(tol, "tol", positive=True)

    def any_stable(v: float) -> bool:
        m = stability_map(model, kg, tg, [v], pade_order, threads=threads)
        return bool((m == STABLE).any())

    lo, hi = float(kv_lo), float(kv_hi)
    if not any_stable(lo):
        raise ValueError(f"kv_lo: nothing is stable at kv = {lo}")
    if any_stable(hi):
        raise ValueError(f"kv_hi: some point is still stable at kv = {hi}")
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if any_stable(mid):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


#: Default constants of :func:`capacity`: with ``length / speed = 7/30 s`` the
#: formula gives the paper's capacities (the paper does not state its constants).
CAPACITY_LENGTH = 7.0
CAPACITY_SPEED = 30.0


def capacity(tg: Any, length: float = CAPACITY_LENGTH, speed: float = CAPACITY_SPEED) -> Any:
    """Capacity of stable flow per lane (veh/h) at time gap ``tg`` (s):
    ``q = 3600 / (tg + length / speed)``, the flow of vehicles of effective length
    ``length`` (m, vehicle plus standstill gap) at speed ``speed`` (m/s) keeping the
    time gap ``tg``. The defaults (``length/speed = 7/30`` s) reproduce the paper's
    1687.5 (1.9 s), 964.3 (3.5 s) and 1479.5 veh/h (2.2 s); the paper does not give
    its formula, this pair is inferred from those numbers. ``tg`` must be finite and
    >= 0 (a ``ValueError`` otherwise; NaN, e.g. "no stable Tg", gives NaN).
    """
    length = check_number(length, "length", nonneg=True)
    speed = check_number(speed, "speed", positive=True)
    t = _floats("tg", tg)
    bad = ~np.isnan(t) & ~((t >= 0) & np.isfinite(t))
    if np.any(bad):
        raise ValueError(f"tg: a time gap must be finite and >= 0, got {t[bad].ravel()[0]:g}")
    with np.errstate(divide="ignore"):
        q = 3600.0 / (t + length / speed)
    if np.any(np.isinf(q)):
        raise ValueError("tg: tg = 0 with length = 0 gives an infinite capacity")
    return q if np.ndim(tg) else float(q)


# ---------------------------------------------------------------------------
# Exact delay (no Padé)
# ---------------------------------------------------------------------------

#: Frequencies (rad/s) of the dense search of :func:`exact_delay_string`.
EXACT_W_MIN = 1e-3
EXACT_W_MAX = 60.0
EXACT_N_W = 3000


def _exact_margin_curve(
    lin: dict[str, float], kg: np.ndarray, tg: np.ndarray, kv: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """f(ω) = (1 − |H(jω)|²)/ω² · |D|²/D0²-free form: ``−Im(C conj B)/(ω |D|²)``
    for points (rows) × frequencies (columns), true delay ``e^{−jωTd}``."""
    s = 1j * w[None, :]
    g = (lin["b1"] * s + lin["b0"]) * np.exp(-s * lin["Td"])
    a = lin["a2"] * s * s + lin["a1"] * s + 1.0
    m = a - lin["K"] * g
    kg_, tg_, kv_ = kg[:, None], tg[:, None], kv[:, None]
    mu = kv_ + tg_ * kg_
    d = m * s * s + g * (mu * s + kg_)
    n = g * (kv_ * s + kg_)
    c = m * s + kg_ * tg_ * g
    b = d + n
    return -np.imag(c * np.conj(b)) / (w[None, :] * np.abs(d) ** 2)


def exact_delay_string(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv: Any,
    *,
    w_min: float = EXACT_W_MIN,
    w_max: float = EXACT_W_MAX,
    n_w: int = EXACT_N_W,
    xtol: float = 1e-9,
) -> tuple[np.ndarray, np.ndarray]:
    """String stability with the true delay: ``(stable, margin)`` per point.

    ``margin = min over ω > 0 of (1 − |H(jω)|²)/ω²`` (in s², > 0 iff string stable),
    from the exact low-frequency limit, a dense log-spaced search of ``n_w``
    frequencies on ``[w_min, w_max]`` and a golden-section refinement of every
    local minimum of the dense curve to a relative frequency tolerance ``xtol``
    (in log ω). The search stops at ``w_max``: beyond it ``|H|`` of these loops falls
    off like ``1/ω`` or faster (``G_fb`` is strictly proper and ``H ~ (kv s + kg) G_fb
    / s²``), so a user with unusual parameters should widen the range.
    """
    n_w = check_int(n_w, "n_w", min=2)
    kg, tg, kv = (np.atleast_1d(_floats(n, a)).ravel()
                  for n, a in (("kg", kg), ("tg", tg), ("kv", kv)))
    kg, tg, kv = np.broadcast_arrays(kg, tg, kv)
    _grid_memory(f"exact_delay_string: {n_w} frequencies", float(n_w), 16 * 8.0)
    lin = model.linear()
    # exact ω -> 0 limit: R(0)/D(0)^2 with R(0) = kg b0 (Tg b0 (2 kv + kg Tg) − 2 (1 − K b0))
    b0, k = lin["b0"], lin["K"]
    with np.errstate(divide="ignore", invalid="ignore"):
        low = (tg * b0 * (2 * kv + kg * tg) - 2 * (1 - k * b0)) / (kg * b0)
    w = np.geomspace(w_min, w_max, int(n_w))
    margin = np.where(np.isfinite(low), low, -np.inf)
    step = max(1, 2_000_000 // len(w))
    for lo in range(0, kg.size, step):
        sl = slice(lo, lo + step)
        f = _exact_margin_curve(lin, kg[sl], tg[sl], kv[sl], w)
        fmin = f.min(axis=1)
        # refine interior local minima of the dense curve (golden section in log ω)
        for i in range(f.shape[0]):
            row = f[i]
            best = fmin[i]
            loc = np.nonzero((row[1:-1] <= row[:-2]) & (row[1:-1] <= row[2:]))[0] + 1
            for j in loc:
                a_, b_ = math.log(w[j - 1]), math.log(w[j + 1])
                gr = (math.sqrt(5) - 1) / 2
                pk, pt, pv = kg[sl][i : i + 1], tg[sl][i : i + 1], kv[sl][i : i + 1]

                def fval(lw: float, pk: Any = pk, pt: Any = pt, pv: Any = pv) -> float:
                    w1 = np.array([math.exp(lw)])
                    return float(_exact_margin_curve(lin, pk, pt, pv, w1)[0, 0])

                c_, d_ = b_ - gr * (b_ - a_), a_ + gr * (b_ - a_)
                fc, fd = fval(c_), fval(d_)
                while b_ - a_ > xtol:
                    if fc < fd:
                        b_, d_, fd = d_, c_, fc
                        c_ = b_ - gr * (b_ - a_)
                        fc = fval(c_)
                    else:
                        a_, c_, fc = c_, d_, fd
                        d_ = a_ + gr * (b_ - a_)
                        fd = fval(d_)
                best = min(best, fc, fd)
            fmin[i] = best
        margin[sl] = np.minimum(margin[sl], fmin)
    return margin > 0, margin


def exact_delay_codes(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv: Any,
    *,
    orders: Sequence[int] = (6, 7, 8),
    threads: int = 0,
    **string_kw: Any,
) -> tuple[np.ndarray, np.ndarray]:
    """Codes with the true delay at scattered points, and a flag array ``settled``.

    Local stability of the quasi-polynomial: Routh–Hurwitz with Padé orders of rising
    ``orders``; ``settled`` is False where those orders disagree (the verdict is then
    that of the highest order). String stability: :func:`exact_delay_string`.
    """
    check_threads(threads)
    kg, tg, kv = np.broadcast_arrays(*(_floats(n, a).ravel()
                                       for n, a in (("kg", kg), ("tg", tg), ("kv", kv))))
    orders = [_order(o) for o in orders]
    if not orders:
        raise ValueError("orders: give at least one Padé order")
    locs = [stability_points(model, kg, tg, kv, o, threads=threads) > 0 for o in orders]
    local = locs[-1]
    settled = np.all([loc == local for loc in locs], axis=0)
    codes = np.zeros(kg.size, dtype=np.uint8)
    idx = np.nonzero(local)[0]
    if idx.size:
        st, _ = exact_delay_string(model, kg[idx], tg[idx], kv[idx], **string_kw)
        codes[idx] = np.where(st, STABLE, STRING_UNSTABLE)
    return codes, settled


@dataclass(frozen=True)
class PadeReport:
    """Where a Padé map differs from the exact-delay verdicts on the same grid.

    ``pade`` and ``exact`` are code maps (``(len(kg), len(tg), len(kv))``),
    ``differs`` their mismatch mask, ``unsettled`` where the rising-order local test
    did not settle; ``fraction`` the share of differing points.
    """

    pade_order: int
    pade: np.ndarray
    exact: np.ndarray
    differs: np.ndarray
    unsettled: np.ndarray
    fraction: float

    def summary(self) -> str:
        """One-line summary."""
        n = int(self.differs.sum())
        parts = []
        for a in range(3):
            for b in range(3):
                if a != b:
                    k = int(((self.pade == a) & (self.exact == b)).sum())
                    if k:
                        parts.append(f"{k} Padé {a} vs exact {b}")
        return (
            f"Padé-{self.pade_order} differs from the exact delay at {n} of "
            f"{self.pade.size} points ({100 * self.fraction:.3f} %)"
            + (": " + ", ".join(parts) if parts else "")
        )


def pade_report(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv: Any,
    pade_order: int = 2,
    *,
    threads: int = 0,
    **exact_kw: Any,
) -> PadeReport:
    """Compares the Padé-``pade_order`` map with the exact-delay verdicts on a grid
    (the exact side runs in numpy: keep such grids moderate, e.g. 10⁴–10⁵ points)."""
    check_threads(threads)
    kg, tg, kv = _axis("kg", kg), _axis("tg", tg), _axis("kv", kv)
    _grid_memory("pade_report", float(kg.size) * tg.size * kv.size, 8 * 8.0)
    pade = stability_map(model, kg, tg, kv, pade_order, threads=threads)
    g = np.meshgrid(kg, tg, kv, indexing="ij")
    codes, settled = exact_delay_codes(model, *g, threads=threads, **exact_kw)
    exact = codes.reshape(pade.shape)
    differs = exact != pade
    return PadeReport(
        pade_order=int(pade_order),
        pade=pade,
        exact=exact,
        differs=differs,
        unsettled=~settled.reshape(pade.shape),
        fraction=float(differs.mean()),
    )


# ---------------------------------------------------------------------------
# Figures (paper Figs. 5–8)
# ---------------------------------------------------------------------------


def _label(model: LowerLevelModel) -> str:
    return {"first": "first-order lag", "second": "second-order", "proposed": "proposed"}.get(
        model.name, model.name
    )


def plot_regions(
    models: Sequence[LowerLevelModel],
    kg: Any,
    tg: Any,
    kv_values: Sequence[float],
    pade_order: int = 2,
    *,
    maps: Sequence[np.ndarray] | None = None,
    threads: int = 0,
) -> Figure:
    """Stable regions (code 2) of several models in the kg–Tg plane, one panel per
    kv, overlaid (paper Figs. 5 and 7). ``maps`` may pass precomputed maps over
    ``kg × tg × kv_values``."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    kg, tg, kvs = _axis("kg", kg), _axis("tg", tg), _axis("kv_values", kv_values)
    if maps is None:
        maps = [stability_map(m, kg, tg, kvs, pade_order, threads=threads) for m in models]
    n = kvs.size
    ncol = min(n, 3)
    nrow = (n + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.6 * nrow), squeeze=False)
    colors = ["tab:blue", "tab:red", "tab:green", "tab:orange"]
    for j in range(n):
        ax = axes[j // ncol][j % ncol]
        for i, mp in enumerate(maps):
            st = (mp[:, :, j] == STABLE).astype(float).T  # (tg, kg)
            c = colors[i % len(colors)]
            if st.any():
                ax.contourf(kg, tg, st, levels=[0.5, 1.5], colors=[c], alpha=0.3)
                if 0 < st.mean() < 1:
                    ax.contour(kg, tg, st, levels=[0.5], colors=[c], linewidths=1.2)
        if not any((mp[:, :, j] == STABLE).any() for mp in maps):
            ax.text(0.5, 0.5, "nothing stable", ha="center", va="center",
                    transform=ax.transAxes)
        ax.set_xlim(kg[0], kg[-1])
        ax.set_ylim(tg[0], tg[-1])
        ax.set_title(f"kv = {kvs[j]:g} 1/s")
        ax.set_xlabel("kg (1/s²)")
        ax.set_ylabel("Tg (s)")
    for j in range(n, nrow * ncol):
        axes[j // ncol][j % ncol].set_visible(False)
    handles = [
        Patch(color=colors[i % len(colors)], alpha=0.4, label=f"{_label(m)}: stable")
        for i, m in enumerate(models)
    ]
    fig.suptitle(f"Stable regions (local and string), Padé order {pade_order}")
    fig.tight_layout()
    fig.legend(handles=handles, loc="upper center", ncol=len(models), frameon=False,
               bbox_to_anchor=(0.5, 0.0))
    return fig


def plot_thresholds(models: Sequence[LowerLevelModel], ths: Sequence[Thresholds]) -> Figure:
    """Thresholds of kg (largest stable) and Tg (smallest stable) against kv for several
    models (paper Figs. 6 and 8)."""
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.6))
    for m, th in zip(models, ths, strict=True):
        a1.plot(th.kv, th.kg_max, label=_label(m))
        a2.plot(th.kv, th.tg_min, label=_label(m))
    a1.set_xlabel("kv (1/s)")
    a1.set_ylabel("threshold of kg (1/s²)")
    a1.set_title("(a) largest stable kg")
    a2.set_xlabel("kv (1/s)")
    a2.set_ylabel("threshold of Tg (s)")
    a2.set_title("(b) smallest stable Tg")
    for a in (a1, a2):
        a.legend()
        a.grid(alpha=0.3)
    fig.tight_layout()
    return fig


# ---------------------------------------------------------------------------
# CLI: avll stability-map
# ---------------------------------------------------------------------------


def _range(spec: Sequence[str], name: str, log: bool = False) -> np.ndarray:
    try:
        lo, hi, n = float(spec[0]), float(spec[1]), int(spec[2])
    except (ValueError, IndexError):
        raise ValueError(f"--{name}: expected MIN MAX N, got {' '.join(spec)}") from None
    if n < 1 or not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise ValueError(f"--{name}: need finite MIN <= MAX and N >= 1, got {lo} {hi} {n}")
    if log:
        if lo <= 0:
            raise ValueError(f"--{name}: a log-spaced axis needs MIN > 0, got {lo}")
        return np.geomspace(lo, hi, n)
    return np.linspace(lo, hi, n)


def _cli(args: argparse.Namespace) -> int:
    from . import PAPER_TABLE_II

    if args.panels < 1:
        raise ValueError(f"--panels: must be >= 1, got {args.panels}")
    names = args.model or ["second", "proposed"]
    models = []
    for n in names:
        if n not in PAPER_TABLE_II:
            raise ValueError(f"--model: unknown model {n!r}; known: {', '.join(PAPER_TABLE_II)}")
        models.append(PAPER_TABLE_II[n])
    kg = _range(args.kg, "kg", log=args.kg_log)
    tg = _range(args.tg, "tg")
    kv = _range(args.kv, "kv")
    total = kg.size * tg.size * kv.size
    show = (not args.quiet) and total >= 2_000_000
    maps = [
        stability_map(m, kg, tg, kv, args.pade_order, threads=args.threads, progress=show)
        for m in models
    ]
    ths = [thresholds(mp, kg, tg, kv) for mp in maps]
    print(
        f"grid: kg {kg[0]:g}..{kg[-1]:g} ({kg.size}{', log' if args.kg_log else ''}), "
        f"Tg {tg[0]:g}..{tg[-1]:g} ({tg.size}), kv {kv[0]:g}..{kv[-1]:g} ({kv.size}), "
        f"Padé order {args.pade_order}"
    )
    print(f"{'model':<10} {'kv last stable':>15} {'kv first empty':>15} {'min Tg':>8} "
          f"{'capacity':>10}")
    for m, th in zip(models, ths, strict=True):
        cap = capacity(th.tg_min_overall, args.length, args.speed)
        print(f"{m.name:<10} {th.kv_last_stable:>15.6g} {th.kv_first_empty:>15.6g} "
              f"{th.tg_min_overall:>8.4g} {cap:>10.1f}")
    print()
    head = "kv".rjust(10) + "".join(
        f"{m.name + ' kg_max':>18}{m.name + ' Tg_min':>18}" for m in models
    )
    print(head)
    for j in range(kv.size):
        print(f"{kv[j]:>10.4g}" + "".join(
            f"{th.kg_max[j]:>18.6g}{th.tg_min[j]:>18.6g}" for th in ths
        ))
    if args.out:
        import matplotlib

        matplotlib.use("Agg")
        idx = np.unique(np.linspace(0, kv.size - 1, min(args.panels, kv.size)).round().astype(int))
        fig = plot_regions(models, kg, tg, kv[idx], args.pade_order,
                           maps=[mp[:, :, idx] for mp in maps])
        _atomic.savefig(fig, args.out, dpi=120, bbox_inches="tight")
        if args.thresholds_out:
            _atomic.savefig(plot_thresholds(models, ths), args.thresholds_out, dpi=120,
                            bbox_inches="tight")
        print(f"\nfigure written to {args.out}")
    if args.json:
        doc = {
            "grid": {"kg": [float(kg[0]), float(kg[-1]), kg.size, "log" if args.kg_log else "lin"],
                     "tg": [float(tg[0]), float(tg[-1]), tg.size],
                     "kv": [float(kv[0]), float(kv[-1]), kv.size],
                     "pade_order": args.pade_order},
            "capacity": {"formula": "3600 / (Tg + length / speed)", "length": args.length,
                         "speed": args.speed},
            "models": {m.name: {**th.to_dict(),
                                "capacity_at_min_tg": None if math.isnan(th.tg_min_overall)
                                else float(capacity(th.tg_min_overall, args.length, args.speed))}
                       for m, th in zip(models, ths, strict=True)},
        }
        _atomic.write_json(args.json, _atomic.json_safe(doc))
    return 0


def register_cli(sub: Any) -> None:
    """Registers ``avll stability-map``."""
    p = sub.add_parser(
        "stability-map",
        help="stability regions and thresholds over a kg-Tg-kv grid (paper Section IV)",
        description="Local (Routh-Hurwitz) and exact string stability of the paper's "
        "Table II models over a kg x Tg x kv grid; prints the thresholds, writes the "
        "region figure and optionally JSON.",
    )
    p.add_argument("--model", action="append", choices=["first", "second", "proposed"],
                   help="model(s) to map (repeat; default: second and proposed)")
    p.add_argument("--kg", nargs=3, default=["0.001", "2", "400"], metavar=("MIN", "MAX", "N"),
                   help="kg axis (1/s^2); default 0.001 2 400, log-spaced")
    p.add_argument("--kg-linear", dest="kg_log", action="store_false",
                   help="space the kg axis linearly instead of logarithmically")
    p.add_argument("--tg", nargs=3, default=["0", "15", "151"], metavar=("MIN", "MAX", "N"),
                   help="Tg axis (s); default 0 15 151 (0.1 s)")
    p.add_argument("--kv", nargs=3, default=["0", "1", "101"], metavar=("MIN", "MAX", "N"),
                   help="kv axis (1/s); default 0 1 101")
    p.add_argument("--pade-order", type=int, default=2, help="Padé order of the delay (1..10)")
    p.add_argument("--threads", type=int, default=0, help="worker threads (0: all cores)")
    p.add_argument("--out", default="stability-map.png", help="region figure (PNG/SVG)")
    p.add_argument("--thresholds-out", default=None, help="thresholds-vs-kv figure")
    p.add_argument("--panels", type=int, default=3, help="kv panels in the region figure")
    p.add_argument("--json", default=None, metavar="PATH", help="write the thresholds as JSON")
    p.add_argument("--length", type=float, default=CAPACITY_LENGTH,
                   help="effective vehicle length (m) of the capacity formula")
    p.add_argument("--speed", type=float, default=CAPACITY_SPEED,
                   help="speed (m/s) of the capacity formula")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cli)
