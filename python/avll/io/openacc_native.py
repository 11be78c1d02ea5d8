"""Loader of the JRC OpenACC database in its native layout (``format="openacc"``).

The layout (the same at every test site of the database; the ZalaZone files were
checked):

.. code-block:: text

    Date,8,10,2019
    Vehicle_order,SMART_TARGET,TESLA_MODEL3,...,
    Number_of_vehicles,7
    ACC,1
    Distance_setting,L
    Time,Speed1,E1,N1,Lon1,Lat1,Alt1,...,SpeedN,EN,NN,LonN,LatN,AltN,IVS1,...,IVS(N-1)
    480.0,11.10,80.28,-117.10,...

Vehicle 1 (the ``*_TARGET``) leads; ``Speed`` is in m/s, ``E``/``N`` in m (local east
and north), ``Alt`` in m and ``IVSi`` the spacing (m) between vehicles ``i`` and
``i+1``. The vehicle numbers are positions in ``Vehicle_order``: a file can lack the
columns of some vehicles (in the ZalaZone handling-course files the target's
columns are absent, so the data start at ``Speed2``), and then the ``IVS`` columns
next to the missing vehicle are absent too.

One closed-loop :class:`avll.Run` per follower whose predecessor was recorded, id
``"<file stem>/v<i-1>-v<i>"`` (the parent folder's name is prefixed when two files of
a folder share a stem). Like the AstaZero pairs, it carries the follower's ``x, v,
a`` and the predecessor's ``lead_x, lead_v, lead_a``, ``command=None`` with
``command_kind="acceleration"`` (no command was recorded: the upper level must be
calibrated with the lower one) and ``upper=None``.

Signals
-------
* ``x``: the follower's position along its path, the cumulative length of its
  east/north track (a step whose two ends are both at standstill, speed below
  :data:`STANDSTILL`, adds nothing: that is GNSS jitter, 0.3–1.7 m over a minute of
  standing in the handling-course files).
* ``lead_x = x + gap``, the predecessor's rear bumper in the follower's path
  coordinate, so ``lead_x - x`` is the measured spacing ``IVS(i-1)``. In the ZalaZone
  files ``IVS`` is exactly the straight-line east/north distance of the two vehicles
  minus a constant per pair (the spread of the difference is below 1 cm), so a cell
  of ``IVS`` that is empty while both vehicles' positions are present is
  reconstructed from the positions with that constant (recorded); on the tracks'
  radii (>= 40 m) the chord and the arc between two cars differ by centimetres.
* ``a`` and ``lead_a``: the time derivative (central differences) of the speed after
  a zero-phase low-pass, a 2nd-order Butterworth filter run forwards and backwards
  (``scipy.signal.sosfiltfilt``), cutoff ``accel_cutoff`` = 1.5 Hz by default. Why:
  in these files the power spectrum of the raw speed derivative falls by more than
  two decades between the 0.5–1 Hz band (vehicle motion: the paper's lower-level
  time constants of 0.5–1 s put its corners at 0.15–0.3 Hz) and 1–1.5 Hz, so the
  speed was already smoothed by the database's processing and what remains above
  1.5 Hz is quantisation noise amplified by the derivative; the zero-phase filter
  does not delay the acceleration relative to the speed. The gain at 1 Hz is 0.84
  (each pass), at 0.5 Hz 0.99.
* ``exo["grade"]``: the road grade (rise over run, uphill positive in the driving
  direction) along the follower's path: the altitude is put on a 1 m grid of the
  path position (mean of the samples per metre, linear interpolation between),
  smoothed and differentiated by a Savitzky–Golay filter of order 2 over
  ``grade_window`` = 30 m. Why: the GNSS altitude is noisy at the centimetre level,
  a 2 cm error over a 30 m window is a grade error below 0.1 %, and the tracks'
  grades change over tens of metres (the dynamic platform: about ±1 % around a
  300 m circle). Over less than one window of path the grade is the slope of a
  straight-line fit.

Known defects handled (each recorded in ``run.meta["cleaning"]``)
-----------------------------------------------------------------------
* ``Vehicle_order`` listing more names than ``Number_of_vehicles``: the first N
  names are taken (the vehicle numbers of the columns index ``Vehicle_order``);
  fewer names than N, or a column of a vehicle number above N, is an error.
* Empty cells: runs of at most ``bridge`` seconds are linearly interpolated, only
  the empty cells (present values are never changed). Runs of empty positions or
  spacings of at most ``bridge_kinematic`` seconds (3 s) while both speeds are
  present are bridged with the speeds: the follower's path length grows by the
  integral of its speed (trapezoid), the spacing by the integral of the speed
  difference from its last known value, the drift to its next known value removed
  linearly. Longer gaps split the record, and the longest stretch where the
  follower, its predecessor and the spacing are all known is the run (the other
  stretches are recorded as dropped). A stretch shorter than ``min_duration``
  seconds gives no run (recorded in the loader's report, see
  :func:`openacc_native_report`).
* GNSS position glitches: an E/N sample whose steps in and out both imply a speed
  more than :data:`GLITCH_TOL` (3 m/s) away from the measured speed is dropped,
  with the spacings computed from it, and bridged as an empty cell (e.g. the
  zig-zag of ``E6``/``N6`` in the last 6 s of ``dynamic_part16``).
* Files of one test day start at different ``Time`` offsets: ``t`` keeps the file's
  own time; ``meta["t_file_start"]`` is the file's first time stamp.
* Vehicles whose columns start late or end early (ZalaZone handling course): their
  runs cover only the samples where they and their predecessor are present.
* The follower's speed disagreeing with its own track length (e.g. ``Speed10`` of
  ``handling_part1`` is about 2.5 % below the speed implied by ``E10``/``N10``,
  whereas the track agrees with the spacing to the predecessor): recorded as
  ``meta["speed_position_ratio"]`` and a cleaning note when off by more than 1 %.

Metadata per run: ``file``, ``folder`` (the parent folder's name), ``date``
(ISO), ``car`` (the follower's model name from ``Vehicle_order``), ``lead_car``,
``setting`` (``"L"``, ``"M"``, ``"S"``; ``None`` without ACC), ``acc`` (bool),
``position`` (1 = the first follower, i.e. vehicle 2), ``vehicle_index``,
``lead_index``, ``track`` (the file name before ``_part``: ``"dynamic"``,
``"handling"``), ``n_vehicles``, ``vehicle_order``, ``gap_column``,
``ivs_offset`` (m, the constant distance − IVS), ``gap_reconstructed`` (samples),
``speed_position_ratio``, ``accel_filter``, ``grade_method``, ``t_file_start``,
``cleaning``.
"""

