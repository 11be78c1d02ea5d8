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

Beyond the paper: :func:`boundary`, :func:`min_stable_tg` and :func:`kv_supremum`
compute boundaries and thresholds directly rather than off a grid;
:func:`exact_delay_codes` tests the true delay ``e^{-jωTd}`` (no Padé) exactly, and
:func:`pade_report` / :func:`pade_error_map` show where a Padé map differs from it.
Labelled (xarray), chunked (Dask) and distributed maps are in :mod:`avll.maps`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from . import _atomic, _core
from ._limits import (
    check_floats,
    check_int,
    check_memory,
    check_number,
    check_threads,
    fmt_bytes,
)
from .models import LowerLevelModel
from .paper import PADE_ORDER
from .paper import SECTION_IV_GRID as _G

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
    "boundary",
    "stable_intervals",
    "Extremum",
    "min_stable_tg",
    "kv_supremum",
    "pade_error_map",
    "PadeReport",
    "pade_report",
    "plot_regions",
    "plot_thresholds",
    "plot_boundaries",
    "CODE_MEANINGS",
    "DEFAULT_RANGES", "MIN_TG_BOX", "KV_SUP_BOX",
]

LOCAL_UNSTABLE = 0
STRING_UNSTABLE = 1
STABLE = 2
#: The meaning of the map codes (stored as an attribute of labelled maps).
CODE_MEANINGS = "0: locally unstable; 1: locally stable, string unstable; 2: stable"
#: Highest Padé order the engine accepts.
PADE_MAX_ORDER: int = int(_core.PADE_MAX_ORDER)


def _model(model: LowerLevelModel) -> tuple[str, list[float]]:
    if not isinstance(model, LowerLevelModel):
        raise ValueError(f"model: expected an avll model object, got {type(model).__name__}")
    return model.name, [float(v) for v in model.to_array()]


_SPLIT_GRID = "split the grid (e.g. a few kv values per call) and concatenate"


def _grid_memory(what: str, points: float, per_point: float, hint: str = _SPLIT_GRID) -> None:
    check_memory(points * per_point, f"{what}: {points:.0f} points x {per_point:g} bytes", hint,
                 per=per_point, unit="points")


def _with_progress(call: Callable[..., Any], progress: bool | str, total: int, desc: str,
                   unit_scale: bool = False) -> Any:
    """``call()``, or with ``progress`` (:func:`avll.progress.resolve_mode`) asking for it
    ``call(progress=cb)`` with ``cb(done, total)`` moving a bar of ``total`` points."""
    from .progress import Progress, resolve_mode

    if resolve_mode(progress) == "none":
        return call()
    with Progress(total, desc, unit="pt", unit_scale=unit_scale, mode=progress) as bar:
        return call(progress=lambda done, _total: bar.advance_to(done))


#: Largest ``n_scan`` (and ``n_w``) the engine accepts (a scan holds that many points
#: per thread).
MAX_SCAN: int = int(_core.MAX_SCAN)
#: Largest ``n_grid`` of :func:`min_stable_tg` / :func:`kv_supremum`.
MAX_GRID: int = int(_core.MAX_GRID)


def _n_threads(threads: int) -> int:
    """The worker threads a call with ``threads`` (0 = all cores) runs."""
    return threads if threads > 0 else int(_core.available_cores())


def _scan_memory(what: str, n_scan: int, threads: int, out_bytes: float = 0.0) -> None:
    """A boundary-type search: ``out_bytes`` of output, plus per thread a scan of
    ``n_scan`` points (8 bytes) and verdicts (1 byte) and its refined copy."""
    per_thread = 2.0 * (n_scan + 16) * 9.0
    check_memory(out_bytes + _n_threads(threads) * per_thread,
                 f"{what}: {fmt_bytes(out_bytes)} of output + {_n_threads(threads)} threads x "
                 f"n_scan={n_scan}",
                 "use a smaller n_scan or fewer threads, or split the grid into several calls "
                 "and concatenate")


def _axis(name: str, x: Any) -> np.ndarray:
    arr = np.require(np.atleast_1d(check_floats(x, name)), requirements=["C", "A"])
    if arr.ndim != 1:
        raise ValueError(f"{name}: must be a scalar or 1-D, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name}: is empty")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: values must be finite")
    return arr


def _order(pade_order: int) -> int:
    if (isinstance(pade_order, (bool, str, bytes))
            or not isinstance(pade_order, (int, float, np.number))
            or not np.isfinite(pade_order) or int(pade_order) != pade_order):
        raise ValueError(f"pade_order: must be an integer, got {pade_order!r}")
    if not 1 <= int(pade_order) <= PADE_MAX_ORDER:
        raise ValueError(f"pade_order: must be in 1..{PADE_MAX_ORDER}, got {pade_order}")
    return int(pade_order)


