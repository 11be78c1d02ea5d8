"""Shared reading and validation helpers of the loaders.

Every error is an :class:`avll.DataError` (a ``ValueError``) whose message names the
file, the column and the row. Rows are counted from 0 over the data rows (the header
excluded); the message also gives the 1-based line of the file for CSV input, so a
user can open the file at that line. Input files are only ever read.

Plausibility (:data:`RANGES`): a value that cannot be in SI units for a road vehicle
(|speed| > 70 m/s, |acceleration| > 15 m/s², a time step > 2 s, |grade| > 1, a position
beyond 1e8 m, any other signal beyond 1e12) is a :class:`DataError` that names the
likely unit; a value that is physically possible but outside the plausible range
(speed below -1 or above 50 m/s, |acceleration| above 10 m/s², a time step outside
0.001..1 s, |grade| above 0.2, a position jump faster than 70 m/s) is a
:class:`avll.PlausibilityWarning` naming the file, the column and the line.
:func:`strict_warnings` (the loaders' ``strict=True``, the CLI's ``--strict``) turns
every :class:`avll.DataWarning` into a :class:`DataError`. Units are never
converted: a speed in km/h or mph (detected from the acceleration or the position)
and time stamps in milliseconds are errors that say so.

Files: the loaders read regular files only (:func:`check_regular_file`): a FIFO, a
socket or a device is refused before it is opened (opening a FIFO would wait for a
writer forever), and so is a symbolic link loop. The header of a CSV file is bounded
(:func:`check_header`): at most :data:`MAX_HEADER_BYTES` bytes and
:data:`MAX_COLUMNS` columns (a Parquet file: :data:`MAX_COLUMNS` columns and a
footer of at most :data:`MAX_PARQUET_FOOTER` bytes), checked before the file is parsed.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import functools
import io
import math
import os
import re
import stat
import warnings
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .._limits import MAX_PLAUSIBLE_ACCEL, MAX_PLAUSIBLE_SPEED, MAX_POSITION_RATE, RANGES, Range
from ..data import DataError, DataWarning, PlausibilityWarning, Run

__all__ = [
    "where",
    "read_table",
    "numeric_column",
    "check_finite",
    "check_time",
    "check_speed_units",
    "check_accel_units",
    "check_runs_for_delay",
    "check_time_step",
    "check_time_span",
    "check_signal",
    "check_columns",
    "check_unique_header",
    "check_regular_file",
    "check_header",
    "MAX_COLUMNS",
    "MAX_HEADER_BYTES",
    "MAX_PARQUET_FOOTER",
    "strict_warnings",
    "with_strict",
    "RANGES",
    "contiguous",
    "summarize",
]

#: Most columns a data file may have (the formats have a few dozen at most).
MAX_COLUMNS = 10_000
#: Longest CSV header line, in bytes.
MAX_HEADER_BYTES = 1_000_000
#: Largest Parquet footer (the schema and the row-group metadata), in bytes.
MAX_PARQUET_FOOTER = 64 * 2**20


_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device"))


def _file_kind(mode: int) -> str:
    return next((kind for test, kind in _KINDS if test(mode)), "not a regular file")


def stat_path(path: str | Path, what: str = "file or folder") -> os.stat_result:
    """``os.stat`` of ``path`` (links followed); its failure as an error naming the
    path: no such ``what`` is a ``FileNotFoundError`` (as Python's ``open`` says it),
    a symbolic link loop, a path too long or no permission a :class:`DataError`."""
    p = Path(path)
    try:
        return os.stat(p)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise DataError(f"{p}: a symbolic link loop (a link that leads back to itself); "
                            "not followed") from None
        if e.errno in (errno.ENOENT, errno.ENOTDIR):
            broken = " (a broken symbolic link)" if os.path.islink(p) else ""
            raise FileNotFoundError(f"{p}: no such {what}{broken}") from None
        if e.errno == errno.ENAMETOOLONG:
            raise DataError(f"{p}: the path is too long") from None
        raise DataError(f"{p}: cannot be read ({e.strerror})") from None


def check_regular_file(path: str | Path) -> os.stat_result:
    """Refuses (:class:`DataError`) anything but a regular file, before it is opened:
    a folder, a FIFO, a socket, a device, a symbolic link loop or a missing file."""
    p = Path(path)
    st = stat_path(p, "file")
    if not stat.S_ISREG(st.st_mode):
        raise DataError(f"{p}: is {_file_kind(st.st_mode)}, expected a CSV or Parquet "
                        "file; avll reads regular files only")
    return st


def _header_end(prefix: bytes) -> int | None:
    """Where the first CSV record of ``prefix`` ends (a newline outside quotes)."""
    quotes = 0
    start = 0
    while True:
        i = prefix.find(b"\n", start)
        if i < 0:
            return None
        quotes += prefix.count(b'"', start, i)
        if quotes % 2 == 0:
            return i
        start = i + 1


def check_header(path: str | Path) -> None:
    """Bounds what the header of a data file can cost before it is parsed: a CSV
    header line of at most :data:`MAX_HEADER_BYTES` bytes and :data:`MAX_COLUMNS`
    fields; a Parquet file with a footer of at most :data:`MAX_PARQUET_FOOTER` bytes
    and at most :data:`MAX_COLUMNS` columns. A :class:`DataError` otherwise."""
    p = Path(path)
    if p.suffix.lower() in (".parquet", ".pq"):
        size = p.stat().st_size
        with open(p, "rb") as f:
            if size >= 12:
                f.seek(size - 8)
                tail = f.read(8)
                footer = int.from_bytes(tail[:4], "little")
                if tail[4:] == b"PAR1" and footer > MAX_PARQUET_FOOTER:
                    raise DataError(f"{p}: a Parquet footer (schema) of {footer} bytes, more "
                                    f"than the {MAX_PARQUET_FOOTER} accepted; not a data "
                                    "file of runs")
        try:
            import pyarrow.parquet as pq

            n = len(pq.read_schema(p).names)
        except Exception:  # noqa: BLE001 - the parser reports a bad file itself
            return
        if n > MAX_COLUMNS:
            raise DataError(f"{p}: {n} columns, more than the {MAX_COLUMNS} accepted; not a "
                            "data file of runs")
        return
    with open(p, "rb") as f:
        prefix = f.read(MAX_HEADER_BYTES + 1)
    end = _header_end(prefix)
    if end is None:
        if len(prefix) <= MAX_HEADER_BYTES:
            end = len(prefix)  # a header without a newline: the whole (short) file
        else:
            raise DataError(f"{p}: the header line is longer than {MAX_HEADER_BYTES} bytes; "
                            f"a data file of runs has a short header (at most {MAX_COLUMNS} "
                            "columns)")
    n = prefix.count(b",", 0, end) + 1  # an upper bound of the fields (commas in quotes)
    if n > MAX_COLUMNS:
        text = prefix[:end].decode("utf-8", errors="replace")
        n = len(next(csv.reader([text]), []))
        if n > MAX_COLUMNS:
            raise DataError(f"{p}: the header has {n} columns, more than the {MAX_COLUMNS} "
                            "accepted; a data file of runs has a few dozen")




def plausibility_warning(msg: str) -> None:
    """Emits an :class:`avll.PlausibilityWarning` (an error under ``strict``)."""
    warnings.warn(PlausibilityWarning(msg), stacklevel=3)


@contextlib.contextmanager
def strict_warnings(strict: bool = True) -> Iterator[None]:
    """Within the block, every :class:`avll.DataWarning` (plausibility, sidecar
    mismatches) raises a :class:`DataError` with the same message (``strict``), or is
    held back and issued when the block ends normally: a load that fails with an
    error does not also print the warnings that led up to it. A ``strict`` that is not a
    bool is a ``TypeError``."""
    if not isinstance(strict, bool):
        raise TypeError(f"strict: must be True or False, got {strict!r}")
    if not strict:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DataWarning)
            yield
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        return
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        try:
            yield
        except DataWarning as w:
            raise DataError(str(w)) from None


def with_strict(loader: Callable[..., list[Run]]) -> Callable[..., list[Run]]:
    """Adds the ``strict=False`` keyword to a loader (see :func:`strict_warnings`)."""

    @functools.wraps(loader)
    def wrapped(*args: Any, strict: bool = False, **kw: Any) -> list[Run]:
        with strict_warnings(strict):
            return loader(*args, **kw)

    return wrapped


def check_unique_header(path: str | Path, columns: Sequence[str], *,
                        encoding: str = "utf-8-sig") -> None:
    """Refuses a duplicated column name (after stripping blanks): pandas would rename
    the second ``a`` to ``a.1`` and the first would silently win. For CSV the header
    line is read as written."""
    p = Path(path)
    names = [str(c).strip() for c in columns]
    if p.suffix.lower() not in (".parquet", ".pq"):
        try:
            with open(p, encoding=encoding, newline="") as f:
                names = [c.strip() for c in next(csv.reader(f), [])]
        except (OSError, UnicodeDecodeError, csv.Error):
            pass
    seen: dict[str, int] = {}
    for i, c in enumerate(names):
        if c in seen:
            raise DataError(f"{where(p, c)}: duplicated column (header fields {seen[c] + 1} "
                            f"and {i + 1}); rename one")
        seen[c] = i


def where(path: str | Path, column: str | None = None, row: int | None = None,
          *, header_lines: int | None = None) -> str:
    """``"file.csv, column 'v', row 12 (line 14)"``: the location part of an error.

    ``row`` counts the data records as pandas reads a CSV file (blank lines skipped):
    its line is found in the file (:func:`record_lines`). ``header_lines``: a format
    read line by line instead (every line a record) whose data start after that many
    lines. Parquet has rows, no lines."""
    s = f"{path}"
    if column is not None:
        s += f", column {column!r}"
    if row is not None:
        row = int(row)
        s += f", row {row}"
        if not str(path).lower().endswith((".parquet", ".pq")):
            line = (row + header_lines + 1 if header_lines is not None
                    else int(record_lines(path, row + 1)[row]))
            s += f" (line {line})"
    return s


def record_lines(path: str | Path, n: int) -> np.ndarray:
    """The 1-based line of the CSV file ``path`` (a one-line header) where each of its
    first ``n`` data records starts, counted as pandas reads them: blank and
    whitespace-only lines skipped, a quoted cell may span lines. A file with neither
    takes the fast path (the record index + 2)."""
    try:
        st = os.stat(path)
    except OSError:
        return np.arange(n) + 2
    starts = _record_starts(str(path), (st.st_mtime_ns, st.st_size))
    if starts is None or starts.size < n + 1:
        return np.arange(n) + 2
    return starts[1:n + 1]


@functools.lru_cache(maxsize=4)
def _record_starts(path: str, stamp: tuple[int, int]) -> np.ndarray | None:
    """The start line of every record of ``path`` (the header first), or ``None`` when
    each record is one line and no line is blank (or the file cannot be read); cached
    per version of the file (``stamp``: its modification time and size)."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return None
    if b'"' not in data and not _has_blank_line(data):
        return None
    rd = csv.reader(io.StringIO(data.decode("utf-8-sig", errors="replace"), newline=""))
    starts: list[int] = []
    end = 0
    for rec in rd:
        start, end = end + 1, rd.line_num
        if rec and not (len(rec) == 1 and not rec[0].strip()):
            starts.append(start)
    return np.array(starts)


def _has_blank_line(data: bytes) -> bool:
    """Whether ``data`` (a CSV file's bytes) has an empty or whitespace-only line before
    its last non-blank one. A vectorised look at the byte after each newline first (a
    50 MB file in 20 ms); the regular expression only when a line starts with white
    space."""
    end = len(data)
    while end and data[end - 1] in b" \t\r\n\v\f":
        end -= 1
    if not end:
        return False
    a = np.frombuffer(data, np.uint8, count=end)
    after = a[1:][a[:-1] == 10]  # each line's first byte (the first line's: a[0])
    white = (after == 10) | (after == 13) | (after == 32) | (after == 9)
    if a[0] == 10 or (after == 10).any():
        return True
    if a[0] not in (9, 13, 32) and not white.any():
        return False
    return re.search(rb"(^|\n)[ \t]*\r?\n", data[:end]) is not None


#: pandas >= 3.1 parses floats in read_csv and to_numeric alike (fast_float, correctly
#: rounded); before, read_csv's default and to_numeric's parsers differ in the last bit.
PANDAS_FAST_FLOAT = tuple(int(x) for x in re.findall(r"\d+", pd.__version__)[:2]) >= (3, 1)


def read_csv_numeric(path: Path, *, text: Collection[str] = (), nan: bool = True,
                     **options: Any) -> pd.DataFrame | None:
    """A CSV file read once with its numbers parsed (pandas' C parser), every column
    that could read differently from its text re-read as text, exactly as
    ``pd.read_csv(path, dtype=str, keep_default_na=False, **options)`` gives it: a
    column that is neither all int64/float64 nor all text, holds an inf (spellings
    differ) or, unless ``nan``, an empty cell, and the columns named in ``text``. A
    numeric column's empty cells are NaN, the rest the number :func:`numeric_column`
    gives for the text; a text column (such as CARMA's date and clock) is kept from
    the one read, its empty cells ``""``. ``None`` when the read fails or pandas is
    older than 3.1 (the text read then says why)."""
    if not PANDAS_FAST_FLOAT:
        return None
    try:
        df = pd.read_csv(path, keep_default_na=False, na_values=[""], low_memory=False,
                         **options)
        if not isinstance(df.index, pd.RangeIndex):  # rows wider than the header
            return None
        num = [j for j, (c, d) in enumerate(zip(df.columns, df.dtypes, strict=True))
               if d in (np.float64, np.int64) and str(c).strip() not in text]
        x = df.iloc[:, num].to_numpy(dtype=np.float64)
        odd = np.isinf(x).any(axis=0) | (np.isnan(x).any(axis=0) & (not nan))
        words = {j for j, (c, d) in enumerate(zip(df.columns, df.dtypes, strict=True))
                 if isinstance(d, pd.StringDtype) and str(c).strip() not in text}
        for j in words:
            df.isetitem(j, df.iloc[:, j].fillna(""))
        redo = sorted(set(range(df.shape[1])) - set(num) - words
                      | {num[i] for i in np.flatnonzero(odd)})
        if redo:
            txt = pd.read_csv(path, dtype=str, keep_default_na=False, usecols=redo, **options)
            if txt.shape != (len(df), len(redo)):
                return None
            for i, j in enumerate(redo):
                df.isetitem(j, txt.iloc[:, i])
    except Exception:  # noqa: BLE001 - any failure: the text read reports it
        return None
    return df


def read_table(path: str | Path, *, encoding: str = "utf-8-sig",
               numeric: bool = False) -> pd.DataFrame:
    """Read a CSV or Parquet file (chosen by suffix) as strings/objects untouched, or
    with ``numeric`` a CSV file's numeric columns as numbers
    (:func:`read_csv_numeric`; the other columns as text).

    Raises :class:`DataError` for an empty file (no header or no data row) and
    ``OSError`` when the file cannot be read.
    """
    p = Path(path)
    if not os.path.lexists(p):
        raise FileNotFoundError(f"{p}: no such file")
    st = check_regular_file(p)
    if st.st_size == 0:
        raise DataError(f"{p}: empty file (no header, no data)")
    check_header(p)
    suffix = p.suffix.lower()
    if suffix in (".parquet", ".pq"):
        try:
            df = pd.read_parquet(p)
        except (ImportError, OSError, ValueError) as e:  # pragma: no cover - env dependent
            raise DataError(f"{p}: cannot read as Parquet ({e})") from e
    elif numeric and (fast := read_csv_numeric(p, encoding=encoding)) is not None:
        df = fast
    else:
        try:
            df = pd.read_csv(p, dtype=str, keep_default_na=False, encoding=encoding)
        except pd.errors.EmptyDataError as e:
            raise DataError(f"{p}: empty file (no header, no data)") from e
        except (pd.errors.ParserError, UnicodeDecodeError) as e:
            raise DataError(f"{p}: not a readable CSV file ({e})") from e
    check_unique_header(p, list(df.columns), encoding=encoding)
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
    dup = np.flatnonzero(d == 0)
    back = np.flatnonzero(d < 0)
    if back.size and (not dup.size or back[0] < dup[0]):
        i = int(back[0]) + 1
        raise DataError(
            f"{where(path, column, _row(rows, i))}: time goes backwards "
            f"({float(t[i - 1]):.10g} then {float(t[i]):.10g}); "
            f"{back.size} such rows; sort the file or use a loader that sorts")
    if dup.size:
        i = int(dup[0]) + 1
        raise DataError(f"{where(path, column, _row(rows, i))}: duplicated time "
                        f"{float(t[i]):.10g} (also at row {_row(rows, i - 1)}); {dup.size} "
                        "duplicates")
    dt = float(np.median(d))
    if uniform:
        off = np.flatnonzero(np.abs(d - dt) > rtol * dt + 1e-12)
        if off.size:
            i = int(off[0]) + 1
            raise DataError(
                f"{where(path, column, _row(rows, i))}: non-uniform sampling: step "
                f"{d[i - 1]:.6g} s where the median step is {dt:.6g} s (tolerance {rtol:g} "
                f"relative; {off.size} such steps); resample with dt=... or fix the file")
    return dt


def _slope(y: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of y on x through the origin, and the fit's R²."""
    m = np.isfinite(x) & np.isfinite(y)
    x, y = x[m], y[m]
    with np.errstate(all="ignore"):
        sxx = float(np.dot(x, x))
        if x.size < 20 or not (0 < sxx < math.inf):
            return math.nan, 0.0
        k = float(np.dot(x, y)) / sxx
        syy = float(np.dot(y, y))
        r2 = 1.0 - float(np.dot(y - k * x, y - k * x)) / syy if 0 < syy < math.inf else 0.0
    return k, r2


def _row(rows: np.ndarray | None, i: int) -> int:
    return int(rows[i]) if rows is not None else int(i)


def _first(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def _range_check(x: np.ndarray, path: str | Path, column: str, kind: str,
                 rows: np.ndarray | None, hint: str, *, rg: Range | None = None,
                 header_lines: int | None = None) -> None:
    """Hard limit (DataError with ``hint``) then plausible range (warning) of a
    ``kind`` of signal: the range ``rg``, by default ``RANGES[kind]``."""
    rg = RANGES[kind] if rg is None else rg
    unit = f" {rg.unit}" if rg.unit else ""
    fin = np.where(np.isfinite(x), x, 0.0)

    def at(i: int) -> str:
        return where(path, column, _row(rows, i), header_lines=header_lines)

    i = _first(np.abs(fin) > rg.hard)
    if i is not None:
        raise DataError(f"{at(i)}: {kind} {x[i]:.4g}{unit} is implausible "
                        f"(|{kind}| > {rg.hard:g}{unit}); {hint}")
    out = (fin < rg.lo) | (fin > rg.hi)
    i = _first(out)
    if i is not None:
        n = int(out.sum())
        plausibility_warning(f"{at(i)}: {kind} {x[i]:.4g}{unit} is outside the plausible range "
                             f"{rg.lo:g}..{rg.hi:g}{unit}" + (f" ({n} such rows)" if n > 1 else ""))


def check_speed_units(v: np.ndarray, path: str | Path, column: str, *, dt: float | None = None,
                      a: np.ndarray | None = None, x: np.ndarray | None = None,
                      rows: np.ndarray | None = None) -> None:
    """Detect a speed column that is not in m/s, by plausibility.

    * any |v| above 70 m/s (252 km/h) is implausible for these vehicles (an error:
      km/h?); a speed below -1 or above 50 m/s is a :class:`avll.PlausibilityWarning`;
    * when the acceleration is known, the slope of dv/dt on ``a`` should be about 1;
      a slope near 3.6 (km/h) or 2.24 (mph) with a good fit reveals the unit, one near
      0.001 time stamps in milliseconds;
    * when the position is known, the slope of dx/dt on ``v`` should be about 1
      (3.6: km/h, 2.24: mph, 1000: time in milliseconds).

    ``rows`` maps the array's samples to the file's data rows (for the messages).
    """
    fin = v[np.isfinite(v)]
    if fin.size and np.max(np.abs(fin)) > MAX_PLAUSIBLE_SPEED:
        i = int(np.flatnonzero(np.abs(np.nan_to_num(v)) > MAX_PLAUSIBLE_SPEED)[0])
        raise DataError(
            f"{where(path, column, _row(rows, i))}: speed {v[i]:.4g} is implausible in m/s "
            f"(> {MAX_PLAUSIBLE_SPEED:g} m/s); is the column in km/h? Convert to m/s")
    if dt is not None and v.shape[0] >= 40:
        _unit_slopes(v, path, column, dt, a, x)
    _range_check(v, path, column, "speed", rows, "is the column in km/h? Convert to m/s")


def _unit_slopes(v: np.ndarray, path: str | Path, column: str, dt: float,
                 a: np.ndarray | None, x: np.ndarray | None) -> None:
    checks = []
    with np.errstate(all="ignore"):
        if a is not None:
            checks.append(("acceleration", 1e-3, *_slope(np.gradient(v, dt), a)))
        if x is not None:
            checks.append(("position derivative", 1e3, *_slope(v, np.gradient(x, dt))))
    for what, ms, k, r2 in checks:
        if not np.isfinite(k) or r2 < 0.5:
            continue
        if abs(k / ms - 1.0) < 0.2:
            raise DataError(
                f"{where(path, column)}: the time stamps look like milliseconds, not seconds: "
                f"the speed is {k:.3g} x the speed implied by the {what} (R² {r2:.2f}); "
                "convert the time to seconds")
        for unit, f in (("km/h", 3.6), ("mph", 2.2369)):
            if abs(k / f - 1.0) < 0.2:
                raise DataError(
                    f"{where(path, column)}: speed looks like {unit}, not m/s: it is "
                    f"{k:.3g} x the speed implied by the {what} (R² {r2:.2f}); convert to m/s")


def check_accel_units(a: np.ndarray, path: str | Path, column: str,
                      rows: np.ndarray | None = None) -> None:
    """|a| above 15 m/s² is implausible for road vehicles (wrong unit or column: an
    error); above 10 m/s² (beyond tyre friction) a :class:`avll.PlausibilityWarning`."""
    fin = np.abs(np.nan_to_num(a, nan=0.0, posinf=np.inf, neginf=np.inf))
    if fin.size and fin.max() > MAX_PLAUSIBLE_ACCEL:
        i = int(np.argmax(fin > MAX_PLAUSIBLE_ACCEL))
        raise DataError(f"{where(path, column, _row(rows, i))}: acceleration {a[i]:.4g} m/s² "
                        f"is implausible (> {MAX_PLAUSIBLE_ACCEL:g}); wrong unit or column?")
    _range_check(a, path, column, "acceleration", rows, "wrong unit or column?")


#: Longest plausible step between two samples of one file (s).
MAX_TIME_GAP = 86400.0


def check_time_span(t: np.ndarray, path: str | Path, column: str,
                    rows: np.ndarray | None = None) -> None:
    """Sorted finite times ``t``: a step longer than a day (a typo in one time stamp)
    is an error naming the row, before a loader builds a grid over the span."""
    if t.shape[0] < 2:
        return
    d = np.diff(t)
    i = int(np.argmax(d))
    if d[i] > MAX_TIME_GAP:
        raise DataError(f"{where(path, column, _row(rows, i + 1))}: the time jumps from "
                        f"{t[i]:.10g} to {t[i + 1]:.10g} s (more than a day); a wrong time "
                        "stamp?")


def check_time_step(dt: float, path: str | Path, column: str, row: int | None = None) -> None:
    """The (median) time step ``dt`` of a time column: above 2 s an error (time stamps
    in milliseconds?), outside 0.001..1 s a :class:`avll.PlausibilityWarning` (too fine
    or too coarse for a lower-level controller)."""
    rg = RANGES["time_step"]
    if dt > rg.hard:
        raise DataError(f"{where(path, column, row)}: the time step is {dt:.6g}: are the time "
                        "stamps in milliseconds? The time must be in seconds (a step "
                        f"above {rg.hard:g} s is implausible)")
    if not rg.lo <= dt <= rg.hi:
        plausibility_warning(f"{where(path, column, row)}: time step {dt:.6g} s is outside the "
                             f"plausible range {rg.lo:g}..{rg.hi:g} s")


def check_signal(kind: str, x: np.ndarray, path: str | Path, column: str, *,
                 rows: np.ndarray | None = None, dt: float | None = None) -> None:
    """Range check of one column of a known ``kind``: ``speed``, ``acceleration``,
    ``grade``, ``position`` (also: jumps faster than 70 m/s, with ``dt``) or
    ``other`` (only the absurd magnitude of 1e12)."""
    if kind == "speed":
        check_speed_units(x, path, column, rows=rows)
    elif kind == "acceleration":
        check_accel_units(x, path, column, rows=rows)
    elif kind == "grade":
        _range_check(x, path, column, "grade", rows,
                     "the grade is rise over run (0.05 = 5 %), not percent or degrees")
    elif kind == "position":
        _range_check(x, path, column, "position", rows, "wrong unit or column?")
        if dt is not None and x.shape[0] > 1:
            fin = np.isfinite(x)
            d = np.abs(np.diff(x)) / dt
            bad = (d > MAX_POSITION_RATE) & fin[1:] & fin[:-1]
            i = _first(bad)
            if i is not None:
                plausibility_warning(
                    f"{where(path, column, _row(rows, i + 1))}: position jumps by "
                    f"{x[i + 1] - x[i]:.4g} m in one step ({d[i]:.4g} m/s, above "
                    f"{MAX_POSITION_RATE:g} m/s)"
                    + (f"; {int(bad.sum())} such steps" if bad.sum() > 1 else ""))
    elif kind == "other":
        fin = np.where(np.isfinite(x), x, 0.0)
        i = _first(np.abs(fin) > RANGES["other"].hard)
        if i is not None:
            raise DataError(f"{where(path, column, _row(rows, i))}: value {x[i]:.4g} is not a "
                            "plausible measurement (magnitude above 1e12)")
    else:  # pragma: no cover - programming error
        raise ValueError(f"kind: unknown signal kind {kind!r}")


#: Kind of each canonical column (``command`` depends on the command kind).
COLUMN_KINDS = {"a": "acceleration", "lead_a": "acceleration", "v": "speed",
                "lead_v": "speed", "x": "position", "lead_x": "position", "exo_grade": "grade"}


def check_columns(cols: Mapping[str, np.ndarray], path: str | Path,
                  names: Mapping[str, str], *, command_kind: str, dt: float | None,
                  rows: np.ndarray | None = None) -> None:
    """Plausibility and unit checks of one run's canonical columns (``t`` excluded):
    ``cols`` by canonical name (``a``, ``command``, ``v``, ``x``, ``lead_*``,
    ``exo_<name>``), ``names`` the file's column for each, ``rows`` the file's data
    row of each sample. ``dt`` enables the unit checks that need the time base. The
    speeds come last, so that the positions and accelerations they are compared with
    are already known to be plausible."""
    for k in sorted(cols, key=lambda k: k in ("v", "lead_v")):
        x, col = cols[k], names.get(k, k)
        if k in ("v", "lead_v"):
            pre = k.removesuffix("v")
            check_speed_units(x, path, col, dt=dt, a=cols.get(pre + "a"),
                              x=cols.get(pre + "x"), rows=rows)
        elif k == "command":
            check_signal("speed" if command_kind == "speed" else "acceleration", x, path, col,
                         rows=rows, dt=dt)
        else:
            check_signal(COLUMN_KINDS.get(k, "other"), x, path, col, rows=rows, dt=dt)


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


def natural_key(p: Path) -> tuple[Any, ...]:
    """Sort key of a path: its digit runs compared as numbers (data5 before data10)."""
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(p)))


def walk_files(path: Path) -> list[Path]:
    """Every regular file below ``path`` in natural order (symbolic links to folders are
    not followed, so a link loop cannot hang the walk; FIFOs and devices are not
    regular files)."""
    out = []
    for d, dirs, names in os.walk(path, followlinks=False):
        dirs.sort()
        out += [p for p in (Path(d) / nm for nm in names) if p.is_file()]
    return sorted(out, key=natural_key)


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