from __future__ import annotations

import csv
import datetime as _dt
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..data import DataError, Run
from ._common import check_speed_units, check_time, contiguous, where

__all__ = [
    "NativeFile",
    "read_openacc_native",
    "load_openacc_native",
    "openacc_native_report",
    "is_openacc_native",
    "arc_length",
    "derive_acceleration",
    "grade_from_altitude",
    "STANDSTILL",
    "POOL_MIN_SPEED",
    "GLITCH_TOL",
    "SETTINGS",
]

#: Speeds (m/s) below which a vehicle is standing still (its GNSS track does not add
#: path length).
STANDSTILL = 0.1
#: Only samples faster than this (m/s) enter the pooled altitude of the grade: the
#: GNSS altitude of standing vehicles drifts and jumps by up to 3 m (handling course).
POOL_MIN_SPEED = 1.0
#: An E/N sample whose steps in and out both imply a speed this far (m/s) from the
#: measured speed is a position glitch and is dropped (then bridged).
GLITCH_TOL = 3.0
#: Gap settings of the ACC, longest first.
SETTINGS = ("L", "M", "S")
#: Lines before the data rows: five metadata lines and the column header.
HEADER_LINES = 6
_META_KEYS = ("Date", "Vehicle_order", "Number_of_vehicles", "ACC", "Distance_setting")
_VEH_COL = re.compile(r"^(Speed|E|N|Lon|Lat|Alt)(\d+)$")
_IVS_COL = re.compile(r"^IVS(\d+)$")


def _loc(path: Path, column: str | None = None, row: int | None = None,
         line: int | None = None) -> str:
    """Location of an error: data rows as in :func:`avll.io._common.where` (with the
    line of the file), metadata by line."""
    if row is not None:
        return where(path, column, row, header_lines=HEADER_LINES)
    s = str(path)
    if column is not None:
        s += f", column {column!r}"
    if line is not None:
        s += f", line {line}"
    return s


@dataclass
class NativeFile:
    """A parsed native OpenACC file: the metadata header and the columns as float
    arrays (NaN for empty cells), before any cleaning.

    ``names`` are the first ``n_vehicles`` names of ``Vehicle_order`` (all listed
    names in ``listed``); ``vehicles`` maps a vehicle number to its columns
    (``speed``, ``E``, ``N``, ``alt`` and, when present, ``lon``, ``lat``); ``ivs``
    maps ``i`` to the spacing between vehicles ``i`` and ``i + 1``.
    """

    path: Path
    date: _dt.date
    listed: tuple[str, ...]
    names: tuple[str, ...]
    n_vehicles: int
    acc: bool
    setting: str | None
    t: np.ndarray
    vehicles: dict[int, dict[str, np.ndarray]]
    ivs: dict[int, np.ndarray]
    notes: list[str] = field(default_factory=list)

    @property
    def track(self) -> str:
        """The file name before ``_part`` (``dynamic``, ``handling``), lower case."""
        stem = self.path.stem
        return (stem.split("_part")[0] if "_part" in stem else stem).lower()

    def name(self, i: int) -> str:
        """The model name of vehicle ``i`` (1-based)."""
        return self.names[i - 1]


def is_openacc_native(path: str | Path) -> bool:
    """Whether ``path`` starts like a native OpenACC file (first cell ``Date`` and
    the second line ``Vehicle_order``)."""
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            first = f.readline().split(",")[0].strip()
            second = f.readline().split(",")[0].strip()
    except (OSError, UnicodeDecodeError):
        return False
    return first == "Date" and second == "Vehicle_order"


def _meta_line(path: Path, rows: list[list[str]], k: int) -> list[str]:
    """Metadata line ``k`` (0-based) with its key checked; returns the values."""
    key = _META_KEYS[k]
    if len(rows) <= k:
        raise DataError(f"{_loc(path, line=k + 1)}: missing metadata line {key!r} (the "
                        "native OpenACC layout starts with Date, Vehicle_order, "
                        "Number_of_vehicles, ACC, Distance_setting)")
    row = rows[k]
    got = row[0].strip() if row else ""
    if got != key:
        raise DataError(f"{_loc(path, line=k + 1)}: expected the metadata line {key!r}, got "
                        f"{got[:40]!r} (is this a native OpenACC file?)")
    return [c.strip() for c in row[1:]]