def stability_map(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv: Any,
    pade_order: int = PADE_ORDER,
    *,
    threads: int = 0,
    progress: bool | str = False,
) -> np.ndarray:
    """Stability codes over the grid ``kg × tg × kv``: a uint8 array of shape
    ``(len(kg), len(tg), len(kv))`` (0 locally unstable, 1 string unstable, 2 stable).

    Runs in parallel with the GIL released (``threads=0``: all cores); memory is the
    output only. Ctrl-C interrupts a long map (``KeyboardInterrupt``); ``progress``
    (``True``, ``"auto"``, ``"bar"``, ``"log"``) shows the points done on stderr
    (:mod:`avll.progress`).
    """
    nt = check_threads(threads)
    name, p = _model(model)
    kg, tg, kv = _axis("kg", kg), _axis("tg", tg), _axis("kv", kv)
    order = _order(pade_order)
    # the uint8 map, and as much again for what a caller derives from it (codes == 2)
    _grid_memory(f"stability_map: {kg.size} kg x {tg.size} tg x {kv.size} kv",
                 float(kg.size) * tg.size * kv.size, 2.0)
    return _with_progress(partial(_core.stability_map, name, p, kg, tg, kv, order, nt),
                          progress, kg.size * tg.size * kv.size, f"stability {name}",
                          unit_scale=True)


def stability_points(
    model: LowerLevelModel, kg: Any, tg: Any, kv: Any, pade_order: int = PADE_ORDER, *,
    threads: int = 0) -> np.ndarray:
    """Codes at scattered points ``(kg[i], tg[i], kv[i])`` (arrays broadcast)."""
    nt = check_threads(threads)
    name, p = _model(model)
    arrs = [check_floats(a, n) for n, a in (("kg", kg), ("tg", tg), ("kv", kv))]
    try:
        kg, tg, kv = np.broadcast_arrays(*arrs)
    except ValueError as e:
        raise ValueError(f"kg, tg, kv: shapes do not broadcast ({e})") from None
    _grid_memory("stability_points", float(kg.size), 3 * 8.0 + 1.0)
    out = _core.stability_points(name, p, *_points(kg, tg, kv), _order(pade_order), nt)
    return out.reshape(kg.shape)


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
    ``tg_min_overall``: smallest stable Tg anywhere on the grid;
    ``kg_edge`` / ``tg_edge``: the largest kg and smallest Tg of the grid (NaN when
    unknown): a ``kg_max`` equal to ``kg_edge`` (a ``tg_min`` equal to ``tg_edge``) is
    the grid's edge, the true threshold lies at or beyond it.
    """

    kv: np.ndarray
    kg_max: np.ndarray
    tg_min: np.ndarray
    kv_last_stable: float
    kv_first_empty: float
    tg_min_overall: float
    kg_edge: float = math.nan
    tg_edge: float = math.nan

    def plot(self, model: Any = None, label: str | None = None) -> Figure:
        """The thresholds against kv (:func:`avll.plotting.thresholds`); ``model`` (a
        model or its name) picks the colour."""
        from . import plotting

        m = model if model is not None else "model"
        return plotting.thresholds([m], [self], labels=None if label is None else [label])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary: NaN -> None with a ``"<key>_note"`` beside it
        (:func:`avll._atomic.json_safe`)."""
        out: dict[str, Any] = _atomic.json_safe(asdict(self))
        return out


def thresholds(codes: Any, kg: Any = None, tg: Any = None, kv: Any = None) -> Thresholds:
    """Thresholds of a map from :func:`stability_map` over the same axes, or of a
    labelled map from :func:`avll.map_dataset` (axes from its coordinates; a
    Dask-backed map is reduced chunk by chunk, see :func:`avll.maps.map_thresholds`)."""
    if kg is None and tg is None and kv is None and hasattr(codes, "dims"):
        # labelled: only the two reductions are computed (chunk by chunk with Dask)
        if tuple(codes.dims) != ("kg", "Tg", "kv"):
            raise ValueError("codes: expected a DataArray with dims ('kg', 'Tg', 'kv') "
                             "(from map_dataset)")
        stable = codes == STABLE
        any_kg, any_tg = stable.any("Tg"), stable.any("kg")
        if hasattr(any_kg.data, "dask"):
            import dask

            any_kg, any_tg = dask.compute(any_kg, any_tg)
        return _reduce(codes["kg"].values, codes["Tg"].values, codes["kv"].values,
                       np.asarray(any_kg.values, dtype=bool),
                       np.asarray(any_tg.values, dtype=bool))
    if kg is None or tg is None or kv is None:
        raise ValueError("kg, tg, kv: the axes are needed with a plain array of codes")
    kg, tg, kv = _axis("kg", kg), _axis("tg", tg), _axis("kv", kv)
    codes = np.asarray(codes)
    if codes.shape != (kg.size, tg.size, kv.size):
        raise ValueError(
            f"codes: shape {codes.shape} does not match the axes "
            f"({kg.size}, {tg.size}, {kv.size})"
        )
    stable = codes == STABLE
    return _reduce(kg, tg, kv, stable.any(axis=1), stable.any(axis=0))


