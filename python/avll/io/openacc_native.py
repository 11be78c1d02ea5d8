"""Loader of the JRC OpenACC database in its native layout (``format="openacc"``),
every campaign as the JRC distributes it (ZalaZone, Casale, JRC low speed, Vicolungo,
Cherasco): a data file, or a campaign folder as distributed.

The layout, from the campaigns' notes (``Zala_notes.txt``, ``Casale_notes.txt``,
``JRC_tests_notes.txt``, ...), which are the specification here:

.. code-block:: text

    Date,8,10,2019
    Vehicle_order,SMART_TARGET,TESLA_MODEL3,...,
    Number_of_vehicles,7
    ACC,1
    Distance_setting,L
    Time,Speed1,E1,N1,Lon1,Lat1,Alt1,...,SpeedN,...,IVS1,...,IVS(N-1)[,Driver2,...]
    480.0,11.10,80.28,-117.10,...

Vocabulary
----------
* ``ACC``: ``0`` manual driving throughout, ``1`` ACC throughout, ``2`` mixed (the
  follower's per-sample ``Driver<i>`` column decides), blank: unknown (the JRC
  low-speed notes: no Driver information for any follower). Per sample of follower
  ``i``: ``Driver<i>`` = ``ACC`` -> ACC, ``Human`` -> human; an empty Driver cell, or
  a follower without the column, takes the header: 1 -> ACC, 0 -> human, 2 or blank
  -> unknown. Runs never mix states: ``meta["acc"]`` is ``True`` (every sample ACC),
  ``False`` (human: a control case) or ``None`` (unknown); ``meta["acc_source"]``
  says where it came from.
* ``Distance_setting``: ``L``, ``M``, ``S`` (ZalaZone), ``SL`` (ZalaZone: mixed, short
  for most cars, long for those of the campaign's list ``Long setting vehs in mixed
  timegap experiment handling.csv``), ``min`` (Casale), ``shortest``, ``second
  shortest`` (JRC low speed), blank. ``meta["setting"]`` is the raw value as written
  (``None`` when blank); ``meta["setting_rank"]`` its order within the campaign,
  larger = longer time gap (:data:`SETTING_RANK`: S/min/shortest 0, M/second shortest
  1, L 2; these ranks compare settings of one campaign only); for ``SL``
  ``meta["setting_resolved"]`` is ``"L"`` or ``"S"`` for the car, from the list found
  beside the file (the file's folder or a parent, up to the folder given); without
  the list or the file in it, the rank is ``None`` and a cleaning note says why.
* Columns: ``Time``; per vehicle ``i`` ``Speed`` (m/s), ``E``, ``N`` (m, local ENU),
  ``U`` (m, ENU up), ``Lon``, ``Lat``, ``Alt`` (m), ``VE``, ``VN``, ``VU`` (velocity
  components, read and kept in :class:`NativeFile`), ``Driver``; per pair ``i``
  (between vehicles ``i`` and ``i + 1``) ``IVS`` (the spacing, m), ``Eff_distance``,
  ``Rel_Speed`` (read, kept in :attr:`NativeFile.pairs`). Only ``Speed`` is required
  per vehicle (``E``/``N`` together or not at all: without them the path length is
  the integral of the speed). ``Alt`` is optional per vehicle (Casale's leader,
  some JRC low-speed cars): the grade then comes from ``U`` if present, else it is
  unavailable for that car (no ``exo["grade"]``, ``meta["grade_available"] =
  False``, a cleaning note). Vehicle numbers are positions in ``Vehicle_order``: a
  vehicle not recorded has no columns and the others keep their numbers (its
  follower has no run: its predecessor was not measured).
* ``Time`` is kept as the file has it (``run.t``): seconds of day, relative seconds
  or GPS time of week alike; it must increase. Where a step differs from the file's
  median step by more than 0.1 % (a part of the series removed, e.g. tolls or
  tunnels in Casale) every stretch ends, and no bridge crosses it.
* A campaign folder as distributed: ``*_notes.txt``, ``copyright.txt``, the
  specification sheet (``Veh_specifications.csv``, ``*_veh_specifications.csv``),
  the long-setting list and any other file that is not ``*.csv`` are recognised and
  skipped (listed in the report's ``non_data``); the folder is walked without
  following symbolic links. The specification sheet's row of each car is attached
  as ``meta["vehicle_spec"]`` (and ``lead_vehicle_spec``; the sheet's own columns,
  e.g. power, drive, propulsion, model year) by the name rule of
  :func:`match_vehicle_spec`.

One closed-loop :class:`avll.Run` per usable stretch of each follower whose
predecessor was recorded, id ``"<file stem>/v<i-1>-v<i>"``, with ``"/s<k>"`` (k = 1, 2,
... in time order) when the follower has several stretches (the parent folder's name
is prefixed when two files of a folder share a stem). It carries the follower's
``x, v, a`` and the predecessor's ``lead_x, lead_v, lead_a``, ``command=None`` with
``command_kind="acceleration"`` and ``upper=None``.

Stretches
---------
Each rule's time is counted in the report (see :func:`openacc_native_report`).
A sample of a follower is usable when its speed, its position, its predecessor's
speed and the spacing are present (after the bridging below), the spacing is
consistent with the speeds, the pair is following and the ACC state is the
stretch's. Every maximal run of usable samples of one ACC state lasting at least
``min_duration`` (20 s) is a run; the others are dropped with the reason:

* missing data: holes longer than the bridges;
* not following: a spacing above :data:`FAR_GAP` (100 m) while the time headway
  (spacing / follower speed) is above :data:`FAR_HEADWAY` (3 s, longer than the
  longest time-gap settings of commercial ACC) marks a cut-in or a lost target
  (invisible otherwise in a GNSS spacing); the whole excursion above 3 s around it
  is split out (e.g. in Casale part7 and JRC low speed part12);
  a spacing below :data:`MIN_GAP` (-5 m) is not a following distance either;
* inconsistent spacing: over every window of :data:`CONSISTENCY_WINDOW` (1 s) the
  change of the spacing must equal the integral of the relative speed (predecessor
  minus follower speed) within :data:`CONSISTENCY_TOL` (1 m, a mean rate error of
  1 m/s); the samples of a violating window are left out, reported as a repair
  that would invent motion when the window holds a repaired sample (below), as a
  jump of the data otherwise. No run therefore has a window beyond the tolerance.

Signals
-------
* ``x``: the follower's path length, the cumulative length of its east/north track
  (a step whose two ends are both at standstill, speed below :data:`STANDSTILL`,
  adds nothing: GNSS jitter).
* ``lead_x = x + gap``, so ``lead_x - x`` is the measured spacing ``IVS(i-1)``. In
  the ZalaZone files ``IVS`` is the straight-line east/north distance minus a
  constant per pair (spread below 1 cm); where the present cells show that (spread
  of distance - IVS within 5 cm), an empty ``IVS`` cell with both positions present
  is reconstructed from the positions.
* ``a`` and ``lead_a``: central differences of the speed after a zero-phase
  2nd-order Butterworth low-pass. The cut-off is chosen per file from the spectrum
  of the speed derivative (:func:`choose_accel_cutoff`; ``accel_cutoff="auto"``, the
  default) and written to ``meta["accel_cutoff_hz"]`` and ``meta["accel_cutoff"]``
  (how): the ZalaZone speed is smoothed by the database's B-splines (its derivative's
  power falls by decades up to the Nyquist frequency: 1.5 Hz), the Casale and JRC
  low-speed speed is raw u-blox 9 Doppler, not filtered (the power has a minimum
  near 0.5 Hz and rises above: noise; cut-off below 1 Hz). A number given as
  ``accel_cutoff`` is used as is.
* ``exo["grade"]``: the road grade along the follower's path from its altitude
  (``Alt``, else ``U``): altitude on a 1 m grid of the path (pooled with the other
  vehicles' altitudes of the same kind within 2 m), Savitzky-Golay filter of order 2
  over ``grade_window`` = 30 m.

Repairs
-------
Each is recorded in ``run.meta["cleaning"]``; none may invent motion: the consistency
rule above checks every repaired sample.

* Empty cells: runs of at most ``bridge`` seconds (1 s) are linearly interpolated
  (only the empty cells). Receiver dropouts (a vehicle's speed and position both
  missing, up to ``bridge_kinematic`` = 3 s, e.g. the short holes of JRC low speed)
  are bridged only when the linear speed bridge's integral matches the
  straight distance between the positions at the hole's ends within
  :data:`CONSISTENCY_TOL`. Empty spacings up to ``bridge_kinematic`` with both speeds
  present are filled by the integral of the speed difference, the drift to the next
  known spacing removed linearly.
* GNSS position glitches: an E/N sample whose steps in and out both imply a speed
  more than :data:`GLITCH_TOL` (3 m/s) away from the measured speed is dropped, with
  the spacings computed from it, and bridged as an empty cell.
* ``Vehicle_order`` listing more names than ``Number_of_vehicles``: the first N.
* Speed in km/h or mph (below the 70 m/s limit) is an error naming the column, found
  from its ratio to the speed of the vehicle's own track; spacings beyond 1e8 m are
  an error, outside -5..1000 m a :class:`avll.PlausibilityWarning`.
* The follower's speed disagreeing with its own track length by more than 1 %:
  ``meta["speed_position_ratio"]`` and a cleaning note.

Metadata per run: ``file``, ``folder``, ``date`` (ISO), ``car``, ``lead_car``,
``setting`` (raw), ``setting_rank``, ``setting_resolved``, ``acc``, ``acc_source``,
``acc_header``, ``position`` (1 = the first follower), ``vehicle_index``,
``lead_index``, ``track`` (file name before ``_part``), ``n_vehicles``,
``vehicle_order``, ``gap_column``, ``ivs_offset``, ``gap_reconstructed``,
``repaired_samples``, ``speed_position_ratio``, ``accel_cutoff_hz``,
``accel_cutoff``, ``accel_filter``, ``grade_method``, ``grade_available``,
``spacing_consistency_tol_m``, ``spacing_consistency_window_s``, ``stretch``,
``n_stretches``, ``vehicle_spec``, ``lead_vehicle_spec``, ``vehicle_spec_file``,
``t_file_start``, ``t_start``, ``t_end``, ``rows`` (first and last data row),
``cleaning``.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import math
import re
from collections import Counter, defaultdict
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..data import DataError, Run
from ._common import (
    PANDAS_FAST_FLOAT,
    Range,
    _range_check,
    check_speed_units,
    check_time,
    contiguous,
    walk_files,
    where,
)

__all__ = [
    "NativeFile",
    "choose_accel_cutoff",
    "match_vehicle_spec",
    "read_vehicle_specs",
    "read_long_setting_list",
    "spacing_consistency",
    "SETTING_RANK",
    "CONSISTENCY_TOL",
    "CONSISTENCY_WINDOW",
    "FAR_GAP",
    "FAR_HEADWAY",
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
#: Consistency of the spacing with the speeds: over every window of
#: :data:`CONSISTENCY_WINDOW` seconds the change of the spacing may differ from the
#: integral of the relative speed (predecessor minus follower) by at most
#: :data:`CONSISTENCY_TOL` metres (a mean rate error of 1 m/s over 1 s).
CONSISTENCY_WINDOW = 1.0
CONSISTENCY_TOL = 1.0
#: Not following: a spacing above :data:`FAR_GAP` metres while the time headway
#: (spacing / follower speed) is above :data:`FAR_HEADWAY` seconds; the whole excursion
#: above :data:`FAR_HEADWAY` around it is split out.
FAR_GAP = 100.0
FAR_HEADWAY = 3.0
#: A spacing below this (m) is not a measurable following distance (bumpers overlap
#: by more than the GNSS error): split out.
MIN_GAP = -5.0
#: Spacings outside -5..1000 m give a :class:`avll.PlausibilityWarning` naming the
#: first row (as the canonical loader does for positions); a magnitude above 1e8 m is
#: an error.
SPACING_RANGE = Range(-5.0, 1000.0, 1e8, "m")
#: Bounds (Hz) of the acceleration cut-off chosen from the spectrum.
CUTOFF_RANGE = (0.5, 1.5)
#: Gap settings of the ACC by rank within a campaign (larger = longer time gap), in
#: every spelling the campaigns' notes document (lower case, blanks collapsed).
SETTING_RANK = {"s": 0, "min": 0, "shortest": 0, "second shortest": 1, "m": 1, "l": 2}
#: The ZalaZone spelling of a mixed file: short for most cars, long for the cars of
#: the campaign's long-setting list.
MIXED_SETTING = "sl"
#: Gap settings of the ZalaZone campaign, longest first.
SETTINGS = ("L", "M", "S")
#: Lines before the data rows: five metadata lines and the column header.
HEADER_LINES = 6
_META_KEYS = ("Date", "Vehicle_order", "Number_of_vehicles", "ACC", "Distance_setting")
_VEH_COL = re.compile(r"^(Speed|E|N|U|Lon|Lat|Alt|VE|VN|VU|Driver)(\d+)$", re.IGNORECASE)
_PAIR_COL = re.compile(r"^(IVS|Eff_distance|Rel_Speed)(\d+)$", re.IGNORECASE)
_VEH_KEYS = {"speed": "speed", "e": "E", "n": "N", "u": "U", "lon": "lon", "lat": "lat",
             "alt": "alt", "ve": "VE", "vn": "VN", "vu": "VU", "driver": "driver"}
_DRIVER = {"acc": 1, "human": 0}


def _setting_key(raw: str | None) -> str:
    return " ".join(str(raw or "").replace("_", " ").split()).lower()


def _loc(path: Path, column: str | None = None, row: int | None = None,
         line: int | None = None) -> str:
    """Location of an error: data rows as in :func:`avll.io._common.where` (with the
    line of the file), metadata by line."""
    if row is not None:
        return where(path, column, row, header_lines=HEADER_LINES)
    return where(path, column) + (f", line {line}" if line is not None else "")


@dataclass
class NativeFile:
    """A parsed native OpenACC file: the metadata header and the columns as float
    arrays (NaN for empty cells), before any cleaning.

    ``names`` are the first ``n_vehicles`` names of ``Vehicle_order`` (all listed
    names in ``listed``); ``acc`` the header's ``ACC`` (0, 1, 2 or ``None`` when
    blank); ``setting`` the header's ``Distance_setting`` as written (``None`` when
    blank); ``vehicles`` maps a vehicle number to its numeric columns (``speed``,
    ``E``, ``N`` and, when present, ``alt``, ``U``, ``lon``, ``lat``, ``VE``, ``VN``,
    ``VU``); ``drivers`` a vehicle number to its per-sample ``Driver`` column (1 ACC,
    0 human, -1 empty); ``ivs`` maps ``i`` to the spacing between vehicles ``i`` and
    ``i + 1``, ``pairs`` the other pair columns (``eff_distance``, ``rel_speed``).
    """

    path: Path
    date: _dt.date
    listed: tuple[str, ...]
    names: tuple[str, ...]
    n_vehicles: int
    acc: int | None
    setting: str | None
    t: np.ndarray
    vehicles: dict[int, dict[str, np.ndarray]]
    ivs: dict[int, np.ndarray]
    notes: list[str] = field(default_factory=list)
    drivers: dict[int, np.ndarray] = field(default_factory=dict)
    pairs: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)

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
    if acc_v not in ([], ["0"], ["1"], ["2"]):
        raise DataError(f"{_loc(path, line=4)}: ACC must be 0, 1, 2 or empty (0 manual, 1 "
                        f"ACC, 2 mixed: see the Driver<i> columns), got {','.join(acc_v)[:40]!r}")
    acc = int(acc_v[0]) if acc_v else None
    st = [v for v in _meta_line(path, rows, 4) if v]
    key = _setting_key(st[0]) if len(st) == 1 else "?"
    if len(st) > 1 or (st and key not in SETTING_RANK and key != MIXED_SETTING):
        raise DataError(f"{_loc(path, line=5)}: Distance_setting must be one of L, M, S, SL, "
                        f"min, shortest, second shortest or empty, got {','.join(st)[:40]!r}")
    setting = st[0] if st else None
    return {"date": date, "listed": listed, "n": n, "acc": acc, "setting": setting}


def _to_float(path: Path, name: str, cells: Sequence[str] | np.ndarray) -> np.ndarray:
    """Cells as float64; empty cells (and ``nan`` text) are NaN, anything else that is
    not a number is an error naming the row and line. An array (a column of
    :func:`_fast_read`) is returned as it is."""
    if isinstance(cells, np.ndarray):
        return cells
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


#: The bytes :func:`_fast_read` takes in a data block: numbers (digits, sign, point,
#: exponent), the comma, the space, line ends and the letters of ``ACC``/``Human``.
_FAST_BYTES = np.zeros(256, dtype=bool)
_FAST_BYTES[list(b"0123456789+-.eE, \r\nACHUMNachumn")] = True
#: pandas >= 3.1 parses floats with fast_float (correctly rounded, as ``float``);
#: before, only its ``round_trip`` converter is (a deprecated option in 3.1).
_FLOAT_OPTS: dict[str, Any] = {} if PANDAS_FAST_FLOAT else {"float_precision": "round_trip"}


def _fast_read(path: Path) -> tuple[list[list[str]], list[Any]] | None:
    """The header lines as ``csv.reader`` gives them and the data columns (float64
    arrays; a ``Driver<i>`` column coded as :func:`_driver` codes it), the data block
    read by pandas' C parser. ``None`` wherever the result could differ from the exact
    path (``csv.reader``, :func:`_to_float` and :func:`_driver`, which word every
    error): a file that is not UTF-8, a quote, a lone CR, any byte but numbers and
    ACC/Human in the data, ``nan`` text, rows of unequal width, fewer cells than the
    header or text beyond it, a line longer than the csv module's field limit, a cell
    that does not parse, an inf, a missing time."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    cut = 3 if data.startswith(b"\xef\xbb\xbf") else 0  # the BOM utf-8-sig drops
    start = cut
    for _ in range(HEADER_LINES):
        cut = data.find(b"\n", cut) + 1
        if not cut:
            return None
    try:  # the data block is checked to be ASCII below
        head_text = data[start:cut].decode("utf-8")
        head = list(csv.reader(io.StringIO(head_text, newline="")))
    except (UnicodeDecodeError, csv.Error):
        return None
    if b'"' in data or "\r" in head_text.replace("\r\n", ""):
        return None
    header = [c.strip() for c in head[-1]]
    while header and header[-1] == "":
        header.pop()
    raw = data[cut:]
    end = len(raw)  # the last row with a value (blank rows after it are dropped)
    while end and raw[end - 1] in b" ,\r\n":
        end -= 1
    a = np.frombuffer(raw, dtype=np.uint8)
    cr = np.flatnonzero(a == 13)
    if (len(header) < 2 or not end or not _FAST_BYTES[a].all() or b"nan" in raw.lower()
            or raw.endswith(b"\r") or (a[cr + 1] != 10).any()):
        return None
    stop = raw.find(b"\n", end) + 1 or len(raw)
    ends = np.flatnonzero(a[:stop] == 10)  # each line's end (exclusive)
    if raw[stop - 1:stop] != b"\n":
        ends = np.r_[ends, stop]
    starts = np.r_[0, ends[:-1] + 1]
    commas = np.flatnonzero(a[:stop] == 44)
    cells = np.searchsorted(commas, ends) - np.searchsorted(commas, starts) + 1
    width, k = len(header), int(cells[0])
    if (cells != k).any() or k < width or (ends - starts).max() >= csv.field_size_limit():
        return None
    text_cols = {j for j, c in enumerate(header)
                 if (m := _VEH_COL.match(c)) and m[1].lower() == "driver"}
    try:  # empty cells NaN, but a Driver cell stays text ("")
        df = pd.read_csv(io.BytesIO(raw[:stop]), header=None, names=range(k), engine="c",
                         dtype={j: object if j in text_cols or j >= width else np.float64
                                for j in range(k)},
                         keep_default_na=False, skip_blank_lines=False,
                         na_values={j: [""] for j in range(k) if j not in text_cols},
                         **_FLOAT_OPTS)
    except (ValueError, TypeError, OverflowError):  # ParserError is a ValueError
        return None
    if len(df) != len(ends) or not df.iloc[:, width:].isna().all().all():
        return None
    cols: list[Any] = []
    for j in range(width):
        if j in text_cols:  # coded as _driver does, unless a cell is not ACC/Human/empty
            code = {c: _DRIVER.get(c.strip().lower(), -2) if c.strip() else -1
                    for c in df[j].unique()}
            ok = -2 not in code.values()
            cols.append(df[j].map(code).to_numpy(np.int8) if ok else df[j].tolist())
            continue
        x = df[j].to_numpy(dtype=np.float64)
        if np.isinf(x).any() or (j == 0 and np.isnan(x).any()):
            return None
        cols.append(x)
    return head, cols


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
    if not path.is_file():
        raise DataError(f"{path}: not a regular file (a FIFO or a device is not read)")
    fast = _fast_read(path)
    if fast is not None:
        rows, data_cols = fast
    else:
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
    pair_cols: dict[str, dict[int, int]] = {}
    n = h["n"]
    for j, c in enumerate(header):
        if c in seen:
            raise DataError(f"{_loc(path, c, line=HEADER_LINES)}: duplicated column")
        seen.add(c)
        if j == 0:
            continue
        mv, mi = _VEH_COL.match(c), _PAIR_COL.match(c)
        if mv:
            k = int(mv[2])
            if not 1 <= k <= n:
                raise DataError(
                    f"{_loc(path, c, line=HEADER_LINES)}: vehicle {k} but "
                    f"Number_of_vehicles (line 3) is {n}: wrong vehicle count")
            veh_cols.setdefault(k, {})[_VEH_KEYS[mv[1].lower()]] = j
        elif mi:
            k = int(mi[2])
            if not 1 <= k < n:
                raise DataError(
                    f"{_loc(path, c, line=HEADER_LINES)}: spacing between vehicles {k} and "
                    f"{k + 1} but Number_of_vehicles (line 3) is {n}: wrong vehicle count")
            pair_cols.setdefault(mi[1].lower(), {})[k] = j
        else:
            raise DataError(f"{_loc(path, c, line=HEADER_LINES)}: unknown column (expected "
                            "Time and, per vehicle <i>, Speed, E, N, U, Lon, Lat, Alt, VE, VN, "
                            "VU, Driver, per pair IVS, Eff_distance, Rel_Speed)")
    if not any("speed" in cols for cols in veh_cols.values()):
        raise DataError(f"{_loc(path, 'Speed1', line=HEADER_LINES)}: missing column: no "
                        "vehicle columns (Speed<i>, E<i>, N<i>, ...)")
    for k, cols in sorted(veh_cols.items()):
        need = ("speed",) if not ({"E", "N"} & set(cols)) else ("speed", "E", "N")
        for q in need:
            if q not in cols:
                name = {"speed": "Speed"}.get(q, q)
                raise DataError(f"{_loc(path, f'{name}{k}', line=HEADER_LINES)}: missing "
                                f"column (vehicle {k} has "
                                f"{', '.join(header[j] for j in cols.values())})")
    if fast is None:
        data = rows[HEADER_LINES:]
        while data and not any(c.strip() for c in data[-1]):
            data.pop()
        if not data:
            raise DataError(f"{path}: no data rows (only the header)")
        width = len(header)
        for r, row in enumerate(data):
            if len(row) < width or any(c.strip() for c in row[width:]):
                raise DataError(f"{_loc(path, header[min(len(row), width - 1)], r)}: the row "
                                f"has {len(row)} cells, the header {width}")
        data_cols = list(zip(*[row[:width] for row in data], strict=True))
    t = _to_float(path, "Time", data_cols[0])
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raw = data_cols[0][int(bad[0])].strip()
        what = "is empty" if not raw else f"is {raw[:20]!r}, not a time"
        raise DataError(f"{_loc(path, 'Time', int(bad[0]))}: the time {what} (every row "
                        "needs its time stamp)")
    # strictly increasing; a step off the median (a removed part of the series) does
    # not stop the file: stretches end there (see _follower_runs)
    check_time(t, path, "Time", uniform=False)
    vehicles: dict[int, dict[str, np.ndarray]] = {}
    drivers: dict[int, np.ndarray] = {}
    for k, cols in sorted(veh_cols.items()):
        vehicles[k] = {}
        for q, j in cols.items():
            if q == "driver":
                drivers[k] = _driver(path, header[j], data_cols[j])
            else:
                vehicles[k][q] = _to_float(path, header[j], data_cols[j])
    pairs = {q: {k: _to_float(path, header[j], data_cols[j]) for k, j in sorted(m.items())}
             for q, m in pair_cols.items()}
    ivs = pairs.pop("ivs", {})
    notes = []
    if len(h["listed"]) > n:
        notes.append(f"Vehicle_order lists {len(h['listed'])} names for {n} vehicles: the "
                     f"first {n} are the cars ({', '.join(h['listed'][n:])} ignored)")
    absent = [k for k in range(1, n + 1) if k not in vehicles]
    if absent:
        notes.append("no columns for vehicle(s) " + ", ".join(
            f"{k} ({h['listed'][k - 1]})" for k in absent))
    dt = float(np.median(np.diff(t))) if t.shape[0] > 1 else 0.1
    for k, v in vehicles.items():
        sp = v["speed"]
        check_speed_units(sp, path, f"Speed{k}")
        neg = np.flatnonzero(sp < -0.5)
        if neg.size:
            raise DataError(f"{_loc(path, f'Speed{k}', int(neg[0]))}: negative speed "
                            f"{sp[neg[0]]:g} m/s")
        if "E" in v:
            _speed_vs_track(path, k, sp, v["E"], v["N"], dt)
    for k, g in ivs.items():
        _range_check(g, path, f"IVS{k}", "spacing", None, "wrong unit or column?",
                     rg=SPACING_RANGE, header_lines=HEADER_LINES)
    return NativeFile(path=path, date=h["date"], listed=h["listed"],
                      names=h["listed"][:n], n_vehicles=n, acc=h["acc"], setting=h["setting"],
                      t=t, vehicles=vehicles, ivs=ivs, notes=notes, drivers=drivers,
                      pairs=pairs)