def _parse_header(path: Path, rows: list[list[str]]) -> dict[str, Any]:
    vals = _meta_line(path, rows, 0)
    try:
        d, m, y = (int(v) for v in [x for x in vals if x][:3])
        date = _dt.date(y, m, d)
    except (ValueError, TypeError):
        raise DataError(f"{_loc(path, line=1)}: Date must be 'Date,D,M,Y' (day, month, "
                        f"year), got {','.join(vals)[:40]!r}") from None
    listed = tuple(v for v in _meta_line(path, rows, 1) if v)
    if not listed:
        raise DataError(f"{_loc(path, line=2)}: Vehicle_order lists no vehicle")
    nv = [v for v in _meta_line(path, rows, 2) if v]
    try:
        n = int(nv[0]) if len(nv) == 1 else -1
    except ValueError:
        n = -1
    if n < 2:
        raise DataError(f"{_loc(path, line=3)}: Number_of_vehicles must be an integer >= 2, "
                        f"got {','.join(nv)[:40]!r}")
    if len(listed) < n:
        raise DataError(f"{_loc(path, line=2)}: Vehicle_order lists {len(listed)} names but "
                        f"Number_of_vehicles (line 3) is {n}")
    acc_v = [v for v in _meta_line(path, rows, 3) if v]
    if acc_v not in (["0"], ["1"]):
        raise DataError(f"{_loc(path, line=4)}: ACC must be 0 or 1, got {','.join(acc_v)!r}")
    acc = acc_v == ["1"]
    st = [v for v in _meta_line(path, rows, 4) if v]
    if len(st) > 1 or (st and st[0].upper() not in SETTINGS):
        raise DataError(f"{_loc(path, line=5)}: Distance_setting must be L, M, S or empty, "
                        f"got {','.join(st)[:40]!r}")
    setting = st[0].upper() if st else None
    return {"date": date, "listed": listed, "n": n, "acc": acc, "setting": setting}


def _to_float(path: Path, name: str, cells: Sequence[str]) -> np.ndarray:
    """Cells as float64; empty cells (and ``nan`` text) are NaN, anything else that is
    not a number is an error naming the row and line."""
    try:  # fast path: numpy parses the numbers, empty cells become NaN
        arr = np.array([c if c.strip() else "nan" for c in cells], dtype=np.float64)
        if not np.isinf(arr).any():
            return arr
    except ValueError:
        pass
    out = np.full(len(cells), np.nan)
    for r, c in enumerate(cells):
        c = c.strip()
        if not c or c.lower() in ("nan", "-nan", "+nan", "na"):
            continue
        try:
            out[r] = float(c)
        except ValueError:
            raise DataError(f"{_loc(path, name, r)}: not a number: {c[:40]!r}") from None
        if not math.isfinite(out[r]):
            raise DataError(f"{_loc(path, name, r)}: value is {c[:40]!r} (inf is not allowed)")
    return out