def _reduce(kg: np.ndarray, tg: np.ndarray, kv: np.ndarray, any_kg: np.ndarray,
            any_tg: np.ndarray) -> Thresholds:
    """The thresholds from a map's two reductions: ``any_kg`` (kg, kv), some Tg
    stable; ``any_tg`` (tg, kv), some kg stable."""
    kg_max = np.array([kg[m].max() if m.any() else np.nan for m in any_kg.T])
    tg_min = np.array([tg[m].min() if m.any() else np.nan for m in any_tg.T])
    order = np.argsort(kv)
    # the last kv (in increasing order) with a stable point, and the grid value after it
    pos = np.flatnonzero(np.asarray(any_kg.any(axis=0))[order])
    last = float(kv[order[pos[-1]]]) if pos.size else np.nan
    first_empty = float(kv[order[pos[-1] + 1]]) if pos.size and pos[-1] + 1 < kv.size else np.nan
    tg_all = tg[any_tg.any(axis=1)]
    return Thresholds(
        kv=kv.copy(),
        kg_max=kg_max,
        tg_min=tg_min,
        kv_last_stable=last,
        kv_first_empty=first_empty,
        tg_min_overall=float(tg_all.min()) if tg_all.size else np.nan,
        kg_edge=float(np.max(kg)) if kg.size else np.nan,
        tg_edge=float(np.min(tg)) if tg.size else np.nan,
    )


def kv_threshold(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv_lo: float,
    kv_hi: float,
    pade_order: int = PADE_ORDER,
    *,
    tol: float = 1e-5,
    threads: int = 0,
) -> float:
    """The kv beyond which no point of the ``kg × tg`` grid is stable, refined by
    bisection between ``kv_lo`` (some point stable) and ``kv_hi`` (none stable) to
    ``tol`` (the midpoint of the last bracket). Assumes the stable set shrinks with kv
    (as in the paper's Fig. 5). The bisection runs in Rust; each "is anything stable"
    test stops at the first stable grid point. This is a grid quantity: the
    continuous supremum over a (kg, Tg) box is :func:`kv_supremum`.
    """
    threads = check_threads(threads)
    name, p = _model(model)
    kg, tg = _axis("kg", kg), _axis("tg", tg)
    kv_lo, kv_hi = check_number(kv_lo, "kv_lo"), check_number(kv_hi, "kv_hi")
    tol = check_number(tol, "tol", positive=True)
    return float(_core.kv_threshold_grid(name, p, kg, tg, kv_lo, kv_hi, _order(pade_order), tol,
                                         threads=threads))


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
    t = check_floats(tg, "tg")
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

#: Frequencies (rad/s) of the sampled margin of :func:`exact_delay_string`.
EXACT_W_MIN = 1e-3
EXACT_W_MAX = 60.0
EXACT_N_W = 3000
#: Interval evaluations allowed per certified exact-delay string test.
EXACT_BUDGET = 20_000


#: Bytes per scattered point of an exact-delay call: three contiguous float64 copies
#: of the broadcast inputs, the uint8 code and the bool flag.
_POINT_BYTES = 3 * 8.0 + 2.0


def _broadcast_size(*arrays: Any) -> float:
    """The number of points :func:`_points` makes of the arrays (each is flattened;
    the lengths broadcast), before any copy is made."""
    return float(max(np.size(a) for a in arrays))