def _driver(path: Path, column: str, cells: Sequence[str] | np.ndarray) -> np.ndarray:
    """A ``Driver<i>`` column: 1 for ``ACC``, 0 for ``Human`` (any case), -1 for an
    empty cell; anything else is an error naming the row. An array (the column coded
    by :func:`_fast_read`) is returned as it is."""
    if isinstance(cells, np.ndarray):
        return cells
    out = np.full(len(cells), -1, dtype=np.int8)
    for r, c in enumerate(cells):
        c = c.strip()
        if not c:
            continue
        v = _DRIVER.get(c.lower())
        if v is None:
            raise DataError(f"{_loc(path, column, r)}: Driver must be 'ACC', 'Human' or empty, "
                            f"got {c[:40]!r}")
        out[r] = v
    return out


def _speed_vs_track(path: Path, k: int, v: np.ndarray, e: np.ndarray, n: np.ndarray,
                    dt: float) -> None:
    """A speed column in km/h or mph (below the 70 m/s limit, e.g. 30 km/h) is found
    by its ratio to the speed of the vehicle's own E/N track (median over the steps
    moving faster than 2 m/s by the track, at least 50): an error naming the unit."""
    step = np.hypot(np.diff(e), np.diff(n)) / dt
    vm = 0.5 * (v[:-1] + v[1:])
    ok = np.isfinite(step) & np.isfinite(vm) & (step > 2.0)
    if ok.sum() < 50:
        return
    k_ratio = float(np.median(vm[ok] / step[ok]))
    for unit, f in (("km/h", 3.6), ("mph", 2.2369)):
        if abs(k_ratio / f - 1.0) < 0.15:
            raise DataError(f"{_loc(path, f'Speed{k}')}: speed looks like {unit}, not m/s: it is "
                            f"{k_ratio:.3g} x the speed of the vehicle's own E{k}/N{k} track "
                            f"(median over {int(ok.sum())} moving steps); convert to m/s")