def read_openacc_native(path: str | Path) -> NativeFile:
    """Parses one native OpenACC file (metadata header, columns) without cleaning.

    Raises :class:`avll.DataError` naming the file, the column and the line for a
    bad header, a wrong vehicle count, a ragged row or a cell that is not a number.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise DataError(f"{path}: is a directory, expected a native OpenACC CSV file")
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            rows = list(csv.reader(f))
    except UnicodeDecodeError as e:
        raise DataError(f"{path}: not a readable text file ({e})") from e
    except csv.Error as e:
        raise DataError(f"{path}: not a readable CSV file ({e})") from e
    if not rows:
        raise DataError(f"{path}: empty file (no header, no data)")
    h = _parse_header(path, rows)
    if len(rows) < HEADER_LINES:
        raise DataError(f"{_loc(path, line=HEADER_LINES)}: missing the column header line "
                        "(Time, Speed1, E1, N1, ...)")
    header = [c.strip() for c in rows[HEADER_LINES - 1]]
    while header and header[-1] == "":
        header.pop()
    if not header or header[0] != "Time":
        raise DataError(f"{_loc(path, header[0] if header else None, line=HEADER_LINES)}: the "
                        "column header must start with 'Time'")
    seen: set[str] = set()
    veh_cols: dict[int, dict[str, int]] = {}
    ivs_cols: dict[int, int] = {}
    n = h["n"]
    for j, c in enumerate(header):
        if c in seen:
            raise DataError(f"{_loc(path, c, line=HEADER_LINES)}: duplicated column")
        seen.add(c)
        if j == 0:
            continue
        mv, mi = _VEH_COL.match(c), _IVS_COL.match(c)
        if mv:
            k = int(mv[2])
            if not 1 <= k <= n:
                raise DataError(
                    f"{_loc(path, c, line=HEADER_LINES)}: vehicle {k} but "
                    f"Number_of_vehicles (line 3) is {n}: wrong vehicle count")
            veh_cols.setdefault(k, {})[mv[1]] = j
        elif mi:
            k = int(mi[1])
            if not 1 <= k < n:
                raise DataError(
                    f"{_loc(path, c, line=HEADER_LINES)}: spacing between vehicles {k} and "
                    f"{k + 1} but Number_of_vehicles (line 3) is {n}: wrong vehicle count")
            ivs_cols[k] = j
        else:
            raise DataError(f"{_loc(path, c, line=HEADER_LINES)}: unknown column (expected "
                            "Time, Speed<i>, E<i>, N<i>, Lon<i>, Lat<i>, Alt<i>, IVS<i>)")
    if not veh_cols:
        raise DataError(f"{_loc(path, 'Speed1', line=HEADER_LINES)}: missing column: no "
                        "vehicle columns (Speed<i>, E<i>, N<i>, Alt<i>)")
    for k, cols in sorted(veh_cols.items()):
        for need in ("Speed", "E", "N", "Alt"):
            if need not in cols:
                raise DataError(f"{_loc(path, f'{need}{k}', line=HEADER_LINES)}: missing "
                                f"column (vehicle {k} has {', '.join(cols)})")
    data = rows[HEADER_LINES:]
    while data and not any(c.strip() for c in data[-1]):
        data.pop()
    if not data:
        raise DataError(f"{path}: no data rows (only the header)")
    width = len(header)
    for r, row in enumerate(data):
        if len(row) < width or any(c.strip() for c in row[width:]):
            raise DataError(f"{_loc(path, header[min(len(row), width - 1)], r)}: the row has "
                            f"{len(row)} cells, the header {width}")
    cols_t = list(zip(*[row[:width] for row in data], strict=True))
    t = _to_float(path, "Time", cols_t[0])
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise DataError(f"{_loc(path, 'Time', int(bad[0]))}: empty (missing) time")
    check_time(t, path, "Time")
    keymap = {"Speed": "speed", "E": "E", "N": "N", "Alt": "alt", "Lon": "lon", "Lat": "lat"}
    vehicles = {k: {keymap[q]: _to_float(path, f"{q}{k}", cols_t[j]) for q, j in cols.items()}
                for k, cols in sorted(veh_cols.items())}
    ivs = {k: _to_float(path, f"IVS{k}", cols_t[j]) for k, j in sorted(ivs_cols.items())}
    notes = []
    if len(h["listed"]) > n:
        notes.append(f"Vehicle_order lists {len(h['listed'])} names for {n} vehicles: the "
                     f"first {n} are the cars ({', '.join(h['listed'][n:])} ignored)")
    absent = [k for k in range(1, n + 1) if k not in vehicles]
    if absent:
        notes.append("no columns for vehicle(s) " + ", ".join(
            f"{k} ({h['listed'][k - 1]})" for k in absent))
    for k, v in vehicles.items():
        sp = v["speed"]
        check_speed_units(sp, path, f"Speed{k}")
        neg = np.flatnonzero(sp < -0.5)
        if neg.size:
            raise DataError(f"{_loc(path, f'Speed{k}', int(neg[0]))}: negative speed "
                            f"{sp[neg[0]]:g} m/s")
    return NativeFile(path=path, date=h["date"], listed=h["listed"],
                      names=h["listed"][:n], n_vehicles=n, acc=h["acc"], setting=h["setting"],
                      t=t, vehicles=vehicles, ivs=ivs, notes=notes)


# ---------------------------------------------------------------------------
# Signal processing
# ---------------------------------------------------------------------------


def _bridge(x: np.ndarray, max_samples: int) -> tuple[np.ndarray, int]:
    """Linear interpolation of interior runs of at most ``max_samples`` NaN cells
    (only those cells); returns the array and the number of cells filled."""
    out = x.copy()
    filled = 0
    fin = np.isfinite(out)
    for a, b in contiguous(~fin):
        if a == 0 or b == out.shape[0] or b - a > max_samples:
            continue
        out[a:b] = np.interp(np.arange(a, b), [a - 1, b], [out[a - 1], out[b]])
        filled += b - a
    return out, filled


def _position_glitches(e: np.ndarray, n: np.ndarray, v: np.ndarray, dt: float,
                       tol: float) -> np.ndarray:
    """Samples whose steps in and out both imply a speed more than ``tol`` m/s away
    from the measured speed (isolated GNSS position glitches)."""
    step = np.hypot(np.diff(e), np.diff(n)) / dt
    vm = 0.5 * (v[:-1] + v[1:])
    with np.errstate(invalid="ignore"):
        badstep = np.abs(step - vm) > tol
    bad = np.zeros(e.shape[0], dtype=bool)
    bad[1:-1] = badstep[:-1] & badstep[1:]
    return bad


def _short_runs(bad: np.ndarray, ok_sides: np.ndarray, max_samples: int) -> np.ndarray:
    """Mask of the interior runs of ``bad`` of at most ``max_samples`` samples whose
    ``ok_sides`` mask holds over the run and its two neighbours."""
    out = np.zeros(bad.shape[0], dtype=bool)
    for a, b in contiguous(bad):
        if a == 0 or b == bad.shape[0] or b - a > max_samples:
            continue
        if ok_sides[a - 1:b + 1].all():
            out[a:b] = True
    return out


def _fill_gap_kinematic(gap: np.ndarray, vf: np.ndarray, vp: np.ndarray, dt: float,
                        max_samples: int) -> tuple[np.ndarray, int]:
    """Fill interior runs of at most ``max_samples`` empty spacing cells by the
    integral of the speed difference (trapezoid) from the last known spacing, with
    the drift to the next known spacing removed linearly; only where both speeds
    are present. Returns the spacing and the number of cells filled."""
    out = gap.copy()
    sides = np.isfinite(vf) & np.isfinite(vp)
    mask = _short_runs(~np.isfinite(out), sides, max_samples)
    n = 0
    for a, b in contiguous(mask):
        d = vp[a - 1:b + 1] - vf[a - 1:b + 1]
        rel = np.concatenate([[0.0], np.cumsum(0.5 * (d[1:] + d[:-1]) * dt)])
        drift = out[b] - (out[a - 1] + rel[-1])
        w = np.arange(rel.shape[0]) / (rel.shape[0] - 1)
        out[a:b] = (out[a - 1] + rel + drift * w)[1:-1]
        n += b - a
    return out, n


def arc_length(e: np.ndarray, n: np.ndarray, v: np.ndarray | None = None,
               standstill: float = STANDSTILL, dt: float | None = None) -> np.ndarray:
    """Cumulative path length (m, from 0) of an east/north track. With speeds ``v``,
    a step whose two ends are both below ``standstill`` adds nothing (GNSS jitter),
    and with ``dt`` too, a step with an empty position adds the integral of the
    speed (trapezoid)."""
    e = np.asarray(e, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    ds = np.hypot(np.diff(e), np.diff(n))
    if v is not None:
        v = np.asarray(v, dtype=np.float64)
        ds[(v[:-1] < standstill) & (v[1:] < standstill)] = 0.0
        if dt is not None:
            hole = ~np.isfinite(ds)
            ds[hole] = 0.5 * (v[:-1] + v[1:])[hole] * dt
    return np.concatenate([[0.0], np.cumsum(ds)])


def derive_acceleration(v: np.ndarray, dt: float, cutoff: float = 1.5) -> np.ndarray:
    """Acceleration from speed: zero-phase 2nd-order Butterworth low-pass at
    ``cutoff`` Hz (forwards and backwards), then central differences. See the
    module doc for the choice of the cutoff."""
    from scipy import signal

    v = np.asarray(v, dtype=np.float64)
    nyq = 0.5 / dt
    if not 0 < cutoff < nyq:
        raise ValueError(f"accel_cutoff: must be in (0, {nyq:g}) Hz, got {cutoff!r}")
    sos = signal.butter(2, cutoff / nyq, output="sos")
    pad = min(v.shape[0] - 1, 3 * 6)
    vf = signal.sosfiltfilt(sos, v, padlen=pad)
    return np.gradient(vf, dt)


def _despike(x: np.ndarray, half: int = 10, k: float = 3.0, floor: float = 0.1) -> np.ndarray:
    """Hampel filter: samples further than ``max(k * 1.4826 * MAD, floor)`` from the
    running median over ``2 half + 1`` samples are replaced by that median."""
    from scipy import ndimage

    size = 2 * half + 1
    med = ndimage.median_filter(x, size=size, mode="nearest")
    mad = 1.4826 * ndimage.median_filter(np.abs(x - med), size=size, mode="nearest")
    out = x.copy()
    bad = np.abs(x - med) > np.maximum(k * mad, floor)
    out[bad] = med[bad]
    return out


def _group_median(groups: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Median of ``values`` per group ``0..n-1`` (NaN for an empty group)."""
    out = np.full(n, np.nan)
    if groups.size == 0:
        return out
    order = np.lexsort((values, groups))
    g, v = groups[order], values[order]
    cnt = np.bincount(g, minlength=n)
    start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    have = cnt > 0
    lo = start[have] + (cnt[have] - 1) // 2
    hi = start[have] + cnt[have] // 2
    out[have] = 0.5 * (v[lo] + v[hi])
    return out