def _points(kg: Any, tg: Any, kv: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points as three contiguous float arrays (each flattened, the lengths
    broadcast), checked finite."""
    flat = [np.atleast_1d(check_floats(a, n)).ravel() for n, a in
            (("kg", kg), ("tg", tg), ("kv", kv))]
    try:
        arrs = np.broadcast_arrays(*flat)
    except ValueError:
        raise ValueError("kg, tg, kv: lengths do not broadcast "
                         f"({', '.join(str(a.size) for a in flat)} points)") from None
    out = tuple(np.ascontiguousarray(a) for a in arrs)
    for n, a in zip(("kg", "tg", "kv"), out, strict=True):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{n}: values must be finite")
    return out  # type: ignore[return-value]


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
    budget: int = EXACT_BUDGET,
    threads: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """String stability with the true delay: ``(stable, margin)`` per point.

    ``stable`` is the certified verdict of the Rust engine: ``|H(jω)| < 1`` for every
    ``ω > 0``, proven by an interval-arithmetic sweep of ``(|D|² − |N|²)/ω²`` over
    ``[0, ω_c]`` (beyond ``ω_c`` a polynomial bound proves it), or disproven by a
    frequency where the enclosure is negative. A point the sweep cannot settle within
    ``budget`` interval evaluations (a point on the boundary) counts as not stable.
    ``margin`` is the sampled figure of merit ``min (1 − |H(jω)|²)/ω²`` (s²) over
    ``n_w`` log-spaced frequencies on ``[w_min, w_max]`` and ``ω → 0``, with each local
    minimum refined by golden section to ``xtol`` in ``log ω``; it is informative only
    (the verdict does not use it).
    """
    n_w = check_int(n_w, "n_w", min=2, max=MAX_SCAN)
    budget = check_int(budget, "budget", min=1)
    threads = check_threads(threads)
    w_min = check_number(w_min, "w_min", positive=True)
    w_max = check_number(w_max, "w_max", positive=True)
    xtol = check_number(xtol, "xtol", positive=True)
    name, p = _model(model)
    # contiguous copies of the inputs, verdicts (Verdict + 2 flags) and margins per
    # point; n_w samples twice per thread
    n_pts = _broadcast_size(kg, tg, kv)
    check_memory(n_pts * (_POINT_BYTES + 9.0) + _n_threads(threads) * 16.0 * n_w,
                 f"exact_delay_string: {n_pts:.0f} points, n_w={n_w}",
                 "split the points into several calls and concatenate",
                 per=_POINT_BYTES + 9.0, unit="points")
    kg, tg, kv = _points(kg, tg, kv)
    st, _ok = _core.delay_string(name, p, kg, tg, kv, int(budget), int(threads))
    margin = _core.delay_margin(
        name, p, kg, tg, kv, float(w_min), float(w_max), int(n_w), float(xtol), int(threads)
    )
    return st, margin


def exact_delay_codes(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv: Any,
    *,
    threads: int = 0,
    budget: int = EXACT_BUDGET,
) -> tuple[np.ndarray, np.ndarray]:
    """Codes with the true delay at scattered points, and a flag array ``settled``.

    Local stability of the quasi-polynomial ``A(s) + B(s) e^{−Td s}`` is decided
    exactly (crossing frequencies from ``|A(jω)| = |B(jω)|``, crossing directions and
    the root count of the delay-free polynomial), string stability by the certified
    sweep of :func:`exact_delay_string`. ``settled`` is False where a test could not
    decide (a point on a boundary; the code is then 0 or 1, never 2).
    """
    threads = check_threads(threads)
    budget = check_int(budget, "budget", min=1)
    name, p = _model(model)
    _grid_memory("exact_delay_codes", _broadcast_size(kg, tg, kv), _POINT_BYTES,
                 "split the points into several calls and concatenate")
    kg, tg, kv = _points(kg, tg, kv)
    codes, ok = _core.delay_points(name, p, kg, tg, kv, int(budget), int(threads))
    return codes, ok


def _exact_grid(model: LowerLevelModel, kg: np.ndarray, tg: np.ndarray, kv: np.ndarray,
                **kw: Any) -> tuple[np.ndarray, np.ndarray]:
    """:func:`exact_delay_codes` (``kw`` its keywords) over the grid ``kg x tg x kv``: the
    codes and the settled flags, each of shape ``(len(kg), len(tg), len(kv))``."""
    g = np.meshgrid(kg, tg, kv, indexing="ij")
    codes, settled = exact_delay_codes(model, *g, **kw)
    return codes.reshape(g[0].shape), settled.reshape(g[0].shape)


@dataclass(frozen=True)
class PadeReport:
    """Where a Padé map differs from the exact-delay verdicts on the same grid.

    ``pade`` and ``exact`` are code maps (``(len(kg), len(tg), len(kv))``),
    ``differs`` their mismatch mask, ``unsettled`` where the exact-delay test could
    not decide (a point on a boundary); ``fraction`` the share of differing points.
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
        counts = {(a, b): int(((self.pade == a) & (self.exact == b)).sum())
                  for a in range(3) for b in range(3) if a != b}
        parts = [f"{k} Padé {a} vs exact {b}" for (a, b), k in counts.items() if k]
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
    pade_order: int = PADE_ORDER,
    *,
    threads: int = 0,
    **exact_kw: Any,
) -> PadeReport:
    """Compares the Padé-``pade_order`` map with the exact-delay verdicts on a grid
    (the exact side is the certified Rust test, much slower than the Padé map: keep
    such grids moderate). :func:`pade_error_map` compares several orders at once."""
    check_threads(threads)
    kg, tg, kv = _axis("kg", kg), _axis("tg", tg), _axis("kv", kv)
    _grid_memory("pade_report", float(kg.size) * tg.size * kv.size, 8 * 8.0)
    pade = stability_map(model, kg, tg, kv, pade_order, threads=threads)
    exact, settled = _exact_grid(model, kg, tg, kv, threads=threads, **exact_kw)
    differs = exact != pade
    return PadeReport(
        pade_order=int(pade_order),
        pade=pade,
        exact=exact,
        differs=differs,
        unsettled=~settled,
        fraction=float(differs.mean()),
    )


