"""Shared reading and validation helpers of the loaders.

Every error is an :class:`avll.DataError` (a ``ValueError``) whose message names the
file, the column and the row. Rows are counted from 0 over the data rows (the header
excluded); the message also gives the 1-based line of the file for CSV input, so a
user can open the file at that line. Input files are only ever read.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from ..data import DataError, Run

__all__ = [
    "where",
    "read_table",
    "numeric_column",
    "check_finite",
    "check_time",
    "check_speed_units",
    "check_accel_units",
    "check_runs_for_delay",
    "contiguous",
    "summarize",
]

#: Speeds above this (m/s, 252 km/h) are not plausible for road vehicles.
MAX_PLAUSIBLE_SPEED = 70.0
#: Accelerations beyond this (m/s²) are not plausible for road vehicles.
MAX_PLAUSIBLE_ACCEL = 15.0


def where(path: str | Path, column: str | None = None, row: int | None = None,
          *, header_lines: int = 1) -> str:
    """``"file.csv, column 'v', row 12 (line 14)"``: the location part of an error."""
    s = f"{path}"
    if column is not None:
        s += f", column {column!r}"
    if row is not None:
        s += f", row {int(row)}"
        if str(path).lower().endswith(".csv"):
            s += f" (line {int(row) + header_lines + 1})"
    return s


def read_table(path: str | Path, *, encoding: str = "utf-8-sig") -> pd.DataFrame:
    """Read a CSV or Parquet file (chosen by suffix) as strings/objects untouched.

    Raises :class:`DataError` for an empty file (no header or no data row) and
    ``OSError`` when the file cannot be read.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    if p.is_dir():
        raise DataError(f"{p}: is a directory, expected a CSV or Parquet file")
    if p.stat().st_size == 0:
        raise DataError(f"{p}: empty file (no header, no data)")
    suffix = p.suffix.lower()
    if suffix in (".parquet", ".pq"):
        try:
            df = pd.read_parquet(p)
        except (ImportError, OSError, ValueError) as e:  # pragma: no cover - env dependent
            raise DataError(f"{p}: cannot read as Parquet ({e})") from e
    else:
        try:
            df = pd.read_csv(p, dtype=str, keep_default_na=False, encoding=encoding)
        except pd.errors.EmptyDataError as e:
            raise DataError(f"{p}: empty file (no header, no data)") from e
        except (pd.errors.ParserError, UnicodeDecodeError) as e:
            raise DataError(f"{p}: not a readable CSV file ({e})") from e
    df.columns = [str(c).strip() for c in df.columns]
    if len(df) == 0:
        raise DataError(f"{p}: no data rows (only a header: {', '.join(df.columns)})")
    return df


def require_columns(df: pd.DataFrame, path: str | Path, columns: Iterable[str]) -> None:
    """Raise :class:`DataError` naming the first missing column."""
    have = set(df.columns)
    missing = [c for c in columns if c not in have]
    if missing:
        more = f" (and {len(missing) - 1} more: {', '.join(missing[1:4])}...)" if len(
            missing) > 1 else ""
        raise DataError(
            f"{where(path, missing[0])}: missing column{more}; the file has "
            f"{', '.join(list(df.columns)[:12])}{'...' if len(df.columns) > 12 else ''}"
        )


