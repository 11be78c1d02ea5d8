"""The canonical long format: one row per sample, SI units.

Columns: ``run, t, command, a`` and, when known, ``v, x``, the leader's
``lead_x, lead_v, lead_a``, and exogenous signals ``exo_<name>`` (e.g.
``exo_grade``). CSV or Parquet (by suffix). A JSON sidecar ``<file>.meta.json``
may give the command kind and, per run, the upper-level law and metadata::

    {"command_kind": "acceleration",
     "runs": {"1": {"upper": {"kg": 0.7, "kv": 0.0, "Tg": 2.0, "Gmin": 9.5},
                    "meta": {...}}}}

The sidecar is validated against that schema (:func:`validate_sidecar`): an object
with only the keys ``command_kind`` (``"acceleration"`` or ``"speed"``) and ``runs``
(an object of run id -> object with only ``upper``, an object of finite numbers
``kg`` (required), ``kv``, ``Tg``, ``Gmin``, and ``meta``, any JSON object); duplicated
keys and documents nested deeper than :data:`MAX_SIDECAR_DEPTH` are refused. Every
violation is a :class:`DataError` naming the sidecar and the JSON path
(``runs.'1'.upper.kg``).

Run ids are text, compared exactly as written in the ``run`` column (``"04"`` is
not ``"4"``; a Parquet float column of whole numbers gives ``"3"``, not ``"3.0"``). A
sidecar entry whose id matches no run is a :class:`DataError` when it equals a run
of the data as a number (``"4"`` vs ``"04"`` or ``"4.0"``: the id is written
differently, the entry would silently be lost) and a :class:`avll.DataWarning`
otherwise (e.g. a sidecar kept for a file that was cut down); ``strict=True`` makes
that an error too.

Every column is checked for plausibility (see :mod:`avll.io._common`): a value that
cannot be SI (a speed above 70 m/s, time stamps in milliseconds, ...) is an error, one
outside the physical range a :class:`avll.PlausibilityWarning`. A duplicated header
column is an error.

Rows are reported as file lines (the header is line 1).
"""

from __future__ import annotations

import math
import numbers
import os
import stat
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .. import _atomic
from ..data import COMMAND_KINDS, DataError, DataWarning, Run
from ..models import UpperLevel
from ._common import (
    _file_kind,
    check_columns,
    check_header,
    check_regular_file,
    check_time_step,
    check_unique_header,
    read_csv_numeric,
    record_lines,
    stat_path,
    strict_warnings,
)

__all__ = ["load_canonical", "write_runs", "validate_sidecar", "REQUIRED", "OPTIONAL",
           "sidecar_path", "MAX_SIDECAR_DEPTH"]

#: Deepest nesting of a sidecar (``runs`` -> id -> ``meta`` -> ... counts 1 each).
MAX_SIDECAR_DEPTH = 32
#: Largest sidecar file read (bytes).
MAX_SIDECAR_BYTES = 64 * 2**20
_UPPER_KEYS = ("kg", "kv", "Tg", "Gmin")

REQUIRED = ("run", "t", "a")
OPTIONAL = ("command", "v", "x", "lead_x", "lead_v", "lead_a")
#: Relative tolerance on the sample time within a run.
DT_RTOL = 1e-3


def sidecar_path(path: Path) -> Path:
    """The metadata sidecar of a data file."""
    return path.with_name(path.name + ".meta.json")


def _read_table(path: Path) -> pd.DataFrame:
    check_regular_file(path)
    check_header(path)
    if path.suffix.lower() in (".parquet", ".pq"):
        try:
            df = pd.read_parquet(path)
        except ImportError as e:
            raise DataError(f"{path}: reading Parquet needs pyarrow ({e})") from None
        except Exception as e:  # noqa: BLE001 - any parser failure is bad input
            raise DataError(f"{path}: not a readable Parquet file ({e})") from None
    elif (fast := read_csv_numeric(path, text=("run",), nan=False,
                                   skipinitialspace=True)) is not None:
        df = fast
    else:
        try:
            df = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
        except pd.errors.EmptyDataError:
            raise DataError(f"{path}: the file is empty") from None
        except (pd.errors.ParserError, UnicodeDecodeError) as e:
            raise DataError(f"{path}: not a readable CSV file ({e})") from None
    check_unique_header(path, list(df.columns), encoding="utf-8")
    df.columns = [str(c).strip() for c in df.columns]
    if df.shape[0] == 0:
        raise DataError(f"{path}: the file has a header but no data rows")
    return df