def grade_from_altitude(s: np.ndarray, alt: np.ndarray, window: float = 30.0,
                        step: float = 1.0, *, e: np.ndarray | None = None,
                        n: np.ndarray | None = None,
                        pool: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                        radius: float = 2.0) -> np.ndarray:
    """Grade (rise over run) along a path of positions ``s`` (m, non-decreasing).

    The altitude is put on a ``step`` grid of ``s``: without ``pool``, the median of
    the path's own altitudes per cell, spikes removed first (Hampel filter over 2.1
    s: further than three scaled MADs and 0.1 m from the running median); with
    ``pool = (E, N, alt)`` (e.g. every vehicle of the file, despiked) and the path's
    east/north ``e``, ``n``, the median of the pooled altitudes whose nearest cell
    point is within ``radius`` metres (cells without any use the path's own). The grid
    (linear interpolation across empty cells) is then smoothed and differentiated
    by a Savitzky–Golay filter of order 2 over ``window`` metres. NaN altitudes
    are ignored. Over less than a window, the straight-line slope."""
    from scipy import signal

    s = np.asarray(s, dtype=np.float64)
    alt = np.asarray(alt, dtype=np.float64)
    ok = np.isfinite(s) & np.isfinite(alt)
    if ok.sum() < 2:
        return np.zeros_like(s)
    s_ok = s[ok]
    a_ok = _despike(alt[ok]) if ok.sum() > 21 else alt[ok]
    lo, hi = float(s_ok.min()), float(s_ok.max())
    if hi - lo < step * 3:
        return np.zeros_like(s)
    cells = np.floor((s_ok - lo) / step).astype(np.int64)
    ncell = int(cells.max()) + 1
    med = _group_median(cells, a_ok, ncell)
    centre = lo + step * (np.arange(ncell) + 0.5)
    if pool is not None and e is not None and n is not None:
        from scipy.spatial import cKDTree

        pe, pn, pa = (np.asarray(q, dtype=np.float64) for q in pool)
        keep = np.isfinite(pe) & np.isfinite(pn) & np.isfinite(pa)
        if keep.any() and np.isfinite(np.asarray(e, dtype=np.float64)).sum() >= 2:
            e = np.asarray(e, dtype=np.float64)
            n = np.asarray(n, dtype=np.float64)
            okp = np.isfinite(s) & np.isfinite(e) & np.isfinite(n)
            su, first = np.unique(s[okp], return_index=True)
            ce = np.interp(centre, su, e[okp][first])
            cn = np.interp(centre, su, n[okp][first])
            tree = cKDTree(np.column_stack([ce, cn]))
            dist, cell = tree.query(np.column_stack([pe[keep], pn[keep]]),
                                    distance_upper_bound=radius)
            near = np.isfinite(dist)
            pooled = _group_median(cell[near], pa[keep][near], ncell)
            med = np.where(np.isfinite(pooled), pooled, med)
    have = np.isfinite(med)
    grid_alt = np.interp(centre, centre[have], med[have])
    win = int(round(window / step)) | 1
    if ncell < win or win < 5:
        k = np.polyfit(s_ok, a_ok, 1)[0]
        return np.full_like(s, float(k))
    g = signal.savgol_filter(grid_alt, win, 2, deriv=1, delta=step, mode="interp")
    return np.interp(s, centre, g)


# ---------------------------------------------------------------------------
# Runs
# ---------------------------------------------------------------------------


def _as_set(name: str, value: Any, norm: Any) -> set[Any] | None:
    if value is None:
        return None
    items = [value] if isinstance(value, str) else list(value)
    if not items:
        raise ValueError(f"{name}: is empty")
    return {norm(v) for v in items}


def _norm_setting(v: Any) -> str | None:
    if v is None:
        return None
    s = str(v).strip().upper()
    if s in ("NONE", "", "0", "NO_ACC", "OFF"):
        return None
    if s not in SETTINGS:
        raise ValueError(f"setting: expected L, M, S or none, got {v!r}")
    return s