# ---------------------------------------------------------------------------
# Exact boundaries
# ---------------------------------------------------------------------------

_AXES = {"kg": 0, "Tg": 1, "kv": 2}
_ALIASES = {"kg": "kg", "tg": "Tg", "Tg": "Tg", "kv": "kv"}
#: Default searched range of each parameter of a 1-D search at fixed others
#: (:func:`boundary`, :func:`stable_intervals`): wider than the boxes below (down to a
#: negative kv), as it looks for where the stable set ends rather than for its extremum.
DEFAULT_RANGES = {"kg": (1e-4, 10.0), "Tg": _G["Tg"][:2], "kv": (-1.0, 2.0)}
#: Default box of the minimum stable time gap (:func:`min_stable_tg`, and the effects'
#: and the samples' in :mod:`avll.effect_stability`, :mod:`avll.maps`): the Section IV
#: grid's kv and Tg ranges, kg from the grid's smallest to 2 1/s².
MIN_TG_BOX = {"kg": (_G["kg"][0], 2.0), "kv": _G["kv"][:2], "Tg": _G["Tg"][:2]}
#: Default box of the kv supremum (:func:`kv_supremum`): the Section IV grid's kg and Tg
#: ranges, kv searched to 2 1/s, beyond the grid's 1.2, so that no supremum is cut there.
KV_SUP_BOX = {"kg": _G["kg"][:2], "Tg": _G["Tg"][:2], "kv": (0.0, 2.0)}
_LEVELS = {"string": 2, "local": 1}


def _pade_arg(pade_order: int | None) -> int:
    """0 selects the exact delay in the engine."""
    return 0 if pade_order is None else _order(pade_order)


def _range_arg(name: str, r: Any) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in r)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: expected (lo, hi), got {r!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"{name}: need finite lo < hi, got ({lo}, {hi})")
    return lo, hi


def _level_arg(level: str) -> int:
    if not isinstance(level, str) or level not in _LEVELS:
        raise ValueError(f"level: must be 'string' or 'local', got {level!r}")
    return _LEVELS[level]


def _attrs(model: LowerLevelModel, pade_order: int | None) -> dict[str, Any]:
    return {
        "model": model.name,
        "model_params": _atomic.dumps(model.to_dict(), indent=None),
        "pade_order": "exact" if pade_order is None else int(pade_order),
    }


def boundary(
    model: LowerLevelModel,
    which: str,
    *,
    kg: Any = None,
    tg: Any = None,
    kv: Any = None,
    pade_order: int | None = PADE_ORDER,
    search_range: tuple[float, float] | None = None,
    level: str = "string",
    n_scan: int = 256,
    rtol: float = 1e-10,
    threads: int = 0,
    progress: bool | str = False,
) -> Any:
    """A stability boundary computed directly (not read off a grid), as an
    ``xarray.DataArray``.

    ``which`` is ``"<axis>_min"`` or ``"<axis>_max"`` with axis ``tg``, ``kg`` or ``kv``:
    ``"tg_min"`` is, for every ``(kg, kv)`` of the given axes, the **infimum of the
    stable set in Tg within** ``search_range`` (default ``(0, 15)``) — stability
    regions in Tg need not be intervals, and the infimum is the lower end of the
    lowest stable stretch; ``"kg_max"`` the supremum of the stable kg for every
    ``(Tg, kv)`` (default range ``(1e-4, 10)``, scanned in log); ``"kv_max"`` the
    supremum of the stable kv for every ``(kg, Tg)``. NaN where no point of the
    searched range is stable; a value equal to an end of the range means the range
    itself is stable there. ``level="string"`` (code 2) or ``"local"`` (code ≥ 1).
    ``pade_order=None`` uses the exact delay (slower).

    Method: the stable set along the axis is scanned at ``n_scan`` points plus the
    exact D-subdivision values where a root of ``D`` crosses the imaginary axis and
    the values where ``R(0)`` or the leading coefficient of ``R`` vanish; each change
    of verdict is bisected on the exact test until the bracket is below ``rtol``
    relative. The returned value is the stable side of the final bracket (a point the
    exact test calls stable, with an unstable point within ``rtol``). A stable
    stretch narrower than the scan spacing that does not start at one of the exact
    values can be missed (see ``docs/stability.md``).
    """
    import xarray as xr

    if not isinstance(which, str) or "_" not in which:
        raise ValueError(f"which: expected e.g. 'tg_min' or 'kg_max', got {which!r}")
    ax_name, end = which.rsplit("_", 1)
    if ax_name not in _ALIASES or end not in ("min", "max"):
        raise ValueError(f"which: expected '<tg|kg|kv>_<min|max>', got {which!r}")
    axis = _ALIASES[ax_name]
    given = {"kg": kg, "Tg": tg, "kv": kv}
    fixed = [a for a in given if a != axis]
    for a in fixed:
        if given[a] is None:
            raise ValueError(f"{a.lower()}: needed for {which!r}")
    if given[axis] is not None:
        raise ValueError(f"{ax_name}: is the searched axis of {which!r}; use search_range")
    u, w = (_axis(a, given[a]) for a in fixed)
    lo, hi = _range_arg("search_range", search_range or DEFAULT_RANGES[axis])
    name, p = _model(model)
    log = axis == "kg" and lo > 0
    lev = _level_arg(level)
    threads = check_threads(threads)
    n_scan = check_int(n_scan, "n_scan", min=2, max=MAX_SCAN)
    rtol = check_number(rtol, "rtol", positive=True)
    _scan_memory(f"boundary: {u.size} {fixed[0]} x {w.size} {fixed[1]}", n_scan, threads,
                 8.0 * u.size * w.size)
    call = partial(_core.stability_boundary, name, p, _AXES[axis], u, w, lo, hi,
                   "inf" if end == "min" else "sup", pade_order=_pade_arg(pade_order),
                   level=lev, n_scan=n_scan, log=log, rtol=rtol, threads=threads)
    vals = _with_progress(call, progress, u.size * w.size, f"boundary {which}")
    attrs = {
        **_attrs(model, pade_order),
        "boundary": which,
        "definition": (
            f"{'infimum' if end == 'min' else 'supremum'} of the "
            f"{'locally' if lev == 1 else 'locally and string'} stable {axis} "
            f"within the searched range (NaN: nothing stable there)"
        ),
        "search_range": [lo, hi],
        "level": level,
        "n_scan": int(n_scan),
        "rtol": float(rtol),
    }
    return xr.DataArray(
        vals, dims=tuple(fixed), coords={fixed[0]: u, fixed[1]: w}, name=which, attrs=attrs
    )


