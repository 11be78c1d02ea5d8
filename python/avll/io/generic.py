"""Generic CSV/Parquet loader with a column mapping (``format="generic"``).

By default the columns are the canonical ones: ``run`` (optional; without it the
whole file is one run named after the file), ``t``, ``command``, ``a``, ``v``, ``x``,
``lead_x``, ``lead_v``, ``lead_a`` and ``exo_<name>``. ``mapping`` renames: it maps a
canonical name to the file's column (``{"t": "Time", "v": "speed_mps"}``); mapped
``exo_<name>`` entries are exogenous signals too. SI units are expected (a speed in
km/h is detected by plausibility and rejected).

Without ``dt`` the time must already be uniform (within ``time_tol``) and every cell
finite. With ``dt`` each run is resampled to that step (:mod:`avll.io.resample`):
empty cells count as missing samples, linear interpolation bridges gaps of at most
``max_gap`` seconds, longer gaps split the run (ids ``<run>/rNN``), all recorded in
``meta["cleaning"]``.

Every column is checked for plausibility (:mod:`avll.io._common`): values that cannot
be SI are errors (a speed in km/h, time stamps in milliseconds, ...), values outside
the physical range are :class:`avll.PlausibilityWarning` (errors with ``strict=True``).
A duplicated header column is an error.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._limits import check_number
from ..data import COMMAND_KINDS, DataError, Run
from ._common import (
    check_columns,
    check_time,
    check_time_step,
    numeric_column,
    read_table,
    require_columns,
    strict_warnings,
    where,
)
from .resample import resample_arrays

__all__ = ["load_generic", "CANONICAL_COLUMNS"]

#: The canonical signal columns (besides ``run`` and ``exo_<name>``).
CANONICAL_COLUMNS = ("t", "command", "a", "v", "x", "lead_x", "lead_v", "lead_a")


def load_generic(
    path: str | Path,
    *,
    mapping: Mapping[str, str] | None = None,
    command_kind: str | None = None,
    dt: float | None = None,
    max_gap: float | None = None,
    time_tol: float = 1e-3,
    min_samples: int = 2,
    strict: bool = False,
) -> list[Run]:
    """Runs of a long CSV/Parquet table (see the module doc).

    ``command_kind`` (``"acceleration"`` or ``"speed"``) is required when the table has
    a command column. ``dt`` asks for resampling (``max_gap`` defaults to ``2.5*dt``).
    Raises :class:`avll.DataError` naming the file, column and row for bad input;
    ``strict=True`` turns plausibility warnings into errors.
    """
    with strict_warnings(strict):
        return _load_generic(Path(path), mapping, command_kind, dt, max_gap, time_tol,
                             min_samples)


def _load_generic(path: Path, mapping: Mapping[str, str] | None, command_kind: str | None,
                  dt: float | None, max_gap: float | None, time_tol: float,
                  min_samples: int) -> list[Run]:
    if command_kind is not None and command_kind not in COMMAND_KINDS:
        raise ValueError(f"command_kind: must be one of {COMMAND_KINDS}, got {command_kind!r}")
    if dt is not None:
        dt = check_number(dt, "dt")
    time_tol = check_number(time_tol, "time_tol")
    if dt is not None and not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a positive time step, got {dt!r}")
    if not (time_tol > 0):
        raise ValueError(f"time_tol: must be > 0, got {time_tol!r}")
    mp: dict[str, str] = {}
    if mapping is not None:
        for k, v in mapping.items():
            if k not in (*CANONICAL_COLUMNS, "run") and not k.startswith("exo_"):
                raise ValueError(f"mapping: unknown canonical name {k!r}; use run, "
                                 f"{', '.join(CANONICAL_COLUMNS)} or exo_<name>")
            mp[k] = str(v)
    df = read_table(path)
    for k in (*CANONICAL_COLUMNS, "run"):
        if k not in mp and k in df.columns:
            mp[k] = k
    for c in df.columns:
        if c.startswith("exo_") and c not in mp and c not in mp.values():
            mp[c] = c
    require_columns(df, path, [mp.get("t", "t"), mp.get("a", "a")])
    require_columns(df, path, list(mp.values()))
    has_cmd = "command" in mp
    if has_cmd and command_kind is None:
        raise ValueError(f"command_kind: {path} has a command column ({mp['command']!r}); "
                         "say whether it is an 'acceleration' or a 'speed'")
    kind = command_kind or "acceleration"
    data: dict[str, np.ndarray] = {}
    for k, c in mp.items():
        if k == "run":
            continue
        no_nan = dt is None or k == "t"  # resampling treats empty cells as missing samples
        arr = numeric_column(df, path, c, allow_empty=not no_nan)
        bad = np.flatnonzero(np.isinf(arr) | (np.isnan(arr) & no_nan))
        if bad.size:
            raise DataError(f"{where(path, c, int(bad[0]))}: value is {arr[bad[0]]} "
                            "(NaN and inf are not allowed)")
        data[k] = arr
    if "run" in mp:
        ids = df[mp["run"]].astype(str).str.strip().to_numpy()
        empty = np.flatnonzero(ids == "")
        if empty.size:
            raise DataError(f"{where(path, mp['run'], int(empty[0]))}: empty run id")
        _, first = np.unique(ids, return_index=True)
        order = ids[np.sort(first)]
    else:
        ids = np.full(len(df), path.stem, dtype=object)
        order = np.array([path.stem], dtype=object)
    runs: list[Run] = []
    for rid in order:
        rows = np.flatnonzero(ids == rid)
        cols = {k: v[rows] for k, v in data.items()}
        tcol = mp["t"]
        step = check_time(cols["t"], path, tcol, rows=rows, rtol=time_tol, uniform=dt is None)
        check_time_step(step, path, tcol, int(rows[1]) if rows.size > 1 else None)
        check_columns({k: v for k, v in cols.items() if k != "t"}, path, mp,
                      command_kind=kind, dt=None if dt else step, rows=rows)
        base_meta: dict[str, Any] = {"format": "generic", "file": str(path),
                                     "rows": [int(rows[0]), int(rows[-1])],
                                     "columns": dict(mp), "cleaning": []}
        if dt is None:
            runs.append(_make(str(rid), cols, kind, base_meta))
            continue
        t = cols.pop("t")
        n_nan = {k: int(np.isnan(v).sum()) for k, v in cols.items() if np.isnan(v).any()}
        segs = resample_arrays(t, cols, dt, max_gap=max_gap, min_samples=min_samples)
        if not segs:
            raise DataError(f"{where(path, tcol, int(rows[0]))}: run {rid!r} has no segment of "
                            f"{min_samples} samples after resampling to dt={dt:g} s")
        for j, s in enumerate(segs):
            meta = dict(base_meta)
            cl = [f"resampled from {t.shape[0]} samples (median step "
                  f"{float(np.median(np.diff(t))):.6g} s) to dt={dt:g} s by linear "
                  f"interpolation across gaps <= {2.5 * dt if max_gap is None else max_gap:g} s"]
            if n_nan:
                cl.append("empty cells treated as missing samples: " +
                          ", ".join(f"{mp[k]}: {n}" for k, n in n_nan.items()))
            if len(segs) > 1:
                cl.append(f"split at gaps > max_gap: segment {j + 1} of {len(segs)} "
                          f"(input rows {int(rows[s.start])}-{int(rows[s.stop - 1])})")
            meta["cleaning"] = cl
            name = str(rid) if len(segs) == 1 else f"{rid}/r{j + 1:02d}"
            runs.append(_make(name, {"t": s.t, **s.columns}, kind, meta))
    return runs


def _make(rid: str, cols: Mapping[str, np.ndarray], kind: str, meta: dict[str, Any]) -> Run:
    exo = {k[4:]: v for k, v in cols.items() if k.startswith("exo_")}
    kw: dict[str, Any] = {k: cols.get(k) for k in CANONICAL_COLUMNS if k != "t"}
    return Run(run_id=rid, t=cols["t"], command_kind=kind, exo=exo, meta=meta, **kw)


