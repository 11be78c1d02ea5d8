"""Resampling to a uniform time step, never across long gaps.

Linear interpolation is used only between two samples at most ``max_gap`` seconds
apart. A longer gap splits the record into segments, each resampled on its own
grid ``t0 + k dt`` (``t0`` = the segment's first sample). Nothing is extrapolated.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data import DataError, Run

__all__ = ["Segment", "resample_arrays", "resample_run"]


@dataclass(frozen=True)
class Segment:
    """A uniformly sampled piece of a record: time ``t``, the resampled ``columns``
    and the index range ``[start, stop)`` of the input samples it came from."""

    t: np.ndarray
    columns: dict[str, np.ndarray]
    start: int
    stop: int


def resample_arrays(t: np.ndarray, columns: Mapping[str, np.ndarray], dt: float, *,
                    max_gap: float | None = None, min_samples: int = 2) -> list[Segment]:
    """Resample ``columns`` (sampled at the strictly increasing times ``t``) every
    ``dt`` seconds, interpolating linearly only across steps of at most ``max_gap``
    seconds (default ``2.5 * dt``) and splitting at longer gaps. NaN samples are
    treated as missing (a gap). Segments with fewer than ``min_samples`` output
    samples are dropped."""
    from .._limits import check_number

    dt = check_number(dt, "dt")
    if not dt > 0:
        raise ValueError(f"dt: must be a positive time step, got {dt!r}")
    if max_gap is not None:
        check_number(max_gap, "max_gap")
    gap = 2.5 * dt if max_gap is None else float(max_gap)
    if not (np.isfinite(gap) and gap > 0):
        raise ValueError(f"max_gap: must be positive, got {max_gap!r}")
    t = np.asarray(t, dtype=np.float64)
    cols = {k: np.asarray(v, dtype=np.float64) for k, v in columns.items()}
    fin = t[np.isfinite(t)]
    if fin.size > 1:
        from .._limits import check_memory

        n_out = (float(fin.max()) - float(fin.min())) / dt + 1.0
        check_memory(8.0 * n_out * (len(cols) + 2),
                     f"resample: {fin.max() - fin.min():.6g} s at dt={dt:g} s x "
                     f"{len(cols) + 1} columns", "resample to a coarser dt",
                     per=8.0 * (len(cols) + 2), unit="samples")
    ok = np.isfinite(t)
    for v in cols.values():
        ok &= np.isfinite(v)
    if ok.any() and np.any(np.diff(t[ok]) <= 0):
        raise DataError("resample: time must be strictly increasing")
    segs: list[Segment] = []
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return segs
    # split where consecutive valid samples are too far apart (or a NaN lies between
    # them and the time span is above max_gap)
    tv = t[idx]
    breaks = np.flatnonzero(np.diff(tv) > gap + 1e-9 * gap)
    bounds = np.r_[0, breaks + 1, idx.size]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        ii = idx[a:b]
        ts = t[ii]
        n = int(np.floor((ts[-1] - ts[0]) / dt + 1e-9)) + 1
        if n < min_samples:
            continue
        tn = ts[0] + dt * np.arange(n)
        out = {k: np.interp(tn, ts, v[ii]) for k, v in cols.items()}
        segs.append(Segment(tn, out, int(ii[0]), int(ii[-1]) + 1))
    return segs


def resample_run(run: Run, dt: float, *, max_gap: float | None = None,
                 min_samples: int = 2) -> list[Run]:
    """Resample a run to the step ``dt`` (see :func:`resample_arrays`). Returns one run
    per segment; the resampling is recorded in ``meta["cleaning"]``."""
    fields = ("a", "command", "v", "x", "lead_x", "lead_v", "lead_a")
    cols = {f: getattr(run, f) for f in fields if getattr(run, f) is not None}
    cols.update({f"exo_{k}": v for k, v in run.exo.items()})
    segs = resample_arrays(run.t, cols, dt, max_gap=max_gap, min_samples=min_samples)
    out = []
    for k, s in enumerate(segs):
        meta = dict(run.meta)
        cl = list(meta.get("cleaning", []))
        cl.append(f"resampled from dt={run.dt:.6g} s to dt={dt:g} s (linear, gaps <= "
                  f"{2.5 * dt if max_gap is None else max_gap:g} s)")
        if len(segs) > 1:
            cl.append(f"split at gaps: segment {k + 1} of {len(segs)}")
        meta["cleaning"] = cl
        rid = run.run_id if len(segs) == 1 else f"{run.run_id}/r{k + 1:02d}"
        exo = {n[4:]: v for n, v in s.columns.items() if n.startswith("exo_")}
        kw: dict[str, Any] = {f: s.columns.get(f) for f in fields}
        out.append(dataclasses.replace(run, run_id=rid, t=s.t, exo=exo, meta=meta, **kw))
    return out