def stable_intervals(
    model: LowerLevelModel,
    axis: str,
    *,
    kg: float | None = None,
    tg: float | None = None,
    kv: float | None = None,
    pade_order: int | None = PADE_ORDER,
    search_range: tuple[float, float] | None = None,
    level: str = "string",
    n_scan: int = 256,
    rtol: float = 1e-10,
) -> list[tuple[float, float]]:
    """The stable set along ``axis`` (``"kg"``, ``"tg"`` or ``"kv"``) through the point
    given by the other two parameters, within ``search_range``, as a list of
    ``(lo, hi)`` intervals (ends found as in :func:`boundary`)."""
    if not isinstance(axis, str) or axis not in _ALIASES:
        raise ValueError(f"axis: must be 'kg', 'tg' or 'kv', got {axis!r}")
    ax = _ALIASES[axis]
    given: dict[str, Any] = {"kg": kg, "Tg": tg, "kv": kv}
    if given[ax] is not None:
        raise ValueError(f"{axis}: is the searched axis; use search_range")
    given[ax] = 0.0
    for a, v in given.items():
        if v is None:
            raise ValueError(f"{a.lower()}: a finite value is needed")
    point = [check_number(v, a.lower()) for a, v in given.items()]
    lo, hi = _range_arg("search_range", search_range or DEFAULT_RANGES[ax])
    name, p = _model(model)
    n_scan = check_int(n_scan, "n_scan", min=2, max=MAX_SCAN)
    rtol = check_number(rtol, "rtol", positive=True)
    _scan_memory("stable_intervals", n_scan, 1)
    ivs = _core.stability_intervals(
        name, p, _AXES[ax], point, lo, hi, _pade_arg(pade_order), _level_arg(level),
        n_scan, ax == "kg" and lo > 0, rtol,
    )
    return [(a, b) for a, b, _, _ in ivs]


