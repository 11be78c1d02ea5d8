"""Loader of the JRC OpenACC AstaZero files (``format="openacc-astazero"``).

* Platoon files (``Time, X1..Xn, SpeedDoppler1..n, Accel1..n, Spacing2..n``; vehicle 1
  leads) give one closed-loop run per predecessor→follower pair, id
  ``"<file stem>/v<i-1>-v<i>"``: the follower's ``x, v, a`` and the predecessor's
  ``lead_x, lead_v, lead_a``; ``command=None`` with ``command_kind="acceleration"``
  (no command was recorded: the upper level must be calibrated with the lower one).
  ``lead_x`` is the predecessor's *rear bumper*, ``X_{i-1} - length_{i-1}``, so
  ``lead_x - x`` is the published bumper-to-bumper ``Spacing_i`` (the loader checks
  this identity and records the largest deviation). Lengths, GPS-antenna offsets and
  type ids from ``Labels.csv`` are in ``meta``.
* Free-flow files (``Time, X1, SpeedDoppler1, Accel1``, named
  ``<platoon id>_<start>_<end>_V<km/h>``) give one run with the ACC set speed of
  ``FreeFlowStableParts.csv`` as a constant speed command (``command_kind="speed"``).
  Their ``X1`` is already wrapped to one lap; the loader unwraps it (recorded).
* ``exo["grade"]``: the road grade (rise over run, positive uphill in the driving
  direction) at the vehicle's position, from ``Slope.csv`` at
  ``(x + grade_offset) mod lap_length`` with ``lap_length`` = the last ``X`` of
  ``Slope.csv`` (5757.904 m) by default. The free-flow files' ``X1`` equals the platoon
  files' ``X1 mod 5757.904`` to 1e-9 m, so the published positions use this very lap;
  see docs/guide/field-data.md § Road grade for the evidence on the offset.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..data import DataError, Run
from ._common import (
    check_accel_units,
    check_finite,
    check_signal,
    check_speed_units,
    check_time,
    check_time_step,
    numeric_column,
    read_table,
    require_columns,
    where,
)

__all__ = ["load_openacc_astazero", "load_slope", "grade_at"]

_FF_NAME = re.compile(
    r"^(?P<id>.+?)_(?P<start>\d+(?:\.\d+)?)_(?P<end>\d+(?:\.\d+)?)_V(?P<kmh>\d+)$")


def load_slope(path: str | Path) -> tuple[np.ndarray, np.ndarray, float]:
    """``Slope.csv``: lap positions ``X`` (m, increasing), grades ``Y`` and the lap
    length (the last ``X``)."""
    path = Path(path)
    df = read_table(path)
    require_columns(df, path, ["X", "Y"])
    x = numeric_column(df, path, "X")
    y = numeric_column(df, path, "Y")
    check_finite(x, path, "X")
    check_finite(y, path, "Y")
    check_time(x, path, "X", uniform=False)
    if np.max(np.abs(y)) > 0.3:
        i = int(np.argmax(np.abs(y) > 0.3))
        raise DataError(f"{where(path, 'Y', i)}: grade {y[i]:g} is implausible (expected a "
                        "dimensionless rise over run, |Y| < 0.3; percent?)")
    return x, y, float(x[-1])


def grade_at(x: np.ndarray, slope: tuple[np.ndarray, np.ndarray, float], *,
             offset: float = 0.0, lap_length: float | None = None) -> np.ndarray:
    """Grade at positions ``x``: linear interpolation of the lap profile at
    ``(x + offset) mod lap_length`` (periodic)."""
    sx, sy, lap = slope
    lap = lap if lap_length is None else float(lap_length)
    if not (lap > 0):
        raise ValueError(f"lap_length: must be > 0, got {lap_length!r}")
    return np.interp(np.mod(np.asarray(x, dtype=np.float64) + offset, lap), sx, sy, period=lap)


def _find(start: Path, name: str, given: str | Path | None) -> Path | None:
    """A side file: ``given``, else the first that exists of ``name`` beside the data,
    in the sibling ``platoon/`` or ``freeflow/`` folders (the shared layout), one
    folder up or in ``../../Exp/`` (C2ART-OPT's ``Data/ASTAZERO/Exp/PyData`` and
    ``ExpFreeFlow/PyData`` with ``Exp/Slope.csv``)."""
    if given is not None:
        p = Path(given)
        if not p.is_file():
            raise FileNotFoundError(f"{p}: no such file (given for {name})")
        return p
    base = start if start.is_dir() else start.parent
    for cand in (base / name, base.parent / "platoon" / name, base.parent / "freeflow" / name,
                 base.parent / name, base.parent.parent / "Exp" / name):
        if cand.is_file():
            return cand
    return None


def _labels(path: Path | None, stem: str) -> dict[str, float]:
    if path is None:
        raise DataError(f"Labels.csv: not found beside the data; needed for {stem} "
                        "(pass labels=PATH)")
    df = read_table(path)
    require_columns(df, path, ["File"])
    hit = np.flatnonzero(df["File"].astype(str).str.strip().to_numpy() == stem)
    if not hit.size:
        raise DataError(f"{where(path, 'File')}: no row for {stem!r}")
    row = df.iloc[[int(hit[0])]].reset_index(drop=True)
    return {c: float(numeric_column(row, path, c)[0]) for c in df.columns[1:]}


def _read_numeric(path: Path, df: pd.DataFrame,
                  cols: Sequence[str]) -> tuple[dict[str, np.ndarray], float]:
    require_columns(df, path, cols)
    data = {c: numeric_column(df, path, c) for c in cols}
    for c in cols:
        check_finite(data[c], path, c)
    dt = check_time(data["Time"], path, "Time")
    check_time_step(dt, path, "Time", 1)
    return data, dt


def _platoon(path: Path, df: pd.DataFrame, slope: Any, labels: Path | None, offset: float,
             lap: float | None) -> list[Run]:
    stem = path.stem
    nveh = 1
    while f"X{nveh + 1}" in df.columns:
        nveh += 1
    if nveh < 2:
        raise DataError(f"{where(path, 'X2')}: missing column: a platoon file needs X1..Xn")
    cols = ["Time"] + [f"{p}{i}" for p in ("X", "SpeedDoppler", "Accel")
                       for i in range(1, nveh + 1)] + [f"Spacing{i}" for i in range(2, nveh + 1)]
    d, dt = _read_numeric(path, df, cols)
    for i in range(1, nveh + 1):
        check_signal("position", d[f"X{i}"], path, f"X{i}", dt=dt)
        check_speed_units(d[f"SpeedDoppler{i}"], path, f"SpeedDoppler{i}", dt=dt,
                          x=d[f"X{i}"])
        check_accel_units(d[f"Accel{i}"], path, f"Accel{i}")
    lab = _labels(labels, stem)
    runs = []
    t = d["Time"]
    for i in range(2, nveh + 1):
        for c in (f"length{i - 1}", f"length{i}"):
            if c not in lab:
                raise DataError(f"{where(labels or 'Labels.csv', c)}: missing column "
                                f"(needed for {stem})")
        lp = lab[f"length{i - 1}"]
        lead_x = d[f"X{i - 1}"] - lp
        x = d[f"X{i}"]
        dev = lead_x - x - d[f"Spacing{i}"]
        cleaning = [f"lead_x = X{i - 1} - length{i - 1} ({lp:g} m): the predecessor's rear "
                    f"bumper; lead_x - x reproduces Spacing{i} within "
                    f"{float(np.max(np.abs(dev))):.2g} m"]
        exo = {}
        if slope is not None:
            exo["grade"] = grade_at(x, slope, offset=offset, lap_length=lap)
        meta = {
            "format": "openacc-astazero", "kind": "platoon", "file": str(path),
            "pair": (i - 1, i), "leader_index": i - 1, "follower_index": i,
            "length": lab.get(f"length{i}"), "lead_length": lp,
            "atf": lab.get(f"atf{i}"), "atb": lab.get(f"atb{i}"),
            "lead_atf": lab.get(f"atf{i - 1}"), "lead_atb": lab.get(f"atb{i - 1}"),
            "type": lab.get(f"type{i}"), "lead_type": lab.get(f"type{i - 1}"),
            "spacing_column": f"Spacing{i}", "spacing_max_deviation": float(np.max(np.abs(dev))),
            "grade_offset": offset, "cleaning": cleaning,
        }
        runs.append(Run(run_id=f"{stem}/v{i - 1}-v{i}", t=t, a=d[f"Accel{i}"],
                        command_kind="acceleration", command=None, v=d[f"SpeedDoppler{i}"],
                        x=x, lead_x=lead_x, lead_v=d[f"SpeedDoppler{i - 1}"],
                        lead_a=d[f"Accel{i - 1}"], exo=exo, meta=meta))
    return runs


def _freeflow(path: Path, df: pd.DataFrame, slope: Any, parts: Path | None, offset: float,
              lap: float | None) -> list[Run]:
    stem = path.stem
    m = _FF_NAME.match(stem)
    if m is None:
        raise DataError(f"{path}: free-flow file name must be <platoon id>_<start>_<end>_V<km/h>")
    if parts is None:
        raise DataError(f"FreeFlowStableParts.csv: not found beside {path} (pass stable_parts=)")
    pdf = read_table(parts)
    require_columns(pdf, parts, ["File", "setSpd_mps", "timeStart", "timeEnd"])
    ts = numeric_column(pdf, parts, "timeStart")
    te = numeric_column(pdf, parts, "timeEnd")
    sp = numeric_column(pdf, parts, "setSpd_mps")
    files = pdf["File"].astype(str).str.strip().to_numpy()
    hit = np.flatnonzero((files == m["id"]) & (ts == float(m["start"])) & (te == float(m["end"])))
    if not hit.size:
        raise DataError(f"{where(parts, 'File')}: no row for {m['id']} from {m['start']} to "
                        f"{m['end']} s (file {path.name})")
    r = int(hit[0])
    vset = float(sp[r])
    check_speed_units(np.array([vset]), parts, "setSpd_mps")
    if abs(vset * 3.6 - float(m["kmh"])) > 1.0:
        raise DataError(f"{where(parts, 'setSpd_mps', r)}: set speed {vset:g} m/s does not match "
                        f"the file name's V{m['kmh']} km/h")
    d, dt = _read_numeric(path, df, ["Time", "X1", "SpeedDoppler1", "Accel1"])
    check_signal("position", d["X1"], path, "X1")
    check_speed_units(d["SpeedDoppler1"], path, "SpeedDoppler1", dt=dt, a=d["Accel1"])
    check_accel_units(d["Accel1"], path, "Accel1")
    lap_len = slope[2] if (lap is None and slope is not None) else lap
    x = d["X1"].copy()
    cleaning = []
    jumps = np.flatnonzero(np.diff(x) < -1000.0)
    if jumps.size:
        if lap_len is None:
            raise DataError(f"{where(path, 'X1', int(jumps[0]) + 1)}: position wraps but no lap "
                            "length is known (pass slope= or lap_length=)")
        for j in jumps:
            x[j + 1:] += lap_len
        cleaning.append(f"unwrapped X1 at {jumps.size} lap crossing(s) (lap {lap_len:.3f} m)")
    check_signal("position", x, path, "X1", dt=dt)
    exo = {}
    if slope is not None:
        exo["grade"] = grade_at(x, slope, offset=offset, lap_length=lap)
    cleaning.append(f"constant speed command = ACC set speed {vset:g} m/s "
                    f"(FreeFlowStableParts.csv row {r})")
    meta = {"format": "openacc-astazero", "kind": "freeflow", "file": str(path),
            "platoon": m["id"], "time_start": float(ts[r]), "time_end": float(te[r]),
            "set_speed": vset, "grade_offset": offset, "cleaning": cleaning}
    return [Run(run_id=stem, t=d["Time"], a=d["Accel1"], command_kind="speed",
                command=np.full(d["Time"].shape[0], vset), v=d["SpeedDoppler1"], x=x,
                exo=exo, meta=meta)]


def load_openacc_astazero(
    path: str | Path,
    *,
    slope: str | Path | None = None,
    labels: str | Path | None = None,
    stable_parts: str | Path | None = None,
    grade: bool = True,
    grade_offset: float = 0.0,
    lap_length: float | None = None,
    command_kind: str | None = None,
) -> list[Run]:
    """Runs of OpenACC AstaZero data: a platoon file (one closed-loop run per
    predecessor→follower pair), a free-flow file (one constant-set-speed run) or a
    directory (all ``ASta_*.csv`` below it, platoon pairs first).

    ``slope``, ``labels`` and ``stable_parts`` default to ``Slope.csv``, ``Labels.csv``
    and ``FreeFlowStableParts.csv`` found beside the file, in the sibling
    ``platoon/``/``freeflow/`` folders (the shared layout), one folder up or in
    ``../../Exp/`` (C2ART-OPT's layout: ``Data/ASTAZERO/Exp/PyData/*.csv`` with
    ``Data/ASTAZERO/Exp/Slope.csv``). ``grade=False`` skips ``exo["grade"]``;
    ``grade_offset`` (m) shifts the position at which the lap profile is read;
    ``lap_length`` (m) overrides the lap length (default: the last ``X`` of
    ``Slope.csv``).
    ``command_kind``, if given, keeps only the runs of that kind (``acceleration``:
    platoon pairs, ``speed``: free flow); it is an error when none is left.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    if command_kind not in (None, "acceleration", "speed"):
        raise ValueError(f"command_kind: must be 'acceleration' or 'speed', got {command_kind!r}")
    if not np.isfinite(grade_offset):
        raise ValueError(f"grade_offset: must be finite, got {grade_offset!r}")
    if lap_length is not None and not (np.isfinite(lap_length) and lap_length > 0):
        raise ValueError(f"lap_length: must be a finite length > 0 (m), got {lap_length!r}")
    if path.is_dir():
        files = sorted(path.glob("**/ASta_*.csv"),
                       key=lambda p: (1 if _FF_NAME.match(p.stem) else 0, p.name, str(p)))
        if not files:
            raise DataError(f"{path}: no ASta_*.csv files in this folder")
    else:
        files = [path]
    runs: list[Run] = []
    for f in files:
        head = read_table(f)
        require_columns(head, f, ["Time", "X1", "SpeedDoppler1", "Accel1"])
        sl_path = _find(f, "Slope.csv", slope) if grade else None
        if grade and sl_path is None:
            raise DataError(f"Slope.csv: not found beside {f} (pass slope=PATH or grade=False)")
        sl = load_slope(sl_path) if sl_path is not None else None
        if "X2" in head.columns:
            runs += _platoon(f, head, sl, _find(f, "Labels.csv", labels), grade_offset,
                             lap_length)
        else:
            runs += _freeflow(f, head, sl, _find(f, "FreeFlowStableParts.csv", stable_parts),
                              grade_offset, lap_length)
    if command_kind is not None:
        runs = [r for r in runs if r.command_kind == command_kind]
        if not runs:
            raise DataError(f"{path}: no {command_kind!r} runs (platoon pairs are closed-loop "
                            "'acceleration' runs without a command; free flow is 'speed')")
    return runs