def _norm_name(v: Any) -> str:
    return str(v).strip().upper()


@dataclass
class _Skip:
    file: str
    follower: int
    car: str
    reason: str


def _follower_runs(nf: NativeFile, rid_stem: str, *, bridge: float, bridge_kinematic: float,
                   min_duration: float,
                   accel_cutoff: float, grade: bool, grade_window: float,
                   require_predecessor: bool, skipped: list[_Skip]) -> list[Run]:
    path = nf.path
    t = nf.t
    dt = float(np.median(np.diff(t)))
    nb = int(math.floor(bridge / dt + 1e-9))
    nk = int(math.floor(bridge_kinematic / dt + 1e-9))
    filled: dict[int, dict[str, int]] = {}
    sig: dict[int, dict[str, np.ndarray]] = {}
    ivs_raw = {k: c.copy() for k, c in nf.ivs.items()}
    glitches: dict[int, int] = {}
    for k, cols in nf.vehicles.items():
        e, nn = cols["E"].copy(), cols["N"].copy()
        bad = _position_glitches(e, nn, cols["speed"], dt, GLITCH_TOL)
        if bad.any():
            glitches[k] = int(bad.sum())
            e[bad] = np.nan
            nn[bad] = np.nan
            for j in (k - 1, k):  # IVS is computed from the positions
                if j in ivs_raw:
                    ivs_raw[j][bad] = np.nan
        sig[k] = {}
        filled[k] = {}
        for q, arr in (("speed", cols["speed"]), ("E", e), ("N", nn), ("alt", cols["alt"])):
            sig[k][q], filled[k][q] = _bridge(arr, nb)
    pool = None
    if grade:
        pe, pn, pa = [], [], []
        for k in sig:
            m = (np.isfinite(sig[k]["E"]) & np.isfinite(sig[k]["N"]) & np.isfinite(sig[k]["alt"])
                 & (sig[k]["speed"] > POOL_MIN_SPEED))
            if m.sum() > 21:
                pe.append(sig[k]["E"][m])
                pn.append(sig[k]["N"][m])
                pa.append(_despike(sig[k]["alt"][m]))
        if pe:
            pool = (np.concatenate(pe), np.concatenate(pn), np.concatenate(pa))
    runs: list[Run] = []
    for i in sorted(nf.vehicles):
        if i == 1:
            continue
        car = nf.name(i)
        lead = i - 1
        if lead not in nf.vehicles:
            skipped.append(_Skip(str(path), i, car, f"predecessor vehicle {lead} "
                                 f"({nf.name(lead)}) has no columns"))
            if not require_predecessor:
                runs += _solo_run(nf, rid_stem, i, sig, filled, dt, min_duration, accel_cutoff,
                                  grade, grade_window, skipped)
            continue
        f, p = sig[i], sig[lead]
        notes = list(nf.notes)
        gcol = f"IVS{lead}"
        dist = np.hypot(f["E"] - p["E"], f["N"] - p["N"])
        for k, who in ((i, "follower"), (lead, "predecessor")):
            if k in glitches:
                notes.append(f"{who} (vehicle {k}): {glitches[k]} E/N samples dropped as "
                             f"glitches (both steps off the speed by > {GLITCH_TOL:g} m/s)")
        if lead in ivs_raw:
            ivs_l = ivs_raw[lead]
            both = np.isfinite(ivs_l) & np.isfinite(dist)
            if both.sum() >= 10:
                off_all = dist[both] - ivs_l[both]
                offset = float(np.median(off_all))
                spread = float(np.percentile(off_all, 95) - np.percentile(off_all, 5))
            else:
                offset, spread = math.nan, math.inf
            gap = ivs_l.copy()
            recon = 0
            if spread <= 0.05:
                fill = ~np.isfinite(gap) & np.isfinite(dist)
                gap[fill] = dist[fill] - offset
                recon = int(fill.sum())
                if recon:
                    notes.append(f"{gcol}: {recon} empty cells reconstructed from the E/N "
                                 f"distance minus {offset:.3f} m (the constant of the present "
                                 f"cells, spread {spread * 100:.2g} cm)")
            else:
                notes.append(f"{gcol}: distance - IVS is not constant (spread "
                             f"{spread:.3g} m): empty cells not reconstructed")
            gap, gfill = _bridge(gap, nb)
            if gfill:
                notes.append(f"{gcol}: {gfill} empty cells interpolated (gaps <= {bridge:g} s)")
            gap, gkin = _fill_gap_kinematic(gap, f["speed"], p["speed"], dt, nk)
            if gkin:
                notes.append(f"{gcol}: {gkin} empty cells (gaps <= {bridge_kinematic:g} s) "
                             "filled by the integral of the speed difference, drift to the "
                             "next spacing removed linearly")
        else:
            skipped.append(_Skip(str(path), i, car, f"no spacing column {gcol}"))
            continue
        pos_ok = np.isfinite(f["E"]) & np.isfinite(f["N"])
        pos_kin = _short_runs(~pos_ok, np.isfinite(f["speed"]), nk)
        if pos_kin.any():
            notes.append(f"follower (vehicle {i}): {int(pos_kin.sum())} samples without E/N "
                         f"(gaps <= {bridge_kinematic:g} s): path length from the speed")
        ok = (np.isfinite(f["speed"]) & (pos_ok | pos_kin)
              & np.isfinite(p["speed"]) & np.isfinite(gap))
        stretches = [(a, b) for a, b in contiguous(ok) if b - a >= 2]
        if not stretches:
            skipped.append(_Skip(str(path), i, car, "no sample with the follower, its "
                                 "predecessor and the spacing all present"))
            continue
        a0, b0 = max(stretches, key=lambda ab: ab[1] - ab[0])
        dur = (b0 - a0 - 1) * dt
        if dur < min_duration:
            skipped.append(_Skip(str(path), i, car, f"longest stretch with the follower, its "
                                 f"predecessor and the spacing present is {dur:.1f} s "
                                 f"(< min_duration {min_duration:g} s)"))
            continue
        others = [(a, b) for a, b in stretches if (a, b) != (a0, b0)]
        if a0 > 0 or b0 < t.shape[0]:
            notes.append(f"kept t = {t[a0]:.1f}..{t[b0 - 1]:.1f} s ({dur:.1f} s) of "
                         f"{t[0]:.1f}..{t[-1]:.1f} s, where the follower, its predecessor "
                         "and the spacing are present"
                         + (f"; dropped {len(others)} other stretch(es) of "
                            f"{sum(b - a for a, b in others) * dt:.1f} s" if others else ""))
        for k, who in ((i, "follower"), (lead, "predecessor")):
            fk = {q: c for q, c in filled[k].items() if c}
            if fk:
                notes.append(f"{who} (vehicle {k}): interpolated empty cells (gaps <= "
                             f"{bridge:g} s): " + ", ".join(f"{q} {c}" for q, c in fk.items()))
        sl = slice(a0, b0)
        v = f["speed"][sl]
        lv = p["speed"][sl]
        x = arc_length(f["E"][sl], f["N"][sl], v, dt=dt)
        g = gap[sl]
        lead_x = x + g
        moving = np.sum(0.5 * (v[1:] + v[:-1]) * dt)
        ratio = float(x[-1] / moving) if moving > 1.0 else math.nan
        if math.isfinite(ratio) and abs(ratio - 1.0) > 0.01:
            notes.append(f"Speed{i} disagrees with the track E{i}/N{i}: path length / "
                         f"integral of speed = {ratio:.4f}")
        check_speed_units(v, path, f"Speed{i}", dt=dt, x=x)
        a = derive_acceleration(v, dt, accel_cutoff)
        la = derive_acceleration(lv, dt, accel_cutoff)
        exo = {}
        if grade:
            exo["grade"] = grade_from_altitude(x, f["alt"][sl], grade_window, e=f["E"][sl],
                                               n=f["N"][sl], pool=pool)
        neg = np.flatnonzero(g < 0)
        if neg.size:
            notes.append(f"{gcol}: {neg.size} negative spacings (min {g.min():.2f} m; the "
                         "constant offset of IVS is not the exact bumper distance)")
        meta = {
            "format": "openacc", "file": str(path), "folder": path.parent.name,
            "date": nf.date.isoformat(), "car": car, "lead_car": nf.name(lead),
            "setting": nf.setting if nf.acc else None, "acc": nf.acc,
            "setting_in_file": nf.setting, "position": i - 1, "vehicle_index": i,
            "lead_index": lead, "track": nf.track, "n_vehicles": nf.n_vehicles,
            "vehicle_order": list(nf.names), "gap_column": gcol,
            "ivs_offset": offset if math.isfinite(offset) else None,
            "gap_reconstructed": recon, "speed_position_ratio":
                ratio if math.isfinite(ratio) else None,
            "accel_filter": f"zero-phase Butterworth order 2, cutoff {accel_cutoff:g} Hz, "
                            "central differences",
            "grade_method": (f"altitude vs path position, Savitzky-Golay order 2 over "
                             f"{grade_window:g} m") if grade else None,
            "t_file_start": float(t[0]), "t_start": float(t[a0]), "t_end": float(t[b0 - 1]),
            "rows": [a0, b0 - 1], "cleaning": notes,
        }
        runs.append(Run(run_id=f"{rid_stem}/v{lead}-v{i}", t=t[sl], a=a,
                        command_kind="acceleration", command=None, v=v, x=x, lead_x=lead_x,
                        lead_v=lv, lead_a=la, exo=exo, meta=meta))
    return runs