# ---------------------------------------------------------------------------
# Signal processing
# ---------------------------------------------------------------------------


def _holes(mask: np.ndarray, max_samples: int,
           breaks: np.ndarray | None) -> Iterator[tuple[int, int]]:
    """The interior runs ``a:b`` of ``mask`` of at most ``max_samples`` samples that
    (with their two neighbours) span no time break."""
    for a, b in contiguous(mask):
        if (0 < a and b < mask.shape[0] and b - a <= max_samples
                and not (breaks is not None and breaks[a:b + 1].any())):
            yield a, b


def _bridge(x: np.ndarray, max_samples: int,
            breaks: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Linear interpolation of interior runs of at most ``max_samples`` NaN cells
    (only those cells, never across a time break); returns the array and the number
    of cells filled."""
    out = x.copy()
    filled = 0
    for a, b in _holes(~np.isfinite(out), max_samples, breaks):
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


def _bridge_vehicle(v: np.ndarray, e: np.ndarray, n: np.ndarray, alt: np.ndarray,
                    dt: float, max_samples: int, breaks: np.ndarray | None = None) -> int:
    """Bridges, in place, interior holes of at most ``max_samples`` samples where a
    vehicle's speed and position are both missing (a receiver dropout), only where
    the data allow: the speed is interpolated linearly across the hole, and the
    bridge is accepted only when its integral matches the straight distance between
    the positions at the two ends within :data:`CONSISTENCY_TOL` metres; the
    positions are then put on that chord in proportion to the integrated speed.
    Returns the number of samples filled."""
    filled = 0
    for a, b in _holes(~np.isfinite(v), max_samples, breaks):
        ends = (a - 1, b)
        if not all(np.isfinite(q[j]) for q in (v, e, n) for j in ends):
            continue
        if np.isfinite(e[a:b]).any() or np.isfinite(n[a:b]).any():
            continue
        vi = np.interp(np.arange(a - 1, b + 1), ends, v[list(ends)])
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (vi[1:] + vi[:-1]) * dt)])
        chord = math.hypot(e[b] - e[a - 1], n[b] - n[a - 1])
        if abs(chord - cum[-1]) > CONSISTENCY_TOL:
            continue
        frac = cum / cum[-1] if cum[-1] > 1e-9 else np.linspace(0.0, 1.0, cum.shape[0])
        v[a:b] = vi[1:-1]
        e[a:b] = (e[a - 1] + frac * (e[b] - e[a - 1]))[1:-1]
        n[a:b] = (n[a - 1] + frac * (n[b] - n[a - 1]))[1:-1]
        if np.isfinite(alt[a - 1]) and np.isfinite(alt[b]):
            alt[a:b] = np.interp(np.arange(a, b), ends, alt[list(ends)])
        filled += b - a
    return filled


def _short_runs(bad: np.ndarray, ok_sides: np.ndarray, max_samples: int,
                breaks: np.ndarray | None = None) -> np.ndarray:
    """Mask of the interior runs of ``bad`` of at most ``max_samples`` samples whose
    ``ok_sides`` mask holds over the run and its two neighbours (not across a time
    break)."""
    out = np.zeros(bad.shape[0], dtype=bool)
    for a, b in _holes(bad, max_samples, breaks):
        if ok_sides[a - 1:b + 1].all():
            out[a:b] = True
    return out


def _fill_gap_kinematic(gap: np.ndarray, vf: np.ndarray, vp: np.ndarray, dt: float,
                        max_samples: int,
                        breaks: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Fill interior runs of at most ``max_samples`` empty spacing cells by the
    integral of the speed difference (trapezoid) from the last known spacing, with
    the drift to the next known spacing removed linearly; only where both speeds
    are present. Returns the spacing and the number of cells filled."""
    out = gap.copy()
    sides = np.isfinite(vf) & np.isfinite(vp)
    mask = _short_runs(~np.isfinite(out), sides, max_samples, breaks)
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
        e, n = np.asarray(e, dtype=np.float64), np.asarray(n, dtype=np.float64)
        if keep.any() and np.isfinite(e).sum() >= 2:
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


def _as_set(name: str, value: Any, norm: Any) -> set[Any] | None:
    if value is None:
        return None
    items = [value] if isinstance(value, str) else list(value)
    if not items:
        raise ValueError(f"{name}: is empty")
    return {norm(v) for v in items}


def _norm_setting(v: Any) -> str | None:
    """A setting filter value: any documented spelling (case and blanks ignored), or
    ``None``/``"none"`` for the files without a setting."""
    if v is None:
        return None
    s = _setting_key(v)
    if s in ("none", "", "0", "no acc", "off"):
        return None
    if s not in SETTING_RANK and s != MIXED_SETTING:
        raise ValueError(f"setting: expected one of L, M, S, SL, min, shortest, second "
                         f"shortest or none, got {v!r}")
    return s


def _norm_name(v: Any) -> str:
    return str(v).strip().upper()


@dataclass
class _Skip:
    file: str
    follower: int
    car: str
    reason: str


# ---------------------------------------------------------------------------
# Campaign side files: specification sheets, long-setting lists
# ---------------------------------------------------------------------------


def _side_kind(f: Path) -> str | None:
    """The kind of a campaign file that is not data (``None`` for a ``*.csv`` that may
    be data): notes, vehicle specifications, copyright, long-setting list, other."""
    name = f.name.lower()
    if f.suffix.lower() != ".csv":
        if name.endswith("notes.txt"):
            return "notes"
        if name.startswith("copyright"):
            return "copyright"
        return "other (not *.csv)"
    if "veh_specification" in name or "vehicle_specification" in name:
        return "vehicle specifications"
    if name.startswith("long setting") or name.startswith("long_setting"):
        return "long-setting list"
    return None


def _read_small_csv(path: Path) -> list[list[str]]:
    try:
        with open(path, encoding="utf-8-sig", newline="") as fh:
            return [[c.strip() for c in r] for r in csv.reader(fh)]
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise DataError(f"{path}: not a readable CSV file ({e})") from e


def _cell(v: str) -> Any:
    v = v.strip()
    if v in ("", "-"):
        return None
    try:
        return float(v)
    except ValueError:
        return v


def read_vehicle_specs(path: str | Path) -> list[dict[str, Any]]:
    """The rows of a campaign's vehicle specification sheet (``Veh_specifications.csv``,
    ``*_veh_specifications.csv``): one dict per vehicle, keyed by the sheet's own
    column names (``-`` and empty cells are ``None``, numbers are floats)."""
    path = Path(path)
    rows = [r for r in _read_small_csv(path) if any(r)]
    if not rows:
        return []
    head = rows[0]
    return [{h: _cell(c) for h, c in zip(head, r, strict=False) if h} for r in rows[1:]]


def _tokens(name: str) -> list[str]:
    return [t for t in re.split(r"[^0-9a-z]+", name.lower()) if t]


def match_vehicle_spec(name: str, specs: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The row of a specification sheet for a car named as in ``Vehicle_order``.

    Rule: the name is split at every character that is not a letter or a digit
    (``MERCEDES_GLE450`` -> ``mercedes``, ``gle450``) and a row matches when each of
    these tokens occurs in the row's first cell lower-cased with everything but
    letters and digits removed (``Mercedes-Benz (GLE 450 4Matic)`` ->
    ``mercedesbenzgle4504matic``). Exactly one matching row is the car's; none or
    several: ``None`` (e.g. ``TESLA_MODELS`` matches only ``Tesla (model S)``,
    ``Hyundai`` matches ``Hyundai Nexo``, ``BMW`` of JRC low speed matches no row of
    that campaign's sheet)."""
    toks = _tokens(name)
    if not toks:
        return None
    hits = []
    for row in specs:
        first = next(iter(row.values()), None)
        key = re.sub(r"[^0-9a-z]+", "", str(first or "").lower())
        if key and all(t in key for t in toks):
            hits.append(row)
    return hits[0] if len(hits) == 1 else None


def read_long_setting_list(path: str | Path) -> dict[str, set[str]]:
    """A ZalaZone long-setting list (``filename,Long timegap setting`` then rows like
    ``handling_part12,BMW_I3/MERCEDES_GLE450``): file stem -> the cars (upper case)
    that drove the long setting in that ``SL`` file."""
    path = Path(path)
    out: dict[str, set[str]] = {}
    for k, r in enumerate(_read_small_csv(path)):
        if k == 0 or not r or not r[0]:
            continue
        cars = r[1] if len(r) > 1 else ""
        out[Path(r[0]).stem.lower()] = {_norm_name(c) for c in cars.split("/") if c.strip()}
    return out


@dataclass
class _Campaign:
    """The side files that apply to a data file (nearest folder upwards)."""

    specs: list[dict[str, Any]] | None = None
    specs_file: str | None = None
    long_list: dict[str, set[str]] | None = None
    long_file: str | None = None


def _campaign_for(f: Path, root: Path, side: dict[Path, list[tuple[Path, str]]],
                  cache: dict[Path, _Campaign]) -> _Campaign:
    """The specification sheet and long-setting list nearest to ``f``: its folder,
    then each parent up to ``root`` (the folder given; for a single file, its
    folder and the one above, where a redistribution's grouping puts them)."""
    folder = f.parent
    if folder in cache:
        return cache[folder]
    c = _Campaign()
    d = folder
    stop = root if root.is_dir() else folder.parent
    while True:
        entries = side.get(d)
        if entries is None:
            try:
                entries = [(p, k) for p in d.iterdir() if p.is_file()
                           and (k := _side_kind(p)) is not None]
            except OSError:
                entries = []
            side[d] = entries
        for p, kind in entries:
            if kind == "vehicle specifications" and c.specs is None:
                c.specs, c.specs_file = read_vehicle_specs(p), str(p)
            elif kind == "long-setting list" and c.long_list is None:
                c.long_list, c.long_file = read_long_setting_list(p), str(p)
        if d == stop or d.parent == d or stop not in d.parents:
            break
        d = d.parent
    cache[folder] = c
    return c


# ---------------------------------------------------------------------------
# Runs
# ---------------------------------------------------------------------------


def choose_accel_cutoff(speeds: Sequence[np.ndarray], dt: float) -> tuple[float, str]:
    """The low-pass cut-off (Hz) of the acceleration for one file, from the spectrum.

    The Welch power spectrum (segments of 25.6 s) of the speed's difference quotient
    ``diff(v)/dt`` is averaged over every stretch of at least one segment of every
    vehicle, its logarithm smoothed over 5 bins; the cut-off is the frequency of its
    minimum above 0.3 Hz: below it the vehicles' motion dominates (power falling with
    frequency), above it the measurement noise, which the derivative amplifies
    (power rising). It is clamped to :data:`CUTOFF_RANGE`: smoothed speed (ZalaZone:
    the power keeps falling to the Nyquist frequency) gets 1.5 Hz, unfiltered
    u-blox 9 speed (Casale, JRC low speed: minimum near 0.5 Hz) about 0.5 Hz.
    Without any stretch long enough, 1.5 Hz. Returns the cut-off and how it was
    chosen."""
    from scipy import signal

    nper = max(16, int(round(25.6 / dt)))
    acc_p = None
    wsum = 0
    freqs = None
    for v in speeds:
        for a, b in contiguous(np.isfinite(v)):
            if b - a < nper + 1:
                continue
            freqs, p = signal.welch(np.diff(v[a:b]) / dt, fs=1.0 / dt, nperseg=nper)
            acc_p = p * (b - a) if acc_p is None else acc_p + p * (b - a)
            wsum += b - a
    lo, hi = CUTOFF_RANGE
    hi = min(hi, 0.4 / dt)
    if acc_p is None or freqs is None:
        return hi, (f"{hi:g} Hz (default: no stretch of {nper * dt:.1f} s for the spectrum)")
    logp = np.log(np.maximum(acc_p / wsum, 1e-300))
    sm = np.convolve(logp, np.ones(5) / 5, mode="same")
    band = (freqs >= 0.3) & (freqs <= freqs[-3])
    if not band.any():
        return hi, f"{hi:g} Hz (default: spectrum too short)"
    fmin = float(freqs[band][int(np.argmin(sm[band]))])
    fc = float(min(max(fmin, lo), hi))
    return fc, (f"{fc:.3g} Hz from the spectrum of the speed derivative (minimum of the "
                f"smoothed power at {fmin:.3g} Hz, clamped to {lo:g}..{hi:g} Hz; "
                f"{wsum * dt:.0f} s of speed)")


def _acc_state(nf: NativeFile, i: int) -> tuple[np.ndarray, str]:
    """Per sample of follower ``i``: 1 under ACC, 0 human, -1 unknown; and where it
    comes from. The ``Driver<i>`` column decides where it has a value; its empty
    cells, and a follower without the column, take the header's ``ACC``: 1 -> ACC,
    0 -> human, 2 (mixed) or blank -> unknown."""
    n = nf.t.shape[0]
    default = {1: 1, 0: 0}.get(nf.acc if nf.acc is not None else -1, -1)
    st = np.full(n, default, dtype=np.int8)
    hdr = "blank" if nf.acc is None else str(nf.acc)
    if i in nf.drivers:
        d = nf.drivers[i]
        st = np.where(d >= 0, d, st).astype(np.int8)
        return st, f"Driver{i} column (empty cells: header ACC {hdr})"
    return st, f"header ACC {hdr}"


def _setting_for(nf: NativeFile, car: str,
                 camp: _Campaign) -> tuple[str | None, int | None, str | None]:
    """(resolved setting, rank, note) of ``car`` in ``nf``."""
    key = _setting_key(nf.setting)
    if not key:
        return None, None, None
    if key != MIXED_SETTING:
        return nf.setting, SETTING_RANK[key], None
    stem = nf.path.stem.lower()
    if camp.long_list is None or stem not in camp.long_list:
        why = ("no long-setting list beside the file" if camp.long_list is None
               else f"{nf.path.stem} is not in {camp.long_file}")
        return None, None, f"Distance_setting SL (mixed) not resolved for {car}: {why}"
    long = _norm_name(car) in camp.long_list[stem]
    res = "L" if long else "S"
    return res, SETTING_RANK[res.lower()], (
        f"Distance_setting SL (mixed): {car} drove the {'long' if long else 'short'} "
        f"setting (per {Path(camp.long_file or '').name})")


_DROP = {1: "missing data (follower, predecessor or spacing absent after bridging)",
         2: (f"not following: spacing above {FAR_GAP:g} m at a time headway above "
             f"{FAR_HEADWAY:g} s (cut-in or lost target), the whole excursion above "
             f"{FAR_HEADWAY:g} s"),
         3: f"spacing below {MIN_GAP:g} m (not a measurable following distance)",
         4: (f"spacing rate inconsistent with the relative speed (change of the spacing "
             f"over {CONSISTENCY_WINDOW:g} s differs from the integral of the speed "
             f"difference by more than {CONSISTENCY_TOL:g} m)"),
         5: (f"repaired spacing or position inconsistent with the relative speed (more "
             f"than {CONSISTENCY_TOL:g} m over {CONSISTENCY_WINDOW:g} s): repair left out")}
_DROP_KEY = {1: "missing", 2: "not_following", 3: "spacing_below_min",
             4: "inconsistent", 5: "repair_inconsistent", 6: "short"}
_KEEP_KEY = {1: "acc", 0: "human", -1: "unknown"}


def spacing_consistency(gap: np.ndarray, v: np.ndarray, lead_v: np.ndarray,
                        dt: float) -> np.ndarray:
    """Residual (m) of each window of :data:`CONSISTENCY_WINDOW` seconds starting at
    sample ``j``: the change of the spacing minus the integral (trapezoid) of the
    relative speed ``lead_v - v`` over the window; NaN where a value is missing."""
    w = max(1, int(round(CONSISTENCY_WINDOW / dt)))
    n = gap.shape[0]
    if n <= w:
        return np.full(0, np.nan)
    dv = lead_v - v
    inc = 0.5 * (dv[1:] + dv[:-1]) * dt
    bad = ~np.isfinite(inc)
    c = np.concatenate([[0.0], np.cumsum(np.where(bad, 0.0, inc))])
    cb = np.concatenate([[0], np.cumsum(bad)])
    res = (gap[w:] - gap[:-w]) - (c[w:] - c[:-w])
    res[(cb[w:] - cb[:-w]) > 0] = np.nan
    return res


def _segments(lab: np.ndarray, breaks: np.ndarray | None = None) -> list[tuple[int, int, int]]:
    """Runs ``(a, b, value)`` of equal values of an integer array, also cut before
    every sample ``k`` where ``breaks[k]``."""
    if lab.shape[0] == 0:
        return []
    change = np.diff(lab) != 0
    if breaks is not None:
        change |= breaks[1:]
    cut = np.flatnonzero(change) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [lab.shape[0]]])
    return [(int(a), int(b), int(lab[a])) for a, b in zip(starts, ends, strict=True)]


def _follower_runs(nf: NativeFile, rid_stem: str, *, bridge: float, bridge_kinematic: float,
                   min_duration: float, accel_cutoff: float | str, grade: bool,
                   grade_window: float, require_predecessor: bool, skipped: list[_Skip],
                   camp: _Campaign, stretches: list[dict[str, Any]],
                   time_acc: defaultdict[str, float], file_info: dict[str, Any],
                   followers: list[dict[str, Any]]) -> list[Run]:
    path = nf.path
    t = nf.t
    dt = float(np.median(np.diff(t)))
    # a time step off the file's median step (by more than 0.1 %, e.g. a toll or a
    # tunnel removed from the series) breaks every stretch there
    tbreak = np.concatenate([[False], np.abs(np.diff(t) - dt) > 1e-3 * dt])
    nb = int(math.floor(bridge / dt + 1e-9))
    nk = int(math.floor(bridge_kinematic / dt + 1e-9))
    filled: dict[int, dict[str, int]] = {}
    sig: dict[int, dict[str, np.ndarray]] = {}
    rep: dict[int, np.ndarray] = {}
    ivs_raw = {k: c.copy() for k, c in nf.ivs.items()}
    glitches: dict[int, int] = {}
    nanv = np.full(t.shape[0], np.nan)
    for k, cols in nf.vehicles.items():
        has_pos = "E" in cols
        e = cols["E"].copy() if has_pos else nanv.copy()
        nn = cols["N"].copy() if has_pos else nanv.copy()
        if has_pos:
            bad = _position_glitches(e, nn, cols["speed"], dt, GLITCH_TOL)
            if bad.any():
                glitches[k] = int(bad.sum())
                e[bad] = np.nan
                nn[bad] = np.nan
                for j in (k - 1, k):  # IVS is computed from the positions
                    if j in ivs_raw:
                        ivs_raw[j][bad] = np.nan
        alt_src = "alt" if "alt" in cols else "U" if "U" in cols else None
        alt = cols[alt_src] if alt_src else nanv
        sig[k] = {"has_pos": np.array(has_pos), "alt_src": np.array(alt_src or "")}
        filled[k] = {}
        r = np.zeros(t.shape[0], dtype=bool)
        for q, arr in (("speed", cols["speed"]), ("E", e), ("N", nn), ("alt", alt)):
            sig[k][q], filled[k][q] = _bridge(arr, nb, tbreak)
        if has_pos:
            filled[k]["dropout"] = _bridge_vehicle(sig[k]["speed"], sig[k]["E"], sig[k]["N"],
                                                   sig[k]["alt"], dt, nk, tbreak)
        for q, before in (("speed", cols["speed"]), ("E", e), ("N", nn)):
            r |= np.isfinite(sig[k][q]) & ~np.isfinite(before)  # bridged or glitch-refilled
        rep[k] = r
    if isinstance(accel_cutoff, str):
        cutoff, cut_how = choose_accel_cutoff([sig[k]["speed"] for k in sig], dt)
    else:
        cutoff, cut_how = float(accel_cutoff), f"{float(accel_cutoff):g} Hz (given)"
    file_info["accel_cutoff_hz"] = cutoff
    file_info["accel_cutoff"] = cut_how
    pools: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    if grade:
        for src in ("alt", "U"):
            pe, pn, pa = [], [], []
            for k in sig:
                if str(sig[k]["alt_src"]) != src:
                    continue
                m = (np.isfinite(sig[k]["E"]) & np.isfinite(sig[k]["N"])
                     & np.isfinite(sig[k]["alt"]) & (sig[k]["speed"] > POOL_MIN_SPEED))
                if m.sum() > 21:
                    pe.append(sig[k]["E"][m])
                    pn.append(sig[k]["N"][m])
                    pa.append(_despike(sig[k]["alt"][m]))
            if pe:
                pools[src] = (np.concatenate(pe), np.concatenate(pn), np.concatenate(pa))
    runs: list[Run] = []

    def skip(fol: dict[str, Any], why: str, key: str, secs: float) -> None:
        """A follower skipped for ``why``: its recorded time ``secs`` counted as ``key``."""
        i, car = fol["follower"], fol["car"]
        skipped.append(_Skip(str(path), i, car, why))
        fol["time_s"][key] += secs
        stretches.append({"file": str(path), "follower": i, "car": car, "kept": False,
                          "acc": None, "t_start": float(t[0]), "t_end": float(t[-1]),
                          "reason": why, "duration_s": secs, "run_id": None})

    for i in sorted(nf.vehicles):
        if i == 1:
            continue
        car = nf.name(i)
        lead = i - 1
        ftime = float(np.isfinite(sig[i]["speed"]).sum() * dt)
        ft: defaultdict[str, float] = defaultdict(float)
        fol: dict[str, Any] = {"file": str(path), "follower": i, "car": car,
                               "lead_car": nf.name(lead), "setting": nf.setting,
                               "acc_header": nf.acc, "time_s": ft, "runs": []}
        followers.append(fol)
        if lead not in nf.vehicles:
            skip(fol, f"predecessor vehicle {lead} ({nf.name(lead)}) has no columns",
                 "no_predecessor", ftime)
            if not require_predecessor:
                runs += _solo_run(nf, rid_stem, i, sig, dt, min_duration, cutoff, grade,
                                  grade_window)
            continue
        f, p = sig[i], sig[lead]
        notes = list(nf.notes)
        gcol = f"IVS{lead}"
        dist = np.hypot(f["E"] - p["E"], f["N"] - p["N"])
        for k, who in ((i, "follower"), (lead, "predecessor")):
            if k in glitches:
                notes.append(f"{who} (vehicle {k}): {glitches[k]} E/N samples dropped as "
                             f"glitches (both steps off the speed by > {GLITCH_TOL:g} m/s)")
        if lead not in ivs_raw:
            skip(fol, f"no spacing column {gcol}", "no_spacing", ftime)
            continue
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
        elif both.sum() >= 10:
            notes.append(f"{gcol}: distance - IVS is not constant (spread "
                         f"{spread:.3g} m): empty cells not reconstructed")
        gap, gfill = _bridge(gap, nb, tbreak)
        if gfill:
            notes.append(f"{gcol}: {gfill} empty cells interpolated (gaps <= {bridge:g} s)")
        gap, gkin = _fill_gap_kinematic(gap, f["speed"], p["speed"], dt, nk, tbreak)
        if gkin:
            notes.append(f"{gcol}: {gkin} empty cells (gaps <= {bridge_kinematic:g} s) "
                         "filled by the integral of the speed difference, drift to the "
                         "next spacing removed linearly")
        repaired = (np.isfinite(gap) & ~np.isfinite(ivs_l)) | rep[i] | rep[lead]
        has_pos = bool(f["has_pos"])
        pos_ok = np.isfinite(f["E"]) & np.isfinite(f["N"]) if has_pos else \
            np.isfinite(f["speed"])
        pos_kin = _short_runs(~pos_ok, np.isfinite(f["speed"]), nk, tbreak)
        if pos_kin.any():
            notes.append(f"follower (vehicle {i}): {int(pos_kin.sum())} samples without E/N "
                         f"(gaps <= {bridge_kinematic:g} s): path length from the speed")
        if not has_pos:
            notes.append(f"follower (vehicle {i}) has no E/N columns: path length from the "
                         "integral of the speed")
        present = (np.isfinite(f["speed"]) & (pos_ok | pos_kin)
                   & np.isfinite(p["speed"]) & np.isfinite(gap))
        cat = np.where(present, 0, 1).astype(np.int8)
        # spacing consistent with the relative speed (repairs first)
        res = spacing_consistency(np.where(present, gap, np.nan), f["speed"], p["speed"], dt)
        w = max(1, int(round(CONSISTENCY_WINDOW / dt)))
        if tbreak.any() and res.size:
            cb = np.cumsum(tbreak)
            res[(cb[w:] - cb[:-w]) > 0] = np.nan  # windows across a time break
        with np.errstate(invalid="ignore"):
            viol = np.flatnonzero(np.abs(res) > CONSISTENCY_TOL)
        for j in viol.tolist():
            win = slice(j, j + w + 1)
            code = 5 if repaired[win].any() else 4
            cw = cat[win]
            cat[win] = np.where(cw == 0, code, np.where((cw == 4) & (code == 5), 5, cw))
        # plausible following range
        with np.errstate(invalid="ignore", divide="ignore"):
            hw = gap / np.maximum(f["speed"], 0.1)
            core = present & (gap > FAR_GAP) & (hw > FAR_HEADWAY)
            exc = present & (hw > FAR_HEADWAY)
            low = present & (gap < MIN_GAP)
        for a, b in contiguous(exc):
            if core[a:b].any():
                seg = cat[a:b]
                cat[a:b] = np.where(seg == 0, 2, seg)
        cat = np.where((cat == 0) & low, 3, cat).astype(np.int8)
        state, acc_src = _acc_state(nf, i)
        lab = np.where(cat == 0, state.astype(np.int16), 10 + cat.astype(np.int16))
        segs = _segments(lab, tbreak)
        fpresent = np.isfinite(f["speed"])
        keep_segs = [(a, b, v) for a, b, v in segs
                     if v < 10 and (b - a - 1) * dt >= min_duration]
        res_setting, rank, set_note = _setting_for(nf, car, camp)
        fol.update(setting_rank=rank, setting_resolved=res_setting, acc_source=acc_src)
        spec = match_vehicle_spec(car, camp.specs) if camp.specs else None
        lspec = match_vehicle_spec(nf.name(lead), camp.specs) if camp.specs else None
        for a, b, v in segs:
            secs = float(fpresent[a:b].sum() * dt)
            rec = {"file": str(path), "follower": i, "car": car,
                   "t_start": float(t[a]), "t_end": float(t[b - 1]),
                   "duration_s": round((b - a - 1) * dt, 3)}
            if v >= 10:
                code = v - 10
                ft[_DROP_KEY[code]] += secs
                if code == 1 and not fpresent[a:b].any():
                    continue  # the follower itself not recorded: not follower time
                stretches.append({**rec, "kept": False, "acc": None, "run_id": None,
                                  "reason": _DROP[code]})
            elif (a, b, v) not in keep_segs:
                ft[f"short_{_KEEP_KEY[v]}"] += secs
                stretches.append({**rec, "kept": False, "acc": _ACC_META[v], "run_id": None,
                                  "reason": f"shorter than min_duration {min_duration:g} s"})
        if not keep_segs:
            reasons = sorted({s["reason"] for s in stretches
                              if s["file"] == str(path) and s["follower"] == i})
            skipped.append(_Skip(str(path), i, car, "no stretch of at least "
                                 f"{min_duration:g} s: " + "; ".join(reasons)))
            continue
        for k, who in ((i, "follower"), (lead, "predecessor")):
            fk = {q: c for q, c in filled[k].items() if c and q != "dropout"}
            if fk:
                notes.append(f"{who} (vehicle {k}): interpolated empty cells (gaps <= "
                             f"{bridge:g} s): " + ", ".join(f"{q} {c}" for q, c in fk.items()))
            if filled[k].get("dropout"):
                notes.append(f"{who} (vehicle {k}): {filled[k]['dropout']} samples of receiver "
                             f"dropouts (speed and position missing, <= {bridge_kinematic:g} s) "
                             "bridged: linear speed whose integral matches the distance between "
                             f"the positions at the ends within {CONSISTENCY_TOL:g} m")
        if set_note:
            notes.append(set_note)
        if tbreak.any():
            notes.append(f"the time jumps at {int(tbreak.sum())} row(s) (step off the "
                         f"median {dt:g} s): stretches end there")
        alt_src = str(f["alt_src"])
        if not alt_src:
            notes.append(f"no Alt{i} or U{i} column: road grade unavailable for {car}")
        elif alt_src == "U":
            notes.append(f"no Alt{i} column: road grade from U{i} (ENU up)")
        for si, (a0, b0, v_state) in enumerate(keep_segs, start=1):
            rid = f"{rid_stem}/v{lead}-v{i}" + (f"/s{si}" if len(keep_segs) > 1 else "")
            dur = (b0 - a0 - 1) * dt
            ft[_KEEP_KEY[v_state]] += float(fpresent[a0:b0].sum() * dt)
            stretches.append({"file": str(path), "follower": i, "car": car,
                              "t_start": float(t[a0]), "t_end": float(t[b0 - 1]),
                              "duration_s": round(dur, 3), "kept": True,
                              "acc": _ACC_META[v_state], "run_id": rid, "reason": None})
            rnotes = list(notes)
            if a0 > 0 or b0 < t.shape[0]:
                rnotes.append(f"stretch {si} of {len(keep_segs)}: t = {t[a0]:.1f}..{t[b0 - 1]:.1f}"
                              f" s ({dur:.1f} s) of {t[0]:.1f}..{t[-1]:.1f} s")
            sl = slice(a0, b0)
            vv = f["speed"][sl]
            lv = p["speed"][sl]
            x = arc_length(f["E"][sl], f["N"][sl], vv, dt=dt)
            g = gap[sl]
            lead_x = x + g
            moving = np.sum(0.5 * (vv[1:] + vv[:-1]) * dt)
            ratio = float(x[-1] / moving) if moving > 1.0 and has_pos else math.nan
            if math.isfinite(ratio) and abs(ratio - 1.0) > 0.01:
                rnotes.append(f"Speed{i} disagrees with the track E{i}/N{i}: path length / "
                              f"integral of speed = {ratio:.4f}")
            check_speed_units(vv, path, f"Speed{i}", dt=dt, x=x if has_pos else None)
            acc_a = derive_acceleration(vv, dt, cutoff)
            la = derive_acceleration(lv, dt, cutoff)
            exo = {}
            if grade and alt_src:
                exo["grade"] = grade_from_altitude(x, f["alt"][sl], grade_window, e=f["E"][sl],
                                                   n=f["N"][sl], pool=pools.get(alt_src))
            neg = np.flatnonzero(g < 0)
            if neg.size:
                rnotes.append(f"{gcol}: {neg.size} negative spacings (min {g.min():.2f} m; the "
                              "constant offset of IVS is not the exact bumper distance)")
            nrep = int(repaired[sl].sum())
            meta = {
                "format": "openacc", "file": str(path), "folder": path.parent.name,
                "date": nf.date.isoformat(), "car": car, "lead_car": nf.name(lead),
                "setting": nf.setting, "setting_rank": rank, "setting_resolved": res_setting,
                "acc": _ACC_META[v_state], "acc_source": acc_src, "acc_header": nf.acc,
                "setting_in_file": nf.setting, "position": i - 1, "vehicle_index": i,
                "lead_index": lead, "track": nf.track, "n_vehicles": nf.n_vehicles,
                "vehicle_order": list(nf.names), "gap_column": gcol,
                "ivs_offset": offset if math.isfinite(offset) else None,
                "gap_reconstructed": recon, "repaired_samples": nrep,
                "speed_position_ratio": ratio if math.isfinite(ratio) else None,
                "accel_cutoff_hz": cutoff, "accel_cutoff": cut_how,
                "accel_filter": f"zero-phase Butterworth order 2, cutoff {cutoff:.3g} Hz, "
                                "central differences",
                "grade_method": (f"altitude ({'Alt' if alt_src == 'alt' else 'U'}{i}) vs path "
                                 f"position, Savitzky-Golay order 2 over {grade_window:g} m")
                if grade and alt_src else None,
                "grade_available": bool(alt_src),
                "spacing_consistency_tol_m": CONSISTENCY_TOL,
                "spacing_consistency_window_s": CONSISTENCY_WINDOW,
                "stretch": si, "n_stretches": len(keep_segs),
                "vehicle_spec": spec, "lead_vehicle_spec": lspec,
                "vehicle_spec_file": camp.specs_file,
                "t_file_start": float(t[0]), "t_start": float(t[a0]), "t_end": float(t[b0 - 1]),
                "rows": [a0, b0 - 1], "cleaning": rnotes,
            }
            fol["runs"].append(rid)
            runs.append(Run(run_id=rid, t=t[sl], a=acc_a, command_kind="acceleration",
                            command=None, v=vv, x=x, lead_x=lead_x, lead_v=lv, lead_a=la,
                            exo=exo, meta=meta))
    for fol in followers:
        if fol["file"] != str(path):
            continue
        for k, v in fol["time_s"].items():
            time_acc[k] += v
        fol["time_s"] = {k: round(v, 3) for k, v in fol["time_s"].items()}
    return runs


_ACC_META: dict[int, bool | None] = {1: True, 0: False, -1: None}


def _solo_run(nf: NativeFile, rid_stem: str, i: int, sig: dict[int, dict[str, np.ndarray]],
              dt: float, min_duration: float, accel_cutoff: float, grade: bool,
              grade_window: float) -> list[Run]:
    """A follower without a recorded predecessor (``require_predecessor=False``):
    its own trajectory only, the longest stretch with speed and position."""
    f = sig[i]
    ok = np.isfinite(f["speed"])
    if bool(f["has_pos"]):
        ok &= np.isfinite(f["E"]) & np.isfinite(f["N"])
    st = [(a, b) for a, b in contiguous(ok) if b - a >= 2]
    if not st:
        return []
    a0, b0 = max(st, key=lambda ab: ab[1] - ab[0])
    if (b0 - a0 - 1) * dt < min_duration:
        return []
    sl = slice(a0, b0)
    v = f["speed"][sl]
    x = arc_length(f["E"][sl], f["N"][sl], v, dt=dt)
    exo = ({"grade": grade_from_altitude(x, f["alt"][sl], grade_window)}
           if grade and str(f["alt_src"]) else {})
    state, _ = _acc_state(nf, i)
    sv = set(np.unique(state[sl]).tolist())
    meta = {"format": "openacc", "file": str(nf.path), "folder": nf.path.parent.name,
            "date": nf.date.isoformat(), "car": nf.name(i), "lead_car": nf.name(i - 1),
            "setting": nf.setting, "acc": _ACC_META[sv.pop()] if len(sv) == 1 else None,
            "setting_in_file": nf.setting, "position": i - 1, "vehicle_index": i,
            "lead_index": i - 1, "track": nf.track, "n_vehicles": nf.n_vehicles,
            "vehicle_order": list(nf.names), "t_file_start": float(nf.t[0]),
            "accel_cutoff_hz": accel_cutoff,
            "t_start": float(nf.t[a0]), "t_end": float(nf.t[b0 - 1]),
            "cleaning": [*nf.notes, "predecessor not recorded: no lead_* signals"]}
    return [Run(run_id=f"{rid_stem}/v{i - 1}-v{i}", t=nf.t[sl],
                a=derive_acceleration(v, dt, accel_cutoff), v=v, x=x, exo=exo, meta=meta)]


def load_openacc_native(path: str | Path, command_kind: str | None = None,
                        **options: Any) -> list[Run]:
    """Runs of native OpenACC files: one closed-loop run per usable stretch of each
    follower (see the module doc), from a file or a campaign folder as distributed
    (every ``*.csv`` below it, recursively; notes, specification sheets, copyright
    and long-setting lists are recognised and skipped). The options are those of
    :func:`openacc_native_report`, which also says what was kept and dropped and why."""
    return openacc_native_report(path, command_kind, **options)[0]


def openacc_native_report(
    path: str | Path,
    command_kind: str | None = None,
    *,
    setting: str | Iterable[str | None] | None = None,
    car: str | Iterable[str] | None = None,
    track: str | Iterable[str] | None = None,
    acc: bool | str | None = None,
    bridge: float = 1.0,
    bridge_kinematic: float = 3.0,
    min_duration: float = 20.0,
    accel_cutoff: float | str = "auto",
    grade: bool = True,
    grade_window: float = 30.0,
    require_predecessor: bool = True,
    skip_foreign: bool = False,
) -> tuple[list[Run], dict[str, Any]]:
    """Runs of native OpenACC files and the loader's report: one closed-loop run per
    usable stretch of each follower (see the module doc), from a file or a folder
    (every ``*.csv`` below it, recursively, in natural order of the paths).

    The report: ``files`` (the data files read), ``non_data`` (``{"file", "kind"}``:
    notes, vehicle specifications, copyright, long-setting list, other files not
    ``*.csv``, recognised and skipped), ``not_native`` (other ``*.csv`` skipped under
    ``skip_foreign``), ``skipped`` (``{"file", "follower", "car", "reason"}``:
    followers without any run), ``stretches`` (every stretch of every follower, kept
    or dropped: ``file``, ``follower``, ``car``, ``t_start``, ``t_end``,
    ``duration_s``, ``kept``, ``acc``, ``run_id``, ``reason``), ``time_s`` (follower
    time in seconds by outcome: ``acc``, ``human``, ``unknown`` kept; ``missing``,
    ``short_acc``, ``short_human``, ``short_unknown`` (stretches shorter than
    ``min_duration``, by ACC state), ``not_following``, ``inconsistent``, ``repair_inconsistent``,
    ``spacing_below_min``, ``no_predecessor``, ``no_spacing`` dropped; per file in
    ``time_s_by_file``), ``followers`` (per file and follower: ``car``,
    ``lead_car``, ``setting``, ``setting_rank``, ``setting_resolved``, ``acc_header``,
    ``acc_source``, ``time_s`` by outcome as above, ``runs``: the run ids) and
    ``accel_cutoff`` (per file: the cut-off and how it was chosen).

    Filters (each a value or a list; a run is kept when it matches every filter
    given): ``setting`` (any documented spelling, matched against the raw setting
    and the per-car resolution of ``SL``; ``None``/``"none"`` for files without a
    setting), ``car`` (model names as in ``Vehicle_order``, any case), ``track``
    (``"dynamic"``, ``"handling"``), ``acc`` (True, False, or ``"unknown"``). It is
    an error when no run is left.

    ``bridge`` (s): longest run of empty cells interpolated; ``bridge_kinematic``
    (s): longest run of empty positions or spacings bridged with the speeds (see
    the module doc); ``min_duration`` (s): shortest stretch kept; ``accel_cutoff``
    (Hz, or ``"auto"``: chosen per file from the spectrum, see
    :func:`choose_accel_cutoff`): low-pass before differentiating the speed;
    ``grade=False`` skips ``exo["grade"]``; ``grade_window`` (m): the Savitzky–Golay
    window of the grade; ``require_predecessor=False`` also returns followers whose
    predecessor was not recorded (without ``lead_*`` signals); ``skip_foreign=True``
    skips (and reports) ``*.csv`` files in a folder that are not native OpenACC files
    instead of failing. ``command_kind`` must be ``None`` or ``"acceleration"`` (the
    runs have no command and are calibrated in closed loop).
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
    if isinstance(accel_cutoff, str):
        if accel_cutoff != "auto":
            raise ValueError(f"accel_cutoff: must be a number of Hz or 'auto', got "
                             f"{accel_cutoff!r}")
    elif not (isinstance(accel_cutoff, (int, float)) and math.isfinite(accel_cutoff)
              and accel_cutoff > 0):
        raise ValueError(f"accel_cutoff: must be > 0 Hz or 'auto', got {accel_cutoff!r}")
    if acc is not None and acc not in (True, False, "unknown"):
        raise ValueError(f"acc: must be True, False or 'unknown', got {acc!r}")
    want_setting = _as_set("setting", setting, _norm_setting)
    want_car = _as_set("car", car, _norm_name)
    want_track = _as_set("track", track, lambda v: str(v).strip().lower())
    root = path
    non_data: list[dict[str, str]] = []
    if path.is_dir():
        files = []
        for f in walk_files(path):
            kind = _side_kind(f)
            if kind is None:
                files.append(f)
            else:
                non_data.append({"file": str(f), "kind": kind})
        if not files:
            raise DataError(f"{path}: no *.csv data files in this folder or below"
                            + (f" (only {', '.join(Path(d['file']).name for d in non_data)})"
                               if non_data else ""))
    else:
        kind = _side_kind(path)
        if kind is not None and path.suffix.lower() == ".csv":
            raise DataError(f"{path}: is the campaign's {kind}, not a data file (give a data "
                            "file or the campaign folder)")
        files = [path]
    stems = Counter(f.stem for f in files)
    runs: list[Run] = []
    skipped: list[_Skip] = []
    foreign: list[str] = []
    stretches: list[dict[str, Any]] = []
    followers: list[dict[str, Any]] = []
    time_all: defaultdict[str, float] = defaultdict(float)
    by_file: dict[str, dict[str, float]] = {}
    cutoffs: dict[str, Any] = {}
    side: dict[Path, list[tuple[Path, str]]] = {}
    cache: dict[Path, _Campaign] = {}
    for f in files:
        if path.is_dir() and skip_foreign and not is_openacc_native(f):
            foreign.append(str(f))
            continue
        nf = read_openacc_native(f)
        camp = _campaign_for(f, root, side, cache)
        rid_stem = f.stem if stems[f.stem] == 1 else f"{f.parent.name}/{f.stem}"
        tf: defaultdict[str, float] = defaultdict(float)
        info: dict[str, Any] = {}
        runs += _follower_runs(nf, rid_stem, bridge=bridge, bridge_kinematic=bridge_kinematic,
                               min_duration=min_duration, accel_cutoff=accel_cutoff,
                               grade=grade, grade_window=grade_window,
                               require_predecessor=require_predecessor, skipped=skipped,
                               camp=camp, stretches=stretches, time_acc=tf, file_info=info,
                               followers=followers)
        by_file[str(f)] = {k: round(v, 3) for k, v in tf.items()}
        cutoffs[str(f)] = info
        for k, v in tf.items():
            time_all[k] += v
    report: dict[str, Any] = {"files": [str(f) for f in files if str(f) not in foreign],
                              "not_native": foreign, "non_data": non_data,
                              "skipped": [vars(s) for s in skipped],
                              "stretches": stretches, "followers": followers,
                              "time_s": {k: round(v, 3) for k, v in time_all.items()},
                              "time_s_by_file": by_file, "accel_cutoff": cutoffs}
    total = len(runs)
    if want_setting is not None:
        runs = [r for r in runs
                if _norm_setting(r.meta["setting"]) in want_setting
                or (r.meta.get("setting_resolved") is not None
                    and _norm_setting(r.meta["setting_resolved"]) in want_setting)]
    if want_car is not None:
        runs = [r for r in runs if _norm_name(r.meta["car"]) in want_car]
    if want_track is not None:
        runs = [r for r in runs if r.meta["track"] in want_track]
    if acc is not None:
        want = None if acc == "unknown" else bool(acc)
        runs = [r for r in runs if r.meta["acc"] is want]
    if not runs:
        what = ", ".join(f"{k}={v!r}" for k, v in (("setting", setting), ("car", car),
                                                   ("track", track), ("acc", acc))
                         if v is not None)
        raise DataError(f"{path}: no follower runs"
                        + (f" match {what} (of {total})" if what else "")
                        + (f"; skipped: {skipped[0].reason}" if skipped and not total else ""))
    return runs, report