@dataclass(frozen=True)
class Extremum:
    """An extremum of a stability boundary over a box of two parameters.

    ``value``: the infimum (``min_stable_tg``) or supremum (``kv_supremum``) found;
    ``kg``, ``tg``, ``kv``: the boundary point where it is reached (the searched
    coordinate equals ``value``). The stable set is open, so an infimum/supremum on a
    boundary is approached, not attained: ``attained`` is True only when ``value`` is
    the end of the searched range and stable there. ``on_edge`` names the box
    coordinates that sit at an end of their range (the extremum is then approached as
    that parameter goes to the range end, e.g. ``kg -> 0``). ``capacity`` is
    :func:`capacity` at ``value`` (for ``min_stable_tg``).
    """

    quantity: str
    value: float
    kg: float
    tg: float
    kv: float
    attained: bool
    on_edge: tuple[str, ...]
    ranges: dict[str, tuple[float, float]]
    pade_order: int | None
    evaluations: int
    capacity: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary: non-finite -> None with a ``"<key>_note"`` beside it
        (:func:`avll._atomic.json_safe`)."""
        out: dict[str, Any] = _atomic.json_safe(asdict(self))
        return out


def _extremum(
    model: LowerLevelModel,
    which: str,
    r1: tuple[str, tuple[float, float]],
    r2: tuple[str, tuple[float, float]],
    r3: tuple[str, tuple[float, float]],
    pade_order: int | None,
    n_scan: int,
    n_grid: int,
    threads: int,
) -> Extremum:
    name, p = _model(model)
    rs = []
    for label, r in (r1, r2, r3):
        lo, hi = _range_arg(f"{label.lower()}_range", r)
        if label == "kg" and lo <= 0:
            raise ValueError(f"kg_range: the lower end must be > 0 (kg = 0 is never "
                             f"asymptotically stable), got {lo}")
        rs.append((lo, hi, label == "kg"))
    n_scan = check_int(n_scan, "n_scan", min=2, max=MAX_SCAN)
    n_grid = check_int(n_grid, "n_grid", min=2, max=MAX_GRID)
    threads = check_threads(threads)
    _scan_memory(which, n_scan, threads, 3 * 8.0 * n_grid)
    val, at, at_end, edge, evals = _core.stability_extremum(
        name, p, which, rs[0], rs[1], rs[2], _pade_arg(pade_order), n_scan,
        n_grid=n_grid, threads=threads,
    )
    kg, tg, kv = (float(x) for x in at)
    return Extremum(
        quantity=which,
        value=float(val),
        kg=kg,
        tg=tg,
        kv=kv,
        attained=bool(at_end) and float(val) == rs[2][0 if which == "tg_min" else 1],
        on_edge=tuple(lab for lab, e in zip((r1[0], r2[0]), edge, strict=True) if e),
        ranges={r1[0]: rs[0][:2], r2[0]: rs[1][:2], r3[0]: rs[2][:2]},
        pade_order=pade_order,
        evaluations=int(evals),
        capacity=float(capacity(val)) if which == "tg_min" and math.isfinite(val) else None,
    )


def min_stable_tg(
    model: LowerLevelModel,
    kg_range: tuple[float, float] = MIN_TG_BOX["kg"],
    kv_range: tuple[float, float] = MIN_TG_BOX["kv"],
    pade_order: int | None = PADE_ORDER,
    *,
    tg_range: tuple[float, float] = MIN_TG_BOX["Tg"],
    n_scan: int = 256,
    n_grid: int = 32,
    threads: int = 0,
) -> Extremum:
    """The minimum stable time gap as a true infimum: the infimum of Tg over every
    locally and string stable point with kg in ``kg_range``, kv in ``kv_range`` and Tg
    in ``tg_range``, and where it is approached.

    Nested 1-D searches of the boundary ``tg_min(kg, kv)`` (:func:`boundary`): an
    outer search over kv of the inner minimum over kg, each a scan of ``n_grid``
    points refined by golden section to ``1e-12`` of the range; where nothing is
    stable the boundary counts as ``+inf``, so a minimum at the tip of a closing
    stable region is approached from the stable side. The result is a stable point
    of the exact test (an upper bound of the infimum the search could not improve);
    the tests check it against dense grids.
    """
    return _extremum(model, "tg_min", ("kg", kg_range), ("kv", kv_range), ("tg", tg_range),
                     pade_order, n_scan, n_grid, threads)


def kv_supremum(
    model: LowerLevelModel,
    kg_range: tuple[float, float] = KV_SUP_BOX["kg"],
    tg_range: tuple[float, float] = KV_SUP_BOX["Tg"],
    pade_order: int | None = PADE_ORDER,
    *,
    kv_range: tuple[float, float] = KV_SUP_BOX["kv"],
    n_scan: int = 256,
    n_grid: int = 32,
    threads: int = 0,
) -> Extremum:
    """The kv threshold as a supremum: the largest kv with a locally and string stable
    point for some kg in ``kg_range`` and Tg in ``tg_range`` (kv searched in
    ``kv_range``), and where it is approached. Same method as :func:`min_stable_tg`
    (outer search over Tg, inner over kg, of the boundary ``kv_max(kg, Tg)``). Unlike
    :func:`kv_threshold` it does not depend on a grid."""
    return _extremum(model, "kv_max", ("kg", kg_range), ("tg", tg_range), ("kv", kv_range),
                     pade_order, n_scan, n_grid, threads)


def pade_error_map(
    model: LowerLevelModel,
    kg: Any,
    tg: Any,
    kv: Any,
    orders: Sequence[int] = tuple(range(1, 11)),
    *,
    threads: int = 0,
    budget: int = EXACT_BUDGET,
) -> Any:
    """Padé-error map: an ``xarray.Dataset`` with the exact-delay codes ``exact``
    (dims kg, Tg, kv), whether each is certified (``certified``), the Padé codes
    ``pade`` (dims pade_order, kg, Tg, kv), and per order the share of certified
    points where the Padé code differs (``fraction_differs``) and the counts of
    Padé-stable-but-exactly-unstable (``false_stable``) and the reverse
    (``false_unstable``) points."""
    import xarray as xr

    kg, tg, kv = _axis("kg", kg), _axis("tg", tg), _axis("kv", kv)
    orders = [_order(o) for o in orders]
    if not orders:
        raise ValueError("orders: at least one Padé order is needed")
    check_threads(threads)
    # the meshgrid and the exact codes, then per order a Padé map and three masks
    _grid_memory(f"pade_error_map: {kg.size} kg x {tg.size} tg x {kv.size} kv x "
                 f"{len(orders)} orders", float(kg.size) * tg.size * kv.size,
                 _POINT_BYTES + 4.0 * len(orders))
    exact, cert = _exact_grid(model, kg, tg, kv, threads=threads, budget=budget)
    pade = np.stack([stability_map(model, kg, tg, kv, o, threads=threads) for o in orders])
    # per order, the certified points where the Padé code differs, is falsely stable
    # and is falsely unstable
    per_order = (1, 2, 3)
    differs = ((pade != exact[None]) & cert[None]).sum(axis=per_order)
    fs = ((pade == STABLE) & (exact[None] != STABLE) & cert[None]).sum(axis=per_order)
    fu = ((pade != STABLE) & (exact[None] == STABLE) & cert[None]).sum(axis=per_order)
    coords = {"kg": kg, "Tg": tg, "kv": kv, "pade_order": np.array(orders)}
    attrs = {**_attrs(model, None), "codes": CODE_MEANINGS}
    return xr.Dataset(
        {
            "exact": (("kg", "Tg", "kv"), exact),
            "certified": (("kg", "Tg", "kv"), cert),
            "pade": (("pade_order", "kg", "Tg", "kv"), pade),
            "fraction_differs": (("pade_order",), differs / max(int(cert.sum()), 1)),
            "false_stable": (("pade_order",), fs),
            "false_unstable": (("pade_order",), fu),
        },
        coords=coords,
        attrs=attrs,
    )


# ---------------------------------------------------------------------------
# Figures (paper Figs. 5–8)
# ---------------------------------------------------------------------------


def plot_regions(
    models: Sequence[LowerLevelModel],
    kg: Any = None,
    tg: Any = None,
    kv_values: Sequence[float] | None = None,
    pade_order: int = PADE_ORDER,
    *,
    maps: Sequence[Any] | None = None,
    threads: int = 0,
    labels: Sequence[str] | None = None,
) -> Figure:
    """Stable regions (code 2) of several models in the kg–Tg plane, one panel per
    kv, overlaid (paper Figs. 5 and 7; drawn by :func:`avll.plotting.regions`: one
    colour per model, a log kg axis for a log-spaced grid). ``maps`` may pass
    precomputed maps over ``kg × tg × kv_values``, or labelled maps
    (:func:`avll.map_dataset`, then the axes may be omitted)."""
    from . import plotting

    if maps is not None and all(hasattr(mp, "dims") for mp in maps) and kg is None:
        # labelled maps (map_dataset): the axes are their coordinates
        first: Any = maps[0]
        kg, tg = np.asarray(first.coords["kg"]), np.asarray(first.coords["Tg"])
        kv_values = [float(v) for v in np.asarray(first.coords["kv"])]
    kg, tg, kvs = _axis("kg", kg), _axis("tg", tg), _axis("kv_values", kv_values)
    if maps is None:
        maps = [stability_map(m, kg, tg, kvs, pade_order, threads=threads) for m in models]
    return plotting.regions(models, kg, tg, kvs, [np.asarray(mp) for mp in maps], pade_order,
                            labels=labels)


def plot_thresholds(models: Sequence[LowerLevelModel], ths: Sequence[Thresholds], *,
                    labels: Sequence[str] | None = None) -> Figure:
    """Thresholds of kg (largest stable) and Tg (smallest stable) against kv for several
    models (paper Figs. 6 and 8; :func:`avll.plotting.thresholds`: values on the grid's
    edge drawn as open markers)."""
    from . import plotting

    return plotting.thresholds(models, ths, labels=labels)


def plot_boundaries(boundaries: Sequence[Any], labels: Sequence[str] | None = None) -> Figure:
    """Boundaries from :func:`boundary` drawn as curves
    (:func:`avll.plotting.boundaries`)."""
    from .plotting import boundaries as draw

    return draw(boundaries, labels)