def _solo_run(nf: NativeFile, rid_stem: str, i: int, sig: dict[int, dict[str, np.ndarray]],
              filled: dict[int, dict[str, int]], dt: float, min_duration: float,
              accel_cutoff: float, grade: bool, grade_window: float,
              skipped: list[_Skip]) -> list[Run]:
    """A follower without a recorded predecessor (``require_predecessor=False``):
    its own trajectory only."""
    f = sig[i]
    ok = np.isfinite(f["speed"]) & np.isfinite(f["E"]) & np.isfinite(f["N"])
    st = [(a, b) for a, b in contiguous(ok) if b - a >= 2]
    if not st:
        return []
    a0, b0 = max(st, key=lambda ab: ab[1] - ab[0])
    if (b0 - a0 - 1) * dt < min_duration:
        return []
    sl = slice(a0, b0)
    v = f["speed"][sl]
    x = arc_length(f["E"][sl], f["N"][sl], v)
    exo = {"grade": grade_from_altitude(x, f["alt"][sl], grade_window)} if grade else {}  # own
    meta = {"format": "openacc", "file": str(nf.path), "folder": nf.path.parent.name,
            "date": nf.date.isoformat(), "car": nf.name(i), "lead_car": nf.name(i - 1),
            "setting": nf.setting if nf.acc else None, "acc": nf.acc,
            "setting_in_file": nf.setting, "position": i - 1, "vehicle_index": i,
            "lead_index": i - 1, "track": nf.track, "n_vehicles": nf.n_vehicles,
            "vehicle_order": list(nf.names), "t_file_start": float(nf.t[0]),
            "t_start": float(nf.t[a0]), "t_end": float(nf.t[b0 - 1]),
            "cleaning": [*nf.notes, "predecessor not recorded: no lead_* signals"]}
    return [Run(run_id=f"{rid_stem}/v{i - 1}-v{i}", t=nf.t[sl],
                a=derive_acceleration(v, dt, accel_cutoff), v=v, x=x, exo=exo, meta=meta)]