def numeric_column(df: pd.DataFrame, path: str | Path, column: str,
                   *, allow_empty: bool = False) -> np.ndarray:
    """The column as float64. Text that is not a number raises :class:`DataError`
    naming the row; empty cells are NaN when ``allow_empty`` and an error otherwise."""
    s = df[column]
    if pd.api.types.is_numeric_dtype(s.dtype) or pd.api.types.is_bool_dtype(s.dtype):
        arr = s.to_numpy(dtype=np.float64, na_value=np.nan)
        if not allow_empty:
            bad = np.flatnonzero(np.isnan(arr))
            if bad.size:
                raise DataError(f"{where(path, column, int(bad[0]))}: empty (missing) value")
        return arr
    txt = s.astype(str).str.strip()
    empty = (txt == "") | s.isna().to_numpy()
    num = pd.to_numeric(txt.where(~empty, "nan"), errors="coerce").to_numpy(dtype=np.float64)
    lowered = txt.str.lower()
    explicit_nan = lowered.isin(("nan", "-nan", "+nan")).to_numpy()
    bad = np.flatnonzero(np.isnan(num) & ~empty & ~explicit_nan)
    if bad.size:
        r = int(bad[0])
        raise DataError(
            f"{where(path, column, r)}: not a number: {str(s.iloc[r])[:40]!r}"
            + (f" ({bad.size} such rows)" if bad.size > 1 else "")
        )
    if not allow_empty:
        e = np.flatnonzero(empty)
        if e.size:
            raise DataError(f"{where(path, column, int(e[0]))}: empty (missing) value")
    return num


def check_finite(arr: np.ndarray, path: str | Path, column: str,
                 rows: np.ndarray | None = None) -> None:
    """NaN or ±inf raise :class:`DataError` naming the (original) row."""
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        r = int(rows[i]) if rows is not None else i
        raise DataError(f"{where(path, column, r)}: value is {arr[i]} (NaN and inf are not "
                        f"allowed){f'; {bad.size} such rows' if bad.size > 1 else ''}")


def check_time(t: np.ndarray, path: str | Path, column: str = "t", *,
               rows: np.ndarray | None = None, rtol: float = 1e-3,
               uniform: bool = True) -> float:
    """Check a time column: finite, strictly increasing (no duplicates), and — when
    ``uniform`` — sampled uniformly within ``rtol`` of the median step. Returns the
    median step."""
    check_finite(t, path, column, rows)
    if t.shape[0] < 2:
        raise DataError(f"{where(path, column)}: needs at least 2 samples, got {t.shape[0]}")
    d = np.diff(t)

    def row(i: int) -> int:
        return int(rows[i]) if rows is not None else i

    dup = np.flatnonzero(d == 0)
    back = np.flatnonzero(d < 0)
    if back.size and (not dup.size or back[0] < dup[0]):
        i = int(back[0]) + 1
        raise DataError(
            f"{where(path, column, row(i))}: time goes backwards "
            f"({float(t[i - 1]):.10g} then {float(t[i]):.10g}); "
            f"{back.size} such rows; sort the file or use a loader that sorts")
    if dup.size:
        i = int(dup[0]) + 1
        raise DataError(f"{where(path, column, row(i))}: duplicated time {float(t[i]):.10g} "
                        f"(also at row {row(i - 1)}); {dup.size} duplicates")
    dt = float(np.median(d))
    if uniform:
        off = np.flatnonzero(np.abs(d - dt) > rtol * dt + 1e-12)
        if off.size:
            i = int(off[0]) + 1
            raise DataError(
                f"{where(path, column, row(i))}: non-uniform sampling: step {d[i - 1]:.6g} s "
                f"where the median step is {dt:.6g} s (tolerance {rtol:g} relative; "
                f"{off.size} such steps); resample with dt=... or fix the file")
    return dt


