"""The canonical long format: one row per sample, SI units.

Columns: ``run, t, command, a`` and, when known, ``v, x``, the leader's
``lead_x, lead_v, lead_a``, and exogenous signals ``exo_<name>`` (e.g.
``exo_grade``). CSV or Parquet (by suffix). A JSON sidecar ``<file>.meta.json``
may give the command kind and, per run, the upper-level law and metadata::

    {"command_kind": "acceleration",
     "runs": {"1": {"upper": {"kg": 0.7, "kv": 0.0, "Tg": 2.0, "Gmin": 9.5},
                    "meta": {...}}}}

Rows are reported as file lines (the header is line 1).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..data import COMMAND_KINDS, DataError, Run
from ..models import UpperLevel

__all__ = ["load_canonical", "write_runs", "REQUIRED", "OPTIONAL", "sidecar_path"]

REQUIRED = ("run", "t", "a")
OPTIONAL = ("command", "v", "x", "lead_x", "lead_v", "lead_a")
#: Relative tolerance on the sample time within a run.
DT_RTOL = 1e-3


def sidecar_path(path: Path) -> Path:
    """The metadata sidecar of a data file."""
    return path.with_name(path.name + ".meta.json")


def _read_table(path: Path) -> pd.DataFrame:
    if path.is_dir():
        raise DataError(f"{path}: is a folder, expected a CSV or Parquet file")
    if path.suffix.lower() in (".parquet", ".pq"):
        try:
            df = pd.read_parquet(path)
        except ImportError as e:
            raise DataError(f"{path}: reading Parquet needs pyarrow ({e})") from None
        except Exception as e:  # noqa: BLE001 - any parser failure is bad input
            raise DataError(f"{path}: not a readable Parquet file ({e})") from None
    else:
        try:
            df = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
        except pd.errors.EmptyDataError:
            raise DataError(f"{path}: the file is empty") from None
        except (pd.errors.ParserError, UnicodeDecodeError) as e:
            raise DataError(f"{path}: not a readable CSV file ({e})") from None
    df.columns = [str(c).strip() for c in df.columns]
    if df.shape[0] == 0:
        raise DataError(f"{path}: the file has a header but no data rows")
    return df


def _numeric(path: Path, df: pd.DataFrame, col: str, line0: int) -> np.ndarray:
    s = df[col]
    if not pd.api.types.is_numeric_dtype(s.dtype):
        txt = s.astype(str).str.strip()
        vals = pd.to_numeric(txt, errors="coerce")
        bad = np.flatnonzero(vals.isna().to_numpy())
        if bad.size:
            i = int(bad[0])
            raw = txt.iloc[i]
            what = "is empty" if raw in ("", "nan", "NaN", "NA") else f"{raw!r} is not a number"
            raise DataError(f"{path}: column {col!r} line {i + line0}: {what}")
        arr = vals.to_numpy(dtype=np.float64)
    else:
        arr = s.to_numpy(dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        raise DataError(f"{path}: column {col!r} line {i + line0}: value {arr[i]} is not finite")
    return arr


def _sidecar(path: Path) -> dict[str, Any]:
    sc = sidecar_path(path)
    if not sc.exists():
        return {}
    try:
        data = json.loads(sc.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(f"{sc}: not valid JSON ({e})") from None
    if not isinstance(data, dict):
        raise DataError(f"{sc}: must hold a JSON object")
    return data


def load_canonical(path: Path, command_kind: str | None = None) -> list[Run]:
    """Reads runs in the canonical long format (see the module doc)."""
    path = Path(path)
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
            f"{path}: the command kind is not given: pass command_kind "
            f"('acceleration' or 'speed') or write it in {sidecar_path(path).name}"
        )
    if kind not in COMMAND_KINDS:
        raise DataError(f"{path}: command kind must be one of {COMMAND_KINDS}, got {kind!r}")
    line0 = 2  # header is line 1 (Parquet: row index + 2 as well, for consistency)
    cols = {c: _numeric(path, df, c, line0) for c in df.columns if c != "run"}
    run_ids = df["run"].astype(str).str.strip().to_numpy()
    empty = np.flatnonzero(run_ids == "")
    if empty.size:
        raise DataError(f"{path}: column 'run' line {int(empty[0]) + line0}: is empty")
    exo_cols = [c for c in df.columns if c.startswith("exo_")]
    per_run = side.get("runs", {})
    runs: list[Run] = []
    order = list(dict.fromkeys(run_ids))
    for rid in order:
        idx = np.flatnonzero(run_ids == rid)
        if idx.size > 1 and np.any(np.diff(idx) != 1):
            gap = int(idx[np.flatnonzero(np.diff(idx) != 1)[0] + 1])
            raise DataError(
                f"{path}: column 'run' line {gap + line0}: rows of run {rid!r} are not contiguous"
            )
        t = cols["t"][idx]
        if idx.size < 2:
            raise DataError(f"{path}: run {rid!r} (line {idx[0] + line0}) has fewer than 2 rows")
        dts = np.diff(t)
        bad = np.flatnonzero(dts <= 0)
        if bad.size:
            i = int(bad[0])
            what = "repeats" if dts[i] == 0 else "goes backwards"
            raise DataError(
                f"{path}: column 't' line {idx[i + 1] + line0}: time {what} in run {rid!r} "
                f"({t[i]} then {t[i + 1]})"
            )
        dt = float(np.median(dts))
        off = np.flatnonzero(np.abs(dts - dt) > DT_RTOL * dt)
        if off.size:
            i = int(off[0])
            raise DataError(
                f"{path}: column 't' line {idx[i + 1] + line0}: non-uniform sampling in run "
                f"{rid!r} (step {dts[i]:.6g} s, median {dt:.6g} s); resample it first"
            )
        info = per_run.get(rid, {})
        upper = None
        if "upper" in info:
            try:
                upper = UpperLevel(**info["upper"])
            except (TypeError, ValueError) as e:
                raise DataError(f"{sidecar_path(path)}: run {rid!r} upper: {e}") from None
        runs.append(
            Run(
                run_id=rid,
                t=t,
                a=cols["a"][idx],
                command_kind=kind,
                command=cols["command"][idx] if "command" in cols else None,
                v=cols["v"][idx] if "v" in cols else None,
                x=cols["x"][idx] if "x" in cols else None,
                lead_x=cols["lead_x"][idx] if "lead_x" in cols else None,
                lead_v=cols["lead_v"][idx] if "lead_v" in cols else None,
                lead_a=cols["lead_a"][idx] if "lead_a" in cols else None,
                exo={c[4:]: cols[c][idx] for c in exo_cols},
                upper=upper,
                meta={
                    **info.get("meta", {}),
                    "source": str(path),
                    "first_line": int(idx[0] + line0),
                },
            )
        )
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
    suffix) plus the JSON sidecar; returns the data file's path."""
    path = Path(path)
    if not runs:
        raise ValueError("runs: nothing to write")
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
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() in (".parquet", ".pq"):
        df.to_parquet(path, index=False)
    else:
        df.to_csv(path, index=False, float_format="%.10g")
    side = {
        "command_kind": runs[0].command_kind,
        "runs": {
            r.run_id: {
                **(
                    {
                        "upper": dict(
                            zip(
                                ("kg", "kv", "Tg", "Gmin"), r.upper.to_array().tolist(), strict=True
                            )
                        )
                    }
                    if r.upper is not None
                    else {}
                ),
                "meta": _jsonable(
                    {k: v for k, v in r.meta.items() if k not in ("source", "first_line")}
                ),
            }
            for r in runs
        },
    }
    sidecar_path(path).write_text(json.dumps(side, indent=1))
    return path