def _numeric(path: Path, df: pd.DataFrame, col: str, line: np.ndarray) -> np.ndarray:
    s = df[col]
    if not pd.api.types.is_numeric_dtype(s.dtype):
        txt = s.astype(str).str.strip()
        vals = pd.to_numeric(txt, errors="coerce")
        bad = np.flatnonzero(vals.isna().to_numpy())
        if bad.size:
            i = int(bad[0])
            raw = txt.iloc[i]
            what = ("is empty" if raw == "" else
                    f"{raw!r} is not a number (NaN is not allowed)"
                    if raw.lower().lstrip("+-") in ("nan", "na")
                    else f"{raw!r} is not a number")
            raise DataError(f"{path}: column {col!r} line {line[i]}: {what}")
        arr = vals.to_numpy(dtype=np.float64)
    else:
        arr = s.to_numpy(dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        raise DataError(f"{path}: column {col!r} line {line[i]}: value {arr[i]} is not finite")
    return arr


def _number(sc: Path, at: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        raise DataError(f"{sc}: {at}: must be a number, got {v!r}")
    try:
        f = float(v)
    except OverflowError:  # an integer beyond the float range
        f = math.inf
    if not math.isfinite(f):
        raise DataError(f"{sc}: {at}: must be finite, got {v!r:.40}")
    return f


def validate_sidecar(doc: Any, sc: Path | str = "sidecar") -> dict[str, Any]:
    """Checks a parsed sidecar against the schema of the module doc; returns it with
    ``runs`` present. Raises :class:`DataError` naming ``sc`` and the JSON path."""
    sc = Path(sc)
    if not isinstance(doc, dict):
        raise DataError(f"{sc}: must hold a JSON object, got {type(doc).__name__}")
    if _atomic.json_depth(doc) > MAX_SIDECAR_DEPTH:
        raise DataError(f"{sc}: nested deeper than {MAX_SIDECAR_DEPTH} levels")
    extra = [k for k in doc if k not in ("command_kind", "runs")]
    if extra:
        raise DataError(f"{sc}: unknown key {extra[0]!r}; allowed: command_kind, runs")
    kind = doc.get("command_kind")
    if kind is not None and kind not in COMMAND_KINDS:
        raise DataError(f"{sc}: command_kind: must be one of {COMMAND_KINDS}, got {kind!r}")
    runs = doc.get("runs", {})
    if not isinstance(runs, dict):
        raise DataError(f"{sc}: runs: must be an object of run id -> entry, got "
                        f"{type(runs).__name__} {_atomic.dumps(runs, indent=None)[:40]}")
    for rid, entry in runs.items():
        at = f"runs.{rid!r}"
        if not isinstance(entry, dict):
            raise DataError(f"{sc}: {at}: must be an object with 'upper' and/or 'meta', got "
                            f"{_atomic.dumps(entry, indent=None)[:40]}")
        extra = [k for k in entry if k not in ("upper", "meta")]
        if extra:
            raise DataError(f"{sc}: {at}: unknown key {extra[0]!r}; allowed: upper, meta")
        if "meta" in entry and not isinstance(entry["meta"], dict):
            raise DataError(f"{sc}: {at}.meta: must be an object, got "
                            f"{_atomic.dumps(entry['meta'], indent=None)[:40]}")
        if "upper" in entry:
            up = entry["upper"]
            if not isinstance(up, dict):
                raise DataError(f"{sc}: {at}.upper: must be an object with kg, kv, Tg, Gmin, "
                                f"got {_atomic.dumps(up, indent=None)[:40]}")
            bad = [k for k in up if k not in _UPPER_KEYS]
            if bad:
                raise DataError(f"{sc}: {at}.upper: unknown key {bad[0]!r}; allowed: "
                                f"{', '.join(_UPPER_KEYS)}")
            if "kg" not in up:
                raise DataError(f"{sc}: {at}.upper: 'kg' is required")
            for k, v in up.items():
                _number(sc, f"{at}.upper.{k}", v)
    return {**doc, "runs": runs}


def _sidecar(path: Path) -> dict[str, Any]:
    sc = sidecar_path(path)
    if not os.path.lexists(sc):
        return {"runs": {}}
    st = stat_path(sc, "sidecar")
    if not stat.S_ISREG(st.st_mode):
        raise DataError(f"{sc}: is {_file_kind(st.st_mode)}, expected the JSON sidecar "
                        "(a regular file)")
    if st.st_size > MAX_SIDECAR_BYTES:
        raise DataError(f"{sc}: larger than {MAX_SIDECAR_BYTES // 2**20} MB; not a sidecar")
    try:
        data = _atomic.loads(sc.read_text(encoding="utf-8"), max_depth=MAX_SIDECAR_DEPTH)
    except ValueError as e:  # not strict JSON, not UTF-8, an int of > 4300 digits
        raise DataError(f"{sc}: {e}") from None
    return validate_sidecar(data, sc)


def _as_number(s: str) -> float | None:
    try:
        f = float(s)
    except ValueError:
        return None
    return f if math.isfinite(f) else None


def _match_sidecar(path: Path, per_run: dict[str, Any], order: Sequence[str]) -> None:
    """Sidecar ids that match no run: an error when a run has the same id as a number
    (written differently), a DataWarning otherwise."""
    ids = set(order)
    unknown = [k for k in per_run if k not in ids]
    if not unknown:
        return
    # the first run of each number (reversed: the first one is written last)
    by_num = {f: rid for rid in reversed(order) if (f := _as_number(rid)) is not None}
    sc = sidecar_path(path)
    for k in unknown:
        f = _as_number(k)
        if f is not None and f in by_num:
            raise DataError(
                f"{sc}: runs.{k!r} matches no run of {path.name}, whose run "
                f"{by_num[f]!r} is the same number written differently; run ids are compared "
                f"as text: write {by_num[f]!r} in the sidecar (or rename the run)")
    shown = ", ".join(repr(k) for k in unknown[:5]) + (" ..." if len(unknown) > 5 else "")
    warnings.warn(DataWarning(
        f"{sc}: names {len(unknown)} run(s) that are not in {path.name}: {shown}; their "
        "entries are not used"),
        stacklevel=3)


def load_canonical(path: Path, command_kind: str | None = None, *,
                   strict: bool = False) -> list[Run]:
    """Reads runs in the canonical long format (see the module doc). ``strict=True``
    turns plausibility and sidecar warnings into :class:`DataError`."""
    with strict_warnings(strict):
        if command_kind is not None and command_kind not in COMMAND_KINDS:
            raise ValueError(f"command_kind: must be one of {COMMAND_KINDS}, got "
                             f"{command_kind!r}")
        return _load_canonical(Path(path), command_kind)


def _run_ids(df: pd.DataFrame) -> np.ndarray:
    s = df["run"]
    if pd.api.types.is_float_dtype(s.dtype):
        v = s.to_numpy(dtype=np.float64)
        if np.all(np.isfinite(v)) and np.all(v == np.round(v)) and np.all(np.abs(v) < 2**53):
            return np.array([str(int(x)) for x in v], dtype=object)
    return s.astype(str).str.strip().to_numpy()


def _load_canonical(path: Path, command_kind: str | None) -> list[Run]:
    df = _read_table(path)
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise DataError(
            f"{path}: missing column(s) {', '.join(map(repr, missing))}; "
            f"found {', '.join(map(repr, df.columns))}"
        )
    side = _sidecar(path)
    kind = command_kind or side.get("command_kind")
    if kind is None:
        raise DataError(
            f"{path}: the command kind is not given: pass command_kind='acceleration' "
            f"or 'speed', or write it in {sidecar_path(path).name}"
        )
    if kind not in COMMAND_KINDS:
        raise DataError(f"{path}: command kind must be one of {COMMAND_KINDS}, got {kind!r}")
    # the line of each row (Parquet: row index + 2, as if the header were line 1)
    line = (np.arange(len(df)) + 2 if path.suffix.lower() in (".parquet", ".pq")
            else record_lines(path, len(df)))
    cols = {c: _numeric(path, df, c, line) for c in df.columns if c != "run"}
    run_ids = _run_ids(df)
    empty = np.flatnonzero((run_ids == "") | (run_ids == "nan") | (run_ids == "None"))
    if empty.size:
        raise DataError(f"{path}: column 'run' line {line[empty[0]]}: is empty")
    exo_cols = [c for c in df.columns if c.startswith("exo_")]
    per_run = side.get("runs", {})
    runs: list[Run] = []
    order = list(dict.fromkeys(run_ids))
    _match_sidecar(path, per_run, order)
    signal_cols = [c for c in df.columns if c not in ("run", "t")]
    for rid in order:
        idx = np.flatnonzero(run_ids == rid)
        if idx.size > 1 and np.any(np.diff(idx) != 1):
            gap = int(idx[np.flatnonzero(np.diff(idx) != 1)[0] + 1])
            raise DataError(
                f"{path}: column 'run' line {line[gap]}: rows of run {rid!r} are not contiguous"
            )
        t = cols["t"][idx]
        if idx.size < 2:
            raise DataError(f"{path}: run {rid!r} (line {line[idx[0]]}) has fewer than 2 rows")
        dts = np.diff(t)
        bad = np.flatnonzero(dts <= 0)
        if bad.size:
            i = int(bad[0])
            what = "repeats" if dts[i] == 0 else "goes backwards"
            raise DataError(
                f"{path}: column 't' line {line[idx[i + 1]]}: time {what} in run {rid!r} "
                f"({t[i]} then {t[i + 1]})"
            )
        dt = float(np.median(dts))
        off = np.flatnonzero(np.abs(dts - dt) > DT_RTOL * dt)
        if off.size:
            i = int(off[0])
            raise DataError(
                f"{path}: column 't' line {line[idx[i + 1]]}: non-uniform sampling in run "
                f"{rid!r} (step {dts[i]:.6g} s, median {dt:.6g} s); resample it first"
            )
        check_time_step(dt, path, "t", int(idx[1]))
        check_columns({c: cols[c][idx] for c in signal_cols}, path, {}, command_kind=kind,
                      dt=dt, rows=idx)
        info = per_run.get(rid, {})
        upper = None
        if "upper" in info:
            try:
                upper = UpperLevel(**info["upper"])
            except (TypeError, ValueError) as e:
                raise DataError(f"{sidecar_path(path)}: run {rid!r} upper: {e}") from None
        optional = {c: cols[c][idx] if c in cols else None for c in OPTIONAL}
        runs.append(Run(run_id=rid, t=t, a=cols["a"][idx], command_kind=kind,
                        exo={c[4:]: cols[c][idx] for c in exo_cols}, upper=upper,
                        meta={**info.get("meta", {}), "source": str(path),
                              "first_line": int(line[idx[0]])}, **optional))
    return runs


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    return str(x)


def write_runs(runs: Sequence[Run], path: str | Path) -> Path:
    """Writes runs in the canonical format (CSV, or Parquet for a ``.parquet``
    suffix) plus the JSON sidecar, atomically (temporary names renamed together);
    returns the data file's path. Refuses to overwrite a file a run was loaded from."""
    path = Path(path)
    if not runs:
        raise ValueError("runs: nothing to write")
    for r in runs:
        for key in ("source", "file"):
            src = r.meta.get(key)
            if isinstance(src, str) and src and (
                    _atomic.same_file(path, src)
                    or _atomic.same_file(sidecar_path(path), sidecar_path(Path(src)))):
                raise ValueError(f"path: {path} is the file run {r.run_id!r} was read from "
                                 f"({src}); writing it would replace the input")
    kinds = {r.command_kind for r in runs}
    if len(kinds) != 1:
        raise ValueError(f"runs: mixed command kinds {sorted(kinds)}")
    exo_names = sorted({k for r in runs for k in r.exo})
    frames = []
    for r in runs:
        d: dict[str, Any] = {"run": r.run_id, "t": r.t}
        for name in ("command", "a", "v", "x", "lead_x", "lead_v", "lead_a"):
            val = getattr(r, name)
            if val is not None:
                d[name] = val
        for k in exo_names:
            if k not in r.exo:
                raise ValueError(f"run {r.run_id!r}: exogenous signal {k!r} missing")
            d[f"exo_{k}"] = r.exo[k]
        frames.append(pd.DataFrame(d))
    df = pd.concat(frames, ignore_index=True)
    per_run: dict[str, Any] = {}
    for r in runs:
        entry = per_run[r.run_id] = {}
        if r.upper is not None:
            entry["upper"] = dict(zip(_UPPER_KEYS, r.upper.to_array().tolist(), strict=True))
        entry["meta"] = _jsonable({k: v for k, v in r.meta.items()
                                   if k not in ("source", "first_line")})
    text = _atomic.dumps({"command_kind": runs[0].command_kind, "runs": per_run}, indent=1)
    # both files to temporary names first, renamed together with Ctrl-C deferred
    with _atomic.atomic_paths(path, sidecar_path(path)) as (tmp_data, tmp_side):
        if path.suffix.lower() in (".parquet", ".pq"):
            df.to_parquet(tmp_data, index=False)
        else:
            df.to_csv(tmp_data, index=False)  # shortest text that reads back exactly
        tmp_side.write_text(text + "\n", encoding="utf-8")
    return path