def _slope(y: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of y on x through the origin, and the fit's R²."""
    m = np.isfinite(x) & np.isfinite(y)
    x, y = x[m], y[m]
    sxx = float(np.dot(x, x))
    if x.size < 20 or sxx <= 0:
        return math.nan, 0.0
    k = float(np.dot(x, y)) / sxx
    syy = float(np.dot(y, y))
    r2 = 1.0 - float(np.dot(y - k * x, y - k * x)) / syy if syy > 0 else 0.0
    return k, r2


def check_speed_units(v: np.ndarray, path: str | Path, column: str, *, dt: float | None = None,
                      a: np.ndarray | None = None, x: np.ndarray | None = None) -> None:
    """Detect a speed column that is not in m/s, by plausibility.

    * any |v| above 70 m/s (252 km/h) is implausible for these vehicles;
    * when the acceleration is known, the slope of dv/dt on ``a`` should be about 1;
      a slope near 3.6 (km/h) or 2.24 (mph) with a good fit reveals the unit;
    * when the position is known, the slope of dx/dt on ``v`` should be about 1.
    """
    fin = v[np.isfinite(v)]
    if fin.size and np.max(np.abs(fin)) > MAX_PLAUSIBLE_SPEED:
        i = int(np.flatnonzero(np.abs(np.nan_to_num(v)) > MAX_PLAUSIBLE_SPEED)[0])
        raise DataError(
            f"{where(path, column, i)}: speed {v[i]:.4g} is implausible in m/s "
            f"(> {MAX_PLAUSIBLE_SPEED:g} m/s); is the column in km/h? Convert to m/s")
    if dt is None or v.shape[0] < 40:
        return
    checks = []
    if a is not None:
        dv = np.gradient(v, dt)
        checks.append(("acceleration", *_slope(dv, a)))
    if x is not None:
        dx = np.gradient(x, dt)
        k, r2 = _slope(v, dx)
        checks.append(("position derivative", k, r2))
    for what, k, r2 in checks:
        if not np.isfinite(k) or r2 < 0.5:
            continue
        for unit, f in (("km/h", 3.6), ("mph", 2.2369)):
            if abs(k / f - 1.0) < 0.2:
                raise DataError(
                    f"{where(path, column)}: speed looks like {unit}, not m/s: it is "
                    f"{k:.3g} x the speed implied by the {what} (R² {r2:.2f}); convert to m/s")


def check_accel_units(a: np.ndarray, path: str | Path, column: str) -> None:
    """|a| above 15 m/s² is implausible for road vehicles (wrong unit or column)."""
    fin = np.abs(np.nan_to_num(a, nan=0.0, posinf=np.inf, neginf=np.inf))
    if fin.size and fin.max() > MAX_PLAUSIBLE_ACCEL:
        i = int(np.argmax(fin > MAX_PLAUSIBLE_ACCEL))
        raise DataError(f"{where(path, column, i)}: acceleration {a[i]:.4g} m/s² is implausible "
                        f"(> {MAX_PLAUSIBLE_ACCEL:g}); wrong unit or column?")


def check_runs_for_delay(runs: Sequence[Run], td: float, *, min_extra_samples: int = 20) -> None:
    """Raise :class:`DataError` naming the run when a run is too short for a model with
    dead time ``td`` (s): it needs ``ceil(td/dt) + min_extra_samples`` samples, so the
    delayed command drives at least ``min_extra_samples`` samples of the response."""
    if not np.isfinite(td) or td < 0:
        raise ValueError(f"td: must be a finite delay >= 0, got {td!r}")
    for r in runs:
        need = math.ceil(td / r.dt - 1e-9) + int(min_extra_samples)
        if len(r) < need:
            src = r.meta.get("file", "")
            raise DataError(
                f"{src + ', ' if src else ''}run {r.run_id!r}: {len(r)} samples "
                f"({(len(r) - 1) * r.dt:.3g} s) is too short for a delay of {td:g} s at "
                f"dt={r.dt:g} s: needs at least {need} samples")


def contiguous(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open ``[start, stop)`` index ranges of the True stretches of ``mask``."""
    m = np.asarray(mask, dtype=bool)
    edges = np.flatnonzero(np.diff(np.r_[0, m.astype(np.int8), 0]))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def summarize(runs: Sequence[Run]) -> str:
    """A plain-text table of runs: id, samples, duration, dt and the cleaning notes."""
    lines = [f"{'run':<40} {'n':>6} {'dur_s':>8} {'dt':>6}  cleaning"]
    for r in runs:
        cl = "; ".join(r.meta.get("cleaning", [])) or "-"
        lines.append(f"{r.run_id:<40} {len(r):>6} {(len(r) - 1) * r.dt:>8.1f} {r.dt:>6.3g}  {cl}")
    return "\n".join(lines)
