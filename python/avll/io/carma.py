"""Loader of the FHWA CARMA platoon CSVs (``format="carma"``).

One file holds, every 0.1 s, a column group per vehicle ``V`` (``leader``,
``follower1`` ...): ``V_CARMA_mode`` (2 = engaged), ``V_Speed_command`` (m/s, the
upper level's command to the speed controller), ``V_CARMA_ovr``,
``V_CARMA_ovr_manual``, ``V_avg_speed_driven_wheels`` (m/s), ``V_acceleration``
(m/s², CAN, quantised) and others. The loader returns one speed-command run per
vehicle and engaged stretch, with the id ``"<file stem>/<vehicle>/sNN"``.

Cleaning, each step recorded in ``run.meta["cleaning"]`` (and the whole file's
account in ``run.meta["file_report"]``):

1. rows are sorted by ``Time`` (the published files have a few misplaced rows);
   exact duplicate rows are dropped, conflicting duplicated times are an error;
2. the rows are put on the uniform 0.1 s grid; steps that are not a multiple of the
   sample time (beyond ``time_tol``) are an error, whole missing rows become holes;
3. a sample is *engaged* when mode == 2, command > 0, the driver override flag is
   not set and the command, wheel speed and acceleration are all present;
   a sample is *missing* when the mode, the command, the speed or the acceleration
   cell is empty (or the row is missing) and *off* otherwise;
4. holes of at most ``max_hole`` seconds of *missing* samples between two engaged
   samples are bridged: the empty cells of command, speed and acceleration are
   linearly interpolated between the nearest present values of the same signal, a
   value present in such a sample is kept as measured (in the published files
   these are single empty cells from the 10 Hz binning of the 20 Hz/40 Hz CAN
   messages); longer holes, and any *off* sample, end a stretch:
   nothing is interpolated across them;
5. stretches shorter than ``min_duration`` seconds are dropped (counted).

The override flags. The data dictionary (data-elements.xlsx) lists two flags,
``override_enabled_cacc`` and ``accelerator_pedal_override_active``. In all four
published files ``V_CARMA_ovr`` equals 1 exactly when ``V_CARMA_mode`` equals 2
(so it is the "override enabled" state of CARMA, not an override event), and
``V_CARMA_ovr_manual`` is empty throughout. The loader therefore excludes samples
with ``V_CARMA_ovr_manual == 1`` (none here), requires ``V_CARMA_ovr == 1`` while
engaged (a consistency check: a 0 there is counted as not engaged), and records
that no driver-override information is present.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .._limits import check_number
from ..data import DataError, Run
from ._common import (
    check_accel_units,
    check_speed_units,
    check_time_span,
    contiguous,
    numeric_column,
    read_table,
    require_columns,
    where,
)

__all__ = ["load_carma", "carma_report", "carma_vehicles", "CARMA_FIELDS"]

#: Suffixes of a vehicle's columns that the loader needs.
CARMA_FIELDS = ("CARMA_mode", "Speed_command", "CARMA_ovr", "avg_speed_driven_wheels",
                "acceleration")


def carma_vehicles(columns: Sequence[str]) -> list[str]:
    """The vehicle prefixes of a CARMA file: every ``<V>`` with at least one
    ``<V>_<field>`` column of :data:`CARMA_FIELDS`, in column order (so a vehicle with a
    missing column is reported, not silently skipped)."""
    return list(dict.fromkeys(c[: -len(f) - 1] for c in columns for f in CARMA_FIELDS
                              if c.endswith("_" + f) and len(c) > len(f) + 1))


def _quantum(a: np.ndarray, share: float = 0.9) -> float:
    """The quantisation step of ``a`` (m/s²).

    The CARMA CAN acceleration is ``k * q`` truncated to two decimals (0.09, 0.19,
    ..., 1.07, ..., 2.35 for q = 0.098 m/s² = 0.01 g). Returns the largest q in
    [0.01, 0.2] for which at least ``share`` of the non-zero samples are such
    truncated multiples (a few samples are averages of two levels, from the 10 Hz
    binning); NaN with fewer than 20 non-zero samples."""
    v = np.abs(a[np.isfinite(a)])
    v = v[v > 0.005]
    if v.size < 20:
        return float("nan")
    u, c = np.unique(np.round(v, 6), return_counts=True)
    qs = np.arange(0.2, 0.01, -1e-4)[:, None]
    k = np.round(u[None, :] / qs)
    gap = k * qs - u[None, :]
    fit = (k > 0) & (gap > -1e-6) & (gap < 0.01 + 1e-6)
    ok = np.flatnonzero((fit * c[None, :]).sum(axis=1) >= share * v.size)
    return round(float(qs[ok[0], 0]), 4) if ok.size else float("nan")


def _why(i: int, step: int, sig: dict[str, np.ndarray], veh: str, hole_max: int,
         dt: float) -> str:
    """Why sample ``i``, just outside a stretch (``step`` -1 before, +1 after), is not
    part of it."""
    n = sig["mode"].shape[0]
    if sig["missing"][i]:
        j = i
        while 0 <= j < n and sig["missing"][j]:
            j += step
        length = abs(j - i)
        if length > hole_max:
            return f"empty cells for {length * dt:.1f} s (> max_hole)"
        nxt = _why(j, step, sig, veh, hole_max, dt) if 0 <= j < n else "the file's edge"
        return f"empty cells for {length * dt:.1f} s then {nxt}"
    mode, cmd = sig["mode"][i], sig["cmd"][i]
    if np.isfinite(mode) and mode != 2:
        return f"mode {mode:g}"
    if np.isfinite(cmd) and cmd <= 0:
        return f"command {cmd:g}"
    if sig["overridden"][i]:
        return "driver override"
    return f"{veh}_CARMA_ovr = {sig['ovr'][i]:g}"


def load_carma(
    path: str | Path,
    *,
    vehicles: Sequence[str] | None = None,
    min_duration: float = 10.0,
    max_hole: float = 0.2,
    dt: float = 0.1,
    time_tol: float = 0.01,
    speed_column: str = "avg_speed_driven_wheels",
    override_column: str = "CARMA_ovr_manual",
    command_kind: str | None = None,
) -> list[Run]:
    """Engaged, not overridden stretches of a CARMA CSV as speed-command runs.

    Parameters
    ----------
    path
        The CSV file.
    vehicles
        Vehicle prefixes to load (default: all in the file). A requested vehicle
        without any engaged stretch is an error.
    min_duration
        Shortest stretch kept (s).
    max_hole
        Longest run of empty cells / missing rows bridged by linear interpolation
        inside an engaged stretch (s); longer holes split the stretch.
    dt
        The nominal sample time (s).
    time_tol
        The tolerance on the time grid (fraction of ``dt``).
    speed_column
        The measured-speed column suffix (``avg_speed_driven_wheels`` or e.g.
        ``GPS_speed``).
    override_column
        Suffix of the driver-override flag (samples where it is 1 are excluded;
        empty cells mean "no information").
    command_kind
        Must be ``None`` or ``"speed"`` (the CARMA command is a speed).

    Returns one :class:`avll.Run` per stretch (``command_kind="speed"``, ``command``
    the speed command, ``v`` the measured speed, ``a`` the CAN acceleration, ``t``
    the file's ``Time``). Raises :class:`avll.DataError` for bad input.
    """
    if command_kind not in (None, "speed"):
        raise ValueError(f"command_kind: CARMA commands are speeds, got {command_kind!r}")
    min_duration, max_hole, dt, time_tol = (check_number(v, n) for v, n in (
        (min_duration, "min_duration"), (max_hole, "max_hole"), (dt, "dt"),
        (time_tol, "time_tol")))
    if not (min_duration >= 0):
        raise ValueError(f"min_duration: must be >= 0, got {min_duration!r}")
    if not (max_hole >= 0):
        raise ValueError(f"max_hole: must be >= 0, got {max_hole!r}")
    if not (dt > 0):
        raise ValueError(f"dt: must be > 0, got {dt!r}")
    path = Path(path)
    df = read_table(path, numeric=True)
    require_columns(df, path, ["Time"])
    found = carma_vehicles(df.columns)
    explicit = vehicles is not None
    if vehicles is None:
        if not found:
            raise DataError(f"{where(path, 'leader_CARMA_mode')}: missing column: no "
                            "'<vehicle>_CARMA_mode' column, is this a CARMA file?")
        vehicles = found
    vehicles = list(vehicles)
    require_columns(df, path, [f"{v}_{f}" for v in vehicles
                               for f in (*CARMA_FIELDS[:4], speed_column, "acceleration")])

    stem = path.stem
    file_notes: list[str] = []
    # --- time: parse, sort, grid --------------------------------------------------
    t_raw = numeric_column(df, path, "Time")
    bad = np.flatnonzero(~np.isfinite(t_raw))
    if bad.size:
        raise DataError(f"{where(path, 'Time', int(bad[0]))}: time is {t_raw[bad[0]]}")
    descents = np.flatnonzero(np.diff(t_raw) < 0)
    order = np.argsort(t_raw, kind="stable")
    if descents.size:
        file_notes.append(
            f"sorted by Time: {descents.size} rows were out of order (first: row "
            f"{int(descents[0])} with Time {t_raw[descents[0]]:g} before row "
            f"{int(descents[0]) + 1} with Time {t_raw[descents[0] + 1]:g})")
    df = df.iloc[order].reset_index(drop=True)
    rows = order  # original data-row index of each sorted row
    t = t_raw[order]
    dup = np.flatnonzero(np.diff(t) == 0)
    if dup.size:  # rows compared as written
        text = read_table(path).iloc[order].reset_index(drop=True)
        keep = np.ones(t.shape[0], dtype=bool)
        for j in (int(x) for x in dup):
            a_row, b_row = text.iloc[j], text.iloc[j + 1]
            if not a_row.equals(b_row):
                raise DataError(
                    f"{where(path, 'Time', int(rows[j + 1]))}: duplicated time {t[j]:g} with "
                    f"different values (also row {int(rows[j])})")
            keep[j + 1] = False
        file_notes.append(f"dropped {int((~keep).sum())} exact duplicate rows")
        df = df[keep].reset_index(drop=True)
        rows, t = rows[keep], t[keep]
    if t.shape[0] < 2:
        raise DataError(f"{where(path, 'Time')}: needs at least 2 rows, got {t.shape[0]}")
    check_time_span(t, path, "Time", rows)  # before the grid over the span is built
    k = np.round((t - t[0]) / dt).astype(np.int64)
    off = np.flatnonzero(np.abs(t - t[0] - k * dt) > time_tol * dt)
    if off.size:
        i = int(off[0])
        raise DataError(
            f"{where(path, 'Time', int(rows[i]))}: non-uniform sampling: "
            f"Time {float(t[i]):.10g} is "
            f"not on the {dt:g} s grid from {t[0]:g} (tolerance {time_tol * dt:g} s)")
    n = int(k[-1]) + 1
    missing_rows = n - t.shape[0]
    if missing_rows:
        file_notes.append(f"{missing_rows} missing rows (time steps absent from the file) "
                          "treated as empty cells")
    grid_t = t[0] + dt * np.arange(n)
    grid_t[k] = t  # the file's own time stamps where the row exists
    grid_row = np.full(n, -1, dtype=np.int64)
    grid_row[k] = rows

    def col(name: str) -> np.ndarray:
        out = np.full(n, np.nan)
        out[k] = numeric_column(df, path, name, allow_empty=True)
        return out

    hole_max = int(np.floor(max_hole / dt + 1e-9))
    runs: list[Run] = []
    report: dict[str, Any] = {"file": str(path), "rows": int(len(t_raw)),
                              "notes": file_notes, "vehicles": {}}
    empty_vehicles = []
    for veh in vehicles:
        mode = col(f"{veh}_CARMA_mode")
        cmd = col(f"{veh}_Speed_command")
        ovr = col(f"{veh}_CARMA_ovr")
        spd = col(f"{veh}_{speed_column}")
        acc = col(f"{veh}_acceleration")
        man_name = f"{veh}_{override_column}"
        man = col(man_name) if man_name in df.columns else np.full(n, np.nan)
        for name, arr in ((f"{veh}_{speed_column}", spd), (f"{veh}_Speed_command", cmd),
                          (f"{veh}_acceleration", acc), (f"{veh}_CARMA_mode", mode),
                          (f"{veh}_CARMA_ovr", ovr)):
            bad = np.flatnonzero(np.isinf(arr))
            if bad.size:
                raise DataError(f"{where(path, name, int(grid_row[bad[0]]))}: value is inf")
        check_accel_units(acc, path, f"{veh}_acceleration")
        check_speed_units(spd, path, f"{veh}_{speed_column}", dt=dt, a=acc)
        check_speed_units(cmd, path, f"{veh}_Speed_command")
        both = (mode == 2) & (cmd > 2.0) & (spd > 2.0)
        if both.sum() >= 50:
            ratio = float(np.median(cmd[both] / spd[both]))
            if not 0.5 < ratio < 2.0:
                i = int(np.flatnonzero(both)[0])
                raise DataError(
                    f"{where(path, f'{veh}_Speed_command', int(grid_row[i]))}: the engaged "
                    f"command is {ratio:.3g} x the measured speed {veh}_{speed_column} (median)"
                    f"; implausible units (km/h would give 3.6): both must be m/s")

        present = (np.isfinite(mode) & np.isfinite(cmd) & np.isfinite(spd) & np.isfinite(acc))
        overridden = man == 1
        ovr_off = np.isfinite(ovr) & (ovr != 1)
        engaged = present & (mode == 2) & (cmd > 0) & ~overridden & ~ovr_off
        # missing: a cell needed to decide or to use the sample is empty, and the known
        # cells do not already say "off"
        known_off = ((np.isfinite(mode) & (mode != 2)) | (np.isfinite(cmd) & (cmd <= 0))
                     | overridden | ovr_off)
        missing = ~present & ~known_off
        # bridge short holes of missing samples between engaged samples: only the empty
        # cells are interpolated (between the nearest present values); a measurement
        # present in a missing sample (e.g. the speed when only the acceleration cell
        # is empty) is kept as it is
        usable = engaged.copy()
        bridged = 0
        filled = 0
        cmd_f, spd_f, acc_f = cmd.copy(), spd.copy(), acc.copy()
        for a, b in contiguous(~engaged):
            if a == 0 or b == n or b - a > hole_max or not missing[a:b].all():
                continue
            idx = np.arange(a - 1, b + 1)
            for arr in (cmd_f, spd_f, acc_f):
                seg = arr[a - 1:b + 1]
                ok = np.isfinite(seg)
                if ok.all():
                    continue
                seg[~ok] = np.interp(idx[~ok], idx[ok], seg[ok])
                filled += int((~ok).sum())
            usable[a:b] = True
            bridged += b - a
        long_holes = [(a, b) for a, b in contiguous(missing)
                      if b - a > hole_max and a > 0 and b < n and engaged[a - 1] and engaged[b]]
        vrep: dict[str, Any] = {
            "engaged_samples": int(engaged.sum()),
            "overridden_samples": int(overridden.sum()),
            "override_flag_present": bool(np.isfinite(man).any()),
            "ovr_flag_equals_mode2": bool(np.all(((ovr == 1) == (mode == 2))[
                np.isfinite(ovr) & np.isfinite(mode)])),
            "bridged_samples": int(bridged),
            "interpolated_cells": int(filled),
            "long_holes_split": len(long_holes),
            "kept": [], "dropped_short": 0, "dropped_short_s": 0.0,
            "a_quantum": _quantum(acc[engaged]),
        }
        sig = {"missing": missing, "mode": mode, "cmd": cmd, "overridden": overridden,
               "ovr": ovr}
        stretches = contiguous(usable)
        s_idx = 0
        for a, b in stretches:
            dur = (b - a - 1) * dt
            if b - a < 2 or dur < min_duration:
                vrep["dropped_short"] += 1
                vrep["dropped_short_s"] += (b - a) * dt
                continue
            s_idx += 1
            nb = int((~engaged[a:b]).sum())
            cleaning = list(file_notes)
            if nb:
                nc = sum(int((~np.isfinite(x[a:b]) & np.isfinite(y[a:b])).sum())
                         for x, y in ((cmd, cmd_f), (spd, spd_f), (acc, acc_f)))
                cleaning.append(f"bridged {nb} samples with empty cells (holes <= "
                                f"{max_hole:g} s): {nc} empty cells of command, speed and "
                                "acceleration linearly interpolated, present values kept")
            ends = []
            if a > 0:
                ends.append(f"start at t={grid_t[a]:.1f} s after "
                            f"{_why(a - 1, -1, sig, veh, hole_max, dt)}")
            if b < n:
                ends.append(f"end at t={grid_t[b - 1]:.1f} s before "
                            f"{_why(b, 1, sig, veh, hole_max, dt)}")
            if ends:
                cleaning.append("stretch bounded by " + ", ".join(ends))
            if not vrep["override_flag_present"]:
                cleaning.append(f"no driver-override information ({man_name} empty)")
            sl = slice(a, b)
            rid = f"{stem}/{veh}/s{s_idx:02d}"
            orig = grid_row[sl]
            meta = {
                "format": "carma", "file": str(path), "vehicle": veh, "stretch": s_idx,
                "t_start": float(grid_t[a]), "t_end": float(grid_t[b - 1]),
                "rows": [int(orig[orig >= 0].min()), int(orig[orig >= 0].max())],
                "cleaning": cleaning, "bridged_samples": nb,
                "speed_column": f"{veh}_{speed_column}",
                "command_column": f"{veh}_Speed_command",
                "accel_column": f"{veh}_acceleration",
                "a_quantum": _quantum(acc[sl][engaged[sl]]),
                "file_report": report,
            }
            runs.append(Run(run_id=rid, t=grid_t[sl], a=acc_f[sl], command_kind="speed",
                            command=cmd_f[sl], v=spd_f[sl], meta=meta))
            vrep["kept"].append({"id": rid, "duration_s": round(dur, 3)})
        report["vehicles"][veh] = vrep
        if s_idx == 0:
            empty_vehicles.append(veh)
    if not runs or (explicit and empty_vehicles):
        veh = empty_vehicles[0]
        raise DataError(
            f"{where(path, f'{veh}_CARMA_mode')}: empty engaged stretch: no engaged, "
            f"not overridden stretch (mode 2, command > 0) of at least {min_duration:g} s "
            f"for {', '.join(empty_vehicles)}")
    return runs


def carma_report(runs: Sequence[Run]) -> pd.DataFrame:
    """Per vehicle and file: stretches kept, their total duration, samples bridged,
    stretches dropped as too short."""
    seen = {rep["file"]: rep for r in runs if (rep := r.meta.get("file_report")) is not None}
    recs = []
    for f, rep in seen.items():
        for veh, v in rep["vehicles"].items():
            durs = [k["duration_s"] for k in v["kept"]]
            recs.append({
                "file": Path(f).stem, "vehicle": veh, "stretches": len(durs),
                "total_s": round(float(np.sum(durs)), 1) if durs else 0.0,
                "min_s": min(durs) if durs else np.nan, "max_s": max(durs) if durs else np.nan,
                "engaged_s": v["engaged_samples"] / 10.0,
                "bridged": v["bridged_samples"], "long_holes": v["long_holes_split"],
                "dropped_short": v["dropped_short"],
            })
    return pd.DataFrame.from_records(recs)