def _natural(p: Path) -> tuple[Any, ...]:
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(p)))


def _files(path: Path) -> list[Path]:
    if path.is_dir():
        files = sorted((f for f in path.rglob("*") if f.is_file()
                        and f.suffix.lower() == ".csv"), key=_natural)
        if not files:
            raise DataError(f"{path}: no *.csv files in this folder or below")
        return files
    return [path]


def load_openacc_native(path: str | Path, command_kind: str | None = None,
                        **options: Any) -> list[Run]:
    """Runs of native OpenACC files: one closed-loop run per follower (see the
    module doc), from a file or a folder (every ``*.csv`` below it, recursively).
    The options are those of :func:`openacc_native_report`, which also says what
    was skipped and why."""
    return openacc_native_report(path, command_kind, **options)[0]


def openacc_native_report(
    path: str | Path,
    command_kind: str | None = None,
    *,
    setting: str | Iterable[str | None] | None = None,
    car: str | Iterable[str] | None = None,
    track: str | Iterable[str] | None = None,
    acc: bool | None = None,
    bridge: float = 1.0,
    bridge_kinematic: float = 3.0,
    min_duration: float = 20.0,
    accel_cutoff: float = 1.5,
    grade: bool = True,
    grade_window: float = 30.0,
    require_predecessor: bool = True,
    skip_foreign: bool = False,
) -> tuple[list[Run], dict[str, Any]]:
    """Runs of native OpenACC files and the loader's report: one closed-loop run per
    follower (see the module doc), from a file or a folder (every ``*.csv`` below
    it, recursively, in natural order of the paths). The report is ``{"files":
    [...], "not_native": [...], "skipped": [{"file", "follower", "car", "reason"}]}``
    (followers without a run and why).

    Filters (each a value or a list; a run is kept when it matches every filter
    given): ``setting`` (``"L"``, ``"M"``, ``"S"``, or ``None``/``"none"`` for the
    files without ACC), ``car`` (model names as in ``Vehicle_order``, any case),
    ``track`` (``"dynamic"``, ``"handling"``), ``acc`` (True/False). It is an error
    when no run is left.

    ``bridge`` (s): longest run of empty cells interpolated; ``bridge_kinematic``
    (s): longest run of empty positions or spacings bridged with the speeds (see
    the module doc); ``min_duration`` (s):
    shortest run kept; ``accel_cutoff`` (Hz): low-pass before differentiating the
    speed; ``grade=False`` skips ``exo["grade"]``; ``grade_window`` (m): the
    Savitzky–Golay window of the grade; ``require_predecessor=False`` also returns
    followers whose predecessor was not recorded (without ``lead_*`` signals);
    ``skip_foreign=True`` skips (and reports) ``*.csv`` files in a folder that are
    not native OpenACC files instead of failing. ``command_kind`` must be ``None``
    or ``"acceleration"`` (the runs have no command and are calibrated in closed
    loop).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if command_kind not in (None, "acceleration"):
        raise DataError(f"{path}: no {command_kind!r} runs: OpenACC followers have no "
                        "recorded command (closed-loop 'acceleration' runs)")
    for nm, val in (("bridge", bridge), ("bridge_kinematic", bridge_kinematic),
                    ("min_duration", min_duration),
                    ("grade_window", grade_window)):
        if not (isinstance(val, (int, float)) and math.isfinite(val) and val >= 0):
            raise ValueError(f"{nm}: must be a finite number >= 0, got {val!r}")
    if not (isinstance(accel_cutoff, (int, float)) and accel_cutoff > 0):
        raise ValueError(f"accel_cutoff: must be > 0 Hz, got {accel_cutoff!r}")
    want_setting = _as_set("setting", setting, _norm_setting)
    want_car = _as_set("car", car, _norm_name)
    want_track = _as_set("track", track, lambda v: str(v).strip().lower())
    files = _files(path)
    stems: dict[str, int] = {}
    for f in files:
        stems[f.stem] = stems.get(f.stem, 0) + 1
    runs: list[Run] = []
    skipped: list[_Skip] = []
    foreign: list[str] = []
    for f in files:
        if path.is_dir() and skip_foreign and not is_openacc_native(f):
            foreign.append(str(f))
            continue
        nf = read_openacc_native(f)
        rid_stem = f.stem if stems[f.stem] == 1 else f"{f.parent.name}/{f.stem}"
        runs += _follower_runs(nf, rid_stem, bridge=bridge, bridge_kinematic=bridge_kinematic,
                               min_duration=min_duration,
                               accel_cutoff=accel_cutoff, grade=grade, grade_window=grade_window,
                               require_predecessor=require_predecessor, skipped=skipped)
    report: dict[str, Any] = {"files": [str(f) for f in files if str(f) not in foreign],
                              "not_native": foreign,
                              "skipped": [vars(s) for s in skipped]}
    total = len(runs)
    if want_setting is not None:
        runs = [r for r in runs if r.meta["setting"] in want_setting]
    if want_car is not None:
        runs = [r for r in runs if _norm_name(r.meta["car"]) in want_car]
    if want_track is not None:
        runs = [r for r in runs if r.meta["track"] in want_track]
    if acc is not None:
        runs = [r for r in runs if r.meta["acc"] == bool(acc)]
    if not runs:
        what = ", ".join(f"{k}={v!r}" for k, v in (("setting", setting), ("car", car),
                                                   ("track", track), ("acc", acc))
                         if v is not None)
        raise DataError(f"{path}: no follower runs"
                        + (f" match {what} (of {total})" if what else "")
                        + (f"; skipped: {skipped[0].reason}" if skipped and not total else ""))
    return runs, report
